"""Gymnasium's stateful vector wrappers for the device-resident vector envs: episode statistics,
observation and reward normalisation, computed on the env's device with torch tensors (the
Gymnasium wrappers of the same names hold NumPy arrays and reject tensors).

* :class:`TorchRecordEpisodeStatistics`: ``info["episode"] = {"r", "l", "t"}`` with the mask
  ``info["_episode"]`` at the step an episode ends, as ``gymnasium.wrappers.vector.
  RecordEpisodeStatistics`` (return in reward units, length in control steps, ``t`` wall time in
  s), honouring the env's ``autoreset_mode``; ``return_queue`` / ``length_queue`` /
  ``time_queue`` keep the last ``buffer_length`` episodes as floats.
* :class:`TorchNormalizeObservation`: ``(obs - mean) / sqrt(var + epsilon)`` with running
  statistics over every observation seen (``update_running_mean`` freezes them).
* :class:`TorchNormalizeReward`: the reward divided by the running standard deviation of the
  discounted return (``gamma``), as Gymnasium's ``NormalizeReward``.

All three also accept NumPy vector envs (arrays are converted on the way in and out), so one
training script can use them on either backend. Shapes: observations (N, obs_size), rewards (N,).
"""
from __future__ import annotations

import time
from collections import deque

import numpy as np
import gymnasium as gym
from gymnasium.vector import AutoresetMode

from .vector_rules import reset_mask_option

__all__ = ["RunningMeanStd", "TorchRecordEpisodeStatistics", "TorchNormalizeObservation", "TorchNormalizeReward"]


def _torch():
    import torch
    return torch


def _tensor(x, device=None):
    """``x`` as a torch tensor (a NumPy array: shared, on the CPU) and whether it was one."""
    torch = _torch()
    if isinstance(x, torch.Tensor):
        return x, True
    return torch.as_tensor(np.asarray(x), device=device), False


def _back(t, was_tensor: bool):
    return t if was_tensor else t.cpu().numpy()


class RunningMeanStd:
    """Running mean and variance over batches (the parallel algorithm Gymnasium's
    ``RunningMeanStd`` uses), float64 tensors of ``shape`` on ``device``."""

    def __init__(self, shape=(), device="cpu", epsilon: float = 1e-4):
        torch = _torch()
        self.mean = torch.zeros(shape, dtype=torch.float64, device=device)
        self.var = torch.ones(shape, dtype=torch.float64, device=device)
        self.count = float(epsilon)

    def update(self, x) -> None:
        """Add the batch ``x`` (B, *shape)."""
        x = x.to(self.mean.dtype)
        b_mean, b_var, b_count = x.mean(0), x.var(0, unbiased=False), x.shape[0]
        delta = b_mean - self.mean
        tot = self.count + b_count
        self.mean = self.mean + delta * b_count / tot
        m2 = self.var * self.count + b_var * b_count + delta ** 2 * self.count * b_count / tot
        self.var = m2 / tot
        self.count = tot


class TorchRecordEpisodeStatistics(gym.vector.VectorWrapper):
    """Episode returns, lengths and times in ``info["episode"]`` (see the module doc)."""

    def __init__(self, env: gym.vector.VectorEnv, buffer_length: int = 100, stats_key: str = "episode"):
        super().__init__(env)
        self._key = stats_key
        self._mode = env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
        self._device = getattr(env, "device", "cpu")
        torch = _torch()
        N = self.num_envs
        self.episode_returns = torch.zeros(N, dtype=torch.float64, device=self._device)
        self.episode_lengths = torch.zeros(N, dtype=torch.int64, device=self._device)
        self.episode_start_times = np.zeros(N)
        self.prev_dones = torch.zeros(N, dtype=torch.bool, device=self._device)
        self.episode_count = 0
        self.return_queue = deque(maxlen=buffer_length)
        self.length_queue = deque(maxlen=buffer_length)
        self.time_queue = deque(maxlen=buffer_length)

    def reset(self, *, seed=None, options=None):
        mask, _ = reset_mask_option(options, self.num_envs)
        obs, info = self.env.reset(seed=seed, options=options)
        torch = _torch()
        m = torch.as_tensor(mask, device=self._device)
        self.episode_returns[m] = 0.0
        self.episode_lengths[m] = 0
        self.prev_dones[m] = False
        self.episode_start_times[mask] = time.perf_counter()
        return obs, info

    def step(self, actions):
        torch = _torch()
        obs, rew, term, trunc, info = self.env.step(actions)
        r, was_tensor = _tensor(rew, self._device)
        te, tr = _tensor(term, self._device)[0], _tensor(trunc, self._device)[0]
        if self._mode == AutoresetMode.NEXT_STEP:     # the step after an end is the reset step: not counted
            keep = ~self.prev_dones
            self.episode_returns = torch.where(keep, self.episode_returns + r.to(torch.float64), 0.0)
            self.episode_lengths = torch.where(keep, self.episode_lengths + 1, 0)
            self.episode_start_times[self.prev_dones.cpu().numpy()] = time.perf_counter()
        else:
            self.episode_returns += r.to(torch.float64)
            self.episode_lengths += 1
        dones = te | tr
        self.prev_dones = dones.clone()
        if bool(dones.any()):
            if self._key in info:
                raise ValueError(f"info already has the key {self._key!r}")
            d = dones.cpu().numpy()
            t = np.round(time.perf_counter() - self.episode_start_times, 6)
            rets = torch.where(dones, self.episode_returns, 0.0)
            lens = torch.where(dones, self.episode_lengths, 0)
            info[self._key] = {"r": _back(rets, was_tensor), "l": _back(lens, was_tensor),
                               "t": _back(torch.as_tensor(np.where(d, t, 0.0), device=self._device), was_tensor)}
            info["_" + self._key] = _back(dones, was_tensor)
            self.episode_count += int(d.sum())
            self.return_queue.extend(rets[dones].cpu().tolist())
            self.length_queue.extend(lens[dones].cpu().tolist())
            self.time_queue.extend(t[d].tolist())
            if self._mode == AutoresetMode.SAME_STEP:
                self.episode_returns[dones] = 0.0
                self.episode_lengths[dones] = 0
                self.episode_start_times[d] = time.perf_counter()
        return obs, rew, term, trunc, info


class TorchNormalizeObservation(gym.vector.VectorWrapper):
    """Observations normalised by running statistics (see the module doc); ``obs_rms`` holds them."""

    def __init__(self, env: gym.vector.VectorEnv, epsilon: float = 1e-8):
        super().__init__(env)
        self.epsilon = epsilon
        self.update_running_mean = True
        self.obs_rms = RunningMeanStd(env.single_observation_space.shape, getattr(env, "device", "cpu"))

    def _norm(self, obs):
        o, was_tensor = _tensor(obs, self.obs_rms.mean.device)
        if self.update_running_mean:
            self.obs_rms.update(o)
        out = ((o.to(self.obs_rms.mean.dtype) - self.obs_rms.mean) / (self.obs_rms.var + self.epsilon).sqrt())
        return _back(out.to(o.dtype), was_tensor)

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        return self._norm(obs), info

    def step(self, actions):
        obs, rew, term, trunc, info = self.env.step(actions)
        return self._norm(obs), rew, term, trunc, info


class TorchNormalizeReward(gym.vector.VectorWrapper):
    """Rewards divided by the running std of the discounted return (see the module doc);
    ``return_rms`` holds the statistics."""

    def __init__(self, env: gym.vector.VectorEnv, gamma: float = 0.99, epsilon: float = 1e-8):
        super().__init__(env)
        torch = _torch()
        self.gamma, self.epsilon = gamma, epsilon
        self.update_running_mean = True
        dev = getattr(env, "device", "cpu")
        self.return_rms = RunningMeanStd((), dev)
        self.accumulated_reward = torch.zeros(self.num_envs, dtype=torch.float64, device=dev)

    def step(self, actions):
        obs, rew, term, trunc, info = self.env.step(actions)
        r, was_tensor = _tensor(rew, self.accumulated_reward.device)
        te = _tensor(term, self.accumulated_reward.device)[0]
        self.accumulated_reward = self.accumulated_reward * self.gamma * (~te).to(r.dtype) + r.to(self.accumulated_reward.dtype)
        if self.update_running_mean:
            self.return_rms.update(self.accumulated_reward)
        out = r.to(self.accumulated_reward.dtype) / (self.return_rms.var + self.epsilon).sqrt()
        return obs, _back(out.to(r.dtype), was_tensor), term, trunc, info
