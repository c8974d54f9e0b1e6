"""Terrain contact sub-steps in ONE compiled call (the numba backend's twin of the Python loop
of :func:`tensegrity_gym.physics.terrain.step`): per step, the terrain forces of each copy
from the state at the step's start (:func:`.terrain.rows_forces`), plus an external force,
held over ONE integrator step. The terrain forces run inside the loop driver, on its lanes
(:func:`.terrain.lanes_forces`; a terrain that is one plane, :func:`.terrain.plane_forces` in
instances of its own), as the ground contact does: the state stays in the driver's
scratch for all sub-steps, and a large batch runs in chunks on all threads. The same kernels
in the same order as the Python loop, so the numbers are bit-identical. SI units: m, s, N.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .api import _frozen, _raise, loop_setup
from .compile import NCHUNK as _NCHUNK, TERRAIN_SLOT_WORK, _parallel
from .driver import _drive_lanes_plane, _drive_lanes_terrain, _drive_one_plane, _drive_one_terrain
from .entries import _chunk, _chunks, _contact_check, _serial_setup, _simd_check
from .layout import _CHUNK_SHIFT, _SOA_MIN_BATCH, _soa_width
from .terrain import codes_known
from .terrain_kinds import check_codes
from .terrain_plane import plane_only

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
                 anchor, eta0, active, slip, plane):
    """``n_steps`` terrain sub-steps of the batch in place, one copy at a time, on this thread:
    the loop driver's one-copy instance with terrain contact. ``bufs`` (1, len) the shared
    packed buffer or (B, len) one per copy (``lanes``: their SIMD lane blocks, unused here);
    ``W`` (B, n, 3) gets each copy's forces of its last step; ``ext`` (0, 1 or B rows of
    (n, 3)) N added to the terrain forces. ``plane``: None (the general driver instance) or True
    (the plane instance, :func:`.terrain.plane_forces`: error 10 unless every row of ``geom`` is
    one plane). Returns the kernel's error code (0: done)."""
    err, ibs, L, k, m, n = _contact_check(q, qd, bufs, l0, fd, W, ext, flags)
    err, terrain, planes = _terrain_tuples(err, plane, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip,
                                           ext)
    if err:
        return err
    lanes1 = _serial_setup(bufs, q.shape[0])[5]
    if plane is None:
        _drive_one_terrain(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                           terrain)
    else:
        _drive_one_plane(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                         planes)
    return 0


@njit(cache=True)   # holds the GIL, as terrain_loop
def terrain_loop_simd(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, geom, prm, hf,
                      anchor, eta0, active, slip, plane):
    """:func:`terrain_loop` for ``_SOA_MIN_BATCH`` copies or more: the SIMD instance, on this
    thread; error 9 for a smaller batch."""
    err, ibs, L, k, m, n, lanes1 = _simd_check(q, qd, bufs, lanes, l0, fd, W, ext, flags)
    err, terrain, planes = _terrain_tuples(err, plane, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip,
                                           ext)
    if err:
        return err
    if plane is None:
        _drive_lanes_terrain(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                             terrain)
    else:
        _drive_lanes_plane(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                           planes)
    return 0


@njit(parallel=True, cache=True)
def terrain_parallel(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, geom, prm, hf,
                     anchor, eta0, active, slip, plane):
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
                                 terrain)
    else:
        for c in prange(nch):
            lo, hi = _chunk(c, E, nb, nch, B)
            _drive_lanes_plane(bufs[0], ibs[0], L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes,
                               planes)
    return 0


def terrain_steps(model, q, qd, dt, name, n_steps, rest_length, force_density, external, params, project, arrays,
                  forces, plane: bool = False) -> bool:
    """The terrain sub-steps of :func:`tensegrity_gym.physics.terrain.advance` in one compiled
    call, in place on ``q``, ``qd`` (B, k, 6) and the contact state. ``arrays``: ``(geom, prm,
    hf, anchor, eta0, active, slip)`` as the forces kernel takes them; ``forces`` (B, n, 3) gets
    each copy's forces of the last sub-step. :func:`terrain_parallel` for a batch with the
    parallel kernel's work in one sub-step, else :func:`terrain_loop` (SIMD from
    ``_SOA_MIN_BATCH`` copies). ``plane``: the terrain is one plane (the driver's plane
    instance; rows that are not, error 10 of the kernels, run the general one). False (nothing
    done) for arrays of another type or layout: the Python loop converts them."""
    setup = loop_setup(model, q, qd, name, rest_length, force_density, external, params, project, forces)
    if setup is None:
        return False
    p, flags, l0, fd, ext, bufs = setup
    B = q.shape[0]
    # threads when one sub-step's work, the terrain slots' included, is the parallel kernel's and
    # the batch makes two SIMD blocks at least (the chunks are whole blocks); a plane's slots cost
    # about what the ground contact's do, which the flat kernels do not count either
    slot_work = 0 if plane else TERRAIN_SLOT_WORK * arrays[3].shape[1]
    if B >= 2 * _soa_width(model.n_bars) and _parallel(p, B, 1, flags, compile_kernel=False, extra_cost=slot_work):
        kernel, flags = terrain_parallel, flags | (_NCHUNK << _CHUNK_SHIFT)
    else:
        kernel = terrain_loop if B < _SOA_MIN_BATCH else terrain_loop_simd
    args = (q, qd, bufs, p.lanes, l0, fd, forces, ext, float(dt), int(n_steps), flags, _frozen(model.eta),
            _frozen(model.rod_a), _frozen(model.rod_c), *arrays)
    try:
        err = kernel(*args, True if plane else None)
        if err == 10:      # rows that are not one plane each: the general instance
            err = kernel(*args, None)
    except TypeError:      # an array of another type or layout: the Python loop converts it
        return False
    if err == 11:          # a feature code of no kind: the host's check names it
        check_codes(arrays[0])
    if err:
        _raise(err, model, q, qd, rest_length, force_density, forces if external is None else external)
    return True

