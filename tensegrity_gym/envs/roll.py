"""TensegrityRoll-v0: roll a tensegrity robot across flat ground by changing its cables.

One batched task (:class:`RollTask`) on B copies; :class:`TensegrityRollEnv` is it with B = 1
and :class:`TensegrityRollVectorEnv` with B = ``num_envs`` (see
:mod:`tensegrity_gym.envs.common`). Ground contact: :mod:`tensegrity_gym.physics.contact`. SI units.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from ..physics.contact import GroundContact, init_contact_state, set_copy_values, stable_step
from ..core.model import compile_model
from ..physics.evaluate import force_densities, project
from ..physics import geometry
from ..core.errors import StabilityWarning
from ..physics.actuation import Actuation
from ..core.checks import check_array, check_flag
from ..core.param_table import contact_arguments, env_fields
from .base import BatchedTask, fixed_step
from .config import RollConfig, flat_signature, roll_config, with_flat
from .domain import container_nominal
from .docs import ROLL_DOC as _DOC
from .roll_obs import RollObservation
from ..physics import terrain
from ..tasks.roll import perturbed_start, roll_step_terms
from ..tasks.state import StateField
from ..core.terrain import Terrain
from ..tasks.terrain import generate, resolve_terrain, start_lift
from .roll_scene import (GRAVITY, MAX_CABLE_ACCELERATION, MAX_PATH, ROD_MASS, SETTLE_TIME,  # noqa: F401
                         STRING_DAMPING, load_robot, place_on_ground, put_on_ground, robot_icosahedron,
                         robot_prism, settle)
from .sensors import RobotSensors
from .shells import TaskEnv, TaskVectorEnv
from .limits import check_domain_rest_lengths, check_domain_stable_dt
from .validate import ACTION_MODES, check_positive, check_rest_length_bounds, check_stable_dt, resolve_actuated

__all__ = ["RollTask", "TensegrityRollEnv", "TensegrityRollVectorEnv", "robot_prism", "robot_icosahedron",
           "place_on_ground", "GRAVITY"]

ENV_ID = "TensegrityRoll-v0"


#: GroundContact field -> this task's argument (for error messages; a view of the parameter table)
_CONTACT_ARGS = contact_arguments()

#: randomised contact parameter (envs/domain.py name) -> its column of the per-copy contact array
#: (a view of the parameter table, tensegrity_gym.core.param_table)
CONTACT_DOMAIN = env_fields("contact")


class RollTask(RollObservation, BatchedTask):
    """Batched rolling task on ``num_envs`` copies (arguments: see :class:`TensegrityRollEnv`).

    State: ``q``, ``qd`` (B, k, 6); ``cstate`` (contact anchors (B, 2k, 2), flags (B, 2k));
    ``ctrl`` (B, na) rest lengths (m) or force densities (N/m) of the actuated strings;
    ``speed`` (B, na) cable speeds (m/s; rest-length mode with ``max_cable_acceleration``,
    else (B, 0));
    ``goal`` (B, 2) unit goal direction in the ground plane; ``start`` (B, 3) centre of mass at reset, m.
    These are its record (:data:`STATE`, :mod:`tensegrity_gym.tasks.state`); :meth:`task_step`
    and :meth:`observe_task` are written once over a record, for this task and the torch env.
    """

    #: the per-copy state every shell holds (:mod:`tensegrity_gym.tasks.state`)
    STATE = (StateField("q"), StateField("qd"), StateField("anchor", host="cstate.anchor"),
             StateField("active", "bool", host="cstate.active"), StateField("ctrl"), StateField("speed"),
             StateField("goal"), StateField("start"))
    CURRICULUM_HOOKS = {"terrain_difficulty": "set_terrain_difficulty"}
    DEVICE_RESET = True

    def __init__(self, num_envs: int = 1, config: RollConfig | None = None, **kwargs):
        self.config = c = with_flat(config, kwargs, "RollTask.__init__", RollConfig)
        structure, string_damping = c.robot.structure, c.robot.string_damping
        integrator, dt, frame_skip = c.simulation.integrator, c.simulation.dt, c.simulation.frame_skip
        backend, divergence_limit = c.simulation.backend, c.simulation.divergence_limit
        allow_unstable_dt = c.simulation.allow_unstable_dt
        a = c.actuation
        action_mode, actuated, max_cable_speed = a.action_mode, a.actuated, a.max_cable_speed
        max_cable_acceleration, rest_length_bounds = a.max_cable_acceleration, a.rest_length_bounds
        force_density_max, force_density_rate, clip_actions = a.force_density_max, a.force_density_rate, a.clip_actions
        action_delay, start_rest_length_offset = a.action_delay, a.start_rest_length_offset
        g = c.contact
        friction, ground_stiffness, ground_damping = g.friction, g.ground_stiffness, g.ground_damping
        tangential_stiffness, tangential_damping = g.tangential_stiffness, g.tangential_damping
        cap_radius, ground_max_damping = g.cap_radius, g.ground_max_damping
        forward_reward_weight, ctrl_cost_weight = c.reward.forward_reward_weight, c.reward.ctrl_cost_weight
        goal_direction, randomize_goal = c.goal.goal_direction, c.goal.randomize_goal
        observation_mode, sensor_noise, history = (c.observation.observation_mode, c.observation.sensor_noise,
                                                   c.observation.history)
        reset_noise_scale, params, randomize = (c.randomization.reset_noise_scale, c.randomization.params,
                                                c.randomization.randomize)
        RobotSensors.check_mode(observation_mode, sensor_noise, history)   # before the robot is built
        allow_unstable_dt = check_flag(allow_unstable_dt, "allow_unstable_dt")
        if action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode: unknown {action_mode!r}; choose one of {ACTION_MODES}")
        if string_damping is not None:
            string_damping = check_positive(string_damping, "string_damping", "N s/m", allow_zero=True)
        s, axis = load_robot(structure, string_damping)
        self.action_mode = action_mode
        integ = fixed_step(integrator)     # the integrator's name, decoded once
        dt = check_positive(dt, "dt", "s")
        if ground_max_damping is None:   # keep c dt / m_eff <= 1 in fast impacts (m_eff = m/4 of the lightest rod)
            ground_max_damping = float(s.bar_mass.min()) / 4.0 / dt
        try:
            self.contact = GroundContact(stiffness=ground_stiffness, damping=ground_damping, friction=friction,
                                            tangential_stiffness=tangential_stiffness,
                                            tangential_damping=tangential_damping, radius=cap_radius,
                                            max_damping=ground_max_damping)
        except ValueError as e:   # name this task's argument, not GroundContact's field
            field, _, rest = str(e).partition(":")
            raise ValueError(f"{_CONTACT_ARGS.get(field, field)}:{rest}") from None
        self.forward_reward_weight = check_positive(forward_reward_weight, "forward_reward_weight", "s/m",
                                                    allow_zero=True)
        self.ctrl_cost_weight = check_positive(ctrl_cost_weight, "ctrl_cost_weight", allow_zero=True)
        self.reset_noise_scale = check_positive(reset_noise_scale, "reset_noise_scale", "m, m/s", allow_zero=True)
        self.max_cable_speed = check_positive(max_cable_speed, "max_cable_speed", "m/s")
        if max_cable_acceleration is not None:
            max_cable_acceleration = check_positive(max_cable_acceleration, "max_cable_acceleration", "m/s^2")
        self.max_cable_acceleration = max_cable_acceleration
        g = check_array(goal_direction, (2,), "goal_direction")
        if np.linalg.norm(g) == 0:
            raise ValueError(f"goal_direction: expected a non-zero (x, y) vector, got {goal_direction!r}")
        self.goal_direction = g / np.linalg.norm(g)
        self.randomize_goal = check_flag(randomize_goal, "randomize_goal")
        self.rest_length_bounds = lo, hi = check_rest_length_bounds(rest_length_bounds)
        act = resolve_actuated(actuated, s.n_strings)
        self.actuated = act

        # place on the ground and let it settle (elastic model, all strings at their rest lengths)
        s, self.stability_margin = put_on_ground(s, self.contact.radius, axis)
        self.structure = s
        elastic = compile_model(s)
        if integ in ("semi_implicit_euler", "rk4"):   # before settling on it
            check_stable_dt(elastic, stable_step(self.contact, elastic)["semi_implicit_euler"], dt, integ,
                            allow_unstable_dt, "this robot's strings and ground contact")
        # built-in scenes: settle once per process and parameter set
        key = (structure, string_damping, self.contact, integ, float(dt)) if isinstance(structure, str) else None
        self.q_nominal, self.qd_nominal = settle(elastic, self.contact, integ, dt, key)
        self.nodes_nominal = geometry.node_positions(elastic, self.q_nominal)[0]
        gamma0, _, _ = force_densities(elastic, self.q_nominal, self.qd_nominal)
        self.gamma_nominal = gamma0[0]
        if np.any(self.gamma_nominal[act] <= 0):
            bad = act[self.gamma_nominal[act] <= 0][0]
            raise ValueError(f"actuated string {bad} is slack in the resting robot; actuate taut strings")
        model = compile_model(self._scene_structure(s), act if action_mode == "force_density" else None)
        self._init_physics(model, num_envs, integ, dt, frame_skip, backend, divergence_limit, clip_actions)
        self.body_length = float(np.max(s.bar_lengths))
        self.actuation = Actuation.for_task(action_mode, act, s.rest_length, (lo, hi), self.max_cable_speed,
                                            self.control_dt, self.gamma_nominal, force_density_max,
                                            force_density_rate, max_cable_acceleration)

        B, k, n, na = self.num_envs, model.n_bars, model.n_nodes, act.size
        # motor model (rest-length mode with an acceleration limit): cable speeds are state, observed
        self.motor = self.actuation.max_accel is not None
        self.n_speed = na if self.motor else 0
        self.n_contacts = 2 * k
        self.action_size = na
        self.observation_size = self._state_size = 6 * n + na + self.n_contacts + 3 + self.n_speed
        self.observation_mode = observation_mode
        # robot observation (envs/sensors.py; None in state mode); the IMUs read the last physics step
        self.sensors = RobotSensors.attach(self, observation_mode, sensor_noise, history, ("goal_direction", 2, "1"),
                                           n_speed=self.n_speed, n_contacts=2 * k)
        self.cstate = init_contact_state(model, B)
        self.ctrl = np.tile(self.actuation.nominal, (B, 1))
        self.speed = np.zeros((B, self.n_speed))
        self.goal = np.tile(self.goal_direction, (B, 1))
        self.q = np.tile(self.q_nominal, (B, 1, 1))
        self.qd = np.zeros_like(self.q)
        self.start = geometry.center_of_mass(model, self.q)
        self.paths: dict[int, list] = {}
        self._init_observation(model)
        self._W = np.zeros((B, n, 3))
        self._slip = np.zeros((B, self.n_contacts), bool)
        self._contact_prm = None     # (B, 9) per-copy contact parameters once any is set (domain)
        self._init_terrain(c.terrain, allow_unstable_dt, friction, ground_stiffness, ground_damping,
                           tangential_stiffness, tangential_damping, ground_max_damping)
        extra = container_nominal("contact", self.contact)
        extra.update(container_nominal("actuation", self.actuation))
        self._init_domain(params, randomize, action_delay, start_rest_length_offset, extra)
        check_domain_rest_lengths(self)
        check_domain_stable_dt(self, allow_unstable_dt, lambda m, c: stable_step(c, m)["semi_implicit_euler"])
        self.travels = True      # divergence: measured from each copy's own centre (it rolls away)
        limit = stable_step(self.contact, model)["semi_implicit_euler"]
        if self.integrator in ("semi_implicit_euler", "rk4"):
            check_stable_dt(model, limit, self.dt, self.integrator, allow_unstable_dt,
                            "this robot's strings and ground contact")
        if self.integrator in ("semi_implicit_euler", "rk4") and self.dt > limit:
            warnings.warn(StabilityWarning(
                f"{ENV_ID}: dt = {self.dt:.4g} s is above the estimated stability limit {limit:.4g} s of "
                "semi-implicit Euler with this robot's strings and ground contact"), stacklevel=3)

    def _init_terrain(self, tcfg, allow_unstable_dt, friction, stiffness, damping, tangential_stiffness, tangential_damping,
                      max_damping) -> None:
        """The terrain (``tcfg``: :class:`~tensegrity_gym.envs.config.TerrainConfig`): None keeps the
        level ground (its fast path, no terrain code); a terrain or a generator replaces it with
        terrain contact of the same contact law (the rods' capsules of ``cap_radius``)."""
        self.set_terrain_difficulty(tcfg.terrain_difficulty)
        self._surface = surface = dict(friction=friction, stiffness=stiffness, damping=damping)
        spec = self._terrain_source(tcfg, surface)
        self.terrain_generator = None if spec is None or isinstance(spec, Terrain) else spec
        if spec is None:
            self.terrains = None
            return
        B = self.num_envs
        first = spec if self.terrain_generator is None else \
            self._draw_terrain(0, np.random.default_rng(0), self.goal_direction)
        self.terrains = [first] * B
        self._terrain_kw = dict(radius=self.contact.radius, tangential_stiffness=tangential_stiffness,
                                tangential_damping=tangential_damping, max_damping=max_damping)
        tc = self.terrain_contact = self._contact_of(self.terrains[0])
        self.tstate = terrain.init_terrain_state(tc, self.model, B)
        self._terrain_slip = np.zeros(self.tstate.active.shape, bool)
        # per-copy rows (one terrain per copy: a generator's differ in numbers, not in shape)
        self.terrain_geom = np.repeat(tc.geom, B, axis=0)
        self.terrain_prm = np.repeat(tc.prm, B, axis=0)
        self.terrain_hf = np.repeat(tc.hf, B, axis=0) if self.terrains[0].heightfield is not None else None
        limit = terrain.stable_step(tc, self.model)["semi_implicit_euler"]
        if self.integrator in ("semi_implicit_euler", "rk4"):
            check_stable_dt(self.model, limit, self.dt, self.integrator, allow_unstable_dt,
                            "this robot's strings and terrain contact")

    def _terrain_source(self, tcfg, surface: dict):
        """None (level ground), a fixed ``Terrain``, or a source of terrains drawn per episode by
        :meth:`_draw_terrain` (here a ``TerrainGenerator``) from the ``terrain`` argument."""
        return resolve_terrain(tcfg.terrain, surface)

    def _draw_terrain(self, i: int, rng: np.random.Generator, goal) -> Terrain:
        """Copy ``i``'s terrain this episode, drawn from ``rng`` (goal: its unit goal direction)."""
        return generate(self.terrain_generator, rng, goal, self.terrain_difficulty)

    def set_terrain_difficulty(self, difficulty: float) -> None:
        """The curriculum hook: terrains drawn from the next resets on are scaled by
        ``difficulty`` in [0, 1] (a generator's slope, step height or bump amplitude)."""
        d = check_positive(difficulty, "terrain_difficulty", allow_zero=True)
        if d > 1:
            raise ValueError(f"terrain_difficulty: must be in [0, 1], got {difficulty!r}")
        self.terrain_difficulty = d

    def _contact_of(self, t) -> "terrain.TerrainContact":
        try:
            return terrain.TerrainContact(t, **self._terrain_kw)
        except ValueError as e:
            raise ValueError(f"terrain: {e}") from None

    def _reset_terrain(self, idx, rngs, goal) -> None:
        """Copies ``idx`` on their terrain: a generator draws each copy's from its generator (after
        the start's noise and goal); stick/slip state released."""
        if self.terrain_generator is not None:
            for j, i in enumerate(idx):
                t = self._draw_terrain(int(i), rngs[j], goal[j])
                tc = self._contact_of(t)
                if tc.geom.shape[1:] != self.terrain_geom.shape[1:] or tc.hf.shape[1:] != self.terrain_contact.hf.shape[1:]:
                    raise RuntimeError("terrain generator: a drawn terrain changed its number of parts")
                self.terrains[i] = t
                self.terrain_geom[i] = tc.geom[0]
                if self.terrain_hf is not None:
                    self.terrain_hf[i] = tc.hf[0]
        self.tstate.anchor[idx] = 0.0
        self.tstate.eta0[idx] = 0.0
        self.tstate.active[idx] = False

    def terrain_height(self, x, y) -> np.ndarray:
        """(B, m) the height of each copy's ground under the points ``x``, ``y`` (B, m) m: its
        terrain's top (:meth:`~tensegrity_gym.core.terrain.Terrain.height_at`), or the level
        ground's plane (the record's ``terrain_height``, :mod:`tensegrity_gym.tasks.state`)."""
        if self.terrains is None:
            return np.full(np.shape(x), self.contact.height)
        return np.stack([t.height_at(x[i], y[i]) for i, t in enumerate(self.terrains)])

    def _scene_structure(self, s):
        """The placed, settled robot ``s`` as the task's physics runs it (here: as it is; a task
        on another scene, e.g. a slope, changes what the scene changes, such as gravity)."""
        return s

    def write_contact(self, rows, columns: dict) -> None:
        """Rows ``rows`` of the per-copy contact parameters the physics steps take ``columns``
        (field -> values): the terrain's (every part of a row), or without a terrain the ground's."""
        if self.terrain_contact is not None:
            prm = self.terrain_prm
        else:
            if self._contact_prm is None:
                self._contact_prm = self.contact.per_copy(self.num_envs)
            prm = self._contact_prm
        for fld, values in columns.items():
            set_copy_values(prm, rows, fld, values)

    def write_actuation(self, rows, fields: dict) -> None:
        """Copies ``rows`` take their own motor limits ``fields`` (``max_rate``, ``max_accel``)."""
        self.actuation.set_copy_limits(self.num_envs, rows, **fields)

    def _apply_task_domain(self, idx) -> None:
        """The rods' mass fractions after the masses of copies ``idx`` changed."""
        if "rod_mass" in self.domain.values:
            mass = np.broadcast_to(self.params.mass, (self.num_envs, self.model.n_bars))
            self._mass_frac = mass / mass.sum(axis=1, keepdims=True)

    # ------------------------------------------------------------------ scene
    # ------------------------------------------------------------------ task API
    @property
    def first_draws(self) -> int:
        """Uniforms per copy a task built on this one draws first at each reset
        (:meth:`reset_first`; here none)."""
        return 0

    def reset_first(self, rec, rows, u) -> None:
        """The first step of a reset of copies ``rows`` on the record ``rec``, from their uniforms
        ``u`` (r, :attr:`first_draws`) in [0, 1): for a task built on this one (a slope)."""

    def reset_info(self, rec, rows) -> dict:
        """Reset infos of copies ``rows`` beyond the rolling task's, from the record ``rec``."""
        return {}

    def reset_idx(self, idx, rngs, options=None) -> dict:
        idx = np.asarray(idx, dtype=int)
        r = idx.size
        n0 = self.first_draws
        if n0:     # a task's own first draws (uniforms, as the device reset reads them)
            self.reset_first(self, idx, np.array([rngs[j].random(n0) for j in range(r)]).reshape(r, n0))
        s = self.reset_noise_scale
        k = self.model.n_bars
        goal = np.tile(self.goal_direction, (r, 1))
        x = np.zeros((r, 4, k, 3))
        for j in range(r):    # each copy's generator: its noise (4 k 3 uniforms), then its goal angle
            rng = rngs[j]
            if s > 0:
                x[j] = rng.uniform(-s, s, (4, k, 3))
            if self.randomize_goal:
                th = rng.uniform(0.0, 2.0 * np.pi)
                goal[j] = (math.cos(th), math.sin(th))
        q, qd = perturbed_start(self.q_nominal, self.model.length[:, None], x)
        q, qd = project(self.model, q, qd)
        # no node below the ground plus cap: lift the copy if the noise pushed one in
        zmin = geometry.node_positions(self.model, q)[..., 2].min(axis=1)
        lift = np.maximum(self.nodes_nominal[:, 2].min() - zmin, 0.0)
        q[..., 2] += lift[:, None]
        if self.terrain_contact is not None:     # on a terrain: its own draws, then clear of it
            self._reset_terrain(idx, rngs, goal)
            nodes = geometry.node_positions(self.model, q)
            for j, i in enumerate(idx):
                q[j, :, 2] += start_lift(self.terrains[i], nodes[j:j + 1], self.contact.radius)[0]
        self.q[idx], self.qd[idx] = q, qd
        self.cstate.anchor[idx] = 0.0
        self.cstate.active[idx] = False
        self.ctrl[idx] = self.start_control
        self.speed[idx] = 0.0
        self.goal[idx] = goal
        self.elapsed[idx] = 0
        com = geometry.center_of_mass(self.model, q, None if self.params is None else self.params.take(
            idx if self.params.batch_size > 1 else np.zeros(len(idx), int)))
        self.start[idx] = com
        if self.sensors is not None:
            self.sensors.reset_reading(self, idx, rngs, goal, self.speed[idx], self.cstate.active[idx])
        if self.record_path:
            for j, i in enumerate(idx):
                self.paths[int(i)] = [com[j].copy()]
        info = {"com_position": com, "com_velocity": np.zeros((r, 3)), "distance_rolled": np.zeros(r),
                "goal_direction": goal.copy()}
        info.update(self.reset_info(self, idx))
        return info

    def task_step(self, rec, com0, com, action) -> tuple[dict, object, dict]:
        """The task's part of one control step on the record ``rec`` (this task, or the torch
        env's tensors) after the physics: centres of mass ``com0`` / ``com`` (B, 3) m before /
        after, ``action`` (B, na). Returns ``(terms, terminated (B,) bool or None (no episode
        ends), infos)``; may update the record's state."""
        terms, infos = roll_step_terms(com0, com, rec.start, rec.goal, action, self.control_dt,
                                       self.forward_reward_weight, self.ctrl_cost_weight)
        return terms, None, infos

    def observe_task(self, rec, obs):
        """The state observation (B, size) from the rolling task's ``obs`` (B, state size) on the
        record ``rec`` (this task's: as it is)."""
        return obs

    def step(self, action):
        com0 = self._com(self.q)
        diverged = self.simulate(action)
        com = self._com(self.q)
        if self.sensors is not None:
            self.sensors.record(self, self.goal, self.speed, self.cstate.active)
        terms, terminated, infos = self.task_step(self, com0, com, action)
        if self.record_path:   # centre-of-mass path for render(), last MAX_PATH points per env
            for i in range(self.num_envs):
                p = self.paths.setdefault(i, [])
                p.append(com[i].copy())
                if len(p) > MAX_PATH:
                    del p[: len(p) - MAX_PATH]
        infos["diverged"] = diverged
        return terms, np.zeros(self.num_envs, bool) if terminated is None else terminated, infos

    def render_data(self, i: int) -> dict:
        q, qd = self.q[i:i + 1], self.qd[i:i + 1]
        inputs = self.actuation.physics_inputs(self.ctrl[i:i + 1])
        gamma, _, L = force_densities(self.model, q, qd, inputs.get("rest_length"), inputs.get("force_density"))
        com = geometry.center_of_mass(self.model, q)[0]
        path = np.array(self.paths.get(i, [com]))
        goal = com + 0.5 * np.array([self.goal[i, 0], self.goal[i, 1], 0.0])
        goal[2] = self.contact.height
        dist = float((com - self.start[i])[:2] @ self.goal[i])
        extra = {} if self.terrains is None else {"terrain": self.terrains[i]}
        return {"nodes": geometry.node_positions(self.model, q)[0], "rods": self.structure.bars,
                "strings": self.structure.strings, "tensions": (gamma * L)[0], "ground_z": self.contact.height,
                "path": path, "goal": goal,
                "caption": f"t = {self.elapsed[i] * self.control_dt:.2f} s, rolled {dist:.2f} m", **extra}


#: the flat arguments (introspection: agents.envs.env_argument_names, the shells' manuals)
RollTask.__signature__ = flat_signature(roll_config(), RollConfig)

TensegrityRollEnv = TaskEnv.for_task(RollTask, ENV_ID, _DOC, __name__)
TensegrityRollVectorEnv = TaskVectorEnv.for_task(RollTask, ENV_ID, _DOC + r"""
    ## Vector env
    ``gymnasium.make_vec("TensegrityRoll-v0", num_envs=N, vectorization_mode="vector_entry_point")``
    or ``TensegrityRollVectorEnv(num_envs=N, **kwargs)``: the same task on N copies, stepped with
    one batched contact update and one batched ``physics.step`` call per physics step.
    Next-step autoreset; ``reset(seed=s)`` seeds env i with s + i (equal to N single envs with
    those seeds); ``max_episode_steps`` truncates every env (``make_vec`` passes the registered
    1000). See :class:`tensegrity_gym.envs.common.TaskVectorEnv`.
""", __name__)
