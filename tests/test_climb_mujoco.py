"""TensegrityClimbMuJoCo-v0: the MuJoCo twin of TensegrityClimb-v0 (the slope as MuJoCo's gravity in
the plane frame); scripts/eval/eval_transfer_terrain.py --slopes. SI units, angles in degrees."""
from __future__ import annotations

import json
import runpy
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

import tensegrity_gym  # noqa: E402,F401
from tensegrity_gym.tools.baselines import RollingGait  # noqa: E402
from tensegrity_gym.envs.climb import TensegrityClimbEnv  # noqa: E402
from tensegrity_gym.envs.climb_mujoco import TensegrityClimbMuJoCoEnv  # noqa: E402
from tensegrity_gym.envs import twin_model  # noqa: E402
from tensegrity_gym.envs.roll_mujoco import TensegrityRollMuJoCoEnv  # noqa: E402
from tensegrity_gym.tasks.climb import plane_gravity  # noqa: E402
from twin_check import assert_same_interface  # noqa: E402


def test_registered_with_the_climb_time_limit():
    env = gym.make("TensegrityClimbMuJoCo-v0", slope_deg=10.0)
    assert env.spec.max_episode_steps == gym.spec("TensegrityClimb-v0").max_episode_steps == 1000
    assert isinstance(env.unwrapped, TensegrityClimbMuJoCoEnv)
    env.reset(seed=0)
    np.testing.assert_allclose(env.unwrapped.model.opt.gravity, plane_gravity(10.0, 9.81), atol=1e-12)


@pytest.mark.parametrize("kwargs", [{}, {"slope_range": (0.0, 30.0)}, {"observation_mode": "robot", "history": 2},
                                    {"structure": "prism", "slope_deg": 5.0, "max_cable_acceleration": None}])
def test_spaces_layout_and_info_keys_equal_the_project_env(kwargs):
    a, b = TensegrityClimbMuJoCoEnv(**kwargs), TensegrityClimbEnv(**kwargs)
    assert_same_interface(a, b)
    _, r, _, _, info = a.step(a.action_space.sample())
    _, _, _, _, info_b = b.step(b.action_space.sample())
    assert set(info) == set(info_b)
    assert r == pytest.approx(info["reward_forward"] + info["reward_ctrl"])
    assert info["uphill_velocity"] == info["forward_velocity"] and info["slope_deg"] == info_b["slope_deg"]


def test_same_slope_for_the_same_seed_as_the_project_env():
    twin, project = (TensegrityClimbMuJoCoEnv(slope_range=(0.0, 30.0)), TensegrityClimbEnv(slope_range=(0.0, 30.0)))
    slopes = []
    for seed in range(5):
        obs, info = twin.reset(seed=seed)
        obs_p, info_p = project.reset(seed=seed)
        assert info["slope_deg"] == info_p["slope_deg"]
        g = plane_gravity(info["slope_deg"], 9.81)
        np.testing.assert_allclose(twin.model.opt.gravity, g, atol=1e-12)
        np.testing.assert_allclose(project.task.params.gravity[0], g, atol=1e-12)
        np.testing.assert_array_equal(obs[-3:], obs_p[-3:])                # gravity_direction
        slopes.append(info["slope_deg"])
    assert np.unique(slopes).size == 5


def test_level_slope_is_the_rolling_twin_bit_for_bit():
    climb, roll = TensegrityClimbMuJoCoEnv(slope_deg=0.0), TensegrityRollMuJoCoEnv()
    o_c, _ = climb.reset(seed=2)
    o_r, _ = roll.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(30):
        a = rng.uniform(-1, 1, 9)
        o_c, r_c, _, _, info = climb.step(a)
        o_r, r_r, _, _, _ = roll.step(a)
        np.testing.assert_array_equal(o_c[:-3], o_r)
        assert r_c == r_r
    np.testing.assert_array_equal(o_c[-3:], np.float32([0, 0, -1]))


def _passive_slide(cls, friction, slope=20.0, seconds=1.0):
    """Distance along the slope (m, uphill +) after each control step of the robot holding its cables."""
    env = cls(slope_deg=slope, friction=friction, reset_noise_scale=0.0)
    env.reset(seed=0)
    hold = np.zeros(env.action_space.shape, np.float32)
    return np.array([env.step(hold)[4]["distance_rolled"] for _ in range(int(round(seconds / env.dt)))])


def test_friction_holds_the_robot_below_the_friction_angle():
    """tan 20 deg = 0.36 < 1: static friction holds it. MuJoCo's static friction is soft (a slow
    creep downhill, 1.6 mm in 2 s here; the project's stick spring: 0.9 mm), so 3 mm in 2 s."""
    x = _passive_slide(TensegrityClimbMuJoCoEnv, friction=1.0, seconds=2.0)
    print(f"twin: largest displacement along the slope in 2 s {np.abs(x).max() * 1e3:.2f} mm")
    assert np.abs(x).max() < 3e-3


def test_a_slippery_slope_slides_at_g_sin_minus_mu_cos():
    """Above the friction angle (mu = 0.2 < tan 20 deg) it slides as a block: 1.51 m/s^2 down the
    slope (the twin: 1.49, the project 1.51)."""
    mu, a = 0.2, np.radians(20.0)
    x = _passive_slide(TensegrityClimbMuJoCoEnv, friction=mu, seconds=0.6)
    t = 0.02 * np.arange(1, x.size + 1)
    acc = -2.0 * np.polyfit(t[10:], x[10:], 2)[0]          # fitted x = x0 + v0 t - a t^2 / 2
    print(f"twin: sliding acceleration {acc:.3f} m/s^2")
    assert acc == pytest.approx(9.81 * (np.sin(a) - mu * np.cos(a)), rel=0.1)


def test_rolling_gait_on_level_ground_moves_as_on_the_project_env():
    """The rolling gait on 0 degrees for 10 s: it rolls the prism toward -x from the reset pose on
    both simulators (its feedback turns it uphill, +x, only after 10-20 s). Displacement along x
    over 10 s: twin -1.57 m, project -1.37 m; asserted: both roll the same way at > 0.05 m/s and
    within a factor 1.5 of each other."""
    moved = {}
    for cls in (TensegrityClimbMuJoCoEnv, TensegrityClimbEnv):
        env = cls(slope_deg=0.0)
        gait = RollingGait(env)
        obs, info = env.reset(seed=0)
        x0, state = info["com_position"][0], None
        for _ in range(500):
            a, state = gait.predict(obs, state)
            obs, _, _, trunc, info = env.step(a)
            assert not trunc
        moved[cls.__name__] = float(info["com_position"][0] - x0)
    print("displacement along x over 10 s, m:", moved)
    twin, project = moved["TensegrityClimbMuJoCoEnv"], moved["TensegrityClimbEnv"]
    assert twin < -0.5 and project < -0.5
    assert 1 / 1.5 < twin / project < 1.5


@pytest.mark.parametrize("kw, match", [
    (dict(slope_deg=-1.0), "slope_deg"), (dict(slope_deg=75.0), "slope_deg"), (dict(slope_deg="steep"), "slope_deg"),
    (dict(slope_range=(30.0, 10.0)), "slope_range"), (dict(slope_range=(0.0, 99.0)), r"slope_range\[1\]"),
    (dict(randomize_goal=True), "randomize_goal"), (dict(goal_direction=(0.0, 1.0)), "goal_direction"),
    (dict(params={"gravity": [0, 0, -3.7]}), "gravity"), (dict(terrain={"generator": "steps"}), "terrain"),
    (dict(action_mode="force_density"), "action_mode"), (dict(params={"node_damping": 0.5}), "node_damping"),
    (dict(spin_damping=-1.0), "spin_damping"), (dict(action_delay=2), "action_delay"),
])
def test_bad_arguments_are_named(kw, match):
    with pytest.raises(ValueError, match=match):
        gym.make("TensegrityClimbMuJoCo-v0", **kw)


def _transfer_main():
    """``main`` of scripts/eval/eval_transfer_terrain.py."""
    script = Path(__file__).resolve().parents[1] / "scripts" / "eval" / "eval_transfer_terrain.py"
    return runpy.run_path(str(script), run_name="eval_transfer_terrain")["main"]


def test_eval_transfer_terrain_climb_mode(tmp_path, capsys):
    main = _transfer_main()
    out = tmp_path / "climb.json"
    assert main(["gait", "--slopes", "0", "10", "--episodes", "2", "--steps", "25", "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["mode"] == "climb" and d["reset_seeds"] == [40000, 40001] and d["slopes_deg"] == [0.0, 10.0]
    assert (d["project_env"], d["twin_env"]) == ("TensegrityClimb-v0", "TensegrityClimbMuJoCo-v0")
    res = d["results"]["gait"]
    assert set(res["slopes"]) == {"0", "10"}
    row = res["slopes"]["10"]
    assert row["env_kwargs"] == {"slope_deg": 10.0, "slope_range": None}
    assert len(row["project"]["speed_m_s"]) == len(row["twin"]["speed_m_s"]) == 2
    assert row["ratio_twin_project"] == pytest.approx(row["twin"]["metric"] / row["project"]["metric"])
    ratios = [r["ratio_twin_project"] for r in res["slopes"].values()]
    assert res["mean_ratio_twin_project"] == pytest.approx(np.mean(ratios))
    assert "TensegrityClimbMuJoCo-v0" in capsys.readouterr().out
    assert main(["gait", "--slopes", "0", "--terrain", "{}", "--out", str(out)]) == 2
    assert main(["gait", "--slopes", "75", "--out", str(out)]) == 2


def test_eval_transfer_terrain_twin_kwargs_reach_the_twin_only(tmp_path):
    main = _transfer_main()
    args = ["gait", "--slopes", "20", "--episodes", "1", "--steps", "25"]
    assert main(args + ["--out", str(tmp_path / "a.json")]) == 0
    assert main(args + ["--twin-kwargs", '{"spin_damping": 0.0}', "--out", str(tmp_path / "b.json")]) == 0
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json"))
    assert (a["twin_kwargs"], b["twin_kwargs"]) == ({}, {"spin_damping": 0.0})
    ra, rb = a["results"]["gait"]["slopes"]["20"], b["results"]["gait"]["slopes"]["20"]
    assert ra["project"]["speed_m_s"] == rb["project"]["speed_m_s"]      # the project env never sees them
    assert ra["twin"]["speed_m_s"] != rb["twin"]["speed_m_s"]            # the twin's rods spin freely
    with pytest.raises(SystemExit, match="TensegrityClimbMuJoCo-v0: contact_dampratio: must be positive"):
        main(args + ["--twin-kwargs", '{"contact_dampratio": -1}', "--out", str(tmp_path / "c.json")])
    with pytest.raises(SystemExit, match="--twin-kwargs: expected a JSON object"):
        main(args + ["--twin-kwargs", "[1]", "--out", str(tmp_path / "c.json")])
    assert not (tmp_path / "c.json").exists()


def test_eval_transfer_terrain_names_diverged_episodes(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)     # MuJoCo writes its warning log into the working directory
    main = _transfer_main()
    # RK4's spin damping let past its explicit bound: MuJoCo's own instability, which the twin flags
    monkeypatch.setattr(twin_model, "RK4_DAMPING_BOUND", 100.0)
    args = ["gait", "--slopes", "20", "--episodes", "2", "--steps", "5", "--out", str(tmp_path / "d.json")]
    assert main(args + ["--twin-kwargs", '{"mj_integrator": "RK4"}']) == 0
    out = capsys.readouterr().out
    assert "DIVERGED: TensegrityClimbMuJoCo-v0 2 of 2 episodes" in out
    row = json.loads((tmp_path / "d.json").read_text())["results"]["gait"]["slopes"]["20"]
    assert row["twin"]["diverged"] == [True] * 2 and row["project"]["diverged"] == [False] * 2
    assert main(args) == 0
    assert "DIVERGED" not in capsys.readouterr().out
