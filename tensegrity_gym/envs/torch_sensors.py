"""The robot observation (``observation_mode="robot"``, :mod:`tensegrity_gym.envs.sensors`) of the
device-resident torch vector envs: the same readings, computed on the device (SI units).

The NumPy :class:`~tensegrity_gym.envs.sensors.RobotSensors` stays the definition (blocks, rod
frame, accelerometer and gyroscope, noise, history); :class:`TorchSensors` is its torch backend,
the equations of :meth:`RobotSensors.frame` written once more in torch, as
:mod:`tensegrity_gym.torch_backend` is for the physics. What differs:

* **reset readings** are the host task's own (``RollTask`` / ``ShapeTask`` compute them at reset
  with each env's generator, as the NumPy env does), copied to the device with the reset rows;
  with ``reset_sampling="device"`` they are computed here (:meth:`TorchSensors.reset_rows`: the
  robot at rest, its noise from the device generator below);
* **noise of later readings** (``sensor_noise``) comes from ONE ``torch.Generator`` on the
  device, seeded from ``reset(seed=...)`` (an int, or the list of per-env seeds; a fresh random
  seed when the first reset has none), not from the per-env NumPy generators: a step reads no
  host random numbers. Same seed, same noise on the same device; the noisy readings are not
  equal number for number to the NumPy env's (without noise they are, to round-off:
  ``tests/test_torch_env.py``).
"""
from __future__ import annotations

import numpy as np

from .. import torch_backend as tb

__all__ = ["TorchSensors", "rod_frames"]

#: mixes the user's seed so that the device noise stream is not the NumPy generators' stream
_NOISE_SALT = 0x5E4503


def rod_frames(b):
    """(B, k, 3, 3) rows x, y, z of each rod's frame from unit axes ``b`` (B, k, 3) (as
    :func:`tensegrity_gym.envs.sensors.rod_frames`: x = world up made perpendicular to the rod,
    the world x axis the same way within 1e-6 of vertical; y = z x x)."""
    torch = tb._torch()
    up = torch.zeros_like(b)
    up[..., 2] = 1.0
    x = up - b * b[..., 2:3]
    nx = torch.linalg.vector_norm(x, dim=-1, keepdim=True)
    vertical = nx < 1e-6
    ex = torch.zeros_like(b)
    ex[..., 0] = 1.0
    alt = ex - b * b[..., 0:1]
    x = torch.where(vertical, alt, x)
    nx = torch.where(vertical, torch.linalg.vector_norm(alt, dim=-1, keepdim=True), nx)
    x = x / nx
    y = torch.linalg.cross(b, x, dim=-1)
    return torch.stack([x, y, b], dim=-2)


class TorchSensors:
    """Readings (history x frame, newest first) of a torch vector env's robot observation.

    ``sens``: the host task's :class:`~tensegrity_gym.envs.sensors.RobotSensors`; ``env``: the
    :class:`~tensegrity_gym.envs.torch_vec._TorchTaskVectorEnv` (device, dtype, model)."""

    def __init__(self, sens, env):
        torch = tb._torch()
        self.sens = sens
        self.env = env
        self.blocks = [name for name, _, _ in sens.blocks]
        self.noise = [(sl, float(s), flip) for sl, s, flip in sens.noise]
        self.com_eta = env._T(sens.model.com_eta)[None, :, None]
        g = sens.model.gravity
        self.gravity0 = env._T(np.zeros(3) if g is None else np.asarray(g, float))[None]
        self.readings = torch.zeros((env.num_envs, sens.history, sens.frame_size), dtype=env.dtype,
                                    device=env.device)
        self.generator = torch.Generator(device=env.device)
        self._seeded = False

    def seed(self, seed) -> None:
        """Seed the device noise generator from ``reset(seed=...)``: an int or a list of per-env
        seeds (None entries skipped); None seeds it randomly once, at the first reset."""
        if seed is None:
            if not self._seeded:
                self.generator.seed()
                self._seeded = True
            return
        parts = [int(s) for s in (seed if isinstance(seed, (list, tuple, np.ndarray)) else [seed]) if s is not None]
        if not parts:
            return
        state = np.random.SeedSequence([*parts, _NOISE_SALT]).generate_state(1, np.uint64)[0]
        self.generator.manual_seed(int(state) & ((1 << 63) - 1))
        self._seeded = True

    def upload_reset(self, it, host_readings) -> None:
        """Reset rows ``it`` get the host task's reset readings (r, history, frame_size)."""
        self.readings[it] = self.env._T(host_readings)

    def frame(self, q, qd, qd_prev, ctrl, speed, contact, command, gravity=None):
        """(N, frame_size) readings after a control step (:meth:`RobotSensors.frame` in torch):
        state ``q``, ``qd`` (N, k, 6), the velocities one physics step earlier ``qd_prev`` (None:
        at rest, as at a reset), controls, motor speeds, contact flags (N, 2k) bool (None where
        the env has no such block), the command (N, size); ``gravity`` (N or 1, 3) m/s^2, default
        the copies' own (:meth:`gravity`)."""
        torch = tb._torch()
        env = self.env
        N = q.shape[0]
        _, L, _ = tb.string_state(env.tm, q, qd, env._node_prm, False)
        b, bd = q[..., 3:], qd[..., 3:]
        R = rod_frames(b)
        if qd_prev is None:
            acc = torch.zeros_like(q[..., :3])
        else:
            d = (qd - qd_prev) / env.task.dt
            acc = d[..., :3] + self.com_eta * d[..., 3:]
        spec = acc - (self.gravity() if gravity is None else gravity)[:, None, :]
        omega = torch.linalg.cross(b, bd, dim=-1)
        parts = {"cable_length": L, "control": ctrl, "cable_speed": speed,
                 "imu_accel": torch.einsum("bkij,bkj->bki", R, spec).reshape(N, 3 * env.tm.k),
                 "imu_gyro": torch.einsum("bkij,bkj->bki", R, omega).reshape(N, 3 * env.tm.k),
                 "contact": None if contact is None else contact.to(q.dtype),
                 self.sens.command[0]: command.reshape(N, self.sens.command[1])}
        out = torch.cat([parts[name] for name in self.blocks], dim=1)
        for sl, s, flip in self.noise:
            shape = (N, sl.stop - sl.start)
            if flip:       # contact switches: each reads wrong with probability s
                wrong = torch.rand(shape, generator=self.generator, dtype=out.dtype, device=out.device) < s
                out[:, sl] = torch.where(wrong, 1.0 - out[:, sl], out[:, sl])
            else:
                out[:, sl] += s * torch.randn(shape, generator=self.generator, dtype=out.dtype, device=out.device)
        return out

    def reset_rows(self, it, q, qd, ctrl, speed, contact, command) -> None:
        """Envs ``it`` (a device reset, ``reset_sampling="device"``): every history slot holds the
        reading at rest (no IMU acceleration but gravity), noise from the device generator, as
        the host task's reset readings."""
        g = self.gravity()
        if g.shape[0] > 1:
            g = g[it]
        f = self.frame(q, qd, None, ctrl, speed, contact, command, gravity=g)
        self.readings[it] = f[:, None, :].expand(-1, self.readings.shape[1], -1)

    def record(self, *args) -> None:
        """Push :meth:`frame` ``(*args)`` into the history (newest first)."""
        torch = tb._torch()
        self.readings = torch.cat([self.frame(*args)[:, None], self.readings[:, :-1]], dim=1)

    def gravity(self):
        """(P, 3) gravity of the copies (the robots' own with ``params``), m/s^2."""
        prm = self.env._params
        return self.gravity0 if prm is None else prm["gravity"].reshape(-1, 3)

    def observation(self):
        """(N, history x frame_size) in the env's dtype."""
        return self.readings.reshape(self.readings.shape[0], -1)
