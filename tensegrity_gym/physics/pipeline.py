"""The physics pipeline of a batch of B copies: actuation -> contact -> forces -> integration.

The public entry points the environments (and any other caller that owns its state arrays) use;
no gymnasium import, SI units. Every function here runs the equations written once in a
backend (:mod:`tensegrity_gym.backends`; the NumPy oracle is ``tests/oracle_numpy.py``) through
:func:`tensegrity_gym.physics.step` or its in-place compiled twin; nothing here copies a kernel
loop.

:func:`step` ``(model, state, dt, integrator, *, n_steps, contact=None, cstate=None, ...)``
    ``n_steps`` physics steps. Without ``contact`` it is :func:`tensegrity_gym.physics.step` (one
    call, all steps inside the compiled loop). With a
    :class:`~tensegrity_gym.physics.contact.GroundContact` each step is: contact forces of the
    whole batch from the state at the step's start (stick/slip anchors updated in ``cstate``),
    then ONE integrator step with those forces held over it (``external=W``). Returns a new
    ``State`` (and a new ``ContactState``). :func:`contact_step` is the same with the contact first.
:func:`control_step` ``(model, state, actuation, controls, action, dt, integrator, *, speed, ...)``
    One control step from actions in [-1, 1]: the actuation update
    (:meth:`tensegrity_gym.physics.actuation.Actuation.update`: rate limits or the cable motor,
    bounds, rest-length offsets), then :func:`step` with the new controls. Returns a
    :class:`ControlStep` ``(state, controls, speed, cstate)``; every env's control step is this.
:func:`run_steps`
    The physics of :func:`step`, in place on C-contiguous float64 arrays ``q``, ``qd`` (B, k, 6)
    and ``cstate``, with caller-owned scratch and no checks: no allocation and no ``State`` per
    step (the env fast path).
:func:`diverged`
    (B,) bool: which copies went non-finite or far (the divergence check of every env).
:func:`compiled_plan`
    For a task that fuses its own bookkeeping with the physics in one compiled call: the packed
    model, integrator and control mode of the serial step kernel as an opaque ``Plan``, run from
    njit code by :func:`tensegrity_gym.backends.numba.entries.run_plan`.

With the numba kernels the contact steps of :func:`run_steps` run in ONE compiled call, written
inside the loop driver (:func:`tensegrity_gym.backends.numba.api.contact_steps`); the Python loop
of :func:`run_steps` (the same calls, in the same order, bit for bit) serves implicit Euler and
tests.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..backends.numba import api as numba_api
from ..backends.numba.api import contact_steps as _contact_compiled, rods_tuple
from ..backends.numba.divergence import diverged
from ..backends.numba.plans import make_plan
from ..core.checks import check_action, check_array
from ..core.integrators import EXPLICIT, resolve, uses_numba
from ..core.model import Model, State
from .contact import ContactState, GroundContact, check_prm_rows, forces_inplace
from .rod_contact import RodContact, add_rod_forces
from .stability import check_stability
from . import integrate   # integrate.step looked up at call time: a caller may wrap it
from .integrate import _as_batch

__all__ = ["step", "contact_step", "control_step", "ControlStep", "run_steps", "diverged", "compiled_physics",
           "compiled_plan"]


def compiled_physics(integrator: str, backend: str = "auto") -> bool:
    """True if :func:`tensegrity_gym.physics.step` runs the numba kernels for ``integrator`` (a fixed-step
    explicit method) and ``backend`` with array inputs; False otherwise (also for a backend name
    :func:`tensegrity_gym.physics.step` refuses: it then raises the ValueError itself)."""
    info = resolve(integrator)
    if info.name not in EXPLICIT:
        return False
    try:
        return uses_numba(backend, info)
    except ValueError:
        return False


# ---------------------------------------------------------------------- stepping
def run_steps(model: Model, q: np.ndarray, qd: np.ndarray, dt: float, integrator: str = "semi_implicit_euler", *,
              n_steps: int = 1, rest_length=None, force_density=None, external=None, params=None,
              project: bool = True, backend: str = "auto", contact: GroundContact | None = None,
              cstate: ContactState | None = None, contact_params=None, forces=None, slip=None,
              compiled: bool | None = None, rods: RodContact | None = None) -> None:
    """In place: ``n_steps`` steps of ``dt`` s of ``q``, ``qd`` (B, k, 6), writable C-contiguous
    float64 (m, 1, m/s, 1/s). Inputs as :func:`tensegrity_gym.physics.step` takes them (``integrator`` a
    resolved name; shapes are checked by the kernels, values are the caller's duty).

    With ``contact`` (and its ``cstate``, updated in place): per step, contact forces from the
    state at the step's start into ``forces`` (B, n, 3) N (plus ``external`` if given), slip
    flags into ``slip`` (B, n_c) bool, then one integrator step with ``external=forces``.
    ``contact_params``: (B, 9) per-copy contact parameters or None (the contact's own).
    ``compiled``: whether the numba kernels run (default: :func:`compiled_physics`).
    ``rods``: a :class:`~tensegrity_gym.physics.rod_contact.RodContact`, or None (no rod-rod
    contact, no rod-rod code runs): its forces at each step's start are added to the step's
    external forces after the ground's (with ``contact``: inside the compiled loop; without: a
    Python loop of one integrator call per step)."""
    if compiled is None:
        compiled = compiled_physics(integrator, backend)
    if contact is None and rods is None:
        _physics(model, q, qd, dt, integrator, n_steps, rest_length, force_density, external, params, project,
                 backend, compiled)
        return
    B = q.shape[0]
    if forces is None:
        forces = np.empty((B, model.n_nodes, 3))
    if contact is None:
        for _ in range(int(n_steps)):
            forces[...] = 0.0 if external is None else external
            add_rod_forces(rods, model, q, qd, forces)
            _physics(model, q, qd, dt, integrator, 1, rest_length, force_density, forces, params, project, backend,
                     compiled)
        return
    if slip is None:
        slip = np.empty((B, 2 * model.n_bars), bool)
    if compiled and _contact_compiled(
            model, q, qd, dt, integrator, n_steps, rest_length, force_density, external, params, project, contact,
            cstate, contact_params, forces, slip, None if rods is None else rods_tuple(model, rods.prm)):
        return
    contact_forces = forces_inplace
    for _ in range(int(n_steps)):
        contact_forces(contact, model, q, qd, cstate, forces, slip, contact_params)
        if external is not None:
            forces += external
        if rods is not None:
            add_rod_forces(rods, model, q, qd, forces)
        _physics(model, q, qd, dt, integrator, 1, rest_length, force_density, forces, params, project, backend,
                 compiled)


def _physics(model, q, qd, dt, name, n_steps, rest_length, force_density, external, params, project, backend,
             compiled):
    """One in-place integrator call: the compiled kernel, or :func:`tensegrity_gym.physics.step` and a copy back."""
    if compiled:
        numba_api.step_inplace(model, q, qd, dt, name, rest_length=rest_length, force_density=force_density,
                               external=external, project=project, n_steps=n_steps, params=params)
        return
    st = integrate.step(model, State(q, qd, 0.0), dt, name, rest_length=rest_length, force_density=force_density,
                        external=external, project=project, n_steps=n_steps, backend=backend, params=params)
    q[...] = st.q
    qd[...] = st.qd


def step(model: Model, state: State, dt: float, integrator: str = "semi_implicit_euler", *, n_steps: int = 1,
         contact: GroundContact | None = None, cstate: ContactState | None = None, contact_params=None,
         external=None, backend: str = "auto", rods: RodContact | None = None, **inputs):
    """``n_steps`` physics steps of ``dt`` s for the whole batch (see the module doc).

    Without ``contact``: :func:`tensegrity_gym.physics.step` (returns a ``State``). With ``contact``:
    returns ``(State, ContactState)``, new objects (the inputs are not modified); ``external``
    (B, n, 3) N is added to the contact forces of every step. ``inputs``: ``rest_length``,
    ``force_density``, ``params``, ``project`` as :func:`tensegrity_gym.physics.step` takes them.
    ``rods``: a :class:`~tensegrity_gym.physics.rod_contact.RodContact` (rod-rod contact forces
    added at each step, :func:`run_steps`) or None; with ``rods`` and no ``contact`` it returns a
    ``State``."""
    if contact is None and rods is None:
        return integrate.step(model, state, dt, integrator, n_steps=n_steps, external=external, backend=backend,
                              **inputs)
    info = resolve(integrator)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a positive finite time step in seconds, got {dt}")
    if rods is not None and not isinstance(rods, RodContact):
        raise ValueError(f"rods: expected a RodContact or None, got {rods!r:.80}")
    if contact is None:
        return _rods_step(model, state, dt, info, n_steps, external, backend, rods, inputs)
    if cstate is None:
        raise ValueError("cstate: a ContactState is needed with contact (contact.init_contact_state)")
    B, m = state.batch_size, model.n_strings
    nc = 2 * model.n_bars
    if cstate.anchor.shape != (B, nc, 2) or cstate.active.shape != (B, nc):
        raise ValueError(f"contact state: expected anchor ({B}, {nc}, 2) and active ({B}, {nc}), got "
                         f"{cstate.anchor.shape} and {cstate.active.shape}")
    for name in ("rest_length", "force_density"):
        inputs[name] = _as_batch(inputs.get(name), B, m, name)
    if inputs.get("params") is None:
        check_stability(model, info, dt)
    if contact_params is not None:
        contact_params = check_prm_rows(contact, contact_params, B)
    q = np.array(state.q, dtype=np.float64, order="C")
    qd = np.array(state.qd, dtype=np.float64, order="C")
    cs = cstate.copy()
    ext = None if external is None else np.asarray(external, dtype=np.float64)
    run_steps(model, q, qd, dt, info.name, n_steps=n_steps, external=ext, backend=backend, contact=contact,
            cstate=cs, contact_params=contact_params, rods=rods, **inputs)
    t = state.t
    for _ in range(int(n_steps)):
        t = t + dt
    return State(q=q, qd=qd, t=t), cs


def _rods_step(model, state, dt, info, n_steps, external, backend, rods, inputs):
    """:func:`step` with rod-rod contact and no ground: a new ``State``."""
    B, m = state.batch_size, model.n_strings
    for name in ("rest_length", "force_density"):
        inputs[name] = _as_batch(inputs.get(name), B, m, name)
    if inputs.get("params") is None:
        check_stability(model, info, dt)
    q = np.array(state.q, dtype=np.float64, order="C")
    qd = np.array(state.qd, dtype=np.float64, order="C")
    ext = None if external is None else np.asarray(external, dtype=np.float64)
    run_steps(model, q, qd, dt, info.name, n_steps=n_steps, external=ext, backend=backend, rods=rods, **inputs)
    t = state.t
    for _ in range(int(n_steps)):
        t = t + dt
    return State(q=q, qd=qd, t=t)


class ControlStep(NamedTuple):
    """What :func:`control_step` returns (new objects; the inputs are not modified)."""
    #: rod state after the control step (q, qd (B, k, 6); t advanced by n_steps * dt s)
    state: State
    #: (B, na) the actuated strings' new controls: rest lengths (m) or force densities (N/m)
    controls: np.ndarray
    #: (B, na) the motor's new cable speeds (unit/s), or None without a motor model
    speed: np.ndarray | None
    #: the contact's new stick/slip state, or None without contact
    cstate: ContactState | None


def control_step(model: Model, state: State, actuation, controls, action, dt: float,
                 integrator: str = "semi_implicit_euler", *, n_steps: int = 1, speed=None, rest_offset=None,
                 contact: GroundContact | None = None, cstate: ContactState | None = None,
                 contact_params=None, external=None, params=None, project: bool = True,
                 backend: str = "auto", rods: RodContact | None = None) -> ControlStep:
    """One control step of the whole batch from actions: actuation, then ``n_steps`` physics
    steps of ``dt`` s (contact inside each when ``contact`` is given). What every env does per
    control step, as one pure call (brax's ``pipeline.step(sys, state, act)``).

    ``actuation``: a :class:`tensegrity_gym.physics.actuation.Actuation` (which strings, rest-length or
    force-density mode, bounds, rate limits, the cable motor). ``controls`` (B, na): the actuated
    strings' current controls (m or N/m); ``action`` (B, na) in [-1, 1] (an entry beyond it by
    more than ``checks.ACTION_TOL`` (1e-6) is an error, not clipped:
    :func:`tensegrity_gym.core.checks.check_action` with ``clip=False``); ``speed`` (B, na): the
    motor's current cable speeds (unit/s), needed when the actuation has a motor model (``max_accel``). ``rest_offset``
    (P, m) m, P = 1 or B: true minus commanded rest lengths of the robots. The actuation update
    is :meth:`Actuation.update <tensegrity_gym.physics.actuation.Actuation.update>`; the physics is
    :func:`step` with its ``rest_length`` / ``force_density`` (the other arguments as there;
    ``rods``: rod-rod contact, a :class:`~tensegrity_gym.physics.rod_contact.RodContact`, or None).
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
    kw = dict(n_steps=n_steps, external=external, backend=backend, params=params, project=project, rods=rods,
              **inputs)
    if contact is None:
        return ControlStep(step(model, state, dt, integrator, **kw), ctrl, speed, None)
    st, cs = step(model, state, dt, integrator, contact=contact, cstate=cstate, contact_params=contact_params, **kw)
    return ControlStep(st, ctrl, speed, cs)




def contact_step(model: Model, contact: GroundContact, state: State, cstate: ContactState, dt: float,
                 integrator: str = "semi_implicit_euler", n_steps: int = 1, external=None, rods=None, **inputs):
    """``n_steps`` physics steps with ground contact: :func:`step` with ``contact`` and ``cstate``
    (per step, contact forces from the state at its start (batched) then ONE integrator step with
    ``external=W + external`` for the whole batch). ``external``: optional (B, n, 3) extra nodal
    forces, N, held over every step. ``inputs``: ``rest_length`` / ``force_density`` /
    ``backend`` / ``project`` / ``params`` as :func:`tensegrity_gym.physics.step` takes them;
    ``rods``: a :class:`~tensegrity_gym.physics.rod_contact.RodContact` (rod-rod contact) or None.
    Returns ``(state, cstate)`` (new objects; the inputs are not modified)."""
    return step(model, state, dt, integrator, n_steps=n_steps, contact=contact, cstate=cstate,
                external=external, rods=rods, **inputs)


def compiled_plan(model: Model, integrator: str, dt: float, n_steps: int, batch_size: int,
                  control: str = "rest_length", backend: str = "auto"):
    """A :class:`~tensegrity_gym.backends.numba.plans.Plan` for ``n_steps`` steps of ``integrator``
    (projected) on ``batch_size`` copies whose control is ``control`` per string
    (``"rest_length"``, m, or ``"force_density"``, N/m, with the model's rest lengths), or None
    where the fused serial kernel does not apply (an implicit method, or a batch large enough for
    the parallel kernel: then :func:`step` runs it). Issues the stability warning of
    :func:`tensegrity_gym.physics.step` once, as it would."""
    if not compiled_physics(integrator, backend):
        return None
    info = resolve(integrator)
    plan = make_plan(model, info.name, dt, n_steps, batch_size, control)
    if plan is not None:
        check_stability(model, info, dt)
    return plan
