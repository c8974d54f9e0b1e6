"""TensegrityRoll-v0 on terrain: the default stays the flat fast path bit for bit, fixed and
generated terrains run through the terrain contact, generated terrains are reproducible from the
seed, and wrong terrain arguments are refused with named errors."""
import gymnasium as gym
import numpy as np
import pytest

import tensegrity_gym  # noqa: F401
from tensegrity_gym.core.terrain import Box, Plane, Terrain
from tensegrity_gym.envs.roll import RollTask, TensegrityRollVectorEnv
from tensegrity_gym.physics import terrain as T
from tensegrity_gym.tasks.terrain import (TerrainGenerator, drawn_values, generate, rod_end_contacts, rough_axis,
                                          terrain_draws)

STEPS = {"generator": "steps", "step_height": 0.04, "n_steps": 3}


def _rollout(n=40, seed=3, **kw):
    env = gym.make("TensegrityRoll-v0", **kw)
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(0)
    out = [obs]
    for _ in range(n):
        obs, r, *_ = env.step(rng.uniform(-1, 1, env.action_space.shape))
        out.append(obs)
    env.close()
    return np.array(out)


def test_no_terrain_and_level_dict_are_the_flat_ground_bit_for_bit():
    flat = _rollout()
    assert np.array_equal(flat, _rollout(terrain=None))
    assert np.array_equal(flat, _rollout(terrain={}))
    task = RollTask(terrain={})
    assert task.terrain_contact is None and task.terrains is None


def test_level_terrain_contact_matches_the_ground_contact_at_rest():
    """A level terrain plane with the ground's parameters holds the resting robot as the ground
    does: after 0.5 s the two states agree to under a millimetre."""
    flat = RollTask()
    level = RollTask(terrain=Terrain(plane=Plane(), friction=1.0, stiffness=1e4, damping=10.0))
    assert level.terrain_contact is not None
    for t in (flat, level):
        t.reset(np.array([0]), [np.random.default_rng(1)])
        for _ in range(25):
            t.simulate(np.zeros((1, t.action_size)))
    assert np.abs(flat.q - level.q).max() < 1e-3
    assert np.array_equal(flat.cstate.active, level.cstate.active)


def test_robot_rests_on_a_box_top():
    """The robot started over a 10 cm block stays on it (held by the block's top face)."""
    box = Box(center=[0.0, 0.0, 0.05], size=[2.0, 2.0, 0.1])
    task = RollTask(terrain=Terrain(plane=Plane(), boxes=(box,)))
    task.reset(np.array([0]), [np.random.default_rng(0)])
    for _ in range(50):                       # 1 s
        task.simulate(np.zeros((1, task.action_size)))
    nodes = T.TerrainContact(task.terrains[0]).terrain.height_at(0.0, 0.0)
    zmin = min(task.q[0, :, 2])               # rod centres
    assert nodes == pytest.approx(0.1)
    assert zmin > 0.1                         # on the block, not through it
    assert task.cstate.active.any()


def test_generated_terrain_is_reproducible_and_per_copy():
    a = RollTask(num_envs=3, terrain=STEPS)
    b = RollTask(num_envs=3, terrain=STEPS)
    rngs = lambda s: [np.random.default_rng(s + i) for i in range(3)]   # noqa: E731
    a.reset(np.arange(3), rngs(10))
    b.reset(np.arange(3), rngs(10))
    assert np.array_equal(a.terrain_geom, b.terrain_geom)
    assert not np.array_equal(a.terrain_geom[0], a.terrain_geom[1])    # each copy its own draw
    b.reset(np.arange(3), rngs(20))
    assert not np.array_equal(a.terrain_geom, b.terrain_geom)


def test_vector_env_equals_single_envs_on_generated_terrain():
    n, seed = 2, 5
    vec = TensegrityRollVectorEnv(num_envs=n, terrain=STEPS)
    obs_v, _ = vec.reset(seed=seed)
    singles = [gym.make("TensegrityRoll-v0", terrain=STEPS) for _ in range(n)]
    obs_s = [e.reset(seed=seed + i)[0] for i, e in enumerate(singles)]
    rng = np.random.default_rng(1)
    for _ in range(10):
        act = rng.uniform(-1, 1, (n,) + singles[0].action_space.shape).astype(np.float32)
        obs_v, *_ = vec.step(act)
        obs_s = [e.step(act[i])[0] for i, e in enumerate(singles)]
    np.testing.assert_array_equal(obs_v, np.array(obs_s))


@pytest.mark.parametrize("kind", ["slope", "steps"])
def test_difficulty_scales_the_generated_terrain(kind):
    gen = TerrainGenerator(kind=kind, slope_range=(10.0, 20.0))
    hard = generate(gen, np.random.default_rng(0), difficulty=1.0)
    easy = generate(gen, np.random.default_rng(0), difficulty=0.0)
    x = np.linspace(0.0, 3.0, 31)
    assert np.all(easy.height_at(x, 0 * x) == 0.0)
    assert hard.height_at(x, 0 * x).max() > 0.02
    task = RollTask(terrain={"generator": kind})
    task.set_terrain_difficulty(0.25)
    assert task.terrain_difficulty == 0.25


@pytest.mark.parametrize("pad", [0.0, 0.4])
def test_rough_heights_are_the_sum_of_their_waves(pad):
    """The drawn heights (each wave by the angle sum) equal their definition on the grid point
    (x_i, y_j): the waves cos(k (cos a x + sin a y) + phase) summed, scaled to [0, amplitude],
    faded inside the pad."""
    gen = TerrainGenerator(kind="rough", size=1.5, cell=0.05, pad=pad, waves=5, amplitude=0.03)
    u = np.random.default_rng(3).random((2, terrain_draws(gen)))
    h = drawn_values(gen, u)
    x = rough_axis(gen)
    X, Y = np.meshgrid(x, x)
    k = 2 * np.pi / gen.wavelength
    for r in range(2):
        ang, phase = 2 * np.pi * u[r, :gen.waves], 2 * np.pi * u[r, gen.waves:]
        z = sum(np.cos(k * (np.cos(a) * X + np.sin(a) * Y) + p) for a, p in zip(ang, phase))
        z = (z - z.min()) / (z.max() - z.min())
        fade = np.clip((np.hypot(X, Y) - pad) / gen.wavelength, 0.0, 1.0)
        np.testing.assert_allclose(h[r], gen.amplitude * z * fade, rtol=0, atol=1e-15)
    assert not np.allclose(h[0], h[0].T, atol=1e-4)        # not symmetric: x and y in their places


def test_the_two_array_namespaces_offer_the_same_operations():
    """A task written once against ``xp`` runs on both: the NumPy and torch namespaces have the
    same public names, and the in-place product the rough heights use writes the same values."""
    torch = pytest.importorskip("torch")
    from tensegrity_gym.tasks.xp import NUMPY, torch_namespace
    tx = torch_namespace()
    public = lambda ns: {n for n in dir(ns) if not n.startswith("_")} - {"name", "torch"}   # noqa: E731
    assert public(NUMPY) == public(tx)
    a, b = np.arange(3.0)[:, None], np.arange(4.0)[None, :] + 0.5
    out_np, out_t = np.empty((3, 4)), torch.empty((3, 4), dtype=torch.float64)
    assert NUMPY.multiply(a, b, out_np) is out_np
    tx.multiply(torch.as_tensor(a), torch.as_tensor(b), out_t)
    np.testing.assert_array_equal(out_t.numpy(), a * b)
    np.testing.assert_array_equal(out_np, a * b)


def test_terrain_rises_along_the_goal_direction():
    t = generate(TerrainGenerator(kind="steps"), np.random.default_rng(0), goal=(0.0, 1.0))
    assert t.height_at(0.0, 2.0) > 0.05 and t.height_at(2.0, 0.0) == 0.0


@pytest.mark.parametrize("kw, match", [
    (dict(terrain="ground.txt"), "terrain: expected a terrain JSON file"),
    (dict(terrain={"generator": "bumpy"}), "unknown kind 'bumpy'"),
    (dict(terrain={"generator": "rough", "cell": -1.0}), "terrain.cell"),
    (dict(terrain={"generator": "steps", "n_steps": 0}), "terrain.n_steps"),
    (dict(terrain={"generator": "slope", "slope_range": (30, 10)}), "terrain.slope_range"),
    (dict(terrain={"generator": "steps", "height": 0.1}), "unknown key 'height'"),
    (dict(terrain={"plane": {"slope_deg": 95}}), "slope_deg"),
    (dict(terrain=42), "terrain: expected"),
    (dict(terrain_difficulty=1.5), "terrain_difficulty"),
    (dict(terrain_difficulty=float("nan")), "terrain_difficulty"),
])
def test_bad_terrain_arguments_are_named(kw, match):
    with pytest.raises(ValueError, match=match):
        RollTask(**kw)


def test_missing_terrain_file_is_named(tmp_path):
    with pytest.raises(ValueError, match="terrain file"):
        RollTask(terrain=str(tmp_path / "nope.json"))


def test_terrain_file_takes_the_task_contact_values(tmp_path):
    p = tmp_path / "ramp.json"
    p.write_text('{"plane": {"slope_deg": 5.0}, "boxes": [{"center": [1, 0, 0], "size": [0.2, 1, 0.1]}]}')
    task = RollTask(terrain=str(p), friction=0.6)
    assert task.terrains[0].friction == 0.6
    assert task.terrain_contact.prm[0, :, T.PRM_FIELDS.index("friction")].tolist() == [0.6, 0.6]


def test_envs_without_terrain_physics_refuse_it():
    with pytest.raises(ValueError, match="terrain: the ground of TensegrityClimb-v0"):
        gym.make("TensegrityClimb-v0", terrain=STEPS)


def test_randomized_friction_reaches_every_terrain_part():
    task = RollTask(num_envs=2, terrain=STEPS, randomize={"friction": 0.5})
    task.reset(np.arange(2), [np.random.default_rng(i) for i in range(2)])
    mu = task.terrain_prm[..., T.PRM_FIELDS.index("friction")]
    assert np.all(mu == mu[:, :1]) and mu[0, 0] != mu[1, 0]


@pytest.mark.parametrize("B, n_bars, parts", [(1, 3, 1), (16, 6, 1), (5, 3, 2), (4, 6, 3)])
def test_rod_end_contacts_are_the_end_slots_of_any_part(B, n_bars, parts):
    """The rod ends' flags (what the observation reports) from the terrain's slot flags, per rod
    and part (end a, end c, interior): an end touches where its slot of some part does; in
    place into ``out`` and as a new array alike."""
    slots = np.random.default_rng(B).random((B, 3 * n_bars * parts)) < 0.4
    want = slots.reshape(B, n_bars, parts, 3)[..., :2].any(axis=2).reshape(B, 2 * n_bars)
    out = np.zeros((B, 2 * n_bars), bool)
    assert rod_end_contacts(slots, n_bars, out=out) is out
    assert np.array_equal(out, want)
    assert np.array_equal(rod_end_contacts(slots, n_bars), want)
