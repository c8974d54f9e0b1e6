"""agents.train / agents.evaluate: hyperparameters that trained to "finished" on nonsense, files
that gave a traceback, flags accepted out of range. Each is one ``error: ...`` line, exit code 2
(the package's convention for input errors), or a correct run."""
from __future__ import annotations

import signal
import zipfile

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
yaml = pytest.importorskip("yaml")

import tensegrity_gym  # noqa: E402,F401  (registers the envs)
from agents import envs, evaluate, hyperparameters, interrupts, train  # noqa: E402


# ---------------------------------------------------------------- hyperparameters
@pytest.mark.parametrize("hp, pattern", [
    ({"normalize": "dict(clip_obs=-1)"}, r"normalize clip_obs must be a positive finite number, got -1"),
    ({"normalize": {"clip_reward": 0.0}}, r"normalize clip_reward must be a positive finite number"),
    ({"normalize": {"clip_ob": 5.0}}, r"normalize takes no key 'clip_ob' \(did you mean clip_obs\?\)"),
    ({"normalize": {"norm_obs": "yes"}}, r"normalize norm_obs must be true or false"),
    ({"clip_range": -0.2}, r"clip_range must be a positive finite number .*got -0.2"),
    ({"clip_range": "lin_-0.2"}, r"clip_range must be a positive .*got -0.2"),
    ({"learning_rate": 0.0}, r"learning_rate must be a positive"),
    ({"policy_kwargs": "dict(net_arch=[0])"}, r"policy_kwargs net_arch entry 0 is 0; layer sizes must be integers >= 1"),
    ({"policy_kwargs": "dict(net_arch=dict(pi=[64], vf=[0]))"}, r"net_arch\['vf'\] entry 0 is 0"),
    ({"env_kwargs": 5}, r"env_kwargs must be a dict of env keyword arguments, got 5"),
    ({"n_timesteps": "abc"}, r"--hyperparams: n_timesteps must be an integer >= 1, got 'abc'"),
    ({"n_envs": 0}, r"--hyperparams: n_envs: must be an integer >= 1"),
])
def test_bad_hyperparameters_named(hp, pattern):
    with pytest.raises(ValueError, match=pattern):
        hyperparameters.resolve_hyperparams("ppo", hp)


def test_good_hyperparameters_unchanged():
    r = hyperparameters.resolve_hyperparams("ppo", {"n_timesteps": "1e4", "normalize": "dict(clip_obs=10.0, norm_reward=False)",
                                           "clip_range": "lin_0.2", "policy_kwargs": "dict(net_arch=[8, 8])",
                                           "env_kwargs": None})
    assert r["n_timesteps"] == 10000 and r["env_kwargs"] == {}
    assert r["normalize"] == {"clip_obs": 10.0, "norm_reward": False}
    assert r["model_kwargs"]["clip_range"](1.0) == pytest.approx(0.2)


# ---------------------------------------------------------------- flags checked when parsed
@pytest.mark.parametrize("flag, value", [("-n", "inf"), ("-n", "abc"), ("--max-wall-time", "nan"),
                                         ("--max-wall-time", "-1"), ("--eval-episodes", "0")])
def test_train_flags_refused_when_parsed(tmp_path, capsys, flag, value):
    with pytest.raises(SystemExit) as e:
        train.main(["--env", "Pendulum-v1", "--log-dir", str(tmp_path / "r"), flag, value])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and flag in err.splitlines()[-1]
    assert not (tmp_path / "r").exists()


def test_evaluate_n_episodes_inf(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        evaluate.main([str(tmp_path), "--n-episodes", "inf"])
    assert e.value.code == 2 and "--n-episodes" in capsys.readouterr().err


# ---------------------------------------------------------------- damaged files
def _run_dir(tmp_path, normalize=None, env="Pendulum-v1"):
    d = tmp_path / "run"
    d.mkdir()
    cfg = {"algo": "ppo", "env": env, "env_kwargs": {}, "seed": 0, "n_envs": 1, "n_timesteps": 64,
           "hyperparams_raw": {}, "hyperparams_resolved": {"normalize": normalize}}
    (d / "config.yaml").write_text(yaml.safe_dump(cfg))
    return d


def _real_model(path):
    from stable_baselines3 import PPO
    PPO("MlpPolicy", "Pendulum-v1", n_steps=8, batch_size=8, policy_kwargs=dict(net_arch=[4])).save(str(path))


def _evaluate(capsys, run_dir, *extra):
    code = evaluate.main([str(run_dir), "--model", "final", "--n-episodes", "1", "--no-baselines", "--no-random",
                          *extra])
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.startswith("error: ") and len(err.strip().splitlines()) == 1, err
    return code, err


def test_evaluate_garbage_model_zip(tmp_path, capsys):
    d = _run_dir(tmp_path)
    (d / "model.zip").write_bytes(b"garbage")
    code, err = _evaluate(capsys, d)
    assert code == 2 and "model.zip: not a loadable PPO model" in err


def test_evaluate_zip_without_data_and_garbage_policy(tmp_path, capsys):
    d = _run_dir(tmp_path)
    with zipfile.ZipFile(d / "model.zip", "w") as z:
        z.writestr("policy.pth", b"not torch")
    code, err = _evaluate(capsys, d)
    assert code == 2 and "model.zip: not a loadable PPO model" in err
    _real_model(d / "model.zip")
    with zipfile.ZipFile(d / "model.zip") as z:
        parts = {n: z.read(n) for n in z.namelist()}
    parts["policy.pth"] = b"garbage"
    with zipfile.ZipFile(d / "model.zip", "w") as z:
        for n, b in parts.items():
            z.writestr(n, b)
    code, err = _evaluate(capsys, d)
    assert code == 2 and "model.zip: not a loadable PPO model" in err


def test_evaluate_garbage_vecnormalize(tmp_path, capsys):
    d = _run_dir(tmp_path, normalize={"gamma": 0.99})
    _real_model(d / "model.zip")
    (d / "vecnormalize.pkl").write_bytes(b"\x80\x04garbage")
    code, err = _evaluate(capsys, d)
    assert code == 2 and "vecnormalize.pkl: not VecNormalize statistics" in err


@pytest.mark.parametrize("text, pattern", [("", "config.yaml: empty"), ("- 1\n", "config.yaml: not a mapping"),
                                           ("algo: ppo\n", r"config.yaml: missing \['env'")])
def test_evaluate_empty_or_partial_config(tmp_path, capsys, text, pattern):
    d = tmp_path / "run"
    d.mkdir()
    (d / "config.yaml").write_text(text)
    code, err = _evaluate(capsys, d)
    assert code == 2
    assert __import__("re").search(pattern, err), err


def test_evaluate_unwritable_out(tmp_path, capsys):
    d = _run_dir(tmp_path)
    _real_model(d / "model.zip")
    (tmp_path / "file").write_text("x")
    code, err = _evaluate(capsys, d, "--out", str(tmp_path / "file" / "eval"))
    assert code == 2 and "file" in err


def test_train_unwritable_log_dir(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    code = train.main(["--env", "Pendulum-v1", "--log-dir", str(tmp_path / "file" / "run"), "-n", "64",
                       "--no-progress-bar"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and err.startswith("error: "), err


def test_train_damaged_state_json_named(tmp_path, capsys):
    d = _run_dir(tmp_path)
    (d / "state.json").write_text("{not json")
    code = train.main(["--resume", str(d), "--no-progress-bar"])
    err = capsys.readouterr().err
    assert code == 2 and "state.json: damaged run state" in err, err


def test_sigterm_exit_code_is_143():
    interrupts.SIGNALS_RECEIVED.clear()
    assert interrupts.interrupted_exit_code() == 130       # Ctrl-C
    interrupts.SIGNALS_RECEIVED.append(signal.SIGTERM)
    try:
        assert interrupts.interrupted_exit_code() == 143
    finally:
        interrupts.SIGNALS_RECEIVED.clear()


# ---------------------------------------------------------------- --vec-env subproc
def test_subproc_vec_env_builds_the_package_envs():
    venv, mode = envs.make_vec("TensegrityShape-v0", 2, 0, {}, vec_env="subproc")
    try:
        assert mode == "subproc"
        obs = venv.reset()
        obs, r, done, info = venv.step(np.zeros((2,) + venv.action_space.shape))
        assert obs.shape[0] == 2 and np.all(np.isfinite(obs))
    finally:
        venv.close()


def test_sigterm_during_a_training_exits_143_and_records_it(tmp_path):
    """A real process: SIGTERM as soon as state.json appears (start-up, or the first steps)."""
    import json
    import os
    import subprocess
    import sys
    import time
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root))
    run = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "agents.train", "--env", "Pendulum-v1", "-n", "1e7", "--log-dir",
                          str(run), "--no-progress-bar", "--eval-freq", "-1", "--save-freq", "-1"],
                         cwd=root, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.time()
        while not (run / "state.json").exists() and time.time() - t0 < 240 and p.poll() is None:
            time.sleep(0.02)
        assert (run / "state.json").exists(), p.communicate()
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=240)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 143, (p.returncode, err[-2000:])
    assert "Traceback" not in err, err[-2000:]
    assert json.loads((run / "state.json").read_text())["status"] == "interrupted"


def test_killed_segment_keeps_its_wall_time(tmp_path):
    """kill -9 after a checkpoint: state.json holds the segment's wall time so far (``--resume``
    adds the next segment's to it) instead of none."""
    import glob
    import json
    import os
    import subprocess
    import sys
    import time
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    run = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "agents.train", "--env", "Pendulum-v1", "-n", "1e7", "--log-dir",
                          str(run), "--no-progress-bar", "--eval-freq", "-1", "--save-freq", "256",
                          "--hyperparams", "n_steps=64", "batch_size=64", "n_epochs=1"],
                         cwd=root, env=dict(os.environ, PYTHONPATH=str(root)), stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.time()
        while not glob.glob(str(run / "checkpoints" / "rl_model_*_steps.zip")) and time.time() - t0 < 240:
            assert p.poll() is None, p.communicate()
            time.sleep(0.05)
        time.sleep(0.5)
        p.kill()
        p.wait(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    state = json.loads((run / "state.json").read_text())
    assert state["status"] == "running" and state["wall_time_s"] > 0, state
