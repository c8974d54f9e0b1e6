"""Structure model of a class-1 tensegrity: nodes, rods, strings, masses, constraints.

Everything is in SI units: positions in m, masses in kg, stiffness in N/m,
rest lengths in m, damping in N s/m, gravity in m/s^2, velocities in m/s.

A :class:`Structure` is immutable and validated on construction; every error
names the offending item (which node, rod, string or field and which value).
It is pure data: the dynamics compile it into a :class:`tensegrity_gym.dynamics.Model`.

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
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

__all__ = ["Structure", "StructureError", "mass_moments", "load_json", "save_json", "from_dict"]


class StructureError(ValueError):
    """Raised when a structure is not a valid class-1 tensegrity."""


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


def _as_per_item(value: Any, count: int, field_name: str, item: str) -> np.ndarray:
    """Broadcast a number or per-item list to a float array of length ``count``."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(count, float(arr))
    if arr.shape != (count,):
        raise StructureError(
            f"{field_name}: expected a number or a list of {count} values (one per {item}), "
            f"got shape {arr.shape}")
    return arr


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
        nodes = np.array(nodes, dtype=float)
        if nodes.ndim != 2 or nodes.shape[1] != 3 or nodes.shape[0] == 0:
            raise StructureError(f"nodes: expected an (n, 3) array with n >= 1, got shape {nodes.shape}")
        if not np.all(np.isfinite(nodes)):
            bad = np.argwhere(~np.isfinite(nodes))[0]
            raise StructureError(f"nodes: node {bad[0]} has a non-finite coordinate {nodes[bad[0]].tolist()}")
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
            if len(mass_points) != k:
                raise StructureError(f"mass_points: expected {k} entries (one per bar), got {len(mass_points)}")
            mp_list = []
            for j, pts in enumerate(mass_points):
                if pts is None:
                    mp_list.append(None)
                    continue
                pts = tuple((float(mu), float(mk)) for mu, mk in pts)
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
        stiffness = _as_per_item(stiffness, m, "stiffness", "string")
        for i, kk in enumerate(stiffness):
            if not (math.isfinite(kk) and kk > 0):
                raise StructureError(
                    f"stiffness of string {i} (nodes {strings[i, 0]}, {strings[i, 1]}): {kk} N/m "
                    "is not positive and finite")
        if rest_length is None:
            rest_length = str_len.copy()
        rest_length = _as_per_item(rest_length, m, "rest_length", "string")
        for i, L0 in enumerate(rest_length):
            if not (math.isfinite(L0) and L0 >= 0):
                raise StructureError(
                    f"rest_length of string {i} (nodes {strings[i, 0]}, {strings[i, 1]}): {L0} m "
                    "is negative or not finite")
        damping = _as_per_item(damping, m, "damping", "string")
        for i, c in enumerate(damping):
            if not (math.isfinite(c) and c >= 0):
                raise StructureError(
                    f"damping of string {i} (nodes {strings[i, 0]}, {strings[i, 1]}): {c} N s/m "
                    "is negative or not finite")

        # gravity
        if gravity is not None:
            gravity = np.array(gravity, dtype=float)
            if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
                raise StructureError(f"gravity: expected 3 finite numbers (m/s^2), got {gravity.tolist()}")

        # constraints
        cons: dict[int, np.ndarray] = {}
        for key, D in (node_constraints or {}).items():
            try:
                node = int(key)
            except (TypeError, ValueError):
                raise StructureError(f"node_constraints: key {key!r} is not a node index") from None
            if not 0 <= node < n:
                raise StructureError(f"node_constraints: node {node} does not exist (there are {n} nodes)")
            if node not in owner:
                raise StructureError(
                    f"node_constraints: node {node} is on no rod; nodes on no rod are already fixed anchors")
            D = np.array(D, dtype=float)
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
            velocities = np.array(velocities, dtype=float)
            if velocities.shape != nodes.shape:
                raise StructureError(f"velocities: expected shape {nodes.shape}, got {velocities.shape}")
            if not np.all(np.isfinite(velocities)):
                raise StructureError("velocities: non-finite entries")
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
        arr = np.asarray(members if members is not None else [], dtype=float)
        if arr.size == 0:
            return np.zeros((0, 2), dtype=np.int64)
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise StructureError(f"{field_name}: expected a list of [a, b] node pairs, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise StructureError(f"{field_name}: node indices must be integers")
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
    return Structure(**{k: d[k] for k in d})


def load_json(path: str | Path) -> Structure:
    """Load a structure from a JSON file."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise StructureError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(d, dict):
        raise StructureError(f"{path}: top level must be a JSON object")
    return from_dict(d)


def save_json(structure: Structure, path: str | Path) -> None:
    """Save a structure to a JSON file (round-trips through :func:`load_json`)."""
    Path(path).write_text(json.dumps(structure.to_dict(), indent=1))
