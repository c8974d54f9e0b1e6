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

Contents
--------
``check_action(action, shape, clip=True)``
    Validates an action: shape, NaN/inf (``ValueError`` naming the index), then clips to
    [-1, 1] (the Box contract, documented in each env) or, with ``clip=False``, raises on
    entries outside it (beyond 1e-6).
``Actuation``
    The actuation model of a set of strings, batched: ``mode`` ``"rest_length"`` (control:
    rest lengths, m, changed at most ``max_rate`` m/s, kept within [``low``, ``high``]) or
    ``"force_density"`` (control: force densities of active strings, N/m, changed at most
    ``max_rate`` N/(m s), within [``low`` >= 0, ``high``]). ``apply(ctrl, action)`` maps an
    action in [-1, 1] to the new control; ``physics_inputs(ctrl)`` gives the
    ``rest_length=`` / ``force_density=`` arrays (B, m) for :func:`tensegrity_gym.integrators.step`.
``BatchedTask``
    Base class of a task: owns ``model``, ``integrator``, ``dt``, ``frame_skip``, ``backend``,
    the batched ``q``, ``qd`` (B, k, 6) and ``elapsed`` (B,) control steps. Subclasses implement
    ``reset_idx``, ``step``, ``observe``, ``render_data``; :meth:`BatchedTask.simulate` runs one
    control step of physics for the whole batch (ONE call of ``integrators.step`` with
    ``n_steps=frame_skip``, or one call per substep when a ``substep_external(q, qd)`` force
    such as drag or contact must be re-evaluated every substep) and handles divergence.
``TaskEnv``, ``TaskVectorEnv``, ``make_sb3_vec_env``: the shells described above.

Divergence
----------
After each control step, a copy whose state is non-finite or has a node farther than
``divergence_limit`` m from the structure's initial centre is *diverged*: its state is put
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

import math
from typing import Any, Sequence

import numpy as np
import gymnasium as gym
from gymnasium import spaces
from gymnasium.utils import seeding

from .. import integrators
from .. import dynamics as dyn
from ..rewards import combine
from . import _fast
from .domain import Domain
from ..params import default_params

__all__ = ["ACTION_MODES", "check_action", "check_positive", "Actuation", "BatchedTask", "TaskEnv",
           "TaskVectorEnv", "make_sb3_vec_env", "resolve_actuated", "registered_max_episode_steps"]

ACTION_MODES = ("rest_length", "force_density")
ACTION_TOL = 1e-6


# ---------------------------------------------------------------------- input checks
def check_positive(value, name: str, unit: str = "", allow_zero: bool = False) -> float:
    """``float(value)`` if finite and > 0 (>= 0 with ``allow_zero``), else ValueError naming ``name``.
    A string or a bool is not a number here (``"1e-3"`` and ``True`` are refused, not converted)."""
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise ValueError(f"{name}: expected a number{' in ' + unit if unit else ''}, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number{' in ' + unit if unit else ''}, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name}: must be {'>= 0' if allow_zero else 'positive'} and finite"
                         f"{' (' + unit + ')' if unit else ''}, got {value!r}")
    return v


def check_action(action, shape: tuple, clip: bool = True, name: str = "action") -> np.ndarray:
    """Validate an action and return it as a float64 array of ``shape``.

    * wrong shape -> ValueError;
    * NaN or inf -> ValueError naming the (first) offending index;
    * entries outside [-1, 1]: clipped to the box if ``clip`` (the documented Box contract,
      like Gymnasium's MuJoCo envs whose actuators saturate), else ValueError naming the
      index when beyond 1e-6 of the bounds.
    """
    if (_fast.AVAILABLE and type(action) is np.ndarray and action.shape == shape
            and (action.dtype == np.float32 or action.dtype == np.float64)):
        # fast path (the common case): a float ndarray of the right shape, checked and clipped in
        # one compiled pass; anything wrong falls through to the reference checks below
        a = np.array(action, dtype=np.float64, order="C")
        if _fast.clip_action(a.reshape(-1), clip, ACTION_TOL):
            return a
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected an array of numbers with shape {shape}, got {action!r}") from None
    if a.shape != tuple(shape):
        if a.size == int(np.prod(shape)) and a.ndim <= 1 and len(shape) == 1:
            a = a.reshape(shape)
        else:
            raise ValueError(f"{name}: expected shape {tuple(shape)}, got {a.shape}")
    finite = np.isfinite(a)
    if not finite.all():
        idx = tuple(int(i) for i in np.argwhere(~finite)[0])
        idx_s = idx[0] if len(idx) == 1 else idx
        raise ValueError(f"{name}: entry {idx_s} is {a[idx]!r}; actions must be finite numbers in [-1, 1]")
    if clip:
        return np.clip(a, -1.0, 1.0)
    bad = np.abs(a) > 1.0 + ACTION_TOL
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        idx_s = idx[0] if len(idx) == 1 else idx
        raise ValueError(f"{name}: entry {idx_s} is {a[idx]:.6g}, outside the action space [-1, 1] "
                         "(construct the env with clip_actions=True to saturate instead)")
    return np.clip(a, -1.0, 1.0)


def check_stable_dt(model: dyn.Model, limit: float, dt: float, integrator: str, allow: bool, what: str) -> None:
    """ValueError if ``dt`` (s) is above the estimated stability ``limit`` (s) of ``integrator``,
    unless ``allow``; the message names the strings' stiffness and damping that set the limit."""
    if dt <= limit or allow:
        return
    k = float(np.max(model.stiffness)) if model.n_strings else 0.0
    c = float(np.max(model.damping)) if model.n_strings else 0.0
    raise ValueError(f"dt: {dt:g} s is above the estimated stability limit {limit:.3g} s of {integrator} for {what} "
                     f"(strings up to {k:.4g} N/m and {c:.4g} N s/m; the state would blow up); use a smaller dt, "
                     "less stiffness or string damping, integrator='implicit_euler' where the task allows it, or "
                     "allow_unstable_dt=True to run it anyway")


def resolve_actuated(actuated, n_strings: int) -> np.ndarray:
    """Sorted unique string indices from ``None`` (all), an int list or a bool mask; errors name the index."""
    if actuated is None:
        return np.arange(n_strings)
    arr = np.asarray(actuated)
    if arr.dtype == bool:
        if arr.shape != (n_strings,):
            raise ValueError(f"actuated: a boolean mask needs {n_strings} entries (one per string), got {arr.shape}")
        arr = np.flatnonzero(arr)
    else:
        arr = arr.reshape(-1)
        if arr.size and (not np.issubdtype(arr.dtype, np.integer)):
            if not np.all(np.asarray(arr, float) == np.round(np.asarray(arr, float))):
                raise ValueError(f"actuated: string indices must be integers, got {actuated!r}")
            arr = arr.astype(int)
        for i in arr:
            if not 0 <= int(i) < n_strings:
                raise ValueError(f"actuated: string {int(i)} does not exist (there are {n_strings} strings)")
        if len(set(arr.tolist())) != arr.size:
            raise ValueError(f"actuated: duplicate string indices in {arr.tolist()}")
        arr = np.sort(arr.astype(int))
    if arr.size == 0:
        raise ValueError("actuated: at least one string must be actuated")
    return arr


# ---------------------------------------------------------------------- actuation
class Actuation:
    """Batched actuation of ``na`` strings (SI units).

    Parameters
    ----------
    mode : ``"rest_length"`` or ``"force_density"``.
    actuated : (na,) indices of the actuated strings.
    low, high : (na,) control bounds: m (rest length) or N/m (force density, ``low`` >= 0).
    max_rate : (na,) largest change of the control per second: m/s or N/(m s).
    control_dt : s, the duration of one control step (``dt * frame_skip``).
    base_rest_length : (m,) rest lengths of all strings (the non-actuated ones keep them), m.
    nominal : (na,) control at the start of an episode.

    max_accel : ``None`` (default) or the largest change of the control *rate* per second
        (rest-length mode: the cable acceleration limit of a motor, m/s^2). See below.

    Without ``max_accel``, an action ``a`` in [-1, 1]^na changes the control by
    ``a * max_rate * control_dt`` per control step, then the control is clipped to
    [``low``, ``high``] (:meth:`apply`, :meth:`advance`).

    With ``max_accel`` (a motor model, :meth:`advance_motor`) the action commands the rate
    ``v_cmd = a * max_rate``; the rate ``v`` (B, na) is state (m/s for rest lengths) and moves
    toward the command by at most ``max_accel * control_dt`` per control step; the control then
    moves by ``v * control_dt`` and is clipped to [``low``, ``high``], and where it sits on a
    bound with ``v`` pushing beyond it, ``v`` is set to 0 (end stop).
    """

    def __init__(self, mode: str, actuated, low, high, max_rate, control_dt: float, base_rest_length,
                 nominal, max_accel: float | None = None):
        if mode not in ACTION_MODES:
            raise ValueError(f"action_mode: unknown {mode!r}; choose one of {ACTION_MODES}")
        self.mode = mode
        self.actuated = np.asarray(actuated, dtype=int)
        na = self.actuated.size
        self.base_rest_length = np.asarray(base_rest_length, float).copy()
        self.n_strings = self.base_rest_length.size

        def per(x, nm):
            arr = np.broadcast_to(np.asarray(x, float), (na,)).copy()
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{nm}: non-finite value(s) {arr.tolist()}")
            return arr
        self.low, self.high = per(low, "low"), per(high, "high")
        self.max_rate = per(max_rate, "max_rate")
        self.nominal = np.clip(per(nominal, "nominal"), self.low, self.high)
        self.control_dt = check_positive(control_dt, "control_dt", "s")
        self.max_accel = None if max_accel is None else check_positive(max_accel, "max_accel", "unit/s^2")
        # per-copy limits (set_copy_limits): (P, na) rates and (P,) accelerations, P = 1 until set
        self.rate_rows = self.max_rate[None].copy()
        self.accel_rows = None if self.max_accel is None else np.array([self.max_accel])
        self._update_steps()
        unit = "m" if mode == "rest_length" else "N/m"
        for i in range(na):
            s = int(self.actuated[i])
            if self.low[i] > self.high[i]:
                raise ValueError(f"bounds of actuated string {s}: lower {self.low[i]:.6g} {unit} is above "
                                 f"upper {self.high[i]:.6g} {unit}")
            if self.low[i] < 0:
                raise ValueError(f"bounds of actuated string {s}: lower bound {self.low[i]:.6g} {unit} is negative")
            if self.max_rate[i] <= 0:
                raise ValueError(f"max rate of actuated string {s}: {self.max_rate[i]:.6g} {unit}/s must be positive")

    def _update_steps(self):
        self._rate = self.rate_rows * self.control_dt     # change of the control per unit action and step
        self._dv = None if self.accel_rows is None else self.accel_rows * self.control_dt

    def set_copy_limits(self, batch_size: int, idx, max_rate=None, max_accel=None) -> None:
        """Copies ``idx`` get their own rate limit ``max_rate`` ((len(idx), na) or (na,), unit/s)
        and/or motor acceleration limit ``max_accel`` ((len(idx),) or a number, unit/s^2); the
        other copies keep theirs (the nominal ones until changed). ValueError naming the copy
        and the value if one is not finite and > 0."""
        idx = np.asarray(idx, dtype=int).reshape(-1)
        if self.rate_rows.shape[0] != batch_size:
            self.rate_rows = np.repeat(self.rate_rows[:1], batch_size, axis=0)
            if self.accel_rows is not None:
                self.accel_rows = np.repeat(self.accel_rows[:1], batch_size)
        for name, val, rows in (("max_cable_speed", max_rate, self.rate_rows),
                                ("max_cable_acceleration", max_accel, self.accel_rows)):
            if val is None:
                continue
            if rows is None:
                raise ValueError(f"{name}: this actuation has no motor acceleration limit")
            v = np.broadcast_to(np.asarray(val, float), (idx.size,) + rows.shape[1:])
            bad = ~(np.isfinite(v) & (v > 0))
            if bad.any():
                pos = np.argwhere(bad)[0]
                raise ValueError(f"{name}: copy {int(idx[pos[0]])}: must be finite and > 0, got {float(v[tuple(pos)])!r}")
            rows[idx] = v
        self._update_steps()

    @property
    def size(self) -> int:
        return int(self.actuated.size)

    @property
    def unit(self) -> str:
        return "m" if self.mode == "rest_length" else "N/m"

    def apply(self, ctrl: np.ndarray, action: np.ndarray) -> np.ndarray:
        """New control (B, na) from the current control (B, na) and an action in [-1, 1] (B, na)."""
        return np.clip(ctrl + action * self._rate, self.low, self.high)

    def physics_inputs(self, ctrl: np.ndarray) -> dict:
        """Keyword arguments ``rest_length`` / ``force_density`` (B, m) for ``integrators.step``."""
        B = ctrl.shape[0]
        if self.mode == "rest_length":
            rl = np.empty((B, self.n_strings))
            rl[:] = self.base_rest_length
            rl[:, self.actuated] = ctrl
            return {"rest_length": rl}
        fd = np.zeros((B, self.n_strings))
        fd[:, self.actuated] = ctrl
        return {"rest_length": None, "force_density": fd}

    def advance(self, ctrl: np.ndarray, action: np.ndarray) -> tuple[np.ndarray, dict]:
        """``(new, physics_inputs(new))`` with ``new = apply(ctrl, action)``: one compiled call
        for C-contiguous float64 (B, na) arrays (the env's own), the two methods otherwise."""
        if (_fast.AVAILABLE and type(ctrl) is np.ndarray and type(action) is np.ndarray
                and ctrl.ndim == 2 and ctrl.shape == action.shape and ctrl.dtype == np.float64
                and action.dtype == np.float64 and ctrl.flags.c_contiguous and action.flags.c_contiguous):
            new = np.empty(ctrl.shape)
            phys = np.empty((ctrl.shape[0], self.n_strings))
            rl = self.mode == "rest_length"
            _fast.apply_controls(ctrl, action, self._rate, self.low, self.high, self.actuated,
                                 self.base_rest_length, rl, new, phys)
            return new, ({"rest_length": phys} if rl else {"rest_length": None, "force_density": phys})
        new = self.apply(ctrl, action)
        return new, self.physics_inputs(new)

    def apply_motor(self, ctrl: np.ndarray, speed: np.ndarray, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Motor model (needs ``max_accel``): ``(new control, new rate)`` (B, na) from the current
        control, the current rate ``speed`` (unit/s) and an action in [-1, 1] (the NumPy reference
        of :meth:`advance_motor`)."""
        if self.max_accel is None:
            raise ValueError("apply_motor: this Actuation has no max_accel (use apply)")
        dv = self._dv[:, None]
        v = speed + np.clip(action * self.rate_rows - speed, -dv, dv)
        new = np.clip(ctrl + v * self.control_dt, self.low, self.high)
        stop = ((new <= self.low) & (v < 0.0)) | ((new >= self.high) & (v > 0.0))
        v = np.where(stop, 0.0, v)
        return new, v

    def advance_motor(self, ctrl: np.ndarray, speed: np.ndarray,
                      action: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
        """``(new, new_speed, physics_inputs(new))`` of the motor model (:meth:`apply_motor`): one
        compiled call for C-contiguous float64 (B, na) arrays, NumPy otherwise (same numbers)."""
        if self.max_accel is None:
            raise ValueError("advance_motor: this Actuation has no max_accel (use advance)")
        if (_fast.AVAILABLE and all(type(x) is np.ndarray and x.ndim == 2 and x.shape == ctrl.shape
                                    and x.dtype == np.float64 and x.flags.c_contiguous
                                    for x in (ctrl, speed, action))):
            new = np.empty(ctrl.shape)
            v = np.empty(ctrl.shape)
            phys = np.empty((ctrl.shape[0], self.n_strings))
            rl = self.mode == "rest_length"
            _fast.apply_motor(ctrl, speed, action, self.rate_rows, self._dv, self.control_dt, self.low, self.high, self.actuated, self.base_rest_length,
                              rl, new, v, phys)
            return new, v, ({"rest_length": phys} if rl else {"rest_length": None, "force_density": phys})
        new, v = self.apply_motor(ctrl, speed, action)
        return new, v, self.physics_inputs(new)

    def describe(self) -> str:
        acc = "" if self.max_accel is None else f", max rate change {self.max_accel:.4g} {self.unit}/s^2"
        return (f"{self.mode}: strings {self.actuated.tolist()}, bounds [{self.low.min():.4g}, "
                f"{self.high.max():.4g}] {self.unit}, max rate {self.max_rate.max():.4g} {self.unit}/s" + acc)


# ---------------------------------------------------------------------- batched task base
#: robot parameters (envs/domain.py) that are Params fields of the physics (tensegrity_gym.params)
_PHYSICS_FIELDS = {"rod_mass": "mass", "stiffness": "stiffness", "damping": "damping", "node_damping": "node_damping",
                   "gravity": "gravity", "rest_length_offset": "rest_length"}


class BatchedTask:
    """Base class of a batched task on B copies of one compiled structure.

    Subclasses set in ``__init__`` (after calling :meth:`_init_physics`): ``action_size``,
    ``observation_size``, ``obs_low``/``obs_high`` (optional, default +-inf) and implement

    * ``reset_idx(idx (r,) int array, rngs: list of r np.random.Generator, options) -> dict``
      of reset infos ((r,) arrays) -- all randomness of copy ``idx[j]`` from ``rngs[j]``,
      drawn in a per-copy order so that B copies equal B single tasks;
    * ``step(action (B, na) validated) -> (terms: dict of (B,), terminated (B,) bool, infos)``
      which must call :meth:`simulate` exactly once;
    * ``observe() -> (B, obs_size) float32``;
    * ``render_data(i) -> dict`` of keyword arguments for :meth:`tensegrity_gym.rendering.Renderer.render`
      (``nodes``, ``rods``, ``strings``, ``tensions``, ``targets``, ``ground_z``, ``path``, ``goal``, ``caption``).
    """

    action_size: int
    observation_size: int

    def _init_physics(self, model: dyn.Model, num_envs: int, integrator: str, dt: float, frame_skip: int,
                      backend: str = "auto", divergence_limit: float | None = None, clip_actions: bool = True):
        if int(num_envs) != num_envs or num_envs < 1:
            raise ValueError(f"num_envs: must be a positive integer, got {num_envs}")
        self.num_envs = int(num_envs)
        self.model = model
        self.integrator = integrators.resolve(integrator).name
        if integrators.INTEGRATORS[self.integrator].adaptive:
            raise ValueError(f"integrator: {integrator!r} is adaptive; envs need a fixed-step method "
                             f"({[k for k, v in integrators.INTEGRATORS.items() if not v.adaptive]})")
        self.dt = check_positive(dt, "dt", "s")
        if int(frame_skip) != frame_skip or frame_skip < 1:
            raise ValueError(f"frame_skip: must be a positive integer, got {frame_skip}")
        self.frame_skip = int(frame_skip)
        if backend not in ("auto", "numpy", "numba"):
            raise ValueError(f"backend: unknown {backend!r}; choose 'auto', 'numpy' or 'numba'")
        self.backend = backend
        self.clip_actions = bool(clip_actions)
        nodes0 = model.structure.nodes
        self.center0 = nodes0.mean(axis=0)
        size = float(np.max(np.linalg.norm(nodes0 - self.center0, axis=1)))
        self.divergence_limit = (100.0 * max(size, 1e-3) if divergence_limit is None
                                 else check_positive(divergence_limit, "divergence_limit", "m"))
        B, k = self.num_envs, model.n_bars
        st = dyn.initial_state(model, B)
        self.q = st.q.copy()
        self.qd = st.qd.copy()
        self.elapsed = np.zeros(B, dtype=np.int64)
        self.params = None        # tensegrity_gym.params.Params of the copies; None: the model's own values
        self.rest_offset = None   # (P, m) true minus commanded rest lengths, m (rest_length_offset)
        self.action_delay = 0

    # ------------------------------------------------------------------ robot parameters (envs/domain.py)
    def _init_domain(self, params=None, randomize=None, action_delay: int = 0, start_rest_length_offset=None,
                     extra_nominal: dict | None = None):
        """Fixed / randomised physical parameters (:mod:`tensegrity_gym.envs.domain`), actuation
        latency (``action_delay`` control steps: the physics receives the action given that many
        steps earlier; zeros at the start of an episode) and the slack start
        (``start_rest_length_offset``, m: the actuated cables start at their nominal rest length
        plus this, rest-length mode). Call at the end of the task's ``__init__``."""
        model, B = self.model, self.num_envs
        g = np.zeros(3) if model.gravity is None else np.asarray(model.gravity, float)
        nominal = {"rod_mass": model.mass, "stiffness": model.structure.stiffness, "damping": model.structure.damping,
                   "node_damping": model.node_damping, "gravity": g, "rest_length_offset": np.zeros(model.n_strings)}
        nominal.update(extra_nominal or {})
        self.domain = Domain(nominal, B, params, randomize)
        if isinstance(action_delay, (bool, np.bool_)) or int(action_delay) != action_delay or action_delay < 0:
            raise ValueError(f"action_delay: must be a non-negative integer (control steps), got {action_delay!r}")
        self.action_delay = int(action_delay)
        self._action_queue = np.zeros((B, self.action_delay, self.action_size))
        act = self.actuation
        self.start_control = act.nominal.copy()
        if start_rest_length_offset is not None:
            if act.mode != "rest_length":
                raise ValueError("start_rest_length_offset: only with action_mode='rest_length'")
            off = np.broadcast_to(np.asarray(start_rest_length_offset, float), act.nominal.shape)
            start = act.nominal + off
            bad = ~np.isfinite(start) | (start < act.low) | (start > act.high)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(f"start_rest_length_offset: actuated cable {int(act.actuated[i])} would start at "
                                 f"{start[i]:.6g} m, outside its bounds [{act.low[i]:.6g}, {act.high[i]:.6g}] m")
            self.start_control = start
        phys_names = set(self.domain.names) & set(_PHYSICS_FIELDS)
        if phys_names:   # Params: one row when fixed, one per copy when randomised (per-copy kernel)
            per_copy = bool(phys_names & set(self.domain.spread))
            self.params = default_params(model, B if per_copy else 1)
        if self.domain.enabled:
            self._apply_domain(np.arange(B) if self.domain.randomized else np.zeros(1, int), init=True)

    def _apply_domain(self, idx: np.ndarray, init: bool = False) -> None:
        """Copies ``idx`` take the domain's current values. ``self.params`` has one row (set once,
        at ``init``) when no physics parameter is randomised, else one per copy (set per reset)."""
        v, model, P = self.domain.values, self.model, (0 if self.params is None else self.params.batch_size)
        # per copy: a physics parameter is randomised (then P = B, also when B = 1)
        per_copy = P > 0 and bool(set(self.domain.spread) & set(_PHYSICS_FIELDS))
        if per_copy or (P == 1 and init):
            rows = idx if per_copy else np.zeros(1, int)
            phys = {}
            for name, fld in _PHYSICS_FIELDS.items():
                if name in v and fld != "rest_length":
                    phys[fld] = v[name][rows]
                    if fld in ("stiffness", "damping"):          # force-density-actuated strings: no elastic part
                        phys[fld] = np.where(model.active, 0.0, phys[fld])
            if "rest_length_offset" in v:
                phys["rest_length"] = model.rest_length + v["rest_length_offset"][rows]
                self.rest_offset = v["rest_length_offset"] if per_copy else v["rest_length_offset"][:1]
            self.params = self.params.set_rows(rows, **phys) if per_copy else self.params.replace(**phys)
        self._apply_task_domain(idx)

    def _apply_task_domain(self, idx: np.ndarray) -> None:
        """Task-specific parameters (contact, motor limits) of copies ``idx``; see RollTask."""

    def with_offset(self, inputs: dict) -> dict:
        """Physics inputs with the cables' rest-length offsets added (``rest_length_offset``)."""
        if self.rest_offset is not None and inputs.get("rest_length") is not None:
            inputs["rest_length"] = inputs["rest_length"] + self.rest_offset
        return inputs

    def reset(self, idx: np.ndarray, rngs: Sequence[np.random.Generator], options: dict | None = None) -> dict:
        """Reset copies ``idx``: robot parameters drawn first (if randomised), then the task's
        :meth:`reset_idx`; ``info["params"]`` reports the parameters when any are set."""
        dom = self.domain
        if dom.randomized:
            dom.sample(idx, rngs)
            self._apply_domain(idx)
        if self.action_delay:
            self._action_queue[idx] = 0.0
        info = self.reset_idx(idx, rngs, options)
        if dom.enabled:
            info["params"] = dom.report(idx if dom.randomized else np.zeros(len(idx), int))
        return info

    def act(self, action: np.ndarray):
        """:meth:`step` with the action delayed by ``action_delay`` control steps."""
        if self.action_delay:
            queue = self._action_queue
            out = queue[:, 0].copy()     # (a view would be overwritten by the shift below)
            queue[:, :-1] = queue[:, 1:]
            queue[:, -1] = action
            action = out
        return self.step(action)

    @property
    def control_dt(self) -> float:
        """Duration of one control step, s (``dt * frame_skip``)."""
        return self.dt * self.frame_skip

    def simulate(self, substep_external=None, **inputs) -> np.ndarray:
        """Advance all B copies by one control step (``frame_skip`` steps of ``dt``).

        ``inputs``: ``rest_length`` / ``force_density`` / ``external`` as
        :func:`tensegrity_gym.integrators.step` takes them. Without ``substep_external`` this is
        ONE call of ``integrators.step`` with ``n_steps=frame_skip`` for the whole batch. With
        ``substep_external(q, qd) -> (B, n, 3)`` nodal forces (N; e.g. drag or contact), it is one
        batched call per physics substep, the force evaluated at the substep's start and held
        over it (what semi-implicit Euler does with velocity-dependent forces anyway).

        Returns ``diverged`` (B,) bool (checked once per control step); diverged copies get
        their pre-step state back (see the module doc). Increments ``elapsed``.
        """
        q0, qd0 = self.q, self.qd
        if substep_external is None and self._compiled_physics():
            # fast path: the compiled kernel raises no floating-point warnings, so no np.errstate,
            # and one compiled pass checks the whole batch; per copy only when something is off
            st = integrators.step(self.model, dyn.State(q0, qd0, 0.0), self.dt, self.integrator,
                                  n_steps=self.frame_skip, backend=self.backend, params=self.params, **inputs)
            q, qd = st.q, st.qd
            if (type(q) is np.ndarray and type(qd) is np.ndarray and q.dtype == np.float64
                    and qd.dtype == np.float64 and q.ndim == 3 and q.shape == qd.shape
                    and _fast.state_ok(q, qd, self.center0, self.divergence_limit)):
                self.q, self.qd = q, qd
                self.elapsed += 1
                return np.zeros(self.num_envs, bool)
            return self._finish_simulate(q0, qd0, q, qd)
        with np.errstate(all="ignore"):
            if substep_external is None:
                st = integrators.step(self.model, dyn.State(q0, qd0, 0.0), self.dt, self.integrator,
                                      n_steps=self.frame_skip, backend=self.backend, params=self.params, **inputs)
            else:
                st = dyn.State(q0, qd0, 0.0)
                for _ in range(self.frame_skip):
                    st = integrators.step(self.model, st, self.dt, self.integrator, backend=self.backend,
                                          external=substep_external(st.q, st.qd), params=self.params, **inputs)
        return self._finish_simulate(q0, qd0, st.q, st.qd)

    def _compiled_physics(self) -> bool:
        """True if :meth:`simulate` runs the numba kernels (explicit integrator, numba present,
        backend not "numpy"); decided once per task."""
        c = self.__dict__.get("_compiled")
        if c is None:
            info = integrators.INTEGRATORS[self.integrator]
            try:
                c = bool(_fast.AVAILABLE and info.name in integrators._EXPLICIT
                         and integrators._use_numba(self.backend, info, None))
            except Exception:   # pragma: no cover - e.g. backend="numba" without numba: let step() raise
                c = False
            self._compiled = c
        return c

    def _finish_simulate(self, q0, qd0, q, qd) -> np.ndarray:
        """Divergence check and state update of :meth:`simulate` (the NumPy reference path)."""
        with np.errstate(all="ignore"):
            q, qd = np.asarray(q), np.asarray(qd)
            # fast path: one reduction each for the whole batch; per-copy only when something is off
            ok = np.isfinite(q.sum() + qd.sum()) and np.abs(q[..., :3] - self.center0).max() <= self.divergence_limit
            if ok:
                diverged = np.zeros(self.num_envs, bool)
            else:
                finite = np.isfinite(q).all(axis=(1, 2)) & np.isfinite(qd).all(axis=(1, 2))
                far = ~(np.abs(np.where(np.isfinite(q[..., :3]), q[..., :3], 0.0) - self.center0).max(axis=(1, 2))
                        <= self.divergence_limit)
                diverged = ~finite | far
        if diverged.any():
            q = np.where(diverged[:, None, None], q0, q)
            qd = np.where(diverged[:, None, None], qd0, qd)
        self.q, self.qd = q, qd
        self.elapsed += 1
        return diverged

    # -- to implement
    def reset_idx(self, idx: np.ndarray, rngs: Sequence[np.random.Generator], options: dict | None = None) -> dict:
        raise NotImplementedError

    def step(self, action: np.ndarray):
        raise NotImplementedError

    def observe(self) -> np.ndarray:
        raise NotImplementedError

    def render_data(self, i: int) -> dict:
        raise NotImplementedError


def _scalar(v):
    v = np.asarray(v)
    return v.item() if v.ndim == 0 else v


# ---------------------------------------------------------------------- single env shell
class TaskEnv(gym.Env):
    """``gymnasium.Env`` shell around a :class:`BatchedTask` with B = 1.

    Subclasses build their task and call ``self._init_task(task, render_mode, width, height)``.
    ``step`` validates the action (:func:`check_action`), steps the task, returns
    ``(obs, reward, terminated, truncated, info)`` with ``truncated = info["diverged"]`` (the
    time limit is added at registration by ``gymnasium.make``'s ``TimeLimit``).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 50}

    def _init_task(self, task: BatchedTask, render_mode: str | None, width: int = 480, height: int = 480,
                   title: str | None = None):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode: unknown {render_mode!r}; choose one of {self.metadata['render_modes']} or None")
        self.task = task
        self.render_mode = render_mode
        self.metadata = dict(self.metadata)
        self.metadata["render_fps"] = int(round(1.0 / task.control_dt))
        self.action_space = spaces.Box(-1.0, 1.0, (task.action_size,), np.float32)
        low = getattr(task, "obs_low", None)
        high = getattr(task, "obs_high", None)
        self.observation_space = spaces.Box(
            -np.inf if low is None else low.astype(np.float32),
            np.inf if high is None else high.astype(np.float32), (task.observation_size,), np.float32)
        self._width, self._height, self._title = int(width), int(height), title
        self._renderer = None
        self._needs_reset = True

    @property
    def dt(self) -> float:
        """Control step, s (as Gymnasium's MuJoCo envs' ``dt``)."""
        return self.task.control_dt

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        info = self.task.reset(np.array([0]), [self.np_random], options)
        self._needs_reset = False
        obs = self.task.observe()[0]
        if self.render_mode == "human":
            self.render()
        return obs, {k: ({n: x[0] for n, x in v.items()} if isinstance(v, dict) else _scalar(v[0]))
                     for k, v in info.items()}

    def step(self, action):
        a = check_action(action, (self.task.action_size,), clip=self.task.clip_actions)
        terms, terminated, infos = self.task.act(a[None, :])
        # reward: combine(terms)[0], summed here in Python floats (IEEE doubles, same order: same value)
        reward = None
        for v in terms.values():
            x = float(v[0])
            reward = x if reward is None else reward + x
        if reward is None:
            raise ValueError("combine: no reward terms given")
        info = {k: (v.item(0) if type(v) is np.ndarray and v.ndim == 1 else _scalar(v[0]))
                for k, v in infos.items()}
        for name, v in terms.items():
            info[f"reward_{name}"] = float(v[0])
        obs = self.task.observe()[0]
        truncated = bool(info.get("diverged", False))
        if self.render_mode == "human":
            self.render()
        return obs, reward, bool(terminated[0]), truncated, info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; construct the env with "
                            "render_mode='rgb_array' or 'human'")
            return None
        frame = self._frame(0)
        if self.render_mode == "human":
            self._renderer.show(frame, self.metadata["render_fps"])
            return None
        return frame

    def _frame(self, i: int) -> np.ndarray:
        from ..rendering import make_renderer
        if self._renderer is None:
            self._renderer = make_renderer(self._width, self._height, title=self._title)
        return self._renderer.render(**self.task.render_data(i))

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


# ---------------------------------------------------------------------- vector env shell
def registered_max_episode_steps(env_id: str) -> int | None:
    """``max_episode_steps`` of a registered id (None if unregistered or unlimited)."""
    from gymnasium.envs.registration import registry
    spec = registry.get(env_id)
    return None if spec is None else spec.max_episode_steps


class TaskVectorEnv(gym.vector.VectorEnv):
    """``gymnasium.vector.VectorEnv`` shell around a :class:`BatchedTask` with B = ``num_envs``.

    * One batched physics call per ``step`` for all envs (no per-env loop, no subprocess).
    * Autoreset: ``AutoresetMode.NEXT_STEP`` (Gymnasium 1.x default): after an env returns
      ``terminated`` or ``truncated``, its next ``step`` ignores its action, resets it and
      returns the reset observation with reward 0 and ``terminated = truncated = False``.
    * Seeding: ``reset(seed=s)`` seeds env i with ``s + i``; ``reset(seed=[s0, s1, ...])``
      seeds each env; each env has its own ``np.random.Generator`` created exactly as a
      single env's ``np_random``, so env i reproduces a single env reset with the same seed.
    * ``reset(options={"reset_mask": mask})`` resets only the envs where ``mask`` (bool (N,)) is true.
    * Time limit: ``max_episode_steps`` (control steps) truncates each env. ``gymnasium.make_vec``
      passes the registered value; constructed directly, the default ``"registered"`` looks
      it up for ``env_id``; ``None`` disables it.
    * ``info``: Gymnasium's vector dict: every key an (N,) array with a boolean mask ``"_key"``.
    * ``render()``: tuple of (H, W, 3) frames, one per env (``render_mode="rgb_array"``).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50,
                "autoreset_mode": gym.vector.AutoresetMode.NEXT_STEP}

    def _init_task(self, task: BatchedTask, env_id: str, max_episode_steps="registered",
                   render_mode: str | None = None, width: int = 480, height: int = 480, title: str | None = None):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode: the vector env supports {self.metadata['render_modes']} or None, "
                             f"got {render_mode!r}")
        self.task = task
        self.num_envs = task.num_envs
        if max_episode_steps == "registered":
            max_episode_steps = registered_max_episode_steps(env_id)
        if max_episode_steps is not None:
            if int(max_episode_steps) != max_episode_steps or max_episode_steps < 1:
                raise ValueError(f"max_episode_steps: must be a positive integer or None, got {max_episode_steps}")
            max_episode_steps = int(max_episode_steps)
        self.max_episode_steps = max_episode_steps
        self.metadata = dict(self.metadata)
        self.metadata["render_fps"] = int(round(1.0 / task.control_dt))
        self.render_mode = render_mode
        self.single_action_space = spaces.Box(-1.0, 1.0, (task.action_size,), np.float32)
        low = getattr(task, "obs_low", None)
        high = getattr(task, "obs_high", None)
        self.single_observation_space = spaces.Box(
            -np.inf if low is None else low.astype(np.float32),
            np.inf if high is None else high.astype(np.float32), (task.observation_size,), np.float32)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, self.num_envs)
        self._rngs: list[np.random.Generator] = [seeding.np_random(None)[0] for _ in range(self.num_envs)]
        self._autoreset = np.zeros(self.num_envs, bool)
        self._width, self._height, self._title = int(width), int(height), title
        self._renderers: dict[int, Any] = {}

    @property
    def dt(self) -> float:
        return self.task.control_dt

    @property
    def np_random_list(self) -> list[np.random.Generator]:
        """Per-env random generators."""
        return self._rngs

    def _vector_info(self, infos: dict, mask: np.ndarray, out: dict | None = None) -> dict:
        out = {} if out is None else out
        for k, v in infos.items():
            if isinstance(v, dict):          # e.g. info["params"]: a nested vector dict
                out[k] = self._vector_info(v, mask, out.get(k))
                out["_" + k] = mask.copy() if "_" + k not in out else out["_" + k] | mask
                continue
            v = np.asarray(v)
            if k in out:
                out[k][mask] = v[mask] if v.shape[:1] == (self.num_envs,) else v
                out["_" + k] |= mask
            else:
                arr = np.zeros((self.num_envs,) + v.shape[1:], dtype=v.dtype)
                arr[mask] = v[mask] if v.shape[:1] == (self.num_envs,) else v
                out[k] = arr
                out["_" + k] = mask.copy()
        return out

    def _reset_envs(self, idx: np.ndarray, options) -> dict:
        """Reset envs ``idx`` (int array); returns their infos as (N,) arrays (others zero)."""
        info = self.task.reset(idx, [self._rngs[i] for i in idx], options)
        full = {}
        for k, v in info.items():
            if isinstance(v, dict):
                full[k] = {}
                for n, x in v.items():
                    arr = np.zeros((self.num_envs,) + x.shape[1:], dtype=x.dtype)
                    arr[idx] = x
                    full[k][n] = arr
                continue
            v = np.asarray(v)
            arr = np.zeros((self.num_envs,) + v.shape[1:], dtype=v.dtype)
            arr[idx] = v
            full[k] = arr
        self.task.elapsed[idx] = 0
        self._autoreset[idx] = False
        return full

    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        super().reset(seed=None)
        N = self.num_envs
        options = dict(options) if options else {}
        mask = options.pop("reset_mask", None)
        if mask is None:
            mask = np.ones(N, bool)
        else:
            mask = np.asarray(mask)
            if mask.shape != (N,) or mask.dtype != np.bool_:
                raise ValueError(f"options['reset_mask']: expected a bool array of shape ({N},), "
                                 f"got {mask.dtype} {mask.shape}")
        if seed is None:
            seeds = [None] * N
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(N)]
        else:
            seeds = list(seed)
            if len(seeds) != N:
                raise ValueError(f"seed: expected an int, None or a list of {N} seeds, got {len(seeds)}")
        for i in range(N):
            if mask[i] and seeds[i] is not None:
                self._rngs[i] = seeding.np_random(int(seeds[i]))[0]
        idx = np.flatnonzero(mask)
        info = self._reset_envs(idx, options or None)
        return self.task.observe().copy(), self._vector_info(info, mask)

    def step(self, actions):
        N = self.num_envs
        a = check_action(actions, (N, self.task.action_size), clip=self.task.clip_actions, name="actions")
        reset_now = self._autoreset.copy()
        # envs to autoreset get zero actions in the physics step, then are reset (their step is discarded)
        if reset_now.any():
            a = a.copy()
            a[reset_now] = 0.0
        terms, terminated, infos = self.task.act(a)
        reward = combine(terms).astype(np.float64)
        terminated = np.asarray(terminated, bool).copy()
        diverged = np.asarray(infos.get("diverged", np.zeros(N, bool)), bool)
        truncated = diverged.copy()
        if self.max_episode_steps is not None:
            truncated |= self.task.elapsed >= self.max_episode_steps
        step_mask = ~reset_now
        all_infos = dict(infos)
        for name, v in terms.items():
            all_infos[f"reward_{name}"] = v
        out = self._vector_info(all_infos, step_mask)
        if reset_now.any():
            idx = np.flatnonzero(reset_now)
            rinfo = self._reset_envs(idx, None)
            self._vector_info(rinfo, reset_now, out)
            reward[reset_now] = 0.0
            terminated[reset_now] = False
            truncated[reset_now] = False
        self._autoreset = terminated | truncated
        return self.task.observe().copy(), reward, terminated, truncated, out

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; use render_mode='rgb_array'")
            return None
        from ..rendering import make_renderer
        frames = []
        for i in range(self.num_envs):
            if i not in self._renderers:
                self._renderers[i] = make_renderer(self._width, self._height, title=self._title)
            frames.append(self._renderers[i].render(**self.task.render_data(i)))
        return tuple(frames)

    def close_extras(self, **kwargs):
        self._renderers.clear()


# ---------------------------------------------------------------------- SB3 adapter
# moved to tensegrity_gym.sb3; imported here for backwards compatibility
from ..sb3 import make_sb3_vec_env  # noqa: E402,F401
