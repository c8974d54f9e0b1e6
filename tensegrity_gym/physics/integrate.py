"""Time steps of a batch of states: :func:`step` (a new ``State``) and :func:`step_inplace` (into
the state's own arrays, as fast as the kernel), dispatched to a backend by name. No gymnasium
import. SI units.

Integrators (select by name):

=======================  =====  ========================================================
name                     order  notes
=======================  =====  ========================================================
``semi_implicit_euler``  1      symplectic Euler: v += dt a(q, v); q += dt v. With
                                ``project=True`` each rod direction moves along its great
                                circle instead of ``b += dt b'`` (``backends/numba/equations._drift_rod``), so
                                energy stays bounded and angular momentum is kept (no
                                secular drift, spinning bodies included) without damping.
``rk4``                  4      classic Runge-Kutta.
``dop853``               8      adaptive, ``scipy.integrate.solve_ivp`` (reference method).
``radau``                5      adaptive implicit (stiff strings), ``solve_ivp``.
``implicit_euler``       1      backward Euler, Newton with a finite-difference Jacobian
                                (usually one linear solve per step): stable at any dt
                                for stiff strings; dissipates energy
                                (:mod:`tensegrity_gym.physics.implicit`).
=======================  =====  ========================================================

Stability checks
----------------
For the explicit fixed-step methods (``semi_implicit_euler``, ``rk4``) the first call of
:func:`step`/:func:`simulate` with a given (model, integrator, dt) compares ``dt`` with the
estimated stability limit (:func:`stability_limit`: :func:`tensegrity_gym.physics.stability.stable_step_estimate`
at the structure's initial state, string damping included; computed once per model and
cached) and issues a
:class:`StabilityWarning` naming the limit when ``dt`` exceeds it. Later calls with the same
(model, integrator, dt) cost one set lookup. :func:`simulate` raises
:class:`SimulationDiverged` naming the time and the likely cause when the state stops being
finite.

Constraint drift
----------------
The equations keep the *second* derivatives of ``|b| = 1``, ``b . b' = 0`` and of the node
constraints, not the constraints themselves. With ``project=True`` (default for the
fixed-step methods) each step ends by normalising ``b``, removing the component of ``b'``
along ``b`` and putting constrained nodes back on their point/line/plane
(:func:`tensegrity_gym.physics.project`); semi-implicit Euler then also moves ``b`` along
its great circle (geodesic on the unit sphere, ``r`` keeps the plain Euler update), so the
projection only removes round-off. With ``project=False`` nothing is changed (plain
``q += dt q'``) and the drift is left to be measured (``physics.geometry.constraint_violation``). The adaptive methods never
project inside ``solve_ivp``; their drift is set by their tolerances.

Backends
--------
The fixed-step methods run fused compiled kernels (:mod:`tensegrity_gym.backends.numba`; with a
callable ``external``, Python calls it and the kernels do the physics: :func:`_callable_step`);
the adaptive and implicit methods evaluate the same kernels' accelerations. ``backend`` is
"auto" (default) or "numba" (the same), or "torch" in :func:`step` / :func:`simulate`
(:mod:`tensegrity_gym.backends.torch`). The NumPy formulation the kernels were transcribed from
is the test oracle ``tests/oracle_numpy.py`` (not installed).
"""
from __future__ import annotations
from __future__ import annotations

import math

import numpy as np

from ..backends.numba import api as numba_api
from ..backends.numba.divergence import finite_pair, unit_axes
from ..backends.numba.plans import lean_plan
from ..core.checks import check_finite, check_unit_axes, is_integer
from ..core.integrators import EXPLICIT, IMPLICIT, resolve
from ..core.model import Model, State
from ..core.params import check_params
from . import implicit
from .backends import get_backend
from .adaptive import adaptive
from .evaluate import external_forces
from .stability import check_stability

__all__ = ["step", "step_inplace", "rk4_update"]

_F8 = np.dtype(np.float64)


def _as_batch(x, B, m, name):
    """``x`` (m,) or (B, m) as a float array; ValueError naming ``name``, the index and the value
    for another shape, a NaN/inf entry or (``rest_length``) a negative one."""
    if x is None:
        return None
    x = np.asarray(x, dtype=float)
    if x.shape not in ((m,), (B, m)):
        raise ValueError(f"{name}: expected shape ({m},) or ({B}, {m}), got {x.shape}")
    check_finite(x, name, nonnegative=name == "rest_length")
    return x


#: | |b| - 1 | above which :func:`step` refuses a rod axis ``b`` of the state it is given: a zero
#: or badly scaled axis is an error, the small drift of a run without projection is not
AXIS_TOLERANCE = 0.5


def _state_ok(q, qd) -> bool:
    """True if the state arrays are finite and every rod axis has unit length within
    :data:`AXIS_TOLERANCE`, by compiled passes (:func:`~tensegrity_gym.backends.numba.divergence.finite_pair`,
    :func:`~tensegrity_gym.backends.numba.divergence.unit_axes`) when they are C-contiguous float64
    (B, k, 6) ndarrays, else False (the caller then runs the NumPy checks, which name the entry)."""
    return (type(q) is np.ndarray and type(qd) is np.ndarray and q.ndim == 3 and qd.ndim == 3
            and q.dtype == np.float64 and qd.dtype == np.float64 and q.flags.c_contiguous
            and qd.flags.c_contiguous and finite_pair(q, qd) and unit_axes(q, AXIS_TOLERANCE))


def _check_inputs(state, n_steps, external) -> int:
    """``n_steps`` as an int (ValueError unless a positive integer) after checking that the state
    is finite with unit rod axes and an array ``external`` is finite (ValueError naming the field,
    the index and the value)."""
    if not is_integer(n_steps) or n_steps < 1:
        raise ValueError(f"n_steps: must be a positive integer (steps per call), got {n_steps!r}")
    if not _state_ok(state.q, state.qd):
        check_finite(np.asarray(state.q), "state.q")
        check_finite(np.asarray(state.qd), "state.qd")
        check_unit_axes(state.q, "state.q", AXIS_TOLERANCE)
    if external is not None and not callable(external):
        check_finite(np.asarray(external, dtype=float), "external")
    return int(n_steps)


def step(model: Model, state: State, dt: float, integrator: str = "semi_implicit_euler", *,
         rest_length=None, force_density=None, external=None, project: bool = True,
         n_steps: int = 1, backend: str = "auto", rtol: float = 1e-10, atol: float = 1e-12,
         params=None, device=None, dtype=None) -> State:
    """Advance ``state`` by ``n_steps`` steps of ``dt`` seconds.

    Parameters
    ----------
    rest_length : (m,) or (B, m) string rest lengths, m. Default: the model's.
    force_density : (m,) or (B, m) force densities added by a controller, N/m.
    external : (B, n, 3) nodal forces in N held over the step, or a callable
        ``external(q, qd, t) -> (B, n, 3)`` evaluated at every stage.
    project : project onto the constraints after each fixed step (see module doc).
    backend : "auto", "numba" (the same) or "torch" (:mod:`tensegrity_gym.backends.torch`, fixed-step
        methods, array ``external`` only; ``device`` / ``dtype``: torch device and float32/float64).
    rtol, atol : tolerances of the adaptive methods.
    params : :class:`~tensegrity_gym.core.params.Params` with 1 row (shared) or B rows (copy b steps
        with row b's masses, stiffnesses, damping, rest lengths, node drag, gravity, anchors);
        default None: the model's own values. With ``params`` the stability check is skipped
        (the model's estimated limit need not hold for other values).

    ValueError naming the field, the index and the value for a non-finite state, a rod axis ``b``
    whose length is not 1 (within :data:`AXIS_TOLERANCE`), a non-finite rest length, force density
    or external force, a negative rest length, and for ``n_steps`` that is not a positive integer.
    """
    info = resolve(integrator)
    if not ((math.isfinite(dt) if type(dt) is float else np.isfinite(dt)) and dt > 0):
        raise ValueError(f"dt: must be a positive finite time step in seconds, got {dt}")
    n_steps = _check_inputs(state, n_steps, external)
    be = get_backend(backend)
    if be.options:    # a backend on another array library: NumPy State in and out, its fixed-step methods
        if info.name not in be.methods:
            raise ValueError(f"integrator: backend={be.name!r} runs {list(be.methods)}, not {info.name!r}")
        if params is None:
            check_stability(model, info, dt)
        return be.step_state(model, state, dt, info.name, rest_length=rest_length,
                             force_density=force_density, external=external, project=project,
                             n_steps=n_steps, device=device, dtype=dtype, params=params)
    if device is not None or dtype is not None:
        raise ValueError(f"device / dtype: options of backend='torch'; backend={backend!r} computes in float64 "
                         "on the CPU")
    B, m = state.batch_size, model.n_strings
    rest_length = _as_batch(rest_length, B, m, "rest_length")
    force_density = _as_batch(force_density, B, m, "force_density")
    if params is not None:
        params = check_params(model, params, B)
    if info.adaptive:
        return adaptive(model, state, dt * n_steps, info, rest_length, force_density, external, rtol, atol,
                        params=params, backend=backend)
    if params is None:
        check_stability(model, info, dt)
    if info.name in IMPLICIT:
        return implicit.step(model, state, dt, info.name, rest_length=rest_length,
                             force_density=force_density, external=external, project=project,
                             n_steps=n_steps, params=params, backend=backend)
    if callable(external):
        return _callable_step(model, state, dt, info.name, rest_length, force_density, external, project,
                              n_steps, params)
    return numba_api.step(model, state, dt, info.name, rest_length=rest_length,
                          force_density=force_density, external=external, project=project,
                          n_steps=n_steps, params=params)


def step_inplace(model: Model, state: State, dt: float, integrator: str = "semi_implicit_euler", *,
                 rest_length=None, force_density=None, external=None, project: bool = True, n_steps: int = 1,
                 params=None, backend: str = "auto", rtol: float = 1e-10, atol: float = 1e-12) -> float:
    """:func:`step` into the state's own arrays: ``state.q`` and ``state.qd`` (B, k, 6), writable
    C-contiguous float64 (m, 1, m/s, 1/s), are overwritten with the state after ``n_steps`` steps
    of ``dt`` s. Returns the time after the steps, s (``state.t`` plus ``dt`` added step by step,
    as :func:`step` sums it; ``State`` is frozen, so ``state.t`` itself stays: keep the returned
    time, or ``State(state.q, state.qd, t)``). Bit for bit what :func:`step` returns, with the
    same arguments and the same checks (ValueError naming the field, the index and the value).

    The fixed-step explicit methods on the numba backend with array inputs (the fast path: no
    allocation, one compiled call, about the kernel's own cost per call) write in place; any
    other method, backend or a callable ``external`` runs :func:`step` and copies its result in.
    ValueError if ``state.q`` / ``state.qd`` are not writable C-contiguous float64 arrays.

    A call that repeats an earlier one's method, ``dt``, ``project`` and ``backend`` on fewer than
    8 copies without control arrays or ``params`` reuses that call's checks of those arguments
    (kept on the model) and checks only ``n_steps`` and the state: then its cost is the compiled
    call's."""
    q = state.q
    qd = state.qd
    plans = model.__dict__.get("_inplace_plans")
    if (plans is not None and rest_length is None and force_density is None and external is None and params is None
            and type(n_steps) is int and n_steps > 0 and type(q) is np.ndarray and type(qd) is np.ndarray
            and q.dtype is _F8 and qd.dtype is _F8 and q.flags.carray and qd.flags.carray):
        plan = plans.get((integrator, dt, project, backend))
        if plan is not None and q.shape[0] < 8 and finite_pair(q, qd) and unit_axes(q, AXIS_TOLERANCE):
            kernel, buf, flags = plan
            try:
                err = kernel(q, qd, q, qd, buf, dt, n_steps, flags)
            except TypeError:      # an array the compiled call does not take: the checks below say why
                err = -1
            if err == 0:
                t = state.t + dt
                if n_steps > 1:
                    for _ in range(n_steps - 1):
                        t = t + dt
                return t
    info = resolve(integrator)
    if not ((math.isfinite(dt) if type(dt) is float else np.isfinite(dt)) and dt > 0):
        raise ValueError(f"dt: must be a positive finite time step in seconds, got {dt}")
    if not (type(q) is np.ndarray and type(qd) is np.ndarray and q.dtype == np.float64 and qd.dtype == np.float64
            and q.ndim == 3 and q.flags.c_contiguous and qd.flags.c_contiguous and q.flags.writeable
            and qd.flags.writeable):
        raise ValueError("step_inplace: state.q and state.qd must be writable C-contiguous float64 arrays (B, k, 6); "
                         f"got {type(q).__name__} {getattr(q, 'dtype', '')} {np.shape(q)} and "
                         f"{type(qd).__name__} {getattr(qd, 'dtype', '')} {np.shape(qd)}")
    if info.name not in EXPLICIT or get_backend(backend).name != "numba" or callable(external):
        new = step(model, state, dt, integrator, rest_length=rest_length, force_density=force_density,
                   external=external, project=project, n_steps=n_steps, backend=backend, rtol=rtol, atol=atol,
                   params=params)
        q[...] = new.q
        qd[...] = new.qd
        return new.t
    n_steps = _check_inputs(state, n_steps, external)
    B, m = q.shape[0], model.n_strings
    if rest_length is not None:
        rest_length = _as_batch(rest_length, B, m, "rest_length")
    if force_density is not None:
        force_density = _as_batch(force_density, B, m, "force_density")
    if params is not None:
        params = check_params(model, params, B)
    else:
        check_stability(model, info, dt)
    numba_api.step_inplace(model, q, qd, dt, info.name, rest_length=rest_length, force_density=force_density,
                           external=external, project=project, n_steps=n_steps, params=params)
    if rest_length is None and force_density is None and external is None and params is None and B < 8:
        plans = model.__dict__.setdefault("_inplace_plans", {})
        if len(plans) >= 64:       # a caller that varies dt from call to call: keep the memo small
            plans.clear()
        plans[(integrator, dt, project, backend)] = lean_plan(model, info.name, project)
    t = state.t + dt
    for _ in range(n_steps - 1):
        t = t + dt
    return t


def _callable_step(model, state, dt, name, rest_length, force_density, external, project, n_steps, params):
    """Fixed steps with a callable ``external(q, qd, t)`` on the numba kernels: Python calls the
    function, the kernels do the physics. Semi-implicit Euler evaluates it once per step, at the
    step's start, so each step is one kernel step with that force held; RK4 evaluates it at each
    of the four stages, so the stages' accelerations come from the kernels' ``accelerations``
    entry and the projection from their ``project`` entry (the same equations as the compiled
    steps: an ``external`` that returns a constant array gives their result to round-off)."""
    q, qd, t = state.q, state.qd, state.t
    for _ in range(n_steps):
        if name == "semi_implicit_euler":
            nxt = numba_api.step(model, State(q, qd, t), dt, name, rest_length=rest_length,
                                 force_density=force_density, external=external_forces(external, q, qd, t),
                                 project=project, params=params)
            q, qd = nxt.q, nxt.qd
        else:   # rk4
            q, qd = rk4_update(lambda q, qd, t: numba_api.accelerations(
                model, q, qd, rest_length, force_density, external_forces(external, q, qd, t), params), q, qd, t, dt)
            if project:
                q, qd = numba_api.project(model, q, qd)
        t = t + dt
    return State(q=q, qd=qd, t=t)


def rk4_update(acc, q, qd, t, dt):
    """One classic RK4 step of ``(q, qd)`` over ``dt`` s for accelerations ``acc(q, qd, t)``
    (returns the new ``(q, qd)``, unprojected). The operations and their order are those of the
    kernels' RK4 (the numba loop driver ``_drive_py`` with ``_stage_soa``), so the results agree bit for bit
    when ``acc`` is the kernels' accelerations entry."""
    h = 0.5 * dt
    a1 = acc(q, qd, t)
    q2, qd2 = q + h * qd, qd + h * a1
    a2 = acc(q2, qd2, t + h)
    q3, qd3 = q + h * qd2, qd + h * a2
    a3 = acc(q3, qd3, t + h)
    q4, qd4 = q + dt * qd3, qd + dt * a3
    a4 = acc(q4, qd4, t + dt)
    return (q + dt / 6.0 * (qd + 2.0 * qd2 + 2.0 * qd3 + qd4),
            qd + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4))


