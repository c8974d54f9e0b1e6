"""Python entry points of the numba backend: the fixed-step integrators, accelerations, forces,
projection and contact sub-steps of :mod:`tensegrity_gym.physics`.

This module is the one implementation of the rod accelerations ((5.37)/(5.40) and the reduced
form (5.49)-(5.51)), the semi-implicit Euler and classic RK4 steps, the projection onto the
constraints and the ground-contact forces (``_point_force``: the driver runs them at every
contact sub-step, ``contact.py`` through ``_forces_kernel``) that
:func:`tensegrity_gym.physics.step`, :func:`tensegrity_gym.physics.project` and every env
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
    Same arguments and result as ``physics.step`` for ``name`` in
    ``{"semi_implicit_euler", "rk4"}``; returns a new :class:`~tensegrity_gym.core.model.State`
    (the input state is never modified). ``physics.step`` dispatches here for
    ``backend="auto"``/``"numba"``.
:func:`accelerations` ``(model, q, qd, rest_length, force_density, external, params)``
    The accelerations ``[r'', b'']`` of a batch of states, no step: the driver's own force and
    rod equations in a kernel of their own (``_run_acc``), for the methods that evaluate accelerations themselves
    (implicit Euler, the adaptive methods, finite-difference Jacobians, through
    :func:`tensegrity_gym.physics.accelerations`).
:func:`step_inplace` ``(model, q, qd, dt, name="semi_implicit_euler", *, ...)``
    The fast path for environments: advances preallocated state arrays ``q``, ``qd``
    (B, k, 6), C-contiguous float64, **in place** and returns nothing. It allocates nothing
    per call and skips the :class:`State` object; an environment that owns its state arrays
    should call this. Time is not tracked (the caller adds ``n_steps * dt``).
:func:`string_forces`, :func:`project`, :func:`contact_steps`
    String force densities and nodal forces, the projection onto the constraints (no step) and
    the contact sub-steps in one compiled call.

The call plans for callers that repeat one call (``Plan``, ``make_plan``, ``lean_plan``,
``packed``) live in :mod:`tensegrity_gym.backends.numba.plans` and are importable from here.

Inputs (both entry points)
--------------------------
``rest_length`` (m,) or (B, m) in m, ``force_density`` (m,) or (B, m) in N/m (added to the
string force densities, result clipped at 0), ``external`` (n, 3) or (B, n, 3) nodal forces
in N held constant over the step(s). ``project``: normalise ``b``, remove the component of
``b'`` along ``b`` and put constrained reference points back on their point/line/plane after
every step (exactly :func:`tensegrity_gym.physics.project`); semi-implicit Euler then moves
``b`` along its great circle (``_drift_rod``; NumPy reference ``tests/oracle_numpy.sphere_drift``). ``n_steps``: steps taken in
one call (all inside the compiled loop).

Implementation notes
--------------------
* Same formulas as the NumPy oracle, with two deliberate differences that only move round-off
  (agreement ~1e-14 relative after hundreds of steps): divisions by per-rod constants and by
  ``|b|^2`` are multiplications by reciprocals, and forces are accumulated string by string.
  Slack strings add nothing; ``error_model="numpy"``: a division by zero gives inf/NaN as in
  NumPy (``physics.simulate`` then reports the divergence), never a Python exception.
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
  batch. All of them run ONE loop driver, ``driver._drive_py``, on structure-of-arrays scratch
  (k, 6, E), through its two instances: ``_drive_lanes``, E = 16 (8 above 24 rods) environments
  per SIMD block from ``_SOA_MIN_BATCH`` = 16 environments (fresh scratch per call), and
  ``_drive_one``, one at a time with E = 1 a compile-time constant, in the packed buffer's
  own scratch reached through ``numba.carray`` views (``_view``: no reference counting)
  (bit-identical results either way).
* numba's threading layer is set to ``workqueue`` unless the user chose one
  (``NUMBA_THREADING_LAYER``): see the comment at the import. The parallel kernel holds
  the GIL, so two Python threads never enter the pool at once.
* Damping work (node velocities, string length rates) is skipped when
  ``model.has_damping`` and ``model.has_node_damping`` are False (node drag ``-c v``,
  :func:`tensegrity_gym.core.model.compile_model` ``node_damping``, is added to the nodal forces
  after gravity, as NumPy does); gravity loads when ``model.has_gravity`` is False.
* Shapes are checked inside the kernel (error code -> ``ValueError`` naming the argument),
  so a wrong shape never reads out of bounds.
* Cold start: the first call compiles (~25 s per entry point group on the 2-core machine);
  later processes load the machine code from ``__pycache__`` in about a second.
"""
from __future__ import annotations

import numpy as np

from ...core.model import new_state
from . import compile as _cm
from .compile import NCHUNK as _NCHUNK, PARALLEL_MIN_WORK, _compile, _parallel, _READY
from .entries import (_contact_loop, _contact_loop_simd, _contact_parallel, _run_acc, _run_copies_serial, _run_forces,
                      _run_lean, _run_parallel, _run_project, _run_serial, _run_serial_simd)
from .layout import _CHUNK_SHIFT, _CONS, _ERRORS, _EXT, _FD, _L0DEF, _RK4, _SOA_MIN_BATCH
from .pack import _CACHE, _array, _flags, _pack, _pack_params, clear_cache
from .plans import Plan, lean_plan, make_plan, packed

__all__ = ["step", "step_inplace", "accelerations", "string_forces", "project", "contact_steps", "Plan",
           "make_plan", "packed", "lean_plan", "PARALLEL_MIN_WORK", "clear_cache", "rods_tuple"]


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
    return _serial_kernel(q.shape[0])(q, qd, qo, qdo, p.buf, l0, fd, ext, float(dt), int(n_steps), flags)


def _serial_kernel(B: int):
    """The serial entry kernel of a batch of B copies (its instance compiled at first use):
    ``_run_serial_simd`` (SIMD blocks) from ``_SOA_MIN_BATCH`` copies, else ``_run_serial`` (one
    copy at a time); the two compute the same numbers."""
    which = "serial_simd" if B >= _SOA_MIN_BATCH else "serial"
    if not _READY[which]:
        _compile(which)
    return _run_serial if which == "serial" else _run_serial_simd


def _raise(err, model, q, qd, l0, fd, ext):
    raise ValueError(_ERRORS[err].format(k=model.n_bars, m=model.n_strings, n=model.n_nodes)
                     + f"; got q {np.shape(q)}, qd {np.shape(qd)}, rest_length {np.shape(l0)}, "
                     f"force_density {np.shape(fd)}, external {np.shape(ext)}")



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
                            "physics.step evaluates a callable and passes its arrays")
        ext = external if getattr(external, "ndim", 0) == 3 else _array(external, 3, "external")
        flags |= _EXT
    return l0, fd, ext, flags


def _control_arrays(p, flags, rest_length, force_density, external):
    """:func:`_controls` with its arrays converted for the kernel boundary (C-contiguous float64)."""
    l0, fd, ext, flags = _controls(p, flags, rest_length, force_density, external)
    return _array(l0, 2, "rest_length"), _array(fd, 2, "force_density"), _array(ext, 3, "external"), flags


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
    l0, fd, ext, flags = _control_arrays(p, flags, rest_length, force_density, external)
    if not (isinstance(dt, (int, float, np.floating, np.integer)) and isinstance(n_steps, (int, np.integer))):
        raise TypeError(f"dt must be a number of seconds and n_steps an integer; got {dt!r}, {n_steps!r}")
    B = q.shape[0]
    work = B * int(n_steps) * p.cost * (4 if flags & _RK4 else 1)
    if B >= 8 and work >= _cm.PARALLEL_MIN_WORK:
        if not _READY["parallel"]:
            _compile("parallel")
        return _run_parallel(q, qd, qo, qdo, p.bufs, l0, fd, ext, float(dt), int(n_steps),
                             flags | (_NCHUNK << _CHUNK_SHIFT), p.lanes)
    return _run_copies_serial(q, qd, qo, qdo, p.bufs, l0, fd, ext, float(dt), int(n_steps), flags, p.lanes)


def step(model, state, dt, name, *, rest_length=None, force_density=None, external=None, project=True,
         n_steps=1, params=None):
    """Advance ``state`` by ``n_steps`` fixed steps of ``dt`` s with the compiled kernel.

    Same contract as :func:`tensegrity_gym.physics.step` (``name`` in
    ``{"semi_implicit_euler", "rk4"}``); returns a new :class:`~tensegrity_gym.core.model.State`
    with ``q``, ``qd`` (B, k, 6) and ``t = state.t + n_steps * dt`` (summed step by step, as
    the NumPy path does). The input state is not modified. ``params``: per-copy physical values
    (:class:`~tensegrity_gym.core.params.Params`, 1 or B rows)."""
    p = (_CACHE.get(id(model)) or _pack(model)) if params is None else _pack_params(model, params)
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
    return new_state(qo, qdo, t)


def _shared_step(model, p, q, qd, qo, qdo, rest_length, force_density, external, dt, n_steps, flags):
    """The kernels with one packed buffer ``p.buf`` shared by every copy (``qo is q``: in place)."""
    flags0 = flags
    big = q.shape[0] >= 8 and _parallel(p, q.shape[0], n_steps, flags)
    try:
        if (rest_length is None and force_density is None and external is None and not big
                and q.shape[0] < _SOA_MIN_BATCH):
            if not _READY["lean"]:
                _compile("lean")
            err = _run_lean(q, qd, qo, qdo, p.buf, dt, n_steps, flags)
        else:
            l0, fd, ext, flags = _controls(p, flags, rest_length, force_density, external)
            if big:
                err = _run_parallel(q, qd, qo, qdo, p.buf[None], l0, fd, ext, dt, n_steps,
                                    flags | (_NCHUNK << _CHUNK_SHIFT), p.lanes)
            else:
                err = _serial_kernel(q.shape[0])(q, qd, qo, qdo, p.buf, l0, fd, ext, dt, n_steps, flags)
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
    p = (_CACHE.get(id(model)) or _pack(model)) if params is None else _pack_params(model, params)
    flags = _flags(p, name, project)
    if p.bufs is not None:
        _copies_step(model, p, q, qd, q, qd, rest_length, force_density, external, dt, n_steps, flags, True)
    else:
        _shared_step(model, p, q, qd, q, qd, rest_length, force_density, external, dt, n_steps, flags)


def accelerations(model, q, qd, rest_length=None, force_density=None, external=None, params=None):
    """Accelerations ``[r'', b'']`` (B, k, 6) (m/s^2, 1/s^2) of the state ``q``, ``qd`` ((B, k, 6)
    or (k, 6): the result has the same shape): :func:`tensegrity_gym.physics.accelerations` (the
    NumPy reference; equal to round-off, ``tests/test_kernels.py``) computed by the loop driver's
    own force and rod equations (``_acc``), no step taken. Inputs as :func:`step`."""
    p = (_CACHE.get(id(model)) or _pack(model)) if params is None else _pack_params(model, params)
    if not _READY["acc"]:
        _compile("acc")
    shape = np.shape(q)
    q, qd = _array(q, 3, "q"), _array(qd, 3, "qd")
    l0, fd, ext, flags = _control_arrays(p, p.flags, rest_length, force_density, external)
    A = np.empty(q.shape)
    err = _run_acc(q, qd, p.bufs if p.bufs is not None else p.buf[None], l0, fd, ext, flags, A)
    if err:
        _raise(err, model, q, qd, rest_length, force_density, external)
    return A.reshape(shape)


def string_forces(model, q, qd, rest_length=None, force_density=None, external=None, params=None):
    """``(gamma, L, F)`` of the states ``q``, ``qd`` (B, k, 6): string force densities gamma
    (B, m), N/m (tension / length, >= 0), string lengths L (B, m), m, and total nodal forces F
    (B, n, 3), N (strings, gravity, node drag, ``external``): the loop driver's own force
    equations (:func:`_forces`, what every step evaluates), no step taken. Inputs as
    :func:`step` (``external`` an array); ``params`` per-copy physical values (1 or B rows)."""
    p = (_CACHE.get(id(model)) or _pack(model)) if params is None else _pack_params(model, params)
    if not _READY["forces"]:
        _compile("forces")
    q, qd = _array(q, 3, "q"), _array(qd, 3, "qd")
    l0, fd, ext, flags = _control_arrays(p, p.flags, rest_length, force_density, external)
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
    p = _CACHE.get(id(model)) or _pack(model)
    if not _READY["project"]:
        _compile("project")
    shape = np.shape(q)
    q, qd = _array(q, 3, "q"), _array(qd, 3, "qd")
    qo, qdo = np.empty(q.shape), np.empty(q.shape)
    err = _run_project(q, qd, p.buf[None], p.flags & _CONS, qo, qdo)
    if err:
        _raise(err, model, q, qd, None, None, None)
    return qo.reshape(shape), qdo.reshape(shape)



# ---------------------------------------------------------------------- contact sub-steps
def loop_setup(model, q, qd, name, rest_length, force_density, external, params, project, forces):
    """``(p, flags, l0, fd, ext, bufs)`` of a compiled contact or terrain sub-step loop: the packed
    model (per-copy with ``params``), its flags with ``forces`` (B, n, 3) as the external force of
    each sub-step, the control arrays, ``external`` read-only (``_NO_EXTERNAL`` when None) and the
    packed buffers (1 or B, len). None where ``q``, ``qd``, ``forces`` or ``external`` is not an
    array the loops take as it is (the Python loop then converts it)."""
    p = (_CACHE.get(id(model)) or _pack(model)) if params is None else _pack_params(model, params)
    flags = _flags(p, name, project)
    for x in (q, qd, forces):
        if not (type(x) is np.ndarray and x.dtype == np.float64 and x.flags.c_contiguous and x.flags.writeable):
            return None
    if external is None:
        ext = _NO_EXTERNAL
    elif type(external) is np.ndarray and external.dtype == np.float64 and external.ndim == 3:
        ext = _frozen(np.ascontiguousarray(external))
    else:
        return None
    l0, fd, _, flags = _control_arrays(p, flags, rest_length, force_density, forces)
    return p, flags, l0, fd, ext, p.buf[None] if p.bufs is None else p.bufs


def contact_steps(model, q, qd, dt, name, n_steps, rest_length, force_density, external, params, project,
                  contact, cstate, contact_params, forces, slip, rods=None) -> bool:
    """The contact sub-steps of :func:`tensegrity_gym.physics.pipeline.run_steps` in ONE compiled call: :func:`_contact_loop` (this
    thread) or, for a batch with enough work for the parallel kernel (``_parallel``),
    :func:`_contact_parallel` (chunks of the batch on all threads, every sub-step inside). False
    (nothing done) for arrays the kernels do not take as they are: the Python loop converts them.
    ``rods``: None or the loop driver's rod-rod contact tuple (:func:`rods_tuple`)."""
    setup = loop_setup(model, q, qd, name, rest_length, force_density, external, params, project, forces)
    if setup is None:
        return False
    p, flags, l0, fd, ext, bufs = setup
    prm = _frozen(contact.prm if contact_params is None else contact_params)
    B = q.shape[0]
    # parallel when ONE sub-step has the parallel kernel's work (not all n_steps together): the
    # threads then meet once per call, but on a 2-core machine waking them between env steps
    # costs more than they save below that
    if B >= 8 and _parallel(p, B, 1, flags, compile_kernel=False):
        kernel, flags = _contact_parallel, flags | (_NCHUNK << _CHUNK_SHIFT)
    else:
        kernel = _contact_loop if B < _SOA_MIN_BATCH else _contact_loop_simd
    try:
        err = kernel(q, qd, bufs, p.lanes, l0, fd, forces, ext, float(dt), int(n_steps), flags, _frozen(model.eta),
                     _frozen(model.rod_a), _frozen(model.rod_c), cstate.anchor, cstate.active, slip, prm, rods)
    except TypeError:      # an array of another type or layout: the Python loop converts it
        return False
    if err:
        _raise(err, model, q, qd, rest_length, force_density, forces if external is None else external)
    return True


def rods_tuple(model, prm) -> tuple:
    """The loop driver's rod-rod contact tuple ``(eta, rod_a, rod_c, prm)`` of ``model`` with the
    (1, 6) parameter row ``prm`` (:attr:`tensegrity_gym.physics.rod_contact.RodContact.prm`),
    read-only as the compiled loops take them."""
    return (_frozen(model.eta), _frozen(model.rod_a), _frozen(model.rod_c), _frozen(prm))


def _frozen(a: np.ndarray) -> np.ndarray:
    """``a`` read-only (a view if it is writable). The compiled contact loop carries the model's
    and the contact's read-only arrays into the loop driver's contact instances, whose numba
    type includes the flag: a writable copy (a deep-copied env's model, per-copy contact
    parameters, a caller's external force) would otherwise compile a second instance of the
    driver (about a minute on 2 cores) instead of reusing the first."""
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


_NO_EXTERNAL = _frozen(np.empty((0, 1, 3)))   # no external force added to the contact or terrain forces
