"""Run files and run metadata shared by :mod:`agents.train`, :mod:`agents.evaluate` and the
scripts: a run's ``config.yaml``, model and normalisation files (with the names of models
pickled from a checkout), atomic writes, the machine and package versions a run records, and
the command-line exit conventions.

Parsing lives in :mod:`agents.parsing`, hyperparameters in :mod:`agents.hyperparameters`, env
construction in :mod:`agents.envs`.
"""
from __future__ import annotations

import importlib
import json
import os
import pickle
import platform
import shlex
import subprocess
import sys
from pathlib import Path

from tensegrity_gym.integrations.sb3 import LinearSchedule
from tensegrity_gym.io import atomic

from .parsing import read_yaml, to_yaml_safe

REPO_ROOT = Path(__file__).resolve().parent.parent


# ---------------------------------------------------------------------- run and model files
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


# ---------------------------------------------------------------------- run metadata
def cpu_model() -> str | None:
    """The CPU's model name as ``lscpu`` prints it (``Model name``), else ``/proc/cpuinfo``'s
    ``model name``, else ``platform.processor()``; None if none of them says. A wall time means
    little without it: the same recipe runs at different speeds on different CPUs."""
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


def repo_cwd() -> str | None:
    """The working directory relative to the repository root (``.`` at the root, ``/`` between
    parts), or None outside the checkout or in an installed copy (no repository): what a run's
    ``command.txt`` records, so that it names no machine path."""
    if not (REPO_ROOT / "pyproject.toml").is_file():
        return None
    try:
        return Path.cwd().resolve().relative_to(REPO_ROOT).as_posix()
    except (OSError, ValueError):   # the working directory removed, or outside the checkout
        return None


def command_line(argv: list[str] | None = None, module: str = f"{PACKAGE}.train") -> str:
    """The command that reproduces this run: ``python -m <module> <argv>`` (``argv`` default sys.argv[1:])."""
    if argv is not None:
        return shlex.join(["python", "-m", module] + [str(a) for a in argv])
    prog = sys.argv[0]
    if prog.endswith(os.path.join("agents", "train.py")) or prog.endswith("-m"):
        head = ["python", "-m", module]
    else:
        head = [os.path.basename(sys.executable), prog]
    return shlex.join(head + sys.argv[1:])
