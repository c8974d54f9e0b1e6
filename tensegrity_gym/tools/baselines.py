"""Non-learning controllers with the SB3 ``predict`` interface (SI units).

Each controller is a policy object: ``predict(obs, state=None, episode_start=None,
deterministic=True) -> (action, state)`` for one observation (obs_dim,) or a batch (B, obs_dim),
exactly like a Stable-Baselines3 model, so evaluation code can take either.

* :class:`NNLSShapeController` -- for ``TensegrityShape-v0`` (both action modes).

(The rolling gait for ``TensegrityRoll-v0`` is added here as a separate class.)
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from ..physics.geometry import string_state
from ..core.model import initial_state
from ..physics import statics

__all__ = ["NNLSShapeController", "nnls_force_densities", "RollingGait", "wave_targets"]


def _task_of(env):
    """The batched task behind an env / vector env / wrapper of this package, or the task itself."""
    if hasattr(env, "observation_layout") and hasattr(env, "actuation"):     # a task
        return env
    for attr in ("task",):
        if hasattr(env, attr):
            return getattr(env, attr)
    un = getattr(env, "unwrapped", None)
    if un is not None and hasattr(un, "task"):
        return un.task
    raise TypeError(f"expected a tensegrity_gym env, vector env or task, got {type(env).__name__}")


def nnls_force_densities(A: np.ndarray, b: np.ndarray, gamma_ref: np.ndarray | None = None,
                         regularization: float = 1e-6) -> tuple[np.ndarray, float]:
    """Force densities ``gamma >= 0`` (N/m) minimising ``|A gamma - b|^2 + mu |gamma - gamma_ref|^2``
    with ``mu = regularization * |A|_F^2 / m`` (a tiny pull toward ``gamma_ref`` that picks a
    solution where ``A`` is rank-deficient, e.g. at a self-stressed shape). Solved as one NNLS
    problem (scipy's Lawson-Hanson). Returns ``(gamma, residual_norm of A gamma - b)``.
    A: (r, m) generalized forces per unit force density (m); b: (r,) N."""
    r, m = A.shape
    mu = regularization * float(np.sum(A * A)) / max(m, 1)
    if mu > 0:
        ref = np.zeros(m) if gamma_ref is None else np.asarray(gamma_ref, float)
        M = np.vstack([A, np.sqrt(mu) * np.eye(m)])
        rhs = np.concatenate([b, np.sqrt(mu) * ref])
    else:
        M, rhs = A, b
    g, _ = nnls(M, rhs, maxiter=50 * m)
    return g, float(np.linalg.norm(A @ g - b))


class NNLSShapeController:
    """Model-based shape controller for ``TensegrityShape-v0`` (no learning).

    The generalized forces of a class-1 tensegrity are linear in the string force densities
    (Skelton & de Oliveira ch. 5): at the target shape ``R = A(q*) gamma + w(q*)`` with ``w``
    the gravity load (:func:`tensegrity_gym.physics.statics.equilibrium_matrix`). The controller

    1. solves the NNLS problem ``min |A_act g + (A_pass gamma_pass + w)|, g >= 0`` for the
       actuated strings' force densities ``g*`` that make the target an equilibrium (the
       passive strings keep their elastic force densities at the target);
    2. ``rest_length`` mode: commands the rest lengths ``l0 = L*(1 - g*/k)`` (``L*`` the target
       string lengths) -- the elastic structure then settles on the target by itself;
       ``force_density`` mode: adds PD feedback (the actuated strings have no stiffness of
       their own): at the *current* shape it solves the NNLS problem for the generalized force
       of nodal forces ``kp (target - x) - kd v`` (N) plus gravity compensation, pulled
       toward ``g*``;
    3. turns the desired control into an action: ``(desired - current) / (max rate * dt_c)``
       clipped to [-1, 1] (the env's rate limit).

    Parameters
    ----------
    env : the env (``gymnasium.make`` result), the vector env or the task: gives the action
        scaling, the structure, the actuated and tracked strings/nodes.
    kp : N/m, kd : N s/m -- feedback gains (force-density mode; also used in rest-length mode
        if ``feedback=True``, through the string force densities).
    regularization : relative Tikhonov weight of the feedforward NNLS toward the nominal force
        densities (see :func:`nnls_force_densities`; tiny: only picks a solution where A is singular).
    feedback_regularization : relative weight of the feedback NNLS toward the feedforward ``g*``
        (keeps unrealizable components of the PD force from swinging the force densities).
    feedback : use the PD feedback (default: in force-density mode only).
    Defaults (kp 100 N/m, kd 20 N s/m, 1e-3) were tuned on 3 training seeds of the default prism.
    """

    def __init__(self, env, kp: float = 100.0, kd: float = 20.0, regularization: float = 1e-9,
                 feedback_regularization: float = 1e-3, feedback: bool | None = None):
        task = _task_of(env)
        self.task = task
        self.mode = task.action_mode
        self.model = task.model
        self.structure = task.structure
        self.act = task.actuated
        self.passive = np.setdiff1d(np.arange(self.structure.n_strings), self.act)
        self.tracked = task.tracked
        self.actuation = task.actuation
        self.kp, self.kd = float(kp), float(kd)
        self.regularization = float(regularization)
        self.feedback_regularization = float(feedback_regularization)
        self.feedback = (self.mode == "force_density") if feedback is None else bool(feedback)
        self.gamma_ref = task.gamma_nominal[self.act]
        self.nodes_fixed = task.nodes_nominal.copy()     # pinned nodes and anchors never move
        layout = {name: sl for name, sl, _ in task.observation_layout()}
        self._sl = layout
        self._step = self.actuation.max_rate * self.actuation.control_dt

    # ------------------------------------------------------------------ pieces
    def _full_nodes(self, tracked_pos: np.ndarray) -> np.ndarray:
        B = tracked_pos.shape[0]
        N = np.tile(self.nodes_fixed, (B, 1, 1))
        N[:, self.tracked] = tracked_pos
        return N

    def _passive_gamma(self, q: np.ndarray) -> np.ndarray:
        _, L, _ = string_state(self.model, q)
        s = self.structure
        k, l0 = s.stiffness[self.passive], s.rest_length[self.passive]
        Lp = L[:, self.passive]
        return np.where(Lp > l0, k * (Lp - l0) / np.where(Lp > 0, Lp, 1.0), 0.0), L

    def _solve(self, q: np.ndarray, extra: np.ndarray | None = None) -> np.ndarray:
        """(B, na) force densities of the actuated strings putting generalized force ``extra`` (B, nx)
        (default 0) on configuration ``q``."""
        A, w = statics.equilibrium_matrix(self.model, q)
        gp, _ = self._passive_gamma(q)
        out = np.zeros((q.shape[0], self.act.size))
        for i in range(q.shape[0]):
            rhs = -(w[i] + A[i][:, self.passive] @ gp[i])
            if extra is not None:
                rhs = rhs + extra[i]
            g, _ = nnls_force_densities(A[i][:, self.act], rhs, self.gamma_ref, self.regularization)
            out[i] = g
        return out

    def feedforward(self, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """NNLS force densities (B, na) N/m of the actuated strings at the target (B, nt, 3) and
        the matching rest lengths (B, na) m."""
        qt = initial_state(self.model, nodes=self._full_nodes(target)).q
        g = self._solve(qt)
        _, L = self._passive_gamma(qt)
        k = self.structure.stiffness[self.act]
        l0 = L[:, self.act] * (1.0 - g / k)
        return g, l0

    # ------------------------------------------------------------------ policy
    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        obs = np.asarray(obs, dtype=np.float64)
        single = obs.ndim == 1
        O = obs[None] if single else obs
        B = O.shape[0]
        nt = self.tracked.size
        pos = O[:, self._sl["node_position"]].reshape(B, nt, 3)
        vel = O[:, self._sl["node_velocity"]].reshape(B, nt, 3)
        ctrl = O[:, self._sl["control"]]
        target = O[:, self._sl["target_position"]].reshape(B, nt, 3)
        g_t, l0_t = self.feedforward(target)
        if self.feedback:
            qc = initial_state(self.model, nodes=self._full_nodes(pos)).q
            F = np.zeros((B, self.model.n_nodes, 3))
            F[:, self.tracked] = self.kp * (target - pos) - self.kd * vel
            rc = statics.ReducedCoordinates(self.model)
            extra = rc.project_forces(qc, F)
            # pull toward the feedforward solution instead of the nominal one
            ref, self.gamma_ref = self.gamma_ref, None
            try:
                A, w = statics.equilibrium_matrix(self.model, qc)
                gp, Lc = self._passive_gamma(qc)
                g = np.zeros((B, self.act.size))
                for i in range(B):
                    rhs = -(w[i] + A[i][:, self.passive] @ gp[i]) + extra[i]
                    g[i], _ = nnls_force_densities(A[i][:, self.act], rhs, g_t[i], self.feedback_regularization)
            finally:
                self.gamma_ref = ref
            if self.mode == "force_density":
                desired = g
            else:
                k = self.structure.stiffness[self.act]
                desired = Lc[:, self.act] * (1.0 - g / k)
        else:
            desired = g_t if self.mode == "force_density" else l0_t
        desired = np.clip(desired, self.actuation.low, self.actuation.high)
        action = np.clip((desired - ctrl) / self._step, -1.0, 1.0).astype(np.float32)
        return (action[0] if single else action), state


# ---------------------------------------------------------------------- TensegrityRoll-v0 gait
_WAVE_SYM = np.tile(np.arange(3), 3)      # symmetry index of each prism string
_WAVE_KIND = np.repeat(np.arange(3), 3)    # its kind: 0 bottom, 1 top, 2 vertical
_WAVE_CONE = np.array([1.0, -1.0, 0.0])[_WAVE_KIND]    # sign of the steering bias per string


def wave_targets(t, nominal, low, high, amplitude, phase, period, direction, sharpness, bias=0.0) -> np.ndarray:
    """Rest-length targets (B, 9), m, of :class:`RollingGait`'s travelling contraction wave at
    times ``t`` (B,) s. ``nominal``, ``low``, ``high`` (9,) m. The wave's parameters are one
    pattern for all B rows (``amplitude``, ``phase`` (3,); ``period`` s, ``direction``,
    ``sharpness`` scalars) or one pattern per row (``(B, 3)`` and ``(B,)``: a batched search
    over patterns, ``scripts/eval/gait_search.py``). ``bias`` (scalar or (B,)) lengthens the bottom
    strings' nominal rest lengths by the factor ``1 + bias`` and shortens the top strings' by
    ``1 - bias`` (a cone-shaped prism: the steering input of :class:`RollingGait`)."""
    t = np.atleast_1d(np.asarray(t, float))
    period = np.asarray(period, float)[..., None]
    direction = np.asarray(direction)[..., None]
    sharpness = np.asarray(sharpness, float)[..., None]
    x = t[:, None] / period - direction * _WAVE_SYM[None, :] / 3.0 - np.asarray(phase, float)[..., _WAVE_KIND]
    p = ((1.0 - np.cos(2.0 * np.pi * x)) / 2.0) ** sharpness
    bias = np.asarray(bias, float)[..., None]
    nom = nominal[None, :] * (1.0 + bias * _WAVE_CONE[None, :])
    tgt = nom * (1.0 - np.asarray(amplitude, float)[..., _WAVE_KIND] * p)
    return np.clip(tgt, low, high)


class RollingGait:
    """Rolling gait for ``TensegrityRoll-v0`` (default 3-bar prism, no learning): an open-loop
    travelling contraction wave, steered by the observed heading.

    **The wave (open loop).** Every string ``s`` of the prism has a symmetry index ``j`` (bottom
    string j, top string j and vertical string j are carried into string j+1 of their kind by
    the prism's 3-fold rotation) and a kind (bottom, top, vertical). Its target rest length is a
    periodic contraction wave around the prism's axis::

        x_s(t)  = t / period - direction * j / 3 - phase[kind]
        l0_s(t) = l0_s^nominal * (1 + c_s * bias) * (1 - amplitude[kind] * ((1 - cos 2 pi x_s) / 2) ** sharpness)

    with ``c_s`` = +1 for the bottom strings, -1 for the top strings, 0 for the vertical ones.
    The strings on the side that is about to touch the ground shorten in turn, which pulls the
    centre of mass past the edge of the support face: the prism rolls face over face
    (``scripts/eval/gait_stats.py gait``: net rotation about the horizontal axis across the goal
    with ``omega x z`` along the motion, see ``docs/contact.md``).

    **Steering (heading feedback).** The twisted prism is chiral: rolled by the wave alone
    (``steer=0``, a purely time-periodic pattern) its path curves, and over 100 s it circles
    (``results/gait_search/``). The ``bias`` makes the prism a slight cone (bottom triangle larger,
    top smaller), which changes the curvature of its path, as a cone rolls around its apex. The
    gait sets::

        v      <- v + (control_dt / heading_time_constant) (v_com - v)      (low-pass, m/s)
        err    = signed angle from v to the goal direction (rad, + = goal to the left)
        bias   = bias0 - steer * clip(err / steer_angle, -1, 1)

    where ``v_com`` (horizontal centre-of-mass velocity) is estimated by the mean of the observed node
    velocities (exact for equal uniform rods; only its direction is used) and the goal direction is read from the observation, so the gait
    follows ``randomize_goal``. Only this one scalar is fed back; the wave's timing stays open
    loop.

    The action is the cable-speed command that moves each rest length toward its target at the
    motor's limit: ``a = clip((l0_target - l0_current) / (max_cable_speed dt_c), -1, 1)`` (the
    current rest lengths are read from the observation's ``control`` block). With the env's
    cable motor model (on by default) the cable speed follows that command with a lag.

    Figures (``python -m scripts.eval.eval_roll_baseline``, 100 s on flat ground, 8 reset seeds,
    ``results/roll_baseline.json``) are in the env's docstring and the README. How the default
    parameters were found: the wave is the pattern of a batched random search
    (``scripts/eval/gait_search.py 1 4096``) that rotated most about a horizontal axis in 10 s; the
    steering constants ``(bias0, steer, steer_angle, heading_time_constant)`` come from a grid
    of 81 settings (3 x 3 x 3 x 3), each run for 100 s on 4 reset seeds with the goal +x and on
    4 with random goals, keeping the setting with the best worse-of-the-two mean progress along
    the goal (``scripts/eval/gait_search.py --steer-grid``).

    ``predict(obs, state=None, episode_start=None, deterministic=True) -> (action, state)`` as a
    Stable-Baselines3 model. ``state`` is a (B, 3) float array: column 0 the control steps since
    the episode start, columns 1-2 the filtered centre-of-mass velocity (m/s). Pass it back in,
    as for SB3 recurrent policies; ``None`` = all episodes start now; ``episode_start`` (B,) bool
    resets those rows.

    Parameters (SI units)
    ---------------------
    env : a ``TensegrityRoll-v0`` env / vector env / its task, ``action_mode="rest_length"``
        with the default prism (9 strings, all actuated).
    amplitude : (3,) relative contraction of the bottom, top and vertical strings (<= 1 - the
        lower rest-length bound).
    phase : (3,) phase offsets (cycles) of the three kinds.
    period : s per cycle of the wave. direction : +1 or -1 (sense of the wave).
    sharpness : exponent of the raised-cosine pulse (higher: shorter contractions).
    bias : steering bias at zero heading error (fraction of the nominal rest length).
    steer : largest change of the bias made by the heading feedback; 0 = open loop.
    steer_angle : rad, heading error at which the correction saturates (> 0).
    heading_time_constant : s, of the low-pass filter on the centre-of-mass velocity (> 0).
    """

    DEFAULT = dict(amplitude=(0.4956, 0.4993, 0.4578), phase=(0.1408, 0.3134, 0.7829), period=1.7096,
                   direction=-1, sharpness=1.0, bias=0.1, steer=0.075, steer_angle=0.5,
                   heading_time_constant=1.0)

    def __init__(self, env, amplitude=None, phase=None, period: float | None = None,
                 direction: int | None = None, sharpness: float | None = None, bias: float | None = None,
                 steer: float | None = None, steer_angle: float | None = None,
                 heading_time_constant: float | None = None):
        task = _task_of(env)
        if getattr(task, "action_mode", None) != "rest_length":
            raise ValueError("RollingGait: needs TensegrityRoll-v0 with action_mode='rest_length'")
        s = task.structure
        if s.n_bars != 3 or s.n_strings != 9 or task.actuated.size != 9:
            raise ValueError("RollingGait: designed for the 3-bar prism with all 9 strings actuated "
                             f"(got {s.n_bars} rods, {s.n_strings} strings, {task.actuated.size} actuated)")
        d = self.DEFAULT
        pick = (lambda name, v: d[name] if v is None else v)
        self.amplitude = np.asarray(pick("amplitude", amplitude), float)
        self.phase = np.asarray(pick("phase", phase), float)
        self.period = float(pick("period", period))
        self.direction = int(pick("direction", direction))
        self.sharpness = float(pick("sharpness", sharpness))
        self.bias = float(pick("bias", bias))
        self.steer = float(pick("steer", steer))
        self.steer_angle = float(pick("steer_angle", steer_angle))
        self.heading_time_constant = float(pick("heading_time_constant", heading_time_constant))
        if self.amplitude.shape != (3,) or self.phase.shape != (3,):
            raise ValueError("RollingGait: amplitude and phase need 3 values (bottom, top, vertical strings)")
        for name in ("period", "steer_angle", "heading_time_constant"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"RollingGait: {name} must be positive and finite, got {v}")
        for name in ("bias", "steer"):
            v = getattr(self, name)
            if not (np.isfinite(v) and abs(v) < 1):
                raise ValueError(f"RollingGait: {name} must be finite with |{name}| < 1, got {v}")
        if self.direction not in (-1, 1):
            raise ValueError(f"RollingGait: direction must be +1 or -1, got {self.direction}")
        self.task = task
        self.actuation = task.actuation
        self.nominal = self.actuation.nominal.copy()
        self.control_dt = task.control_dt
        self._step = self.actuation.max_rate * self.control_dt
        lay = {name: sl for name, sl, _ in task.observation_layout()}
        if "node_velocity" not in lay:
            raise ValueError("RollingGait: reads the node velocities of the state observation; this env has "
                             f"observation_mode={getattr(task, 'sensors', None) and 'robot'!r} "
                             "(construct it with observation_mode='state')")
        self._sl, self._vel, self._goal = lay["control"], lay["node_velocity"], lay["goal_direction"]

    def target(self, t, bias=None) -> np.ndarray:
        """(B, 9) target rest lengths (m) at times ``t`` (B,) s, with steering ``bias`` (scalar or
        (B,); default the constant ``self.bias``)."""
        return wave_targets(t, self.nominal, self.actuation.low, self.actuation.high, self.amplitude,
                            self.phase, self.period, self.direction, self.sharpness,
                            self.bias if bias is None else bias)

    def steering(self, obs, v) -> tuple[np.ndarray, np.ndarray]:
        """Heading feedback: observations (B, obs_dim) and filtered centre-of-mass velocities
        (B, 2) m/s -> (bias (B,), updated filtered velocities (B, 2)). The four steering
        constants may also be set to (B,) arrays after construction (one setting per row: the
        grid of ``scripts/eval/gait_search.py --steer-grid``)."""
        vel = obs[:, self._vel].reshape(obs.shape[0], -1, 3)[:, :, :2].mean(axis=1)
        a = np.minimum(1.0, self.control_dt / np.asarray(self.heading_time_constant, float))
        v = v + np.reshape(a, (-1, 1)) * (vel - v)
        g = obs[:, self._goal]
        err = np.arctan2(v[:, 0] * g[:, 1] - v[:, 1] * g[:, 0], np.einsum("bi,bi->b", v, g))
        return self.bias - self.steer * np.clip(err / self.steer_angle, -1.0, 1.0), v

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        obs = np.asarray(obs, dtype=np.float64)
        single = obs.ndim == 1
        O = obs[None] if single else obs
        B = O.shape[0]
        st = np.zeros((B, 3)) if state is None else np.array(state, dtype=np.float64).reshape(B, 3)
        if episode_start is not None:
            st[np.asarray(episode_start, bool).reshape(B)] = 0.0
        bias, v = self.steering(O, st[:, 1:])
        tgt = self.target(st[:, 0] * self.control_dt, bias)
        action = np.clip((tgt - O[:, self._sl]) / self._step, -1.0, 1.0).astype(np.float32)
        st = np.column_stack([st[:, 0] + 1.0, v])
        return (action[0] if single else action), st
