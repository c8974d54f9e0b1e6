"""TensegrityNavigate-v0: courses are reproducible, solvable and clear of the start and the goals;
the planner's guidance leads around the walls to each goal; goals are reached in turn with their
bonus; wrong arguments are refused by name."""
import gymnasium as gym
import numpy as np
import pytest

import tensegrity_gym  # noqa: F401
from tensegrity_gym.envs.navigate import NavigateTask, TensegrityNavigateVectorEnv
from tensegrity_gym.tasks.navigate import CourseSpec, draw_course, guidance
from tensegrity_gym.tools.baselines import RollingGait


def test_course_is_reproducible_and_keeps_its_clearances():
    spec = CourseSpec()
    a, b = draw_course(spec, np.random.default_rng(7)), draw_course(spec, np.random.default_rng(7))
    assert np.array_equal(a.goals, b.goals) and np.array_equal(a.field, b.field)
    assert not np.array_equal(a.goals, draw_course(spec, np.random.default_rng(8)).goals)
    assert a.goals.shape == (3, 2) and np.all(np.abs(a.goals) <= spec.arena)
    assert len(a.terrain.boxes) == 5 and a.terrain.heightfield is not None
    keep = np.vstack([np.zeros((1, 2)), a.goals])
    for box in a.terrain.boxes:
        reach = 0.5 * np.hypot(*box.size[:2])
        assert np.min(np.linalg.norm(keep - box.center[:2], axis=1)) - reach >= spec.clearance - 1e-12
        assert box.size[2] == spec.obstacle_height


def test_course_parts_equal_their_full_grid_forms():
    """The planner's graph (the full grid's canonical CSR, filtered), the walls' blocked cells and
    the rough patches (computed on the square each can reach) equal their straightforward forms
    over the whole grid: a coo graph of the free cells' edges, every cell's distance to every wall,
    every patch's heights everywhere."""
    import math

    from scipy.sparse import coo_matrix

    from tensegrity_gym.tasks import navigate as nav
    rng = np.random.default_rng(3)
    for trial in range(6):
        spec = CourseSpec() if trial < 4 else CourseSpec(arena=2.0, cell=0.07 + 0.01 * trial)
        xs, ys = nav._grid(spec)
        X, Y = np.meshgrid(xs, ys)
        blocked = rng.uniform(size=X.shape) < 0.2 * (trial % 4)
        ny, nx = blocked.shape
        idx = np.arange(ny * nx).reshape(ny, nx)
        rows, cols, w = [], [], []
        for dj, di in ((0, 1), (1, 0), (1, 1), (1, -1)):
            a = idx[max(0, -dj):ny - max(0, dj), max(0, -di):nx - max(0, di)]
            b = idx[max(0, dj):max(0, dj) + a.shape[0], max(0, di):max(0, di) + a.shape[1]]
            ok = ~blocked.reshape(-1)[a] & ~blocked.reshape(-1)[b]
            rows.append(a[ok])
            cols.append(b[ok])
            w.append(np.full(ok.sum(), spec.cell * math.hypot(dj, di)))
        r, c, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
        ref = coo_matrix((np.concatenate([ww, ww]), (np.concatenate([r, c]), np.concatenate([c, r]))),
                         shape=(ny * nx, ny * nx)).tocsr()
        ref.sort_indices()
        G = nav._graph(blocked, spec.cell)
        assert G.has_sorted_indices
        for x, y in ((G.indptr, ref.indptr), (G.indices, ref.indices), (G.data, ref.data)):
            assert np.array_equal(x, y)
    for seed in range(6):
        spec = CourseSpec() if seed < 4 else CourseSpec(arena=2.0, cell=0.07, inflate=0.2, rough_radius=(0.2, 0.9))
        xs, ys = nav._grid(spec)
        X, Y = np.meshgrid(xs, ys)
        rng = np.random.default_rng(seed)
        boxes = nav._place_walls(spec, rng, np.zeros((1, 2)))
        full = np.zeros(X.shape, bool)
        for bx in boxes:
            cs, sn = math.cos(math.radians(bx.yaw_deg)), math.sin(math.radians(bx.yaw_deg))
            dx, dy = X - bx.center[0], Y - bx.center[1]
            u = np.abs(cs * dx + sn * dy) - bx.size[0] / 2
            v = np.abs(-sn * dx + cs * dy) - bx.size[1] / 2
            full |= np.hypot(np.maximum(u, 0.0), np.maximum(v, 0.0)) <= spec.inflate
        assert full.any() and np.array_equal(nav._blocked(spec, boxes, X, Y), full)
        state = rng.bit_generator.state
        h, centres = nav._rough(spec, rng, X, Y)
        rng.bit_generator.state = state
        k, ref = 2 * np.pi / spec.rough_wavelength, np.zeros(X.shape)
        for _ in range(spec.n_rough):
            cx, cy = rng.uniform(-spec.arena, spec.arena, 2)
            rad = rng.uniform(*spec.rough_radius)
            ang, ph = rng.uniform(0.0, 2 * np.pi, 4), rng.uniform(0.0, 2 * np.pi, 4)
            z = (sum(np.cos(k * (np.cos(a) * X + np.sin(a) * Y) + p) for a, p in zip(ang, ph)) + 4.0) / 8.0
            fade = np.clip((rad - np.hypot(X - cx, Y - cy)) / (0.25 * rad), 0.0, 1.0)
            ref = np.maximum(ref, spec.rough_amplitude * z * fade)
        assert (h > 0).any() and np.array_equal(h, ref)


@pytest.mark.parametrize("seed", range(5))
def test_guidance_leads_around_the_walls_to_every_goal(seed):
    spec = CourseSpec()
    c = draw_course(spec, np.random.default_rng(seed))
    p = np.zeros(2)
    for g in range(spec.n_goals):
        for _ in range(400):
            d, _ = guidance(c, g, p)
            p = p + 0.05 * d
            # never on a wall: the terrain under the path is the ground or a rough patch, not a wall top
            assert c.terrain.height_at(*p) < 0.1
            if np.hypot(*(c.goals[g] - p)) <= spec.goal_radius:
                break
        assert np.hypot(*(c.goals[g] - p)) <= spec.goal_radius


def test_unsolvable_course_spec_is_refused():
    # goals farther apart than the arena allows; walls too large to keep clear of the goals
    for kw in (dict(goal_distance=(10.0, 12.0)), dict(arena=1.0, obstacle_size=(1.5, 2.0))):
        with pytest.raises(ValueError, match="course: no solvable course"):
            draw_course(CourseSpec(**kw), np.random.default_rng(0))
        with pytest.raises(ValueError, match="course: no solvable course"):
            NavigateTask(**kw)


def test_env_observation_info_and_goal_bonus():
    env = gym.make("TensegrityNavigate-v0")
    roll = gym.make("TensegrityRoll-v0")
    assert env.spec.max_episode_steps == 3000
    obs, info = env.reset(seed=3)
    assert obs.shape == (roll.observation_space.shape[0] + 2,) == env.observation_space.shape
    task = env.unwrapped.task
    assert np.allclose(np.linalg.norm(task.goal[0]), 1.0) and info["path_distance"] > 0
    lay = {name: sl for name, sl, _ in task.observation_layout()}
    assert obs[lay["goals_left"]][0] == 3 and obs[lay["path_distance"]][0] == pytest.approx(task.path[0], rel=1e-6)
    # put the robot on the first goal: the next step reaches it, pays the bonus, guides to the second
    goal = task.courses[0].goals[0]
    com = task._com(task.q)[0]
    task.q[0, :, :2] += goal - com[:2]
    obs, r, term, trunc, info = env.step(np.zeros(env.action_space.shape))
    assert info["goal_reached"] and info["goals_reached"] == 1 and info["reward_goal"] == 10.0
    assert not term and obs[lay["goals_left"]][0] == 2
    roll.close()
    env.close()


def test_success_terminates_the_episode():
    env = gym.make("TensegrityNavigate-v0", n_goals=1)
    env.reset(seed=0)
    task = env.unwrapped.task
    task.q[0, :, :2] += task.courses[0].goals[0] - task._com(task.q)[0, :2]
    *_, term, trunc, info = env.step(np.zeros(env.action_space.shape))
    assert term and info["success"] and info["path_distance"] == 0.0


def test_vector_env_equals_single_envs():
    n, seed = 2, 11
    vec = TensegrityNavigateVectorEnv(num_envs=n)
    obs_v, _ = vec.reset(seed=seed)
    singles = [gym.make("TensegrityNavigate-v0") for _ in range(n)]
    obs_s = np.array([e.reset(seed=seed + i)[0] for i, e in enumerate(singles)])
    np.testing.assert_array_equal(obs_v, obs_s)
    rng = np.random.default_rng(0)
    for _ in range(5):
        act = rng.uniform(-1, 1, (n,) + singles[0].action_space.shape).astype(np.float32)
        obs_v, *_ = vec.step(act)
        obs_s = np.array([e.step(act[i])[0] for i, e in enumerate(singles)])
    np.testing.assert_array_equal(obs_v, obs_s)


def test_height_scan_observes_the_walls():
    env = gym.make("TensegrityNavigate-v0", height_scan=(5, 0.3))
    obs, _ = env.reset(seed=0)
    task = env.unwrapped.task
    lay = {name: sl for name, sl, _ in task.observation_layout()}
    scan = obs[lay["height_scan"]]
    assert scan.shape == (25,) and env.observation_space.shape[0] == obs.shape[0]
    # move the robot next to a wall: the scan reads its height
    box = task.terrains[0].boxes[0]
    task.q[0, :, :2] += box.center[:2] + np.array([0.45, 0.0]) - task._com(task.q)[0, :2]
    assert task.observe()[0, lay["height_scan"]].max() == pytest.approx(box.size[2], abs=0.03)


def test_rolling_gait_drives_the_navigation_env():
    env = gym.make("TensegrityNavigate-v0")
    obs, _ = env.reset(seed=1)
    gait = RollingGait(env)
    st = None
    for _ in range(20):
        a, st = gait.predict(obs[None], st)
        obs, *_ = env.step(a[0])
    assert np.isfinite(obs).all()


@pytest.mark.parametrize("kw, match", [
    (dict(n_goals=0), "n_goals"),
    (dict(goal_distance=(2.0, 1.0)), "goal_distance"),
    (dict(goal_radius=-0.1), "goal_radius"),
    (dict(n_obstacles=1.5), "n_obstacles"),
    (dict(rough_amplitude=float("nan")), "rough_amplitude"),
    (dict(height_scan=(0, 0.1)), "height_scan"),
    (dict(height_scan=3), "height_scan"),
    (dict(terrain={"generator": "steps"}), "terrain: the ground of TensegrityNavigate-v0"),
    (dict(randomize_goal=True), "randomize_goal"),
])
def test_bad_arguments_are_named(kw, match):
    with pytest.raises(ValueError, match=match):
        NavigateTask(**kw)


def test_state_observation_is_in_the_guidance_frame():
    from tensegrity_gym.physics.geometry import node_velocities
    from tensegrity_gym.tasks.navigate import guidance_frame
    env = gym.make("TensegrityNavigate-v0")
    obs, _ = env.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(10):
        obs, *_ = env.step(rng.uniform(-1, 1, env.action_space.shape))
    task = env.unwrapped.task
    lay = {name: sl for name, sl, _ in task.observation_layout()}
    assert obs[lay["goal_direction"]].tolist() == [1.0, 0.0]
    vel = node_velocities(task.model, task.qd)
    np.testing.assert_allclose(obs[lay["node_velocity"]], guidance_frame(vel, task.goal).reshape(-1), rtol=1e-5,
                               atol=1e-6)
    # the frame is a rotation about the vertical: x along the guidance, lengths and z kept
    v = rng.normal(size=(3, 4, 3))
    d = rng.normal(size=(3, 2))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    w = guidance_frame(v, d)
    np.testing.assert_allclose(np.linalg.norm(w, axis=-1), np.linalg.norm(v, axis=-1))
    np.testing.assert_array_equal(w[..., 2], v[..., 2])
    np.testing.assert_allclose(guidance_frame(np.array([[[d[0, 0], d[0, 1], 0.0]]]), d[:1])[0, 0], [1, 0, 0],
                               atol=1e-12)
