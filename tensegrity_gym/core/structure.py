"""Structure model of a class-1 tensegrity: nodes, rods, strings, masses, constraints.

Everything is in SI units: positions in m, masses in kg, stiffness in N/m,
rest lengths in m, damping in N s/m, gravity in m/s^2, velocities in m/s.

A :class:`Structure` is immutable and validated on construction; every error
names the offending item (which node, rod, string or field and which value).
It is pure data: the dynamics compile it into a :class:`tensegrity_gym.core.model.Model`.

Conventions
-----------
* ``nodes`` (n, 3): node coordinates.
* ``bars`` (k, 2): rod end nodes ``(a, c)``; the rod's unit vector points a -> c.
* ``strings`` (m, 2): string end nodes.
* Nodes on no rod are fixed anchors.
* ``node_constraints``: ``{node: D}`` with ``D`` of shape (p, 3), rank p in 1..3:
  the node obeys ``D n = D n0`` for all time (p = 1: slides on a plane,
  p = 2: on a line, p = 3: pinned). At most one constrained node per rod.
* ``mass_points``: per rod ``None`` (uniform rod of mass ``bar_mass[j]``) or a
  tuple of ``(mu, m)`` lumped masses at fraction ``mu`` in [0, 1] from node a
  (the seed's Example 5.2); ``bar_mass[j]`` is then their sum.

Accepted values (the JSON Schema ``tensegrity_gym/structure.schema.json`` shipped with the package states
them per key; :func:`load_json` / :func:`from_dict` check a file against it first, and every
message cites the key's description there):

* numbers are JSON numbers: no strings (``"1000"``), no ``true``/``false``, no NaN or infinity;
  node indices are integers;
* coordinates within +-1e6 m, rod masses (and lumped masses) in [1e-9, 1e9] kg, stiffness in
  [1e-6, 1e12] N/m, damping in [0, 1e9] N s/m, gravity and initial velocities within
  +-1e4 m/s^2 and +-1e4 m/s: values outside these are unit errors, not structures (and
  products such as ``k / m`` of extreme values overflow to NaN states);
* each string's own mode, ``omega_i^2 = k_i (1/m_a + 1/m_b)`` with ``m_a``, ``m_b`` the
  effective masses of the rods at its two ends along the string (rigid-body motion of least
  kinetic energy, constraints included; an anchor is immovable), and its damping rate
  ``c_i (1/m_a + 1/m_b)`` must allow an explicit step of at least ``MIN_STABLE_STEP`` = 1e-9 s
  (``2 / omega_i`` and ``2 / rate_i``). Each string's mode is a Rayleigh quotient of the
  linearised dynamics, so the structure's real stable step is at most this; below 1e-9 s
  one second of simulation needs more than 1e9 steps, which signals a unit error (g for kg,
  N/mm for N/m) rather than a structure.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .checks import read_bounded
from .errors import StructureError
from .schema import SCHEMA_PATH, _as_per_item, _describe, _in_range, _numeric, _show, loads, schema, validate_dict

__all__ = ["Structure", "StructureError", "mass_moments", "load_json", "save_json", "from_dict",
           "SCHEMA_PATH", "schema", "validate_dict", "MIN_STABLE_STEP", "MAX_FILE_BYTES"]

#: smallest accepted explicit stable step of any single string's mode, s (see the module docstring)
MIN_STABLE_STEP = 1e-9
#: largest structure file :func:`load_json` reads, bytes: about 70,000 rods as written by
#: :func:`save_json` (about 480 bytes per rod), parsed and validated in seconds; a larger file would
#: take minutes and gigabytes of memory before any check could refuse it
MAX_FILE_BYTES = 32 * 2**20


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


def _check_string_modes(nodes, bars, strings, bar_mass, mass_points, cons, stiffness, damping, rod_len):
    """Each string's own mode must allow an explicit step of at least MIN_STABLE_STEP.

    For string i with unit vector e, the length rate is linear in the rods' rigid-body
    velocities (v, w): d|s|/dt = g^T (v, w), g = (e, r x e) per end (r from the rod's centre of
    mass to the node). The least kinetic energy for a unit length rate gives the inverse effective
    mass q_i = g^T M^-1 g (M^-1 = diag(I/m, (I - b b^T)/J), projected onto the node constraint
    D (v + w x r) = 0 of a constrained rod; anchors are immovable). Then omega_i^2 = k_i q_i and
    the damping rate is c_i q_i (a Rayleigh quotient: the linearised structure is at least this
    fast), and 2/omega_i and 2/(c_i q_i) must be >= MIN_STABLE_STEP."""
    m = len(strings)
    if m == 0:
        return
    k = len(bars)
    b = (nodes[bars[:, 1]] - nodes[bars[:, 0]]) / rod_len[:, None]
    mp = mass_points or (None,) * k
    Minv = np.zeros((k, 6, 6))
    com = np.empty((k, 3))
    for j in range(k):
        sig = Structure._com_fraction(mp[j])
        J = mass_moments(rod_len[j], bar_mass[j], sig, mp[j])[1]
        com[j] = nodes[bars[j, 0]] + sig * rod_len[j] * b[j]
        Minv[j, :3, :3] = np.eye(3) / bar_mass[j]
        Minv[j, 3:, 3:] = (np.eye(3) - np.outer(b[j], b[j])) / J
    rod_of = np.full(len(nodes), -1)
    rod_of[bars[:, 0]] = np.arange(k)
    rod_of[bars[:, 1]] = np.arange(k)
    for node, D in cons.items():
        j = rod_of[node]
        r = nodes[node] - com[j]
        rx = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
        A = D @ np.hstack([np.eye(3), -rx])                 # node velocity v + w x r = v - [r]x w
        MA = Minv[j] @ A.T
        Minv[j] = Minv[j] - MA @ np.linalg.pinv(A @ MA) @ MA.T
    sa, sb = strings[:, 0], strings[:, 1]
    e = nodes[sb] - nodes[sa]
    e /= np.linalg.norm(e, axis=1)[:, None]
    g = np.zeros((m, 2, 6))                                 # per end: (e, r x e), sign of the end
    ja, jb = rod_of[sa], rod_of[sb]
    for end, (nd, jj, sign) in enumerate(((sa, ja, -1.0), (sb, jb, 1.0))):
        ok = jj >= 0
        r = nodes[nd[ok]] - com[jj[ok]]
        g[ok, end, :3] = sign * e[ok]
        g[ok, end, 3:] = sign * np.cross(r, e[ok])
    same = (ja == jb) & (ja >= 0)
    g[same, 1] += g[same, 0]
    g[same, 0] = 0.0
    q = np.zeros(m)
    for end, jj in ((0, ja), (1, jb)):
        ok = jj >= 0
        q[ok] += np.einsum("si,sij,sj->s", g[ok, end], Minv[jj[ok]], g[ok, end])
    q = np.maximum(q, 0.0)
    with np.errstate(divide="ignore", over="ignore"):
        dt_k = 2.0 / np.sqrt(stiffness * q)
        dt_c = 2.0 / (damping * q)
    for name, dts, vals, unit in (("stiffness", dt_k, stiffness, "N/m"), ("damping", dt_c, damping, "N s/m")):
        i = int(np.argmin(dts))
        if dts[i] < MIN_STABLE_STEP:
            ends = ", ".join("an anchor" if rod_of[x] < 0 else f"{1.0 / max(q_end, 1e-300):.3g} kg on bar {rod_of[x]}"
                             for x, q_end in ((sa[i], g[i, 0] @ Minv[max(ja[i], 0)] @ g[i, 0]),
                                              (sb[i], g[i, 1] @ Minv[max(jb[i], 0)] @ g[i, 1])))
            what = (f"its mode omega = sqrt(k (1/m_a + 1/m_b)) = {np.sqrt(vals[i] * q[i]):.3g} rad/s"
                    if name == "stiffness" else f"its damping rate c (1/m_a + 1/m_b) = {vals[i] * q[i]:.3g} 1/s")
            raise StructureError(
                f"{name} of string {i} (nodes {sa[i]}, {sb[i]}): {vals[i]:.6g} {unit} with effective end masses "
                f"{ends}: {what} allows an explicit step of only {dts[i]:.3g} s, below the accepted "
                f"{MIN_STABLE_STEP:g} s (a 1 s simulation would need over 1e9 steps; check the units of "
                f"{name} and bar_mass) (schema, {name}: {_describe(name)})")


@dataclass(frozen=True, eq=False, init=False)
class Structure:
    """A validated class-1 tensegrity structure (SI units).

    Parameters
    ----------
    nodes : (n, 3) array, m.
    bars : (k, 2) int array of node indices (rods).
    strings : (m, 2) int array of node indices.
    bar_mass : number or (k,) array, kg (ignored for rods with ``mass_points``).
    stiffness : number or (m,) array, N/m, > 0.
    rest_length : (m,) array, m, >= 0. ``None``: the strings' initial lengths (no prestress).
    damping : number or (m,) array, N s/m, >= 0. Default 0.
    gravity : (3,) array, m/s^2, or ``None`` (no gravity: no gravity code runs).
    node_constraints : mapping node -> (p, 3) matrix ``D``.
    velocities : (n, 3) array of initial node velocities, m/s. Default zeros.
    mass_points : per-rod ``None`` or sequence of ``(mu, mass)`` pairs.
    name : free text.
    """

    nodes: np.ndarray
    bars: np.ndarray
    strings: np.ndarray
    bar_mass: np.ndarray
    stiffness: np.ndarray
    rest_length: np.ndarray
    damping: np.ndarray
    gravity: np.ndarray | None = None
    node_constraints: Mapping[int, np.ndarray] = field(default_factory=dict)
    velocities: np.ndarray | None = None
    mass_points: tuple | None = None
    name: str = "structure"

    # ------------------------------------------------------------------ construction
    def __init__(self, nodes, bars, strings, bar_mass=1.0, stiffness=1000.0, rest_length=None,
                 damping=0.0, gravity=None, node_constraints=None, velocities=None,
                 mass_points=None, name="structure"):
        set_ = object.__setattr__
        nodes = _numeric(nodes, "nodes")
        if nodes.ndim != 2 or nodes.shape[1] != 3 or nodes.shape[0] == 0:
            raise StructureError(f"nodes: expected an (n, 3) array with n >= 1, got shape {nodes.shape}")
        if not np.all(np.isfinite(nodes)):
            bad = np.argwhere(~np.isfinite(nodes))[0]
            raise StructureError(f"nodes: node {bad[0]} has a non-finite coordinate {nodes[bad[0]].tolist()}")
        _in_range(nodes, "nodes", "coordinate", "m", "node")
        n = nodes.shape[0]
        bars = self._members(bars, "bars", "bar", n)
        strings = self._members(strings, "strings", "string", n)
        k, m = len(bars), len(strings)
        if k == 0:
            raise StructureError("bars: a structure needs at least one rod")

        # class 1: no node on two rods
        owner: dict[int, int] = {}
        for j, (a, c) in enumerate(bars):
            for node in (a, c):
                if node in owner:
                    raise StructureError(
                        f"bar {j} (nodes {a}, {c}): node {node} is already on bar {owner[node]}; "
                        "class-1 tensegrity allows one rod per node")
                owner[node] = j

        # lengths
        rod_len = np.linalg.norm(nodes[bars[:, 1]] - nodes[bars[:, 0]], axis=1)
        for j, L in enumerate(rod_len):
            if not L > 1e-12:
                raise StructureError(f"bar {j} (nodes {bars[j, 0]}, {bars[j, 1]}): zero length")
        str_len = np.linalg.norm(nodes[strings[:, 1]] - nodes[strings[:, 0]], axis=1) if m else np.zeros(0)
        for i, L in enumerate(str_len):
            if not L > 1e-12:
                raise StructureError(
                    f"string {i} (nodes {strings[i, 0]}, {strings[i, 1]}): zero length "
                    "(its two nodes coincide)")

        # masses
        if mass_points is not None:
            if not isinstance(mass_points, (list, tuple, np.ndarray)):
                raise StructureError(f"mass_points: expected a list with one entry per bar (null or "
                                     f"[[mu, m], ...]), got {_show(mass_points)}")
            if len(mass_points) != k:
                raise StructureError(f"mass_points: expected {k} entries (one per bar), got {len(mass_points)}")
            mp_list = []
            for j, pts in enumerate(mass_points):
                if pts is None:
                    mp_list.append(None)
                    continue
                arr = _numeric(pts, "mass_points")
                if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
                    raise StructureError(f"mass_points[{j}] (bar {j}): expected null or a list of [mu, m] pairs, "
                                         f"got shape {arr.shape}")
                pts = tuple((float(mu), float(mk)) for mu, mk in arr)
                for mu, mk in pts:
                    if not (math.isfinite(mu) and 0.0 <= mu <= 1.0):
                        raise StructureError(f"mass_points of bar {j}: position {mu} is not in [0, 1]")
                    if not (math.isfinite(mk) and mk > 0):
                        raise StructureError(f"mass_points of bar {j}: mass {mk} kg is not positive and finite")
                mp_list.append(pts)
            mass_points = tuple(mp_list)
        bar_mass = _as_per_item(bar_mass, k, "bar_mass", "bar")
        if mass_points is not None:
            bar_mass = bar_mass.copy()
            for j, pts in enumerate(mass_points):
                if pts is not None:
                    bar_mass[j] = sum(p[1] for p in pts)
        for j, mj in enumerate(bar_mass):
            if not (math.isfinite(mj) and mj > 0):
                raise StructureError(f"bar_mass of bar {j}: {mj} kg is not positive and finite")
        _in_range(bar_mass, "bar_mass", "mass", "kg", "bar")
        for j, pts in enumerate(mass_points or ()):
            if pts is not None:
                _in_range(np.array([p[1] for p in pts]), f"mass_points[{j}]", "mass", "kg", "lumped mass")
        # the rod's inertia about its centre must be positive (Lemma 5.1)
        for j in range(k):
            pts = None if mass_points is None else mass_points[j]
            sig = self._com_fraction(pts)
            f0, J0 = mass_moments(rod_len[j], bar_mass[j], sig, pts)
            if not J0 > 1e-15 * bar_mass[j] * rod_len[j] ** 2:
                raise StructureError(
                    f"mass_points of bar {j}: all mass at one point; the rod has no rotational inertia "
                    "(use at least two distinct positions)")

        # strings
        def per_string(value, name, unit, positive):
            """(m,) values of a per-string field, each finite and > 0 (``positive``) or >= 0."""
            arr = _as_per_item(value, m, name, "string")
            for i, v in enumerate(arr):
                if not (math.isfinite(v) and (v > 0 if positive else v >= 0)):
                    rule = "is not positive and finite" if positive else "is negative or not finite"
                    raise StructureError(f"{name} of string {i} (nodes {strings[i, 0]}, {strings[i, 1]}): "
                                         f"{v} {unit} {rule}")
            return arr
        stiffness = per_string(stiffness, "stiffness", "N/m", True)
        _in_range(stiffness, "stiffness", "stiffness", "N/m", "string")
        rest_length = per_string(str_len.copy() if rest_length is None else rest_length, "rest_length", "m", False)
        damping = per_string(damping, "damping", "N s/m", False)
        _in_range(damping, "damping", "damping", "N s/m", "string")

        # gravity
        if gravity is not None:
            gravity = _numeric(gravity, "gravity")
            if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
                raise StructureError(f"gravity: expected 3 finite numbers (m/s^2), got {gravity.tolist()}")
            _in_range(gravity, "gravity", "acceleration", "m/s^2", "component")

        # constraints
        cons: dict[int, np.ndarray] = {}
        if node_constraints is not None and not isinstance(node_constraints, Mapping):
            raise StructureError(f"node_constraints: expected an object {{node: D}} (e.g. {{\"0\": [[0, 0, 1]]}}), "
                                 f"got {_show(node_constraints)}")
        for key, D in (node_constraints or {}).items():
            try:
                if isinstance(key, (bool, np.bool_, float)):
                    raise TypeError
                node = int(key)
            except (TypeError, ValueError):
                raise StructureError(f"node_constraints: key {key!r} is not a node index") from None
            if not 0 <= node < n:
                raise StructureError(f"node_constraints: node {node} does not exist (there are {n} nodes)")
            if node not in owner:
                raise StructureError(
                    f"node_constraints: node {node} is on no rod; nodes on no rod are already fixed anchors")
            D = _numeric(D, f"node_constraints[{key!r}]")
            if D.ndim == 1 and D.shape == (3,):
                D = D[None, :]
            if D.ndim != 2 or D.shape[1] != 3 or not 1 <= D.shape[0] <= 3:
                raise StructureError(
                    f"node_constraints of node {node}: D must have shape (p, 3) with p in 1..3, got {D.shape}")
            if not np.all(np.isfinite(D)):
                raise StructureError(f"node_constraints of node {node}: D has non-finite entries")
            rank = np.linalg.matrix_rank(D, tol=1e-9 * max(1.0, np.abs(D).max()))
            if rank != D.shape[0]:
                raise StructureError(
                    f"node_constraints of node {node}: D has {D.shape[0]} rows but rank {rank}; "
                    "rows must be linearly independent")
            cons[node] = D
        for j, (a, c) in enumerate(bars):
            if a in cons and c in cons:
                raise StructureError(
                    f"bar {j} (nodes {a}, {c}): both ends are constrained; at most one constrained node per rod")

        # velocities
        if velocities is None:
            velocities = np.zeros_like(nodes)
        else:
            velocities = _numeric(velocities, "velocities")
            if velocities.shape != nodes.shape:
                raise StructureError(f"velocities: expected shape {nodes.shape}, got {velocities.shape}")
            if not np.all(np.isfinite(velocities)):
                raise StructureError("velocities: non-finite entries")
            _in_range(velocities, "velocities", "speed", "m/s", "node")
            vscale = max(1.0, float(np.abs(velocities).max()))
            for node in range(n):
                if node not in owner and np.any(velocities[node] != 0):
                    raise StructureError(
                        f"velocities of node {node}: node is a fixed anchor (on no rod) but has velocity "
                        f"{velocities[node].tolist()} m/s")
            for j, (a, c) in enumerate(bars):
                dv = velocities[c] - velocities[a]
                dn = nodes[c] - nodes[a]
                stretch = float(dv @ dn) / rod_len[j]
                if abs(stretch) > 1e-9 * vscale:
                    raise StructureError(
                        f"velocities of bar {j} (nodes {a}, {c}): the rod would stretch at {stretch:.3g} m/s; "
                        "relative velocity of rod ends must be perpendicular to the rod")
            for node, D in cons.items():
                viol = D @ velocities[node]
                if np.any(np.abs(viol) > 1e-9 * vscale):
                    raise StructureError(
                        f"velocities of node {node}: breaks its constraint D v = 0 (D v = {viol.tolist()})")

        _check_string_modes(nodes, bars, strings, bar_mass, mass_points, cons, stiffness, damping, rod_len)

        for arr in (nodes, bars, strings, bar_mass, stiffness, rest_length, damping, velocities):
            arr.setflags(write=False)
        if gravity is not None:
            gravity.setflags(write=False)
        for D in cons.values():
            D.setflags(write=False)
        set_(self, "nodes", nodes)
        set_(self, "bars", bars)
        set_(self, "strings", strings)
        set_(self, "bar_mass", bar_mass)
        set_(self, "stiffness", stiffness)
        set_(self, "rest_length", rest_length)
        set_(self, "damping", damping)
        set_(self, "gravity", gravity)
        set_(self, "node_constraints", cons)
        set_(self, "velocities", velocities)
        set_(self, "mass_points", mass_points)
        set_(self, "name", str(name))

    @staticmethod
    def _members(members, field_name, item, n):
        arr = _numeric(members if members is not None else [], field_name)
        if arr.size == 0:
            return np.zeros((0, 2), dtype=np.int64)
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise StructureError(f"{field_name}: expected a list of [a, b] node pairs, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            bad = np.argwhere(~np.isfinite(arr) | (arr != np.round(arr)))[0]
            raise StructureError(f"{field_name}: node indices must be integers; {field_name}[{bad[0]}][{bad[1]}] "
                                 f"({item} {bad[0]}) is {arr[bad[0], bad[1]]!r}")
        if np.any(np.abs(arr) > 2**62):
            bad = np.argwhere(np.abs(arr) > 2**62)[0]
            raise StructureError(f"{item} {bad[0]}: node {arr[bad[0], bad[1]]:.4g} does not exist "
                                 f"(there are {n} nodes)")
        arr = arr.astype(np.int64)
        seen: dict[tuple[int, int], int] = {}
        for i, (a, b) in enumerate(arr):
            for node in (a, b):
                if not 0 <= node < n:
                    raise StructureError(
                        f"{item} {i} (nodes {a}, {b}): node {node} does not exist (there are {n} nodes)")
            if a == b:
                raise StructureError(f"{item} {i} (nodes {a}, {b}): both ends are the same node")
            key = (min(a, b), max(a, b))
            if key in seen:
                raise StructureError(
                    f"{item} {i} (nodes {a}, {b}): duplicate of {item} {seen[key]}")
            seen[key] = i
        return arr

    @staticmethod
    def _com_fraction(pts) -> float:
        if pts is None:
            return 0.5
        tot = sum(p[1] for p in pts)
        return sum(p[0] * p[1] for p in pts) / tot

    # ------------------------------------------------------------------ derived data
    @property
    def n_nodes(self) -> int:
        return self.nodes.shape[0]

    @property
    def n_bars(self) -> int:
        return self.bars.shape[0]

    @property
    def n_strings(self) -> int:
        return self.strings.shape[0]

    @property
    def bar_lengths(self) -> np.ndarray:
        """(k,) rod lengths, m."""
        return np.linalg.norm(self.nodes[self.bars[:, 1]] - self.nodes[self.bars[:, 0]], axis=1)

    @property
    def string_lengths(self) -> np.ndarray:
        """(m,) initial string lengths, m."""
        return np.linalg.norm(self.nodes[self.strings[:, 1]] - self.nodes[self.strings[:, 0]], axis=1)

    @property
    def anchors(self) -> np.ndarray:
        """Indices of the fixed nodes (on no rod)."""
        on_rod = np.zeros(self.n_nodes, bool)
        on_rod[self.bars.ravel()] = True
        return np.flatnonzero(~on_rod)

    @property
    def com_fraction(self) -> np.ndarray:
        """(k,) position of each rod's centre of mass as a fraction from node a."""
        mp = self.mass_points or (None,) * self.n_bars
        return np.array([self._com_fraction(p) for p in mp])

    @property
    def total_mass(self) -> float:
        return float(np.sum(self.bar_mass))

    @property
    def height(self) -> float:
        """Extent of the nodes along z, m (used for default tolerances)."""
        return float(np.ptp(self.nodes[:, 2]))

    def initial_tensions(self) -> np.ndarray:
        """(m,) string tensions at the initial nodes, N (0 for slack strings)."""
        return self.stiffness * np.maximum(0.0, self.string_lengths - self.rest_length)

    def replace(self, **changes) -> "Structure":
        """A new validated structure with some fields changed."""
        d = dict(nodes=self.nodes, bars=self.bars, strings=self.strings, bar_mass=self.bar_mass,
                 stiffness=self.stiffness, rest_length=self.rest_length, damping=self.damping,
                 gravity=self.gravity, node_constraints=self.node_constraints,
                 velocities=self.velocities, mass_points=self.mass_points, name=self.name)
        d.update(changes)
        return Structure(**d)

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict:
        d: dict[str, Any] = {
            "name": self.name,
            "nodes": self.nodes.tolist(),
            "bars": self.bars.tolist(),
            "strings": self.strings.tolist(),
            "bar_mass": self.bar_mass.tolist(),
            "stiffness": self.stiffness.tolist(),
            "rest_length": self.rest_length.tolist(),
            "damping": self.damping.tolist(),
        }
        if self.gravity is not None:
            d["gravity"] = self.gravity.tolist()
        if self.node_constraints:
            d["node_constraints"] = {str(k): v.tolist() for k, v in self.node_constraints.items()}
        if np.any(self.velocities != 0):
            d["velocities"] = self.velocities.tolist()
        if self.mass_points is not None:
            d["mass_points"] = [None if p is None else [list(x) for x in p] for p in self.mass_points]
        return d

    def __repr__(self) -> str:
        return (f"Structure(name={self.name!r}, nodes={self.n_nodes}, bars={self.n_bars}, "
                f"strings={self.n_strings}, constrained={sorted(self.node_constraints)}, "
                f"gravity={None if self.gravity is None else self.gravity.tolist()})")


_JSON_KEYS = {"name", "nodes", "bars", "strings", "bar_mass", "stiffness", "rest_length", "damping",
              "gravity", "node_constraints", "velocities", "mass_points"}


def from_dict(d: Mapping[str, Any]) -> Structure:
    """Build a :class:`Structure` from a JSON-like mapping (see the README for the keys)."""
    unknown = set(d) - _JSON_KEYS
    if unknown:
        raise StructureError(f"unknown key(s) {sorted(unknown)}; known keys: {sorted(_JSON_KEYS)}")
    for req in ("nodes", "bars", "strings"):
        if req not in d:
            raise StructureError(f"missing required key {req!r}")
    validate_dict(d)
    try:
        return Structure(**{k: d[k] for k in d})
    except StructureError as e:   # a check across keys: cite the schema's description of the key
        key = re.match(r"[a-z_]+", str(e))
        key = key and {"bar": "bars", "string": "strings"}.get(key.group(0), key.group(0))
        desc = _describe(key) if key else ""
        if desc and "(schema," not in str(e):
            raise StructureError(f"{e} (schema, {key}: {desc})") from None
        raise


def load_json(path: str | Path) -> Structure:
    """Load a structure from a JSON file."""
    path = Path(path)
    if path.is_dir():
        raise StructureError(f"{path}: is a directory, not a structure file")
    try:
        raw = read_bounded(path, MAX_FILE_BYTES, "structure file", binary=True)
    except ValueError as e:
        raise StructureError(str(e)) from None
    except PermissionError as e:
        raise StructureError(f"{path}: cannot be read ({e.strerror})") from None
    except IsADirectoryError:
        raise StructureError(f"{path}: is a directory, not a structure file") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise StructureError(f"{path}: not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start})") from None
    d = loads(text, str(path))
    if not isinstance(d, dict):
        raise StructureError(f"{path}: top level must be a JSON object")
    return from_dict(d)


def save_json(structure: Structure, path: str | Path) -> None:
    """Save a structure to a JSON file (round-trips through :func:`load_json`)."""
    Path(path).write_text(json.dumps(structure.to_dict(), indent=1))
