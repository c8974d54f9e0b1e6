"""Algorithms and hyperparameters: the algorithm registry, the hyperparameter files in
rl-baselines3-zoo's format (keyed by env id) and their translation into SB3 constructor
arguments, with checks that name the key and the value.

The package ships its files under ``hyperparams/`` (installed or in a checkout alike);
``--conf-file`` names one of them relative to that folder (``time_to_policy/ppo.yml``) or a file
of the user's own (a path, absolute or relative to the working directory).
"""
from __future__ import annotations

import importlib
import inspect
import math
import sys
from pathlib import Path
from typing import Any

from tensegrity_gym.core.checks import check_count
from tensegrity_gym.integrations.sb3 import LinearSchedule

from .parsing import did_you_mean, find_file, read_yaml, safe_literal, shipped_files

#: the hyperparameter files shipped with the package
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"

# ---------------------------------------------------------------------- algorithms
_SB3_ALGOS = {"a2c": "A2C", "ddpg": "DDPG", "dqn": "DQN", "ppo": "PPO", "sac": "SAC", "td3": "TD3"}
_CONTRIB_ALGOS = {"tqc": "TQC", "trpo": "TRPO", "ars": "ARS", "crossq": "CrossQ", "qrdqn": "QRDQN"}
OFF_POLICY = {"ddpg", "dqn", "sac", "td3", "tqc", "crossq", "qrdqn"}


def algo_names() -> list[str]:
    return sorted(_SB3_ALGOS) + sorted(_CONTRIB_ALGOS)


def get_algo(name: str):
    """The SB3 (or sb3-contrib) class of algorithm ``name`` (lower case: ppo, sac, td3, ...)."""
    key = name.lower()
    if key in _SB3_ALGOS:
        return getattr(importlib.import_module("stable_baselines3"), _SB3_ALGOS[key])
    if key in _CONTRIB_ALGOS:
        try:
            mod = importlib.import_module("sb3_contrib")
        except ImportError:
            raise ValueError(f"--algo {name}: needs sb3-contrib (pip install sb3-contrib)") from None
        return getattr(mod, _CONTRIB_ALGOS[key])
    raise ValueError(f"--algo: unknown {name!r}; choose one of {algo_names()}")



# ---------------------------------------------------------------------- hyperparameter files
def shipped_hyperparams_files() -> list[str]:
    """The names of the shipped hyperparameter files, relative to :data:`HYPERPARAMS_DIR`
    (``ppo.yml``, ``time_to_policy/ppo.yml``, ...): the names ``--conf-file`` takes."""
    return shipped_files(HYPERPARAMS_DIR)


def find_hyperparams_file(conf_file: str | Path) -> Path:
    """The file ``--conf-file`` names: a file of the user's own, else the shipped file of that
    name relative to :data:`HYPERPARAMS_DIR` (``time_to_policy/ppo.yml``); see :func:`.parsing.find_file`."""
    return find_file(conf_file, HYPERPARAMS_DIR, "--conf-file")


def load_hyperparams_file(path: str | Path) -> dict:
    """The mapping from env id to hyperparameters in the zoo-format file ``path``."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"hyperparameter file {path} does not exist")
    data = read_yaml(path) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping from env id to hyperparameters")
    return data


def shipped_entries(algo: str, env_id: str) -> list[str]:
    """The shipped files (names as :func:`shipped_hyperparams_files`) of algorithm ``algo`` (file
    name starting with it) that hold an entry for ``env_id``."""
    out = []
    for name in shipped_hyperparams_files():
        if Path(name).name.startswith(algo.lower()) and env_id in load_hyperparams_file(HYPERPARAMS_DIR / name):
            out.append(name)
    return out


def hyperparams_for(algo: str, env_id: str, conf_file: str | Path | None = None) -> tuple[dict, str]:
    """Hyperparameters of ``env_id`` from ``conf_file`` (:func:`find_hyperparams_file`), by default
    the shipped ``<algo>.yml``; returns (dict, source description).

    A missing file is an error (FileNotFoundError naming it), also the default one of an algorithm
    the package ships none for. A file without an entry for ``env_id`` gives its ``default``
    entry if it has one, else SB3's defaults (plus ``--hyperparams``), with a warning on stderr
    that names the shipped files holding an entry for ``env_id``.
    """
    if conf_file:
        path = find_hyperparams_file(conf_file)
    else:
        path = HYPERPARAMS_DIR / f"{algo.lower()}.yml"
        if not path.is_file():
            raise FileNotFoundError(f"no hyperparameter file for --algo {algo}: the package ships "
                                    f"{', '.join(shipped_hyperparams_files())} (in {HYPERPARAMS_DIR}); pass "
                                    "--conf-file FILE (rl-baselines3-zoo format, keyed by env id)")
    data = load_hyperparams_file(path)
    if env_id in data:
        return dict(data[env_id] or {}), f"{path}:{env_id}"
    if "default" in data:
        return dict(data["default"] or {}), f"{path}:default"
    hint = shipped_entries(algo, env_id)
    print(f"warning: {path} has no entry for {env_id} (and no 'default' entry): training with SB3's defaults"
          + (f"; the shipped files with an entry for it: {', '.join(hint)} (--conf-file {hint[0]})" if hint else ""),
          file=sys.stderr)
    return {}, f"SB3 defaults ({env_id} not in {path})"


def _schedule(value, key: str):
    """zoo's ``lin_<x>`` linear schedule (from x to 0), a number, or a callable."""
    if isinstance(value, str):
        if value.startswith("lin_"):
            try:
                v0 = float(value[4:])
            except ValueError:
                raise ValueError(f"{key}: bad linear schedule {value!r} (expected lin_<number>)") from None
            return LinearSchedule(v0)
        try:
            return float(value)
        except ValueError:
            raise ValueError(f"{key}: expected a number or lin_<number>, got {value!r}") from None
    return value


UNSUPPORTED_ZOO_KEYS = ("frame_stack", "env_wrapper", "vec_env_wrapper", "callback")


def resolve_hyperparams(algo: str, hp: dict) -> dict:
    """Turn a zoo entry into pieces: model kwargs, n_timesteps, n_envs, normalize kwargs, env_kwargs,
    policy. Raises on keys this trainer does not implement (rather than ignoring them)."""
    hp = dict(hp)
    out: dict[str, Any] = {}
    for k in UNSUPPORTED_ZOO_KEYS:
        if k in hp:
            raise ValueError(f"hyperparameter {k!r} (rl-zoo wrapper/callback key) is not supported by "
                             "agents/train.py; use rl_zoo3.train for it or remove it")
    out["n_timesteps"] = check_hp_count(hp.pop("n_timesteps", 1e5), "n_timesteps", 1)
    out["n_envs"] = check_hp_count(hp.pop("n_envs", 1), "n_envs", 1)
    out["policy"] = hp.pop("policy", "MlpPolicy")
    out["env_kwargs"] = check_env_kwargs(hp.pop("env_kwargs", {}))
    norm = hp.pop("normalize", False)
    if isinstance(norm, str):
        norm = safe_literal(norm)
    if norm is True:
        norm = {}
    elif norm is False or norm is None:
        norm = None
    elif not isinstance(norm, dict):
        raise ValueError(f"normalize: expected true/false or dict(...), got {norm!r}")
    check_normalize_kwargs(norm)
    if norm is not None and "gamma" in hp and "gamma" not in norm:
        norm["gamma"] = hp["gamma"]
    out["normalize"] = norm
    for key in ("policy_kwargs", "replay_buffer_kwargs"):
        if key in hp and isinstance(hp[key], str):
            hp[key] = safe_literal(hp[key])
    for key in ("learning_rate", "clip_range", "clip_range_vf"):
        if key in hp:
            hp[key] = _schedule(hp[key], key)
    if "train_freq" in hp and isinstance(hp["train_freq"], list):
        hp["train_freq"] = tuple(hp["train_freq"])
    if "noise_type" in hp:
        out["noise"] = (str(hp.pop("noise_type")).strip(), float(hp.pop("noise_std", 0.1)))
    else:
        out["noise"] = None
        hp.pop("noise_std", None)
    for k in ("n_envs", "n_timesteps"):
        hp.pop(k, None)
    check_model_kwargs(algo, hp)
    check_schedules_and_arch(hp)
    out["model_kwargs"] = hp
    return out


#: hyperparameters that are fractions in [0, 1] and counts (minimum) in SB3's algorithms
_FRACTIONS = ("gamma", "gae_lambda", "tau", "exploration_fraction", "exploration_initial_eps",
              "exploration_final_eps", "target_update_interval_fraction")
_COUNTS = {"n_steps": 1, "batch_size": 2, "n_epochs": 1, "buffer_size": 1, "learning_starts": 0,
           "target_update_interval": 1, "policy_delay": 1}


def check_model_kwargs(algo: str, kwargs: dict) -> None:
    """ValueError naming ``--hyperparams`` and the key for a keyword ``algo``'s constructor does
    not take (with the nearest names), a fraction outside [0, 1] or a count that is not an
    integer >= its minimum: SB3 would answer with a TypeError/AssertionError traceback, or train
    to NaN (gamma = 2). Counts given as integral floats (``buffer_size=1e6``) become ints in
    ``kwargs``."""
    cls = get_algo(algo)
    params = inspect.signature(cls.__init__).parameters
    names = [p for p in params if p not in ("self", "policy", "env")]
    for key, value in kwargs.items():
        if key not in names:
            raise ValueError(f"--hyperparams: {cls.__name__} takes no hyperparameter {key!r}{did_you_mean(key, names)}")
        if key in _FRACTIONS and not (isinstance(value, (int, float)) and not isinstance(value, bool)
                                      and 0.0 <= value <= 1.0):
            raise ValueError(f"--hyperparams: {key} must be a number in [0, 1], got {value!r}")
        if key in _COUNTS:   # an integral float such as buffer_size=1e6 is the integer it names
            kwargs[key] = check_count(value, f"--hyperparams: {key}", _COUNTS[key])
        default = params[key].default
        if isinstance(default, (int, float)) and not isinstance(default, bool) and isinstance(value, str):
            raise ValueError(f"--hyperparams: {key} must be a number ({cls.__name__}'s default is {default!r}), "
                             f"got {value!r}")


def check_hp_count(value, key: str, minimum: int) -> int:
    """A count hyperparameter (``n_timesteps``, ``n_envs``) as an int: an integer or an integral
    number (``1e5``, ``"1e5"`` from a YAML file); ValueError naming ``--hyperparams`` and the key."""
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise ValueError(f"--hyperparams: {key} must be an integer >= {minimum}, got {value!r}") from None
    return check_count(value, f"--hyperparams: {key}", minimum)


def check_env_kwargs(value) -> dict:
    """``env_kwargs`` as a dict (None: empty); ValueError naming it for anything else."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ValueError(f"--hyperparams: env_kwargs must be a dict of env keyword arguments, got {value!r}")
    return dict(value)


def check_normalize_kwargs(norm) -> None:
    """ValueError naming ``normalize`` and the key for a keyword SB3's ``VecNormalize`` does not
    take, and for ``clip_obs`` / ``clip_reward`` that are not positive numbers (a clip of -1 turns
    every observation into -1), ``epsilon`` not positive, ``gamma`` outside [0, 1]."""
    if not norm:
        return
    from stable_baselines3.common.vec_env import VecNormalize
    names = [p for p in inspect.signature(VecNormalize.__init__).parameters if p not in ("self", "venv")]
    for key, value in norm.items():
        if key not in names:
            raise ValueError(f"--hyperparams: normalize takes no key {key!r}{did_you_mean(str(key), names)} "
                             f"(VecNormalize's keywords: {names})")
        if key in ("clip_obs", "clip_reward", "epsilon"):
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0
            if not ok:
                raise ValueError(f"--hyperparams: normalize {key} must be a positive finite number, got {value!r}")
        if key in ("norm_obs", "norm_reward", "training") and not isinstance(value, bool):
            raise ValueError(f"--hyperparams: normalize {key} must be true or false, got {value!r}")
        if key == "gamma" and not (isinstance(value, (int, float)) and not isinstance(value, bool)
                                   and 0.0 <= value <= 1.0):
            raise ValueError(f"--hyperparams: normalize gamma must be a number in [0, 1], got {value!r}")


def check_schedules_and_arch(kwargs: dict) -> None:
    """ValueError naming ``--hyperparams`` and the key for a ``learning_rate`` / ``clip_range`` /
    ``clip_range_vf`` that is not positive (a number, or the start of a ``lin_`` schedule), and a
    ``policy_kwargs`` ``net_arch`` layer that is not a positive integer (``[0]``: no layer at all)."""
    for key in ("learning_rate", "clip_range", "clip_range_vf"):
        if key not in kwargs or kwargs[key] is None or (callable(kwargs[key]) and not isinstance(kwargs[key],
                                                                                                LinearSchedule)):
            continue
        v = kwargs[key].initial if isinstance(kwargs[key], LinearSchedule) else kwargs[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise ValueError(f"--hyperparams: {key} must be a positive finite number or lin_<positive number>, "
                             f"got {v!r}")
    pk = kwargs.get("policy_kwargs")
    if pk is None:
        return
    if not isinstance(pk, dict):
        raise ValueError(f"--hyperparams: policy_kwargs must be dict(...), got {pk!r}")
    arch = pk.get("net_arch")
    if arch is None:
        return
    layers = []
    if isinstance(arch, dict):
        for name, sub in arch.items():
            layers += [(f"net_arch[{name!r}]", i, x) for i, x in enumerate(sub if isinstance(sub, (list, tuple)) else [sub])]
    elif isinstance(arch, (list, tuple)):
        for i, x in enumerate(arch):
            if isinstance(x, dict):
                for name, sub in x.items():
                    layers += [(f"net_arch[{i}][{name!r}]", j, y)
                               for j, y in enumerate(sub if isinstance(sub, (list, tuple)) else [sub])]
            else:
                layers.append(("net_arch", i, x))
    else:
        raise ValueError(f"--hyperparams: policy_kwargs net_arch must be a list of layer sizes, got {arch!r}")
    for where, i, x in layers:
        if isinstance(x, bool) or not isinstance(x, int) or x < 1:
            raise ValueError(f"--hyperparams: policy_kwargs {where} entry {i} is {x!r}; layer sizes must be "
                             "integers >= 1")

