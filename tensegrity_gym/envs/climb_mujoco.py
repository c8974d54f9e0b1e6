"""TensegrityClimbMuJoCo-v0: TensegrityClimb-v0 simulated by MuJoCo (a sim-to-sim twin).

The rolling twin (:mod:`tensegrity_gym.envs.roll_mujoco`: the same robot, actions, observation,
rewards and control step as the project's env, the motion from MuJoCo's own contact, friction and
integrator) on the climbing task's slope. SI units, angles in degrees.

What is shared (not copied): the env holds a one-copy :class:`~tensegrity_gym.envs.climb.ClimbTask`
built from the arguments of ``TensegrityClimb-v0`` (``slope_deg``, ``slope_range``, the robot,
observation and actuation arguments of ``TensegrityRoll-v0``), and takes from it

* the slope: the task's reset draws it from the env's ``np_random`` as ``TensegrityClimb-v0`` does
  (with ``slope_range``: the first draw of the reset), so the same reset seed gives the same slope
  on both simulators;
* the slope's physics: as the project simulates a plane in its own frame (:mod:`tensegrity_gym.tasks.climb`:
  x uphill, z along the plane's normal, the level ground z = 0, gravity tilted), the twin's MuJoCo
  scene keeps its level floor and sets ``opt.gravity`` to the task's gravity of the episode
  (:meth:`ClimbTask.slope_gravity`) at every reset: MuJoCo's own contact on a tilted plane, rotated;
* the observation (:meth:`ClimbTask.observe`: the rolling task's plus ``gravity_direction``; in
  robot mode the accelerometers read the tilted gravity from the task), the reward (the velocity
  along the goal, uphill +x) and the info keys ``slope_deg`` and ``uphill_velocity``
  (:meth:`ClimbTask.climb_info`), computed from MuJoCo's state synced into the task.

The robot settles on level ground (as ``TensegrityClimb-v0``'s robot does) and the episode starts
from that pose, plus the reset noise, on the slope.

Modelling differences on a slope (besides those of the rolling twin's module doc): MuJoCo's
static friction is soft (its friction constraint is solved with the contact's ``solref`` softness,
so a resting contact creeps slowly in the direction of the force it holds), where the project's is
a stick spring that holds the contact still below the friction limit. On a slope a resting robot
therefore creeps downhill on the twin, slowly, well below the friction angle; above it, both slide
at about ``g (sin a - mu cos a)``.

Not supported (ValueError): as the rolling twin, and as ``TensegrityClimb-v0`` (``terrain``,
``randomize_goal``, a goal other than uphill, ``gravity`` in ``params`` / ``randomize``).
Registered as ``TensegrityClimbMuJoCo-v0`` with ``max_episode_steps`` = 1000 (20 s), as
``TensegrityClimb-v0``.
"""
from __future__ import annotations

import numpy as np

from .climb import ClimbTask
from .config import ClimbConfig
from .roll_mujoco import TensegrityRollMuJoCoEnv

__all__ = ["TensegrityClimbMuJoCoEnv", "ENV_ID"]

ENV_ID = "TensegrityClimbMuJoCo-v0"


class TensegrityClimbMuJoCoEnv(TensegrityRollMuJoCoEnv):
    """MuJoCo twin of ``TensegrityClimb-v0`` (see the module doc).

    Arguments: those of ``TensegrityClimb-v0`` (passed to its :class:`ClimbTask`: ``slope_deg``
    (degrees, default 20), ``slope_range`` ((low, high) degrees, drawn per reset), the robot,
    observation and actuation arguments), plus the rolling twin's own (``mj_integrator``,
    ``contact_dampratio``, ``spin_damping``, ``render_mode``, ``width``, ``height``: see
    :class:`~tensegrity_gym.envs.roll_mujoco.TensegrityRollMuJoCoEnv`). ``env.unwrapped.task`` is the
    :class:`ClimbTask`; ``env.unwrapped.model`` / ``data`` are MuJoCo's ``MjModel`` / ``MjData``.
    """

    env_id = ENV_ID
    task_class = ClimbTask
    config_class = ClimbConfig

    def _reset_task_state(self, info: dict) -> dict:
        # this episode's slope as MuJoCo's gravity in the plane frame, before the first step
        self.model.opt.gravity[:] = self.task.slope_gravity()[0]
        return {"slope_deg": float(info["slope_deg"][0])}

    def _step_task_terms(self, info: dict) -> tuple[dict, bool, dict]:
        extra = self.task.climb_info(self.task, np.array([info["forward_velocity"]]))
        return {}, False, {name: np.asarray(v).item(0) for name, v in extra.items()}
