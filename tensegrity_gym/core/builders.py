"""Factories that return validated :class:`~tensegrity_gym.core.structure.Structure` objects.

All lengths in m, masses in kg, stiffness in N/m, tensions in N, gravity in m/s^2.

* :func:`prism` -- Snelson p-bar prism (bottom, top, vertical strings).
* :func:`pinned_rod` -- the seed's Example 5.3: a rod pinned at one end, three strings.
* :func:`constrained_prism` -- the seed's Example 5.8: a 3-prism whose bottom rod ends
  are pinned / sliding on a line / sliding on the plane z = 0.
* :func:`icosahedron` -- 6-bar "expanded octahedron" (24 strings), the shape of SUPERball.
* :func:`tower` -- q stacked class-1 prism stages.
* :func:`build` -- any of the above by name (``"prism3"``, ``"icosahedron"``, ...).
"""
from __future__ import annotations

import difflib
import math
import os

import numpy as np

from .mjcf_import import from_mjcf
from .structure import Structure, StructureError, load_json

__all__ = ["load_structure", "prism", "pinned_rod", "constrained_prism", "icosahedron", "tower", "build", "BUILDERS",
           "self_stress", "rest_lengths_for_force_densities"]


def _equilibrium_matrix(nodes: np.ndarray, bars: np.ndarray, strings: np.ndarray) -> np.ndarray:
    """Matrix A (6k, m): A @ gamma stacks, per rigid rod, the net force and the
    component of the end-force difference normal to the rod produced by string
    force densities gamma (N/m). A @ gamma = 0 <=> every rod is in equilibrium."""
    n, m = len(nodes), len(strings)
    cols = np.zeros((n, 3, m))
    for i, (a, b) in enumerate(strings):
        s = nodes[b] - nodes[a]
        cols[a, :, i] += s          # node a pulled towards b
        cols[b, :, i] -= s
    rows = []
    for a, c in bars:
        bvec = nodes[c] - nodes[a]
        P = np.eye(3) - np.outer(bvec, bvec) / (bvec @ bvec)
        rows.append(cols[a] + cols[c])
        rows.append(P @ (cols[c] - cols[a]))
    return np.concatenate(rows, axis=0)


def self_stress(nodes, bars, strings) -> tuple[np.ndarray, float]:
    """Unit-norm string force densities (N/m up to scale) that put every free rod
    in equilibrium with no external load, and the relative residual.

    Returns ``(gamma, residual)`` with ``gamma >= 0`` oriented so that strings pull.
    Raises :class:`StructureError` if the best self-stress is not all-tension.
    """
    A = _equilibrium_matrix(np.asarray(nodes, float), np.asarray(bars), np.asarray(strings))
    _, sv, vt = np.linalg.svd(A)
    gamma = vt[-1]
    if gamma.sum() < 0:
        gamma = -gamma
    resid = float(sv[-1] / sv[0]) if len(sv) == A.shape[1] else 0.0
    if np.any(gamma < -1e-12):
        raise StructureError(
            f"the self-stress of this geometry has compressed strings (min force density {gamma.min():.3g}); "
            "check the twist / connectivity")
    return np.maximum(gamma, 0.0), resid


def rest_lengths_for_force_densities(lengths, gamma, stiffness) -> np.ndarray:
    """Rest lengths (m) that give force densities ``gamma`` (N/m) at string ``lengths`` (m):
    ``k (L - l0) / L = gamma``  =>  ``l0 = L (1 - gamma / k)``."""
    lengths, gamma, stiffness = np.broadcast_arrays(*(np.asarray(x, float) for x in (lengths, gamma, stiffness)))
    l0 = lengths * (1.0 - gamma / stiffness)
    if np.any(l0 <= 0):
        i = int(np.argmin(l0))
        raise StructureError(
            f"string {i}: force density {gamma[i]:.4g} N/m needs stiffness above {gamma[i]:.4g} N/m "
            f"(got {stiffness[i]:.4g}); the rest length would be {l0[i]:.4g} m")
    return l0


def _prestressed_rest_lengths(nodes, bars, strings, stiffness, prestress, which) -> np.ndarray:
    """Rest lengths putting the structure in exact equilibrium, scaled so the largest
    tension among strings ``which`` (a slice/index array) equals ``prestress`` (N)."""
    nodes = np.asarray(nodes, float)
    gamma, resid = self_stress(nodes, bars, strings)
    if resid > 1e-9:
        raise StructureError(f"this geometry admits no exact self-stress (relative residual {resid:.2e})")
    L = np.linalg.norm(nodes[strings[:, 1]] - nodes[strings[:, 0]], axis=1)
    tension = gamma * L
    gamma = gamma * prestress / np.max(tension[which])
    return rest_lengths_for_force_densities(L, gamma, np.broadcast_to(stiffness, L.shape))


def _prism_layout(p: int, radius: float, height: float, twist: float, z0: float = 0.0,
                  phase: float = 0.0, offset: int = 0):
    """Nodes, bars and strings of one p-bar prism stage. Bottom node i at angle
    ``phase + 2 pi i / p``; top node i at the same angle plus ``twist``; vertical
    string i joins bottom i to top i; rod i joins bottom i to top i+1."""
    ang = phase + 2 * np.pi * np.arange(p) / p
    bottom = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.full(p, z0)], axis=1)
    top = np.stack([radius * np.cos(ang + twist), radius * np.sin(ang + twist), np.full(p, z0 + height)], axis=1)
    nodes = np.concatenate([bottom, top])
    o = offset
    bars = np.array([[o + i, o + p + (i + 1) % p] for i in range(p)])
    bottom_s = [[o + i, o + (i + 1) % p] for i in range(p)]
    top_s = [[o + p + i, o + p + (i + 1) % p] for i in range(p)]
    vert_s = [[o + i, o + p + i] for i in range(p)]
    return nodes, bars, np.array(bottom_s + top_s + vert_s)


def prism(p: int = 3, radius: float = 0.5, height: float = 1.0, twist: float | None = None,
          bar_mass: float = 1.0, stiffness: float = 1000.0, prestress: float | None = 100.0,
          damping: float = 0.0, gravity=None, name: str | None = None) -> Structure:
    """Snelson p-bar prism: p rods, p bottom + p top + p vertical strings (3p strings, 2p nodes).

    Parameters (SI units)
    ---------------------
    p : number of rods (>= 3).
    radius : circumradius of the top and bottom polygons, m.
    height : distance between the polygons, m.
    twist : rotation of the top polygon relative to the bottom, rad.
        Default ``pi/2 - pi/p``, the only twist at which the prism has a prestressed equilibrium.
    bar_mass : kg per rod. stiffness : N/m per string.
    prestress : tension of the vertical strings in N at which the prism is in exact
        equilibrium (rest lengths are set accordingly); ``None`` = rest lengths equal to
        the string lengths (no prestress; then any twist is allowed).
    damping : N s/m per string. gravity : (3,) m/s^2 or None.

    Node order: bottom 0..p-1, top p..2p-1. String order: bottom, top, vertical.
    """
    if int(p) != p or p < 3:
        raise StructureError(f"prism: p must be an integer >= 3, got {p}")
    for nm, v in (("radius", radius), ("height", height)):
        if not (math.isfinite(v) and v > 0):
            raise StructureError(f"prism: {nm} must be positive, got {v} m")
    twist = np.pi / 2 - np.pi / p if twist is None else float(twist)
    nodes, bars, strings = _prism_layout(p, radius, height, twist)
    if prestress is None:
        rest = None
    else:
        if not (math.isfinite(prestress) and prestress > 0):
            raise StructureError(f"prism: prestress must be positive (N) or None, got {prestress}")
        rest = _prestressed_rest_lengths(nodes, bars, strings, stiffness, prestress, slice(2 * p, 3 * p))
    return Structure(nodes, bars, strings, bar_mass=bar_mass, stiffness=stiffness, rest_length=rest,
                     damping=damping, gravity=gravity, name=name or f"prism{p}")


def pinned_rod(length: float = 1.0, bar_mass: float = 1.0, stiffness: float = 1000.0,
               anchor_radius: float = 1.0, anchor_height: float = 0.5, tilt: float = 0.2,
               prestrain: float = 0.05, damping: float = 0.0, gravity=(0.0, 0.0, -9.81)) -> Structure:
    """The seed's Example 5.3: a rod with node 0 pinned at the origin and node 1 held by
    three strings to fixed anchors (nodes 2, 3, 4) on a circle of ``anchor_radius`` at
    height ``anchor_height``. The rod starts tilted by ``tilt`` rad from vertical;
    strings have rest length ``(1 - prestrain)`` times their initial length."""
    top = length * np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    ang = 2 * np.pi * np.arange(3) / 3 + np.pi / 3
    anchors = np.stack([anchor_radius * np.cos(ang), anchor_radius * np.sin(ang), np.full(3, anchor_height)], 1)
    nodes = np.concatenate([[[0.0, 0.0, 0.0]], [top], anchors])
    strings = np.array([[1, 2], [1, 3], [1, 4]])
    L = np.linalg.norm(nodes[strings[:, 1]] - nodes[strings[:, 0]], axis=1)
    return Structure(nodes, [[0, 1]], strings, bar_mass=bar_mass, stiffness=stiffness,
                     rest_length=(1 - prestrain) * L, damping=damping, gravity=gravity,
                     node_constraints={0: np.eye(3)}, name="pinned_rod")


def constrained_prism(radius: float = 0.5, height: float = 1.0, bar_mass: float = 1.0,
                      stiffness: float = 1000.0, prestress: float = 100.0, damping: float = 0.0,
                      gravity=(0.0, 0.0, -9.81)) -> Structure:
    """The seed's Example 5.8: a 3-bar prism standing on the plane z = 0 with its bottom
    rod ends constrained: node 0 pinned, node 1 sliding on the line through nodes 0
    and 1 (the x axis), node 2 sliding on the plane z = 0. This removes the six
    rigid-body modes. Geometry and prestress as :func:`prism` (p = 3), rotated so that
    node 0 is at the origin and node 1 on the +x axis."""
    base = prism(3, radius=radius, height=height, bar_mass=bar_mass, stiffness=stiffness,
                 prestress=prestress, damping=damping)
    nodes = base.nodes - base.nodes[0]
    d = nodes[1] / np.linalg.norm(nodes[1])
    rot = np.array([[d[0], d[1], 0.0], [-d[1], d[0], 0.0], [0.0, 0.0, 1.0]])
    nodes = nodes @ rot.T
    cons = {0: np.eye(3), 1: np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), 2: np.array([[0.0, 0.0, 1.0]])}
    return Structure(nodes, base.bars, base.strings, bar_mass=bar_mass, stiffness=stiffness,
                     rest_length=base.rest_length, damping=damping, gravity=gravity,
                     node_constraints=cons, name="constrained_prism")


def _icosahedron_layout(length: float, separation: float):
    a, s = length / 2, separation / 2
    nodes = []
    bars = []
    # rods along z at (0, +-s), along x at (+-s in z), along y at (+-s in x)
    for sign in (-1, 1):
        nodes += [[0, sign * s, -a], [0, sign * s, a]]
    for sign in (-1, 1):
        nodes += [[-a, 0, sign * s], [a, 0, sign * s]]
    for sign in (-1, 1):
        nodes += [[sign * s, -a, 0], [sign * s, a, 0]]
    nodes = np.array(nodes, float)
    bars = np.arange(12).reshape(6, 2)
    # strings: the 24 shortest node-to-node distances between nodes of non-parallel rods
    pairs = []
    for i in range(12):
        for j in range(i + 1, 12):
            if i // 4 == j // 4:      # same parallel pair (or same rod)
                continue
            pairs.append((np.linalg.norm(nodes[i] - nodes[j]), i, j))
    pairs.sort()
    strings = np.array([[i, j] for _, i, j in pairs[:24]])
    return nodes, bars, strings


def icosahedron(length: float = 1.0, bar_mass: float = 1.0, stiffness: float = 1000.0,
                prestress: float | None = 50.0, damping: float = 0.0, gravity=None) -> Structure:
    """6-bar "expanded octahedron" tensegrity icosahedron (12 nodes, 6 rods, 24 strings),
    the shape of NASA's SUPERball. Rods come in three parallel pairs along x, y, z.
    The separation of each pair is form-found (half the rod length) so that equal
    force densities in all 24 strings give an exact equilibrium. ``prestress``: string
    tension in N (all strings carry the same), or None for no prestress."""
    separation = length / 2.0
    nodes, bars, strings = _icosahedron_layout(length, separation)
    # centre at z = length/2 so that it can rest above the ground
    if prestress is None:
        rest = None
    else:
        rest = _prestressed_rest_lengths(nodes, bars, strings, stiffness, prestress, slice(None))
    return Structure(nodes, bars, strings, bar_mass=bar_mass, stiffness=stiffness, rest_length=rest,
                     damping=damping, gravity=gravity, name="icosahedron")


def tower(q: int = 3, p: int = 3, radius: float = 0.5, stage_height: float = 1.0, overlap: float = 0.25,
          bar_mass: float = 1.0, stiffness: float = 1000.0, pretension: float = 0.02,
          damping: float = 0.0, gravity=None) -> Structure:
    """q stacked class-1 p-prism stages (q p rods, 2 q p nodes). Stage s+1 starts
    ``overlap`` * ``stage_height`` below the top of stage s and is rotated by pi/p;
    its bottom nodes are tied to the top nodes of stage s by 2p saddle strings.
    ``pretension`` sets every rest length to ``(1 - pretension)`` times the initial
    length (a uniform strain: the tower is *not* exactly in equilibrium; it is
    a benchmark scene, not a statics example)."""
    if int(q) != q or q < 1:
        raise StructureError(f"tower: q must be an integer >= 1, got {q}")
    twist = np.pi / 2 - np.pi / p
    all_nodes, all_bars, all_str = [], [], []
    for s in range(q):
        z0 = s * stage_height * (1 - overlap)
        nodes, bars, strings = _prism_layout(p, radius, stage_height, twist, z0=z0,
                                             phase=s * np.pi / p, offset=2 * p * s)
        all_nodes.append(nodes)
        all_bars.append(bars)
        all_str.append(strings)
        if s > 0:
            prev_top = 2 * p * (s - 1) + p + np.arange(p)
            bottom = 2 * p * s + np.arange(p)
            saddle = [[prev_top[i], bottom[i]] for i in range(p)] + \
                     [[prev_top[i], bottom[(i + 1) % p]] for i in range(p)]
            all_str.append(np.array(saddle))
    nodes = np.concatenate(all_nodes)
    strings = np.concatenate(all_str)
    L = np.linalg.norm(nodes[strings[:, 1]] - nodes[strings[:, 0]], axis=1)
    return Structure(nodes, np.concatenate(all_bars), strings, bar_mass=bar_mass, stiffness=stiffness,
                     rest_length=(1 - pretension) * L, damping=damping, gravity=gravity, name=f"tower{q}")


# TensegrityRoll-v0's robots (the env puts them on the ground: envs/roll_scene.py)
GRAVITY = (0.0, 0.0, -9.81)   # m/s^2
ROD_MASS = 0.2          # kg per rod
STRING_STIFFNESS = 1000.0   # N/m
STRING_DAMPING = 2.0    # N s/m
PRISM_RADIUS = 0.15     # m
PRISM_HEIGHT = 0.25     # m
PRISM_PRESTRESS = 20.0  # N in the vertical strings
ICO_LENGTH = 0.4        # m
ICO_PRESTRESS = 10.0    # N in every string


def robot_prism(string_damping: float = STRING_DAMPING) -> Structure:
    """The default 3-bar prism robot (not yet placed on the ground): rods 0.383 m, 0.2 kg."""
    return prism(3, radius=PRISM_RADIUS, height=PRISM_HEIGHT, bar_mass=ROD_MASS,
                 stiffness=STRING_STIFFNESS, prestress=PRISM_PRESTRESS, damping=string_damping,
                 gravity=GRAVITY, name="prism_robot")


def robot_icosahedron(string_damping: float = STRING_DAMPING) -> Structure:
    """The 6-bar icosahedron robot (SUPERball's shape at the 3-bar robot's rod scale): rods 0.4 m, 0.2 kg."""
    return icosahedron(length=ICO_LENGTH, bar_mass=ROD_MASS, stiffness=STRING_STIFFNESS,
                       prestress=ICO_PRESTRESS, damping=string_damping,
                       gravity=GRAVITY).replace(name="icosahedron_robot")


BUILDERS = {
    "prism3": lambda: prism(3),
    "prism4": lambda: prism(4),
    "prism6": lambda: prism(6),
    "pinned_rod": pinned_rod,
    "constrained_prism": constrained_prism,
    "icosahedron": icosahedron,
    "tower3": lambda: tower(3),
    "tower30": lambda: tower(30),
    "prism_robot": robot_prism,                # TensegrityRoll-v0's structure="prism"
    "icosahedron_robot": robot_icosahedron,    # ... and structure="icosahedron"
}


def build(name: str) -> Structure:
    """A built-in structure by name: one of :data:`BUILDERS`, or ``prism<p>`` / ``tower<q>``."""
    if name in BUILDERS:
        return BUILDERS[name]()
    for prefix, fn in (("prism", prism), ("tower", tower)):
        if name.startswith(prefix) and name[len(prefix):].isdigit():
            return fn(int(name[len(prefix):]))
    close = difflib.get_close_matches(name, BUILDERS, n=4, cutoff=0.5)
    raise StructureError(f"unknown structure {name!r}" + (f" (did you mean {', '.join(close)}?)" if close else "")
                         + f"; built-in names: {sorted(BUILDERS)} "
                         "(or prism<p>, tower<q>), or a path to a JSON file")


def load_structure(spec) -> Structure:
    """A :class:`Structure` from a Structure, a built-in name (``"prism3"``), a JSON path or a
    MuJoCo model path (``.xml``: :func:`tensegrity_gym.core.mjcf_import.from_mjcf`, whose report is
    not returned here; ``python -m tensegrity_gym import`` prints it)."""
    if isinstance(spec, Structure):
        return spec
    if isinstance(spec, (str, os.PathLike)):
        s = str(spec)
        if s.lower().endswith(".xml"):
            return from_mjcf(s)[0]
        if s.endswith(".json") or os.path.exists(s):
            return load_json(s)
        return build(s)
    raise StructureError(f"structure: expected a Structure, a builder name, a JSON path or an MJCF (.xml) path, "
                         f"got {spec!r}")
