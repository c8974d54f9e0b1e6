"""TensegrityNavigateMuJoCo-v0: TensegrityNavigate-v0 simulated by MuJoCo (a sim-to-sim twin).

:class:`TensegrityNavigateMuJoCoEnv` holds a one-copy :class:`~tensegrity_gym.envs.navigate.NavigateTask`
(the arguments of ``TensegrityNavigate-v0``): the course (walls, rough patches, goals) is drawn at
reset as ``TensegrityNavigate-v0`` draws it and becomes the scene's terrain; the planner's guidance,
goals reached, goal bonus (``reward_goal``), success (terminates), observation and info keys are
the task's own, computed from MuJoCo's state. Registered with ``max_episode_steps`` = 3000 (60 s).

The rolling twin's module doc (:mod:`tensegrity_gym.envs.roll_mujoco`) says what the twins share
with the project's envs and where they differ. SI units.
"""
from __future__ import annotations

from .config import NavigateConfig
from .navigate import NavigateTask
from .roll_mujoco import TensegrityRollMuJoCoEnv

__all__ = ["TensegrityNavigateMuJoCoEnv", "ENV_ID"]

ENV_ID = "TensegrityNavigateMuJoCo-v0"


class TensegrityNavigateMuJoCoEnv(TensegrityRollMuJoCoEnv):
    """MuJoCo twin of ``TensegrityNavigate-v0``: the rolling twin (:mod:`tensegrity_gym.envs.roll_mujoco`) on the
    navigation task's courses.

    The env holds a one-copy :class:`~tensegrity_gym.envs.navigate.NavigateTask` (arguments: those
    of ``TensegrityNavigate-v0``, plus the twin's own, as :class:`TensegrityRollMuJoCoEnv`), whose
    reset draws the course from the env's ``np_random`` as ``TensegrityNavigate-v0`` does (the same
    reset seed gives the same course, goals and start on both); the course's walls and rough patches
    become the MuJoCo scene's terrain (changed in place per episode, :mod:`~tensegrity_gym.envs.twin_terrain`).
    The planner's guidance, the goals reached, the goal bonus, success (it terminates the
    episode), the observation (guidance, ``path_distance``, ``goals_left``, ``height_scan``) and
    the info keys are the task's own (:meth:`NavigateTask.track_goals`, :meth:`NavigateTask.guide`),
    computed from MuJoCo's state synced into the task. Registered as ``TensegrityNavigateMuJoCo-v0``
    with ``max_episode_steps`` = 3000 (60 s), as ``TensegrityNavigate-v0``.
    """

    env_id = ENV_ID
    task_class = NavigateTask
    config_class = NavigateConfig

    def _reset_task_state(self, info: dict) -> dict:
        t = self.task
        t.guide([0])     # the guidance from MuJoCo's start state
        return {"goal_position": t.courses[0].goals[0].copy(), "path_distance": float(t.path[0])}

    def _step_task_terms(self, info: dict) -> tuple[dict, bool, dict]:
        terms, success, infos = self.task.track_goals()
        return ({name: float(v[0]) for name, v in terms.items()}, bool(success[0]),
                {k: v.item(0) for k, v in infos.items()})
