"""TensegrityRollMuJoCo-v0: the MuJoCo twin of TensegrityRoll-v0. SI units."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

import tensegrity_gym  # noqa: E402,F401
from tensegrity_gym.tools.baselines import RollingGait  # noqa: E402
from tensegrity_gym.envs.roll import TensegrityRollEnv  # noqa: E402
from tensegrity_gym.envs.roll_mujoco import TensegrityRollMuJoCoEnv  # noqa: E402
from twin_check import assert_same_interface  # noqa: E402


@pytest.fixture(scope="module")
def twin():
    return TensegrityRollMuJoCoEnv()


@pytest.mark.parametrize("kwargs", [{}, {"observation_mode": "robot", "history": 3},
                                    {"max_cable_acceleration": None}])
def test_spaces_equal_roll_env(kwargs):
    a, b = TensegrityRollMuJoCoEnv(**kwargs), TensegrityRollEnv(**kwargs)
    assert_same_interface(a, b)
    obs, r, term, trunc, info = a.step(a.action_space.sample())
    _, _, _, _, info_b = b.step(b.action_space.sample())
    assert set(info) == set(info_b)
    assert r == pytest.approx(info["reward_forward"] + info["reward_ctrl"])


def test_registered_with_roll_time_limit():
    env = gym.make("TensegrityRollMuJoCo-v0")
    assert env.spec.max_episode_steps == gym.spec("TensegrityRoll-v0").max_episode_steps == 1000
    assert isinstance(env.unwrapped, TensegrityRollMuJoCoEnv)


def test_resting_robot_neither_sinks_nor_slides(twin):
    """Zero actions for 2 s: no cap sinks more than 2 mm into the ground, no node moves more than 3 mm."""
    r = twin.task.contact.radius
    obs, info = twin.reset(seed=3)
    nodes0 = twin.data.site_xpos.copy()
    deepest = 0.0
    for _ in range(100):
        obs, rew, term, trunc, info = twin.step(np.zeros(9))
        assert not trunc
        deepest = max(deepest, r - twin.data.site_xpos[:, 2].min())
    moved = np.linalg.norm(twin.data.site_xpos - nodes0, axis=1).max()
    com_slide = np.linalg.norm(info["com_position"][:2] - twin.start[:2])
    print(f"deepest cap penetration {deepest * 1e3:.3f} mm, largest node displacement {moved * 1e3:.3f} mm, "
          f"centre of mass slid {com_slide * 1e3:.3f} mm")
    assert deepest < 2e-3
    assert moved < 3e-3
    assert com_slide < 3e-3
    assert np.linalg.norm(obs[18:36]) < 0.05      # node velocities have died down


def test_slack_strings_carry_no_spring_force(twin):
    """Dead band: a string shorter than its rest length adds nothing to MuJoCo's spring forces;
    a stretched one does."""
    m, d = twin.model, twin.data
    twin.reset(seed=0)
    d.qvel[:] = 0.0
    mujoco.mj_forward(m, d)
    L = d.ten_length.copy()
    saved = m.tendon_lengthspring.copy()
    try:
        for i, slack in ((0, True), (0, False), (7, True)):
            m.tendon_lengthspring[:] = saved
            m.tendon_lengthspring[i, 1] = L[i] + (0.01 if slack else -0.01)
            mujoco.mj_forward(m, d)
            f_with = d.qfrc_spring.copy()
            tension = twin.tendon_tension()[i]
            k = m.tendon_stiffness[i]
            m.tendon_stiffness[i] = 0.0
            mujoco.mj_forward(m, d)
            f_without = d.qfrc_spring.copy()
            m.tendon_stiffness[i] = k
            if slack:
                np.testing.assert_allclose(f_with, f_without, atol=1e-12)
                assert tension == 0.0
            else:
                assert np.abs(f_with - f_without).max() > 1.0
                assert tension == pytest.approx(k * 0.01)
    finally:
        m.tendon_lengthspring[:] = saved
        mujoco.mj_forward(m, d)


def test_rolling_gait_rolls_the_twin():
    """The rolling gait, trained for nothing and tuned on TensegrityRoll-v0, rolls the twin along
    its goal. The wave rolls the prism toward -x from the reset pose (on both simulators; with goal
    +x its feedback turns it round within 15-20 s), so the goal here is -x: 10 s."""
    speeds = {}
    for cls in (TensegrityRollMuJoCoEnv, TensegrityRollEnv):
        env = cls(goal_direction=(-1.0, 0.0))
        gait = RollingGait(env)
        obs, _ = env.reset(seed=0)
        state = None
        for _ in range(500):
            a, state = gait.predict(obs, state)
            obs, _, _, trunc, info = env.step(a)
            assert not trunc
        speeds[cls.__name__] = info["distance_rolled"] / 10.0
    print("speed along the goal over 10 s, m/s:", speeds)
    assert speeds["TensegrityRollMuJoCoEnv"] > 0.03
    assert speeds["TensegrityRollEnv"] > 0.03


def test_seeding_reproducible():
    def episode(seed):
        env = TensegrityRollMuJoCoEnv()
        rng = np.random.default_rng(1)
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for _ in range(30):
            out.append(env.step(rng.uniform(-1, 1, 9))[0])
        return np.array(out)
    a, b, c = episode(5), episode(5), episode(6)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-4


def test_robot_observation_imu_at_rest():
    env = TensegrityRollMuJoCoEnv(observation_mode="robot")
    lay = {n: s for n, s, _ in env.task.observation_layout()}
    env.reset(seed=0)
    for _ in range(50):
        obs, *_ = env.step(np.zeros(9))
    acc = obs[lay["imu_accel"]].reshape(3, 3)
    np.testing.assert_allclose(np.linalg.norm(acc, axis=1), 9.81, atol=0.5)   # specific force -g at rest
    assert obs[lay["contact"]].sum() >= 3                                     # resting on >= 3 caps
    d = env.data
    np.testing.assert_allclose(obs[lay["cable_length"]], d.ten_length, atol=1e-6)


@pytest.mark.parametrize("kwargs", [{"action_mode": "force_density"}, {"randomize": {"node_damping": 0.1}},
                                    {"params": {"node_damping": 0.5}}, {"action_delay": 2},
                                    {"ground_damping": 0.0, "params": {"ground_damping": 5.0}},
                                    {"spin_damping": -1.0}, {"contact_dampratio": -1.0}])
def test_unsupported_arguments_raise(kwargs):
    name = next(iter(kwargs))
    with pytest.raises(ValueError, match=name):
        TensegrityRollMuJoCoEnv(**kwargs)


def test_rk4_twin_holds_its_spin_damping_within_the_explicit_bound():
    # MuJoCo's RK4 integrates joint damping explicitly: the default 1 N m s on the rods' axial
    # inertia diverged at the first step; with RK4 the default is half the bound, more is refused
    twin = TensegrityRollMuJoCoEnv(mj_integrator="RK4", randomize=TWIN_RANDOM)
    axial = float(twin.model.body_inertia[twin._body, 2].min())
    assert twin.spin_damping == pytest.approx(0.5 * 2.785 * axial / twin.task.dt)
    assert twin.spin_damping == twin.rk4_spin_damping_max() < 1.0
    rng = np.random.default_rng(0)
    for seed in range(3):
        twin.reset(seed=seed)
        for _ in range(300):
            *_, info = twin.step(rng.uniform(-1, 1, 9))
            assert not info["diverged"]
    with pytest.raises(ValueError, match=r"spin_damping: 1.0 N m s .*mj_integrator='RK4'"):
        TensegrityRollMuJoCoEnv(mj_integrator="RK4", spin_damping=1.0)
    assert TensegrityRollMuJoCoEnv(mj_integrator="RK4", spin_damping=0.0).spin_damping == 0.0
    assert TensegrityRollMuJoCoEnv().spin_damping == 1.0


TWIN_RANDOM = {"rod_mass": 0.2, "stiffness": 0.2, "damping": 0.2, "rest_length_offset": 0.005, "friction": 0.2,
               "ground_stiffness": 0.2, "ground_damping": 0.2, "gravity": 0.05, "max_cable_speed": 0.2,
               "max_cable_acceleration": 0.2}


def _rollout(env, seed, steps=25):
    rng = np.random.default_rng(0)
    obs, info = env.reset(seed=seed)
    out = [obs]
    for _ in range(steps):
        out.append(env.step(rng.uniform(-1, 1, 9))[0])
    return np.array(out), info


def test_randomised_twin_reports_the_roll_env_draws_and_equals_fixed_params():
    """randomize= draws the same robot as TensegrityRoll-v0 for the same seed (domain.py's
    sampling from np_random), reports it in info["params"], and a twin built with params= set to
    the reported values runs the same trajectory, bit for bit; the nominal twin runs another."""
    rand = TensegrityRollMuJoCoEnv(randomize=TWIN_RANDOM)
    a, info = _rollout(rand, 5)
    p = info["params"]
    assert set(p) == set(TWIN_RANDOM)
    _, info_roll = TensegrityRollEnv(randomize=TWIN_RANDOM).reset(seed=5)
    for name in TWIN_RANDOM:
        np.testing.assert_array_equal(p[name], info_roll["params"][name])
    k0 = rand.task.structure.stiffness
    assert np.all(np.abs(p["stiffness"] / k0 - 1) <= 0.2) and np.ptp(p["stiffness"] / k0) > 0.05
    fixed = TensegrityRollMuJoCoEnv(params={n: np.asarray(v).tolist() for n, v in p.items()})
    b, info_b = _rollout(fixed, 5)
    np.testing.assert_array_equal(a, b)
    for name in TWIN_RANDOM:
        np.testing.assert_array_equal(info_b["params"][name], p[name])
    nominal, _ = _rollout(TensegrityRollMuJoCoEnv(), 5)
    assert np.abs(a - nominal).max() > 1e-3
    _, info2 = rand.reset(seed=6)                                 # a new robot at the next seed
    assert not np.array_equal(info2["params"]["rod_mass"], p["rod_mass"])


def test_params_reach_the_mujoco_model():
    base = TensegrityRollMuJoCoEnv()
    m0 = base.model
    mass0, inertia0 = m0.body_mass[base._body].copy(), m0.body_inertia[base._body].copy()
    rest0, solref0 = m0.tendon_lengthspring[:, 1].copy(), m0.geom_solref[0].copy()
    k = np.linspace(800.0, 1200.0, 9)
    env = TensegrityRollMuJoCoEnv(params={"rod_mass": [0.3, 0.2, 0.25], "stiffness": k.tolist(), "damping": 3.0,
                                          "rest_length_offset": 0.004, "friction": 0.7, "gravity": [0, 0, -5.0],
                                          "ground_stiffness": 2e4, "ground_damping": 5.0})
    m = env.model
    env.reset(seed=0)
    body = env._body
    np.testing.assert_allclose(m.body_mass[body], [0.3, 0.2, 0.25])
    np.testing.assert_allclose(m.body_inertia[body], inertia0 * (np.array([0.3, 0.2, 0.25]) / mass0)[:, None])
    np.testing.assert_allclose(m.body_subtreemass[0], 0.75)                 # mj_setConst ran
    np.testing.assert_allclose(m.tendon_stiffness, k)
    np.testing.assert_allclose(m.tendon_damping, 3.0)
    passive = np.setdiff1d(np.arange(9), env._act)
    np.testing.assert_allclose(m.tendon_lengthspring[passive, 1], rest0[passive] + 0.004)
    np.testing.assert_allclose(m.tendon_lengthspring[env._act, 1], env.task.ctrl[0] + 0.004)
    env.step(np.ones(9))                                                     # rewritten every control step
    np.testing.assert_allclose(m.tendon_lengthspring[env._act, 1], env.task.ctrl[0] + 0.004)
    np.testing.assert_allclose(m.geom_friction[:, 0], 0.7)
    np.testing.assert_allclose(m.opt.gravity, [0, 0, -5.0])
    tc = max(np.sqrt(0.2 / 4 / 2e4), 2 * env.task.dt)                      # lightest rod 0.2 kg
    np.testing.assert_allclose(m.geom_solref, np.tile([tc, 1.0 * 5.0 / 10.0], (m.ngeom, 1)))
    assert tuple(solref0) == (base.contact_timeconst, 1.0)
    heavy = TensegrityRollMuJoCoEnv(params={"rod_mass": 0.4})
    heavy.reset(seed=0)
    np.testing.assert_allclose(heavy.model.geom_solref[:, 0], np.sqrt(0.4 / 4 / 1e4))   # m_eff follows the mass


def test_friction_and_contact_softness_from_the_env():
    env = TensegrityRollMuJoCoEnv(friction=0.6, ground_stiffness=5e3)
    np.testing.assert_allclose(env.model.geom_friction[:, 0], 0.6)
    assert env.contact_timeconst == pytest.approx(np.sqrt(0.2 / 4 / 5e3))    # sqrt(m_eff / k), m_eff = m / 4
    np.testing.assert_allclose(env.model.geom_solref[:, 0], env.contact_timeconst)
    stiff = TensegrityRollMuJoCoEnv(ground_stiffness=1e5)
    assert stiff.contact_timeconst == pytest.approx(2 * stiff.task.dt)         # floored at 2 steps


def test_eval_transfer_script(tmp_path, capsys):
    import json
    import runpy
    from pathlib import Path
    script = Path(__file__).resolve().parents[1] / "scripts" / "eval" / "eval_transfer.py"
    main = runpy.run_path(str(script), run_name="eval_transfer")["main"]
    out = tmp_path / "t.json"
    assert main(["--policy", "gait", "--robots", "2", "--time", "0.2", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    assert set(data["results"]) == {"nominal", "randomised", "mujoco_twin"}
    for row in data["results"].values():
        assert len(row["per_robot_m_s"]) == 2 and np.isfinite(row["mean_m_s"])
    assert len(data["randomised_params_drawn"]["rod_mass"]) == 2
    assert "mujoco_twin" in capsys.readouterr().out
    assert main(["--robots", "0"]) == 2
    out2 = tmp_path / "t2.json"
    assert main(["--policy", "gait", "--robots", "2", "--time", "0.2", "--twin-randomised", "--out", str(out2)]) == 0
    data2 = json.loads(out2.read_text())
    assert set(data2["results"]) == {"nominal", "randomised", "mujoco_twin", "mujoco_twin_randomised"}
    for name in ("nominal", "randomised", "mujoco_twin"):     # the existing rows are unchanged by the option
        assert data2["results"][name]["per_robot_m_s"] == data["results"][name]["per_robot_m_s"]
    assert set(data2["twin_randomised_params_drawn"]) == set(data2["randomize"])
    for name in data2["twin_randomised_params_drawn"]:        # twin i is randomised robot i of (b)
        v = data2["randomised_params_drawn"][name]
        np.testing.assert_array_equal(data2["twin_randomised_params_drawn"][name], v)
    assert data2["results"]["mujoco_twin_randomised"]["per_robot_m_s"] != data2["results"]["mujoco_twin"]["per_robot_m_s"]
    with pytest.raises(SystemExit, match="no such file"):
        main(["--policy", str(tmp_path / "missing.zip"), "--robots", "1", "--time", "0.1"])


def test_render_rgb_array_follows_mujoco_state():
    env = gym.make("TensegrityRollMuJoCo-v0", render_mode="rgb_array", width=120, height=120)
    env.reset(seed=0)
    for _ in range(3):
        env.step(env.action_space.sample())
    frame = env.render()
    assert frame.shape == (120, 120, 3) and frame.dtype == np.uint8 and frame.std() > 0
    task = env.unwrapped.task
    assert len(task.paths[0]) == 4
    np.testing.assert_allclose(task.paths[0][-1], env.unwrapped.com())
    env.close()


def test_eval_transfer_uses_the_runs_observation_and_writes_a_table(tmp_path):
    """A run trained with the robot observation is evaluated with it (its robot, randomize/params,
    is the evaluation's own); --twin-robots sets the twin's episode count; --table prints one row
    per result file."""
    import json
    import runpy
    from pathlib import Path
    yaml = pytest.importorskip("yaml")
    script = Path(__file__).resolve().parents[1] / "scripts" / "eval" / "eval_transfer.py"
    ns = runpy.run_path(str(script), run_name="eval_transfer")
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text(yaml.safe_dump({"env_kwargs": {
        "observation_mode": "robot", "history": 2, "randomize": {"stiffness": 0.2}, "goal_direction": [0.0, 1.0]}}))
    assert ns["run_env_kwargs"](str(run)) == {"observation_mode": "robot", "history": 2}
    assert ns["run_env_kwargs"]("gait") == {}
    out = tmp_path / "g.json"
    assert ns["main"](["--policy", "gait", "--robots", "2", "--twin-robots", "1", "--time", "0.1", "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["twin_robots"] == 1 and len(d["results"]["mujoco_twin"]["per_robot_m_s"]) == 1
    assert len(d["results"]["randomised"]["per_robot_m_s"]) == 2
    md = tmp_path / "t.md"
    assert ns["main"](["--table", str(out), str(out), "--out", str(md)]) == 0
    text = md.read_text()
    assert text.count("| `gait` |") == 2 and "2 robots on our physics, 1 on the twin" in text
    assert ns["main"](["--robots", "2", "--twin-robots", "0"]) == 2
