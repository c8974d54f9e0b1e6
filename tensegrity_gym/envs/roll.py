"""TensegrityRoll-v0: roll a tensegrity robot across flat ground by changing its cables.

One batched task (:class:`RollTask`) on B copies; :class:`TensegrityRollEnv` is it with B = 1
and :class:`TensegrityRollVectorEnv` with B = ``num_envs`` (see
:mod:`tensegrity_gym.envs.common`). Ground contact: :mod:`tensegrity_gym.physics.contact`. SI units.
"""
from __future__ import annotations

import warnings

import numpy as np

from ..physics.contact import GroundContact, impact_damping_cap, init_contact_state, set_copy_values, stable_step
from ..physics import rod_contact as rods
from ..core.model import compile_model
from ..physics.evaluate import force_densities
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
from .roll_reset import RollReset
from .roll_terrain import RollTerrain
from ..tasks.roll import roll_step_terms
from ..tasks.state import StateField
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


class RollTask(RollObservation, RollReset, RollTerrain, BatchedTask):
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
    STATE = (StateField("q"), StateField("qd"), StateField("anchor"), StateField("active", "bool"),
             StateField("ctrl"), StateField("speed"), StateField("goal"), StateField("start"))
    CONSTANTS = (StateField("q_nominal"), StateField("rod_length"), StateField("start_control"),
                 StateField("goal_direction"))
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
            ground_max_damping = impact_damping_cap(s.bar_mass, dt)
        try:
            self.contact = GroundContact(stiffness=ground_stiffness, damping=ground_damping, friction=friction,
                                            tangential_stiffness=tangential_stiffness,
                                            tangential_damping=tangential_damping, radius=cap_radius,
                                            max_damping=ground_max_damping)
        except ValueError as e:   # name this task's argument, not GroundContact's field
            field, _, rest = str(e).partition(":")
            raise ValueError(f"{_CONTACT_ARGS.get(field, field)}:{rest}") from None
        # rod-rod contact (None: off, no rod-rod code runs); its damping capped for two rod ends (m/8)
        self.rod_contact = rods.resolve_option(g.rod_contact, rods.pair_damping_cap(s.bar_mass, dt))
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
        self.z_floor = float(self.nodes_nominal[:, 2].min())     # m: no node of a reset start below it
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
        if self.rod_contact is not None and self.integrator in ("semi_implicit_euler", "rk4"):
            check_stable_dt(model, rods.stable_step(self.rod_contact, model), self.dt, self.integrator,
                            allow_unstable_dt, "this robot's rod-rod contact")
        if self.integrator in ("semi_implicit_euler", "rk4") and self.dt > limit:
            warnings.warn(StabilityWarning(
                f"{ENV_ID}: dt = {self.dt:.4g} s is above the estimated stability limit {limit:.4g} s of "
                "semi-implicit Euler with this robot's strings and ground contact"), stacklevel=3)

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
