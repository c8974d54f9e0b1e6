"""TensegrityRoll-v0 cable motor model (``max_cable_acceleration``): acceleration limit, end
stops, observation of the cable speeds, fast path == NumPy, ``None`` == the plain rate model,
argument checks. (``None`` was also checked once, bit for bit, against the commit before the motor
model, ee5f975: prism, icosahedron, vector env, force-density mode and both shape modes.)"""
import warnings

import gymnasium as gym
import numpy as np
import pytest

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.envs.common import Actuation
from tensegrity_gym.envs.roll import MAX_CABLE_ACCELERATION, TensegrityRollEnv, TensegrityRollVectorEnv
from vector_check import step_vector_beside_singles

import oracle_numpy as oracle

ENV_ID = "TensegrityRoll-v0"


def _speed(env):
    return env.unwrapped.task.speed.copy()


def _layout(env):
    return {n: s for n, s, _ in env.unwrapped.task.observation_layout()}


def test_default_limit_and_observation_layout():
    env = TensegrityRollEnv()
    task = env.task
    assert task.max_cable_acceleration == MAX_CABLE_ACCELERATION == 2.0
    n, k, na = task.model.n_nodes, task.model.n_bars, task.action_size
    assert env.observation_space.shape == (6 * n + na + 2 * k + 3 + na,)
    layout = task.observation_layout()
    assert layout[-1][0] == "cable_speed" and layout[-1][2] == "m/s"
    assert layout[-1][1] == slice(6 * n + na + 2 * k + 3, 6 * n + 2 * na + 2 * k + 3)
    assert [b[0] for b in layout[:-1]] == ["node_position_rel_com", "node_velocity", "control", "contact",
                                           "goal_direction", "com_height"]
    obs, _ = env.reset(seed=0)
    sl = _layout(env)
    np.testing.assert_array_equal(obs[sl["cable_speed"]], 0.0)
    np.testing.assert_array_equal(obs[sl["control"]], task.actuation.nominal.astype(np.float32))
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs, *_ = env.step(rng.uniform(-1, 1, na))
        np.testing.assert_array_equal(obs[sl["cable_speed"]], task.speed[0].astype(np.float32))
        np.testing.assert_array_equal(obs[sl["control"]], task.ctrl[0].astype(np.float32))
    # no limit, or force-density mode: the old observation (no cable_speed block)
    for kw in ({"max_cable_acceleration": None}, {"action_mode": "force_density"}):
        e = TensegrityRollEnv(**kw)
        assert e.observation_space.shape == (6 * n + na + 2 * k + 3,)
        assert "cable_speed" not in _layout(e) and not e.task.motor


@pytest.mark.parametrize("pattern", ["random", "bang_bang"])
def test_speed_change_is_limited_per_step(pattern):
    env = TensegrityRollVectorEnv(num_envs=2, max_episode_steps=None)
    task = env.task
    dv = task.max_cable_acceleration * task.control_dt
    vmax = task.max_cable_speed
    env.reset(seed=1)
    rng = np.random.default_rng(3)
    na = task.action_size
    v0 = task.speed.copy()
    hit_stop = False
    n_stops = 0
    seen = 0.0
    for t in range(300):
        if pattern == "random":
            a = rng.uniform(-1.5, 1.5, (2, na))
        else:
            a = np.full((2, na), 1.0 if t % 2 == 0 else -1.0)
            a[1] *= -1.0
        ctrl0 = task.ctrl.copy()
        env.step(a)
        v = task.speed
        # the only larger change: the end stop (cable on a bound, speed set to 0)
        stopped = ((task.ctrl <= task.actuation.low) | (task.ctrl >= task.actuation.high)) & (v == 0.0)
        assert np.all((np.abs(v - v0) <= dv * (1 + 1e-12) + 1e-15) | stopped), t
        n_stops += int((stopped & (np.abs(v - v0) > dv)).sum())
        # the rest length moves by v dt_c (clipped to the bounds; where the end stop fired it sits on one)
        expect = np.clip(ctrl0 + v * task.control_dt, task.actuation.low, task.actuation.high)
        np.testing.assert_array_equal(task.ctrl[~stopped], expect[~stopped])
        assert np.all(np.abs(v) <= vmax * (1 + 1e-12))
        hit_stop |= bool(np.any(task.ctrl <= task.actuation.low) | np.any(task.ctrl >= task.actuation.high))
        seen = max(seen, float(np.abs(v).max()))
        v0 = v.copy()
    if pattern == "bang_bang":
        # alternating +1 / -1 from rest: the speed alternates between 0 and +-amax dt_c (0.04 m/s),
        # so the cable creeps at amax dt_c / 2 (0.02 m/s, a tenth of the top speed) at most
        assert seen <= dv * (1 + 1e-12)
        assert np.abs(task.ctrl - task.actuation.nominal).max() <= 150 * dv * task.control_dt * (1 + 1e-9)
    else:
        assert seen > 0.5 * vmax and hit_stop


@pytest.mark.parametrize("amax", [2.0, 0.5])
def test_constant_action_reaches_max_speed_after_vmax_over_amax(amax):
    env = TensegrityRollEnv(max_cable_acceleration=amax, rest_length_bounds=(0.5, 1.5))
    task = env.task
    env.reset(seed=0)
    vmax, dt = task.max_cable_speed, task.control_dt
    n_ramp = int(round(vmax / amax / dt))     # 5 steps (0.1 s) at 2 m/s^2, 20 steps (0.4 s) at 0.5 m/s^2
    na = task.action_size
    for t in range(1, n_ramp + 3):
        env.step(np.ones(na))
        if t < n_ramp:
            np.testing.assert_allclose(task.speed, t * amax * dt, rtol=1e-12)
            assert np.all(task.speed < vmax)
        else:
            np.testing.assert_allclose(task.speed, vmax, rtol=1e-12)
    # half speed command from full speed: decelerates at amax
    env.step(np.full(na, 0.5))
    np.testing.assert_allclose(task.speed, max(vmax - amax * dt, 0.5 * vmax), rtol=1e-12)


def test_end_stops_zero_the_speed():
    env = TensegrityRollEnv()
    task = env.task
    env.reset(seed=0)
    na = task.action_size
    low, high = task.actuation.low, task.actuation.high
    # shorten every cable at full speed until all sit on their lower bounds (0.5 x nominal)
    for _ in range(200):
        env.step(-np.ones(na))
    np.testing.assert_array_equal(task.ctrl[0], low)
    np.testing.assert_array_equal(task.speed[0], 0.0)
    # reversing starts from rest: the first step lengthens at amax dt only
    env.step(np.ones(na))
    np.testing.assert_allclose(task.speed[0], task.max_cable_acceleration * task.control_dt, rtol=1e-12)
    for _ in range(200):
        env.step(np.ones(na))
    np.testing.assert_array_equal(task.ctrl[0], high)
    np.testing.assert_array_equal(task.speed[0], 0.0)
    # pushing into the stop keeps the speed at 0; pulling away is allowed
    env.step(np.ones(na))
    np.testing.assert_array_equal(task.speed[0], 0.0)
    env.step(-np.ones(na))
    assert np.all(task.speed[0] < 0) and np.all(task.ctrl[0] < high)


def test_reset_zeroes_the_speed_and_vector_autoreset_too():
    env = TensegrityRollVectorEnv(num_envs=2, max_episode_steps=4)
    env.reset(seed=0)
    na = env.task.action_size
    for _ in range(4):
        env.step(np.ones((2, na)))
    assert np.all(env.task.speed > 0)
    obs, *_ = env.step(np.ones((2, na)))     # autoreset step
    np.testing.assert_array_equal(env.task.speed, 0.0)
    np.testing.assert_array_equal(obs[:, _layout(env)["cable_speed"]], 0.0)
    e = TensegrityRollEnv()
    e.reset(seed=0)
    e.step(np.ones(na))
    e.reset(seed=1)
    np.testing.assert_array_equal(e.task.speed, 0.0)


@pytest.mark.parametrize("num_envs", [1, 3])
def test_motor_fast_path_is_bit_identical_to_numpy(num_envs):
    """The env with the compiled motor update, divergence check and observation against the
    same env running their NumPy references (tests/oracle_numpy.py), bit for bit."""
    def make():
        if num_envs == 1:
            return TensegrityRollEnv()
        return TensegrityRollVectorEnv(num_envs=num_envs, max_episode_steps=9)
    fast = make()
    with oracle.reference_paths():
        ref = make()
        o2, _ = ref.reset(seed=2)
    o1, _ = fast.reset(seed=2)
    np.testing.assert_array_equal(o1, o2)
    rng = np.random.default_rng(5)
    for t in range(30):
        a = rng.uniform(-1.3, 1.3, fast.action_space.shape)
        if t % 3 == 0:
            a = np.sign(a)
        r1 = fast.step(a)
        with oracle.reference_paths():
            r2 = ref.step(a)
        for x, y in zip(r1[:4], r2[:4]):
            x, y = np.asarray(x), np.asarray(y)
            assert x.dtype == y.dtype and np.array_equal(x, y), t
        np.testing.assert_array_equal(fast.unwrapped.task.speed, ref.unwrapped.task.speed)


def test_actuation_motor_numpy_and_compiled_agree_at_bounds():
    rng = np.random.default_rng(0)
    na, B = 5, 64
    act = Actuation("rest_length", np.arange(na), 0.5, 1.0, 0.2, 0.02, np.ones(na + 2), 0.75, max_accel=2.0)
    ctrl = rng.uniform(0.5, 1.0, (B, na))
    ctrl[:8] = 0.5
    ctrl[8:16] = 1.0
    speed = rng.uniform(-0.2, 0.2, (B, na))
    action = rng.choice([-1.0, 1.0, 0.3], (B, na))
    new_np, v_np = oracle.actuation_apply_motor(act, ctrl, speed, action)
    new_c, v_c, phys = act.update_motor(ctrl, speed, action)
    np.testing.assert_array_equal(new_np, new_c)
    np.testing.assert_array_equal(v_np, v_c)
    np.testing.assert_array_equal(phys["rest_length"][:, :na], new_c)
    np.testing.assert_array_equal(phys["rest_length"][:, na:], 1.0)
    assert np.all(v_c[new_c <= 0.5] >= 0) and np.all(v_c[new_c >= 1.0] <= 0)
    with pytest.raises(ValueError, match="max_accel"):
        Actuation("rest_length", np.arange(na), 0.5, 1.0, 0.2, 0.02, np.ones(na), 0.75).update_motor(
            ctrl, speed, action)


def test_checkers_pass_with_the_speed_observation():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check
    for structure in ("prism", "icosahedron"):
        env = gym.make(ENV_ID, structure=structure)
        assert env.unwrapped.task.motor
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            check_env(env.unwrapped, skip_render_check=True)
        sb3_check(TensegrityRollEnv(structure=structure), warn=False)


def test_vector_env_equals_single_envs():
    T, N = 10, 3
    rng = np.random.default_rng(2)
    shape = (N,) + TensegrityRollEnv().action_space.shape

    def equal(vr, r):
        assert vr == r

    step_vector_beside_singles(T, N, 11, lambda step: rng.choice([-1.0, 1.0], shape).astype(np.float32),
                               equal, randomize_goal=True)


@pytest.mark.parametrize("bad", [-1.0, 0.0, float("nan"), float("inf"), "fast"])
def test_bad_max_cable_acceleration_raises(bad):
    with pytest.raises(ValueError, match="max_cable_acceleration"):
        TensegrityRollEnv(max_cable_acceleration=bad)
    with pytest.raises(ValueError, match="max_cable_acceleration"):
        gym.make(ENV_ID, max_cable_acceleration=bad)


def test_no_limit_is_the_old_rate_model():
    """``None``: the rest length moves by a * max_cable_speed * dt_c at once (no speed state)."""
    env = TensegrityRollEnv(max_cable_acceleration=None)
    task = env.task
    env.reset(seed=0)
    assert task.speed.shape == (1, 0)
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = rng.choice([-1.0, 1.0], task.action_size)
        c0 = task.ctrl.copy()
        env.step(a)
        np.testing.assert_array_equal(task.ctrl, np.clip(c0 + a * (task.max_cable_speed * task.control_dt),
                                                         task.actuation.low, task.actuation.high))
