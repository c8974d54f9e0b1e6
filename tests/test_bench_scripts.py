"""The benchmark scripts run end to end in their smallest size (they print tables, they are not
timed here: timings are the scripts' business, on a quiet machine)."""
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}


def test_bench_envs_default_env_runs(tmp_path):
    # the shape env's single step is measured by bench_step_overhead; bench_envs must skip it, not crash
    r = subprocess.run([sys.executable, "-m", "scripts.bench.bench_envs", "--quick", "--env", "shape",
                        "--methods", "batched", "--n-envs", "1", "--seconds", "0.05", "--out", str(tmp_path / "b")],
                       capture_output=True, text=True, timeout=600, cwd=tmp_path, env=ENV)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Targets" in r.stdout


def test_profile_learner_runs(tmp_path):
    r = subprocess.run([sys.executable, "-m", "scripts.bench.profile_learner", "--rollouts", "1"],
                       capture_output=True, text=True, timeout=600, cwd=tmp_path, env=ENV)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = [line for line in r.stdout.splitlines() if line.startswith("| ")]
    assert any("**learner**" in line for line in rows) and any(line.startswith("| backward") for line in rows)
    assert "80 minibatch updates" in r.stdout


def test_bench_navigate_reset_runs(tmp_path):
    out = tmp_path / "r.json"
    cmd = [sys.executable, "-m", "scripts.bench.bench_navigate_reset", "--courses", "2", "--envs", "2",
           "--steps", "2", "--repeats", "1", "--json", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=ENV)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "| draw and plan a course |" in r.stdout and out.exists()
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=ENV)
    assert r.returncode == 2 and "exists" in r.stderr           # a result is not overwritten


def test_bench_rough_reset_runs(tmp_path):
    out = tmp_path / "r.json"
    cmd = [sys.executable, "-m", "scripts.bench.bench_rough_reset", "--repeats", "1", "--json", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=ENV)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "| heights (drawn_values) |" in r.stdout and "| contact arrays (TerrainContact) |" in r.stdout
    assert out.exists()
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=ENV)
    assert r.returncode == 2 and "exists" in r.stderr           # a result is not overwritten


def test_bench_rod_contact_runs(tmp_path):
    r = subprocess.run([sys.executable, "-m", "scripts.bench.bench_rod_contact", "--envs", "1", "--seconds", "0.05"],
                       capture_output=True, text=True, timeout=1200, cwd=tmp_path, env=ENV)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "| TensegrityRoll-v0 | 1 |" in r.stdout
