"""The physics pipeline of a batch of B copies: actuation -> contact -> forces -> integration.

The public entry points the environments (and any other caller that owns its state arrays) use;
no gymnasium import, SI units. Every function here runs the equations written once in the
backend (``_kernels``, numba; the NumPy oracle is ``tests/oracle_numpy.py``) through
:func:`tensegrity_gym.integrators.step` or its in-place compiled twin; nothing here copies a
kernel loop.

:func:`step` ``(model, state, dt, integrator, *, n_steps, contact=None, cstate=None, ...)``
    ``n_steps`` physics steps. Without ``contact`` it is :func:`integrators.step` (one call,
    all steps inside the compiled loop). With a :class:`~tensegrity_gym.contact.GroundContact`
    each step is: contact forces of the whole batch from the state at the step's start
    (stick/slip anchors updated in ``cstate``), then ONE integrator step with those forces
    held over it (``external=W``). Returns a new ``State`` (and a new ``ContactState``).
:func:`control_step` ``(model, state, actuation, controls, action, dt, integrator, *, speed, ...)``
    One control step from actions in [-1, 1]: the actuation update
    (:meth:`tensegrity_gym.actuation.Actuation.update`: rate limits or the cable motor, bounds,
    rest-length offsets), then :func:`step` with the new controls. Returns a
    :class:`ControlStep` ``(state, controls, speed, cstate)``; every env's control step is this.
:func:`advance`
    The same, in place on C-contiguous float64 arrays ``q``, ``qd`` (B, k, 6) and ``cstate``,
    with caller-owned scratch: no allocation and no ``State`` per step (the env fast path).
:func:`diverged`
    (B,) bool: which copies went non-finite or far (the divergence check of every env).
:func:`apply_controls`, :func:`apply_motor`
    Compiled actuation updates (new controls and the ``rest_length`` / ``force_density`` input
    of the physics), bit-identical to the NumPy reference in ``actuation.Actuation``.
:func:`compiled_plan` / :func:`run_plan`
    For a task that fuses its own bookkeeping with the physics in one compiled call: the
    packed model, integrator and control mode of ``integrators.step``'s serial kernel as an
    opaque :class:`Plan`, and the njit-callable that runs it.

With the numba kernels the contact steps of :func:`advance` run in ONE compiled call, written
inside the loop driver (``_kernels._advance_py`` with its ``contact`` tuple: at every step the
contact forces of its SIMD lanes, ``_kernels._contact_lanes``, then the integrator step, the
lanes kept in structure-of-arrays scratch for all sub-steps) and run either on the whole batch
on this thread (``_contact_loop``) or on chunks of whole SIMD blocks on all threads
(``_contact_parallel``, when one sub-step has the parallel kernel's work: every sub-step of a
chunk runs inside one ``prange`` iteration). The
Python loop of :func:`advance` (the same calls, in the same order, bit for bit) serves implicit
Euler and tests. numba's on-disk cache does not notice edits of the kernels that these and
:func:`run_plan` inline or call: clear ``__pycache__`` (``*.nbi``, ``*.nbc``) after editing
``_kernels.py`` or ``contact.py``.

The bookkeeping around the physics (control update :func:`apply_controls` / :func:`apply_motor`,
divergence check :func:`diverged`) is compiled too, written once; numba is a required dependency,
so nothing here has a NumPy twin (the tests compare with ``tests/oracle_numpy.py``).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from . import _kernels
from . import contact as gc
from . import integrators
from .checks import check_action, check_array
from .dynamics import Model, State

__all__ = ["step", "control_step", "ControlStep", "advance", "diverged", "compiled_physics",
           "apply_controls", "apply_motor", "state_ok", "state_ok_local", "bad_copies", "Plan", "compiled_plan",
           "run_plan"]


def compiled_physics(integrator: str, backend: str = "auto") -> bool:
    """True if :func:`integrators.step` runs the numba kernels for ``integrator`` (a fixed-step
    explicit method) and ``backend`` with array inputs; False otherwise (also for a backend name
    :func:`integrators.step` refuses: it then raises the ValueError itself)."""
    info = integrators.resolve(integrator)
    if info.name not in integrators._EXPLICIT:
        return False
    try:
        return integrators._use_numba(backend, info)
    except ValueError:
        return False


# ---------------------------------------------------------------------- stepping
def advance(model: Model, q: np.ndarray, qd: np.ndarray, dt: float, integrator: str = "semi_implicit_euler", *,
            n_steps: int = 1, rest_length=None, force_density=None, external=None, params=None,
            project: bool = True, backend: str = "auto", contact: gc.GroundContact | None = None,
            cstate: gc.ContactState | None = None, contact_params=None, forces=None, slip=None,
            compiled: bool | None = None) -> None:
    """In place: ``n_steps`` steps of ``dt`` s of ``q``, ``qd`` (B, k, 6), writable C-contiguous
    float64 (m, 1, m/s, 1/s). Inputs as :func:`integrators.step` takes them (``integrator`` a
    resolved name; shapes are checked by the kernels, values are the caller's duty).

    With ``contact`` (and its ``cstate``, updated in place): per step, contact forces from the
    state at the step's start into ``forces`` (B, n, 3) N (plus ``external`` if given), slip
    flags into ``slip`` (B, n_c) bool, then one integrator step with ``external=forces``.
    ``contact_params``: (B, 9) per-copy contact parameters or None (the contact's own).
    ``compiled``: whether the numba kernels run (default: :func:`compiled_physics`)."""
    if compiled is None:
        compiled = compiled_physics(integrator, backend)
    if contact is None:
        _physics(model, q, qd, dt, integrator, n_steps, rest_length, force_density, external, params, project,
                 backend, compiled)
        return
    B = q.shape[0]
    if forces is None:
        forces = np.empty((B, model.n_nodes, 3))
    if slip is None:
        slip = np.empty((B, 2 * model.n_bars), bool)
    if compiled and _contact_compiled(
            model, q, qd, dt, integrator, n_steps, rest_length, force_density, external, params, project, contact,
            cstate, contact_params, forces, slip):
        return
    contact_forces = gc.forces_inplace
    for _ in range(int(n_steps)):
        contact_forces(contact, model, q, qd, cstate, forces, slip, contact_params)
        if external is not None:
            forces += external
        _physics(model, q, qd, dt, integrator, 1, rest_length, force_density, forces, params, project, backend,
                 compiled)


def _physics(model, q, qd, dt, name, n_steps, rest_length, force_density, external, params, project, backend,
             compiled):
    """One in-place integrator call: the compiled kernel, or integrators.step and a copy back."""
    if compiled:
        _kernels.step_inplace(model, q, qd, dt, name, rest_length=rest_length, force_density=force_density,
                              external=external, project=project, n_steps=n_steps, params=params)
        return
    st = integrators.step(model, State(q, qd, 0.0), dt, name, rest_length=rest_length, force_density=force_density,
                          external=external, project=project, n_steps=n_steps, backend=backend, params=params)
    q[...] = st.q
    qd[...] = st.qd


def step(model: Model, state: State, dt: float, integrator: str = "semi_implicit_euler", *, n_steps: int = 1,
         contact: gc.GroundContact | None = None, cstate: gc.ContactState | None = None, contact_params=None,
         external=None, backend: str = "auto", **inputs):
    """``n_steps`` physics steps of ``dt`` s for the whole batch (see the module doc).

    Without ``contact``: :func:`integrators.step` (returns a ``State``). With ``contact``:
    returns ``(State, ContactState)``, new objects (the inputs are not modified); ``external``
    (B, n, 3) N is added to the contact forces of every step. ``inputs``: ``rest_length``,
    ``force_density``, ``params``, ``project`` as :func:`integrators.step` takes them."""
    if contact is None:
        return integrators.step(model, state, dt, integrator, n_steps=n_steps, external=external, backend=backend,
                                **inputs)
    info = integrators.resolve(integrator)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a positive finite time step in seconds, got {dt}")
    if cstate is None:
        raise ValueError("cstate: a ContactState is needed with contact (contact.init_contact_state)")
    B, m = state.batch_size, model.n_strings
    nc = 2 * model.n_bars
    if cstate.anchor.shape != (B, nc, 2) or cstate.active.shape != (B, nc):
        raise ValueError(f"contact state: expected anchor ({B}, {nc}, 2) and active ({B}, {nc}), got "
                         f"{cstate.anchor.shape} and {cstate.active.shape}")
    for name in ("rest_length", "force_density"):
        inputs[name] = integrators._as_batch(inputs.get(name), B, m, name)
    if inputs.get("params") is None:
        integrators._check_stability(model, info, dt)
    if contact_params is not None:
        contact_params = gc._prm_rows(contact, contact_params, B)
    q = np.array(state.q, dtype=np.float64, order="C")
    qd = np.array(state.qd, dtype=np.float64, order="C")
    cs = cstate.copy()
    ext = None if external is None else np.asarray(external, dtype=np.float64)
    advance(model, q, qd, dt, info.name, n_steps=n_steps, external=ext, backend=backend, contact=contact,
            cstate=cs, contact_params=contact_params, **inputs)
    t = state.t
    for _ in range(int(n_steps)):
        t = t + dt
    return State(q=q, qd=qd, t=t), cs


class ControlStep(NamedTuple):
    """What :func:`control_step` returns (new objects; the inputs are not modified)."""
    #: rod state after the control step (q, qd (B, k, 6); t advanced by n_steps * dt s)
    state: State
    #: (B, na) the actuated strings' new controls: rest lengths (m) or force densities (N/m)
    controls: np.ndarray
    #: (B, na) the motor's new cable speeds (unit/s), or None without a motor model
    speed: np.ndarray | None
    #: the contact's new stick/slip state, or None without contact
    cstate: gc.ContactState | None


def control_step(model: Model, state: State, actuation, controls, action, dt: float,
                 integrator: str = "semi_implicit_euler", *, n_steps: int = 1, speed=None, rest_offset=None,
                 contact: gc.GroundContact | None = None, cstate: gc.ContactState | None = None,
                 contact_params=None, external=None, params=None, project: bool = True,
                 backend: str = "auto") -> ControlStep:
    """One control step of the whole batch from actions: actuation, then ``n_steps`` physics
    steps of ``dt`` s (contact inside each when ``contact`` is given). What every env does per
    control step, as one pure call (brax's ``pipeline.step(sys, state, act)``).

    ``actuation``: a :class:`tensegrity_gym.actuation.Actuation` (which strings, rest-length or
    force-density mode, bounds, rate limits, the cable motor). ``controls`` (B, na): the actuated
    strings' current controls (m or N/m); ``action`` (B, na) in [-1, 1] (an entry beyond it by
    more than ``checks.ACTION_TOL`` (1e-6) is an error, not clipped:
    :func:`tensegrity_gym.checks.check_action` with ``clip=False``); ``speed`` (B, na): the
    motor's current cable speeds (unit/s), needed when the actuation has a motor model (``max_accel``). ``rest_offset``
    (P, m) m, P = 1 or B: true minus commanded rest lengths of the robots. The actuation update
    is :meth:`Actuation.update <tensegrity_gym.actuation.Actuation.update>`; the physics is
    :func:`step` with its ``rest_length`` / ``force_density`` (the other arguments as there).
    Returns a :class:`ControlStep`. ValueError naming the argument, the index and the value for
    a wrong shape, a non-finite entry or an action outside [-1, 1]."""
    B, na = state.batch_size, actuation.size
    controls = check_array(controls, (B, na), "controls")
    action = check_action(action, (B, na), clip=False)
    if speed is not None:
        speed = check_array(speed, (B, na), "speed")
    if rest_offset is not None:
        ro = np.asarray(rest_offset)
        ro = ro[None] if ro.ndim == 1 else ro
        rows = B if ro.ndim == 2 and ro.shape[0] == B else 1
        rest_offset = check_array(ro, (rows, model.n_strings), "rest_offset")
    ctrl, speed, inputs = actuation.update(np.ascontiguousarray(controls), np.ascontiguousarray(action),
                                           None if speed is None else np.ascontiguousarray(speed), rest_offset)
    kw = dict(n_steps=n_steps, external=external, backend=backend, params=params, project=project, **inputs)
    if contact is None:
        return ControlStep(step(model, state, dt, integrator, **kw), ctrl, speed, None)
    st, cs = step(model, state, dt, integrator, contact=contact, cstate=cstate, contact_params=contact_params, **kw)
    return ControlStep(st, ctrl, speed, cs)


def _contact_compiled(model, q, qd, dt, name, n_steps, rest_length, force_density, external, params, project,
                      contact, cstate, contact_params, forces, slip) -> bool:
    """The contact loop of :func:`advance` in ONE compiled call: :func:`_contact_loop` (this
    thread) or, for a batch with enough work for the parallel kernel (``_kernels._parallel``),
    :func:`_contact_parallel` (chunks of the batch on all threads, every sub-step inside). False
    (nothing done) for arrays the kernels do not take as they are: the Python loop converts them."""
    p = (_kernels._CACHE.get(id(model)) or _kernels._packed(model)) if params is None else \
        _kernels._pack_params(model, params)
    flags = _kernels._flags(p, name, project)
    for x in (q, qd, forces):
        if not (type(x) is np.ndarray and x.dtype == np.float64 and x.flags.c_contiguous and x.flags.writeable):
            return False
    if external is None:
        ext = _NO_EXTERNAL
    elif type(external) is np.ndarray and external.dtype == np.float64 and external.ndim == 3:
        ext = _frozen(np.ascontiguousarray(external))
    else:
        return False
    l0, fd, _, flags = _kernels._controls(p, flags, rest_length, force_density, forces)
    l0, fd = _kernels._array(l0, 2, "rest_length"), _kernels._array(fd, 2, "force_density")
    prm = _frozen(contact._prm if contact_params is None else contact_params)
    bufs = p.buf[None] if p.bufs is None else p.bufs
    B = q.shape[0]
    # parallel when ONE sub-step has the parallel kernel's work (not all n_steps together): the
    # threads then meet once per call, but on a 2-core machine waking them between env steps
    # costs more than they save below that (results/refactor/contact_loop.md)
    if B >= 8 and _kernels._parallel(p, B, 1, flags, compile_kernel=False):
        kernel, flags = _contact_parallel, flags | (_kernels._NCHUNK << _kernels._CHUNK_SHIFT)
    else:
        kernel = _contact_loop
        if p.bufs is not None and not _kernels._READY["copies"]:
            _kernels._compile("copies")
    try:
        err = kernel(q, qd, bufs, p.lanes, l0, fd, forces, ext, float(dt), int(n_steps), flags, _frozen(model.eta),
                     _frozen(model.rod_a), _frozen(model.rod_c), cstate.anchor, cstate.active, slip, prm)
    except TypeError:      # an array of another type or layout: the Python loop converts it
        return False
    if err:
        _kernels._raise(err, model, q, qd, rest_length, force_density, forces if external is None else external)
    return True


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


_NO_EXTERNAL = _frozen(np.empty((0, 1, 3)))   # no external force added to the contact forces


# ---------------------------------------------------------------------- divergence
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


# ---------------------------------------------------------------------- fused steps
class Plan:
    """What a compiled caller needs to run ``integrators.step``'s serial kernel from its own
    njit code (:func:`run_plan`): ``buf`` (the packed model), ``flags`` (integrator, projection,
    control mode), ``dt`` (s) and ``n_steps``. Opaque: build it with :func:`compiled_plan`."""
    __slots__ = ("model", "buf", "flags", "dt", "n_steps")

    def buffer(self, params=None) -> np.ndarray | None:
        """The packed buffer for ``params`` (one shared row) or the model's own (None); None
        when ``params`` has one row per copy (the per-copy kernels do not fuse)."""
        if params is None:
            return self.buf
        if params.batch_size != 1:
            return None
        return _kernels._pack_params(self.model, params).buf


def compiled_plan(model: Model, integrator: str, dt: float, n_steps: int, batch_size: int,
                  control: str = "rest_length", backend: str = "auto") -> Plan | None:
    """A :class:`Plan` for ``n_steps`` steps of ``integrator`` (projected) on ``batch_size``
    copies whose control is ``control`` per string (``"rest_length"``, m, or
    ``"force_density"``, N/m, with the model's rest lengths), or None where the fused serial
    kernel does not apply (an implicit method, or a batch large
    enough for the parallel kernel: then :func:`step` runs it). Issues the stability warning
    of :func:`integrators.step` once, as it would."""
    if not compiled_physics(integrator, backend):
        return None
    info = integrators.resolve(integrator)
    p = _kernels._CACHE.get(id(model)) or _kernels._packed(model)
    flags = _kernels._flags(p, info.name, True)
    if batch_size >= 8 and _kernels._parallel(p, batch_size, n_steps, flags):
        return None
    if control == "force_density":
        flags |= _kernels._L0DEF | _kernels._FD
    elif control != "rest_length":
        raise ValueError(f"control: unknown {control!r}; choose 'rest_length' or 'force_density'")
    integrators._check_stability(model, info, dt)
    plan = Plan()
    plan.model, plan.buf, plan.flags, plan.dt, plan.n_steps = model, p.buf, int(flags), float(dt), int(n_steps)
    return plan


_run_serial, _serial_setup = _kernels._run_serial, _kernels._serial_setup

_advance_c, _advance_one_c = _kernels._advance_contact, _kernels._advance_one_contact
_copies_check, _view, _soa_width_nb = _kernels._copies_check, _kernels._view, _kernels._soa_width_nb

@njit(inline="always", cache=True)
def _contact_check(q, qd, bufs, l0, fd, W, ext, flags):
    """(error code, int64 view of bufs, layout, k, m, n) of a contact loop call: the driver's
    checks (``_kernels._copies_check``, W as its external force) and ext rows 0, 1 or B of
    (n, 3) (error 5 otherwise)."""
    err, ibs, L, k, m, n = _copies_check(q, qd, q, qd, bufs, l0, fd, W, flags, True)
    if err == 0 and ext.shape[0] > 0 and ((ext.shape[0] != 1 and ext.shape[0] != q.shape[0])
                                          or ext.shape[1] != n or ext.shape[2] != 3):
        err = 5
    return err, ibs, L, k, m, n

@njit(cache=True)   # holds the GIL: the one-copy driver uses the scratch inside the buffers
def _contact_loop(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, anchor, active,
                  slip, prm):
    """The contact sub-steps of :func:`advance` on the whole batch, on this thread, in place: the
    loop driver with contact (``_kernels._advance_contact``, or its one-copy instance below
    ``_SOA_MIN_BATCH`` copies), ``n_steps`` steps, each with the contact forces of its start
    plus ``ext`` (0, 1 or B rows of (n, 3) N); ``W`` (B, n, 3) gets the last step's forces,
    ``anchor``, ``active``, ``slip`` the contact state. ``bufs`` (1, len) the shared
    packed buffer or (B, len) one per copy (``lanes``: their SIMD lane blocks). Returns the
    kernel's error code (0: done)."""
    err, ibs, L, k, m, n = _contact_check(q, qd, bufs, l0, fd, W, ext, flags)
    if err:
        return err
    E, lanes1 = _serial_setup(bufs, q.shape[0])[4:]     # the serial kernels' choice of instance
    if E != 1:       # the SIMD instance reads per-copy constants from the lane blocks, shared ones from w
        lanes1 = _view(lanes, 0, (lanes.shape[0] if bufs.shape[0] > 1 else 0, lanes.shape[1], lanes.shape[2]))
    contact = (eta, rod_a, rod_c, prm, anchor, active, slip, ext)
    if E == 1:
        _advance_one_c(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                       contact)
    else:
        _advance_c(bufs[0], ibs[0], L, k, m, n, q, qd, 0, q.shape[0], l0, fd, W, dt, n_steps, flags, lanes1,
                   contact)
    return 0

@njit(parallel=True, cache=True)   # holds the GIL, as _kernels._run_parallel does
def _contact_parallel(q, qd, bufs, lanes, l0, fd, W, ext, dt, n_steps, flags, eta, rod_a, rod_c, anchor,
                      active, slip, prm):
    """:func:`_contact_loop` on chunks of whole SIMD blocks on all threads (``prange``; the
    chunk count in ``flags >> _CHUNK_SHIFT``): each chunk runs all ``n_steps`` sub-steps of
    its copies (contact forces, then the SIMD driver with its own scratch), so the threads
    meet once per call, not once per sub-step. Same arguments and bits as
    :func:`_contact_loop`."""
    err, ibs, L, k, m, n = _contact_check(q, qd, bufs, l0, fd, W, ext, flags)
    if err:
        return err
    B = q.shape[0]
    E = _soa_width_nb(k)
    nb = (B + E - 1) // E
    nch = min(nb, max(flags >> _kernels._CHUNK_SHIFT, 1))
    contact = (eta, rod_a, rod_c, prm, anchor, active, slip, ext)
    for c in prange(nch):
        # the driver only reads the buffers; each chunk has its own scratch and copies
        _advance_c(bufs[0], ibs[0], L, k, m, n, q, qd, (c * nb // nch) * E, min(B, ((c + 1) * nb // nch) * E),
                   l0, fd, W, dt, n_steps, flags, lanes, contact)
    return 0

@njit(cache=True)   # holds the GIL: the physics kernel uses the scratch inside buf
def run_plan(q, qd, qo, qdo, buf, controls, dt, n_steps, flags):
    """From njit code: the physics of a :class:`Plan` (its ``buf``, ``dt``, ``n_steps``,
    ``flags``) from ``q``, ``qd`` into ``qo``, ``qdo`` (B, k, 6) with ``controls`` (B, m)
    the rest lengths or force densities of its control mode. Returns the kernel's error
    code (0: done)."""
    return _run_serial(q, qd, qo, qdo, buf, controls, controls, q, dt, n_steps, flags)

@njit(inline="always", cache=True, nogil=True)
def _update(ctrl, speed, action, rate, dv, dt, low, high, actuated, base, fill_base, motor, ctrl_out,
            speed_out, phys_out):
    B, na = ctrl.shape
    m = phys_out.shape[1]
    per_copy = rate.shape[0] > 1
    for b in range(B):
        if fill_base:            # the physics row before its actuated columns are set
            for j in range(m):
                phys_out[b, j] = base[j]
        else:
            for j in range(m):
                phys_out[b, j] = 0.0
        rb = b if per_copy else 0
        for i in range(na):
            v = 0.0
            if motor:
                d = action[b, i] * rate[rb, i] - speed[b, i]
                if d < -dv[rb]:
                    d = -dv[rb]
                if d > dv[rb]:
                    d = dv[rb]
                v = speed[b, i] + d
                x = ctrl[b, i] + v * dt
            else:
                x = ctrl[b, i] + action[b, i] * rate[rb, i]
            # np.clip(x, lo, hi) == minimum(maximum(x, lo), hi), NaN propagating
            if x < low[i]:
                x = low[i]
            if x > high[i]:
                x = high[i]
            if motor:
                if (x <= low[i] and v < 0.0) or (x >= high[i] and v > 0.0):
                    v = 0.0
                speed_out[b, i] = v
            ctrl_out[b, i] = x
            phys_out[b, actuated[i]] = x

@njit(cache=True, nogil=True)
def apply_controls(ctrl, action, rate, low, high, actuated, base, fill_base, ctrl_out, phys_out):
    """``ctrl_out = clip(ctrl + action * rate, low, high)`` (B, na) and the physics input
    ``phys_out`` (B, m): ``base`` (m,) (rest lengths; zeros for force densities when
    ``fill_base`` is False) with the actuated columns set to ``ctrl_out``. ``rate`` (P, na):
    one row shared by every copy (P = 1) or one per copy (P = B)."""
    _update(ctrl, ctrl, action, rate, low, 0.0, low, high, actuated, base, fill_base, False, ctrl_out,
            ctrl_out, phys_out)

@njit(cache=True, nogil=True)
def apply_motor(ctrl, speed, action, max_rate, dv, dt, low, high, actuated, base, fill_base,
                ctrl_out, speed_out, phys_out):
    """Motor model of ``Actuation.apply_motor``: ``v = speed + clip(action * max_rate - speed,
    -dv, dv)``, ``ctrl_out = clip(ctrl + v * dt, low, high)``, ``v = 0`` where the control
    sits on a bound and ``v`` pushes beyond it (``speed_out``), and the physics input
    ``phys_out`` as :func:`apply_controls`. ``max_rate`` (P, na) and ``dv`` (P,): one row
    shared (P = 1) or one per copy (P = B)."""
    _update(ctrl, speed, action, max_rate, dv, dt, low, high, actuated, base, fill_base, True, ctrl_out,
            speed_out, phys_out)

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
