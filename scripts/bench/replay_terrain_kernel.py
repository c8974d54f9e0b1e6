#!/usr/bin/env python
"""Time of the numba terrain kernel alone: the compiled terrain sub-step calls of a vector env
run (``TensegrityRoll-v0`` on a terrain scene, random actions) are recorded with their inputs,
then replayed from copies of those inputs, so that every variant of the kernel does the same
work. Prints microseconds per env step (the kernel's calls of one env step) per replay, and
with ``--threads`` the threaded kernel and the one-thread kernel on the same calls.

    PYTHONPATH=. TENSEGRITY_GYM_QUIET=1 python -m scripts.bench.replay_terrain_kernel --scene steps --envs 16 \
        [--steps 200] [--replays 10] [--threads] [--save calls.pkl | --load calls.pkl]

``--save`` keeps the recorded calls and ``--load`` replays them, so that versions of the kernel
are timed on the very same calls (a version's own run records slightly different ones).

Scenes: those of ``scripts/bench/bench_terrain.py`` (``slope``, ``steps``, ``rough``, ``steps-under``: the
steps under the robot, where the boxes' search along the rods runs; ``navigate`` is
``TensegrityNavigate-v0``). The env's resets (their settling steps) are not recorded. The first
replay includes nothing to compile (the env run compiled the kernels); the minimum and median
over ``--replays`` are printed: the environment's env-steps/s are ``bench_terrain.py``'s.
"""
from __future__ import annotations

import argparse
import pickle
import statistics
import time

import gymnasium as gym
import numpy as np

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.backends.numba import terrain_steps as TS

SCENES = {"slope": ("TensegrityRoll-v0", {"terrain": {"plane": {"slope_deg": 20.0}}}),
          "steps": ("TensegrityRoll-v0", {"terrain": {"generator": "steps"}}),
          "steps-under": ("TensegrityRoll-v0", {"terrain": {"generator": "steps", "pad": 0.05, "tread": 0.2}}),
          "rough": ("TensegrityRoll-v0", {"terrain": {"generator": "rough", "amplitude": 0.02, "pad": 0.0}}),
          "navigate": ("TensegrityNavigate-v0", {})}
KERNELS = ("terrain_loop", "terrain_loop_simd", "terrain_parallel")


def _copy(args):
    return [a.copy() if isinstance(a, np.ndarray) else a for a in args]


def record(scene: str, n: int, steps: int, seed: int = 0) -> list:
    """``[(kernel name, inputs)]`` of the terrain kernel calls of ``steps`` env steps (after 5)."""
    env_id, kwargs = SCENES[scene]
    env = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    acts = rng.uniform(-1, 1, (steps + 5, n) + env.single_action_space.shape).astype(np.float32)
    for a in acts[:5]:
        env.step(a)
    calls, kept = [], {name: getattr(TS, name) for name in KERNELS}

    def hook(name):
        def call(*args):
            args_ = _copy(args)
            if calls:
                # an input equal to the call before's (the terrain, its heights) is kept once
                prev = calls[-1][1]
                args_ = [p if (isinstance(a, np.ndarray) and isinstance(p, np.ndarray) and a.shape == p.shape
                               and a.dtype == p.dtype and np.array_equal(a, p)) else a for a, p in zip(args_, prev)]
            calls.append((name, args_))
            return kept[name](*args)
        return call
    try:
        for name in KERNELS:
            setattr(TS, name, hook(name))
        for a in acts[5:]:
            env.step(a)
    finally:
        for name, fn in kept.items():
            setattr(TS, name, fn)
        env.close()
    return calls


def replay(calls: list, steps: int, kernel: str | None = None) -> float:
    """Microseconds per env step of the recorded ``calls`` run again (each on fresh copies of its
    inputs; ``kernel``: run every call with that kernel instead of the recorded one)."""
    runs = [(getattr(TS, kernel or name), _copy(args)) for name, args in calls]
    t0 = time.perf_counter()
    for fn, args in runs:
        err = fn(*args)
        if err:
            raise RuntimeError(f"{fn.__name__}: error code {err}")
    return (time.perf_counter() - t0) / steps * 1e6


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", choices=sorted(SCENES), default="steps")
    ap.add_argument("--envs", type=int, default=16)
    ap.add_argument("--steps", type=int, default=200, help="env steps recorded")
    ap.add_argument("--replays", type=int, default=10)
    ap.add_argument("--threads", action="store_true",
                    help="also replay the threaded and the one-thread SIMD kernel on the same calls")
    ap.add_argument("--save", metavar="FILE", help="also write the recorded calls to FILE (a pickle; not overwritten)")
    ap.add_argument("--load", metavar="FILE",
                    help="replay the calls of FILE (written by --save, from a file of your own: a pickle runs code) "
                         "instead of recording: kernel variants timed on the same calls")
    args = ap.parse_args(argv)
    if args.envs < 1 or args.steps < 1 or args.replays < 1:
        ap.error(f"--envs, --steps and --replays must be at least 1, got {args.envs}, {args.steps}, {args.replays}")
    if args.load:
        try:
            with open(args.load, "rb") as fh:
                saved = pickle.load(fh)
        except (OSError, pickle.UnpicklingError, EOFError) as err:
            ap.error(f"--load {args.load}: {err}")
        calls = saved["calls"]
        args.scene, args.envs, args.steps = saved["scene"], saved["envs"], saved["steps"]
    else:
        calls = record(args.scene, args.envs, args.steps)
    if args.save:
        try:
            with open(args.save, "xb") as fh:
                pickle.dump({"scene": args.scene, "envs": args.envs, "steps": args.steps, "calls": calls}, fh)
        except OSError as err:
            ap.error(f"--save {args.save}: {err}")
    if not calls:
        ap.error(f"scene {args.scene!r} ran no compiled terrain kernel")
    names = sorted({name for name, _ in calls})
    variants = [(None, "+".join(names))]
    if args.threads:
        variants = [("terrain_parallel", "terrain_parallel"), ("terrain_loop_simd", "terrain_loop_simd")]
    print(f"{args.scene}, N = {args.envs}: {len(calls)} kernel calls over {args.steps} env steps")
    print("| kernel | us per env step, min | median |")
    print("|---|---:|---:|")
    for kernel, label in variants:
        times = [replay(calls, args.steps, kernel) for _ in range(args.replays)]
        print(f"| {label} | {min(times):.1f} | {statistics.median(times):.1f} |")


if __name__ == "__main__":
    main()
