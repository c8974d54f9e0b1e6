"""TensegrityShape-v0: drive an anchored tensegrity to a commanded (reachable) shape.

One batched task (:class:`ShapeTask`) on B copies; :class:`TensegrityShapeEnv` is it with
B = 1 and :class:`TensegrityShapeVectorEnv` with B = ``num_envs`` (see
:mod:`tensegrity_gym.envs.common`). SI units throughout.
"""
from __future__ import annotations

import numpy as np

from ..core.model import compile_model
from ..physics.evaluate import force_densities, project
from ..physics.geometry import node_positions, node_velocities
from ..physics import statics
from ..physics.stability import stability_limit
from ..physics.actuation import Actuation
from ..core.checks import check_flag
from ..tasks.shape import node_errors, shape_state_observation, shape_step_terms
from ..tasks.state import StateField
from ..tasks.xp import NUMPY
from . import compiled
from .base import BatchedTask, fixed_step
from .config import (DEFAULT_SHAPE_NODE_DAMPING, DEFAULT_SHAPE_STRING_DAMPING, ShapeConfig, flat_signature,
                     shape_config, with_flat)
from .docs import SHAPE_DOC as _DOC
from .shape_fused import FusedShapeStep
from .sensors import RobotSensors
from .shells import TaskEnv, TaskVectorEnv
from .limits import check_domain_rest_lengths, check_domain_stable_dt
from .validate import (ACTION_MODES, check_positive, check_rest_length_bounds, check_stable_dt, load_env_structure,
                       resolve_actuated)

__all__ = ["ShapeTask", "TensegrityShapeEnv", "TensegrityShapeVectorEnv", "DEFAULT_STRING_DAMPING",
           "DEFAULT_NODE_DAMPING"]

ENV_ID = "TensegrityShape-v0"
DEFAULT_STRING_DAMPING = DEFAULT_SHAPE_STRING_DAMPING   # N s/m per string
DEFAULT_NODE_DAMPING = DEFAULT_SHAPE_NODE_DAMPING       # N s/m per rod node (viscous drag / joint friction)
MAX_TARGET_TRIES = 50


class ShapeTask(FusedShapeStep, BatchedTask):
    """Batched shape-tracking task on ``num_envs`` copies (arguments: see :class:`TensegrityShapeEnv`).

    State: ``q``, ``qd`` (B, k, 6); ``ctrl`` (B, na) current rest lengths (m) or force densities
    (N/m) of the actuated strings; ``target`` (B, nt, 3) target positions of the tracked nodes, m
    (its record, :mod:`tensegrity_gym.tasks.state`).
    """

    STATE = (StateField("q"), StateField("qd"), StateField("ctrl"), StateField("target"))
    NO_DEVICE_RESET = ("its targets are stable static equilibria found by Newton's method with rejection, "
                       "statics.solve_equilibria, on the host")

    def __init__(self, num_envs: int = 1, config: ShapeConfig | None = None, **kwargs):
        self.config = c = with_flat(config, kwargs, "ShapeTask.__init__", ShapeConfig)
        structure, string_damping, node_damping = c.robot.structure, c.robot.string_damping, c.robot.node_damping
        integrator, dt, frame_skip = c.simulation.integrator, c.simulation.dt, c.simulation.frame_skip
        backend, divergence_limit = c.simulation.backend, c.simulation.divergence_limit
        allow_unstable_dt = c.simulation.allow_unstable_dt
        a = c.actuation
        action_mode, actuated, rest_length_bounds, max_speed = a.action_mode, a.actuated, a.rest_length_bounds, a.max_speed
        force_density_max, force_density_rate, clip_actions = a.force_density_max, a.force_density_rate, a.clip_actions
        action_delay, start_rest_length_offset = a.action_delay, a.start_rest_length_offset
        r = c.reward
        tracking_weight, proximity_weight, ctrl_cost_weight = r.tracking_weight, r.proximity_weight, r.ctrl_cost_weight
        success_tolerance, target_range = r.success_tolerance, c.target.target_range
        observation_mode, sensor_noise, history = (c.observation.observation_mode, c.observation.sensor_noise,
                                                   c.observation.history)
        reset_noise_scale, params, randomize = (c.randomization.reset_noise_scale, c.randomization.params,
                                                c.randomization.randomize)
        allow_unstable_dt = check_flag(allow_unstable_dt, "allow_unstable_dt")
        s = load_env_structure(structure)
        if not s.node_constraints and s.anchors.size == 0:
            raise ValueError(f"structure {s.name!r}: the shape task needs an anchored structure (node_constraints "
                             "or fixed anchor nodes); a free structure has no unique shape under gravity")
        if string_damping is not None:
            s = s.replace(damping=check_positive(string_damping, "string_damping", "N s/m", allow_zero=True))
        if action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode: unknown {action_mode!r}; choose one of {ACTION_MODES}")
        self.action_mode = action_mode
        self.structure = s
        act = resolve_actuated(actuated, s.n_strings)
        self.actuated = act
        self.node_damping = check_positive(node_damping, "node_damping", "N s/m", allow_zero=True)
        self.tracking_weight = check_positive(tracking_weight, "tracking_weight", "1/m", allow_zero=True)
        self.proximity_weight = check_positive(proximity_weight, "proximity_weight", allow_zero=True)
        self.ctrl_cost_weight = check_positive(ctrl_cost_weight, "ctrl_cost_weight", allow_zero=True)
        self.reset_noise_scale = check_positive(reset_noise_scale, "reset_noise_scale", "m", allow_zero=True)
        self.target_range = check_positive(target_range, "target_range", allow_zero=True)
        if self.target_range >= 1:
            raise ValueError(f"target_range: relative rest-length change must be < 1, got {target_range}")
        self.rest_length_bounds = lo, hi = check_rest_length_bounds(rest_length_bounds)
        self.max_speed = check_positive(max_speed, "max_speed", "m/s")

        # the elastic model (targets) and the nominal equilibrium (start shape)
        self.elastic_model = compile_model(s)
        integ = fixed_step(integrator)     # the integrator's name, decoded once
        # before the equilibrium solve, whose relaxation would fail with a misleading message
        check_stable_dt(self.elastic_model, stability_limit(self.elastic_model).get(integ, float("inf")),
                        check_positive(dt, "dt", "s"), integ, allow_unstable_dt, "this structure")
        try:
            eq = statics.equilibrium(self.elastic_model, relax_steps=20000)
        except statics.EquilibriumError as e:
            raise ValueError(f"structure {s.name!r}: its nominal rest lengths give no stable equilibrium: {e}") from None
        self.q_nominal = eq.q[None]
        self.nodes_nominal = eq.nodes
        self.gamma_nominal = eq.force_density
        if np.any(eq.force_density[act] <= 0):
            bad = act[eq.force_density[act] <= 0][0]
            raise ValueError(f"actuated string {bad} is slack at the nominal equilibrium; actuate taut strings")
        # node drag is part of the model (core.model.compile_model(node_damping=...)): one fused
        # integrator call per control step, no drag code at all when node_damping == 0
        model = compile_model(s, act if action_mode == "force_density" else None,
                                  node_damping=self.node_damping if self.node_damping > 0 else None)
        self.height = s.height if s.height > 0 else float(np.ptp(eq.nodes, axis=0).max())
        self.success_tolerance = (0.01 * self.height if success_tolerance is None
                                  else check_positive(success_tolerance, "success_tolerance", "m"))
        self._init_physics(model, num_envs, integ, dt, frame_skip, backend, divergence_limit, clip_actions)
        check_stable_dt(model, stability_limit(model).get(self.integrator, float("inf")), self.dt,
                        self.integrator, allow_unstable_dt, "this structure with its node drag")

        # actuation
        l0 = s.rest_length[act]
        self.rest_low, self.rest_high = lo * l0, hi * l0
        self.actuation = Actuation.for_task(action_mode, act, s.rest_length, (lo, hi), self.max_speed,
                                            self.control_dt, self.gamma_nominal, force_density_max,
                                            force_density_rate)
        self.force_density_max = float(self.actuation.high.max()) if action_mode == "force_density" else None

        # tracked nodes: every rod node that can move (not pinned)
        pinned = {nd for nd, D in s.node_constraints.items() if D.shape[0] == 3}
        self.tracked = np.array(sorted(set(s.bars.ravel().tolist()) - pinned), dtype=int)
        nt, na = self.tracked.size, act.size
        self.action_size = na
        self.observation_size = 4 * 3 * nt + na
        B = self.num_envs
        self.rc = statics.ReducedCoordinates(model)
        self.ctrl = np.tile(self.actuation.nominal, (B, 1))
        self.target = np.tile(eq.nodes[self.tracked], (B, 1, 1))
        self.target_control = np.tile(self.actuation.nominal, (B, 1))
        self.q = np.tile(self.q_nominal, (B, 1, 1))
        self.qd = np.zeros_like(self.q)
        self._last_action = np.zeros((B, na))
        self._N = None     # tracked node positions cached from step() for observe()
        self._obs = None   # observation cached from step() (compiled path) for observe()
        self._obs_of = None
        # robot observation (envs/sensors.py; None in state mode): NumPy observe and step paths;
        # else the compiled observation (envs/compiled.py; None where it does not apply)
        self.sensors = RobotSensors.attach(self, observation_mode, sensor_noise, history, ("target_position", 3 * nt, "m"))
        self._obs_rod, self._obs_eta = compiled.node_sources(model, self.tracked)
        if self.sensors is not None:
            self._obs_rod = None
        self._init_domain(params, randomize, action_delay, start_rest_length_offset)
        check_domain_rest_lengths(self)
        check_domain_stable_dt(self, allow_unstable_dt, lambda m, c: stability_limit(m)[self.integrator])

    # ------------------------------------------------------------------ targets
    def _sample_rest_lengths(self, rng: np.random.Generator) -> np.ndarray:
        l0 = self.structure.rest_length[self.actuated]
        x = l0 * (1.0 + rng.uniform(-self.target_range, self.target_range, self.actuated.size))
        return np.clip(x, self.rest_low, self.rest_high)

    def sample_targets(self, rngs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Targets for ``len(rngs)`` copies: (r, nt, 3) node positions (m), (r, na) the actuated
        strings' rest lengths (m) and (r, na) force densities (N/m) that hold them.

        Rest lengths of the actuated strings are drawn uniformly within ``target_range`` of the
        structure's (and within the rest-length bounds); the stable equilibrium reached from the
        nominal shape (Newton from it, :func:`tensegrity_gym.physics.statics.solve_equilibria`) is the
        target. A draw is rejected and redrawn (same generator) unless the equilibrium is found,
        stable, has every actuated string taut and (force-density mode) needs force densities
        within the bounds. (Under *constant* force densities the target is an exact equilibrium
        but, with no elastic stiffness in the actuated strings, not necessarily a stable one.)"""
        r = len(rngs)
        act = self.actuated
        na = act.size
        out_t = np.zeros((r, self.tracked.size, 3))
        out_l = np.zeros((r, na))
        out_g = np.zeros((r, na))
        pending = np.arange(r)
        tries = 0
        while pending.size:
            tries += 1
            if tries > MAX_TARGET_TRIES:
                raise RuntimeError(f"{ENV_ID}: no admissible target after {MAX_TARGET_TRIES} draws; reduce "
                                   f"target_range ({self.target_range}) or widen the bounds")
            rl = np.tile(self.structure.rest_length, (pending.size, 1))
            rl[:, act] = np.stack([self._sample_rest_lengths(rngs[i]) for i in pending])
            res = statics.solve_equilibria(self.elastic_model, np.repeat(self.q_nominal, pending.size, 0), rl,
                                           max_iter=15)
            ok = (res["status"] == statics.OK) & np.all(res["force_density"][:, act] > 0, axis=1)
            gam = res["force_density"][:, act]
            if self.action_mode == "force_density":
                ok &= np.all(gam <= self.actuation.high, axis=1)
            done = pending[ok]
            out_t[done] = res["nodes"][ok][:, self.tracked]
            out_l[done] = rl[ok][:, act]
            out_g[done] = gam[ok]
            pending = pending[~ok]
        return out_t, out_l, out_g

    # ------------------------------------------------------------------ task API
    def reset_idx(self, idx, rngs, options=None) -> dict:
        idx = np.asarray(idx, dtype=int)
        r = idx.size
        tgt, l_t, g_t = self.sample_targets(rngs)
        self.target[idx] = tgt
        self.target_control[idx] = l_t if self.action_mode == "rest_length" else g_t
        # start: nominal equilibrium with small noise on the reduced coordinates (m, m/s)
        q0 = np.repeat(self.q_nominal, r, 0)
        nx, s = self.rc.nx, self.reset_noise_scale
        dx, dv = np.zeros((r, nx)), np.zeros((r, nx))      # (r may be 0: a reset_mask that selects no env)
        if s > 0:
            for j in range(r):
                dx[j] = rngs[j].uniform(-s, s, nx)
            for j in range(r):
                dv[j] = rngs[j].uniform(-s, s, nx)
        q, qd = project(self.model, *self.rc.perturb(q0, dx, dv))
        self.q[idx], self.qd[idx] = q, qd
        self.ctrl[idx] = self.start_control
        self._last_action[idx] = 0.0
        self.elapsed[idx] = 0
        self._N = None
        self._obs = None
        if self.sensors is not None:
            self.sensors.reset_reading(self, idx, rngs, self.target[idx].reshape(r, 3 * self.tracked.size))
        err, emax = self._errors(idx)
        return {"tracking_error": err, "max_node_error": emax, "is_success": emax <= self.success_tolerance}

    def _errors(self, idx=None):
        q = self.q if idx is None else self.q[idx]
        tgt = self.target if idx is None else self.target[idx]
        return NUMPY.mean_max(node_errors(node_positions(self.model, q)[:, self.tracked], tgt))

    def simulate_controls(self):
        """One control step of physics for the batch at the current controls: ONE batched
        ``physics.step`` call of ``frame_skip`` steps (the node drag is in the model)."""
        return self.simulate(**self.actuation.physics_inputs(self.ctrl))

    def _compiled_observe(self):
        """(obs (B, size) float32, node errors d (B, nt)) in one compiled call, or None when the
        compiled helpers do not apply (anchored tracked node, robot observation, foreign array types).
        Bit-identical to the NumPy path of :meth:`observe` and :meth:`step`."""
        if self._obs_rod is None:
            return None
        q, qd, ctrl, tgt = self.q, self.qd, self.ctrl, self.target
        for x in (q, qd, ctrl, tgt):
            if type(x) is not np.ndarray or x.dtype != np.float64:
                return None
        B = q.shape[0]
        obs = np.empty((B, self.observation_size), np.float32)
        d = np.empty((B, self._obs_rod.size))
        compiled.shape_observe(q, qd, self._obs_rod, self._obs_eta, ctrl, tgt, obs, d)
        return obs, d

    def step(self, action):
        if self.sensors is not None:    # robot observation: the IMUs need the last physics step (envs/sensors.py)
            self._last_action = action
            out = self._finish_step(action, self.simulate(action))
            self.sensors.record(self, self.target.reshape(self.num_envs, -1))
            return out
        fz = self.__dict__.get("_fused")
        if fz is None:
            fz = self._fused_setup()
        if fz:
            out = self._fused_step(fz, action)
            if out is not None:
                return out
        self._last_action = action
        diverged = self.simulate(action)
        return self._finish_step(action, diverged)

    def _finish_step(self, action, diverged):
        """Observation, errors, reward terms and infos of :meth:`step` after the physics."""
        fast = self._compiled_observe()
        if fast is not None:
            self._obs, d = fast
            self._obs_of = (self.q, self.qd, self.ctrl, self.target)
            self._N = None
        else:
            self._N = node_positions(self.model, self.q)[:, self.tracked]
            self._N_of = self.q
            d = node_errors(self._N, self.target)
        err, emax = np.empty(d.shape[0]), np.empty(d.shape[0])
        if fast is None or not compiled.mean_max(d, err, emax):
            err, emax = NUMPY.mean_max(d)
        terms, infos = shape_step_terms(err, emax, np.asarray(action, float), self.success_tolerance,
                                        self.tracking_weight, self.proximity_weight, self.ctrl_cost_weight)
        infos["diverged"] = diverged
        return terms, np.zeros(self.num_envs, bool), infos

    def observe(self) -> np.ndarray:
        if self.sensors is not None:
            return self.sensors.observation(self)
        obs, self._obs = self._obs, None
        if obs is not None:
            of = self._obs_of
            if of[0] is self.q and of[1] is self.qd and of[2] is self.ctrl and of[3] is self.target:
                return obs
        fast = self._compiled_observe()
        if fast is not None:
            return fast[0]
        cached = self._N is not None and self._N_of is self.q
        N = self._N if cached else node_positions(self.model, self.q)[:, self.tracked]
        self._N = None
        V = node_velocities(self.model, self.qd)[:, self.tracked]
        return shape_state_observation(N, V, self.ctrl, self.target).astype(np.float32)

    def render_data(self, i: int) -> dict:
        q, qd = self.q[i:i + 1], self.qd[i:i + 1]
        inputs = self.actuation.physics_inputs(self.ctrl[i:i + 1])
        gamma, _, L = force_densities(self.model, q, qd, inputs.get("rest_length"), inputs.get("force_density"))
        _, emax = self._errors(np.array([i]))
        return {"nodes": node_positions(self.model, q)[0], "rods": self.structure.bars,
                "strings": self.structure.strings, "tensions": (gamma * L)[0], "targets": self.target[i],
                "caption": f"t = {self.elapsed[i] * self.control_dt:.2f} s, max error {emax[0] * 1e3:.1f} mm"}

    # ------------------------------------------------------------------ layout
    def observation_layout(self) -> list[tuple[str, slice, str]]:
        """(name, slice, unit) of each block of the observation vector (robot mode: of the newest
        reading; the ``history - 1`` older readings follow it in the same layout)."""
        if self.sensors is not None:
            return self.sensors.layout()
        nt, na = 3 * self.tracked.size, self.actuated.size
        u = self.actuation.unit
        blocks = [("node_position", nt, "m"), ("node_velocity", nt, "m/s"), ("control", na, u),
                  ("target_position", nt, "m"), ("target_error", nt, "m")]
        out, i = [], 0
        for name, n, unit in blocks:
            out.append((name, slice(i, i + n), unit))
            i += n
        return out


#: the flat arguments (introspection: agents.envs.env_argument_names, the shells' manuals)
ShapeTask.__signature__ = flat_signature(shape_config(), ShapeConfig)

TensegrityShapeEnv = TaskEnv.for_task(ShapeTask, ENV_ID, _DOC, __name__)
TensegrityShapeVectorEnv = TaskVectorEnv.for_task(ShapeTask, ENV_ID, _DOC + r"""
    ## Vector env
    ``gymnasium.make_vec("TensegrityShape-v0", num_envs=N, vectorization_mode="vector_entry_point")``
    or ``TensegrityShapeVectorEnv(num_envs=N, **kwargs)``: the same task on N copies stepped in
    one batched physics call. Next-step autoreset; ``reset(seed=s)`` seeds env i with s + i
    (equal to N single envs with those seeds); ``max_episode_steps`` truncates every env
    (``make_vec`` passes the registered 200; constructed directly, ``"registered"`` looks it up;
    ``None`` disables it). See :class:`tensegrity_gym.envs.common.TaskVectorEnv`.
""", __name__)
