"""Terrain contact sub-steps in ONE compiled call (the numba backend's twin of the Python loop
of :func:`tensegrity_gym.physics.terrain.step`): per step, the terrain forces of the batch from
the state at the step's start (:func:`.terrain.terrain_forces_kernel`), plus an external force,
held over ONE integrator step of the serial entry kernel. The same kernels in the same order as
the Python loop, so the numbers are bit-identical; what goes is the Python call overhead of each
sub-step (two kernel calls and the argument conversions, several microseconds per physics step).

The kernels called here are the package's compiled entries (``_run_serial``, ``_run_serial_simd``,
``_run_copies_serial``), linked in, not compiled again: a loop here compiles in about a second
once they are. One loop per entry kernel, so a scene compiles only the instance it uses.
SI units: m, s, N.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .api import _control_arrays, _raise
from .compile import _compile, _parallel, _READY
from .entries import _run_copies_serial, _run_serial, _run_serial_simd
from .layout import _SOA_MIN_BATCH
from .pack import _CACHE, _flags, _pack, _pack_params
from .terrain import terrain_forces_kernel


@njit(inline="always", cache=True)
def _terrain_forces(q, qd, W, ext, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip, info):
    """Terrain forces of the batch into ``W`` (B, n, 3) N, then ``ext`` (0, 1 or B rows of
    (n, 3)) N added: the external force of one sub-step."""
    terrain_forces_kernel(q, qd, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip, W, info)
    if ext.shape[0] > 0:
        per = ext.shape[0] > 1
        for c in range(W.shape[0]):
            r = c if per else 0
            for p in range(W.shape[1]):
                for i in range(3):
                    W[c, p, i] += ext[r, p, i]


@njit(cache=True)
def terrain_loop(q, qd, buf, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, geom, prm, hf, anchor,
                 eta0, active, slip):
    """``n_steps`` terrain sub-steps of the batch in place, one copy at a time (``_run_serial``;
    one packed buffer ``buf`` shared by the copies). ``flags`` as the serial kernel takes them
    with the external-force bit set (``W`` is its external force). Returns the kernel's error
    code (0: done)."""
    info = np.empty((0, 0, 6))
    for _ in range(n_steps):
        _terrain_forces(q, qd, W, ext, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip, info)
        err = _run_serial(q, qd, q, qd, buf, l0, fd, W, dt, 1, flags)
        if err:
            return err
    return 0


@njit(cache=True)
def terrain_loop_simd(q, qd, buf, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, geom, prm, hf, anchor,
                      eta0, active, slip):
    """:func:`terrain_loop` in SIMD blocks (``_run_serial_simd``: ``_SOA_MIN_BATCH`` copies or more)."""
    info = np.empty((0, 0, 6))
    for _ in range(n_steps):
        _terrain_forces(q, qd, W, ext, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip, info)
        err = _run_serial_simd(q, qd, q, qd, buf, l0, fd, W, dt, 1, flags)
        if err:
            return err
    return 0


@njit(cache=True)
def terrain_loop_copies(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, geom, prm, hf,
                        anchor, eta0, active, slip):
    """:func:`terrain_loop` with one packed buffer per copy (``bufs`` (B, len), their SIMD lane
    blocks ``lanes``; ``_run_copies_serial``): per-copy physical parameters."""
    info = np.empty((0, 0, 6))
    for _ in range(n_steps):
        _terrain_forces(q, qd, W, ext, eta, rod_a, rod_c, geom, prm, hf, anchor, eta0, active, slip, info)
        err = _run_copies_serial(q, qd, q, qd, bufs, l0, fd, W, dt, 1, flags, lanes)
        if err:
            return err
    return 0


def terrain_steps(model, q, qd, dt, name, n_steps, rest_length, force_density, external, params, project, arrays,
                  forces) -> bool:
    """The terrain sub-steps of :func:`tensegrity_gym.physics.terrain.advance` in one compiled
    call, in place on ``q``, ``qd`` (B, k, 6) and the contact state. ``arrays``: ``(geom, prm,
    hf, anchor, eta0, active, slip)`` as the forces kernel takes them; ``forces`` (B, n, 3) the
    scratch of each sub-step's forces. False (nothing done) where the Python loop is the better
    caller: arrays of another type or layout (it converts them), and a batch large enough for
    the multi-threaded step kernel (the loop then calls it once per sub-step)."""
    p = (_CACHE.get(id(model)) or _pack(model)) if params is None else _pack_params(model, params)
    flags = _flags(p, name, project)
    for x in (q, qd, forces):
        if not (type(x) is np.ndarray and x.dtype == np.float64 and x.flags.c_contiguous and x.flags.writeable):
            return False
    B = q.shape[0]
    if B >= 8 and _parallel(p, B, 1, flags, compile_kernel=False):
        return False
    if external is None:
        ext = _NO_EXTERNAL
    elif type(external) is np.ndarray and external.dtype == np.float64 and external.ndim == 3:
        ext = np.ascontiguousarray(external)
    else:
        return False
    l0, fd, _, flags = _control_arrays(p, flags, rest_length, force_density, forces)
    common = (float(dt), int(n_steps), flags, model.eta, model.rod_a, model.rod_c) + tuple(arrays)
    if p.bufs is not None:
        which = "copies"
    else:
        which = "serial_simd" if B >= _SOA_MIN_BATCH else "serial"
    if not _READY[which]:
        _compile(which)
    try:
        if p.bufs is not None:
            err = terrain_loop_copies(q, qd, p.bufs, p.lanes, l0, fd, forces, ext, *common)
        else:
            kernel = terrain_loop_simd if which == "serial_simd" else terrain_loop
            err = kernel(q, qd, p.buf, l0, fd, forces, ext, *common)
    except TypeError:      # an array of another type or layout: the Python loop converts it
        return False
    if err:
        _raise(err, model, q, qd, rest_length, force_density, forces if external is None else external)
    return True


_NO_EXTERNAL = np.empty((0, 1, 3))   # no external force added to the terrain forces
