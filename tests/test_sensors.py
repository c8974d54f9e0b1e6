"""Robot observation mode (tensegrity_gym.envs.sensors): IMU readings in known motions, the
env's robot observation, sensor noise and history."""
import numpy as np
import gymnasium as gym
import pytest

import tensegrity_gym as tg
from tensegrity_gym import dynamics as dyn
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
    np.testing.assert_allclose(obs[lay["cable_length"]], dyn.string_state(task.model, task.q)[1][0], rtol=1e-6)
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


@pytest.mark.parametrize("kw,match", [
    ({"observation_mode": "camera"}, "observation_mode: unknown 'camera'"),
    ({"observation_mode": "robot", "sensor_noise": {"contact": 0.1}}, "unknown or noiseless block 'contact'"),
    ({"observation_mode": "robot", "sensor_noise": {"imu_gyro": -1}}, r"sensor_noise\['imu_gyro'\]: must be"),
    ({"observation_mode": "robot", "history": 0}, "history: must be a positive integer"),
    ({"sensor_noise": {"imu_gyro": 0.1}}, "only with observation_mode='robot'"),
])
def test_bad_sensor_arguments(kw, match):
    with pytest.raises(ValueError, match=match):
        gym.make("TensegrityRoll-v0", **kw)
