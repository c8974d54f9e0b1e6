"""Drops onto terrain: a structure released at rest from a height, its energy over the fall and
the impacts, with the terrain contact the envs and ``simulate --terrain`` run (normal damping
capped by :func:`~tensegrity_gym.physics.contact.impact_damping_cap`). What the drop checks of
``tests/test_drops.py`` and ``python -m scripts.eval.drop_matrix`` measure; docs/contact.md
("Impacts") explains the law. SI units.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.model import compile_model, initial_state
from ..core.placement import place_on_terrain
from ..core.terrain import Box, Heightfield, Terrain
from ..physics import geometry
from ..physics import terrain as terrain_physics
from ..physics.contact import impact_damping_cap
from ..physics.loads import member_loads

__all__ = ["DropResult", "drop", "drop_terrains"]


def drop_terrains() -> dict[str, Terrain]:
    """The terrains of the drop checks: a level plane; the face of a 0.5 m thick box; a box edge
    (a 0.3 m step turned 30 degrees under the robot); a 0.2 m slot between two boxes; a
    heightfield of 5 cm bumps (seeded); a plate as thick as the default cap radius (2 cm)."""
    rng = np.random.default_rng(0)
    return {
        "plane": Terrain(),
        "box_face": Terrain(plane=None, boxes=(Box(center=[0, 0, -0.25], size=[4, 4, 0.5]),)),
        "box_edge": Terrain(boxes=(Box(center=[0.2, 0, 0.15], size=[0.4, 2, 0.3], yaw_deg=30),)),
        "slot": Terrain(boxes=(Box(center=[-0.35, 0, 0.25], size=[0.5, 2, 0.5]),
                               Box(center=[0.35, 0, 0.25], size=[0.5, 2, 0.5]))),
        "heightfield": Terrain(plane=None, heightfield=Heightfield(heights=0.05 * rng.standard_normal((41, 41)),
                                                                   cell=0.1, origin=[-2, -2])),
        "plate_2cm": Terrain(plane=None, boxes=(Box(center=[0, 0, -0.01], size=[4, 4, 0.02]),)),
    }


@dataclass(frozen=True)
class DropResult:
    """One drop: ``t`` (S,) s and ``energy`` (S,) J (kinetic + gravity + strings; the contact
    springs' energy left out, so passive contact keeps it at or below the start's), ``lowest``
    (S,) m the lowest node's height, recorded every ``record_every`` steps; ``impact_speed`` m/s
    of free fall from ``height``; ``energy_ratio`` the largest energy over the start's."""

    t: np.ndarray
    energy: np.ndarray
    lowest: np.ndarray
    height: float
    impact_speed: float
    #: with ``loads=True``, per record: the largest rod compression, string tension and nodal
    #: contact force, N (:func:`tensegrity_gym.physics.loads.member_loads`); else None
    rod_compression: np.ndarray | None = None
    string_tension: np.ndarray | None = None
    contact_force: np.ndarray | None = None

    @property
    def energy_ratio(self) -> float:
        return float(self.energy.max() / self.energy[0])


def drop(structure, terrain: Terrain, height: float, integrator: str = "semi_implicit_euler", dt: float = 1e-3,
         after: float = 1.0, radius: float = 0.02, record_every: int = 10, max_damping: float | None = None,
         backend: str = "auto", loads: bool = False) -> DropResult:
    """Drop ``structure`` (with gravity) from ``height`` m above where it rests on ``terrain``
    (its rods' capsules of ``radius`` m), at rest, and run ``after`` s past the free fall's
    time to impact with ``integrator`` at ``dt`` s. ``max_damping`` (N s/m): the contact's
    damping cap; None: :func:`~tensegrity_gym.physics.contact.impact_damping_cap` at ``dt``
    (what the envs and the command line use; ``math.inf``: no cap). ``loads``: also record the
    members' largest loads (the contact forces and strings at each record's state; use
    ``record_every=1`` to catch an impact's peak)."""
    s, _ = place_on_terrain(structure, terrain, radius)
    s = s.replace(nodes=s.nodes + np.array([0.0, 0.0, float(height)]))
    model = compile_model(s)
    state = initial_state(model)
    cap = impact_damping_cap(s.bar_mass, dt) if max_damping is None else max_damping
    tc = terrain_physics.TerrainContact(terrain, radius=radius, max_damping=cap)
    tstate = terrain_physics.init_terrain_state(tc, model)
    g = float(np.linalg.norm(s.gravity))
    fall = math.sqrt(2.0 * height / g)
    n_rec = int(math.ceil((fall + after) / (dt * record_every)))
    t, E, low = np.empty(n_rec + 1), np.empty(n_rec + 1), np.empty(n_rec + 1)
    peaks = np.zeros((3, n_rec + 1)) if loads else None

    def record(i, st):
        t[i] = st.t
        E[i] = float(geometry.energy(model, st.q, st.qd)[0])
        low[i] = float(geometry.node_positions(model, st.q)[0, :, 2].min())
        if loads:
            W = terrain_physics.contact_forces(tc, model, st.q, st.qd, tstate)[0]
            ld = member_loads(model, st.q, st.qd, external=W)
            peaks[:, i] = (ld["rod_compression"].max(), ld["string_tension"].max(),
                           np.linalg.norm(W, axis=-1).max())
    record(0, state)
    for i in range(1, n_rec + 1):
        state, tstate = terrain_physics.step(model, state, dt, tc, tstate, integrator, n_steps=record_every,
                                             backend=backend)
        record(i, state)
    extra = {} if peaks is None else dict(rod_compression=peaks[0], string_tension=peaks[1], contact_force=peaks[2])
    return DropResult(t=t, energy=E, lowest=low, height=float(height), impact_speed=g * fall, **extra)
