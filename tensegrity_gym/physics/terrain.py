"""Contact of the rod capsules with a terrain (sloped plane, boxes, heightfield): the backend-neutral API.

The terrain itself is data (:class:`tensegrity_gym.core.terrain.Terrain`); this module turns it
into the arrays of the compiled kernel (:mod:`tensegrity_gym.backends.numba.terrain`, torch twin
:mod:`tensegrity_gym.backends.torch.terrain`) and steps a batch with it. SI units: m, kg, s, N.
Scenes without a terrain never reach this module: the flat-ground fast path
(:mod:`tensegrity_gym.physics.contact`) is unchanged.

Geometry: a rod is a capsule, the segment between its two nodes swept by a sphere of radius
``radius`` (the cap radius, m). Against each feature (the plane, each box, the heightfield) it
has three contact slots: its two nodes, where a capsule first touches a plane, and the interior
point of the segment nearest a box or lowest over the heightfield, used when it is deeper than
both ends: a rod lying across a box edge, a ridge or a bump is held where it touches. For a box
it is a golden-section search of the signed distance (convex along the segment, as a box is
convex); for the heightfield the exact lowest point of the rod axis, found by walking the cells
it crosses (:mod:`tensegrity_gym.backends.numba.heightfield`). The heightfield's contact measure
is the vertical gap ``z - h`` above the bilinear surface (:meth:`Heightfield.gap`), in place of
a signed distance: its gradient is the unnormalised normal ``(-h_x, -h_y, 1)``, so the normal
force derives from a potential. Slot ``(j F + f) 3 + s`` for rod j, feature f, s = 0 node a,
1 node c, 2 interior; F features in :meth:`Terrain.parts` order.

Contact law (as :mod:`tensegrity_gym.physics.contact`, with the feature's normal n in place of
+z): penetration ``delta = radius - d`` (d the contact measure of the contact point: signed
distance, or the heightfield's gap), potential ``U = k delta^(e+1) / (e+1)``, Hunt-Crossley
normal force ``w max(0, k delta^e - min(k delta^e d_n, c_max) w v.n) n`` (w the length of the
measure's gradient: 1, or ``|(-h_x, -h_y, 1)|``), and stick-slip Coulomb friction: a
tangential spring ``k_t`` with damper ``c_t`` from the contact's surface point to its anchor (a
3-D point on the surface, set at touch-down), projected on the tangent plane and capped at
``mu`` times the normal force (the anchor then follows: slip). The interior slot's penetration
is measured from the deeper touching node, ``min(radius, d_a, d_c) - d``, with the reaction
along that node's measure gradient at the node (a continuous contact energy; details in
:mod:`tensegrity_gym.backends.numba.terrain_law`).

Generalized force: a force F at the rod point ``v(eta) = r + eta b`` enters the equations as
``[F, eta F]`` (the seed's (5.9), (5.21)); the kernels pass it as the nodal forces
``(eta_c - eta)/(eta_c - eta_a) F`` at node a and ``(eta - eta_a)/(eta_c - eta_a) F`` at node c,
whose generalized force ``W Psi`` is exactly ``[F, eta F]`` (``tests/test_terrain.py``).

Stepping: per step, the forces of the whole batch from the state at the step's start, held over
one integrator step as ``external`` nodal forces, as the ground contact's. With the numba
kernels all sub-steps run in one compiled call (:mod:`tensegrity_gym.backends.numba.terrain_steps`);
a terrain that is one plane (``TerrainContact.plane_only``) runs the loop driver's plane instance,
the same numbers at about the ground contact's cost.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..backends.numba.api import _frozen as read_only, rods_tuple   # the kernels take read-only arrays
from ..backends.numba.terrain import terrain_forces_kernel
from ..backends.numba.terrain_kinds import HFIELD, PLANE, check_codes, geom_row
from ..backends.numba.terrain_steps import terrain_steps
from ..core.checks import check_positive
from ..core.integrators import resolve
from ..core.model import Model, State
from ..core.param_table import part_columns
from ..core.terrain import Terrain
from .contact import GroundContact, stable_step as ground_stable_step
from .pipeline import compiled_physics, run_steps as _run_steps
from .rod_contact import add_rod_forces
from .stability import check_stability

__all__ = ["TerrainContact", "TerrainState", "init_terrain_state", "contact_forces", "forces_inplace",
           "contact_energy", "stable_step", "step", "advance", "PRM_FIELDS", "SLOTS"]

#: columns of the (P, F, 8) per-feature contact parameters ``prm`` (SI units): the ground contact's
#: columns without the ground height (a view of tensegrity_gym.core.param_table)
PRM_FIELDS = part_columns()
#: contact slots per rod per feature: node a, node c, the interior point nearest a box or the heightfield
SLOTS = 3


@dataclass(frozen=True, eq=False)
class TerrainContact:
    """Contact of the rods with a :class:`Terrain` (SI units).

    ``terrain`` gives per feature the friction, the normal stiffness k (N/m^exponent) and the
    Hunt-Crossley damping (s/m); the rest is the rods' and the contact model's, as in
    :class:`~tensegrity_gym.physics.contact.GroundContact`: ``radius`` (cap radius, m),
    ``exponent`` (>= 1), ``tangential_stiffness`` (N/m; None: each feature's normal stiffness),
    ``tangential_damping`` (N s/m), ``max_damping`` (cap on the normal damping coefficient,
    N s/m).

    Arrays of the kernels (read-only): ``geom`` (1, F, 10) and ``prm`` (1, F, 8) per feature in
    :meth:`Terrain.parts` order, ``hf`` (1, ny, nx) the heightfield's heights m (a (1, 1, 1)
    zero array without one); layouts in :mod:`tensegrity_gym.backends.numba.terrain_kinds`.
    ``plane_only``: True when the terrain is one plane and nothing else."""

    terrain: Terrain
    radius: float = 0.02
    exponent: float = 1.0
    tangential_stiffness: float | None = None
    tangential_damping: float = 10.0
    max_damping: float = math.inf

    def __post_init__(self):
        s = object.__setattr__
        if not isinstance(self.terrain, Terrain):
            raise ValueError(f"terrain: expected a Terrain, got {self.terrain!r}")
        s(self, "radius", check_positive(self.radius, "radius", "m", allow_zero=True))
        e = check_positive(self.exponent, "exponent", "1")
        if e < 1:
            raise ValueError(f"exponent: must be >= 1 (1 linear, 1.5 Hertz), got {self.exponent!r}")
        s(self, "exponent", e)
        if self.tangential_stiffness is not None:
            s(self, "tangential_stiffness", check_positive(self.tangential_stiffness, "tangential_stiffness", "N/m"))
        s(self, "tangential_damping", check_positive(self.tangential_damping, "tangential_damping", "N s/m",
                                                     allow_zero=True))
        try:
            cmax = math.nan if isinstance(self.max_damping, (str, bool)) else float(self.max_damping)
        except (TypeError, ValueError):
            cmax = math.nan
        if not cmax > 0:
            raise ValueError(f"max_damping: must be positive (N s/m; inf = no cap), got {self.max_damping!r}")
        s(self, "max_damping", cmax)
        if not self.terrain.parts():
            raise ValueError("terrain: no plane, no box and no heightfield, nothing to touch "
                             "(a Terrain() is a level plane)")
        geom, prm = [], []
        hf = np.zeros((1, 1, 1))
        for part in self.terrain.parts():
            row, heights = geom_row(part)       # the numba backend's table of kinds
            if heights is not None:
                hf = heights
            geom.append(row)
            friction, k, d = self.terrain.surface(part)
            kt = k if self.tangential_stiffness is None else self.tangential_stiffness
            cols = dict(radius=self.radius, stiffness=k, damping=d, exponent=e, friction=friction,
                        tangential_stiffness=kt, tangential_damping=self.tangential_damping, max_damping=cmax)
            prm.append([cols[f] for f in PRM_FIELDS])
        geom = np.array(geom, float).reshape(1, -1, 10)
        prm = np.array(prm, float).reshape(1, -1, 8)
        geom.setflags(write=False)
        prm.setflags(write=False)
        hf.setflags(write=False)
        s(self, "geom", geom)
        s(self, "prm", prm)
        s(self, "hf", hf)
        # one plane and nothing else: the compiled loop's plane instance
        s(self, "plane_only", geom.shape[1] == 1 and geom[0, 0, 0] == PLANE)

    @property
    def n_features(self) -> int:
        return self.geom.shape[1]

    def per_copy(self, batch_size: int) -> np.ndarray:
        """(B, F, 8) per-copy parameters (columns :data:`PRM_FIELDS`), every row this contact's:
        change rows and pass them as ``prm`` (each copy its own friction, stiffness, ...)."""
        return np.repeat(self.prm, int(batch_size), axis=0)


@dataclass(frozen=True, eq=False)
class TerrainState:
    """Stick/slip state of B x S contact slots (S = 3 k F): ``anchor`` (B, S, 3) m (a point on the
    feature's surface), ``eta0`` (B, S) m (the rod coordinate of the material point the anchor
    holds: the node's for the node slots, where it touched or last slipped for the interior slot),
    ``active`` (B, S) bool (the slot touched at the last force evaluation)."""

    anchor: np.ndarray
    eta0: np.ndarray
    active: np.ndarray

    def copy(self) -> "TerrainState":
        return TerrainState(self.anchor.copy(), self.eta0.copy(), self.active.copy())


def n_slots(tc: TerrainContact, model: Model) -> int:
    return SLOTS * model.n_bars * tc.n_features


def init_terrain_state(tc: TerrainContact, model: Model, batch_size: int = 1) -> TerrainState:
    """No slot active, anchors zero."""
    S = n_slots(tc, model)
    return TerrainState(np.zeros((batch_size, S, 3)), np.zeros((batch_size, S)), np.zeros((batch_size, S), bool))


def _rows(arr, default, B, width, name):
    """``arr`` (1 or B, F, width) as a C-contiguous float64 read-only view (one compiled kernel
    for the contact's own arrays and the caller's), or ``default``; ValueError otherwise."""
    if arr is None:
        return default
    if (type(arr) is np.ndarray and arr.dtype == np.float64 and arr.ndim == 3 and not arr.flags.writeable
            and arr.flags.c_contiguous and arr.shape[0] in (1, B) and arr.shape[1:] == default.shape[1:]):
        return arr      # already as the kernel takes it (an env's read-only view of its rows): no new view
    a = np.ascontiguousarray(arr, dtype=np.float64)
    if a.ndim != 3 or a.shape[0] not in (1, B) or a.shape[1:] != default.shape[1:]:
        raise ValueError(f"{name}: expected shape (1, {default.shape[1]}, {width}) or ({B}, {default.shape[1]}, "
                         f"{width}), got {a.shape}")
    a = a.view()
    a.setflags(write=False)
    return a


def _geom_rows(geom, hf, tc: TerrainContact, B: int):
    """:func:`_rows` of ``geom``; with the caller's heights ``hf`` and the contact's own geometry,
    the heightfield row's slope bound (column 6) is cleared: the kernel then bounds the slope of
    the heights it is given. A caller passing both gives each row the bound of its own heights
    (:func:`tensegrity_gym.backends.numba.terrain_kinds.hf_bound`)."""
    g = _rows(geom, tc.geom, B, 10, "geom")
    if geom is not None:
        check_codes(g)
    if hf is not None and geom is None and tc.terrain.heightfield is not None:
        g = g.copy()
        g[..., 6] = np.where(g[..., 0] == HFIELD, 0.0, g[..., 6])
        g.setflags(write=False)
    return g


def _hf_rows(hf, tc: TerrainContact, B: int):
    """Per-copy heightfield heights ``hf`` (1 or B, ny, nx) m as the kernel takes them (the
    contact's own ``tc.hf`` when None); ValueError naming ``hf``, the shape or the bad value."""
    if hf is None:
        return tc.hf
    ny, nx = tc.hf.shape[1:]
    try:
        a = np.ascontiguousarray(hf, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"hf: expected an array of heights (m), got {type(hf).__name__}") from None
    if a.ndim != 3 or a.shape[0] not in (1, B) or a.shape[1:] != (ny, nx):
        what = "heights (m) of the terrain's heightfield" if tc.terrain.heightfield is not None else \
            "placeholder (the terrain has no heightfield)"
        raise ValueError(f"hf: expected shape (1, {ny}, {nx}) or ({B}, {ny}, {nx}), the {what}, got {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        c, j, i = np.argwhere(bad)[0]
        raise ValueError(f"hf[{c}, {j}, {i}]: must be finite (m), got {float(a[c, j, i])!r}")
    a = a.view()
    a.setflags(write=False)
    return a


def _check_state(tstate: TerrainState, B: int, S: int) -> None:
    if tstate.anchor.shape != (B, S, 3) or tstate.active.shape != (B, S):
        raise ValueError(f"terrain state: expected anchor ({B}, {S}, 3) and active ({B}, {S}), got "
                         f"{tstate.anchor.shape} and {tstate.active.shape}")


def contact_forces(tc: TerrainContact, model: Model, q, qd, tstate: TerrainState, inplace: bool = False,
                   prm=None, geom=None, info: bool = False, hf=None):
    """Terrain contact forces at ``q``, ``qd`` (B, k, 6) and the updated stick/slip state.

    Returns ``(W, new_state, slip)`` (``W`` (B, n, 3) nodal forces N, ``slip`` (B, S) bool) and,
    with ``info=True``, a fourth array (B, S, 6): per slot eta (m), contact measure (m: signed
    distance, the heightfield's vertical gap), outward unit normal and spring energy (J). ``prm`` (1 or B, F, 8): per-copy parameters
    (:meth:`TerrainContact.per_copy`); ``geom`` (1 or B, F, 10): per-copy feature geometry in
    the kernel's layout; ``hf`` (1 or B, ny, nx): per-copy heightfield heights m (defaults: the
    contact's ``prm``, ``geom``, ``hf``). ``inplace=True`` updates ``tstate``'s arrays."""
    B = q.shape[0]
    S = n_slots(tc, model)
    _check_state(tstate, B, S)
    ts = tstate if inplace else tstate.copy()
    W = np.empty((B, model.n_nodes, 3))
    slip = np.empty((B, S), bool)
    inf = np.empty((B, S, 6) if info else (0, 0, 6))
    terrain_forces_kernel(np.ascontiguousarray(q, dtype=np.float64), np.ascontiguousarray(qd, dtype=np.float64),
                          model.eta, model.rod_a, model.rod_c, _geom_rows(geom, hf, tc, B),
                          _rows(prm, tc.prm, B, 8, "prm"), _hf_rows(hf, tc, B), ts.anchor, ts.eta0, ts.active,
                          slip, W, inf)
    return (W, ts, slip, inf) if info else (W, ts, slip)


def forces_inplace(tc: TerrainContact, model: Model, q, qd, tstate: TerrainState, W, slip, prm=None,
                   geom=None, hf=None) -> None:
    """Allocation-free :func:`contact_forces`: forces into ``W`` (B, n, 3), slip flags into
    ``slip`` (B, S) and ``tstate`` updated in place; C-contiguous float64 inputs, shapes and the
    kind codes of ``geom`` are the caller's duty (:func:`contact_forces`, :func:`step` and
    :func:`advance` check them)."""
    terrain_forces_kernel(q, qd, model.eta, model.rod_a, model.rod_c, tc.geom if geom is None else geom,
                          tc.prm if prm is None else prm, tc.hf if hf is None else hf, tstate.anchor,
                          tstate.eta0, tstate.active, slip, W, np.empty((0, 0, 6)))


def contact_energy(tc: TerrainContact, model: Model, q, tstate: TerrainState, prm=None, geom=None,
                   hf=None) -> np.ndarray:
    """(B,) energy stored in the contact springs, J: normal ``k delta^(e+1)/(e+1)`` plus tangential
    ``k_t |xi_t|^2 / 2`` of every touching slot (anchors from ``tstate``, not modified)."""
    q = np.asarray(q, dtype=np.float64)
    _, _, _, inf = contact_forces(tc, model, q, np.zeros_like(q), tstate, prm=prm, geom=geom, info=True, hf=hf)
    return inf[..., 5].sum(axis=1)


def stable_step(tc: TerrainContact, model: Model) -> dict:
    """Stability estimate (s) of semi-implicit Euler with terrain contact: the ground contact's
    estimate (:func:`tensegrity_gym.physics.contact.stable_step`: a contact at a rod end, the
    lightest effective mass m/4, strings and damping included) for each feature's parameters;
    the smallest limit wins. A heightfield's normal force is ``w k delta^e`` on its vertical gap
    ``delta``, ``w = sqrt(1 + |grad h|^2)``: along the normal its stiffness is ``k w^(1+e)`` and
    its damping ``d w``, taken at the field's steepest ``w`` (its slope bound, ``geom`` column
    6). Returns that feature's dict with ``"feature"`` (its index)."""
    best = None
    for f in range(tc.n_features):
        radius, k, d, e, friction, kt, ct, cmax = (tc.prm[0, f, PRM_FIELDS.index(c)] for c in (
            "radius", "stiffness", "damping", "exponent", "friction", "tangential_stiffness", "tangential_damping",
            "max_damping"))
        if tc.geom[0, f, 0] == HFIELD:
            w = max(float(tc.geom[0, f, 6]), 1.0)
            k, d = k * w ** (1.0 + e), d * w
        est = ground_stable_step(GroundContact(stiffness=k, damping=d, exponent=e, friction=friction,
                                               tangential_stiffness=kt, tangential_damping=ct, radius=radius,
                                               max_damping=cmax), model)
        if best is None or est["semi_implicit_euler"] < best["semi_implicit_euler"]:
            best = dict(est, feature=f)
    return best


def advance(tc: TerrainContact, model: Model, q, qd, dt: float, integrator: str, tstate: TerrainState, *,
            n_steps: int = 1, external=None, prm=None, geom=None, hf=None, forces=None, slip=None,
            backend: str = "auto",
            compiled: bool | None = None, rods=None, **inputs) -> None:
    """In place: ``n_steps`` steps of ``dt`` s of ``q``, ``qd`` (B, k, 6), writable C-contiguous
    float64, and of ``tstate``: per step the terrain forces of the batch from the state at its
    start (plus ``external`` (B, n, 3) N) held over ONE step of ``integrator`` (a resolved
    name). ``prm`` / ``geom`` / ``hf``: per-copy rows as :func:`contact_forces` takes them
    (checked by the caller); ``forces`` (B, n, 3) and ``slip`` (B, S) optional scratch; ``inputs``:
    ``rest_length``, ``force_density``, ``params``, ``project``. With the numba kernels every
    sub-step runs inside one compiled call (:mod:`tensegrity_gym.backends.numba.terrain_steps`),
    the same kernels in the same order as the Python loop here (bit-identical). ``rods``: a
    :class:`~tensegrity_gym.physics.rod_contact.RodContact` (its forces added after the terrain's
    and ``external`` at every step) or None (no rod-rod code runs)."""
    B = q.shape[0]
    prm = tc.prm if prm is None else read_only(prm)
    geom = _geom_rows(None, hf, tc, B) if geom is None else read_only(geom)
    hf = tc.hf if hf is None else read_only(hf)
    W = np.empty((B, model.n_nodes, 3)) if forces is None else forces
    sl = np.empty((B, n_slots(tc, model)), bool) if slip is None else slip
    if compiled is None:
        compiled = compiled_physics(integrator, backend)
    arrays = (geom, prm, hf, tstate.anchor, tstate.eta0, tstate.active, sl)
    if compiled and terrain_steps(model, q, qd, dt, integrator, n_steps, inputs.get("rest_length"),
                                  inputs.get("force_density"), external, inputs.get("params"),
                                  inputs.get("project", True), arrays, W, tc.plane_only,
                                  None if rods is None else rods_tuple(model, rods.prm)):
        return
    check_codes(geom)       # the compiled call refuses an unknown kind code itself
    for _ in range(int(n_steps)):
        forces_inplace(tc, model, q, qd, tstate, W, sl, prm, geom, hf)
        if external is not None:
            W += external
        if rods is not None:
            add_rod_forces(rods, model, q, qd, W)
        _run_steps(model, q, qd, dt, integrator, n_steps=1, external=W, backend=backend, compiled=compiled,
                   **inputs)


def step(model: Model, state: State, dt: float, tc: TerrainContact, tstate: TerrainState,
         integrator: str = "semi_implicit_euler", *, n_steps: int = 1, external=None, prm=None, geom=None,
         hf=None, backend: str = "auto", rods=None, **inputs):
    """``n_steps`` physics steps of ``dt`` s with terrain contact: per step, the contact forces of
    the batch from the state at its start (plus ``external`` (B, n, 3) N), held over ONE
    integrator step. ``prm``, ``geom``, ``hf``: per-copy arrays as :func:`contact_forces` takes
    them. ``inputs``: ``rest_length``, ``force_density``, ``params``, ``project`` as
    :func:`tensegrity_gym.physics.step` takes them; ``rods``: rod-rod contact
    (:class:`~tensegrity_gym.physics.rod_contact.RodContact`) or None. Returns ``(State,
    TerrainState)``, new objects (the inputs are not modified)."""
    info = resolve(integrator)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a positive finite time step in seconds, got {dt}")
    B = state.batch_size
    if inputs.get("params") is None:
        check_stability(model, info, dt)
    q = np.array(state.q, dtype=np.float64, order="C")
    qd = np.array(state.qd, dtype=np.float64, order="C")
    ts = tstate.copy()
    S = n_slots(tc, model)
    _check_state(ts, B, S)
    prm, geom, hf = _rows(prm, tc.prm, B, 8, "prm"), _geom_rows(geom, hf, tc, B), _hf_rows(hf, tc, B)
    ext = None if external is None else np.ascontiguousarray(external, dtype=np.float64)
    advance(tc, model, q, qd, dt, info.name, ts, n_steps=n_steps, external=ext, prm=prm, geom=geom, hf=hf,
            backend=backend, rods=rods, **inputs)
    t = state.t
    for _ in range(int(n_steps)):
        t = t + dt
    return State(q=q, qd=qd, t=t), ts
