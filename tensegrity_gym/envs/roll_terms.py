"""The roll task's reward terms, step infos and state observation, written once for NumPy arrays
and torch tensors. The NumPy envs and the device vector env both compute the reward terms and
infos with :func:`roll_step_terms`; the device vector env builds its observation with
:func:`roll_state_observation`, and the NumPy envs with its compiled single pass
(:func:`tensegrity_gym.envs.compiled.roll_observe`, tested equal to it). SI units."""
from __future__ import annotations

import numpy as np

from ..rewards import quadratic_cost

__all__ = ["sum_squares", "roll_step_terms", "roll_state_observation"]


def sum_squares(x):
    """``sum(x**2)`` over the last axis, (..., a) -> (...): :func:`tensegrity_gym.rewards.quadratic_cost`
    for a NumPy array, the same sum on a torch tensor's own device."""
    if isinstance(x, np.ndarray):
        return quadratic_cost(x)
    return (x * x).sum(dim=-1)


def _concat(parts):
    """``parts`` (each (B, ...)) joined along axis 1, NumPy or torch."""
    if isinstance(parts[0], np.ndarray):
        return np.concatenate(parts, axis=1)
    import torch   # an optional dependency, reached only with torch tensors
    return torch.cat(parts, dim=1)


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


def roll_state_observation(nodes, node_vel, com, ctrl, active, goal, speed):
    """The roll task's state observation (B, 6n + na + nc + 3 + ns), in the dtype of ``nodes``:
    node positions relative to the centre of mass (m), node velocities (m/s), controls (m or
    N/m), contact flags (1 touching, 0 not), goal direction, centre-of-mass height (m), cable
    speeds (m/s; ns = 0 without the motor model).

    ``nodes`` / ``node_vel`` (B, n, 3); ``com`` (B, 3); ``ctrl`` (B, na); ``active`` (B, nc) bool;
    ``goal`` (B, 2); ``speed`` (B, ns)."""
    B = nodes.shape[0]
    flags = active.astype(nodes.dtype) if isinstance(active, np.ndarray) else active.to(nodes.dtype)
    return _concat([(nodes - com[:, None, :]).reshape(B, -1), node_vel.reshape(B, -1), ctrl, flags, goal,
                    com[:, 2:3], speed])
