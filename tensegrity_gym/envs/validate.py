"""Input checks of the environments: numbers, time steps, actuated strings (and the action check
of :mod:`tensegrity_gym.core.checks`, re-exported).

Every error is a ``ValueError`` naming the argument, the index and the value. SI units.
"""
from __future__ import annotations

import numpy as np

from ..core.model import Model
from ..core.builders import load_structure
from ..physics.actuation import ACTION_MODES
from ..core.checks import ACTION_TOL, check_action, check_positive

__all__ = ["ACTION_MODES", "ACTION_TOL", "check_positive", "check_action", "check_stable_dt", "resolve_actuated",
           "check_rest_length_bounds", "load_env_structure"]


def check_rest_length_bounds(bounds) -> tuple[float, float]:
    """``(low, high)`` fractions of the nominal rest lengths, ``0 < low <= 1 <= high``; ValueError
    naming ``rest_length_bounds`` and the value otherwise."""
    try:
        lo, hi = (float(x) for x in bounds)
    except (TypeError, ValueError):
        raise ValueError(f"rest_length_bounds: expected two numbers (low, high), got {bounds!r}") from None
    if not (0 < lo <= 1 <= hi) or not np.isfinite(hi):
        raise ValueError(f"rest_length_bounds: need 0 < low <= 1 <= high, finite (fractions of the nominal rest "
                         f"lengths), got {bounds!r}")
    return lo, hi


def check_stable_dt(model: Model, limit: float, dt: float, integrator: str, allow: bool, what: str) -> None:
    """ValueError if ``dt`` (s) is above the estimated stability ``limit`` (s) of ``integrator``,
    unless ``allow``; the message names the strings' stiffness and damping that set the limit."""
    if dt <= limit or allow:
        return
    k = float(np.max(model.stiffness)) if model.n_strings else 0.0
    c = float(np.max(model.damping)) if model.n_strings else 0.0
    raise ValueError(f"dt: {dt:g} s is above the estimated stability limit {limit:.3g} s of {integrator} for {what} "
                     f"(strings up to {k:.4g} N/m and {c:.4g} N s/m; the state would blow up); use a smaller dt, "
                     "less stiffness or string damping, integrator='implicit_euler' where the task allows it, or "
                     "allow_unstable_dt=True to run it anyway")


def load_env_structure(spec):
    """:func:`tensegrity_gym.load_structure` for an env's ``structure`` argument (a Structure, a
    built-in name or a JSON path); its errors name the argument (``structure: ...``)."""
    try:
        return load_structure(spec)
    except ValueError as e:
        raise ValueError(str(e) if str(e).startswith("structure") else f"structure: {e}") from None


def resolve_actuated(actuated, n_strings: int) -> np.ndarray:
    """Sorted unique string indices from ``None`` (all), an int list or a bool mask; errors name the index."""
    if actuated is None:
        return np.arange(n_strings)
    arr = np.asarray(actuated)
    if arr.dtype == bool:
        if arr.shape != (n_strings,):
            raise ValueError(f"actuated: a boolean mask needs {n_strings} entries (one per string), got {arr.shape}")
        arr = np.flatnonzero(arr)
    else:
        arr = arr.reshape(-1)
        if arr.size and (not np.issubdtype(arr.dtype, np.integer)):
            if not np.issubdtype(arr.dtype, np.floating) or not np.all(arr == np.round(arr)):
                raise ValueError(f"actuated: string indices must be integers, got {actuated!r}")
            arr = arr.astype(int)
        for i in arr:
            if not 0 <= int(i) < n_strings:
                raise ValueError(f"actuated: string {int(i)} does not exist (there are {n_strings} strings)")
        if len(set(arr.tolist())) != arr.size:
            raise ValueError(f"actuated: duplicate string indices in {arr.tolist()}")
        arr = np.sort(arr.astype(int))
    if arr.size == 0:
        raise ValueError("actuated: at least one string must be actuated")
    return arr

