"""Checks of user input shared by the physics and the environments: every error is a
``ValueError`` naming the argument and the value."""
from __future__ import annotations

import math

import numpy as np

__all__ = ["ACTION_TOL", "check_positive", "check_array"]

#: an action may lie this far outside [-1, 1] (round-off of a float32 policy) before it is an error
ACTION_TOL = 1e-6


def check_positive(value, name: str, unit: str = "", allow_zero: bool = False) -> float:
    """``float(value)`` if finite and > 0 (>= 0 with ``allow_zero``), else ValueError naming ``name``.
    A string or a bool is not a number here (``"1e-3"`` and ``True`` are refused, not converted)."""
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise ValueError(f"{name}: expected a number{' in ' + unit if unit else ''}, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number{' in ' + unit if unit else ''}, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name}: must be {'>= 0' if allow_zero else 'positive'} and finite"
                         f"{' (' + unit + ')' if unit else ''}, got {value!r}")
    return v


def check_array(value, shape: tuple, name: str, bound: float | None = None, tol: float = 0.0) -> np.ndarray:
    """``value`` as a float64 array of ``shape``; ValueError naming ``name`` for another shape, and
    naming the first offending index and its value for a NaN/inf entry or (with ``bound``) an
    entry beyond ``[-bound, bound]`` by more than ``tol``."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected an array of numbers with shape {tuple(shape)}, got {value!r}") from None
    if a.shape != tuple(shape):
        raise ValueError(f"{name}: expected shape {tuple(shape)}, got {a.shape}")
    bad = ~np.isfinite(a)
    what = "is not finite"
    if not bad.any() and bound is not None:
        bad = np.abs(a) > bound + tol
        what = f"is outside [-{bound:g}, {bound:g}]"
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name}: entry {idx[0] if len(idx) == 1 else idx} {what}: {float(a[idx])!r}")
    return a
