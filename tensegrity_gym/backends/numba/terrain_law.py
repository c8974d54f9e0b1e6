"""The contact law of the numba terrain contact, shared by every terrain kind: the contact slots,
the Hunt-Crossley normal force and stick-slip Coulomb friction of a slot (:func:`_slot_force`), the
interior slot's force (:func:`_interior_force`) and the lane scratch of the node slots that the
loop driver's kinds share. SI units.

* contact slots: three per rod per feature, slot ``(j F + f) 3 + s``: s = 0 the rod's node a,
  s = 1 node c, s = 2 the interior point of the segment nearest a box or lowest over a
  heightfield (used only when it is strictly deeper than both ends, as when a rod lies across a box edge or a
  bump; a plane's nearest point is always an end, so its slot 2 never touches). ``anchor``
  (B, S, 3) m (a point on the feature's surface), ``eta0`` (B, S) m the rod coordinate of the
  material point the anchor holds (the slot's own eta for the node slots; for the interior
  slot the point where it touched or last slipped, so that friction holds the rod's material
  while the contact point moves along the rod; a slot that neither touches nor touched at the
  step before holds its own eta, the rod's middle for the interior slot), ``active`` /
  ``slip`` (B, S) bool.
* the interior slot's penetration is measured from the deeper node when that node touches:
  ``delta = min(radius, sd_a, sd_c) - sd``. It goes to 0 as the interior minimum merges with a
  node, so the contact energy is continuous there and the node's own contact is not counted
  twice. Its normal force ``fn w n`` acts at the interior point, and ``-fn w_node n_node`` at
  that node (the gradient of ``sd_node`` in delta): the normal springs are the gradient of
  ``sum U(delta)``. Its Hunt-Crossley damping acts on the rate of that delta (the interior
  point's ``w v.n`` less the node's), with the same pair of points, so it only dissipates; its
  friction acts at the interior point, capped at ``mu fn w``.
* ``info`` (B, S, 6) or (0, 0, 6): per slot the rod coordinate eta m of the contact point, its
  contact measure m (below; infinite, with the normal (0, 0, 1), where the far test finds the
  rod out of the feature's reach), the feature's outward unit normal there and the energy J of the
  slot's springs at the given state with the anchors before the update (the interior slot's
  normal spring on the delta above).
"""
from __future__ import annotations

import math

from numba import njit

from .layout import _TILE_LANES, _opts


@njit(inline="always", **_opts)
def _slot_force(px, py, pz, mx, my, mz, vx, vy, vz, sd, nx, ny, nz, w, ax, ay, az, was_active,
                radius, kn, dn, ex, mu, kt, ct, cmax):
    """Contact force (N) on the rod point p (its velocity v m/s) at the contact measure ``sd`` m
    (signed distance, a heightfield's vertical gap) from a feature with outward unit normal n,
    the measure's gradient ``w n`` (w = 1 but for a heightfield): penetration ``delta = radius -
    sd``, potential ``U = k delta^(e+1) / (e+1)``, Hunt-Crossley normal force ``fn w n`` with
    ``fn = k delta^e - min(k delta^e dn, cmax) w v.n >= 0`` (its spring part is ``-grad U``, its
    damping acts on the rate of delta), and a tangential spring ``kt`` (damper ``ct``) from the
    anchor (a surface point, set at touch-down to ``s = p - (sd / w) n``) to the rod's material
    point m that touched there (p itself for a node slot), projected on the tangent plane and
    capped at ``mu fn w`` (slip: the anchor follows to ``s + F_t / kt``).
    The interior slot passes as ``radius`` the level its penetration is measured from and as
    ``v`` its velocity relative to that level's end (see the kernel).
    Returns (touching, fx, fy, fz, ax, ay, az, slip, energy J of the springs with the anchor
    before the update, fn N)."""
    # written with selects only (every value computed, those of a slot that does not touch then
    # replaced by the no-contact ones), so that a loop of it over SIMD lanes compiles to SIMD code
    # (an early return made LLVM's cost model keep such a loop scalar); the numbers of a touching
    # slot are those of the law as written out with branches
    delta = radius - sd
    touch = delta > 0.0
    de = delta if ex == 1.0 else max(delta, 0.0) ** ex
    fs = kn * de
    cn = fs * dn
    cn = cmax if cn > cmax else cn
    vn = vx * nx + vy * ny + vz * nz
    fn = fs - cn * w * vn
    fn = 0.0 if fn < 0.0 else fn
    fw = fn * w
    sw = sd / w
    sx, sy, sz = px - sw * nx, py - sw * ny, pz - sw * nz
    bx = ax if was_active else sx
    by = ay if was_active else sy
    bz = az if was_active else sz
    x0 = (mx if was_active else px) - bx
    x1 = (my if was_active else py) - by
    x2 = (mz if was_active else pz) - bz
    xn = x0 * nx + x1 * ny + x2 * nz
    x0, x1, x2 = x0 - xn * nx, x1 - xn * ny, x2 - xn * nz
    energy = fs * delta / (ex + 1.0) + 0.5 * kt * (x0 * x0 + x1 * x1 + x2 * x2)
    fx = -kt * x0 - ct * (vx - vn * nx)
    fy = -kt * x1 - ct * (vy - vn * ny)
    fz = -kt * x2 - ct * (vz - vn * nz)
    nrm = math.sqrt(fx * fx + fy * fy + fz * fz)
    lim = mu * fw
    slip = nrm > lim
    sc = lim / nrm
    fx = fx * sc if slip else fx
    fy = fy * sc if slip else fy
    fz = fz * sc if slip else fz
    bx = sx + fx / kt if slip else bx
    by = sy + fy / kt if slip else by
    bz = sz + fz / kt if slip else bz
    return (touch, fx + fw * nx if touch else 0.0, fy + fw * ny if touch else 0.0, fz + fw * nz if touch else 0.0,
            bx if touch else ax, by if touch else ay, bz if touch else az, slip and touch, energy if touch else 0.0,
            fn if touch else 0.0)


# compiled on its own and called: inlined, with the contact arrays among its arguments, it made
# the boxes' kernel slower (steps at N = 16: 92-94 -> 97-102 us per env step); the call costs
# little beside the interior search before it
@njit(**_opts)
def _interior_force(c, ci, r, j, e, sd, nx, ny, nz, w, rod, QD, Wc, ends, radius, pr, anchor, eta0, active, slip,
                    info, rod_a, rod_c):
    """The interior slot ``ci`` of rod j of copy c (row r of ``QD`` (., k, 6) m/s and ``Wc``
    (., n, 3) N) at its point eta = ``e`` m (gap ``sd`` m, unit normal n, gradient length w; an
    infinite gap: no point): its force (:func:`_slot_force`, contact parameters ``pr``) on the
    rod's nodes, its contact state and ``info`` (when it has rows) updated. ``rod`` the tuple
    (r0, r1, r2, b0, b1, b2, ea, ec, em) of the rod's state and its nodes' and middle's eta m.
    The penetration is measured from the deeper node when that node touches, ``min(radius,
    sd_a, sd_c) - sd``: 0 when the interior minimum merges with a node (a continuous potential;
    no double count of the node's contact); ``ends`` the tuple (sd_a, na0, na1, na2, w_a, vn_a,
    sd_c, nc0, nc1, nc2, w_c, vn_c) of the nodes' gaps m, unit normals, gradient lengths and
    normal velocities m/s (a call with more than 30 arguments would not inline)."""
    r0, r1, r2, b0, b1, b2, ea, ec, em = rod
    sd_a, na0, na1, na2, w_a, vn_a, sd_c, nc0, nc1, nc2, w_c, vn_c = ends
    px, py, pz = r0 + e * b0, r1 + e * b1, r2 + e * b2
    vx = QD[r, j, 0] + e * QD[r, j, 3]
    vy = QD[r, j, 1] + e * QD[r, j, 4]
    vz = QD[r, j, 2] + e * QD[r, j, 5]
    level, end = radius, -1
    if sd_a < level:
        level, end = sd_a, 0
    if sd_c < level:
        level, end = sd_c, 1
    if end >= 0:
        # damping on the rate of that penetration, w v.n here less the node's w v.n (the
        # tangential part, so friction, is unchanged)
        vr = vn_a * (w_a / w) if end == 0 else vn_c * (w_c / w)
        vx, vy, vz = vx - vr * nx, vy - vr * ny, vz - vr * nz
    # the anchored material point: where the rod touched (the contact point moves along the rod;
    # friction holds the material, not the point)
    e0 = eta0[c, ci] if active[c, ci] else e
    touch, fx, fy, fz, ax, ay, az, sl, en, fn = _slot_force(
        px, py, pz, r0 + e0 * b0, r1 + e0 * b1, r2 + e0 * b2, vx, vy, vz, sd, nx, ny, nz, w,
        anchor[c, ci, 0], anchor[c, ci, 1], anchor[c, ci, 2], active[c, ci], level,
        pr[1], pr[2], pr[3], pr[4], pr[5], pr[6], pr[7])
    anchor[c, ci, 0], anchor[c, ci, 1], anchor[c, ci, 2] = ax, ay, az
    if touch or active[c, ci]:
        eta0[c, ci] = e if (sl or not active[c, ci]) else e0
    else:
        # neither touches nor touched: the rod's middle (where a search stopped does not matter)
        eta0[c, ci] = em
    active[c, ci] = touch
    slip[c, ci] = sl
    if info.shape[0] > 0:
        info[c, ci, 0], info[c, ci, 1] = e, sd
        info[c, ci, 2], info[c, ci, 3], info[c, ci, 4] = nx, ny, nz
        info[c, ci, 5] = en
    if touch:
        span = ec - ea
        wc = (e - ea) / span
        wa = (ec - e) / span
        na, nc = rod_a[j], rod_c[j]
        Wc[r, na, 0] += wa * fx
        Wc[r, na, 1] += wa * fy
        Wc[r, na, 2] += wa * fz
        Wc[r, nc, 0] += wc * fx
        Wc[r, nc, 1] += wc * fy
        Wc[r, nc, 2] += wc * fz
        if end >= 0:
            # the reaction: -fn w n of the node at that node (the gradient of the level sd_node
            # in the penetration min(...) - sd)
            if end == 0:
                fr = fn * w_a
                Wc[r, na, 0] -= fr * na0
                Wc[r, na, 1] -= fr * na1
                Wc[r, na, 2] -= fr * na2
            else:
                fr = fn * w_c
                Wc[r, nc, 0] -= fr * nc0
                Wc[r, nc, 1] -= fr * nc1
                Wc[r, nc, 2] -= fr * nc2


@njit(inline="always", **_opts)
def _ends_moved(Q, r, eta, ref, fresh):
    """The largest move m (1-norm, which bounds the move of every rod point) of the rod ends of row
    r of ``Q`` (., k, 6) from their points ``ref[r]`` (k, 2, 3) m; ``fresh``: the ends' points
    written there instead, 0 returned."""
    moved = 0.0
    for j in range(Q.shape[1]):
        for s in range(2):
            e = eta[j, s]
            p0, p1, p2 = Q[r, j, 0] + e * Q[r, j, 3], Q[r, j, 1] + e * Q[r, j, 4], Q[r, j, 2] + e * Q[r, j, 5]
            if fresh:
                ref[r, j, s, 0], ref[r, j, s, 1], ref[r, j, s, 2] = p0, p1, p2
            else:
                moved = max(moved, abs(p0 - ref[r, j, s, 0]) + abs(p1 - ref[r, j, s, 1]) + abs(p2 - ref[r, j, s, 2]))
    return moved


@njit(inline="always", **_opts)
def slots_load(anchor, active, AN, AC, c0, ne, k, F, f, E):
    """Lanes 0..E-1 of a lane scratch take the node slots' anchors AN (2 k, 3, E) m and active
    flags AC (2 k, E) of feature f of copies c0..c0+ne-1 (pad lanes repeat copy c0; node slot
    2 j + s is the contact slot 3 (j F + f) + s of F features)."""
    for e in range(E):
        src = c0 + e if e < ne else c0
        for j in range(k):
            for s in range(2):
                ci = 3 * (j * F + f) + s
                AN[2 * j + s, 0, e] = anchor[src, ci, 0]
                AN[2 * j + s, 1, e] = anchor[src, ci, 1]
                AN[2 * j + s, 2, e] = anchor[src, ci, 2]
                AC[2 * j + s, e] = active[src, ci]


@njit(inline="always", **_opts)
def slots_store(anchor, eta0, active, slip, AN, AC, SL, eta, c0, ne, k, F, f):
    """Copies c0..c0+ne-1 take their lanes' node slots of feature f (anchors, active and slip
    flags; their anchored point is the node's own, ``eta0`` its eta; F features)."""
    for e in range(ne):
        for j in range(k):
            for s in range(2):
                ci = 3 * (j * F + f) + s
                anchor[c0 + e, ci, 0] = AN[2 * j + s, 0, e]
                anchor[c0 + e, ci, 1] = AN[2 * j + s, 1, e]
                anchor[c0 + e, ci, 2] = AN[2 * j + s, 2, e]
                active[c0 + e, ci] = AC[2 * j + s, e]
                slip[c0 + e, ci] = SL[2 * j + s, e]
                eta0[c0 + e, ci] = eta[j, s]


@njit(inline="always", **_opts)
def add_ext(EX, ext, c0, ne, n, E):
    """Lanes 0..E-1 of EX (n, 3, E) N gain the external force ``ext`` (0, 1 or B rows of
    (n, 3)) N of their copies (pad lanes: copy c0's)."""
    if ext.shape[0] > 0:
        for e in range(E):
            r = (c0 + e if e < ne else c0) if ext.shape[0] > 1 else 0
            for p in range(n):
                for i in range(3):
                    EX[p, i, e] += ext[r, p, i]


@njit(inline="always", **_opts)
def _lane_point(Q, j, h, e):
    """The point at rod coordinate ``h`` m of rod j in lane e of Q (k, 6, E) m (of QD: its
    velocity, m/s)."""
    return Q[j, 0, e] + h * Q[j, 3, e], Q[j, 1, e] + h * Q[j, 4, e], Q[j, 2, e] + h * Q[j, 5, e]


@njit(inline="always", **_opts)
def _tile_slot_store(T, AN, AC, SL, EX, a, node, E):
    """A node slot's law over E lanes, rows 0-7 of the stack tile T (row r of lane e at
    ``T[r W + e]``, W = ``_TILE_LANES``: the force N, the anchor m, the touching and slipping
    flags), into the lane scratch at slot a (AN (., 3, E) m, AC, SL (., E)), its force added to
    EX[node] (n, 3, E) N."""
    W = _TILE_LANES
    for e in range(E):
        AN[a, 0, e] = T[3 * W + e]
        AN[a, 1, e] = T[4 * W + e]
        AN[a, 2, e] = T[5 * W + e]
        AC[a, e] = T[6 * W + e] != 0.0
        SL[a, e] = T[7 * W + e] != 0.0
    for e in range(E):
        EX[node, 0, e] += T[e]
        EX[node, 1, e] += T[W + e]
        EX[node, 2, e] += T[2 * W + e]
