"""Terrain contact on tensors: the rod capsules against a sloped plane, boxes and a
heightfield, batched over copies (:func:`terrain_forces`), and steps with it
(:func:`terrain_step`). The same equations, slots and arithmetic as the numba kernel
:mod:`tensegrity_gym.backends.numba.terrain` (the array layouts ``geom`` (G, F, 10), ``prm``
(P, F, 8), ``hf`` (H, ny, nx): :mod:`tensegrity_gym.backends.numba.terrain_kinds`; the slot order:
:mod:`tensegrity_gym.backends.numba.terrain_law`; each kind's measure and top:
:mod:`tensegrity_gym.backends.torch.terrain_kinds`, the heightfield's search:
:mod:`tensegrity_gym.backends.torch.heightfield`); the arrays come from
:class:`tensegrity_gym.physics.terrain.TerrainContact`
(``.geom``, ``.prm``, ``.hf``, ``.per_copy``). SI units.

What the steps branch on (each feature's kind, the contact exponent, the most grid lines a rod
crosses) is read from the host once, as a :class:`TerrainLayout`. Under ``torch.compile``
(``terrain_step(..., layout=layout, substep=torch.compile(terrain_substep,
options=compile_options(layout)))``) the steps read nothing back from the device: a part every rod is far from is searched all the same
(its unused slots are released as a skipped search releases them), and the heightfield search
lists the layout's bound of grid crossings per rod (the extra entries are the rod's far end, as
for a rod with fewer crossings than another); eager steps skip the far parts and list the
crossings the rods have. Both give the same forces and contact state.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..numba.terrain_kinds import BOX, HFIELD, PLANE
from .driver import prepare_steps, step_once
from .heightfield import hf_lipschitz, hf_lowest, hf_patch
from .model import TorchModel, _torch, torch_model
from .terrain_kinds import _Part, _closest, _hf_normal, _host, _interior, _passed_over, check_kinds, top_height

__all__ = ["TerrainLayout", "terrain_layout", "init_terrain_state", "terrain_forces", "terrain_step", "terrain_substep",
           "compile_options", "top_height"]

class TerrainLayout(NamedTuple):
    """What a terrain's contact steps branch on, read from the host once (:func:`terrain_layout`)."""

    #: each feature column's kind (``PLANE``, ``BOX``, ``HFIELD`` of :mod:`tensegrity_gym.backends.numba.terrain_kinds`)
    kinds: tuple
    #: every part's contact exponent is 1 (the penetration taken as it is, not raised to a power)
    unit_exponent: bool
    #: (ny, nx) of the heightfield's grid, (1, 1) without one
    hf_shape: tuple
    #: per feature, the most grid lines a rod crosses along x and along y ((0, 0) off a heightfield)
    crossings: tuple


def terrain_layout(geom, prm, model) -> TerrainLayout:
    """The :class:`TerrainLayout` of ``geom`` (1 or B, F, 10) and ``prm`` (1 or B, F, 8) (arrays
    or tensors; one read from the device) for the rods of ``model`` (a
    :class:`~tensegrity_gym.core.model.Model` or :class:`TorchModel`). Every row of a feature
    column must have that column's kind (as :class:`~tensegrity_gym.physics.terrain.TerrainContact`
    and the terrain generators make them). A rod of length L (m) crosses at most
    ``ceil(L / cell)`` grid lines of a cell-wide grid along an axis; the bound is that plus one
    (an axis up to ``cell / L`` longer than unit, as an unprojected step may drift) and never
    more than the grid has."""
    g, p = _host(geom), _host(prm)
    rows, cols = np.nonzero(g[:, :, 0] != g[:1, :, 0])
    if rows.size:
        raise ValueError(f"geom[{rows[0]}, {cols[0]}, 0]: every row of a feature column must have the column's "
                         f"kind (row 0: {g[0, cols[0], 0]:g}), got {g[rows[0], cols[0], 0]:g}")
    m = model.model if isinstance(model, TorchModel) else model
    length = float(np.abs(m.eta[:, 1] - m.eta[:, 0]).max())
    kinds = tuple(float(v) for v in g[0, :, 0])
    check_kinds(kinds)
    hf_shape, crossings = (1, 1), []
    for f, kind in enumerate(kinds):
        if kind != HFIELD:
            crossings.append((0, 0))
            continue
        hf_shape = (int(g[0, f, 4]), int(g[0, f, 5]))
        lines = math.ceil(length / float(g[:, f, 3].min())) + 1
        crossings.append((min(hf_shape[1], lines), min(hf_shape[0], lines)))
    return TerrainLayout(kinds, bool((p[..., 3] == 1.0).all()), hf_shape, tuple(crossings))


def compile_options(layout: TerrainLayout):
    """Inductor options for ``torch.compile(terrain_substep, options=...)`` on a terrain of this
    layout, or None (the defaults). With boxes: inductor inlines an expression into its users
    until it passes 30 operations, and the box search's ~90 chained distance evaluations then
    compile for minutes and run several times slower than with a buffer kept past 16
    operations (docs/terrain.md)."""
    return {"realize_opcount_threshold": 16} if BOX in layout.kinds else None


def init_terrain_state(tm_or_model, n_features: int, batch_size: int, device=None, dtype=None):
    """``(anchor (B, S, 3) m, eta0 (B, S) m, active (B, S) bool)``, S = 3 k F: no slot active."""
    torch = _torch()
    tm = tm_or_model if isinstance(tm_or_model, TorchModel) else torch_model(tm_or_model, device, dtype)
    S = 3 * tm.k * int(n_features)
    z = dict(dtype=tm.dtype, device=tm.device)
    return (torch.zeros((batch_size, S, 3), **z), torch.zeros((batch_size, S), **z),
            torch.zeros((batch_size, S), dtype=torch.bool, device=tm.device))


def _as(x, q, name, width):
    torch = _torch()
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.array(x, dtype=float))
    t = t.to(device=q.device, dtype=q.dtype)
    if t.ndim != 3 or t.shape[2] != width or t.shape[0] not in (1, q.shape[0]):
        raise ValueError(f"{name}: expected shape (1, F, {width}) or ({q.shape[0]}, F, {width}), got {tuple(t.shape)}")
    return t


def _as_hf(hf, layout, q):
    """The heights ``hf`` (1 or B, ny, nx) m as a tensor like ``q``; required (and shaped as the
    layout's grid) when the terrain has a heightfield, a (1, 1, 1) zero tensor otherwise."""
    torch = _torch()
    has = HFIELD in layout.kinds
    if hf is None:
        if has:
            raise ValueError("hf: geom has a heightfield feature; pass its heights hf (1 or B, ny, nx) m "
                             "(TerrainContact.hf)")
        return torch.zeros((1, 1, 1), dtype=q.dtype, device=q.device)
    t = hf if isinstance(hf, torch.Tensor) else torch.as_tensor(np.array(hf, dtype=float))
    t = t.to(device=q.device, dtype=q.dtype)
    shape = layout.hf_shape
    if t.ndim != 3 or t.shape[0] not in (1, q.shape[0]) or tuple(t.shape[1:]) != shape:
        raise ValueError(f"hf: expected shape (1, {shape[0]}, {shape[1]}) or ({q.shape[0]}, {shape[0]}, {shape[1]}), "
                         f"got {tuple(t.shape)}")
    return t


def terrain_forces(model, q, qd, geom, prm, anchor, eta0, active, hf=None, layout=None):
    """Terrain contact forces as the numba kernel's: returns ``(W (B, n, 3) N, anchor, eta0,
    active, slip)``, the state as new tensors. ``geom`` (1 or B, F, 10), ``prm`` (1 or B, F, 8),
    ``hf`` (1 or B, ny, nx) heightfield heights m (needed only with a heightfield): arrays or
    tensors (:class:`tensegrity_gym.physics.terrain.TerrainContact`'s ``geom`` / ``per_copy``
    / ``hf``); ``layout`` their :func:`terrain_layout` (None: read from them here)."""
    tm = model if isinstance(model, TorchModel) else torch_model(model, q.device, q.dtype)
    geom, prm, H, lips, layout = _prepare(geom, prm, hf, q, tm, layout)
    return _forces(tm, layout, geom, prm, H, lips, q, qd, anchor, eta0, active)


def _prepare(geom, prm, hf, q, tm, layout=None):
    """``geom``, ``prm``, the heights as tensors like ``q`` (checked), the heightfield parts'
    slope bounds (:func:`~tensegrity_gym.backends.torch.heightfield.hf_lipschitz` per feature,
    (G or B, 1), None off a heightfield), computed once for the steps that share them, and the
    :class:`TerrainLayout` (read from ``geom`` and ``prm`` when None)."""
    geom_in, prm_in = geom, prm
    geom, prm = _as(geom, q, "geom", 10), _as(prm, q, "prm", 8)
    if layout is None:      # from the inputs: arrays read where they are, not copied back from the device
        layout = terrain_layout(geom_in, prm_in, tm)
    F = geom.shape[1]
    if prm.shape[1] != F:
        raise ValueError(f"prm: expected {F} features as geom, got {prm.shape[1]}")
    if len(layout.kinds) != F:
        raise ValueError(f"layout: expected {F} features as geom, got {len(layout.kinds)}")
    H = _as_hf(hf, layout, q)
    lips = tuple(hf_lipschitz(geom[:, f], H) if kind == HFIELD else None for f, kind in enumerate(layout.kinds))
    return geom, prm, H, lips, layout


def _slot_law(P, V, M, sd, n, w, level, was, an, pr, unit_exponent: bool):
    """The contact law of slots (..., s) at points P (..., s, 3) m moving at V m/s, the anchored
    material points M, contact measure ``sd`` m, outward unit normal n, gradient length w, the
    level the penetration is measured from, ``was`` active at the last step, anchors ``an``
    (..., s, 3) m, ``pr`` the part's 8 parameter columns (P, 1), ``unit_exponent`` the
    layout's (the numba ``_slot_force``):
    returns the anchors, touching and slip flags, the force (..., s, 3) N and the normal force
    magnitude ``fn`` N."""
    torch = _torch()
    radius, kn, dn, ex, mu, kt, ct, cmax = pr
    kn_, dn_, mu_, kt_, ct_, cmax_ = (x[..., None] for x in (kn, dn, mu, kt, ct, cmax))
    delta = level - sd
    touch = delta > 0.0
    dpos = torch.where(touch, delta, torch.zeros_like(delta))
    de = dpos if unit_exponent else dpos ** ex[..., None]
    fs = kn_ * de
    cn = torch.minimum(fs * dn_, cmax_.expand_as(fs))
    vn = (V * n).sum(-1)
    fn = (fs - cn * w * vn).clamp(min=0.0)
    fw = fn * w
    S = P - (sd / w)[..., None] * n
    new = (~was)[..., None]
    A = torch.where(new, S, an)
    M = torch.where(new, P, M)
    xi = M - A
    xn = (xi * n).sum(-1, keepdim=True)
    xi = xi - xn * n
    Ft = -kt_[..., None] * xi - ct_[..., None] * (V - vn[..., None] * n)
    nrm = torch.sqrt((Ft * Ft).sum(-1))
    lim = mu_ * fw
    slip = touch & (nrm > lim)
    scale = torch.where(slip, lim / torch.where(slip, nrm, torch.ones_like(nrm)), torch.ones_like(nrm))
    Ft = Ft * scale[..., None]
    A = torch.where(slip[..., None], S + Ft / kt_[..., None], A)
    A = torch.where(touch[..., None], A, an)
    Fc = torch.where(touch[..., None], Ft + fw[..., None] * n, torch.zeros_like(Ft))
    return A, touch, slip, Fc, fn


def _plane_slots(r, b, rd, bd, ea, ec, em, part, pr, an, e0s, acs, unit_exponent: bool):
    """The slots of every rod against the plane ``part`` (:func:`_forces` on a plane, with fewer
    operations: a plane's nearest point of a rod is an end, so its interior slot never touches and
    is released as the general path releases it, the anchored point kept if it was active).
    Returns the rods' (anchors (B, k, 3, 3), eta0 (B, k, 3), active, slip (B, k, 3), forces at
    the node slots (B, k, 2, 3) N)."""
    torch = _torch()
    B, k = r.shape[0], r.shape[1]
    E = torch.stack([ea, ec], dim=-1).expand(B, k, 2)
    P = r[:, :, None, :] + E[..., None] * b[:, :, None, :]                # (B, k, 2, 3)
    V = rd[:, :, None, :] + E[..., None] * bd[:, :, None, :]
    sd, nx, ny, nz, w = _closest(P[..., 0], P[..., 1], P[..., 2], part)
    n = torch.stack([nx, ny, nz], dim=-1)
    was = acs[..., :2]
    A, touch, slip, Fc, _ = _slot_law(P, V, P, sd, n, w, pr[0][..., None], was, an[:, :, :2], pr, unit_exponent)
    no = torch.zeros_like(touch[..., :1])
    e0_2 = torch.where(acs[..., 2], e0s[..., 2], em.expand(B, k))
    return (torch.cat([A, an[:, :, 2:]], dim=2), torch.cat([E, e0_2[..., None]], dim=-1),
            torch.cat([touch, no], dim=-1), torch.cat([slip, no], dim=-1), Fc)


def _groups(kinds):
    """``(kind, f0, f1)``: the features f0..f1-1 handled together, consecutive boxes in one group
    (searched at once), every plane and heightfield alone."""
    out = []
    for f, kind in enumerate(kinds):
        if out and kind == BOX and out[-1][0] == BOX:
            out[-1] = (BOX, out[-1][1], f + 1)
        else:
            out.append((kind, f, f + 1))
    return out


def _forces(tm, layout, geom, prm, H, lips, q, qd, anchor, eta0, active):
    """:func:`terrain_forces` on prepared inputs (:func:`_prepare`)."""
    torch = _torch()
    compiling = torch.compiler.is_compiling()
    B, k, F = q.shape[0], tm.k, geom.shape[1]
    r, b, rd, bd = q[..., :3], q[..., 3:], qd[..., :3], qd[..., 3:]
    ea, ec = tm.eta_a[..., 0], tm.eta_c[..., 0]                          # (1, k)
    em = 0.5 * (ea + ec)
    an = anchor.reshape(B, k, F, 3, 3)
    e0s = eta0.reshape(B, k, F, 3)
    acs = active.reshape(B, k, F, 3)
    Wa = torch.zeros_like(r)
    Wc = torch.zeros_like(r)
    outs = []
    # the rods with a features axis: (B, k, 1, 3), their ends and middles (1, k, 1) m
    R, Bv, Rd, Bd = (x[:, :, None, :] for x in (r, b, rd, bd))
    ea3, ec3, em3 = ea[..., None], ec[..., None], em[..., None]
    span3 = ec3 - ea3
    slot2 = torch.tensor([False, False, True], device=q.device)
    for kind, f0, f1 in _groups(layout.kinds):
        nf = f1 - f0
        part = _Part(geom[:, f0:f1], H, kind, layout.crossings[f0])
        if kind == PLANE:
            pr = [prm[:, f0, i].reshape(-1, 1) for i in range(8)]            # (P, 1)
            out = _plane_slots(r, b, rd, bd, ea, ec, em, part, pr, an[:, :, f0], e0s[:, :, f0], acs[:, :, f0],
                               layout.unit_exponent)
            outs.append(tuple(x[:, :, None] for x in out[:4]))
            Wa = Wa + out[4][:, :, 0]
            Wc = Wc + out[4][:, :, 1]
            continue
        pr = [prm[:, f0:f1, i].reshape(-1, 1, nf) for i in range(8)]         # (P, 1, f)
        radius = pr[0]
        mid = [R[..., i] + em3 * Bv[..., i] for i in range(3)]                 # (B, k, 1)
        hfield = kind == HFIELD
        if hfield:
            # the vertical gap's Lipschitz bound (the numba kernel's far early-out)
            far = (mid[2] - hf_patch(mid[0], mid[1], part)[0] - lips[f0].reshape(-1, 1, 1) * (0.5 * span3.abs())
                   >= radius)
        else:
            far = _closest(mid[0], mid[1], mid[2], part, normal=False) - 0.5 * span3.abs() >= radius
        shape = far.shape                                                      # (B, k, f)
        eas, ecs, ems = ea3.expand(shape), ec3.expand(shape), em3.expand(shape)
        kink = False
        if not compiling and bool(far.all()):
            # parts every rod is far from leave the interior slot unused (eager: one device read)
            ei, deeper = ems, torch.zeros(shape, dtype=torch.bool, device=q.device)
        elif not compiling and not hfield and bool((far | _passed_over(eas, ecs, R, Bv, part, radius)).all()):
            # boxes no rod's interior point can touch: the search would leave the slot released
            # (its point, not used, is the rod's middle here; eager: one more device read)
            ei, deeper = ems, torch.zeros(shape, dtype=torch.bool, device=q.device)
        elif hfield:
            ei, deeper, kgx, kgy = hf_lowest(eas, ecs, R, Bv, part)
            ei, kink = torch.where(far, ems, ei), True
        else:
            ei, deeper = _interior(eas, ecs, R, Bv, part)
            ei = torch.where(far, ems, ei)
        E = torch.stack([eas, ecs, ei], dim=-1)                                # (B, k, f, 3)
        use = torch.stack([~far, ~far, ~far & deeper], dim=-1)
        P = R[..., None, :] + E[..., None] * Bv[..., None, :]                  # (B, k, f, 3, 3)
        V = Rd[..., None, :] + E[..., None] * Bd[..., None, :]
        sd, nx, ny, nz, w = _closest(P[..., 0], P[..., 1], P[..., 2], part)
        sd = torch.where(use, sd, torch.full_like(sd, math.inf))
        n = torch.stack([nx, ny, nz], dim=-1)
        if kink:
            # the interior slot's normal from the gradient of the lowest point (a kink's combination;
            # a heightfield every rod is far from has no search, and its unused slot 2 keeps _closest's)
            kx, ky, kz, wk = _hf_normal(kgx, kgy)
            nk = torch.stack([kx, ky, kz], dim=-1)
            n = torch.cat([n[..., :2, :], nk[..., None, :]], dim=-2)
            w = torch.cat([w[..., :2], wk[..., None]], dim=-1)
        # the interior slot's level: min(radius, sd_a, sd_c), the deeper touching node (the numba
        # kernel's first-of-equals order), and the normal velocity relative to that node's
        vn_all = (V * n).sum(-1)
        rad_b = radius.expand(shape)
        end_a = sd[..., 0] < rad_b
        lvl = torch.where(end_a, sd[..., 0], rad_b)
        end_c = sd[..., 1] < lvl
        lvl = torch.where(end_c, sd[..., 1], lvl)
        end_a = end_a & ~end_c
        has_end = end_a | end_c
        vr = torch.where(end_c, vn_all[..., 1] * (w[..., 1] / w[..., 2]),
                         torch.where(end_a, vn_all[..., 0] * (w[..., 0] / w[..., 2]), torch.zeros_like(lvl)))
        n_end = torch.where(end_c[..., None], n[..., 1, :], n[..., 0, :])
        w_end = torch.where(end_c, w[..., 1], w[..., 0])
        V2 = torch.where(has_end[..., None], V[..., 2, :] - vr[..., None] * n[..., 2, :], V[..., 2, :])
        V = torch.stack([V[..., 0, :], V[..., 1, :], V2], dim=-2)
        level = torch.stack([rad_b, rad_b, lvl], dim=-1)
        was = acs[:, :, f0:f1]
        e0 = torch.where(slot2 & was, e0s[:, :, f0:f1], E)
        M = R[..., None, :] + e0[..., None] * Bv[..., None, :]
        A, touch, slip, Fc, fn = _slot_law(P, V, M, sd, n, w, level, was, an[:, :, f0:f1], pr, layout.unit_exponent)
        e0n = torch.where(slip | ~was, E, e0)
        # a slot that neither touches nor touched holds its own eta, the rod's middle for the interior slot
        e0n = torch.where(slot2 & ~touch & ~was, em3[..., None], e0n)
        wc = (E - ea3[..., None]) / span3[..., None]
        wa = (ec3[..., None] - E) / span3[..., None]
        # the interior slot's reaction: -fn w n of the deeper node at that node
        Rn = torch.where((touch[..., 2] & has_end)[..., None], -(fn[..., 2] * w_end)[..., None] * n_end,
                         torch.zeros_like(n_end))
        Sa, Sc = (wa[..., None] * Fc).sum(3), (wc[..., None] * Fc).sum(3)     # (B, k, f, 3)
        Ra = torch.where(end_a[..., None], Rn, torch.zeros_like(Rn))
        Rc = torch.where(end_c[..., None], Rn, torch.zeros_like(Rn))
        for j in range(nf):                     # the features' loads in order (the numba kernel's sums)
            Wa = Wa + Sa[:, :, j] + Ra[:, :, j]
            Wc = Wc + Sc[:, :, j] + Rc[:, :, j]
        outs.append((A, e0n, touch, slip))
    anchor = torch.cat([o[0] for o in outs], dim=2).reshape(B, -1, 3)
    eta0 = torch.cat([o[1] for o in outs], dim=2).reshape(B, -1)
    active = torch.cat([o[2] for o in outs], dim=2).reshape(B, -1)
    slip = torch.cat([o[3] for o in outs], dim=2).reshape(B, -1)
    return tm.gather_nodes(Wa, Wc), anchor, eta0, active, slip


def terrain_step(model, geom, prm, q, qd, anchor, eta0, active, dt: float, integrator: str = "semi_implicit_euler",
                 n_steps: int = 1, rest_length=None, force_density=None, params=None, project: bool = True,
                 external=None, hf=None, layout=None, substep=None):
    """``n_steps`` physics steps with terrain contact: per step the forces from the state at its
    start (plus ``external``), held over one integrator step (:func:`terrain_substep`); ``hf``
    the heightfield's heights and ``layout`` as :func:`terrain_forces` takes them; ``substep``
    a replacement for :func:`terrain_substep` with its signature (e.g.
    ``torch.compile(terrain_substep)``). Returns ``(q, qd, anchor, eta0, active)``."""
    name, dt, tm, p, rl, fd, ext = prepare_steps(model, q, integrator, dt, params, rest_length, force_density,
                                                 external)
    geom, prm, H, lips, layout = _prepare(geom, prm, hf, q, tm, layout)
    one = terrain_substep if substep is None else substep
    for _ in range(int(n_steps)):
        q, qd, anchor, eta0, active = one(tm, layout, geom, prm, H, lips, q, qd, anchor, eta0, active, dt, name, p,
                                          rl, fd, ext, project)
    return q, qd, anchor, eta0, active


def terrain_substep(tm, layout, geom, prm, H, lips, q, qd, anchor, eta0, active, dt, name, p, rl, fd, ext, project_):
    """One physics step with terrain contact on prepared inputs (:func:`_prepare`'s terrain,
    :func:`~tensegrity_gym.backends.torch.driver.prepare_steps`' model, parameters and controls):
    the forces from the state at the step's start (plus ``ext``), then one integrator step.
    Returns ``(q, qd, anchor, eta0, active)``."""
    W, anchor, eta0, active, _ = _forces(tm, layout, geom, prm, H, lips, q, qd, anchor, eta0, active)
    if ext is not None:
        W = W + ext
    q, qd = step_once(tm, q, qd, dt, name, p, rl, fd, W, project_)
    return q, qd, anchor, eta0, active
