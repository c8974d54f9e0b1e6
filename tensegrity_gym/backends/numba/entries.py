"""The compiled entry kernels of the numba backend, each for ONE explicit signature
(C-contiguous float64 arrays; other inputs are converted at the boundary by :mod:`.api`, never
compiled again): ``_run_lean`` (no control arrays: the single-env fast path), ``_run_serial``,
``_run_copies_serial`` (one packed buffer per copy), ``_run_parallel`` (``prange`` over chunks
of the batch), ``_run_forces`` (string and nodal forces, no step), the contact loops
``_contact_loop`` / ``_contact_parallel`` and :func:`run_plan` (a fused caller's step).

The serial kernels come in two instances of the one loop driver, which compute the same numbers:
one copy at a time (``_run_lean``, ``_run_serial``, ``_contact_loop``, ``run_plan``; any batch)
and in SIMD blocks (``_run_serial_simd``, ``_contact_loop_simd``, ``run_plan_simd``; from
``_SOA_MIN_BATCH`` copies, error 9 below). Each kernel holds one instance only, so a single env
compiles the one-copy instance and never the SIMD one (the compile is the first-run cost a user
waits for); the Python side picks by the batch size.
"""
from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from .driver import (_drive_lanes, _drive_lanes_contact, _drive_one, _drive_one_contact, _load, _scratch,
                     _view)
from .equations import _acc, _forces, _project
from .layout import _CHUNK_SHIFT, _CONS, _EXT, _FD, _L0DEF, _lane_width, _layout_nb, _opts, _soa_width_nb

@njit(inline="always", **_opts)
def _chunks(B, k, flags):
    """(E, blocks, chunks) of a threaded call on B copies: SIMD blocks of E copies, split into
    the chunk count carried in the high bits of ``flags`` (at most one chunk per block)."""
    E = _soa_width_nb(k)
    nb = (B + E - 1) // E
    return E, nb, min(nb, max(flags >> _CHUNK_SHIFT, 1))

@njit(inline="always", **_opts)
def _chunk(c, E, nb, nch, B):
    """(lo, hi): the copies of chunk c, whole SIMD blocks."""
    return (c * nb // nch) * E, min(B, ((c + 1) * nb // nch) * E)

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
def _serial_checks(q, qd, qo, qdo, bufs, l0, fd, ext, flags, setup):
    """The error code of a serial call's inputs (0: fine)."""
    L, k, m, n, E, lanes1 = setup
    err = _check(q, qd, qo, qdo, k, m, n, l0, fd, ext, flags)
    if err == 0 and bufs.shape[0] != q.shape[0] and bufs.shape[0] != 1:
        err = 7
    return err


@njit(inline="always", **_opts)
def _serial_one(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, setup):
    """The serial step of every copy, one copy at a time (the driver's E = 1 instance only: a
    kernel built on this never compiles the SIMD one). Any batch size; from ``_SOA_MIN_BATCH``
    copies :func:`_serial_simd` computes the same numbers faster. ``setup`` from
    :func:`_serial_setup`, reusable for repeated calls. Returns the error code (0: done)."""
    L, k, m, n, E, lanes1 = setup
    err = _serial_checks(q, qd, qo, qdo, bufs, l0, fd, ext, flags, setup)
    if err:
        return err
    _drive_one(bufs[0], bufs[0].view(np.int64), L, k, m, n, q, qd, qo, qdo, 0, q.shape[0], l0, fd, ext, dt,
               n_steps, flags, lanes1)
    return 0


@njit(inline="always", **_opts)
def _serial_simd(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, lanes, setup):
    """:func:`_serial_one` for a batch of ``_SOA_MIN_BATCH`` copies or more: the SIMD instance
    only, in blocks of E copies (``lanes``: the copies' lane blocks, or (0, 1, 1)); error 9 for
    a smaller batch."""
    L, k, m, n, E, lanes1 = setup
    err = _serial_checks(q, qd, qo, qdo, bufs, l0, fd, ext, flags, setup)
    if err:
        return err
    if E == 1:
        return 9
    _drive_lanes(bufs[0], bufs[0].view(np.int64), L, k, m, n, q, qd, qo, qdo, 0, q.shape[0], l0, fd, ext, dt,
                 n_steps, flags,
                 _view(lanes, 0, (lanes.shape[0] if bufs.shape[0] > 1 else 0, lanes.shape[1], lanes.shape[2])))
    return 0


@njit(inline="always", **_opts)
def _serial(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, lanes, setup):
    """The serial step of every copy, whichever the batch size (:func:`_serial_one` below
    ``_SOA_MIN_BATCH`` copies, else :func:`_serial_simd`). Returns the error code (0: done)."""
    if setup[4] == 1:
        return _serial_one(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, setup)
    return _serial_simd(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, lanes, setup)


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
_SIG_ACC = _i64(_a3, _a3, _a2, _a2, _a2, _a3, _i64, _a3)
_SIG_PROJECT = _i64(_a3, _a3, _a2, _i64, _a3, _a3)

# Entry points are compiled lazily for ONE explicit signature each (see _compile): the serial
# ones on first use of any model, the parallel one on first use of a large batch.
@njit(cache=True, fastmath=False, error_model="numpy")   # holds the GIL: it uses the scratch inside buf
def _run_serial(q, qd, qo, qdo, buf, l0, fd, ext, dt, n_steps, flags):
    """A serial step, one copy at a time (:func:`_serial_one`)."""
    bufs = _view(buf, 0, (1, buf.shape[0]))
    return _serial_one(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, _serial_setup(bufs, q.shape[0]))


@njit(cache=True, fastmath=False, error_model="numpy")   # holds the GIL: it uses the scratch inside buf
def _run_serial_simd(q, qd, qo, qdo, buf, l0, fd, ext, dt, n_steps, flags):
    """A serial step of ``_SOA_MIN_BATCH`` copies or more (:func:`_serial_simd`; error 9 otherwise)."""
    bufs = _view(buf, 0, (1, buf.shape[0]))
    return _serial_simd(q, qd, qo, qdo, bufs, l0, fd, ext, dt, n_steps, flags, _view(buf, 0, (1, buf.shape[0], 1)),
                        _serial_setup(bufs, q.shape[0]))

@njit(cache=True, fastmath=False, error_model="numpy")
def _run_lean(q, qd, qo, qdo, buf, dt, n_steps, flags):
    """_run_serial with the model's rest lengths and no force density / external force:
    three array arguments fewer to convert at the Python boundary (single-env fast path)."""
    flags = (flags | _L0DEF) & ~(_FD | _EXT)
    d2 = q[0]                             # placeholders of the right type, never read
    bufs = _view(buf, 0, (1, buf.shape[0]))
    return _serial_one(q, qd, qo, qdo, bufs, d2, d2, q, dt, n_steps, flags, _serial_setup(bufs, q.shape[0]))

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
    E, nb, nch = _chunks(B, k, flags)
    for c in prange(nch):
        # _drive_lanes only reads the buffers; each chunk has its own scratch: threads share nothing written
        lo, hi = _chunk(c, E, nb, nch, B)
        _drive_lanes(bufs[0], ibs[0], L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes)
    return 0



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


@njit(cache=True, fastmath=False, error_model="numpy")   # holds the GIL: it uses the scratch inside bufs
def _run_acc(q, qd, bufs, l0, fd, ext, flags, A):
    """Accelerations A (B, k, 6) ``[r'', b'']`` (m/s^2, 1/s^2) of the states ``q``, ``qd``
    (B, k, 6): the loop driver's :func:`_acc` (the same equations and operations as its
    acceleration-only pass), one copy at a time, each with its packed buffer ``bufs[b]``
    ((B, len) per copy, or (1, len) shared). A kernel of its own so that evaluating
    accelerations (stability estimates, Jacobians) does not compile the stepping driver.
    Returns the error code (0: done)."""
    err, ibs, L, k, m, n = _copies_check(q, qd, q, qd, bufs, l0, fd, ext, flags, True)
    if err:
        return err
    if A.shape[0] != q.shape[0] or A.shape[1] != k or A.shape[2] != 6:
        return 6
    per_copy = bufs.shape[0] > 1
    for b in range(q.shape[0]):
        w = bufs[b if per_copy else 0]        # the copy's own buffer: its constants, anchors and scratch
        ib = ibs[b if per_copy else 0]
        S, N, V, F, L0, FD, EX, PC = _scratch(w, L, k, m, n, 1, False)
        _load(q, qd, l0, fd, ext, b, 1, S[0], S[1], L0, FD, EX, PC, L[2], k, m, n, 1, flags)
        A1 = S[2]
        _acc(w, ib, L, k, m, n, S[0], S[1], A1, N, V, F, L0, FD, EX, 1, flags, PC)
        for j in range(k):
            for i in range(6):
                A[b, j, i] = A1[j, i, 0]
    return 0


@njit(cache=True, fastmath=False, error_model="numpy")   # holds the GIL: it uses the scratch inside buf
def _run_project(q, qd, bufs, flags, qo, qdo):
    """``q``, ``qd`` (B, k, 6) projected onto the constraints into ``qo``, ``qdo``: the loop
    driver's :func:`_project`, one copy at a time (topology only: the shared buffer
    ``bufs[0]``). A kernel of its own so that a projection does not compile the stepping
    driver. Returns the error code (0: done)."""
    ibs = bufs.view(np.int64)
    w, ib = bufs[0], ibs[0]
    k, m, n = ib[0], ib[1], ib[2]
    d2 = q[0]                             # control placeholders of the right type, never read (_L0DEF)
    err = _check(q, qd, qo, qdo, k, m, n, d2, d2, q, _L0DEF)
    if err:
        return err
    B = q.shape[0]
    L = _layout_nb(k, m, n)
    Q = np.empty((k, 6, 1))
    QD = np.empty((k, 6, 1))
    any_cons = (flags & _CONS) != 0
    for b in range(B):
        for j in range(k):
            for i in range(6):
                Q[j, i, 0] = q[b, j, i]
                QD[j, i, 0] = qd[b, j, i]
        _project(w, ib, L[0], k, Q, QD, 1, any_cons)
        for j in range(k):
            for i in range(6):
                qo[b, j, i] = Q[j, i, 0]
                qdo[b, j, i] = QD[j, i, 0]
    return 0


# ---------------------------------------------------------------------- Python side
_CACHE: dict = {}


# ---------------------------------------------------------------------- contact loops and fused plans
@njit(inline="always", cache=True)
def _contact_check(q, qd, bufs, l0, fd, W, ext, flags):
    """(error code, int64 view of bufs, layout, k, m, n) of a contact loop call: the driver's
    checks (``_copies_check``, W as its external force) and ext rows 0, 1 or B of
    (n, 3) (error 5 otherwise)."""
    err, ibs, L, k, m, n = _copies_check(q, qd, q, qd, bufs, l0, fd, W, flags, True)
    if err == 0 and ext.shape[0] > 0 and ((ext.shape[0] != 1 and ext.shape[0] != q.shape[0])
                                          or ext.shape[1] != n or ext.shape[2] != 3):
        err = 5
    return err, ibs, L, k, m, n

@njit(inline="always", cache=True)
def _simd_check(q, qd, bufs, lanes, l0, fd, W, ext, flags):
    """:func:`_contact_check` of a SIMD contact or terrain loop, error 9 for a batch under one
    SIMD block, and the lane blocks the driver reads: ``lanes`` where every copy has its own
    buffer, none (0 rows) where ``bufs`` is shared."""
    err, ibs, L, k, m, n = _contact_check(q, qd, bufs, l0, fd, W, ext, flags)
    if err == 0 and _serial_setup(bufs, q.shape[0])[4] == 1:
        err = 9
    lanes1 = _view(lanes, 0, (lanes.shape[0] if bufs.shape[0] > 1 else 0, lanes.shape[1], lanes.shape[2]))
    return err, ibs, L, k, m, n, lanes1

@njit(cache=True)   # holds the GIL: the one-copy driver uses the scratch inside the buffers
def _contact_loop(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, anchor, active,
                  slip, prm, rods):
    """The contact sub-steps of :func:`tensegrity_gym.physics.pipeline.run_steps` on the batch, one
    copy at a time, on this thread, in place: the loop driver's one-copy instance with contact, ``n_steps`` steps, each with the contact forces of its start plus
    ``ext`` (0, 1 or B rows of (n, 3) N); ``W`` (B, n, 3) gets the last step's forces,
    ``anchor``, ``active``, ``slip`` the contact state. ``bufs`` (1, len) the shared packed
    buffer or (B, len) one per copy (``lanes``: their SIMD lane blocks, unused here). Returns
    the kernel's error code (0: done). From ``_SOA_MIN_BATCH`` copies :func:`_contact_loop_simd`
    computes the same numbers faster. ``rods``: None, or the rod-rod contact tuple of the loop
    driver (its forces added at every step; the instances with None carry no rod-rod code)."""
    err, ibs, L, k, m, n = _contact_check(q, qd, bufs, l0, fd, W, ext, flags)
    if err:
        return err
    lanes1 = _serial_setup(bufs, q.shape[0])[5]
    contact = (eta, rod_a, rod_c, prm, anchor, active, slip, ext)
    _drive_one_contact(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                       contact, rods)
    return 0


@njit(cache=True)   # holds the GIL, as _contact_loop
def _contact_loop_simd(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, anchor, active,
                       slip, prm, rods):
    """:func:`_contact_loop` for a batch of ``_SOA_MIN_BATCH`` copies or more: the SIMD
    instance with contact, on this thread (per-copy constants read from the lane blocks
    ``lanes``, shared ones from ``bufs[0]``); error 9 for a smaller batch."""
    err, ibs, L, k, m, n, lanes1 = _simd_check(q, qd, bufs, lanes, l0, fd, W, ext, flags)
    if err:
        return err
    contact = (eta, rod_a, rod_c, prm, anchor, active, slip, ext)
    _drive_lanes_contact(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                         contact, rods)
    return 0


@njit(parallel=True, cache=True)   # holds the GIL, as _run_parallel does
def _contact_parallel(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, anchor,
                      active, slip, prm, rods):
    """:func:`_contact_loop` on chunks of whole SIMD blocks on all threads (``prange``; the
    chunk count in ``flags >> _CHUNK_SHIFT``): each chunk runs all ``n_steps`` sub-steps of
    its copies (contact forces, then the SIMD driver with its own scratch), so the threads
    meet once per call, not once per sub-step. Same arguments and bits as
    :func:`_contact_loop`."""
    err, ibs, L, k, m, n = _contact_check(q, qd, bufs, l0, fd, W, ext, flags)
    if err:
        return err
    B = q.shape[0]
    E, nb, nch = _chunks(B, k, flags)
    contact = (eta, rod_a, rod_c, prm, anchor, active, slip, ext)
    for c in prange(nch):
        # the driver only reads the buffers; each chunk has its own scratch and copies
        lo, hi = _chunk(c, E, nb, nch, B)
        _drive_lanes_contact(bufs[0], ibs[0], L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, contact,
                             rods)
    return 0

@njit(cache=True)   # holds the GIL: the physics kernel uses the scratch inside buf
def run_plan(q, qd, qo, qdo, buf, controls, dt, n_steps, flags):
    """From njit code: the physics of a :class:`Plan` (its ``buf``, ``dt``, ``n_steps``,
    ``flags``) from ``q``, ``qd`` into ``qo``, ``qdo`` (B, k, 6) with ``controls`` (B, m)
    the rest lengths or force densities of its control mode, one copy at a time. Returns the
    kernel's error code (0: done)."""
    return _run_serial(q, qd, qo, qdo, buf, controls, controls, q, dt, n_steps, flags)


@njit(cache=True)   # holds the GIL: the physics kernel uses the scratch inside buf
def run_plan_simd(q, qd, qo, qdo, buf, controls, dt, n_steps, flags):
    """:func:`run_plan` on ``_SOA_MIN_BATCH`` copies or more (the SIMD instance)."""
    return _run_serial_simd(q, qd, qo, qdo, buf, controls, controls, q, dt, n_steps, flags)
