"""TensegrityRoll-v0: roll a tensegrity robot across flat ground by changing its cables.

One batched task (:class:`RollTask`) on B copies; :class:`TensegrityRollEnv` is it with B = 1
and :class:`TensegrityRollVectorEnv` with B = ``num_envs`` (see
:mod:`tensegrity_gym.envs.common`). Ground contact: :mod:`tensegrity_gym.contact`. SI units.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from .. import _kernels, builders, integrators
from .. import contact as gc
from .. import dynamics as dyn
from ..rewards import quadratic_cost
from ..structure import Structure
from . import _fast
from .common import (ACTION_MODES, Actuation, BatchedTask, TaskEnv, TaskVectorEnv, check_positive,
                     check_stable_dt, resolve_actuated)

__all__ = ["RollTask", "TensegrityRollEnv", "TensegrityRollVectorEnv", "robot_prism", "robot_icosahedron",
           "place_on_ground", "GRAVITY"]

ENV_ID = "TensegrityRoll-v0"
GRAVITY = (0.0, 0.0, -9.81)

# default robot (see the class docstring, "Scene")
ROD_MASS = 0.2          # kg per rod
STRING_STIFFNESS = 1000.0   # N/m
STRING_DAMPING = 2.0    # N s/m
PRISM_RADIUS = 0.15     # m
PRISM_HEIGHT = 0.25     # m
PRISM_PRESTRESS = 20.0  # N in the vertical strings
MAX_CABLE_ACCELERATION = 2.0   # m/s^2, cable motor acceleration limit (0.2 m/s reached in 0.1 s)
ICO_LENGTH = 0.4        # m
ICO_PRESTRESS = 10.0    # N in every string
SETTLE_TIME = 1.5       # s of simulated settling at construction
_SETTLED: dict = {}     # settled rest states of the built-in scenes, by parameters
MAX_PATH = 5000         # centre-of-mass points kept per env for rendering


def robot_prism(string_damping: float = STRING_DAMPING) -> Structure:
    """The default 3-bar prism robot (not yet placed on the ground): rods 0.383 m, 0.2 kg."""
    return builders.prism(3, radius=PRISM_RADIUS, height=PRISM_HEIGHT, bar_mass=ROD_MASS,
                          stiffness=STRING_STIFFNESS, prestress=PRISM_PRESTRESS, damping=string_damping,
                          gravity=GRAVITY, name="prism_robot")


def robot_icosahedron(string_damping: float = STRING_DAMPING) -> Structure:
    """The 6-bar icosahedron robot (SUPERball's shape at the 3-bar robot's rod scale): rods 0.4 m, 0.2 kg."""
    return builders.icosahedron(length=ICO_LENGTH, bar_mass=ROD_MASS, stiffness=STRING_STIFFNESS,
                                prestress=ICO_PRESTRESS, damping=string_damping, gravity=GRAVITY)


def _rot_to(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation matrix taking unit vector a to unit vector b."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        if c > 0:
            return np.eye(3)
        p = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(p) < 1e-6:
            p = np.cross(a, [0.0, 1.0, 0.0])
        p /= np.linalg.norm(p)
        return 2.0 * np.outer(p, p) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def place_on_ground(nodes: np.ndarray, masses_com: np.ndarray, radius: float, exclude_axis=None,
                    roll_axis=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, float]:
    """Rotate/translate ``nodes`` (n, 3) so that the structure rests on the face of its convex hull
    with the largest stability margin (distance from the centre of mass's projection to the face's
    nearest edge), faces normal to ``exclude_axis`` excluded (the prism lies on its side), the
    caps touching ``z = 0`` (node height ``radius``), centre of mass above the origin and
    ``exclude_axis`` (if given) turned towards ``roll_axis`` so that the prism rolls along x.
    Returns ``(nodes, margin m)``."""
    from scipy.spatial import ConvexHull
    hull = ConvexHull(nodes)
    best = None
    for simplex, eq in zip(hull.simplices, hull.equations):
        nrm = eq[:3]
        if exclude_axis is not None and abs(nrm @ exclude_axis) / np.linalg.norm(exclude_axis) > 0.9:
            continue
        R = _rot_to(nrm, np.array([0.0, 0.0, -1.0]))
        tri = ((nodes - masses_com) @ R.T)[simplex][:, :2]
        marg = np.inf
        for i in range(3):
            a, b, c = tri[i], tri[(i + 1) % 3], tri[(i + 2) % 3]
            e = b - a
            nn = np.array([e[1], -e[0]]) / np.linalg.norm(e)
            if (c - a) @ nn < 0:
                nn = -nn
            marg = min(marg, float(-a @ nn))
        if best is None or marg > best[0] + 1e-9:
            best = (marg, R)
    marg, R = best
    P = (nodes - masses_com) @ R.T
    if exclude_axis is not None:
        ax = R @ np.asarray(exclude_axis, float)
        ang = math.atan2(ax[1], ax[0])
        tgt = math.atan2(roll_axis[1], roll_axis[0])
        th = tgt - ang
        Rz = np.array([[math.cos(th), -math.sin(th), 0.0], [math.sin(th), math.cos(th), 0.0], [0.0, 0.0, 1.0]])
        P = P @ Rz.T
    P[:, 2] += radius - P[:, 2].min()
    return P, marg


def _load(structure, string_damping):
    if isinstance(structure, str) and structure in ("prism", "prism_robot"):
        s = robot_prism(STRING_DAMPING if string_damping is None else string_damping)
        axis = s.nodes[3:].mean(0) - s.nodes[:3].mean(0)
        return s, axis
    if isinstance(structure, str) and structure == "icosahedron":
        s = robot_icosahedron(STRING_DAMPING if string_damping is None else string_damping)
        return s, None
    from .. import load_structure
    s = load_structure(structure)
    if s.node_constraints or s.anchors.size:
        raise ValueError(f"structure {s.name!r}: the roll task needs a free structure (no node constraints, "
                         "no fixed anchor nodes)")
    if s.gravity is None:
        s = s.replace(gravity=GRAVITY)
    if string_damping is not None:
        s = s.replace(damping=string_damping)
    return s, None


class RollTask(BatchedTask):
    """Batched rolling task on ``num_envs`` copies (arguments: see :class:`TensegrityRollEnv`).

    State: ``q``, ``qd`` (B, k, 6); ``cstate`` (contact anchors (B, 2k, 2), flags (B, 2k));
    ``ctrl`` (B, na) rest lengths (m) or force densities (N/m) of the actuated strings;
    ``speed`` (B, na) cable speeds (m/s; rest-length mode with ``max_cable_acceleration``,
    else (B, 0));
    ``goal`` (B, 2) unit goal direction in the ground plane; ``start`` (B, 3) centre of mass at reset, m.
    """

    def __init__(self, num_envs: int = 1, structure="prism", action_mode: str = "rest_length", actuated=None,
                 integrator: str = "semi_implicit_euler", dt: float = 1e-3, frame_skip: int = 20,
                 string_damping: float | None = STRING_DAMPING,
                 forward_reward_weight: float = 1.0, ctrl_cost_weight: float = 0.01,
                 goal_direction=(1.0, 0.0), randomize_goal: bool = False, reset_noise_scale: float = 1e-3,
                 max_cable_speed: float = 0.2, max_cable_acceleration: float | None = MAX_CABLE_ACCELERATION,
                 rest_length_bounds=(0.5, 1.1),
                 force_density_max: float | None = None, force_density_rate: float | None = None,
                 friction: float = 1.0, ground_stiffness: float = 1e4, ground_damping: float = 10.0,
                 tangential_stiffness: float | None = None, tangential_damping: float = 10.0,
                 cap_radius: float = 0.02, ground_max_damping: float | None = None, backend: str = "auto",
                 divergence_limit: float | None = None, clip_actions: bool = True,
                 params: dict | None = None, randomize: dict | None = None, action_delay: int = 0,
                 start_rest_length_offset=None, observation_mode: str = "state", sensor_noise: dict | None = None,
                 history: int = 1, allow_unstable_dt: bool = False):
        if observation_mode not in ("state", "robot"):
            raise ValueError(f"observation_mode: unknown {observation_mode!r}; choose 'state' or 'robot'")
        if observation_mode == "state" and (sensor_noise or history != 1):
            raise ValueError("sensor_noise / history: only with observation_mode='robot'")
        if action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode: unknown {action_mode!r}; choose one of {ACTION_MODES}")
        if string_damping is not None:
            string_damping = check_positive(string_damping, "string_damping", "N s/m", allow_zero=True)
        s, axis = _load(structure, string_damping)
        self.action_mode = action_mode
        dt = check_positive(dt, "dt", "s")
        if ground_max_damping is None:   # keep c dt / m_eff <= 1 in fast impacts (m_eff = m/4 of the lightest rod)
            ground_max_damping = float(s.bar_mass.min()) / 4.0 / dt
        self.contact = gc.GroundContact(stiffness=ground_stiffness, damping=ground_damping, friction=friction,
                                        tangential_stiffness=tangential_stiffness,
                                        tangential_damping=tangential_damping, radius=cap_radius,
                                        max_damping=ground_max_damping,
                                        backend="numpy" if backend == "numpy" else "auto")
        self.forward_reward_weight = check_positive(forward_reward_weight, "forward_reward_weight", "s/m",
                                                    allow_zero=True)
        self.ctrl_cost_weight = check_positive(ctrl_cost_weight, "ctrl_cost_weight", allow_zero=True)
        self.reset_noise_scale = check_positive(reset_noise_scale, "reset_noise_scale", "m, m/s", allow_zero=True)
        self.max_cable_speed = check_positive(max_cable_speed, "max_cable_speed", "m/s")
        if max_cable_acceleration is not None:
            max_cable_acceleration = check_positive(max_cable_acceleration, "max_cable_acceleration", "m/s^2")
        self.max_cable_acceleration = max_cable_acceleration
        g = np.asarray(goal_direction, float).reshape(-1)
        if g.shape != (2,) or not np.all(np.isfinite(g)) or np.linalg.norm(g) == 0:
            raise ValueError(f"goal_direction: expected a non-zero finite (x, y) vector, got {goal_direction!r}")
        self.goal_direction = g / np.linalg.norm(g)
        self.randomize_goal = bool(randomize_goal)
        lo, hi = (float(x) for x in rest_length_bounds)
        if not (0 < lo <= 1 <= hi) or not math.isfinite(hi):
            raise ValueError(f"rest_length_bounds: need 0 < low <= 1 <= high (fractions of the nominal rest "
                             f"lengths), got {rest_length_bounds}")
        self.rest_length_bounds = (lo, hi)
        act = resolve_actuated(actuated, s.n_strings)
        self.actuated = act

        # place on the ground and let it settle (elastic model, all strings at their rest lengths)
        rod_com = (s.nodes[s.bars[:, 0]] * (1 - s.com_fraction)[:, None]
                   + s.nodes[s.bars[:, 1]] * s.com_fraction[:, None])
        com = s.bar_mass @ rod_com / s.bar_mass.sum()
        nodes, self.stability_margin = place_on_ground(s.nodes, com, self.contact.radius, exclude_axis=axis)
        s = s.replace(nodes=nodes)
        self.structure = s
        elastic = dyn.compile_model(s)
        integ = integrators.resolve(integrator).name
        if integ in ("semi_implicit_euler", "rk4"):   # before settling on it
            check_stable_dt(elastic, gc.stable_step(self.contact, elastic)["semi_implicit_euler"], dt, integ,
                            allow_unstable_dt, "this robot's strings and ground contact")
        key = None
        if isinstance(structure, str):   # built-in scenes: settle once per process and parameter set
            key = (structure, string_damping, self.contact, integrators.resolve(integrator).name, float(dt))
        if key is not None and key in _SETTLED:
            self.q_nominal, self.qd_nominal = (x.copy() for x in _SETTLED[key])
        else:
            self.q_nominal, self.qd_nominal = self._settle(elastic, s, integrator, dt)
            if key is not None:
                _SETTLED[key] = (self.q_nominal.copy(), self.qd_nominal.copy())
        self.nodes_nominal = dyn.node_positions(elastic, self.q_nominal)[0]
        gamma0, _, _ = dyn.force_densities(elastic, self.q_nominal, self.qd_nominal)
        self.gamma_nominal = gamma0[0]
        if np.any(self.gamma_nominal[act] <= 0):
            bad = act[self.gamma_nominal[act] <= 0][0]
            raise ValueError(f"actuated string {bad} is slack in the resting robot; actuate taut strings")
        model = dyn.compile_model(s, act if action_mode == "force_density" else None)
        self._init_physics(model, num_envs, integrator, dt, frame_skip, backend, divergence_limit, clip_actions)
        self.body_length = float(np.max(s.bar_lengths))

        l0 = s.rest_length[act]
        if action_mode == "rest_length":
            self.actuation = Actuation("rest_length", act, lo * l0, hi * l0, self.max_cable_speed,
                                       self.control_dt, s.rest_length, l0, max_accel=max_cable_acceleration)
        else:
            g0 = self.gamma_nominal[act]
            fmax = 3.0 * float(g0.max()) if force_density_max is None else check_positive(
                force_density_max, "force_density_max", "N/m")
            frate = 2.0 * fmax if force_density_rate is None else check_positive(
                force_density_rate, "force_density_rate", "N/(m s)")
            self.actuation = Actuation("force_density", act, 0.0, fmax, frate, self.control_dt, s.rest_length, g0)

        B, k, n, na = self.num_envs, model.n_bars, model.n_nodes, act.size
        # motor model (rest-length mode with an acceleration limit): cable speeds are state, observed
        self.motor = self.actuation.max_accel is not None
        self.n_speed = na if self.motor else 0
        self.n_contacts = 2 * k
        self.action_size = na
        self.observation_size = 6 * n + na + self.n_contacts + 3 + self.n_speed
        self.observation_mode = observation_mode
        self.sensors = None
        if observation_mode == "robot":
            from .sensors import RobotSensors
            self.sensors = RobotSensors(model, na, self.n_speed, 2 * k, sensor_noise, history, self.actuation.unit)
            self.observation_size = self.sensors.size
            self._readings = np.zeros((B, self.sensors.history, self.sensors.frame_size))
            self._sensor_rngs = [None] * B
            self._qd_prev = None
        self.cstate = gc.init_contact_state(model, B)
        self.ctrl = np.tile(self.actuation.nominal, (B, 1))
        self.speed = np.zeros((B, self.n_speed))
        self.goal = np.tile(self.goal_direction, (B, 1))
        self.q = np.tile(self.q_nominal, (B, 1, 1))
        self.qd = np.zeros_like(self.q)
        self.start = dyn.center_of_mass(model, self.q)
        self.record_path = False
        self.paths: dict[int, list] = {}
        # node -> (rod, signed distance from the rod's reference point) for the observation
        self._node_rod = np.empty(n, int)
        self._node_rod[model.rod_a] = np.arange(k)
        self._node_rod[model.rod_c] = np.arange(k)
        eta = np.empty(n)
        eta[model.rod_a] = model.eta[:, 0]
        eta[model.rod_c] = model.eta[:, 1]
        self._node_eta = eta[None, :, None]
        self._node_rod_i64 = np.ascontiguousarray(self._node_rod, dtype=np.int64)
        self._node_eta_1d = np.ascontiguousarray(eta, dtype=np.float64)
        self._com_at_r = bool(np.all(model.com_eta == 0.0))
        self._mass_frac = model.mass / model.mass.sum()
        self._W = np.zeros((B, n, 3))
        self._slip = np.zeros((B, self.n_contacts), bool)
        self._fast = (backend != "numpy" and _kernels.AVAILABLE
                      and self.integrator in ("semi_implicit_euler", "rk4"))
        self._contact_prm = None     # (B, 9) per-copy contact parameters once any is set (domain)
        extra = {"friction": np.array(self.contact.friction), "ground_stiffness": np.array(self.contact.stiffness),
                 "ground_damping": np.array(self.contact.damping), "max_cable_speed": self.actuation.max_rate.copy()}
        if self.motor:
            extra["max_cable_acceleration"] = np.array(self.actuation.max_accel)
        self._init_domain(params, randomize, action_delay, start_rest_length_offset, extra)
        limit = gc.stable_step(self.contact, model)["semi_implicit_euler"]
        if self.integrator in ("semi_implicit_euler", "rk4"):
            check_stable_dt(model, limit, self.dt, self.integrator, allow_unstable_dt,
                            "this robot's strings and ground contact")
        if self.integrator in ("semi_implicit_euler", "rk4") and self.dt > limit:
            warnings.warn(integrators.StabilityWarning(
                f"{ENV_ID}: dt = {self.dt:.4g} s is above the estimated stability limit {limit:.4g} s of "
                "semi-implicit Euler with this robot's strings and ground contact"), stacklevel=3)

    def _apply_task_domain(self, idx) -> None:
        """Contact, motor and mass-fraction values of copies ``idx`` (see BatchedTask._apply_domain)."""
        v, B = self.domain.values, self.num_envs
        # randomised: copies idx take their own rows; fixed: every copy takes row 0
        rows, src = (idx, idx) if self.domain.randomized else (np.arange(B), np.zeros(B, int))
        contact = {"friction": "friction", "ground_stiffness": "stiffness", "ground_damping": "damping"}
        if any(n in v for n in contact):
            if self._contact_prm is None:
                self._contact_prm = self.contact.per_copy(B)
            for name, fld in contact.items():
                if name in v:
                    gc.set_copy_values(self._contact_prm, rows, fld, v[name][src])
        if "max_cable_speed" in v or "max_cable_acceleration" in v:
            self.actuation.set_copy_limits(
                B, rows, max_rate=v["max_cable_speed"][src] if "max_cable_speed" in v else None,
                max_accel=v["max_cable_acceleration"][src] if "max_cable_acceleration" in v else None)
        if "rod_mass" in v:
            mass = np.broadcast_to(self.params.mass, (B, self.model.n_bars))
            self._mass_frac = mass / mass.sum(axis=1, keepdims=True)

    # ------------------------------------------------------------------ scene
    def _settle(self, model, s, integrator, dt):
        """Rest state under gravity on the ground: SETTLE_TIME s from the placed shape, with extra
        viscous drag on the nodes (only here) so that it comes to rest."""
        st = dyn.initial_state(model, 1)
        cs = gc.init_contact_state(model, 1)
        drag = 4.0 * float(s.bar_mass.max())  # N s/m per node
        n = int(round(SETTLE_TIME / dt))
        for _ in range(n):
            ext = -drag * dyn.node_velocities(model, st.qd)
            st, cs = gc.step(model, self.contact, st, cs, dt, integrator, external=ext)
        if not np.all(np.isfinite(st.q)):
            raise ValueError(f"structure {s.name!r}: settling on the ground diverged at dt = {dt} s; reduce dt")
        # freeze: keep the configuration, zero velocities
        return st.q.copy(), np.zeros_like(st.qd)

    # ------------------------------------------------------------------ task API
    def reset_idx(self, idx, rngs, options=None) -> dict:
        idx = np.asarray(idx, dtype=int)
        r = idx.size
        q = np.repeat(self.q_nominal, r, 0)
        qd = np.zeros_like(q)
        s = self.reset_noise_scale
        k = self.model.n_bars
        goal = np.tile(self.goal_direction, (r, 1))
        for j in range(r):
            rng = rngs[j]
            if s > 0:
                q[j, :, :3] += rng.uniform(-s, s, (k, 3))
                q[j, :, 3:] += rng.uniform(-s, s, (k, 3)) / self.model.length[:, None]
                qd[j, :, :3] = rng.uniform(-s, s, (k, 3))
                qd[j, :, 3:] = rng.uniform(-s, s, (k, 3)) / self.model.length[:, None]
            if self.randomize_goal:
                th = rng.uniform(0.0, 2.0 * np.pi)
                goal[j] = (math.cos(th), math.sin(th))
        q, qd = dyn.project(self.model, q, qd)
        # no node below the ground plus cap: lift the copy if the noise pushed one in
        zmin = dyn.node_positions(self.model, q)[..., 2].min(axis=1)
        lift = np.maximum(self.nodes_nominal[:, 2].min() - zmin, 0.0)
        q[..., 2] += lift[:, None]
        self.q[idx], self.qd[idx] = q, qd
        self.cstate.anchor[idx] = 0.0
        self.cstate.active[idx] = False
        self.ctrl[idx] = self.start_control
        self.speed[idx] = 0.0
        self.goal[idx] = goal
        self.elapsed[idx] = 0
        com = dyn.center_of_mass(self.model, q, None if self.params is None else self.params.take(
            idx if self.params.batch_size > 1 else np.zeros(len(idx), int)))
        self.start[idx] = com
        if self.sensors is not None:
            for j, i in enumerate(idx):
                self._sensor_rngs[i] = rngs[j]
            frame = self.sensors.frame(q, qd, None, self.dt, self._gravity(idx), self.ctrl[idx], self.speed[idx],
                                       self.cstate.active[idx], goal, rngs)
            self._readings[idx] = frame[:, None, :]
        if self.record_path:
            for j, i in enumerate(idx):
                self.paths[int(i)] = [com[j].copy()]
        return {"com_position": com, "com_velocity": np.zeros((r, 3)), "distance_rolled": np.zeros(r),
                "goal_direction": goal.copy()}

    def simulate_contact(self, inputs: dict) -> np.ndarray:
        """One control step of physics for the whole batch: ``frame_skip`` times (batched contact
        forces from the state at the step's start -> ONE integrator call with ``external=W`` for
        all B copies). The integrator call is ``integrators.step``; with the numba backend and an
        explicit method it is the same compiled kernel called in place
        (``_kernels.step_inplace``: no State objects, no allocation). Divergence handling as
        :meth:`BatchedTask.simulate` (state and contact state of a diverged copy put back).
        Returns ``diverged`` (B,) bool."""
        q, qd, cs = self.q, self.qd, self.cstate
        q0, qd0, anchor0, active0 = q.copy(), qd.copy(), cs.anchor.copy(), cs.active.copy()
        W, slip, dt, model, contact, name = self._W, self._slip, self.dt, self.model, self.contact, self.integrator
        forces, step_inplace = gc.forces_inplace, _kernels.step_inplace
        params, prm = self.params, self._contact_prm
        inputs = self.with_offset(inputs)
        with np.errstate(all="ignore"):
            for sub in range(self.frame_skip):
                if self.sensors is not None and sub == self.frame_skip - 1:
                    self._qd_prev = qd.copy()     # the IMUs read the last physics step's acceleration
                forces(contact, model, q, qd, cs, W, slip, prm)
                if self._fast:
                    step_inplace(model, q, qd, dt, name, external=W, params=params, **inputs)
                else:
                    st = integrators.step(self.model, dyn.State(q, qd, 0.0), dt, self.integrator, external=W,
                                          backend=self.backend, params=params, **inputs)
                    q[...] = st.q
                    qd[...] = st.qd
            # the robot travels: "far" is measured from its own centre (and its height from the
            # start's), so rolling any distance is never taken for a blow-up
            if _fast.AVAILABLE and q.dtype == np.float64 and qd.dtype == np.float64:
                ok = _fast.state_ok_local(q, qd, self.center0[2], self.divergence_limit)   # one compiled pass
                diverged = np.zeros(self.num_envs, bool) if ok else self._far_or_nonfinite(q, qd)
            else:
                diverged = self._far_or_nonfinite(q, qd)
        if diverged.any():
            q[diverged], qd[diverged] = q0[diverged], qd0[diverged]
            cs.anchor[diverged], cs.active[diverged] = anchor0[diverged], active0[diverged]
            if self.sensors is not None:
                self._qd_prev[diverged] = qd[diverged]
        self.elapsed += 1
        return diverged

    def _far_or_nonfinite(self, q, qd) -> np.ndarray:
        """(B,) bool: a non-finite entry in ``q``/``qd``, a rod reference point farther than
        ``divergence_limit`` (per coordinate) from its copy's mean reference point, or that mean
        farther than ``divergence_limit`` above or below the start's centre (NumPy reference of
        ``_fast.state_ok_local``)."""
        finite = np.isfinite(q).all(axis=(1, 2)) & np.isfinite(qd).all(axis=(1, 2))
        r = np.where(np.isfinite(q[..., :3]), q[..., :3], 0.0)
        m = r.mean(axis=1, keepdims=True)
        lim = self.divergence_limit
        far = ~((np.abs(r - m).max(axis=(1, 2)) <= lim) & (np.abs(m[:, 0, 2] - self.center0[2]) <= lim))
        return ~finite | far

    def step(self, action):
        if self.motor:
            self.ctrl, self.speed, inputs = self.actuation.advance_motor(self.ctrl, self.speed, action)
        else:
            self.ctrl, inputs = self.actuation.advance(self.ctrl, action)
        com0 = self._com(self.q)
        diverged = self.simulate_contact(inputs)
        com = self._com(self.q)
        vel = (com - com0) / self.control_dt
        forward = np.einsum("bi,bi->b", vel[:, :2], self.goal)
        terms = {"forward": self.forward_reward_weight * forward,
                 "ctrl": -self.ctrl_cost_weight * quadratic_cost(action)}
        dist = np.einsum("bi,bi->b", (com - self.start)[:, :2], self.goal)
        if self.record_path:   # centre-of-mass path for render(), last MAX_PATH points per env
            for i in range(self.num_envs):
                p = self.paths.setdefault(i, [])
                p.append(com[i].copy())
                if len(p) > MAX_PATH:
                    del p[: len(p) - MAX_PATH]
        infos = {"com_position": com, "com_velocity": vel, "distance_rolled": dist, "forward_velocity": forward,
                 "diverged": diverged}
        if self.sensors is not None:
            frame = self.sensors.frame(self.q, self.qd, self._qd_prev, self.dt, self._gravity(slice(None)), self.ctrl,
                                       self.speed, self.cstate.active, self.goal, self._sensor_rngs)
            R = self._readings
            R[:, 1:] = R[:, :-1].copy()
            R[:, 0] = frame
        return terms, np.zeros(self.num_envs, bool), infos

    def _gravity(self, idx) -> np.ndarray:
        """(r, 3) or (3,) gravity of copies ``idx``, m/s^2 (the robot's own with ``params``)."""
        if self.params is not None:
            g = self.params.gravity
            return g[idx] if g.shape[0] > 1 else g[0]
        return np.zeros(3) if self.model.gravity is None else np.asarray(self.model.gravity, float)

    def _com(self, q) -> np.ndarray:
        """(B, 3) centre of mass, m (= dynamics.center_of_mass, one matrix product)."""
        if self._com_at_r:
            if self._mass_frac.ndim == 2:     # per-copy rod masses
                return np.einsum("bk,bki->bi", self._mass_frac, q[..., :3])
            return np.einsum("k,bki->bi", self._mass_frac, q[..., :3])
        return dyn.center_of_mass(self.model, q, self.params)

    def observe(self) -> np.ndarray:
        B = self.num_envs
        if self.sensors is not None:
            return self._readings.reshape(B, -1).astype(np.float32)
        q, qd = self.q, self.qd
        if _fast.AVAILABLE:   # one compiled pass, bit-identical to the NumPy below
            com = self._com(q)
            arrs = (q, qd, com, self.ctrl, self.goal, self.speed)
            if all(type(x) is np.ndarray and x.dtype == np.float64 for x in arrs) and \
                    type(self.cstate.active) is np.ndarray and self.cstate.active.dtype == np.bool_:
                obs = np.empty((B, self.observation_size), np.float32)
                _fast.roll_observe(q, qd, self._node_rod_i64, self._node_eta_1d, com, self.ctrl,
                                   self.cstate.active, self.goal, self.speed, obs)
                return obs
        e = self._node_eta
        # node positions / velocities (= dynamics.node_positions / node_velocities of a free structure)
        N = q[:, self._node_rod, :3] + e * q[:, self._node_rod, 3:]
        V = qd[:, self._node_rod, :3] + e * qd[:, self._node_rod, 3:]
        com = self._com(q)
        obs = np.empty((B, self.observation_size), np.float32)
        n3 = N.shape[1] * 3
        obs[:, :n3] = (N - com[:, None, :]).reshape(B, -1)
        obs[:, n3:2 * n3] = V.reshape(B, -1)
        i = 2 * n3
        na = self.ctrl.shape[1]
        obs[:, i:i + na] = self.ctrl
        i += na
        obs[:, i:i + self.n_contacts] = self.cstate.active
        i += self.n_contacts
        obs[:, i:i + 2] = self.goal
        obs[:, i + 2] = com[:, 2]
        i += 3
        if self.n_speed:
            obs[:, i:i + self.n_speed] = self.speed
        return obs

    def observation_layout(self) -> list[tuple[str, slice, str]]:
        """(name, slice, unit) of each block of the observation vector (robot mode: of the newest
        reading; the ``history - 1`` older readings follow it in the same layout)."""
        if self.sensors is not None:
            return self.sensors.layout()
        n, na = self.model.n_nodes, self.actuated.size
        blocks = [("node_position_rel_com", 3 * n, "m"), ("node_velocity", 3 * n, "m/s"),
                  ("control", na, self.actuation.unit), ("contact", self.n_contacts, "1"),
                  ("goal_direction", 2, "1"), ("com_height", 1, "m")]
        if self.n_speed:
            blocks.append(("cable_speed", self.n_speed, "m/s"))
        out, i = [], 0
        for name, sz, unit in blocks:
            out.append((name, slice(i, i + sz), unit))
            i += sz
        return out

    def render_data(self, i: int) -> dict:
        q, qd = self.q[i:i + 1], self.qd[i:i + 1]
        inputs = self.actuation.physics_inputs(self.ctrl[i:i + 1])
        gamma, _, L = dyn.force_densities(self.model, q, qd, inputs.get("rest_length"), inputs.get("force_density"))
        com = dyn.center_of_mass(self.model, q)[0]
        path = np.array(self.paths.get(i, [com]))
        goal = com + 0.5 * np.array([self.goal[i, 0], self.goal[i, 1], 0.0])
        goal[2] = self.contact.height
        dist = float((com - self.start[i])[:2] @ self.goal[i])
        return {"nodes": dyn.node_positions(self.model, q)[0], "rods": self.structure.bars,
                "strings": self.structure.strings, "tensions": (gamma * L)[0], "ground_z": self.contact.height,
                "path": path, "goal": goal,
                "caption": f"t = {self.elapsed[i] * self.control_dt:.2f} s, rolled {dist:.2f} m"}


_DOC = r"""
    Rolling locomotion of a tensegrity robot on flat ground (``TensegrityRoll-v0``).

    ## Description
    A free class-1 tensegrity robot (default: a 3-bar prism lying on its side; ``structure=
    "icosahedron"``: the 6-bar SUPERball shape) rests on the ground under gravity (-9.81 m/s^2
    along z). The policy changes the rest lengths (``action_mode="rest_length"``, motor-driven
    cables with a maximum cable speed and rest-length limits) or the force densities
    (``action_mode="force_density"``) of its strings and must roll the robot's centre of mass
    along the goal direction (+x by default). Dynamics: the exact configuration-matrix equations
    of Skelton & de Oliveira ch. 5 (rigid rods, tension-only damped strings), with ground
    contact at the rods' end caps (compliant Hunt-Crossley normal force, Coulomb friction with a
    stick phase; :mod:`tensegrity_gym.contact`, ``docs/contact.md``). Semi-implicit Euler at
    ``dt`` = 1 ms, ``frame_skip`` = 20 (50 Hz control); contact forces are computed once per
    physics step for the whole batch and held over it.

    ## Scene (default robot)
    | quantity | prism (default) | icosahedron |
    |----------|-----------------|-------------|
    | rods | 3 x 0.383 m, 0.2 kg each | 6 x 0.40 m, 0.2 kg each |
    | strings | 9 (3 bottom, 3 top, 3 vertical), 1000 N/m, 2 N s/m | 24, 1000 N/m, 2 N s/m |
    | prestress | 20 N in the vertical strings | 10 N in every string |
    | shape | radius 0.15 m, height 0.25 m, twist 30 deg | rod pairs 0.2 m apart |
    | end caps | radius 0.02 m, friction 1.0 | same |
    | ground | k = 1e4 N/m, Hunt-Crossley d = 10 s/m; k_t = 1e4 N/m, c_t = 10 N s/m | same |

    Why: rods of ~0.35-0.4 m and ~0.2 kg are the scale of the 3-bar prism robots built in labs
    (a few hundred grams per actuated rod); 1000 N/m strings (an elastic cord or a spring in
    series with each cable, as most such robots use) keep the robot stiff under its own weight
    (it sags by 1.8 mm (prism) and 8 mm (icosahedron) when it settles on the ground) while the highest string frequency (~250 rad/s) and the contact frequency
    (~450 rad/s for k = 1e4 N/m on a rod end of effective mass m/4) allow explicit steps of a few
    ms: the estimated limit of semi-implicit Euler with contact and damping is 2.6 ms
    (:func:`tensegrity_gym.contact.stable_step`; measured: stable at 2 ms, unstable at 3 ms), so
    the default 1 ms has a margin of 2-2.5x.
    Caps of 2 cm radius with friction 1 model rubber feet. The prism lies on a side face (the
    face of its convex hull with the largest stability margin, not top or bottom) with its axis
    along y, so rolling over its side faces moves it along x. The icosahedron rests on its most
    stable face.

    ## Action space
    ``Box(-1, 1, (na,), float32)``, one entry per actuated string (``actuated``, default all
    strings, in the structure's string order). Out-of-box entries are clipped (``clip_actions=
    False``: ``ValueError``); a NaN or inf entry raises ``ValueError`` naming its index.

    | mode | action a_i in [-1, 1] does | bounds |
    |------|---------------------------|--------|
    | ``rest_length`` | commands the cable speed v_cmd,i = a_i * ``max_cable_speed`` (0.2 m/s); the motor's speed v_i follows it at most ``max_cable_acceleration`` (2 m/s^2) fast; l0_i += v_i * dt_c (m) | ``rest_length_bounds`` x nominal (0.5 to 1.1) |
    | ``force_density`` | force density g_i += a_i * ``force_density_rate`` * dt_c (N/m) | [0, ``force_density_max``] (3 x the largest nominal) |

    with dt_c = ``dt * frame_skip`` = 0.02 s. The control is held over the control step.

    Cable motor model (``rest_length`` mode). Each control step, per actuated cable::

        v_cmd = a * max_cable_speed                                       # m/s
        v    <- v + clip(v_cmd - v, -max_cable_acceleration * dt_c, +max_cable_acceleration * dt_c)
        l0   <- clip(l0 + v * dt_c, low, high)
        v    <- 0 where l0 is on a bound and v pushes beyond it            # end stop

    and ``v = 0`` at reset. The cable speed v is state and is observed (block
    ``cable_speed``). Why 2 m/s^2: the robots this env models (NTRT's and the Rutgers /
    Berkeley 3-bar prisms) wind their cables on spools driven by small geared DC motors, which
    reach full cable speed in about 0.1 s (motor time constant plus the spool's and gearbox's
    inertia, current-limited drivers); 0.2 m/s in 0.1 s is 2 m/s^2, i.e. the cable speed can
    reverse fully (-0.2 to +0.2 m/s) in 0.2 s, 10 control steps. Without such a limit a policy
    can flip every cable between full speed in and out at every control step (25 Hz bang-bang)
    and shuffle the robot forward by vibration instead of rolling it, which no real motor
    could do. ``max_cable_acceleration=None`` removes the limit: the rest-length rate is then
    a_i * ``max_cable_speed`` at once (the behaviour before this motor model; no
    ``cable_speed`` block). ``force_density`` mode ignores the argument.

    ## Observation space
    ``Box(-inf, inf, (6 n + na + 2 k + 3 + ns,), float32)`` with ns = na (the cable speeds) in
    ``rest_length`` mode with the motor model (the default) and ns = 0 otherwise (prism: n = 6
    nodes, k = 3 rods, na = 9: size 63, or 54 with ``max_cable_acceleration=None`` or in
    ``force_density`` mode; icosahedron: n = 12, k = 6, na = 24: size 135, or 111):

    | index | observation | unit |
    |-------|-------------|------|
    | 0 .. 3n-1 | node positions relative to the centre of mass (x, y, z per node) | m |
    | 3n .. 6n-1 | node velocities | m/s |
    | 6n .. 6n+na-1 | control of each actuated string: rest length or force density | m or N/m |
    | 6n+na .. 6n+na+2k-1 | contact flag of each end cap (rod 0 end a, rod 0 end c, ...) | 0/1 |
    | next 2 | goal direction (unit vector in the ground plane) | 1 |
    | next 1 | height of the centre of mass | m |
    | last ns | cable speed v_i of each actuated string (motor model only; positive: lengthening) | m/s |

    The absolute x, y position is not observed (as Ant/Hopper exclude it by default).
    ``env.unwrapped.task.observation_layout()`` lists the blocks.

    ## Rewards
    ``reward = reward_forward + reward_ctrl``:

    * ``reward_forward = forward_reward_weight * (c_xy(t + dt_c) - c_xy(t)) . goal / dt_c``:
      the centre of mass's velocity along the goal direction, m/s (weight 1);
    * ``reward_ctrl = -ctrl_cost_weight * sum_i a_i^2`` (weight 0.01).

    Each term is in ``info`` as ``reward_<name>``; their sum is the reward exactly.

    ## Info
    ``com_position`` (3,) m, ``com_velocity`` (3,) m/s (mean over the control step),
    ``forward_velocity`` m/s, ``distance_rolled`` (displacement of the centre of mass along the
    goal since reset, m), ``diverged``, the ``reward_*`` terms; at reset also ``goal_direction``.

    ## Starting state
    The robot at rest on the ground: placed on its face and settled under gravity for 1.5 s at
    construction (nominal rest lengths). Each reset adds uniform noise of +-``reset_noise_scale``
    (default 1 mm) to the rods' centres (m), of +-``reset_noise_scale``/l to their unit vectors,
    and the same (m/s) to their velocities; the copy is lifted if a cap went further into the
    ground than at rest. All contacts start released (anchors are set at the first contact).
    Goal: ``goal_direction`` (default +x), or, with ``randomize_goal=True``, a uniform random
    direction in the ground plane. All randomness comes from ``np_random``.

    ## Episode end
    No termination (a tensegrity cannot fall over). Truncation: by the time limit at
    registration (``max_episode_steps`` = 1000 control steps = 20 s), and at once with
    ``info["diverged"] = True`` if the state becomes non-finite, a rod moves more than
    ``divergence_limit`` from the robot's centre (the structure blew apart) or that centre more
    than ``divergence_limit`` up or down from the start; the state is then put back to the last
    finite one, so observations stay finite. Horizontal travel is not limited.

    ## Arguments
    ``gymnasium.make("TensegrityRoll-v0", **kwargs)``:

    | argument | default | meaning |
    |----------|---------|---------|
    | ``structure`` | ``"prism"`` | ``"prism"``, ``"icosahedron"``, or any free ``Structure``/builder name/JSON path (gravity added if missing) |
    | ``action_mode`` | ``"rest_length"`` | or ``"force_density"`` |
    | ``actuated`` | ``None`` (all) | string indices or boolean mask |
    | ``integrator`` | ``"semi_implicit_euler"`` | (``"rk4"`` holds contact forces over each step: first order in contact) |
    | ``dt``, ``frame_skip`` | ``1e-3``, ``20`` | physics step (s), steps per control step |
    | ``allow_unstable_dt`` | ``False`` | a ``dt`` above the estimated stability limit (strings + contact) raises ValueError unless True (then it warns) |
    | ``string_damping`` | ``2.0`` | N s/m on every string (``None``: the structure's) |
    | ``forward_reward_weight``, ``ctrl_cost_weight`` | ``1.0``, ``0.01`` | reward weights |
    | ``goal_direction``, ``randomize_goal`` | ``(1, 0)``, ``False`` | goal in the ground plane |
    | ``reset_noise_scale`` | ``1e-3`` | m, m/s |
    | ``max_cable_speed`` | ``0.2`` | m/s (rest-length mode) |
    | ``max_cable_acceleration`` | ``2.0`` | m/s^2, cable motor acceleration limit (rest-length mode; ``None``: none, the speed follows the action at once) |
    | ``rest_length_bounds`` | ``(0.5, 1.1)`` | fractions of the nominal rest lengths |
    | ``force_density_max``, ``force_density_rate`` | ``None`` | N/m, N/(m s) (force-density mode) |
    | ``friction`` | ``1.0`` | Coulomb coefficient of the caps |
    | ``ground_stiffness``, ``ground_damping`` | ``1e4``, ``10`` | N/m, s/m (Hunt-Crossley) |
    | ``tangential_stiffness``, ``tangential_damping`` | ``None`` (= ground_stiffness), ``10`` | N/m, N s/m (stick spring) |
    | ``cap_radius`` | ``0.02`` | m |
    | ``ground_max_damping`` | ``None`` (= m/(4 dt), 50 N s/m) | N s/m, cap on the Hunt-Crossley damping coefficient (explicit stability in fast impacts) |
    | ``backend`` | ``"auto"`` | ``"numpy"`` / ``"numba"`` |
    | ``divergence_limit`` | ``None`` | m (default 100 x the robot's size) |
    | ``clip_actions`` | ``True`` | clip out-of-box actions (``False``: raise) |
    | ``params`` | ``None`` | fix robot parameters by name, absolute SI values (``rod_mass``, ``stiffness``, ``damping``, ``node_damping``, ``gravity``, ``rest_length_offset``, ``friction``, ``ground_stiffness``, ``ground_damping``, ``max_cable_speed``, ``max_cable_acceleration``; a number or one per rod/string/node/cable): see :mod:`tensegrity_gym.envs.domain` |
    | ``randomize`` | ``None`` | ``{name: spread}`` drawn per copy at every reset (relative U(1 - s, 1 + s) x nominal; ``rest_length_offset`` absolute U(-s, s) m); ``info["params"]`` at reset reports the values |
    | ``action_delay`` | ``0`` | control steps between an action and its effect (zeros at the start of an episode) |
    | ``start_rest_length_offset`` | ``None`` | m added to the actuated cables' rest lengths at reset (a slack start; must stay within the bounds) |
    | ``observation_mode`` | ``"state"`` | ``"robot"``: what a lab robot senses (cable lengths, motor encoders and speeds, rod IMUs, contact switches, goal; :mod:`tensegrity_gym.envs.sensors`) |
    | ``sensor_noise`` | ``None`` | robot mode: ``{block: sigma}`` Gaussian noise, SI units (``cable_length``, ``control``, ``cable_speed``, ``imu_accel``, ``imu_gyro``) |
    | ``history`` | ``1`` | robot mode: readings stacked, newest first |
    | ``render_mode``, ``width``, ``height`` | ``None``, 480, 480 | ``"rgb_array"`` or ``"human"`` |

    ``render()`` draws the rods, the strings coloured by tension, the ground, the path of the
    centre of mass (orange) and a star 0.5 m ahead of it along the goal.

    ## Baseline
    :class:`tensegrity_gym.baselines.RollingGait` (no learning): a periodic contraction wave of
    rest lengths around the prism's axis (period 1.71 s, open loop in time) that rolls the prism
    face over face, steered by one fed-back scalar (the top/bottom rest-length bias, from the
    heading of the observed centre-of-mass velocity). ``python scripts/eval_roll_baseline.py``
    (100 s on flat ground, 8 reset seeds, default env; ``results/roll_baseline.json``): goal +x
    0.196 m/s along the goal (min 0.191) = 0.51 body lengths/s (body length = rod length
    0.383 m), 0.250 m/s = 0.65 body lengths/s after the first 20 s; random goals 0.232 m/s. From
    the reset pose the wave rolls the prism toward -x first and the feedback turns it round in
    its first 15-20 s, so in one registered 20 s episode it gains little (about 0 m). It
    rolls: +18.9 net turns about the axis across the goal in 100 s
    (``scripts/gait_stats.py gait --steps 5000``). The same wave without the feedback
    (``steer=0``, purely open loop) rolls as fast over the ground (0.244 m/s) but in circles:
    -0.085 m/s along +x.

    ## Version history
    * v0: initial version.
    * v0 (0.2): ``params``, ``randomize``, ``action_delay``, ``start_rest_length_offset``, ``observation_mode="robot"``, ``sensor_noise``, ``history``; defaults unchanged (bit-identical).
    * v0 (motor model): rest-length mode got a cable acceleration limit
      (``max_cable_acceleration``, default 2 m/s^2; the cable speed is now state, reset to 0,
      stopped at the rest-length bounds) and the cable speeds were appended to the observation
      (block ``cable_speed``; prism 54 -> 63 entries). This changes the default dynamics and
      observation of rest-length mode (the id was kept): policies trained before it need
      ``max_cable_acceleration=None``, which reproduces the old env exactly.
      ``force_density`` mode is unchanged.
"""


class TensegrityRollEnv(TaskEnv):
    __doc__ = _DOC

    def __init__(self, render_mode: str | None = None, width: int = 480, height: int = 480, **kwargs):
        task = RollTask(num_envs=1, **kwargs)
        self._init_task(task, render_mode, width, height, title=ENV_ID)
        task.record_path = render_mode is not None


class TensegrityRollVectorEnv(TaskVectorEnv):
    __doc__ = _DOC + r"""
    ## Vector env
    ``gymnasium.make_vec("TensegrityRoll-v0", num_envs=N, vectorization_mode="vector_entry_point")``
    or ``TensegrityRollVectorEnv(num_envs=N, **kwargs)``: the same task on N copies, stepped with
    one batched contact update and one batched ``integrators.step`` call per physics step.
    Next-step autoreset; ``reset(seed=s)`` seeds env i with s + i (equal to N single envs with
    those seeds); ``max_episode_steps`` truncates every env (``make_vec`` passes the registered
    1000). See :class:`tensegrity_gym.envs.common.TaskVectorEnv`.
"""

    def __init__(self, num_envs: int = 1, max_episode_steps="registered", render_mode: str | None = None,
                 width: int = 480, height: int = 480, **kwargs):
        task = RollTask(num_envs=num_envs, **kwargs)
        self._init_task(task, ENV_ID, max_episode_steps, render_mode, width, height, title=ENV_ID)
        task.record_path = render_mode is not None
