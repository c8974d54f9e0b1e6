"""Recorded runs: :func:`simulate` (fixed-step methods step by step, adaptive methods in one
``scipy.integrate.solve_ivp`` call copy by copy) and :class:`Schedule` (inputs held piecewise
constant over time). SI units.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import SimulationDiverged
from ..core.integrators import resolve
from ..core.model import Model, State
from ..core.params import check_params
from .adaptive import adaptive
from .stability import check_stability, divergence_cause
from .integrate import _as_batch, step

__all__ = ["simulate", "Schedule"]


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
        _, sol = adaptive(model, state, dt * n_steps, info, _as_batch(rest_length, B, m, "rest_length"),
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
        check_stability(model, info, dt)
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
                + divergence_cause(model, info, dt, last, _as_batch(rest_length, state.batch_size,
                                                                       model.n_strings, "rest_length")))
        qs[i], qds[i] = st.q, st.qd
        if bar is not None:
            bar.update(record_every)
    if bar is not None:
        bar.close()
    return ts, qs, qds
