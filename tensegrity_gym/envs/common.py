"""Machinery shared by the tensegrity environments (structure-agnostic). SI units throughout.

Design (brax / dm_control style): every environment is a **batched task** -- one object that
holds the physics state of B copies of a scene (arrays with a leading batch axis) and
implements reset of selected copies, actions, one batched physics call per control step,
observations, reward terms and success. Two thin shells wrap the same task:

* :class:`TaskEnv` (``gymnasium.Env``) -- the task with B = 1;
* :class:`TaskVectorEnv` (``gymnasium.vector.VectorEnv``) -- the task with B = ``num_envs``,
  Gymnasium 1.x next-step autoreset, per-env seeding, time limit from the registration;
* :func:`make_sb3_vec_env` -- an adapter that lets Stable-Baselines3 train on a
  ``gymnasium.vector.VectorEnv`` directly (SB3 imported lazily).

So the single env and the vector env run one implementation, and a vector env seeded with
``seed`` reproduces N single envs seeded with ``seed + i``.

Modules (this one re-exports their public names, so ``from tensegrity_gym.envs.common import ...``
keeps working)
--------------------------------------------------------------------------------------------
:mod:`~tensegrity_gym.envs.validate`
    ``check_action`` (shape, NaN/inf naming the index, clip to [-1, 1] or raise with
    ``clip=False``), ``check_positive``, ``check_stable_dt``, ``resolve_actuated``.
:mod:`~tensegrity_gym.physics.actuation` (a physics-layer module, re-exported here)
    ``Actuation``: rest-length or force-density controls of a set of strings, batched, with
    rate limits and the cable motor; ``update`` gives the new controls, the motor's speeds and
    the ``rest_length=`` / ``force_density=`` inputs (B, m) of :func:`tensegrity_gym.physics.pipeline.step`.
:mod:`~tensegrity_gym.envs.base`
    ``BatchedTask``: owns ``model``, ``integrator``, ``dt``, ``frame_skip``, ``backend``, the
    batched ``q``, ``qd`` (B, k, 6), ``elapsed`` (B,) and the robot parameters. Subclasses
    implement ``reset_idx``, ``step``, ``observe``, ``render_data``; :meth:`BatchedTask.simulate`
    runs one control step of physics for the whole batch through :mod:`tensegrity_gym.physics.pipeline`
    (contact inside it when the task has ``contact``) and handles divergence.
:mod:`~tensegrity_gym.envs.shells`
    ``TaskEnv``, ``TaskVectorEnv``: the shells described above; ``make_sb3_vec_env`` lives in
    :mod:`tensegrity_gym.integrations.sb3`.

Divergence
----------
After each control step (:func:`tensegrity_gym.physics.pipeline.diverged`, the one check), a copy whose
state is non-finite or has a rod farther than ``divergence_limit`` m from the structure's
initial centre (a task that ``travels``: from its own centre) is *diverged*: its state is put
back to the last finite one (so observations stay finite; a NaN is never passed on), the env
reports ``info["diverged"] = True`` and truncates the episode. The vector env autoresets it.

Info conventions
----------------
A task's ``step`` returns ``(reward_terms, terminated, infos)`` with ``reward_terms`` a dict of
(B,) arrays (the reward is their sum, each also reported as ``info["reward_<name>"]``) and
``infos`` a dict of (B,) arrays. The single env turns them into Python scalars; the vector
env returns Gymnasium's vector info dict (arrays plus ``"_<key>"`` masks).
"""
from __future__ import annotations

from .validate import ACTION_MODES, ACTION_TOL, check_action, check_positive, check_stable_dt, resolve_actuated
from ..physics.actuation import Actuation
from .base import BatchedTask
from .shells import TaskEnv, TaskVectorEnv, registered_max_episode_steps
from ..integrations.sb3 import make_sb3_vec_env

__all__ = ["ACTION_MODES", "check_action", "check_positive", "Actuation", "BatchedTask", "TaskEnv",
           "TaskVectorEnv", "make_sb3_vec_env", "resolve_actuated", "registered_max_episode_steps",
           "check_stable_dt", "ACTION_TOL"]
