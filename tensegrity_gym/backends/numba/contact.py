"""Ground contact on the numba backend: Hunt-Crossley normal force with stick-slip Coulomb
friction at one rod end (``_point_force``), every rod end of E SIMD lanes (``_contact_lanes``,
the loop driver's per-step contact forces), the anchors' load and store, and the one-copy
kernel :func:`forces_kernel` (contact forces of a batch, no step). SI units.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .layout import CONTACT_COLUMNS, _opts

# the columns of the contact parameter rows (tensegrity_gym.core.param_table.contact_columns)
_HEIGHT, _RADIUS, _KN, _DN, _EX, _FRICTION, _KT, _CT, _CMAX = (
    CONTACT_COLUMNS.index(f) for f in ("height", "radius", "stiffness", "damping", "exponent", "friction",
                                       "tangential_stiffness", "tangential_damping", "max_damping"))

@njit(inline="always", **_opts)
def _point_force(px, py, pz, vx, vy, vz, ax, ay, was_active, height, radius, kn, dn, ex, friction, kt, ct, cmax):
    """The ground-contact force on one rod-end point (the one implementation of the contact
    equation; NumPy reference ``tests/oracle_numpy.contact_forces``): cap of radius ``radius``
    m at (px, py, pz) m moving at (vx, vy, vz) m/s over the plane z = ``height`` m.
    Hunt-Crossley normal force ``fn = k d^e - min(k d^e dn, cmax) vz`` >= 0 N (d the
    penetration, m); stick-slip Coulomb friction: a tangential spring ``kt`` N/m to the anchor
    (ax, ay) m (set at touch-down, ``was_active`` False) with damping ``ct`` N s/m, capped at
    ``friction fn`` (the anchor then follows the point: slip). Returns (touching, fx, fy, fn, ax, ay,
    slip); no force and the anchor unchanged when the cap is clear of the ground."""
    delta = height + radius - pz
    if not (delta > 0.0):
        return False, 0.0, 0.0, 0.0, ax, ay, False
    de = delta if ex == 1.0 else delta ** ex
    fs = kn * de
    cn = fs * dn
    if cn > cmax:
        cn = cmax
    fn = fs - cn * vz
    if fn < 0.0:
        fn = 0.0
    if not was_active:
        ax = px
        ay = py
    fx = -kt * (px - ax) - ct * vx
    fy = -kt * (py - ay) - ct * vy
    nrm = math.sqrt(fx * fx + fy * fy)
    lim = friction * fn
    if nrm > lim:
        s = lim / nrm
        fx *= s
        fy *= s
        return True, fx, fy, fn, px + fx / kt, py + fy / kt, True
    return True, fx, fy, fn, ax, ay, False

@njit(inline="always", **_opts)
def _contact_lanes(Q, QD, EX, AN, AC, SL, eta, rod_a, rod_c, prm, ext, c0, ne, k, n, E):
    """Ground-contact forces of E lanes (copies c0..c0+ne-1; pad lanes repeat copy c0) into
    EX (n, 3, E) N from the rods' state Q, QD (k, 6, E) (m, m/s): every rod end (node
    ``rod_a[j]`` at ``eta[j, 0]``, ``rod_c[j]`` at ``eta[j, 1]``; contact 2j + end) through
    :func:`_point_force`, its anchor AN (2k, 2, E) m and active / slip flags AC, SL (2k, E)
    updated in place; then ``ext`` (0, 1 or B rows of (n, 3)) N added. ``prm`` (1 or B, 9)
    (columns ``contact.PRM_FIELDS``, read by name) one row shared
    or one per copy. The one loop over contact points: the driver runs it on its lanes at every
    step (:func:`.driver._drive_py` with ``contact``), :func:`forces_kernel` one copy at a time."""
    per_prm = prm.shape[0] > 1
    per_ext = ext.shape[0] > 1
    has_ext = ext.shape[0] > 0
    for e in range(E):
        src = c0 + e if e < ne else c0
        pe = src if per_prm else 0
        height, radius, kn, dn, ex = prm[pe, _HEIGHT], prm[pe, _RADIUS], prm[pe, _KN], prm[pe, _DN], prm[pe, _EX]
        friction, kt, ct, cmax = prm[pe, _FRICTION], prm[pe, _KT], prm[pe, _CT], prm[pe, _CMAX]
        for p in range(n):
            EX[p, 0, e] = 0.0
            EX[p, 1, e] = 0.0
            EX[p, 2, e] = 0.0
        for j in range(k):
            for end in range(2):
                ci = 2 * j + end
                h = eta[j, end]
                node = rod_a[j] if end == 0 else rod_c[j]
                touch, fx, fy, fn, AN[ci, 0, e], AN[ci, 1, e], SL[ci, e] = _point_force(
                    Q[j, 0, e] + h * Q[j, 3, e], Q[j, 1, e] + h * Q[j, 4, e], Q[j, 2, e] + h * Q[j, 5, e],
                    QD[j, 0, e] + h * QD[j, 3, e], QD[j, 1, e] + h * QD[j, 4, e], QD[j, 2, e] + h * QD[j, 5, e],
                    AN[ci, 0, e], AN[ci, 1, e], AC[ci, e], height, radius, kn, dn, ex, friction, kt, ct, cmax)
                AC[ci, e] = touch
                if touch:
                    EX[node, 0, e] += fx
                    EX[node, 1, e] += fy
                    EX[node, 2, e] += fn
        if has_ext:
            r = src if per_ext else 0
            for p in range(n):
                for i in range(3):
                    EX[p, i, e] += ext[r, p, i]

@njit(inline="always", **_opts)
def _contact_load(anchor, active, AN, AC, c0, ne, k, E):
    """Lanes 0..E-1 of the contact scratch AN (2k, 2, E), AC (2k, E) take the anchors and
    active flags of copies c0..c0+ne-1 (pad lanes repeat copy c0)."""
    for e in range(E):
        src = c0 + e if e < ne else c0
        for ci in range(2 * k):
            AN[ci, 0, e] = anchor[src, ci, 0]
            AN[ci, 1, e] = anchor[src, ci, 1]
            AC[ci, e] = active[src, ci]

@njit(inline="always", **_opts)
def _contact_store(anchor, active, slip, W, AN, AC, SL, EX, c0, ne, k, n):
    """Copies c0..c0+ne-1 take their lanes' anchors, active and slip flags and forces EX."""
    for e in range(ne):
        for ci in range(2 * k):
            anchor[c0 + e, ci, 0] = AN[ci, 0, e]
            anchor[c0 + e, ci, 1] = AN[ci, 1, e]
            active[c0 + e, ci] = AC[ci, e]
            slip[c0 + e, ci] = SL[ci, e]
        for p in range(n):
            for i in range(3):
                W[c0 + e, p, i] = EX[p, i, e]


@njit(cache=True, nogil=True)
def forces_kernel(q, qd, eta, rod_a, rod_c, anchor, active, W, slip, prm):
    """The contact forces of every copy of ``q``, ``qd`` (B, k, 6) into ``W`` (B, n, 3) N, their
    anchors, active and slip flags updated in place; ``prm`` (1, 9) shared or (B, 9) one row
    per copy. One copy at a time through the loop driver's own contact pieces
    (``_contact_load``, ``_contact_lanes``, ``_contact_store`` with one lane): the
    contact equation exists once (``_point_force``; NumPy reference
    ``tests/oracle_numpy.contact_forces``)."""
    B, k, n = q.shape[0], q.shape[1], W.shape[1]
    Q = np.empty((k, 6, 1))
    QD = np.empty((k, 6, 1))
    EX = np.empty((n, 3, 1))
    AN = np.empty((2 * k, 2, 1))
    AC = np.empty((2 * k, 1), np.bool_)
    SL = np.empty((2 * k, 1), np.bool_)
    no_ext = np.empty((0, n, 3))
    for e in range(B):
        for j in range(k):
            for i in range(6):
                Q[j, i, 0] = q[e, j, i]
                QD[j, i, 0] = qd[e, j, i]
        _contact_load(anchor, active, AN, AC, e, 1, k, 1)
        _contact_lanes(Q, QD, EX, AN, AC, SL, eta, rod_a, rod_c, prm, no_ext, e, 1, k, n, 1)
        _contact_store(anchor, active, slip, W, AN, AC, SL, EX, e, 1, k, n)


