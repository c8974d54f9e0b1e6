"""The robot observation (``observation_mode="robot"``, :mod:`tensegrity_gym.envs.sensors`) of the
device-resident torch vector envs: the same readings, computed on the device (SI units).

The NumPy :class:`~tensegrity_gym.envs.sensors.RobotSensors` stays the definition (blocks, rod
frame, accelerometer and gyroscope, noise, history); :class:`TorchSensors` is its torch backend,
computing the same reading with the same code (:func:`tensegrity_gym.tasks.sensors.reading`,
written once for NumPy and torch). What differs:

* **reset readings** are the host task's own (``RollTask`` / ``ShapeTask`` compute them at reset
  with each env's generator, as the NumPy env does), copied to the device with the reset rows;
  with ``reset_sampling="device"`` they are computed here (:meth:`TorchSensors.reset_rows`: the
  robot at rest, its noise from the device streams below, at step 0);
* **noise of later readings** (``sensor_noise``) comes from per-env counter-based streams on
  the device (:class:`~tensegrity_gym.envs.torch_reset.CounterStreams` with their own salt),
  keyed by ``reset(seed=...)`` with the vector envs' rule (env i: seed + i; a list per env; an
  env never seeded gets a random key at its first reset), not from the per-env NumPy generators:
  a step reads no host random numbers. The reading at step t of an env's e-th episode reads
  the uniforms of (key, e, t) (:func:`~tensegrity_gym.envs.torch_reset.reference_uniforms`,
  ``use="sensor_noise"``): Gaussian noise by the Box-Muller transform of two uniforms per
  entry, a contact switch read wrong when its uniform is below the probability. So an env's
  noise does not depend on ``num_envs``, on the other envs or on the device (the uniforms are
  bit-identical on CPU and CUDA). The noisy readings are not equal number for number to the
  NumPy env's (without noise they are, to round-off: ``tests/test_torch_env.py``).
"""
from __future__ import annotations

import numpy as np

from ..backends.torch.model import torch_module
from ..backends.torch.equations import string_state
from ..tasks.sensors import add_noise, reading, rod_frames
from .torch_reset import CounterStreams

__all__ = ["TorchSensors", "rod_frames"]   # rod_frames: the one definition, tasks.sensors


class TorchSensors:
    """Readings (history x frame, newest first) of a torch vector env's robot observation.

    ``sens``: the host task's :class:`~tensegrity_gym.envs.sensors.RobotSensors`; ``env``: the
    :class:`~tensegrity_gym.envs.torch_shell.TorchTaskVectorEnv` (device, dtype, model)."""

    def __init__(self, sens, env):
        torch = torch_module()
        self.sens = sens
        self.env = env
        self.blocks = [name for name, _, _ in sens.blocks]
        self.noise = [(sl, float(s), flip) for sl, s, flip in sens.noise]
        self.com_eta = env._T(sens.model.com_eta)[None, :, None]
        g = sens.model.gravity
        self.gravity0 = env._T(np.zeros(3) if g is None else np.asarray(g, float))[None]
        self.readings = torch.zeros((env.num_envs, sens.history, sens.frame_size), dtype=env.dtype,
                                    device=env.device)
        self.streams = CounterStreams(env.num_envs, env.device, use="sensor_noise")
        # uniforms per reading: two per Gaussian entry (Box-Muller), one per contact switch
        self.n_draws = sum((1 if flip else 2) * (sl.stop - sl.start) for sl, _, flip in self.noise)

    def seed(self, seed, mask) -> None:
        """Key the noise streams of the envs selected by ``mask`` (N,) bool from ``reset(seed=...)``
        (:meth:`CounterStreams.seed`: seed + i, a list, None keeps; unkeyed envs get random keys)."""
        self.streams.seed(seed, mask)

    def _count_episode(self, it) -> None:
        self.streams.resets[it] = self.streams.resets[it] + 1

    def upload_reset(self, it, host_readings) -> None:
        """Reset rows ``it`` get the host task's reset readings (r, history, frame_size); their
        noise streams start a new episode."""
        self._count_episode(it)
        self.readings[it] = self.env._T(host_readings)

    def frame(self, q, qd, qd_prev, ctrl, speed, contact, command, gravity=None, rows=None):
        """(N, frame_size) readings after a control step (:meth:`RobotSensors.frame` in torch):
        state ``q``, ``qd`` (N, k, 6), the velocities one physics step earlier ``qd_prev`` (None:
        at rest, as at a reset), controls, motor speeds, contact flags (N, 2k) bool (None where
        the env has no such block), the command (N, size); ``gravity`` (N or 1, 3) m/s^2, default
        the copies' own (:meth:`gravity`); ``rows``: the envs these are (an index tensor; None:
        all), whose noise streams are read at their current episode and step (``env.elapsed``)."""
        env = self.env
        _, L, _ = string_state(env.tm, q, qd, env._node_prm, False)
        out = reading(self.blocks, L, q, qd, qd_prev, env.task.dt, self.com_eta,
                      self.gravity() if gravity is None else gravity, ctrl, speed, contact,
                      command.reshape(q.shape[0], self.sens.command[1]))
        if not self.n_draws:
            return out
        st = self.streams
        keys, resets, steps = ((st.keys, st.resets, env.elapsed) if rows is None
                               else (st.keys[rows], st.resets[rows], env.elapsed[rows]))
        u = st.uniform_at(keys, resets, steps, self.n_draws)
        draws, j = [], 0
        for sl, s, flip in self.noise:
            n = sl.stop - sl.start
            if flip:       # contact switches: one uniform each
                draws.append(u[:, j:j + n])
                j += n
            else:          # Box-Muller: N(0, 1) from two uniforms (1 - u in (0, 1]: no log of 0)
                torch = torch_module()
                z = torch.sqrt(-2.0 * torch.log1p(-u[:, j:j + n])) * torch.cos((2.0 * np.pi) * u[:, j + n:j + 2 * n])
                draws.append(s * z.to(out.dtype))
                j += 2 * n
        add_noise(out, self.noise, draws)
        return out

    def reset_rows(self, it, q, qd, ctrl, speed, contact, command) -> None:
        """Envs ``it`` (a device reset, ``reset_sampling="device"``): every history slot holds the
        reading at rest (no IMU acceleration but gravity), noise from the env's stream at step 0, as
        the host task's reset readings."""
        g = self.gravity()
        if g.shape[0] > 1:
            g = g[it]
        self._count_episode(it)
        f = self.frame(q, qd, None, ctrl, speed, contact, command, gravity=g, rows=it)
        self.readings[it] = f[:, None, :].expand(-1, self.readings.shape[1], -1)

    def record(self, *args) -> None:
        """Push :meth:`frame` ``(*args)`` of all envs into the history (newest first); call it
        after the env counted the step (``env.elapsed``: its noise is that step's)."""
        torch = torch_module()
        self.readings = torch.cat([self.frame(*args)[:, None], self.readings[:, :-1]], dim=1)

    def gravity(self):
        """(P, 3) gravity of the copies (the robots' own with ``params``), m/s^2."""
        prm = self.env._params
        return self.gravity0 if prm is None else prm["gravity"].reshape(-1, 3)

    def observation(self):
        """(N, history x frame_size) in the env's dtype."""
        return self.readings.reshape(self.readings.shape[0], -1)
