"""The README's main job: PPO training on the default scene, evaluation, results folder.

    python scripts/main_job.py                      # about 5-8 min on a 2-core machine
    python scripts/main_job.py --train-seconds 60   # shorter

1. trains PPO (``agents/hyperparams/ppo.yml``, entry ``TensegrityShape-v0``) on the default
   ``TensegrityShape-v0`` scene (the seed's Example 5.8 prism, rest-length actions) for at most
   ``--n-timesteps`` env steps or ``--train-seconds`` of wall time, whichever comes first;
2. evaluates the trained policy on ``--n-episodes`` held-out targets beside the NNLS baseline
   controller and a random policy (:mod:`agents.evaluate`);
3. writes ``results/main_job/``: ``metrics.json`` (numbers), ``table.md``, ``learning_curve.png``,
   ``episodes.png``, ``rollout.gif``, and the run's ``config.yaml``, ``command.txt``,
   ``versions.json``, ``model.zip``, ``vecnormalize.pkl``.

With the file's tuned entry (1.5M steps, about 3 min of training on 2 cores) this is the full
training behind the committed result ``results/ppo_shape_rest_length/`` (94 % success on 100
held-out targets); a machine slower than that stops at ``--train-seconds`` with less. Every
committed result and its command: ``results/README.md``.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=str(ROOT / "results" / "main_job"))
    p.add_argument("--train-seconds", type=float, default=360.0, help="wall-time budget of the training (s)")
    p.add_argument("--n-timesteps", type=int, default=1_500_000, help="env-step budget of the training")
    p.add_argument("--n-episodes", type=int, default=100, help="held-out evaluation episodes (trained policy)")
    p.add_argument("--baseline-episodes", type=int, default=50, help="episodes for the NNLS baseline and random")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    from agents import evaluate, train

    t0 = time.time()
    out = Path(args.out)
    run = ROOT / "runs" / f"main_job_{time.strftime('%Y%m%d_%H%M%S')}"
    print(f"[main job] 1/3 training PPO on TensegrityShape-v0 for at most {args.n_timesteps} steps / "
          f"{args.train_seconds:.0f} s -> {run}")
    train.train(["--algo", "ppo", "--env", "TensegrityShape-v0", "--seed", str(args.seed), "--log-dir", str(run),
                 "--n-timesteps", str(args.n_timesteps), "--max-wall-time", str(args.train_seconds),
                 "--eval-freq", str(max(args.n_timesteps // 15, 1)), "--eval-episodes", "10",
                 "--save-freq", "-1"])
    t1 = time.time()
    print(f"[main job] 2/3 evaluating on {args.n_episodes} held-out targets (NNLS baseline and random on "
          f"{args.baseline_episodes})")
    # write into a fresh folder beside OUT and swap it in only at the end: an interrupted run
    # (Ctrl-C, crash) leaves the previous results untouched
    final = out
    out = final.parent / f".{final.name}.partial-{os.getpid()}"
    out.mkdir(parents=True)
    metrics = evaluate.evaluate([str(run), "--model", "best", "--n-episodes", str(args.n_episodes),
                                 "--baseline-episodes", str(args.baseline_episodes), "--gif", "--out", str(out)])
    t2 = time.time()
    print("[main job] 3/3 copying the run's config, command, versions and model")
    for f in ("config.yaml", "command.txt", "versions.json", "state.json", "best_model.zip",
              "best_vecnormalize.pkl"):
        if (run / f).exists():
            shutil.copy2(run / f, out / f)
    summary = (f"training {t1 - t0:.0f} s ({metrics['model_num_timesteps']} steps of the best model), "
               f"evaluation {t2 - t1:.0f} s, total {time.time() - t0:.0f} s")
    (out / "README.md").write_text(
        "# Main job: PPO training on TensegrityShape-v0 (default scene)\n\n"
        f"{summary}.\n\nHeld-out evaluation ({args.n_episodes} targets for the trained policy, "
        f"{args.baseline_episodes} for the baselines):\n\n```\n{(out / 'table.md').read_text()}```\n\n"
        "Reproduce: `python scripts/main_job.py`. The same training without the wall-time cap, and "
        "every other committed result with its command: `results/README.md`:\n\n"
        "```\npython -m agents.train --algo ppo --env TensegrityShape-v0 --seed 0 --log-dir runs/ppo_shape\n"
        "python -m agents.evaluate runs/ppo_shape --gif --copy-run-files --out results/ppo_shape\n```\n")
    if final.exists():   # swap: old -> backup, new -> OUT, then drop the backup
        backup = final.parent / f".{final.name}.old-{os.getpid()}"
        final.rename(backup)
        out.rename(final)
        shutil.rmtree(backup)
    else:
        out.rename(final)
    print(f"[main job] done: {summary}; results in {final}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
