"""Terrain contact on tensors: the rod capsules against a sloped plane, boxes and a
heightfield, batched over copies (:func:`terrain_forces`), and steps with it
(:func:`terrain_step`). The same equations, slots and arithmetic as the numba kernel
:mod:`tensegrity_gym.backends.numba.terrain` (see there for the array layouts ``geom``
(G, F, 10), ``prm`` (P, F, 8), ``hf`` (H, ny, nx) and the slot order; the heightfield's
measure and search: :mod:`tensegrity_gym.backends.torch.heightfield`); the arrays come from
:class:`tensegrity_gym.physics.terrain.TerrainContact`
(``.geom``, ``.prm``, ``.hf``, ``.per_copy``). SI units.
"""
from __future__ import annotations

import math

import numpy as np

from ..numba.terrain import BOX, GOLDEN_ITERS, HFIELD, LEVEL_TOL, PLANE
from .driver import prepare_steps, step_once
from .heightfield import hf_lipschitz, hf_lowest, hf_patch
from .model import TorchModel, _torch, torch_model

__all__ = ["init_terrain_state", "terrain_forces", "terrain_step", "top_height"]

_GR = 0.6180339887498949


def init_terrain_state(tm_or_model, n_features: int, batch_size: int, device=None, dtype=None):
    """``(anchor (B, S, 3) m, eta0 (B, S) m, active (B, S) bool)``, S = 3 k F: no slot active."""
    torch = _torch()
    tm = tm_or_model if isinstance(tm_or_model, TorchModel) else torch_model(tm_or_model, device, dtype)
    S = 3 * tm.k * int(n_features)
    z = dict(dtype=tm.dtype, device=tm.device)
    return (torch.zeros((batch_size, S, 3), **z), torch.zeros((batch_size, S), **z),
            torch.zeros((batch_size, S), dtype=torch.bool, device=tm.device))


class _Part:
    """One terrain part: its geom rows ``g`` (G, 10) (every row of one feature column has the
    part's kind), the heightfield heights ``H``; the kind read once (one device read) and the
    columns shaped once per rank of the points they meet (the box search evaluates the distance
    ~140 times a step; the heightfield's functions in
    :mod:`tensegrity_gym.backends.torch.heightfield` take the part too)."""

    def __init__(self, g, H):
        self.g, self.H, self.kind = g, H, float(g[0, 0])
        self._cols: dict = {}

    def col(self, i: int, like):
        """Column i, shaped to broadcast against the points ``like`` (leading axis: the copies)."""
        key = (i, like.ndim)
        c = self._cols.get(key)
        if c is None:
            c = self._cols[key] = self.g[:, i].reshape(-1, *([1] * (like.ndim - 1)))
        return c


def _box(p0, p1, p2, part, normal: bool = True):
    """Signed distance and outward normal of points (p0, p1, p2) to the boxes of ``part``, rows
    broadcast against the points' leading axis (as the numba ``_box_closest``); the distance
    alone with ``normal=False`` (the same number)."""
    torch = _torch()
    cx, cy, cz, hx, hy, hz, c, s = (part.col(i, p0) for i in range(1, 9))
    dx, dy, dz = p0 - cx, p1 - cy, p2 - cz
    l0 = c * dx + s * dy
    l1 = (-s) * dx + c * dy
    l2 = dz
    q0, q1, q2 = l0.abs() - hx, l1.abs() - hy, l2.abs() - hz
    o0, o1, o2 = q0.clamp(min=0.0), q1.clamp(min=0.0), q2.clamp(min=0.0)
    dout = torch.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
    out = dout > 0.0
    # inside: the nearest face, the first of the largest q (numba's sequential comparisons)
    a1 = q1 > q0
    d = torch.where(a1, q1, q0)
    a2 = q2 > d
    d = torch.where(a2, q2, d)
    if not normal:
        return torch.where(out, dout, d)
    one = torch.ones_like(l0)
    s0, s1, s2 = (torch.where(x >= 0.0, one, -one) for x in (l0, l1, l2))
    safe = torch.where(out, dout, one)
    zero = torch.zeros_like(l0)
    n0 = torch.where(out, s0 * o0 / safe, torch.where(a1 | a2, zero, s0))
    n1 = torch.where(out, s1 * o1 / safe, torch.where(a1 & ~a2, s1, zero))
    n2 = torch.where(out, s2 * o2 / safe, torch.where(a2, s2, zero))
    d = torch.where(out, dout, d)
    return d, c * n0 - s * n1, s * n0 + c * n1, n2


def _closest(p0, p1, p2, part, normal: bool = True):
    """Contact measure of points against the terrain part ``part`` (:class:`_Part`): (signed
    distance or a heightfield's vertical gap, outward unit normal, w), the measure's gradient
    ``w n`` (the numba ``_closest``); the measure alone with ``normal=False`` (the same number)."""
    torch = _torch()
    kind = part.kind
    if kind == PLANE:
        nx, ny, nz, off = (part.col(i, p0) for i in range(1, 5))
        d = nx * p0 + ny * p1 + nz * p2 - off
        return (d, nx.expand_as(p0), ny.expand_as(p0), nz.expand_as(p0), torch.ones_like(p0)) if normal else d
    if kind == HFIELD:
        h, gx, gy = hf_patch(p0, p1, part)
        if not normal:
            return p2 - h
        w = torch.sqrt(1.0 + gx * gx + gy * gy)
        return p2 - h, -gx / w, -gy / w, 1.0 / w, w
    if not normal:
        return _box(p0, p1, p2, part, False)
    return _box(p0, p1, p2, part) + (torch.ones_like(p0),)


def _interior(ea, ec, r, b, part):
    """The interior contact point of every rod against the box ``part``, (eta, deeper) (B, k):
    the numba ``_interior`` on tensors (golden section, then the middle of the level set)."""
    torch = _torch()

    r0, r1, r2 = (r[..., i, None] for i in range(3))      # (views taken once, not per evaluation)
    b0, b1, b2 = (b[..., i, None] for i in range(3))

    def sd(e):
        e3 = e if e.ndim == r.ndim else e[..., None]
        return _box(r0 + e3 * b0, r1 + e3 * b1, r2 + e3 * b2, part, normal=False).reshape(e.shape)
    ea, ec = ea.expand_as(r[..., 0]), ec.expand_as(r[..., 0])
    fa, fc = sd(ea), sd(ec)
    lo, hi = ea, ec
    x1 = hi - _GR * (hi - lo)
    x2 = lo + _GR * (hi - lo)
    f1, f2 = sd(x1), sd(x2)
    for _ in range(GOLDEN_ITERS):
        c = f1 <= f2
        hi_n = torch.where(c, x2, hi)
        lo_n = torch.where(c, lo, x1)
        x1_n = torch.where(c, hi_n - _GR * (hi_n - lo_n), x2)
        x2_n = torch.where(c, x1, lo_n + _GR * (hi_n - lo_n))
        fe = sd(torch.where(c, x1_n, x2_n))
        f1, f2 = torch.where(c, fe, f2), torch.where(c, f1, fe)
        lo, hi, x1, x2 = lo_n, hi_n, x1_n, x2_n
    em = 0.5 * (lo + hi)
    fm = sd(em)
    deeper = fm < torch.minimum(fa, fc) - LEVEL_TOL
    level = fm + LEVEL_TOL
    a, bb = ea, em
    for _ in range(GOLDEN_ITERS):
        mid = 0.5 * (a + bb)
        up = sd(mid) > level
        a, bb = torch.where(up, mid, a), torch.where(up, bb, mid)
    left = bb
    a, bb = em, ec
    for _ in range(GOLDEN_ITERS):
        mid = 0.5 * (a + bb)
        up = sd(mid) > level
        a, bb = torch.where(up, a, mid), torch.where(up, mid, bb)
    return torch.where(deeper, 0.5 * (left + a), em), deeper


def _as(x, q, name, width):
    torch = _torch()
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.array(x, dtype=float))
    t = t.to(device=q.device, dtype=q.dtype)
    if t.ndim != 3 or t.shape[2] != width or t.shape[0] not in (1, q.shape[0]):
        raise ValueError(f"{name}: expected shape (1, F, {width}) or ({q.shape[0]}, F, {width}), got {tuple(t.shape)}")
    return t


def _as_hf(hf, geom, q):
    """The heights ``hf`` (1 or B, ny, nx) m as a tensor like ``q``; required (and shaped as the
    geom rows' ny, nx) when ``geom`` has a heightfield, a (1, 1, 1) zero tensor otherwise."""
    torch = _torch()
    rows = [f for f in range(geom.shape[1]) if float(geom[0, f, 0]) == HFIELD]
    if hf is None:
        if rows:
            raise ValueError("hf: geom has a heightfield feature; pass its heights hf (1 or B, ny, nx) m "
                             "(TerrainContact.hf)")
        return torch.zeros((1, 1, 1), dtype=q.dtype, device=q.device)
    t = hf if isinstance(hf, torch.Tensor) else torch.as_tensor(np.array(hf, dtype=float))
    t = t.to(device=q.device, dtype=q.dtype)
    shape = (int(geom[0, rows[0], 4]), int(geom[0, rows[0], 5])) if rows else (1, 1)
    if t.ndim != 3 or t.shape[0] not in (1, q.shape[0]) or tuple(t.shape[1:]) != shape:
        raise ValueError(f"hf: expected shape (1, {shape[0]}, {shape[1]}) or ({q.shape[0]}, {shape[0]}, {shape[1]}), "
                         f"got {tuple(t.shape)}")
    return t


def terrain_forces(model, q, qd, geom, prm, anchor, eta0, active, hf=None):
    """Terrain contact forces as the numba kernel's: returns ``(W (B, n, 3) N, anchor, eta0,
    active, slip)``, the state as new tensors. ``geom`` (1 or B, F, 10), ``prm`` (1 or B, F, 8),
    ``hf`` (1 or B, ny, nx) heightfield heights m (needed only with a heightfield): arrays or
    tensors (:class:`tensegrity_gym.physics.terrain.TerrainContact`'s ``geom`` / ``per_copy``
    / ``hf``)."""
    tm = model if isinstance(model, TorchModel) else torch_model(model, q.device, q.dtype)
    geom, prm, H, lips = _prepare(geom, prm, hf, q)
    return _forces(tm, q, qd, geom, prm, H, lips, anchor, eta0, active)


def _prepare(geom, prm, hf, q):
    """``geom``, ``prm``, the heights as tensors like ``q`` (checked) and the heightfield parts'
    slope bounds (:func:`~tensegrity_gym.backends.torch.heightfield.hf_lipschitz`, feature ->
    (G or B, 1)), computed once for the steps that share them."""
    geom, prm = _as(geom, q, "geom", 10), _as(prm, q, "prm", 8)
    H = _as_hf(hf, geom, q)
    F = geom.shape[1]
    if prm.shape[1] != F:
        raise ValueError(f"prm: expected {F} features as geom, got {prm.shape[1]}")
    lips = {f: hf_lipschitz(geom[:, f], H) for f in range(F) if float(geom[0, f, 0]) == HFIELD}
    return geom, prm, H, lips


def _slot_law(P, V, M, sd, n, w, level, was, an, pr):
    """The contact law of slots (..., s) at points P (..., s, 3) m moving at V m/s, the anchored
    material points M, contact measure ``sd`` m, outward unit normal n, gradient length w, the
    level the penetration is measured from, ``was`` active at the last step, anchors ``an``
    (..., s, 3) m, ``pr`` the part's 8 parameter columns (P, 1) (the numba ``_slot_force``):
    returns the anchors, touching and slip flags, the force (..., s, 3) N and the normal force
    magnitude ``fn`` N."""
    torch = _torch()
    radius, kn, dn, ex, mu, kt, ct, cmax = pr
    kn_, dn_, mu_, kt_, ct_, cmax_ = (x[..., None] for x in (kn, dn, mu, kt, ct, cmax))
    delta = level - sd
    touch = delta > 0.0
    dpos = torch.where(touch, delta, torch.zeros_like(delta))
    ex0 = float(ex.reshape(-1)[0])
    de = dpos if ex0 == 1.0 else dpos ** ex[..., None]
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


def _plane_slots(r, b, rd, bd, ea, ec, em, part, pr, an, e0s, acs):
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
    A, touch, slip, Fc, _ = _slot_law(P, V, P, sd, n, w, pr[0][..., None], was, an[:, :, :2], pr)
    no = torch.zeros_like(touch[..., :1])
    e0_2 = torch.where(acs[..., 2], e0s[..., 2], em.expand(B, k))
    return (torch.cat([A, an[:, :, 2:]], dim=2), torch.cat([E, e0_2[..., None]], dim=-1),
            torch.cat([touch, no], dim=-1), torch.cat([slip, no], dim=-1), Fc)


def _forces(tm, q, qd, geom, prm, H, lips, anchor, eta0, active):
    """:func:`terrain_forces` on prepared inputs (:func:`_prepare`)."""
    torch = _torch()
    B, k, F = q.shape[0], tm.k, geom.shape[1]
    r, b, rd, bd = q[..., :3], q[..., 3:], qd[..., :3], qd[..., 3:]
    ea, ec = tm.eta_a[..., 0], tm.eta_c[..., 0]                          # (1, k)
    span = ec - ea
    an = anchor.reshape(B, k, F, 3, 3)
    e0s = eta0.reshape(B, k, F, 3)
    acs = active.reshape(B, k, F, 3)
    Wa = torch.zeros_like(r)
    Wc = torch.zeros_like(r)
    outs = []
    for f in range(F):
        part = _Part(geom[:, f], H)
        pr = [prm[:, f, i].reshape(-1, 1) for i in range(8)]             # (P, 1)
        radius = pr[0]
        em = 0.5 * (ea + ec)
        if part.kind == PLANE:
            outs.append(_plane_slots(r, b, rd, bd, ea, ec, em, part, pr, an[:, :, f], e0s[:, :, f], acs[:, :, f]))
            Wa = Wa + outs[-1][4][:, :, 0]
            Wc = Wc + outs[-1][4][:, :, 1]
            continue
        mid = [r[..., i] + em * b[..., i] for i in range(3)]
        hfield = part.kind == HFIELD
        if hfield:
            # the vertical gap's Lipschitz bound (the numba kernel's far early-out)
            far = mid[2] - hf_patch(mid[0], mid[1], part)[0] - lips[f] * (0.5 * span.abs()) >= radius
        else:
            far = _closest(mid[0], mid[1], mid[2], part, normal=False) - 0.5 * span.abs() >= radius
        kink = False
        if part.kind == PLANE or bool(far.all()):
            # a plane has no interior slot; a part every rod is far from leaves it unused
            ei, deeper = em.expand(B, k), torch.zeros((B, k), dtype=torch.bool, device=q.device)
        elif hfield:
            ei, deeper, kgx, kgy = hf_lowest(ea.expand(B, k), ec.expand(B, k), r, b, part)
            ei, kink = torch.where(far, em.expand(B, k), ei), True
        else:
            ei, deeper = _interior(ea, ec, r, b, part)
            ei = torch.where(far, em.expand(B, k), ei)
        E = torch.stack([ea.expand(B, k), ec.expand(B, k), ei], dim=-1)  # (B, k, 3)
        use = torch.stack([~far, ~far, ~far & deeper], dim=-1)
        P = r[:, :, None, :] + E[..., None] * b[:, :, None, :]          # (B, k, 3, 3)
        V = rd[:, :, None, :] + E[..., None] * bd[:, :, None, :]
        sd, nx, ny, nz, w = _closest(P[..., 0], P[..., 1], P[..., 2], part)
        sd = torch.where(use, sd, torch.full_like(sd, math.inf))
        n = torch.stack([nx, ny, nz], dim=-1)
        if kink:
            # the interior slot's normal from the gradient of the lowest point (a kink's combination;
            # a heightfield every rod is far from has no search, and its unused slot 2 keeps _closest's)
            wk = torch.sqrt(1.0 + kgx * kgx + kgy * kgy)
            nk = torch.stack([-kgx / wk, -kgy / wk, 1.0 / wk], dim=-1)
            n = torch.cat([n[..., :2, :], nk[..., None, :]], dim=-2)
            w = torch.cat([w[..., :2], wk[..., None]], dim=-1)
        # the interior slot's level: min(radius, sd_a, sd_c), the deeper touching node (the numba
        # kernel's first-of-equals order), and the normal velocity relative to that node's
        vn_all = (V * n).sum(-1)
        rad_b = radius.expand(B, k)
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
        was = acs[:, :, f]
        slot2 = torch.tensor([False, False, True], device=q.device)
        e0 = torch.where(slot2 & was, e0s[:, :, f], E)
        M = r[:, :, None, :] + e0[..., None] * b[:, :, None, :]
        A, touch, slip, Fc, fn = _slot_law(P, V, M, sd, n, w, level, was, an[:, :, f], pr)
        e0n = torch.where(slip | ~was, E, e0)
        # a slot that neither touches nor touched holds its own eta, the rod's middle for the interior slot
        e0n = torch.where(slot2 & ~touch & ~was, em[..., None], e0n)
        wc = (E - ea[..., None]) / span[..., None]
        wa = (ec[..., None] - E) / span[..., None]
        # the interior slot's reaction: -fn w n of the deeper node at that node
        R = torch.where((touch[..., 2] & has_end)[..., None], -(fn[..., 2] * w_end)[..., None] * n_end,
                        torch.zeros_like(n_end))
        Wa = Wa + (wa[..., None] * Fc).sum(2) + torch.where(end_a[..., None], R, torch.zeros_like(R))
        Wc = Wc + (wc[..., None] * Fc).sum(2) + torch.where(end_c[..., None], R, torch.zeros_like(R))
        outs.append((A, e0n, touch, slip, Fc))
    anchor = torch.stack([o[0] for o in outs], dim=2).reshape(B, -1, 3)
    eta0 = torch.stack([o[1] for o in outs], dim=2).reshape(B, -1)
    active = torch.stack([o[2] for o in outs], dim=2).reshape(B, -1)
    slip = torch.stack([o[3] for o in outs], dim=2).reshape(B, -1)
    return tm.gather_nodes(Wa, Wc), anchor, eta0, active, slip


def terrain_step(model, geom, prm, q, qd, anchor, eta0, active, dt: float, integrator: str = "semi_implicit_euler",
                 n_steps: int = 1, rest_length=None, force_density=None, params=None, project: bool = True,
                 external=None, hf=None):
    """``n_steps`` physics steps with terrain contact: per step the forces from the state at its
    start (plus ``external``), held over one integrator step; ``hf`` the heightfield's heights
    as :func:`terrain_forces` takes them. Returns ``(q, qd, anchor, eta0, active)``."""
    name, dt, tm, p, rl, fd, ext = prepare_steps(model, q, integrator, dt, params, rest_length, force_density,
                                                 external)
    geom, prm, H, lips = _prepare(geom, prm, hf, q)
    for _ in range(int(n_steps)):
        W, anchor, eta0, active, _ = _forces(tm, q, qd, geom, prm, H, lips, anchor, eta0, active)
        if ext is not None:
            W = W + ext
        q, qd = step_once(tm, q, qd, dt, name, p, rl, fd, W, project)
    return q, qd, anchor, eta0, active


def top_height(geom, H, x, y):
    """Height (m) of the terrain's top surface at (x, y) m (tensors (r, ...), leading axis the
    copies): the highest of the plane, the tops of the boxes over (x, y) and the heightfield's
    bilinear height; -inf where none is (:meth:`tensegrity_gym.core.terrain.Terrain.height_at` on
    the kernels' rows). ``geom`` (1 or r, F, 10), ``H`` (1 or r, ny, nx) m or None."""
    torch = _torch()
    h = torch.full_like(x, -math.inf)
    for f in range(geom.shape[1]):
        part = _Part(geom[:, f], H)
        if part.kind == PLANE:          # the solid n.p <= offset
            n0, n1, n2, off = (part.col(i, x) for i in range(1, 5))
            h = torch.maximum(h, (off - (n0 * x + n1 * y)) / n2)
        elif part.kind == BOX:
            cx, cy, cz, hx, hy, hz, c, s = (part.col(i, x) for i in range(1, 9))
            dx, dy = x - cx, y - cy
            inside = ((c * dx + s * dy).abs() <= hx) & (((-s) * dx + c * dy).abs() <= hy)
            h = torch.where(inside, torch.maximum(h, cz + hz), h)
        else:
            h = torch.maximum(h, hf_patch(x, y, part)[0])
    return h
