"""Placing a structure on a terrain: the vertical lift that makes its rod capsules clear the ground.

SI units (m). The geometry is :meth:`tensegrity_gym.core.terrain.Terrain.closest` (signed
distance and outward normal); nothing here re-derives the shape of a plane, a box or a
heightfield. Used by the command line (``simulate --terrain``, ``export --terrain``) so that a
run starts with no rod inside the ground: a structure built standing on z = 0 is lifted by its
cap radius on a level plane, and onto the ramp, the step or the heightfield under it elsewhere.
"""
from __future__ import annotations

import numpy as np

from .terrain import Terrain

__all__ = ["terrain_lift", "place_on_terrain", "MAX_ROD_SAMPLES"]

#: most points per rod where the capsule's clearance is checked
MAX_ROD_SAMPLES = 2001


def _rod_points(nodes: np.ndarray, bars: np.ndarray, radius: float) -> np.ndarray:
    """(k S, 3) points along the rods (m), both nodes and the points between, at most ``radius / 4``
    apart (S <= :data:`MAX_ROD_SAMPLES`): a box or a bump under the middle of a rod lifts it too.
    The signed distance changes by at most the spacing between two points, so the capsule between
    them clears the terrain by at least ``radius - spacing / 2``. The nodes alone when there are no rods."""
    if len(bars) == 0:
        return nodes
    a, c = nodes[bars[:, 0]][:, None, :], nodes[bars[:, 1]][:, None, :]
    longest = float(np.linalg.norm(c - a, axis=-1).max())
    n = int(min(MAX_ROD_SAMPLES, max(2, np.ceil(4.0 * longest / radius) + 1 if radius > 0 else 2)))
    s = np.linspace(0.0, 1.0, n)[None, :, None]
    return (a + s * (c - a)).reshape(-1, 3)


def terrain_lift(terrain: Terrain, nodes, bars, radius: float, max_iter: int = 200) -> float:
    """The smallest upward shift (m, >= 0) after which every rod's capsule of ``radius`` m (the
    segment between its nodes, ``bars`` (k, 2) node indices, swept by the sphere) lies on or
    above ``terrain``: the signed distance of the nodes and of points along the rods (at most
    ``radius / 4`` apart) to the terrain is at least ``radius``. 0 when the structure already
    clears it (a structure above the ground stays where it is and falls). ``nodes`` (n, 3) m.

    Each iteration lifts by the missing clearance divided by the vertical component of the
    outward normal where it is smallest (exact in one step for a plane or a heightfield patch;
    along a box's side the normal is horizontal and the lift grows until the rod is above the
    box). ValueError if it has not converged in ``max_iter`` iterations (a structure under a
    box, for instance)."""
    nodes = np.asarray(nodes, float)
    radius = float(radius)
    pts = _rod_points(nodes, np.asarray(bars, int).reshape(-1, 2), radius)
    span = float(np.ptp(pts, axis=0).max()) if len(pts) > 1 else 1.0
    tol = 1e-12 * max(span, radius, 1.0)
    lift = 0.0
    for _ in range(max_iter):
        d, n = terrain.closest(pts + np.array([0.0, 0.0, lift]))
        i = int(np.argmin(d))
        short = radius - float(d[i])
        if short <= tol:
            return lift
        # a normal near horizontal (a box side) or pointing down (under a box): lift by the gap itself
        lift += short / max(float(n[i, 2]), 0.1) + tol
    raise ValueError(f"terrain: no upward shift below {lift:.4g} m puts the rods on the terrain "
                     "(is the structure under a box?)")


def place_on_terrain(structure, terrain: Terrain, radius: float):
    """``(structure, lift)``: the structure shifted up by :func:`terrain_lift` (m) so that its rods'
    capsules of ``radius`` m rest on or above ``terrain`` (unchanged when the lift is 0). The
    whole structure moves: anchors and constrained nodes with it (``Structure.replace``)."""
    lift = terrain_lift(terrain, structure.nodes, structure.bars, radius)
    if lift == 0.0:
        return structure, 0.0
    return structure.replace(nodes=structure.nodes + np.array([0.0, 0.0, lift])), lift
