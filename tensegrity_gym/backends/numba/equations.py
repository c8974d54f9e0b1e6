"""The book's equations as scalar numba functions (Skelton & de Oliveira ch. 5) run by the loop
driver (:mod:`.driver`; :func:`_acc` compiled on its own and called, the rest inlined): rod accelerations ((5.37)/(5.40), reduced form
(5.49)-(5.51)), the great-circle drift of semi-implicit Euler, nodes linear in the
configuration (5.17), tension-only string forces (5.20) and generalized forces (5.21), and the
projection onto the constraints. Same formulas as the NumPy oracle ``tests/oracle_numpy.py``
(equal to round-off). SI units.

Implementation notes: divisions by per-rod constants and by ``|b|^2`` are multiplications by
reciprocals, and forces are accumulated string by string (only round-off moves). Slack
strings add nothing; ``error_model="numpy"``: a division by zero gives inf/NaN as in NumPy,
never a Python exception.
"""
from __future__ import annotations

import math

from numba import njit

from .layout import _DAMP, _EXT, _FD, _GRAV, _N_NODE_DAMPING, _NDAMP, _ROD, _S_DAMPING, _S_STIFFNESS, _SINC_SMALL, _STR, _opts

@njit(inline="always", **_opts)
def _rod_acc(b0, b1, b2, bd0, bd1, bd2, Fa0, Fa1, Fa2, Fc0, Fc1, Fc2, ea, ec, free, im, iJ, fJ, beta, alpha,
             ialpha, fm, w, pj):
    """(r'', b'') of one rod from its direction ``b``, rate ``b'``, the forces on its nodes
    ``F_a``, ``F_c`` (N) at ``eta_a``, ``eta_c`` and its constants (1/m, 1/J, f/J, beta,
    alpha, 1/alpha, f; projector Pi at ``w[pj:pj + 9]``, read only for a constrained rod;
    at most 30 arguments: CPython passes more as a tuple, which numba cannot inline):
    (5.37)/(5.40) for a free rod at its centre of mass
    (``free``: f = 0, A = I/m), the reduced form (5.49)-(5.51) with the branch-free
    Sherman-Morrison ``A`` for a constrained one (see :mod:`tensegrity_gym.core.model`). The one copy of the rod
    equations of the numba backend (_acc inlines it)."""
    fr0 = Fa0 + Fc0
    fr1 = Fa1 + Fc1
    fr2 = Fa2 + Fc2
    fb0 = ea * Fa0 + ec * Fc0
    fb1 = ea * Fa1 + ec * Fc1
    fb2 = ea * Fa2 + ec * Fc2
    ibb = 1.0 / (b0 * b0 + b1 * b1 + b2 * b2)
    wv = (bd0 * bd0 + bd1 * bd1 + bd2 * bd2) * ibb
    c = (b0 * fb0 + b1 * fb1 + b2 * fb2) * ibb
    P0 = fb0 - b0 * c
    P1 = fb1 - b1 * c
    P2 = fb2 - b2 * c
    if free:
        return (fr0 * im, fr1 * im, fr2 * im, P0 * iJ - wv * b0, P1 * iJ - wv * b1, P2 * iJ - wv * b2)
    fw = fm * wv         # f w
    h0 = fr0 - fJ * P0 + fw * b0
    h1 = fr1 - fJ * P1 + fw * b1
    h2 = fr2 - fJ * P2 + fw * b2
    isb = math.sqrt(ibb)
    p00, p01, p02 = w[pj], w[pj + 1], w[pj + 2]
    p10, p11, p12 = w[pj + 3], w[pj + 4], w[pj + 5]
    p20, p21, p22 = w[pj + 6], w[pj + 7], w[pj + 8]
    u0 = (p00 * b0 + p01 * b1 + p02 * b2) * isb
    u1 = (p10 * b0 + p11 * b1 + p12 * b2) * isb
    u2 = (p20 * b0 + p21 * b1 + p22 * b2) * isb
    Ph0 = p00 * h0 + p01 * h1 + p02 * h2
    Ph1 = p10 * h0 + p11 * h1 + p12 * h2
    Ph2 = p20 * h0 + p21 * h1 + p22 * h2
    uu = u0 * u0 + u1 * u1 + u2 * u2
    uh = u0 * h0 + u1 * h1 + u2 * h2
    cu = beta * uh / (alpha + beta * uu)
    r0 = (Ph0 - cu * u0) * ialpha
    r1 = (Ph1 - cu * u1) * ialpha
    r2 = (Ph2 - cu * u2) * ialpha
    br = (b0 * r0 + b1 * r1 + b2 * r2) * ibb
    return (r0, r1, r2, P0 * iJ - fJ * (r0 - b0 * br) - wv * b0, P1 * iJ - fJ * (r1 - b1 * br) - wv * b1,
            P2 * iJ - fJ * (r2 - b2 * br) - wv * b2)

@njit(inline="always", **_opts)
def _drift_rod(q0, q1, q2, b0, b1, b2, v0, v1, v2, d0, d1, d2, dt):
    """Semi-implicit Euler drift with projection for one rod (oracle_numpy.sphere_drift, same
    operations in the same order): r += dt r'; b along its great circle. Returns the new
    (r, b, b') as a 9-tuple (r' is unchanged)."""
    q0 = q0 + dt * v0
    q1 = q1 + dt * v1
    q2 = q2 + dt * v2
    inb = 1.0 / math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    b0 = b0 * inb
    b1 = b1 * inb
    b2 = b2 * inb
    dot = b0 * d0 + b1 * d1 + b2 * d2
    d0 = d0 - b0 * dot
    d1 = d1 - b1 * dot
    d2 = d2 - b2 * dot
    wv = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    x = wv * dt
    if x < _SINC_SMALL:
        sinc = 1.0 - x * x / 6.0
    else:
        sinc = math.sin(x) / x
    c = math.cos(x)
    ds = dt * sinc
    ws = wv * (x * sinc)
    return (q0, q1, q2, b0 * c + d0 * ds, b1 * c + d1 * ds, b2 * c + d2 * ds,
            d0 * c - b0 * ws, d1 * c - b1 * ws, d2 * c - b2 * ws)


@njit(inline="always", **_opts)
def _rod_topology(w, ib, o_rod, j):
    """(slot of rod j in the packed buffer, node a, node c, eta_a, eta_c)."""
    rj = o_rod + _ROD * j
    return rj, ib[rj], ib[rj + 1], w[rj + 3], w[rj + 4]

@njit(inline="always", **_opts)
def _nodes(w, ib, o_rod, k, Qi, Vi, N, V, E, need_v):
    """Node positions N (n, 3, E) (and velocities V if ``need_v``) of the rods' end nodes from
    the configuration Qi (and Vi) (k, 6, E): N = Q Psi^T (+ Y: the anchor rows are preset)."""
    for j in range(k):
        rj, ia, ic, ea, ec = _rod_topology(w, ib, o_rod, j)
        for i in range(3):
            for e in range(E):
                N[ia, i, e] = Qi[j, i, e] + ea * Qi[j, 3 + i, e]
                N[ic, i, e] = Qi[j, i, e] + ec * Qi[j, 3 + i, e]
        if need_v:
            for i in range(3):
                for e in range(E):
                    V[ia, i, e] = Vi[j, i, e] + ea * Vi[j, 3 + i, e]
                    V[ic, i, e] = Vi[j, i, e] + ec * Vi[j, 3 + i, e]


@njit(inline="always", **_opts)
def _forces(w, ib, L, k, m, n, Qi, Vi, N, V, F, L0, FD, EX, E, flags, PC, G, LS, store):
    """Total nodal forces F (n, 3, E), N, of E copies: the strings' -C^T Gamma C N (the string
    force equation: tension k (L - l0) + c dL/dt, zero when slack or pushing, over L, plus the
    force density control FD, clipped at 0), gravity loads, node drag and external forces EX.
    With ``store`` (a compile-time constant at each call) also each string's force density
    G (m, E), N/m, and length LS (m, E), m. The one copy of these equations in the numba
    backend (:func:`_acc` inlines it; :func:`_run_forces` returns its results)."""
    o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end = L
    has_damp = (flags & _DAMP) != 0
    _nodes(w, ib, o_rod, k, Qi, Vi, N, V, E, (flags & (_DAMP | _NDAMP)) != 0)
    F[:] = 0.0
    has_fd = (flags & _FD) != 0
    for s in range(m):
        ps = o_str + _STR * s
        si = ib[ps]
        sj = ib[ps + 1]
        for e in range(E):
            kk = PC[ps + _S_STIFFNESS, e]
            cc = PC[ps + _S_DAMPING, e]
            s0 = N[sj, 0, e] - N[si, 0, e]
            s1 = N[sj, 1, e] - N[si, 1, e]
            s2 = N[sj, 2, e] - N[si, 2, e]
            Ls = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            l0s = L0[s, e]
            tension = kk * (Ls - l0s)
            if has_damp:
                d0 = V[sj, 0, e] - V[si, 0, e]
                d1 = V[sj, 1, e] - V[si, 1, e]
                d2 = V[sj, 2, e] - V[si, 2, e]
                tension = tension + cc * ((s0 * d0 + s1 * d1 + s2 * d2) / Ls)
            g = tension / Ls
            if not (Ls > l0s) or tension < 0.0:
                g = 0.0
            if has_fd:
                g = g + FD[s, e]
                if g < 0.0:
                    g = 0.0
            if store:
                G[s, e] = g
                LS[s, e] = Ls
            F[sj, 0, e] -= g * s0
            F[sj, 1, e] -= g * s1
            F[sj, 2, e] -= g * s2
            F[si, 0, e] += g * s0
            F[si, 1, e] += g * s1
            F[si, 2, e] += g * s2
    if (flags & _GRAV) != 0:
        for p in range(n):
            for i in range(3):
                for e in range(E):
                    F[p, i, e] = F[p, i, e] + PC[o_W0 + 3 * p + i, e]
    if (flags & _NDAMP) != 0:
        o_nd = o_cn + 3 * n * _N_NODE_DAMPING
        for p in range(n):
            for i in range(3):
                for e in range(E):
                    F[p, i, e] = F[p, i, e] - PC[o_nd + 3 * p + i, e] * V[p, i, e]
    if (flags & _EXT) != 0:
        for p in range(n):
            for i in range(3):
                for e in range(E):
                    F[p, i, e] = F[p, i, e] + EX[p, i, e]


@njit(**_opts)
def _acc(w, ib, L, k, m, n, Qi, Vi, A, N, V, F, L0, FD, EX, E, flags, PC):
    """Accelerations A (k, 6, E) of E copies at once (physics.accelerations), in
    structure-of-arrays scratch: Qi, Vi, A (k, 6, E), N, V, F, EX (n, 3, E), L0, FD (m, E).
    The innermost loops run over the copies (SIMD; one iteration in the E = 1 instance).
    Topology (node indices, eta, projectors) comes from ``w``; the physical constants of lane
    e from ``PC[slot, e]`` (the buffer's slots, one column per lane: see _lane_physics).
    The nodal forces are :func:`_forces`, the rod equations :func:`_rod_acc`."""
    _forces(w, ib, L, k, m, n, Qi, Vi, N, V, F, L0, FD, EX, E, flags, PC, L0, L0, False)
    o_rod = L[0]
    for j in range(k):
        rj, fa, fc, ea, ec = _rod_topology(w, ib, o_rod, j)
        free = ib[rj + 2] == 0
        for e in range(E):
            (A[j, 0, e], A[j, 1, e], A[j, 2, e], A[j, 3, e], A[j, 4, e], A[j, 5, e]) = _rod_acc(
                Qi[j, 3, e], Qi[j, 4, e], Qi[j, 5, e], Vi[j, 3, e], Vi[j, 4, e], Vi[j, 5, e],
                F[fa, 0, e], F[fa, 1, e], F[fa, 2, e], F[fc, 0, e], F[fc, 1, e], F[fc, 2, e], ea, ec, free,
                PC[rj + 5, e], PC[rj + 6, e], PC[rj + 7, e], PC[rj + 8, e], PC[rj + 9, e], PC[rj + 10, e],
                PC[rj + 11, e], w, rj + 12)



@njit(inline="always", **_opts)
def _project(w, ib, o_rod, k, Q, QD, E, any_cons):
    """In place on Q, QD (k, 6, E): |b| = 1, b.b' = 0 and constrained reference points back on
    their point/line/plane with tangent velocity (physics.project, same operations)."""
    for j in range(k):
        rj = o_rod + _ROD * j
        for e in range(E):
            b0 = Q[j, 3, e]
            b1 = Q[j, 4, e]
            b2 = Q[j, 5, e]
            inb = 1.0 / math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
            b0 = b0 * inb
            b1 = b1 * inb
            b2 = b2 * inb
            Q[j, 3, e] = b0
            Q[j, 4, e] = b1
            Q[j, 5, e] = b2
            dot = b0 * QD[j, 3, e] + b1 * QD[j, 4, e] + b2 * QD[j, 5, e]
            QD[j, 3, e] = QD[j, 3, e] - b0 * dot
            QD[j, 4, e] = QD[j, 4, e] - b1 * dot
            QD[j, 5, e] = QD[j, 5, e] - b2 * dot
        if any_cons and ib[rj + 2] != 0:
            pj = rj + 12
            oj = rj + 21
            for e in range(E):
                x0 = Q[j, 0, e]
                x1 = Q[j, 1, e]
                x2 = Q[j, 2, e]
                v0 = QD[j, 0, e]
                v1 = QD[j, 1, e]
                v2 = QD[j, 2, e]
                for i in range(3):
                    Q[j, i, e] = w[oj + i] + (w[pj + 3 * i] * x0 + w[pj + 3 * i + 1] * x1
                                              + w[pj + 3 * i + 2] * x2)
                    QD[j, i, e] = w[pj + 3 * i] * v0 + w[pj + 3 * i + 1] * v1 + w[pj + 3 * i + 2] * v2

