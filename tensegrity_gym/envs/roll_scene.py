"""The TensegrityRoll-v0 robots and how they are put on the ground (no gymnasium). SI units."""
from __future__ import annotations

import math

import numpy as np

from ..core.builders import (GRAVITY, ICO_LENGTH, ICO_PRESTRESS, PRISM_HEIGHT, PRISM_PRESTRESS,  # noqa: F401
                             PRISM_RADIUS, ROD_MASS, STRING_DAMPING, STRING_STIFFNESS, robot_icosahedron,
                             robot_prism)
from ..physics.contact import GroundContact, init_contact_state
from ..physics.pipeline import contact_step
from ..core.model import initial_state
from ..physics.geometry import node_velocities
from ..core.structure import Structure
from .validate import load_env_structure

__all__ = ["robot_prism", "robot_icosahedron", "place_on_ground", "put_on_ground", "settle", "load_robot",
           "GRAVITY"]

# default robot (see the class docstring, "Scene"): its structure and constants live in core.builders
MAX_CABLE_ACCELERATION = 2.0   # m/s^2, cable motor acceleration limit (0.2 m/s reached in 0.1 s)
SETTLE_TIME = 1.5       # s of simulated settling at construction
MAX_PATH = 5000         # centre-of-mass points kept per env for rendering
_SETTLED: dict = {}     # settled rest states of the built-in scenes, by parameters


def _rot_to(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation matrix taking unit vector a to unit vector b."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        if c > 0:
            return np.eye(3)
        p = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(p) < 1e-6:
            p = np.cross(a, [0.0, 1.0, 0.0])
        p /= np.linalg.norm(p)
        return 2.0 * np.outer(p, p) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def place_on_ground(nodes: np.ndarray, masses_com: np.ndarray, radius: float, exclude_axis=None,
                    roll_axis=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, float]:
    """Rotate/translate ``nodes`` (n, 3) so that the structure rests on the face of its convex hull
    with the largest stability margin (distance from the centre of mass's projection to the face's
    nearest edge), faces normal to ``exclude_axis`` excluded (the prism lies on its side), the
    caps touching ``z = 0`` (node height ``radius``), centre of mass above the origin and
    ``exclude_axis`` (if given) turned towards ``roll_axis`` so that the prism rolls along x.
    Returns ``(nodes, margin m)``."""
    from scipy.spatial import ConvexHull
    hull = ConvexHull(nodes)
    best = None
    for simplex, eq in zip(hull.simplices, hull.equations):
        nrm = eq[:3]
        if exclude_axis is not None and abs(nrm @ exclude_axis) / np.linalg.norm(exclude_axis) > 0.9:
            continue
        R = _rot_to(nrm, np.array([0.0, 0.0, -1.0]))
        tri = ((nodes - masses_com) @ R.T)[simplex][:, :2]
        marg = np.inf
        for i in range(3):
            a, b, c = tri[i], tri[(i + 1) % 3], tri[(i + 2) % 3]
            e = b - a
            nn = np.array([e[1], -e[0]]) / np.linalg.norm(e)
            if (c - a) @ nn < 0:
                nn = -nn
            marg = min(marg, float(-a @ nn))
        if best is None or marg > best[0] + 1e-9:
            best = (marg, R)
    marg, R = best
    P = (nodes - masses_com) @ R.T
    if exclude_axis is not None:
        ax = R @ np.asarray(exclude_axis, float)
        ang = math.atan2(ax[1], ax[0])
        tgt = math.atan2(roll_axis[1], roll_axis[0])
        th = tgt - ang
        Rz = np.array([[math.cos(th), -math.sin(th), 0.0], [math.sin(th), math.cos(th), 0.0], [0.0, 0.0, 1.0]])
        P = P @ Rz.T
    P[:, 2] += radius - P[:, 2].min()
    return P, marg


def load_robot(structure, string_damping):
    """(structure, prism axis or None) of a built-in robot name or any free structure (gravity added)."""
    if isinstance(structure, str) and structure in ("prism", "prism_robot"):
        s = robot_prism(STRING_DAMPING if string_damping is None else string_damping)
        axis = s.nodes[3:].mean(0) - s.nodes[:3].mean(0)
        return s, axis
    if isinstance(structure, str) and structure in ("icosahedron", "icosahedron_robot"):
        s = robot_icosahedron(STRING_DAMPING if string_damping is None else string_damping)
        return s, None
    s = load_env_structure(structure)
    if s.node_constraints or s.anchors.size:
        raise ValueError(f"structure {s.name!r}: the roll task needs a free structure (no node constraints, "
                         "no fixed anchor nodes)")
    if s.gravity is None:
        s = s.replace(gravity=GRAVITY)
    if string_damping is not None:
        s = s.replace(damping=string_damping)
    return s, None


def put_on_ground(s: Structure, radius: float, axis=None) -> tuple[Structure, float]:
    """``s`` placed on its most stable face with its caps (radius m) on ``z = 0``
    (:func:`place_on_ground` from its centre of mass; ``axis``: the prism's, turned along y).
    Returns ``(structure, stability margin m)``."""
    rod_com = (s.nodes[s.bars[:, 0]] * (1 - s.com_fraction)[:, None]
               + s.nodes[s.bars[:, 1]] * s.com_fraction[:, None])
    com = s.bar_mass @ rod_com / s.bar_mass.sum()
    nodes, margin = place_on_ground(s.nodes, com, radius, exclude_axis=axis)
    return s.replace(nodes=nodes), margin


def settle(model, ground: GroundContact, integrator: str, dt: float, key=None) -> tuple[np.ndarray, np.ndarray]:
    """Rest state ``(q, qd = 0)`` (1, k, 6) of the placed robot ``model`` under gravity on the
    ``ground`` (a :class:`~tensegrity_gym.physics.contact.GroundContact`): SETTLE_TIME s from the
    placed shape (``physics.pipeline.contact_step``), with extra viscous drag on the nodes (only
    here) so that it comes to rest. ``key``: remember the result for the process
    (built-in scenes: one settling per parameter set)."""
    if key is not None and key in _SETTLED:
        return tuple(x.copy() for x in _SETTLED[key])
    st = initial_state(model, 1)
    cs = init_contact_state(model, 1)
    drag = 4.0 * float(model.mass.max())  # N s/m per node
    for _ in range(int(round(SETTLE_TIME / dt))):
        ext = -drag * node_velocities(model, st.qd)
        st, cs = contact_step(model, ground, st, cs, dt, integrator, external=ext)
    if not np.all(np.isfinite(st.q)):
        name = model.structure.name
        raise ValueError(f"structure {name!r}: settling on the ground diverged at dt = {dt} s; reduce dt")
    q, qd = st.q.copy(), np.zeros_like(st.qd)     # freeze: keep the configuration, zero velocities
    if key is not None:
        _SETTLED[key] = (q.copy(), qd.copy())
    return q, qd
