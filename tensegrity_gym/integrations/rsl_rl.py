"""rsl_rl adapter: the ``VecEnv`` that rsl_rl's ``OnPolicyRunner`` trains (the interface of Isaac
Lab, mjlab and MuJoCo Playground), over a tensegrity vector env.

:class:`RslRlVecEnv` wraps a Gymnasium vector env built with ``autoreset_mode="same_step"``:

* the torch device env (``gymnasium.make_vec(id, num_envs=N,
  vectorization_mode="vector_entry_point", backend="torch", device=...)``): tensors stay on its
  device; or
* the NumPy vector env (same call without ``backend``): arrays are converted to torch tensors on
  ``device`` (default ``"cpu"``) each step.

What rsl_rl reads (``rsl_rl.env.VecEnv``):

* observations: a ``tensordict.TensorDict`` of batch size (N,) with the groups ``"policy"`` and
  ``"critic"`` (both the env's observation (N, obs_size), float32; the runner's ``obs_groups``
  pick them);
* ``step(actions)`` with ``actions`` (N, num_actions): clipped to the action box [-1, 1] (rsl_rl's
  Gaussian policy is unbounded), returns ``(obs, rewards (N,) float32, dones (N,) long, extras)``;
  envs that ended are reset in the same step (the observation is the new episode's);
* ``extras["time_outs"]`` (N,) bool: the episode ended by the time limit or a divergence restore
  (``truncated``), so that PPO bootstraps it; ``extras["log"]``: the mean of each reward term
  over the envs (``"/reward/<term>"``);
* ``episode_length_buf`` (N,) int64: control steps of the current episodes, writable (the runner's
  ``init_at_random_ep_len`` writes random lengths to spread the time-outs); ``max_episode_length``
  (control steps); ``num_envs``, ``num_actions``, ``device``, ``cfg``.

rsl_rl and tensordict are imported when the adapter is built (the core install does not need
them); the base class is rsl_rl's ``VecEnv`` so that ``isinstance`` checks hold.

Training command (``python -m tensegrity_gym.integrations.rsl_rl --help``)::

    python -m tensegrity_gym.integrations.rsl_rl --env-id TensegrityRoll-v0 --num-envs 64 \\
        --iterations 100 --backend torch --device cpu
"""
from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from ..backends.torch.model import resolve_device
from .torch_threads import num_threads_arg, set_torch_threads

__all__ = ["RslRlVecEnv", "make_rsl_rl_env", "train_config"]

_CLASS = None


def _torch():
    import torch
    return torch


def _build_class():
    """The adapter class, built once on first use (rsl_rl's ``VecEnv`` as its base)."""
    from rsl_rl.env import VecEnv
    from tensordict import TensorDict
    torch = _torch()

    class _RslRlVecEnv(VecEnv):
        __doc__ = RslRlVecEnv.__doc__

        def __init__(self, env, device=None, cfg: dict | None = None):
            from gymnasium.vector import AutoresetMode
            mode = getattr(env, "autoreset_mode", env.metadata.get("autoreset_mode"))
            if mode != AutoresetMode.SAME_STEP:
                raise ValueError(f"RslRlVecEnv: the env must reset ended envs in the same step (rsl_rl stores the "
                                 f"step's observation as the next episode's start); got autoreset_mode={mode!r}. "
                                 "Build it with autoreset_mode='same_step' (or use make_rsl_rl_env)")
            from ..envs.torch_shell import TorchTaskVectorEnv
            self.env = env
            self._base = env.unwrapped                                           # the env under any wrappers
            self._on_torch = isinstance(self._base, TorchTaskVectorEnv)          # the device-resident env
            # devices compared as their tensors report them ("cuda" is cuda:0, "cpu:0" is cpu)
            self.device = resolve_device(self._base.device if self._on_torch else (device or "cpu"))
            if self._on_torch and device is not None and resolve_device(device) != self.device:
                raise ValueError(f"device: the torch env runs on {self.device}; got device={device!r}")
            self.num_envs = env.num_envs
            self.num_actions = int(env.single_action_space.shape[0])
            limit = self._base.max_episode_steps
            self.max_episode_length = limit if limit is not None else 2 ** 31 - 1
            self.cfg = dict(cfg or {})
            self._obs = None

        # ------------------------------------------------------------ conversions
        def _t(self, x, dtype=None):
            """``x`` (array or tensor) as a tensor on the adapter's device (``dtype`` if given)."""
            t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
            return t.to(device=self.device, dtype=dtype)

        def _group(self, obs) -> TensorDict:
            o = self._t(obs, torch.float32)
            return TensorDict({"policy": o, "critic": o}, batch_size=[self.num_envs], device=self.device)

        # ------------------------------------------------------------ episode counters
        def _elapsed(self):
            """The env's step counter (N,) int64: the torch env's tensor, or the NumPy env's array
            seen as a tensor (shared memory, so in-place writes reach the env)."""
            return self._base.elapsed if self._on_torch else torch.from_numpy(self._base.task.elapsed)

        @property
        def episode_length_buf(self):
            e = self._elapsed()
            return e if e.device == self.device else e.to(self.device)

        @episode_length_buf.setter
        def episode_length_buf(self, value):
            e = self._elapsed()
            e.copy_(torch.as_tensor(value).to(device=e.device, dtype=e.dtype))

        # ------------------------------------------------------------ VecEnv API
        def reset(self, seed: int | None = None):
            """Reset every env (``seed``: env i gets ``seed + i``); returns the observation groups."""
            obs, _ = self.env.reset(seed=seed)
            self._obs = self._group(obs)
            return self._obs, {}

        def get_observations(self):
            if self._obs is None:
                self.reset(seed=self.cfg.get("seed"))
            return self._obs

        def step(self, actions):
            a = torch.clamp(actions.detach(), -1.0, 1.0)
            if not self._on_torch:
                a = a.cpu().numpy()
            obs, rew, term, trunc, info = self.env.step(a)
            term, trunc = self._t(term, torch.bool), self._t(trunc, torch.bool)
            self._obs = self._group(obs)
            log = {}
            for k, v in info.items():
                if k.startswith("reward_"):
                    log["/reward/" + k[len("reward_"):]] = self._t(v, torch.float32).mean()
            extras = {"time_outs": trunc, "log": log}
            return self._obs, self._t(rew, torch.float32), (term | trunc).to(torch.long), extras

        def close(self):
            self.env.close()

    _RslRlVecEnv.__name__ = _RslRlVecEnv.__qualname__ = "RslRlVecEnv"
    return _RslRlVecEnv


class RslRlVecEnv:
    """rsl_rl ``VecEnv`` over a tensegrity vector env built with ``autoreset_mode="same_step"``
    (see the module doc). ``RslRlVecEnv(env, device=None, cfg=None)`` returns an instance of a
    subclass of ``rsl_rl.env.VecEnv``; ``device`` only for the NumPy env (the torch env's device
    is used as is); ``cfg`` is what the runner's logger records as the env config."""

    def __new__(cls, env, device=None, cfg: dict | None = None):
        global _CLASS
        if _CLASS is None:
            _CLASS = _build_class()
        return _CLASS(env, device=device, cfg=cfg)


def make_rsl_rl_env(env_id: str = "TensegrityRoll-v0", num_envs: int = 64, backend: str = "torch",
                    device: str = "cpu", seed: int | None = 0, **env_kwargs):
    """The env ``env_id`` with ``num_envs`` copies and same-step autoreset, wrapped for rsl_rl:
    ``backend="torch"`` the device env on ``device`` (float32), ``"numpy"`` the NumPy vector env
    with tensors on ``device``. ``env_kwargs`` go to the env (e.g. ``max_episode_steps``)."""
    import gymnasium as gym
    import tensegrity_gym  # noqa: F401  (registers the ids)
    if backend == "torch":
        env_kwargs = {"backend": "torch", "device": device, "dtype": "float32", **env_kwargs}
    elif backend != "numpy":
        raise ValueError(f"backend: expected 'torch' or 'numpy', got {backend!r}")
    env = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
                       autoreset_mode="same_step", **env_kwargs)
    return RslRlVecEnv(env, device=device, cfg={"env_id": env_id, "num_envs": num_envs, "backend": backend,
                                                "seed": seed})


def train_config(num_steps_per_env: int = 24, hidden: tuple[int, ...] = (64, 64), learning_rate: float = 1e-3,
                 seed: int = 0, **algorithm) -> dict:
    """A small ``OnPolicyRunner`` config (rsl_rl 5.x layout): PPO, Gaussian MLP actor and MLP
    critic of ``hidden`` units on the ``"policy"`` / ``"critic"`` groups, observation
    normalisation on. ``algorithm`` overrides PPO's arguments."""
    model = {"class_name": "MLPModel", "hidden_dims": list(hidden), "activation": "elu", "obs_normalization": True}
    return {
        "num_steps_per_env": num_steps_per_env, "save_interval": 10 ** 9, "seed": seed,
        "obs_groups": {"actor": ["policy"], "critic": ["critic"]},
        "actor": {**model, "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": 0.5}},
        "critic": dict(model),
        "algorithm": {"class_name": "PPO", "learning_rate": learning_rate, "num_learning_epochs": 5,
                      "num_mini_batches": 4, "gamma": 0.99, "lam": 0.95, "entropy_coef": 0.0,
                      "desired_kl": 0.01, "schedule": "adaptive", **algorithm},
        "multi_gpu": None, "check_for_nan": True,
    }


def train(env_id: str = "TensegrityRoll-v0", num_envs: int = 64, iterations: int = 50, backend: str = "torch",
          device: str = "cpu", seed: int = 0, log_dir: str | None = None, eval_steps: int = 200,
          **env_kwargs) -> dict[str, Any]:
    """``iterations`` of rsl_rl's PPO (``OnPolicyRunner.learn``) on ``env_id``; returns
    ``{"steps", "mean_reward_per_step"}``: the env steps trained and the mean reward per env step
    of the trained policy's mean action over ``eval_steps`` more steps of every env."""
    import torch
    from rsl_rl.runners import OnPolicyRunner
    torch.manual_seed(seed)
    env = make_rsl_rl_env(env_id, num_envs, backend, device, seed, **env_kwargs)
    cfg = train_config(seed=seed)
    runner = OnPolicyRunner(env, cfg, log_dir=log_dir, device=device)
    runner.learn(iterations)
    policy = runner.get_inference_policy(device)          # the mean action
    obs = env.get_observations()
    total, n = 0.0, 0
    with torch.inference_mode():
        for _ in range(eval_steps):
            obs, rew, _, _ = env.step(policy(obs))
            total, n = total + float(rew.sum()), n + rew.numel()
    return {"steps": iterations * cfg["num_steps_per_env"] * num_envs, "mean_reward_per_step": total / n}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m tensegrity_gym.integrations.rsl_rl",
                                description="Train rsl_rl's PPO on a tensegrity env (OnPolicyRunner).")
    p.add_argument("--env-id", default="TensegrityRoll-v0")
    p.add_argument("--num-envs", type=int, default=64)
    p.add_argument("--iterations", type=int, default=50, help="learning iterations (24 steps per env each)")
    p.add_argument("--backend", choices=["torch", "numpy"], default="torch")
    p.add_argument("--device", default="cpu")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-steps", type=int, default=200, help="vector steps of the trained policy's mean action")
    p.add_argument("--log-dir", default="runs/rsl_rl", help="TensorBoard logs and checkpoints; rsl_rl prints a "
                   "progress table per iteration when it is set ('' for neither)")
    p.add_argument("--num-threads", type=num_threads_arg, default=1,
                   help="torch CPU threads (default 1, as agents.train)")
    a = p.parse_args(argv)
    set_torch_threads(a.num_threads)
    out = train(a.env_id, a.num_envs, a.iterations, a.backend, a.device, a.seed, a.log_dir or None, a.eval_steps)
    print(f"rsl_rl PPO on {a.env_id} ({a.backend}, {a.device}): {out['steps']} env steps, "
          f"mean reward per step of the trained policy (mean action, {a.eval_steps} steps) "
          f"{out['mean_reward_per_step']:.4f}")


if __name__ == "__main__":
    main()
