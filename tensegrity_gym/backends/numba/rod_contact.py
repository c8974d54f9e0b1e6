"""Rod-rod contact on the numba backend: the closest points of two rod segments
(:func:`closest_params`, parallel segments included), the force between two capsules
(:func:`_pair_force`), every rod pair of E SIMD lanes (:func:`rods_lanes`, what the loop driver
adds to its per-step external forces) and the batch kernel :func:`rod_forces_kernel` (adds the
forces of a batch into its nodal forces, no step). The law: ``tensegrity_gym.physics.rod_contact``
(NumPy reference ``tests/oracle_numpy.rod_contact_forces``). SI units.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .layout import _opts

#: the columns of a rod contact parameter row (``RodContact.prm``)
ROD_COLUMNS = ("radius", "stiffness", "damping", "friction", "max_damping", "friction_speed")

#: segments whose ``sin^2`` of the angle between them is below this are treated as parallel
PARALLEL_SIN2 = 1e-12


@njit(inline="always", **_opts)
def _clamp01(x):
    return 0.0 if x < 0.0 else (1.0 if x > 1.0 else x)


@njit(inline="always", **_opts)
def closest_params(d1x, d1y, d1z, d2x, d2y, d2z, rx, ry, rz):
    """The parameters ``(s, t)`` in [0, 1] of the closest points ``P1 + s d1`` and ``P2 + t d2``
    of two segments of nonzero lengths (``r = P1 - P2``, m). Non-parallel segments: the closest
    points of the two lines clamped to the segments and corrected once each way (Ericson,
    Real-Time Collision Detection 5.1.9, exact for segments). Parallel segments (``sin^2`` of
    their angle below :data:`PARALLEL_SIN2`): the middle of the overlap of their projections on
    the first one (so that two rods lying side by side touch at the middle of their common
    length, not at one end), or the nearest ends where they do not overlap."""
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    b = d1x * d2x + d1y * d2y + d1z * d2z
    c = d1x * rx + d1y * ry + d1z * rz
    f = d2x * rx + d2y * ry + d2z * rz
    denom = a * e - b * b
    if denom > PARALLEL_SIN2 * a * e:
        s = _clamp01((b * f - c * e) / denom)
    else:
        # P2 and P2 + d2 projected on the first segment's parameter
        s0 = -c / a
        s1 = s0 + b / a
        lo = s0 if s0 < s1 else s1
        hi = s1 if s0 < s1 else s0
        lo = 0.0 if lo < 0.0 else lo
        hi = 1.0 if hi > 1.0 else hi
        if lo <= hi:
            s = 0.5 * (lo + hi)
        else:       # no overlap: the end of the first segment nearest to the second
            s = 0.0 if hi < 0.0 else 1.0
    t = (b * s + f) / e
    if t < 0.0:
        t = 0.0
        s = _clamp01(-c / a)
    elif t > 1.0:
        t = 1.0
        s = _clamp01((b - c) / a)
    return s, t


@njit(inline="always", **_opts)
def _pair_force(a1x, a1y, a1z, c1x, c1y, c1z, va1x, va1y, va1z, vc1x, vc1y, vc1z,
                a2x, a2y, a2z, c2x, c2y, c2z, va2x, va2y, va2z, vc2x, vc2y, vc2z,
                gx, gy, gz, reach, law):
    """The contact force between rod 1 (nodes a1, c1 m, their velocities va1, vc1 m/s) and rod 2
    (a2, c2, va2, vc2), capsules of radius ``radius`` m. ``g`` = centre of rod 1 minus centre of
    rod 2 (m) and ``reach`` (m) the largest centre distance at which they can touch (a cheap
    rejection before the closest points); ``law`` the tuple (radius, kn, dn, mu, cmax, veps) of
    the row :data:`ROD_COLUMNS` (a tuple: a call of more than 30 arguments compiles to a
    ``*args`` call, which numba cannot inline). Returns ``(touch, s, t, fx, fy, fz)``: the force (N)
    on rod 1 at its parameter ``s`` (rod 2 takes the opposite at ``t``). Normal force
    ``max(0, kn delta + min(dn, cmax) delta')`` along the line of the closest points (delta the
    overlap ``2 radius - distance``); friction ``-min(mu F_n / max(|v_t|, veps), cmax) v_t``
    against the tangential relative velocity ``v_t`` of the closest points."""
    radius, kn, dn, mu, cmax, veps = law
    if gx * gx + gy * gy + gz * gz > reach * reach:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    d1x, d1y, d1z = c1x - a1x, c1y - a1y, c1z - a1z
    d2x, d2y, d2z = c2x - a2x, c2y - a2y, c2z - a2z
    s, t = closest_params(d1x, d1y, d1z, d2x, d2y, d2z, a1x - a2x, a1y - a2y, a1z - a2z)
    nx = (a1x + s * d1x) - (a2x + t * d2x)
    ny = (a1y + s * d1y) - (a2y + t * d2y)
    nz = (a1z + s * d1z) - (a2z + t * d2z)
    dist = math.sqrt(nx * nx + ny * ny + nz * nz)
    delta = 2.0 * radius - dist
    if not (delta > 0.0):
        return False, s, t, 0.0, 0.0, 0.0
    if dist > 1e-12:
        nx, ny, nz = nx / dist, ny / dist, nz / dist
    else:
        # the axes meet: the normal of the plane of the two axes, pointing from rod 2's centre to
        # rod 1's (any perpendicular of rod 1 where the axes are parallel too)
        nx = d1y * d2z - d1z * d2y
        ny = d1z * d2x - d1x * d2z
        nz = d1x * d2y - d1y * d2x
        nn = math.sqrt(nx * nx + ny * ny + nz * nz)
        if not (nn > 1e-12 * math.sqrt((d1x * d1x + d1y * d1y + d1z * d1z) * (d2x * d2x + d2y * d2y + d2z * d2z))):
            # d1 x e_z, or d1 x e_x for a vertical rod
            nx, ny, nz = d1y, -d1x, 0.0
            if nx * nx + ny * ny < 1e-6 * (d1x * d1x + d1y * d1y + d1z * d1z):
                nx, ny, nz = 0.0, d1z, -d1y
            nn = math.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / nn, ny / nn, nz / nn
        if nx * gx + ny * gy + nz * gz < 0.0:
            nx, ny, nz = -nx, -ny, -nz
    # relative velocity of the closest points (material points of rod 1 at s, rod 2 at t)
    vx = (va1x + s * (vc1x - va1x)) - (va2x + t * (vc2x - va2x))
    vy = (va1y + s * (vc1y - va1y)) - (va2y + t * (vc2y - va2y))
    vz = (va1z + s * (vc1z - va1z)) - (va2z + t * (vc2z - va2z))
    vn = vx * nx + vy * ny + vz * nz          # separation rate, m/s: delta' = -vn
    cn = dn if dn < cmax else cmax
    fn = kn * delta - cn * vn
    if fn < 0.0:
        fn = 0.0
    fx, fy, fz = fn * nx, fn * ny, fn * nz
    if mu > 0.0:
        tx, ty, tz = vx - vn * nx, vy - vn * ny, vz - vn * nz
        vt = math.sqrt(tx * tx + ty * ty + tz * tz)
        ct = mu * fn / (vt if vt > veps else veps)
        if ct > cmax:
            ct = cmax
        fx -= ct * tx
        fy -= ct * ty
        fz -= ct * tz
    return True, s, t, fx, fy, fz


@njit(inline="always", **_opts)
def rods_lanes(Q, QD, EX, eta, rod_a, rod_c, prm, k, E):
    """Adds the rod-rod contact forces of E lanes into EX (n, 3, E) N from the rods' state
    Q, QD (k, 6, E) (m, m/s): every pair i < j through :func:`_pair_force`, the force at a
    closest point split between the rod's nodes by its parameter (``1 - s`` to node a, ``s``
    to node c: the exact generalized force, the nodes being linear in the state). ``prm`` (1, 6)
    the row of :data:`ROD_COLUMNS`. The one loop over rod pairs: the driver runs it on its lanes
    at every step after the ground or terrain forces, :func:`rod_forces_kernel` one copy at a time."""
    law = (prm[0, 0], prm[0, 1], prm[0, 2], prm[0, 3], prm[0, 4], prm[0, 5])
    radius = prm[0, 0]
    for i in range(k - 1):
        ha, hc = eta[i, 0], eta[i, 1]
        ri = max(abs(ha), abs(hc))
        na, nc = rod_a[i], rod_c[i]
        for j in range(i + 1, k):
            ga, gc = eta[j, 0], eta[j, 1]
            reach = ri + max(abs(ga), abs(gc)) + 2.0 * radius
            ma, mc = rod_a[j], rod_c[j]
            for e in range(E):
                touch, s, t, fx, fy, fz = _pair_force(
                    Q[i, 0, e] + ha * Q[i, 3, e], Q[i, 1, e] + ha * Q[i, 4, e], Q[i, 2, e] + ha * Q[i, 5, e],
                    Q[i, 0, e] + hc * Q[i, 3, e], Q[i, 1, e] + hc * Q[i, 4, e], Q[i, 2, e] + hc * Q[i, 5, e],
                    QD[i, 0, e] + ha * QD[i, 3, e], QD[i, 1, e] + ha * QD[i, 4, e], QD[i, 2, e] + ha * QD[i, 5, e],
                    QD[i, 0, e] + hc * QD[i, 3, e], QD[i, 1, e] + hc * QD[i, 4, e], QD[i, 2, e] + hc * QD[i, 5, e],
                    Q[j, 0, e] + ga * Q[j, 3, e], Q[j, 1, e] + ga * Q[j, 4, e], Q[j, 2, e] + ga * Q[j, 5, e],
                    Q[j, 0, e] + gc * Q[j, 3, e], Q[j, 1, e] + gc * Q[j, 4, e], Q[j, 2, e] + gc * Q[j, 5, e],
                    QD[j, 0, e] + ga * QD[j, 3, e], QD[j, 1, e] + ga * QD[j, 4, e], QD[j, 2, e] + ga * QD[j, 5, e],
                    QD[j, 0, e] + gc * QD[j, 3, e], QD[j, 1, e] + gc * QD[j, 4, e], QD[j, 2, e] + gc * QD[j, 5, e],
                    Q[i, 0, e] - Q[j, 0, e], Q[i, 1, e] - Q[j, 1, e], Q[i, 2, e] - Q[j, 2, e],
                    reach, law)
                if touch:
                    u, w = 1.0 - s, 1.0 - t
                    EX[na, 0, e] += u * fx
                    EX[na, 1, e] += u * fy
                    EX[na, 2, e] += u * fz
                    EX[nc, 0, e] += s * fx
                    EX[nc, 1, e] += s * fy
                    EX[nc, 2, e] += s * fz
                    EX[ma, 0, e] -= w * fx
                    EX[ma, 1, e] -= w * fy
                    EX[ma, 2, e] -= w * fz
                    EX[mc, 0, e] -= t * fx
                    EX[mc, 1, e] -= t * fy
                    EX[mc, 2, e] -= t * fz


@njit(cache=True, nogil=True)
def rod_forces_kernel(q, qd, eta, rod_a, rod_c, prm, W):
    """Adds the rod-rod contact forces of every copy of ``q``, ``qd`` (B, k, 6) (m, m/s) into
    ``W`` (B, n, 3) N, one copy at a time through :func:`rods_lanes` with one lane (the loop
    driver's own function, in the same order: a Python loop of ground forces, then this, gives
    the driver's bits). ``prm`` (1, 6): the row of :data:`ROD_COLUMNS`."""
    B, k, n = q.shape[0], q.shape[1], W.shape[1]
    Q = np.empty((k, 6, 1))
    QD = np.empty((k, 6, 1))
    EX = np.empty((n, 3, 1))
    for e in range(B):
        for j in range(k):
            for i in range(6):
                Q[j, i, 0] = q[e, j, i]
                QD[j, i, 0] = qd[e, j, i]
        for p in range(n):
            for i in range(3):
                EX[p, i, 0] = W[e, p, i]
        rods_lanes(Q, QD, EX, eta, rod_a, rod_c, prm, k, 1)
        for p in range(n):
            for i in range(3):
                W[e, p, i] = EX[p, i, 0]


@njit(cache=True, nogil=True)
def pair_distances_kernel(q, eta, D):
    """``D`` (B, P) m: the distance between the segments (the rods' axes between their nodes) of
    every rod pair i < j (in the order (0, 1), (0, 2), ..., (1, 2), ...) at ``q`` (B, k, 6), from
    the contact's own closest points (:func:`closest_params`)."""
    B, k = q.shape[0], q.shape[1]
    for e in range(B):
        p = 0
        for i in range(k - 1):
            a1x = q[e, i, 0] + eta[i, 0] * q[e, i, 3]
            a1y = q[e, i, 1] + eta[i, 0] * q[e, i, 4]
            a1z = q[e, i, 2] + eta[i, 0] * q[e, i, 5]
            d1x = (eta[i, 1] - eta[i, 0]) * q[e, i, 3]
            d1y = (eta[i, 1] - eta[i, 0]) * q[e, i, 4]
            d1z = (eta[i, 1] - eta[i, 0]) * q[e, i, 5]
            for j in range(i + 1, k):
                a2x = q[e, j, 0] + eta[j, 0] * q[e, j, 3]
                a2y = q[e, j, 1] + eta[j, 0] * q[e, j, 4]
                a2z = q[e, j, 2] + eta[j, 0] * q[e, j, 5]
                d2x = (eta[j, 1] - eta[j, 0]) * q[e, j, 3]
                d2y = (eta[j, 1] - eta[j, 0]) * q[e, j, 4]
                d2z = (eta[j, 1] - eta[j, 0]) * q[e, j, 5]
                s, t = closest_params(d1x, d1y, d1z, d2x, d2y, d2z, a1x - a2x, a1y - a2y, a1z - a2z)
                nx = a1x + s * d1x - a2x - t * d2x
                ny = a1y + s * d1y - a2y - t * d2y
                nz = a1z + s * d1z - a2z - t * d2z
                D[e, p] = math.sqrt(nx * nx + ny * ny + nz * nz)
                p += 1
