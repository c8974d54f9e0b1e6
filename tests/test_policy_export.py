"""Policy export (``python -m agents.export``) and its runner
(:mod:`tensegrity_gym.integrations.policy_runner`).

Fresh, untrained SB3 models (PPO, SAC, TD3) with VecNormalize statistics of real observations
are saved as run folders the way ``agents.train`` saves them; each exported file must give
``model.predict(vecnorm.normalize_obs(obs), deterministic=True)`` to 1e-5 on 50 observations
of real env steps. The output layers are scaled up so that PPO's clip to the action space and
SAC's tanh saturate on some entries. TorchScript and npz run here; ONNX where onnx and
onnxruntime are installed.
"""
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
torch = pytest.importorskip("torch")
yaml = pytest.importorskip("yaml")

from agents import common, envs, export  # noqa: E402
from tensegrity_gym.integrations import policy_runner  # noqa: E402
from tensegrity_gym.integrations.policy_runner import PolicyRunner, spec_path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TOL = 1e-5
ROLL_ROBOT = {"observation_mode": "robot", "history": 2, "action_delay": 1}

#: name -> (algo, env id, env kwargs, VecNormalize clip_obs)
RUNS = {
    "ppo_roll_robot": ("ppo", "TensegrityRoll-v0", ROLL_ROBOT, 5.0),
    "sac_shape": ("sac", "TensegrityShape-v0", {}, 10.0),
    "sac_pendulum": ("sac", "Pendulum-v1", {}, 10.0),      # action space [-2, 2]: the affine map
    "ppo_pendulum": ("ppo", "Pendulum-v1", {}, 10.0),      # and the clip to it
    "td3_pendulum": ("td3", "Pendulum-v1", {}, 10.0),
}


def make_run(folder: Path, algo: str, env_id: str, env_kwargs: dict, clip_obs: float, seed: int = 0) -> Path:
    """A run folder as agents.train leaves it (config.yaml, model.zip, vecnormalize.pkl) holding an
    untrained model; its VecNormalize statistics from 60 random steps of 2 envs."""
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.vec_env import VecNormalize
    venv, _ = envs.make_vec(env_id, 2, seed, env_kwargs, "auto")
    vn = VecNormalize(venv, norm_obs=True, norm_reward=False, clip_obs=clip_obs)
    vn.reset()
    rng = np.random.default_rng(seed)
    space = venv.action_space
    for _ in range(60):
        vn.step(rng.uniform(space.low, space.high, (2,) + space.shape).astype(np.float32))
    Algo = {"ppo": PPO, "sac": SAC, "td3": TD3}[algo]
    model = Algo("MlpPolicy", vn, seed=seed, policy_kwargs={"net_arch": [32, 32]}, device="cpu")
    with torch.no_grad():   # output weights ~ N(0, 1): the clip / tanh saturate on some entries
        last = model.policy.action_net if algo == "ppo" else model.policy.actor.mu
        (last[-2] if isinstance(last, torch.nn.Sequential) else last).weight.normal_(
            0.0, 1.0, generator=torch.Generator().manual_seed(seed))
    folder.mkdir(parents=True)
    common.save_pickle_atomic(vn, folder / "vecnormalize.pkl")
    common.save_model_atomic(model, folder / "model.zip")
    config = {"algo": algo, "env": env_id, "env_kwargs": env_kwargs, "seed": seed, "n_envs": 2, "n_timesteps": 0,
              "hyperparams_raw": {}, "hyperparams_resolved": {"normalize": {"norm_obs": True, "norm_reward": False,
                                                                            "clip_obs": clip_obs}}}
    common.write_text(folder / "config.yaml", yaml.safe_dump(config, sort_keys=False))
    vn.close()
    return folder


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("runs")
    return {name: make_run(base / name, *args) for name, args in RUNS.items()}


def reference(run: Path):
    """(config, predict(obs) of the saved model as SB3 runs it: VecNormalize, then predict)."""
    from agents.evaluate import load_trained
    cfg, trained, _, _ = load_trained(run, "final")
    return cfg, lambda obs: trained.predict(obs, deterministic=True)[0]


def env_observations(cfg: dict, act, n: int = 50) -> np.ndarray:
    return export.check_observations(cfg["env"], cfg["env_kwargs"], act, n, seed=123)


def run_export(*argv) -> int:
    return export.main([str(a) for a in argv])


# ---------------------------------------------------------------------- exported == SB3
@pytest.mark.parametrize("name", sorted(RUNS))
@pytest.mark.parametrize("fmt", ["npz", "torchscript"])
def test_exported_policy_reproduces_sb3_predict(runs, name, fmt, tmp_path):
    out = tmp_path / f"policy{policy_runner.FORMATS[fmt][0]}"
    assert run_export(runs[name], "--format", fmt, "--out", out, "--check-steps", 0) == 0
    runner = PolicyRunner(out)
    assert runner.backend == {"npz": "numpy", "torchscript": "torch"}[fmt]
    cfg, predict = reference(runs[name])
    obs = env_observations(cfg, predict)
    expected = np.stack([predict(o) for o in obs])
    batch = runner(obs)
    single = np.stack([runner(o) for o in obs])
    assert batch.dtype == np.float32 and batch.shape == expected.shape
    assert np.abs(batch - expected).max() <= TOL and np.abs(single - expected).max() <= TOL
    low, high = runner.spec["action"]["low"], runner.spec["action"]["high"]
    assert (batch >= np.asarray(low, np.float32)).all() and (batch <= np.asarray(high, np.float32)).all()
    if name.startswith("ppo"):     # the clip is exercised: some actions sit on the bounds
        assert np.isclose(np.abs(expected), np.asarray(high)).any()


def test_onnx_export_reproduces_sb3_predict(runs, tmp_path):
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    for name in ("ppo_roll_robot", "sac_shape"):
        out = tmp_path / name / "policy.onnx"
        assert run_export(runs[name], "--format", "onnx", "--out", out, "--check-steps", 0) == 0
        runner = PolicyRunner(out)
        assert runner.backend == "onnxruntime"
        cfg, predict = reference(runs[name])
        obs = env_observations(cfg, predict)
        assert np.abs(runner(obs) - np.stack([predict(o) for o in obs])).max() <= TOL


def test_onnx_without_the_onnx_package_is_one_line(runs, capsys, tmp_path):
    if importlib.util.find_spec("onnx") is not None:
        pytest.skip("onnx is installed")
    assert run_export(runs["sac_shape"], "--format", "onnx", "--out", tmp_path / "p.onnx") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install onnx" in err and not (tmp_path / "p.onnx").exists()


# ---------------------------------------------------------------------- the built-in check and the spec
def test_export_checks_itself_and_writes_the_spec(runs, tmp_path, capsys):
    out = tmp_path / "deploy" / "policy.npz"
    assert run_export(runs["ppo_roll_robot"], "--format", "npz", "--out", out) == 0
    printed = capsys.readouterr().out
    assert "check: max |action - SB3 predict| = " in printed and "over 50 observations" in printed
    spec = json.loads(spec_path(out).read_text())
    assert spec["check"]["observations"] == 50 and spec["check"]["max_abs_action_error"] <= TOL
    assert spec["format"] == "npz" and spec["file"] == "policy.npz" and spec["format_version"] == 1
    assert spec["sha256"] == policy_runner.sha256_of(out)
    assert spec["env"] == {"id": "TensegrityRoll-v0", "kwargs": ROLL_ROBOT}
    obs = spec["observation"]
    assert obs["mode"] == "robot" and obs["history"] == 2 and obs["size"] == 2 * obs["reading_size"]
    names = [b["name"] for b in obs["layout"]]
    assert names[0] == "cable_length" and "imu_gyro" in names
    assert {b["name"]: b["unit"] for b in obs["layout"]}["imu_accel"] == "m/s^2"
    assert obs["layout"][-1]["stop"] == obs["reading_size"]
    assert obs["normalization"]["clip"] == 5.0 and obs["normalization"]["folded_in"]
    act = spec["action"]
    assert act["size"] == 9 and act["action_mode"] == "rest_length" and act["unit"] == "m"
    assert len(act["actuated"]) == 9 and len(act["actuated"][0]["nodes"]) == 2
    assert act["max_accel"] == 2.0 and "clipped" in act["policy_output"]
    assert spec["control"] == {"control_dt": 0.02, "rate_hz": 50.0, "physics_dt": 0.001, "frame_skip": 20}
    assert spec["latency"]["action_delay_steps"] == 1 and spec["latency"]["action_delay_s"] == pytest.approx(0.02)
    assert spec["training"]["algo"] == "ppo" and spec["export_command"].startswith("python -m agents.export ")
    assert not list(out.parent.glob(".*"))      # no lock or temporary file left


def test_spec_of_a_plain_gymnasium_env(runs, tmp_path):
    out = tmp_path / "p.npz"
    assert run_export(runs["sac_pendulum"], "--format", "npz", "--out", out, "--check-steps", 5) == 0
    spec = PolicyRunner(out).spec
    assert spec["observation"]["layout"] == [{"name": "observation", "start": 0, "stop": 3, "unit": None}]
    assert spec["action"]["low"] == [-2.0] and "mapped from [-1, 1]" in spec["action"]["policy_output"]
    assert spec["control"]["rate_hz"] == pytest.approx(20.0) and spec["latency"]["action_delay_steps"] == 0


# ---------------------------------------------------------------------- errors and outputs
def test_one_line_errors(runs, tmp_path, capsys):
    run = runs["sac_shape"]
    no_model = tmp_path / "no_model"
    no_model.mkdir()
    (no_model / "config.yaml").write_text((run / "config.yaml").read_text())
    cases = [((tmp_path / "missing", "--format", "npz"), "no such run folder"),
             ((tmp_path, "--format", "npz"), "no config.yaml"),
             ((no_model, "--format", "npz"), "model.zip does not exist"),
             ((run, "--format", "tflite"), "--format: unknown 'tflite'"),
             ((run, "--format", "npz", "--model", tmp_path / "nope.zip"), "nope.zip does not exist")]
    for argv, words in cases:
        assert run_export(*argv, "--out", tmp_path / "x.npz") == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1 and words in err, (argv, err)
    assert not (tmp_path / "x.npz").exists()


def test_existing_outputs_are_kept_without_force(runs, tmp_path, capsys):
    out = tmp_path / "policy.npz"
    argv = (runs["sac_shape"], "--format", "npz", "--out", out, "--check-steps", 0)
    assert run_export(*argv) == 0
    spec_path(out).write_text("{}")        # either output existing refuses the export
    before = out.read_bytes()
    out.unlink()
    assert run_export(*argv) == 2
    err = capsys.readouterr().err
    assert "exists; pass --force" in err and not out.exists() and spec_path(out).read_text() == "{}"
    assert run_export(*argv, "--force") == 0
    assert out.read_bytes() == before and PolicyRunner(out).spec["format"] == "npz"


# ---------------------------------------------------------------------- the runner
def test_runner_refuses_bad_input(runs, tmp_path):
    out = tmp_path / "policy.npz"
    assert run_export(runs["sac_shape"], "--format", "npz", "--out", out, "--check-steps", 0) == 0
    runner = PolicyRunner(spec_path(out))          # the spec's path works too
    n = runner.obs_size
    with pytest.raises(ValueError, match=r"obs: expected shape \(69,\)"):
        runner(np.zeros(n + 1))
    bad = np.zeros(n)
    bad[4] = np.nan
    with pytest.raises(ValueError, match=r"obs: non-finite entry nan at index \(4,\)"):
        runner(bad)
    data = bytearray(out.read_bytes())
    data[-30] ^= 0xFF
    out.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="SHA-256 differs"):
        PolicyRunner(out)
    spec_path(out).unlink()
    with pytest.raises(FileNotFoundError, match="no spec"):
        PolicyRunner(out)


def test_runner_runs_without_sb3_torch_or_the_package(runs, tmp_path):
    """The runner file copied alone (as onto a robot's computer) runs an npz export with NumPy only."""
    out = tmp_path / "policy.npz"
    assert run_export(runs["ppo_roll_robot"], "--format", "npz", "--out", out, "--check-steps", 0) == 0
    robot = tmp_path / "robot"
    robot.mkdir()
    (robot / "policy_runner.py").write_text(Path(policy_runner.__file__).read_text())
    cfg, predict = reference(runs["ppo_roll_robot"])
    obs = env_observations(cfg, predict, 5)
    np.save(tmp_path / "obs.npy", obs)
    code = ("import sys, numpy as np; import policy_runner as pr; r = pr.PolicyRunner(sys.argv[1]); "
            "np.save(sys.argv[3], r(np.load(sys.argv[2]))); "
            "bad = [m for m in ('torch', 'stable_baselines3', 'tensegrity_gym', 'gymnasium', 'scipy') if m in sys.modules]; "
            "assert not bad, bad")
    p = subprocess.run([sys.executable, "-c", code, str(out), str(tmp_path / "obs.npy"), str(tmp_path / "act.npy")],
                       cwd=robot, capture_output=True, text=True, timeout=120, env={"PATH": "/usr/bin:/bin"})
    assert p.returncode == 0, p.stderr
    assert np.abs(np.load(tmp_path / "act.npy") - np.stack([predict(o) for o in obs])).max() <= TOL


def test_committed_run_exports(tmp_path):
    """A committed results model: its npz export gives SB3's actions (observations around its
    normalisation statistics; no env)."""
    from agents import hyperparameters
    from agents.evaluate import load_vecnormalize
    run = ROOT / "results" / "ppo_shape_rest_length"
    if not (run / "model.zip").exists():
        pytest.skip("results/ppo_shape_rest_length is not in this checkout")
    cfg = common.read_run_config(run / "config.yaml")
    model = common.load_model_file(hyperparameters.get_algo(cfg["algo"]), run / "model.zip", device="cpu")
    vn = load_vecnormalize(run / "vecnormalize.pkl")
    program, arrays = export.actor_program(model, vn)
    assert [layer["op"] for layer in program["layers"]] == ["linear", "tanh", "linear", "tanh", "linear"]
    rng = np.random.default_rng(0)
    mean, std = vn.obs_rms.mean, np.sqrt(vn.obs_rms.var)
    obs = (mean + 2.0 * std * rng.standard_normal((50, mean.size))).astype(np.float32)
    expected = model.predict(vn.normalize_obs(obs), deterministic=True)[0]
    assert np.abs(policy_runner.npz_forward(program, arrays, obs) - expected).max() <= TOL


# ---------------------------------------------------------------------- the deployment loop
def test_deploy_loop_example_runs(runs, tmp_path):
    out = tmp_path / "policy.npz"
    assert run_export(runs["ppo_roll_robot"], "--format", "npz", "--out", out, "--check-steps", 0) == 0
    p = subprocess.run([sys.executable, str(ROOT / "examples" / "deploy_loop.py"), str(out), "--steps", "5",
                        "--no-sleep"], cwd=ROOT, capture_output=True, text=True, timeout=300,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert p.returncode == 0, p.stderr
    assert "5 control steps at 50 Hz" in p.stdout and "robot observations" in p.stdout and "(numpy)" in p.stdout


def test_deploy_loop_keeps_the_control_rate(runs, tmp_path):
    out = tmp_path / "policy.pt"
    assert run_export(runs["sac_shape"], "--format", "torchscript", "--out", out, "--check-steps", 0) == 0
    spec = importlib.util.spec_from_file_location("deploy_loop", ROOT / "examples" / "deploy_loop.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    runner = PolicyRunner(out)
    robot = mod.SimulatedRobot(runner.spec, seed=0)
    try:
        stats = mod.control_loop(runner, robot, 5, sleep=True)
    finally:
        robot.close()
    assert stats["steps"] == 5 and stats["wall_s"] >= 5 * 0.02 - 1e-3   # slept to each tick of 50 Hz
