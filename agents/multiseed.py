"""Results over training seeds: evaluate every seed's policy on the held-out seeds, then report
the IQM over training seeds with a 95 % bootstrap interval and learning curves with bands.

Usage::

    python -m agents.multiseed runs/roll_fast_s0 runs/roll_fast_s1 ... --out results/ppo_roll_fast
    python -m agents.multiseed runs_tune/roll5/runs/*/ --out results/ppo_roll_fast --env-kwargs randomize:...

For each run directory (one training seed, written by :mod:`agents.train`), the policy (``--model``:
``best`` by default, as :mod:`agents.evaluate`) runs ``--n-episodes`` episodes on the held-out
seeds ``--seed`` (default 1,000,000) ... (the same for every training seed; each run's own seeds
must be clear of them, :mod:`agents.heldout`), deterministic actions. The per-seed
evaluation lands in ``OUT/seeds/<run name>/`` (``metrics.json``, ``table.md``, ``episodes.json``).

Aggregates (``OUT/summary.json``, ``OUT/summary.md``, ``OUT/learning_curves.png``):

* per training seed: success rate (tasks with a success criterion), mean speed (m/s and body
  lengths/s, rolling tasks), mean return, median final node error (shape), the training wall
  time and steps (``state.json``);
* over seeds: the IQM (25 % trimmed mean, rliable's ``aggregate_iqm``) and its 95 % percentile
  bootstrap interval (``scipy.stats.bootstrap``, 2000 resamples, seeded:
  :func:`agents.summary.iqm_interval`; rliable itself does not import with pandas 3), plus min,
  max and the number of seeds that reached ``--goal`` (if given);
* learning curves: each seed's evaluation during training (``eval/evaluations.npz``: mean return
  and success rate) against env steps and against wall-clock seconds, IQM over seeds with the
  interval as a band.

Nothing here trains: the runs come from ``agents.train`` or ``agents.tune``.
"""
from __future__ import annotations

import argparse
import json
import sys
import textwrap
from pathlib import Path

import numpy as np

from . import common, heldout, parsing
from .summary import iqm_interval

#: per-seed metrics aggregated over seeds: (summary key, key in agents.evaluate's results, unit)
METRICS = (("success_rate", "success_rate", "fraction"),
           ("speed_m_s", "speed_mean_m_s", "m/s"),
           ("speed_body_lengths_s", "speed_mean_body_lengths_s", "body lengths/s"),
           ("return_mean", "return_mean", "-"),
           ("final_max_node_error_median_m", "final_max_node_error_median_m", "m"),
           ("diverged_rate", "diverged_rate", "fraction"))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"python -m {common.PACKAGE}.multiseed", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", help="run directories of agents.train, one per training seed")
    p.add_argument("--out", required=True, help="output directory (summary.json/.md, learning_curves.png, seeds/)")
    p.add_argument("--model", default="best", help="best (default) or final")
    p.add_argument("--n-episodes", type=int, default=100, help="held-out episodes per training seed (default 100)")
    p.add_argument("--seed", type=int, default=None,
                   help="first held-out reset seed (default agents.evaluate's, 1000000)")
    p.add_argument("--env-kwargs", nargs="*", metavar="KEY:VALUE", default=[],
                   help="env kwargs for evaluation on top of each run's own (e.g. a randomised robot)")
    p.add_argument("--goal", nargs="*", metavar="METRIC>=VALUE", default=[],
                   help="goals to count per seed, e.g. speed_m_s>=0.345 success_rate>=0.95")
    p.add_argument("--title", default=None)
    p.add_argument("--reuse", action="store_true",
                   help="reuse a seed's existing OUT/seeds/<run>/metrics.json if it evaluated the same model")
    return p


def _goals(specs: list[str]) -> list[tuple[str, float]]:
    known = {k for k, _, _ in METRICS}
    out = []
    for s in specs:
        if ">=" not in s:
            raise ValueError(f"--goal: expected METRIC>=VALUE, got {s!r}")
        k, v = s.split(">=", 1)
        if k not in known:
            raise ValueError(f"--goal: unknown metric {k!r}; choose one of {sorted(known)}")
        try:
            out.append((k, float(v)))
        except ValueError:
            raise ValueError(f"--goal {s!r}: {v!r} is not a number") from None
    return out


def _evaluate_seed(run: Path, out: Path, args) -> dict:
    from . import evaluate
    m_path = out / "metrics.json"
    if args.reuse and m_path.exists():
        m = json.loads(m_path.read_text())
        model_path = evaluate.resolve_model(run, args.model)[0]
        if (m.get("model") == str(model_path) and m["results"][next(iter(m["results"]))]["n_episodes"] == args.n_episodes
                and (m.get("held_out_seeds") or [None])[0] == args.seed):
            return m
    argv = [str(run), "--model", args.model, "--n-episodes", str(args.n_episodes), "--out", str(out),
            "--no-baselines", "--no-random", "--seed", str(args.seed)]
    if args.env_kwargs:
        argv += ["--env-kwargs", *args.env_kwargs]
    return evaluate.evaluate(argv)


def _curves(run: Path) -> dict | None:
    ev = run / "eval" / "evaluations.npz"
    if not ev.exists():
        return None
    d = np.load(ev)
    c = {"timesteps": d["timesteps"].astype(float), "return": d["results"].mean(1)}
    if "successes" in d.files and d["successes"].size:
        c["success"] = d["successes"].mean(1)
    state = json.loads((run / "state.json").read_text()) if (run / "state.json").exists() else {}
    wall, steps = state.get("wall_time_s"), state.get("num_timesteps")
    if wall and steps:   # evaluation times in wall-clock seconds, at the run's mean rate
        c["wall_s"] = c["timesteps"] * float(wall) / float(steps)
    return c


def _band(curves: list[dict], xkey: str, ykey: str, n: int = 40):
    from scipy import stats
    cs = [c for c in curves if c is not None and xkey in c and ykey in c and len(c[xkey])]
    if not cs:
        return None
    hi = min(c[xkey][-1] for c in cs)
    lo = max(c[xkey][0] for c in cs)
    if hi <= lo:
        return None
    grid = np.linspace(lo, hi, n)
    Y = np.array([np.interp(grid, c[xkey], c[ykey]) for c in cs])
    iqm = stats.trim_mean(Y, 0.25, axis=0)
    band = np.array([iqm_interval(col)[1:] for col in Y.T]) if len(cs) >= 2 else None
    return grid, Y, iqm, band


def _plot(path: Path, curves: list[dict], title: str) -> bool:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    panels = [(x, y) for y in ("return", "success") for x in ("timesteps", "wall_s")
              if _band(curves, x, y) is not None]
    if not panels:
        return False
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 3.8), squeeze=False)
    names = {"timesteps": "env steps", "wall_s": "training wall-clock time, s", "return": "evaluation return",
             "success": "evaluation success rate"}
    for ax, (x, y) in zip(axes[0], panels):
        grid, Y, iqm, band = _band(curves, x, y)
        for row in Y:
            ax.plot(grid, row, color="0.6", lw=0.7)
        ax.plot(grid, iqm, color="C0", lw=2, label=f"IQM of {len(Y)} seeds")
        if band is not None:
            ax.fill_between(grid, band[:, 0], band[:, 1], color="C0", alpha=0.25, label="95 % bootstrap CI")
        ax.set_xlabel(names[x])
        if x == "timesteps":  # 100000 200000 ... ran into each other below 1e6
            ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
        ax.set_ylabel(names[y])
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    # a long title wraps to the figure's width (9 pt: about 15 characters per inch)
    fig.suptitle(textwrap.fill(title, max(40, int(15 * 4.6 * len(panels)))), fontsize=9)
    fig.tight_layout()
    common.atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)
    return True


def aggregate(per_seed: list[dict], goals: list[tuple[str, float]]) -> dict:
    """IQM, 95 % bootstrap interval, min and max over training seeds of every metric in
    :data:`METRICS` present for all seeds; per goal, how many seeds reach it."""
    agg = {}
    for key, _, unit in METRICS:
        vals = [s[key] for s in per_seed if s.get(key) is not None]
        if len(vals) != len(per_seed) or not vals:
            continue
        iqm, lo, hi = iqm_interval(vals)
        agg[key] = {"unit": unit, "iqm": iqm, "ci95": [lo, hi], "min": float(np.min(vals)),
                    "max": float(np.max(vals)), "mean": float(np.mean(vals)), "per_seed": vals}
    for key, v in goals:
        if key in agg:
            agg[key]["goal"] = v
            agg[key]["seeds_reaching_goal"] = int(sum(x >= v for x in agg[key]["per_seed"]))
    return agg


def run(argv: list[str] | None = None) -> dict:
    args = build_parser().parse_args(argv)
    goals = _goals(args.goal)
    if args.n_episodes < 1:
        raise ValueError(f"--n-episodes: must be >= 1, got {args.n_episodes}")
    runs = [Path(r) for r in args.runs]
    for r in runs:
        if not (r / "config.yaml").exists():
            raise FileNotFoundError(f"{r}: no config.yaml (not a run directory of agents.train)")
    names = [r.name for r in runs]
    if len(set(names)) != len(names):
        raise ValueError(f"runs: two run directories share a name ({names}); each seed needs its own")
    from .evaluate import HELD_OUT_SEED
    if args.seed is None:
        args.seed = HELD_OUT_SEED
    # every run checked before any is evaluated (agents.evaluate checks each again)
    heldout.check_heldout(heldout.heldout_seeds(args.seed, args.n_episodes), runs)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    per_seed, curves, env_ids = [], [], set()
    for r in runs:
        m = _evaluate_seed(r, out / "seeds" / r.name, args)
        res = m["results"][next(k for k in m["results"] if k.endswith("(trained)"))]
        cfg = parsing.read_yaml(r / "config.yaml")
        env_ids.add(m["env"])
        st = json.loads((r / "state.json").read_text()) if (r / "state.json").exists() else {}
        row = {"run": str(r), "seed": cfg.get("seed"), "model": m["model"],
               "time_split_s": st.get("time_split_last_segment_s"),
               "model_num_timesteps": m["model_num_timesteps"],
               "training_wall_time_s": m["training_wall_time_s"], "training_status": m["training_status"],
               "training_cpu_model": m.get("training_cpu_model") or "CPU not recorded"}
        for key, src, _ in METRICS:
            row[key] = res.get(src)
        per_seed.append(row)
        curves.append(_curves(r))
    agg = aggregate(per_seed, goals)
    title = args.title or f"{', '.join(sorted(env_ids))}: {len(runs)} training seeds"
    summary = {"title": title, "n_seeds": len(runs), "held_out_episodes_per_seed": args.n_episodes,
               "held_out_seeds": [args.seed, args.seed + args.n_episodes - 1],
               "model": args.model, "eval_env_kwargs": parsing.parse_kv_list(args.env_kwargs, ":", "--env-kwargs"),
               "per_seed": per_seed, "aggregate": agg,
               "learning_curve_runs": [str(r) for r, c in zip(runs, curves) if c is not None],
               "interval": "IQM (25 % trimmed mean) over training seeds, 95 % percentile bootstrap "
                           "(scipy.stats.bootstrap, 2000 resamples, seed 0)",
               "command": " ".join(["python", "-m", f"{common.PACKAGE}.multiseed"] + (argv if argv is not None else sys.argv[1:])),
               "versions": common.package_versions()}
    common.write_json(out / "summary.json", summary)
    md = _table(summary)
    common.write_text(out / "summary.md", md)
    if _plot(out / "learning_curves.png", curves, title):
        print(f"wrote {out / 'learning_curves.png'}")
    print(md)
    print(f"wrote {out / 'summary.json'}")
    return summary


def _table(s: dict) -> str:
    def f(x):
        return "-" if x is None else (f"{x:.4g}" if isinstance(x, float) else str(x))
    agg = s["aggregate"]
    keys = [k for k, _, _ in METRICS if k in agg]
    lines = [f"# {s['title']}", "",
             f"{s['n_seeds']} training seeds, each evaluated on {s['held_out_episodes_per_seed']} held-out seeds "
             f"({s['held_out_seeds'][0]} ... {s['held_out_seeds'][1]}), model `{s['model']}`.", "",
             "| metric | IQM | 95 % CI | min | max | goal | seeds at goal |", "|---|---:|---|---:|---:|---:|---:|"]
    for k in keys:
        a = agg[k]
        lines.append(f"| {k} ({a['unit']}) | {f(a['iqm'])} | [{f(a['ci95'][0])}, {f(a['ci95'][1])}] | {f(a['min'])} | "
                     f"{f(a['max'])} | {f(a.get('goal'))} | {f(a.get('seeds_reaching_goal'))} |")
    lines += ["", "| run | seed | steps | training wall s | CPU | " + " | ".join(keys) + " |",
              "|---|---:|---:|---:|---|" + "---:|" * len(keys)]
    for r in s["per_seed"]:
        lines.append(f"| {Path(r['run']).name} | {f(r['seed'])} | {f(r['model_num_timesteps'])} | "
                     f"{f(r['training_wall_time_s'])} | {r.get('training_cpu_model') or 'CPU not recorded'} | "
                     + " | ".join(f(r[k]) for k in keys) + " |")
    lc = s.get("learning_curve_runs")
    if lc is not None and len(lc) < s["n_seeds"]:
        lines += ["", f"Learning curves (`learning_curves.png`): {len(lc)} of {s['n_seeds']} seeds; the other runs "
                      "have no `eval/evaluations.npz`."]
    lines += ["", f"Interval: {s['interval']}.", "", f"Command: `{s['command']}`", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return common.run_cli(run, argv)


if __name__ == "__main__":
    sys.exit(main())
