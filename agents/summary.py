"""Summaries over training seeds: the IQM of a metric with its bootstrap interval
(:func:`iqm_interval`); within one training seed, the mean over its episodes with its bootstrap
interval (:func:`mean_interval`) or a success rate with its Wilson interval (:func:`rate_interval`);
and the per-variant summary of an :mod:`agents.tune` sweep
(``summary.json``, ``summary.md``, ``summary.png``).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from . import common, parsing
from .run_dir import evaluation_metrics

METRIC_MEANING = {"eval_return": "mean return of the last evaluation",
                  "eval_success": "success rate of the last evaluation",
                  "timesteps": "env steps trained"}


def final_metrics(run_dir: Path, config: dict) -> dict:
    """The metrics of a finished trial: its variant and seed, and those of its last evaluation
    (:func:`agents.run_dir.evaluation_metrics`)."""
    out = {"variant": config.get("variant") or run_dir.name.rsplit("_s", 1)[0], "seed": int(config["seed"]),
           "run_dir": str(run_dir), "done_training": True}
    ev = run_dir / "eval" / "evaluations.npz"
    if ev.exists():
        d = np.load(ev)
        out.update(evaluation_metrics(d["timesteps"].tolist(), d["results"].tolist(),
                                      d["successes"].tolist() if "successes" in d.files else None))
    st = run_dir / "state.json"
    if st.exists():
        s = json.loads(st.read_text())
        out["timesteps"] = int(s.get("num_timesteps", out.get("timesteps", 0)))
        out["wall_time_s"] = float(s.get("wall_time_s", 0.0))
        out["status"] = s.get("status")
    return out


def iqm_interval(x, confidence: float = 0.95, n_resamples: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """IQM (25 % trimmed mean, rliable's ``aggregate_iqm``) of ``x`` and its percentile-bootstrap
    ``confidence`` interval (``scipy.stats.bootstrap``; seeded). Fewer than 2 values: (x, nan, nan)."""
    from scipy import stats
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    iqm = float(stats.trim_mean(x, 0.25))
    if x.size < 2 or np.ptp(x) == 0:
        return iqm, (iqm if x.size >= 2 else float("nan")), (iqm if x.size >= 2 else float("nan"))
    res = stats.bootstrap((x,), lambda s, axis: stats.trim_mean(s, 0.25, axis=axis), confidence_level=confidence,
                          n_resamples=n_resamples, method="percentile", rng=np.random.default_rng(seed))
    return iqm, float(res.confidence_interval.low), float(res.confidence_interval.high)


def mean_interval(x, confidence: float = 0.95, n_resamples: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """Mean of ``x`` (one training seed's episodes) and its percentile-bootstrap ``confidence``
    interval over the episodes (``scipy.stats.bootstrap``, seeded). Non-finite values are dropped;
    fewer than 2 values: (mean, nan, nan); all equal: (mean, mean, mean)."""
    from scipy import stats
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    mean = float(x.mean())
    if x.size < 2:
        return mean, float("nan"), float("nan")
    if np.ptp(x) == 0:
        return mean, mean, mean
    res = stats.bootstrap((x,), np.mean, confidence_level=confidence, n_resamples=n_resamples,
                          method="percentile", rng=np.random.default_rng(seed))
    return mean, float(res.confidence_interval.low), float(res.confidence_interval.high)


def rate_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float, float]:
    """Success rate ``successes / n`` and its Wilson score ``confidence`` interval. For a rate the
    Wilson interval, not the bootstrap: a bootstrap of 100 % successes is [1, 1], whatever n;
    Wilson's of 100 / 100 is [0.963, 1]. ValueError unless 0 <= successes <= n, n >= 1."""
    from scipy import stats
    if not (n >= 1 and 0 <= successes <= n):
        raise ValueError(f"successes, n: need 0 <= successes <= n and n >= 1, got {successes}, {n}")
    p = successes / n
    z = float(stats.norm.ppf(0.5 + confidence / 2))
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return float(p), float(max(0.0, centre - half)), float(min(1.0, centre + half))


def summarize(exp_dir: Path, metric: str = "eval_return", sweep: dict | None = None) -> dict:
    """Per-variant table from the trial run directories under ``exp_dir/runs``; writes
    ``summary.json``, ``summary.md`` and ``summary.png`` in ``exp_dir``. ``sweep``: what only the
    sweep itself knows (``sweep_wall_time_s``, ``max_concurrent``, ``errors``); without it
    (``--summary-only``) those of an earlier ``summary.json`` are kept."""
    runs_dir = exp_dir / "runs"
    per: dict[str, list[dict]] = {}
    for d in sorted(p for p in runs_dir.iterdir() if p.is_dir()) if runs_dir.exists() else []:
        if not (d / "config.yaml").exists():
            continue
        name, _, seed = d.name.rpartition("_s")
        m = final_metrics(d, {"variant": name, "seed": int(seed) if seed.isdigit() else -1})
        ev = d / "eval" / "evaluations.npz"
        if ev.exists():
            z = np.load(ev)
            m["curve_steps"] = z["timesteps"].tolist()
            m["curve_return"] = z["results"].mean(axis=1).tolist()
        rc = parsing.read_yaml(d / "config.yaml") or {}
        m["params"] = {**{f"hyperparams.{k}": v for k, v in (rc.get("hyperparams_raw") or {}).items()
                          if k != "env_kwargs"},
                       **{f"env_kwargs.{k}": v for k, v in (rc.get("env_kwargs") or {}).items()},
                       "algo": rc.get("algo"), "env": rc.get("env")}
        per.setdefault(name, []).append(m)
    # the settings that differ between variants (e.g. the sampled values of a search)
    allp = [r["params"] for runs in per.values() for r in runs[:1]]
    keys = sorted({k for p in allp for k in p})
    differ = [k for k in keys if len({json.dumps(p.get(k), sort_keys=True, default=str) for p in allp}) > 1]
    rows = []
    for name, runs in per.items():
        vals = [r.get(metric, np.nan) for r in runs]
        iqm, lo, hi = iqm_interval(vals)
        succ = [r["eval_success"] for r in runs if "eval_success" in r]
        s_iqm, s_lo, s_hi = iqm_interval(succ) if succ else (np.nan, np.nan, np.nan)
        rows.append({"variant": name, "n_seeds": len(runs), "seeds": [r["seed"] for r in runs],
                     "settings": {k: runs[0]["params"].get(k) for k in differ},
                     f"{metric}_per_seed": [float(v) for v in vals], f"{metric}_iqm": iqm,
                     f"{metric}_ci95": [lo, hi], "eval_success_iqm": s_iqm, "eval_success_ci95": [s_lo, s_hi],
                     "timesteps": [r.get("timesteps") for r in runs],
                     "status": [r.get("status") for r in runs],
                     "wall_time_s": [round(r.get("wall_time_s", 0.0), 1) for r in runs]})
    out = {"experiment": str(exp_dir), "metric": metric,
           "interval": "95 % percentile bootstrap of the IQM over seeds (scipy.stats.bootstrap, 2000 resamples, "
                       "seed 0)", "variants": rows}
    old = exp_dir / "summary.json"
    if sweep is None and old.exists():
        try:
            prev = json.loads(old.read_text())
        except (OSError, ValueError):
            prev = {}
        sweep = {k: prev[k] for k in ("sweep_wall_time_s", "max_concurrent", "errors") if k in prev}
    out.update(sweep or {})
    common.write_json(exp_dir / "summary.json", out)
    lines = [f"# {exp_dir.name}: final evaluation per variant", "",
             f"IQM over training seeds with a 95 % percentile-bootstrap interval (scipy.stats.bootstrap). "
             f"Metric: `{metric}` = {METRIC_MEANING.get(metric, metric)}.", "",
             f"| variant | settings | seeds | {metric} per seed | IQM [95 % CI] | success IQM [95 % CI] | steps | status |",
             "|---|---|---|---|---|---|---|---|"]

    def f(x):
        return "nan" if x is None or not np.isfinite(x) else f"{x:.3g}"
    for r in sorted(rows, key=lambda r: -np.nan_to_num(r[f"{metric}_iqm"], nan=-np.inf)):
        lo, hi = r[f"{metric}_ci95"]
        slo, shi = r["eval_success_ci95"]
        sets = ", ".join(f"{k.split('.', 1)[-1]}={v:.3g}" if isinstance(v, float) else f"{k.split('.', 1)[-1]}={v}"
                         for k, v in r["settings"].items())
        lines.append(f"| {r['variant']} | {sets} | {r['n_seeds']} | {', '.join(f(v) for v in r[f'{metric}_per_seed'])} | "
                     f"{f(r[f'{metric}_iqm'])} [{f(lo)}, {f(hi)}] | {f(r['eval_success_iqm'])} [{f(slo)}, {f(shi)}] | "
                     f"{', '.join(str(t) for t in r['timesteps'])} | {', '.join(str(s) for s in set(r['status']))} |")
    common.write_text(exp_dir / "summary.md", "\n".join(lines) + "\n")
    _plot(exp_dir / "summary.png", per)
    return out


def _plot(path: Path, per: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy import stats
    fig, ax = plt.subplots(figsize=(10, 4.5))
    styles = ("-", "--", ":", "-.")   # the colour cycle has 10 colours: more variants change the line style
    for i, (name, runs) in enumerate(sorted(per.items())):
        curves = [(np.asarray(r["curve_steps"]), np.asarray(r["curve_return"])) for r in runs if r.get("curve_steps")]
        if not curves:
            continue
        grid = np.unique(np.concatenate([c[0] for c in curves]))
        Y = np.array([np.interp(grid, s, y, left=np.nan, right=np.nan) for s, y in curves])
        iqm = np.array([stats.trim_mean(c[np.isfinite(c)], 0.25) if np.isfinite(c).any() else np.nan for c in Y.T])
        line, = ax.plot(grid, iqm, styles[(i // 10) % len(styles)], label=f"{name} ({len(curves)} seeds)")
        if len(curves) >= 2:
            band = np.array([iqm_interval(c)[1:] for c in Y.T])
            ax.fill_between(grid, band[:, 0], band[:, 1], color=line.get_color(), alpha=0.2)
    ax.set_xlabel("env steps")
    ax.set_ylabel("evaluation return (IQM over seeds, 95 % CI band)")
    if ax.lines:
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    common.atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)
