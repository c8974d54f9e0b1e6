"""Terrain contact sub-steps in ONE compiled call (the numba backend's twin of the Python loop
of :func:`tensegrity_gym.physics.terrain.step`): per step, the terrain forces of each copy
from the state at the step's start (:func:`.terrain.rows_forces`), plus an external force,
held over ONE integrator step. The terrain forces run inside the loop driver, on its lanes
(:func:`.terrain.lanes_forces`; a terrain that is one plane, :func:`.terrain.plane_forces` in
instances of its own), as the ground contact does: the state stays in the driver's
scratch for all sub-steps, and a large batch runs in chunks on all threads. The same kernels
in the same order as the Python loop, so the numbers are bit-identical. The kernels are those of
:mod:`.terrain_loops`; this module is the Python entry point that picks one. SI units: m, s, N.
"""
from __future__ import annotations

from .api import _frozen, _raise, loop_setup
from .compile import NCHUNK as _NCHUNK, TERRAIN_SLOT_WORK, _parallel
from .layout import _CHUNK_SHIFT, _SOA_MIN_BATCH, _soa_width
from .terrain_kinds import check_codes
from .terrain_loops import terrain_loop, terrain_loop_simd, terrain_parallel

__all__ = ["terrain_steps", "terrain_loop", "terrain_loop_simd", "terrain_parallel"]


def terrain_steps(model, q, qd, dt, name, n_steps, rest_length, force_density, external, params, project, arrays,
                  forces, plane: bool = False, rods=None) -> bool:
    """The terrain sub-steps of :func:`tensegrity_gym.physics.terrain.advance` in one compiled
    call, in place on ``q``, ``qd`` (B, k, 6) and the contact state. ``arrays``: ``(geom, prm,
    hf, anchor, eta0, active, slip)`` as the forces kernel takes them; ``forces`` (B, n, 3) gets
    each copy's forces of the last sub-step. :func:`terrain_parallel` for a batch with the
    parallel kernel's work in one sub-step, else :func:`terrain_loop` (SIMD from
    ``_SOA_MIN_BATCH`` copies). ``plane``: the terrain is one plane (the driver's plane
    instance; rows that are not, error 10 of the kernels, run the general one). False (nothing
    done) for arrays of another type or layout: the Python loop converts them. ``rods``: None or
    the loop driver's rod-rod contact tuple (:func:`.api.rods_tuple`)."""
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
        err = kernel(*args, True if plane else None, rods)
        if err == 10:      # rows that are not one plane each: the general instance
            err = kernel(*args, None, rods)
    except TypeError:      # an array of another type or layout: the Python loop converts it
        return False
    if err == 11:          # a feature code of no kind: the host's check names it
        check_codes(arrays[0])
    if err:
        _raise(err, model, q, qd, rest_length, force_density, forces if external is None else external)
    return True

