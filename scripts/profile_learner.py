#!/usr/bin/env python
"""Where PPO's time goes on TensegrityShape-v0 (the main job's ppo.yml entry): rollout against
learner, and inside the learner (``PPO.train``, profiled with cProfile, which adds its own
overhead) the torch operations, per minibatch update.

    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 taskset -c 1 python scripts/profile_learner.py [--rollouts 10]

Prints one table (docs/time_to_policy.md quotes it). The first rollout and update (numba
compilation, torch warm-up) are not timed.
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import gymnasium as gym
import torch

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.sb3 import make_sb3_vec_env

#: (label, [(file name part, function name)], cumulative?): builtins by their own time, Python
#: functions with what they call (none of these calls another row's function)
ROWS = (("backward", [("~", "<method 'run_backward' of 'torch._C._EngineBase' objects>")], False),
        ("forward: linear layers", [("~", "<built-in method torch._C._nn.linear>")], False),
        ("forward: tanh", [("~", "<built-in method torch.tanh>")], False),
        ("Adam step", [("optim/adam.py", "_single_tensor_adam"), ("optim/adam.py", "_multi_tensor_adam")], True),
        ("gradient clipping", [("nn/utils/clip_grad.py", "clip_grad_norm_")], True),
        ("minibatch sampling", [("common/buffers.py", "_get_samples")], True),
        ("Gaussian log-prob and entropy", [("distributions/normal.py", "log_prob"),
                                           ("distributions/normal.py", "entropy")], True))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rollouts", type=int, default=10, help="timed rollouts of 64 envs x 64 steps (default 10)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    a = p.parse_args(argv)
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize
    torch.set_num_threads(a.threads)
    venv = gym.make_vec("TensegrityShape-v0", num_envs=64, vectorization_mode="vector_entry_point",
                        tracking_weight=100.0)
    env = VecNormalize(make_sb3_vec_env(venv), norm_obs=True, norm_reward=True, gamma=0.95)
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=512, n_epochs=10, gamma=0.95, gae_lambda=0.95,
                learning_rate=3e-4, clip_range=0.2, ent_coef=0.0, max_grad_norm=0.5, seed=0, device="cpu",
                policy_kwargs=dict(log_std_init=-1.0, net_arch=dict(pi=[128, 128], vf=[128, 128])))
    model.learn(4096)   # warm-up: compilation, first update
    spent = {"learner": 0.0, "rollout": 0.0}
    train, collect = model.train, model.collect_rollouts

    prof = cProfile.Profile()

    def timed_train():      # only the learner is profiled
        t0 = time.perf_counter()
        prof.enable()
        train()
        prof.disable()
        spent["learner"] += time.perf_counter() - t0

    def timed_collect(*args, **kw):
        t0 = time.perf_counter()
        out = collect(*args, **kw)
        spent["rollout"] += time.perf_counter() - t0
        return out
    model.train, model.collect_rollouts = timed_train, timed_collect
    model.learn(4096 * a.rollouts, reset_num_timesteps=False)
    updates = a.rollouts * 10 * (4096 // 512)
    stats = pstats.Stats(prof).stats
    print(f"{4096 * a.rollouts} env steps, {updates} minibatch updates of 512 samples, torch threads {a.threads}")
    print("| part | s | ms per update | share of the learner |")
    print("|---|---:|---:|---:|")
    print(f"| rollout (env, policy inference, normalisation, buffer) | {spent['rollout']:.2f} | | |")
    L = spent["learner"]
    print(f"| **learner** (`PPO.train`) | {L:.2f} | {1e3 * L / updates:.2f} | 100 % |")
    counted = 0.0
    for label, keys, cumulative in ROWS:
        s = sum(v[3] if cumulative else v[2] for k, v in stats.items()
                if any(part in k[0] and k[2] == fn for part, fn in keys))
        counted += s
        print(f"| {label} | {s:.2f} | {1e3 * s / updates:.2f} | {100 * s / L:.0f} % |")
    print(f"| rest (SB3 and torch Python overhead, logging) | {L - counted:.2f} | {1e3 * (L - counted) / updates:.2f} "
          f"| {100 * (L - counted) / L:.0f} % |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
