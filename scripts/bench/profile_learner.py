#!/usr/bin/env python
"""Where PPO's time goes on TensegrityShape-v0 (the main job's ppo.yml entry): rollout against
learner, and inside the learner (``PPO.train``, profiled with cProfile, which adds its own
overhead) the torch operations, per minibatch update.

    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 taskset -c 1 python -m scripts.bench.profile_learner [--rollouts 10]

Prints one table (docs/time_to_policy.md quotes it). The first rollout and update (numba
compilation, torch warm-up) are not timed.

``--recipe shape_1min`` profiles the one-minute shape recipe instead (time_to_policy/ppo.yml:
256 envs x 16 steps, minibatch 128, 2 epochs, 64x64); ``--batch-size`` overrides the minibatch,
``--no-mkldnn`` turns oneDNN off (``torch.backends.mkldnn.enabled``), ``--json`` appends one JSON
line with the learner's time per sample and the machine (CPU model, threads, BLAS environment
variables) for tables over settings (``scripts/bench/learner_settings_table.py``).
"""
from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import time

import gymnasium as gym
import torch

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.integrations.sb3 import make_sb3_vec_env

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
    p.add_argument("--rollouts", type=int, default=10, help="timed rollouts of 4096 samples (default 10)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--recipe", choices=("main", "shape_1min"), default="main",
                   help="main: the main job's earlier ppo.yml entry (64 envs x 64 steps, minibatch 512, 10 epochs, "
                        "128x128); shape_1min: time_to_policy/ppo.yml (256 x 16, minibatch 128, 2 epochs, 64x64)")
    p.add_argument("--batch-size", type=int, default=None, help="minibatch size (default: the recipe's)")
    p.add_argument("--no-mkldnn", action="store_true", help="torch.backends.mkldnn.enabled = False")
    p.add_argument("--json", default=None, help="append one JSON line with the figures to this file")
    a = p.parse_args(argv)
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize
    torch.set_num_threads(a.threads)
    if a.no_mkldnn:
        torch.backends.mkldnn.enabled = False
    if a.recipe == "main":
        n_envs, kw = 64, dict(n_steps=64, batch_size=512, n_epochs=10, gamma=0.95, gae_lambda=0.95,
                              learning_rate=3e-4, net=[128, 128])
    else:
        n_envs, kw = 256, dict(n_steps=16, batch_size=128, n_epochs=2, gamma=0.8, gae_lambda=0.8,
                               learning_rate=1.06e-3, net=[64, 64])
    if a.batch_size:
        kw["batch_size"] = a.batch_size
    net = kw.pop("net")
    venv = gym.make_vec("TensegrityShape-v0", num_envs=n_envs, vectorization_mode="vector_entry_point",
                        tracking_weight=100.0)
    env = VecNormalize(make_sb3_vec_env(venv), norm_obs=True, norm_reward=True, gamma=kw["gamma"])
    model = PPO("MlpPolicy", env, clip_range=0.2, ent_coef=0.0, max_grad_norm=0.5, seed=0, device="cpu",
                policy_kwargs=dict(log_std_init=-1.0, net_arch=dict(pi=net, vf=net)), **kw)
    rollout = n_envs * kw["n_steps"]            # 4096 samples per rollout in both recipes
    model.learn(rollout)   # warm-up: compilation, first update
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
    model.learn(rollout * a.rollouts, reset_num_timesteps=False)
    bs = kw["batch_size"]
    updates = a.rollouts * kw["n_epochs"] * (rollout // bs)
    stats = pstats.Stats(prof).stats
    print(f"{rollout * a.rollouts} env steps, {updates} minibatch updates of {bs} samples, torch threads "
          f"{a.threads}, oneDNN {'off' if a.no_mkldnn else 'on'}, recipe {a.recipe}")
    per_sample_us = 1e6 * spent["learner"] / (a.rollouts * rollout)
    print(f"learner {per_sample_us:.2f} us per collected sample ({1e6 * spent['learner'] / (updates * bs):.2f} us per "
          f"sample-epoch); rollout {1e6 * spent['rollout'] / (a.rollouts * rollout):.2f} us per sample")
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
    if a.json:
        from tensegrity_gym_agents.common import machine
        row = {"label": os.environ.get("PROFILE_LABEL"), "recipe": a.recipe, "batch_size": bs, "threads": a.threads, "mkldnn": not a.no_mkldnn,
               "rollouts": a.rollouts, "learner_s": round(L, 3), "rollout_s": round(spent["rollout"], 3),
               "learner_us_per_sample": round(per_sample_us, 3),
               "rollout_us_per_sample": round(1e6 * spent["rollout"] / (a.rollouts * rollout), 3),
               "ms_per_update": round(1e3 * L / updates, 3), **machine(),
               "env": {k: os.environ[k] for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "MKL_ENABLE_INSTRUCTIONS",
                                                  "ONEDNN_MAX_CPU_ISA", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS",
                                                  "OMP_WAIT_POLICY")
                       if k in os.environ},
               "load_1min": round(os.getloadavg()[0], 2)}
        with open(a.json, "a") as f:
            f.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
