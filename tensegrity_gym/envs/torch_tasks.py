"""The device-resident task envs on :class:`~tensegrity_gym.envs.torch_shell.TorchTaskVectorEnv`:
the rolling robot (``TensegrityRoll-v0``), climbing (``TensegrityClimb-v0``), navigation
(``TensegrityNavigate-v0``) and shape tracking (``TensegrityShape-v0``) with ``backend="torch"``
(see :mod:`tensegrity_gym.envs.torch_vec` for what runs where)."""
from __future__ import annotations

import gymnasium as gym
import numpy as np

from ..backends.torch.model import torch_module
from ..backends.torch.equations import node_positions, node_velocities, project
from ..backends.torch.actuation import update_motor, update_rate
from ..backends.torch.driver import step
from ..backends.torch import divergence
from ..backends.torch.contact import contact_step
from ..backends.torch.terrain import compile_options, terrain_substep, top_height
from .climb import ClimbTask
from .navigate import NavigateTask
from .roll import RollTask
from ..tasks.climb import gravity_direction, plane_gravity
from ..tasks.navigate import current_goal, guidance_batch, height_scan, navigate_observation, track_goals
from ..tasks.roll import center_of_mass, perturbed_start, roll_state_observation, roll_step_terms
from ..tasks.shape import node_errors, shape_state_observation, shape_step_terms
from ..tasks.terrain import terrain_draws
from ..tasks.xp import namespace
from .shape import ShapeTask
from .torch_shell import TorchTaskVectorEnv
from .torch_terrain import TorchTerrain

__all__ = ["TorchRollVectorEnv", "TorchShapeVectorEnv", "TorchClimbVectorEnv", "TorchNavigateVectorEnv"]

# gymnasium.vector.VectorEnv is listed as a direct base of each env class: libraries that pick their
# wrapper from the class's __bases__ (skrl's wrap_env) then recognise a Gymnasium vector env


class TorchRollVectorEnv(TorchTaskVectorEnv, gym.vector.VectorEnv):
    """``TensegrityRoll-v0`` on N copies stepped on a torch device (see the module doc)."""

    ENV_ID = "TensegrityRoll-v0"
    DEVICE_RESET = True

    def _make_task(self, num_envs, kwargs):
        return RollTask(num_envs=num_envs, **kwargs)

    def _physics_substep(self):
        """With a terrain, :func:`~tensegrity_gym.backends.torch.terrain.terrain_substep` and its
        :func:`~tensegrity_gym.backends.torch.terrain.compile_options`."""
        if self._terrain is None:
            return super()._physics_substep()
        return terrain_substep, compile_options(self._terrain.layout)

    def _init_state(self):
        torch = torch_module()
        task, dev = self.task, self.device
        self._com_eta = self._T(task.model.com_eta)[None, :, None]
        self.q = self._T(task.q)
        self.qd = self._T(task.qd)
        self.anchor = self._T(task.cstate.anchor)
        self.active = torch.as_tensor(task.cstate.active, device=dev)
        self.ctrl = self._T(task.ctrl)
        self.speed = self._T(task.speed)
        self.goal = self._T(task.goal)
        self.start = self._T(task.start)
        # device resets (reset_sampling="device"): the resting robot, rod lengths, lowest node height
        self._q_nominal = self._T(task.q_nominal)
        self._length = self._T(task.model.length)[None, :, None]
        self._z_floor = float(task.nodes_nominal[:, 2].min())
        self._start_control = self._T(task.start_control)[None]
        self._goal_default = self._T(task.goal_direction)[None]
        # terrain=: its rows and contact state on the device (None: the level ground's contact)
        self._terrain = None if task.terrain_contact is None else TorchTerrain(self)

    def _upload_rows(self, it, idx):
        torch = torch_module()
        task = self.task
        self.q[it] = self._T(task.q[idx])
        self.qd[it] = self._T(task.qd[idx])
        self.anchor[it] = self._T(task.cstate.anchor[idx])
        self.active[it] = torch.as_tensor(task.cstate.active[idx], device=self.device)
        self.ctrl[it] = self._T(task.ctrl[idx])
        self.speed[it] = self._T(task.speed[idx])
        self.goal[it] = self._T(task.goal[idx])
        self.start[it] = self._T(task.start[idx])
        if self._terrain is not None:
            self._terrain.upload_rows(self, it, idx)

    def _com(self, q, it=None):
        """(N, 3) centre of mass, m (as ``RollTask._com``); of envs ``it`` when ``q`` holds only them."""
        mf = self._mass_frac
        if it is not None and mf.shape[0] > 1:
            mf = mf[it]
        return center_of_mass(q, mf.expand(q.shape[0], -1), None if self.task._com_at_r else self._com_eta)

    def _reset_draws(self) -> int:
        """Uniforms a device reset of one env reads for the task: the initial-state noise (4 x k x 3:
        rod centres, axes, their rates), then the goal angle with ``randomize_goal``, then a
        terrain generator's draws."""
        task = self.task
        gen = task.terrain_generator
        return ((12 * task.model.n_bars if task.reset_noise_scale > 0 else 0) + (1 if task.randomize_goal else 0)
                + (0 if gen is None else terrain_draws(gen)))

    def _device_reset_rows(self, it, u) -> dict:
        """``RollTask.reset_idx`` on the device for envs ``it`` from their uniforms ``u`` (r, n)
        float64: the resting robot plus U(-s, s) noise on the rod centres (m) and velocities (m/s)
        and, divided by the rod length, on the axes and their rates, projected (unit axes), lifted
        so that no node is below the resting robot's lowest; no contact anchors; the start
        control; the goal (angle U(0, 2 pi) with ``randomize_goal``); on a terrain, a generator's
        new terrain (:meth:`TorchTerrain.draw`), the start lifted clear of it and its contact
        state released."""
        torch = torch_module()
        task = self.task
        r, k, s = it.shape[0], task.model.n_bars, task.reset_noise_scale
        used = 0
        if s > 0:
            x = (-s + (s - -s) * u[:, :12 * k]).to(self.dtype).reshape(r, 4, k, 3)   # U(-s, s) as NumPy's
            used = 12 * k
        else:
            x = torch.zeros((r, 4, k, 3), dtype=self.dtype, device=self.device)
        q, qd = perturbed_start(self._q_nominal, self._length, x)
        if task.randomize_goal:
            th = 0.0 + (2.0 * np.pi - 0.0) * u[:, used]     # U(0, 2 pi) as NumPy's
            goal = torch.stack([torch.cos(th), torch.sin(th)], dim=1).to(self.dtype)
            used += 1
        else:
            goal = self._goal_default.expand(r, -1)
        q, qd = project(self.tm, q, qd)
        zmin = node_positions(self.tm, q, self._node_prm)[..., 2].amin(dim=1)
        q[..., 2] += torch.clamp(self._z_floor - zmin, min=0.0)[:, None]
        if self._terrain is not None:       # a generator's new terrain; clear of it, its contact let go
            if task.terrain_generator is not None:
                self._terrain.draw(self, it, u[:, used:], goal)
            nodes = node_positions(self.tm, q, self._node_prm)
            q[..., 2] += self._terrain.start_lift(nodes, task.contact.radius, it)[:, None]
            self._terrain.release(it)
        ctrl = self._start_control.expand(r, -1)
        self.q[it], self.qd[it] = q, qd
        self.anchor[it] = 0.0
        self.active[it] = False
        self.ctrl[it] = ctrl
        self.speed[it] = 0.0
        self.goal[it] = goal
        com = self._com(q, it)
        self.start[it] = com
        if self._sens is not None:
            self._sens.reset_rows(it, q, qd, ctrl, self.speed[it], self.active[it], goal)
        return {"com_position": com, "com_velocity": torch.zeros_like(com),
                "distance_rolled": com.new_zeros(r), "goal_direction": goal.clone()}

    def _observe(self):
        if self._sens is not None:
            return self._sens.observation()
        q, qd = self.q, self.qd
        return roll_state_observation(node_positions(self.tm, q, self._node_prm), node_velocities(self.tm, qd),
                                      self._com(q), self.ctrl, self.active, self.goal, self.speed)

    def _act(self, action):
        """One control step of the task for the whole batch: ``(terms, infos)`` as (N,) tensors."""
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
        com0 = self._com(q0)
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
        com = self._com(self.q)
        terms, infos = roll_step_terms(com0, com, self.start, self.goal, action, task.control_dt,
                                       task.forward_reward_weight, task.ctrl_cost_weight)
        infos["diverged"] = diverged
        return terms, infos



class TorchShapeVectorEnv(TorchTaskVectorEnv, gym.vector.VectorEnv):
    """``TensegrityShape-v0`` on N copies stepped on a torch device: the task of
    :class:`~tensegrity_gym.envs.shape.ShapeTask` (targets and initial states drawn on the host
    at reset from each env's generator; control update, physics with the model's node drag,
    divergence check, tracking errors, the ``tracking`` / ``proximity`` / ``ctrl`` reward terms
    and the observation on the device). Arguments: those of ``TensegrityShape-v0`` plus
    ``device``, ``dtype``, ``max_episode_steps``, ``compile`` (``torch.compile`` of
    :func:`tensegrity_gym.backends.torch.driver.step_once`)."""

    ENV_ID = "TensegrityShape-v0"
    _NO_DEVICE_RESET = ("its targets are stable static equilibria found by Newton's method with rejection, "
                        "statics.solve_equilibria, on the host")

    def _make_task(self, num_envs, kwargs):
        return ShapeTask(num_envs=num_envs, **kwargs)

    def _init_state(self):
        task = self.task
        torch = torch_module()
        self.q = self._T(task.q)
        self.qd = self._T(task.qd)
        self.ctrl = self._T(task.ctrl)
        self.target = self._T(task.target)
        self._tracked = torch.as_tensor(np.asarray(task.tracked, dtype=np.int64), device=self.device)
        self._center0 = self._T(task.center0)

    def _upload_rows(self, it, idx):
        task = self.task
        self.q[it] = self._T(task.q[idx])
        self.qd[it] = self._T(task.qd[idx])
        self.ctrl[it] = self._T(task.ctrl[idx])
        self.target[it] = self._T(task.target[idx])

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
        return terms, infos

    def _observe(self):
        if self._sens is not None:
            return self._sens.observation()
        V = node_velocities(self.tm, self.qd).index_select(1, self._tracked)
        return shape_state_observation(self._tracked_nodes(self.q), V, self.ctrl, self.target)


class TorchClimbVectorEnv(TorchRollVectorEnv):
    """``TensegrityClimb-v0`` on N copies stepped on a torch device: :class:`TorchRollVectorEnv`
    on :class:`~tensegrity_gym.envs.climb.ClimbTask` (the slope as tilted gravity in the plane
    frame, drawn per reset; with ``reset_sampling="device"`` on the device, the first draw of
    the reset as on the host)."""

    ENV_ID = "TensegrityClimb-v0"

    def _reset_draws(self) -> int:
        """The slope (with a ``slope_range``), then the rolling task's draws."""
        return int(self.task._draws_slope) + super()._reset_draws()

    def _device_reset_rows(self, it, u) -> dict:
        """``ClimbTask.reset_idx`` on the device: each reset env's slope U(lo, hi) degrees from
        its first uniform, its gravity in the plane frame (:func:`~tensegrity_gym.tasks.climb.plane_gravity`)
        and gravity direction (held in float32 as the host's), then the rolling task's rows."""
        task = self.task
        if task._draws_slope:
            torch = torch_module()
            lo, hi = task.slope_range
            a = lo + (hi - lo) * u[:, 0]             # U(lo, hi) as NumPy's
            g = plane_gravity(a, task._g)
            self._params["gravity"][it] = g.to(self.dtype)
            self.slope[it] = a.to(self.slope.dtype)
            self.gdir[it] = gravity_direction(g).to(torch.float32).to(self.gdir.dtype)
            u = u[:, 1:]
        info = super()._device_reset_rows(it, u)
        info["slope_deg"] = self.slope[it].clone()
        return info

    def _make_task(self, num_envs, kwargs):
        return ClimbTask(num_envs=num_envs, **kwargs)

    def _init_state(self):
        super()._init_state()
        self.gdir = self._T(self.task._gdir)
        self.slope = self._T(self.task.slope)

    def _upload_rows(self, it, idx):
        super()._upload_rows(it, idx)
        self.gdir[it] = self._T(self.task._gdir[idx])
        self.slope[it] = self._T(self.task.slope[idx])

    def _observe(self):
        obs = super()._observe()
        if self._sens is not None:
            return obs
        return namespace(obs).concat([obs, self.gdir], axis=1)

    def _act(self, action):
        terms, infos = super()._act(action)
        infos["slope_deg"] = self.slope.clone()
        infos["uphill_velocity"] = infos["forward_velocity"]
        return terms, infos


class TorchNavigateVectorEnv(TorchRollVectorEnv):
    """``TensegrityNavigate-v0`` on N copies stepped on a torch device: :class:`TorchRollVectorEnv`
    on :class:`~tensegrity_gym.envs.navigate.NavigateTask`. Each reset env's course (goals,
    walls, rough patches and the planner's path-distance fields) is drawn and planned on the host
    (``reset_sampling="host"`` only) and its rows copied to the device: the fields (N, n_goals,
    ny, nx) m, about 120 kB per env on the default course. Each step then runs on the device: the
    terrain contact, the rolling task's terms along the planner's guidance, the goals reached
    and the guidance toward the next (:func:`~tensegrity_gym.tasks.navigate.track_goals`,
    :func:`~tensegrity_gym.tasks.navigate.guidance_batch`), the ``goal`` reward term, the end of
    the episode when every goal is reached, and the observation in the guidance frame with the
    optional height scan (:func:`~tensegrity_gym.tasks.navigate.navigate_observation`): the
    NumPy env's functions, on tensors."""

    ENV_ID = "TensegrityNavigate-v0"
    DEVICE_RESET = False
    _NO_DEVICE_RESET = "its courses are drawn and planned per reset on the host"

    def _make_task(self, num_envs, kwargs):
        return NavigateTask(num_envs=num_envs, **kwargs)

    def _init_state(self):
        super()._init_state()
        torch = torch_module()
        task = self.task
        self.fields = self._T(np.nan_to_num(task._fields, nan=np.inf))   # rows drawn at reset
        self.goals = self._T(np.nan_to_num(task._goals))
        self.goal_index = torch.as_tensor(task.goal_index, dtype=torch.int64, device=self.device)
        self.path = self._T(task.path)
        self._origin = self._T(task.courses[0].origin)
        self._scan = None if task.scan is None else self._T(task.scan)

    def _upload_rows(self, it, idx):
        torch = torch_module()
        super()._upload_rows(it, idx)
        task = self.task
        self.fields[it] = self._T(task._fields[idx])
        self.goals[it] = self._T(task._goals[idx])
        self.goal_index[it] = torch.as_tensor(task.goal_index[idx], dtype=torch.int64, device=self.device)
        self.path[it] = self._T(task.path[idx])

    def _guide(self):
        """``goal`` (the planner's unit guidance) and ``path`` (m) of every env toward its current goal."""
        torch = torch_module()
        task = self.task
        g, goal = current_goal(self.goals, self.goal_index, torch.arange(self.num_envs, device=self.device))
        self.goal, self.path = guidance_batch(self.fields, self._origin, task.courses[0].cell, goal,
                                              self._com(self.q)[:, :2], task.spec.lookahead, g)

    def _act(self, action):
        terms, infos = super()._act(action)
        task = self.task
        self.goal_index, reached, success, dist = track_goals(self.goals, self.goal_index, self._com(self.q)[:, :2],
                                                              task.spec.goal_radius)
        self._guide()
        terms["goal"] = task.goal_bonus * reached.to(self.dtype)
        infos.update(goals_reached=self.goal_index.clone(), goal_reached=reached, success=success,
                     distance_to_goal=dist, path_distance=namespace(dist).where(success, 0.0, self.path))
        return terms, infos

    def _terminated(self, infos: dict):
        return infos["success"].clone()

    def _observe(self):
        obs = super()._observe()
        if self._sens is not None:
            return obs
        task = self.task
        scan = None
        if self._scan is not None:
            tt = self._terrain
            scan = height_scan(lambda x, y: top_height(tt.geom, tt.hf, x, y, tt.layout.kinds), self._com(self.q),
                               self._scan)
        return navigate_observation(obs, task._blocks, self.goal, self.path, self.goal_index, task.spec.n_goals, scan)
