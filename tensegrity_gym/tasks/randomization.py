"""Randomised robot parameters (``randomize={name: spread}``) from uniform draws, written once for
NumPy arrays and torch tensors. SI units.

A parameter's spec (:class:`tensegrity_gym.core.param_table.DomainSpec`) says how its spread
``s`` applies: an **absolute** spread adds U(-s, s) (in the parameter's unit) to each item; a
relative one multiplies each item by U(1 - s, 1 + s), or the whole vector by one factor
(``one_factor``: the gravity vector keeps its direction). The NumPy envs draw the uniforms from
each copy's generator (:class:`tensegrity_gym.envs.domain.Domain`), the device envs from their
counter-based streams (:class:`tensegrity_gym.envs.torch_reset.TorchDomain`); both turn them
into values with :func:`draw_count`, :func:`draw_range` and :func:`values_from_draws`.
"""
from __future__ import annotations

import math

__all__ = ["draw_count", "draw_range", "values_from_draws"]


def draw_count(spec, base) -> int:
    """Uniforms one copy reads for a parameter of nominal value ``base`` (an array)."""
    return 1 if spec.one_factor else math.prod(base.shape)


def draw_range(spec, s: float) -> tuple[float, float]:
    """(low, high) of the uniform draws for spread ``s``: (-s, s) absolute, (1 - s, 1 + s) relative."""
    return (-s, s) if spec.absolute else (1.0 - s, 1.0 + s)


def values_from_draws(spec, base, x):
    """(r,) + base.shape values of r copies from their draws ``x`` (r, :func:`draw_count`), each
    U(:func:`draw_range`): ``base + x`` absolute, ``base x x`` relative (one factor per copy
    with ``one_factor``)."""
    r = x.shape[0]
    if spec.one_factor:
        return base * x.reshape((r,) + (1,) * base.ndim)
    x = x.reshape((r,) + tuple(base.shape))
    return base + x if spec.absolute else base * x
