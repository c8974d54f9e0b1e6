#!/usr/bin/env python
"""Batched random search over RollingGait travelling-wave patterns on TensegrityRoll-v0.

    python -m scripts.eval.gait_search 1 4096        # seed 1, 4096 patterns, 10 s each (~35 s on 2 cores)
    python -m scripts.eval.gait_search 7 2048 --time 40
    python -m scripts.eval.gait_search --steer-grid     # RollingGait's steering constants (~40 s)

Every pattern runs in one env of one batched vector env (the same physics as the env): the
rest-length targets of ``tensegrity_gym.tools.baselines.wave_targets`` (RollingGait's wave) with
per-env parameters, the cable-speed action that tracks them, and, per control step, the
best-fit rigid rotation of the nodes (``scripts/_bench.rotation_vectors``, Kabsch)
accumulated as a rotation vector. Prints the patterns that progressed most along +x and those
that rotated most about a horizontal axis, and saves everything to ``--out`` (npz). A pattern
rolls when its displacement is along (net turns) x z. Findings: ``results/gait_search/README.md``.

``--steer-grid`` instead runs :class:`RollingGait` itself (its default wave) with every one of
81 settings of its steering constants (bias, steer, steer_angle, heading_time_constant; 3
values each), for ``--time`` s (default 100) on 4 reset seeds with the goal +x and on 4 with
random goals, and prints the settings ranked by the worse of the two mean speeds along the goal.
SI units.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from scripts._bench import rotation_vectors
from tensegrity_gym.physics.geometry import center_of_mass, node_positions  # noqa: E402
from tensegrity_gym.tools.baselines import RollingGait, wave_targets  # noqa: E402
from tensegrity_gym.envs.roll import TensegrityRollVectorEnv  # noqa: E402


def run(P: dict, T: float = 10.0, seed: int = 0):
    """Run ``len(P["period"])`` patterns for ``T`` s from the same reset; returns the
    centre-of-mass displacements (B, 3), m, and the net rotations (B, 3), turns about x, y, z."""
    B = len(P["period"])
    env = TensegrityRollVectorEnv(num_envs=B, max_episode_steps=None)
    obs, _ = env.reset(seed=seed)
    task, act = env.task, env.task.actuation
    sl = {n: s for n, s, _ in task.observation_layout()}["control"]
    step = act.max_rate * task.control_dt

    def centred_nodes():
        N = node_positions(task.model, task.q)
        return N - N.mean(axis=1, keepdims=True)

    prev = centred_nodes()
    rot = np.zeros((B, 3))
    start = center_of_mass(task.model, task.q)
    for k in range(int(round(T / task.control_dt))):
        t = np.full(B, k * task.control_dt)
        tgt = wave_targets(t, act.nominal, act.low, act.high, P["amplitude"], P["phase"], P["period"],
                           P["direction"], P["sharpness"])
        obs, *_ = env.step(np.clip((tgt - obs[:, sl]) / step, -1, 1).astype(np.float32))
        cur = centred_nodes()
        rot += rotation_vectors(prev, cur)
        prev = cur
    env.close()
    return center_of_mass(task.model, task.q) - start, rot / (2 * np.pi)


def sample(rng: np.random.Generator, B: int) -> dict:
    """B random patterns (RollingGait's parameters, one per row)."""
    return {"amplitude": rng.uniform(0.0, 0.5, (B, 3)), "phase": rng.uniform(0, 1, (B, 3)),
            "period": rng.uniform(0.5, 4.0, B), "direction": rng.choice([-1, 1], B).astype(float),
            "sharpness": rng.choice([1.0, 2.0, 4.0], B)}


STEER_GRID = dict(bias=(0.05, 0.075, 0.1), steer=(0.025, 0.05, 0.075), steer_angle=(0.1, 0.5, 1.0),
                  heading_time_constant=(1.0, 2.0, 4.0))


def steer_grid(T: float = 100.0, repeats: int = 4) -> tuple[list, np.ndarray]:
    """Every combination of ``STEER_GRID`` (81), ``repeats`` reset seeds each, goal +x and random
    goals. Returns the settings and their speeds along the goal (81, 2, repeats), m/s."""
    import itertools
    names = list(STEER_GRID)
    settings = list(itertools.product(*STEER_GRID.values()))
    out = np.zeros((len(settings), 2, repeats))
    for g, randomize in enumerate((False, True)):
        B = len(settings) * repeats
        env = TensegrityRollVectorEnv(num_envs=B, max_episode_steps=None, randomize_goal=randomize)
        obs, _ = env.reset(seed=0)
        gait = RollingGait(env)
        for i, name in enumerate(names):
            setattr(gait, name, np.repeat([c[i] for c in settings], repeats))
        state = None
        for _ in range(int(round(T / env.task.control_dt))):
            a, state = gait.predict(obs, state)
            obs, _, _, _, info = env.step(a)
        out[:, g] = (info["distance_rolled"] / T).reshape(len(settings), repeats)
        env.close()
    return [dict(zip(names, c)) for c in settings], out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("seed", type=int, nargs="?", default=0)
    p.add_argument("n", type=int, nargs="?", default=256, help="patterns (one env each)")
    p.add_argument("--time", type=float, default=None, help="simulated seconds per pattern (default 10, "
                   "100 with --steer-grid)")
    p.add_argument("--out", default=None, help="npz with every pattern and its result")
    p.add_argument("--steer-grid", action="store_true", help="grid over RollingGait's steering constants")
    args = p.parse_args(argv)
    t0 = time.time()
    if args.steer_grid:
        T = 100.0 if args.time is None else args.time
        settings, v = steer_grid(T)
        print(f"{len(settings)} steering settings x 2 goal modes x {v.shape[2]} seeds, {T:g} s each, "
              f"in {time.time() - t0:.0f} s; speed along the goal, m/s")
        score = v.mean(axis=2).min(axis=1)
        for i in np.argsort(-score)[:10]:
            print(f"{settings[i]}  goal +x {v[i, 0].round(3).tolist()}  random goals {v[i, 1].round(3).tolist()}"
                  f"  worse mean {score[i]:.3f}")
        return 0
    args.time = 10.0 if args.time is None else args.time
    P = sample(np.random.default_rng(args.seed), args.n)
    disp, turns = run(P, T=args.time)
    print(f"{args.n} patterns x {args.time:g} s in {time.time() - t0:.1f} s")

    def show(i):
        print(f"dx {disp[i, 0]:+.3f} dy {disp[i, 1]:+.3f} turns {turns[i].round(2)} "
              f"amp {P['amplitude'][i].round(3).tolist()} ph {P['phase'][i].round(3).tolist()} "
              f"per {P['period'][i]:.3f} dir {P['direction'][i]:+.0f} sh {P['sharpness'][i]}")

    print("-- most progress along +x")
    for i in np.argsort(-disp[:, 0])[:12]:
        show(i)
    print("-- largest net rotation about a horizontal axis")
    for i in np.argsort(-np.linalg.norm(turns[:, :2], axis=1))[:8]:
        show(i)
    if args.out:
        np.savez(args.out, disp=disp, turns=turns, **P)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
