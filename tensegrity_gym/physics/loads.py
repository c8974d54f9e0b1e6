"""Member loads: the string tensions and rod compressions a state puts on a tensegrity's members,
and the loads its members can take (rod tube buckling and yield, string breaking). What drop
survival is judged by. SI units: N, m, Pa, kg.

Rod compression
---------------
A rod is rigid in the model, but its axial force is not zero: cut a uniform rod of mass ``m``
and length ``l`` at its centre and the half holding node c balances, along the rod's axis
``b``, the nodal force ``f_c`` on it, the other half's push ``C b`` and the inertia of its mass.
With ``r''`` the centre's acceleration (the rod's total force over ``m``) and ``b . b'' =
-|b'|^2``, that balance gives the compression at the centre

    C = (f_a - f_c) . b / 2  -  m l |b'|^2 / 8

(``f_a``, ``f_c``: the total nodal forces on the rod's ends: strings, gravity's nodal loads,
contact and other external forces; the second term is the spin's centrifugal tension). A
massless rod between two equal and opposite end forces gives the statics answer ``C = -f_c .
b``. Rods with point masses (``mass_points``) are taken as uniform in the inertial term;
the constraint forces on a pinned or sliding node are not part of ``f`` (such a rod's load
is then its free part only).

Member capacities
-----------------
:class:`RodSection` (a round tube: outer diameter, wall, Young's modulus, yield stress) gives a
rod's Euler buckling load ``pi^2 E I / l^2`` (pinned ends, the tensegrity's ball joints) and its
yield load ``sigma_y A``; the smaller is its capacity. A string's capacity is its breaking load.
:data:`MATERIALS` holds handbook values of common rod materials (each with its source).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.model import Model
from .evaluate import string_forces

__all__ = ["member_loads", "RodSection", "MATERIALS", "overload"]

#: rod materials: name -> (Young's modulus Pa, yield stress Pa, density kg/m^3, source)
MATERIALS = {
    "aluminium_6061_t6": (68.9e9, 276e6, 2700.0, "ASM Aerospace Specification Metals, Aluminum 6061-T6"),
    "titanium_ti6al4v": (113.8e9, 880e6, 4430.0, "ASM Aerospace Specification Metals, Ti-6Al-4V (Grade 5), annealed"),
    "steel_4130": (205e9, 460e6, 7850.0, "MatWeb, AISI 4130 steel, normalized at 870 C"),
    "carbon_fibre_tube": (70e9, 600e6, 1550.0, "typical pultruded CFRP tube, axial (manufacturer ranges 60-135 GPa)"),
}


@dataclass(frozen=True)
class RodSection:
    """A rod's tube: ``outer_diameter`` and ``wall`` (m, 0 < wall <= outer_diameter / 2: a solid
    rod at the half), ``youngs_modulus`` and ``yield_stress`` (Pa). :meth:`of` builds one from a
    material of :data:`MATERIALS`."""

    outer_diameter: float
    wall: float
    youngs_modulus: float
    yield_stress: float

    def __post_init__(self):
        for name in ("outer_diameter", "wall", "youngs_modulus", "yield_stress"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not \
                    (math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a positive finite number, got {v!r}")
        if self.wall > self.outer_diameter / 2:
            raise ValueError(f"wall: at most half the outer diameter ({self.outer_diameter / 2:g} m), got {self.wall!r}")

    @classmethod
    def of(cls, material: str, outer_diameter: float, wall: float) -> "RodSection":
        if material not in MATERIALS:
            raise ValueError(f"material: unknown {material!r}; choose one of {sorted(MATERIALS)}")
        E, sy, _, _ = MATERIALS[material]
        return cls(outer_diameter, wall, E, sy)

    @property
    def area(self) -> float:
        """Cross-section area, m^2."""
        d = self.outer_diameter - 2 * self.wall
        return math.pi / 4 * (self.outer_diameter ** 2 - d ** 2)

    @property
    def second_moment(self) -> float:
        """Second moment of area, m^4."""
        d = self.outer_diameter - 2 * self.wall
        return math.pi / 64 * (self.outer_diameter ** 4 - d ** 4)

    def capacity(self, length) -> np.ndarray:
        """The compression (N) a rod of ``length`` m (array) takes: the smaller of its Euler
        buckling load (pinned ends) and its yield load."""
        length = np.asarray(length, float)
        euler = math.pi ** 2 * self.youngs_modulus * self.second_moment / length ** 2
        return np.minimum(euler, self.yield_stress * self.area)


def member_loads(model: Model, q, qd, rest_length=None, force_density=None, external=None, params=None) -> dict:
    """The members' loads in the states ``q``, ``qd`` (B, k, 6): ``string_tension`` (B, m) N (0
    when slack) and ``rod_compression`` (B, k) N at each rod's centre (negative: the rod is in
    tension), with ``external`` (B, n, 3) N the forces beyond the strings and gravity (contact).
    Inputs as :func:`tensegrity_gym.physics.evaluate.string_forces` takes them."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, model.n_bars, 6)
    qd = np.asarray(qd, dtype=np.float64).reshape(-1, model.n_bars, 6)
    gamma, L, F = string_forces(model, q, qd, rest_length, force_density, external, params)
    b, bd = q[..., 3:], qd[..., 3:]
    fa, fc = F[:, model.rod_a], F[:, model.rod_c]
    mass = model.nominal.mass if params is None else params.mass
    mass = np.broadcast_to(np.asarray(mass, float), (q.shape[0], model.n_bars))
    comp = 0.5 * np.einsum("bki,bki->bk", fa - fc, b) - mass * model.length * np.einsum("bki,bki->bk", bd, bd) / 8
    return {"string_tension": gamma * L, "rod_compression": comp}


def overload(loads: dict, rod_capacity=None, string_capacity=None) -> dict:
    """Each member's load over its capacity: ``rod_load_ratio`` (B, k) = compression / rod
    capacity (N; (k,) or a number; None: not checked) and ``string_load_ratio`` (B, m) =
    tension / breaking load; ``member_overload`` (B,) bool: any ratio above 1."""
    out = {}
    over = np.zeros(loads["rod_compression"].shape[0], bool)
    if rod_capacity is not None:
        out["rod_load_ratio"] = loads["rod_compression"] / np.asarray(rod_capacity, float)
        over |= (out["rod_load_ratio"] > 1).any(axis=1)
    if string_capacity is not None:
        out["string_load_ratio"] = loads["string_tension"] / np.asarray(string_capacity, float)
        over |= (out["string_load_ratio"] > 1).any(axis=1)
    out["member_overload"] = over
    return out
