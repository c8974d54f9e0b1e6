"""The roll task's reward terms and infos (tensegrity_gym.envs.roll_terms), one definition for
NumPy arrays and torch tensors: the NumPy result is the einsum form's bit for bit, the torch one
equals it (float64)."""
import numpy as np
import pytest

from tensegrity_gym.envs.roll_terms import roll_step_terms
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
    from tensegrity_gym.envs.roll_terms import roll_state_observation
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
