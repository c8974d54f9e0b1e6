"""scripts/eval/main_job.py end to end on a tiny budget: a new folder, a verdict against the reference,
a cut-short run said as such, and an existing folder refused."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg", "TENSEGRITY_GYM_QUIET": "1"}


def _main_job(*args, cwd):
    return subprocess.run([sys.executable, "-m", "scripts.eval.main_job", *args], cwd=cwd, env=ENV,
                          capture_output=True, text=True, timeout=1200)


def test_main_job_tiny_budget_writes_a_new_folder_and_says_it_fell_short(tmp_path):
    out = tmp_path / "mj"
    r = _main_job("--out", str(out), "--n-timesteps", "4096", "--n-episodes", "2", "--baseline-episodes", "1",
                  "--max-wall-time", "0.001", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    m = json.loads((out / "metrics.json").read_text())
    mj = m["main_job"]
    assert mj["budget_steps"] == 4096 and not mj["training_complete"]
    assert "CUT SHORT" in mj["verdict"] and "CUT SHORT" in r.stdout
    ref = json.loads((ROOT / "results" / "main_job" / "reference.json").read_text())
    assert mj["reference"] == ref and not mj["reference_applies"]     # another budget: no comparison
    assert "does not apply to a budget of 4,096" in mj["verdict"] and "IQM over" not in mj["verdict"]
    for f in ("README.md", "table.md", "rollout.gif", "run/config.yaml", "run/model.zip"):
        assert (out / f).exists(), f
    assert "[train]" in r.stdout or "steps" in r.stdout
    again = _main_job("--out", str(out), "--n-timesteps", "4096", cwd=tmp_path)   # never over a saved folder
    assert again.returncode == 2 and "exists" in again.stderr


def test_verdict_of_a_complete_run_quotes_the_reference():
    import importlib
    mod = importlib.import_module("scripts.eval.main_job")
    ref = {"n_seeds": 5, "budget_steps": 1_200_000,
           "success_rate": {"iqm": 0.97, "ci": [0.95, 0.99], "min": 0.9, "max": 1.0}}
    text = mod.verdict(0.96, 1_200_128, 1_200_000, "finished", ref)
    assert "96 %" in text and "97 %" in text and "CUT SHORT" not in text
    other = mod.verdict(0.96, 2_400_128, 2_400_000, "finished", ref)   # the reference holds for its budget only
    assert "97 %" not in other and "does not apply to a budget of 2,400,000" in other
    short = mod.verdict(0.1, 300_000, 1_200_000, "interrupted", ref)
    assert "CUT SHORT" in short and "300,000 of 1,200,000" in short


def test_progress_line_honours_the_wall_time_cap_and_a_cold_start():
    from agents.progress import progress_line
    cold = progress_line(256, 20_000, 148.0, 0.0)
    assert "measuring speed" in cold and "ETA" not in cold   # the first interval holds the compile
    line = progress_line(350_208, 1_200_000, 60.0, 5840.0, None, "eval @300,032: return -55.2")
    assert "29 %" in line and "ETA 2:26" in line and "eval @300,032" in line
    capped = progress_line(350_208, 1_200_000, 60.0, 5840.0, wall_left=30.0)
    assert "ETA 0:30 (wall-time cap" in capped
