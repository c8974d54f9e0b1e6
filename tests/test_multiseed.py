"""agents.multiseed: per-seed held-out evaluation, IQM with bootstrap interval, learning-curve bands."""
from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("yaml")

from scipy import stats  # noqa: E402

from agents import evaluate, multiseed, train  # noqa: E402

TINY = ["--n-timesteps", "128", "--n-envs", "2", "--eval-freq", "64", "--eval-episodes", "2", "--save-freq", "-1",
        "--no-progress-bar", "--hyperparams", "n_steps=32", "batch_size=32", "n_epochs=1",
        "policy_kwargs=dict(net_arch=[16, 16])"]


def test_aggregate_iqm_interval_and_goal_counts():
    vals = [0.1, 0.2, 0.3, 0.9, 1.0]
    per = [{"success_rate": v, "return_mean": -v} for v in vals]
    agg = multiseed.aggregate(per, [("success_rate", 0.25)])
    a = agg["success_rate"]
    assert a["iqm"] == pytest.approx(stats.trim_mean(vals, 0.25))
    assert a["ci95"][0] <= a["iqm"] <= a["ci95"][1]
    assert a["seeds_reaching_goal"] == 3 and a["min"] == 0.1 and a["max"] == 1.0
    assert "speed_m_s" not in agg            # absent for every seed: not reported
    # a metric missing for one seed is not aggregated over the others
    per[0]["speed_m_s"] = 0.3
    assert "speed_m_s" not in multiseed.aggregate(per, [])


@pytest.mark.parametrize("spec", ["success_rate>0.9", "nope>=1", "success_rate>=high"])
def test_bad_goal_is_refused_naming_it(spec):
    with pytest.raises(ValueError, match="--goal"):
        multiseed._goals([spec])


def test_two_seeds_end_to_end(tmp_path):
    runs = []
    for seed in (0, 1):
        run = tmp_path / f"s{seed}"
        train.train(["--algo", "ppo", "--env", "TensegrityShape-v0", "--seed", str(seed), "--log-dir", str(run), *TINY])
        runs.append(str(run))
    out = tmp_path / "out"
    s = multiseed.run([*runs, "--out", str(out), "--n-episodes", "2", "--goal", "success_rate>=0.95"])
    assert s["n_seeds"] == 2 and len(s["per_seed"]) == 2
    # each seed's number is its own held-out evaluation, the same one agents.evaluate writes
    for r, row in zip(runs, s["per_seed"]):
        m = json.loads((out / "seeds" / r.split("/")[-1] / "metrics.json").read_text())
        assert m["held_out_seeds"] == [evaluate.HELD_OUT_SEED, evaluate.HELD_OUT_SEED + 1]
        assert row["return_mean"] == m["results"]["ppo (trained)"]["return_mean"]
    rets = [row["return_mean"] for row in s["per_seed"]]
    assert s["aggregate"]["return_mean"]["iqm"] == pytest.approx(np.mean(rets))   # IQM of 2 = mean
    assert (out / "summary.md").read_text().startswith("# TensegrityShape-v0")
    assert (out / "learning_curves.png").stat().st_size > 0
    assert json.loads((out / "summary.json").read_text())["aggregate"]["success_rate"]["goal"] == 0.95
    assert s["learning_curve_runs"] == runs and "Learning curves" not in (out / "summary.md").read_text()
    # a second call with --reuse evaluates nothing new and gives the same summary
    s2 = multiseed.run([*runs, "--out", str(out), "--n-episodes", "2", "--reuse"])
    assert s2["per_seed"] == s["per_seed"]
    # a committed result folder (agents.evaluate --copy-run-files) keeps the run's evaluations, so
    # its learning curve is drawn after the run folder is gone
    res = tmp_path / "results" / "s0"
    evaluate.evaluate([runs[0], "--n-episodes", "1", "--no-baselines", "--no-random", "--out", str(res),
                       "--copy-run-files"])
    assert (res / "eval" / "evaluations.npz").exists() and (res / "model.zip").exists()
    s3 = multiseed.run([str(res), runs[1], "--out", str(tmp_path / "out3"), "--n-episodes", "1"])
    assert s3["learning_curve_runs"] == [str(res), runs[1]]
    (res / "eval" / "evaluations.npz").unlink()
    s4 = multiseed.run([str(res), runs[1], "--out", str(tmp_path / "out4"), "--n-episodes", "1"])
    assert s4["learning_curve_runs"] == [runs[1]]
    assert "Learning curves (`learning_curves.png`): 1 of 2 seeds" in (tmp_path / "out4" / "summary.md").read_text()


def test_not_a_run_dir_or_duplicate_names(tmp_path):
    assert multiseed.main([str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    (tmp_path / "a" / "x").mkdir(parents=True)
    (tmp_path / "b" / "x").mkdir(parents=True)
    for d in ("a", "b"):
        (tmp_path / d / "x" / "config.yaml").write_text("env: TensegrityShape-v0\n")
    with pytest.raises(ValueError, match="share a name"):
        multiseed.run([str(tmp_path / "a" / "x"), str(tmp_path / "b" / "x"), "--out", str(tmp_path / "o")])
