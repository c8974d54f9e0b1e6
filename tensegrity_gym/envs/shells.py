"""The Gymnasium shells around a :class:`~tensegrity_gym.envs.base.BatchedTask`: the single env
(B = 1) and the vector env (B = ``num_envs``, selectable autoreset mode, per-env seeding)."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import gymnasium as gym
from gymnasium import spaces
from gymnasium.utils import seeding

from ..core.checks import check_count, check_frame_size
from ..rewards import combine
from .pickling import picklable_state
from .vector_rules import VectorApi, check_reset_called, check_seed_value, reset_mask_option
from .base import BatchedTask
from .validate import check_action

__all__ = ["TaskEnv", "TaskVectorEnv", "registered_max_episode_steps"]


def _spaces(task: BatchedTask) -> tuple[spaces.Box, spaces.Box]:
    """(action space, observation space) of one copy of ``task``: actions in [-1, 1]^na,
    observations within the task's ``obs_low`` / ``obs_high`` (default unbounded), float32."""
    low = getattr(task, "obs_low", None)
    high = getattr(task, "obs_high", None)
    obs = spaces.Box(-np.inf if low is None else low.astype(np.float32),
                     np.inf if high is None else high.astype(np.float32), (task.observation_size,), np.float32)
    return spaces.Box(-1.0, 1.0, (task.action_size,), np.float32), obs


def _scalar(v):
    v = np.asarray(v)
    return v.item() if v.ndim == 0 else v


# ---------------------------------------------------------------------- single env shell
def _for_task(cls, task_class: type, env_id: str, doc: str, module: str) -> type:
    """The subclass of the shell ``cls`` for one task: named after ``env_id``
    (``TensegrityRoll-v0`` -> ``TensegrityRollEnv`` / ``TensegrityRollVectorEnv``), building
    ``task_class`` from the constructor's ``**kwargs``, documented by ``doc``; ``module`` is the
    defining module's ``__name__`` (where pickle and the registry's entry point find the class)."""
    vector = issubclass(cls, gym.vector.VectorEnv)
    name = env_id.split("-")[0] + ("VectorEnv" if vector else "Env")
    # gymnasium.vector.VectorEnv listed as a direct base too: libraries that pick their wrapper from
    # the class's __bases__ (skrl's wrap_env) then recognise a Gymnasium vector env
    bases = (cls, gym.vector.VectorEnv) if vector else (cls,)
    return type(name, bases, {"__doc__": doc, "__module__": module, "__qualname__": name,
                               "task_class": task_class, "env_id": env_id})


class TaskEnv(gym.Env):
    """``gymnasium.Env`` shell around a :class:`BatchedTask` with B = 1.

    A task's env is ``TaskEnv.for_task(task_class, env_id, doc, __name__)``: its constructor builds
    ``task_class(num_envs=1, **kwargs)``.
    ``step`` validates the action (:func:`check_action`), steps the task, returns
    ``(obs, reward, terminated, truncated, info)`` with ``truncated = info["diverged"]`` (the
    time limit is added at registration by ``gymnasium.make``'s ``TimeLimit``).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 50}
    #: the task the constructor builds; its arguments are the constructor's ``**kwargs``
    task_class: type | None = None
    #: the registered id (window title, registered time limit)
    env_id: str = ""

    for_task = classmethod(_for_task)

    def __init__(self, render_mode: str | None = None, width: int = 480, height: int = 480, **kwargs):
        self._init_task(self.task_class(num_envs=1, **kwargs), render_mode, width, height, title=self.env_id)

    def _init_task(self, task: BatchedTask, render_mode: str | None, width: int = 480, height: int = 480,
                   title: str | None = None):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode: unknown {render_mode!r}; choose one of {self.metadata['render_modes']} or None")
        self.task = task
        task.record_path = render_mode is not None
        self.render_mode = render_mode
        self.metadata = dict(self.metadata)
        self.metadata["render_fps"] = int(round(1.0 / task.control_dt))
        self.action_space, self.observation_space = _spaces(task)
        self._width, self._height, self._title = *check_frame_size(width, height), title
        self._renderer = None
        self._needs_reset = True

    @property
    def dt(self) -> float:
        """Control step, s (as Gymnasium's MuJoCo envs' ``dt``)."""
        return self.task.control_dt

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        info = self.task.reset(np.array([0]), [self.np_random], options)
        self._needs_reset = False
        obs = self.task.observe()[0]
        if self.render_mode == "human":
            self.render()
        return obs, {k: ({n: x[0] for n, x in v.items()} if isinstance(v, dict) else _scalar(v[0]))
                     for k, v in info.items()}

    def step(self, action):
        a = check_action(action, (self.task.action_size,), clip=self.task.clip_actions)
        terms, terminated, infos = self.task.act(a[None, :])
        # reward: combine(terms)[0], summed here in Python floats (IEEE doubles, same order: same value)
        reward = None
        for v in terms.values():
            x = float(v[0])
            reward = x if reward is None else reward + x
        if reward is None:
            raise ValueError("combine: no reward terms given")
        info = {k: (v.item(0) if type(v) is np.ndarray and v.ndim == 1 else _scalar(v[0]))
                for k, v in infos.items()}
        for name, v in terms.items():
            info[f"reward_{name}"] = float(v[0])
        obs = self.task.observe()[0]
        truncated = bool(info.get("diverged", False))
        if self.render_mode == "human":
            self.render()
        return obs, reward, bool(terminated[0]), truncated, info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; construct the env with "
                            "render_mode='rgb_array' or 'human'")
            return None
        frame = self._frame(0)
        if self.render_mode == "human":
            self._renderer.show(frame, self.metadata["render_fps"])
            return None
        return frame

    def _frame(self, i: int) -> np.ndarray:
        from ..tools.rendering import make_renderer
        if self._renderer is None:
            self._renderer = make_renderer(self._width, self._height, title=self._title)
        return self._renderer.render(**self.task.render_data(i))

    def __getstate__(self):   # picklable after render(): the renderer is made again when needed
        return picklable_state(self.__dict__)

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


# ---------------------------------------------------------------------- vector env shell
def per_env_seeds(seed, N: int) -> list:
    """The vector envs' seeding rule (Gymnasium's): ``seed`` an int gives env i ``seed + i``, a
    list gives each env its own (None: keep), None keeps every env's; returns the N seeds (None
    where kept). ValueError naming ``seed`` for anything else or a list of another length."""
    if seed is None:
        return [None] * N
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
        return [int(seed) + i for i in range(N)]
    if isinstance(seed, (bool, np.bool_, str, bytes)) or not hasattr(seed, "__len__"):
        raise ValueError(f"seed: expected an int, None or a list of {N} seeds, got {seed!r:.80}")
    seeds = list(seed)
    if len(seeds) != N:
        raise ValueError(f"seed: expected an int, None or a list of {N} seeds, got {len(seeds)}")
    return [check_seed_value(s, i) for i, s in enumerate(seeds)]


def reseed(rngs: list, seed, mask: np.ndarray) -> None:
    """Vector-env seeding (:func:`per_env_seeds`): only the envs selected by ``mask`` (N,) bool
    and given a seed get a new generator, in place in ``rngs``."""
    N = len(rngs)
    seeds = per_env_seeds(seed, N)
    for i in range(N):
        if mask[i] and seeds[i] is not None:
            rngs[i] = seeding.np_random(int(seeds[i]))[0]


def registered_max_episode_steps(env_id: str) -> int | None:
    """``max_episode_steps`` of a registered id (None if unregistered or unlimited)."""
    from gymnasium.envs.registration import registry
    spec = registry.get(env_id)
    return None if spec is None else spec.max_episode_steps


def episode_limit(max_episode_steps, env_id: str) -> int | None:
    """The vector envs' truncation limit in control steps: ``"registered"`` looks up ``env_id``'s,
    None means no limit, else an integer >= 1 (ValueError naming ``max_episode_steps`` otherwise)."""
    if isinstance(max_episode_steps, str) and max_episode_steps == "registered":
        return registered_max_episode_steps(env_id)
    if max_episode_steps is None:
        return None
    return check_count(max_episode_steps, "max_episode_steps", 1, "control steps; or None")


class VectorSeeding(VectorApi):
    """What the NumPy and the torch vector envs share: the control step ``dt`` (s), the per-env
    generators ``np_random_list`` (``self._rngs``), the partial-reset options
    (:func:`~tensegrity_gym.envs.vector_rules.reset_mask_option`), ``autoreset_mode`` and
    ``call`` / ``get_attr`` / ``set_attr`` (:class:`~tensegrity_gym.envs.vector_rules.VectorApi`)."""

    @property
    def dt(self) -> float:
        """Control step, s."""
        return self.task.control_dt

    @property
    def np_random_list(self) -> list[np.random.Generator]:
        """Per-env random generators (the host's; used at reset)."""
        return self._rngs

    def _attr_setters(self) -> dict:
        out = super()._attr_setters()
        env_id = getattr(self, "env_id", "") or getattr(self, "ENV_ID", "")
        out["max_episode_steps"] = lambda v: setattr(self, "max_episode_steps", episode_limit(v, env_id))
        return out

    def _reset_mask(self, options: dict | None) -> tuple[np.ndarray, dict]:
        """(mask (N,) bool of the envs to reset, the other options) from ``options['reset_mask']``
        or ``options['env_idx']`` (default: all; a torch tensor is brought to the host)."""
        return reset_mask_option(options, self.num_envs)


class TaskVectorEnv(VectorSeeding, gym.vector.VectorEnv):
    """``gymnasium.vector.VectorEnv`` shell around a :class:`BatchedTask` with B = ``num_envs``.

    * One batched physics call per ``step`` for all envs (no per-env loop, no subprocess).
    * Autoreset: ``autoreset_mode`` (Gymnasium 1.x's ``AutoresetMode``, also in
      ``metadata["autoreset_mode"]``): ``"next_step"`` (default): after an env returns
      ``terminated`` or ``truncated``, its next ``step`` ignores its action, resets it and
      returns the reset observation with reward 0 and ``terminated = truncated = False``;
      ``"same_step"``: the step that ends an env resets it and returns the reset observation,
      the last one in ``info["final_obs"]`` (an object array, None for the others, as
      ``SyncVectorEnv``) and that step's info in ``info["final_info"]``; ``"disabled"``: the
      caller resets ended envs (``reset(options={"reset_mask": ...})``); stepping one first is
      Gymnasium's ``ResetNeeded``.
    * Seeding: ``reset(seed=s)`` seeds env i with ``s + i``; ``reset(seed=[s0, s1, ...])``
      seeds each env; each env has its own ``np.random.Generator`` created exactly as a
      single env's ``np_random``, so env i reproduces a single env reset with the same seed.
    * ``reset(options={"reset_mask": mask})`` resets only the envs where ``mask`` (bool (N,)) is
      true; ``reset(options={"env_idx": idx})`` only the envs ``idx`` (int indices).
    * ``call`` / ``get_attr`` / ``set_attr``: :class:`~tensegrity_gym.envs.vector_rules.VectorApi`.
    * Time limit: ``max_episode_steps`` (control steps) truncates each env. ``gymnasium.make_vec``
      passes the registered value; constructed directly, the default ``"registered"`` looks
      it up for ``env_id``; ``None`` disables it.
    * ``info``: Gymnasium's vector dict: every key an (N,) array with a boolean mask ``"_key"``.
    * ``render()``: tuple of (H, W, 3) frames, one per env (``render_mode="rgb_array"``).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50,
                "autoreset_mode": gym.vector.AutoresetMode.NEXT_STEP}
    task_class: type | None = None     # as TaskEnv's
    env_id: str = ""
    for_task = classmethod(_for_task)

    def __init__(self, num_envs: int = 1, max_episode_steps="registered", render_mode: str | None = None,
                 width: int = 480, height: int = 480, autoreset_mode="next_step", **kwargs):
        self._init_task(self.task_class(num_envs=num_envs, **kwargs), self.env_id, max_episode_steps, render_mode,
                        width, height, title=self.env_id)
        self._init_autoreset(autoreset_mode)

    def _init_task(self, task: BatchedTask, env_id: str, max_episode_steps="registered",
                   render_mode: str | None = None, width: int = 480, height: int = 480, title: str | None = None):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode: the vector env supports {self.metadata['render_modes']} or None, "
                             f"got {render_mode!r}")
        self.task = task
        task.record_path = render_mode is not None
        self.num_envs = task.num_envs
        self.max_episode_steps = episode_limit(max_episode_steps, env_id)
        self.metadata = dict(self.metadata)
        self.metadata["render_fps"] = int(round(1.0 / task.control_dt))
        self.render_mode = render_mode
        self.single_action_space, self.single_observation_space = _spaces(task)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, self.num_envs)
        self._rngs: list[np.random.Generator] = [seeding.np_random(None)[0] for _ in range(self.num_envs)]
        self._autoreset = np.zeros(self.num_envs, bool)
        self._width, self._height, self._title = *check_frame_size(width, height), title
        self._renderers: dict[int, Any] = {}

    def _vector_info(self, infos: dict, mask: np.ndarray, out: dict | None = None) -> dict:
        """``infos`` as Gymnasium's vector info: per key an (N, ...) array holding the values of
        the envs in ``mask`` (zero elsewhere) and its ``"_" + key`` mask; into ``out`` (adding
        ``mask``'s envs) when given."""
        out = {} if out is None else out
        whole = bool(mask.all())     # every env (most steps): a copy, not a masked write into zeros
        for k, v in infos.items():
            if isinstance(v, dict):          # e.g. info["params"]: a nested vector dict
                out[k] = self._vector_info(v, mask, out.get(k))
                out["_" + k] = mask.copy() if "_" + k not in out else out["_" + k] | mask
                continue
            v = np.asarray(v)
            if k in out:
                out[k][mask] = v[mask] if v.shape[:1] == (self.num_envs,) else v
                out["_" + k] |= mask
            elif whole and v.shape[:1] == (self.num_envs,):
                out[k] = v.copy()
                out["_" + k] = mask.copy()
            else:
                arr = np.zeros((self.num_envs,) + v.shape[1:], dtype=v.dtype)
                arr[mask] = v[mask] if v.shape[:1] == (self.num_envs,) else v
                out[k] = arr
                out["_" + k] = mask.copy()
        return out

    def _reset_envs(self, idx: np.ndarray, options) -> dict:
        """Reset envs ``idx`` (int array); returns their infos as (N,) arrays (others zero)."""
        info = self.task.reset(idx, [self._rngs[i] for i in idx], options)
        full = {}
        for k, v in info.items():
            if isinstance(v, dict):
                full[k] = {}
                for n, x in v.items():
                    arr = np.zeros((self.num_envs,) + x.shape[1:], dtype=x.dtype)
                    arr[idx] = x
                    full[k][n] = arr
                continue
            v = np.asarray(v)
            arr = np.zeros((self.num_envs,) + v.shape[1:], dtype=v.dtype)
            arr[idx] = v
            full[k] = arr
        self.task.elapsed[idx] = 0
        self._autoreset[idx] = False
        return full

    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        super().reset(seed=None)
        mask, options = self._reset_mask(options)
        reseed(self._rngs, seed, mask)
        idx = np.flatnonzero(mask)
        info = self._reset_envs(idx, options or None)
        self._reset_called = True
        return self.task.observe().copy(), self._vector_info(info, mask)

    def step(self, actions):
        check_reset_called(self)
        N = self.num_envs
        a = check_action(actions, (N, self.task.action_size), clip=self.task.clip_actions, name="actions")
        reset_now = self._autoreset.copy()
        mode = self.autoreset_mode
        if mode is gym.vector.AutoresetMode.DISABLED and reset_now.any():
            raise gym.error.ResetNeeded(f"autoreset_mode='disabled': envs {np.flatnonzero(reset_now).tolist()} ended; "
                                        "reset them (reset(options={'reset_mask': mask})) before stepping them")
        # NEXT_STEP: envs to autoreset get zero actions in the physics step, then are reset (their step is discarded)
        if reset_now.any():
            a = a.copy()
            a[reset_now] = 0.0
        terms, terminated, infos = self.task.act(a)
        reward = combine(terms).astype(np.float64)
        terminated = np.asarray(terminated, bool).copy()
        diverged = np.asarray(infos.get("diverged", np.zeros(N, bool)), bool)
        truncated = diverged.copy()
        if self.max_episode_steps is not None:
            truncated |= self.task.elapsed >= self.max_episode_steps
        all_infos = dict(infos)
        for name, v in terms.items():
            all_infos[f"reward_{name}"] = v
        if mode is gym.vector.AutoresetMode.SAME_STEP:
            return self._same_step(reward, terminated, truncated, all_infos)
        step_mask = ~reset_now
        out = self._vector_info(all_infos, step_mask)
        if reset_now.any():
            idx = np.flatnonzero(reset_now)
            rinfo = self._reset_envs(idx, None)
            self._vector_info(rinfo, reset_now, out)
            reward[reset_now] = 0.0
            terminated[reset_now] = False
            truncated[reset_now] = False
        self._autoreset = terminated | truncated
        return self.task.observe().copy(), reward, terminated, truncated, out

    def _same_step(self, reward, terminated, truncated, all_infos):
        """SAME_STEP: the envs that ended are reset now; their last observation and step info go
        to ``info["final_obs"]`` / ``info["final_info"]`` (as ``SyncVectorEnv`` builds them) and
        their ``info`` entries are the reset's."""
        done = terminated | truncated
        obs = self.task.observe().copy()
        if not done.any():
            return obs, reward, terminated, truncated, self._vector_info(all_infos, np.ones(self.num_envs, bool))
        out = self._vector_info(all_infos, ~done)
        final_obs = np.full(self.num_envs, None, dtype=object)
        for i in np.flatnonzero(done):
            final_obs[i] = obs[i].copy()
        out["final_obs"], out["_final_obs"] = final_obs, done.copy()
        out["final_info"], out["_final_info"] = self._vector_info(all_infos, done), done.copy()
        rinfo = self._reset_envs(np.flatnonzero(done), None)
        self._vector_info(rinfo, done, out)
        return self.task.observe().copy(), reward, terminated, truncated, out

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; use render_mode='rgb_array'")
            return None
        from ..tools.rendering import make_renderer
        frames = []
        for i in range(self.num_envs):
            if i not in self._renderers:
                self._renderers[i] = make_renderer(self._width, self._height, title=self._title)
            frames.append(self._renderers[i].render(**self.task.render_data(i)))
        return tuple(frames)

    def __getstate__(self):   # picklable after render(): the renderers are made again when needed
        return picklable_state(self.__dict__)

    def close_extras(self, **kwargs):
        self._renderers.clear()

