"""Helpers shared by :mod:`agents.train` and :mod:`agents.evaluate` (no ``eval`` anywhere).

* parsing of ``--env-kwargs`` / ``--hyperparams`` values and of rl-baselines3-zoo's string
  forms (``"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"``, ``"lin_3e-4"``) with a
  restricted AST walker instead of ``eval``;
* the algorithm registry;
* env construction: the project's batched vector env through the SB3 adapter when the env id
  has a ``vector_entry_point``, else SB3's ``make_vec_env``; VecMonitor; VecNormalize;
* run-directory layout and package versions.
"""
from __future__ import annotations

import ast
import difflib
import functools
import importlib
import json
import math
import os
import platform
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np

from tensegrity_gym.integrations.sb3 import LinearSchedule
from tensegrity_gym.io import atomic

REPO_ROOT = Path(__file__).resolve().parent.parent
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


# ---------------------------------------------------------------------- safe parsing
def _torch_name(dotted: str):
    """Whitelisted names allowed in zoo strings: torch activation / optimizer classes."""
    import torch
    parts = dotted.split(".")
    if parts[0] in ("th", "torch"):
        parts = parts[1:]
    if len(parts) == 2 and parts[0] == "nn":
        obj = getattr(torch.nn, parts[1], None)
        if isinstance(obj, type) and issubclass(obj, torch.nn.Module):
            return obj
    if len(parts) == 2 and parts[0] == "optim":
        obj = getattr(torch.optim, parts[1], None)
        if isinstance(obj, type) and issubclass(obj, torch.optim.Optimizer):
            return obj
    raise ValueError(f"name {dotted!r} is not allowed here; only torch activation/optimizer classes "
                     "such as nn.Tanh, nn.ReLU, th.optim.Adam")


def safe_literal(text: str) -> Any:
    """Parse a Python-like literal that may use ``dict(...)`` calls and ``nn.<Activation>`` names.

    Accepts: numbers, strings, True/False/None, lists, tuples, dicts, ``dict(k=v, ...)``,
    unary minus, and whitelisted torch class names. Anything else (function calls, attribute
    access on other modules, comprehensions, ...) raises ValueError. Never calls ``eval``.
    """
    try:
        tree = ast.parse(text.strip(), mode="eval").body
    except SyntaxError as e:
        raise ValueError(f"cannot parse {text!r}: {e.msg}") from None

    def conv(n):
        if isinstance(n, ast.Constant):
            return n.value
        if isinstance(n, ast.UnaryOp) and isinstance(n.op, (ast.USub, ast.UAdd)):
            v = conv(n.operand)
            if not isinstance(v, (int, float)):
                raise ValueError(f"cannot negate {v!r} in {text!r}")
            return -v if isinstance(n.op, ast.USub) else v
        if isinstance(n, ast.List):
            return [conv(e) for e in n.elts]
        if isinstance(n, ast.Tuple):
            return tuple(conv(e) for e in n.elts)
        if isinstance(n, ast.Dict):
            return {conv(k): conv(v) for k, v in zip(n.keys, n.values)}
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "dict" and not n.args:
            return {kw.arg: conv(kw.value) for kw in n.keywords}
        if isinstance(n, ast.Name) and n.id in ("True", "False", "None"):
            return {"True": True, "False": False, "None": None}[n.id]
        if isinstance(n, (ast.Name, ast.Attribute)):
            return _torch_name(ast.unparse(n))
        raise ValueError(f"unsupported expression {ast.unparse(n)!r} in {text!r} (only literals, dict(...) "
                         "and torch class names are accepted)")

    return conv(tree)


def parse_value(text: str) -> Any:
    """Value of a command-line ``key:value`` / ``key=value``: JSON, else a Python literal, else the string."""
    s = text.strip()
    for lit in ({"true": True, "false": False, "null": None, "none": None},):
        if s.lower() in lit:
            return lit[s.lower()]
    try:
        return json.loads(s)
    except (json.JSONDecodeError, ValueError):
        pass
    try:
        return ast.literal_eval(s)
    except (ValueError, SyntaxError):
        return s


def parse_kv_list(items: list[str] | None, sep: str, what: str) -> dict:
    """``["a:1", "b:rest_length"]`` -> ``{"a": 1, "b": "rest_length"}``; a single JSON object is accepted too."""
    out: dict = {}
    if not items:
        return out
    if len(items) == 1 and items[0].strip().startswith("{"):
        try:
            d = json.loads(items[0])
        except json.JSONDecodeError as e:
            raise ValueError(f"{what}: invalid JSON object {items[0]!r}: {e}") from None
        if not isinstance(d, dict):
            raise ValueError(f"{what}: expected a JSON object, got {items[0]!r}")
        return d
    for item in items:
        if sep not in item:
            raise ValueError(f"{what}: expected key{sep}value, got {item!r}")
        k, v = item.split(sep, 1)
        k = k.strip()
        if not k:
            raise ValueError(f"{what}: empty key in {item!r}")
        out[k] = parse_value(v)
    return out


# ---------------------------------------------------------------------- hyperparameters (zoo format)
def read_yaml(path: str | Path):
    """The YAML document in ``path``; ValueError naming the file, the line and the problem for a
    file that is not valid YAML or not UTF-8 text (PyYAML's parser traceback otherwise)."""
    import yaml
    path = Path(path)
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text (UTF-8) file") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise ValueError(f"{path}: not valid YAML{where}: {problem}") from None


#: keys every config.yaml written by agents.train holds
RUN_CONFIG_KEYS = ("algo", "env", "env_kwargs", "seed", "n_envs", "n_timesteps", "hyperparams_raw",
                   "hyperparams_resolved")


def read_run_config(path: str | Path) -> dict:
    """The ``config.yaml`` of a run directory as a dict; ValueError naming the file for an empty
    file, one that is not a mapping, or one that lacks a key agents.train writes."""
    path = Path(path)
    cfg = read_yaml(path)
    if not isinstance(cfg, dict):
        raise ValueError(f"{path}: {'empty' if cfg is None else 'not a mapping of settings'}; expected the "
                         "config.yaml agents.train writes")
    missing = [k for k in RUN_CONFIG_KEYS if k not in cfg]
    if missing:
        raise ValueError(f"{path}: missing {missing}; expected the config.yaml agents.train writes")
    if not isinstance(cfg["env_kwargs"] or {}, dict) or not isinstance(cfg["hyperparams_resolved"] or {}, dict):
        raise ValueError(f"{path}: env_kwargs and hyperparams_resolved must be mappings")
    return cfg


#: the module names under which models trained from a checkout (``python -m agents.train``) pickled
#: their ``lin_`` schedules (the class ``_LinearSchedule`` of this module, now
#: :class:`tensegrity_gym.integrations.sb3.LinearSchedule`): an installed package has no ``agents``
_CHECKOUT_MODULES = ("agents", "agents.common")


#: the schedule class under the name models trained from a checkout pickled it by (``agents`` importable)
_LinearSchedule = LinearSchedule


class _LegacySchedules:
    """Stand-in for the module ``agents.common`` of a checkout while a model is unpickled: only
    the schedule class, under its old name."""
    _LinearSchedule = LinearSchedule


def _load_with_checkout_names(Algo, path, kwargs):
    """``Algo.load`` with the checkout's module names (:data:`_CHECKOUT_MODULES`) resolving to the
    schedule class for the duration of the load only (names already importable are left alone)."""
    added = [name for name in _CHECKOUT_MODULES if name not in sys.modules]
    for name in added:
        sys.modules[name] = _LegacySchedules
    try:
        return Algo.load(str(path), **kwargs)
    finally:
        for name in added:
            sys.modules.pop(name, None)


def load_model_file(Algo, path: str | Path, **kwargs):
    """``Algo.load(path, **kwargs)``; ValueError naming the file for a zip SB3 cannot load (a
    damaged or foreign zip, one without ``data``, a garbage ``policy.pth``). A model trained from a
    checkout before the schedule class moved into the package names its schedules as
    ``agents.common._LinearSchedule``; it is loaded with that name mapped to the class."""
    try:
        try:
            return Algo.load(str(path), **kwargs)
        except ModuleNotFoundError as e:
            if e.name not in _CHECKOUT_MODULES:
                raise
            return _load_with_checkout_names(Algo, path, kwargs)
    except (FileNotFoundError, IsADirectoryError):
        raise
    except Exception as e:  # noqa: BLE001 -- SB3/torch/zipfile raise many kinds; all mean "not a model"
        raise ValueError(f"{path}: not a loadable {Algo.__name__} model ({type(e).__name__}: "
                         f"{' '.join(str(e).split())[:200]})") from None


def load_vecnormalize_file(path: str | Path, venv=None):
    """VecNormalize statistics from the pickle at ``path`` (attached to ``venv`` when given, as
    ``VecNormalize.load``; else as pickled); ValueError naming the file for anything that is not
    such a pickle."""
    import pickle
    from stable_baselines3.common.vec_env import VecNormalize
    try:
        if venv is not None:
            return VecNormalize.load(str(path), venv)
        with open(path, "rb") as f:
            vn = pickle.load(f)
    except (FileNotFoundError, IsADirectoryError):
        raise
    except Exception as e:  # noqa: BLE001 -- unpickling garbage raises many kinds
        raise ValueError(f"{path}: not VecNormalize statistics ({type(e).__name__}: "
                         f"{' '.join(str(e).split())[:200]})") from None
    if not isinstance(vn, VecNormalize):
        raise ValueError(f"{path}: holds a {type(vn).__name__}, not VecNormalize statistics")
    return vn


def arg_type(check, kind=float):
    """An argparse ``type=`` from a check of this package (``check(value)`` -> value or
    ValueError): the text is parsed by ``kind``, then checked; errors become argparse's one-line
    usage errors (exit code 2)."""
    import argparse

    def parse(text):
        try:
            v = kind(text)
        except (TypeError, ValueError, OverflowError):
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        try:
            return check(v)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e).split(": ", 1)[-1]) from None
    return parse


def load_hyperparams_file(path: str | Path) -> dict:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"hyperparameter file {path} does not exist")
    data = read_yaml(path) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping from env id to hyperparameters")
    return data


def hyperparams_for(algo: str, env_id: str, conf_file: str | Path | None = None) -> tuple[dict, str]:
    """Hyperparameters of ``env_id`` from ``agents/hyperparams/<algo>.yml`` (or ``conf_file``).

    Falls back to the ``default`` entry if present, else ``{}``. Returns (dict, source description).
    """
    path = Path(conf_file) if conf_file else HYPERPARAMS_DIR / f"{algo.lower()}.yml"
    if not path.exists():
        if conf_file:
            raise FileNotFoundError(f"--conf-file {path} does not exist")
        return {}, "SB3 defaults (no hyperparameter file)"
    data = load_hyperparams_file(path)
    if env_id in data:
        return dict(data[env_id] or {}), f"{path}:{env_id}"
    if "default" in data:
        return dict(data["default"] or {}), f"{path}:default"
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
    import inspect
    from tensegrity_gym.core.checks import check_count
    cls = get_algo(algo)
    params = inspect.signature(cls.__init__).parameters
    names = [p for p in params if p not in ("self", "policy", "env")]
    for key, value in kwargs.items():
        if key not in names:
            raise ValueError(f"--hyperparams: {cls.__name__} takes no hyperparameter {key!r}{_did_you_mean(key, names)}")
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
    from tensegrity_gym.core.checks import check_count
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
    import inspect
    from stable_baselines3.common.vec_env import VecNormalize
    names = [p for p in inspect.signature(VecNormalize.__init__).parameters if p not in ("self", "venv")]
    for key, value in norm.items():
        if key not in names:
            raise ValueError(f"--hyperparams: normalize takes no key {key!r}{_did_you_mean(str(key), names)} "
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


def to_yaml_safe(obj):
    """Config values as plain YAML/JSON types (classes by name, schedules as lin_x)."""
    if isinstance(obj, dict):
        return {str(k): to_yaml_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_yaml_safe(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, type):
        return f"{obj.__module__}.{obj.__qualname__}"
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    return repr(obj)


# ---------------------------------------------------------------------- envs
def import_env_packages(packages=("tensegrity_gym",)):
    for p in packages:
        importlib.import_module(p)


def make_registered_env(env_id: str, **kwargs):
    """``gymnasium.make(env_id, **kwargs)`` after importing the env packages: the env factory of
    ``--vec-env subproc``, whose worker processes do not import ``tensegrity_gym`` otherwise (its
    ids would be unknown there). Module level, so that it pickles."""
    import gymnasium as gym
    import_env_packages()
    return gym.make(env_id, **kwargs)


def has_vector_entry_point(env_id: str) -> bool:
    from gymnasium.envs.registration import registry
    spec = registry.get(env_id)
    return spec is not None and spec.vector_entry_point is not None


def check_env_id(env_id: str):
    from gymnasium.envs.registration import registry
    if env_id not in registry:
        close = [k for k in registry if env_id.lower().split("-")[0] in k.lower()][:5]
        raise ValueError(f"--env: {env_id!r} is not a registered Gymnasium id"
                         + (f" (did you mean {close}?)" if close else ""))


def _did_you_mean(key: str, names) -> str:
    """`` (did you mean a, b?)`` for the accepted names nearest ``key``, or ``""``."""
    close = difflib.get_close_matches(key, names, n=3)
    return f" (did you mean {', '.join(close)}?)" if close else ""


_UNEXPECTED = re.compile(r"unexpected keyword argument '([^']+)'")


def make_env(env_id: str, env_kwargs: dict, **extra):
    """``gymnasium.make(env_id, **extra, **env_kwargs)``; a keyword the env does not take is a
    ValueError naming ``--env-kwargs``, the key and the nearest accepted names (the env's own
    TypeError would reach a CLI user as a traceback)."""
    import gymnasium as gym
    try:
        return gym.make(env_id, **extra, **env_kwargs)
    except TypeError as e:
        m = _UNEXPECTED.search(str(e))
        if m is None or m.group(1) not in env_kwargs:
            raise
        key = m.group(1)
        names = env_argument_names(env_id)
        raise ValueError(f"--env-kwargs: {env_id} takes no argument {key!r}{_did_you_mean(key, names)}; its arguments: "
                         f"{', '.join(names)}") from None


def env_argument_names(env_id: str) -> list[str]:
    """The keyword arguments ``gymnasium.make(env_id, ...)`` accepts: the env class's named
    arguments and, where it forwards ``**kwargs`` to a task (``task_class``), the task's."""
    import inspect
    from gymnasium.envs.registration import load_env_creator, registry
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
    from tensegrity_gym.core.checks import is_integer
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
    import gymnasium as gym
    from stable_baselines3.common.vec_env import VecMonitor, DummyVecEnv, SubprocVecEnv
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    if vec_env == "auto":
        vec_env = "batched" if has_vector_entry_point(env_id) else "dummy"
    if vec_env == "batched":
        if not has_vector_entry_point(env_id):
            raise ValueError(f"--vec-env batched: {env_id} has no vector_entry_point")
        from tensegrity_gym.integrations.sb3 import make_sb3_vec_env
        venv = make_sb3_vec_env(gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point",
                                             **env_kwargs))
        venv.seed(seed)
    elif vec_env == "torch":
        if not has_vector_entry_point(env_id):
            raise ValueError(f"--vec-env torch: {env_id} has no vector_entry_point")
        from tensegrity_gym.integrations.sb3 import make_sb3_torch_vec_env
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
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "already wrapped with a Monitor" (dummy/subproc)
        venv = VecMonitor(venv, filename=monitor_file, info_keywords=tuple(info_keywords))
    return venv, vec_env


# ---------------------------------------------------------------------- run metadata
def passive_openmp_wait() -> bool:
    """Let idle OpenMP threads sleep instead of spin (``OMP_WAIT_POLICY=PASSIVE``), unless the
    variable is set already or torch (whose OpenMP runtime reads it when it loads) is imported.

    With more than one torch thread, each of PPO's many small operations ends at an OpenMP
    barrier; waiting threads spin there by default. On a machine whose cores are shared with other
    work, a spinning thread takes the core from the thread the barrier waits for: on 2 shared
    cores (load 4) the learner ran 13x slower per sample with 2 threads than with 2 threads that
    sleep (``docs/time_to_policy.md``). With one thread (the default of ``--num-threads``) there is
    no team and nothing changes. Returns True if it set the variable."""
    if "OMP_WAIT_POLICY" in os.environ or "torch" in sys.modules:
        return False
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    return True


def cpu_model() -> str | None:
    """The CPU's model name as ``lscpu`` prints it (``Model name``), else ``/proc/cpuinfo``'s
    ``model name``, else ``platform.processor()``; None if none of them says. A wall time means
    little without it: the same recipe runs at different speeds on different CPUs."""
    import subprocess
    try:
        p = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=5,
                           env={**os.environ, "LC_ALL": "C"})
        for line in p.stdout.splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "Model name" and value.strip():
                return value.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                return value.strip()
    except OSError:
        pass
    return platform.processor() or None


def cpus_available() -> int:
    """CPUs this process may run on (its affinity set, e.g. under ``taskset``), else ``os.cpu_count()``."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def machine() -> dict:
    """Where a wall time was measured: CPU model, CPUs available to the process, torch threads."""
    out = {"cpu_model": cpu_model(), "cpus_available": cpus_available(),
           "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY")}
    try:
        import torch
        out["torch_num_threads"] = torch.get_num_threads()
    except ImportError:
        pass
    return out


def package_versions() -> dict:
    out = {"python": platform.python_version(), "platform": platform.platform(), **machine()}
    for name in ("numpy", "scipy", "torch", "stable_baselines3", "sb3_contrib", "gymnasium", "tensegrity_gym",
                 "rl_zoo3", "numba"):
        try:
            mod = importlib.import_module(name)
            out[name] = getattr(mod, "__version__", "unknown")
        except Exception:  # noqa: BLE001 -- absent optional package
            out[name] = None
    try:
        import subprocess
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO_ROOT, capture_output=True, text=True,
                             timeout=5)
        if rev.returncode == 0:
            out["git_commit"] = rev.stdout.strip()
            dirty = subprocess.run(["git", "status", "--porcelain"], cwd=REPO_ROOT, capture_output=True,
                                   text=True, timeout=5)
            out["git_dirty"] = bool(dirty.stdout.strip())
    except Exception:  # noqa: BLE001 -- not a git checkout
        pass
    return out


# ---------------------------------------------------------------------- atomic files
# The one atomic writer of the package (a run folder's files are rewritten by the run that claimed it).
TMP_TAG = atomic.TMP_TAG
pid_alive = atomic.pid_alive
remove_stale_tmp = atomic.remove_stale_tmp


def atomic_write(path: str | Path, writer) -> Path:
    """Write ``path`` atomically (:func:`tensegrity_gym.io.atomic.write_atomic`): ``writer(f)``
    fills a temporary file in the same folder, which is fsynced and renamed over ``path``. An
    interrupt, a crash or a kill at any moment leaves the old file or the new one, never a partial
    one; a stale temporary file is removed by :func:`remove_stale_tmp`. Returns ``path``."""
    return atomic.write_atomic(path, writer)


def save_model_atomic(model, path: str | Path) -> Path:
    """``model.save`` (SB3 zip) through :func:`atomic_write`."""
    return atomic_write(path, model.save)


def save_pickle_atomic(obj, path: str | Path) -> Path:
    """Pickle ``obj`` (e.g. a ``VecNormalize``, as ``VecNormalize.save`` does) through :func:`atomic_write`."""
    import pickle
    return atomic_write(path, lambda f: pickle.dump(obj, f))


def save_replay_buffer_atomic(model, path: str | Path) -> Path:
    """``model.save_replay_buffer`` through :func:`atomic_write`."""
    return atomic_write(path, model.save_replay_buffer)


def write_json(path: str | Path, data) -> None:
    """JSON file written atomically (temporary file in the same folder, fsync, rename)."""
    text = json.dumps(to_yaml_safe(data), indent=2) + "\n"
    atomic_write(path, lambda f: f.write(text.encode()))


def write_text(path: str | Path, text: str) -> None:
    """Text file written atomically."""
    atomic_write(path, lambda f: f.write(text.encode()))


def run_cli(fn, argv: list[str] | None = None, errors=(ValueError, FileNotFoundError)) -> int:
    """Exit status of a command-line entry point: 0 after ``fn(argv)``, 2 with a one-line
    ``error: ...`` on stderr for the input errors ``errors`` (no traceback)."""
    try:
        fn(argv)
    except errors as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


#: the import name of this package: ``agents`` in a checkout (``python -m agents.train``),
#: ``tensegrity_gym_agents`` once installed (the name ``agents`` belongs to another distribution)
PACKAGE = __package__ or "agents"


def command_line(argv: list[str] | None = None, module: str = f"{PACKAGE}.train") -> str:
    """The command that reproduces this run: ``python -m <module> <argv>`` (``argv`` default sys.argv[1:])."""
    import shlex
    if argv is not None:
        return shlex.join(["python", "-m", module] + [str(a) for a in argv])
    prog = sys.argv[0]
    if prog.endswith(os.path.join("agents", "train.py")) or prog.endswith("-m"):
        head = ["python", "-m", module]
    else:
        head = [os.path.basename(sys.executable), prog]
    return shlex.join(head + sys.argv[1:])
