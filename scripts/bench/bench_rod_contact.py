#!/usr/bin/env python
"""Cost of rod-rod contact on an ordinary rolling step: env-steps/s with ``rod_contact`` off
(the default) and on, and their ratio, measured in the same run.

    PYTHONPATH=. TENSEGRITY_GYM_QUIET=1 python -m scripts.bench.bench_rod_contact [--envs 1 16] \
        [--env-ids TensegrityRoll-v0 ...] [--seconds 4] [--json out.json]

For each env id and N (``--envs``) a NumPy vector env of N copies (N = 1: ``gymnasium.make``)
with seeded random actions, stepped without resets for ``--seconds`` s per configuration,
off and on interleaved round by round (:func:`scripts._bench.interleaved_windows`: a load
change on a shared machine hits both alike). Both run the compiled loop driver (the ground,
plane or terrain instance, with or without the rod-rod forces at every physics step). Kernels
are compiled (or loaded) before the timing.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import gymnasium as gym
import numpy as np

import tensegrity_gym  # registers the envs

from scripts._bench import interleaved_windows


def _stepper(env_id: str, n: int, rod_contact):
    env = (gym.make(env_id, rod_contact=rod_contact, max_episode_steps=None) if n == 1 else
           gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", rod_contact=rod_contact,
                        max_episode_steps=None))
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    pool = [rng.uniform(-1, 1, env.action_space.shape).astype(np.float32) for _ in range(16)]
    i = [0]

    def step():
        env.step(pool[i[0] % 16])
        i[0] += 1
    return step


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--envs", type=int, nargs="+", default=[1, 16], help="copies N (default 1 16)")
    ap.add_argument("--env-ids", nargs="+", default=["TensegrityRoll-v0"])
    ap.add_argument("--seconds", type=float, default=4.0, help="timed seconds per configuration (default 4)")
    ap.add_argument("--json", metavar="FILE", help="also write the table to FILE (not overwritten)")
    args = ap.parse_args(argv)
    if min(args.envs) < 1 or not args.seconds > 0:
        ap.error(f"--envs must be >= 1 and --seconds > 0, got {args.envs}, {args.seconds}")
    if args.json and os.path.exists(args.json):
        print(f"--json {args.json}: exists (not overwritten)", file=sys.stderr)
        return 2
    rows = []
    print(f"tensegrity_gym {tensegrity_gym.__version__}, {args.seconds} s per configuration")
    print("| env | N | off: env-steps/s | on: env-steps/s | on / off cost |")
    print("|---|---:|---:|---:|---:|")
    for env_id in args.env_ids:
        for n in args.envs:
            t = interleaved_windows({"off": _stepper(env_id, n, None), "on": _stepper(env_id, n, True)},
                                    args.seconds)
            off, on = n / t["off"], n / t["on"]
            rows.append({"env": env_id, "N": n, "off": off, "on": on, "cost": t["on"] / t["off"]})
            print(f"| {env_id} | {n} | {off:.0f} | {on:.0f} | {t['on'] / t['off']:.2f} |", flush=True)
    if args.json:
        with open(args.json, "x") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
