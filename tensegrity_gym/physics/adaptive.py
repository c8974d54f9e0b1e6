"""The adaptive methods (``dop853``, ``radau``): ``scipy.integrate.solve_ivp`` copy by copy on
the backend's accelerations, with an optional budget of right-hand-side evaluations. SI units.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import EvaluationBudgetExceeded, SimulationDiverged
from ..core.model import State
from .evaluate import accelerations, external_forces

__all__ = ["adaptive"]


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
        a = accelerations(model, q, qd, rest_length, force_density, external_forces(external, q, qd, t), params, backend)
        return np.concatenate([qd.reshape(-1), a.reshape(-1)])
    return f


def _copy_rows(x, b):
    """Row b (as a batch of one) of an (m,) or (B, m) input already checked by :func:`_as_batch`."""
    return x[b:b + 1] if x is not None and x.ndim == 2 else x


def adaptive(model, state, T, info, rest_length, force_density, external, rtol, atol, t_eval=None, params=None,
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
            runs.append(adaptive(model, st_b, T, info, _copy_rows(rest_length, b), _copy_rows(force_density, b),
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


