"""agents.tune: sweep configs, the IQM interval, and the smoke sweep on Ray Tune (interrupted and
resumed). Tests that run Ray skip cleanly without it."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("yaml")

from agents import summary, train, tune  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SWEEPS = ROOT / "agents" / "sweeps"
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""), "MPLBACKEND": "Agg",
       "RAY_AUTH_MODE": "disabled"}


# ---------------------------------------------------------------------- configs (no Ray needed)
@pytest.mark.parametrize("name,n_runs", [("sweep1", 14), ("sweep2", 14), ("sweep3", 10)])
def test_sweep_configs_keep_the_former_run_lists(name, n_runs):
    """sweep{1,2,3}.yml express the runs of the former agents/sweeps/*.txt: every run's agents.train
    arguments parse and its hyperparameters resolve."""
    cfg = tune.load_config(SWEEPS / f"{name}.yml")
    runs = tune.trial_list(cfg)
    assert len(runs) == n_runs
    from agents import hyperparameters, parsing
    for r in runs:
        argv = tune.train_argv(r["opts"], r["seed"], "x")
        a = train.build_parser().parse_args(argv)
        assert a.max_wall_time > 0 and a.save_freq == -1
        hp = parsing.parse_kv_list(a.hyperparams, "=", "--hyperparams")
        hyperparameters.resolve_hyperparams(a.algo, {**hyperparameters.hyperparams_for(a.algo, a.env)[0], **hp})
        parsing.parse_kv_list(a.env_kwargs, ":", "--env-kwargs")


def test_sweep_configs_all_load():
    for p in SWEEPS.glob("*.yml"):
        tune.load_config(p)
    assert not list(SWEEPS.glob("*.txt")) and not (ROOT / "scripts" / "sweep_train.sh").exists()


def test_bad_configs_name_the_field(tmp_path):
    cases = {
        "variants: [{name: a}]\nsearch: {space: {hyperparams.x: {choice: [1]}}}\n": "exactly one",
        "variants: [{name: a, n_timestep: 5}]\n": "n_timestep",
        "variants: [{name: a}, {name: a}]\n": "duplicate name 'a'",
        "seeds: 3\nvariants: [{name: a}]\n": "seeds",
        "search: {space: {gamma: {choice: [1]}}}\n": "gamma",
        "search: {space: {hyperparams.gamma: {normal: [0, 1]}}}\n": "hyperparams.gamma",
        "search: {search_alg: grid, space: {hyperparams.gamma: {choice: [1]}}}\n": "search_alg",
        "train: {log_dir: x}\nvariants: [{name: a}]\n": "log_dir",
        "metric: success\nvariants: [{name: a}]\n": "metric must be one of .*'success'",
        "search: {time_attr: seconds, space: {hyperparams.gamma: {choice: [1]}}}\n": "time_attr .*'seconds'",
        "search: {time_attr: wall_time_s, space: {hyperparams.gamma: {choice: [1]}}}\n":
            "wall_time_s needs train.max_wall_time",
    }
    for i, (text, match) in enumerate(cases.items()):
        p = tmp_path / f"c{i}.yml"
        p.write_text(text)
        with pytest.raises(ValueError, match=match):
            tune.load_config(p)


def test_iqm_interval():
    from scipy import stats
    x = np.array([0.1, 0.5, 0.55, 0.6, 0.62, 0.7, 0.9, 3.0])
    iqm, lo, hi = summary.iqm_interval(x)
    assert iqm == pytest.approx(np.mean(np.sort(x)[2:6]))       # mean of the middle half
    assert iqm == pytest.approx(stats.trim_mean(x, 0.25))
    assert x.min() <= lo < iqm < hi <= x.max()
    assert summary.iqm_interval(x) == (iqm, lo, hi)                    # seeded: reproducible
    one = summary.iqm_interval([2.0])
    assert one[0] == 2.0 and np.isnan(one[1]) and np.isnan(one[2])  # one seed: no interval


# ---------------------------------------------------------------------- Ray Tune
def _warm_numba():
    """Compile (and cache) the shape env's kernels once, so that the trials do not each compile them."""
    import gymnasium as gym
    import tensegrity_gym  # noqa: F401
    env = gym.make_vec("TensegrityShape-v0", num_envs=2, vectorization_mode="vector_entry_point")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    env.close()


def test_smoke_sweep_is_interrupted_and_resumes(tmp_path):
    """agents/sweeps/smoke.yml on embedded local Ray (2 trials, 2 seeds): Ctrl-C in the middle,
    the same command again resumes (Tuner.restore; the trials continue from their checkpoints),
    and the summary reports both seeds with the IQM and its interval."""
    pytest.importorskip("ray.tune")
    _warm_numba()
    cmd = [sys.executable, "-m", "agents.tune", str(SWEEPS / "smoke.yml"), "--storage", str(tmp_path)]
    t0 = time.time()
    p = subprocess.Popen(cmd, cwd=str(tmp_path), env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         text=True)
    runs = tmp_path / "smoke" / "runs"
    while time.time() - t0 < 170 and p.poll() is None:
        if list(runs.glob("*/checkpoints/rl_model_128_steps.zip")):
            break
        time.sleep(0.2)
    interrupted = p.poll() is None
    if interrupted:
        p.send_signal(signal.SIGINT)
    out1 = p.communicate(timeout=120)[0]
    states = [json.loads(s.read_text()) for s in runs.glob("*/state.json")]
    assert states, out1[-3000:]
    p2 = subprocess.run(cmd, cwd=str(tmp_path), env=ENV, capture_output=True, text=True, timeout=300)
    out2 = p2.stdout + p2.stderr
    assert p2.returncode == 0, out2[-4000:]
    if interrupted:
        assert "resuming the sweep" in out2
        # a trial that was cut short after it had made progress continued its run (agents.train
        # --resume), not a new one; one cut before its first step (a loaded machine: Ctrl-C while
        # the trial starts up) is started again in its folder, as agents.train allows
        unfinished = [s for s in states if s["status"] not in ("finished",)
                      and s.get("num_timesteps", 0) > 0 and not s.get("failed_before_first_step")]
        if unfinished:
            cmds = [(d / "command.txt").read_text() for d in runs.iterdir()]
            assert any("--resume" in c for c in cmds), (unfinished, cmds)
    summary = json.loads((tmp_path / "smoke" / "summary.json").read_text())
    (row,) = summary["variants"]
    assert row["n_seeds"] == 2 and sorted(row["seeds"]) == [0, 1]
    assert row["timesteps"] == [512, 512] and set(row["status"]) == {"finished"}
    vals = row["eval_return_per_seed"]
    lo, hi = row["eval_return_ci95"]
    assert min(vals) <= lo <= row["eval_return_iqm"] <= hi <= max(vals)
    for s in (runs / "ppo_tiny_s0", runs / "ppo_tiny_s1"):
        ck = sorted(int(f.name.split("_")[2]) for f in (s / "checkpoints").glob("rl_model_*_steps.zip"))
        assert ck == [128, 256, 384, 512]  # the schedule survived the interrupt
    assert (tmp_path / "smoke" / "summary.png").stat().st_size > 1000
    assert "ppo_tiny" in (tmp_path / "smoke" / "summary.md").read_text()
    # no wall-clock assertion: timings are the benchmarks' business on this shared machine (this
    # test took 304 s with three trainings beside it); the subprocess timeouts above catch a hang


@pytest.mark.slow
def test_search_with_optuna_and_asha(tmp_path):
    pytest.importorskip("ray.tune")
    pytest.importorskip("optuna")
    cmd = [sys.executable, "-m", "agents.tune", str(SWEEPS / "smoke_search.yml"), "--storage", str(tmp_path),
           "--max-concurrent", "2"]
    p = subprocess.run(cmd, cwd=str(tmp_path), env=ENV, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, (p.stdout + p.stderr)[-4000:]
    summary = json.loads((tmp_path / "smoke_search" / "summary.json").read_text())
    assert len(summary["variants"]) == 2
    lrs = [r["settings"]["hyperparams.learning_rate"] for r in summary["variants"]]
    assert all(1e-4 <= lr <= 1e-3 for lr in lrs) and lrs[0] != lrs[1]   # sampled from the space
    assert summary["max_concurrent"] == 2


def test_without_ray_the_cli_says_how_to_install_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)       # import ray -> ImportError
    assert tune.main([str(SWEEPS / "smoke.yml"), "--storage", str(tmp_path)]) == 2
    assert "pip install 'tensegrity_gym[tune]'" in capsys.readouterr().err
    assert tune.main([str(tmp_path / "missing.yml")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_train_reports_each_evaluation_with_its_wall_time(tmp_path):
    """What agents.tune's trials report (ASHA's time_attr: timesteps or wall_time_s)."""
    from agents import train
    got = []
    train.train(["--algo", "ppo", "--env", "Pendulum-v1", "-n", "128", "--n-envs", "2", "--eval-freq", "64",
                 "--eval-episodes", "1", "--save-freq", "-1", "--no-progress-bar", "--log-dir", str(tmp_path / "r"),
                 "--hyperparams", "n_steps=32", "batch_size=32", "n_epochs=1", "policy_kwargs=dict(net_arch=[8])"],
                report=got.append)
    assert [m["timesteps"] for m in got] == [64, 128]
    assert 0 < got[0]["wall_time_s"] <= got[1]["wall_time_s"]
    assert {"eval_return", "n_evaluations"} <= set(got[-1])


def test_summary_only_keeps_what_the_sweep_recorded(tmp_path):
    """--summary-only rewrites the table and plot from the run folders; the sweep's wall time,
    concurrency and errors, which only the sweep itself knew, stay in summary.json."""
    exp = tmp_path / "exp"
    (exp / "runs").mkdir(parents=True)
    (exp / "summary.json").write_text(json.dumps({"sweep_wall_time_s": 12.5, "max_concurrent": 2, "errors": []}))
    out = summary.summarize(exp)
    assert (out["sweep_wall_time_s"], out["max_concurrent"], out["errors"]) == (12.5, 2, [])
    assert json.loads((exp / "summary.json").read_text())["sweep_wall_time_s"] == 12.5
