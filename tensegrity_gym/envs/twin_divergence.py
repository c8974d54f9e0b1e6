"""Divergence of the MuJoCo twin, reported as the native env reports its own: MuJoCo's warnings, a
non-finite state, or the robot beyond the task's ``divergence_limit`` (m)."""
from __future__ import annotations

import numpy as np

from ..physics import pipeline

__all__ = ["MUJOCO_DIVERGENCE_WARNINGS", "clear_mujoco_warnings", "twin_diverged"]


#: MuJoCo warnings that mean the simulation blew up (MuJoCo resets the data on a bad acceleration, so
#: the state alone can look fine afterwards)
MUJOCO_DIVERGENCE_WARNINGS = ("mjWARN_BADQACC", "mjWARN_BADQPOS", "mjWARN_BADQVEL")


def clear_mujoco_warnings(mujoco, data) -> None:
    """Zero the counters of :data:`MUJOCO_DIVERGENCE_WARNINGS` in ``data`` (an ``MjData``), so that
    the next step's warnings are seen even where MuJoCo's own reset re-counts them from zero."""
    for name in MUJOCO_DIVERGENCE_WARNINGS:
        data.warning[getattr(mujoco.mjtWarning, name)].number = 0


def twin_diverged(mujoco, data, task) -> bool:
    """True if the MuJoCo twin's last control step diverged, by the native env's rule and more:
    a MuJoCo divergence warning since :func:`clear_mujoco_warnings`, a non-finite ``qpos`` /
    ``qvel``, or the task's state (``task.q``, ``task.qd``, synced from MuJoCo) out of the task's
    ``divergence_limit`` (m) as :func:`tensegrity_gym.physics.pipeline.diverged` measures it for the native env."""
    if any(data.warning[getattr(mujoco.mjtWarning, n)].number > 0 for n in MUJOCO_DIVERGENCE_WARNINGS):
        return True
    if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
        return True
    return bool(pipeline.diverged(task.q, task.qd, task.center0, task.divergence_limit, task.travels)[0])
