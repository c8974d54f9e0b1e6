"""Terrain contact on the numba backend: the rod capsules (segments between a rod's nodes,
swept by a sphere of the cap radius) against a sloped plane, boxes and a heightfield, with the
Hunt-Crossley normal force and stick-slip Coulomb friction of the ground contact. SI units.

Arrays (built by :mod:`tensegrity_gym.physics.terrain`):

* ``geom`` (G, F, 10), G = 1 (shared) or B (one terrain per copy): feature f's kind in
  column 0 (:data:`PLANE` = 0: outward normal (1:4) and offset (4), the solid is
  ``n.p <= offset``; :data:`BOX` = 1: centre (1:4) m, half sizes (4:7) m, cos and sin of the
  yaw (7:9); :data:`HFIELD` = 2: grid origin x0, y0 (1:3) m, cell size (3) m, grid rows ny
  and columns nx (4:6), ``sqrt(1 + L^2)`` (6) for L the steepest slope of its heights (the
  "too far to touch" bound; 0: computed from ``hf`` at each call), the rest 0).
* ``hf`` (H, ny, nx), H = 1 (shared) or B: the heightfield's heights m, ``hf[., j, i]`` at
  ``x = x0 + i cell``, ``y = y0 + j cell``, bilinear in between, the edge values held outside
  the grid (:meth:`tensegrity_gym.core.terrain.Heightfield.gap` is the NumPy oracle). At most
  one heightfield per terrain; without one, a (1, 1, 1) array that nothing reads.
* ``prm`` (P, F, 8), P = 1 or B: per feature the contact parameters ``radius`` m, ``kn``
  N/m^e, ``dn`` s/m, exponent ``e``, ``mu``, ``kt`` N/m, ``ct`` N s/m, ``cmax`` N s/m.
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

from .heightfield import (LEVEL_TOL, hf_blend, hf_cell, hf_flat_under, hf_grid, hf_lipschitz, hf_lowest,
                          hf_monotone, hf_patch)
from .layout import _TILE_LANES, _opts, _stack_tile

#: feature kinds (column 0 of ``geom``)
PLANE = 0.0
BOX = 1.0
HFIELD = 2.0
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
def _closest(px, py, pz, g, H):
    """Contact measure of a point against the feature ``g`` (plane, box or heightfield with
    heights ``H``): (gap m, outward unit normal, w) with the measure's gradient ``w n``: the
    signed distance (w = 1) for a plane or a box, the vertical gap for a heightfield."""
    if g[0] == PLANE:
        return g[1] * px + g[2] * py + g[3] * pz - g[4], g[1], g[2], g[3], 1.0
    if g[0] == HFIELD:
        return _hf_closest(px, py, pz, g, H)
    d, n0, n1, n2 = _box_closest(px, py, pz, g)
    return d, n0, n1, n2, 1.0


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
def hf_bound_of(geom_row, H):
    """``sqrt(1 + L^2)`` of the heightfield among the features ``geom_row`` (F, 10) with heights
    ``H`` (its column 6, else one pass over the heights: :func:`hf_lipschitz`); 1 without one."""
    for f in range(geom_row.shape[0]):
        g = geom_row[f]
        if g[0] == HFIELD:
            return g[6] if g[6] >= 1.0 else hf_lipschitz(g, H)
    return 1.0


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
def plane_first(geom):
    """True when feature 0 of every copy's terrain ``geom`` (G, F, 10) is a plane."""
    if geom.shape[1] == 0:
        return False
    for c in range(geom.shape[0]):
        if geom[c, 0, 0] != PLANE:
            return False
    return True


@njit(inline="always", **_opts)
def has_box(geom):
    """True when some copy's terrain ``geom`` (G, F, 10) has a box."""
    for c in range(geom.shape[0]):
        for f in range(geom.shape[1]):
            if geom[c, f, 0] == BOX:
                return True
    return False


@njit(inline="always", **_opts)
def plane_only(geom):
    """True when every copy's terrain ``geom`` (G, F, 10) is one plane and nothing else."""
    return geom.shape[1] == 1 and plane_first(geom)


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
def plane_load(anchor, eta0, active, AN, AC, PP, eta, geom, prm, c0, ne, k, F, E):
    """Lanes 0..E-1 of the plane scratch take the node slots of feature 0, a plane, of copies
    c0..c0+ne-1 (:func:`slots_load`), and PP (12, E) the plane's row (normal, offset: rows 0..3)
    and contact parameters (radius .. cmax: rows 4..11) of each lane, constant over a call; the
    interior slots of that feature, which never touch a plane, are released as
    :func:`rows_forces` releases them (the anchored point kept if it was active), once per
    call: every step would do the same."""
    slots_load(anchor, active, AN, AC, c0, ne, k, F, 0, E)
    for e in range(E):
        c = c0 + e if e < ne else c0
        gr = c if geom.shape[0] > 1 else 0
        pc = c if prm.shape[0] > 1 else 0
        for i in range(4):
            PP[i, e] = geom[gr, 0, 1 + i]
        for i in range(8):
            PP[4 + i, e] = prm[pc, 0, i]
    for e in range(ne):
        for j in range(k):
            ci = 3 * j * F + 2
            if not active[c0 + e, ci]:
                eta0[c0 + e, ci] = 0.5 * (eta[j, 0] + eta[j, 1])
            active[c0 + e, ci] = False


@njit(inline="always", **_opts)
def plane_store(anchor, eta0, active, slip, AN, AC, SL, eta, c0, ne, k, F):
    """Copies c0..c0+ne-1 take their lanes' node slots of feature 0 (:func:`slots_store`) and no
    slip at its interior slots."""
    slots_store(anchor, eta0, active, slip, AN, AC, SL, eta, c0, ne, k, F, 0)
    for e in range(ne):
        for j in range(k):
            slip[c0 + e, 3 * j * F + 2] = False


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


@njit(inline="always", **_opts)
def plane_forces(Q, QD, EX, AN, AC, SL, PP, eta, rod_a, rod_c, k, n, E):
    """:func:`rows_forces` of E lanes of the loop driver for feature 0 of the terrain, a plane
    (:func:`plane_first`), read in the lanes (Q, QD (k, 6, E) m, m/s), into EX (n, 3, E) N; the
    node slots' state and each lane's plane and contact parameters PP in the lane scratch of
    :func:`plane_load`. The same force law (:func:`_slot_force`) on the same numbers in the
    same order, so the same bits, without what a plane never needs (the transposed copy of the
    state, the far test, the interior slot: a plane's nearest point of a rod is an end, and a
    node slot's force goes to its own node whole). The lanes are the innermost loop, so that the
    law compiles to SIMD code over them (a slot clear of the plane adds the law's zero force,
    which leaves EX's bits as they are: EX starts at +0 and a sum is never -0); with a force
    exponent other than 1 in some lane the same loop runs with the exponent read per lane.
    The loop driver's plane instances call it (their step loop carries no code for boxes or
    heights: a branch to it, never taken, made the step of a plane 1.5 times slower at one
    copy), and its general terrain instance for a terrain whose feature 0 is a plane (the
    ground under steps and walls), before :func:`lanes_forces` adds the other features."""
    for p in range(n):
        for i in range(3):
            for e in range(E):
                EX[p, i, e] = 0.0
    linear = True
    for e in range(E):
        if PP[7, e] != 1.0:
            linear = False
    if E == 1:
        _plane_slots(Q, QD, EX, AN, AC, SL, PP, eta, rod_a, rod_c, k, E, False, True)
    elif linear:
        _plane_slots(Q, QD, EX, AN, AC, SL, PP, eta, rod_a, rod_c, k, E, True, False)
    else:
        _plane_slots(Q, QD, EX, AN, AC, SL, PP, eta, rod_a, rod_c, k, E, False, False)


@njit(inline="always", **_opts)
def _plane_slots(Q, QD, EX, AN, AC, SL, PP, eta, rod_a, rod_c, k, E, linear, skip):
    """The node slots' forces of :func:`plane_forces`, lanes innermost: the law of each slot
    over the lanes into a stack tile T (:func:`.layout._stack_tile`: written there, the loop
    compiles to SIMD code), then its anchors, flags and forces from T into the lane scratch.
    ``linear``: every lane's force exponent is 1 (the law's power then compiles away, and with
    it the one call that keeps the loop scalar). ``skip`` (one lane, scalar code): a slot clear
    of the plane takes the law's no-contact values without computing the law (its sqrt and
    divisions), as :func:`rows_forces` does; the same numbers."""
    T = _stack_tile(8)      # row r of lane e at T[r W + e]
    W = _TILE_LANES
    for j in range(k):
        for s in range(2):
            ci = 2 * j + s
            h = eta[j, s]
            node = rod_a[j] if s == 0 else rod_c[j]
            for e in range(E):
                px, py, pz = _lane_point(Q, j, h, e)
                vx, vy, vz = _lane_point(QD, j, h, e)
                g1, g2, g3, g4 = PP[0, e], PP[1, e], PP[2, e], PP[3, e]
                sd = g1 * px + g2 * py + g3 * pz - g4
                if skip and not (PP[4, e] - sd > 0.0):
                    for i in range(8):
                        T[i * W + e] = 0.0
                    T[3 * W + e], T[4 * W + e], T[5 * W + e] = AN[ci, 0, e], AN[ci, 1, e], AN[ci, 2, e]
                    continue
                (touch, T[e], T[W + e], T[2 * W + e], T[3 * W + e], T[4 * W + e], T[5 * W + e], slip, en,
                 fn) = _slot_force(
                    px, py, pz, px, py, pz, vx, vy, vz, sd, g1, g2, g3, 1.0,
                    AN[ci, 0, e], AN[ci, 1, e], AN[ci, 2, e], AC[ci, e], PP[4, e], PP[5, e], PP[6, e],
                    1.0 if linear else PP[7, e], PP[8, e], PP[9, e], PP[10, e], PP[11, e])
                T[6 * W + e] = 1.0 if touch else 0.0
                T[7 * W + e] = 1.0 if slip else 0.0
            _tile_slot_store(T, AN, AC, SL, EX, ci, node, E)


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
