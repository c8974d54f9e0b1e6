"""The device-resident task envs on :class:`~tensegrity_gym.envs.torch_shell.TorchTaskVectorEnv`:
the rolling robot's physics (ground or terrain contact) for ``TensegrityRoll-v0`` and every task
built on :class:`~tensegrity_gym.envs.roll.RollTask` (``TensegrityClimb-v0``,
``TensegrityNavigate-v0``), and the shape task's (``TensegrityShape-v0``), with
``backend="torch"`` (see :mod:`tensegrity_gym.envs.torch_vec` for what runs where). The task's
own step, observation and reset rows are its record functions (:mod:`tensegrity_gym.tasks.state`),
the ones the NumPy task runs; :func:`torch_env_class` gives a task class its device env."""
from __future__ import annotations

import gymnasium as gym
import numpy as np

from ..backends.torch.model import torch_module
from ..backends.torch.equations import node_positions, node_velocities, project
from ..backends.torch.actuation import update_motor, update_rate
from ..backends.torch.driver import step
from ..backends.torch import divergence
from ..backends.torch.contact import contact_step
from ..backends.torch.rod_contact import rod_terrain_substep
from ..backends.torch.terrain import compile_options, terrain_substep, top_height
from .base import BatchedTask
from .climb import ClimbTask
from .navigate import NavigateTask
from .roll import RollTask
from ..tasks.roll import center_of_mass, roll_state_observation
from ..tasks.shape import node_errors, shape_state_observation, shape_step_terms
from ..tasks.terrain import terrain_draws
from ..tasks.xp import namespace
from .shape import ShapeTask
from .torch_shell import TorchTaskVectorEnv
from .torch_terrain import TorchTerrain

__all__ = ["TorchRollVectorEnv", "TorchShapeVectorEnv", "TorchClimbVectorEnv", "TorchNavigateVectorEnv",
           "torch_env_class"]

# gymnasium.vector.VectorEnv is listed as a direct base of each env class: libraries that pick their
# wrapper from the class's __bases__ (skrl's wrap_env) then recognise a Gymnasium vector env


class TorchRollVectorEnv(TorchTaskVectorEnv, gym.vector.VectorEnv):
    """A :class:`~tensegrity_gym.envs.roll.RollTask` (``TensegrityRoll-v0``, or a task built on
    it: ``TASK``) on N copies stepped on a torch device (see the module doc)."""

    ENV_ID = "TensegrityRoll-v0"
    TASK = RollTask
    DEVICE_RESET = RollTask.DEVICE_RESET

    def _physics_substep(self):
        """With a terrain, :func:`~tensegrity_gym.backends.torch.terrain.terrain_substep` (with
        ``rod_contact``: :func:`~tensegrity_gym.backends.torch.rod_contact.rod_terrain_substep`)
        and its :func:`~tensegrity_gym.backends.torch.terrain.compile_options`."""
        if self._terrain is None:
            return super()._physics_substep()
        rc = self.task.rod_contact
        return (terrain_substep if rc is None else rod_terrain_substep(rc)), compile_options(self._terrain.layout)

    def _init_device(self):
        task = self.task
        self._com_eta = self._T(task.model.com_eta)[None, :, None]
        # terrain=: its rows and contact state on the device (None: the level ground's contact)
        self._terrain = None if task.terrain_contact is None else TorchTerrain(self)

    def _upload_rows(self, it, idx):
        super()._upload_rows(it, idx)
        if self._terrain is not None:
            self._terrain.upload_rows(self, it, idx)

    # the record's functions (tasks/state.py)
    def com(self, q, it=None):
        """(N, 3) centre of mass, m (as ``RollTask.com``); of envs ``it`` when ``q`` holds only them."""
        mf = self._mass_frac
        if it is not None and mf.shape[0] > 1:
            mf = mf[it]
        return center_of_mass(q, mf.expand(q.shape[0], -1), None if self.task._com_at_r else self._com_eta)

    def project_state(self, q, qd):
        """``(q, qd)`` projected onto the rod constraints (unit axes)."""
        return project(self.tm, q, qd)

    def node_positions(self, q):
        """(r, n, 3) node positions of the robots ``q`` (r, k, 6), m."""
        return node_positions(self.tm, q, self._node_prm)

    def terrain_height(self, x, y):
        """(N, m) each env's ground height under ``x``, ``y`` (N, m) m (the record's)."""
        torch = torch_module()
        tt = self._terrain
        if tt is None:
            return torch.full_like(x, self.task.contact.height)
        return top_height(tt.geom, tt.hf, x, y, tt.layout.kinds)

    def _reset_draws(self) -> int:
        """Uniforms a device reset of one env reads for the task: ``RollTask.reset_draws`` (its
        first draws, the initial-state noise, the goal angle), then a terrain generator's draws."""
        task = self.task
        gen = task.terrain_generator
        return task.reset_draws + (0 if gen is None else terrain_draws(gen))

    def _device_reset_rows(self, it, u) -> dict:
        """``RollTask.reset_idx`` on the device for envs ``it`` from their uniforms ``u`` (r, n)
        float64: the task's start (``RollTask.reset_start``: the same function the host reset
        runs); on a terrain, a generator's new terrain (:meth:`TorchTerrain.draw`), the start
        lifted clear of it and its contact state released; the start written
        (``RollTask.reset_write``); the task's reset infos (``RollTask.reset_info``)."""
        torch = torch_module()
        task = self.task
        n = task.reset_draws
        q, qd, goal = task.reset_start(self, it, u[:, :n])
        if self._terrain is not None:       # a generator's new terrain; clear of it, its contact let go
            if task.terrain_generator is not None:
                self._terrain.draw(self, it, u[:, n:], goal)
            q[..., 2] += self._terrain.start_lift(self.node_positions(q), task.contact.radius, it)[:, None]
            self._terrain.release(it)
        task.reset_write(self, it, q, qd, goal)
        com = self.com(q, it)
        self.start[it] = com
        if self._sens is not None:
            self._sens.reset_rows(it, q, qd, self.ctrl[it], self.speed[it], self.active[it], goal)
        info = {"com_position": com, "com_velocity": torch.zeros_like(com),
                "distance_rolled": com.new_zeros(com.shape[0]), "goal_direction": goal.clone()}
        info.update(task.reset_info(self, it))
        return info

    def _observe(self):
        if self._sens is not None:
            return self._sens.observation()
        q, qd = self.q, self.qd
        obs = roll_state_observation(node_positions(self.tm, q, self._node_prm), node_velocities(self.tm, qd),
                                     self.com(q), self.ctrl, self.active, self.goal, self.speed)
        return self.task.observe_task(self, obs)

    def _act(self, action):
        """One control step for the whole batch: the control update, the physics with contact, the
        divergence restore, then the task's step on this record (``RollTask.task_step``):
        ``(terms, terminated or None, infos)`` as (N,) tensors."""
        torch = torch_module()
        task = self.task
        action = self._delayed(action)
        act = task.actuation
        if task.motor:
            self.ctrl, self.speed = update_motor(act, self.ctrl, self.speed, action, self._max_rate, self._max_accel)
        else:
            self.ctrl = update_rate(act, self.ctrl, action, self._max_rate)
        inputs = self._physics_inputs()
        q0, qd0, anchor0, active0 = self.q, self.qd, self.anchor, self.active
        com0 = self.com(q0)
        if self._terrain is not None:       # terrain contact; diverged copies restored there
            self.q, self.qd, qd_prev, diverged = self._terrain.advance(self, q0, qd0, inputs)
            d3 = diverged[:, None, None]
        else:
            kw = dict(rest_length=inputs.get("rest_length"), force_density=inputs.get("force_density"),
                      params=self._params, contact_prm=self._contact_prm, substep=self._substep)
            run = self._physics_call(contact_step)
            (q, qd, anchor, active), qd_prev = self._advance(
                lambda n, *s: run(self.tm, task.contact, *s, task.dt, task.integrator, n, **kw),
                (q0, qd0, anchor0, active0))
            diverged = divergence.diverged(q, qd, task.center0, task.divergence_limit, local=True)   # pipeline.diverged
            d3 = diverged[:, None, None]
            self.q = torch.where(d3, q0, q)
            self.qd = torch.where(d3, qd0, qd)
            self.anchor = torch.where(d3, anchor0, anchor)
            self.active = torch.where(diverged[:, None], active0, active)
        self.elapsed = self.elapsed + 1
        if qd_prev is not None:
            self._sens.record(self.q, self.qd, torch.where(d3, qd0, qd_prev), self.ctrl, self.speed, self.active,
                              self.goal)
        terms, terminated, infos = task.task_step(self, com0, self.com(self.q), action)
        infos["diverged"] = diverged
        return terms, terminated, infos


class TorchShapeVectorEnv(TorchTaskVectorEnv, gym.vector.VectorEnv):
    """``TensegrityShape-v0`` on N copies stepped on a torch device: the task of
    :class:`~tensegrity_gym.envs.shape.ShapeTask` (targets and initial states drawn on the host
    at reset from each env's generator; control update, physics with the model's node drag,
    divergence check, tracking errors, the ``tracking`` / ``proximity`` / ``ctrl`` reward terms
    and the observation on the device). Arguments: those of ``TensegrityShape-v0`` plus
    ``device``, ``dtype``, ``max_episode_steps``, ``compile`` (``torch.compile`` of
    :func:`tensegrity_gym.backends.torch.driver.step_once`)."""

    ENV_ID = "TensegrityShape-v0"
    TASK = ShapeTask
    _NO_DEVICE_RESET = ShapeTask.NO_DEVICE_RESET

    def _init_device(self):
        torch = torch_module()
        self._tracked = torch.as_tensor(np.asarray(self.task.tracked, dtype=np.int64), device=self.device)
        self._center0 = self._T(self.task.center0)

    def _tracked_nodes(self, q):
        return node_positions(self.tm, q, self._node_prm).index_select(1, self._tracked)

    def _act(self, action):
        torch = torch_module()
        task = self.task
        action = self._delayed(action)
        self.ctrl = update_rate(task.actuation, self.ctrl, action, self._max_rate)
        inputs = self._physics_inputs()
        q0, qd0 = self.q, self.qd
        kw = dict(rest_length=inputs.get("rest_length"), force_density=inputs.get("force_density"),
                  params=self._params, substep=self._substep)
        run = self._physics_call(step)
        (q, qd), qd_prev = self._advance(lambda n, *s: run(self.tm, *s, task.dt, task.integrator, n, **kw),
                                         (q0, qd0))
        diverged = divergence.diverged(q, qd, self._center0, task.divergence_limit)   # pipeline.diverged
        d3 = diverged[:, None, None]
        self.q = torch.where(d3, q0, q)
        self.qd = torch.where(d3, qd0, qd)
        self.elapsed = self.elapsed + 1
        if qd_prev is not None:
            self._sens.record(self.q, self.qd, torch.where(d3, qd0, qd_prev), self.ctrl, None, None, self.target)
        err, emax = namespace(self.q).mean_max(node_errors(self._tracked_nodes(self.q), self.target))
        terms, infos = shape_step_terms(err, emax, action, task.success_tolerance, task.tracking_weight,
                                        task.proximity_weight, task.ctrl_cost_weight)
        infos["diverged"] = diverged
        return terms, None, infos

    def _observe(self):
        if self._sens is not None:
            return self._sens.observation()
        V = node_velocities(self.tm, self.qd).index_select(1, self._tracked)
        return shape_state_observation(self._tracked_nodes(self.q), V, self.ctrl, self.target)


#: task class -> the device env that runs its physics (the first row the task is a subclass of);
#: a task class with no row has no device env (a ValueError, never a fallback)
DEVICE_ENVS = ((RollTask, TorchRollVectorEnv), (ShapeTask, TorchShapeVectorEnv))


def torch_env_class(task_class: type, env_id: str) -> type:
    """The device vector env class of the task class ``task_class`` (registered as ``env_id``):
    a subclass of the device env of the physics it runs (:data:`DEVICE_ENVS`) with ``TASK`` and
    ``ENV_ID`` set; the task's record and record functions do the rest."""
    if not (isinstance(task_class, type) and issubclass(task_class, BatchedTask)):
        raise ValueError(f"task_class: expected a BatchedTask subclass, got {task_class!r}")
    for task_base, env in DEVICE_ENVS:
        if issubclass(task_class, task_base):
            if task_class is env.TASK and env_id == env.ENV_ID:
                return env
            name = "Torch" + task_class.__name__.removesuffix("Task") + "VectorEnv"
            return type(name, (env,), {"TASK": task_class, "ENV_ID": env_id, "__module__": __name__,
                                       "DEVICE_RESET": env.DEVICE_RESET and task_class.DEVICE_RESET,
                                       "_NO_DEVICE_RESET": task_class.NO_DEVICE_RESET,
                                       "__doc__": f"``{env_id}`` on N copies stepped on a torch device: "
                                                  f":class:`{env.__name__}` on ``{task_class.__name__}``."})
    raise ValueError(f"task_class: {task_class.__name__} has no device env (backend='torch'): it is not built "
                     f"on {' or '.join(t.__name__ for t, _ in DEVICE_ENVS)}")


TorchClimbVectorEnv = torch_env_class(ClimbTask, "TensegrityClimb-v0")
TorchNavigateVectorEnv = torch_env_class(NavigateTask, "TensegrityNavigate-v0")
