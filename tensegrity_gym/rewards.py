"""Small reward-shaping helpers shared by the environments (dm_control style; no gymnasium import).

Everything is batched NumPy: inputs may be scalars or arrays of any shape, outputs have the
same shape. Units are whatever the caller passes (the envs pass metres).

* :func:`tolerance` -- dm_control's ``rewards.tolerance``: 1 inside ``bounds``, decaying
  smoothly to ``value_at_margin`` at distance ``margin`` outside them, with a choice of
  ``sigmoid`` shapes (``gaussian``, ``hyperbolic``, ``long_tail``, ``reciprocal``,
  ``cosine``, ``linear``, ``quadratic``, ``tanh_squared``).
* :func:`quadratic_cost` -- ``sum(x**2)`` over the last axis (control effort).
* :func:`combine` -- sum of named terms (the envs report every term as ``info["reward_<name>"]``
  and the reward equals their sum exactly).

Example::

    >>> tolerance(np.array([0.0, 0.01, 0.1]), bounds=(0.0, 0.01), margin=0.1)
    array([1.  , 1.  , 0.1])   # gaussian, value_at_margin = 0.1 at 0.1 m beyond the bound
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

__all__ = ["tolerance", "quadratic_cost", "sum_squares", "combine", "SIGMOIDS"]

SIGMOIDS = ("gaussian", "hyperbolic", "long_tail", "reciprocal", "cosine", "linear", "quadratic",
            "tanh_squared")


def _sigmoids(x: np.ndarray, value_at_1: float, sigmoid: str) -> np.ndarray:
    """Functions of distance ``x >= 0`` with value 1 at 0 and ``value_at_1`` at 1 (dm_control)."""
    if sigmoid in ("cosine", "linear", "quadratic"):
        if not 0 <= value_at_1 < 1:
            raise ValueError(f"value_at_margin: must be in [0, 1) for sigmoid {sigmoid!r}, got {value_at_1}")
    elif not 0 < value_at_1 < 1:
        raise ValueError(f"value_at_margin: must be in (0, 1) for sigmoid {sigmoid!r}, got {value_at_1}")
    if sigmoid == "gaussian":
        scale = np.sqrt(-2 * np.log(value_at_1))
        return np.exp(-0.5 * (x * scale) ** 2)
    if sigmoid == "hyperbolic":
        scale = np.arccosh(1 / value_at_1)
        return 1 / np.cosh(x * scale)
    if sigmoid == "long_tail":
        scale = np.sqrt(1 / value_at_1 - 1)
        return 1 / ((x * scale) ** 2 + 1)
    if sigmoid == "reciprocal":
        scale = 1 / value_at_1 - 1
        return 1 / (np.abs(x) * scale + 1)
    if sigmoid == "cosine":
        scale = np.arccos(2 * value_at_1 - 1) / np.pi
        sx = x * scale
        return np.where(np.abs(sx) < 1, (1 + np.cos(np.pi * sx)) / 2, 0.0)
    if sigmoid == "linear":
        scale = 1 - value_at_1
        sx = x * scale
        return np.where(np.abs(sx) < 1, 1 - sx, 0.0)
    if sigmoid == "quadratic":
        scale = np.sqrt(1 - value_at_1)
        sx = x * scale
        return np.where(np.abs(sx) < 1, 1 - sx ** 2, 0.0)
    if sigmoid == "tanh_squared":
        scale = np.arctanh(np.sqrt(1 - value_at_1))
        return 1 - np.tanh(x * scale) ** 2
    raise ValueError(f"sigmoid: unknown {sigmoid!r}; choose one of {SIGMOIDS}")


def tolerance(x, bounds=(0.0, 0.0), margin: float = 0.0, sigmoid: str = "gaussian",
              value_at_margin: float = 0.1) -> np.ndarray:
    """1 where ``bounds[0] <= x <= bounds[1]``, otherwise a ``sigmoid`` of the distance to the
    nearest bound divided by ``margin`` (``value_at_margin`` at one margin). ``margin = 0``:
    a hard 0/1 indicator. Same semantics as ``dm_control.utils.rewards.tolerance``.

    Parameters: ``x`` array-like (any shape); ``bounds`` (lower, upper) with lower <= upper;
    ``margin`` >= 0 in the units of ``x``. Returns float array of ``x``'s shape, values in [0, 1].
    """
    lower, upper = bounds
    if lower > upper:
        raise ValueError(f"bounds: lower bound {lower} is above upper bound {upper}")
    if margin < 0:
        raise ValueError(f"margin: must be >= 0, got {margin}")
    x = np.asarray(x, dtype=float)
    if x.size == 1 and margin > 0 and sigmoid == "gaussian":
        return _tolerance_one(x, lower, upper, margin, value_at_margin)
    in_bounds = (lower <= x) & (x <= upper)
    if margin == 0:
        return np.where(in_bounds, 1.0, 0.0)
    d = np.where(x < lower, lower - x, x - upper) / margin
    return np.where(in_bounds, 1.0, _sigmoids(d, value_at_margin, sigmoid))


_GAUSS_SCALE: dict = {}


def _tolerance_one(x: np.ndarray, lower, upper, margin, value_at_margin) -> np.ndarray:
    """:func:`tolerance` of a one-element ``x`` with the gaussian sigmoid (what the envs call each
    step at B = 1): the same operations on the same doubles, without the array ``np.where``s."""
    scale = _GAUSS_SCALE.get(value_at_margin)
    if scale is None:
        _sigmoids(np.zeros(1), value_at_margin, "gaussian")      # validates value_at_margin
        scale = _GAUSS_SCALE.setdefault(value_at_margin, np.sqrt(-2 * np.log(value_at_margin)))
    xv = float(x.reshape(-1)[0])
    if lower <= xv and xv <= upper:
        return np.ones(x.shape)
    dv = (lower - xv if xv < lower else xv - upper) / margin
    t = np.full(x.shape, dv * scale)
    return np.exp(-0.5 * t ** 2)


try:   # what np.einsum(...) runs (optimize=False), without its Python wrapper (~1 us a call)
    from numpy._core.multiarray import c_einsum as _c_einsum
except ImportError:  # pragma: no cover - NumPy < 2
    try:
        from numpy.core.multiarray import c_einsum as _c_einsum
    except ImportError:
        _c_einsum = np.einsum


def sum_squares(x: np.ndarray) -> np.ndarray:
    """``sum(x**2)`` over the last axis of a float array, (..., a) -> (...), without conversion
    (the hot-path form of :func:`quadratic_cost`)."""
    return _c_einsum("...i,...i->...", x, x)


def quadratic_cost(x) -> np.ndarray:
    """``sum(x**2)`` over the last axis: (..., a) -> (...)."""
    return sum_squares(np.asarray(x, dtype=float))


def combine(terms: Mapping[str, np.ndarray]) -> np.ndarray:
    """Sum of the named reward terms (arrays of one shape), added in the mapping's order.
    The envs report each term as ``info["reward_<name>"]``; this sum is the reward."""
    total = None
    for v in terms.values():
        total = np.asarray(v, dtype=float) if total is None else total + v
    if total is None:
        raise ValueError("combine: no reward terms given")
    return total
