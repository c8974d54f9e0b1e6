#!/usr/bin/env python
"""Shape tracking under model error: on held-out robots whose stiffness, rod masses
and cable rest lengths differ from the nominal model, the NNLS controller (which believes the
nominal model) against a policy trained with randomisation.

    python -m scripts.eval.eval_model_error --run runs/ppo_shape_randomized [--n 100] [--seed 1000000] \
        [--out results/model_error/metrics.json]

Robots: ``TensegrityShape-v0`` with ``randomize={"stiffness": 0.2, "rod_mass": 0.2,
"rest_length_offset": 0.01}`` (every string's stiffness and every rod's mass x U(0.8, 1.2), every
string's rest length + U(-1 cm, 1 cm)), held-out seeds ``--seed`` + i (default 1,000,000,
agents.evaluate's; they must be clear of the run's training seeds ``seed + i`` and evaluation
seeds during training ``seed + 10000 + i``, else refused with exit status 2:
:mod:`agents.heldout`), one 200-step episode each, the same robots and targets for every
controller. Also on the nominal robot (no randomisation, same seeds) for reference. Reports the
final max node error (m and % of the structure's height) and the success rate (every tracked node
within 1 % of the height at the episode's end).
"""
from __future__ import annotations

import argparse
import os
import sys
import platform
from pathlib import Path

import numpy as np

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.tools.baselines import NNLSShapeController
from tensegrity_gym_agents import evaluate as ev
from tensegrity_gym_agents.common import write_json
from tensegrity_gym_agents.episode_metrics import scene_scales
from tensegrity_gym_agents.heldout import script_heldout_seeds

ENV = "TensegrityShape-v0"
RANDOM = {"stiffness": 0.2, "rod_mass": 0.2, "rest_length_offset": 0.01}
#: default first held-out reset seed
SEED0 = 1_000_000


def _summary(eps: list[dict], height: float) -> dict:
    err = np.array([e["final"]["max_node_error"] for e in eps])
    ok = np.array([bool(e["final"]["is_success"]) for e in eps])
    return {"episodes": len(eps), "success_rate": float(ok.mean()),
            "final_max_error_median_m": float(np.median(err)), "final_max_error_mean_m": float(err.mean()),
            "final_max_error_median_pct_height": float(100 * np.median(err) / height),
            "final_max_error_p90_m": float(np.quantile(err, 0.9))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, required=True, help="training run directory (agents.train --log-dir)")
    p.add_argument("--which", default="best", help="best | final | path to a model zip")
    p.add_argument("--n", type=int, default=100)
    p.add_argument("--seed", type=int, default=SEED0,
                   help=f"first held-out reset seed (default {SEED0}); must be clear of the run's own seeds")
    p.add_argument("--out", type=Path, default=Path("results/model_error/metrics.json"))
    args = p.parse_args(argv)
    if args.n < 1:
        print(f"error: --n: must be >= 1, got {args.n}", file=sys.stderr)
        return 2
    seeds = list(script_heldout_seeds(args.seed, args.n, [args.run] + ([] if args.which in ("best", "final")
                                                                       else [args.which])))
    cfg, policy, model_path, _ = ev.load_trained(args.run, args.which)
    base_kwargs = {k: v for k, v in (cfg.get("env_kwargs") or {}).items() if k != "randomize"}
    scales = scene_scales(ENV, base_kwargs)
    height = float(scales.get("height", 1.0))
    controllers = {
        "NNLS (nominal model, feedforward)": lambda env: NNLSShapeController(env),
        "NNLS (nominal model, with PD feedback)": lambda env: NNLSShapeController(env, feedback=True),
        f"PPO trained with randomisation ({args.run.name})": lambda env: policy,
    }
    results = {}
    for robots, kw in (("held-out randomised robots", {"randomize": RANDOM}), ("nominal robot", {})):
        for name, factory in controllers.items():
            eps = ev.run_episodes(ENV, dict(base_kwargs, **kw), factory, seeds)
            results[f"{robots} | {name}"] = _summary(eps, height)
    print(f"| robots | controller | success | median final max error | % of height | 90th pct |\n"
          f"|---|---|---:|---:|---:|---:|")
    for key, r in results.items():
        robots, name = key.split(" | ")
        print(f"| {robots} | {name} | {100 * r['success_rate']:.0f} % | {1e3 * r['final_max_error_median_m']:.2f} mm "
              f"| {r['final_max_error_median_pct_height']:.2f} % | {1e3 * r['final_max_error_p90_m']:.2f} mm |")
    doc = {"command": "python -m scripts.eval.eval_model_error --run " + str(args.run) + f" --n {args.n}"
                      + ("" if args.seed == SEED0 else f" --seed {args.seed}"),
           "machine": f"{platform.machine()}, {os.cpu_count()} cores", "env": ENV, "randomize": RANDOM,
           "seeds": [seeds[0], seeds[-1]], "reset_seeds": [seeds[0], seeds[-1]], "model": str(model_path), "training_config": cfg.get("env_kwargs"),
           "results": results}
    write_json(args.out, doc)      # atomic (temporary file, fsync, rename)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
