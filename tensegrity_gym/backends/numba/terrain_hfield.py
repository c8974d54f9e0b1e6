"""The heightfield kind of the numba terrain contact: the contact measure of a point (the vertical
gap and its gradient), the heightfield's interior slot and its node slots over the loop driver's
SIMD lanes. The geometry (bilinear height, slope bound, lowest point of a rod) is
:mod:`.heightfield`'s. SI units: m.

A heightfield's geom row (:mod:`.terrain_kinds`): grid origin x0, y0 (1:3) m, cell size (3) m,
grid rows ny and columns nx (4:6), ``sqrt(1 + L^2)`` (6) for L the steepest slope of its heights
(the "too far to touch" bound; 0: computed from ``hf`` at each call).
"""
from __future__ import annotations

import math

from numba import njit

from .heightfield import (LEVEL_TOL, hf_blend, hf_cell, hf_flat_under, hf_grid, hf_lipschitz, hf_lowest,
                          hf_monotone, hf_patch)
from .layout import _TILE_LANES, _opts, _stack_tile
from .terrain_kinds import HFIELD
from .terrain_law import _interior_force, _slot_force


@njit(inline="always", **_opts)
def _hf_normal(gx, gy):
    """The unit normal of a surface of height gradient (gx, gy) and the length of its
    unnormalised normal ``|(-gx, -gy, 1)|``, the gradient of the vertical gap."""
    w = math.sqrt(1.0 + gx * gx + gy * gy)
    return -gx / w, -gy / w, 1.0 / w, w


@njit(inline="always", **_opts)
def _hf_closest(px, py, pz, g, H):
    """The heightfield's contact measure at (px, py, pz): the vertical gap m (< 0 below the
    surface), the unit normal of the bilinear patch and the length of its unnormalised normal
    ``|(-h_x, -h_y, 1)|``, the gradient of the gap (module doc of :mod:`.heightfield`)."""
    h, gx, gy = hf_patch(px, py, g, H)
    nx, ny, nz, w = _hf_normal(gx, gy)
    return pz - h, nx, ny, nz, w


@njit(inline="always", **_opts)
def hf_bound_of(geom_row, H):
    """``sqrt(1 + L^2)`` of the heightfield among the features ``geom_row`` (F, 10) with heights
    ``H`` (its column 6, else one pass over the heights: :func:`hf_lipschitz`); 1 without one."""
    for f in range(geom_row.shape[0]):
        g = geom_row[f]
        if g[0] == HFIELD:
            return g[6] if g[6] >= 1.0 else hf_lipschitz(g, H)
    return 1.0


@njit(inline="always", **_opts)
def hf_last(geom):
    """True when the last feature of every copy's terrain ``geom`` (G, F, 10) is a heightfield."""
    if geom.shape[1] == 0:
        return False
    for c in range(geom.shape[0]):
        if geom[c, geom.shape[1] - 1, 0] != HFIELD:
            return False
    return True


#: rows of the heightfield's lane scratch ``LAM`` before its rods' rows (:func:`hf_lam_load`)
HF_LANE_ROWS = 8


@njit(inline="always", **_opts)
def hf_lam_load(LAM, geom, prm, hf, lam, c0, ne):
    """Rows 0 .. :data:`HF_LANE_ROWS` - 1 of lanes e < ne (copies c0 + e) of ``LAM``: the slope
    bound ``sqrt(1 + L^2)`` of the copy's heightfield (the shared heights' ``lam``, per-copy
    heights' their own: :func:`hf_bound_of`, as :func:`rows_forces` computes it), the slope bound
    L, the grid's origin x0, y0 m and cell m, its last column and row indices ``nx - 1``, ``ny - 1``
    and the contact's cap radius m (the heightfield is the last feature)."""
    per_hf = (geom.shape[0] > 1 or hf.shape[0] > 1) and hf.shape[1] * hf.shape[2] > 1
    f = geom.shape[1] - 1
    for e in range(ne):
        c = c0 + e
        gc = geom[c if geom.shape[0] > 1 else 0]
        H = hf[c if hf.shape[0] > 1 else 0]
        LAM[0, e] = hf_bound_of(gc, H) if per_hf else lam
        LAM[1, e] = math.sqrt(max(LAM[0, e] * LAM[0, e] - 1.0, 0.0))
        LAM[2, e], LAM[3, e], LAM[4, e] = gc[f, 1], gc[f, 2], gc[f, 3]
        ny, nx = hf_grid(gc[f], H)
        LAM[5, e], LAM[6, e] = nx - 1.0, ny - 1.0
        LAM[7, e] = prm[c if prm.shape[0] > 1 else 0, f, 0]


# compiled on its own (a rod whose gap is not monotone along it is rare): inlined, its search
# would be compiled into every terrain instance of the loop driver
@njit(**_opts)
def hf_interior_slot(c, ci, r, j, Q, QD, Wc, ea, ec, em, ends, g, H, pr, mono, whole, anchor, eta0, active, slip,
                     info, rod_a, rod_c):
    """The interior slot ``ci`` of rod j of copy c (row r of ``Q``, ``QD`` (., k, 6), ``Wc``
    (., n, 3)) over the heightfield ``g`` (heights ``H``, contact parameters ``pr``), given its
    ends' data ``ends`` (:func:`_interior_force`): at the lowest point of the axis where it is
    lower than both ends (:func:`.heightfield.hf_lowest`, with the gradient its force uses),
    searched for only where it can touch, below the slot's level ``min(radius, sd_a, sd_c)``
    (at or above its gap when it touches) with a margin beyond the level-run tolerance, or along
    the whole axis (``whole``: info asked for); none (an infinite gap at the rod's middle ``em``)
    where the gap is monotone along the rod (``mono``, :func:`.heightfield.hf_monotone`: lowest
    at an end) or the ground under the rod is level (as a plane, no point is lower than both
    ends). :func:`rows_forces` and :func:`hf_lanes_forces` call it."""
    r0, r1, r2, b0, b1, b2 = Q[r, j, 0], Q[r, j, 1], Q[r, j, 2], Q[r, j, 3], Q[r, j, 4], Q[r, j, 5]
    sd_a, sd_c = ends[0], ends[6]
    e, sd, nx, ny, nz, w = em, math.inf, 0.0, 0.0, 1.0, 1.0
    if not (mono or hf_flat_under(r0 + ea * b0, r1 + ea * b1, r0 + ec * b0, r1 + ec * b1, g, H)):
        cut = math.inf if whole else min(pr[0], min(sd_a, sd_c)) + 2.0 * LEVEL_TOL
        e, use, kgx, kgy = hf_lowest(ea, ec, r0, r1, r2, b0, b1, b2, g, H, cut, sd_a, sd_c)
        if use:
            nx, ny, nz, w = _hf_normal(kgx, kgy)
            sd = r2 + e * b2 - hf_patch(r0 + e * b0, r1 + e * b1, g, H)[0]
    _interior_force(c, ci, r, j, e, sd, nx, ny, nz, w, (r0, r1, r2, b0, b1, b2, ea, ec, em), QD, Wc, ends, pr[0], pr,
                    anchor, eta0, active, slip, info, rod_a, rod_c)


# compiled once on its own and called once per SIMD block and physics step, as rows_forces: inlined
# into every terrain instance of the loop driver, it doubled their cold compile (a steps env's first
# step 13 -> 28 s). Without the runtime's reference counting (_nrt=False: it allocates nothing; its
# views live within the call): the counts of its array arguments made the call about 8 % of the
# rough-ground kernel's time
@njit(_nrt=False, **_opts)
def hf_lanes_forces(QT, QDT, EXT, AN, AC, SL, LAM, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active,
                    slip, info, g, pr, c0, ne, k, n, zero):
    """:func:`rows_forces` of the last feature, a heightfield (:func:`hf_last`), of the loop
    driver's lanes e < ne (copies c0 + e; ``QT``, ``QDT`` (E, k, 6) m, m/s and ``EXT`` (E, n, 3)
    N the lanes' transposed views), added to EXT (``zero``: set, no other feature's forces in
    it). The node slots' state in lane scratch (AN, AC, SL of :func:`slots_load`), ``LAM``
    (HF_LANE_ROWS + 8 k, E) the lanes' grid and contact parameters in its first
    :data:`HF_LANE_ROWS` rows (:func:`hf_lam_load`); the interior slot, which a rod needs only
    where its gap is not monotone along it, in the copies' state (:func:`hf_interior_slot`). The
    same arithmetic in the same order as :func:`rows_forces`, so the same bits, without its
    per-copy bookkeeping of the node slots, its loop over features and, where the gap is
    monotone along a rod, the upper end's contact when the rise of the gap along the rod keeps
    that end clear.
    Three passes over the lanes' rods: the first finds every rod's end gaps and gradients and
    decides far and monotony (into rows ``HF_LANE_ROWS + 8 j ..`` of ``LAM``: ga, gc m, the
    gradients at a and c, 1 where the rod is far or its gap monotone, one spare), the lanes
    innermost, so that all but its height lookups compile to SIMD code; the second runs the node
    slots from them, the third the interior slots. The rods of the second and third pass are
    independent, so the processor overlaps their chains of dependent operations (a force law's),
    which a single pass, one long chain per rod, leaves waiting. A node receives its slot's force, then
    its rod's interior slot's, as in one pass: the same bits."""
    F = geom.shape[1]
    f = F - 1
    H = hf[0]
    if zero:
        for e in range(ne):
            for p in range(n):
                EXT[e, p, 0] = 0.0
                EXT[e, p, 1] = 0.0
                EXT[e, p, 2] = 0.0
    # pass 1 runs rod by rod with the lanes innermost, through a stack tile T (row r of lane e at
    # T[r W + e]: scratch that overlaps no argument, so that its loops compile to SIMD code): the
    # rod's state (rows 0-5), both ends' cells (6-11: end a, 12-17: end c; hf_cell's i, j, the
    # fractions in the cell and the beyond-the-grid flags), their corner heights (18-25, looked
    # up in a scalar loop: numba does not vectorise a lookup with computed indices), then the gaps
    W = _TILE_LANES
    T = _stack_tile(26)
    for j in range(k):                  # pass 1: the end gaps, far and monotony
        ea, ec = eta[j, 0], eta[j, 1]
        span = ec - ea
        for e in range(ne):
            for i in range(6):
                T[i * W + e] = QT[e, j, i]
        for e in range(ne):
            r0, r1, b0, b1 = T[e], T[W + e], T[3 * W + e], T[4 * W + e]
            x0, y0, cell, nxm, nym = LAM[2, e], LAM[3, e], LAM[4, e], LAM[5, e], LAM[6, e]
            for s in range(2):
                t, h = (6 + 6 * s) * W + e, ea if s == 0 else ec
                fi, fj, u, v, T[t + 4 * W], T[t + 5 * W] = hf_cell(r0 + h * b0, r1 + h * b1, x0, y0, cell, nxm,
                                                                   nym)
                T[t], T[t + W], T[t + 2 * W], T[t + 3 * W] = fi, fj, u - fi, v - fj
        H = hf[0]
        for e in range(ne):
            if hf.shape[0] > 1:
                H = hf[c0 + e]
            for s in range(2):
                t, q = (6 + 6 * s) * W + e, (18 + 4 * s) * W + e
                i, jj = int(T[t]), int(T[t + W])
                T[q], T[q + W], T[q + 2 * W], T[q + 3 * W] = H[jj, i], H[jj, i + 1], H[jj + 1, i], H[jj + 1, i + 1]
        for e in range(ne):
            r0, r1, r2, b0, b1, b2 = T[e], T[W + e], T[2 * W + e], T[3 * W + e], T[4 * W + e], T[5 * W + e]
            lam, radius, cell = LAM[0, e], LAM[7, e], LAM[4, e]
            t, q = 6 * W + e, 18 * W + e
            ha, gxa, gya = hf_blend(T[t + 2 * W], T[t + 3 * W], T[t + 4 * W], T[t + 5 * W], T[q], T[q + W],
                                    T[q + 2 * W], T[q + 3 * W], cell)
            t, q = 12 * W + e, 22 * W + e
            hc, gxc, gyc = hf_blend(T[t + 2 * W], T[t + 3 * W], T[t + 4 * W], T[t + 5 * W], T[q], T[q + W],
                                    T[q + 2 * W], T[q + 3 * W], cell)
            za, zc = r2 + ea * b2, r2 + ec * b2
            ga, gc = za - ha, zc - hc
            mono = hf_monotone(b0, b1, b2, lam)
            if mono:
                # the lower end's gap, and the upper end's only where it can be under the cap
                # radius: the gap rises along the rod by at least |span| (|b_z| - L |b_xy|) >= 0
                # (|b_xy| <= |b_x| + |b_y|), with a margin far above round-off; an end clear by
                # that bound has an infinite gap here and a zero gradient (no contact: the same
                # decisions, bits and state as with its own gap, which is at least the cap radius)
                rise = abs(span) * (abs(b2) - LAM[1, e] * (abs(b0) + abs(b1)))
                tol = 1e-9 * (1.0 + abs(r0) + abs(r1) + abs(r2) + abs(span))
                if za <= zc:
                    if not (ga + rise - tol * (1.0 + abs(ha)) < radius):
                        gc, gxc, gyc = math.inf, 0.0, 0.0
                elif not (gc + rise - tol * (1.0 + abs(hc)) < radius):
                    ga, gxa, gya = math.inf, 0.0, 0.0
            far = (min(ga, gc) if mono else 0.5 * (ga + gc - lam * abs(span))) >= radius
            if far:
                ga, gc = math.inf, math.inf     # no slot touches: the node slots released below
            T[e], T[W + e], T[2 * W + e], T[3 * W + e], T[4 * W + e], T[5 * W + e] = ga, gc, gxa, gya, gxc, gyc
            T[6 * W + e] = 1.0 if (far or mono) else 0.0
        o = HF_LANE_ROWS + 8 * j        # the rod's rows of the end scratch
        for e in range(ne):
            for i in range(7):
                LAM[o + i, e] = T[i * W + e]
    for e in range(ne):                 # pass 2: the node slots
        pc = c0 + e if prm.shape[0] > 1 else 0
        for i in range(pr.shape[0]):
            pr[i] = prm[pc, f, i]
        radius = pr[0]
        for j in range(k):
            for s in range(2):
                a = 2 * j + s
                sd = LAM[HF_LANE_ROWS + 8 * j + s, e]
                if not (radius - sd > 0.0):
                    AC[a, e] = False
                    SL[a, e] = False
                    continue
                h = eta[j, s]
                px = QT[e, j, 0] + h * QT[e, j, 3]
                py = QT[e, j, 1] + h * QT[e, j, 4]
                pz = QT[e, j, 2] + h * QT[e, j, 5]
                o = HF_LANE_ROWS + 8 * j + 2 * s
                nx, ny, nz, w = _hf_normal(LAM[o + 2, e], LAM[o + 3, e])
                vx = QDT[e, j, 0] + h * QDT[e, j, 3]
                vy = QDT[e, j, 1] + h * QDT[e, j, 4]
                vz = QDT[e, j, 2] + h * QDT[e, j, 5]
                touch, fx, fy, fz, AN[a, 0, e], AN[a, 1, e], AN[a, 2, e], SL[a, e], en, fn = _slot_force(
                    px, py, pz, px, py, pz, vx, vy, vz, sd, nx, ny, nz, w,
                    AN[a, 0, e], AN[a, 1, e], AN[a, 2, e], AC[a, e], radius,
                    pr[1], pr[2], pr[3], pr[4], pr[5], pr[6], pr[7])
                AC[a, e] = touch
                if touch:
                    node = rod_a[j] if s == 0 else rod_c[j]
                    EXT[e, node, 0] += fx
                    EXT[e, node, 1] += fy
                    EXT[e, node, 2] += fz
    for e in range(ne):                 # pass 3: the interior slots
        c = c0 + e
        for j in range(k):
            ea, ec = eta[j, 0], eta[j, 1]
            em = 0.5 * (ea + ec)
            ci = 3 * (j * F + f) + 2
            o = HF_LANE_ROWS + 8 * j
            if LAM[o + 6, e] != 0.0:
                # no interior contact (a monotone gap is lowest at an end), released as rows_forces
                # releases it (written here once: an inlined function of these arrays measured slower)
                if active[c, ci]:
                    active[c, ci] = False
                elif eta0[c, ci] != em:
                    eta0[c, ci] = em
                if slip[c, ci]:
                    slip[c, ci] = False
                continue
            if hf.shape[0] > 1:
                H = hf[c]
            for i in range(g.shape[0]):
                g[i] = geom[c if geom.shape[0] > 1 else 0, f, i]
            for i in range(pr.shape[0]):
                pr[i] = prm[c if prm.shape[0] > 1 else 0, f, i]
            ends = (_hf_end(QDT, e, j, LAM[o, e], LAM[o + 2, e], LAM[o + 3, e], ea, pr[0])
                    + _hf_end(QDT, e, j, LAM[o + 1, e], LAM[o + 4, e], LAM[o + 5, e], ec, pr[0]))
            hf_interior_slot(c, ci, e, j, QT, QDT, EXT, ea, ec, em, ends, g, H, pr, False, False, anchor, eta0, active,
                             slip, info, rod_a, rod_c)


@njit(inline="always", **_opts)
def _hf_end(QDT, e, j, sd, gx, gy, h, radius):
    """``(sd, n0, n1, n2, w, vn)`` of the node slot at rod point h of rod j of lane e for the
    interior slot's level (:func:`_interior_force`'s ``ends``): its gap m and, where it touches,
    the normal, its length w and the normal velocity m/s (those of no contact where not)."""
    if not (radius - sd > 0.0):
        return sd, 0.0, 0.0, 1.0, 1.0, 0.0
    nx, ny, nz, w = _hf_normal(gx, gy)
    vx = QDT[e, j, 0] + h * QDT[e, j, 3]
    vy = QDT[e, j, 1] + h * QDT[e, j, 4]
    vz = QDT[e, j, 2] + h * QDT[e, j, 5]
    return sd, nx, ny, nz, w, vx * nx + vy * ny + vz * nz
