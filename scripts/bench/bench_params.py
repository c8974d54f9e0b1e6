#!/usr/bin/env python
"""Cost of per-copy physical parameters (targets: shared values cost nothing measurable;
env throughput with randomisation on vs off within 10 %).

    NUMBA_NUM_THREADS=2 python -m scripts.bench.bench_params [--rounds 15] [--out results/bench_params.json]

Physics rows: ``physics.step`` of the free 3-prism (semi-implicit Euler, dt = 1 ms, 20 steps
per call) at B = 1, 64 and 4096 with ``params=None``, with one shared row
(``default_params(model)``) and with B rows holding the same values (``default_params(model, B)``:
the per-copy kernel). Env rows: env-steps/s of a single env and of a vector env (N = 256) of
``TensegrityRoll-v0`` and ``TensegrityShape-v0`` with no robot parameters, and with
``randomize={...}`` (every parameter the env has): stepping (no reset inside the timed window)
and, as a separate group, resetting every copy (where the parameters are drawn; per second of
resets, counted per copy). Every cell is the best of ``--rounds`` rounds, the
variants interleaved round by round (a load change hits them alike); ratios are against the
first row of each group, measured in the same run.
"""
from __future__ import annotations

import argparse
import os
import platform

import numpy as np
import gymnasium as gym

import tensegrity_gym as tg
from tensegrity_gym.core.params import default_params
from tensegrity_gym_agents.common import write_json

from scripts._bench import interleaved_reps

ROLL_RANDOM = {"rod_mass": 0.2, "stiffness": 0.2, "damping": 0.2, "friction": 0.2, "ground_stiffness": 0.2,
               "ground_damping": 0.2, "rest_length_offset": 0.005, "max_cable_speed": 0.2,
               "max_cable_acceleration": 0.2, "gravity": 0.05}
SHAPE_RANDOM = {"rod_mass": 0.2, "stiffness": 0.2, "damping": 0.2, "node_damping": 0.2, "rest_length_offset": 0.003}


def physics_rows(rounds: int) -> list[dict]:
    model = tg.compile_model(tg.prism(3, prestress=100.0))
    rows = []
    for B in (1, 64, 4096):
        st = tg.initial_state(model, B)
        variants = {"params=None": None, "shared Params (P = 1)": default_params(model),
                    f"per-copy Params (P = {B}), equal values": default_params(model, B)}
        reps = max(1, 20000 // (B * 20))
        fns = {k: ((lambda p=p: tg.step(model, st, 1e-3, "semi_implicit_euler", n_steps=20, params=p)), reps)
               for k, p in variants.items()}
        for f, _ in fns.values():   # compile / pack outside the timing
            f()
        best = interleaved_reps(fns, rounds)
        ref = best["params=None"]
        for k, t in best.items():
            rows.append({"group": f"physics B = {B}", "variant": k, "env_steps_per_s": B * 20 / t,
                         "ratio_to_first": t / ref})
    return rows


def env_rows(rounds: int) -> list[dict]:
    rows = []
    for env_id, rnd in (("TensegrityRoll-v0", ROLL_RANDOM), ("TensegrityShape-v0", SHAPE_RANDOM)):
        for N in (1, 256):
            steps, resets = {}, {}
            for label, kw in (("defaults", {}), ("randomize (all parameters)", {"randomize": rnd})):
                env = (gym.make(env_id, **kw) if N == 1 else
                       gym.make_vec(env_id, num_envs=N, vectorization_mode="vector_entry_point",
                                    max_episode_steps=None, **kw))
                env.reset(seed=0)
                a = np.zeros(env.action_space.shape, np.float32)

                def run(env=env, a=a):
                    for _ in range(20):
                        env.step(a)

                def reset(env=env):
                    env.reset()
                steps[label] = (run, 1)
                resets[label] = (reset, 1)
                run()
            for what, fns, per in (("step", steps, N * 20), ("reset (all copies)", resets, N)):
                best = interleaved_reps(fns, rounds)
                ref = best["defaults"]
                for k, t in best.items():
                    rows.append({"group": f"{env_id} N = {N}, {what}", "variant": k, "env_steps_per_s": per / t,
                                 "ratio_to_first": t / ref})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=15)
    p.add_argument("--out", default=None, help="also write the rows as JSON here (atomically)")
    args = p.parse_args(argv)
    rows = physics_rows(args.rounds) + env_rows(args.rounds)
    print("| group | variant | env-steps/s | time ratio to the first row |\n|---|---|---:|---:|")
    for r in rows:
        print(f"| {r['group']} | {r['variant']} | {r['env_steps_per_s']:,.0f} | {r['ratio_to_first']:.3f} |")
    if args.out:
        doc = {"machine": f"{platform.machine()}, {os.cpu_count()} cores", "rounds": args.rounds, "rows": rows,
               "command": "python -m scripts.bench.bench_params" + (f" --rounds {args.rounds}" if args.rounds != 15 else "")}
        write_json(args.out, doc)      # atomic (temporary file, fsync, rename)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
