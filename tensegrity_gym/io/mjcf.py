"""Export a :class:`~tensegrity_gym.core.structure.Structure` to a MuJoCo model (MJCF XML).

The reverse, :func:`from_mjcf` (a structure and an :class:`ImportReport` from an MJCF file), is
:mod:`tensegrity_gym.core.mjcf_import`, re-exported here.

SI units throughout (m, kg, s, N). The model is built from the structure alone; MuJoCo is
needed only to *load* the result (``mujoco.MjModel.from_xml_string(to_mjcf(s))``), not to write it.

Mapping
-------
* **Rods** are rigid bodies named ``rod<j>``. The body frame has its z axis along the rod's unit
  vector ``b`` (node a -> node c) and its origin at the rod's reference point: the centre of
  mass of a free rod (``<freejoint/>``), the constrained node of a constrained rod. Mass and
  centre of mass are the structure's (``bar_mass``, ``mass_points``); the inertia about the
  centre of mass is ``diag(J, J, I_axial)`` with ``J`` the rod's second mass moment about its
  centre of mass (``m l^2 / 12`` for a uniform rod, ``sum m_k (mu_k - sigma)^2 l^2`` for lumped
  masses).
* **Axial inertia.** Our rods are 1-D bodies with no spin about their own axis (5 DOF). MuJoCo
  bodies have 6 DOF and need a positive inertia, so ``I_axial = m r^2 / 2`` (a solid cylinder
  of radius ``rod_radius``; default 1 % of the longest rod). This changes nothing in the motion:
  every force on a rod (string forces and contact at its nodes, gravity at its centre of mass)
  acts at a point of its axis, so the torque about the axis is zero; and the inertia is
  axisymmetric (``I_1 = I_2 = J``), so Euler's equation for the axial spin is
  ``I_axial w_3' = (I_1 - I_2) w_1 w_2 + tau_3 = 0``. A rod that starts without axial spin
  (the initial velocities built from node velocities have none) never gets any, and the
  transverse equations ``J w_1' = tau_1 + (J - I_axial) w_2 w_3`` reduce to ours exactly, for any
  ``I_axial > 0``. ``tests/test_mjcf.py`` checks this numerically (two very different
  ``rod_radius`` give the same trajectory to ~1e-12 m).
* **Node constraints** ``D n = D n0`` (``node_constraints``): the rod's body gets one slide
  joint per column of an orthonormal basis ``E`` of the null space of ``D`` (plane: 2, line: 1,
  pinned: 0), then a ball joint at the node.
* **Nodes** are sites named ``node<i>``: on their rod's body, or, for anchors (nodes on no rod),
  fixed sites in the world body.
* **Strings** are spatial tendons ``string<i>`` between the two node sites with
  ``stiffness`` = k, ``damping`` = c and the two-value ``springlength="0 l0"``: MuJoCo's dead
  band, no spring force for lengths in [0, l0], ``-k (L - l0)`` above, so a string never pushes.
* **Damping difference.** MuJoCo's tendon damping ``-c L'`` acts at every length, slack or
  taut, and can make the total tendon force push; ours acts only while the string is taut and
  the total force density is clipped at 0 (a string never pushes). With ``damping > 0`` the two
  models therefore agree only while every damped string stays taut and pulling; undamped
  strings agree exactly. MuJoCo has no per-tendon switch for this, so it is documented, not
  reproduced.
* **Gravity** is ``<option gravity>`` (zero if the structure has none).
* **Ground** (``ground=True``): a plane at ``ground_height``; rods are capsules of radius
  ``rod_radius`` that collide with the ground only (``rod_contact=True``: with each other too, as
  this package's optional rod-rod contact, :mod:`tensegrity_gym.physics.rod_contact`). MuJoCo's
  soft-constraint contact is not our Hunt-Crossley + stick/slip model: trajectories with
  contact agree qualitatively, not to round-off. Without ground, contact is disabled.
* **Terrain** (``terrain=``, a :class:`~tensegrity_gym.core.terrain.Terrain`; instead of
  ``ground``): the plane is a MuJoCo ``plane`` geom through the origin whose z axis is the
  plane's outward normal (tilted by the slope about the horizontal axis perpendicular to the
  uphill direction); each box a ``box`` geom (half sizes, yaw as a quaternion about z); the
  heightfield an ``<hfield>`` asset (``nrow`` = ny, ``ncol`` = nx, elevations normalised to
  [0, 1] with ``size[2]`` = the height range and ``size[3]`` a base below the lowest point, the
  rows written from the highest y down as MuJoCo reads them) with an ``hfield`` geom at the
  grid's centre and lowest height. Each part's ``friction`` is the geom's sliding friction; the
  stiffness and damping are not mapped (MuJoCo's soft contact is its own). MuJoCo triangulates
  a heightfield cell where ours is bilinear (equal at the grid points and along cell edges) and
  ends at the grid where ours holds the edge values beyond it. Rods collide with the terrain
  only, as with ``ground``.
* **Initial state**: a keyframe ``initial`` holds the structure's node positions and velocities
  (``mujoco.mj_resetDataKeyframe(model, data, 0)``); ``qpos0`` is the same pose.

Agreement (``tests/test_mjcf.py``): MuJoCo's RK4 at ``timestep=1e-4`` against our RK4 at the
same step, over 0.5 s, node positions agree to about 2e-14 m (round-off) for a free prism released off
equilibrium, the icosahedron and the constrained prism (pinned, line and plane nodes).
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from .atomic import write_atomic
from ..core.checks import check_flag, xml_text
from ..core.rod_mass import mass_moments
from ..core.terrain import Terrain
from ..core.structure import Structure
from ..core.terrain_kinds import require
from ..core.mjcf_import import ImportReport, from_mjcf

__all__ = ["to_mjcf", "export", "rod_frame", "initial_qpos_qvel", "default_rod_radius", "terrain_xml",
           "terrain_xml_bytes", "from_mjcf", "ImportReport"]

#: thickness (m) of the solid under a heightfield's lowest point (MuJoCo's ``size[3]``), as a
#: fraction of the grid's larger side and at least 1 cm
_HFIELD_BASE = 0.1


def _fmt(x) -> str:
    return " ".join(repr(float(v)) for v in np.atleast_1d(np.asarray(x, float)).ravel())


def _quat_z_to(b: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) rotating the z axis onto the unit vector ``b``."""
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ b)
    if c < -1.0 + 1e-12:                     # b = -z: half turn about x
        return np.array([0.0, 1.0, 0.0, 0.0])
    axis = np.cross(z, b)
    q = np.array([1.0 + c, axis[0], axis[1], axis[2]])
    return q / np.linalg.norm(q)


def _rotation(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _null_basis(D: np.ndarray) -> np.ndarray:
    """(3, 3-p) orthonormal basis of the null space of D (p, 3)."""
    _, sv, vt = np.linalg.svd(D)
    p = int(np.sum(sv > 1e-9 * sv.max()))
    return vt[p:].T


def rod_frame(structure: Structure, j: int) -> dict:
    """Body frame of rod ``j`` as exported: ``pos`` (3,) m (reference point), ``quat`` (4,),
    ``sigma`` (fraction of the reference point from node a), ``com`` (fraction of the centre of
    mass), ``length`` m, ``mass`` kg, ``J`` kg m^2 (about the centre of mass), ``node``
    (constrained node or None), ``E`` (3, d) allowed directions of the reference point."""
    s = structure
    a, c = (int(v) for v in s.bars[j])
    na, nc = s.nodes[a], s.nodes[c]
    L = float(np.linalg.norm(nc - na))
    b = (nc - na) / L
    pts = None if s.mass_points is None else s.mass_points[j]
    com = float(s.com_fraction[j])
    _, J = mass_moments(L, float(s.bar_mass[j]), com, pts)
    node, sigma, E = None, com, np.eye(3)
    for end, nd in ((0.0, a), (1.0, c)):
        if nd in s.node_constraints:
            node, sigma, E = nd, end, _null_basis(s.node_constraints[nd])
    return {"pos": na + sigma * L * b, "quat": _quat_z_to(b), "sigma": sigma, "com": com, "length": L,
            "mass": float(s.bar_mass[j]), "J": J, "node": node, "E": E, "a": a, "c": c, "b": b}


def initial_qpos_qvel(structure: Structure) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo ``qpos``, ``qvel`` of the exported model at the structure's initial nodes and
    velocities (free joint: position, quaternion, linear velocity (world), angular velocity
    (body frame); slides: 0 and the node's velocity along the slide; ball: identity and the
    angular velocity in the body frame)."""
    s = structure
    qpos, qvel = [], []
    for j in range(s.n_bars):
        f = rod_frame(s, j)
        va, vc = s.velocities[f["a"]], s.velocities[f["c"]]
        bdot = (vc - va) / f["length"]
        w_world = np.cross(f["b"], bdot)
        R = _rotation(f["quat"])
        w_body = R.T @ w_world
        v_ref = va + f["sigma"] * f["length"] * bdot
        if f["node"] is None:
            qpos += list(f["pos"]) + list(f["quat"])
            qvel += list(v_ref) + list(w_body)
        else:
            for e in f["E"].T:
                qpos.append(0.0)
                qvel.append(float(e @ v_ref))
            qpos += [1.0, 0.0, 0.0, 0.0]
            qvel += list(w_body)
    return np.array(qpos), np.array(qvel)


def default_rod_radius(structure: Structure) -> float:
    """The rods' capsule radius (m) of the export when ``rod_radius`` is not given: 1 % of the longest rod."""
    return 0.01 * float(structure.bar_lengths.max())


def _plane_xml(part, i, attrs):
    return [], [f'    <geom name="terrain_plane" type="plane" size="0 0 1" pos="0 0 0" '
                f'quat="{_fmt(_quat_z_to(part.normal))}" material="grid" {attrs}/>']


def _box_xml(b, i, attrs):
    yaw = math.radians(b.yaw_deg)
    return [], [f'    <geom name="terrain_box{i}" type="box" size="{_fmt(b.size / 2)}" pos="{_fmt(b.center)}" '
                f'quat="{_fmt([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])}" rgba=".62 .56 .48 1" {attrs}/>']


def _hfield_xml(hf, i, attrs):
    H = hf.heights
    ny, nx = H.shape
    lo, hi = float(H.min()), float(H.max())
    rng = hi - lo
    # MuJoCo keeps elevations in [0, 1] scaled by size[2] (> 0): a flat grid is zeros under any scale
    elev = (H - lo) / rng if rng > 0 else np.zeros_like(H)
    rx, ry = 0.5 * (nx - 1) * hf.cell, 0.5 * (ny - 1) * hf.cell
    base = max(_HFIELD_BASE * 2 * max(rx, ry), 0.01)
    # the attribute's first row is MuJoCo's highest y: our rows reversed
    return ([f'    <hfield name="terrain_hfield" nrow="{ny}" ncol="{nx}" '
             f'size="{_fmt([rx, ry, rng if rng > 0 else 1e-6, base])}" elevation="{_fmt(elev[::-1])}"/>'],
            [f'    <geom name="terrain_hfield" type="hfield" hfield="terrain_hfield" '
             f'pos="{_fmt([hf.origin[0] + rx, hf.origin[1] + ry, lo])}" rgba=".55 .62 .5 1" {attrs}/>'])


#: terrain kind name (:mod:`tensegrity_gym.core.terrain_kinds`) -> ``xml(part, i, attrs)``: the
#: ``(assets, geoms)`` MJCF lines of the kind's i-th part, ``attrs`` its contact and friction attributes
TERRAIN_GEOMS = {"plane": _plane_xml, "box": _box_xml, "heightfield": _hfield_xml}


#: memory (bytes) :func:`to_mjcf` holds per terrain part (its geom line and the strings it is
#: built from; about 660 measured for a box) and per heightfield cell (each elevation's text, the
#: list of them and the document's copies; about 140 measured), with a margin
MJCF_BYTES_PER_PART = 1024
MJCF_BYTES_PER_CELL = 192


def terrain_xml_bytes(terrain) -> float:
    """Estimated peak memory (bytes) of writing ``terrain`` as MJCF (:func:`to_mjcf`): linear in
    its parts and its heightfield cells; what a caller compares with a memory limit before the work."""
    parts = terrain.parts()
    cells = sum(int(np.size(p.heights)) for p in parts if hasattr(p, "heights"))
    return float(MJCF_BYTES_PER_PART * len(parts) + MJCF_BYTES_PER_CELL * cells)


def terrain_xml(terrain, floor_height: float | None = None) -> tuple[list, list]:
    """``(assets, geoms)``: the MJCF lines of ``terrain``'s heightfield asset and of its geoms
    (world body; they collide with the rods only), each part by its kind's row of
    :data:`TERRAIN_GEOMS` (ValueError naming a kind without one). See the module docstring for
    the mapping. ``floor_height``: also a level floor plane ``terrain_floor`` at this height (m),
    with the heightfield's friction (else the terrain's), after the terrain's geoms."""
    if not isinstance(terrain, Terrain):
        raise ValueError(f"terrain: expected a Terrain, got {type(terrain).__name__}")
    if floor_height is not None and not math.isfinite(float(floor_height)):
        raise ValueError(f"floor_height: must be finite (m), got {floor_height!r}")
    contact = 'contype="0" conaffinity="1"'
    fr = lambda part: f'friction="{float(terrain.surface(part)[0])!r} 0.005 0.0001"'
    assets, geoms, count = [], [], {}
    for part in terrain.parts():
        xml = require(TERRAIN_GEOMS, part, "the MJCF writer (tensegrity_gym.io.mjcf.TERRAIN_GEOMS)")
        i = count[xml] = count.get(xml, -1) + 1
        a, g = xml(part, i, f"{contact} {fr(part)}")
        assets += a
        geoms += g
    if floor_height is not None:
        hf = terrain.heightfield
        geoms.append(f'    <geom name="terrain_floor" type="plane" size="0 0 1" pos="0 0 {float(floor_height)!r}" '
                     f'material="grid" {contact} {fr(hf if hf is not None else terrain)}/>')
    return assets, geoms


#: MuJoCo's integrators (``<option integrator=...>``)
MJ_INTEGRATORS = ("RK4", "Euler", "implicit", "implicitfast")


def check_mj_integrator(name, field: str = "integrator") -> str:
    """``name`` if it is one of :data:`MJ_INTEGRATORS`; ValueError naming ``field`` otherwise."""
    if not (isinstance(name, str) and name in MJ_INTEGRATORS):
        raise ValueError(f"{field}: one of {', '.join(MJ_INTEGRATORS)}, got {name!r}")
    return name


def to_mjcf(structure: Structure, ground: bool = False, *, timestep: float = 1e-3, integrator: str = "RK4",
            rod_radius: float | None = None, string_width: float | None = None, ground_height: float = 0.0,
            friction: float = 1.0, model_name: str | None = None, terrain=None,
            floor_height: float | None = None, rod_contact: bool = False) -> str:
    """The MJCF XML text of ``structure`` (see the module docstring for the mapping).

    Parameters
    ----------
    ground : add a ground plane at ``ground_height`` (m) with Coulomb ``friction``.
    terrain : a :class:`~tensegrity_gym.core.terrain.Terrain` (plane, boxes, heightfield) instead
        of ``ground``; its parts' own friction. The structure is written where it is
        (:func:`tensegrity_gym.core.placement.place_on_terrain` lifts it onto the terrain).
    floor_height : with ``terrain``, also a level floor plane at this height, m (a floor beyond
        a heightfield's grid, where MuJoCo's heightfield ends; :func:`terrain_xml`).
    timestep : MuJoCo step, s. integrator : MuJoCo integrator ("RK4", "Euler", "implicit", "implicitfast").
    rod_radius : rod capsule radius, m (drawing, contact and the axial inertia ``m r^2 / 2``);
        default 1 % of the longest rod.
    string_width : tendon drawing radius, m; default ``rod_radius / 3``.
    rod_contact : the rods' capsules also collide with each other (``conaffinity="1"``; MuJoCo's
        own soft contact, as with the ground, not this package's rod-rod law), with or without
        ground; default False: the rods collide with the ground only.
    """
    s = structure
    if not isinstance(s, Structure):
        raise TypeError(f"structure: expected a Structure, got {type(s).__name__}")
    if not (isinstance(timestep, (int, float)) and math.isfinite(timestep) and timestep > 0):
        raise ValueError(f"timestep: must be a positive finite number of seconds, got {timestep!r}")
    check_mj_integrator(integrator)
    if terrain is not None and ground:
        raise ValueError("ground, terrain: give one of them (a level terrain plane is the ground)")
    if floor_height is not None and terrain is None:
        raise ValueError("floor_height: needs terrain (the floor lies under a terrain)")
    t_assets, t_geoms = ([], []) if terrain is None else terrain_xml(terrain, floor_height)
    rod_contact = check_flag(rod_contact, "rod_contact")
    contact = ground or terrain is not None or rod_contact
    r = default_rod_radius(s) if rod_radius is None else float(rod_radius)
    if not (math.isfinite(r) and r > 0):
        raise ValueError(f"rod_radius: must be positive and finite (m), got {rod_radius!r}")
    w = r / 3 if string_width is None else float(string_width)
    if not (math.isfinite(w) and w > 0):
        raise ValueError(f"string_width: must be positive and finite (m), got {string_width!r}")
    for nm, v in (("ground_height", ground_height), ("friction", friction)):
        if not math.isfinite(float(v)) or (nm == "friction" and v < 0):
            raise ValueError(f"{nm}: must be finite{' and >= 0' if nm == 'friction' else ''}, got {v!r}")
    g = np.zeros(3) if s.gravity is None else np.asarray(s.gravity, float)
    name = xml_text(model_name or s.name)   # XML 1.0 holds no control characters
    out = [f"<mujoco model={quoteattr(name)}>",
           '  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>',
           f'  <option timestep="{timestep!r}" integrator="{integrator}" gravity="{_fmt(g)}">',
           "" if contact else '    <flag contact="disable"/>',
           "  </option>",
           "  <visual>",
           '    <global offwidth="1920" offheight="1080"/>',
           "  </visual>",
           "  <asset>",
           '    <texture name="grid" type="2d" builtin="checker" rgb1=".82 .84 .86" rgb2=".74 .76 .78" '
           'width="512" height="512"/>',
           '    <material name="grid" texture="grid" texrepeat="4 4" texuniform="true" reflectance="0"/>',
           *t_assets,
           "  </asset>",
           "  <worldbody>",
           '    <light name="sun" directional="true" pos="0 0 10" dir="-0.3 -0.3 -1" diffuse=".8 .8 .8"/>']
    out = [line for line in out if line]
    if ground:
        out.append(f'    <geom name="ground" type="plane" size="0 0 1" pos="0 0 {ground_height!r}" '
                   f'material="grid" contype="0" conaffinity="1" friction="{float(friction)!r} 0.005 0.0001"/>')
    out += t_geoms
    for i in s.anchors:
        out.append(f'    <site name="node{i}" pos="{_fmt(s.nodes[i])}" size="{2 * r!r}" rgba=".2 .6 .2 1"/>')
    for j in range(s.n_bars):
        f = rod_frame(s, j)
        L, sig = f["length"], f["sigma"]
        R = _rotation(f["quat"])
        out.append(f'    <body name="rod{j}" pos="{_fmt(f["pos"])}" quat="{_fmt(f["quat"])}">')
        if f["node"] is None:
            out.append(f'      <freejoint name="rod{j}"/>')
        else:
            for d, e in enumerate(f["E"].T):
                out.append(f'      <joint name="rod{j}_slide{d}" type="slide" axis="{_fmt(R.T @ e)}"/>')
            out.append(f'      <joint name="rod{j}_ball" type="ball" pos="0 0 0"/>')
        Ia = 0.5 * f["mass"] * r * r
        out.append(f'      <inertial pos="0 0 {(f["com"] - sig) * L!r}" mass="{f["mass"]!r}" '
                   f'diaginertia="{f["J"]!r} {f["J"]!r} {Ia!r}"/>')
        za, zc = -sig * L, (1.0 - sig) * L
        out.append(f'      <geom name="rod{j}" type="capsule" fromto="0 0 {za!r} 0 0 {zc!r}" size="{r!r}" '
                   f'contype="1" conaffinity="{1 if rod_contact else 0}" rgba=".25 .27 .3 1"/>')
        out.append(f'      <site name="node{f["a"]}" pos="0 0 {za!r}" size="{1.2 * r!r}"/>')
        out.append(f'      <site name="node{f["c"]}" pos="0 0 {zc!r}" size="{1.2 * r!r}"/>')
        out.append("    </body>")
    out.append("  </worldbody>")
    if s.n_strings:
        out.append("  <tendon>")
        for i, (a, c) in enumerate(s.strings):
            out.append(f'    <spatial name="string{i}" stiffness="{float(s.stiffness[i])!r}" '
                       f'damping="{float(s.damping[i])!r}" springlength="0 {float(s.rest_length[i])!r}" '
                       f'width="{w!r}" rgba=".85 .3 .2 1">')
            out.append(f'      <site site="node{a}"/>')
            out.append(f'      <site site="node{c}"/>')
            out.append("    </spatial>")
        out.append("  </tendon>")
    qpos, qvel = initial_qpos_qvel(s)
    out.append("  <keyframe>")
    out.append(f'    <key name="initial" qpos="{_fmt(qpos)}" qvel="{_fmt(qvel)}"/>')
    out.append("  </keyframe>")
    out.append("</mujoco>")
    return "\n".join(out) + "\n"


def export(structure: Structure, path: str | os.PathLike, **kwargs) -> Path:
    """Write :func:`to_mjcf` to ``path`` atomically (:func:`tensegrity_gym.io.atomic.write_atomic`:
    an interrupted export never leaves a half-written model). Returns the path."""
    text = to_mjcf(structure, **kwargs)
    return write_atomic(path, lambda f: f.write(text.encode("utf-8")))
