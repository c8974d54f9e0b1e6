"""TensegrityRoll-v0: API checks, determinism, stability under extreme actions, vector == single,
make_vec, the open-loop gait, reward bookkeeping, divergence handling."""
import warnings

import gymnasium as gym
import numpy as np
import pytest

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.tools.baselines import RollingGait
from tensegrity_gym.envs.roll import TensegrityRollEnv, TensegrityRollVectorEnv
from vector_check import step_vector_beside_singles

ENV_ID = "TensegrityRoll-v0"
COMBOS = [("prism", "rest_length"), ("prism", "force_density"), ("icosahedron", "rest_length"),
          ("icosahedron", "force_density")]


@pytest.mark.parametrize("structure,mode", COMBOS)
def test_gymnasium_and_sb3_check_env(structure, mode):
    from gymnasium.utils.env_checker import check_env
    env = gym.make(ENV_ID, structure=structure, action_mode=mode)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env.unwrapped, skip_render_check=True)
    from stable_baselines3.common.env_checker import check_env as sb3_check
    sb3_check(TensegrityRollEnv(structure=structure, action_mode=mode), warn=False)
    n = env.unwrapped.task.model.n_nodes
    k = env.unwrapped.task.model.n_bars
    na = env.action_space.shape[0]
    ns = na if mode == "rest_length" else 0    # cable speeds (motor model, on by default in rest-length mode)
    assert env.observation_space.shape == (6 * n + na + 2 * k + 3 + ns,)


def test_determinism_per_seed():
    def rollout(seed):
        env = gym.make(ENV_ID)
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        out = [obs]
        for _ in range(40):
            obs, r, *_ = env.step(env.action_space.sample())
            out.append(obs)
        return np.array(out)
    a, b, c = rollout(3), rollout(3), rollout(4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("structure,mode", [("prism", "rest_length"), ("icosahedron", "rest_length"),
                                            ("prism", "force_density")])
def test_finite_under_random_and_extreme_actions(structure, mode):
    env = TensegrityRollVectorEnv(num_envs=3, structure=structure, action_mode=mode, max_episode_steps=None)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    na = env.single_action_space.shape[0]
    for i in range(600):
        a = np.stack([np.ones(na), -np.ones(na), rng.uniform(-1, 1, na)])
        if i % 100 >= 50:
            a[2] = rng.choice([-1.0, 1.0], na)       # bang-bang
        obs, r, term, trunc, info = env.step(a)
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(r))
        assert not info["diverged"].any()
    com = info["com_position"]
    assert np.all(np.abs(com[:, :2]) < 20.0) and np.all(com[:, 2] > 0.0)


def test_vector_env_equals_single_envs_with_autoreset():
    T, N = 12, 3
    rng = np.random.default_rng(1)
    shape = (N,) + TensegrityRollEnv().action_space.shape

    def close(vr, r):
        assert vr == pytest.approx(r, abs=0, rel=1e-12)

    n_trunc = step_vector_beside_singles(T, N, 7, lambda step: rng.uniform(-1, 1, shape).astype(np.float32),
                                         close, randomize_goal=True)
    assert n_trunc == 2 * N   # every env crossed two episode boundaries (truncation at T, autoreset)


def test_make_vec_vector_entry_point_and_registered_time_limit():
    venv = gym.make_vec(ENV_ID, num_envs=4, vectorization_mode="vector_entry_point")
    assert isinstance(venv.unwrapped, TensegrityRollVectorEnv)
    assert venv.unwrapped.max_episode_steps == gym.spec(ENV_ID).max_episode_steps
    assert venv.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    obs, _ = venv.reset(seed=0)
    assert obs.shape == (4,) + venv.single_observation_space.shape
    venv.unwrapped.max_episode_steps = 5
    for i in range(5):
        obs, r, term, trunc, info = venv.step(venv.action_space.sample())
    assert trunc.all() and not term.any()
    obs, r, term, trunc, info = venv.step(venv.action_space.sample())   # autoreset step
    assert not trunc.any() and np.all(r == 0)
    assert np.allclose(info["distance_rolled"], 0.0)


def test_reward_is_sum_of_terms_and_info():
    env = gym.make(ENV_ID, ctrl_cost_weight=0.1, forward_reward_weight=2.0)
    env.reset(seed=0)
    for _ in range(20):
        obs, r, term, trunc, info = env.step(env.action_space.sample())
        terms = {k: v for k, v in info.items() if k.startswith("reward_")}
        assert set(terms) == {"reward_forward", "reward_ctrl"}
        assert r == pytest.approx(sum(terms.values()), abs=1e-12)
        assert info["reward_forward"] == pytest.approx(2.0 * info["forward_velocity"])
        assert info["com_position"].shape == (3,) and info["com_velocity"].shape == (3,)
        assert np.isfinite(info["distance_rolled"])
        assert not term


def test_nan_action_names_index_and_bad_args():
    env = gym.make(ENV_ID)
    env.reset(seed=0)
    a = np.zeros(env.action_space.shape)
    a[4] = np.nan
    with pytest.raises(ValueError, match="4"):
        env.step(a)
    with pytest.raises(ValueError, match="action_mode"):
        TensegrityRollEnv(action_mode="torque")
    with pytest.raises(ValueError, match="goal_direction"):
        TensegrityRollEnv(goal_direction=(0.0, 0.0))
    with pytest.raises(ValueError, match="friction"):
        TensegrityRollEnv(friction=-1.0)


def test_goal_randomised_and_observed():
    env = TensegrityRollEnv(randomize_goal=True)
    sl = {n: s for n, s, _ in env.task.observation_layout()}["goal_direction"]
    goals = []
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        g = obs[sl]
        assert np.linalg.norm(g) == pytest.approx(1.0, abs=1e-6)
        np.testing.assert_allclose(g, info["goal_direction"], atol=1e-6)
        goals.append(g)
    assert np.ptp(np.array(goals), axis=0).max() > 0.1
    env0 = TensegrityRollEnv()
    obs, _ = env0.reset(seed=0)
    np.testing.assert_allclose(obs[sl], [1.0, 0.0])


def test_divergence_truncates_with_finite_observation():
    env = TensegrityRollEnv()
    obs, _ = env.reset(seed=0)
    env.task.qd[0, 0, :3] = 1e7    # a kick that sends a rod far beyond the divergence limit
    obs, r, term, trunc, info = env.step(np.zeros(env.action_space.shape))
    assert info["diverged"] and trunc and not term
    assert np.all(np.isfinite(obs)) and np.isfinite(r)


def test_travelling_far_is_not_divergence():
    """The divergence check measures a rod from the robot's own centre: a robot that has rolled
    1 km (here: moved there) keeps going; one torn apart there is still caught. The compiled
    check and its NumPy reference agree on both."""
    env = TensegrityRollEnv()
    env.reset(seed=0)
    task = env.task
    limit = task.divergence_limit
    task.q[0, :, 0] += 10.0 * limit + 1000.0     # every rod, and the contact anchors with them
    task.cstate.anchor[..., 0] += 10.0 * limit + 1000.0
    for _ in range(5):
        obs, r, term, trunc, info = env.step(np.zeros(env.action_space.shape))
        assert not info["diverged"] and not trunc
    assert info["com_position"][0] > 1000.0 and np.all(np.isfinite(obs))
    from tensegrity_gym.backends.numba.divergence import state_ok_local
    from tensegrity_gym.physics.pipeline import diverged
    import oracle_numpy as oracle

    def reference(q, qd):      # the NumPy reference of pipeline.diverged
        return oracle.diverged(q, qd, task.center0, limit, local=True)
    assert task.travels
    assert not reference(task.q, task.qd).any()
    torn = task.q.copy()
    torn[0, 0, 1] += 2.0 * limit
    assert reference(torn, task.qd).all()
    lifted = task.q.copy()
    lifted[0, :, 2] += 2.0 * limit
    assert reference(lifted, task.qd).all()
    z = task.center0[2]
    assert state_ok_local(task.q, task.qd, z, limit)
    assert not state_ok_local(torn, task.qd, z, limit)
    assert not state_ok_local(lifted, task.qd, z, limit)
    assert diverged(torn, task.qd, task.center0, limit, local=True).all()
    assert not diverged(task.q, task.qd, task.center0, limit, local=True).any()


def test_gait_rolls_the_prism_forward_more_than_a_body_length():
    """The baseline gait's test window is 40 s: from the reset pose the wave first rolls the
    prism toward -x and the heading feedback turns it round in its first ~15-20 s (see
    ``results/roll_baseline.json``, ``distance_every_10s_m``); by 40 s it is well ahead."""
    env = gym.make(ENV_ID, max_episode_steps=2000)
    gait = RollingGait(env)
    obs, _ = env.reset(seed=0)
    state = None
    T = 40.0
    for _ in range(int(T / env.unwrapped.dt)):
        a, state = gait.predict(obs, state)
        obs, r, term, trunc, info = env.step(a)
        assert not info["diverged"]
    L = env.unwrapped.task.body_length
    assert info["distance_rolled"] > L, (info["distance_rolled"], L)


def test_gait_predict_state_batches_and_resets():
    """RollingGait.predict: a batch of observations gives the rows' single-observation actions;
    the state is (B, 3) (step counter, filtered velocity) and episode_start zeroes its rows."""
    venv = TensegrityRollVectorEnv(num_envs=3, max_episode_steps=None)
    gait = RollingGait(venv)
    obs, _ = venv.reset(seed=4)
    state = None
    for _ in range(30):
        a, state = gait.predict(obs, state)
        obs, *_ = venv.step(a)
    assert state.shape == (3, 3) and np.all(state[:, 0] == 30) and np.all(np.abs(state[:, 1:]) > 0)
    a_batch, s_batch = gait.predict(obs, state, episode_start=np.array([False, True, False]))
    assert np.all(s_batch[1] == [1.0, *s_batch[1, 1:]]) and s_batch[0, 0] == 31
    for b in range(3):
        st = state[b:b + 1].copy()
        if b == 1:
            st[:] = 0.0
        a1, s1 = gait.predict(obs[b], st)
        np.testing.assert_array_equal(a1, a_batch[b])
        np.testing.assert_allclose(s1.reshape(-1), s_batch[b])
    with pytest.raises(ValueError, match="steer_angle"):
        RollingGait(venv, steer_angle=0.0)
    with pytest.raises(ValueError, match="bias"):
        RollingGait(venv, bias=float("nan"))


def test_gait_heading_feedback_follows_a_random_goal():
    """With ``randomize_goal`` the gait reads the goal from the observation and rolls toward it:
    4 random goals, 40 s, each ends more than a body length along its goal."""
    venv = TensegrityRollVectorEnv(num_envs=4, max_episode_steps=None, randomize_goal=True)
    gait = RollingGait(venv)
    obs, _ = venv.reset(seed=11)
    goals = venv.task.goal.copy()
    assert np.ptp(goals[:, 0]) > 0.1
    state = None
    for _ in range(2000):
        a, state = gait.predict(obs, state)
        obs, r, term, trunc, info = venv.step(a)
    assert np.all(info["distance_rolled"] > venv.task.body_length), info["distance_rolled"]


def test_render_rgb_array_has_ground_and_path():
    env = gym.make(ENV_ID, render_mode="rgb_array", width=160, height=160)
    env.reset(seed=0)
    for _ in range(3):
        env.step(env.action_space.sample())
    frame = env.render()
    assert frame.shape == (160, 160, 3) and frame.dtype == np.uint8
    assert len(env.unwrapped.task.paths[0]) == 4
    env.close()


def test_sb3_adapter_on_the_batched_vector_env():
    from tensegrity_gym.envs.common import make_sb3_vec_env
    venv = make_sb3_vec_env(TensegrityRollVectorEnv(num_envs=2, max_episode_steps=3))
    obs = venv.reset()
    assert obs.shape == (2,) + venv.observation_space.shape
    for i in range(3):
        obs, rew, done, infos = venv.step(np.zeros((2,) + venv.action_space.shape, np.float32))
    assert done.all() and all(info["TimeLimit.truncated"] for info in infos)
    assert all("terminal_observation" in info for info in infos)
    assert np.all(np.isfinite(obs))


def test_python_contact_loop_matches_the_fast_path(monkeypatch):
    """The generic path (a Python loop of contact forces and one physics.step per physics
    step, NumPy bookkeeping) and the default compiled path give the same trajectory to
    round-off. (The NumPy oracle of the contact step: tests/test_contact.py.)"""
    from tensegrity_gym.physics import pipeline   # where the compiled contact call is looked up
    acts = np.random.default_rng(0).uniform(-1, 1, (25, 9))
    calls = []
    real = pipeline._contact_compiled
    monkeypatch.setattr(pipeline, "_contact_compiled", lambda *a: calls.append(1) or real(*a))
    fast = TensegrityRollEnv()
    fast.reset(seed=3)
    for act in acts:
        fast.step(act)
    assert calls or fast.task._kernels_run     # the compiled path ran
    import oracle_numpy as oracle
    monkeypatch.setattr(pipeline, "_contact_compiled", lambda *a: False)   # the Python contact loop
    with oracle.reference_paths():                             # NumPy bookkeeping
        slow = TensegrityRollEnv()
        slow.task._kernels_run = False                         # physics.step per physics step
        slow.reset(seed=3)
        for act in acts:
            slow.step(act)
    assert slow.task.cstate.active.any()
    np.testing.assert_allclose(slow.task.q, fast.task.q, rtol=0, atol=1e-10)
    np.testing.assert_allclose(slow.task.qd, fast.task.qd, rtol=0, atol=1e-8)
    np.testing.assert_array_equal(slow.task.cstate.active, fast.task.cstate.active)


def test_step_above_the_contact_stability_limit_warns():
    from tensegrity_gym.core.errors import StabilityWarning
    with pytest.warns(StabilityWarning, match="stability limit"):
        TensegrityRollEnv(dt=2.8e-3, frame_skip=7, allow_unstable_dt=True)


@pytest.mark.parametrize("structure", ["prism", "icosahedron"])
def test_robot_at_rest_stays_put_with_zero_action(structure):
    env = TensegrityRollEnv(structure=structure, reset_noise_scale=0.0)
    env.reset(seed=0)
    for _ in range(250):     # 5 s
        obs, r, term, trunc, info = env.step(np.zeros(env.action_space.shape))
    assert np.linalg.norm(info["com_position"][:2] - env.task.start[0, :2]) < 1e-3
    assert abs(info["com_velocity"]).max() < 1e-3
