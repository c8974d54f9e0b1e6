"""TensegrityShape-v0: API conformance, determinism, robustness, reward bookkeeping, targets,
vector env == N single envs, SB3 on the batched env, NNLS baseline."""
import warnings

import gymnasium as gym
import numpy as np
import pytest

import tensegrity_gym  # noqa: F401
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.physics.geometry import node_positions, node_velocities
from tensegrity_gym.tools.baselines import NNLSShapeController
from tensegrity_gym.envs.shape import TensegrityShapeEnv, TensegrityShapeVectorEnv

MODES = ("rest_length", "force_density")
ENV_ID = "TensegrityShape-v0"


def rollout(env, seed, actions):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append(np.concatenate([obs, [r]]))
    return out


@pytest.mark.parametrize("mode", MODES)
def test_gymnasium_check_env(mode):
    from gymnasium.utils.env_checker import check_env
    env = gym.make(ENV_ID, action_mode=mode)
    check_env(env.unwrapped, skip_render_check=True)
    assert env.spec.max_episode_steps == 200


@pytest.mark.parametrize("mode", MODES)
def test_sb3_check_env(mode):
    from stable_baselines3.common.env_checker import check_env
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(TensegrityShapeEnv(action_mode=mode), warn=False)


def test_spaces_and_observation_layout():
    env = TensegrityShapeEnv()
    obs, info = env.reset(seed=3)
    task = env.task
    assert env.action_space.shape == (9,) and env.observation_space.shape == (69,)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)
    assert {"tracking_error", "max_node_error", "is_success"} <= set(info)
    L = {name: sl for name, sl, _ in task.observation_layout()}
    N = node_positions(task.model, task.q)[0, task.tracked]
    assert np.allclose(obs[L["node_position"]], N.ravel(), atol=1e-6)
    assert np.allclose(obs[L["target_position"]], task.target[0].ravel(), atol=1e-6)
    assert np.allclose(obs[L["target_error"]], (task.target[0] - N).ravel(), atol=1e-6)
    assert np.allclose(obs[L["control"]], task.structure.rest_length, atol=1e-6)
    assert env.metadata["render_fps"] == 50 and env.unwrapped.dt == pytest.approx(0.02)


@pytest.mark.parametrize("mode", MODES)
def test_same_seed_same_rollout(mode):
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (25, 9))
    a = rollout(gym.make(ENV_ID, action_mode=mode), 42, acts)
    b = rollout(gym.make(ENV_ID, action_mode=mode), 42, acts)
    c = rollout(gym.make(ENV_ID, action_mode=mode), 43, acts)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c[0])


@pytest.mark.parametrize("mode", MODES)
def test_finite_observations_under_extreme_actions_long_episodes(mode):
    """Random, constant +1 and constant -1 actions for 400 control steps (8 s, twice the time
    limit) in 3 envs of one batched env: every observation and reward finite."""
    env = TensegrityShapeVectorEnv(num_envs=3, max_episode_steps=None, action_mode=mode)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(1)
    for _ in range(400):
        a = np.stack([rng.uniform(-1, 1, 9), np.ones(9), -np.ones(9)])
        obs, r, term, trunc, info = env.step(a)
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(r))
    ctrl = env.task.ctrl
    # the constant actions drove the controls to their bounds
    assert np.allclose(ctrl[1], env.task.actuation.high) and np.allclose(ctrl[2], env.task.actuation.low)


@pytest.mark.parametrize("mode", MODES)
def test_reward_is_sum_of_terms(mode):
    env = gym.make(ENV_ID, action_mode=mode, ctrl_cost_weight=0.1)
    env.reset(seed=1)
    for _ in range(10):
        a = env.action_space.sample()
        _, r, _, _, info = env.step(a)
        terms = {k: v for k, v in info.items() if k.startswith("reward_")}
        assert set(terms) == {"reward_tracking", "reward_proximity", "reward_ctrl"}
        assert r == pytest.approx(sum(terms.values()), abs=1e-12)
        assert info["reward_tracking"] == pytest.approx(-10.0 * info["tracking_error"])
        assert info["reward_ctrl"] == pytest.approx(-0.1 * float(np.sum(np.square(a, dtype=np.float64))), rel=1e-6)
        assert info["is_success"] == (info["max_node_error"] <= 0.01)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_action_raises_naming_index(bad):
    env = gym.make(ENV_ID)
    env.reset(seed=0)
    a = np.zeros(9)
    a[4] = bad
    with pytest.raises(ValueError, match="entry 4"):
        env.step(a)
    venv = TensegrityShapeVectorEnv(num_envs=2)
    venv.reset(seed=0)
    A = np.zeros((2, 9))
    A[1, 7] = bad
    with pytest.raises(ValueError, match=r"entry \(1, 7\)"):
        venv.step(A)


def test_out_of_box_actions_are_clipped_or_rejected():
    e1, e2 = TensegrityShapeEnv(), TensegrityShapeEnv()
    e1.reset(seed=0)
    e2.reset(seed=0)
    a = np.full(9, 1.0)
    a[2] = 7.0
    o1 = e1.step(a)[0]
    o2 = e2.step(np.ones(9))[0]
    assert np.array_equal(o1, o2)          # documented Box contract: clipped
    strict = TensegrityShapeEnv(clip_actions=False)
    strict.reset(seed=0)
    with pytest.raises(ValueError, match="entry 2"):
        strict.step(a)
    with pytest.raises(ValueError, match="shape"):
        strict.step(np.zeros(4))


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="action_mode"):
        TensegrityShapeEnv(action_mode="torque")
    with pytest.raises(ValueError, match="string 12"):
        TensegrityShapeEnv(actuated=[0, 12])
    with pytest.raises(ValueError, match="frame_skip"):
        TensegrityShapeEnv(frame_skip=0)
    with pytest.raises(ValueError, match="anchored"):
        TensegrityShapeEnv(structure="prism3")


@pytest.mark.parametrize("mode", MODES)
def test_target_sampled_at_reset_is_an_equilibrium(mode):
    env = TensegrityShapeEnv(action_mode=mode, actuated=[0, 3, 6, 7])
    for seed in range(3):
        env.reset(seed=seed)
        task = env.task
        nodes = task.nodes_nominal.copy()
        nodes[task.tracked] = task.target[0]
        q = initial_state(task.model, nodes=nodes).q
        inp = task.actuation.physics_inputs(task.target_control[:1])
        acc = tensegrity_gym.physics.evaluate.accelerations(task.model, q, np.zeros_like(q), inp.get("rest_length"), inp.get("force_density"))
        assert np.abs(acc).max() < 1e-7
        # and it differs from the start shape (the task is not trivial)
        assert np.abs(task.target[0] - task.nodes_nominal[task.tracked]).max() > 0.01
        # targets respect the control bounds
        assert np.all(task.target_control[0] >= task.actuation.low - 1e-12)
        assert np.all(task.target_control[0] <= task.actuation.high + 1e-12)


def test_divergence_truncates_with_finite_observations():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = TensegrityShapeEnv(dt=0.08, frame_skip=1, string_damping=0.0, node_damping=0.0, allow_unstable_dt=True,
                                 structure=tensegrity_gym.constrained_prism(stiffness=20000.0, prestress=2000.0))
        env.reset(seed=0)
        info = {}
        for _ in range(50):
            obs, r, term, trunc, info = env.step(np.ones(9))
            assert np.all(np.isfinite(obs)) and np.isfinite(r)
            if trunc:
                break
    assert info["diverged"] and trunc


def test_vector_env_equals_single_envs_including_autoreset():
    N, T = 3, 14
    venv = TensegrityShapeVectorEnv(num_envs=N, max_episode_steps=6, action_mode="rest_length")
    singles = [gym.make(ENV_ID, action_mode="rest_length", max_episode_steps=6) for _ in range(N)]
    rng = np.random.default_rng(5)
    acts = rng.uniform(-1, 1, (T, N, 9))
    vobs, _ = venv.reset(seed=100)
    sobs = [s.reset(seed=100 + i)[0] for i, s in enumerate(singles)]
    assert np.allclose(vobs, np.stack(sobs), atol=1e-6, rtol=0)
    s_done = [False] * N
    for t in range(T):
        vobs, vr, vterm, vtrunc, vinfo = venv.step(acts[t])
        for i, s in enumerate(singles):
            if s_done[i]:   # next-step autoreset: the single env resets (RNG continues)
                o, _ = s.reset()
                r, term, trunc = 0.0, False, False
                s_done[i] = False
            else:
                o, r, term, trunc, info = s.step(acts[t, i])
                s_done[i] = term or trunc
                assert vinfo["_tracking_error"][i]
                assert vinfo["tracking_error"][i] == pytest.approx(info["tracking_error"], abs=1e-9)
            assert np.allclose(vobs[i], o, atol=1e-6, rtol=0), (t, i)
            assert vr[i] == pytest.approx(r, abs=1e-9)
            assert vterm[i] == term and vtrunc[i] == trunc
    assert venv.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP


def test_make_vec_vector_entry_point():
    venv = gym.make_vec(ENV_ID, num_envs=4, vectorization_mode="vector_entry_point", action_mode="force_density")
    assert isinstance(venv.unwrapped, TensegrityShapeVectorEnv)
    assert venv.unwrapped.max_episode_steps == 200          # the registered limit, passed by make_vec
    assert TensegrityShapeVectorEnv(num_envs=2).max_episode_steps == 200   # looked up when constructed directly
    obs, info = venv.reset(seed=0)
    assert obs.shape == (4, 69) and venv.action_space.shape == (4, 9)
    # time limit in the vector env: truncation exactly at step 200
    task = venv.unwrapped.task
    task.elapsed[:] = 198
    _, _, _, trunc, _ = venv.step(np.zeros((4, 9)))
    assert not trunc.any()
    _, _, _, trunc, _ = venv.step(np.zeros((4, 9)))
    assert trunc.all()
    obs, r, term, trunc, info = venv.step(np.zeros((4, 9)))   # autoreset step
    assert np.all(r == 0) and not trunc.any() and np.all(task.elapsed == 0)
    # masked reset
    obs2, _ = venv.reset(options={"reset_mask": np.array([True, False, False, False])})
    assert np.array_equal(obs2[1:], obs[1:]) and not np.array_equal(obs2[0], obs[0])


def test_render_rgb_array():
    env = gym.make(ENV_ID, render_mode="rgb_array", width=160, height=120)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    frame = env.render()
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8 and frame.std() > 0
    venv = TensegrityShapeVectorEnv(num_envs=2, render_mode="rgb_array", width=64, height=64)
    venv.reset(seed=0)
    frames = venv.render()
    assert len(frames) == 2 and frames[0].shape == (64, 64, 3)


def test_sb3_ppo_trains_on_batched_vector_env():
    from stable_baselines3 import PPO
    from tensegrity_gym.envs.common import make_sb3_vec_env
    venv = make_sb3_vec_env(gym.make_vec(ENV_ID, num_envs=4, vectorization_mode="vector_entry_point",
                                         max_episode_steps=40))
    venv.seed(7)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=256)          # 64 steps x 4 envs; episodes end (40 steps) and reset
    assert model.num_timesteps >= 256
    obs = venv.reset()
    # episode boundaries: terminal observation and TimeLimit flag come with a same-step reset
    for k in range(40):
        obs, rew, done, infos = venv.step(np.zeros((4, 9), np.float32))
        assert obs.shape == (4, 69) and rew.shape == (4,) and len(infos) == 4
        assert done.all() == (k == 39) and done.any() == (k == 39)
    assert all("terminal_observation" in i and i["TimeLimit.truncated"] for i in infos)
    assert not np.array_equal(infos[0]["terminal_observation"], obs[0])   # obs is the reset one
    assert np.all(venv.venv.unwrapped.task.elapsed == 0)


@pytest.mark.parametrize("mode", MODES)
def test_baseline_reaches_targets(mode):
    """The NNLS controller brings 3 held-out targets within the 1 cm tolerance in 3 s."""
    venv = TensegrityShapeVectorEnv(num_envs=3, max_episode_steps=None, action_mode=mode)
    pol = NNLSShapeController(venv)
    obs, info = venv.reset(seed=2024)
    assert not info["is_success"].any()
    for _ in range(150):
        a, _ = pol.predict(obs)
        assert a.shape == (3, 9) and np.all(np.abs(a) <= 1)
        obs, r, term, trunc, info = venv.step(a)
    assert info["is_success"].all(), info["max_node_error"]
    if mode == "rest_length":
        assert info["max_node_error"].max() < 1e-4     # the NNLS rest lengths are exact
    # single-observation interface like an SB3 model
    single = TensegrityShapeEnv(action_mode=mode)
    o, _ = single.reset(seed=1)
    a, state = NNLSShapeController(single).predict(o, deterministic=True)
    assert a.shape == (9,) and state is None


@pytest.mark.parametrize("mode", MODES)
def test_node_drag_is_in_the_model_one_integrator_call_per_step(mode, monkeypatch):
    """The node drag lives in the model: one integrator call of frame_skip steps per control
    step, with the same physics as the drag applied as an external force every substep."""
    from tensegrity_gym.physics import integrate   # where pipeline.step looks the step up
    env = TensegrityShapeEnv(action_mode=mode, node_damping=3.0)
    task = env.task
    assert task.model.has_node_damping and np.all(task.model.node_damping == 3.0)
    env.reset(seed=1)
    a = np.linspace(-0.8, 0.8, env.action_space.shape[0]).astype(np.float32)
    env.step(a)
    q0, qd0 = task.q.copy(), task.qd.copy()
    inputs = task.actuation.advance(task.ctrl, a[None].astype(np.float64))[1]
    plain = compile_model(task.structure, task.actuated if mode == "force_density" else None)
    st = State(q0, qd0, 0.0)
    for _ in range(task.frame_skip):                 # the old formulation: drag as an external force
        st = integrate.step(plain, st, task.dt, task.integrator, backend=task.backend,
                            external=-3.0 * node_velocities(plain, st.qd), **inputs)
    calls = []
    real = integrate.step
    monkeypatch.setattr(integrate, "step", lambda *x, **k: calls.append(k.get("n_steps")) or real(*x, **k))
    fused = []
    ctrl0 = task.ctrl.copy()
    assert task._fused
    # the fused fast path (envs/compiled.shape_step): ONE compiled call per control step that
    # runs the physics kernel for frame_skip steps (its n_steps argument), no physics.step call
    disp = task._fused[0]
    task._fused = (lambda *x: fused.append(int(x[7])) or disp(*x),) + task._fused[1:]
    env.step(a)
    assert (calls, fused) == ([], [task.frame_skip])
    assert np.abs(task.q - st.q).max() < 1e-12 and np.abs(task.qd - st.qd).max() < 1e-10
    assert np.abs(task.qd - qd0).max() > 1e-4                     # it moves
    # the reference path (no fused step): ONE physics.step call of frame_skip steps, same state
    q1, qd1 = task.q.copy(), task.qd.copy()
    task.q, task.qd, task.ctrl = q0.copy(), qd0.copy(), ctrl0
    calls.clear()
    task._fused = False
    env.step(a)
    assert calls == [task.frame_skip] and len(fused) == 1
    assert np.array_equal(task.q, q1) and np.array_equal(task.qd, qd1)
    # without drag, no drag code: the model has none
    env0 = TensegrityShapeEnv(action_mode=mode, node_damping=0.0)
    assert not env0.task.model.has_node_damping
