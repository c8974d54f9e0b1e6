#!/usr/bin/env python
"""Cost of a navigation reset against a control step: the time to draw and plan one course
(``tasks.navigate.draw_course``: goals, walls, rough patches and the three path-distance fields),
and the NumPy vector env of ``TensegrityNavigate-v0`` (numba physics): ``reset()`` of all its
envs and a control step of random actions, per env, with their ratio measured in the same run.
Each figure is the least of ``--repeats`` runs.

    TENSEGRITY_GYM_QUIET=1 python -m scripts.bench.bench_navigate_reset [--courses 300] [--envs 64]
        [--steps 50] [--repeats 3] [--json FILE]

The torch device env draws and plans its reset envs' courses on the host in the same function,
so the first row is what a reset costs it on the host per env.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

import gymnasium as gym
import numpy as np

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.tasks.navigate import CourseSpec, draw_course

from scripts._bench import best_of


def course_ms(n: int, repeats: int) -> float:
    """ms to draw one course (default spec), least over ``repeats`` runs of ``n`` courses."""
    spec = CourseSpec()
    return best_of(lambda rng: draw_course(spec, rng), repeats, setup=lambda: np.random.default_rng(1), calls=n) * 1e3


def env_ms(n: int, steps: int, repeats: int) -> tuple:
    """(reset ms per env, control step ms per env) of the vector env of ``n`` envs."""
    env = gym.make_vec("TensegrityNavigate-v0", num_envs=n, vectorization_mode="vector_entry_point")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (steps + 2, n) + env.single_action_space.shape).astype(np.float32)
    for a in acts[:2]:
        env.step(a)
    resets, step = [], []
    for rep in range(repeats):
        t0 = time.perf_counter()
        env.reset(seed=rep + 1)
        resets.append((time.perf_counter() - t0) / n * 1e3)
        t0 = time.perf_counter()
        for a in acts[2:]:
            env.step(a)
        step.append((time.perf_counter() - t0) / (n * steps) * 1e3)
    env.close()
    return min(resets), min(step)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--courses", type=int, default=300)
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--steps", type=int, default=50, help="control steps timed per repeat")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", metavar="FILE", help="also write the figures here (not overwritten)")
    args = ap.parse_args(argv)
    for name in ("courses", "envs", "steps", "repeats"):
        if getattr(args, name) < 1:
            ap.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    if args.json and os.path.exists(args.json):
        ap.error(f"--json {args.json}: exists; give a new file")
    course = course_ms(args.courses, args.repeats)
    reset, step = env_ms(args.envs, args.steps, args.repeats)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores")
    print("| what | ms per env | / control step |")
    print("|---|---:|---:|")
    print(f"| draw and plan a course | {course:.2f} | {course / step:.1f} |")
    print(f"| vector env reset ({args.envs} envs) | {reset:.2f} | {reset / step:.1f} |")
    print(f"| control step, random actions ({args.envs} envs) | {step:.3f} | 1.0 |")
    if args.json:
        with open(args.json, "x") as fh:
            json.dump({"course_ms": course, "reset_ms_per_env": reset, "step_ms_per_env": step,
                       "envs": args.envs, "courses": args.courses, "steps": args.steps, "repeats": args.repeats}, fh,
                      indent=1)


if __name__ == "__main__":
    main()
