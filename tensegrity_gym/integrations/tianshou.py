"""tianshou adapter: a tensegrity vector env as a ``tianshou.env.BaseVectorEnv``.

tianshou's ``Collector`` steps a ``BaseVectorEnv`` (``step(actions, env_ids)`` returning NumPy
arrays and an array of per-env info dicts) and resets the envs that ended itself
(``reset(env_id=ids)``). :func:`make_tianshou_env` builds the NumPy vector env or the torch
device env with ``autoreset_mode="disabled"`` and wraps it in :class:`TianshouVectorEnv`, which
maps those two calls onto one batched ``step`` and a partial ``reset(options={"reset_mask":
...})``; tensors from the torch env come back as NumPy arrays (tianshou's batches are NumPy).

Limits: a batched env steps every copy at once, so ``step`` must be given every env (tianshou
does that when collecting by steps, ``collect(n_step=...)``, what its on-policy trainer does
for training); a subset (``collect(n_episode=...)`` with more envs than episodes) is a
ValueError. For evaluation by episodes, use tianshou's standard route, a
``DummyVectorEnv([lambda: gymnasium.make(id) for _ in range(n)])`` of single envs.

tianshou is imported when the adapter is built (the core install does not need it).

Shapes: observations (N, obs_size) float32 (torch env: its dtype as NumPy), rewards (N,)
float64, terminated / truncated (N,) bool, infos an (N,) object array of dicts with
``"env_id"``.
"""
from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["TianshouVectorEnv", "make_tianshou_env"]

_CLASS = None
_SPACE_KEYS = {"action_space": "single_action_space", "observation_space": "single_observation_space"}


def _np(x):
    """A torch tensor as a NumPy array on the host; anything else through ``np.asarray``."""
    if hasattr(x, "detach") and hasattr(x, "cpu"):
        return x.detach().cpu().numpy()
    return np.asarray(x)


def _infos(info: dict, ids) -> np.ndarray:
    """Gymnasium's vector info dict -> an object array of one dict per env in ``ids`` (the keys
    whose ``"_key"`` mask holds for that env, nested dicts kept flat by name)."""
    out = np.empty(len(ids), dtype=object)
    flat = {}
    for k, v in info.items():
        if k.startswith("_") or isinstance(v, dict) or k in ("final_obs", "final_info"):
            continue
        flat[k] = (_np(v), _np(info.get("_" + k, np.ones(len(_np(v)), bool))))
    for j, i in enumerate(ids):
        d = {"env_id": int(i)}
        for k, (v, m) in flat.items():
            if m[i]:
                d[k] = v[i]
        out[j] = d
    return out


def _build_class():
    from gymnasium.vector import AutoresetMode
    from tianshou.env import BaseVectorEnv

    class _TianshouVectorEnv(BaseVectorEnv):
        __doc__ = TianshouVectorEnv.__doc__

        def __init__(self, venv):
            # BaseVectorEnv.__init__ builds one worker per env; a batched env has none, so the
            # attributes the collector reads are set here
            if getattr(venv, "autoreset_mode", None) != AutoresetMode.DISABLED:
                raise ValueError("TianshouVectorEnv: tianshou's Collector resets ended envs itself; build the env "
                                 "with autoreset_mode='disabled' (or use make_tianshou_env), got "
                                 f"{getattr(venv, 'autoreset_mode', None)!r}")
            self.venv = venv
            self.env_num = self.wait_num = venv.num_envs
            self.timeout = None
            self.is_async = False
            self.waiting_conn, self.waiting_id = [], []
            self.ready_id = list(range(self.env_num))
            self.is_closed = False
            self._seed = None

        def get_env_attr(self, key: str, id=None) -> list[Any]:
            ids = self._wrap_id(id)
            if key in _SPACE_KEYS:
                value = getattr(self.venv, _SPACE_KEYS[key])
            elif key == "reward_range":
                value = (-float("inf"), float("inf"))
            else:
                value = getattr(self.venv, key, None)
            return [value for _ in ids]

        def set_env_attr(self, key: str, value: Any, id=None) -> None:
            if id is not None and len(self._wrap_id(id)) != self.env_num:
                raise ValueError(f"set_env_attr({key!r}): the copies of a batched env share it; set it for all envs")
            self.venv.set_attr(key, value)

        def _mask(self, ids) -> np.ndarray:
            mask = np.zeros(self.env_num, bool)
            mask[np.asarray(ids, dtype=np.int64)] = True
            return mask

        def reset(self, env_id=None, **kwargs):
            self._assert_is_not_closed()
            ids = np.asarray(self._wrap_id(env_id), dtype=np.int64)
            seed = kwargs.pop("seed", self._seed)
            self._seed = None
            options = dict(kwargs.pop("options", None) or {})
            options["reset_mask"] = self._mask(ids)
            obs, info = self.venv.reset(seed=seed, options=options)
            return _np(obs)[ids], _infos(info, ids)

        def step(self, action, id=None):
            self._assert_is_not_closed()
            ids = np.asarray(self._wrap_id(id), dtype=np.int64)
            if action is None:
                raise ValueError("action must be given (the batched env steps synchronously)")
            if len(ids) != self.env_num or not np.array_equal(np.sort(ids), np.arange(self.env_num)):
                raise ValueError(f"TianshouVectorEnv.step: the batched env steps all {self.env_num} envs at once, got "
                                 f"ids {ids.tolist()}; collect by steps (collect(n_step=...)), or evaluate episodes "
                                 "on a DummyVectorEnv of single envs")
            a = np.empty((self.env_num,) + np.shape(action)[1:], dtype=np.float32)
            a[ids] = _np(action)
            obs, rew, term, trunc, info = self.venv.step(a)
            return (_np(obs)[ids], _np(rew).astype(np.float64)[ids], _np(term)[ids], _np(trunc)[ids],
                    _infos(info, ids))

        def seed(self, seed=None):
            """Seeds for the next ``reset``: an int (env i: ``seed + i``), a list, or None."""
            self._seed = seed
            if seed is None:
                return [None] * self.env_num
            return [[s] for s in (list(seed) if isinstance(seed, (list, tuple)) else
                                  [seed + i for i in range(self.env_num)])]

        def render(self, **kwargs):
            return list(self.venv.call("render"))

        def close(self) -> None:
            if not self.is_closed:
                self.venv.close()
            self.is_closed = True

    _TianshouVectorEnv.__name__ = _TianshouVectorEnv.__qualname__ = "TianshouVectorEnv"
    return _TianshouVectorEnv


class TianshouVectorEnv:
    """``tianshou.env.BaseVectorEnv`` over a tensegrity vector env built with
    ``autoreset_mode="disabled"`` (see the module doc); ``TianshouVectorEnv(venv)`` returns an
    instance of a ``BaseVectorEnv`` subclass."""

    def __new__(cls, venv):
        global _CLASS
        if _CLASS is None:
            _CLASS = _build_class()
        return _CLASS(venv)


def make_tianshou_env(env_id: str = "TensegrityRoll-v0", num_envs: int = 8, backend: str = "numpy",
                      **env_kwargs):
    """``env_id`` with ``num_envs`` copies (``backend="numpy"``: the NumPy vector env;
    ``"torch"``: the device env, ``device`` / ``dtype`` in ``env_kwargs``) and autoreset
    disabled, as a :class:`TianshouVectorEnv`."""
    import gymnasium as gym
    import tensegrity_gym  # noqa: F401  (registers the ids)
    if backend == "torch":
        env_kwargs = {"backend": "torch", **env_kwargs}
    elif backend != "numpy":
        raise ValueError(f"backend: expected 'numpy' or 'torch', got {backend!r}")
    venv = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
                        autoreset_mode="disabled", **env_kwargs)
    return TianshouVectorEnv(venv)
