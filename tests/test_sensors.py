"""Robot observation mode (tensegrity_gym.envs.sensors): IMU readings in known motions, the
env's robot observation, sensor noise and history."""
import numpy as np
import gymnasium as gym
import pytest

import tensegrity_gym as tg
from tensegrity_gym.physics.geometry import string_state
from tensegrity_gym.envs.sensors import RobotSensors, rod_frames

G = np.array([0.0, 0.0, -9.81])


def _reading(sensors, name, frame):
    return frame[:, dict((n, s) for n, s, _ in sensors.layout())[name]]


def _sensors(model):
    return RobotSensors(model, 0, 0, 2 * model.n_bars)


def _frame(sens, model, q, qd, qd_prev, dt):
    r = q.shape[0]
    return sens.frame(q, qd, qd_prev, dt, G, np.zeros((r, 0)), np.zeros((r, 0)), np.zeros((r, 2 * model.n_bars), bool),
                      np.zeros((r, 2)), None)


def test_rod_frames_are_orthonormal_with_z_along_the_rod_and_no_roll():
    rng = np.random.default_rng(0)
    b = rng.standard_normal((5, 7, 3))
    b /= np.linalg.norm(b, axis=-1, keepdims=True)
    b[0, 0] = (0.0, 0.0, 1.0)                       # vertical rod: x from the world x axis
    R = rod_frames(b)
    np.testing.assert_allclose(np.einsum("bkij,bklj->bkil", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(R[..., 2, :], b)
    assert np.all((np.abs(R[..., 1, 2]) < 1e-12) | (np.abs(b[..., 2]) > 1 - 1e-9))   # y horizontal
    np.testing.assert_allclose(R[0, 0, 0], (1.0, 0.0, 0.0))


def test_imu_in_free_fall_reads_zero_and_at_rest_reads_minus_g():
    # a prestressed prism in equilibrium released under gravity, no ground: every rod falls at g
    model = tg.compile_model(tg.prism(3, prestress=100.0).replace(gravity=G))
    sens = _sensors(model)
    st = tg.initial_state(model, 1)
    out = tg.step(model, st, 1e-3, "semi_implicit_euler")
    acc = _reading(sens, "imu_accel", _frame(sens, model, out.q, out.qd, st.qd, 1e-3))
    assert np.abs(acc).max() < 1e-9
    # at rest (no velocity change): the specific force -g, magnitude 9.81, in each rod's frame
    acc = _reading(sens, "imu_accel", _frame(sens, model, st.q, st.qd, st.qd, 1e-3)).reshape(1, -1, 3)
    np.testing.assert_allclose(np.linalg.norm(acc, axis=-1), 9.81)
    b = st.q[..., 3:]
    np.testing.assert_allclose(acc[..., 2], 9.81 * b[..., 2])               # along the rod: up . b
    np.testing.assert_allclose(acc[..., 1], 0.0, atol=1e-12)                # y is horizontal
    assert np.all(acc[..., 0] >= 0)                                         # x points up the slope


def test_gyro_reads_a_known_spin_rate():
    model = tg.compile_model(tg.prism(3, prestress=100.0))
    sens = _sensors(model)
    st = tg.initial_state(model, 1)
    b = st.q[0, :, 3:]
    w = np.cross(b, [0.3, -0.2, 0.5])                 # an angular velocity perpendicular to each rod
    w = 2.5 * w / np.linalg.norm(w, axis=-1, keepdims=True)    # 2.5 rad/s
    qd = st.qd.copy()
    qd[0, :, 3:] = np.cross(w, b)                       # b' = w x b
    gyro = _reading(sens, "imu_gyro", _frame(sens, model, st.q, qd, qd, 1e-3)).reshape(-1, 3)
    R = rod_frames(st.q[..., 3:])[0]
    np.testing.assert_allclose(gyro, np.einsum("kij,kj->ki", R, w), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(gyro, axis=-1), 2.5)
    np.testing.assert_allclose(gyro[:, 2], 0.0, atol=1e-12)


def test_roll_env_robot_observation_noise_and_history():
    env = gym.make("TensegrityRoll-v0", observation_mode="robot", history=3)
    task = env.unwrapped.task
    F = task.sensors.frame_size
    k, m, na = task.model.n_bars, task.model.n_strings, task.actuated.size
    assert F == m + na + na + 3 * k + 3 * k + 2 * k + 2 == env.observation_space.shape[0] // 3
    names = [n for n, _, _ in task.observation_layout()]
    assert names == ["cable_length", "control", "cable_speed", "imu_accel", "imu_gyro", "contact", "goal_direction"]
    obs, _ = env.reset(seed=1)
    assert np.array_equal(obs[:F], obs[F:2 * F]) and np.array_equal(obs[:F], obs[2 * F:])
    lay = dict((n, s) for n, s, _ in task.observation_layout())
    acc = obs[lay["imu_accel"]].reshape(k, 3)
    np.testing.assert_allclose(np.linalg.norm(acc, axis=1), 9.81, rtol=1e-6)      # at rest: -g
    np.testing.assert_allclose(obs[lay["cable_length"]], string_state(task.model, task.q)[1][0], rtol=1e-6)
    prev = obs
    obs, *_ = env.step(np.ones(na))
    assert np.array_equal(obs[F:2 * F], prev[:F]) and np.array_equal(obs[2 * F:], prev[F:2 * F])
    # noise: seeded, Gaussian around the clean reading, vector env == single envs
    noisy = dict(observation_mode="robot", sensor_noise={"imu_accel": 0.05, "cable_length": 1e-3})
    a = gym.make("TensegrityRoll-v0", **noisy)
    b = gym.make("TensegrityRoll-v0", **noisy)
    clean = gym.make("TensegrityRoll-v0", observation_mode="robot")
    oa, _ = a.reset(seed=4)
    ob, _ = b.reset(seed=4)
    oc, _ = clean.reset(seed=4)
    assert np.array_equal(oa, ob) and not np.array_equal(oa, oc)
    d = (oa - oc)[lay["imu_accel"]]
    assert 0.01 < d.std() < 0.1
    venv = gym.make_vec("TensegrityRoll-v0", num_envs=2, vectorization_mode="vector_entry_point", **noisy)
    ov, _ = venv.reset(seed=4)
    assert np.array_equal(ov[0], oa)
    for _ in range(5):
        act = np.full(na, 0.5)
        ov, *_ = venv.step(np.stack([act, act]))
        oa, *_ = a.step(act)
    assert np.array_equal(ov[0], oa)


def test_contact_switch_noise_flips_readings():
    """sensor_noise={"contact": p}: each switch reads wrong with probability p; nothing else changes
    (the physics and the other blocks equal the noiseless env's for the same seed and actions)."""
    kw = dict(observation_mode="robot", num_envs=32, vectorization_mode="vector_entry_point")
    clean = gym.make_vec("TensegrityRoll-v0", **kw)
    noisy = gym.make_vec("TensegrityRoll-v0", sensor_noise={"contact": 0.25}, **kw)
    sl = dict((n, s) for n, s, _ in clean.task.sensors.layout())["contact"]
    clean.reset(seed=3)
    noisy.reset(seed=3)
    wrong, total = 0, 0
    for _ in range(6):
        a = np.full((32, clean.single_action_space.shape[0]), 0.4)
        oc, *_ = clean.step(a)
        on, *_ = noisy.step(a)
        d = on[:, :clean.task.sensors.frame_size] - oc[:, :clean.task.sensors.frame_size]
        rest = np.ones(d.shape[1], bool)
        rest[sl] = False
        assert np.abs(d[:, rest]).max() == 0.0
        assert set(np.unique(np.abs(d[:, sl]))) <= {0.0, 1.0}
        wrong += int(np.abs(d[:, sl]).sum())
        total += d[:, sl].size
    p = wrong / total                                         # 1152 readings: 4 standard errors ~ 0.05
    assert abs(p - 0.25) < 0.05, p
    assert np.array_equal(clean.task.q, noisy.task.q)


@pytest.mark.parametrize("kw,match", [
    ({"observation_mode": "camera"}, "observation_mode: unknown 'camera'"),
    ({"observation_mode": "robot", "sensor_noise": {"contact": 1.5}}, r"sensor_noise\['contact'\]: the probability"),
    ({"observation_mode": "robot", "sensor_noise": {"goal_direction": 0.1}}, "unknown or noiseless block 'goal_direction'"),
    ({"observation_mode": "robot", "sensor_noise": {"imu_gyro": -1}}, r"sensor_noise\['imu_gyro'\]: must be"),
    ({"observation_mode": "robot", "history": 0}, "history: must be a positive integer"),
    ({"sensor_noise": {"imu_gyro": 0.1}}, "only with observation_mode='robot'"),
])
def test_bad_sensor_arguments(kw, match):
    with pytest.raises(ValueError, match=match):
        gym.make("TensegrityRoll-v0", **kw)


# ---------------------------------------------------------------------- TensegrityShape-v0 (same sensor code)
def _shape_rollout(env, seed=2, steps=12):
    rng = np.random.default_rng(0)
    obs, info = env.reset(seed=seed)
    out = [(obs, None, info)]
    for _ in range(steps):
        o, r, term, trunc, inf = env.step(rng.uniform(-1, 1, env.action_space.shape))
        out.append((o, r, inf))
    return out


@pytest.mark.parametrize("action_mode,unit", [("rest_length", "m"), ("force_density", "N/m")])
def test_shape_env_robot_observation_layout_and_readings(action_mode, unit):
    env = gym.make("TensegrityShape-v0", observation_mode="robot", history=2, action_mode=action_mode)
    task = env.unwrapped.task
    k, m, na, nt = task.model.n_bars, task.model.n_strings, task.actuated.size, task.tracked.size
    lay = {n: (s, u) for n, s, u in task.observation_layout()}
    assert list(lay) == ["cable_length", "control", "imu_accel", "imu_gyro", "target_position"]
    assert lay["control"][1] == unit and lay["target_position"][1] == "m"
    F = task.sensors.frame_size
    assert F == m + na + 6 * k + 3 * nt == 51 and env.observation_space.shape == (2 * F,)
    obs, _ = env.reset(seed=1)
    assert np.array_equal(obs[:F], obs[F:])                                          # history filled at reset
    acc = obs[lay["imu_accel"][0]].reshape(k, 3)
    np.testing.assert_allclose(np.linalg.norm(acc, axis=1), 9.81, rtol=1e-6)        # reset reading: -g
    prev = obs
    obs, *_ = env.step(np.full(na, 0.5))
    assert np.array_equal(obs[F:], prev[:F])                                          # newest first
    np.testing.assert_allclose(obs[lay["cable_length"][0]], string_state(task.model, task.q)[1][0], rtol=1e-6)
    np.testing.assert_allclose(obs[lay["control"][0]], task.ctrl[0], rtol=1e-6)
    np.testing.assert_allclose(obs[lay["target_position"][0]], task.target[0].ravel(), rtol=1e-6)
    assert env.observation_space.contains(obs)


def test_shape_env_imu_reads_the_last_physics_step():
    """frame_skip = 1: the accelerometer is (v(t) - v(t - dt)) / dt - g and the gyroscope b x b',
    in each rod's frame, from the task's own state before and after the step."""
    env = gym.make("TensegrityShape-v0", observation_mode="robot", frame_skip=1)
    task = env.unwrapped.task
    lay = {n: s for n, s, _ in task.observation_layout()}
    env.reset(seed=0)
    for _ in range(3):
        qd0 = task.qd.copy()
        obs, *_ = env.step(np.full(9, -1.0))
    acc = (task.qd[0, :, :3] - qd0[0, :, :3]) / task.dt + task.model.com_eta[:, None] * (
        task.qd[0, :, 3:] - qd0[0, :, 3:]) / task.dt - np.asarray(task.model.gravity)
    R = rod_frames(task.q[:, :, 3:])[0]
    np.testing.assert_allclose(obs[lay["imu_accel"]].reshape(-1, 3), np.einsum("kij,kj->ki", R, acc), rtol=1e-5, atol=1e-4)
    w = np.cross(task.q[0, :, 3:], task.qd[0, :, 3:])
    np.testing.assert_allclose(obs[lay["imu_gyro"]].reshape(-1, 3), np.einsum("kij,kj->ki", R, w), rtol=1e-5, atol=1e-6)
    assert np.abs(obs[lay["imu_accel"]].reshape(-1, 3) - np.einsum("kij,j->ki", R, -np.asarray(task.model.gravity))).max() > 0.1


def test_shape_env_at_rest_reads_minus_g_and_no_rotation():
    env = gym.make("TensegrityShape-v0", observation_mode="robot", reset_noise_scale=0.0)
    task = env.unwrapped.task
    lay = {n: s for n, s, _ in task.observation_layout()}
    env.reset(seed=0)
    for _ in range(5):
        obs, *_ = env.step(np.zeros(9))             # nominal controls at the nominal equilibrium
    acc = obs[lay["imu_accel"]].reshape(-1, 3)
    np.testing.assert_allclose(np.linalg.norm(acc, axis=1), 9.81, rtol=1e-4)
    np.testing.assert_allclose(acc[:, 2], 9.81 * task.q[0, :, 5], rtol=1e-4, atol=1e-4)   # along the rod: up . b
    assert np.abs(obs[lay["imu_gyro"]]).max() < 1e-4


def test_shape_env_robot_mode_same_physics_rewards_infos_as_state_mode():
    rob = gym.make("TensegrityShape-v0", observation_mode="robot")
    sta = gym.make("TensegrityShape-v0")
    default = gym.make("TensegrityShape-v0", observation_mode="state")
    a, b, c = _shape_rollout(rob), _shape_rollout(sta), _shape_rollout(default)
    np.testing.assert_array_equal(rob.unwrapped.task.q, sta.unwrapped.task.q)
    for (_, ra, ia), (ob, rb, ib), (oc, _, _) in zip(a, b, c):
        assert ra == rb
        assert np.array_equal(ob, oc)
        for key in ("tracking_error", "max_node_error", "is_success"):
            assert ia[key] == ib[key]
    assert sta.unwrapped.task.sensors is None and sta.observation_space.shape == (69,)


def test_shape_env_sensor_noise_seeded_and_vector_equals_single():
    noisy = dict(observation_mode="robot", sensor_noise={"imu_gyro": 0.02, "cable_length": 1e-3}, history=2)
    a, b = gym.make("TensegrityShape-v0", **noisy), gym.make("TensegrityShape-v0", **noisy)
    clean = gym.make("TensegrityShape-v0", observation_mode="robot", history=2)
    lay = {n: s for n, s, _ in a.unwrapped.task.observation_layout()}
    oa, ob, oc = a.reset(seed=4)[0], b.reset(seed=4)[0], clean.reset(seed=4)[0]
    assert np.array_equal(oa, ob) and not np.array_equal(oa, oc)
    d = (oa - oc)[lay["cable_length"]]
    assert 2e-4 < d.std() < 5e-3
    assert np.array_equal(oa[lay["target_position"]], oc[lay["target_position"]])   # the command is not noisy
    venv = gym.make_vec("TensegrityShape-v0", num_envs=2, vectorization_mode="vector_entry_point", **noisy)
    ov, _ = venv.reset(seed=4)
    assert np.array_equal(ov[0], oa)
    env1 = gym.make("TensegrityShape-v0", **noisy)
    o1, _ = env1.reset(seed=5)
    assert np.array_equal(ov[1], o1)
    rng = np.random.default_rng(3)
    for _ in range(4):
        acts = rng.uniform(-1, 1, (2, 9))
        ov, rv, *_ = venv.step(acts)
        oa, ra, *_ = a.step(acts[0])
        o1, *_ = env1.step(acts[1])
    assert np.array_equal(ov[0], oa) and np.array_equal(ov[1], o1) and rv[0] == ra


@pytest.mark.parametrize("kw,match", [
    ({"observation_mode": "camera"}, "observation_mode: unknown 'camera'"),
    ({"observation_mode": "robot", "sensor_noise": {"contact": 0.1}}, "unknown or noiseless block 'contact'"),
    ({"observation_mode": "robot", "sensor_noise": {"cable_speed": 0.1}}, "unknown or noiseless block 'cable_speed'"),
    ({"observation_mode": "robot", "sensor_noise": {"target_position": 0.1}}, "unknown or noiseless block"),
    ({"observation_mode": "robot", "history": 1.5}, "history: must be a positive integer"),
    ({"history": 3}, "only with observation_mode='robot'"),
])
def test_shape_env_bad_sensor_arguments(kw, match):
    with pytest.raises(ValueError, match=match):
        gym.make("TensegrityShape-v0", **kw)


def test_rolling_gait_refuses_the_robot_observation_by_name():
    """The gait reads node velocities of the state observation: in robot mode it is refused
    with a ValueError (agents.evaluate then skips the baseline with a note), not a KeyError."""
    import gymnasium as gym
    from tensegrity_gym.tools.baselines import RollingGait
    env = gym.make("TensegrityRoll-v0", observation_mode="robot")
    with pytest.raises(ValueError, match="observation_mode='robot'"):
        RollingGait(env)
    env.close()
