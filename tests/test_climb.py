"""TensegrityClimb-v0: the rolling task on a slope, simulated in the plane frame (tilted gravity)."""
import gymnasium as gym
import numpy as np
import pytest

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.tasks.climb import plane_gravity

VEC = dict(vectorization_mode="vector_entry_point")


def _rollout(env, steps, seed=0, action_seed=1):
    o, _ = env.reset(seed=seed)
    rng = np.random.default_rng(action_seed)
    obs, rew, infos = [o], [], []
    for _ in range(steps):
        o, r, te, tr, info = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        obs.append(o)
        rew.append(r)
        infos.append(info)
    return np.array(obs), np.array(rew), infos


def test_level_slope_is_the_rolling_task_bit_for_bit():
    roll = gym.make_vec("TensegrityRoll-v0", num_envs=3, **VEC)
    climb = gym.make_vec("TensegrityClimb-v0", num_envs=3, slope_deg=0.0, **VEC)
    o_r, r_r, _ = _rollout(roll, 30)
    o_c, r_c, info = _rollout(climb, 30)
    np.testing.assert_array_equal(o_c[..., :-3], o_r)
    np.testing.assert_array_equal(o_c[..., -3:], np.broadcast_to(np.float32([0, 0, -1]), o_c[..., -3:].shape))
    np.testing.assert_array_equal(r_c, r_r)
    np.testing.assert_array_equal(info[-1]["uphill_velocity"], info[-1]["forward_velocity"])


def test_gravity_is_tilted_in_the_plane_frame():
    g = plane_gravity(np.array([0.0, 30.0]), 9.81)
    np.testing.assert_allclose(g, [[0, 0, -9.81], [-9.81 / 2, 0, -9.81 * np.sqrt(3) / 2]], atol=1e-12)
    env = gym.make("TensegrityClimb-v0", slope_deg=30.0)
    np.testing.assert_allclose(env.unwrapped.task.model.gravity, g[1], atol=1e-12)


def _passive_slide(friction, slope=20.0, seconds=1.0):
    env = gym.make("TensegrityClimb-v0", slope_deg=slope, friction=friction, reset_noise_scale=0.0,
                   max_episode_steps=None)
    env.reset(seed=0)
    hold = np.zeros(env.action_space.shape, np.float32)      # no cable motion
    steps = int(round(seconds / env.unwrapped.task.control_dt))
    xs = []
    for _ in range(steps):
        _, _, _, _, info = env.step(hold)
        xs.append(info["distance_rolled"])
    return np.array(xs)


def test_friction_holds_the_robot_on_a_slope_below_the_friction_angle():
    x = _passive_slide(friction=1.0)          # tan 20 deg = 0.36 < 1: static friction holds it
    assert np.abs(x).max() < 2e-3


def test_a_slippery_slope_slides_at_g_sin_minus_mu_cos():
    mu, a = 0.2, np.radians(20.0)
    x = _passive_slide(friction=mu, seconds=0.6)
    expected = 9.81 * (np.sin(a) - mu * np.cos(a))          # 1.51 m/s^2 down the slope (a block sliding)
    t = 0.02 * np.arange(1, x.size + 1)
    acc = -2.0 * np.polyfit(t[10:], x[10:], 2)[0]          # fitted x = x0 + v0 t - a t^2 / 2
    assert acc == pytest.approx(expected, rel=0.1)


def test_slope_range_draws_a_slope_per_copy_and_reset_from_the_seed():
    env = gym.make_vec("TensegrityClimb-v0", num_envs=6, slope_range=(5.0, 26.0), **VEC)
    _, info = env.reset(seed=3)
    s1 = info["slope_deg"]
    assert np.all((s1 >= 5) & (s1 <= 26)) and np.unique(s1).size == 6
    task = env.unwrapped.task if hasattr(env, "unwrapped") else env.task
    np.testing.assert_allclose(task.params.gravity, plane_gravity(s1, 9.81), atol=1e-12)
    _, info2 = env.reset(seed=3)
    np.testing.assert_array_equal(info2["slope_deg"], s1)
    single = gym.make("TensegrityClimb-v0", slope_range=(5.0, 26.0))
    _, info3 = single.reset(seed=5)          # env 2 of the vector env seeded 3 is seeded 5
    assert info3["slope_deg"] == s1[2]


def test_torch_env_equals_the_numpy_env():
    torch = pytest.importorskip("torch")
    kw = dict(num_envs=3, slope_range=(0.0, 30.0), **VEC)
    v = gym.make_vec("TensegrityClimb-v0", **kw)
    tv = gym.make_vec("TensegrityClimb-v0", backend="torch", device="cpu", dtype="float64", **kw)
    o, i = v.reset(seed=1)
    o2, i2 = tv.reset(seed=1)
    np.testing.assert_allclose(i2["slope_deg"].numpy(), i["slope_deg"])
    rng = np.random.default_rng(0)
    for _ in range(40):
        a = rng.uniform(-1, 1, (3, v.single_action_space.shape[0]))
        o, r, _, _, info = v.step(a)
        o2, r2, _, _, info2 = tv.step(torch.as_tensor(a))
    np.testing.assert_allclose(o2.numpy(), o, rtol=1e-5, atol=1e-6)        # the NumPy obs is float32
    np.testing.assert_allclose(r2.numpy(), r, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(info2["uphill_velocity"].numpy(), info["uphill_velocity"], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("kw, match", [
    (dict(slope_deg=-1.0), "slope_deg"), (dict(slope_deg=75.0), "slope_deg"), (dict(slope_deg="steep"), "slope_deg"),
    (dict(slope_deg=float("nan")), "slope_deg"), (dict(slope_range=(30.0, 10.0)), "slope_range"),
    (dict(slope_range=(0.0, 99.0)), r"slope_range\[1\]"), (dict(slope_range=5.0), "slope_range"),
    (dict(randomize_goal=True), "randomize_goal"), (dict(goal_direction=(0.0, 1.0)), "goal_direction"),
    (dict(params={"gravity": [0, 0, -3.7]}), "gravity"), (dict(randomize={"gravity": 0.1}), "gravity"),
])
def test_bad_slope_arguments_are_named(kw, match):
    with pytest.raises(ValueError, match=match):
        gym.make("TensegrityClimb-v0", **kw)
