"""Terrain contact on the numba backend: the rod capsules (segments between a rod's nodes,
swept by a sphere of the cap radius) against the terrain's parts, one kind per row of
:mod:`.terrain_kinds` (a plane: :mod:`.terrain_plane`, boxes: :mod:`.terrain_box`, a heightfield:
:mod:`.terrain_hfield`), with the contact law of :mod:`.terrain_law`. This module holds the one
implementation over every kind (:func:`rows_forces`, the kind dispatch :func:`_closest`), the
forces kernel and the loop driver's lanes entry (:func:`lanes_forces`). SI units.

Contact measure ``sd`` and its gradient ``w n`` (n the unit normal): the signed distance (w = 1)
for a plane or a box; for the heightfield the vertical gap ``z - h`` above the bilinear surface,
whose gradient is ``(-h_x, -h_y, 1)``, ``w = sqrt(1 + |grad h|^2)``, so that the normal force is
minus the gradient of the potential (:mod:`tensegrity_gym.backends.numba.heightfield`, where the
interior slot's point, the exact lowest point of the rod axis, is found). The far early-out of a
rod (no slot can touch): the signed distance is 1-Lipschitz, the vertical gap
``sqrt(1 + L^2)``-Lipschitz along a unit rod, L bounding the field's slope (largest height step
between grid neighbours over the cell, per axis); a heightfield's is decided from the rod's end
gaps (which its node slots then use): the lower end's where the gap is monotone along the rod
(``|b_z| >= L |b_xy|``, :func:`.heightfield.hf_monotone`, whose interior slot then needs no
search), else ``(gap_a + gap_c - sqrt(1 + L^2) |span|) / 2``.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .heightfield import hf_monotone, hf_patch
from .layout import _opts
from .terrain_box import (BOUND_SLACK, _box_closest, _box_face_bound, _box_passed_over, _interior,
                          box_lanes_forces)
from .terrain_hfield import _hf_closest, _hf_normal, hf_bound_of, hf_interior_slot, hf_lanes_forces
from .terrain_kinds import BOX, HFIELD, PLANE
from .terrain_law import _ends_moved, _interior_force, _slot_force, add_ext


@njit(inline="always", **_opts)
def _closest(px, py, pz, g, H):
    """Contact measure of a point against the feature ``g`` (plane, box or heightfield with
    heights ``H``): (gap m, outward unit normal, w) with the measure's gradient ``w n``: the
    signed distance (w = 1) for a plane or a box, the vertical gap for a heightfield. A code of
    no kind (never here: :func:`codes_known`) gives NaN."""
    if g[0] == PLANE:
        return g[1] * px + g[2] * py + g[3] * pz - g[4], g[1], g[2], g[3], 1.0
    if g[0] == HFIELD:
        return _hf_closest(px, py, pz, g, H)
    if g[0] == BOX:
        d, n0, n1, n2 = _box_closest(px, py, pz, g)
        return d, n0, n1, n2, 1.0
    return math.nan, math.nan, math.nan, math.nan, math.nan


@njit(inline="always", **_opts)
def codes_known(geom):
    """True when every feature code of ``geom`` (G, F, 10) is one that :func:`_closest` and
    :func:`rows_forces` dispatch on (:mod:`.terrain_kinds`); the kernels' entries refuse the
    others before any work (:func:`.terrain_steps._terrain_tuples`)."""
    for c in range(geom.shape[0]):
        for f in range(geom.shape[1]):
            k = geom[c, f, 0]
            if not (k == PLANE or k == BOX or k == HFIELD):
                return False
    return True


# compiled once on its own, called by the kernel below and the loop driver's terrain instances:
# inlined into each (numba copies an inlined function's IR once per basic block of the caller), it
# made the first terrain step of a new install compile for 77 s, not 19 s; the call costs one
# function call per SIMD block and physics step. Without the runtime's reference counting
# (_nrt=False: it allocates nothing; its views live within the call), which on its array arguments
# cost about 6 % of the navigation kernel's time
@njit(_nrt=False, **_opts)
def rows_forces(c0, nr, Q, QD, Wc, eta, rod_a, rod_c, geom, prm, hf, lam, anchor, eta0, active, slip, info, f0, f1,
                g, pr, clr, ref, fresh):
    """The terrain forces of copies ``c0 .. c0 + nr - 1`` at ``Q[r]``, ``QD[r]`` (k, 6) into
    ``Wc[r]`` (n, 3) N, row r = copy - c0: the one implementation of the terrain contact
    (:func:`terrain_forces_kernel` calls it on the whole batch, the loop driver on each block
    of lanes at each step). ``lam`` the shared heights' slope bound (:func:`hf_bound_of`; per-copy
    heights: computed here); ``geom``, ``prm``, ``hf``, ``anchor``, ``eta0``, ``active``,
    ``slip`` and ``info`` (when it has rows) indexed by copy, as the kernel takes them.
    ``f0``: the first feature (0: all, ``Wc`` zeroed first; 1: the loop driver has put feature
    0's forces, a plane's, in ``Wc`` (:func:`plane_forces`), and the others are added to them in
    the order of the features, as with ``f0`` = 0); ``f1``: the feature after the last (F: all;
    F - 1: the loop driver adds a last heightfield's forces after these, :func:`hf_lanes_forces`).
    ``g`` (10,), ``pr`` (8,): scratch for a feature's rows, copied there once per copy and
    feature.
    ``clr`` (nr, F), ``ref`` (nr, k, 2, 3): the boxes' clearance over the loop driver's sub-steps
    of one call (0 rows: not kept). At the first sub-step (``fresh``) ``ref`` takes the rods' end
    points m and ``clr[r, f]`` the least, over the rods, of the box's far-test slack m (the lower
    bound :func:`_box_face_bound` of the box's distance along the rod less the cap radius and
    :data:`BOUND_SLACK`; < 0 where a rod is not far). At a later sub-step a box whose clearance
    exceeds the largest move of a rod end from ``ref`` (1-norm, which bounds the move of every rod
    point) is still out of reach (the signed distance is 1-Lipschitz) and its slots, released at
    the first sub-step, are still released: the box is passed over, the same numbers for less
    work. A box computed at a later sub-step is computed at every sub-step after it in the call
    (its clearance set to -inf)."""
    k, n = Q.shape[1], Wc.shape[1]
    F = geom.shape[1]
    has_info = info.shape[0] > 0
    # per-copy rows with a heightfield: its slope bound per copy (a (., 1, 1) hf is no heightfield)
    per_hf = (geom.shape[0] > 1 or hf.shape[0] > 1) and hf.shape[1] * hf.shape[2] > 1
    H = hf[0]       # shared heights: one view for all copies
    for r in range(nr):
        c = c0 + r
        g_row = c if geom.shape[0] > 1 else 0
        p_row = c if prm.shape[0] > 1 else 0
        if hf.shape[0] > 1:
            H = hf[c]
        if per_hf:
            lam = hf_bound_of(geom[g_row], H)
        if f0 == 0:
            for p in range(n):
                Wc[r, p, 0] = 0.0
                Wc[r, p, 1] = 0.0
                Wc[r, p, 2] = 0.0
        # the boxes' clearance: set at the call's first sub-step; after it, the rod ends' largest move since
        moved = math.inf
        if clr.shape[0] > 0:
            moved = _ends_moved(Q, r, eta, ref, fresh)
            if fresh:
                for f in range(f0, f1):
                    clr[r, f] = math.inf
        # features outer, rods inner: a node's forces come from its own rod's slots only (class 1),
        # added feature by feature as with the rods outer; a feature's rows copied once per copy
        for f in range(f0, f1):
            kind = geom[g_row, f, 0]
            if kind == BOX and not fresh and clr.shape[0] > 0:
                if moved + 1e-12 < clr[r, f]:
                    continue        # out of reach since the call's first sub-step, whose release stands
                # computed at a sub-step after the first: at every one after it in the call (a slot
                # it touches with stays in the computation, to be released by it)
                clr[r, f] = -math.inf
            radius = prm[p_row, f, 0]
            loaded = False
            for j in range(k):
                r0, r1, r2 = Q[r, j, 0], Q[r, j, 1], Q[r, j, 2]
                b0, b1, b2 = Q[r, j, 3], Q[r, j, 4], Q[r, j, 5]
                ea, ec = eta[j, 0], eta[j, 1]
                span = ec - ea
                em = 0.5 * (ea + ec)
                base = (j * F + f) * 3
                # a rod whose every point is at least the cap radius from the feature touches
                # nowhere. The box is the intersection of the half-spaces behind its six faces, so
                # a point's distance to it is at least its distance beyond any face, which is
                # linear along the rod, least at an end: every point of the rod is at least the
                # largest, over the faces, of its ends' lesser distance beyond the face from the
                # box (_box_face_bound). Far by that bound (with BOUND_SLACK for the round-off of
                # the interior search), the slots are released, as the distances would release them
                far = False
                if kind == BOX:
                    clear = _box_face_bound(r0 + ea * b0, r1 + ea * b1, r2 + ea * b2, r0 + ec * b0, r1 + ec * b1,
                                            r2 + ec * b2, geom[g_row, f])
                    far = clear >= radius + BOUND_SLACK
                    if fresh and clr.shape[0] > 0:
                        clr[r, f] = min(clr[r, f], clear - radius - BOUND_SLACK)
                # a heightfield's end gaps (m) and gradients, for the far test and the node slots,
                # and whether its gap is monotone along the rod
                ha, gxa, gya, hc, gxc, gyc = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
                mono = False
                if not far:
                    if not loaded:
                        for i in range(g.shape[0]):
                            g[i] = geom[g_row, f, i]
                        for i in range(pr.shape[0]):
                            pr[i] = prm[p_row, f, i]
                        loaded = True
                    if kind == HFIELD:
                        # the vertical gap is sqrt(1 + L^2)-Lipschitz along the unit rod (module
                        # doc), so at least (gap_a + gap_c - sqrt(1 + L^2) |span|) / 2 anywhere on
                        # it, and at least the lower end's where it is monotone: a rod whose bound
                        # reaches the cap radius touches nowhere
                        ha, gxa, gya = hf_patch(r0 + ea * b0, r1 + ea * b1, g, H)
                        hc, gxc, gyc = hf_patch(r0 + ec * b0, r1 + ec * b1, g, H)
                        ga, gc = r2 + ea * b2 - ha, r2 + ec * b2 - hc
                        mono = hf_monotone(b0, b1, b2, lam)
                        far = (min(ga, gc) if mono else 0.5 * (ga + gc - lam * abs(span))) >= radius
                    else:
                        far = _closest(r0 + em * b0, r1 + em * b1, r2 + em * b2, g, H)[0] - 0.5 * abs(span) >= radius
                if far and not has_info:
                    # no slot touches: what _slot_force gives for an infinite gap, each slot
                    # released (the interior slot keeps the anchored point of a contact that
                    # ends here), with no write where the slot is released already
                    for s in range(3):
                        ci = base + s
                        e = ea if s == 0 else (ec if s == 1 else em)
                        if active[c, ci]:
                            if s < 2:
                                eta0[c, ci] = e
                            active[c, ci] = False
                        elif eta0[c, ci] != e:
                            eta0[c, ci] = e
                        if slip[c, ci]:
                            slip[c, ci] = False
                    continue
                # the nodes' distances, normals and normal velocities, for the interior slot's level
                sd_a, na0, na1, na2, w_a, vn_a = math.inf, 0.0, 0.0, 1.0, 1.0, 0.0
                sd_c, nc0, nc1, nc2, w_c, vn_c = math.inf, 0.0, 0.0, 1.0, 1.0, 0.0
                for s in range(3):
                    ci = base + s
                    e = ea if s == 0 else (ec if s == 1 else em)
                    if far or (s == 2 and (kind == PLANE or (kind == BOX and not has_info and _box_passed_over(
                            sd_a, na0, na1, na2, sd_c, nc0, nc1, nc2, ea, span, r0, r1, r2, b0, b1, b2, g, radius)))):
                        # no contact (a plane's nearest point is an end; a box's bound leaves no
                        # interior point that touches, so its search is passed over: the same
                        # numbers, info=True searches): what _slot_force gives for an infinite gap,
                        # without computing it; the interior slot keeps the anchored point of a
                        # contact that ends here
                        if not (s == 2 and active[c, ci]):
                            eta0[c, ci] = e
                        active[c, ci] = False
                        slip[c, ci] = False
                        if has_info:
                            info[c, ci, 0], info[c, ci, 1] = e, math.inf
                            info[c, ci, 2], info[c, ci, 3], info[c, ci, 4] = 0.0, 0.0, 1.0
                            info[c, ci, 5] = 0.0
                        continue
                    if s == 2:
                        # the interior point nearest the feature, where it can be deeper than both ends
                        ends = (sd_a, na0, na1, na2, w_a, vn_a, sd_c, nc0, nc1, nc2, w_c, vn_c)
                        if kind == HFIELD:
                            hf_interior_slot(c, ci, r, j, Q, QD, Wc, ea, ec, em, ends, g, H, pr, mono, has_info,
                                             anchor, eta0, active, slip, info, rod_a, rod_c)
                        else:
                            e, use = _interior(ea, ec, r0, r1, r2, b0, b1, b2, g, H)
                            sd, nx, ny, nz, w = math.inf, 0.0, 0.0, 1.0, 1.0
                            if use:
                                sd, nx, ny, nz, w = _closest(r0 + e * b0, r1 + e * b1, r2 + e * b2, g, H)
                            _interior_force(c, ci, r, j, e, sd, nx, ny, nz, w, (r0, r1, r2, b0, b1, b2, ea, ec, em),
                                            QD, Wc, ends, radius, pr, anchor, eta0, active, slip, info, rod_a, rod_c)
                        continue
                    px, py, pz = r0 + e * b0, r1 + e * b1, r2 + e * b2
                    if kind == PLANE:
                        # a plane's node slot (its nearest point of a rod is an end): the geometry
                        # directly, as _closest computes it
                        sd, nx, ny, nz, w = g[1] * px + g[2] * py + g[3] * pz - g[4], g[1], g[2], g[3], 1.0
                    elif kind == HFIELD:
                        # an end's gap first (_hf_closest's arithmetic): an end clear of the
                        # heightfield needs no normal; what _slot_force gives for no contact
                        h, hgx, hgy = (ha, gxa, gya) if s == 0 else (hc, gxc, gyc)
                        sd = pz - h
                        if not (radius - sd > 0.0) and not has_info:
                            if s == 0:
                                sd_a = sd
                            else:
                                sd_c = sd
                            eta0[c, ci] = e
                            active[c, ci] = False
                            slip[c, ci] = False
                            continue
                        nx, ny, nz, w = _hf_normal(hgx, hgy)
                    else:
                        sd, nx, ny, nz, w = _closest(px, py, pz, g, H)
                    vx = QD[r, j, 0] + e * QD[r, j, 3]
                    vy = QD[r, j, 1] + e * QD[r, j, 4]
                    vz = QD[r, j, 2] + e * QD[r, j, 5]
                    if s == 0:
                        sd_a, na0, na1, na2, w_a, vn_a = sd, nx, ny, nz, w, vx * nx + vy * ny + vz * nz
                    else:
                        sd_c, nc0, nc1, nc2, w_c, vn_c = sd, nx, ny, nz, w, vx * nx + vy * ny + vz * nz
                    if not (radius - sd > 0.0) and not has_info:
                        # clear of the feature: what _slot_force gives for no contact, without computing it
                        eta0[c, ci] = e
                        active[c, ci] = False
                        slip[c, ci] = False
                        continue
                    # a node slot's anchored material point is the node itself
                    touch, fx, fy, fz, ax, ay, az, sl, en, fn = _slot_force(
                        px, py, pz, px, py, pz, vx, vy, vz, sd, nx, ny, nz, w,
                        anchor[c, ci, 0], anchor[c, ci, 1], anchor[c, ci, 2], active[c, ci], radius,
                        pr[1], pr[2], pr[3], pr[4], pr[5], pr[6], pr[7])
                    anchor[c, ci, 0], anchor[c, ci, 1], anchor[c, ci, 2] = ax, ay, az
                    eta0[c, ci] = e
                    active[c, ci] = touch
                    slip[c, ci] = sl
                    if has_info:
                        info[c, ci, 0], info[c, ci, 1] = e, sd
                        info[c, ci, 2], info[c, ci, 3], info[c, ci, 4] = nx, ny, nz
                        info[c, ci, 5] = en
                    if touch:
                        # a node slot's force goes to its node whole
                        node = rod_a[j] if s == 0 else rod_c[j]
                        Wc[r, node, 0] += fx
                        Wc[r, node, 1] += fy
                        Wc[r, node, 2] += fz


@njit(cache=True, nogil=True)
def terrain_forces_kernel(q, qd, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip, W, info):
    """Terrain contact forces of every copy of ``q``, ``qd`` (B, k, 6) as nodal forces ``W``
    (B, n, 3) N, against the features ``geom`` (heightfield heights ``hf``); anchors, the
    material coordinates ``eta0`` (B, S) m of the rod points anchored, active and slip flags
    (B, S) updated in place; ``info`` filled when it has B rows (see the module doc). A force F
    at the rod point ``r + eta b`` goes to the rod's nodes a, c (at eta_a, eta_c) as
    ``(eta_c - eta) / (eta_c - eta_a) F`` and ``(eta - eta_a) / (eta_c - eta_a) F``: the
    generalized force ``[F, eta F]`` exactly (:func:`rows_forces`)."""
    lam = 1.0 if (geom.shape[0] > 1 or hf.shape[0] > 1) else hf_bound_of(geom[0], hf[0])
    rows_forces(0, q.shape[0], q, qd, W, eta, rod_a, rod_c, geom, prm, hf, lam, anchor, eta0, active, slip, info, 0,
                geom.shape[1], np.empty(geom.shape[2]), np.empty(prm.shape[2]), np.empty((0, 0)),
                np.empty((0, 0, 2, 3)), False)


@njit(inline="always", **_opts)
def has_box(geom):
    """True when some copy's terrain ``geom`` (G, F, 10) has a box."""
    for c in range(geom.shape[0]):
        for f in range(geom.shape[1]):
            if geom[c, f, 0] == BOX:
                return True
    return False


@njit(inline="always", **_opts)
def lanes_forces(QT, QDT, EXT, EX, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip, info, ext, lam, g,
                 pr, boxes, c0, ne, k, n, E, feats, hfs, bxs):
    """The terrain forces of E lanes of the loop driver (copies c0..c0+ne-1) into EX (n, 3, E) N,
    plus the external force ``ext``: :func:`rows_forces` on the lanes' state Q, QD (k, 6, E) m,
    m/s read through their transposed views ``QT``, ``QDT`` (E, k, 6) and the forces written
    through ``EXT`` (E, n, 3), EX's (views made once per call: no copy of the state per step);
    the contact state of the copies updated in place. Pad lanes (e >= ne, copies of lane 0)
    take lane 0's forces. ``eta`` .. ``info`` as :func:`terrain_forces_kernel` takes them,
    ``ext`` (0, 1 or B rows of (n, 3)) N; ``lam`` the shared heights' slope bound; ``g``,
    ``pr`` rows_forces' scratch, ``boxes`` the tuple (clr, ref, fresh) of its boxes' clearance.
    ``feats`` = (f0, f1): features f0 .. f1 - 1 in rows_forces (f0 = 1: EX holds feature 0's
    forces already, :func:`plane_forces`, the other features' are added to them); f1 = F - 1:
    the last feature, a heightfield, after them in :func:`hf_lanes_forces`, ``hfs`` the tuple
    (AN, AC, SL, LAM) of its node slots' lane scratch and slope bounds with the rods' end scratch
    (tuples: a call with more than 30 arguments would not inline; a fifth array in this tuple made
    the one-copy driver loaded from numba's cache a quarter slower). ``bxs``: the tuple (bx, Q, QD,
    BAN, BAC, BSL, BP, BT): bx where features f0 .. f1 - 1 are boxes in every copy
    (:func:`boxes_between`; SIMD blocks, no ``info``), which then run in :func:`box_lanes_forces`
    on the lanes Q, QD and the boxes' lane scratch of :func:`box_load`."""
    clr, ref, fresh = boxes
    f0, f1 = feats
    AN, AC, SL, LAM = hfs
    if f1 > f0:
        bx, Q, QD, BAN, BAC, BSL, BP, BT = bxs
        if bx:
            box_lanes_forces(Q, QD, EX, QT, QDT, EXT, BAN, BAC, BSL, BP, BT, eta, rod_a, rod_c, geom, prm, hf, anchor,
                             eta0, active, slip, info, clr, ref, fresh, c0, ne, k, n, f0, f1)
        else:
            rows_forces(c0, ne, QT, QDT, EXT, eta, rod_a, rod_c, geom, prm, hf, lam, anchor, eta0, active, slip, info,
                        f0, f1, g, pr, clr, ref, fresh)
    if f1 < geom.shape[1]:
        hf_lanes_forces(QT, QDT, EXT, AN, AC, SL, LAM, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active,
                        slip, info, g, pr, c0, ne, k, n, f1 == 0)
    add_ext(EX, ext, c0, ne, n, E)
    for e in range(ne, E):
        for p in range(n):
            for i in range(3):
                EX[p, i, e] = EX[p, i, 0]
