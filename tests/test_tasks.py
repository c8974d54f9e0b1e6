"""The tasks written once for NumPy arrays and torch tensors (tensegrity_gym.tasks): each function's
NumPy result is the plain NumPy formula's bit for bit (the NumPy envs' numbers), and the same
function on torch float64 tensors equals it to round-off."""
import numpy as np
import pytest

from tensegrity_gym.tasks.roll import roll_step_terms
from tensegrity_gym.rewards import quadratic_cost


def _inputs(B=257, na=9, seed=0):
    rng = np.random.default_rng(seed)
    goal = rng.normal(size=(B, 2))
    goal /= np.linalg.norm(goal, axis=1, keepdims=True)
    return (rng.normal(size=(B, 3)), rng.normal(size=(B, 3)), rng.normal(size=(B, 3)), goal,
            rng.uniform(-1, 1, (B, na)))


def test_numpy_terms_equal_the_einsum_forms():
    com0, com, start, goal, action = _inputs()
    terms, infos = roll_step_terms(com0, com, start, goal, action, 0.02, 1.5, 0.01)
    vel = (com - com0) / 0.02
    forward = np.einsum("bi,bi->b", vel[:, :2], goal)
    np.testing.assert_array_equal(terms["forward"], 1.5 * forward)
    np.testing.assert_array_equal(terms["ctrl"], -0.01 * quadratic_cost(action))
    np.testing.assert_array_equal(infos["distance_rolled"], np.einsum("bi,bi->b", (com - start)[:, :2], goal))
    np.testing.assert_array_equal(infos["com_velocity"], vel)
    np.testing.assert_array_equal(infos["forward_velocity"], forward)
    assert infos["com_position"] is com


def test_torch_terms_equal_the_numpy_terms():
    torch = pytest.importorskip("torch")
    arrays = _inputs(seed=1)
    t_terms, t_infos = roll_step_terms(*(torch.as_tensor(a) for a in arrays), 0.02, 1.5, 0.01)
    n_terms, n_infos = roll_step_terms(*arrays, 0.02, 1.5, 0.01)
    for name in n_terms:
        np.testing.assert_allclose(t_terms[name].numpy(), n_terms[name], rtol=1e-14, atol=1e-14)
    for name in n_infos:
        np.testing.assert_allclose(t_infos[name].numpy(), n_infos[name], rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("kw", [dict(), dict(max_cable_acceleration=None, randomize={"rod_mass": 0.2}),
                                dict(structure="icosahedron", action_mode="force_density")])
def test_compiled_observation_equals_the_one_definition(kw):
    """RollTask.observe's compiled single pass is roll_state_observation cast to float32, bit for bit."""
    from tensegrity_gym.envs.roll import RollTask
    from tensegrity_gym.tasks.roll import roll_state_observation
    task = RollTask(num_envs=3, frame_skip=5, **kw)
    rngs = [np.random.default_rng(i) for i in range(3)]
    task.reset(np.arange(3), rngs)
    rng = np.random.default_rng(7)
    for _ in range(4):
        task.step(rng.uniform(-1, 1, (3, task.action_size)))
        q, qd = task.q, task.qd
        rod, e = task._node_rod_i64, task._node_eta_1d[None, :, None]    # node i at r + e_i b of rod rod[i]
        nodes, vel = q[:, rod, :3] + e * q[:, rod, 3:], qd[:, rod, :3] + e * qd[:, rod, 3:]
        ref = roll_state_observation(nodes, vel, task._com(q), task.ctrl, task.cstate.active, task.goal, task.speed)
        assert ref.dtype == np.float64
        np.testing.assert_array_equal(task.observe(), ref.astype(np.float32))


# ---------------------------------------------------------------- every task function, NumPy vs torch
def _torch_equal(fn, *arrays, rtol=1e-13, atol=1e-13, **kw):
    """fn on NumPy arrays and on torch float64 tensors: equal to round-off (dicts, tuples compared item by item)."""
    torch = pytest.importorskip("torch")
    n = fn(*arrays, **kw)
    t = fn(*(torch.as_tensor(a) if isinstance(a, np.ndarray) else a for a in arrays), **kw)

    def flat(x):
        if isinstance(x, dict):
            return [v for k in sorted(x) for v in flat(x[k])]
        if isinstance(x, tuple):
            return [v for item in x for v in flat(item)]
        return [x]
    for a, b in zip(flat(n), flat(t), strict=True):
        b = b.numpy() if hasattr(b, "numpy") else b
        np.testing.assert_allclose(np.asarray(b, float), np.asarray(a, float), rtol=rtol, atol=atol)
    return n


def test_shape_terms_one_definition():
    from tensegrity_gym.rewards import tolerance
    from tensegrity_gym.tasks.shape import node_errors, proximity, shape_state_observation, shape_step_terms
    rng = np.random.default_rng(3)
    B, nt, na = 64, 4, 6
    nodes, target = rng.normal(size=(B, nt, 3)), rng.normal(size=(B, nt, 3))
    d = _torch_equal(node_errors, nodes, target)
    np.testing.assert_array_equal(d, np.linalg.norm(nodes - target, axis=-1))
    emax = np.concatenate([rng.uniform(0, 0.02, 32), rng.uniform(0.02, 0.5, 32)])
    np.testing.assert_array_equal(_torch_equal(proximity, emax, 0.02), tolerance(emax, (0.0, 0.02), margin=0.2))
    err, action = rng.uniform(0, 0.1, B), rng.uniform(-1, 1, (B, na))
    terms, infos = _torch_equal(shape_step_terms, err, emax, action, 0.02, 10.0, 1.0, 0.01)
    np.testing.assert_array_equal(terms["tracking"], -10.0 * err)
    np.testing.assert_array_equal(infos["is_success"], emax <= 0.02)
    obs = _torch_equal(shape_state_observation, nodes, rng.normal(size=(B, nt, 3)), rng.normal(size=(B, na)), target)
    assert obs.shape == (B, 12 * nt + na)


def test_roll_reset_and_centre_of_mass_one_definition():
    from tensegrity_gym.tasks.roll import center_of_mass, perturbed_start
    rng = np.random.default_rng(4)
    r, k = 5, 3
    q_nom, length, x = rng.normal(size=(1, k, 6)), rng.uniform(0.3, 0.5, (k, 1)), rng.uniform(-1e-3, 1e-3, (r, 4, k, 3))
    q, qd = _torch_equal(perturbed_start, q_nom, length, x)
    np.testing.assert_array_equal(q[..., :3], q_nom[..., :3] + x[:, 0])
    np.testing.assert_array_equal(qd[..., 3:], x[:, 3] / length)
    mf = rng.uniform(0.1, 1, k)
    mf /= mf.sum()
    np.testing.assert_array_equal(_torch_equal(center_of_mass, q, mf), np.einsum("k,bki->bi", mf, q[..., :3]))
    eta = rng.uniform(-0.1, 0.1, (1, k, 1))
    _torch_equal(center_of_mass, q, np.tile(mf, (r, 1)), eta)


def test_sensor_reading_one_definition():
    from tensegrity_gym.tasks.sensors import add_noise, reading, rod_frames
    rng = np.random.default_rng(5)
    B, k, m = 7, 3, 9
    q = rng.normal(size=(B, k, 6))
    q[..., 3:] /= np.linalg.norm(q[..., 3:], axis=-1, keepdims=True)
    q[0, 0, 3:] = (0.0, 0.0, 1.0)                     # a vertical rod: the frame falls back to the world x axis
    R = _torch_equal(rod_frames, q[..., 3:])
    np.testing.assert_allclose(np.einsum("bkij,bklj->bkil", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    blocks = ["cable_length", "control", "imu_accel", "imu_gyro", "contact", "goal_direction"]
    args = (rng.uniform(0.1, 1, (B, m)), q, rng.normal(size=(B, k, 6)), rng.normal(size=(B, k, 6)), 1e-3,
            rng.uniform(-0.1, 0.1, (1, k, 1)), np.array([[0.0, 0.0, -9.81]]), rng.normal(size=(B, 4)), None,
            rng.uniform(size=(B, 2 * k)) < 0.5, rng.normal(size=(B, 2)))
    out = _torch_equal(reading, blocks, *args)
    assert out.shape == (B, m + 4 + 6 * k + 2 * k + 2)
    at_rest = reading(blocks, *args[:3], None, *args[4:])
    imu = at_rest[:, m + 4:m + 4 + 3 * k].reshape(B, k, 3)     # at rest the accelerometer reads -g in the rod frame
    np.testing.assert_allclose(imu, np.einsum("bkij,j->bki", R, [0.0, 0.0, 9.81]), rtol=1e-14, atol=1e-14)
    # noise: gaussian draws are added, a switch flips where its uniform is below the probability
    noisy = out.copy()
    sl_c = slice(m + 4 + 6 * k, m + 4 + 8 * k)
    u = rng.uniform(size=(B, 2 * k))
    g = rng.normal(size=(B, m))
    add_noise(noisy, [(slice(0, m), 0.1, False), (sl_c, 0.3, True)], [g, u])
    np.testing.assert_array_equal(noisy[:, :m], out[:, :m] + g)
    np.testing.assert_array_equal(noisy[:, sl_c], np.where(u < 0.3, 1.0 - out[:, sl_c], out[:, sl_c]))


def test_randomization_draws_one_definition():
    from tensegrity_gym.core.param_table import domain_specs
    from tensegrity_gym.tasks.randomization import draw_count, draw_range, values_from_draws
    specs = domain_specs()
    rng = np.random.default_rng(6)
    for name, base in (("rod_mass", rng.uniform(0.1, 1, 3)), ("rest_length_offset", np.zeros(9)),
                       ("gravity", np.array([0.0, 0.0, -9.81]))):
        spec = specs[name]
        lo, hi = draw_range(spec, 0.1)
        x = rng.uniform(lo, hi, (4, draw_count(spec, base)))
        v = _torch_equal(lambda base, x, spec=spec: values_from_draws(spec, base, x), base, x)
        assert v.shape == (4,) + base.shape
        if spec.one_factor:
            np.testing.assert_array_equal(v, base * x)
        elif spec.absolute:
            np.testing.assert_array_equal(v, base + x)
        else:
            np.testing.assert_array_equal(v, base * x)
