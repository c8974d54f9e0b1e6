#!/usr/bin/env python
"""Single TensegrityShape-v0 step() against the physics it runs (target: <= 2x).

    NUMBA_NUM_THREADS=1 python -m scripts.bench.bench_step_overhead [--rounds 40] [--repeats 3]

Per action mode: ``env.unwrapped.step(a)`` for 300 random actions in [-0.1, 0.1], and the bare
physics of a control step, ``physics.step(model, state, dt, integrator, n_steps=frame_skip,
**inputs)`` 300 times, interleaved in each round; the best round of each, in microseconds, and
their ratio, printed per repeat. Run it on an otherwise idle machine: a loaded core shifts one of
the two numbers more than the other. (The roll env's figure, which counts the contact forces as
physics, is in docs/bench_envs.md.)
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np


import gymnasium as gym  # noqa: E402

import tensegrity_gym  # noqa: E402,F401  (registers the envs)
from tensegrity_gym.core.model import State  # noqa: E402
from tensegrity_gym.physics.integrate import step  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=40)
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args(argv)
    print("| action mode | repeat | step() (us) | physics (us) | ratio |\n|---|---|---:|---:|---:|")
    for mode in ("rest_length", "force_density"):
        env = gym.make("TensegrityShape-v0", action_mode=mode)
        env.reset(seed=0)
        u, t = env.unwrapped, env.unwrapped.task
        A = np.random.default_rng(0).uniform(-0.1, 0.1, (300, t.action_size)).astype(np.float32)
        for rep in range(args.repeats):
            best_step = best_phys = float("inf")
            for r in range(args.rounds):
                u.reset(seed=r)
                inputs = t.actuation.physics_inputs(t.ctrl)
                st = State(t.q.copy(), t.qd.copy(), 0.0)
                t0 = time.perf_counter()
                for a in A:
                    u.step(a)
                best_step = min(best_step, (time.perf_counter() - t0) / len(A))
                t0 = time.perf_counter()
                for _ in range(len(A)):
                    step(t.model, st, t.dt, t.integrator, n_steps=t.frame_skip, **inputs)
                best_phys = min(best_phys, (time.perf_counter() - t0) / len(A))
            print(f"| {mode} | {rep} | {best_step * 1e6:.1f} | {best_phys * 1e6:.1f} | {best_step / best_phys:.2f} |")
        env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
