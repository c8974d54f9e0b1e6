"""TensegrityNavigate-v0 on the torch device vector env (TorchNavigateVectorEnv).

In float64 on CPU it must reproduce the NumPy/numba vector env (same seeds, same actions): the
same courses drawn per copy at reset, the same goals reached, guidance, rewards (the ``goal``
term included), episodes ended by success, infos and observations. The NumPy env rotates its
float32 state observation into the guidance frame, so its rotated blocks carry that rounding
(about 1e-7 of the node positions, m); the torch env rotates the float64 values.
"""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gymnasium as gym  # noqa: E402

from test_torch_env import _close_info  # noqa: E402

ID = "TensegrityNavigate-v0"
# goals close together and wide: goals are reached (and courses finished) within a few steps
NEAR = dict(goal_distance=(0.3, 0.5), goal_radius=0.45, n_obstacles=3, max_episode_steps=12)

CASES = {
    "near_goals": NEAR,
    "height_scan": dict(NEAR, height_scan=(3, 0.2), goal_bonus=2.5),
    "robot_obs": dict(NEAR, observation_mode="robot"),
}


def _pair(N, **kw):
    mk = dict(num_envs=N, vectorization_mode="vector_entry_point")
    return gym.make_vec(ID, **mk, **kw), gym.make_vec(ID, **mk, backend="torch", device="cpu", dtype="float64", **kw)


def _close_obs(o_np, o_t):
    o_t = o_t.numpy()
    assert o_np.shape == o_t.shape
    err = np.abs(o_np.astype(np.float64) - o_t)
    assert np.all(err <= 6e-8 * np.abs(o_t) + 1e-6), err.max()


@pytest.mark.parametrize("case", sorted(CASES))
def test_navigate_matches_numpy_vector_env(case):
    N, steps = 3, 30
    ref, ten = _pair(N, **CASES[case])
    assert type(ten).__name__ == "TorchNavigateVectorEnv"
    o1, i1 = ref.reset(seed=5)
    o2, i2 = ten.reset(seed=5)
    _close_obs(o1, o2)
    _close_info(i1, i2)
    rng = np.random.default_rng(2)
    reached = success = truncated = 0
    for _ in range(steps):
        a = rng.uniform(-1, 1, (N, ref.single_action_space.shape[0]))
        o1, r1, te1, tr1, i1 = ref.step(a)
        o2, r2, te2, tr2, i2 = ten.step(torch.as_tensor(a))
        _close_obs(o1, o2)
        assert np.abs(r1 - r2.numpy()).max() <= 1e-9
        assert np.array_equal(te1, te2.numpy()) and np.array_equal(tr1, tr2.numpy())
        _close_info(i1, i2)
        reached += int(i1["goal_reached"][i1["_goal_reached"]].sum())
        success += int(te1.sum())
        truncated += int(tr1.sum())
    task = ref.unwrapped.task
    assert np.abs(task.q - ten.q.numpy()).max() <= 1e-9
    np.testing.assert_array_equal(ten.goal_index.numpy(), task.goal_index)
    np.testing.assert_allclose(ten.goal.numpy(), task.goal, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(ten.goals.numpy(), task.goals)
    assert reached >= 3 and success >= 1 and truncated >= 1, (reached, success, truncated)


def test_device_resets_refused_and_numpy_kwargs_kept():
    with pytest.raises(ValueError, match="reset_sampling: 'device' is not available for TensegrityNavigate-v0"):
        gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point", backend="torch", device="cpu",
                     reset_sampling="device")
    with pytest.raises(ValueError, match="device: only with backend='torch'"):
        gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point", device="cpu")
    with pytest.raises(ValueError, match="n_goals"):
        gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point", backend="torch", device="cpu",
                     n_goals=0)
