"""The vector envs' rules shared by the NumPy and the torch shells: per-env seeds, no step before
``reset()``, the autoreset mode (Gymnasium 1.x's ``AutoresetMode``: ``NEXT_STEP`` default,
``SAME_STEP``, ``DISABLED``), the partial-reset options (``reset_mask``, ``env_idx``) and
Gymnasium's ``call`` / ``get_attr`` / ``set_attr`` on a batched env (one object for N copies)."""
from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode

from ..core.checks import check_options, is_integer

__all__ = ["check_seed_value", "check_reset_called", "check_autoreset_mode", "reset_mask_option",
           "VectorApi"]

# by name without case or separators: "next_step" / "NextStep" / "NEXT_STEP", "same_step", "disabled"
_MODES = {m.name.replace("_", "").lower(): m for m in AutoresetMode}
_NAMES = ["next_step", "same_step", "disabled"]


def check_seed_value(seed, i: int = 0):
    """``seed`` of env ``i`` as an int if it is a non-negative integer (not a bool, float or
    string), None kept; ValueError naming the env otherwise (the vector envs' seeding rule, as the
    single env's ``reset(seed=...)`` refuses them)."""
    if seed is None:
        return None
    if not is_integer(seed) or seed < 0:
        raise ValueError(f"seed: env {i}: expected a non-negative int or None, got {seed!r}")
    return int(seed)


def check_reset_called(env) -> None:
    """Gymnasium's ``ResetNeeded`` when a vector env is stepped before its first ``reset()`` (as
    ``gymnasium.make`` does for a single env)."""
    if not getattr(env, "_reset_called", False):
        raise ResetNeeded("Cannot call env.step() before calling env.reset()")


def check_autoreset_mode(mode) -> AutoresetMode:
    """``mode`` as a ``gymnasium.vector.AutoresetMode``: the enum itself or its value
    (``"next_step"``, ``"same_step"``, ``"disabled"``; case and ``-`` / ``_`` ignored);
    ValueError naming the three otherwise.

    * ``NEXT_STEP``: an env that ended is reset by the following ``step()`` (its action ignored;
      reward 0, ``terminated = truncated = False``).
    * ``SAME_STEP``: it is reset inside the step that ended it; the step returns the reset
      observation, the episode's last observation in ``info["final_obs"]`` and its step info in
      ``info["final_info"]`` (masks ``"_final_obs"`` / ``"_final_info"``).
    * ``DISABLED``: never reset by ``step()``; the caller resets ended envs with
      ``reset(options={"reset_mask": mask})`` (or ``{"env_idx": idx}``) before stepping them.
    """
    if isinstance(mode, AutoresetMode):
        return mode
    if isinstance(mode, str):
        key = mode.strip().lower().replace("-", "").replace("_", "")
        if key in _MODES:
            return _MODES[key]
    raise ValueError(f"autoreset_mode: expected one of {_NAMES} or a gymnasium.vector.AutoresetMode, "
                     f"got {mode!r}")


def _host(x):
    """A torch tensor brought to the host as a NumPy array; anything else as given."""
    if hasattr(x, "detach") and hasattr(x, "cpu"):
        return x.detach().cpu().numpy()
    return x


def reset_mask_option(options, num_envs: int) -> tuple[np.ndarray, dict]:
    """(mask (N,) bool of the envs to reset, the other options) from ``reset(options=...)``:
    ``"reset_mask"`` (Gymnasium: a bool (N,) array or tensor) or ``"env_idx"`` (the
    device-env convention of ManiSkill, Isaac Lab and skrl: indices, an int array, list or
    tensor); neither: every env. ValueError for both, a wrong shape or dtype, or an index out of
    range."""
    N = num_envs
    options = check_options(options)
    mask = options.pop("reset_mask", None)
    idx = options.pop("env_idx", None)
    if mask is not None and idx is not None:
        raise ValueError("options: give 'reset_mask' or 'env_idx', not both")
    if idx is not None:
        idx = np.asarray(_host(idx))
        if idx.ndim > 1 or (idx.size and not np.issubdtype(idx.dtype, np.integer)):
            raise ValueError(f"options['env_idx']: expected a 1-D array of env indices, got {idx.dtype} {idx.shape}")
        idx = idx.reshape(-1).astype(np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= N):
            raise ValueError(f"options['env_idx']: indices must lie in [0, {N}), got {idx.tolist()}")
        mask = np.zeros(N, bool)
        mask[idx] = True
        return mask, options
    if mask is None:
        return np.ones(N, bool), options
    mask = np.asarray(_host(mask))
    if mask.shape != (N,) or mask.dtype != np.bool_:
        raise ValueError(f"options['reset_mask']: expected a bool array of shape ({N},), "
                         f"got {mask.dtype} {mask.shape}")
    return mask, options


class VectorApi:
    """Gymnasium's ``VectorEnv`` methods over the N copies of a batched env, which are one object:

    * ``call(name, *args, **kwargs)``: calls the method ``name`` once (or reads the attribute);
      a result that is a tuple or list with one entry per copy (``render()``'s frames) is
      returned as that tuple, any other result repeated N times (Gymnasium returns one result
      per sub-env);
    * ``get_attr(name)``: ``call(name)``; ``"np_random"`` gives each copy's own generator, a
      task's curriculum hook (``terrain_difficulty``, ``slope_range``) the task's value;
    * ``set_attr(name, values)``: one value (or a list / tuple of N equal values) set on the
      shared object, validated: ``max_episode_steps``, ``autoreset_mode`` and the task's
      curriculum hooks (forwarded to the task: ``terrain_difficulty`` to
      ``task.set_terrain_difficulty``, ``slope_range`` to ``task.set_slope_range``);
      ``"np_random"`` takes one generator per copy. Different values for different copies of a
      shared attribute are a ValueError (use a ``SyncVectorEnv`` of single envs for that), and
      so is any other name (read-only, such as ``num_envs``, or unknown).
    Sets ``autoreset_mode`` (attribute and ``metadata["autoreset_mode"]``, as ``SyncVectorEnv``).
    """

    #: attributes whose one value is itself a sequence (``slope_range = (low, high)``): a list /
    #: tuple of numbers is that one value, N values are a list of N sequences
    SEQUENCE_VALUED = ("slope_range",)
    #: how ``step`` autoresets (:func:`check_autoreset_mode`)
    autoreset_mode: AutoresetMode = AutoresetMode.NEXT_STEP

    def _init_autoreset(self, mode) -> None:
        self.autoreset_mode = check_autoreset_mode(mode)
        self.metadata = dict(self.metadata)
        self.metadata["autoreset_mode"] = self.autoreset_mode

    def _per_copy(self, result) -> tuple:
        if isinstance(result, (list, tuple)) and len(result) == self.num_envs:
            return tuple(result)
        return tuple(result for _ in range(self.num_envs))

    def _attr_setters(self) -> dict:
        """The names ``set_attr`` writes (besides ``"np_random"``): name -> a function that
        validates and sets one value. Here ``autoreset_mode`` and the task's curriculum hooks
        (``task.CURRICULUM_HOOKS``: e.g. ``terrain_difficulty``, ``slope_range``)."""
        out = {"autoreset_mode": self._init_autoreset}
        task = getattr(self, "task", None)
        for name, method in getattr(task, "CURRICULUM_HOOKS", {}).items():
            out[name] = getattr(task, method)
        return out

    def _task_hook(self, name: str) -> bool:
        """Whether ``name`` is one of the task's curriculum hooks (read and set on the task)."""
        return name in getattr(getattr(self, "task", None), "CURRICULUM_HOOKS", {})

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        """The method ``name`` called with ``args`` / ``kwargs`` (an attribute: its value; a task's
        curriculum hook: the task's value), as a tuple of N per-copy results."""
        if name == "np_random":
            return tuple(self._rngs)
        if self._task_hook(name) and not hasattr(type(self), name):
            return self._per_copy(getattr(self.task, name))
        fn = getattr(self, name)
        return self._per_copy(fn(*args, **kwargs) if callable(fn) else fn)

    def get_attr(self, name: str) -> tuple[Any, ...]:
        """The attribute ``name`` of each copy (a tuple of N)."""
        return self.call(name)

    def set_attr(self, name: str, values: list[Any] | tuple[Any, ...] | Any) -> None:
        """Set the attribute ``name``: one value for every copy, or a list / tuple of N values
        (equal ones for a shared attribute; one ``numpy.random.Generator`` per copy for
        ``"np_random"``). Only the names of :meth:`_attr_setters` are set, each validated; the
        task's curriculum hooks (``terrain_difficulty``, ``slope_range``) act on the task from
        the next resets. Any other name is a ValueError (a read-only attribute such as
        ``num_envs``, or an unknown one: setting it would change nothing)."""
        N = self.num_envs
        setters = self._attr_setters()
        if name != "np_random" and name not in setters:
            what = "is read-only on" if isinstance(name, str) and hasattr(self, name) else "is not an attribute of"
            raise ValueError(f"set_attr({name!r}): {what} {type(self).__name__}; settable: "
                             f"{sorted(['np_random', *setters])}")
        one = not isinstance(values, (list, tuple)) or (
            name in self.SEQUENCE_VALUED and not all(isinstance(v, (list, tuple, np.ndarray)) for v in values))
        per = [values] * N if one else list(values)
        if len(per) != N:
            raise ValueError(f"set_attr({name!r}): expected one value or {N} values, got {len(per)}")
        if name == "np_random":
            for i, g in enumerate(per):
                if not isinstance(g, np.random.Generator):
                    raise ValueError(f"set_attr('np_random'): env {i}: expected a numpy.random.Generator, "
                                     f"got {g!r:.80}")
            self._rngs[:] = per
            return
        first = per[0]
        for v in per[1:]:
            same = v is first
            if not same:
                try:
                    same = bool(np.all(v == first))
                except Exception:
                    same = False
            if not same:
                raise ValueError(f"set_attr({name!r}): the {N} copies of this batched env share the attribute; "
                                 "give one value (or N equal ones), or use a SyncVectorEnv of single envs")
        setters[name](first)
