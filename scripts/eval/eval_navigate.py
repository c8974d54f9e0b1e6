#!/usr/bin/env python
"""Navigation table: success rate of trained TensegrityNavigate-v0 policies (one run folder per
training seed) and of the non-learning baseline on held-out courses.

    python -m scripts.eval.eval_navigate runs/ppo_navigate_s0 [runs/ppo_navigate_s1 ...] --out results/navigate \
        [--courses 100] [--model final] [--env-kwargs '{}'] [--no-baseline]

Each policy runs one episode on each of ``--courses`` courses, drawn from reset seeds 20000,
20001, ... (never used in training: training seeds its envs with ``seed + i`` for i < n_envs and
its evaluations from 1000; the course is drawn from the reset seed): 3 goal points among 5 walls
and 2 rough patches, 60 s (the registered time limit), deterministic actions. Success: all goals
reached. The baseline is :class:`tensegrity_gym.tools.baselines.RollingGait` steered by the same
planner guidance the policies observe. Across runs: IQM of the success rate with a 95 % bootstrap
interval (``agents.summary.iqm_interval``), min and max. Writes ``navigate.json`` and ``navigate.csv``
into ``--out``.
"""
from __future__ import annotations

import csv
import json
import sys

import numpy as np

from tensegrity_gym_agents.evaluate import run_episodes
from tensegrity_gym_agents.summary import iqm_interval
from tensegrity_gym.io.atomic import write_atomic
from tensegrity_gym.tools.baselines import RollingGait

from scripts.eval._policy_table import parse_table_args, table_parser, trained_policies

ENV_ID = "TensegrityNavigate-v0"
SEED0 = 20000


def course_results(policy_factory, courses: int, env_kwargs: dict) -> dict:
    """Per course: success, goals reached and the time to the last goal reached (s)."""
    eps = run_episodes(ENV_ID, env_kwargs, policy_factory, list(range(SEED0, SEED0 + courses)))
    success = np.array([bool(e["final"]["success"]) for e in eps])
    goals = np.array([int(e["final"]["goals_reached"]) for e in eps])
    time_s = np.array([e["length"] * e["dt"] for e in eps])
    return {"success_rate": float(success.mean()), "mean_goals_reached": float(goals.mean()),
            "mean_time_of_successes_s": float(time_s[success].mean()) if success.any() else None,
            "success": success.tolist(), "goals_reached": goals.tolist()}


def main(argv=None) -> int:
    ap = table_parser(__doc__)
    ap.add_argument("--courses", type=int, default=100)
    args, env_kwargs = parse_table_args(ap, argv)
    per_run = {}
    for run, policy, model_path in trained_policies(args.runs, args.model):
        r = course_results(lambda env: policy, args.courses, env_kwargs)
        per_run[str(run)] = {"model": str(model_path), **r}
        print(f"{run}: success {r['success_rate']:.0%}, goals {r['mean_goals_reached']:.2f}", flush=True)
    baseline = None
    if not args.no_baseline:
        baseline = course_results(lambda env: RollingGait(env), args.courses, env_kwargs)
        print(f"rolling gait + planner: success {baseline['success_rate']:.0%}, "
              f"goals {baseline['mean_goals_reached']:.2f}", flush=True)
    summary = {}
    rates = [r["success_rate"] for r in per_run.values()]
    if rates:
        iqm, lo, hi = iqm_interval(rates)
        summary = {"iqm_success": iqm, "ci95": [lo, hi], "min": float(min(rates)), "max": float(max(rates)),
                   "runs": len(rates)}
    out = {"env_id": ENV_ID, "env_kwargs": env_kwargs, "model": args.model, "courses": args.courses,
           "reset_seeds": [SEED0, SEED0 + args.courses - 1], "runs": per_run, "baseline": baseline,
           "summary": summary, "command": " ".join(["python", "-m", "scripts.eval.eval_navigate"] + (argv or sys.argv[1:]))}
    payload = json.dumps(out, indent=1).encode()
    write_atomic(args.out / "navigate.json", lambda f: f.write(payload))
    with open(args.out / "navigate.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["policy", "success_rate", "mean_goals_reached", "mean_time_of_successes_s"])
        for name, r in per_run.items():
            w.writerow([name, r["success_rate"], r["mean_goals_reached"], r["mean_time_of_successes_s"]])
        if baseline is not None:
            w.writerow(["rolling gait + planner", baseline["success_rate"], baseline["mean_goals_reached"],
                        baseline["mean_time_of_successes_s"]])
    if summary:
        print(f"IQM success {summary['iqm_success']:.0%} [{summary['ci95'][0]:.0%}, {summary['ci95'][1]:.0%}] "
              f"over {summary['runs']} seeds")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
