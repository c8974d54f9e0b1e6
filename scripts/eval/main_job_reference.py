"""The main job's reference figure: the same training over several seeds, evaluated as the main job does.

    python -m scripts.eval.main_job_reference                       # seeds 0-4, about 5 x 2 min on 2 cores
    python -m scripts.eval.main_job_reference --seeds 0 1 2 --runs runs/main_job_reference

Trains ``scripts/eval/main_job.py``'s PPO (same settings file, same step budget, same evaluation
schedule) once per seed into ``--runs``/s<seed>, evaluates each final policy on the 100 held-out
targets with :mod:`agents.multiseed` (IQM over seeds with a 95 % bootstrap interval) into
``--out``, and writes ``--out``/reference.json, which the main job reads to say how its own
result compares. A run folder that holds a finished training is reused (not trained again).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from main_job import BUDGET, CONF, ENV_ID, REFERENCE, ROOT, train_argv


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--runs", default=str(ROOT / "runs" / "main_job_reference"), help="folder of the run folders")
    p.add_argument("--out", default=str(REFERENCE.parent), help="multiseed output folder (reference.json there)")
    p.add_argument("--n-timesteps", type=int, default=BUDGET)
    args = p.parse_args(argv)

    from tensegrity_gym_agents import multiseed, train

    runs = []
    for s in args.seeds:
        run = Path(args.runs) / f"s{s}"
        state = run / "state.json"
        done = state.exists() and json.loads(state.read_text()).get("status") == "finished"
        if not done:
            print(f"[reference] training seed {s} -> {run}", flush=True)
            train.train(train_argv(s, run, args.n_timesteps) + (["--resume", str(run)] if state.exists() else []))
        runs.append(str(run))
    title = (f"{ENV_ID}: the main job (PPO, agents/hyperparams/{CONF}, {args.n_timesteps:,} env steps), "
             f"{len(runs)} training seeds, final models")
    rc = multiseed.main(runs + ["--out", args.out, "--model", "final", "--goal", "success_rate>=0.95", "--title", title])
    if rc:
        return rc
    summary = json.loads((Path(args.out) / "summary.json").read_text())
    agg = summary["aggregate"]["success_rate"]
    ref = {"what": title, "n_seeds": len(runs), "seeds": args.seeds, "budget_steps": args.n_timesteps,
           "held_out_episodes": summary["held_out_episodes_per_seed"],
           "success_rate": {"iqm": agg["iqm"], "ci": agg["ci95"], "min": agg["min"], "max": agg["max"]},
           "per_seed": {str(r["seed"]): {"success_rate": r["success_rate"], "steps": r["model_num_timesteps"],
                                         "training_wall_time_s": r["training_wall_time_s"]}
                        for r in summary["per_seed"]},
           "command": "python -m scripts.eval.main_job_reference " + " ".join(argv if argv is not None else sys.argv[1:])}
    (Path(args.out) / "reference.json").write_text(json.dumps(ref, indent=2) + "\n")
    print(f"[reference] success IQM {100 * agg['iqm']:.1f} % [{100 * agg['ci95'][0]:.1f}, {100 * agg['ci95'][1]:.1f}] "
          f"over {len(runs)} seeds -> {Path(args.out) / 'reference.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
