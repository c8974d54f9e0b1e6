#!/usr/bin/env python
"""Climbing table: uphill speed against slope for trained TensegrityClimb-v0 policies (one run
folder per training seed) and for the non-learning rolling gait, on held-out reset seeds.

    python -m scripts.eval.eval_climb runs/ppo_climb_s0 [runs/ppo_climb_s1 ...] --out results/climb \
        [--slopes 0 5 10 15 20 24 26 28 30] [--episodes 8] [--model final] [--env-kwargs '{"structure": "prism"}']

Per slope: each run's mean uphill speed over ``--episodes`` episodes of 20 s (the registered time
limit) from reset seeds 10000, 10001, ... (never used in training: training seeds its envs with
``seed + i`` for i < n_envs and its evaluations from 1000); the speed of an episode is its
distance climbed along the slope divided by its duration (m/s, and body lengths/s with the
robot's longest rod). Across runs: IQM with a 95 % bootstrap interval (``agents.summary.iqm_interval``),
min and max. Writes ``climb.json``, ``climb.csv`` and ``climb.png`` into ``--out``.
"""
from __future__ import annotations

import csv
import json
import sys

import numpy as np

from tensegrity_gym_agents.evaluate import run_episodes
from tensegrity_gym.io.atomic import write_atomic
from tensegrity_gym.tools.baselines import RollingGait

from scripts.eval._policy_table import iqm_row, parse_table_args, table_parser, trained_policies

ENV_ID = "TensegrityClimb-v0"
SEED0 = 10000


def episode_speeds(policy_factory, slope: float, episodes: int, env_kwargs: dict) -> np.ndarray:
    """(episodes,) uphill speed, m/s, of each held-out episode on a slope of ``slope`` degrees."""
    eps = run_episodes(ENV_ID, dict(env_kwargs, slope_deg=float(slope)), policy_factory,
                       list(range(SEED0, SEED0 + episodes)))
    return np.array([e["final"]["distance_rolled"] / (e["length"] * e["dt"]) for e in eps])


def main(argv=None) -> int:
    ap = table_parser(__doc__, env_kwargs_help="JSON object of extra env arguments (the robot)")
    ap.add_argument("--slopes", type=float, nargs="+", default=[0, 5, 10, 15, 20, 24, 26, 28, 30])
    ap.add_argument("--episodes", type=int, default=8)
    args, env_kwargs = parse_table_args(ap, argv)
    import gymnasium as gym
    body = float(np.max(gym.make(ENV_ID, **env_kwargs).unwrapped.task.structure.bar_lengths))
    rows, per_run = [], {}
    for run, policy, model_path in trained_policies(args.runs, args.model):
        per_run[str(run)] = {"model": str(model_path),
                             "speed_m_s": [float(episode_speeds(lambda env: policy, s, args.episodes, env_kwargs).mean())
                                           for s in args.slopes]}
        print(f"{run}: " + " ".join(f"{s:g}:{v:.3f}" for s, v in zip(args.slopes, per_run[str(run)]["speed_m_s"])),
              flush=True)
    baseline = None
    if not args.no_baseline and env_kwargs.get("structure", "prism") == "prism":
        baseline = [float(episode_speeds(lambda env: RollingGait(env), s, args.episodes, env_kwargs).mean())
                    for s in args.slopes]
        print("rolling gait: " + " ".join(f"{s:g}:{v:.3f}" for s, v in zip(args.slopes, baseline)), flush=True)
    table = []
    for j, s in enumerate(args.slopes):
        vals = [r["speed_m_s"][j] for r in per_run.values()]
        row = {"slope_deg": s}
        if vals:
            row.update(iqm_row(vals))
            row.update(iqm_body_lengths_s=row["iqm_m_s"] / body, runs_climbing=int(sum(v > 0 for v in vals)))
        if baseline is not None:
            row["gait_m_s"] = baseline[j]
        table.append(row)
        rows.append([s] + ([row["iqm_m_s"], *row["ci95_m_s"], row["min_m_s"], row["max_m_s"],
                            row["iqm_body_lengths_s"]] if vals else [""] * 6) + [row.get("gait_m_s", "")])
    out = {"env_id": ENV_ID, "env_kwargs": env_kwargs, "model": args.model, "episodes": args.episodes,
           "reset_seeds": [SEED0, SEED0 + args.episodes - 1], "body_length_m": body, "runs": per_run,
           "table": table, "command": " ".join(["python", "-m", "scripts.eval.eval_climb"] + (argv or sys.argv[1:]))}
    payload = json.dumps(out, indent=1).encode()
    write_atomic(args.out / "climb.json", lambda f: f.write(payload))
    with open(args.out / "climb.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["slope_deg", "iqm_m_s", "ci95_low", "ci95_high", "min_m_s", "max_m_s", "iqm_body_lengths_s",
                    "gait_m_s"])
        w.writerows(rows)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    if per_run:
        ax.plot(args.slopes, [r["iqm_m_s"] for r in table], "o-", label=f"PPO, IQM of {len(per_run)} seeds")
        ax.fill_between(args.slopes, [r["ci95_m_s"][0] for r in table], [r["ci95_m_s"][1] for r in table], alpha=0.3)
    if baseline is not None:
        ax.plot(args.slopes, baseline, "s--", label="rolling gait (no learning)")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.axvline(24.0, color="gray", ls=":", label="24 deg: hardware record")
    ax.set_xlabel("slope (degrees)")
    ax.set_ylabel("uphill speed (m/s)")
    ax.set_title(f"{ENV_ID}: uphill speed against slope")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out / "climb.png", dpi=100)
    for r in table:
        print(f"{r['slope_deg']:5.1f} deg  " + (f"IQM {r['iqm_m_s']:.3f} m/s [{r['ci95_m_s'][0]:.3f}, "
                                                f"{r['ci95_m_s'][1]:.3f}]  " if "iqm_m_s" in r else "")
              + (f"gait {r['gait_m_s']:.3f} m/s" if "gait_m_s" in r else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
