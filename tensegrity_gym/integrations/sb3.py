"""Stable-Baselines3 adapter: train SB3 on a ``gymnasium.vector.VectorEnv`` directly.

:func:`make_sb3_vec_env` wraps a Gymnasium vector env -- the tensegrity envs' batched vector env
(``gymnasium.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")``: one physics
call steps all N copies) or a ``SyncVectorEnv`` of separate envs -- as an SB3 ``VecEnv``.
SB3 is imported when the adapter is first built, not at module import (the core install does
not need SB3).

Per-sub-env methods (SB3's ``VecEnv`` contract, ``indices`` = which sub-envs):

* a vector env of separate envs (``SyncVectorEnv``, anything with an ``envs`` list):
  ``get_attr`` / ``set_attr`` / ``env_method`` act on each selected sub-env (through
  ``get_wrapper_attr`` / ``set_wrapper_attr`` as SB3's ``DummyVecEnv`` does) and
  ``env_is_wrapped`` checks each sub-env's wrapper chain;
* the batched vector env has no sub-env objects: its copies share one object, so
  ``get_attr`` returns the shared value for each selected index (``np_random``: each copy's own
  generator), ``set_attr`` (the vector env's own ``set_attr``: validated, curriculum hooks
  such as ``terrain_difficulty`` set on the task, other names refused) and ``env_method`` act
  once on the shared object when ``indices``
  selects every copy (``env_method`` then splits a result with one entry per copy, e.g.
  ``render``) and raise ``ValueError`` naming the attribute when it selects only some (setting
  a shared attribute for one copy cannot be honoured; use separate envs for that);
  ``env_is_wrapped`` is ``False`` for every copy (no per-copy Gymnasium wrappers).
"""
from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["make_sb3_vec_env", "make_sb3_torch_vec_env", "LinearSchedule"]


class LinearSchedule:
    """SB3 schedule (a function of ``progress_remaining``, 1 at the start of training, 0 at the
    end) falling linearly from ``initial`` to 0: the zoo's ``lin_<x>``. A class of the installed
    package, so that a model pickled with it loads wherever ``tensegrity_gym`` is installed."""

    def __init__(self, initial: float):
        self.initial = float(initial)

    def __call__(self, progress_remaining: float) -> float:
        return progress_remaining * self.initial

    def __repr__(self):
        return f"lin_{self.initial:g}"

_SB3_CLASS = None
_SB3_TORCH_CLASS = None


def _reset(vec):
    """SB3 ``VecEnv.reset`` on the wrapped Gymnasium vector env ``vec.venv``: the seeds and options
    SB3 set since the last reset (``seed()`` / ``set_options()``) are passed on, then cleared."""
    seeds = vec._seeds if any(s is not None for s in vec._seeds) else None
    opts = vec._options[0] if vec._options and vec._options[0] else None
    obs, _ = vec.venv.reset(seed=seeds, options=opts)
    vec._reset_seeds()
    vec._reset_options()
    return obs


def _build_class():
    from stable_baselines3.common.env_util import is_wrapped
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    class GymnasiumVectorToSB3(VecEnv):
        """SB3 ``VecEnv`` over a gymnasium ``VectorEnv`` (see :func:`make_sb3_vec_env`)."""

        def __init__(self, venv):
            from gymnasium.vector import AutoresetMode
            # the adapter resets ended envs itself right after their last step: an env that already
            # reset them in that step (same_step) would be reset twice
            if venv.metadata.get("autoreset_mode") == AutoresetMode.SAME_STEP:
                raise ValueError("make_sb3_vec_env: the adapter resets ended envs itself; build the vector env with "
                                 "autoreset_mode='next_step' (the default) or 'disabled', not 'same_step'")
            self.venv = venv
            super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
            self._actions = None

        # ------------------------------------------------------------ stepping
        def reset(self):
            return _reset(self)

        def step_async(self, actions):
            self._actions = actions

        def step_wait(self):
            obs, rew, term, trunc, info = self.venv.step(self._actions)
            done = term | trunc
            infos = [{} for _ in range(self.num_envs)]
            for k, v in info.items():
                if k.startswith("_"):
                    continue
                m = info.get("_" + k)
                for i in range(self.num_envs):
                    if m is None or m[i]:
                        infos[i][k] = v[i]
            obs = np.array(obs, copy=True)
            if done.any():
                for i in np.flatnonzero(done):
                    infos[i]["terminal_observation"] = obs[i].copy()
                    infos[i]["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
                new_obs, _ = self.venv.reset(options={"reset_mask": done.copy()})
                obs[done] = new_obs[done]
            return obs, np.asarray(rew, np.float32), done, infos

        def close(self):
            self.venv.close()

        def get_images(self):
            frames = self.venv.render()
            return list(frames) if frames is not None else [None] * self.num_envs

        # ------------------------------------------------------------ per-sub-env access
        def _sub_envs(self):
            envs = getattr(self.venv, "envs", None)
            return list(envs) if envs is not None else None

        def _all(self, idx) -> bool:
            return sorted(int(i) for i in idx) == list(range(self.num_envs))

        def get_attr(self, attr_name: str, indices=None) -> list[Any]:
            idx = self._get_indices(indices)
            subs = self._sub_envs()
            if subs is not None:
                return [subs[i].get_wrapper_attr(attr_name) for i in idx]
            if attr_name == "np_random" and hasattr(self.venv, "np_random_list"):
                rngs = self.venv.np_random_list
                return [rngs[i] for i in idx]
            batched = self._batched_api()
            if batched is not None and attr_name in getattr(batched.task, "CURRICULUM_HOOKS", {}):
                vals = batched.get_attr(attr_name)
                return [vals[i] for i in idx]
            val = getattr(self.venv, attr_name)
            return [val for _ in idx]

        def _batched_api(self):
            """The batched vector env under the wrappers when it validates ``set_attr`` (the
            tensegrity envs' :class:`~tensegrity_gym.envs.vector_rules.VectorApi`), else None."""
            from ..envs.vector_rules import VectorApi
            env = getattr(self.venv, "unwrapped", self.venv)
            return env if isinstance(env, VectorApi) and hasattr(env, "task") else None

        def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
            idx = list(self._get_indices(indices))
            subs = self._sub_envs()
            if subs is not None:
                for i in idx:
                    subs[i].set_wrapper_attr(attr_name, value)
                return
            if not self._all(idx):
                raise ValueError(f"set_attr({attr_name!r}, indices={idx}): the {self.num_envs} copies of the "
                                 "batched vector env share this attribute; set it for all copies "
                                 "(indices=None) or use a vector env of separate envs")
            batched = self._batched_api()
            if batched is not None:       # validated; a curriculum hook reaches the task
                batched.set_attr(attr_name, value)
                return
            setattr(self.venv, attr_name, value)

        def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
            idx = list(self._get_indices(indices))
            subs = self._sub_envs()
            if subs is not None:
                return [subs[i].get_wrapper_attr(method_name)(*method_args, **method_kwargs) for i in idx]
            if not self._all(idx):
                raise ValueError(f"env_method({method_name!r}, indices={idx}): the {self.num_envs} copies of the "
                                 "batched vector env are one object; call it for all copies (indices=None) "
                                 "or use a vector env of separate envs")
            result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
            if isinstance(result, (list, tuple)) and len(result) == self.num_envs:
                return [result[i] for i in idx]
            return [result for _ in idx]

        def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
            idx = self._get_indices(indices)
            subs = self._sub_envs()
            if subs is not None:
                return [is_wrapped(subs[i], wrapper_class) for i in idx]
            return [False for _ in idx]

    return GymnasiumVectorToSB3


def make_sb3_vec_env(vector_env):
    """Wrap a ``gymnasium.vector.VectorEnv`` (e.g. ``gymnasium.make_vec("TensegrityShape-v0",
    num_envs=64, vectorization_mode="vector_entry_point")``) as a Stable-Baselines3
    ``VecEnv`` so that SB3 trains on the batched env directly::

        venv = make_sb3_vec_env(gymnasium.make_vec("TensegrityShape-v0", num_envs=64,
                                                   vectorization_mode="vector_entry_point"))
        PPO("MlpPolicy", venv).learn(100_000)

    SB3 resets finished envs in the same step and passes the last observation of the
    episode as ``info["terminal_observation"]`` (with ``info["TimeLimit.truncated"]``). The
    adapter does this with a masked reset (``options={"reset_mask": done}``, which
    Gymnasium >= 1.1 vector envs support) right after a step in which envs finished, so the
    wrapped env's own next-step autoreset never fires. Infos become a list of per-env dicts.
    ``seed(s)`` seeds env i with ``s + i`` at the next reset. ``get_attr``, ``set_attr``,
    ``env_method`` and ``env_is_wrapped`` act per sub-env (see the module docstring).
    """
    global _SB3_CLASS
    if _SB3_CLASS is None:
        _SB3_CLASS = _build_class()
    return _SB3_CLASS(vector_env)


def _build_torch_class():
    import torch
    from gymnasium import spaces

    class TorchVectorToSB3(_SB3_CLASS):
        """SB3 ``VecEnv`` over a device-resident torch vector env (see :func:`make_sb3_torch_vec_env`)."""

        def __init__(self, venv, info_keys=()):
            super().__init__(venv)
            sp = venv.single_observation_space
            self.observation_space = spaces.Box(sp.low.astype(np.float32), sp.high.astype(np.float32),
                                                sp.shape, np.float32)
            self.info_keys = tuple(info_keys)
            self._obs_size = int(np.prod(sp.shape))

        def _host_obs(self, obs):
            return obs.to(torch.float32).cpu().numpy()

        def reset(self):
            return self._host_obs(_reset(self))

        def step_async(self, actions):
            self._actions = torch.as_tensor(np.asarray(actions), device=self.venv.device)   # one host -> device copy

        def step_wait(self):
            obs, rew, term, trunc, info = self.venv.step(self._actions)
            N, D = self.num_envs, self._obs_size
            cols = [obs.reshape(N, D), rew[:, None].to(obs.dtype), term[:, None].to(obs.dtype),
                    trunc[:, None].to(obs.dtype)]
            widths = []
            for k in self.info_keys:
                if k not in info:
                    raise ValueError(f"info_keys: {k!r} is not in the env's step info (it has "
                                     f"{sorted(x for x in info if not x.startswith('_'))})")
                v = info[k].reshape(N, -1).to(obs.dtype)
                cols.append(v)
                cols.append(info["_" + k][:, None].to(obs.dtype))
                widths.append((k, v.shape[1], info[k].shape[1:]))
            host = torch.cat(cols, dim=1).cpu().numpy()           # ONE device -> host copy per step
            obs_np = host[:, :D].astype(np.float32).reshape((N,) + self.observation_space.shape)
            rew_np = host[:, D].astype(np.float32)
            term_np, trunc_np = host[:, D + 1] != 0, host[:, D + 2] != 0
            infos = [{} for _ in range(N)]
            o = D + 3
            for k, w, shape in widths:
                vals = host[:, o:o + w].reshape((N,) + tuple(shape))
                has = host[:, o + w] != 0
                o += w + 1
                for i in np.flatnonzero(has):
                    infos[i][k] = vals[i]
            done = term_np | trunc_np
            if done.any():
                for i in np.flatnonzero(done):
                    infos[i]["terminal_observation"] = obs_np[i].copy()
                    infos[i]["TimeLimit.truncated"] = bool(trunc_np[i] and not term_np[i])
                new_obs, _ = self.venv.reset(options={"reset_mask": torch.as_tensor(done, device=self.venv.device)})
                obs_np[done] = self._host_obs(new_obs)[done]     # a second copy only when an env finished
            return obs_np, rew_np, done, infos

    return TorchVectorToSB3


def make_sb3_torch_vec_env(vector_env, info_keys=()):
    """Wrap a device-resident torch vector env (``gymnasium.make_vec("TensegrityRoll-v0",
    num_envs=N, vectorization_mode="vector_entry_point", backend="torch", device=...)``) as a
    Stable-Baselines3 ``VecEnv``. SB3 works on NumPy arrays, so the adapter copies between
    device and host, and only this:

    * ``step_async``: the (N, na) action array, host -> device, one copy;
    * ``step_wait``: ONE device -> host copy of one packed (N, obs_size + 3 + ...) tensor holding
      the observations, rewards, ``terminated`` and ``truncated`` flags and the ``info_keys``
      infos (default none: infos stay on the device; e.g. ``info_keys=("reward_forward",)``
      adds those columns and their ``"_key"`` masks); when an env finished, a masked reset on the device and a second
      copy of the reset observations (SB3 resets in the same step, with
      ``info["terminal_observation"]`` and ``info["TimeLimit.truncated"]``);
    * ``reset``: the observations, one copy.

    Observations reach SB3 as float32 (the adapter's ``observation_space`` is float32 whatever
    the env's ``dtype``), rewards as float32. ``get_attr`` / ``set_attr`` / ``env_method`` as
    :func:`make_sb3_vec_env`."""
    global _SB3_CLASS, _SB3_TORCH_CLASS
    if _SB3_CLASS is None:
        _SB3_CLASS = _build_class()
    if _SB3_TORCH_CLASS is None:
        _SB3_TORCH_CLASS = _build_torch_class()
    for k in info_keys:
        if not isinstance(k, str):
            raise ValueError(f"info_keys: expected info key names, got {k!r}")
    return _SB3_TORCH_CLASS(vector_env, info_keys)
