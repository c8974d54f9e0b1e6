"""The box kind of the numba terrain contact: the signed distance of a point to a box and its
outward normal, the interior point of a rod nearest a box (a golden-section search), the far
tests' lower bounds, and the boxes' node slots over the loop driver's SIMD lanes. SI units: m.

A box's geom row (:mod:`.terrain_kinds`): centre (1:4) m, half sizes (4:7) m, cos and sin of the
yaw (7:9).
"""
from __future__ import annotations

import math

from numba import njit

from .heightfield import LEVEL_TOL
from .layout import _TILE_LANES, _opts, _stack_tile
from .terrain_kinds import BOX
from .terrain_law import _ends_moved, _interior_force, _lane_point, _slot_force, _tile_slot_store, slots_load, slots_store

#: golden-section iterations of the box interior search (interval shrinks to 0.618^40 = 4e-9 of the rod)
GOLDEN_ITERS = 40
_GR = 0.6180339887498949


@njit(inline="always", **_opts)
def _box_closest(px, py, pz, g):
    """Signed distance (m; < 0 inside) of (px, py, pz) to the box ``g`` (a geom row) and the
    outward normal there (nearest face inside, direction to the nearest surface point outside)."""
    return _box_closest_at(px, py, pz, g[1], g[2], g[3], g[4], g[5], g[6], g[7], g[8])


@njit(inline="always", **_opts)
def _box_closest_at(px, py, pz, x, y, z, hx, hy, hz, c, s):
    """:func:`_box_closest` of the box of centre (x, y, z) m, half sizes (hx, hy, hz) m and yaw
    cosine and sine (c, s). Written with selects only, so that a loop over SIMD lanes of it
    compiles to SIMD code (:func:`box_lanes_forces`)."""
    dx, dy, dz = px - x, py - y, pz - z
    l0 = c * dx + s * dy
    l1 = -s * dx + c * dy
    l2 = dz
    q0, q1, q2 = abs(l0) - hx, abs(l1) - hy, abs(l2) - hz
    s0 = 1.0 if l0 >= 0.0 else -1.0
    s1 = 1.0 if l1 >= 0.0 else -1.0
    s2 = 1.0 if l2 >= 0.0 else -1.0
    o0, o1, o2 = max(q0, 0.0), max(q1, 0.0), max(q2, 0.0)
    dout = math.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
    # inside: the face of the largest q (the first of equal ones)
    i1 = q1 > q0
    di = q1 if i1 else q0
    i2 = q2 > di
    di = q2 if i2 else di
    out = dout > 0.0
    d = dout if out else di
    n0 = s0 * o0 / dout if out else (0.0 if (i1 or i2) else s0)
    n1 = s1 * o1 / dout if out else (s1 if (i1 and not i2) else 0.0)
    n2 = s2 * o2 / dout if out else (s2 if i2 else 0.0)
    return d, c * n0 - s * n1, s * n0 + c * n1, n2


@njit(inline="always", **_opts)
def _sd_at(e, r0, r1, r2, b0, b1, b2, g, H):
    """Signed distance of the rod point ``r + e b`` to the box ``g``."""
    return _box_closest(r0 + e * b0, r1 + e * b1, r2 + e * b2, g)[0]


# compiled on its own and called once per rod near a box (without reference counting, as
# rows_forces): inlined, its nine copies of the box distance (seven in the golden-section search,
# one in each bisection) made half of rows_forces' cold compile
@njit(_nrt=False, **_opts)
def _interior(ea, ec, r0, r1, r2, b0, b1, b2, g, H):
    """The interior contact point of a rod segment [ea, ec] against the box ``g``: the signed
    distance is convex along the segment (the box is convex), so a golden-section search over
    the segment finds its minimum; the point returned is the middle of the part within
    ``LEVEL_TOL`` of the minimum (found by bisection on both sides). Returns (eta, deeper):
    deeper = the point is deeper than both ends by more than ``LEVEL_TOL``."""
    fa = _sd_at(ea, r0, r1, r2, b0, b1, b2, g, H)
    fc = _sd_at(ec, r0, r1, r2, b0, b1, b2, g, H)
    lo, hi = ea, ec
    x1 = hi - _GR * (hi - lo)
    x2 = lo + _GR * (hi - lo)
    f1 = _sd_at(x1, r0, r1, r2, b0, b1, b2, g, H)
    f2 = _sd_at(x2, r0, r1, r2, b0, b1, b2, g, H)
    for _ in range(GOLDEN_ITERS):
        if f1 <= f2:
            hi = x2
            x2, f2 = x1, f1
            x1 = hi - _GR * (hi - lo)
            f1 = _sd_at(x1, r0, r1, r2, b0, b1, b2, g, H)
        else:
            lo = x1
            x1, f1 = x2, f2
            x2 = lo + _GR * (hi - lo)
            f2 = _sd_at(x2, r0, r1, r2, b0, b1, b2, g, H)
    em = 0.5 * (lo + hi)
    fm = _sd_at(em, r0, r1, r2, b0, b1, b2, g, H)
    if not (fm < min(fa, fc) - LEVEL_TOL):
        return em, False
    level = fm + LEVEL_TOL
    # the level's crossings on both sides, f(ea) > level >= f(em) and f(ec) > level >= f(em): two
    # bisections of GOLDEN_ITERS halvings each, in one loop, so that their independent chains of
    # distances overlap (the same halvings, so the same points, as one after the other)
    a_out, a_in, c_out, c_in = ea, em, ec, em
    for _ in range(GOLDEN_ITERS):
        ma = 0.5 * (a_out + a_in)
        mc = 0.5 * (c_out + c_in)
        above_a = _sd_at(ma, r0, r1, r2, b0, b1, b2, g, H) > level
        above_c = _sd_at(mc, r0, r1, r2, b0, b1, b2, g, H) > level
        a_out, a_in = (ma, a_in) if above_a else (a_out, ma)
        c_out, c_in = (mc, c_in) if above_c else (c_out, mc)
    return 0.5 * (a_in + c_in), True


#: slack m of the box interior slot's lower bound (:func:`_box_dip_bound`): above the rounding of
#: the distances and the bound (about 1e-15 of the coordinates), far below ``LEVEL_TOL``
BOUND_SLACK = 1e-9
#: cutting-plane steps of that bound (each one box distance)
BOUND_CUTS = 2


@njit(inline="always", **_opts)
def _box_dip_bound(fa, sa, fc, sc, ea, span, r0, r1, r2, b0, b1, b2, g, level):
    """A lower bound m of the box ``g``'s signed distance along the rod segment ``r + eta b``,
    eta in [ea, ea + span] (span > 0), from its ends' distances ``fa``, ``fc`` m and slopes
    along the rod ``sa = n_a . b``, ``sc = n_c . b`` (n the ends' normals), or -inf once a point
    of the segment at or below ``level`` m is found (no bound above it). The distance is convex
    (the box is convex) and a point's normal is a subgradient of it (outside the box its
    gradient; inside the normal of a nearest face, whose plane's signed distance is below the
    box's everywhere), so it lies above every tangent line: where an end's slope leads away from
    the box the minimum is at that end; else it lies between a point of negative and one of
    positive slope, above the upper envelope of their two lines, whose least value is the bound.
    While the bound is not above ``level``, up to :data:`BOUND_CUTS` times the distance at that
    least point replaces the bracket's end on its side (a cutting-plane step)."""
    if sa >= 0.0:
        return fa
    if sc <= 0.0:
        return fc
    ul, fl, sl, ur, fr, sr = 0.0, fa, sa, span, fc, sc
    bound = -math.inf
    for it in range(BOUND_CUTS + 1):
        u = min(max((fl - fr + sr * ur - sl * ul) / (sr - sl), ul), ur)
        bound = max(fl + sl * (u - ul), fr + sr * (u - ur))
        if bound > level or it == BOUND_CUTS:
            break
        e = ea + u
        fm, n0, n1, n2 = _box_closest(r0 + e * b0, r1 + e * b1, r2 + e * b2, g)
        if fm <= level:
            return -math.inf
        sm = n0 * b0 + n1 * b1 + n2 * b2
        if sm >= 0.0:
            ur, fr, sr = u, fm, sm
        else:
            ul, fl, sl = u, fm, sm
    return bound


@njit(inline="always", **_opts)
def _box_face_bound(xa, ya, za, xc, yc, zc, g):
    """A lower bound m of the box ``g``'s signed distance along the segment from (xa, ya, za) to
    (xc, yc, zc) m: the largest, over the box's six faces, of the ends' lesser signed distance to
    the face's plane (outward positive). The box lies behind each face's plane and the distance
    to a plane is linear along the segment, so no point of it is nearer the box."""
    return _box_face_bound_at(xa, ya, za, xc, yc, zc, g[1], g[2], g[3], g[4], g[5], g[6], g[7], g[8])


@njit(inline="always", **_opts)
def _box_face_bound_at(xa, ya, za, xc, yc, zc, x, y, z, hx, hy, hz, c, s):
    """:func:`_box_face_bound` of the box of centre (x, y, z) m, half sizes (hx, hy, hz) m and yaw
    cosine and sine (c, s)."""
    dxa, dya, dxc, dyc = xa - x, ya - y, xc - x, yc - y
    la0, lc0 = c * dxa + s * dya, c * dxc + s * dyc
    la1, lc1 = -s * dxa + c * dya, -s * dxc + c * dyc
    la2, lc2 = za - z, zc - z
    b0 = max(min(la0, lc0), -max(la0, lc0)) - hx
    b1 = max(min(la1, lc1), -max(la1, lc1)) - hy
    b2 = max(min(la2, lc2), -max(la2, lc2)) - hz
    return max(b0, b1, b2)


@njit(inline="always", **_opts)
def _box_passed_over(fa, na0, na1, na2, fc, nc0, nc1, nc2, ea, span, r0, r1, r2, b0, b1, b2, g, radius):
    """Whether no interior point of the rod can touch the box ``g``: by :func:`_box_dip_bound`
    (the ends' distances m and unit normals), no point of it is deeper than both ends by
    ``LEVEL_TOL`` and below ``min(radius, fa, fc)``, so the box search would release the
    interior slot."""
    level = min(radius, min(fa, fc) - LEVEL_TOL) + BOUND_SLACK
    return span > 0.0 and _box_dip_bound(fa, na0 * b0 + na1 * b1 + na2 * b2, fc, nc0 * b0 + nc1 * b1 + nc2 * b2,
                                         ea, span, r0, r1, r2, b0, b1, b2, g, level) > level


@njit(inline="always", **_opts)
def boxes_between(geom, f0, f1):
    """True when features f0 .. f1 - 1 (at least one) of every copy's terrain ``geom`` (G, F, 10)
    are boxes."""
    if f1 <= f0:
        return False
    for c in range(geom.shape[0]):
        for f in range(f0, f1):
            if geom[c, f, 0] != BOX:
                return False
    return True


#: rows of a box's lane parameters ``BP[b]`` (:func:`box_load`): centre, half sizes, yaw cosine and
#: sine (0..7), then the contact parameters radius .. cmax (8..15)
BOX_LANE_ROWS = 16
#: rows of a rod's ends in the boxes' lane scratch ``BT[j]`` (:func:`box_lanes_forces`): far (0), then
#: per end its signed distance m, unit normal and normal velocity m/s (1..5: node a, 6..10: node c)
BOX_END_ROWS = 11


@njit(inline="always", **_opts)
def box_load(anchor, active, BAN, BAC, BP, geom, prm, c0, ne, k, f0, E):
    """Lanes 0..E-1 of the boxes' lane scratch take, for box b = feature f0 + b of copies
    c0..c0+ne-1 (pad lanes repeat copy c0), its node slots' anchors and active flags (BAN (nb, 2 k,
    3, E), BAC (nb, 2 k, E), :func:`slots_load`) and its geometry and contact parameters (BP (nb,
    :data:`BOX_LANE_ROWS`, E)), constant over a call."""
    F = geom.shape[1]
    for b in range(BP.shape[0]):
        f = f0 + b
        slots_load(anchor, active, BAN[b], BAC[b], c0, ne, k, F, f, E)
        for e in range(E):
            c = c0 + e if e < ne else c0
            gr = c if geom.shape[0] > 1 else 0
            pc = c if prm.shape[0] > 1 else 0
            for i in range(8):
                BP[b, i, e] = geom[gr, f, 1 + i]
                BP[b, 8 + i, e] = prm[pc, f, i]


@njit(inline="always", **_opts)
def box_store(anchor, eta0, active, slip, BAN, BAC, BSL, eta, c0, ne, k, F, f0):
    """Copies c0..c0+ne-1 take their lanes' node slots of the boxes f0, f0 + 1, ..
    (:func:`slots_store`)."""
    for b in range(BAN.shape[0]):
        slots_store(anchor, eta0, active, slip, BAN[b], BAC[b], BSL[b], eta, c0, ne, k, F, f0 + b)


@njit(inline="always", **_opts)
def _box_slots(Q, QD, EX, BAN, BAC, BSL, BP, BT, clr, eta, rod_a, rod_c, b, f, k, ne, E, fresh, linear):
    """The node slots of box b (feature f) of :func:`box_lanes_forces`, lanes innermost: per rod the
    far test (:func:`_box_face_bound`; at the call's first sub-step the box's clearance in ``clr``),
    then each end's distance and normal (:func:`_box_closest`) and its slot's force law
    (:func:`_slot_force`) over the lanes into a stack tile T, from which the anchors, flags and
    forces go to the lane scratch and EX, and the ends' data to BT for the interior slots.
    ``linear``: every lane's force exponent is 1."""
    W = _TILE_LANES
    T = _stack_tile(14)      # row r of lane e at T[r W + e]
    for j in range(k):
        ea, ec = eta[j, 0], eta[j, 1]
        for e in range(E):
            r0, r1, r2, b0, b1, b2 = Q[j, 0, e], Q[j, 1, e], Q[j, 2, e], Q[j, 3, e], Q[j, 4, e], Q[j, 5, e]
            T[13 * W + e] = _box_face_bound_at(r0 + ea * b0, r1 + ea * b1, r2 + ea * b2, r0 + ec * b0,
                                               r1 + ec * b1, r2 + ec * b2, BP[b, 0, e], BP[b, 1, e], BP[b, 2, e],
                                               BP[b, 3, e], BP[b, 4, e], BP[b, 5, e], BP[b, 6, e], BP[b, 7, e])
        for e in range(E):
            BT[j, 0, e] = 1.0 if T[13 * W + e] >= BP[b, 8, e] + BOUND_SLACK else 0.0
        if fresh and clr.shape[0] > 0:
            for e in range(ne):
                clr[e, f] = min(clr[e, f], T[13 * W + e] - BP[b, 8, e] - BOUND_SLACK)
        for s in range(2):
            a = 2 * j + s
            h = eta[j, s]
            node = rod_a[j] if s == 0 else rod_c[j]
            for e in range(E):
                px, py, pz = _lane_point(Q, j, h, e)
                vx, vy, vz = _lane_point(QD, j, h, e)
                sd, nx, ny, nz = _box_closest_at(px, py, pz, BP[b, 0, e], BP[b, 1, e], BP[b, 2, e], BP[b, 3, e],
                                                 BP[b, 4, e], BP[b, 5, e], BP[b, 6, e], BP[b, 7, e])
                (touch, T[e], T[W + e], T[2 * W + e], T[3 * W + e], T[4 * W + e], T[5 * W + e], slip, en,
                 fn) = _slot_force(
                    px, py, pz, px, py, pz, vx, vy, vz, sd, nx, ny, nz, 1.0,
                    BAN[b, a, 0, e], BAN[b, a, 1, e], BAN[b, a, 2, e], BAC[b, a, e], BP[b, 8, e], BP[b, 9, e],
                    BP[b, 10, e], 1.0 if linear else BP[b, 11, e], BP[b, 12, e], BP[b, 13, e], BP[b, 14, e],
                    BP[b, 15, e])
                T[6 * W + e] = 1.0 if touch else 0.0
                T[7 * W + e] = 1.0 if slip else 0.0
                T[8 * W + e], T[9 * W + e], T[10 * W + e], T[11 * W + e] = sd, nx, ny, nz
                T[12 * W + e] = vx * nx + vy * ny + vz * nz
            _tile_slot_store(T, BAN[b], BAC[b], BSL[b], EX, a, node, E)
            for i in range(5):
                for e in range(E):
                    BT[j, 1 + 5 * s + i, e] = T[(8 + i) * W + e]


# compiled once on its own and called once per SIMD block and physics step, as hf_lanes_forces (inlined,
# it would be compiled into every terrain instance of the loop driver); without reference counting
@njit(_nrt=False, **_opts)
def box_lanes_forces(Q, QD, EX, QT, QDT, EXT, BAN, BAC, BSL, BP, BT, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0,
                     active, slip, info, clr, ref, fresh, c0, ne, k, n, f0, f1):
    """:func:`rows_forces` of features f0 .. f1 - 1, boxes in every copy (:func:`boxes_between`),
    of the loop driver's E lanes (copies c0 .. c0 + ne - 1; Q, QD (k, 6, E) m, m/s, forces added to
    EX (n, 3, E) N, or set where f0 = 0; ``QT``, ``QDT``, ``EXT`` their transposed views (E, k, 6),
    (E, n, 3)), without ``info``. The node slots run with the lanes innermost, so that they compile
    to SIMD code (:func:`_box_slots`; their state in the lane scratch BAN, BAC, BSL of
    :func:`box_load`, the boxes' parameters in BP; BT (k, :data:`BOX_END_ROWS`, E) scratch), the
    interior slots, which a rod needs only where it can touch deeper than both ends, one lane at a
    time in the copies' state, as rows_forces runs them. The boxes' clearance ``clr``, ``ref`` over
    the call's sub-steps as rows_forces keeps it; a box is passed over at a later sub-step where it
    is in every lane (one lane within reach: all lanes computed; a lane out of reach is then far,
    which releases what its pass-over leaves released). The same arithmetic in the same order on
    each lane as rows_forces (a slot clear of the box adds the law's zero force, which leaves EX's
    bits as they are), so the same bits."""
    E = Q.shape[2]
    F = geom.shape[1]
    H = hf[0]
    if f0 == 0:
        for p in range(n):
            for i in range(3):
                for e in range(E):
                    EX[p, i, e] = 0.0
    has_clr = clr.shape[0] > 0
    MV = _stack_tile(1)         # each lane's rod ends' move since the call's first sub-step
    if has_clr:
        for e in range(ne):
            MV[e] = _ends_moved(QT, e, eta, ref, fresh)
            if fresh:
                for f in range(f0, f1):
                    clr[e, f] = math.inf
    for f in range(f0, f1):
        b = f - f0
        if has_clr and not fresh:
            # out of reach since the call's first sub-step in every lane: passed over; a lane
            # within reach is computed at every sub-step after it in the call (rows_forces)
            skip = True
            for e in range(ne):
                if not (MV[e] + 1e-12 < clr[e, f]):
                    clr[e, f] = -math.inf
                    skip = False
            if skip:
                continue
        linear = True
        for e in range(E):
            if BP[b, 11, e] != 1.0:
                linear = False
        if linear:
            _box_slots(Q, QD, EX, BAN, BAC, BSL, BP, BT, clr, eta, rod_a, rod_c, b, f, k, ne, E, fresh, True)
        else:
            _box_slots(Q, QD, EX, BAN, BAC, BSL, BP, BT, clr, eta, rod_a, rod_c, b, f, k, ne, E, fresh, False)
        for e in range(ne):             # the interior slots, in the copies' state
            c = c0 + e
            for j in range(k):
                ea, ec = eta[j, 0], eta[j, 1]
                span = ec - ea
                em = 0.5 * (ea + ec)
                ci = 3 * (j * F + f) + 2
                r0, r1, r2, b0, b1, b2 = QT[e, j, 0], QT[e, j, 1], QT[e, j, 2], QT[e, j, 3], QT[e, j, 4], QT[e, j, 5]
                g = geom[c if geom.shape[0] > 1 else 0, f]
                radius = BP[b, 8, e]
                sd_a, na0, na1, na2, vn_a = BT[j, 1, e], BT[j, 2, e], BT[j, 3, e], BT[j, 4, e], BT[j, 5, e]
                sd_c, nc0, nc1, nc2, vn_c = BT[j, 6, e], BT[j, 7, e], BT[j, 8, e], BT[j, 9, e], BT[j, 10, e]
                if BT[j, 0, e] != 0.0 or _box_passed_over(sd_a, na0, na1, na2, sd_c, nc0, nc1, nc2, ea, span, r0, r1,
                                                          r2, b0, b1, b2, g, radius):
                    # no interior point touches: released as rows_forces releases it (the
                    # anchored point of a contact that ends here kept)
                    if active[c, ci]:
                        active[c, ci] = False
                    elif eta0[c, ci] != em:
                        eta0[c, ci] = em
                    if slip[c, ci]:
                        slip[c, ci] = False
                    continue
                e_in, use = _interior(ea, ec, r0, r1, r2, b0, b1, b2, g, H)
                sd, nx, ny, nz = math.inf, 0.0, 0.0, 1.0
                if use:
                    sd, nx, ny, nz = _box_closest(r0 + e_in * b0, r1 + e_in * b1, r2 + e_in * b2, g)
                _interior_force(c, ci, e, j, e_in, sd, nx, ny, nz, 1.0, (r0, r1, r2, b0, b1, b2, ea, ec, em), QDT,
                                EXT, (sd_a, na0, na1, na2, 1.0, vn_a, sd_c, nc0, nc1, nc2, 1.0, vn_c), radius,
                                prm[c if prm.shape[0] > 1 else 0, f], anchor, eta0, active, slip, info, rod_a, rod_c)
