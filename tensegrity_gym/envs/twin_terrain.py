"""The terrain of the MuJoCo twins (:mod:`tensegrity_gym.envs.roll_mujoco`): a terrain drawn per
episode written into the live ``MjModel``. SI units.

The terrain's MuJoCo geoms (plane, boxes, heightfield) are those of
:func:`tensegrity_gym.io.mjcf.terrain_xml`, the one mapping of a
:class:`~tensegrity_gym.core.terrain.Terrain` onto MuJoCo. A generator's terrains keep their parts
and grid shape (:mod:`tensegrity_gym.tasks.terrain`), so the model's structure never changes from
one episode to the next: each episode's terrain is compiled by MuJoCo from the same MJCF and its
numbers are copied into the live model in place, namely the world geoms' ``geom_pos``,
``geom_quat``, ``geom_size``, bounding sphere and box (``geom_rbound``, ``geom_aabb``) and
``geom_friction``, the heightfield's ``hfield_size`` and ``hfield_data``, and the world body's
bounding-volume tree (``bvh_*``: MuJoCo's collision mid-phase reads it, so a geom moved without it
could be missed). Copying what MuJoCo compiled, rather than recomputing it, keeps MuJoCo's own
derived values (an hfield geom's size and bounds follow from the field's height range).

A heightfield ends at its grid in MuJoCo, where ours holds its edge values beyond it. A terrain
with a heightfield and no plane (the navigation courses, the ``"rough"`` generator) would leave the
robot nothing to stand on past the grid, so the twin's scene adds a level floor
(:func:`floor_height`) :data:`FLOOR_GAP` below the heightfield's lowest point: it never touches a
robot standing on the grid (MuJoCo's caps rest about 0.01 mm deep), and beyond the grid it is ours
to within ``FLOOR_GAP`` where the edge heights are the lowest (the courses: 0, their rough patches
end inside the grid) and lower by at most the edge's height above the lowest point elsewhere (the
``"rough"`` generator: its ``amplitude``).
"""
from __future__ import annotations

import numpy as np

from ..core.terrain import Terrain

__all__ = ["GEOM_FIELDS", "BVH_FIELDS", "world_geoms", "copy_terrain", "floor_height", "FLOOR_GAP"]

#: per-geom fields of the terrain's geoms copied from the compiled model
GEOM_FIELDS = ("geom_pos", "geom_quat", "geom_size", "geom_rbound", "geom_aabb", "geom_friction")
#: per-node fields of the world body's bounding-volume tree copied with them
BVH_FIELDS = ("bvh_aabb", "bvh_child", "bvh_nodeid", "bvh_depth")


#: the floor's depth below a heightfield's lowest point, m
FLOOR_GAP = 1e-3


def floor_height(terrain: Terrain) -> float | None:
    """Height (m) of the floor under ``terrain``'s heightfield in the twin's scene (module doc), or
    None (a terrain with a plane, or without a heightfield, needs none)."""
    hf = terrain.heightfield
    if terrain.plane is not None or hf is None:
        return None
    return float(hf.heights.min()) - FLOOR_GAP


def world_geoms(model) -> np.ndarray:
    """Ids of the geoms on the world body (the terrain's: the rods' geoms are on their own bodies)."""
    return np.flatnonzero(model.geom_bodyid == 0)


def copy_terrain(model, source) -> None:
    """Write the terrain of ``source`` (an ``MjModel`` of the same scene compiled with another
    terrain of the same parts and grid shape) into ``model`` in place (see the module doc).
    RuntimeError when the two scenes' terrains differ in parts, geom types or grid shape."""
    g = world_geoms(model)
    same = (np.array_equal(g, world_geoms(source)) and np.array_equal(model.geom_type[g], source.geom_type[g])
            and model.nhfield == source.nhfield and np.array_equal(model.hfield_nrow, source.hfield_nrow)
            and np.array_equal(model.hfield_ncol, source.hfield_ncol) and model.nbvh == source.nbvh
            and model.body_bvhadr[0] == source.body_bvhadr[0] and model.body_bvhnum[0] == source.body_bvhnum[0])
    if not same:
        raise RuntimeError("terrain generator: a drawn terrain changed the MuJoCo scene's parts or grid shape")
    for name in GEOM_FIELDS:
        getattr(model, name)[g] = getattr(source, name)[g]
    model.hfield_size[:] = source.hfield_size
    model.hfield_data[:] = source.hfield_data
    a, n = int(model.body_bvhadr[0]), int(model.body_bvhnum[0])
    if a >= 0:
        for name in BVH_FIELDS:
            getattr(model, name)[a:a + n] = getattr(source, name)[a:a + n]
