"""The checks a :class:`~tensegrity_gym.core.structure.Structure` runs on construction.

SI units: positions in m, masses in kg, stiffness in N/m, rest lengths in m, damping in N s/m,
gravity in m/s^2, velocities in m/s. :func:`checked_fields` turns the constructor's arguments
into the structure's validated, read-only arrays or raises a
:class:`~tensegrity_gym.core.errors.StructureError` naming the offending item (which node,
rod, string or field and which value). The checks live apart from the dataclass so that the
class reads as data and derived quantities, and every rule is in one place.

Accepted values (the JSON Schema ``tensegrity_gym/structure.schema.json`` shipped with the package states
them per key; :func:`~tensegrity_gym.core.structure.load_json` / :func:`~tensegrity_gym.core.structure.from_dict`
check a file against it first, and every message cites the key's description there):

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

import math
from typing import Mapping

import numpy as np

from .errors import StructureError
from .rod_mass import centre_of_mass_fraction, mass_moments
from .schema import _as_per_item, _describe, _in_range, _numeric, _show

__all__ = ["checked_fields", "check_members", "check_string_modes", "MIN_STABLE_STEP"]

#: smallest accepted explicit stable step of any single string's mode, s (see the module docstring)
MIN_STABLE_STEP = 1e-9


def checked_fields(nodes, bars, strings, bar_mass, stiffness, rest_length, damping, gravity,
                   node_constraints, velocities, mass_points) -> dict:
    """The validated fields of a structure (arguments as :class:`~tensegrity_gym.core.structure.Structure`),
    as a dict in field order from ``nodes`` to ``mass_points``; every array in it is read-only.
    Raises :class:`StructureError` naming the first item that breaks a rule."""
    nodes = _numeric(nodes, "nodes")
    if nodes.ndim != 2 or nodes.shape[1] != 3 or nodes.shape[0] == 0:
        raise StructureError(f"nodes: expected an (n, 3) array with n >= 1, got shape {nodes.shape}")
    if not np.all(np.isfinite(nodes)):
        bad = np.argwhere(~np.isfinite(nodes))[0]
        raise StructureError(f"nodes: node {bad[0]} has a non-finite coordinate {nodes[bad[0]].tolist()}")
    _in_range(nodes, "nodes", "coordinate", "m", "node")
    n = nodes.shape[0]
    bars = check_members(bars, "bars", "bar", n)
    strings = check_members(strings, "strings", "string", n)
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
        sig = centre_of_mass_fraction(pts)
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

    check_string_modes(nodes, bars, strings, bar_mass, mass_points, cons, stiffness, damping, rod_len)

    for arr in (nodes, bars, strings, bar_mass, stiffness, rest_length, damping, velocities):
        arr.setflags(write=False)
    if gravity is not None:
        gravity.setflags(write=False)
    for D in cons.values():
        D.setflags(write=False)
    return {"nodes": nodes, "bars": bars, "strings": strings, "bar_mass": bar_mass, "stiffness": stiffness,
            "rest_length": rest_length, "damping": damping, "gravity": gravity, "node_constraints": cons,
            "velocities": velocities, "mass_points": mass_points}


def check_members(members, field_name, item, n):
    """(k, 2) int64 node pairs of ``bars`` or ``strings``: integer indices of existing nodes, no
    member from a node to itself, no member twice."""
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


def check_string_modes(nodes, bars, strings, bar_mass, mass_points, cons, stiffness, damping, rod_len):
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
        sig = centre_of_mass_fraction(mp[j])
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
