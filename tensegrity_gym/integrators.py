"""Time integrators for the batched dynamics of :mod:`tensegrity_gym.dynamics`.

Pure functions ``step(model, state, dt, ...) -> State``; no gymnasium import. SI units.

Integrators (select by name):

=======================  =====  ========================================================
name                     order  notes
=======================  =====  ========================================================
``semi_implicit_euler``  1      symplectic Euler: v += dt a(q, v); q += dt v. With
                                ``project=True`` each rod direction moves along its great
                                circle instead of ``b += dt b'`` (``_kernels._drift_rod``), so
                                energy stays bounded and angular momentum is kept (no
                                secular drift, spinning bodies included) without damping.
``rk4``                  4      classic Runge-Kutta.
``dop853``               8      adaptive, ``scipy.integrate.solve_ivp`` (reference method).
``radau``                5      adaptive implicit (stiff strings), ``solve_ivp``.
``implicit_euler``       1      backward Euler, Newton with a finite-difference Jacobian
                                (usually one linear solve per step): stable at any dt
                                for stiff strings; dissipates energy
                                (:mod:`tensegrity_gym.implicit`).
=======================  =====  ========================================================

Stability checks
----------------
For the explicit fixed-step methods (``semi_implicit_euler``, ``rk4``) the first call of
:func:`step`/:func:`simulate` with a given (model, integrator, dt) compares ``dt`` with the
estimated stability limit (:func:`stability_limit`: :func:`tensegrity_gym.dynamics.stable_step_estimate`
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
(:func:`tensegrity_gym.dynamics.project`); semi-implicit Euler then also moves ``b`` along
its great circle (geodesic on the unit sphere, ``r`` keeps the plain Euler update), so the
projection only removes round-off. With ``project=False`` nothing is changed (plain
``q += dt q'``) and the drift is left to be measured (``dynamics.constraint_violation``). The adaptive methods never
project inside ``solve_ivp``; their drift is set by their tolerances.

Backends
--------
The fixed-step methods run fused compiled kernels (:mod:`tensegrity_gym._kernels`; with a
callable ``external``, Python calls it and the kernels do the physics: :func:`_callable_step`);
the adaptive and implicit methods evaluate the same kernels' accelerations. ``backend`` is
"auto" (default) or "numba" (the same), or "torch" in :func:`step` / :func:`simulate`
(:mod:`tensegrity_gym.torch_backend`). The NumPy formulation the kernels were transcribed from
is the test oracle ``tests/oracle_numpy.py`` (not installed), no longer a backend.
"""
from __future__ import annotations

from dataclasses import dataclass

import math
import warnings
import weakref

import numpy as np

from . import dynamics as dyn
from .dynamics import Model, State
from .checks import check_finite, check_unit_axes, is_integer
from .params import check_params
from . import _kernels as _KERNELS   # numba is a required dependency: no fallback when it is missing

__all__ = ["INTEGRATORS", "step", "simulate", "accelerations", "Schedule", "IntegratorInfo", "SimulationDiverged",
           "StabilityWarning", "EvaluationBudgetExceeded", "stability_limit"]


class SimulationDiverged(FloatingPointError):
    """Raised when the state stops being finite; the message names time and cause."""


class Schedule:
    """Inputs that change over time, held piecewise constant (zero-order hold): ``values[i]``
    applies from ``t[i]`` s until ``t[i + 1]`` (the last row to the end of the run). Give one as
    ``rest_length=`` or ``force_density=`` to :func:`simulate` to replay cable commands.

    Parameters
    ----------
    t : (C,) command times, s, strictly increasing and finite.
    values : (C, m) one row per command (every copy), or (C, B, m) one per copy: rest lengths
        in m (finite, >= 0) or force densities in N/m (finite).
    name : ``"rest_length"`` or ``"force_density"`` (for the checks and the error messages).

    Time steps see the inputs at their start: the step from ``t_s`` to ``t_s + dt`` uses the row
    in force at ``t_s`` (a command time within ``1e-9 dt`` of a step's start counts as at it), so
    a command that falls inside a step takes effect at the next step. ValueError naming the
    field, the row and the value for bad input.
    """

    def __init__(self, t, values, name: str = "rest_length"):
        if name not in ("rest_length", "force_density"):
            raise ValueError(f"Schedule: name must be 'rest_length' or 'force_density', got {name!r}")
        try:
            tt = np.asarray(t, dtype=float)
            v = np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{name} schedule: times and values must be arrays of numbers") from None
        if tt.ndim != 1 or tt.size == 0:
            raise ValueError(f"{name} schedule: t must be a non-empty 1-D array of times (s), got shape {tt.shape}")
        if v.ndim not in (2, 3) or v.shape[0] != tt.size:
            raise ValueError(f"{name} schedule: values must have shape ({tt.size}, m) or ({tt.size}, B, m) "
                             f"(one row per command time), got {v.shape}")
        bad = np.flatnonzero(~np.isfinite(tt))
        if bad.size:
            raise ValueError(f"{name} schedule: t[{bad[0]}] is {float(tt[bad[0]])!r}; times must be finite (s)")
        back = np.flatnonzero(np.diff(tt) <= 0)
        if back.size:
            i = int(back[0]) + 1
            raise ValueError(f"{name} schedule: t[{i}] = {float(tt[i])!r} s is not after "
                             f"t[{i - 1}] = {float(tt[i - 1])!r} s; times must be strictly increasing")
        bad = ~np.isfinite(v) if name == "force_density" else ~(np.isfinite(v) & (v >= 0))
        if bad.any():
            pos = tuple(int(x) for x in np.argwhere(bad)[0])
            rule = "finite (N/m)" if name == "force_density" else "finite and >= 0 (m)"
            raise ValueError(f"{name} schedule: row {pos[0]} (t = {tt[pos[0]]:g} s), "
                             f"{'string' if v.ndim == 2 else 'copy, string'} {pos[1:] if v.ndim == 3 else pos[1]} "
                             f"is {float(v[pos])!r}; must be {rule}")
        self.t, self.values, self.name = tt, v, name

    def rows(self, times: np.ndarray, dt: float) -> np.ndarray:
        """Row index in force at each of ``times`` (s); ValueError if one is before ``t[0]``."""
        idx = np.searchsorted(self.t, np.asarray(times, float) + 1e-9 * dt, side="right") - 1
        if idx.size and idx[0] < 0:
            raise ValueError(f"{self.name} schedule: its first command is at t = {self.t[0]:g} s, after the "
                             f"run's start at t = {float(times[0]):g} s; add a row for the start")
        return idx

    def value(self, i: int, B: int, m: int) -> np.ndarray:
        """Row ``i`` as ``step`` takes it: (m,) or (B, m)."""
        v = self.values[i]
        if v.shape not in ((m,), (B, m)):
            raise ValueError(f"{self.name} schedule: values must have shape (C, {m}) or (C, {B}, {m}) for this "
                             f"structure and batch, got {self.values.shape}")
        return v

    def __repr__(self) -> str:
        return f"Schedule({self.name}, {self.t.size} commands from t = {self.t[0]:g} s to {self.t[-1]:g} s)"


def _records(state, n_rec, n_steps, name, progress):
    """``(q, qd)`` record arrays (n_rec + 1, B, k, 6), the first filled with ``state``, and a
    tqdm progress bar over ``n_steps`` (None without ``progress`` or tqdm) of :func:`simulate`."""
    qs = np.empty((n_rec + 1,) + state.q.shape)
    qds = np.empty_like(qs)
    qs[0], qds[0] = state.q, state.qd
    bar = None
    if progress:
        try:
            from tqdm import tqdm
            bar = tqdm(total=n_steps, unit="step", desc=name)
        except ImportError:  # pragma: no cover
            bar = None
    return qs, qds, bar


def _simulate_scheduled(model, state, dt, n_steps, integrator, record_every, rest_length, force_density, progress,
                        kw):
    """:func:`simulate` with :class:`Schedule` inputs: runs of steps with constant inputs, each
    an ordinary :func:`simulate` call (adaptive methods restart where the inputs change), split
    so that the records fall on the run's grid of ``record_every`` steps."""
    B, m = state.batch_size, model.n_strings
    n_steps = (n_steps // record_every) * record_every     # as simulate: the steps up to the last record
    starts = state.t + dt * np.arange(n_steps)
    idx = {}
    change = np.zeros(n_steps, bool)
    for name, x in (("rest_length", rest_length), ("force_density", force_density)):
        if isinstance(x, Schedule):
            if x.name != name:
                raise ValueError(f"{name}: got a Schedule of {x.name}")
            idx[name] = x.rows(starts, dt)
            change[1:] |= idx[name][1:] != idx[name][:-1]
    cuts = sorted(set(np.flatnonzero(change).tolist()) | {0, n_steps})
    n_rec = n_steps // record_every
    t0 = state.t
    ts = t0 + dt * record_every * np.arange(n_rec + 1)
    qs, qds, bar = _records(state, n_rec, n_steps, resolve(integrator).name, progress)
    st = state
    try:
        for a, b in zip(cuts[:-1], cuts[1:]):
            inputs = {name: (x.value(int(idx[name][a]), B, m) if isinstance(x, Schedule) else x)
                      for name, x in (("rest_length", rest_length), ("force_density", force_density))}
            # the head up to the first record boundary, the aligned middle (a record every
            # record_every steps), the tail after the last boundary (head and tail: < record_every steps)
            first = min(-(-a // record_every) * record_every, b)
            last = max(first, (b // record_every) * record_every)
            for lo, hi in ((a, first), (first, last), (last, b)):
                if hi <= lo:
                    continue
                middle = lo % record_every == 0 and hi % record_every == 0
                every = record_every if middle else hi - lo
                _, q, qd = simulate(model, st, dt, hi - lo, integrator, record_every=every, **inputs, **kw)
                if middle:
                    qs[lo // record_every + 1:hi // record_every + 1] = q[1:]
                    qds[lo // record_every + 1:hi // record_every + 1] = qd[1:]
                elif hi % record_every == 0:
                    qs[hi // record_every], qds[hi // record_every] = q[-1], qd[-1]
                st = State(q=q[-1], qd=qd[-1], t=t0 + dt * hi)
                if bar is not None:
                    bar.update(hi - lo)
    finally:
        if bar is not None:
            bar.close()
    return ts, qs, qds


class EvaluationBudgetExceeded(RuntimeError):
    """An adaptive method needed more right-hand-side evaluations than ``max_evaluations``
    (tolerances too tight for the span, or a very stiff structure): raised instead of running on."""


class StabilityWarning(UserWarning):
    """``dt`` is above the estimated stability limit of an explicit integrator."""


@dataclass(frozen=True)
class IntegratorInfo:
    name: str
    order: int
    adaptive: bool
    symplectic: bool
    description: str


INTEGRATORS: dict[str, IntegratorInfo] = {
    "semi_implicit_euler": IntegratorInfo("semi_implicit_euler", 1, False, True, "symplectic Euler"),
    "rk4": IntegratorInfo("rk4", 4, False, False, "classic 4th-order Runge-Kutta"),
    "dop853": IntegratorInfo("dop853", 8, True, False, "adaptive Dormand-Prince 8(5,3), scipy"),
    "radau": IntegratorInfo("radau", 5, True, False, "adaptive implicit Radau IIA, scipy (stiff)"),
    "implicit_euler": IntegratorInfo("implicit_euler", 1, False, False,
                                     "backward Euler, Newton, FD Jacobian (stiff strings, dissipative)"),
}
_IMPLICIT = ("implicit_euler",)
_EXPLICIT = ("semi_implicit_euler", "rk4")
_ALIASES = {"euler": "semi_implicit_euler", "symplectic_euler": "semi_implicit_euler",
            "semi-implicit-euler": "semi_implicit_euler", "DOP853": "dop853", "Radau": "radau"}


def resolve(name: str) -> IntegratorInfo:
    """The :class:`IntegratorInfo` for a name or alias; ValueError listing the choices otherwise."""
    if not isinstance(name, str):
        raise ValueError(f"integrator: expected a method name (one of {sorted(INTEGRATORS)}), got {name!r}")
    key = _ALIASES.get(name, name)
    if key not in INTEGRATORS:
        raise ValueError(f"integrator: unknown name {name!r}; choose one of {sorted(INTEGRATORS)}")
    return INTEGRATORS[key]


def _ext(external, q, qd, t):
    if external is None:
        return None
    if callable(external):
        return external(q, qd, t)
    return external


def accelerations(model: Model, q: np.ndarray, qd: np.ndarray, rest_length=None, force_density=None,
                  external=None, params=None, backend: str = "auto") -> np.ndarray:
    """Accelerations ``[r'', b'']`` (B, k, 6) (m/s^2, 1/s^2) of the states ``q``, ``qd`` (B, k, 6)
    (or (k, 6)), inputs as :func:`step` takes them (``external`` an array). What the adaptive and
    implicit methods and the finite-difference Jacobians evaluate: the numba kernels' equations
    (:func:`tensegrity_gym._kernels.accelerations`, the ones every fixed step runs; their NumPy
    reference is the test oracle ``tests/oracle_numpy.py``). ``backend``: "auto" or "numba"."""
    _numba_backend(backend)
    return _KERNELS.accelerations(model, q, qd, rest_length, force_density, external, params)


def _use_numba(backend: str, info: IntegratorInfo) -> bool:
    """Whether :func:`step` runs the numba kernels (the fixed-step explicit methods)."""
    return not info.adaptive and _numba_backend(backend)


#: what ``backend="numpy"`` says since the NumPy step path became the test oracle (issue 12)
NUMPY_REMOVED = ("'numpy' is no longer a backend: every fixed step, projection, acceleration and contact "
                 "force runs on the numba kernels (the NumPy reference equations are the test oracle "
                 "tests/oracle_numpy.py of the repository); choose 'auto' or 'numba'")


def _numba_backend(backend: str) -> bool:
    """True for ``backend`` "auto" or "numba" (the numba kernels); ValueError naming ``backend``
    for another name ("numpy": no longer a backend, :data:`NUMPY_REMOVED`)."""
    if backend == "numpy":
        raise ValueError(f"backend: {NUMPY_REMOVED}")
    if backend not in ("auto", "numba"):
        raise ValueError(f"backend: unknown {backend!r}; choose 'auto' or 'numba'")
    return True


_LIMIT_CACHE: "weakref.WeakKeyDictionary[Model, dict]" = weakref.WeakKeyDictionary()


def stability_limit(model: Model) -> dict:
    """Largest stable step (s) of the explicit methods for ``model`` at its initial state,
    computed once per model and cached: :func:`dynamics.stable_step_estimate`
    (``{"omega_max": rad/s, "lambda_max": 1/s, "semi_implicit_euler": s, "rk4": s}``), which
    accounts for string damping (it lowers the explicit limits, by 6x for 50 N s/m on the
    default prism)."""
    est = _LIMIT_CACHE.get(model)
    if est is None:
        try:
            est = dict(dyn.stable_step_estimate(model))
        except Exception:  # pragma: no cover - an estimate must never break a simulation
            est = {"omega_max": float("nan"), "lambda_max": float("nan"), "semi_implicit_euler": float("inf"),
                   "rk4": float("inf")}
        _LIMIT_CACHE[model] = est
    return est


def _check_stability(model: Model, info: IntegratorInfo, dt: float, stacklevel: int = 3) -> None:
    """Warn once per (model, integrator, dt) if an explicit method's dt is above its limit.
    The (integrator, dt) pairs already checked live in the model's own ``__dict__`` (the frozen
    dataclass allows it; nothing else reads it), so a repeated call costs one set lookup."""
    seen = model.__dict__.get("_stability_checked")
    if seen is None:
        seen = model.__dict__.setdefault("_stability_checked", set())
    key = (info.name, dt)
    if key in seen:
        return
    seen.add(key)
    if info.name not in _EXPLICIT:
        return
    limit = stability_limit(model)[info.name]
    if dt > limit:
        warnings.warn(StabilityWarning(
            f"{info.name}: dt = {dt:.4g} s is above the estimated stability limit {limit:.4g} s of this "
            f"structure (highest natural frequency {stability_limit(model)['omega_max']:.4g} rad/s); "
            f"use dt <= {limit:.3g} s or integrator='implicit_euler'"),
            stacklevel=stacklevel)


def _divergence_cause(model: Model, info: IntegratorInfo, dt: float, last: State, rest_length) -> str:
    """A short diagnosis of why a fixed-step run went non-finite, from the last finite state."""
    if info.name in _EXPLICIT:
        est = stability_limit(model)
        limit = est[info.name]
        if dt > limit:
            return (f"dt = {dt:g} s is above the estimated stability limit {limit:.3g} s of {info.name} "
                    f"(highest natural frequency {est['omega_max']:.4g} rad/s): reduce dt or use "
                    "integrator='implicit_euler'")
    parts = []
    try:
        l0 = model.rest_length if rest_length is None else rest_length
        _, L, _ = dyn.string_state(model, last.q)
        strain = np.where(l0 > 0, (L - l0) / np.where(l0 > 0, l0, 1.0), 0.0)
        i = np.unravel_index(int(np.nanargmax(strain)), strain.shape)[-1]
        parts.append(f"largest string strain {float(np.nanmax(strain)):.3g} (string {i}, "
                     f"stiffness {model.stiffness[i]:.3g} N/m)")
        parts.append(f"largest speed {float(np.nanmax(np.abs(last.qd[..., :3]))):.3g} m/s")
    except Exception:  # pragma: no cover
        pass
    what = ", ".join(parts)
    return ("a string far too stiff for this step, a huge external/control force or a rod rotating "
            f"more than about one radian per step (last finite state at t = {last.t:.6g} s: {what})")


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


def _finite_state(q, qd) -> bool:
    """True if the state arrays are finite, by the compiled pass (``_kernels.finite_pair``) when
    they are C-contiguous float64 (B, k, 6) ndarrays and numba runs, else False (the caller then
    runs :func:`~tensegrity_gym.checks.check_finite`, which also names the entry)."""
    return (type(q) is np.ndarray and type(qd) is np.ndarray and q.ndim == 3 and qd.ndim == 3
            and q.dtype == np.float64 and qd.dtype == np.float64 and q.flags.c_contiguous
            and qd.flags.c_contiguous and _KERNELS.finite_pair(q, qd))


#: | |b| - 1 | above which integrators.step refuses a rod axis b of the state it is given
AXIS_TOLERANCE = 0.5


def _check_inputs(state, n_steps, external) -> int:
    """``n_steps`` as an int (ValueError unless a positive integer) after checking that the state
    and an array ``external`` are finite (ValueError naming the field, the index and the value)."""
    if not is_integer(n_steps) or n_steps < 1:
        raise ValueError(f"n_steps: must be a positive integer (steps per call), got {n_steps!r}")
    if not _finite_state(state.q, state.qd):
        check_finite(np.asarray(state.q), "state.q")
        check_finite(np.asarray(state.qd), "state.qd")
    # a zero or badly scaled rod axis gives NaN / wrong rod lengths; small drift (a run without
    # projection) is the caller's choice and is let through
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
    backend : "auto", "numba" (the same) or "torch" (:mod:`tensegrity_gym.torch_backend`, fixed-step
        methods, array ``external`` only; ``device`` / ``dtype``: torch device and float32/float64).
    rtol, atol : tolerances of the adaptive methods.
    params : :class:`~tensegrity_gym.params.Params` with 1 row (shared) or B rows (copy b steps
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
    if backend == "torch":   # torch backend: NumPy State in and out, computed on `device` in `dtype`
        from . import torch_backend
        if info.name not in _EXPLICIT:
            raise ValueError(f"integrator: backend='torch' runs 'semi_implicit_euler' and 'rk4', not {info.name!r}")
        if params is None:
            _check_stability(model, info, dt)
        return torch_backend.step_state(model, state, dt, info.name, rest_length=rest_length,
                                        force_density=force_density, external=external, project=project,
                                        n_steps=n_steps, device=device, dtype=dtype, params=params)
    B, m = state.batch_size, model.n_strings
    rest_length = _as_batch(rest_length, B, m, "rest_length")
    force_density = _as_batch(force_density, B, m, "force_density")
    if params is not None:
        params = check_params(model, params, B)
    if info.adaptive:
        return _adaptive(model, state, dt * n_steps, info, rest_length, force_density, external, rtol, atol,
                         params=params, backend=backend)
    if params is None:
        _check_stability(model, info, dt)
    if info.name in _IMPLICIT:
        from . import implicit
        return implicit.step(model, state, dt, info.name, rest_length=rest_length,
                             force_density=force_density, external=external, project=project,
                             n_steps=n_steps, params=params, backend=backend)
    _numba_backend(backend)
    if callable(external):
        return _callable_step(model, state, dt, info.name, rest_length, force_density, external, project,
                              n_steps, params)
    return _KERNELS.step(model, state, dt, info.name, rest_length=rest_length,
                         force_density=force_density, external=external, project=project,
                         n_steps=n_steps, params=params)


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
            nxt = _KERNELS.step(model, State(q, qd, t), dt, name, rest_length=rest_length,
                                force_density=force_density, external=_ext(external, q, qd, t), project=project,
                                params=params)
            q, qd = nxt.q, nxt.qd
        else:   # rk4
            q, qd = rk4_update(lambda q, qd, t: _KERNELS.accelerations(
                model, q, qd, rest_length, force_density, _ext(external, q, qd, t), params), q, qd, t, dt)
            if project:
                q, qd = _KERNELS.project(model, q, qd)
        t = t + dt
    return State(q=q, qd=qd, t=t)


def rk4_update(acc, q, qd, t, dt):
    """One classic RK4 step of ``(q, qd)`` over ``dt`` s for accelerations ``acc(q, qd, t)``
    (returns the new ``(q, qd)``, unprojected). The operations and their order are those of the
    kernels' RK4 (``_kernels._advance_py`` with ``_stage_soa``), so the results agree bit for bit
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


@dataclass(frozen=True)
class _Solution:
    """The parts of a solve_ivp result that :func:`simulate` reads, for a batch run copy by copy."""
    t: np.ndarray
    y: np.ndarray


def _rhs(model, shape, rest_length, force_density, external, params=None, budget=None, backend="auto"):
    half = int(np.prod(shape))
    count = [0]

    def f(t, y):
        if budget is not None:
            count[0] += 1
            if count[0] > budget:
                raise EvaluationBudgetExceeded(
                    f"the adaptive solver needed more than {budget} evaluations of the accelerations before "
                    f"t = {t:.6g} s (tolerances too tight for this span, or a very stiff structure)")
        q = y[:half].reshape(shape)
        qd = y[half:].reshape(shape)
        a = accelerations(model, q, qd, rest_length, force_density, _ext(external, q, qd, t), params, backend)
        return np.concatenate([qd.reshape(-1), a.reshape(-1)])
    return f


def _copy_rows(x, b):
    """Row b (as a batch of one) of an (m,) or (B, m) input already checked by :func:`_as_batch`."""
    return x[b:b + 1] if x is not None and x.ndim == 2 else x


def _adaptive(model, state, T, info, rest_length, force_density, external, rtol, atol, t_eval=None, params=None,
              max_evaluations=None, backend="auto"):
    """solve_ivp over [t, t + T]. A batch is integrated copy by copy (each copy its own step-size
    control, so no copy's result depends on another's), unless ``external`` is a callable of
    the whole batch."""
    from scipy.integrate import solve_ivp
    B = state.batch_size
    if B > 1 and not callable(external):
        ext = None if external is None else np.asarray(external)
        runs = []
        for b in range(B):
            st_b = State(q=state.q[b:b + 1], qd=state.qd[b:b + 1], t=state.t)
            runs.append(_adaptive(model, st_b, T, info, _copy_rows(rest_length, b), _copy_rows(force_density, b),
                                  ext[b:b + 1] if ext is not None and ext.ndim == 3 else ext, rtol, atol, t_eval,
                                  params if params is None or params.batch_size == 1 else params.take([b]),
                                  max_evaluations, backend))
        if t_eval is None:
            return State(q=np.concatenate([r.q for r in runs]), qd=np.concatenate([r.qd for r in runs]),
                         t=state.t + T)
        sols = [r[1] for r in runs]
        half = sols[0].y.shape[0] // 2
        y = np.concatenate([s_.y[:half] for s_ in sols] + [s_.y[half:] for s_ in sols], axis=0)
        out = State(q=np.concatenate([r[0].q for r in runs]), qd=np.concatenate([r[0].qd for r in runs]),
                    t=state.t + T)
        return out, _Solution(t=sols[0].t, y=y)
    shape = state.q.shape
    y0 = np.concatenate([state.q.reshape(-1), state.qd.reshape(-1)])
    method = {"dop853": "DOP853", "radau": "Radau"}[info.name]
    try:
        sol = solve_ivp(_rhs(model, shape, rest_length, force_density, external, params, max_evaluations, backend),
                        (state.t, state.t + T), y0, method=method, rtol=rtol, atol=atol, t_eval=t_eval)
    except (ValueError, np.linalg.LinAlgError) as e:   # scipy's checks on a non-finite state / Jacobian
        if "inf" not in str(e).lower() and "nan" not in str(e).lower() and "singular" not in str(e).lower():
            raise
        raise SimulationDiverged(f"{info.name} failed: the state or its Jacobian became non-finite or singular "
                                 f"({e}); loosen rtol/atol or shorten the span") from None
    if sol.status < 0:
        at = f"after t = {sol.t[-1]:.6g} s" if len(sol.t) else f"in its first step from t = {state.t:.6g} s"
        raise SimulationDiverged(f"{info.name} failed {at}: {sol.message}")
    half = y0.size // 2
    y = sol.y[:, -1]
    out = State(q=y[:half].reshape(shape), qd=y[half:].reshape(shape), t=state.t + T)
    if t_eval is not None:
        return out, sol
    return out


def simulate(model: Model, state: State, dt: float, n_steps: int, integrator: str = "rk4", *,
             record_every: int = 1, rest_length=None, force_density=None, external=None,
             project: bool = True, backend: str = "auto", rtol: float = 1e-10, atol: float = 1e-12,
             progress: bool = False, params=None, max_evaluations: int | None = None):
    """Integrate ``n_steps`` steps of ``dt`` and record every ``record_every``-th state.

    Returns ``(t, q, qd)`` with ``t`` (S,) in s and ``q``, ``qd`` (S, B, k, 6); the first
    record is the initial state. Adaptive methods integrate the whole span in one
    ``solve_ivp`` call and report the solution at the record times.
    Raises :class:`SimulationDiverged` naming the time if the state stops being finite.
    ``params``: per-copy physical values, as in :func:`step`. ``max_evaluations``: adaptive methods
    raise :class:`EvaluationBudgetExceeded` after that many evaluations of the accelerations (per
    copy) instead of running on (default None: no limit).
    """
    info = resolve(integrator)
    if int(n_steps) != n_steps or n_steps < 0:
        raise ValueError(f"n_steps: must be a non-negative integer, got {n_steps}")
    if int(record_every) != record_every or record_every < 1:
        raise ValueError(f"record_every: must be a positive integer, got {record_every}")
    if isinstance(rest_length, Schedule) or isinstance(force_density, Schedule):
        kw = dict(external=external, project=project, backend=backend, rtol=rtol, atol=atol, params=params,
                  max_evaluations=max_evaluations)
        return _simulate_scheduled(model, state, dt, int(n_steps), integrator, int(record_every), rest_length,
                                   force_density, progress, kw)
    n_rec = n_steps // record_every
    ts = state.t + dt * record_every * np.arange(n_rec + 1)
    if info.adaptive:
        B, m = state.batch_size, model.n_strings
        _, sol = _adaptive(model, state, dt * n_steps, info, _as_batch(rest_length, B, m, "rest_length"),
                           _as_batch(force_density, B, m, "force_density"), external, rtol, atol,
                           t_eval=ts, params=None if params is None else check_params(model, params, B),
                           max_evaluations=max_evaluations, backend=backend)
        half = sol.y.shape[0] // 2
        S = sol.y.shape[1]
        q = sol.y[:half].T.reshape((S,) + state.q.shape)
        qd = sol.y[half:].T.reshape((S,) + state.q.shape)
        return sol.t, q, qd
    qs, qds, bar = _records(state, n_rec, n_steps, info.name, progress)
    st = state
    if params is None:
        _check_stability(model, info, dt)
    for i in range(1, n_rec + 1):
        last = st
        try:
            st = step(model, st, dt, info.name, rest_length=rest_length, force_density=force_density,
                      external=external, project=project, n_steps=record_every, backend=backend,
                      params=params)
            finite = bool(np.all(np.isfinite(st.q)) and np.all(np.isfinite(st.qd)))
            what = "state became non-finite"
        except (ZeroDivisionError, OverflowError, FloatingPointError) as exc:  # compiled kernels
            finite, what = False, f"{type(exc).__name__} ({exc})"
            st = State(q=last.q, qd=last.qd, t=last.t + dt * record_every)
        if not finite:
            raise SimulationDiverged(
                f"{info.name}: {what} between t = {last.t:.6g} s and t = {st.t:.6g} s "
                f"(dt = {dt:g} s); likely cause: "
                + _divergence_cause(model, info, dt, last, _as_batch(rest_length, state.batch_size,
                                                                       model.n_strings, "rest_length")))
        qs[i], qds[i] = st.q, st.qd
        if bar is not None:
            bar.update(record_every)
    if bar is not None:
        bar.close()
    return ts, qs, qds
