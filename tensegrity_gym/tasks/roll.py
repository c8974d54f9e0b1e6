"""The rolling task (``TensegrityRoll-v0``): reward terms, step infos, state observation, centre of
mass and the reset's initial-state noise, written once for NumPy arrays and torch tensors
(:mod:`tensegrity_gym.tasks.xp`). The NumPy envs (:class:`~tensegrity_gym.envs.roll.RollTask`),
the device vector env (:class:`~tensegrity_gym.envs.torch_tasks.TorchRollVectorEnv`) and the
MuJoCo twin call these functions; the NumPy envs build their state observation with a compiled
single pass (:func:`tensegrity_gym.envs.compiled.roll_observe`) tested equal to
:func:`roll_state_observation`. SI units."""
from __future__ import annotations

from .xp import namespace

__all__ = ["sum_squares", "roll_step_terms", "roll_state_observation", "center_of_mass", "perturbed_start"]


def sum_squares(x):
    """``sum(x**2)`` over the last axis, (..., a) -> (...)."""
    return namespace(x).sum_squares(x)


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
    xp = namespace(nodes)
    B = nodes.shape[0]
    return xp.concat([(nodes - com[:, None, :]).reshape(B, -1), node_vel.reshape(B, -1), ctrl,
                      xp.to_float(active, nodes), goal, com[:, 2:3], speed], axis=1)


def center_of_mass(q, mass_frac, com_eta=None):
    """(B, 3) centre of mass of the robots ``q`` (B, k, 6), m: the rods' centres of mass
    ``r + com_eta b`` (``com_eta`` (1, k, 1), None where every rod's is at ``r``) weighted by the
    rods' mass fractions ``mass_frac`` (k,) or (B, k) (each row sums to 1)."""
    xp = namespace(q)
    r = q[..., :3] if com_eta is None else q[..., :3] + com_eta * q[..., 3:]
    return xp.einsum("bk,bki->bi" if mass_frac.ndim == 2 else "k,bki->bi", mass_frac, r)


def perturbed_start(q_nominal, length, x):
    """(q, qd) (r, k, 6) of the reset: the resting robot ``q_nominal`` (1, k, 6) plus the noise
    ``x`` (r, 4, k, 3), drawn U(-s, s): ``x[:, 0]`` on the rod centres (m), ``x[:, 1]`` divided by
    the rod lengths ``length`` (k, 1) or (1, k, 1) m on the axes, ``x[:, 2]`` the centres'
    velocities (m/s), ``x[:, 3] / length`` the axes' rates (1/s). Not yet projected onto the
    constraints (unit axes)."""
    xp = namespace(x)
    q = xp.concat([q_nominal[..., :3] + x[:, 0], q_nominal[..., 3:] + x[:, 1] / length], axis=-1)
    qd = xp.concat([x[:, 2], x[:, 3] / length], axis=-1)
    return q, qd
