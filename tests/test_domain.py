"""Robot parameters in the envs (tensegrity_gym.envs.domain): fixed ``params=``, randomised
``randomize=``, ``info["params"]``, vector env == single envs, action delay, slack start."""
import numpy as np
import gymnasium as gym
import pytest

import tensegrity_gym  # noqa: F401  (registers the envs)

ROLL_RANDOM = {"rod_mass": 0.2, "stiffness": 0.2, "damping": 0.2, "friction": 0.2, "ground_stiffness": 0.2,
               "ground_damping": 0.2, "rest_length_offset": 0.005, "max_cable_speed": 0.2,
               "max_cable_acceleration": 0.2, "gravity": 0.05}
SHAPE_RANDOM = {"rod_mass": 0.2, "stiffness": 0.2, "damping": 0.2, "node_damping": 0.2, "rest_length_offset": 0.003}


def _params_of(info, i):
    return {k: v[i] for k, v in info["params"].items() if not k.startswith("_")}


def _as_kwargs(p):
    return {k: (np.asarray(v).tolist() if np.ndim(v) else float(v)) for k, v in p.items()}


@pytest.mark.parametrize("env_id,randomize,kw", [
    ("TensegrityRoll-v0", ROLL_RANDOM, {}),
    ("TensegrityShape-v0", SHAPE_RANDOM, {}),
    ("TensegrityShape-v0", {"stiffness": 0.2, "damping": 0.3}, {"action_mode": "force_density"}),
])
def test_vector_with_randomize_equals_single_envs_with_reported_params(env_id, randomize, kw):
    N, T = 3, 25
    venv = gym.make_vec(env_id, num_envs=N, vectorization_mode="vector_entry_point", randomize=randomize, **kw)
    obs, info = venv.reset(seed=7)
    rng = np.random.default_rng(1)
    acts = rng.uniform(-1, 1, (T, N) + venv.single_action_space.shape)
    traj = [(obs, None)]
    for a in acts:
        o, r, *_ = venv.step(a)
        traj.append((o, r))
    ps = [_params_of(info, i) for i in range(N)]
    assert not np.allclose(ps[0]["stiffness"], ps[1]["stiffness"])      # copies really differ
    for i in range(N):
        env = gym.make(env_id, params=_as_kwargs(ps[i]), **kw)
        o, info1 = env.reset(seed=7 + i)
        assert np.array_equal(o, traj[0][0][i])
        for name, v in ps[i].items():
            np.testing.assert_array_equal(info1["params"][name], v)
        for t, a in enumerate(acts):
            o, r, *_ = env.step(a[i])
            assert np.array_equal(o, traj[t + 1][0][i]), (i, t)
            assert r == traj[t + 1][1][i]


def test_randomized_values_follow_the_documented_distribution_and_seed():
    N = 64
    venv = gym.make_vec("TensegrityRoll-v0", num_envs=N, vectorization_mode="vector_entry_point",
                        randomize={"stiffness": 0.2, "rest_length_offset": 0.01, "friction": 0.5})
    _, info = venv.reset(seed=3)
    task = venv.unwrapped.task if hasattr(venv, "unwrapped") else venv.task
    k0 = task.structure.stiffness
    ratio = info["params"]["stiffness"] / k0
    assert ratio.min() >= 0.8 and ratio.max() <= 1.2 and ratio.max() - ratio.min() > 0.3   # U(0.8, 1.2)
    off = info["params"]["rest_length_offset"]
    assert np.abs(off).max() <= 0.01 and off.std() > 0.003
    np.testing.assert_array_equal(task.params.stiffness, np.where(task.model.active, 0.0, info["params"]["stiffness"]))
    mu = info["params"]["friction"]
    assert 0.5 <= mu.min() and mu.max() <= 1.5
    from tensegrity_gym.physics.contact import PRM_FIELDS
    assert np.array_equal(task._contact_prm[:, PRM_FIELDS.index("friction")], mu)   # the contact rows' friction column
    # same seed, same values; another seed, other values; a new episode draws anew
    _, info2 = venv.reset(seed=3)
    assert np.array_equal(info2["params"]["stiffness"], info["params"]["stiffness"])
    _, info3 = venv.reset(seed=4)
    assert not np.array_equal(info3["params"]["stiffness"], info["params"]["stiffness"])
    _, info4 = venv.reset()
    assert not np.array_equal(info4["params"]["stiffness"], info3["params"]["stiffness"])


def test_fixed_params_change_the_physics_and_defaults_stay_bit_identical():
    a = gym.make("TensegrityRoll-v0")
    b = gym.make("TensegrityRoll-v0", params={})
    c = gym.make("TensegrityRoll-v0", params={"rod_mass": 0.4})
    outs = []
    for env in (a, b, c):
        o, info = env.reset(seed=0)
        for _ in range(20):
            o, *_ = env.step(np.ones(env.action_space.shape))
        outs.append((o, info))
    assert np.array_equal(outs[0][0], outs[1][0])
    assert "params" not in outs[0][1]
    assert not np.allclose(outs[0][0], outs[2][0])
    np.testing.assert_array_equal(outs[2][1]["params"]["rod_mass"], [0.4, 0.4, 0.4])


def test_action_delay_shifts_actions_by_whole_control_steps():
    d, T = 3, 15
    rng = np.random.default_rng(2)
    acts = rng.uniform(-1, 1, (T, 9))
    delayed = gym.make("TensegrityShape-v0", action_delay=d)
    plain = gym.make("TensegrityShape-v0")
    o1, _ = delayed.reset(seed=5)
    o2, _ = plain.reset(seed=5)
    shifted = np.concatenate([np.zeros((d, 9)), acts[:-d]])
    for t in range(T):
        o1, *_ = delayed.step(acts[t])
        o2, *_ = plain.step(shifted[t])
        assert np.array_equal(o1, o2), t
    # a new episode starts with an empty queue
    o1, _ = delayed.reset(seed=6)
    o2, _ = plain.reset(seed=6)
    o1, *_ = delayed.step(acts[0])
    o2, *_ = plain.step(np.zeros(9))
    assert np.array_equal(o1, o2)


def test_slack_start_and_its_bounds():
    env = gym.make("TensegrityRoll-v0", start_rest_length_offset=0.02)
    env.reset(seed=0)
    task = env.unwrapped.task
    np.testing.assert_allclose(task.ctrl[0], task.actuation.nominal + 0.02)
    with pytest.raises(ValueError, match="start_rest_length_offset: actuated cable 0 would start at .* outside"):
        gym.make("TensegrityRoll-v0", start_rest_length_offset=10.0)
    with pytest.raises(ValueError, match="only with action_mode='rest_length'"):
        gym.make("TensegrityRoll-v0", action_mode="force_density", start_rest_length_offset=0.01)


@pytest.mark.parametrize("kw,match", [
    ({"params": {"mass": 1.0}}, r"params: unknown parameter 'mass'; known: \['damping'"),
    ({"params": {"rod_mass": -1.0}}, r"params\['rod_mass'\]: rod 0: must be > 0 kg, got -1\.0"),
    ({"params": {"stiffness": [1.0, 2.0]}}, r"params\['stiffness'\]: expected a number or 9 values"),
    ({"params": {"stiffness": "stiff"}}, r"params\['stiffness'\]: expected a number"),
    ({"params": {"friction": float("nan")}}, r"params\['friction'\]: copy 0: must be >= 0, got nan"),
    ({"randomize": {"stiffness": 1.5}}, r"randomize\['stiffness'\]: spread must be in \[0, 1\)"),
    ({"randomize": {"rest_length_offset": -0.1}}, r"randomize\['rest_length_offset'\]: spread must be a finite"),
    ({"randomize": {"friction": True}}, r"randomize\['friction'\]: spread must be"),
    ({"action_delay": -1}, r"action_delay: must be an integer >= 0 \(control steps\)"),
    ({"action_delay": 1.5}, r"action_delay: must be an integer >= 0 \(control steps\)"),
])
def test_bad_domain_arguments_name_the_parameter(kw, match):
    with pytest.raises(ValueError, match=match):
        gym.make("TensegrityRoll-v0", **kw)


def test_shape_task_has_no_contact_parameters():
    with pytest.raises(ValueError, match="'friction' is not a parameter of this task"):
        gym.make("TensegrityShape-v0", randomize={"friction": 0.1})


@pytest.mark.parametrize("env_id,randomize", [("TensegrityRoll-v0", {"stiffness": 0.2, "rod_mass": 0.2}),
                                              ("TensegrityShape-v0", {"stiffness": 0.2, "rest_length_offset": 0.003})])
def test_single_env_randomize_uses_the_drawn_physics(env_id, randomize):
    """A single env (one copy) with randomised physics parameters runs the values it reports
    (it ran the nominal robot when the per-copy rows were only written for more than one copy)."""
    def rollout(env):
        obs, info = env.reset(seed=3)
        rng, out = np.random.default_rng(0), [obs]
        for _ in range(10):
            out.append(env.step(rng.uniform(-1, 1, env.action_space.shape))[0])
        return np.array(out), info
    a, info = rollout(gym.make(env_id, randomize=randomize))
    b, _ = rollout(gym.make(env_id, params=_as_kwargs(_params_of(info, slice(None)))))
    nominal, _ = rollout(gym.make(env_id))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - nominal).max() > 1e-6
