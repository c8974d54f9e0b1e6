"""Checks of user input that would otherwise fail late (inside a step, hours into a training) or
silently: robot parameters against what the physics can take, noise in the observation's dtype,
bounded reads of input files, ports. Every error is a ``ValueError`` naming the argument, the
index and the value, and the accepted range. SI units.
"""
from __future__ import annotations

import dataclasses
import importlib
import math
import types

import numpy as np

from . import pipeline
from .checks import is_integer
from .params import _moments

__all__ = ["check_domain_rest_lengths", "check_domain_stable_dt", "check_noise_sigma", "worst_case_values",
           "check_seed_value", "check_reset_called",
           "check_autoreset_mode", "clear_mujoco_warnings", "twin_diverged", "MUJOCO_DIVERGENCE_WARNINGS",
           "picklable_state", "restore_state", "close_after_error"]


def _spread(domain, name: str) -> float:
    return float(domain.spread.get(name, 0.0))


def worst_case_values(domain, name: str) -> np.ndarray:
    """The per-item value of parameter ``name`` that lowers the stable step the most over every
    draw of ``domain`` (:class:`~tensegrity_gym.envs.domain.Domain`): the largest stiffness,
    damping and gravity, the smallest rod mass (relative spreads ``base x (1 +- s)``)."""
    base, s = np.asarray(domain.base[name], float), _spread(domain, name)
    return base * (1.0 - s) if name == "rod_mass" else base * (1.0 + s)


def check_domain_rest_lengths(task) -> None:
    """ValueError unless every string's rest length stays positive for every draw of the task's
    ``rest_length_offset`` (fixed ``params`` value plus the ``randomize`` spread ``s``, m): the
    shortest rest length a string can have (its nominal one, or the lower bound of an actuated
    cable in rest-length mode) plus the offset minus ``s`` must be > 0. Checked at construction, so
    that no reset hours later draws a negative rest length (NumPy and device resets alike)."""
    dom = task.domain
    if "rest_length_offset" not in dom.base:
        return
    model, act = task.model, task.actuation
    shortest = np.array(model.rest_length, float)
    if act.mode == "rest_length":
        shortest[act.actuated] = np.minimum(shortest[act.actuated], act.low)
    s = _spread(dom, "rest_length_offset")
    low = shortest + dom.base["rest_length_offset"] - s
    bad = ~model.active & (low <= 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        off = float(dom.base["rest_length_offset"][i])
        raise ValueError(
            f"randomize['rest_length_offset'] / params['rest_length_offset']: string {i} (shortest rest length "
            f"{shortest[i]:.6g} m, offset {off:.6g} m, spread {s:.6g} m) could get a rest length of {low[i]:.6g} m; "
            f"rest lengths must stay > 0 for every draw: need offset - spread > -{shortest[i]:.6g} m")


def _worst_model(model, dom, names):
    """``model`` with the worst-case values of ``names`` (physics fields) for the stability estimate."""
    kw = {}
    if "rod_mass" in names:
        mass = worst_case_values(dom, "rod_mass")
        f, J = _moments(model, mass[None])
        kw.update(mass=mass, f=f[0], J=J[0])
    for name in ("stiffness", "damping"):
        if name in names:
            kw[name] = np.where(model.active, 0.0, worst_case_values(dom, name))
    if "node_damping" in names:
        nd = worst_case_values(dom, "node_damping")
        kw.update(node_damping=nd, has_node_damping=bool(np.any(nd > 0)))
    if "damping" in names:
        kw["has_damping"] = bool(np.any(kw["damping"] > 0))
    if "gravity" in names:
        kw["gravity"] = worst_case_values(dom, "gravity")
    return dataclasses.replace(model, **kw) if kw else model


def _worst_contact(contact, dom, names):
    kw = {}
    if "ground_stiffness" in names:
        kw["stiffness"] = float(worst_case_values(dom, "ground_stiffness"))
    if "ground_damping" in names:
        kw["damping"] = float(worst_case_values(dom, "ground_damping"))
    return dataclasses.replace(contact, **kw) if kw and contact is not None else contact


#: robot parameters that move the stable step of the explicit integrators
STABILITY_PARAMETERS = ("rod_mass", "stiffness", "damping", "node_damping", "gravity", "ground_stiffness",
                        "ground_damping")


def check_domain_stable_dt(task, allow: bool, limit_of) -> None:
    """ValueError if the ``params`` / ``randomize`` values of ``task`` push the estimated stable
    step of its explicit integrator below its ``dt`` (s), unless ``allow`` (``allow_unstable_dt``).
    ``limit_of(model, contact) -> s`` is the task's own estimate (the one that refuses a too-large
    ``dt``), evaluated on the worst-case draw (stiffest, most damped, lightest); the message names
    the parameter(s) that set the limit. Nothing runs without such parameters."""
    dom = task.domain
    names = [n for n in STABILITY_PARAMETERS if n in dom.base]
    if allow or not names or task.integrator not in ("semi_implicit_euler", "rk4"):
        return
    contact = getattr(task, "contact", None)

    def limit(sel):
        return float(limit_of(_worst_model(task.model, dom, sel), _worst_contact(contact, dom, sel)))

    lim = limit(names)
    if not (lim < task.dt):     # a NaN estimate never refuses (as the dt check)
        return
    guilty = [n for n in names if limit([n]) < task.dt] or names
    parts = []
    for n in guilty:
        w = worst_case_values(dom, n)
        pick = np.min(w) if n == "rod_mass" else np.max(w)
        where = "randomize" if n in dom.spread else "params"
        parts.append(f"{where}[{n!r}] (worst draw {float(pick):.4g})")
    raise ValueError(f"{', '.join(parts)}: the estimated stability limit of {task.integrator} drops to {lim:.3g} s, "
                     f"below dt = {task.dt:g} s (the state would blow up at once); use values nearer the nominal ones, "
                     "a smaller dt, or allow_unstable_dt=True to run it anyway")


#: largest observation noise (standard deviation) of a float32 observation: a 10-sigma draw stays finite
MAX_FLOAT32_NOISE = float(np.finfo(np.float32).max) / 10.0


def check_noise_sigma(name: str, sigma, flip: bool) -> float:
    """``sensor_noise[name]`` as a float: a probability in [0, 1] for a switch (``flip``), else a
    standard deviation >= 0 that a float32 observation can hold (a 10-sigma draw stays finite:
    at most :data:`MAX_FLOAT32_NOISE`). A string, a bool or a non-number is refused (as elsewhere,
    ``"0.1"`` is not converted)."""
    s = float("nan")
    if not isinstance(sigma, (str, bytes, bool, np.bool_)):
        try:
            s = float(sigma)
        except (TypeError, ValueError):
            pass
    hi = 1.0 if flip else MAX_FLOAT32_NOISE
    if not (math.isfinite(s) and 0 <= s <= hi):
        raise ValueError(f"sensor_noise[{name!r}]: " + ("the probability that a switch reads wrong, a number in [0, 1]"
                         if flip else f"must be a finite standard deviation in [0, {hi:.3g}] (a number; the "
                         "observation is float32)") + f"; got {sigma!r}")
    return s





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
        from gymnasium.error import ResetNeeded
        raise ResetNeeded("Cannot call env.step() before calling env.reset()")


def check_autoreset_mode(kwargs: dict) -> dict:
    """``kwargs`` without ``autoreset_mode``: the vector envs autoreset on the next step only
    (``gymnasium.vector.AutoresetMode.NEXT_STEP``, or ``"next_step"``); any other request is a
    ValueError saying which autoreset mode the env implements."""
    if "autoreset_mode" not in kwargs:
        return kwargs
    from gymnasium.vector import AutoresetMode
    kwargs = dict(kwargs)
    mode = kwargs.pop("autoreset_mode")
    ok = mode is AutoresetMode.NEXT_STEP or (isinstance(mode, str) and mode.replace("_", "").lower() == "nextstep")
    if not ok:
        raise ValueError(f"autoreset_mode: these vector envs autoreset in NEXT_STEP mode only (an env that ended "
                         f"is reset by the following step() call), got {mode!r}; choose "
                         "gymnasium.vector.AutoresetMode.NEXT_STEP or wrap single envs in SyncVectorEnv("
                         "..., autoreset_mode=...) for SAME_STEP / DISABLED")
    return kwargs


#: MuJoCo warnings that mean the simulation blew up (MuJoCo resets the data on a bad acceleration, so
#: the state alone can look fine afterwards)
MUJOCO_DIVERGENCE_WARNINGS = ("mjWARN_BADQACC", "mjWARN_BADQPOS", "mjWARN_BADQVEL")


def clear_mujoco_warnings(mujoco, data) -> None:
    """Zero the counters of :data:`MUJOCO_DIVERGENCE_WARNINGS` in ``data`` (an ``MjData``), so that
    the next step's warnings are seen even where MuJoCo's own reset re-counts them from zero."""
    for name in MUJOCO_DIVERGENCE_WARNINGS:
        data.warning[getattr(mujoco.mjtWarning, name)].number = 0


def twin_diverged(mujoco, data, task) -> bool:
    """True if the MuJoCo twin's last control step diverged, by the native env's rule and more:
    a MuJoCo divergence warning since :func:`clear_mujoco_warnings`, a non-finite ``qpos`` /
    ``qvel``, or the task's state (``task.q``, ``task.qd``, synced from MuJoCo) out of the task's
    ``divergence_limit`` (m) as :func:`tensegrity_gym.pipeline.diverged` measures it for the native env."""
    if any(data.warning[getattr(mujoco.mjtWarning, n)].number > 0 for n in MUJOCO_DIVERGENCE_WARNINGS):
        return True
    if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
        return True
    return bool(pipeline.diverged(task.q, task.qd, task.center0, task.divergence_limit, task.travels)[0])


class _ModuleRef:
    """A module held by an env, pickled by name (modules do not pickle)."""

    def __init__(self, name: str):
        self.name = name


def picklable_state(state: dict) -> dict:
    """An env's ``__dict__`` for pickling: renderers (a window, a GL context: not picklable, and
    made again at the next ``render()``) left out, modules held by name."""
    out = dict(state)
    for k, v in state.items():
        if k == "_renderer":
            out[k] = None
        elif k == "_renderers":
            out[k] = {}
        elif isinstance(v, types.ModuleType):
            out[k] = _ModuleRef(v.__name__)
    return out


def restore_state(obj, state: dict) -> None:
    """Inverse of :func:`picklable_state`: ``obj.__dict__`` from ``state``, modules imported again."""
    obj.__dict__.update({k: importlib.import_module(v.name) if isinstance(v, _ModuleRef) else v
                         for k, v in state.items()})


def close_after_error(resource) -> None:
    """``resource.close()`` on an error path: an error of the close itself (a full disk, a broken
    pipe to a dead encoder) is dropped, so that the error being handled is the one reported."""
    try:
        resource.close()
    except Exception:  # noqa: BLE001 -- the original error propagates
        pass
