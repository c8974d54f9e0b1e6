"""Actuation of a set of strings, batched: rest-length or force-density controls with rate
limits and the cable motor model. SI units. No gymnasium import (a physics-layer module).

:meth:`Actuation.update` is the one entry that turns actions in [-1, 1] (B, na) into new
controls, the motor's new cable speeds and the ``rest_length`` / ``force_density`` inputs of
:func:`tensegrity_gym.physics.pipeline.step`; :func:`tensegrity_gym.physics.pipeline.control_step`
runs it and the physics in one call. The update itself is compiled, written once:
:func:`tensegrity_gym.backends.numba.actuation.apply_controls` /
:func:`~tensegrity_gym.backends.numba.actuation.apply_motor` (their NumPy reference is the test
oracle ``tests/oracle_numpy.py``; the torch backend's twin is
:func:`tensegrity_gym.backends.torch.actuation.update_rate` / ``update_motor``).
"""
from __future__ import annotations

import numpy as np

from ..backends.numba.actuation import apply_controls, apply_motor
from ..core.checks import check_positive

__all__ = ["ACTION_MODES", "Actuation"]

#: the control modes of an actuated string: its rest length (m) or its force density (N/m)
ACTION_MODES = ("rest_length", "force_density")


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
    [``low``, ``high``] (:meth:`update_rate`).

    With ``max_accel`` (a motor model, :meth:`update_motor`) the action commands the rate
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

    @classmethod
    def for_task(cls, mode: str, actuated, rest_length, bounds, max_speed: float, control_dt: float, gamma_nominal,
                 force_density_max: float | None = None, force_density_rate: float | None = None,
                 max_accel: float | None = None) -> "Actuation":
        """The actuation of a task's strings ``actuated`` (rest lengths ``rest_length`` (m,) m, force
        densities ``gamma_nominal`` (m,) N/m at rest). ``"rest_length"``: within ``bounds`` (low,
        high fractions of the rest lengths), at most ``max_speed`` m/s (a motor with ``max_accel``
        m/s^2 if given). ``"force_density"``: within [0, ``force_density_max``] N/m (default 3x the
        largest nominal), at most ``force_density_rate`` N/(m s) (default twice the maximum per s)."""
        if mode not in ACTION_MODES:
            raise ValueError(f"action_mode: unknown {mode!r}; choose one of {ACTION_MODES}")
        l0 = np.asarray(rest_length, float)[actuated]
        if mode == "rest_length":
            for name, v in (("force_density_max", force_density_max), ("force_density_rate", force_density_rate)):
                if v is not None:   # not silently ignored
                    raise ValueError(f"{name}: only with action_mode='force_density' (this task has "
                                     f"action_mode='rest_length'), got {v!r}")
            lo, hi = bounds
            return cls("rest_length", actuated, lo * l0, hi * l0, max_speed, control_dt, rest_length, l0,
                       max_accel=max_accel)
        g0 = np.asarray(gamma_nominal, float)[actuated]
        fmax = 3.0 * float(g0.max()) if force_density_max is None else check_positive(
            force_density_max, "force_density_max", "N/m")
        frate = 2.0 * fmax if force_density_rate is None else check_positive(
            force_density_rate, "force_density_rate", "N/(m s)")
        return cls("force_density", actuated, 0.0, fmax, frate, control_dt, rest_length, g0)

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

    def physics_inputs(self, ctrl: np.ndarray) -> dict:
        """Keyword arguments ``rest_length`` / ``force_density`` (B, m) for :func:`tensegrity_gym.physics.step`."""
        phys = np.empty((ctrl.shape[0], self.n_strings))
        phys[:] = self.base_rest_length if self.mode == "rest_length" else 0.0
        phys[:, self.actuated] = ctrl
        return self._inputs(phys)

    def _batch(self, ctrl, *others) -> tuple:
        """``ctrl`` (B, na) and the other (B, na) arrays as C-contiguous float64 (the compiled
        update's inputs); ValueError naming the array and its shape otherwise."""
        ctrl = np.ascontiguousarray(ctrl, dtype=np.float64)
        if ctrl.ndim != 2 or ctrl.shape[1] != self.size:
            raise ValueError(f"ctrl: expected shape (B, {self.size}), got {ctrl.shape}")
        out = [ctrl]
        for name, x in others:
            x = np.ascontiguousarray(x, dtype=np.float64)
            if x.shape != ctrl.shape:
                raise ValueError(f"{name}: expected shape {ctrl.shape} (as ctrl), got {x.shape}")
            out.append(x)
        return tuple(out)

    def _inputs(self, phys: np.ndarray) -> dict:
        """The keyword arguments of :func:`tensegrity_gym.physics.step` for the physics input ``phys`` (B, m)."""
        return {"rest_length": phys} if self.mode == "rest_length" else {"rest_length": None, "force_density": phys}

    def update_rate(self, ctrl: np.ndarray, action: np.ndarray) -> tuple[np.ndarray, dict]:
        """``(new, physics_inputs(new))`` without a motor model: ``new = clip(ctrl + action *
        max_rate * control_dt, low, high)`` (B, na) from the current control and an action in
        [-1, 1] (B, na). One compiled call (:func:`tensegrity_gym.backends.numba.actuation.apply_controls`)."""
        ctrl, action = self._batch(ctrl, ("action", action))
        new = np.empty(ctrl.shape)
        phys = np.empty((ctrl.shape[0], self.n_strings))
        apply_controls(ctrl, action, self._rate, self.low, self.high, self.actuated,
                                self.base_rest_length, self.mode == "rest_length", new, phys)
        return new, self._inputs(phys)

    def update_motor(self, ctrl: np.ndarray, speed: np.ndarray,
                     action: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
        """``(new, new_speed, physics_inputs(new))`` of the motor model (needs ``max_accel``; see
        the class doc) from the current control, the current rate ``speed`` (unit/s) and an
        action in [-1, 1], all (B, na). One compiled call
        (:func:`tensegrity_gym.backends.numba.actuation.apply_motor`)."""
        if self.max_accel is None:
            raise ValueError("update_motor: this Actuation has no max_accel (use update_rate)")
        ctrl, speed, action = self._batch(ctrl, ("speed", speed), ("action", action))
        new = np.empty(ctrl.shape)
        v = np.empty(ctrl.shape)
        phys = np.empty((ctrl.shape[0], self.n_strings))
        apply_motor(ctrl, speed, action, self.rate_rows, self._dv, self.control_dt, self.low, self.high,
                             self.actuated, self.base_rest_length, self.mode == "rest_length", new, v, phys)
        return new, v, self._inputs(phys)

    def update(self, ctrl: np.ndarray, action: np.ndarray, speed: np.ndarray | None = None,
               rest_offset: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None, dict]:
        """One control step of the actuation: ``(new control (B, na), new cable speed (B, na) or
        None, physics inputs)`` from the current control (B, na), an action in [-1, 1] (B, na)
        and, with a motor model (``max_accel``), the current speed (B, na) (unit/s).

        Without a motor model it is :meth:`update_rate` (``speed`` is ignored and returned as
        given); with one, :meth:`update_motor`. ``rest_offset`` (P, m) m, P = 1 or B: true minus
        commanded rest lengths of the robots (``rest_length_offset``), added to the
        ``rest_length`` input (rest-length mode only; ignored for force densities).
        ValueError if a motor model has no ``speed`` of shape (B, na)."""
        if self.max_accel is None:
            new, inputs = self.update_rate(ctrl, action)
        else:
            if speed is None or np.shape(speed) != np.shape(ctrl):
                raise ValueError(f"speed: the motor model needs the cable speeds, shape {np.shape(ctrl)} "
                                 f"(unit/s), got {None if speed is None else np.shape(speed)}")
            new, speed, inputs = self.update_motor(ctrl, speed, action)
        rl = inputs.get("rest_length")
        if rest_offset is not None and rl is not None:
            rl += rest_offset        # a fresh (B, m) array of this call: += is rl + rest_offset
        return new, speed, inputs

    #: the names these updates had before (the same methods)
    advance = update_rate
    advance_motor = update_motor

    def describe(self) -> str:
        acc = "" if self.max_accel is None else f", max rate change {self.max_accel:.4g} {self.unit}/s^2"
        return (f"{self.mode}: strings {self.actuated.tolist()}, bounds [{self.low.min():.4g}, "
                f"{self.high.max():.4g}] {self.unit}, max rate {self.max_rate.max():.4g} {self.unit}/s" + acc)

