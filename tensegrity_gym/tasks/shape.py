"""The shape-tracking task (``TensegrityShape-v0``): tracking errors, reward terms, infos and state
observation, written once for NumPy arrays and torch tensors (:mod:`tensegrity_gym.tasks.xp`).
The NumPy envs (:class:`~tensegrity_gym.envs.shape.ShapeTask`) and the device vector env
(:class:`~tensegrity_gym.envs.torch_tasks.TorchShapeVectorEnv`) call these functions; the NumPy
single env's fused compiled step (:mod:`tensegrity_gym.envs.shape_fused`) is tested equal to
them. SI units."""
from __future__ import annotations

import numpy as np

from .xp import namespace

__all__ = ["GAUSS_SCALE", "node_errors", "proximity", "shape_step_terms", "shape_state_observation"]

#: the gaussian sigmoid of :func:`tensegrity_gym.rewards.tolerance` with value 0.1 at the margin
GAUSS_SCALE = float(np.sqrt(-2 * np.log(0.1)))


def node_errors(nodes, target):
    """(B, nt) distance of each tracked node ``nodes`` (B, nt, 3) from its target (B, nt, 3), m."""
    return namespace(nodes).norm(nodes - target)


def proximity(emax, tol: float):
    """1 where the largest node error ``emax`` (B,) m is within ``tol`` m, else the gaussian
    ``exp(-t^2 / 2)`` of ``t = (emax - tol) / (10 tol) x GAUSS_SCALE`` (0.1 at 10 ``tol`` beyond):
    :func:`tensegrity_gym.rewards.tolerance` ``(emax, (0, tol), margin=10 tol)`` for errors >= 0."""
    xp = namespace(emax)
    t = (emax - tol) / (10.0 * tol) * GAUSS_SCALE
    return xp.where(emax <= tol, 1.0, xp.exp(-0.5 * t * t))


def shape_step_terms(err, emax, action, tol: float, tracking_weight: float, proximity_weight: float,
                     ctrl_weight: float) -> tuple[dict, dict]:
    """The shape task's reward terms and infos of one control step, for B copies: mean and largest
    node errors ``err`` / ``emax`` (B,) m, ``action`` (B, na), success tolerance ``tol`` m.
    Terms: ``tracking`` = -``tracking_weight`` x err, ``proximity`` = ``proximity_weight`` x
    :func:`proximity`, ``ctrl`` = -``ctrl_weight`` x sum(action^2). Infos: ``tracking_error``,
    ``max_node_error`` (m), ``is_success`` (emax <= tol)."""
    xp = namespace(err)
    terms = {"tracking": -tracking_weight * err, "proximity": proximity_weight * proximity(emax, tol),
             "ctrl": -ctrl_weight * xp.sum_squares(action)}
    return terms, {"tracking_error": err, "max_node_error": emax, "is_success": emax <= tol}


def shape_state_observation(nodes, node_vel, ctrl, target):
    """The shape task's state observation (B, 12 nt + na) in the dtype of ``nodes``: tracked node
    positions (m), their velocities (m/s), controls (m or N/m), targets (m), target - node (m).
    ``nodes`` / ``node_vel`` / ``target`` (B, nt, 3), ``ctrl`` (B, na)."""
    xp = namespace(nodes)
    B = nodes.shape[0]
    return xp.concat([nodes.reshape(B, -1), node_vel.reshape(B, -1), ctrl, target.reshape(B, -1),
                      (target - nodes).reshape(B, -1)], axis=1)
