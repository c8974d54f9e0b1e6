"""The MuJoCo twins on terrain: TensegrityRollMuJoCo-v0 with ``terrain=`` (fixed and drawn per
episode, written into the MjModel in place) and TensegrityNavigateMuJoCo-v0 (the navigation task's
courses, guidance, goals and rewards on MuJoCo's state); scripts/eval/eval_transfer_terrain.py. SI units."""
from __future__ import annotations

import json
import runpy
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

import tensegrity_gym  # noqa: E402,F401
from tensegrity_gym.envs.navigate_mujoco import TensegrityNavigateMuJoCoEnv  # noqa: E402
from tensegrity_gym.envs.roll_mujoco import TensegrityRollMuJoCoEnv  # noqa: E402
from tensegrity_gym.envs.twin_terrain import BVH_FIELDS, FLOOR_GAP, GEOM_FIELDS, world_geoms  # noqa: E402

BLOCK = {"boxes": [{"center": [0.0, 0.0, 0.05], "size": [2.0, 2.0, 0.1]}]}
ROUGH = {"generator": "rough", "size": 3.0, "cell": 0.1, "amplitude": 0.03}
STEPS = {"generator": "steps", "step_height": 0.05, "n_steps": 3}


def _ray_height(m, d, x, y):
    """Height of the first surface MuJoCo's ray meets going down from z = 50 m at (x, y)."""
    gid = np.zeros(1, np.int32)
    dist = mujoco.mj_ray(m, d, np.array([x, y, 50.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, gid)
    return 50.0 - dist if dist >= 0 else -np.inf


def _far_points(rng, half, n=8):
    """``n`` points (x, y) in [-half, half]^2 at least 0.6 m from the robot at the origin."""
    p = rng.uniform(-half, half, (4 * n, 2))
    return p[np.hypot(*p.T) > 0.6][:n]


def test_level_ground_terrain_is_the_floor_scene():
    a, b = TensegrityRollMuJoCoEnv(), TensegrityRollMuJoCoEnv(terrain={})
    assert a.task.terrains is None and b.task.terrains is None
    assert [a.model.geom(i).name for i in world_geoms(a.model)] == ["ground"]
    obs_a, _ = a.reset(seed=2)
    obs_b, _ = b.reset(seed=2)
    np.testing.assert_array_equal(obs_a, obs_b)


def test_robot_started_over_a_block_stays_on_it():
    env = TensegrityRollMuJoCoEnv(terrain=BLOCK)
    m, d, r = env.model, env.data, env.task.contact.radius
    names = [m.geom(i).name for i in world_geoms(m)]
    assert names == ["terrain_plane", "terrain_box0"]
    obs, info = env.reset(seed=0)
    assert d.site_xpos[:, 2].min() - r >= 0.1 - 1e-9          # lifted clear of the block's top
    lay = {name: sl for name, sl, _ in env.task.observation_layout()}
    for _ in range(50):                                       # 1 s at rest
        obs, rew, term, trunc, info = env.step(np.zeros(env.action_space.shape))
        assert not trunc
    assert d.site_xpos[:, 2].min() - r > 0.1 - 2e-3           # resting on the top, not sunk through it
    assert info["com_position"][2] > 0.1 + r
    assert np.linalg.norm(info["com_position"][:2] - env.start[:2]) < 5e-3
    flags = obs[lay["contact"]]
    assert flags.sum() >= 3                                   # ends touching the block (MuJoCo's contacts)
    # every rod-terrain contact is with the block
    box = m.geom("terrain_box0").id
    touching = {int(g) for g in d.contact.geom[:d.ncon].ravel()} & set(world_geoms(m).tolist())
    assert touching == {box}


def test_terrain_parts_keep_their_friction():
    env = TensegrityRollMuJoCoEnv(terrain={"friction": 0.4, "boxes": [{"center": [2, 0, 0], "size": [1, 1, 0.2],
                                                                        "friction": 0.7}]}, friction=0.9)
    m = env.model
    g = world_geoms(m)
    np.testing.assert_allclose(m.geom_friction[g, 0], [0.4, 0.7])
    rods = [m.geom(f"rod{j}").id for j in range(env.task.structure.n_bars)]
    assert np.all(m.geom_friction[rods, 0] == 0.0)            # MuJoCo takes the larger: the part's governs
    env.reset(seed=0)
    np.testing.assert_allclose(m.geom_friction[g, 0], [0.4, 0.7])
    rnd = TensegrityRollMuJoCoEnv(terrain=BLOCK, randomize={"friction": 0.3})
    _, info = rnd.reset(seed=1)
    np.testing.assert_allclose(rnd.model.geom_friction[:, 0], info["params"]["friction"])


@pytest.mark.parametrize("terrain", [STEPS, ROUGH])
def test_generator_terrain_changes_per_reset_as_the_project_env(terrain):
    """The same reset seed draws the same terrain on the twin and on TensegrityRoll-v0; the twin's
    MjModel holds it (in place: equal to a fresh compile of that terrain's scene) and changes with it."""
    twin = TensegrityRollMuJoCoEnv(terrain=terrain)
    roll = gym.make("TensegrityRoll-v0", terrain=terrain)
    m = twin.model
    g = world_geoms(m)
    seen = []
    for seed in (0, 1):
        twin.reset(seed=seed)
        roll.reset(seed=seed)
        a, b = twin.task.terrains[0], roll.unwrapped.task.terrains[0]
        assert len(a.boxes) == len(b.boxes)
        for x, y in zip(a.boxes, b.boxes):
            np.testing.assert_array_equal(x.center, y.center)
            np.testing.assert_array_equal(x.size, y.size)
            assert x.yaw_deg == y.yaw_deg
        if a.heightfield is not None:
            np.testing.assert_array_equal(a.heightfield.heights, b.heightfield.heights)
        # the model's geoms are this terrain: the boxes' centres and half sizes, and a fresh compile's numbers
        boxes = [i for i in g if m.geom(i).name.startswith("terrain_box")]
        for i, box in zip(boxes, a.boxes):
            np.testing.assert_allclose(m.geom_pos[i], box.center)
            np.testing.assert_allclose(m.geom_size[i], box.size / 2)
        fresh = mujoco.MjModel.from_xml_string(twin._terrain_xml(a))
        for name in GEOM_FIELDS:
            np.testing.assert_array_equal(getattr(m, name)[g], getattr(fresh, name)[g], err_msg=name)
        np.testing.assert_array_equal(m.hfield_size, fresh.hfield_size)
        np.testing.assert_array_equal(m.hfield_data, fresh.hfield_data)
        for name in BVH_FIELDS:
            np.testing.assert_array_equal(getattr(m, name), getattr(fresh, name), err_msg=name)
        seen.append(np.concatenate([m.geom_pos[g].ravel(), m.geom_size[g].ravel(), m.hfield_data.ravel()]))
    assert not np.array_equal(seen[0], seen[1])
    roll.close()


@pytest.mark.parametrize("terrain", [STEPS, ROUGH])
def test_twin_terrain_heights_equal_height_at(terrain):
    """MuJoCo's surface (by mj_ray) is Terrain.height_at after each reset's in-place update (a
    heightfield: MuJoCo's triangles against our bilinear cells, within a few mm)."""
    env = TensegrityRollMuJoCoEnv(terrain=terrain)
    rng = np.random.default_rng(0)
    for seed in (3, 4):
        env.reset(seed=seed)
        ter = env.task.terrains[0]
        pts = _far_points(rng, 1.4)
        for x, y in pts:
            want = float(ter.height_at(x, y))
            assert abs(_ray_height(env.model, env.data, x, y) - want) < 3e-3, (seed, x, y, want)
        if terrain is STEPS:   # on a step's top, away from its edges: exact
            b = ter.boxes[1]
            x, y = b.center[0], b.center[1] + 0.5
            assert _ray_height(env.model, env.data, x, y) == pytest.approx(b.center[2] + b.size[2] / 2, abs=1e-9)


def test_floor_beyond_a_heightfield_without_a_plane():
    """A course's heightfield ends at its grid in MuJoCo: the scene's floor, 1 mm under its lowest
    point, holds the robot beyond it, where our heightfield holds its edge values (0)."""
    env = gym.make("TensegrityNavigateMuJoCo-v0")
    env.reset(seed=1)
    u = env.unwrapped
    m, ter = u.model, u.task.terrains[0]
    assert ter.plane is None and m.geom("terrain_floor").id in world_geoms(m)
    assert m.geom_pos[m.geom("terrain_floor").id][2] == pytest.approx(ter.heightfield.heights.min() - FLOOR_GAP)
    edge = -ter.heightfield.origin[0] + 1.0                  # 1 m beyond the grid
    for x, y in ((edge, 0.0), (0.0, -edge), (edge, edge)):
        assert float(ter.height_at(x, y)) == 0.0
        assert _ray_height(m, u.data, x, y) == pytest.approx(-FLOOR_GAP, abs=1e-9)
    adr = m.jnt_qposadr[m.body_jntadr[u._body]]
    for a in adr:                                            # the robot beyond the grid
        u.data.qpos[a:a + 3] += [edge, edge, 0.002]
    mujoco.mj_forward(m, u.data)
    for _ in range(25):
        *_, trunc, info = env.step(np.zeros(env.action_space.shape))
        assert not trunc
    assert info["com_position"][2] > 0.05                    # standing on the floor, not fallen
    env.close()


def test_navigation_twin_course_spaces_and_info_as_the_project_env():
    twin = gym.make("TensegrityNavigateMuJoCo-v0")
    nav = gym.make("TensegrityNavigate-v0")
    assert twin.spec.max_episode_steps == nav.spec.max_episode_steps == 3000
    assert isinstance(twin.unwrapped, TensegrityNavigateMuJoCoEnv)
    assert twin.observation_space == nav.observation_space and twin.action_space == nav.action_space
    t, n = twin.unwrapped.task, nav.unwrapped.task
    assert t.observation_layout() == n.observation_layout()
    obs, info = twin.reset(seed=5)
    _, info_n = nav.reset(seed=5)
    assert set(info) == set(info_n)
    np.testing.assert_array_equal(t.courses[0].goals, n.courses[0].goals)
    # the same guidance and path from the start, which differs by MuJoCo's resting depth (< 1 mm)
    np.testing.assert_allclose(info["goal_direction"], info_n["goal_direction"], atol=1e-3)
    assert abs(info["path_distance"] - info_n["path_distance"]) <= 0.15    # at most one grid cell
    m = twin.unwrapped.model
    boxes = [i for i in world_geoms(m) if m.geom(i).name.startswith("terrain_box")]
    assert len(boxes) == len(n.courses[0].terrain.boxes)
    for i, box in zip(boxes, n.courses[0].terrain.boxes):
        np.testing.assert_allclose(m.geom_pos[i], box.center)
    lay = {name: sl for name, sl, _ in t.observation_layout()}
    assert obs[lay["goals_left"]][0] == 3
    for _ in range(5):
        obs, r, term, trunc, info = twin.step(twin.action_space.sample())
        assert not trunc and np.isfinite(obs).all()
    _, _, _, _, info_n = nav.step(nav.action_space.sample())
    assert set(info) == set(info_n)
    assert r == pytest.approx(info["reward_forward"] + info["reward_ctrl"] + info["reward_goal"])
    twin.close()
    nav.close()


def _put_on_goal(env):
    """Move the twin's robot (MuJoCo's free joints) over its current goal, 3 cm up (clear of a rough patch)."""
    u = env.unwrapped
    goal = u.task.courses[0].goals[u.task.goal_index[0]]
    adr = u.model.jnt_qposadr[u.model.body_jntadr[u._body]]
    shift = np.array([*(goal - u.com()[:2]), 0.03])
    for a in adr:
        u.data.qpos[a:a + 3] += shift
    mujoco.mj_forward(u.model, u.data)


def test_navigation_twin_goal_bonus_and_success():
    env = gym.make("TensegrityNavigateMuJoCo-v0")
    obs, _ = env.reset(seed=3)
    lay = {name: sl for name, sl, _ in env.unwrapped.task.observation_layout()}
    _put_on_goal(env)
    obs, r, term, trunc, info = env.step(np.zeros(env.action_space.shape))
    assert info["goal_reached"] and info["goals_reached"] == 1 and info["reward_goal"] == 10.0
    assert not term and obs[lay["goals_left"]][0] == 2
    env.close()
    one = gym.make("TensegrityNavigateMuJoCo-v0", n_goals=1)
    one.reset(seed=0)
    _put_on_goal(one)
    *_, term, trunc, info = one.step(np.zeros(one.action_space.shape))
    assert term and info["success"] and info["path_distance"] == 0.0
    one.close()


def test_eval_transfer_terrain_script(tmp_path, capsys):
    script = Path(__file__).resolve().parents[1] / "scripts" / "eval" / "eval_transfer_terrain.py"
    main = runpy.run_path(str(script), run_name="eval_transfer_terrain")["main"]
    out = tmp_path / "nav.json"
    assert main(["gait", "--courses", "2", "--steps", "20", "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["mode"] == "navigate" and d["reset_seeds"] == [20000, 20001]
    row = d["results"]["gait"]
    assert len(row["project"]["success"]) == len(row["twin"]["success"]) == 2
    assert "TensegrityNavigateMuJoCo-v0" in capsys.readouterr().out
    out2 = tmp_path / "steps.json"
    assert main(["gait", "--terrain", json.dumps(STEPS), "--episodes", "2", "--steps", "25", "--out", str(out2)]) == 0
    d2 = json.loads(out2.read_text())
    row = d2["results"]["gait"]
    assert d2["mode"] == "terrain" and row["env_kwargs"]["terrain"] == STEPS
    assert len(row["twin"]["speed_m_s"]) == 2 and np.isfinite(row["project"]["metric"])
    assert row["ratio_twin_project"] == pytest.approx(row["twin"]["metric"] / row["project"]["metric"])
    assert main(["gait", "--courses", "0", "--out", str(out)]) == 2
    with pytest.raises(SystemExit, match="neither 'gait' nor a run folder"):
        main([str(tmp_path), "--out", str(out)])


def test_eval_transfer_terrain_with_a_trained_run(tmp_path):
    """A run of agents.train (PPO, a few hundred steps on TensegrityNavigate-v0) evaluated on both."""
    pytest.importorskip("stable_baselines3")
    from agents import train
    run = tmp_path / "run"
    train.train(["--algo", "ppo", "--env", "TensegrityNavigate-v0", "--log-dir", str(run), "--n-timesteps", "64",
                 "--n-envs", "2", "--eval-freq", "-1", "--save-freq", "-1", "--no-progress-bar",
                 "--hyperparams", "n_steps=32", "batch_size=64", "n_epochs=1", "policy_kwargs=dict(net_arch=[16])"])
    script = Path(__file__).resolve().parents[1] / "scripts" / "eval" / "eval_transfer_terrain.py"
    main = runpy.run_path(str(script), run_name="eval_transfer_terrain")["main"]
    out = tmp_path / "t.json"
    assert main([str(run), "--courses", "1", "--steps", "10", "--out", str(out)]) == 0
    row = json.loads(out.read_text())["results"][str(run)]
    assert len(row["project"]["goals_reached"]) == len(row["twin"]["goals_reached"]) == 1
