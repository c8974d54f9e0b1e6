"""What the physics can take, checked when an env is built: rest lengths stay positive and the
stable step stays above ``dt`` for every draw of ``params`` / ``randomize``, and observation noise
fits the observation's float32. Every error is a ``ValueError`` naming the argument, the index and
the value, and the accepted range. SI units.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..core.params import rod_moments

__all__ = ["check_domain_rest_lengths", "check_domain_stable_dt", "check_noise_sigma", "worst_case_values",
           "STABILITY_PARAMETERS", "MAX_FLOAT32_NOISE"]


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
        f, J = rod_moments(model, mass[None])
        kw.update(mass=mass, f=f[0], J=J[0])
    for name in ("stiffness", "damping"):
        if name in names:
            kw[name] = np.where(model.active, 0.0, worst_case_values(dom, name))
    if "node_damping" in names:
        kw["node_damping"] = worst_case_values(dom, "node_damping")
    if "gravity" in names:
        kw["gravity"] = worst_case_values(dom, "gravity")
    return model.replace(W0=model.W0, **kw) if kw else model   # the nominal weights: the estimate's loads


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
