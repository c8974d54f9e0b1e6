"""``python -m agents.train --warm-start RUN_DIR``: a new run starts from a trained policy, the
observation blocks matched by name (agents/warm_start.py)."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
yaml = pytest.importorskip("yaml")

import tensegrity_gym  # noqa: E402,F401  (registers the envs)
from agents import evaluate, train, warm_start  # noqa: E402

TINY = ["--n-envs", "2", "--eval-freq", "-1", "--save-freq", "-1", "--no-progress-bar",
        "--hyperparams", "learning_starts=64", "batch_size=32", "buffer_size=2000",
        "policy_kwargs=dict(net_arch=[32, 32])", "normalize=dict(norm_obs=True, norm_reward=False)"]


def test_observation_map_matches_blocks_by_name():
    src = (5, [("a", slice(0, 2), "m"), ("b", slice(2, 5), "m/s")])
    dst = (8, [("b", slice(0, 3), "m/s"), ("g", slice(3, 6), "1"), ("a", slice(6, 8), "m")])
    assert warm_start.observation_map(src, dst).tolist() == [6, 7, 0, 1, 2]
    assert warm_start.observation_map((4, None), (4, None)).tolist() == [0, 1, 2, 3]
    with pytest.raises(ValueError, match="'a'.*does not observe"):
        warm_start.observation_map(src, (3, [("b", slice(0, 3), "m/s")]))
    with pytest.raises(ValueError, match="block 'b' has 3 values in the source env and 4"):
        warm_start.observation_map(src, (6, [("a", slice(0, 2), "m"), ("b", slice(2, 6), "m/s")]))
    with pytest.raises(ValueError, match="observes 4 values.*5"):
        warm_start.observation_map((4, None), (5, None))


@pytest.fixture(scope="module")
def roll_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("ws") / "roll"
    train.train(["--algo", "sac", "--env", "TensegrityRoll-v0", "--log-dir", str(run), "--n-timesteps", "96", *TINY])
    return run


def _climb_obs(seed=5):
    import gymnasium as gym
    env = gym.make("TensegrityClimb-v0", slope_deg=12.0)
    lay = {n: sl for n, sl, _ in env.unwrapped.task.observation_layout()}
    n = env.observation_space.shape[0]
    keep = np.setdiff1d(np.arange(n), np.arange(n)[lay["gravity_direction"]])
    obs, _ = env.reset(seed=seed)
    env.close()
    return obs, keep, lay["gravity_direction"]


def test_climb_starts_as_the_rolling_policy_acts(roll_run):
    """The warm-started climbing policy acts on the climbing observation as the rolling policy
    acts on the same observation less the slope block; the statistics are the rolling run's for
    the shared blocks and measured on resets for the new one."""
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import VecNormalize
    from agents import envs
    env_kwargs = {"slope_range": [0.0, 30.0]}
    venv, _ = envs.make_vec("TensegrityClimb-v0", 2, 0, env_kwargs, "batched")
    venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    model = SAC("MlpPolicy", venv, policy_kwargs=dict(net_arch=[32, 32]), seed=0)
    src_info = warm_start.check_source(roll_run, "sac")
    out = warm_start.warm_start(model, venv, src_info, "TensegrityClimb-v0", env_kwargs, 0)
    assert out["env"] == "TensegrityRoll-v0" and len(out["new_observations"]) == 3
    assert any("qf0.0" in n for n in out["remapped_layers"])        # the critic's input is (obs, action)
    _, src, _, src_model = evaluate.load_trained(roll_run, "final")
    obs, keep, g = _climb_obs()
    a_src, _ = src.predict(obs[keep], deterministic=True)
    a_dst, _ = model.predict(venv.normalize_obs(obs), deterministic=True)
    np.testing.assert_allclose(a_dst, a_src, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(venv.obs_rms.mean[keep], src.vn.obs_rms.mean)
    np.testing.assert_array_equal(venv.obs_rms.var[keep], src.vn.obs_rms.var)
    assert venv.obs_rms.mean[g][2] < -0.8 and np.all(venv.obs_rms.var[g] > 0)   # cos of 0-30 degree slopes
    assert float(model.log_ent_coef.detach()) == float(src_model.log_ent_coef.detach())
    venv.close()


def test_train_records_the_warm_start(roll_run, tmp_path):
    run = tmp_path / "climb"
    train.train(["--algo", "sac", "--env", "TensegrityClimb-v0", "--log-dir", str(run), "--n-timesteps", "2",
                 "--warm-start", str(roll_run), *TINY])
    ws = yaml.safe_load((run / "config.yaml").read_text())["warm_start"]
    assert ws["run"] == str(roll_run) and ws["env"] == "TensegrityRoll-v0" and ws["model_num_timesteps"] == 96
    assert len(ws["new_observations"]) == 3 and ws["vecnormalize"].endswith("vecnormalize.pkl")
    # no update yet (learning_starts 64): the saved policy still acts as the rolling one
    _, src, _, _ = evaluate.load_trained(roll_run, "final")
    _, dst, _, _ = evaluate.load_trained(run, "final")
    obs, keep, _ = _climb_obs()
    o = dst.vn.normalize_obs(obs.astype(np.float32))
    a_src, _ = src.model.predict(o[keep], deterministic=True)
    a_dst, _ = dst.model.predict(o, deterministic=True)
    np.testing.assert_allclose(a_dst, a_src, rtol=0, atol=1e-6)


def test_warm_start_refusals(roll_run, tmp_path):
    with pytest.raises(ValueError, match="trained with sac, this training uses ppo"):
        train.train(["--algo", "ppo", "--env", "TensegrityRoll-v0", "--log-dir", str(tmp_path / "a"),
                     "--warm-start", str(roll_run), "--n-timesteps", "64", "--no-progress-bar"])
    with pytest.raises(FileNotFoundError, match="--warm-start .*no config.yaml"):
        train.train(["--algo", "sac", "--env", "TensegrityRoll-v0", "--log-dir", str(tmp_path / "b"),
                     "--warm-start", str(tmp_path), "--n-timesteps", "64", "--no-progress-bar"])
    with pytest.raises(ValueError, match="net_arch"):
        train.train(["--algo", "sac", "--env", "TensegrityRoll-v0", "--log-dir", str(tmp_path / "c"),
                     "--warm-start", str(roll_run), "--n-timesteps", "2", *TINY, "policy_kwargs=dict(net_arch=[16])"])
    with pytest.raises(ValueError, match="'gravity_direction'.*does not observe"):
        climb = tmp_path / "d"
        train.train(["--algo", "sac", "--env", "TensegrityClimb-v0", "--log-dir", str(climb), "--n-timesteps", "2",
                     "--warm-start", str(roll_run), *TINY])
        train.train(["--algo", "sac", "--env", "TensegrityRoll-v0", "--log-dir", str(tmp_path / "e"),
                     "--n-timesteps", "2", "--warm-start", str(climb), *TINY])
    with pytest.raises(ValueError, match="--warm-start: a new run only"):
        train.train(["--resume", str(roll_run), "--warm-start", str(roll_run)])
