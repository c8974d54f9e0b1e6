"""What a lab tensegrity robot senses (``observation_mode="robot"``), with optional Gaussian
sensor noise and a history of past readings (SI units).

One reading (``frame``) holds, in this order:

=====================  ==========  =======  =============================================================
block                  size        unit     meaning
=====================  ==========  =======  =============================================================
``cable_length``       m           m        length |s| of every string (a length sensor / cable encoder)
``control``            na          m        each actuated cable's motor encoder: its rest length
                                            (N/m: the commanded force density in force-density mode)
``cable_speed``        na          m/s      each motor's cable speed (only with the motor model)
``imu_accel``          3 k         m/s^2    each rod's accelerometer at its centre of mass, in the rod
                                            frame: specific force a - g (at rest: +9.81 along the frame's
                                            "up"; in free fall: 0)
``imu_gyro``           3 k         rad/s    each rod's angular velocity in the rod frame (the z component,
                                            about the rod's own axis, is 0: a rod has no roll in this model)
``contact``            2 k         1        end-cap contact switches (1 = touching the ground)
``goal_direction``     2           1        the commanded heading (x, y) (a command, not a sensor)
=====================  ==========  =======  =============================================================

Rod frame (the rod's own axis carries no roll, so the frame is fixed by gravity): ``z`` is the rod
axis ``b`` (node a to node c); ``x`` is the world "up" (0, 0, 1) made perpendicular to ``b``
(``(up - (up.b) b) / |...|``), or the world x axis the same way when the rod is within 1e-6 rad of
vertical; ``y = z x x``. The accelerometer reads the rod centre's acceleration averaged over the
last physics step, ``(v(t) - v(t - dt)) / dt`` (exactly the acceleration semi-implicit Euler applied),
minus gravity; at reset it reads ``-g`` (the robot starts at rest). The gyroscope reads
``b x b'``.

``sensor_noise={block: sigma}`` adds N(0, sigma^2) to every entry of a block (SI units; the
contact switches and the goal are not noisy), drawn from the copy's own generator (the env's
``np_random``) once per control step. ``history=H`` stacks the last H readings, newest first
(at reset all H are the reset reading), so a policy can infer rates.
"""
from __future__ import annotations

import numpy as np

from .. import dynamics as dyn

__all__ = ["NOISY_BLOCKS", "rod_frames", "RobotSensors"]

NOISY_BLOCKS = ("cable_length", "control", "cable_speed", "imu_accel", "imu_gyro")


def rod_frames(b: np.ndarray) -> np.ndarray:
    """(B, k, 3, 3) rows x, y, z of each rod's frame (world coordinates) from unit axes b (B, k, 3)."""
    up = np.array([0.0, 0.0, 1.0])
    x = up - b * b[..., 2:3]
    nx = np.linalg.norm(x, axis=-1, keepdims=True)
    vertical = nx[..., 0] < 1e-6
    if vertical.any():
        ex = np.array([1.0, 0.0, 0.0])
        alt = ex - b * b[..., 0:1]
        x = np.where(vertical[..., None], alt, x)
        nx = np.linalg.norm(x, axis=-1, keepdims=True)
    x = x / nx
    y = np.cross(b, x)
    return np.stack([x, y, b], axis=-2)


class RobotSensors:
    """The robot reading of a batched task (see the module doc)."""

    def __init__(self, model, n_actuated: int, n_speed: int, n_contacts: int, noise: dict | None = None,
                 history: int = 1, control_unit: str = "m"):
        self.model = model
        k, m = model.n_bars, model.n_strings
        self.blocks = [("cable_length", m, "m"), ("control", n_actuated, control_unit), ("cable_speed", n_speed, "m/s"),
                       ("imu_accel", 3 * k, "m/s^2"), ("imu_gyro", 3 * k, "rad/s"), ("contact", n_contacts, "1"),
                       ("goal_direction", 2, "1")]
        self.blocks = [b for b in self.blocks if b[1] > 0]
        self.frame_size = sum(b[1] for b in self.blocks)
        if isinstance(history, (bool, np.bool_)) or int(history) != history or history < 1:
            raise ValueError(f"history: must be a positive integer (readings stacked), got {history!r}")
        self.history = int(history)
        noise = {} if noise is None else noise
        if not isinstance(noise, dict):
            raise ValueError(f"sensor_noise: expected a dict {{block: sigma}}, got {type(noise).__name__}")
        names = [b[0] for b in self.blocks]
        self.noise = []
        for name, sigma in sorted(noise.items()):
            if name not in NOISY_BLOCKS or name not in names:
                raise ValueError(f"sensor_noise: unknown or noiseless block {name!r}; noisy blocks of this env: "
                                 f"{[n for n in NOISY_BLOCKS if n in names]}")
            try:
                s = float(sigma)
            except (TypeError, ValueError):
                raise ValueError(f"sensor_noise[{name!r}]: expected a standard deviation (number), got {sigma!r}") from None
            if isinstance(sigma, bool) or not (np.isfinite(s) and s >= 0):
                raise ValueError(f"sensor_noise[{name!r}]: must be a finite standard deviation >= 0, got {sigma!r}")
            if s > 0:
                i = names.index(name)
                start = sum(b[1] for b in self.blocks[:i])
                self.noise.append((slice(start, start + self.blocks[i][1]), s))

    @property
    def size(self) -> int:
        return self.frame_size * self.history

    def layout(self) -> list[tuple[str, slice, str]]:
        """(name, slice, unit) of each block of the newest reading (the first ``frame_size`` entries)."""
        out, i = [], 0
        for name, sz, unit in self.blocks:
            out.append((name, slice(i, i + sz), unit))
            i += sz
        return out

    def frame(self, q, qd, qd_prev, dt: float, gravity, ctrl, speed, contact, goal, rngs) -> np.ndarray:
        """(r, frame_size) float64 readings of r copies: state ``q``, ``qd`` (r, k, 6), the rod
        velocities one physics step ``dt`` earlier ``qd_prev`` (None: at rest), ``gravity`` (3,)
        or (r, 3) m/s^2, controls (r, na), motor speeds (r, n_speed), contact flags (r, 2k),
        goal (r, 2); noise from ``rngs`` (one generator per copy)."""
        model = self.model
        r = q.shape[0]
        _, L, _ = dyn.string_state(model, q)
        b, bd = q[..., 3:], qd[..., 3:]
        R = rod_frames(b)
        if qd_prev is None:
            acc = np.zeros((r, model.n_bars, 3))
        else:
            d = (qd - qd_prev) / dt
            acc = d[..., :3] + model.com_eta[None, :, None] * d[..., 3:]
        g = np.broadcast_to(np.asarray(gravity, float), (r, 3))
        spec = acc - g[:, None, :]
        omega = np.cross(b, bd)
        parts = {"cable_length": L, "control": ctrl, "cable_speed": speed,
                 "imu_accel": np.einsum("bkij,bkj->bki", R, spec).reshape(r, -1),
                 "imu_gyro": np.einsum("bkij,bkj->bki", R, omega).reshape(r, -1),
                 "contact": contact.astype(float), "goal_direction": goal}
        out = np.concatenate([parts[name] for name, _, _ in self.blocks], axis=1)
        for j in range(r) if self.noise else ():
            for sl, s in self.noise:
                out[j, sl] += rngs[j].normal(0.0, s, sl.stop - sl.start)
        return out
