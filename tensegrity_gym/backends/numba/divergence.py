"""Divergence checks of the numba backend: which copies went non-finite or far
(:func:`diverged`, one compiled pass :func:`bad_copies`), the compiled per-batch checks
:func:`state_ok` / :func:`state_ok_local` for fused callers, and :func:`finite_pair` (the input
check of a step). SI units.
"""
from __future__ import annotations

import numpy as np
from numba import njit

@njit(cache=True, nogil=True)
def finite_pair(a, b):
    """True if every entry of the C-contiguous float64 arrays ``a`` and ``b`` (3-D: a state's
    ``q``, ``qd``) is finite: the input check of ``physics.step`` in one compiled pass.
    It counts entries whose exponent bits are all set (inf or NaN) with integer operations,
    which the compiler vectorises (a float test per entry would not be)."""
    bad = 0
    for x in (a, b):
        bits = x.reshape(-1).view(np.int64)
        for i in range(bits.size):
            bad += (bits[i] & 0x7FF0000000000000) == 0x7FF0000000000000
    return bad == 0


@njit(cache=True, nogil=True)
def unit_axes(q, tol):
    """True if every rod axis ``b`` (entries 3:6 of the C-contiguous float64 ``q`` (B, k, 6)) has
    a length within ``tol`` of 1: with :func:`finite_pair`, the input check of ``physics.step``
    (a zero axis would give NaN, a badly scaled one wrong rod lengths)."""
    for c in range(q.shape[0]):
        for j in range(q.shape[1]):
            n2 = q[c, j, 3] * q[c, j, 3] + q[c, j, 4] * q[c, j, 4] + q[c, j, 5] * q[c, j, 5]
            if not abs(np.sqrt(n2) - 1.0) <= tol:
                return False
    return True


# one packed buffer per copy (bufs (B, len)), each lane reading its copy's constants

@njit(inline="always", cache=True, nogil=True)
def _copy_ok(q, qd, b, center, limit):
    """Copy b of ``q``, ``qd`` (B, k, 6): every entry finite and every reference point within
    ``limit`` (per coordinate) of ``center`` (3,)."""
    k = q.shape[1]
    for j in range(k):
        for c in range(6):
            if not (np.isfinite(q[b, j, c]) and np.isfinite(qd[b, j, c])):
                return False
        for c in range(3):
            if not (abs(q[b, j, c] - center[c]) <= limit):
                return False
    return True


@njit(inline="always", cache=True, nogil=True)
def _copy_ok_local(q, qd, b, center_z, limit):
    """Copy b of a robot that travels: every entry finite, every reference point within
    ``limit`` (per coordinate) of the copy's mean reference point, that mean's height within
    ``limit`` of ``center_z``."""
    k = q.shape[1]
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for j in range(k):
        for c in range(6):
            if not (np.isfinite(q[b, j, c]) and np.isfinite(qd[b, j, c])):
                return False
        m0 += q[b, j, 0]
        m1 += q[b, j, 1]
        m2 += q[b, j, 2]
    m0 /= k
    m1 /= k
    m2 /= k
    if not (abs(m2 - center_z) <= limit):
        return False
    for j in range(k):
        if not (abs(q[b, j, 0] - m0) <= limit and abs(q[b, j, 1] - m1) <= limit
                and abs(q[b, j, 2] - m2) <= limit):
            return False
    return True


@njit(cache=True, nogil=True)
def state_ok(q, qd, center, limit):
    """True if every copy of ``q``, ``qd`` (B, k, 6) is finite with every reference point within
    ``limit`` (per coordinate) of ``center`` (3,) (the fused steps' check, from njit code)."""
    for b in range(q.shape[0]):
        if not _copy_ok(q, qd, b, center, limit):
            return False
    return True


@njit(cache=True, nogil=True)
def state_ok_local(q, qd, center_z, limit):
    """Like :func:`state_ok` for a robot that travels (see :func:`diverged`, ``local``)."""
    for b in range(q.shape[0]):
        if not _copy_ok_local(q, qd, b, center_z, limit):
            return False
    return True


@njit(cache=True, nogil=True)
def bad_copies(q, qd, center, limit, local, out):
    """``out[b]`` (B,) bool: copy b failed the check of :func:`state_ok` (``local`` False) or of
    :func:`state_ok_local` (``local``: ``center[2]`` the height); returns how many failed."""
    n_bad = 0
    for b in range(q.shape[0]):
        ok = _copy_ok_local(q, qd, b, center[2], limit) if local else _copy_ok(q, qd, b, center, limit)
        out[b] = not ok
        n_bad += not ok
    return n_bad


def diverged(q: np.ndarray, qd: np.ndarray, center, limit: float, local: bool = False) -> np.ndarray:
    """(B,) bool: copy b has a non-finite entry in ``q``/``qd`` (B, k, 6), or a rod reference
    point farther than ``limit`` m (per coordinate) from ``center`` (3,) m; with ``local`` (a
    robot that travels) from its copy's mean reference point instead, that mean's height
    checked against ``center[2]`` (horizontal travel is not limited). One compiled pass over
    the batch (:func:`bad_copies`)."""
    q = np.ascontiguousarray(q, dtype=np.float64)
    qd = np.ascontiguousarray(qd, dtype=np.float64)
    if q.ndim != 3 or q.shape != qd.shape or q.shape[2] != 6:
        raise ValueError(f"diverged: q and qd must both have shape (B, k, 6); got {q.shape} and {qd.shape}")
    center = np.ascontiguousarray(center, dtype=np.float64).reshape(3)
    out = np.empty(q.shape[0], np.bool_)
    bad_copies(q, qd, center, float(limit), bool(local), out)
    return out


