"""The roll task's reward terms and step infos, written once for NumPy arrays (the NumPy envs)
and torch tensors (the device vector env). SI units."""
from __future__ import annotations

import numpy as np

from ..rewards import quadratic_cost

__all__ = ["sum_squares", "roll_step_terms"]


def sum_squares(x):
    """``sum(x**2)`` over the last axis, (..., a) -> (...): :func:`tensegrity_gym.rewards.quadratic_cost`
    for a NumPy array, the same sum on a torch tensor's own device."""
    if isinstance(x, np.ndarray):
        return quadratic_cost(x)
    return (x * x).sum(dim=-1)


def roll_step_terms(com0, com, start, goal, action, control_dt: float, forward_weight: float,
                    ctrl_weight: float) -> tuple[dict, dict]:
    """The roll task's reward terms and infos of one control step, for B copies.

    ``com0`` / ``com`` (B, 3): centre of mass before / after the step, m; ``start`` (B, 3): at
    reset, m; ``goal`` (B, 2) unit goal direction; ``action`` (B, na); ``control_dt`` s.
    Terms: ``forward`` = ``forward_weight`` x the centre of mass velocity along the goal (m/s),
    ``ctrl`` = -``ctrl_weight`` x sum(action^2). Infos: ``com_position`` (m), ``com_velocity``
    (m/s), ``distance_rolled`` (displacement from ``start`` along the goal, m),
    ``forward_velocity`` (m/s)."""
    vel = (com - com0) / control_dt
    forward = vel[:, 0] * goal[:, 0] + vel[:, 1] * goal[:, 1]
    terms = {"forward": forward_weight * forward, "ctrl": -ctrl_weight * sum_squares(action)}
    disp = com - start
    dist = disp[:, 0] * goal[:, 0] + disp[:, 1] * goal[:, 1]
    infos = {"com_position": com, "com_velocity": vel, "distance_rolled": dist, "forward_velocity": forward}
    return terms, infos
