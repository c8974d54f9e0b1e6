"""Tests of agents/train.py and agents/evaluate.py (SB3 training scripts).

Small budgets only: each training run is a few hundred env steps.
"""
from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
yaml = pytest.importorskip("yaml")

ROOT = Path(__file__).resolve().parent.parent

import gymnasium as gym  # noqa: E402
import tensegrity_gym  # noqa: E402,F401  (registers the envs)
from agents import envs, evaluate, hyperparameters, parsing, train  # noqa: E402

ENV_IDS = [e for e in ("TensegrityShape-v0", "TensegrityRoll-v0")
           if e in gym.envs.registry]
TINY = ["--n-timesteps", "256", "--n-envs", "4", "--eval-freq", "128", "--eval-episodes", "2",
        "--save-freq", "128", "--no-progress-bar"]


def _env_ok(env_id):
    """The env can be constructed (its module exists)."""
    try:
        gym.make(env_id).close()
        return True
    except (ImportError, ModuleNotFoundError, gym.error.Error):
        return False


def _tiny_hp(algo):
    if algo == "ppo":
        return ["--hyperparams", "n_steps=32", "batch_size=64", "n_epochs=2",
                "policy_kwargs=dict(net_arch=[32, 32])"]
    return ["--hyperparams", "learning_starts=64", "batch_size=32", "buffer_size=2000",
            "policy_kwargs=dict(net_arch=[32, 32])"]


# ---------------------------------------------------------------------- parsing (no eval)
def test_safe_literal_parses_zoo_strings_and_rejects_code():
    import torch
    d = parsing.safe_literal("dict(log_std_init=-1.0, net_arch=dict(pi=[64, 64], vf=[64]), activation_fn=nn.Tanh)")
    assert d == {"log_std_init": -1.0, "net_arch": {"pi": [64, 64], "vf": [64]}, "activation_fn": torch.nn.Tanh}
    assert parsing.safe_literal("th.nn.ReLU") is torch.nn.ReLU
    for bad in ("__import__('os').system('true')", "os.system", "dict(a=open('x'))", "[x for x in ()]",
                "nn.functional"):
        with pytest.raises(ValueError):
            parsing.safe_literal(bad)


def test_kv_parsing():
    assert parsing.parse_kv_list(["action_mode:force_density", "frame_skip:10", "actuated:[0, 1]",
                                 "target_range:0.05", "clip_actions:false"], ":", "x") == {
        "action_mode": "force_density", "frame_skip": 10, "actuated": [0, 1], "target_range": 0.05,
        "clip_actions": False}
    assert parsing.parse_kv_list(['{"a": 1, "b": "c"}'], ":", "x") == {"a": 1, "b": "c"}
    assert parsing.parse_kv_list(["learning_rate=3e-4", "lr=lin_1e-3"], "=", "x") == {
        "learning_rate": 3e-4, "lr": "lin_1e-3"}
    with pytest.raises(ValueError, match="key:value"):
        parsing.parse_kv_list(["oops"], ":", "--env-kwargs")


def test_resolve_hyperparams_schedules_and_unsupported_keys():
    hp = hyperparameters.resolve_hyperparams("ppo", {"n_timesteps": 1e4, "n_envs": 2, "learning_rate": "lin_1e-3",
                                            "normalize": True, "gamma": 0.9,
                                            "policy_kwargs": "dict(net_arch=[8])"})
    assert hp["n_timesteps"] == 10000 and hp["n_envs"] == 2
    assert hp["normalize"] == {"gamma": 0.9}
    assert hp["model_kwargs"]["learning_rate"](0.5) == pytest.approx(5e-4)
    assert hp["model_kwargs"]["policy_kwargs"] == {"net_arch": [8]}
    with pytest.raises(ValueError, match="env_wrapper"):
        hyperparameters.resolve_hyperparams("ppo", {"env_wrapper": "x.Y"})


# ---------------------------------------------------------------------- hyperparameter files
def _check_entries(path, algo: str) -> dict:
    """The entries of the hyperparameter file ``path``, each checked: a registered env id, the
    entry resolves for ``algo`` (strings parse safely) and its model arguments are the
    algorithm's."""
    import inspect
    data = hyperparameters.load_hyperparams_file(path)
    assert data, f"{path} is empty"
    Algo = hyperparameters.get_algo(algo)
    params = inspect.signature(Algo.__init__).parameters
    for env_id, hp in data.items():
        assert env_id in gym.envs.registry, f"{path}: {env_id} is not a registered env id"
        r = hyperparameters.resolve_hyperparams(algo, hp)
        assert r["n_timesteps"] > 0 and r["n_envs"] >= 1
        for k in r["model_kwargs"]:
            assert k in params, f"{path}:{env_id}: {k!r} is not a {Algo.__name__} argument"
    return data


@pytest.mark.parametrize("name", ["ppo.yml", "sac.yml", "td3.yml", "time_to_policy/ppo.yml"])
def test_hyperparam_files_parse_and_name_registered_envs(name):
    path = ROOT / "agents" / "hyperparams" / name
    algo = path.stem
    data = _check_entries(path, algo)
    for env_id in ENV_IDS:
        assert env_id in data or algo == "td3", f"{path} has no entry for {env_id}"


@pytest.mark.parametrize("path", sorted((ROOT / "agents" / "hyperparams").glob("*/*.yml")),
                         ids=lambda p: p.parent.name + "/" + p.name)
def test_task_hyperparam_files_resolve_and_make_their_envs(path):
    """The recipes of the committed task results (climb/, navigate/, time_to_policy/): each entry
    checked as the top-level files' are, for the algorithm its file name starts with, and its
    env_kwargs (robot, slopes, randomised parameters) make the env (every argument accepted by
    name)."""
    for env_id, hp in _check_entries(path, path.stem.split("_")[0]).items():
        gym.make(env_id, **(hp.get("env_kwargs") or {})).close()


def test_time_to_policy_entries_are_the_ones_the_results_trained():
    """agents/hyperparams/time_to_policy/ppo.yml (for --conf-file; parsed and resolved by the test
    above): the only file there, and its entries are those of results/ppo_shape_1min/ and
    results/ppo_roll_5min/lin_lr_std1/."""
    folder = ROOT / "agents" / "hyperparams" / "time_to_policy"
    assert [f.name for f in folder.glob("*.yml")] == ["ppo.yml"]
    hp, source = hyperparameters.hyperparams_for("ppo", "TensegrityShape-v0", folder / "ppo.yml")
    r = hyperparameters.resolve_hyperparams("ppo", hp)
    assert source.endswith("time_to_policy/ppo.yml:TensegrityShape-v0")
    assert r["n_envs"] == 256
    mk = r["model_kwargs"]
    assert (mk["n_steps"], mk["batch_size"], mk["n_epochs"], mk["gamma"], mk["gae_lambda"]) == (16, 128, 2, 0.8, 0.8)
    assert mk["policy_kwargs"]["net_arch"] == {"pi": [64, 64], "vf": [64, 64]}
    hp, _ = hyperparameters.hyperparams_for("ppo", "TensegrityRoll-v0", folder / "ppo.yml")
    r = hyperparameters.resolve_hyperparams("ppo", hp)
    assert (r["n_envs"], r["n_timesteps"]) == (128, 9_000_000)
    mk = r["model_kwargs"]
    assert (mk["n_steps"], mk["batch_size"], mk["n_epochs"], mk["gamma"], mk["gae_lambda"]) == (128, 2048, 2, 0.995, 0.98)
    assert mk["learning_rate"](1.0) == pytest.approx(1.12e-3) and mk["learning_rate"](0.0) == 0.0
    assert mk["policy_kwargs"] == {"log_std_init": 0.0, "net_arch": {"pi": [128, 128], "vf": [128, 128]}}


# ---------------------------------------------------------------------- train -> save -> reload -> evaluate
@pytest.mark.parametrize("algo", ["ppo", "sac"])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_train_save_reload_evaluate(tmp_path, env_id, algo):
    if not _env_ok(env_id):
        pytest.skip(f"{env_id} is not importable yet")
    run = tmp_path / "run"
    train.train(["--algo", algo, "--env", env_id, "--log-dir", str(run), *TINY, *_tiny_hp(algo)])
    for f in ("model.zip", "vecnormalize.pkl", "config.yaml", "command.txt", "versions.json", "state.json",
              "best_model.zip", "best_vecnormalize.pkl", "eval/evaluations.npz"):
        assert (run / f).exists(), f"missing {f}"
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    assert cfg["env"] == env_id and cfg["algo"] == algo and cfg["vec_env"] == "batched"
    versions = json.loads((run / "versions.json").read_text())
    for k in ("python", "numpy", "torch", "stable_baselines3", "gymnasium", "tensegrity_gym", "cpus_available"):
        assert versions[k], k
    assert "cpu_model" in versions          # None only where neither lscpu nor /proc/cpuinfo says
    stamp, command = (run / "command.txt").read_text().splitlines()[:2]
    assert "agents.train" in command and str(Path.cwd()) not in stamp   # the working directory: repository-relative
    state = json.loads((run / "state.json").read_text())
    assert state["status"] == "finished" and state["num_timesteps"] >= 256
    assert {"cpu_model", "cpus_available", "torch_num_threads"} <= set(state["machine"])   # where the wall time ran
    assert list((run / "checkpoints").glob("rl_model_*_steps.zip"))
    assert list((run / "monitor").glob("*.monitor.csv"))
    tb = list((run / "tb").rglob("events.out.tfevents*"))
    assert tb
    # reload and evaluate (few episodes, no gif) against the baselines and random
    out = tmp_path / "eval"
    m = evaluate.evaluate([str(run), "--model", "final", "--n-episodes", "2", "--out", str(out)])
    res = m["results"]
    trained = next(k for k in res if "trained" in k)
    assert "random" in res
    for k, r in res.items():
        assert np.isfinite(r["return_mean"]) and r["n_episodes"] == 2
    assert m["model_num_timesteps"] == state["num_timesteps"]
    if env_id == "TensegrityShape-v0":
        assert "nnls" in res
        assert 0.0 <= res[trained]["success_rate"] <= 1.0
        assert res[trained]["final_max_node_error_median_m"] > 0
    for f in ("metrics.json", "episodes.json", "learning_curve.png", "episodes.png", "table.md"):
        assert (out / f).exists(), f
    # the reloaded policy's actions equal the model's with the saved normalisation
    from stable_baselines3.common.base_class import BaseAlgorithm  # noqa: F401
    cfg2, pol, _, model = evaluate.load_trained(run, "final")
    env = gym.make(env_id)
    obs, _ = env.reset(seed=3)
    a1, _ = pol.predict(obs)
    assert env.action_space.contains(np.asarray(a1, np.float32))
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_train_on_the_torch_vector_env(tmp_path, env_id):
    """--vec-env torch trains on the device-resident torch env (here on the CPU) and records it;
    the evaluation env stays the NumPy one, and the saved model evaluates like any other."""
    pytest.importorskip("torch")
    run = tmp_path / "run"
    sampling = "device" if env_id == "TensegrityRoll-v0" else "host"     # resets drawn on the device (roll)
    train.train(["--algo", "ppo", "--env", env_id, "--log-dir", str(run), "--vec-env", "torch",
                 "--env-device", "cpu", "--env-dtype", "float64", "--env-reset-sampling", sampling,
                 *TINY, *_tiny_hp("ppo")])
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    assert (cfg["vec_env"], cfg["env_device"], cfg["env_dtype"], cfg["env_reset_sampling"]) == (
        "torch", "cpu", "float64", sampling)
    state = json.loads((run / "state.json").read_text())
    assert state["status"] == "finished" and state["num_timesteps"] >= 256
    rows = (run / "monitor" / "train_0.monitor.csv").read_text().splitlines()
    assert len(rows) >= 2 and rows[1].startswith("r,l,t")       # the torch env's infos reach VecMonitor
    m = evaluate.evaluate([str(run), "--model", "final", "--n-episodes", "2", "--out", str(tmp_path / "eval")])
    assert np.isfinite(m["results"][next(k for k in m["results"] if "trained" in k)]["return_mean"])


def test_env_device_needs_the_torch_vec_env(tmp_path):
    for flag, value in (("--env-device", "cpu"), ("--env-dtype", "float64"), ("--env-reset-sampling", "device")):
        with pytest.raises(ValueError, match=f"{flag}: only with --vec-env torch"):
            train.train(["--algo", "ppo", "--env", "TensegrityShape-v0", flag, value,
                         "--log-dir", str(tmp_path / flag.strip("-")), *TINY])


def test_evaluate_numbers_match_a_manual_rollout(tmp_path):
    """The evaluation's return and final error equal a hand-written single-env rollout."""
    env_id = "TensegrityShape-v0"
    if not _env_ok(env_id):
        pytest.skip("shape env not importable yet")
    run = tmp_path / "run"
    train.train(["--algo", "ppo", "--env", env_id, "--log-dir", str(run), "--n-timesteps", "64", "--n-envs", "2",
                 "--eval-freq", "-1", "--save-freq", "-1", "--no-progress-bar", *_tiny_hp("ppo")])
    cfg, pol, _, _ = evaluate.load_trained(run, "final")
    eps = evaluate.run_episodes(env_id, cfg["env_kwargs"], lambda env: pol, [123, 124],
                                ("max_node_error",), batched=True)
    env = gym.make(env_id, **cfg["env_kwargs"])
    for e in eps:
        obs, _ = env.reset(seed=e["seed"])
        R, done = 0.0, False
        while not done:
            a, _ = pol.predict(obs)
            obs, r, term, trunc, info = env.step(a)
            R += r
            done = term or trunc
        assert e["return"] == pytest.approx(R, rel=1e-5, abs=1e-6)
        assert e["final"]["max_node_error"] == pytest.approx(info["max_node_error"], rel=1e-6, abs=1e-9)
    env.close()


# ---------------------------------------------------------------------- resume and Ctrl-C
def test_interrupt_saves_and_resume_continues_step_count(tmp_path):
    env_id = ENV_IDS[0] if ENV_IDS and _env_ok(ENV_IDS[0]) else "Pendulum-v1"
    run = tmp_path / "run"
    from agents.callbacks import InterruptAt
    args = ["--algo", "ppo", "--env", env_id, "--log-dir", str(run), "--n-timesteps", "512", "--n-envs", "4",
            "--eval-freq", "128", "--eval-episodes", "2", "--save-freq", "128", "--no-progress-bar",
            "--hyperparams", "n_steps=32", "batch_size=64", "n_epochs=1", "normalize=true"]
    train.train(args, extra_callbacks=[InterruptAt(200)])
    st = json.loads((run / "state.json").read_text())
    assert st["status"] == "interrupted"
    n_int = st["num_timesteps"]
    assert 200 <= n_int < 512
    assert (run / "model.zip").exists() and (run / "vecnormalize.pkl").exists()
    from stable_baselines3.common.vec_env import VecNormalize  # noqa: F401
    vn_before = evaluate.load_vecnormalize(run / "vecnormalize.pkl")
    ev_before = np.load(run / "eval" / "evaluations.npz")["timesteps"].tolist()

    run_dir = train.train(["--resume", str(run), "--no-progress-bar"])
    st2 = json.loads((run_dir / "state.json").read_text())
    assert st2["status"] == "finished"
    assert st2["num_timesteps"] >= 512
    from stable_baselines3 import PPO
    m = PPO.load(run / "model.zip")
    assert m.num_timesteps == st2["num_timesteps"]
    # the normalisation statistics continued from the saved ones (count grew, not restarted)
    vn_after = evaluate.load_vecnormalize(run / "vecnormalize.pkl")
    assert vn_after.obs_rms.count > vn_before.obs_rms.count
    ev_after = np.load(run / "eval" / "evaluations.npz")["timesteps"].tolist()
    assert ev_after[: len(ev_before)] == ev_before and len(ev_after) > len(ev_before)
    assert all(t > n_int for t in ev_after[len(ev_before):])
    assert len(list((run / "monitor").glob("*.monitor.csv"))) == 2
    cmd = (run / "command.txt").read_text()
    assert cmd.count("agents.train") == 2
    # resuming again with a larger target extends the run
    train.train(["--resume", str(run), "--n-timesteps", "640", "--no-progress-bar"])
    assert PPO.load(run / "model.zip").num_timesteps >= 640


def test_recorded_working_directory_is_relative_to_the_repository(tmp_path, monkeypatch):
    from agents import common
    monkeypatch.chdir(common.REPO_ROOT)
    assert common.repo_cwd() == "."
    monkeypatch.chdir(common.REPO_ROOT / "agents")
    assert common.repo_cwd() == "agents"
    monkeypatch.chdir(tmp_path)
    assert common.repo_cwd() is None     # outside the checkout: not recorded


def test_existing_run_dir_is_not_overwritten(tmp_path):
    run = tmp_path / "run"
    args = ["--algo", "ppo", "--env", "Pendulum-v1", "--log-dir", str(run), "--n-timesteps", "64", "--n-envs", "1",
            "--eval-freq", "-1", "--save-freq", "-1", "--no-progress-bar", "--hyperparams", "n_steps=64",
            "batch_size=64", "n_epochs=1"]
    train.train(args)
    with pytest.raises(FileExistsError, match="--resume"):
        train.train(args)


def test_bad_arguments_give_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="not a registered"):
        train.train(["--env", "NoSuchEnv-v0", "--log-dir", str(tmp_path / "a")])
    with pytest.raises(ValueError, match="--algo"):
        train.train(["--algo", "nope", "--env", "Pendulum-v1", "--log-dir", str(tmp_path / "b")])
    with pytest.raises(ValueError, match="not allowed|unsupported"):
        train.train(["--algo", "ppo", "--env", "Pendulum-v1", "--log-dir", str(tmp_path / "c"),
                     "--hyperparams", "policy_kwargs=dict(x=__import__('os'))"])
    # a misspelt env argument: named with the nearest accepted one (was gym.make's TypeError traceback)
    with pytest.raises(ValueError, match=r"--env-kwargs: TensegrityShape-v0 takes no argument 'tracking_weigth' "
                                         r"\(did you mean tracking_weight\?\); its arguments: .*success_tolerance"):
        train.train(["--algo", "ppo", "--env", "TensegrityShape-v0", "--log-dir", str(tmp_path / "d"),
                     "--env-kwargs", '{"tracking_weigth": 1}', "-n", "64"])
    with pytest.raises(ValueError, match=r"--seed: must be an integer in 0..4294967295, got -3"):
        train.train(["--algo", "ppo", "--env", "Pendulum-v1", "--log-dir", str(tmp_path / "e"), "--seed", "-3"])
    # hyperparameters SB3 answers with a traceback (or trains to NaN: gamma = 2), named before any run folder
    base = ["--algo", "ppo", "--env", "Pendulum-v1", "-n", "64", "--n-envs", "1", "--eval-freq", "-1",
            "--save-freq", "-1", "--no-progress-bar", "--hyperparams"]
    for i, (hp, pattern) in enumerate([
            ("bach_size=64", r"--hyperparams: PPO takes no hyperparameter 'bach_size' \(did you mean batch_size\?\)"),
            ("gamma=2", r"--hyperparams: gamma must be a number in \[0, 1\], got 2"),
            ("batch_size=-1", r"--hyperparams: batch_size: must be an integer >= 2, got -1"),
            ("n_epochs=abc", r"--hyperparams: n_epochs: must be an integer >= 1, got 'abc'"),
            ("ent_coef=abc", r"--hyperparams: ent_coef must be a number \(PPO's default is 0.0\), got 'abc'"),
            ("policy_kwargs=dict(net_arch=[-5])", r"--hyperparams: policy_kwargs net_arch entry 0 is -5; layer sizes")]):
        with pytest.raises(ValueError, match=pattern):
            train.train(base + [hp, "--log-dir", str(tmp_path / f"hp{i}")])
        assert not (tmp_path / f"hp{i}" / "model.zip").exists()
    assert hyperparameters.resolve_hyperparams("sac", {"buffer_size": 1e6})["model_kwargs"]["buffer_size"] == 1000000
    # a malformed YAML file (hyperparameters, sweep config): file, line and problem (was PyYAML's traceback)
    bad = tmp_path / "bad.yml"
    bad.write_text("foo: [\n")
    with pytest.raises(ValueError, match=r"bad.yml: not valid YAML at line 2, column 1: expected the node content"):
        train.train(["--algo", "ppo", "--env", "Pendulum-v1", "--conf-file", str(bad), "--log-dir", str(tmp_path / "y")])
    from agents import tune
    with pytest.raises(ValueError, match=r"bad.yml: not valid YAML at line 2"):
        tune.load_config(bad)


def test_env_kwargs_checked_for_every_registered_env():
    """envs.make_env names an unknown key for the roll env (its task's arguments) and the MuJoCo
    twin (its own and the task's), and passes known ones through."""
    names = envs.env_argument_names("TensegrityRoll-v0")
    assert {"frame_skip", "ground_stiffness", "observation_mode", "width"} <= set(names)
    assert "num_envs" not in names and "kwargs" not in names
    with pytest.raises(ValueError, match=r"TensegrityRoll-v0 takes no argument 'ground_stifness' "
                                         r"\(did you mean ground_stiffness"):
        envs.make_env("TensegrityRoll-v0", {"ground_stifness": 1e4})
    if importlib.util.find_spec("mujoco"):
        assert {"mj_integrator", "friction"} <= set(envs.env_argument_names("TensegrityRollMuJoCo-v0"))
    env = envs.make_env("TensegrityShape-v0", {"frame_skip": 10})
    assert env.unwrapped.task.frame_skip == 10
    env.close()


# ---------------------------------------------------------------------- rl-baselines3-zoo compatibility
def test_rl_zoo3_trains_with_our_hyperparameter_file(tmp_path):
    pytest.importorskip("rl_zoo3")
    env_id = "TensegrityShape-v0"
    if not _env_ok(env_id):
        pytest.skip("shape env not importable yet")
    cmd = [sys.executable, "-m", "rl_zoo3.train", "--gym-packages", "tensegrity_gym", "--algo", "ppo",
           "--env", env_id, "-f", str(tmp_path), "--conf-file", str(ROOT / "agents" / "hyperparams" / "ppo.yml"),
           "-n", "256", "--eval-freq", "-1", "--save-freq", "-1", "--seed", "0", "--num-threads", "1",
           "--vec-env", "dummy", "-params", "n_envs:2", "n_steps:64", "batch_size:64", "n_epochs:1"]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    zips = list(tmp_path.rglob(f"{env_id}.zip"))
    assert zips, list(tmp_path.rglob("*"))
    assert list(tmp_path.rglob("vecnormalize.pkl"))


# ---------------------------------------------------------------------- the SB3 adapter (tensegrity_gym.integrations.sb3)
def test_adapter_per_sub_env_methods_on_separate_envs():
    """get_attr / set_attr / env_method / env_is_wrapped act on the selected sub-envs only."""
    from gymnasium.wrappers import TimeLimit
    from stable_baselines3.common.vec_env import DummyVecEnv
    from tensegrity_gym.integrations.sb3 import make_sb3_vec_env
    from tensegrity_gym.envs.common import make_sb3_vec_env as legacy
    assert legacy is make_sb3_vec_env  # the old import path still works
    venv = make_sb3_vec_env(gym.vector.SyncVectorEnv([lambda: gym.make("Pendulum-v1") for _ in range(3)]))
    ref = DummyVecEnv([lambda: gym.make("Pendulum-v1") for _ in range(3)])
    for v in (venv, ref):
        v.set_attr("foo", 7, indices=[1])
        assert v.get_attr("foo", indices=[1]) == [7]
        with pytest.raises(AttributeError):
            v.get_attr("foo", indices=[0])
        v.set_attr("foo", 1)
        assert v.get_attr("foo") == [1, 1, 1]
        assert v.env_is_wrapped(TimeLimit) == [True, True, True]
        assert v.env_is_wrapped(gym.wrappers.RecordEpisodeStatistics, indices=[0, 2]) == [False, False]
        v.seed(5)
        v.reset()
        spaces_ = v.env_method("get_wrapper_attr", "observation_space", indices=[2])
        assert len(spaces_) == 1 and spaces_[0].shape == (3,)
    # the seeds reach the sub-envs as in DummyVecEnv: env i gets seed + i
    venv.seed(11)
    ref.seed(11)
    np.testing.assert_array_equal(venv.reset(), ref.reset())
    assert venv.get_attr("np_random", indices=[0])[0] is not venv.get_attr("np_random", indices=[1])[0]
    venv.close()
    ref.close()


def test_adapter_per_sub_env_methods_on_the_batched_env():
    if not _env_ok("TensegrityShape-v0"):
        pytest.skip("shape env not importable yet")
    from tensegrity_gym.integrations.sb3 import make_sb3_vec_env
    venv = make_sb3_vec_env(gym.make_vec("TensegrityShape-v0", num_envs=3, vectorization_mode="vector_entry_point",
                                         render_mode="rgb_array", width=32, height=32))
    venv.seed(0)
    venv.reset()
    rngs = venv.get_attr("np_random")
    assert len(rngs) == 3 and len({id(r) for r in rngs}) == 3          # each copy its own generator
    assert venv.get_attr("render_mode", indices=[2]) == ["rgb_array"]
    assert venv.env_is_wrapped(gym.Wrapper, indices=[0, 1]) == [False, False]
    frames = venv.env_method("render", indices=[0, 1, 2])
    assert len(frames) == 3 and frames[0].shape == (32, 32, 3)
    venv.set_attr("max_episode_steps", 3)                               # all copies: allowed
    assert venv.get_attr("max_episode_steps") == [3, 3, 3]
    with pytest.raises(ValueError, match="not an attribute"):            # validated: no new attribute
        venv.set_attr("foo", 3)
    with pytest.raises(ValueError, match="share this attribute"):
        venv.set_attr("foo", 4, indices=[1])
    with pytest.raises(ValueError, match="one object"):
        venv.env_method("render", indices=[1])
    venv.close()


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_state_records_where_the_time_went(tmp_path, algo):
    """state.json's time_split_last_segment_s: rollout, learner and evaluation/checkpoint seconds,
    each >= 0, together no more than the segment's wall time; a run with evaluations has
    evaluation time, a learner that updates has learner time."""
    run = tmp_path / "run"
    train.train(["--algo", algo, "--env", "Pendulum-v1", "--log-dir", str(run), *TINY, *_tiny_hp(algo)])
    st = json.loads((run / "state.json").read_text())
    split = st["time_split_last_segment_s"]
    assert set(split) == {"rollout", "learner", "evaluation_and_checkpoints"}
    assert all(v >= 0 for v in split.values())
    assert sum(split.values()) <= st["wall_time_s"] + 1e-3
    assert split["learner"] > 0 and split["rollout"] > 0 and split["evaluation_and_checkpoints"] > 0


def test_wall_time_stop_keeps_the_replay_buffer_for_resume(tmp_path, capsys):
    """An off-policy run stopped by --max-wall-time saves its replay buffer (before, only Ctrl-C
    did, so --resume of a time-limited SAC segment started from an empty buffer, or from the stale
    buffer of an earlier interrupted segment); --resume loads it."""
    run = tmp_path / "run"
    args = ["--algo", "sac", "--env", "Pendulum-v1", "--log-dir", str(run), "--n-timesteps", "100000",
            "--max-wall-time", "2", "--eval-freq", "-1", "--save-freq", "-1", "--no-progress-bar",
            "--hyperparams", "learning_starts=50", "batch_size=32", "buffer_size=5000"]
    train.train(args)
    st = json.loads((run / "state.json").read_text())
    assert st["status"] == "time_limit" and 0 < st["num_timesteps"] < 100000
    assert (run / "replay_buffer.pkl").exists() and (run / "model.zip").exists()
    from stable_baselines3 import SAC
    saved = SAC.load(run / "model.zip")
    saved.load_replay_buffer(run / "replay_buffer.pkl")
    assert min(st["num_timesteps"], 5000) - 1 <= saved.replay_buffer.size() <= min(st["num_timesteps"], 5000)
    capsys.readouterr()
    train.train(["--resume", str(run), "--max-wall-time", "1", "--no-progress-bar"])
    assert "no replay buffer" not in capsys.readouterr().out
