"""TensegrityRollMuJoCo-v0, TensegrityNavigateMuJoCo-v0: TensegrityRoll-v0 and TensegrityNavigate-v0 simulated by MuJoCo.

Sim-to-sim twins (the navigation twin: the section "Navigation" below).

The same robot, action space, observation space and layout, rewards, info keys and control
step as :class:`tensegrity_gym.envs.roll.TensegrityRollEnv`, but the motion comes from MuJoCo
(an independent simulator, its own contact, friction and integrator), so a policy trained on
this project's physics runs on it unchanged. SI units (m, kg, s, N).

What is shared (not copied): the env builds a one-copy :class:`~tensegrity_gym.envs.roll.RollTask`
with the same keyword arguments and takes from it the robot placed on the ground and settled
(the settled node positions become the MuJoCo model's pose), its nominal rest lengths, its
:class:`~tensegrity_gym.physics.actuation.Actuation` (the cable motor model: speed
command, acceleration limit, rest-length bounds, end stops), its reset (the same reset noise
and goal drawn from ``np_random`` in the same order), its observation (``RollTask.observe``,
fed with the MuJoCo state converted to rod coordinates ``[r, b]``, ``[r', b']``) and, with
``observation_mode="robot"``, its sensor model (:mod:`tensegrity_gym.envs.sensors`: cable
lengths from the rod state, IMUs from the change of MuJoCo's rod velocities over the last
physics step, contact switches from MuJoCo's contacts).

The MuJoCo model is :func:`tensegrity_gym.io.mjcf.to_mjcf` of the settled robot with ``ground=True``:
rods are free bodies with capsules of radius ``cap_radius`` (the capsule's lowest point on a
plane is always at an end, so the capsule-plane contact is the end caps' contact), strings are
spatial tendons with the dead band ``springlength="0 l0"`` (no spring force while slack). The
actuated cables' rest lengths are written to ``model.tendon_lengthspring[i, 1]`` once per
control step (the control is held over the control step, as in ``TensegrityRoll-v0``; no
MuJoCo actuators are used).

Modelling differences from the project's physics (``docs/contact.md``, ``EQUATIONS.md``)
-----------------------------------------------------------------------------------------
* **Contact.** MuJoCo's soft-constraint contact (``solref``/``solimp``, solved by its convex
  optimiser) instead of the compliant Hunt-Crossley normal force with a stick spring. The
  softness is chosen to resemble the ground stiffness: ``solref = (timeconst, dampratio)`` with
  ``timeconst = sqrt(m_eff / ground_stiffness)``, m_eff = a quarter of the lightest rod mass
  (the effective mass of a rod end, as ``contact.stable_step`` uses), i.e. the contact's natural
  frequency is the project's ``sqrt(k / m_eff)`` (2.24 ms, 447 rad/s for the default 1e4 N/m and 0.2 kg), floored at
  2 x the step (MuJoCo's own safety limit); ``dampratio = contact_dampratio`` (default 1,
  critical: Hunt-Crossley damping k d delta grows with the penetration delta; at the resting
  penetration of the default robot, 0.1-0.24 mm, it is about half of critical, so no single
  value matches); ``solimp`` MuJoCo's
  default. ``ground_damping``, ``tangential_stiffness``/``tangential_damping`` and
  ``ground_max_damping`` have no counterpart and are ignored.
* **Friction.** Coulomb, coefficient ``friction`` on both the caps and the ground (MuJoCo takes
  the larger of the two geoms' values), elliptic friction cone (isotropic like ours), condim 3
  (no torsional or rolling friction). MuJoCo's static friction is also soft (a slowly creeping
  stick), ours is a stick spring.
* **Damping on slack strings.** MuJoCo's tendon damping ``-c L'`` acts at every length, slack
  or taut, and the total tendon force may push; ours acts only while the string is taut and the
  total force is clipped at 0. The spring part has the same dead band in both.
* **Integrator.** MuJoCo's ``implicitfast`` (default; ``mj_integrator``: "Euler", "RK4",
  "implicit") at the project's ``dt`` (1 ms), instead of the project's semi-implicit Euler
  with contact forces held over each step. The contact switches are MuJoCo's active contacts.
* **Rod spin.** Our rods have no rotation about their own axis and the contact force acts at
  the node (on the axis); MuJoCo's rods are 6-DOF bodies and the contact acts at the capsule's
  surface, ``cap_radius`` off the axis, so friction exerts an axial torque. Left free, the rods
  of the resting robot spin (up to ~1 rad/s with ``to_mjcf``'s axial inertia ``m r^2 / 2``) and
  roll on their caps like wheels, so the resting robot creeps by mm per s. The twin therefore
  damps each rod's spin about its own axis (``spin_damping``, default 1 N m s, on the free
  joint's axial rotation, integrated implicitly): spin rates at rest stay near 2e-3 rad/s and
  the rods behave as ours (no axial rotation). ``spin_damping=0`` gives MuJoCo's free spin.
  MuJoCo's ``RK4`` integrates joint damping explicitly, stable only for ``spin_damping * dt / I``
  up to about 2.785 (I the rods' axial inertia, 4e-5 kg m^2 on the default prism): with
  ``mj_integrator="RK4"`` the default is half that bound (0.056 N m s on the default prism at
  1 ms; its spin at rest is larger than with 1 N m s), a larger value is refused, and the
  settling's drag on the spin is held to the same value.
* **Start pose.** MuJoCo's contact rests at another depth than ours (caps 0.007 mm into the
  ground against our 0.1-0.24 mm), so the robot is
  settled again on MuJoCo's ground at construction (SETTLE_TIME s with viscous drag on the
  rods, as RollTask settles it) and resets add the reset noise to that pose. The contact flags
  in the reset observation are MuJoCo's contacts (ours start released: all 0).

Terrain: ``terrain=``
---------------------
As ``TensegrityRoll-v0`` takes it (a terrain file, a dict, a ``Terrain`` or a generator,
:mod:`tensegrity_gym.tasks.terrain`; ``None`` or ``{}``: the floor plane, unchanged). The twin's
:class:`RollTask` resolves and draws it (a generator: per episode from ``np_random``, the same
terrain for a reset seed as ``TensegrityRoll-v0``). The robot settles on the floor plane as above;
then the MuJoCo scene is the robot on the terrain's geoms (:func:`tensegrity_gym.io.mjcf.terrain_xml`:
tilted plane, boxes, heightfield) instead of the floor, and resets start from the task's reset
state, which lifts the robot clear of the terrain (``tasks.terrain.start_lift``). A drawn terrain
is written into the ``MjModel`` in place at each reset (same parts and grid shape, new numbers:
:mod:`tensegrity_gym.envs.twin_terrain`). The contact flags are MuJoCo's contacts of the rod
capsules with any terrain geom. Friction is each terrain part's own (the rods' geoms have friction
0, and MuJoCo takes the larger of two geoms' values; a randomised ``friction`` sets every geom);
the contact softness (``solref``) is the same on every part, from ``ground_stiffness``: a part's
own ``stiffness`` / ``damping`` is not mapped. MuJoCo's heightfield is triangulated where ours is
bilinear (within a few mm on gentle bumps) and ends at its grid, where ours holds the edge values:
a heightfield without a plane (the navigation courses, the ``"rough"`` generator) gets a level
floor 1 mm under its lowest point in the scene (:func:`~tensegrity_gym.envs.twin_terrain.floor_height`).

Navigation (``TensegrityNavigateMuJoCo-v0``) and climbing (``TensegrityClimbMuJoCo-v0``): this
twin on those tasks, :mod:`tensegrity_gym.envs.navigate_mujoco` and :mod:`tensegrity_gym.envs.climb_mujoco`.

Robot parameters: ``params=`` and ``randomize=``
-------------------------------------------------
As ``TensegrityRoll-v0`` (:mod:`tensegrity_gym.envs.domain`): the twin's :class:`RollTask` holds
the :class:`~tensegrity_gym.envs.domain.Domain`, so the values are drawn at every reset from the
env's ``np_random`` by the same code, in the same order, as ``TensegrityRoll-v0`` draws them (the
same seed gives the same robot on both), and ``info["params"]`` at reset reports them. How each
value reaches the ``MjModel`` (and why ``node_damping`` cannot): :mod:`tensegrity_gym.envs.twin_params`.

Not supported (ValueError): ``action_mode="force_density"``, ``node_damping`` in ``params`` /
``randomize``, ``action_delay``, ``start_rest_length_offset`` and divergence limits (a non-finite
state or a MuJoCo bad-acceleration warning truncates the episode with ``info["diverged"] = True``).
Registered as ``TensegrityRollMuJoCo-v0`` with ``max_episode_steps`` = 1000 (20 s), as
``TensegrityRoll-v0``. ``render_mode="rgb_array"`` draws MuJoCo's state with the project's
renderer (as ``TensegrityRoll-v0`` does; ``mujoco.Renderer`` would need ``MUJOCO_GL`` set before
``mujoco`` is imported, which :mod:`tensegrity_gym.tools.rendering` does not need).
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..physics.geometry import node_positions, node_velocities
from ..io.mjcf import check_mj_integrator, initial_qpos_qvel, to_mjcf
from ..tasks.roll import roll_step_terms
from ..core.checks import check_frame_size
from . import twin_model
from .pickling import picklable_state, restore_state
from .twin_divergence import clear_mujoco_warnings, twin_diverged
from .common import check_action, check_positive
from .config import RollConfig, flatten, with_flat
from .roll import MAX_PATH, SETTLE_TIME, RollTask
from .twin_params import TwinParams, check_twin_kwargs, contact_timeconst
from .twin_terrain import copy_terrain, floor_height

__all__ = ["TensegrityRollMuJoCoEnv", "ENV_ID"]

ENV_ID = "TensegrityRollMuJoCo-v0"
_UNSUPPORTED = ("start_rest_length_offset",)


class TensegrityRollMuJoCoEnv(gym.Env):
    """MuJoCo twin of ``TensegrityRoll-v0`` (see the module docstring).

    Arguments: those of ``TensegrityRoll-v0`` (passed to its :class:`RollTask`; rest-length mode
    only; ``params`` / ``randomize`` as the module doc maps them onto the MjModel; ``terrain`` as the
    module doc's "Terrain"), plus ``mj_integrator`` ("implicitfast"), ``contact_dampratio`` (1.0, the damping ratio
    of MuJoCo's contact ``solref``), ``spin_damping`` (None: 1.0 N m s, with ``RK4`` the largest it
    integrates stably (:meth:`rk4_spin_damping_max`); damping of each rod's spin about its own
    axis, see the module doc), ``render_mode`` (None or "rgb_array"), ``width``, ``height``.
    ``env.unwrapped.task`` is the :class:`RollTask` (so :class:`tensegrity_gym.tools.baselines.RollingGait`
    and ``observation_layout()`` work as on ``TensegrityRoll-v0``); ``env.unwrapped.model`` /
    ``data`` are the MuJoCo ``MjModel`` / ``MjData``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}
    env_id = ENV_ID
    task_class = RollTask   # where ``**kwargs`` go (the arguments agents' CLIs check)
    config_class = RollConfig   # the task's grouped arguments (``config=``)

    def __init__(self, render_mode: str | None = None, width: int = 480, height: int = 480,
                 mj_integrator: str = "implicitfast", contact_dampratio: float = 1.0,
                 spin_damping: float | None = None, **kwargs):
        try:
            import mujoco
        except ImportError:
            raise ImportError(f"{self.env_id} needs MuJoCo: pip install 'tensegrity_gym[mujoco]'") from None
        self._mj = mujoco
        env_id = self.env_id
        # the task's arguments, flat (a grouped config= and flat keywords alike), checked below
        kwargs = flatten(with_flat(kwargs.pop("config", None), kwargs, f"{self.task_class.__name__}.__init__",
                                   self.config_class))
        for name in _UNSUPPORTED:
            if kwargs.get(name) is not None:
                raise ValueError(f"{name}: not supported by {env_id}")
        check_twin_kwargs(kwargs, env_id)
        if kwargs.get("rod_contact") not in (None, False):
            raise ValueError(f"rod_contact: not supported by {env_id} (its rods collide with the ground only), "
                             f"got {kwargs['rod_contact']!r:.80}")
        if kwargs.get("action_delay", 0):
            raise ValueError(f"action_delay: not supported by {env_id}, got {kwargs['action_delay']!r}")
        if kwargs.get("action_mode", "rest_length") != "rest_length":
            raise ValueError(f"action_mode: {env_id} supports 'rest_length' only, got {kwargs['action_mode']!r}")
        check_mj_integrator(mj_integrator, "mj_integrator")
        if spin_damping is not None:
            check_positive(spin_damping, "spin_damping", "N m s", allow_zero=True)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode: unknown {render_mode!r}; choose 'rgb_array' or None")
        self.contact_dampratio = check_positive(contact_dampratio, "contact_dampratio")
        self.task = task = self.task_class(num_envs=1, **kwargs)
        c, s = task.contact, task.structure.replace(nodes=task.nodes_nominal)
        self._mjcf = dict(timestep=task.dt, integrator=mj_integrator, rod_radius=c.radius,
                          model_name="tensegrity_roll_twin")
        self.contact_timeconst = contact_timeconst(float(s.bar_mass.min()), c.stiffness, task.dt)
        # the robot settles on a floor plane (as RollTask settles it on level ground); on a terrain,
        # the terrain's scene then replaces the floor's (the same bodies, joints and tendons)
        self.model = m = self._compile(to_mjcf(s, ground=True, ground_height=c.height, friction=c.friction,
                                               **self._mjcf))
        self.data = mujoco.MjData(m)
        m.geom_friction[:, 0] = c.friction
        k = s.n_bars
        self._body = np.array([m.body(f"rod{j}").id for j in range(k)])
        self._dof = m.jnt_dofadr[m.body_jntadr[self._body]]
        self.spin_damping = twin_model.spin_damping_for(spin_damping, mj_integrator, self.rk4_spin_damping_max(),
                                                        task.dt)
        self._settle()
        if task.terrains is not None:
            self.model = m = self._compile(self._terrain_xml(task.terrains[0]))
            self.data = mujoco.MjData(m)
            # rods frictionless: MuJoCo takes the larger friction of two geoms, so each terrain part's own governs
            m.geom_friction[[m.geom(f"rod{j}").id for j in range(k)], 0] = 0.0
            m.dof_damping[self._dof + 5] = self.spin_damping
        self._rod_of_geom = np.full(m.ngeom, -1)
        self._rod_of_geom[[m.geom(f"rod{j}").id for j in range(k)]] = np.arange(k)
        self._params = TwinParams(m, self._body, c, task.dt, self.contact_dampratio, env_id, any(
            isinstance(kwargs.get(a), dict) and "ground_damping" in kwargs[a] for a in ("params", "randomize")))
        self._rest_offset = np.zeros(m.ntendon)   # rest_length_offset of this episode, m
        self._eta = task.model.eta                          # (k, 2) node offsets from the reference point, m
        self._act = task.actuated
        self.action_space = spaces.Box(-1.0, 1.0, (task.action_size,), np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, (task.observation_size,), np.float32)
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / task.control_dt)))
        self.render_mode, self._size, self._renderer = render_mode, check_frame_size(width, height)[::-1], None
        task.record_path = render_mode is not None
        self.start = np.zeros(3)
        self._needs_reset = True

    def _compile(self, xml: str):
        """The ``MjModel`` of ``xml`` with the twin's contact
        (:func:`~tensegrity_gym.envs.twin_model.compile_scene`)."""
        return twin_model.compile_scene(self._mj, xml, self.contact_timeconst, self.contact_dampratio)

    def _terrain_xml(self, terrain) -> str:
        """MJCF of the settled robot on ``terrain`` (its geoms: :func:`tensegrity_gym.io.mjcf.terrain_xml`;
        a floor under a heightfield without a plane: :func:`~tensegrity_gym.envs.twin_terrain.floor_height`)."""
        t = self.task
        return to_mjcf(t.structure.replace(nodes=t.nodes_nominal), terrain=terrain, floor_height=floor_height(terrain),
                       **self._mjcf)

    def rk4_spin_damping_max(self) -> float:
        """The largest ``spin_damping`` (N m s) the twin takes with MuJoCo's ``RK4``
        (:func:`~tensegrity_gym.envs.twin_model.rk4_spin_damping_max`)."""
        return twin_model.rk4_spin_damping_max(self.model, self._body, self.task.dt)

    def _settle(self) -> None:
        """Let the robot settle on MuJoCo's ground (:func:`~tensegrity_gym.envs.twin_model.settle`: SETTLE_TIME s
        with viscous drag on the rods, as RollTask settles it on its own ground) and make that the task's
        nominal start pose, so that resets start at MuJoCo's rest (its contact rests at another depth than ours)."""
        t = self.task
        qpos = initial_qpos_qvel(t.structure.replace(nodes=t.nodes_nominal))[0]
        twin_model.settle(self._mj, self.model, self.data, qpos, float(t.structure.bar_mass.max()), self._dof,
                          self.spin_damping, SETTLE_TIME, t.dt)
        q, _ = self.rod_state()
        if not np.all(np.isfinite(q)):
            raise ValueError(f"{self.env_id}: settling on MuJoCo's ground diverged at dt = {t.dt} s; reduce dt")
        t.q_nominal = q.copy()
        t.nodes_nominal = node_positions(t.model, q)[0]

    @property
    def dt(self) -> float:
        """Control step, s (``dt * frame_skip``, as ``TensegrityRoll-v0``)."""
        return self.task.control_dt

    # ------------------------------------------------------------------ state conversion
    def rod_state(self) -> tuple[np.ndarray, np.ndarray]:
        """MuJoCo's state as the project's rod coordinates ``q``, ``qd`` (1, k, 6)
        (:func:`~tensegrity_gym.envs.twin_model.rod_state`)."""
        return twin_model.rod_state(self.data, self._body, self._dof)

    def contact_flags(self) -> np.ndarray:
        """(2k,) bool: end cap touching the ground in MuJoCo's current contacts
        (:func:`~tensegrity_gym.envs.twin_model.contact_flags`)."""
        return twin_model.contact_flags(self.data, self.task.q[0], self._rod_of_geom, self._eta)

    def _sync(self) -> None:
        """Project MuJoCo's current state into the task (q, qd, contact flags) for its observation."""
        self._mj.mj_forward(self.model, self.data)
        t = self.task
        t.q, t.qd = self.rod_state()
        t.cstate.active[0] = self.contact_flags()

    def com(self) -> np.ndarray:
        """(3,) centre of mass of the robot, m (MuJoCo's, after :meth:`_sync`)."""
        return self.data.subtree_com[0].copy()

    def tendon_tension(self) -> np.ndarray:
        """(m,) force each tendon applies as MuJoCo computes it, N (positive: pulling; dead band
        while slack, damping at any length: :func:`~tensegrity_gym.envs.twin_model.tendon_tension`)."""
        return twin_model.tendon_tension(self.model, self.data)

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        mj, m, d, t = self._mj, self.model, self.data, self.task
        info = t.reset(np.array([0]), [self.np_random], options)   # same params, noise, goal, controls as TensegrityRoll-v0
        if t.terrain_generator is not None:   # this episode's terrain (same parts and grid shape, new numbers)
            copy_terrain(m, mj.MjModel.from_xml_string(self._terrain_xml(t.terrains[0])))
        if t.domain.enabled:   # this episode's robot into the MjModel (envs/twin_params.py)
            self._rest_offset, self.contact_timeconst = self._params.apply(
                mj, m, d, {name: x[0] for name, x in t.domain.values.items()})
        N = node_positions(t.model, t.q)[0]
        V = node_velocities(t.model, t.qd)[0]
        mj.mj_resetData(m, d)
        d.qpos[:], d.qvel[:] = initial_qpos_qvel(t.structure.replace(nodes=N, velocities=V))
        m.tendon_lengthspring[self._act, 1] = t.ctrl[0] + self._rest_offset[self._act]
        self._sync()
        self.start = self.com()
        t.start[0] = self.start
        extra = self._reset_task_state(info)
        if t.sensors is not None:   # the reset reading from MuJoCo's state (contacts included)
            t.sensors.reset_reading(t, np.array([0]), [self.np_random], t.goal, t.speed, t.cstate.active)
        self._needs_reset = False
        out = {"com_position": self.start.copy(), "com_velocity": np.zeros(3), "distance_rolled": 0.0,
               "goal_direction": t.goal[0].copy()}
        if "params" in info:
            out["params"] = {n: x[0] for n, x in info["params"].items()}
        out.update(extra)
        return t.observe()[0], out

    def _reset_task_state(self, info: dict) -> dict:
        """The task's own state after a reset, from MuJoCo's state (synced into the task); its
        reset info beyond the rolling task's (here none). ``info``: the task's reset info."""
        return {}

    def _step_task_terms(self, info: dict) -> tuple[dict, bool, dict]:
        """After a step, the task's own reward terms (name -> value), termination and info, from MuJoCo's
        state (synced into the task) and this step's rolling ``info``; none: the rolling task never ends."""
        return {}, False, {}

    def step(self, action):
        if self._needs_reset:
            raise RuntimeError(f"{self.env_id}: call reset() before step()")
        mj, m, d, t = self._mj, self.model, self.data, self.task
        a = check_action(action, (t.action_size,), clip=t.clip_actions)[None, :].astype(np.float64)
        t.ctrl, t.speed, _ = t.actuation.update(t.ctrl, a, t.speed)
        m.tendon_lengthspring[self._act, 1] = t.ctrl[0] + self._rest_offset[self._act]
        com0 = self.com()
        qpos0, qvel0 = d.qpos.copy(), d.qvel.copy()
        clear_mujoco_warnings(mj, d)
        for sub in range(t.frame_skip):
            if sub == t.frame_skip - 1 and t.sensors is not None:
                mj.mj_kinematics(m, d)
                t._qd_prev = self.rod_state()[1]   # the IMUs read the last physics step's change of velocity
            mj.mj_step(m, d)
        with np.errstate(all="ignore"):
            self._sync()
        diverged = twin_diverged(mj, d, t)
        if diverged:
            d.qpos[:], d.qvel[:] = qpos0, qvel0
            self._sync()
        t.elapsed += 1
        com = self.com()
        terms, step_info = roll_step_terms(com0[None], com[None], self.start[None], t.goal, a, t.control_dt,
                                           t.forward_reward_weight, t.ctrl_cost_weight)
        r_fwd, r_ctrl = float(terms["forward"][0]), float(terms["ctrl"][0])
        if t.sensors is not None:
            if diverged:
                t._qd_prev = t.qd
            t.sensors.record(t, t.goal, t.speed, t.cstate.active)
        if t.record_path:   # centre-of-mass path for render(), the last MAX_PATH points
            path = t.paths.setdefault(0, [])
            path.append(com.copy())
            del path[:-MAX_PATH]
        info = {"com_position": com, "com_velocity": step_info["com_velocity"][0],
                "distance_rolled": float(step_info["distance_rolled"][0]),
                "forward_velocity": float(step_info["forward_velocity"][0]), "diverged": bool(diverged),
                "reward_forward": r_fwd, "reward_ctrl": r_ctrl}
        reward = r_fwd + r_ctrl
        terms, terminated, extra = self._step_task_terms(info)
        for name, v in terms.items():
            reward += v
            info[f"reward_{name}"] = v
        info.update(extra)
        return t.observe()[0], reward, bool(terminated), bool(diverged), info

    def render(self):
        """RGB frame (H, W, 3) uint8 of MuJoCo's current state, drawn by the project's renderer
        (:func:`tensegrity_gym.tools.rendering.make_renderer`, as ``TensegrityRoll-v0``: rods, strings
        coloured by the project's tension model at this state, path of the centre of mass, goal)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; construct the env with render_mode='rgb_array'")
            return None
        if self._renderer is None:
            from ..tools.rendering import make_renderer
            self._renderer = make_renderer(self._size[1], self._size[0], title=self.env_id)
        return self._renderer.render(**self.task.render_data(0))

    def __getstate__(self):   # the mujoco module by name, no renderer (MjModel / MjData pickle)
        return picklable_state(self.__dict__)

    def __setstate__(self, state):
        restore_state(self, state)

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
