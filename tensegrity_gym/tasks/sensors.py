"""One reading of the robot's sensors (``observation_mode="robot"``), written once for NumPy arrays
and torch tensors (:mod:`tensegrity_gym.tasks.xp`). SI units.

The blocks, the rod frame, the IMU model and the noise model are described in
:mod:`tensegrity_gym.envs.sensors`, whose :class:`~tensegrity_gym.envs.sensors.RobotSensors`
(NumPy envs) and :class:`~tensegrity_gym.envs.torch_sensors.TorchSensors` (device envs) keep
the readings' history and draw the noise from their own random streams; both compute a reading
with :func:`reading` and add the noise with :func:`add_noise`.
"""
from __future__ import annotations

from .xp import namespace

__all__ = ["rod_frames", "reading", "add_noise"]


def rod_frames(b):
    """(B, k, 3, 3) rows x, y, z of each rod's frame (world coordinates) from unit axes ``b``
    (B, k, 3): z = b; x = the world up (0, 0, 1) made perpendicular to b, or the world x axis
    the same way within 1e-6 of vertical; y = z x x."""
    xp = namespace(b)
    up = xp.const([0.0, 0.0, 1.0], b)
    ex = xp.const([1.0, 0.0, 0.0], b)
    x = up - b * b[..., 2:3]
    alt = ex - b * b[..., 0:1]
    vertical = xp.norm(x, keepdims=True) < 1e-6
    x = xp.where(vertical, alt, x)
    x = x / xp.norm(x, keepdims=True)
    y = xp.cross(b, x)
    return xp.stack([x, y, b], axis=-2)


def reading(blocks, string_length, q, qd, qd_prev, dt: float, com_eta, gravity, ctrl, speed, contact, command):
    """(B, frame size) clean reading of B copies: the ``blocks`` (names, in order) of
    ``cable_length`` ``string_length`` (B, m) m, ``control`` ``ctrl`` (B, na), ``cable_speed``
    ``speed`` (B, ns) m/s, ``imu_accel`` / ``imu_gyro`` (3 k each, rod frames), ``contact``
    ``contact`` (B, nc) bool, and the command block (any other name) ``command`` (B, size).

    State ``q``, ``qd`` (B, k, 6); ``qd_prev`` (B, k, 6) the velocities one physics step ``dt``
    (s) earlier, or None for a robot at rest; ``com_eta`` (1, k, 1) each rod's centre-of-mass
    position along its axis; ``gravity`` (B or 1, 3) m/s^2. The accelerometer reads the rod
    centre's mean acceleration over the last step minus gravity; the gyroscope ``b x b'``."""
    xp = namespace(q)
    B, k = q.shape[0], q.shape[1]
    b, bd = q[..., 3:], qd[..., 3:]
    R = rod_frames(b)
    if qd_prev is None:
        acc = xp.zeros_like(q[..., :3])
    else:
        d = (qd - qd_prev) / dt
        acc = d[..., :3] + com_eta * d[..., 3:]
    spec = acc - gravity[:, None, :]
    omega = xp.cross(b, bd)
    parts = {"cable_length": string_length, "control": ctrl, "cable_speed": speed,
             "imu_accel": xp.einsum("bkij,bkj->bki", R, spec).reshape(B, 3 * k),
             "imu_gyro": xp.einsum("bkij,bkj->bki", R, omega).reshape(B, 3 * k),
             "contact": None if contact is None else xp.to_float(contact, q)}
    return xp.concat([parts[name] if name in parts else command for name in blocks], axis=1)


def add_noise(out, noise, draws) -> None:
    """Add the sensor noise to the readings ``out`` (B, frame size) in place: ``noise`` is a list of
    (slice, sigma or probability, flip) per noisy block, ``draws`` the matching list of (B, n)
    random numbers: N(0, sigma^2) samples for a Gaussian block (added), U(0, 1) uniforms for a
    block of switches (``flip``: a switch reads wrong where its uniform is below the
    probability)."""
    xp = namespace(out)
    for (sl, s, flip), v in zip(noise, draws):
        if flip:
            out[:, sl] = xp.where(v < s, 1.0 - out[:, sl], out[:, sl])
        else:
            out[:, sl] += v
