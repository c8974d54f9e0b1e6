"""Env construction for training and evaluation: registered ids with errors that name the
argument, and monitored SB3 vector envs: the project's batched vector env through the SB3
adapter when the env id has a ``vector_entry_point``, else SB3's ``make_vec_env``.
"""
from __future__ import annotations

import functools
import importlib
import inspect
import os
import re
import warnings

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import load_env_creator, registry

from tensegrity_gym.core.checks import is_integer
from tensegrity_gym.integrations.sb3 import make_sb3_torch_vec_env, make_sb3_vec_env

from .parsing import did_you_mean


def import_env_packages(packages=("tensegrity_gym",)):
    for p in packages:
        importlib.import_module(p)


def make_registered_env(env_id: str, **kwargs):
    """``gymnasium.make(env_id, **kwargs)`` after importing the env packages: the env factory of
    ``--vec-env subproc``, whose worker processes do not import ``tensegrity_gym`` otherwise (its
    ids would be unknown there). Module level, so that it pickles."""
    import_env_packages()
    return gym.make(env_id, **kwargs)


def has_vector_entry_point(env_id: str) -> bool:
    spec = registry.get(env_id)
    return spec is not None and spec.vector_entry_point is not None


def check_env_id(env_id: str):
    if env_id not in registry:
        close = [k for k in registry if env_id.lower().split("-")[0] in k.lower()][:5]
        raise ValueError(f"--env: {env_id!r} is not a registered Gymnasium id"
                         + (f" (did you mean {close}?)" if close else ""))


_UNEXPECTED = re.compile(r"unexpected keyword argument '([^']+)'")


def make_env(env_id: str, env_kwargs: dict, **extra):
    """``gymnasium.make(env_id, **extra, **env_kwargs)``; a keyword the env does not take is a
    ValueError naming ``--env-kwargs``, the key and the nearest accepted names (the env's own
    TypeError would reach a CLI user as a traceback)."""
    try:
        return gym.make(env_id, **extra, **env_kwargs)
    except TypeError as e:
        m = _UNEXPECTED.search(str(e))
        if m is None or m.group(1) not in env_kwargs:
            raise
        key = m.group(1)
        names = env_argument_names(env_id)
        raise ValueError(f"--env-kwargs: {env_id} takes no argument {key!r}{did_you_mean(key, names)}; its arguments: "
                         f"{', '.join(names)}") from None


def env_argument_names(env_id: str) -> list[str]:
    """The keyword arguments ``gymnasium.make(env_id, ...)`` accepts: the env class's named
    arguments and, where it forwards ``**kwargs`` to a task (``task_class``), the task's."""
    ep = registry[env_id].entry_point
    names: list[str] = []
    fn = load_env_creator(ep) if isinstance(ep, str) else ep
    while fn is not None:
        params = inspect.signature(fn).parameters.values()
        names += [p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
                  and p.name not in names and p.name not in ("self", "num_envs")]
        fn = getattr(fn, "task_class", None) if any(p.kind is p.VAR_KEYWORD for p in params) else None
    return names


def check_seed(seed: int, flag: str = "--seed", top: int = 2**32 - 1) -> int:
    """``seed`` if it is an integer in 0..``top``; ValueError naming ``flag`` otherwise (NumPy's
    and Gymnasium's own messages do not say which argument)."""
    if not is_integer(seed) or not 0 <= seed <= top:
        raise ValueError(f"{flag}: must be an integer in 0..{top}, got {seed!r}")
    return int(seed)


def probe_info_keys(env_id: str, env_kwargs: dict) -> tuple[list[str], list[str]]:
    """(scalar numeric info keys of one step, reward_* keys among them) of a single env."""
    env = make_env(env_id, env_kwargs)
    try:
        env.reset(seed=0)
        _, _, _, _, info = env.step(env.action_space.sample())
    finally:
        env.close()
    keys = []
    for k, v in info.items():
        if k.startswith("_") or k in ("TimeLimit.truncated", "terminal_observation", "episode"):
            continue
        if np.ndim(v) == 0 and isinstance(np.asarray(v).item(), (bool, int, float, np.number)):
            keys.append(k)
    return keys, [k for k in keys if k.startswith("reward_")]


def make_vec(env_id: str, n_envs: int, seed: int, env_kwargs: dict, vec_env: str = "auto",
             monitor_file: str | None = None, info_keywords: tuple = (), env_device: str = "cpu",
             env_dtype: str = "float32", info_keys: tuple = (), env_reset_sampling: str = "host"):
    """A monitored SB3 VecEnv of ``n_envs`` copies of ``env_id``, env i seeded with ``seed + i``.

    ``vec_env``: ``"batched"`` (the env's ``vector_entry_point``: one batched physics call per step,
    through :func:`tensegrity_gym.integrations.sb3.make_sb3_vec_env`), ``"torch"`` (the device-resident torch
    vector env on ``env_device`` in ``env_dtype`` with ``reset_sampling=env_reset_sampling``, through
    :func:`tensegrity_gym.integrations.sb3.make_sb3_torch_vec_env`, which copies ``info_keys`` to the host),
    ``"dummy"``, ``"subproc"``, or ``"auto"`` (batched when available, else dummy).
    """
    from stable_baselines3.common.vec_env import VecMonitor, DummyVecEnv, SubprocVecEnv
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    if vec_env == "auto":
        vec_env = "batched" if has_vector_entry_point(env_id) else "dummy"
    if vec_env == "batched":
        if not has_vector_entry_point(env_id):
            raise ValueError(f"--vec-env batched: {env_id} has no vector_entry_point")
        venv = make_sb3_vec_env(gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point",
                                             **env_kwargs))
        venv.seed(seed)
    elif vec_env == "torch":
        if not has_vector_entry_point(env_id):
            raise ValueError(f"--vec-env torch: {env_id} has no vector_entry_point")
        venv = make_sb3_torch_vec_env(gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point",
                                                   backend="torch", device=env_device, dtype=env_dtype,
                                                   reset_sampling=env_reset_sampling,
                                                   **env_kwargs), info_keys=tuple(info_keys))
        venv.seed(seed)
    elif vec_env in ("dummy", "subproc"):
        venv = sb3_make_vec_env(functools.partial(make_registered_env, env_id), n_envs=n_envs, seed=seed,
                                env_kwargs=env_kwargs,
                                vec_env_cls=DummyVecEnv if vec_env == "dummy" else SubprocVecEnv)
        # make_vec_env wraps each env in Monitor already; VecMonitor below writes the csv + keywords
    else:
        raise ValueError(f"--vec-env: unknown {vec_env!r}; choose auto, batched, torch, dummy or subproc")
    if monitor_file:
        os.makedirs(os.path.dirname(monitor_file), exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "already wrapped with a Monitor" (dummy/subproc)
        venv = VecMonitor(venv, filename=monitor_file, info_keywords=tuple(info_keywords))
    return venv, vec_env

