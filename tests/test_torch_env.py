"""The device-resident torch vector env of TensegrityRoll-v0 (tensegrity_gym.envs.torch_vec),
its SB3 adapter, and the torch Jacobian of the sys-ID fit.

The torch env runs RollTask's task on the torch backend; in float64 on CPU it must reproduce
the NumPy/numba vector env (same seeds, same actions) to round-off: observations (the NumPy
env's are float32, so to float32 rounding), rewards, reward terms, infos, terminations,
autoresets, with randomised and fixed robot parameters, action delay and force-density mode.
"""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gymnasium as gym  # noqa: E402

import tensegrity_gym  # noqa: E402,F401  (registers the envs)
from tensegrity_gym.envs.roll import TensegrityRollVectorEnv  # noqa: E402
from tensegrity_gym.envs.torch_vec import TorchRollVectorEnv  # noqa: E402

ID = "TensegrityRoll-v0"


def _pair(N, **kw):
    ref = gym.make_vec(ID, num_envs=N, vectorization_mode="vector_entry_point", **kw)
    ten = gym.make_vec(ID, num_envs=N, vectorization_mode="vector_entry_point", backend="torch", device="cpu",
                       dtype="float64", **kw)
    return ref, ten


def _close_obs(o_np, o_t, atol=1e-12):
    """The NumPy env's float32 observation is the float64 value rounded: within 2^-24 relative
    (``atol``: the robot observation's accelerometers difference velocities over one step, so
    round-off of order 1e-16 m/s / 1e-3 s shows in readings that are 0)."""
    o_t = o_t.numpy()
    assert o_np.shape == o_t.shape
    err = np.abs(o_np.astype(np.float64) - o_t)
    assert np.all(err <= 6e-8 * np.abs(o_t) + atol), err.max()


def _close_info(i_np, i_t, tol=1e-9):
    assert set(i_np) == set(i_t), (sorted(i_np), sorted(i_t))
    for k, v in i_np.items():
        if isinstance(v, dict):
            _close_info(v, i_t[k], tol)
            continue
        w = i_t[k]
        assert isinstance(w, torch.Tensor), k
        w = w.numpy()
        if v.dtype == np.bool_:
            assert np.array_equal(v, w), k
        else:
            assert np.abs(v - w).max() <= tol, (k, np.abs(v - w).max())


def _compare_rollouts(ref, ten, N, steps, seed, action_seed, obs_atol=1e-12):
    """Reset both vector envs with ``seed``, step them ``steps`` times with the same random actions
    (some outside [-1, 1]: clipped) and assert equal observations, rewards (1e-9), dones and infos
    at every step and equal final states (1e-9). Returns (episodes ended by the time limit, the
    NumPy env's last infos)."""
    o1, i1 = ref.reset(seed=seed)
    o2, i2 = ten.reset(seed=seed)
    _close_obs(o1, o2, obs_atol)
    _close_info(i1, i2)
    rng = np.random.default_rng(action_seed)
    resets = 0
    for _ in range(steps):
        a = rng.uniform(-1.2, 1.2, (N, ref.single_action_space.shape[0]))
        o1, r1, te1, tr1, i1 = ref.step(a)
        o2, r2, te2, tr2, i2 = ten.step(torch.as_tensor(a))
        _close_obs(o1, o2, obs_atol)
        assert np.abs(r1 - r2.numpy()).max() <= 1e-9
        assert np.array_equal(te1, te2.numpy()) and np.array_equal(tr1, tr2.numpy())
        _close_info(i1, i2)
        resets += int(tr1.sum())
    assert np.abs(ref.unwrapped.task.q - ten.q.numpy()).max() <= 1e-9
    return resets, i1


def _torch_equals_fd_jacobian(problem, theta, q0, qd0, W):
    """The sys-ID problem's projected Jacobians (parameters, window states) with
    ``jacobian="torch"`` equal the production forward differences to 1e-5 relative."""
    sim = problem.simulate(q0, qd0, problem.physics(theta), np.arange(W))
    Jf, Xf = problem.full_jacobian(theta, q0, qd0, sim)
    problem.jacobian = "torch"
    Jp, Xp = problem.full_jacobian(theta, q0, qd0, sim)
    assert np.linalg.norm(Jp - Jf) / np.linalg.norm(Jp) < 1e-5
    assert np.linalg.norm(Xp - Xf) / np.linalg.norm(Xp) < 1e-5


CASES = {
    "default_autoreset": dict(max_episode_steps=20),
    "randomized_delay": dict(max_episode_steps=20, action_delay=2, randomize_goal=True,
                             randomize={"friction": 0.3, "rod_mass": 0.2, "max_cable_speed": 0.2,
                                        "rest_length_offset": 0.005, "stiffness": 0.1, "ground_damping": 0.2,
                                        "max_cable_acceleration": 0.3, "gravity": 0.1},
                             params={"damping": 1.0, "node_damping": 0.1, "ground_stiffness": 2e4}),
    "force_density": dict(action_mode="force_density", max_episode_steps=30),
    "icosahedron_rk4": dict(structure="icosahedron", integrator="rk4", max_episode_steps=20),
    "robot_observation": dict(max_episode_steps=20, observation_mode="robot", history=3,
                              randomize={"rod_mass": 0.2, "gravity": 0.1, "friction": 0.2}),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_float64_matches_numpy_vector_env(case):
    N, steps = 3, 50
    ref, ten = _pair(N, **CASES[case])
    assert isinstance(ten, TorchRollVectorEnv) and isinstance(ref, TensegrityRollVectorEnv)
    resets, i1 = _compare_rollouts(ref, ten, N, steps, seed=7, action_seed=0,
                                   obs_atol=1e-8 if "observation_mode" in CASES[case] else 1e-12)
    assert resets >= N           # the autoreset was exercised (time limit 20 or 30 < 50 steps)
    moved = np.abs(ref.unwrapped.task.q - ref.unwrapped.task.q_nominal).max()
    assert moved > 1e-3          # not a comparison of robots at rest


SHAPE_CASES = {
    "default_autoreset": dict(max_episode_steps=20),
    "randomized_delay": dict(max_episode_steps=20, action_delay=1, randomize={"stiffness": 0.1, "rod_mass": 0.2,
                                                                                "rest_length_offset": 0.003},
                             params={"damping": 4.0}),
    "force_density": dict(action_mode="force_density", max_episode_steps=30),
    "robot_observation": dict(max_episode_steps=20, observation_mode="robot", history=2,
                              randomize={"stiffness": 0.1, "rod_mass": 0.2}),
}


@pytest.mark.parametrize("case", sorted(SHAPE_CASES))
def test_shape_float64_matches_numpy_vector_env(case):
    """TensegrityShape-v0: the torch env equals the NumPy vector env (obs, rewards, the tracking,
    proximity and ctrl terms, errors, success, autoreset)."""
    from tensegrity_gym.envs.shape import TensegrityShapeVectorEnv
    from tensegrity_gym.envs.torch_vec import TorchShapeVectorEnv
    N, steps = 3, 50
    kw = SHAPE_CASES[case]
    ref = gym.make_vec("TensegrityShape-v0", num_envs=N, vectorization_mode="vector_entry_point", **kw)
    ten = gym.make_vec("TensegrityShape-v0", num_envs=N, vectorization_mode="vector_entry_point", backend="torch",
                       device="cpu", dtype="float64", **kw)
    assert isinstance(ten, TorchShapeVectorEnv) and type(ref) is TensegrityShapeVectorEnv
    resets, i1 = _compare_rollouts(ref, ten, N, steps, seed=5, action_seed=4,
                                   obs_atol=1e-8 if "observation_mode" in kw else 1e-12)
    assert resets >= N
    assert np.abs(i1["reward_proximity"]).max() > 0 and np.abs(i1["reward_tracking"]).max() > 0


def test_tensors_on_device_autoreset_and_seeding():
    env = gym.make_vec(ID, num_envs=4, vectorization_mode="vector_entry_point", backend="torch", device="cpu",
                       dtype="float32", max_episode_steps=3)
    assert env.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    obs, info = env.reset(seed=5)
    assert obs.dtype == torch.float32 and obs.shape == (4, env.single_observation_space.shape[0])
    assert env.single_observation_space.dtype == np.float32
    a = torch.full((4, env.single_action_space.shape[0]), 0.3)
    for t in range(3):
        obs, rew, term, trunc, info = env.step(a)
        assert rew.dtype == torch.float32 and term.dtype == torch.bool and isinstance(info["reward_forward"],
                                                                                      torch.Tensor)
        assert torch.isfinite(obs).all()
        torch.testing.assert_close(rew, info["reward_forward"] + info["reward_ctrl"])
    assert trunc.all() and not term.any()
    obs, rew, term, trunc, info = env.step(a)          # next-step autoreset: reset obs, reward 0
    assert (rew == 0).all() and not trunc.any() and info["_goal_direction"].all()
    assert not info["_reward_forward"].any()
    # env i is seeded seed + i: it equals a one-copy env seeded with seed + i
    env.reset(seed=11)
    one = gym.make_vec(ID, num_envs=1, vectorization_mode="vector_entry_point", backend="torch", device="cpu",
                       dtype="float32")
    o_one, _ = one.reset(seed=13)
    o_all, _ = env.reset(seed=11)
    assert torch.equal(o_all[2], o_one[0])
    # a masked reset leaves the other copies alone
    env.step(a)
    before = env.q.clone()
    env.reset(options={"reset_mask": torch.tensor([True, False, False, False])})
    assert torch.equal(env.q[1:], before[1:]) and not torch.equal(env.q[0], before[0])


def test_float32_close_to_float64():
    envs = [gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point", backend="torch", device="cpu",
                         dtype=d) for d in ("float32", "float64")]
    outs = [e.reset(seed=1)[0] for e in envs]
    rng = np.random.default_rng(2)
    for _ in range(15):
        a = rng.uniform(-1, 1, (2, 9))
        outs = [e.step(torch.as_tensor(a, dtype=torch.float32))[0] for e in envs]
    err = (outs[0].double() - outs[1]).abs().max().item()
    assert 0 < err < 1e-3, err


@pytest.mark.parametrize("env_id", [ID, "TensegrityShape-v0"])
def test_robot_observation_noise_on_the_device(env_id):
    """sensor_noise in the torch env: the noisy blocks differ from the noiseless env's by N(0, sigma^2)
    (checked on the accelerometers: mean ~ 0, std ~ sigma), the others not at all; the same seed gives
    the same noise, another seed other noise."""
    mk = dict(num_envs=64, vectorization_mode="vector_entry_point", backend="torch", device="cpu", dtype="float64",
              observation_mode="robot", max_episode_steps=None)
    sigma, p = 2.0, 0.25
    noise = {"imu_accel": sigma, **({"contact": p} if env_id == ID else {})}
    envs = [gym.make_vec(env_id, sensor_noise=noise, **mk) for _ in range(3)]
    clean = gym.make_vec(env_id, **mk)
    layout = dict((name, sl) for name, sl, _ in clean.task.sensors.layout())
    acc = layout["imu_accel"]
    for e, seed in zip(envs + [clean], (3, 3, 4, 3)):
        e.reset(seed=seed)
    a = torch.full((64, clean.single_action_space.shape[0]), 0.3, dtype=torch.float64)
    for _ in range(2):
        outs = [e.step(a)[0] for e in envs + [clean]]
    d = outs[0] - outs[3]
    n = d[:, acc].numel()                                   # 4 standard errors on the mean, ~4 on the std
    assert abs(float(d[:, acc].mean())) < 4 * sigma / n ** 0.5 and abs(float(d[:, acc].std()) / sigma - 1) < 4 / (2 * n) ** 0.5
    rest = torch.ones(d.shape[1], dtype=torch.bool)
    rest[acc] = False
    if "contact" in noise:                                  # switches read wrong with probability p
        c = d[:, layout["contact"]].abs()
        assert set(c.unique().tolist()) <= {0.0, 1.0} and abs(float(c.mean()) - p) < 4 * (p * (1 - p) / c.numel()) ** 0.5
        rest[layout["contact"]] = False
    assert float(d[:, rest].abs().max()) < 1e-12            # only the accelerometers are noisy (newest frame)
    assert torch.equal(outs[0], outs[1]) and not torch.equal(outs[0], outs[2])


@pytest.mark.parametrize("env_id", [ID, "TensegrityShape-v0"])
def test_compiled_step_equals_eager(env_id):
    """compile=True (torch.compile of the task's physics step; inductor needs a C++ compiler on CPU)
    gives the eager env's observations in float64."""
    mk = dict(num_envs=2, vectorization_mode="vector_entry_point", backend="torch", device="cpu", dtype="float64")
    envs = [gym.make_vec(env_id, compile=c, **mk) for c in (False, True)]
    assert envs[0]._substep is None and envs[1]._substep is not None
    outs = [e.reset(seed=2)[0] for e in envs]
    a = torch.as_tensor(np.random.default_rng(1).uniform(-1, 1, (2, envs[0].single_action_space.shape[0])))
    for _ in range(3):
        try:
            outs = [e.step(a)[0] for e in envs]
        except Exception as exc:  # noqa: BLE001 -- no C++ toolchain for inductor on this machine
            if "compiler" in str(exc).lower() or "InductorError" in type(exc).__name__:
                pytest.skip(f"torch.compile unavailable here: {type(exc).__name__}")
            raise
    assert float((outs[0] - outs[1]).abs().max()) < 1e-10


def test_a_device_spelled_with_its_index_is_the_device_its_tensors_report():
    """device="cpu:0" (like "cuda" for cuda:0) is the device the env's tensors report: the env
    takes the actions it hands out on that device."""
    env = gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point", backend="torch", device="cpu:0")
    obs, _ = env.reset(seed=0)
    assert env.device == obs.device == torch.device("cpu")
    env.step(torch.zeros(2, env.single_action_space.shape[0], dtype=obs.dtype))


def test_bad_input_named():
    mk = dict(num_envs=2, vectorization_mode="vector_entry_point", backend="torch")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="device: 'cuda'.*CUDA is not available"):
            gym.make_vec(ID, device="cuda", **mk)
    with pytest.raises(ValueError, match="dtype: 'float16'"):
        gym.make_vec(ID, dtype="float16", **mk)
    for env_id in (ID, "TensegrityShape-v0"):
        with pytest.raises(ValueError, match="observation_mode: unknown 'robt'"):
            gym.make_vec(env_id, observation_mode="robt", **mk)
        with pytest.raises(ValueError, match="sensor_noise: unknown or noiseless block 'goal_direction'"):
            gym.make_vec(env_id, observation_mode="robot", sensor_noise={"goal_direction": 0.1}, **mk)
    with pytest.raises(ValueError, match="render_mode"):
        gym.make_vec(ID, render_mode="rgb_array", **mk)
    with pytest.raises(ValueError, match="device: only with backend='torch'"):
        gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point", device="cpu")
    with pytest.raises(ValueError, match="integrator"):
        gym.make_vec(ID, integrator="implicit_euler", **mk)
    with pytest.raises(ValueError, match="compile: expected True or False"):
        gym.make_vec(ID, compile="yes", **mk)
    with pytest.raises(ValueError, match="compile: only with backend='torch'"):
        gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point", compile=True)
    env = gym.make_vec(ID, clip_actions=False, **mk)
    env.reset(seed=0)
    a = torch.zeros((2, 9), dtype=torch.float64)
    a[1, 4] = float("nan")
    with pytest.raises(ValueError, match=r"actions: entry \(1, 4\) is nan"):
        env.step(a)
    a[1, 4] = 1.5
    with pytest.raises(ValueError, match=r"actions: entry \(1, 4\) is 1.5, outside"):
        env.step(a)
    with pytest.raises(ValueError, match=r"actions: expected shape \(2, 9\)"):
        env.step(torch.zeros((2, 8)))


def test_default_path_unchanged():
    """Without backend='torch' the registered id builds the NumPy vector env with the same arguments."""
    env = gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point")
    assert type(env) is TensegrityRollVectorEnv
    direct = TensegrityRollVectorEnv(num_envs=2)
    o1, _ = env.reset(seed=3)
    o2, _ = direct.reset(seed=3)
    a = np.full((2, 9), 0.5)
    assert np.array_equal(env.step(a)[0], direct.step(a)[0])
    assert np.array_equal(o1, o2)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    envs = [gym.make_vec(ID, num_envs=3, vectorization_mode="vector_entry_point", backend="torch", device=d,
                         dtype="float64") for d in ("cpu", "cuda")]
    outs = [e.reset(seed=4)[0] for e in envs]
    assert outs[1].device.type == "cuda"
    a = torch.full((3, 9), -0.4, dtype=torch.float64)
    for _ in range(10):
        outs = [e.step(a.to(e.device))[0] for e in envs]
    assert (outs[0] - outs[1].cpu()).abs().max().item() < 1e-9


# ---------------------------------------------------------------------- SB3 route
def test_sb3_adapter_matches_numpy_adapter():
    """The torch adapter gives SB3 the NumPy adapter's arrays (float64 env, float32 obs)."""
    pytest.importorskip("stable_baselines3")
    from tensegrity_gym.integrations.sb3 import make_sb3_torch_vec_env, make_sb3_vec_env
    ref, ten = _pair(3, max_episode_steps=5)
    a_ref, a_ten = make_sb3_vec_env(ref), make_sb3_torch_vec_env(ten, info_keys=("reward_forward", "com_position"))
    assert a_ten.observation_space.dtype == np.float32
    a_ref.seed(2)
    a_ten.seed(2)
    o1, o2 = a_ref.reset(), a_ten.reset()
    assert o2.dtype == np.float32 and np.abs(o1 - o2).max() <= 1e-6
    rng = np.random.default_rng(1)
    dones = 0
    for _ in range(12):
        a = rng.uniform(-1, 1, (3, 9)).astype(np.float32)
        o1, r1, d1, i1 = a_ref.step(a)
        o2, r2, d2, i2 = a_ten.step(a)
        assert np.abs(o1 - o2).max() <= 1e-6 and np.abs(r1 - r2).max() <= 1e-6
        assert np.array_equal(d1, d2)
        for x, y in zip(i1, i2):
            assert abs(x["reward_forward"] - y["reward_forward"]) <= 1e-9
            assert np.abs(x["com_position"] - y["com_position"]).max() <= 1e-9
            if "terminal_observation" in x:
                assert np.abs(x["terminal_observation"] - y["terminal_observation"]).max() <= 1e-6
                assert x["TimeLimit.truncated"] == y["TimeLimit.truncated"]
        dones += int(d1.sum())
    assert dones == 6          # two time limits of 5 steps per env in 12 steps
    with pytest.raises(ValueError, match="info_keys: 'nope'"):
        make_sb3_torch_vec_env(ten, info_keys=("nope",)).step(np.zeros((3, 9), np.float32))


@pytest.fixture
def one_thread():
    """One torch thread: on a shared 2-core CI machine torch's thread pool makes tiny MLPs 3x slower."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def test_ppo_trains_on_the_torch_env(one_thread):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO
    from tensegrity_gym.integrations.sb3 import make_sb3_torch_vec_env
    env = gym.make_vec(ID, num_envs=4, vectorization_mode="vector_entry_point", backend="torch", device="cpu",
                       dtype="float32", max_episode_steps=40)
    venv = make_sb3_torch_vec_env(env)
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=64, n_epochs=1, seed=0, device="cpu")
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(total_timesteps=256)
    assert model.num_timesteps >= 256
    assert any(not torch.equal(b, p) for b, p in zip(before, model.policy.parameters()))   # it updated
    obs = venv.reset()
    act, _ = model.predict(obs, deterministic=True)
    assert act.shape == (4, 9) and np.all(np.isfinite(act))


# ---------------------------------------------------------------------- sys-ID with torch gradients
def _pinned_record(true, T=0.13, h=4e-3, seed=0):
    """(model, t, nodes): the damped pinned rod released off equilibrium, recorded every ``h``
    s by rk4 at the same step as the fits below (no model error: the fit must recover ``true``)."""
    import tensegrity_gym as tg
    from tensegrity_gym.core.model import State
    from tensegrity_gym.physics.geometry import node_positions
    from tensegrity_gym.physics.evaluate import project
    from tensegrity_gym.core.params import default_params
    s = tg.pinned_rod(damping=3.0)
    model = tg.compile_model(s)
    st = tg.initial_state(model, nodes=s.nodes + 0.03 * np.random.default_rng(seed).standard_normal(s.nodes.shape))
    st = State(*project(model, st.q, st.qd))
    P = default_params(model).replace(**true)
    t, q, _ = tg.simulate(model, st, h, int(round(T / h)), "rk4", params=P)
    return model, t, node_positions(model, q[:, 0])


def test_sysid_torch_jacobian_equals_finite_differences(one_thread):
    """The autograd residual Jacobian (parameters and window states) equals central finite
    differences of the NumPy/numba rollout to 1e-6 relative, and the production forward
    differences to ~1e-6."""
    from tensegrity_gym.tools import sysid
    model, t, nodes = _pinned_record({"stiffness": np.array([900.0, 1100.0, 1000.0])})
    names, items, init, base = sysid._parse_fit(model, ("stiffness", "damping"), "per_member", None)
    t_, rec, mask, rl, h = sysid._check_record(model, t, nodes, None, None)
    pb = sysid._Problem(model, t_, rec, mask, rl, h, names, items, init, base, "per_member", 0.06, "rk4", 4e-3, 1)
    q0, qd0 = pb.guess()
    theta = np.random.default_rng(3).uniform(-0.1, 0.1, pb.p)
    Jt = pb.torch_jacobian(theta, q0, qd0)                     # (W, R, p + ns), unprojected
    # central differences of the NumPy path, every column
    W, ns, p = pb.W, pb.ns, pb.p
    cols = []
    for i in range(p + ns):
        out = []
        for sgn in (1.0, -1.0):
            th, x = theta.copy(), np.zeros((W, ns))
            eps = 1e-5
            if i < p:
                th[i] += sgn * eps
            else:
                x[:, i - p] = sgn * eps
            qp, qdp = pb.apply(q0, qd0, x)
            out.append(pb.residual(pb.simulate(qp, qdp, pb.physics(th), np.arange(W)), np.arange(W)))
        cols.append((out[0] - out[1]) / (2 * eps))
    Jc = np.stack(cols, -1)
    rel = np.linalg.norm(Jt - Jc, axis=(0, 1)) / np.linalg.norm(Jc, axis=(0, 1))
    assert rel.max() < 1e-6, rel
    # the projected Jacobians of the fit: torch against the production forward differences
    _torch_equals_fd_jacobian(pb, theta, q0, qd0, W)
    # with recorded (actuated) rest lengths, held per sample interval
    rl = model.rest_length[None] * (1 + 0.01 * np.sin(np.arange(t.size)[:, None] * 0.3 + np.arange(3)))
    t_, rec, mask, rl_, h = sysid._check_record(model, t, nodes, rl, None)
    pa = sysid._Problem(model, t_, rec, mask, rl_, h, names, items, init, base, "per_member", 0.06, "rk4", 4e-3, 1)
    _torch_equals_fd_jacobian(pa, theta, q0, qd0, W)
    # a wrong gradient is caught: one parameter column off by 0.1 %
    bad = Jt.copy()
    bad[..., 0] *= 1.001
    assert np.linalg.norm(bad[..., 0] - Jc[..., 0]) / np.linalg.norm(Jc[..., 0]) > 1e-6


def test_sysid_fit_with_torch_jacobian_recovers_parameters(one_thread):
    from tensegrity_gym.tools.sysid import identify
    true = {"stiffness": np.array([900.0, 1100.0, 1000.0]), "damping": np.array([2.5, 3.5, 3.0])}
    model, t, nodes = _pinned_record(true)
    r = identify(model, t, nodes, fit=("stiffness", "damping"), window=0.06, dt=4e-3, jacobian="torch")
    assert r.converged and r.ok, r.message
    for f in ("stiffness", "damping"):
        assert np.abs(r.values[f] / true[f] - 1).max() < 1e-3, (f, r.values[f])
    assert np.abs(r.initial["stiffness"] / true["stiffness"] - 1).max() > 0.05     # it had to move
    with pytest.raises(ValueError, match="jacobian: expected 'fd' or 'torch', got 'ad'"):
        identify(model, t, nodes, fit=("stiffness",), jacobian="ad")
    with pytest.raises(ValueError, match="jacobian: 'torch' supports integrator"):
        identify(model, t, nodes, fit=("stiffness",), integrator="implicit_euler", jacobian="torch")


def test_single_env_with_the_torch_backend_points_to_the_vector_env():
    """gym.make(id, backend='torch') says how to get the torch env (a vector env), naming the call."""
    for env_id in ("TensegrityRoll-v0", "TensegrityShape-v0"):
        with pytest.raises(ValueError, match="make_vec.*vector_entry_point.*backend='torch'"):
            gym.make(env_id, backend="torch")
