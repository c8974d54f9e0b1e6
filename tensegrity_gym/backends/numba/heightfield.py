"""Heightfield geometry of the numba terrain contact (:mod:`tensegrity_gym.backends.numba.terrain`):
the bilinear height and its gradient, the slope bound, the level-ground test and the lowest point
of a rod's axis above the surface. SI units: m.

Contact measure: the vertical gap ``gap(p) = z - h(x, y)`` of a point above the bilinear surface
h (continuous, bilinear per cell, the edge values held beyond the grid). Its gradient is the
unnormalised surface normal ``N = (-h_x, -h_y, 1)``, so a contact potential ``U(radius - gap)``
gives the force ``U' N`` exactly: a conservative normal force (the surface's kinks at the grid
lines make it piecewise smooth, not discontinuous).

Lowest point of a rod axis ``p(eta) = r + eta b``, eta in [ea, ec] (:func:`hf_lowest`): the
grid coordinates are linear in eta, so between consecutive crossings of grid lines (the
breakpoints, ends included) the point stays in one cell and the gap is a quadratic in eta
(the bilinear patch's ``fu fv`` term). Its minimum over the segment is at a breakpoint or at the
stationary point of a convex piece: the pieces are walked in order and the lowest candidate
kept (the first of equals); no sampling, the minimum is exact. A level run around it
(consecutive pieces within ``LEVEL_TOL`` of the minimum: a rod lying on a plateau) gives its
middle, so that such a rod is held under its middle. At a kink (the minimum on a grid line) the
gradient used is the combination of the two cells' gradients whose normal is perpendicular to
the rod (``N.b = 0``), the derivative of the minimum over eta (envelope theorem): a rod slides
over a kink without a push along itself.
The contact asks only for a minimum that can touch (below the slot's level, :func:`hf_lowest`'s
``cut``): a piece whose lower end is higher than its cell's highest grid height by the cut is
passed over, its gap not evaluated. A rod that rises faster than the surface can
(:func:`hf_monotone`) is not walked at all: its gap is monotone, lowest at an end.
"""
from __future__ import annotations

import math

from numba import njit

from .layout import _opts

#: the interior slot touches only where it is deeper than both ends by this much, m; it sits at the
#: middle of the level run of the rod within this distance of the deepest point (a rod lying flat on
#: a plateau rests on the middle of its part on the plateau, not on an arbitrary point of it)
LEVEL_TOL = 1e-7


@njit(inline="always", **_opts)
def hf_grid(g, H):
    """The rows ny and columns nx of the heightfield ``g`` (a geom row) with heights ``H``: the
    geom's grid shape, bounded by ``H``'s, so that no grid index leaves the array."""
    return min(int(g[4]), H.shape[0]), min(int(g[5]), H.shape[1])


@njit(inline="always", **_opts)
def hf_cell(rx, ry, x0, y0, cell, nxm, nym):
    """The grid cell of a reference point (rx, ry) m in a grid of origin (x0, y0) m, cell size
    ``cell`` m and last column and row indices ``nxm`` = nx - 1, ``nym`` = ny - 1 (floats): its
    column i and row j (integral floats, at most nx - 2 and ny - 2), the point's grid coordinates
    u, v clamped to the grid and 1.0 where it is beyond the grid along x, along y (else 0.0)."""
    ur = (rx - x0) / cell
    vr = (ry - y0) / cell
    out_u = 1.0 if (ur < 0.0 or ur > nxm) else 0.0
    out_v = 1.0 if (vr < 0.0 or vr > nym) else 0.0
    u = min(max(ur, 0.0), nxm)
    v = min(max(vr, 0.0), nym)
    return min(math.floor(u), nxm - 1.0), min(math.floor(v), nym - 1.0), u, v, out_u, out_v


@njit(inline="always", **_opts)
def hf_blend(fu, fv, out_u, out_v, h00, h10, h01, h11, cell):
    """Bilinear height m at the fractions (fu, fv) of a cell with corner heights h00 (i, j), h10
    (i + 1, j), h01 (i, j + 1), h11, and its gradient (dh/dx, dh/dy), 0 along an axis where the
    reference point is beyond the grid (``out_u``, ``out_v`` of :func:`hf_cell`)."""
    h = (1 - fu) * (1 - fv) * h00 + fu * (1 - fv) * h10 + (1 - fu) * fv * h01 + fu * fv * h11
    gx = 0.0 if out_u != 0.0 else ((1 - fv) * (h10 - h00) + fv * (h11 - h01)) / cell
    gy = 0.0 if out_v != 0.0 else ((1 - fu) * (h01 - h00) + fu * (h11 - h10)) / cell
    return h, gx, gy


@njit(inline="always", **_opts)
def hf_at(px, py, rx, ry, g, H):
    """Bilinear height (m) at (px, py) m of the cell holding the reference point (rx, ry), its
    gradient (dh/dx, dh/dy) and the cell's twist ``(h11 - h10 - h01 + h00) / cell^2`` (1/m);
    beyond the grid (at the reference point) the edge values are held: that gradient component
    and the twist are 0. Same arithmetic as ``Heightfield._interp`` with (rx, ry) = (px, py)."""
    ny, nx = hf_grid(g, H)
    nxm, nym = nx - 1.0, ny - 1.0
    fi, fj, _, _, out_u, out_v = hf_cell(rx, ry, g[1], g[2], g[3], nxm, nym)
    u = min(max((px - g[1]) / g[3], 0.0), nxm)
    v = min(max((py - g[2]) / g[3], 0.0), nym)
    i, j = int(fi), int(fj)
    h00, h10, h01, h11 = H[j, i], H[j, i + 1], H[j + 1, i], H[j + 1, i + 1]
    h, gx, gy = hf_blend(u - fi, v - fj, out_u, out_v, h00, h10, h01, h11, g[3])
    tw = 0.0 if (out_u != 0.0 or out_v != 0.0) else (h11 - h10 - h01 + h00) / (g[3] * g[3])
    return h, gx, gy, tw


@njit(inline="always", **_opts)
def hf_patch(px, py, g, H):
    """Bilinear height (m) of the heightfield ``g`` (a geom row), heights ``H`` (ny, nx), at
    (px, py) m and its gradient (dh/dx, dh/dy) (the cell under the point)."""
    h, gx, gy, _ = hf_at(px, py, px, py, g, H)
    return h, gx, gy


@njit(**_opts)
def hf_flat_under(xa, ya, xc, yc, g, H) -> bool:
    """True if every grid height that the bilinear surface uses under the segment from (xa, ya)
    to (xc, yc) m (the cells of its bounding box, clamped to the grid) is the same: the surface is
    level there, so a point inside the segment is never deeper than both ends (as for a plane)."""
    ny, nx = hf_grid(g, H)
    i0 = min(max(int(math.floor((min(xa, xc) - g[1]) / g[3])), 0), nx - 2)
    i1 = min(max(int(math.floor((max(xa, xc) - g[1]) / g[3])) + 1, 1), nx - 1)
    j0 = min(max(int(math.floor((min(ya, yc) - g[2]) / g[3])), 0), ny - 2)
    j1 = min(max(int(math.floor((max(ya, yc) - g[2]) / g[3])) + 1, 1), ny - 1)
    h = H[j0, i0]
    for j in range(j0, j1 + 1):
        for i in range(i0, i1 + 1):
            if H[j, i] != h:
                return False
    return True


@njit(**_opts)
def hf_lipschitz(g, H):
    """``sqrt(1 + L^2)``: a bound on the Lipschitz constant (along any unit line) of the vertical
    gap ``z - h(x, y)``, L = |(largest |step| along x, along y)| / cell bounding the slope (a
    bilinear patch's gradient is affine in the patch coordinates, so its steepest is at a corner,
    made of one x step and one y step of the grid)."""
    ny, nx = hf_grid(g, H)
    mx, my = 0.0, 0.0
    for j in range(ny):
        for i in range(nx):
            if i + 1 < nx:
                mx = max(mx, abs(H[j, i + 1] - H[j, i]))
            if j + 1 < ny:
                my = max(my, abs(H[j + 1, i] - H[j, i]))
    return math.sqrt(1.0 + (mx * mx + my * my) / (g[3] * g[3]))


@njit(inline="always", **_opts)
def hf_monotone(b0, b1, b2, lam) -> bool:
    """True if the vertical gap is monotone along the rod axis of direction ``b``: the axis rises
    (or falls) at least as fast as the surface can, ``|b_z| >= L |b_xy|`` with ``lam`` =
    ``sqrt(1 + L^2)`` (:func:`hf_lipschitz`; the bilinear gradient's x part is bounded by the
    largest x step over the cell, its y part by the largest y step, so ``|grad h| <= L``), with a
    margin of 1e-9 of L^2 for round-off. Such a rod's lowest point is an end: no interior point is
    deeper than both, and :func:`hf_lowest` need not walk it."""
    return b2 * b2 >= (lam * lam - 1.0) * (1.0 + 1e-9) * (b0 * b0 + b1 * b1)


@njit(inline="always", **_opts)
def hf_lines(a, c, n):
    """The grid lines 0..n-1 strictly between the grid coordinates a (at ea) and c (at ec), in
    the order the rod meets them: (first index, step +-1, count)."""
    if c > a:
        m0 = max(int(math.floor(a)) + 1, 0)
        return m0, 1, max(min(int(math.ceil(c)) - 1, n - 1) - m0 + 1, 0)
    if c < a:
        m0 = min(int(math.ceil(a)) - 1, n - 1)
        return m0, -1, max(m0 - max(int(math.floor(c)) + 1, 0) + 1, 0)
    return 0, 1, 0


@njit(inline="always", **_opts)
def hf_cross(m, origin, cell, r, b, ea, ec):
    """Rod coordinate (m) where the axis ``r + eta b`` (one horizontal component) meets grid line
    m (``origin + m cell``), held in [ea, ec] against round-off."""
    return min(max((origin + m * cell - r) / b, ea), ec)


@njit(inline="always", **_opts)
def _walk_start(ua, uc, va, vc, nx, ny, ea, ec, r0, r1, b0, b1, g):
    """The walk of a rod axis over the grid from grid coordinates (ua, va) at ea to (uc, vc) at
    ec: the grid lines it crosses (:func:`hf_lines` of x and y) and the walk's state before the
    first piece, ``(tx, ty, ex, ey, ci, cj)``: the x and y crossings passed, the next ones (inf
    after the last), and the cell of the piece (ci, cj: the cell the rod starts in, along its
    direction, -1 or n - 1 beyond the grid's first or last line; clamped to the grid when read)."""
    x_line, y_line = hf_lines(ua, uc, nx), hf_lines(va, vc, ny)
    mx0, sx, nxl = x_line
    my0, sy, nyl = y_line
    ex = hf_cross(mx0, g[1], g[3], r0, b0, ea, ec) if nxl > 0 else math.inf
    ey = hf_cross(my0, g[2], g[3], r1, b1, ea, ec) if nyl > 0 else math.inf
    ci = min(max(int(math.floor(ua)) if sx > 0 else int(math.ceil(ua)) - 1, -1), nx - 1)
    cj = min(max(int(math.floor(va)) if sy > 0 else int(math.ceil(va)) - 1, -1), ny - 1)
    return x_line, y_line, (0, 0, ex, ey, ci, cj)


@njit(inline="always", **_opts)
def _walk_next(state, x_line, y_line, ea, ec, r0, r1, b0, b1, g):
    """The walk's next breakpoint (the nearer crossing, x first of equals; ``ec`` after both)
    and its state there (:func:`_walk_start`): one further crossing, computed once."""
    tx, ty, ex, ey, ci, cj = state
    mx0, sx, nxl = x_line
    my0, sy, nyl = y_line
    if tx < nxl and (ty >= nyl or ex <= ey):
        hi, tx, ci = ex, tx + 1, ci + sx
        ex = hf_cross(mx0 + sx * tx, g[1], g[3], r0, b0, ea, ec) if tx < nxl else math.inf
    elif ty < nyl:
        hi, ty, cj = ey, ty + 1, cj + sy
        ey = hf_cross(my0 + sy * ty, g[2], g[3], r1, b1, ea, ec) if ty < nyl else math.inf
    else:
        hi = ec
    return hi, (tx, ty, ex, ey, ci, cj)


@njit(**_opts)
def hf_lowest(ea, ec, r0, r1, r2, b0, b1, b2, g, H, cut, ga, gc):
    """The interior contact point of the rod axis ``r + eta b``, eta in [ea, ec], against the
    heightfield ``g`` (heights ``H``): the lowest point of the gap (module doc), searched for
    below ``cut`` m: a piece whose every gap is at least ``cut`` (its lower end's height above the
    cell's highest grid height) is passed over, so the point returned is the lowest when its gap
    is below ``cut`` less ``LEVEL_TOL`` (``cut = inf``: always). Returns ``(eta, deeper, gx, gy)``:
    eta m (the middle of the rod when not deeper), deeper = the gap there is below both ends' by
    more than ``LEVEL_TOL``, and the gradient of h the slot's normal uses (the two cells'
    combination at a kink). ``ga``, ``gc``: the gaps (m) at the ends, ``r2 + e b2 - h`` with h the
    bilinear height (:func:`hf_patch`) at ``(r0 + e b0, r1 + e b1)``, e = ea, ec (the node slots'
    own, passed in rather than computed twice)."""
    ny, nx = hf_grid(g, H)
    em = 0.5 * (ea + ec)
    ua, uc = (r0 + ea * b0 - g[1]) / g[3], (r0 + ec * b0 - g[1]) / g[3]
    va, vc = (r1 + ea * b1 - g[2]) / g[3], (r1 + ec * b1 - g[2]) / g[3]
    x_line, y_line, start = _walk_start(ua, uc, va, vc, nx, ny, ea, ec, r0, r1, b0, b1, g)
    last = x_line[2] + y_line[2] + 1            # pieces: between ea, the crossings and ec
    # pass 1: the lowest candidate (breakpoint 2 k, stationary point of piece k 2 k + 1); a piece
    # passed over leaves the gap at its end unknown (inf: above every candidate that can win)
    lo = ea
    glo = ga
    fmin, cbest, ebest = glo, 0, ea
    gx, gy, gxr, gyr = 0.0, 0.0, 0.0, 0.0
    lvl_l, lvl_r, pend = False, False, False
    walk = start
    for k in range(last):
        i = min(max(walk[4], 0), nx - 2)          # the piece's cell
        j = min(max(walk[5], 0), ny - 2)
        hi, walk = _walk_next(walk, x_line, y_line, ea, ec, r0, r1, b0, b1, g)
        if k == last - 1:
            hi = ec
        if not (hi > lo):
            continue            # an empty piece (two grid lines met at once): the gap at hi is glo's
        mid = 0.5 * (lo + hi)
        mx, my = r0 + mid * b0, r1 + mid * b1
        if pend:           # the right-hand cell's gradient at the kink found at lo
            _, gxr, gyr, _ = hf_at(r0 + lo * b0, r1 + lo * b1, mx, my, g, H)
        if r2 + (lo if b2 >= 0.0 else hi) * b2 - max(max(H[j, i], H[j, i + 1]), max(H[j + 1, i], H[j + 1, i + 1])) >= cut:
            # the piece's lower end is above its cell's highest grid height by the cut
            lvl_r = lvl_r and not pend
            lo, glo, pend = hi, math.inf, False
            continue
        ghi = r2 + hi * b2 - hf_patch(r0 + hi * b0, r1 + hi * b1, g, H)[0]
        hm, gxm, gym, tw = hf_at(mx, my, mx, my, g, H)
        gmid = r2 + mid * b2 - hm
        if pend:
            lvl_r = max(glo, max(gmid, ghi)) <= fmin + LEVEL_TOL
            pend = False
        curv = -2.0 * tw * b0 * b1                        # d2 gap / d eta2 in this cell
        if curv > 0.0:
            s = mid - (b2 - gxm * b0 - gym * b1) / curv
            if lo < s < hi:
                hs, gxs, gys, _ = hf_at(r0 + s * b0, r1 + s * b1, mx, my, g, H)
                gs = r2 + s * b2 - hs
                if gs < fmin:
                    fmin, cbest, ebest, gx, gy = gs, 2 * k + 1, s, gxs, gys
                    lvl_l = max(glo, max(gmid, ghi)) <= fmin + LEVEL_TOL
                    lvl_r = lvl_l
        if ghi < fmin:
            _, gx, gy, _ = hf_at(r0 + hi * b0, r1 + hi * b1, mx, my, g, H)
            fmin, cbest, ebest = ghi, 2 * k + 2, hi
            lvl_l = max(glo, max(gmid, ghi)) <= fmin + LEVEL_TOL
            lvl_r, pend = False, True
        lo, glo = hi, ghi
    if not (fmin < min(ga, gc) - LEVEL_TOL):
        return em, False, 0.0, 0.0
    e = ebest
    if cbest % 2 == 0:
        # a kink: the combination of the two cells' normals perpendicular to the rod
        dl = b2 - gx * b0 - gy * b1
        dr = b2 - gxr * b0 - gyr * b1
        lam = min(max(-dl / (dr - dl), 0.0), 1.0) if dr > dl else 0.5
        gx, gy = gx + lam * (gxr - gx), gy + lam * (gyr - gy)
    if lvl_l or lvl_r:
        left, right = _level_run(cbest, fmin, ea, ec, r0, r1, r2, b0, b1, b2, g, H, x_line, y_line, start, last, ga)
        e = 0.5 * (left + right)
        if left < right:
            _, gx, gy = hf_patch(r0 + e * b0, r1 + e * b1, g, H)
    return e, True, gx, gy


@njit(**_opts)
def _level_run(cbest, fmin, ea, ec, r0, r1, r2, b0, b1, b2, g, H, x_line, y_line, walk, last, ga):
    """Ends (m) of the level run around candidate ``cbest`` of :func:`hf_lowest`: the consecutive
    pieces whose ends and middle are within ``LEVEL_TOL`` of ``fmin``, those left of it (pieces
    < cbest // 2) and right of it (pieces >= (cbest + 1) // 2). ``walk``: the walk's start
    (:func:`_walk_start`), ``ga`` the gap at ea."""
    il, ir = cbest // 2, (cbest + 1) // 2
    left, right = ea, ec
    lo = ea
    glo = ga
    for k in range(last):
        hi, walk = _walk_next(walk, x_line, y_line, ea, ec, r0, r1, b0, b1, g)
        if k == last - 1:
            hi = ec
        ghi = r2 + hi * b2 - hf_patch(r0 + hi * b0, r1 + hi * b1, g, H)[0]
        mid = 0.5 * (lo + hi)
        gmid = r2 + mid * b2 - hf_patch(r0 + mid * b0, r1 + mid * b1, g, H)[0]
        level = max(glo, max(gmid, ghi)) <= fmin + LEVEL_TOL
        if not level:
            if k < il:
                left = hi
            elif k >= ir:
                right = lo
                break
        lo, glo = hi, ghi
    return left, right
