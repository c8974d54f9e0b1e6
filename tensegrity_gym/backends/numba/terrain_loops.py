"""The compiled kernels of the terrain contact sub-steps (:mod:`.terrain_steps` calls them): per
step, the terrain forces of each copy from the state at the step's start, plus an external
force, held over ONE integrator step, inside the loop driver (:func:`terrain_loop` one copy at
a time, :func:`terrain_loop_simd` in SIMD blocks, :func:`terrain_parallel` in chunks of blocks
on all threads). This module imports the compiled modules its kernels call and nothing else,
so that its cached kernels depend on those alone (``cache_guard``). SI units: m, s, N.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .driver import _drive_lanes_plane, _drive_lanes_terrain, _drive_one_plane, _drive_one_terrain
from .entries import _chunk, _chunks, _contact_check, _serial_setup, _simd_check
from .terrain import codes_known
from .terrain_plane import plane_only

__all__ = ["terrain_loop", "terrain_loop_simd", "terrain_parallel"]

@njit(inline="always", cache=True)
def _terrain_tuples(err, plane, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip, ext):
    """(error code, the general driver's terrain tuple, the plane instance's tuple) of an entry
    call: error 11 where a feature code of ``geom`` is no kind's (:func:`.terrain.codes_known`),
    error 10 where ``plane`` is given and a row of ``geom`` is not one plane."""
    if err == 0 and not codes_known(geom):
        err = 11
    if err == 0 and plane is not None and not plane_only(geom):
        err = 10
    return (err, (eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip, np.empty((0, 0, 6)), ext),
            (eta, rod_a, rod_c, geom, prm, anchor, eta0, active, slip, ext))


@njit(cache=True)   # holds the GIL: the one-copy driver uses the scratch inside the buffers
def terrain_loop(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, geom, prm, hf,
                 anchor, eta0, active, slip, plane, rods):
    """``n_steps`` terrain sub-steps of the batch in place, one copy at a time, on this thread:
    the loop driver's one-copy instance with terrain contact. ``bufs`` (1, len) the shared
    packed buffer or (B, len) one per copy (``lanes``: their SIMD lane blocks, unused here);
    ``W`` (B, n, 3) gets each copy's forces of its last step; ``ext`` (0, 1 or B rows of
    (n, 3)) N added to the terrain forces. ``plane``: None (the general driver instance) or True
    (the plane instance, :func:`.terrain.plane_forces`: error 10 unless every row of ``geom`` is
    one plane). ``rods``: None, or the rod-rod contact tuple of the loop driver (its forces added
    at every step after the terrain's). Returns the kernel's error code (0: done)."""
    err, ibs, L, k, m, n = _contact_check(q, qd, bufs, l0, fd, W, ext, flags)
    err, terrain, planes = _terrain_tuples(err, plane, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip,
                                           ext)
    if err:
        return err
    lanes1 = _serial_setup(bufs, q.shape[0])[5]
    if plane is None:
        _drive_one_terrain(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                           terrain, rods)
    else:
        _drive_one_plane(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                         planes, rods)
    return 0


@njit(cache=True)   # holds the GIL, as terrain_loop
def terrain_loop_simd(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, geom, prm, hf,
                      anchor, eta0, active, slip, plane, rods):
    """:func:`terrain_loop` for ``_SOA_MIN_BATCH`` copies or more: the SIMD instance, on this
    thread; error 9 for a smaller batch."""
    err, ibs, L, k, m, n, lanes1 = _simd_check(q, qd, bufs, lanes, l0, fd, W, ext, flags)
    err, terrain, planes = _terrain_tuples(err, plane, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip,
                                           ext)
    if err:
        return err
    if plane is None:
        _drive_lanes_terrain(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                             terrain, rods)
    else:
        _drive_lanes_plane(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                           planes, rods)
    return 0


@njit(parallel=True, cache=True)
def terrain_parallel(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, geom, prm, hf,
                     anchor, eta0, active, slip, plane, rods):
    """:func:`terrain_loop` on chunks of whole SIMD blocks on all threads (``prange``; the chunk
    count in ``flags >> _CHUNK_SHIFT``): each chunk runs all ``n_steps`` sub-steps of its
    copies, whose contact state is their own rows, so the threads meet once per call. Same
    arguments and bits as :func:`terrain_loop`."""
    err, ibs, L, k, m, n = _contact_check(q, qd, bufs, l0, fd, W, ext, flags)
    err, terrain, planes = _terrain_tuples(err, plane, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip,
                                           ext)
    if err:
        return err
    B = q.shape[0]
    E, nb, nch = _chunks(B, k, flags)
    if plane is None:
        for c in prange(nch):
            lo, hi = _chunk(c, E, nb, nch, B)
            _drive_lanes_terrain(bufs[0], ibs[0], L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes,
                                 terrain, rods)
    else:
        for c in prange(nch):
            lo, hi = _chunk(c, E, nb, nch, B)
            _drive_lanes_plane(bufs[0], ibs[0], L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes,
                               planes, rods)
    return 0
