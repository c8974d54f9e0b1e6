"""Mass moments of one rod of a class-1 tensegrity: a uniform rod or lumped masses along it.

SI units: lengths in m, masses in kg, first moments in kg m, second moments in kg m^2.
A rod's mass distribution enters the dynamics only through its mass, the fraction of its
length at which its centre of mass lies and its first and second mass moments about a
reference point; the structure's checks, the compiled model, the per-copy parameters and the
MJCF export all take them from here, so every layer uses the same numbers.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["mass_moments", "centre_of_mass_fraction"]


def mass_moments(length: float, mass: float, sigma: float,
                 mass_points: Sequence[tuple[float, float]] | None = None) -> tuple[float, float]:
    """First and second mass moments ``f(sigma)`` (kg m) and ``J(sigma)`` (kg m^2)
    of a rod of ``length`` (m) about the point at fraction ``sigma`` from node a.

    Uniform rod: ``f = m l (1 - 2 sigma) / 2``, ``J = m l^2 (1 - 3 sigma + 3 sigma^2) / 3``.
    Lumped masses ``m_k`` at ``mu_k``: ``f = l sum m_k (mu_k - sigma)``,
    ``J = l^2 sum m_k (mu_k - sigma)^2``.
    """
    if mass_points is None:
        f = mass * length * (1.0 - 2.0 * sigma) / 2.0
        J = mass * length**2 * (1.0 - 3.0 * sigma + 3.0 * sigma**2) / 3.0
    else:
        mu = np.array([p[0] for p in mass_points], dtype=float)
        mk = np.array([p[1] for p in mass_points], dtype=float)
        f = float(length * np.sum(mk * (mu - sigma)))
        J = float(length**2 * np.sum(mk * (mu - sigma) ** 2))
    return float(f), float(J)


def centre_of_mass_fraction(pts) -> float:
    """Position of a rod's centre of mass as a fraction of its length from node a: 0.5 for a
    uniform rod (``pts`` None), else the mass-weighted mean of the lumped masses' ``(mu, m)``."""
    if pts is None:
        return 0.5
    tot = sum(p[1] for p in pts)
    return sum(p[0] * p[1] for p in pts) / tot
