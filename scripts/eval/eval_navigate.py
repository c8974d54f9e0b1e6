#!/usr/bin/env python
"""Navigation table: success rate of trained TensegrityNavigate-v0 policies (one run folder per
training seed) and of the non-learning baseline on held-out courses.

    python -m scripts.eval.eval_navigate runs/ppo_navigate_s0 [runs/ppo_navigate_s1 ...] --out results/navigate \
        [--courses 100] [--seed 20000] [--model final] [--env-kwargs '{}'] [--no-baseline]

Each policy runs one episode on each of ``--courses`` courses, drawn from reset seeds ``--seed``,
``--seed`` + 1, ... (default 20000; the course is drawn from the reset seed): 3 goal points among
5 walls and 2 rough patches, 60 s (the registered time limit), deterministic actions. The seeds
must be clear of every seed a run used (its training envs ``seed + i`` for i < n_envs, its
evaluation env during training ``seed + 10000 + i`` for i < n_eval_envs): an overlap is refused,
exit status 2, naming the run and the seeds (:mod:`agents.heldout`). Success: all goals reached.
The baseline is :class:`tensegrity_gym.tools.baselines.RollingGait` steered by the same planner
guidance the policies observe. Per training seed: the success rate with its 95 % Wilson interval
over the courses (``agents.summary.rate_interval``). Across runs: IQM of the success rate with a
95 % bootstrap interval (``agents.summary.iqm_interval``), min and max, and the lowest per-seed
interval (what a claim about every seed can state). Writes ``navigate.json`` and ``navigate.csv``
into ``--out``.
"""
from __future__ import annotations

import csv
import json
import sys

import numpy as np

from tensegrity_gym_agents.evaluate import run_episodes
from tensegrity_gym_agents.summary import iqm_interval, rate_interval
from tensegrity_gym.io.atomic import write_atomic
from tensegrity_gym.tools.baselines import RollingGait

from scripts.eval._policy_table import held_out, parse_table_args, table_parser, trained_policies

ENV_ID = "TensegrityNavigate-v0"
#: default first held-out reset seed (courses)
SEED0 = 20000


def course_results(policy_factory, seeds: list[int], env_kwargs: dict) -> dict:
    """Per course (one per reset seed in ``seeds``): success, goals reached and the time to the
    last goal reached (s); the success rate with its 95 % Wilson interval."""
    eps = run_episodes(ENV_ID, env_kwargs, policy_factory, seeds)
    success = np.array([bool(e["final"]["success"]) for e in eps])
    goals = np.array([int(e["final"]["goals_reached"]) for e in eps])
    time_s = np.array([e["length"] * e["dt"] for e in eps])
    _, lo, hi = rate_interval(int(success.sum()), success.size)
    return {"success_rate": float(success.mean()), "ci95": [lo, hi], "mean_goals_reached": float(goals.mean()),
            "mean_time_of_successes_s": float(time_s[success].mean()) if success.any() else None,
            "success": success.tolist(), "goals_reached": goals.tolist()}


def main(argv=None) -> int:
    ap = table_parser(__doc__, SEED0)
    ap.add_argument("--courses", type=int, default=100)
    args, env_kwargs = parse_table_args(ap, argv)
    if args.courses < 1:
        print(f"error: --courses: must be >= 1, got {args.courses}", file=sys.stderr)
        return 2
    seeds = held_out(args, args.courses)
    per_run = {}
    for run, policy, model_path in trained_policies(args.runs, args.model):
        r = course_results(lambda env: policy, seeds, env_kwargs)
        per_run[str(run)] = {"model": str(model_path), **r}
        print(f"{run}: success {r['success_rate']:.1%} [{r['ci95'][0]:.1%}, {r['ci95'][1]:.1%}], "
              f"goals {r['mean_goals_reached']:.2f}", flush=True)
    baseline = None
    if not args.no_baseline:
        baseline = course_results(lambda env: RollingGait(env), seeds, env_kwargs)
        print(f"rolling gait + planner: success {baseline['success_rate']:.1%} [{baseline['ci95'][0]:.1%}, "
              f"{baseline['ci95'][1]:.1%}], goals {baseline['mean_goals_reached']:.2f}", flush=True)
    summary = {}
    rates = [r["success_rate"] for r in per_run.values()]
    if rates:
        iqm, lo, hi = iqm_interval(rates)
        worst = min(per_run, key=lambda k: per_run[k]["ci95"][0])
        summary = {"iqm_success": iqm, "ci95": [lo, hi], "min": float(min(rates)), "max": float(max(rates)),
                   "runs": len(rates), "lowest_seed_ci95": {"run": worst, "success_rate": per_run[worst]["success_rate"],
                                                            "ci95": per_run[worst]["ci95"]}}
    out = {"env_id": ENV_ID, "env_kwargs": env_kwargs, "model": args.model, "courses": args.courses,
           "reset_seeds": [seeds[0], seeds[-1]],
           "per_seed_interval": "success rate over the courses, 95 % Wilson score interval",
           "runs": per_run, "baseline": baseline,
           "summary": summary, "command": " ".join(["python", "-m", "scripts.eval.eval_navigate"] + (argv or sys.argv[1:]))}
    payload = json.dumps(out, indent=1).encode()
    write_atomic(args.out / "navigate.json", lambda f: f.write(payload))
    with open(args.out / "navigate.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["policy", "success_rate", "mean_goals_reached", "mean_time_of_successes_s", "ci95_low",
                    "ci95_high", "first_reset_seed", "last_reset_seed"])
        named = list(per_run.items()) + ([("rolling gait + planner", baseline)] if baseline is not None else [])
        for name, r in named:
            w.writerow([name, r["success_rate"], r["mean_goals_reached"], r["mean_time_of_successes_s"],
                        *r["ci95"], seeds[0], seeds[-1]])
    if summary:
        low = summary["lowest_seed_ci95"]
        print(f"IQM success {summary['iqm_success']:.1%} [{summary['ci95'][0]:.1%}, {summary['ci95'][1]:.1%}] "
              f"over {summary['runs']} seeds; lowest seed {low['run']}: {low['success_rate']:.1%} "
              f"[{low['ci95'][0]:.1%}, {low['ci95'][1]:.1%}]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
