"""The RL libraries on the tensegrity vector envs, each with its own PPO for a few hundred env
steps on CPU, on the NumPy vector env and on the torch device env (``device="cpu"``): rsl_rl
(``OnPolicyRunner`` over :mod:`tensegrity_gym.integrations.rsl_rl`), skrl (``wrap_env``
auto-detection and its trainer defaults, no adapter), TorchRL (``GymWrapper`` +
``check_env_specs``, no adapter), tianshou (:mod:`tensegrity_gym.integrations.tianshou`) and
the CleanRL-style example. Each test skips when its library is not installed. Short episodes
(``max_episode_steps``) so that every run crosses episode ends and resets."""
import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gymnasium as gym  # noqa: E402

import tensegrity_gym  # noqa: E402,F401  (registers the envs)

SHAPE = "TensegrityShape-v0"
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
BACKENDS = ["numpy", "torch"]


def _example(name: str):
    """The module ``examples/<name>.py`` (imported from its path: examples/ is not a package)."""
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _finite(out: dict) -> None:
    assert math.isfinite(out["mean_reward_per_step"]), out


# ---------------------------------------------------------------- rsl_rl
@pytest.mark.parametrize("backend", BACKENDS)
def test_rsl_rl_on_policy_runner_learns_on_the_vec_env(backend, tmp_path):
    pytest.importorskip("rsl_rl")
    from rsl_rl.env import VecEnv
    from rsl_rl.runners import OnPolicyRunner
    from tensegrity_gym.integrations.rsl_rl import make_rsl_rl_env, train_config
    env = make_rsl_rl_env(SHAPE, num_envs=4, backend=backend, device="cpu", max_episode_steps=20)
    assert isinstance(env, VecEnv) and env.max_episode_length == 20 and env.num_actions == 9
    obs = env.get_observations()
    assert set(obs.keys()) == {"policy", "critic"} and obs["policy"].dtype == torch.float32
    cfg = train_config(num_steps_per_env=24)
    runner = OnPolicyRunner(env, cfg, log_dir=None, device="cpu")
    runner.learn(3, init_at_random_ep_len=True)            # 3 x 24 x 4 = 288 env steps
    assert int(env.episode_length_buf.max()) <= 20
    obs, rew, dones, extras = env.step(torch.zeros(4, env.num_actions))
    assert rew.shape == (4,) and dones.dtype == torch.long and extras["time_outs"].dtype == torch.bool
    assert all(k.startswith("/reward/") for k in extras["log"])


def test_rsl_rl_episode_length_buf_is_the_env_counter_and_time_outs_reset():
    pytest.importorskip("rsl_rl")
    from tensegrity_gym.integrations.rsl_rl import make_rsl_rl_env
    for backend in BACKENDS:
        env = make_rsl_rl_env(SHAPE, num_envs=3, backend=backend, max_episode_steps=5)
        env.get_observations()
        env.episode_length_buf = torch.tensor([0, 2, 4])
        _, _, dones, extras = env.step(torch.zeros(3, env.num_actions))
        assert dones.tolist() == [0, 0, 1] and extras["time_outs"].tolist() == [False, False, True]
        assert env.episode_length_buf.tolist() == [1, 3, 0]    # env 2 was reset in the same step


def test_rsl_rl_refuses_an_env_that_does_not_reset_in_the_same_step():
    pytest.importorskip("rsl_rl")
    from tensegrity_gym.integrations.rsl_rl import RslRlVecEnv
    venv = gym.make_vec(SHAPE, num_envs=2, vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError, match="same_step"):
        RslRlVecEnv(venv)


def test_rsl_rl_device_names_one_device_however_spelled():
    """A device named without its index ("cuda" for "cuda:0"; here "cpu:0" for "cpu") is the
    torch env's device; a device that is not is refused by name."""
    pytest.importorskip("rsl_rl")
    from tensegrity_gym.integrations.rsl_rl import RslRlVecEnv, make_rsl_rl_env
    env = make_rsl_rl_env(SHAPE, num_envs=2, backend="torch", device="cpu:0")
    assert env.device == torch.device("cpu")
    with pytest.raises(ValueError, match=r"device: 'meta' is not supported"):
        RslRlVecEnv(env.env, device="meta")


def test_rsl_rl_command_line(capsys):
    pytest.importorskip("rsl_rl")
    from tensegrity_gym.integrations.rsl_rl import main
    main(["--env-id", SHAPE, "--num-envs", "4", "--iterations", "1", "--backend", "numpy", "--eval-steps", "3",
          "--log-dir", ""])
    assert "rsl_rl PPO on TensegrityShape-v0 (numpy, cpu): 96 env steps" in capsys.readouterr().out


# ---------------------------------------------------------------- skrl
@pytest.mark.parametrize("backend", BACKENDS)
def test_skrl_ppo_with_wrap_env_auto_detection(backend, tmp_path):
    pytest.importorskip("skrl")
    from skrl.envs.wrappers.torch import wrap_env
    from skrl.envs.wrappers.torch.gymnasium_envs import GymnasiumWrapper
    mod = _example("skrl_ppo")
    assert isinstance(wrap_env(mod.make_env(SHAPE, 2, backend, "next_step", 0), verbose=False), GymnasiumWrapper)
    out = mod.main(["--env-id", SHAPE, "--num-envs", "4", "--timesteps", "64", "--rollouts", "16",
                    "--max-episode-steps", "20", "--backend", backend, "--directory", str(tmp_path), "--eval-steps", "5"])
    assert out["env_steps"] == 256 and "random_reward_per_step" in out
    _finite(out)


def test_skrl_device_env_route_resets_by_env_idx():
    """skrl's wrapper for device-resident envs (its ManiSkill wrapper) resets ended envs with
    ``reset(options={"env_idx": ...})``; the torch env with autoreset disabled takes it."""
    pytest.importorskip("skrl")
    from skrl.envs.wrappers.torch import wrap_env
    env = gym.make_vec(SHAPE, num_envs=3, vectorization_mode="vector_entry_point", backend="torch", device="cpu",
                       dtype="float32", autoreset_mode="disabled", max_episode_steps=3)
    w = wrap_env(env, wrapper="mani-skill", verbose=False)
    w.reset()
    ends = []
    for _ in range(7):
        _, _, _, trunc, _ = w.step(torch.zeros(3, 9))
        ends.append(bool(trunc.all()))
    assert ends == [False, False, True] * 2 + [False] and env.elapsed.tolist() == [1, 1, 1]


# ---------------------------------------------------------------- TorchRL
@pytest.mark.parametrize("backend", BACKENDS)
def test_torchrl_ppo_with_gym_wrapper(backend):
    pytest.importorskip("torchrl")
    mod = _example("torchrl_ppo")
    out = mod.main(["--env-id", SHAPE, "--num-envs", "4", "--frames", "256", "--frames-per-batch", "128",
                    "--max-episode-steps", "20", "--backend", backend, "--eval-steps", "5"])
    _finite(out)


@pytest.mark.parametrize("backend", BACKENDS)
def test_torchrl_check_env_specs_in_same_step_mode(backend):
    pytest.importorskip("torchrl")
    from torchrl.envs.utils import check_env_specs
    env = _example("torchrl_ppo").make_env(SHAPE, 2, backend, "same_step", 5)
    check_env_specs(env)
    td = env.rollout(12, break_when_any_done=False)            # crosses two episode ends
    assert td.batch_size[:2] == (2, 12)
    assert bool(td["next", "truncated"].any())


# ---------------------------------------------------------------- tianshou
@pytest.mark.parametrize("backend", BACKENDS)
def test_tianshou_ppo_through_the_adapter(backend):
    pytest.importorskip("tianshou")
    out = _example("tianshou_ppo").main(["--env-id", SHAPE, "--num-envs", "4", "--steps", "256",
                                         "--steps-per-collect", "128", "--max-episode-steps", "20",
                                         "--backend", backend, "--eval-steps", "5"])
    assert out["env_steps"] >= 256
    _finite(out)


def test_tianshou_adapter_resets_only_the_given_envs_and_refuses_subsets():
    pytest.importorskip("tianshou")
    from tianshou.env import BaseVectorEnv
    from tensegrity_gym.integrations.tianshou import make_tianshou_env
    envs = make_tianshou_env(SHAPE, num_envs=3, max_episode_steps=2)
    assert isinstance(envs, BaseVectorEnv) and len(envs) == 3
    obs, info = envs.reset()
    assert obs.shape == (3, envs.observation_space[0].shape[0]) and info[2]["env_id"] == 2
    a = np.zeros((3, envs.action_space[0].shape[0]), np.float32)
    envs.step(a)
    *_, trunc, _ = envs.step(a)
    assert trunc.all()
    obs1, _ = envs.reset(env_id=[0, 2])
    assert obs1.shape[0] == 2
    with pytest.raises(gym.error.ResetNeeded):                  # env 1 ended and was not reset
        envs.step(a)
    envs.reset(env_id=[1])
    with pytest.raises(ValueError, match="steps all 3 envs"):
        envs.step(a[:2], id=[0, 1])


# ---------------------------------------------------------------- CleanRL-style example
@pytest.mark.parametrize("backend", ["single", "numpy", "torch"])
def test_cleanrl_ppo_continuous_example(backend):
    out = _example("cleanrl_ppo_continuous").main(
        ["--env-id", SHAPE, "--backend", backend, "--num-envs", "4", "--num-steps", "32",
         "--total-timesteps", "256", "--max-episode-steps", "20", "--eval-steps", "5"])
    assert out["env_steps"] == 256 and out["episodes"] >= 4 and math.isfinite(out["mean_return"])
    _finite(out)


# ---------------------------------------------------------------- SB3 adapter and the autoreset modes
def test_sb3_adapter_refuses_a_same_step_env_and_takes_the_others():
    pytest.importorskip("stable_baselines3")
    from tensegrity_gym.integrations.sb3 import make_sb3_vec_env
    with pytest.raises(ValueError, match="same_step"):
        make_sb3_vec_env(gym.make_vec(SHAPE, num_envs=2, vectorization_mode="vector_entry_point",
                                      autoreset_mode="same_step"))
    for mode in ("next_step", "disabled"):
        v = make_sb3_vec_env(gym.make_vec(SHAPE, num_envs=2, vectorization_mode="vector_entry_point",
                                          autoreset_mode=mode, max_episode_steps=2))
        v.reset()
        for _ in range(3):
            _, _, done, infos = v.step(np.zeros((2, 9), np.float32))
            if done.any():
                assert "terminal_observation" in infos[0]
