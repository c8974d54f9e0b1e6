"""Compiled (numba) kernels for the fixed-step integrators of :mod:`tensegrity_gym.integrators`.

This module is the one implementation of the rod accelerations ((5.37)/(5.40) and the reduced
form (5.49)-(5.51)), the semi-implicit Euler and classic RK4 steps, the projection onto the
constraints and the ground-contact forces (``_point_force``: the driver runs them at every
contact sub-step, ``contact.py`` through ``_forces_kernel``) that
:func:`tensegrity_gym.integrators.step`, :func:`tensegrity_gym.dynamics.project` and every env
run. It reproduces, operation for operation, the vectorised NumPy formulation kept as the test
oracle ``tests/oracle_numpy.py`` (the two agree to round-off, checked in ``tests/test_kernels.py``
and ``tests/test_contact.py``). It never imports gymnasium. SI units throughout (m, kg, s, N).

Why numba: one NumPy call costs about 1 us, and a NumPy step of even the 3-bar prism chains
dozens of them, so a single-environment step cannot reach MuJoCo's ``mj_step`` rate without a
compiled kernel. numba compiles the plain loops below with no build step for the user
(``cache=True`` keeps the machine code on disk between runs) and runs the batch loop on all
cores with ``prange`` when the batch is large.

Entry points
------------
:func:`step` ``(model, state, dt, name, *, rest_length, force_density, external, project, n_steps)``
    Same arguments and result as ``integrators.step`` for ``name`` in
    ``{"semi_implicit_euler", "rk4"}``; returns a new :class:`~tensegrity_gym.dynamics.State`
    (the input state is never modified). ``integrators.step`` dispatches here for
    ``backend="auto"``/``"numba"``.
:func:`accelerations` ``(model, q, qd, rest_length, force_density, external, params)``
    The accelerations ``[r'', b'']`` of a batch of states, no step: the driver's own force and
    rod equations (flag ``_ACC``), for the methods that evaluate accelerations themselves
    (implicit Euler, the adaptive methods, finite-difference Jacobians, through
    :func:`tensegrity_gym.integrators.accelerations`).
:func:`step_inplace` ``(model, q, qd, dt, name="semi_implicit_euler", *, ...)``
    The fast path for environments: advances preallocated state arrays ``q``, ``qd``
    (B, k, 6), C-contiguous float64, **in place** and returns nothing. It allocates nothing
    per call and skips the :class:`State` object; an environment that owns its state arrays
    should call this. Time is not tracked (the caller adds ``n_steps * dt``).

Inputs (both entry points)
--------------------------
``rest_length`` (m,) or (B, m) in m, ``force_density`` (m,) or (B, m) in N/m (added to the
string force densities, result clipped at 0), ``external`` (n, 3) or (B, n, 3) nodal forces
in N held constant over the step(s). ``project``: normalise ``b``, remove the component of
``b'`` along ``b`` and put constrained reference points back on their point/line/plane after
every step (exactly :func:`tensegrity_gym.dynamics.project`); semi-implicit Euler then moves
``b`` along its great circle (``_drift_rod``; NumPy reference ``tests/oracle_numpy.sphere_drift``). ``n_steps``: steps taken in
one call (all inside the compiled loop).

Implementation notes
--------------------
* Same formulas as dynamics.py, with two deliberate differences that only move round-off
  (agreement ~1e-14 relative after hundreds of steps): divisions by per-rod constants and by
  ``|b|^2`` are multiplications by reciprocals, and forces are accumulated string by string.
  Slack strings add nothing; ``error_model="numpy"``: a division by zero gives inf/NaN as in
  NumPy (``integrators.simulate`` then reports the divergence), never a Python exception.
* Per-model data are packed once into ONE float64 buffer (integers as int64 bit patterns,
  then the serial scratch; see ``_layout``), cached by ``id(model)`` and dropped when the
  model is garbage collected: every array argument of a numba call costs ~0.1 us at the
  boundary, and array views inside a kernel cost reference counting, so the kernels index
  flat buffers with computed offsets instead.
* Three compiled entry points, each for ONE explicit signature (C-contiguous float64 arrays;
  other inputs -- float32, strided or read-only arrays -- are converted at the boundary, never
  compiled again): ``_run_lean`` (no control arrays: three arguments fewer, the single-env
  fast path), ``_run_serial`` and ``_run_parallel`` (``prange`` over chunks of the batch, used
  when a call carries at least ``PARALLEL_MIN_WORK`` units of work; it takes the packed buffers
  (P, len): the shared one, P = 1, or one per copy). The serial ones compile
  (or load from numba's disk cache) on the first call, the parallel one on the first large
  batch. All of them run ONE loop driver, ``_advance_py``, on structure-of-arrays scratch
  (k, 6, E), through its two instances: ``_advance``, E = 16 (8 above 24 rods) environments
  per SIMD block from ``_SOA_MIN_BATCH`` = 16 environments (fresh scratch per call), and
  ``_advance_one``, one at a time with E = 1 a compile-time constant, in the packed buffer's
  own scratch reached through ``numba.carray`` views (``_view``: no reference counting)
  (bit-identical results either way).
* numba's threading layer is set to ``workqueue`` unless the user chose one
  (``NUMBA_THREADING_LAYER``): see the comment at the import. The parallel kernel holds
  the GIL, so two Python threads never enter the pool at once.
* Damping work (node velocities, string length rates) is skipped when
  ``model.has_damping`` and ``model.has_node_damping`` are False (node drag ``-c v``,
  :func:`tensegrity_gym.dynamics.compile_model` ``node_damping``, is added to the nodal forces
  after gravity, as NumPy does); gravity loads when ``model.has_gravity`` is False.
* Shapes are checked inside the kernel (error code -> ``ValueError`` naming the argument),
  so a wrong shape never reads out of bounds.
* Cold start: the first call compiles (~25 s per entry point group on the 2-core machine);
  later processes load the machine code from ``__pycache__`` in about a second.
"""
from __future__ import annotations

import math
import os
import weakref

import numpy as np

import numba   # a required dependency: these kernels are the package's only step implementation
from numba import njit, prange

if "NUMBA_THREADING_LAYER" not in os.environ and numba.config.THREADING_LAYER == "default":
    # numba's default picks GNU OpenMP here; on a machine with more runnable threads than cores
    # (other jobs, or torch's own OpenMP pool during training) each parallel call then waits
    # ~12-16 ms for a descheduled worker, measured on the 2-core benchmark machine, against
    # ~0.1 ms with numba's own workqueue pool. Set NUMBA_THREADING_LAYER to choose otherwise.
    numba.config.THREADING_LAYER = "workqueue"

__all__ = ["step", "step_inplace", "accelerations", "string_forces", "project", "PARALLEL_MIN_WORK", "clear_cache"]

#: a call runs the multi-threaded kernel when B * n_steps * (strings + rods) * (4 for RK4, else 1)
#: reaches this (about 0.3 ms of single-core work: below it, waking threads costs more than they save,
#: and much more on a loaded machine). B < 8 is always serial.
PARALLEL_MIN_WORK = 10_000

# flag bits passed to the kernel
_RK4 = 1
_DAMP = 2
_GRAV = 4
_FD = 8
_EXT = 16
_PROJ = 32
_CONS = 64
_L0DEF = 128   # use the model's rest lengths stored in the buffer
_NDAMP = 256   # per-node viscous drag (model.node_damping)
_ACC = 512     # no step: write the accelerations [r'', b''] of (q, qd) into qdo (q into qo)
_PONLY = 1024  # no step: write the projection of (q, qd) onto the constraints (_project) into qo, qdo
_CHUNK_SHIFT = 16   # the parallel kernel's chunk count rides in flags >> _CHUNK_SHIFT
_SINC_SMALL = 1e-4    # integrators._SINC_SMALL: below this angle per step sin(x)/x = 1 - x^2/6
_SOA_MIN_BATCH = 16   # serial calls with at least this many environments use the SIMD (SoA) loop

_ERRORS = {
    1: "q: expected shape (B, {k}, 6)",
    2: "qd: expected the same shape as q (B, {k}, 6)",
    3: "rest_length: expected shape ({m},) or (B, {m})",
    4: "force_density: expected shape ({m},) or (B, {m})",
    5: "external: expected shape ({n}, 3) or (B, {n}, 3)",
    6: "output arrays: expected the same shape as q",
    7: "params: expected one row (shared) or one per copy of q",
}


_ROD = 24   # slots per rod in the packed buffer
_STR = 4    # slots per string


def _layout(k, m, n):
    """Offsets into the packed model buffer (float64, 1-D; integer fields hold int64 bit patterns
    read through an int64 view of the same memory):

    ========  ======  ==============================================================
    offset    size    content
    ========  ======  ==============================================================
    0         3       k, m, n (int)
    o_rod     24 k    per rod: a, c, constrained (int), eta_a, eta_c, 1/m, 1/J, f/J,
                      beta = f^2/J, alpha = m - f^2/J, 1/alpha, f, Pi (9), offset (3)
    o_str     4 m     per string: i, j (int), stiffness, damping
    o_l0      m       default rest lengths
    o_W0      3 n     gravity nodal loads
    o_ws      60 k    10 stage arrays (k, 6) of the integrators (scratch)
    o_N/V/F   3 n     node positions (anchor rows preset), velocities (anchor rows 0), forces
    o_cn      3 n     node drag coefficients c (N s/m), repeated for x, y, z
    +3 n      2 m+3n  one copy's rest lengths, force densities, external forces (scratch)
    ========  ======  ==============================================================
    """
    o_rod = 3
    o_str = o_rod + _ROD * k
    o_l0 = o_str + _STR * m
    o_W0 = o_l0 + m
    o_ws = o_W0 + 3 * n
    o_N = o_ws + 60 * k
    o_V = o_N + 3 * n
    o_F = o_V + 3 * n
    o_cn = o_F + 3 * n
    end = o_cn + 3 * n + 2 * m + 3 * n
    return (o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end)


def _soa_width(k):
    """E, the copies per block of the SIMD (structure-of-arrays) loop for k rods."""
    return 16 if k <= 24 else 8


# The kernels index one flat float64 buffer ``w`` (model data + scratch, see _layout) with
# computed offsets instead of slicing views: every numba array view costs reference-count
# traffic that, at B = 1, is larger than the physics of a small structure.
_opts = dict(cache=True, fastmath=False, error_model="numpy")
_layout_nb = njit(**_opts)(_layout)
_soa_width_nb = njit(inline="always", **_opts)(_soa_width)

@njit(inline="always", **_opts)
def _lane_width(k, B):
    """E for a serial call on B copies: SIMD blocks from _SOA_MIN_BATCH copies, else one copy
    at a time (a padded block would compute up to 15 copies for nothing)."""
    return _soa_width_nb(k) if B >= _SOA_MIN_BATCH else 1

@njit(inline="always", **_opts)
def _rod_acc(b0, b1, b2, bd0, bd1, bd2, Fa0, Fa1, Fa2, Fc0, Fc1, Fc2, ea, ec, free, im, iJ, fJ, beta, alpha,
             ialpha, fm, w, pj):
    """(r'', b'') of one rod from its direction ``b``, rate ``b'``, the forces on its nodes
    ``F_a``, ``F_c`` (N) at ``eta_a``, ``eta_c`` and its constants (1/m, 1/J, f/J, beta,
    alpha, 1/alpha, f; projector Pi at ``w[pj:pj + 9]``, read only for a constrained rod;
    at most 30 arguments: CPython passes more as a tuple, which numba cannot inline):
    (5.37)/(5.40) for a free rod at its centre of mass
    (``free``: f = 0, A = I/m), the reduced form (5.49)-(5.51) with the branch-free
    Sherman-Morrison ``A`` for a constrained one (see dynamics.py). The one copy of the rod
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
def _point_force(px, py, pz, vx, vy, vz, ax, ay, was_active, height, radius, kn, dn, ex, mu, kt, ct, cmax):
    """The ground-contact force on one rod-end point (the one implementation of the contact
    equation; NumPy reference ``tests/oracle_numpy.contact_forces``): cap of radius ``radius``
    m at (px, py, pz) m moving at (vx, vy, vz) m/s over the plane z = ``height`` m.
    Hunt-Crossley normal force ``fn = k d^e - min(k d^e dn, cmax) vz`` >= 0 N (d the
    penetration, m); stick-slip Coulomb friction: a tangential spring ``kt`` N/m to the anchor
    (ax, ay) m (set at touch-down, ``was_active`` False) with damping ``ct`` N s/m, capped at
    ``mu fn`` (the anchor then follows the point: slip). Returns (touching, fx, fy, fn, ax, ay,
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
    lim = mu * fn
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
    (``contact.PRM_FIELDS``: height, radius, kn, dn, exponent, mu, kt, ct, cmax) one row shared
    or one per copy. The one loop over contact points: the driver runs it on its lanes at every
    step (:func:`_advance_py` with ``contact``), ``contact._forces_kernel`` one copy at a time."""
    per_prm = prm.shape[0] > 1
    per_ext = ext.shape[0] > 1
    has_ext = ext.shape[0] > 0
    for e in range(E):
        src = c0 + e if e < ne else c0
        pe = src if per_prm else 0
        height, radius, kn, dn, ex, mu = prm[pe, 0], prm[pe, 1], prm[pe, 2], prm[pe, 3], prm[pe, 4], prm[pe, 5]
        kt, ct, cmax = prm[pe, 6], prm[pe, 7], prm[pe, 8]
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
                    AN[ci, 0, e], AN[ci, 1, e], AC[ci, e], height, radius, kn, dn, ex, mu, kt, ct, cmax)
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
            kk = PC[ps + 2, e]
            cc = PC[ps + 3, e]
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
        for p in range(n):
            for i in range(3):
                for e in range(E):
                    F[p, i, e] = F[p, i, e] - PC[o_cn + 3 * p + i, e] * V[p, i, e]
    if (flags & _EXT) != 0:
        for p in range(n):
            for i in range(3):
                for e in range(E):
                    F[p, i, e] = F[p, i, e] + EX[p, i, e]


@njit(inline="always", **_opts)
def _acc(w, ib, L, k, m, n, Qi, Vi, A, N, V, F, L0, FD, EX, E, flags, PC):
    """Accelerations A (k, 6, E) of E copies at once (dynamics.accelerations), in
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
def _lane_physics(PC, N, src, L, k, m, n, e):
    """Lane e of the SoA scratch takes the physical constants of the packed buffer ``src``:
    rod constants (slots 5..11), string stiffness and damping, default rest lengths, gravity
    loads, node drag (into ``PC[slot, e]``) and the anchor positions (rows of ``N``)."""
    o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end = L
    for j in range(k):
        rj = o_rod + _ROD * j
        for x in range(rj + 5, rj + 12):
            PC[x, e] = src[x]
    for s in range(m):
        ps = o_str + _STR * s
        PC[ps + 2, e] = src[ps + 2]
        PC[ps + 3, e] = src[ps + 3]
        PC[o_l0 + s, e] = src[o_l0 + s]
    for p in range(3 * n):
        PC[o_W0 + p, e] = src[o_W0 + p]
        PC[o_cn + p, e] = src[o_cn + p]
    _lane_physics_anchors(N, src, L, n, e)

@njit(inline="always", **_opts)
def _lane_physics_anchors(N, src, L, n, e):
    """Lane e of the node scratch ``N`` takes the node rows of the packed buffer ``src``
    (anchors: their fixed positions; rod nodes are overwritten by every force evaluation)."""
    o_N = L[5]
    for p in range(n):
        for i in range(3):
            N[p, i, e] = src[o_N + 3 * p + i]

@njit(inline="always", **_opts)
def _stage_soa(Q, QD, V, A, c, QS, QDn, k, E):
    """An RK4 stage state of E lanes: ``QS = Q + c V``, ``QDn = QD + c A`` (k, 6, E)."""
    for j in range(k):
        for i in range(6):
            for e in range(E):
                QS[j, i, e] = Q[j, i, e] + c * V[j, i, e]
                QDn[j, i, e] = QD[j, i, e] + c * A[j, i, e]

@njit(inline="always", **_opts)
def _project(w, ib, o_rod, k, Q, QD, E, any_cons):
    """In place on Q, QD (k, 6, E): |b| = 1, b.b' = 0 and constrained reference points back on
    their point/line/plane with tangent velocity (dynamics.project, same operations)."""
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

@numba.extending.intrinsic
def _address(typingctx, arr, offset):
    """Pointer to ``arr.flat[offset]`` (C-contiguous ``arr``), for numba.carray views into the
    packed buffer that cost no reference counting and no reshape call."""
    def codegen(context, builder, sig, args):
        return builder.gep(context.make_array(sig.args[0])(context, builder, args[0]).data, [args[1]])
    return numba.types.CPointer(arr.dtype)(arr, offset), codegen

@njit(inline="always", **_opts)
def _view(arr, offset, shape):
    """C-contiguous view of ``arr`` from flat index ``offset`` with ``shape`` (no bounds check:
    the caller's layout guarantees it). Unlike slicing and reshape, it costs no reference
    counting and no library call, which matter at one copy and one step per call."""
    return numba.carray(_address(arr, offset), shape)

@njit(inline="always", **_opts)
def _scratch(w, L, k, m, n, E, per_copy):
    """The driver's scratch for E lanes, (S, N, V, F, L0, FD, EX, PC): stage arrays S
    (10, k, 6, E), node positions / velocities / forces (n, 3, E), rest lengths and force
    densities (m, E), external forces (n, 3, E), and the lanes' physical constants PC
    (len, E). Separate arrays (the compiler may assume they do not overlap). Where every
    copy shares ``w`` (``per_copy`` False) its constants and anchor rows are written here,
    once; one copy reads them from ``w`` in place. Reusable across calls of the same model
    and E (V's anchor rows, FD and EX stay 0 where unused)."""
    if E == 1:        # one copy (serial calls, GIL held): the packed buffer's own scratch
        o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end = L
        o_x = o_cn + 3 * n
        PC = _view(w, 0, (0 if per_copy else w.shape[0], 1))
        return (_view(w, o_ws, (10, k, 6, 1)), _view(w, o_N, (n, 3, 1)), _view(w, o_V, (n, 3, 1)),
                _view(w, o_F, (n, 3, 1)), _view(w, o_x, (m, 1)), _view(w, o_x + m, (m, 1)),
                _view(w, o_x + 2 * m, (n, 3, 1)), PC)
    N = np.empty((n, 3, E))
    if per_copy:
        PC = np.empty((0, E))
    else:
        PC = np.empty((L[9], E))
        for e in range(E):
            _lane_physics(PC, N, w, L, k, m, n, e)
    return (np.empty((10, k, 6, E)), N, np.zeros((n, 3, E)), np.empty((n, 3, E)), np.empty((m, E)),
            np.zeros((m, E)), np.zeros((n, 3, E)), PC)

@njit(inline="always", **_opts)
def _load(q, qd, l0, fd, ext, c0, ne, Q, QD, L0, FD, EX, PC, o_l0, k, m, n, E, flags):
    """Lanes 0..E-1 of the scratch take copies c0..c0+ne-1 (pad lanes repeat copy c0): the
    state ``q``, ``qd`` (B, k, 6) into Q, QD (k, 6, E), the rest lengths (the lane's defaults in
    ``PC`` with _L0DEF, else ``l0`` (1 or B, m)), force densities ``fd`` (with _FD) and external
    forces ``ext`` (with _EXT), each one row shared or one per copy."""
    l0def = (flags & _L0DEF) != 0
    has_fd = (flags & _FD) != 0
    has_ext = (flags & _EXT) != 0
    nl, nf, ne_ = l0.shape[0], fd.shape[0], ext.shape[0]
    for e in range(E):
        src = c0 + e if e < ne else c0          # pad lanes repeat the first environment
        for j in range(k):
            for i in range(6):
                Q[j, i, e] = q[src, j, i]
                QD[j, i, e] = qd[src, j, i]
        for s in range(m):
            L0[s, e] = PC[o_l0 + s, e] if l0def else l0[src if nl > 1 else 0, s]
        if has_fd:
            for s in range(m):
                FD[s, e] = fd[src if nf > 1 else 0, s]
        if has_ext:
            for p in range(n):
                for i in range(3):
                    EX[p, i, e] = ext[src if ne_ > 1 else 0, p, i]


def _advance_py(w, ib, L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes, E, contact):
    """``n_steps`` fixed steps of copies lo..hi-1 from (q[e], qd[e]) into (qo[e], qdo[e]) (which
    may be the same arrays): the one loop driver of the numba backend. E copies at a time in
    structure-of-arrays scratch (k, 6, E), so that every inner loop runs over copies and
    compiles to SIMD code; E = 1 (one copy at a time) for small batches. The equations are
    inlined (_acc, _rod_acc, _drift_rod, _project), so nothing is called per copy or per step.
    ``w``/``ib``: the packed buffer (topology; its physical constants where every copy shares
    them). ``lanes`` (ceil(B/E), len, E): the copies' packed buffers in blocks of E lanes
    (:func:`_lanes`, or (P, len, 1) for E = 1; per-copy parameters, ``lo`` a multiple of E),
    read in place: no copy per call; or (0, 1, 1): every copy uses ``w``'s constants.
    Its scratch (:func:`_scratch`) is made here: fresh arrays for SIMD blocks (which the
    compiler knows do not overlap), views of ``w``'s own scratch for E = 1.
    ``contact``: None (the instances without ground contact: the compiler prunes every
    ``contact is not None`` branch, so they carry no contact code) or the tuple
    (eta, rod_a, rod_c, prm, anchor, active, slip, cext) of the contact sub-steps: at the start
    of every step the contact forces of the lanes (:func:`_contact_lanes`, from the step's
    start, plus ``cext``) replace the external forces EX for that step (``flags`` carry
    ``_EXT``; ``ext`` is the (B, n, 3) output of the last step's forces); anchors, active and
    slip flags stay in lane scratch for all ``n_steps`` and are stored with the state."""
    S, N, V, F, L0, FD, EX, PC = _scratch(w, L, k, m, n, E, lanes.shape[0] > 0)
    if contact is not None:
        eta, rod_a, rod_c, prm, anchor, active, slip, cext = contact
        AN = np.empty((2 * k, 2, E))
        AC = np.zeros((2 * k, E), np.bool_)
        SL = np.zeros((2 * k, E), np.bool_)
    Q, QD, A1, A2, A3, A4, QS, QD2, QD3, QD4 = S[0], S[1], S[2], S[3], S[4], S[5], S[6], S[7], S[8], S[9]
    per_copy = lanes.shape[0] > 0
    rk4 = (flags & _RK4) != 0
    n_stages = 4 if rk4 else 1
    do_proj = (flags & _PROJ) != 0
    any_cons = (flags & _CONS) != 0
    acc_only = (flags & _ACC) != 0
    proj_only = (flags & _PONLY) != 0
    n_loop = 0 if proj_only else n_steps
    h = 0.5 * dt
    c6 = dt / 6.0
    o_l0 = L[2]
    o_rod = L[0]
    o_N = L[5]
    for c0 in range(lo, hi, E):
        ne = min(E, hi - c0)
        if per_copy:                                # this block's lane constants and anchor rows
            PC = lanes[c0 // E]
            if E == 1:
                # one copy at a time: its node scratch is its own buffer's node rows (anchors
                # included); the shared scratch of w would carry this copy's anchors into the
                # next call of copy 0, whose buffer w is
                N = _view(PC, o_N, (n, 3, 1))
            for p in range(n):
                for i in range(3):
                    for e in range(E):
                        N[p, i, e] = PC[o_N + 3 * p + i, e]
        _load(q, qd, l0, fd, ext, c0, ne, Q, QD, L0, FD, EX, PC, o_l0, k, m, n, E, flags)
        if contact is not None:
            _contact_load(anchor, active, AN, AC, c0, ne, k, E)
        if acc_only:                                # accelerations only (the entry `accelerations`)
            _acc(w, ib, L, k, m, n, Q, QD, A1, N, V, F, L0, FD, EX, E, flags, PC)
            for e in range(ne):
                for j in range(k):
                    for i in range(6):
                        qo[c0 + e, j, i] = Q[j, i, e]
                        qdo[c0 + e, j, i] = A1[j, i, e]
            continue
        if proj_only:                               # projection only (the entry `project`)
            _project(w, ib, o_rod, k, Q, QD, E, any_cons)
        for _ in range(n_loop):
            if contact is not None:                 # held over the step, as contact.step does
                _contact_lanes(Q, QD, EX, AN, AC, SL, eta, rod_a, rod_c, prm, cext, c0, ne, k, n, E)
            Qi = Q
            Vi = QD
            A = A1
            for stage in range(n_stages):
                _acc(w, ib, L, k, m, n, Qi, Vi, A, N, V, F, L0, FD, EX, E, flags, PC)
                if not rk4 and do_proj:
                    for j in range(k):
                        for i in range(6):
                            for e in range(E):
                                QD[j, i, e] = QD[j, i, e] + dt * A1[j, i, e]
                        for e in range(E):
                            (Q[j, 0, e], Q[j, 1, e], Q[j, 2, e], Q[j, 3, e], Q[j, 4, e], Q[j, 5, e],
                             QD[j, 3, e], QD[j, 4, e], QD[j, 5, e]) = _drift_rod(
                                Q[j, 0, e], Q[j, 1, e], Q[j, 2, e], Q[j, 3, e], Q[j, 4, e], Q[j, 5, e],
                                QD[j, 0, e], QD[j, 1, e], QD[j, 2, e], QD[j, 3, e], QD[j, 4, e],
                                QD[j, 5, e], dt)
                elif not rk4:
                    for j in range(k):
                        for i in range(6):
                            for e in range(E):
                                QD[j, i, e] = QD[j, i, e] + dt * A1[j, i, e]
                                Q[j, i, e] = Q[j, i, e] + dt * QD[j, i, e]
                elif stage == 0:
                    _stage_soa(Q, QD, QD, A1, h, QS, QD2, k, E)
                    Qi, Vi, A = QS, QD2, A2
                elif stage == 1:
                    _stage_soa(Q, QD, QD2, A2, h, QS, QD3, k, E)
                    Qi, Vi, A = QS, QD3, A3
                elif stage == 2:
                    _stage_soa(Q, QD, QD3, A3, dt, QS, QD4, k, E)
                    Qi, Vi, A = QS, QD4, A4
                else:
                    for j in range(k):
                        for i in range(6):
                            for e in range(E):
                                Q[j, i, e] = Q[j, i, e] + c6 * (QD[j, i, e] + 2.0 * QD2[j, i, e]
                                                                + 2.0 * QD3[j, i, e] + QD4[j, i, e])
                                QD[j, i, e] = QD[j, i, e] + c6 * (A1[j, i, e] + 2.0 * A2[j, i, e]
                                                                  + 2.0 * A3[j, i, e] + A4[j, i, e])
            if do_proj:
                _project(w, ib, o_rod, k, Q, QD, E, any_cons)
        for e in range(ne):
            for j in range(k):
                for i in range(6):
                    qo[c0 + e, j, i] = Q[j, i, e]
                    qdo[c0 + e, j, i] = QD[j, i, e]
        if contact is not None:
            _contact_store(anchor, active, slip, ext, AN, AC, SL, EX, c0, ne, k, n)

# The one driver, inlined into its two instances with E known to the compiler: SIMD blocks
# (E = 16 or 8) and one copy at a time (E = 1, lane loops dropped). Same source, same operations.
_advance_inline = njit(inline="always", **_opts)(_advance_py)

@njit(**_opts)
def _advance(w, ib, L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes):
    """_advance_py in SIMD blocks of E = :func:`_soa_width` copies (fresh scratch arrays)."""
    _advance_inline(w, ib, L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes,
                    _soa_width_nb(k), None)

@njit(**_opts)
def _advance_one(w, ib, L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes):
    """_advance one copy at a time (E = 1, a compile-time constant), in the scratch of ``w``."""
    _advance_inline(w, ib, L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes, 1, None)

@njit(**_opts)
def _advance_contact(w, ib, L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, contact):
    """_advance with ground contact (``contact`` the tuple of :func:`_advance_py`), in place on
    q, qd; ``W`` (B, n, 3) receives each copy's forces of its last step."""
    _advance_inline(w, ib, L, k, m, n, q, qd, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes,
                    _soa_width_nb(k), contact)

@njit(**_opts)
def _advance_one_contact(w, ib, L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, contact):
    """_advance_one with ground contact (see :func:`_advance_contact`)."""
    _advance_inline(w, ib, L, k, m, n, q, qd, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, 1, contact)

@njit(inline="always", **_opts)
def _serial_setup(bufs, B):
    """(layout, k, m, n, E, lanes) of serial calls on B copies with ``bufs`` (1, len)
    shared or (B, len) one packed buffer per copy; ``lanes`` is for E = 1 only (the buffers
    themselves, (B, len, 1)); a SIMD call takes the caller's :func:`_lanes` blocks."""
    ibs = bufs.view(np.int64)
    k, m, n = ibs[0, 0], ibs[0, 1], ibs[0, 2]
    L = _layout_nb(k, m, n)
    E = _lane_width(k, B)
    per_copy = bufs.shape[0] > 1
    lanes = _view(bufs, 0, (bufs.shape[0] if per_copy else 0, bufs.shape[1], 1))
    return L, k, m, n, E, lanes

@njit(inline="always", **_opts)
def _serial(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, lanes, setup):
    """The serial step of every copy (checks, then the driver: its E = 1 instance for one copy
    at a time); ``setup`` from :func:`_serial_setup`, reusable for repeated calls (the contact
    sub-steps). Returns the error code (0: done)."""
    L, k, m, n, E, lanes1 = setup
    err = _check(q, qd, qo, qdo, k, m, n, l0, fd, ext, flags)
    if err == 0 and bufs.shape[0] != q.shape[0] and bufs.shape[0] != 1:
        err = 7
    if err:
        return err
    ib = bufs[0].view(np.int64)
    if E == 1:
        _advance_one(bufs[0], ib, L, k, m, n, q, qd, qo, qdo, 0, q.shape[0], l0, fd, ext, dt, n_steps, flags,
                     lanes1)
    else:
        _advance(bufs[0], ib, L, k, m, n, q, qd, qo, qdo, 0, q.shape[0], l0, fd, ext, dt, n_steps, flags,
                 _view(lanes, 0, (lanes.shape[0] if bufs.shape[0] > 1 else 0, lanes.shape[1], lanes.shape[2])))
    return 0


@njit(**_opts)
def _check(q, qd, qo, qdo, k, m, n, l0, fd, ext, flags):
    B = q.shape[0]
    if q.shape[1] != k or q.shape[2] != 6:
        return 1
    if qd.shape[0] != B or qd.shape[1] != k or qd.shape[2] != 6:
        return 2
    if qo.shape[0] != B or qo.shape[1] != k or qo.shape[2] != 6:
        return 6
    if qdo.shape[0] != B or qdo.shape[1] != k or qdo.shape[2] != 6:
        return 6
    if (flags & _L0DEF) == 0 and (l0.shape[1] != m or (l0.shape[0] != 1 and l0.shape[0] != B)):
        return 3
    if (flags & _FD) != 0 and (fd.shape[1] != m or (fd.shape[0] != 1 and fd.shape[0] != B)):
        return 4
    if (flags & _EXT) != 0 and (ext.shape[1] != n or ext.shape[2] != 3
                                or (ext.shape[0] != 1 and ext.shape[0] != B)):
        return 5
    return 0

# explicit signatures (no other variant is ever compiled): C-contiguous float64 arrays
_f8 = numba.types.float64
_a1, _a2, _a3 = (numba.types.Array(_f8, d, "C") for d in (1, 2, 3))
_i64 = numba.types.int64
_SIG = _i64(_a3, _a3, _a3, _a3, _a1, _a2, _a2, _a3, _f8, _i64, _i64)
_SIG_LEAN = _i64(_a3, _a3, _a3, _a3, _a1, _f8, _i64, _i64)
_SIG_COPIES = _i64(_a3, _a3, _a3, _a3, _a2, _a2, _a2, _a3, _f8, _i64, _i64, _a3)
_SIG_FORCES = _i64(_a3, _a3, _a2, _a2, _a2, _a3, _i64, _a2, _a2, _a3)

# Entry points are compiled lazily for ONE explicit signature each (see _compile): the serial
# ones on first use of any model, the parallel one on first use of a large batch.
@njit(cache=True, fastmath=False, error_model="numpy")   # holds the GIL: it uses the scratch inside buf
def _run_serial(q, qd, qo, qdo, buf, l0, fd, ext, dt, n_steps, flags):
    bufs = _view(buf, 0, (1, buf.shape[0]))
    return _serial(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, _view(buf, 0, (1, buf.shape[0], 1)),
                   _serial_setup(bufs, q.shape[0]))

@njit(cache=True, fastmath=False, error_model="numpy")
def _run_lean(q, qd, qo, qdo, buf, dt, n_steps, flags):
    """_run_serial with the model's rest lengths and no force density / external force:
    three array arguments fewer to convert at the Python boundary (single-env fast path)."""
    flags = (flags | _L0DEF) & ~(_FD | _EXT)
    d2 = q[0]                             # placeholders of the right type, never read
    bufs = _view(buf, 0, (1, buf.shape[0]))
    return _serial(q, qd, qo, qdo, bufs, d2, d2, q, dt, n_steps, flags, _view(buf, 0, (1, buf.shape[0], 1)),
                   _serial_setup(bufs, q.shape[0]))

@njit(inline="always", **_opts)
def _copies_check(q, qd, qo, qdo, bufs, l0, fd, ext, flags, shared):
    """(error code, int64 view of bufs, layout, k, m, n) of a call on packed buffers (P, len):
    the shape checks of _check, and one buffer per copy of q, or one (``shared`` allowed)
    (error 7 otherwise)."""
    ibs = bufs.view(np.int64)
    k, m, n = ibs[0, 0], ibs[0, 1], ibs[0, 2]
    err = _check(q, qd, qo, qdo, k, m, n, l0, fd, ext, flags)
    if err == 0 and ibs.shape[0] != q.shape[0] and not (shared and ibs.shape[0] == 1):
        err = 7
    return err, ibs, _layout_nb(k, m, n), k, m, n

# holds the GIL too: then no two Python threads can be inside the thread pool at once (the
# workqueue threading layer, chosen below, does not support concurrent callers)
# Per-copy parameters: bufs (P, len) holds one packed buffer per copy (its physics and its
# scratch, P = B), or the one buffer shared by every copy (P = 1).
@njit(parallel=True, cache=True, fastmath=False, error_model="numpy")
def _run_parallel(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, lanes):
    """The batch in chunks of whole SIMD blocks on all threads (``prange``), each chunk the
    SIMD loop; ``bufs`` (1, len) shared or (B, len) one packed buffer per copy, ``lanes`` their
    lane blocks (:func:`_lanes`) or (0, 1, 1)."""
    err, ibs, L, k, m, n = _copies_check(q, qd, qo, qdo, bufs, l0, fd, ext, flags, True)
    if err:
        return err
    B = q.shape[0]
    E = _soa_width_nb(k)
    nb = (B + E - 1) // E                             # SIMD blocks
    nch = min(nb, max(flags >> _CHUNK_SHIFT, 1))      # number of chunks in the high bits of flags
    for c in prange(nch):
        # _advance only reads the buffers; each chunk has its own scratch: threads share nothing written
        _advance(bufs[0], ibs[0], L, k, m, n, q, qd, qo, qdo, (c * nb // nch) * E,
                 min(B, ((c + 1) * nb // nch) * E), l0, fd, ext, dt, n_steps, flags, lanes)
    return 0



@njit(cache=True, nogil=True)
def finite_pair(a, b):
    """True if every entry of the C-contiguous float64 arrays ``a`` and ``b`` (3-D: a state's
    ``q``, ``qd``) is finite: the input check of ``integrators.step`` in one compiled pass.
    It counts entries whose exponent bits are all set (inf or NaN) with integer operations,
    which the compiler vectorises (a float test per entry would not be)."""
    bad = 0
    for x in (a, b):
        bits = x.reshape(-1).view(np.int64)
        for i in range(bits.size):
            bad += (bits[i] & 0x7FF0000000000000) == 0x7FF0000000000000
    return bad == 0

# one packed buffer per copy (bufs (B, len)), each lane reading its copy's constants
@njit(cache=True, fastmath=False, error_model="numpy")
def _run_copies_serial(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, lanes):
    return _serial(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, lanes, _serial_setup(bufs, q.shape[0]))


@njit(cache=True, fastmath=False, error_model="numpy")   # holds the GIL: it uses the scratch inside bufs
def _run_forces(q, qd, bufs, l0, fd, ext, flags, G, LS, FO):
    """The string force densities G (B, m), N/m, string lengths LS (B, m), m, and total nodal
    forces FO (B, n, 3), N, of the states ``q``, ``qd`` (B, k, 6): :func:`_forces` (the
    equations every step runs) one copy at a time, each with its packed buffer ``bufs[b]``
    ((B, len) per copy, or (1, len) shared). Returns the error code (0: done)."""
    err, ibs, L, k, m, n = _copies_check(q, qd, q, qd, bufs, l0, fd, ext, flags, True)
    if err:
        return err
    if G.shape[0] != q.shape[0] or G.shape[1] != m or LS.shape[0] != q.shape[0] or LS.shape[1] != m \
            or FO.shape[0] != q.shape[0] or FO.shape[1] != n or FO.shape[2] != 3:
        return 6
    per_copy = bufs.shape[0] > 1
    g1 = np.empty((m, 1))
    ls1 = np.empty((m, 1))
    for b in range(q.shape[0]):
        w = bufs[b if per_copy else 0]        # the copy's own buffer: its constants, anchors and scratch
        ib = ibs[b if per_copy else 0]
        S, N, V, F, L0, FD, EX, PC = _scratch(w, L, k, m, n, 1, False)
        _load(q, qd, l0, fd, ext, b, 1, S[0], S[1], L0, FD, EX, PC, L[2], k, m, n, 1, flags)
        _forces(w, ib, L, k, m, n, S[0], S[1], N, V, F, L0, FD, EX, 1, flags, PC, g1, ls1, True)
        for s in range(m):
            G[b, s] = g1[s, 0]
            LS[b, s] = ls1[s, 0]
        for p in range(n):
            for i in range(3):
                FO[b, p, i] = F[p, i, 0]
    return 0


# ---------------------------------------------------------------------- Python side
_CACHE: dict = {}
_STEPPERS = {"semi_implicit_euler": 0, "rk4": _RK4}


def clear_cache() -> None:
    """Forget the packed per-model arrays (they are rebuilt on the next call)."""
    _CACHE.clear()


class _Packed:
    """Packed buffer(s) of one model or one Params: ``buf`` (len,) for values shared by every
    copy, or ``bufs`` (B, len) one per copy (then ``buf`` is None)."""
    __slots__ = ("buf", "bufs", "lanes", "l0", "fd", "ext", "flags", "cost", "__weakref__")


def _fill_physics(buf, model, p, b):
    """Write the physical values of row ``b`` of ``p`` (the model itself, b = None, or a
    :class:`~tensegrity_gym.params.Params`) into the packed buffer ``buf`` (see ``_layout``)."""
    k, n, m = model.n_bars, model.n_nodes, model.n_strings
    o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end = _layout(k, m, n)
    row = (lambda a: a) if b is None else (lambda a: a[b])   # noqa: E731
    mass_, f_, J_ = row(p.mass), row(p.f), row(p.J)
    for j in range(k):
        rj = o_rod + _ROD * j
        mass, f, J = float(mass_[j]), float(f_[j]), float(J_[j])
        alpha = mass - f * f / J
        buf[rj + 5:rj + 12] = (1.0 / mass, 1.0 / J, f / J, f * f / J, alpha, 1.0 / alpha, f)
    ps = o_str + _STR * np.arange(m)
    buf[ps + 2] = row(p.stiffness)
    buf[ps + 3] = row(p.damping)
    buf[o_l0:o_l0 + m] = row(p.rest_length)
    buf[o_W0:o_W0 + 3 * n] = row(p.W0).reshape(-1)
    buf[o_cn:o_cn + 3 * n] = np.repeat(row(p.node_damping), 3)
    for a, pos in zip(model.anchor_idx, row(p.anchor_pos)):   # anchor rows of the node scratch
        buf[o_N + 3 * a:o_N + 3 * a + 3] = pos


def _physics_flags(model, p):
    return ((_DAMP if p.has_damping else 0) | (_GRAV if p.has_gravity else 0)
            | (_CONS if bool(np.any(model.constrained)) else 0) | (_NDAMP if p.has_node_damping else 0))


def _pack(model):
    """Pack the model into one float64 buffer (see ``_layout``) plus default control arrays;
    cached by id(model) for the model's lifetime."""
    k, n, m = model.n_bars, model.n_nodes, model.n_strings
    o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end = _layout(k, m, n)
    buf = np.zeros(end)
    ib = buf.view(np.int64)
    ib[0:3] = (k, m, n)
    for j in range(k):
        rj = o_rod + _ROD * j
        ib[rj:rj + 3] = (model.rod_a[j], model.rod_c[j], int(bool(model.constrained[j])))
        buf[rj + 3:rj + 5] = (model.eta[j, 0], model.eta[j, 1])
        buf[rj + 12:rj + 21] = model.proj[j].reshape(-1)
        buf[rj + 21:rj + 24] = model.offset[j]
    for s in range(m):
        ps = o_str + _STR * s
        ib[ps:ps + 2] = (model.str_i[s], model.str_j[s])
    _fill_physics(buf, model, model, None)
    p = _Packed()
    p.buf = buf
    p.bufs = None
    p.lanes = _NO_LANES
    p.l0 = np.array(model.rest_length, dtype=np.float64).reshape(1, m)
    p.fd = np.zeros((1, m))
    p.ext = np.zeros((1, n, 3))
    p.cost = m + k
    p.flags = _physics_flags(model, model)
    key = id(model)
    _CACHE[key] = p
    weakref.finalize(model, _CACHE.pop, key, None)
    return p


def _pack_params(model, params):
    """The packed buffers of ``params`` (a :class:`~tensegrity_gym.params.Params` of this
    model): one shared buffer when it has one row (then the kernels run exactly as for the
    model), else one buffer per copy. Cached by id(params) for the params' lifetime."""
    key = ("params", id(params), id(model))
    p = _CACHE.get(key)
    if p is not None:
        return p
    base = _CACHE.get(id(model)) or _packed(model)
    P = params.batch_size
    parent = params.parent() if params.parent is not None else None
    pp = None if parent is None else _CACHE.get(("params", id(parent), id(model)))
    if pp is not None and pp.bufs is not None and pp.bufs.shape[0] == P:
        bufs = pp.bufs.copy()            # Params.set_rows: only its changed rows differ from the parent
        rows = params.changed_rows
    else:
        bufs = np.repeat(base.buf[None], P, axis=0)
        rows = range(P)
    for b in rows:
        _fill_physics(bufs[b], model, params, b)
    p = _Packed()
    p.buf, p.bufs = (bufs[0], None) if P == 1 else (None, bufs)
    p.lanes = _NO_LANES if P == 1 else _lanes(bufs, model.n_bars)
    p.l0 = np.array(params.rest_length[:1], dtype=np.float64)
    p.fd, p.ext, p.cost = base.fd, base.ext, base.cost
    p.flags = _physics_flags(model, params)
    _CACHE[key] = p
    weakref.finalize(params, _CACHE.pop, key, None)
    return p


_NO_LANES = np.empty((0, 1, 1))   # no per-copy lane blocks: the SIMD loop takes the shared buffer's constants


def _lanes(bufs, k):
    """(ceil(P/E), len, E): the per-copy buffers ``bufs`` (P, len) in blocks of E copies, lane
    e of block c holding copy c E + e (the SIMD loop reads its lane constants from it in place);
    the pad lanes of the last block repeat its first copy, as the SIMD loop's pad lanes do."""
    P, size = bufs.shape
    E = _soa_width(k)
    nb = -(-P // E)
    idx = np.arange(nb * E)
    idx = np.where(idx < P, idx, (idx // E) * E)
    return np.ascontiguousarray(bufs[idx].reshape(nb, E, size).transpose(0, 2, 1))


def _array(x, ndim, what):
    """A C-contiguous, writable float64 copy/view of x with a leading batch axis added if needed."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == ndim - 1:
        x = x[None]
    if x.ndim != ndim:
        raise ValueError(f"{what}: expected a {ndim - 1}- or {ndim}-dimensional array, got shape {x.shape}")
    if not (x.flags.c_contiguous and x.flags.writeable):
        x = np.array(x, dtype=np.float64, order="C")
    return x


def _check_inplace(q, qd):
    for x, nm in ((q, "q"), (qd, "qd")):
        if not (isinstance(x, np.ndarray) and x.dtype == np.float64 and x.ndim == 3
                and x.flags.c_contiguous and x.flags.writeable):
            raise ValueError(f"step_inplace: {nm} must be a writable C-contiguous float64 array (B, k, 6); "
                             f"got {type(x).__name__} {getattr(x, 'dtype', '')} {np.shape(x)}")


def _slow_call(model, p, q, qd, qo, qdo, l0, fd, ext, dt, n_steps, flags, inplace):
    """After a TypeError at the kernel boundary: convert the inputs (C-contiguous, writable
    float64, batch axis added) and call the general kernel. In place, q and qd must already
    be writable C-contiguous float64 arrays (B, k, 6)."""
    if inplace:
        _check_inplace(q, qd)
        qo, qdo = q, qd
    else:
        q, qd = _array(q, 3, "state.q"), _array(qd, 3, "state.qd")
    l0, fd, ext = _array(l0, 2, "rest_length"), _array(fd, 2, "force_density"), _array(ext, 3, "external")
    if not (isinstance(dt, (int, float, np.floating, np.integer)) and isinstance(n_steps, (int, np.integer))):
        raise TypeError(f"dt must be a number of seconds and n_steps an integer; got {dt!r}, {n_steps!r}")
    flags |= _NCHUNK << _CHUNK_SHIFT
    if _parallel(p, q.shape[0], n_steps, flags):
        return _run_parallel(q, qd, qo, qdo, p.buf[None], l0, fd, ext, float(dt), int(n_steps), flags, p.lanes)
    return _run_serial(q, qd, qo, qdo, p.buf, l0, fd, ext, float(dt), int(n_steps), flags)


def _raise(err, model, q, qd, l0, fd, ext):
    raise ValueError(_ERRORS[err].format(k=model.n_bars, m=model.n_strings, n=model.n_nodes)
                     + f"; got q {np.shape(q)}, qd {np.shape(qd)}, rest_length {np.shape(l0)}, "
                     f"force_density {np.shape(fd)}, external {np.shape(ext)}")


def _flags(p, name, project):
    try:
        flags = p.flags | _STEPPERS[name]
    except KeyError:
        raise ValueError(f"integrator: the numba kernels implement {sorted(_STEPPERS)}, got {name!r}") from None
    return flags | _PROJ if project else flags


def _controls(p, flags, rest_length, force_density, external):
    """Control arrays for the general kernel (defaults from the packed model) and the flags."""
    l0, fd, ext = p.l0, p.fd, p.ext
    if rest_length is None:
        flags |= _L0DEF
    else:
        l0 = rest_length if getattr(rest_length, "ndim", 0) == 2 else _array(rest_length, 2, "rest_length")
    if force_density is not None:
        fd = force_density if getattr(force_density, "ndim", 0) == 2 else _array(force_density, 2, "force_density")
        flags |= _FD
    if external is not None:
        if callable(external):
            raise TypeError("external: the numba kernels take an array held over the step; "
                            "integrators.step evaluates a callable and passes its arrays")
        ext = external if getattr(external, "ndim", 0) == 3 else _array(external, 3, "external")
        flags |= _EXT
    return l0, fd, ext, flags


_READY = {"serial": False, "parallel": False, "copies": False, "forces": False}


def _compile(which: str) -> None:
    """Compile (or load from numba's on-disk cache) the serial entry points or the parallel one
    for their single signature, then forbid further compilation: an argument of another type
    raises TypeError (handled by converting it) instead of compiling a new variant."""
    from ._compile_notice import compile_with_notice   # says so on stderr when numba really compiles
    if which == "serial":
        pairs = ((_run_lean, _SIG_LEAN), (_run_serial, _SIG))
    elif which == "copies":
        pairs = ((_run_copies_serial, _SIG_COPIES),)
    elif which == "forces":
        pairs = ((_run_forces, _SIG_FORCES),)
    else:
        pairs = ((_run_parallel, _SIG_COPIES),)
    compile_with_notice(pairs, f"{'physics' if which == 'serial' else which + ' physics'} kernels")
    for disp, _ in pairs:
        disp.disable_compile()
    _READY[which] = True


def _parallel(p, B, n_steps, flags, compile_kernel=True):
    """True if this call should run the multi-threaded kernel (see PARALLEL_MIN_WORK); compiles
    ``_run_parallel`` then unless ``compile_kernel`` is False (a caller with its own parallel kernel)."""
    try:
        work = B * int(n_steps) * p.cost * (4 if flags & _RK4 else 1)
    except (TypeError, ValueError):
        return False
    if work < PARALLEL_MIN_WORK:
        return False
    if compile_kernel and not _READY["parallel"]:
        _compile("parallel")
    return True


def _packed(model):
    if not _READY["serial"]:
        _compile("serial")
    return _pack(model)


def _copies_step(model, p, q, qd, qo, qdo, rest_length, force_density, external, dt, n_steps, flags, inplace):
    """:func:`step` / :func:`step_inplace` with per-copy buffers ``p.bufs`` (B, len)."""
    if inplace:
        _check_inplace(q, qd)
        qo, qdo = q, qd
    else:
        q, qd = _array(q, 3, "state.q"), _array(qd, 3, "state.qd")
    err = _copies_call(p, q, qd, qo, qdo, rest_length, force_density, external, dt, n_steps, flags)
    if err:
        _raise(err, model, q, qd, rest_length, force_density, external)


def _copies_call(p, q, qd, qo, qdo, rest_length, force_density, external, dt, n_steps, flags):
    """One step call with per-copy buffers ``p.bufs`` (B, len): inputs converted at the boundary."""
    if not _READY["copies"]:
        _compile("copies")
    l0, fd, ext, flags = _controls(p, flags, rest_length, force_density, external)
    l0, fd, ext = _array(l0, 2, "rest_length"), _array(fd, 2, "force_density"), _array(ext, 3, "external")
    if not (isinstance(dt, (int, float, np.floating, np.integer)) and isinstance(n_steps, (int, np.integer))):
        raise TypeError(f"dt must be a number of seconds and n_steps an integer; got {dt!r}, {n_steps!r}")
    B = q.shape[0]
    work = B * int(n_steps) * p.cost * (4 if flags & _RK4 else 1)
    if B >= 8 and work >= PARALLEL_MIN_WORK:
        if not _READY["parallel"]:
            _compile("parallel")
        return _run_parallel(q, qd, qo, qdo, p.bufs, l0, fd, ext, float(dt), int(n_steps),
                             flags | (_NCHUNK << _CHUNK_SHIFT), p.lanes)
    return _run_copies_serial(q, qd, qo, qdo, p.bufs, l0, fd, ext, float(dt), int(n_steps), flags, p.lanes)


def step(model, state, dt, name, *, rest_length=None, force_density=None, external=None, project=True,
         n_steps=1, params=None):
    """Advance ``state`` by ``n_steps`` fixed steps of ``dt`` s with the compiled kernel.

    Same contract as :func:`tensegrity_gym.integrators.step` (``name`` in
    ``{"semi_implicit_euler", "rk4"}``); returns a new :class:`~tensegrity_gym.dynamics.State`
    with ``q``, ``qd`` (B, k, 6) and ``t = state.t + n_steps * dt`` (summed step by step, as
    the NumPy path does). The input state is not modified. ``params``: per-copy physical values
    (:class:`~tensegrity_gym.params.Params`, 1 or B rows)."""
    p = (_CACHE.get(id(model)) or _packed(model)) if params is None else _pack_params(model, params)
    flags = _flags(p, name, project)
    q = state.q
    qd = state.qd
    qo = np.empty(q.shape)
    qdo = np.empty(q.shape)
    if p.bufs is not None:
        _copies_step(model, p, q, qd, qo, qdo, rest_length, force_density, external, dt, n_steps, flags, False)
    else:
        _shared_step(model, p, q, qd, qo, qdo, rest_length, force_density, external, dt, n_steps, flags)
    t = state.t + dt
    for _ in range(n_steps - 1):
        t = t + dt
    return _new_state(qo, qdo, t)


def _shared_step(model, p, q, qd, qo, qdo, rest_length, force_density, external, dt, n_steps, flags):
    """The kernels with one packed buffer ``p.buf`` shared by every copy (``qo is q``: in place)."""
    flags0 = flags
    big = q.shape[0] >= 8 and _parallel(p, q.shape[0], n_steps, flags)
    try:
        if rest_length is None and force_density is None and external is None and not big:
            err = _run_lean(q, qd, qo, qdo, p.buf, dt, n_steps, flags)
        else:
            l0, fd, ext, flags = _controls(p, flags, rest_length, force_density, external)
            if big:
                err = _run_parallel(q, qd, qo, qdo, p.buf[None], l0, fd, ext, dt, n_steps,
                                    flags | (_NCHUNK << _CHUNK_SHIFT), p.lanes)
            else:
                err = _run_serial(q, qd, qo, qdo, p.buf, l0, fd, ext, dt, n_steps, flags)
    except TypeError:
        l0, fd, ext, flags = _controls(p, flags0, rest_length, force_density, external)
        err = _slow_call(model, p, q, qd, qo, qdo, l0, fd, ext, dt, n_steps, flags, qo is q)
    if err:
        _raise(err, model, q, qd, rest_length, force_density, external)


def step_inplace(model, q, qd, dt, name="semi_implicit_euler", *, rest_length=None, force_density=None,
                 external=None, project=True, n_steps=1, params=None):
    """Advance ``q``, ``qd`` (B, k, 6), writable C-contiguous float64 arrays (m, 1, m/s, 1/s),
    **in place** by ``n_steps`` steps of ``dt`` s. The fast path for environments that own
    their state arrays: no allocation, no :class:`State`. Other arguments as :func:`step`.
    Returns None; the caller tracks time. ``params``: per-copy physical values, as in :func:`step`."""
    p = (_CACHE.get(id(model)) or _packed(model)) if params is None else _pack_params(model, params)
    flags = _flags(p, name, project)
    if p.bufs is not None:
        _copies_step(model, p, q, qd, q, qd, rest_length, force_density, external, dt, n_steps, flags, True)
    else:
        _shared_step(model, p, q, qd, q, qd, rest_length, force_density, external, dt, n_steps, flags)


def accelerations(model, q, qd, rest_length=None, force_density=None, external=None, params=None):
    """Accelerations ``[r'', b'']`` (B, k, 6) (m/s^2, 1/s^2) of the state ``q``, ``qd`` ((B, k, 6)
    or (k, 6): the result has the same shape): :func:`tensegrity_gym.dynamics.accelerations` (the
    NumPy reference; equal to round-off, ``tests/test_kernels.py``) computed by the loop driver's
    own force and rod equations (``_acc``), no step taken. Inputs as :func:`step`."""
    p = (_CACHE.get(id(model)) or _packed(model)) if params is None else _pack_params(model, params)
    flags = p.flags | _ACC
    shape = np.shape(q)
    q, qd = _array(q, 3, "q"), _array(qd, 3, "qd")
    qo, qdo = np.empty(q.shape), np.empty(q.shape)
    if p.bufs is not None:
        _copies_step(model, p, q, qd, qo, qdo, rest_length, force_density, external, 0.0, 1, flags, False)
    else:
        _shared_step(model, p, q, qd, qo, qdo, rest_length, force_density, external, 0.0, 1, flags)
    return qdo.reshape(shape)


def string_forces(model, q, qd, rest_length=None, force_density=None, external=None, params=None):
    """``(gamma, L, F)`` of the states ``q``, ``qd`` (B, k, 6): string force densities gamma
    (B, m), N/m (tension / length, >= 0), string lengths L (B, m), m, and total nodal forces F
    (B, n, 3), N (strings, gravity, node drag, ``external``): the loop driver's own force
    equations (:func:`_forces`, what every step evaluates), no step taken. Inputs as
    :func:`step` (``external`` an array); ``params`` per-copy physical values (1 or B rows)."""
    p = (_CACHE.get(id(model)) or _packed(model)) if params is None else _pack_params(model, params)
    if not _READY["forces"]:
        _compile("forces")
    q, qd = _array(q, 3, "q"), _array(qd, 3, "qd")
    l0, fd, ext, flags = _controls(p, p.flags, rest_length, force_density, external)
    l0, fd, ext = _array(l0, 2, "rest_length"), _array(fd, 2, "force_density"), _array(ext, 3, "external")
    B, m, n = q.shape[0], model.n_strings, model.n_nodes
    G, LS, F = np.empty((B, m)), np.empty((B, m)), np.empty((B, n, 3))
    bufs = p.bufs if p.bufs is not None else p.buf[None]
    err = _run_forces(q, qd, bufs, l0, fd, ext, flags, G, LS, F)
    if err:
        _raise(err, model, q, qd, rest_length, force_density, external)
    return G, LS, F


def project(model, q, qd):
    """``(q, qd)`` projected onto the constraints ((B, k, 6) or (k, 6), new arrays of the same
    shape): ``|b| = 1``, ``b . b' = 0``, constrained reference points back on their point, line
    or plane with their velocity tangent to it; free rods' reference points untouched. The loop
    driver's own ``_project`` (what every fixed step with ``project=True`` ends with), no step
    taken. The projection is topology only: per-copy parameters do not enter it."""
    p = _CACHE.get(id(model)) or _packed(model)
    flags = (p.flags & _CONS) | _PONLY | _L0DEF
    shape = np.shape(q)
    q, qd = _array(q, 3, "q"), _array(qd, 3, "qd")
    qo, qdo = np.empty(q.shape), np.empty(q.shape)
    _shared_step(model, p, q, qd, qo, qdo, None, None, None, 0.0, 1, flags)
    return qo.reshape(shape), qdo.reshape(shape)


from .dynamics import State  # noqa: E402  (after the kernels: dynamics never imports this module)

_NCHUNK = 4 * numba.get_num_threads()   # chunks of the parallel batch loop


def _fast_state_ok() -> bool:
    import dataclasses
    return (dataclasses.is_dataclass(State) and [f.name for f in dataclasses.fields(State)] == ["q", "qd", "t"]
            and not hasattr(State, "__post_init__") and not hasattr(State, "__slots__"))


if _fast_state_ok():
    _object_new = object.__new__

    def _new_state(q, qd, t):
        """State(q=q, qd=qd, t=t) without the frozen dataclass __init__ (3x faster; same object)."""
        s = _object_new(State)
        d = s.__dict__
        d["q"] = q
        d["qd"] = qd
        d["t"] = t
        return s
else:  # pragma: no cover - State changed shape: use its constructor
    def _new_state(q, qd, t):
        return State(q=q, qd=qd, t=t)
