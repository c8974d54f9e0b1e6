"""Evaluate the NNLS shape controller on TensegrityShape-v0 over held-out targets, both action modes.

Runs the batched vector env (one physics call per step for all targets) with the controller's
batched predict. Held-out targets: reset seeds ``--seed`` .. ``--seed`` + n - 1 (default 10_000;
the gains were tuned on seeds 0-2, which are refused). Reports, per mode: success rate at the end of the episode (every tracked node within
the success tolerance, 1 cm for the default prism), final max/mean node error (m) and the time
to first success. Writes results/shape_baseline.json.

Usage: python -m scripts.eval.eval_shape_baseline [--n 100] [--steps 200] [--seed 10000] [--out results/shape_baseline.json]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.tools.baselines import NNLSShapeController
from tensegrity_gym.envs.shape import TensegrityShapeVectorEnv

#: default first held-out reset seed
SEED0 = 10_000
#: the reset seeds the controller's gains were tuned on
TUNING_SEEDS = range(0, 3)


def evaluate(mode: str, n: int, steps: int, seed0: int = SEED0, **env_kwargs) -> dict:
    env = TensegrityShapeVectorEnv(num_envs=n, max_episode_steps=None, action_mode=mode, **env_kwargs)
    pol = NNLSShapeController(env)
    obs, _ = env.reset(seed=seed0)
    tol = env.task.success_tolerance
    first = np.full(n, -1)
    t0 = time.perf_counter()
    for i in range(steps):
        a, _ = pol.predict(obs)
        obs, r, term, trunc, info = env.step(a)
        newly = info["is_success"] & (first < 0)
        first[newly] = i + 1
        if info["diverged"].any():
            print(f"  {mode}: {int(info['diverged'].sum())} env(s) diverged at step {i + 1}")
    wall = time.perf_counter() - t0
    emax, emean = info["max_node_error"], info["tracking_error"]
    succ = emax <= tol
    dtc = env.task.control_dt
    return {"action_mode": mode, "n_targets": n, "episode_steps": steps, "episode_s": steps * dtc,
            "success_tolerance_m": tol, "success_rate": float(succ.mean()),
            "final_max_error_m": {"mean": float(emax.mean()), "median": float(np.median(emax)),
                                  "p95": float(np.percentile(emax, 95)), "max": float(emax.max())},
            "final_mean_error_m": float(emean.mean()),
            "time_to_first_success_s": {"median": float(np.median(first[first > 0]) * dtc) if (first > 0).any() else None,
                                        "never": int((first < 0).sum())},
            "wall_s": wall}


def settle_time(n: int = 20, noise: float = 0.02, threshold: float = 1e-3, seconds: float = 4.0, **env_kwargs) -> dict:
    """Damping check: start ``n`` envs at the nominal equilibrium disturbed by +-``noise`` (m, m/s on
    each reduced coordinate), hold the nominal controls (zero actions) and report the time after
    which every node stays within ``threshold`` m of the equilibrium."""
    from tensegrity_gym.physics.geometry import node_positions
    env = TensegrityShapeVectorEnv(num_envs=n, max_episode_steps=None, reset_noise_scale=noise, **env_kwargs)
    env.reset(seed=0)
    task = env.task
    steps = int(round(seconds / task.control_dt))
    last_out = np.zeros(n)
    for i in range(steps):
        env.step(np.zeros((n, task.action_size)))
        dev = np.abs(node_positions(task.model, task.q) - task.nodes_nominal).max(axis=(1, 2))
        last_out[dev > threshold] = (i + 1) * task.control_dt
    return {"noise_m": noise, "threshold_m": threshold, "n": n, "settle_time_s_median": float(np.median(last_out)),
            "settle_time_s_max": float(last_out.max()), "env_kwargs": {k: str(v) for k, v in env_kwargs.items()}}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--n", type=int, default=100)
    p.add_argument("--steps", type=int, default=200, help="control steps (200 = the registered time limit)")
    p.add_argument("--seed", type=int, default=SEED0, help=f"first held-out reset seed (default {SEED0})")
    p.add_argument("--out", default="results/shape_baseline.json")
    args = p.parse_args(argv)
    if args.n < 1 or args.seed < 0 or args.seed + args.n - 1 > 2**32 - 1:
        print(f"error: --n, --seed: need n >= 1 and seeds in 0..2**32-1, got {args.n}, {args.seed}", file=sys.stderr)
        return 2
    tuned = sorted(set(TUNING_SEEDS) & set(range(args.seed, args.seed + args.n)))
    if tuned:
        print(f"error: --seed: the held-out seeds {args.seed}..{args.seed + args.n - 1} include the seeds the "
              f"controller's gains were tuned on ({tuned})", file=sys.stderr)
        return 2
    results = {}
    for mode in ("rest_length", "force_density"):
        r = evaluate(mode, args.n, args.steps, args.seed)
        results[mode] = r
        print(f"{mode:14s} success {r['success_rate'] * 100:5.1f}%  final max error mean "
              f"{r['final_max_error_m']['mean'] * 1e3:.2f} mm, p95 {r['final_max_error_m']['p95'] * 1e3:.2f} mm, "
              f"max {r['final_max_error_m']['max'] * 1e3:.2f} mm; median time to success "
              f"{r['time_to_first_success_s']['median']} s  ({r['wall_s']:.1f} s wall)", flush=True)
    st = settle_time()
    st0 = settle_time(node_damping=0.0)
    print(f"settling (2 cm disturbance to < 1 mm, default damping): median {st['settle_time_s_median']:.2f} s, "
          f"max {st['settle_time_s_max']:.2f} s; without node drag: median {st0['settle_time_s_median']:.2f} s, "
          f"max {st0['settle_time_s_max']:.2f} s (>= 4 s means not settled in the 4 s simulated)")
    results["settling_default_damping"] = st
    results["settling_no_node_damping"] = st0
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"command": "python -m scripts.eval.eval_shape_baseline --n %d --steps %d --seed %d" % (args.n, args.steps,
                                                                                               args.seed),
            "env": "TensegrityShape-v0 defaults (constrained_prism, 50 Hz control)",
            "held_out_seeds": f"{args.seed} + i", "reset_seeds": [args.seed, args.seed + args.n - 1]}
    out.write_text(json.dumps({"meta": meta, **results}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
