"""The README's main job: PPO on the default scene, held-out evaluation, a new results folder.

    python -m scripts.eval.main_job                          # minutes; the first run also compiles the kernels
    python -m scripts.eval.main_job --out runs/my_main_job   # a folder of your choice (must not exist)

1. trains PPO with the time-to-policy settings (``agents/hyperparams/time_to_policy/ppo.yml``,
   entry ``TensegrityShape-v0``: 256 envs, short horizon, small updates) on the default
   ``TensegrityShape-v0`` scene (a 3-bar prism tracking target shapes with rest-length actions)
   for a budget of ``--n-timesteps`` env steps. The budget is in steps, not seconds, so the
   result does not depend on the machine's speed; progress is printed as a line every 10 s;
2. evaluates the final policy on ``--n-episodes`` held-out targets beside the NNLS baseline
   controller and a random policy (:mod:`agents.evaluate`), with a GIF of one episode;
3. writes everything into a NEW folder (default ``runs/main_job/<date_time>``; an existing
   folder is refused, so nothing saved before is overwritten): ``metrics.json``, ``table.md``,
   ``README.md``, ``learning_curve.png``, ``episodes.png``, ``rollout.gif``, and ``run/`` (the
   training run: model, normalisation statistics, config, command, versions);
4. says what was reached against what the project reaches with the same command
   (``results/main_job/reference.json``: the default budget over 5 training seeds) when the
   budget is the reference's (another budget: that the reference does not apply), and says so
   when the budget was cut short (Ctrl-C or ``--max-wall-time``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: the shipped hyperparameter file, named relative to the package's hyperparams folder
CONF = "time_to_policy/ppo.yml"
REFERENCE = ROOT / "results" / "main_job" / "reference.json"
ENV_ID = "TensegrityShape-v0"
BUDGET = 1_200_000


def train_argv(seed: int, run: Path, budget: int, max_wall_time: float | None = None) -> list[str]:
    """agents.train's arguments of the main job's training (also the reference's, one per seed)."""
    argv = ["--algo", "ppo", "--env", ENV_ID, "--conf-file", CONF, "--seed", str(seed), "--log-dir", str(run),
            "--n-timesteps", str(budget), "--eval-freq", str(max(budget // 12, 1)), "--eval-episodes", "20",
            "--save-freq", "-1"]
    return argv + (["--max-wall-time", str(max_wall_time)] if max_wall_time is not None else [])


def reference() -> dict | None:
    """The committed multi-seed figure of this job (None if the file is absent)."""
    try:
        return json.loads(REFERENCE.read_text())
    except (OSError, ValueError):
        return None


def verdict(success: float, trained_steps: int, budget: int, status: str, ref: dict | None) -> str:
    """One paragraph: what was reached, against the reference, and whether the budget ran out."""
    lines = [f"Success on held-out targets: {100 * success:.0f} % after {trained_steps:,} env steps "
             f"of training (budget {budget:,})."]
    complete = status == "finished" and trained_steps >= budget
    if not complete:
        lines.append(f"TRAINING WAS CUT SHORT ({status}: {trained_steps:,} of {budget:,} steps): this policy is "
                     f"not the trained result; run again without interrupting it (and without --max-wall-time).")
    if ref is not None and reference_applies(ref, budget):
        s = ref["success_rate"]
        lines.append(f"The project reaches {100 * s['iqm']:.0f} % (IQM over {ref['n_seeds']} training seeds, "
                     f"95 % CI [{100 * s['ci'][0]:.0f}, {100 * s['ci'][1]:.0f}] %, per seed "
                     f"{100 * s['min']:.0f}-{100 * s['max']:.0f} %) with this command and budget "
                     f"({REFERENCE.relative_to(ROOT)}).")
    elif ref is not None:
        lines.append(f"The project's reference ({REFERENCE.relative_to(ROOT)}) was trained for "
                     f"{ref.get('budget_steps', 0):,} env steps, so it does not apply to a budget of {budget:,}; "
                     f"run with the default --n-timesteps to compare.")
    return " ".join(lines)


def reference_applies(ref: dict, budget: int) -> bool:
    """Whether the reference was trained with this env-step budget (its figures hold for no other)."""
    return ref.get("budget_steps") == budget


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=None, help="a new output folder (default runs/main_job/<date_time>)")
    p.add_argument("--n-timesteps", type=int, default=BUDGET, help=f"env-step budget of the training "
                                                                   f"(default {BUDGET:,})")
    p.add_argument("--max-wall-time", type=float, default=None, metavar="SECONDS",
                   help="also stop training after this many seconds (the summary then says it was cut short)")
    p.add_argument("--n-episodes", type=int, default=100, help="held-out evaluation episodes (trained policy)")
    p.add_argument("--baseline-episodes", type=int, default=50, help="episodes for the NNLS baseline and random")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if args.n_timesteps < 1:
        p.error(f"--n-timesteps: must be >= 1, got {args.n_timesteps}")
    out = Path(args.out) if args.out else ROOT / "runs" / "main_job" / time.strftime("%Y%m%d_%H%M%S")
    try:
        out.mkdir(parents=True, exist_ok=False)   # claims the folder: a second run into it is refused here
    except FileExistsError:
        p.error(f"--out: {out} exists; the main job writes only into a new folder (nothing is overwritten)")

    from tensegrity_gym_agents import evaluate, train

    t0 = time.time()
    run = out / "run"
    cap = f" or {args.max_wall_time:.0f} s" if args.max_wall_time is not None else ""
    print(f"[main job] 1/3 training PPO on {ENV_ID} for {args.n_timesteps:,} env steps{cap} -> {run}", flush=True)
    train.train(train_argv(args.seed, run, args.n_timesteps, args.max_wall_time))
    t1 = time.time()
    print(f"[main job] 2/3 evaluating the final policy on {args.n_episodes} held-out targets (NNLS baseline and "
          f"random on {args.baseline_episodes})", flush=True)
    metrics = evaluate.evaluate([str(run), "--model", "final", "--n-episodes", str(args.n_episodes),
                                 "--baseline-episodes", str(args.baseline_episodes), "--gif", "--gif-size", "400",
                                 "--out", str(out)])
    t2 = time.time()
    state = json.loads((run / "state.json").read_text())
    status, steps = state.get("status", "unknown"), int(metrics["model_num_timesteps"])
    success = metrics["results"]["ppo (trained)"]["success_rate"]
    ref = reference()
    text = verdict(success, steps, args.n_timesteps, status, ref)
    metrics["main_job"] = {"budget_steps": args.n_timesteps, "trained_steps": steps, "training_status": status,
                           "training_complete": status == "finished" and steps >= args.n_timesteps,
                           "training_s": t1 - t0, "evaluation_s": t2 - t1, "verdict": text,
                           "reference": ref, "reference_applies": ref is not None and reference_applies(ref, args.n_timesteps),
                           "command": " ".join(["python", "-m", "scripts.eval.main_job"] +
                                                                 list(argv if argv is not None else sys.argv[1:]))}
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2, default=str) + "\n")
    (out / "README.md").write_text(
        f"# Main job: PPO on {ENV_ID} (default scene)\n\n{text}\n\n"
        f"Training {t1 - t0:.0f} s, evaluation {t2 - t1:.0f} s.\n\n"
        f"Held-out evaluation ({args.n_episodes} targets for the trained policy, {args.baseline_episodes} for the "
        f"baselines):\n\n```\n{(out / 'table.md').read_text()}```\n\n"
        f"Command: `{metrics['main_job']['command']}`\n")
    print(f"[main job] 3/3 done in {time.time() - t0:.0f} s (training {t1 - t0:.0f} s, evaluation {t2 - t1:.0f} s); "
          f"results in {out}\n\n{text}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
