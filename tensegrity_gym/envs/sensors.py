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
command                            the task's command (not a sensor), as its state mode gives it:
``goal_direction``     2           1        ``TensegrityRoll-v0``: the commanded heading (x, y)
``target_position``    3 nt        m        ``TensegrityShape-v0``: the target positions of the tracked nodes
=====================  ==========  =======  =============================================================

Blocks an env does not have are left out (no ``cable_speed`` without the motor model, no
``contact`` without ground contact: ``TensegrityShape-v0`` has neither).

Rod frame (the rod's own axis carries no roll, so the frame is fixed by gravity): ``z`` is the rod
axis ``b`` (node a to node c); ``x`` is the world "up" (0, 0, 1) made perpendicular to ``b``
(``(up - (up.b) b) / |...|``), or the world x axis the same way when the rod is within 1e-6 rad of
vertical; ``y = z x x``. The accelerometer reads the rod centre's acceleration averaged over the
last physics step, ``(v(t) - v(t - dt)) / dt`` (exactly the acceleration semi-implicit Euler applied),
minus gravity; at reset it reads ``-g`` (the robot starts at rest). The gyroscope reads
``b x b'``.

``sensor_noise={block: sigma}`` adds N(0, sigma^2) to every entry of a block (SI units; the goal
is not noisy), drawn from the copy's own generator (the env's ``np_random``) once per control
step. For the ``contact`` switches the value is instead a probability p in [0, 1]: each switch
reads wrong (0 for 1, 1 for 0) with probability p, independently per reading. ``history=H``
stacks the last H readings, newest first (at reset all H are the reset reading), so a policy can
infer rates.

A task uses this module through :meth:`RobotSensors.attach` (construction),
:meth:`RobotSensors.reset_reading` (reset), :meth:`RobotSensors.simulate` (its physics for one
control step, split so that the IMUs see the last physics step) and :meth:`RobotSensors.record`
(after the step); ``TensegrityRoll-v0`` keeps its own stepping loop (contact) and calls
:meth:`RobotSensors.frame` itself.
"""
from __future__ import annotations

import numpy as np

from ..physics.geometry import string_state
from ..tasks.sensors import add_noise, reading, rod_frames
from .limits import check_noise_sigma

__all__ = ["NOISY_BLOCKS", "rod_frames", "RobotSensors"]

NOISY_BLOCKS = ("cable_length", "control", "cable_speed", "imu_accel", "imu_gyro", "contact")


class RobotSensors:
    """The robot reading of a batched task (see the module doc)."""

    def __init__(self, model, n_actuated: int, n_speed: int, n_contacts: int, noise: dict | None = None,
                 history: int = 1, control_unit: str = "m", command: tuple = ("goal_direction", 2, "1")):
        """``command``: (name, size, unit) of the task's command block, the last of a reading."""
        self.model = model
        k, m = model.n_bars, model.n_strings
        self.command = tuple(command)
        self.blocks = [("cable_length", m, "m"), ("control", n_actuated, control_unit), ("cable_speed", n_speed, "m/s"),
                       ("imu_accel", 3 * k, "m/s^2"), ("imu_gyro", 3 * k, "rad/s"), ("contact", n_contacts, "1"),
                       self.command]
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
            flip = name == "contact"          # a switch: the probability of a wrong reading
            s = check_noise_sigma(name, sigma, flip)
            if s > 0:
                i = names.index(name)
                start = sum(b[1] for b in self.blocks[:i])
                self.noise.append((slice(start, start + self.blocks[i][1]), s, flip))

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

    def frame(self, q, qd, qd_prev, dt: float, gravity, ctrl, speed, contact, command, rngs) -> np.ndarray:
        """(r, frame_size) float64 readings of r copies: state ``q``, ``qd`` (r, k, 6), the rod
        velocities one physics step ``dt`` earlier ``qd_prev`` (None: at rest), ``gravity`` (3,)
        or (r, 3) m/s^2, controls (r, na), motor speeds (r, n_speed), contact flags (r, 2k)
        (``speed`` / ``contact`` unused, may be None, when the env has no such block), the
        command (r, size) (the goal (r, 2) of the roll task); noise from ``rngs`` (one generator
        per copy)."""
        model = self.model
        r = q.shape[0]
        _, L, _ = string_state(model, q)
        g = np.asarray(gravity, float).reshape(-1, 3)
        out = reading([name for name, _, _ in self.blocks], L, q, qd, qd_prev, dt, model.com_eta[None, :, None], g,
                      ctrl, speed, contact, np.asarray(command, float).reshape(r, self.command[1]))
        if self.noise and r:
            # per copy, per noisy block in order: the copy's generator's draws
            per_copy = [[rngs[j].random(sl.stop - sl.start) if flip else rngs[j].normal(0.0, s, sl.stop - sl.start)
                         for sl, s, flip in self.noise] for j in range(r)]
            add_noise(out, self.noise, [np.stack([d[i] for d in per_copy]) for i in range(len(self.noise))])
        return out

    # ------------------------------------------------------------------ the task side
    @staticmethod
    def check_mode(observation_mode: str, sensor_noise: dict | None, history: int) -> bool:
        """Validate the observation arguments of a task; True in robot mode, False in state mode."""
        if observation_mode not in ("state", "robot"):
            raise ValueError(f"observation_mode: unknown {observation_mode!r}; choose 'state' or 'robot'")
        if observation_mode == "state" and (sensor_noise or history != 1):
            raise ValueError("sensor_noise / history: only with observation_mode='robot'")
        return observation_mode == "robot"

    @classmethod
    def attach(cls, task, observation_mode: str, sensor_noise: dict | None, history: int, command: tuple,
               n_speed: int = 0, n_contacts: int = 0) -> "RobotSensors | None":
        """Validate ``observation_mode`` / ``sensor_noise`` / ``history`` for ``task`` (a
        :class:`~tensegrity_gym.envs.common.BatchedTask` whose ``model``, ``actuation`` and
        ``num_envs`` are set) and, in robot mode, set its ``observation_size`` and reading buffers.
        Returns the sensors, or None in state mode (nothing of the task is touched then)."""
        if not cls.check_mode(observation_mode, sensor_noise, history):
            return None
        act = task.actuation
        sens = cls(task.model, act.actuated.size, n_speed, n_contacts, sensor_noise, history, act.unit, command)
        B = task.num_envs
        task.observation_size = sens.size
        task._readings = np.zeros((B, sens.history, sens.frame_size))
        task._sensor_rngs = [None] * B
        task._qd_prev = None
        task.track_last_velocity = True   # BatchedTask.simulate keeps the last physics step's start velocities
        return sens

    @staticmethod
    def gravity(task, idx) -> np.ndarray:
        """(r, 3) or (3,) gravity of copies ``idx`` of ``task``, m/s^2 (the robot's own with ``params``)."""
        if task.params is not None:
            g = task.params.gravity
            return g[idx] if g.shape[0] > 1 else g[0]
        return np.zeros(3) if task.model.gravity is None else np.asarray(task.model.gravity, float)

    def reset_reading(self, task, idx: np.ndarray, rngs, command, speed=None, contact=None) -> None:
        """The reset reading of copies ``idx`` (at rest: the IMUs read -g), copied into every
        history slot; the copies' generators ``rngs`` are kept for the noise of later readings."""
        for j, i in enumerate(idx):
            task._sensor_rngs[i] = rngs[j]
        frame = self.frame(task.q[idx], task.qd[idx], None, task.dt, self.gravity(task, idx), task.ctrl[idx],
                           speed, contact, command, rngs)
        task._readings[idx] = frame[:, None, :]

    def record(self, task, command, speed=None, contact=None) -> None:
        """Push the reading after a control step into the history (newest first)."""
        frame = self.frame(task.q, task.qd, task._qd_prev, task.dt, self.gravity(task, slice(None)), task.ctrl,
                           speed, contact, command, task._sensor_rngs)
        R = task._readings
        R[:, 1:] = R[:, :-1].copy()
        R[:, 0] = frame

    @staticmethod
    def observation(task) -> np.ndarray:
        """(B, history x frame_size) float32: the readings, newest first."""
        return task._readings.reshape(task.num_envs, -1).astype(np.float32)
