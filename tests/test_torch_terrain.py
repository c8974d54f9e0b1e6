"""TensegrityRoll-v0's ``terrain=`` on the torch device vector env (tensegrity_gym.envs.torch_terrain).

In float64 on CPU the torch env on a terrain must reproduce the NumPy/numba vector env (same
seeds, same actions) to round-off, as the level-ground env does (tests/test_torch_env.py): the
same terrains drawn per copy from the same seeds, the same lift of the start, the same contact
flags; wrong terrain arguments are refused with the NumPy env's errors; a partial reset redraws
only the reset copies' terrains and releases only their contact state.
"""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gymnasium as gym  # noqa: E402

from test_torch_env import _close_obs, _compare_rollouts, _pair  # noqa: E402

ID = "TensegrityRoll-v0"
STEPS = {"generator": "steps", "step_height": 0.04, "n_steps": 3, "pad": 0.05, "tread": 0.2}

CASES = {
    "slope_generator": dict(terrain={"generator": "slope", "slope_range": (5.0, 15.0)}, randomize_goal=True),
    "steps_generator": dict(terrain=STEPS, randomize={"friction": 0.3, "rod_mass": 0.2}),
    "rough_generator": dict(terrain={"generator": "rough", "size": 2.0, "cell": 0.05, "pad": 0.0,
                                     "amplitude": 0.03}, terrain_difficulty=0.8),
    "fixed_boxes_robot_obs": dict(terrain={"plane": {"slope_deg": 3.0},
                                           "boxes": [{"center": [0.1, 0.0, 0.0], "size": [0.2, 2.0, 0.06]}]},
                                  observation_mode="robot", history=2),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_terrain_matches_numpy_vector_env(case):
    """Observations, rewards, dones and infos equal the NumPy vector env's at every step (autoreset
    twice per copy), and so do the per-copy terrains and the terrain contact state."""
    N, steps = 2, 24
    ref, ten = _pair(N, max_episode_steps=10, **CASES[case])
    resets, _ = _compare_rollouts(ref, ten, N, steps, seed=11, action_seed=3,
                                  obs_atol=1e-8 if "observation_mode" in CASES[case] else 1e-12)
    assert resets >= N
    task, tt = ref.unwrapped.task, ten._terrain
    rows = slice(None) if tt.per_copy else slice(0, 1)
    np.testing.assert_array_equal(tt.geom.numpy(), task.terrain_geom[rows])
    if task.terrain_hf is not None:
        np.testing.assert_array_equal(tt.hf.numpy(), task.terrain_hf[rows])
    np.testing.assert_array_equal(tt.active.numpy(), task.tstate.active)
    np.testing.assert_allclose(tt.anchor.numpy(), task.tstate.anchor, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(ten.active.numpy(), task.cstate.active)
    assert task.tstate.active.any()          # on the terrain, not above it
    if tt.per_copy:                          # each copy its own draw
        assert not np.array_equal(task.terrain_geom[0], task.terrain_geom[1]) or \
            not np.array_equal(task.terrain_hf[0], task.terrain_hf[1])


BAD = [
    (dict(terrain="ground.txt"), "terrain: expected a terrain JSON file"),
    (dict(terrain={"generator": "bumpy"}), "unknown kind 'bumpy'"),
    (dict(terrain={"generator": "steps", "height": 0.1}), "unknown key 'height'"),
    (dict(terrain={"plane": {"slope_deg": 95}}), "slope_deg"),
    (dict(terrain=42), "terrain: expected"),
    (dict(terrain_difficulty=1.5), "terrain_difficulty"),
]


@pytest.mark.parametrize("kw, match", BAD)
def test_bad_terrain_refused_with_the_numpy_envs_error(kw, match):
    errors = []
    for extra in ({}, dict(backend="torch", device="cpu")):
        with pytest.raises(ValueError, match=match) as e:
            gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point", **kw, **extra)
        errors.append(str(e.value))
    assert errors[0] == errors[1]


def test_device_resets_draw_a_generators_terrains_per_copy():
    """``reset_sampling="device"`` with a generator: each copy its own terrain, a partial reset
    redraws only the reset copies' terrains, every start clear of its copy's terrain and the
    difficulty applied (the draws equal the host's fed the same uniforms: tests/test_torch_reset.py)."""
    from tensegrity_gym.physics.geometry import node_positions
    mk = dict(num_envs=4, vectorization_mode="vector_entry_point", backend="torch", device="cpu", dtype="float64",
              terrain=STEPS, reset_sampling="device", randomize_goal=True, terrain_difficulty=0.5)
    env = gym.make_vec(ID, **mk)
    env.reset(seed=3)
    tt, task = env._terrain, env.task
    g0 = tt.geom.clone()
    assert all(not torch.equal(g0[0], g0[i]) for i in range(1, 4))
    tops = g0[:, 1:, 3] + g0[:, 1:, 6]                      # box centre z + half height: the step tops, m
    assert float(tops.max()) <= 0.5 * 0.04 * 3 + 1e-12      # difficulty 0.5 of 3 steps of at most 4 cm
    env.reset(options={"env_idx": [1, 3]})
    changed = [not torch.equal(g0[i], tt.geom[i]) for i in range(4)]
    assert changed == [False, True, False, True]
    nodes = node_positions(task.model, env.q.numpy())
    for i in range(4):   # clear of the copy's own terrain (its rows' top surface under its nodes)
        gap = nodes[i, :, 2] - task.contact.radius - _top(tt.geom[i:i + 1], nodes[i])
        assert gap.min() > -1e-9, (i, gap.min())
    assert not tt.active.any()


def _top(geom, nodes):
    from tensegrity_gym.backends.torch.terrain import top_height
    x, y = (torch.as_tensor(nodes[None, :, j]) for j in (0, 1))
    return top_height(geom, None, x, y)[0].numpy()


def _every_kind():
    """A plane, a yawed box across the robot's path and a bumpy heightfield (a Terrain)."""
    from tensegrity_gym.core.terrain import Box, Heightfield, Plane, Terrain
    rng = np.random.default_rng(4)
    hf = Heightfield(0.02 * rng.uniform(-1, 1, (14, 14)), 0.05, origin=(-0.35, -0.35))
    return Terrain(plane=Plane(4.0, 40.0), boxes=[Box([0.25, 0.0, 0.0], [0.2, 1.0, 0.06], 15.0)], heightfield=hf)


def test_compiled_terrain_step_equals_eager():
    """compile=True on a terrain with every kind of part (torch.compile of terrain_substep: no
    device reads, the heightfield search over the layout's bound of crossings, the far parts
    searched) gives the eager env's observations, rewards and contact state in float64, with
    the rods on all three parts; the layout and options are the terrain's."""
    from tensegrity_gym.backends.torch.terrain import BOX, compile_options
    mk = dict(num_envs=3, vectorization_mode="vector_entry_point", backend="torch", device="cpu", dtype="float64",
              terrain=_every_kind(), max_episode_steps=12, reset_noise_scale=0.05)
    envs = [gym.make_vec(ID, compile=c, **mk) for c in (False, True)]
    layout = envs[1]._terrain.layout
    assert BOX in layout.kinds and compile_options(layout) is not None and max(layout.crossings)[0] > 0
    for e in envs:
        e.reset(seed=5)
    rng = np.random.default_rng(2)
    touched = np.zeros(envs[0]._terrain.active.shape[1], dtype=bool)
    for _ in range(16):
        a = torch.as_tensor(rng.uniform(-1, 1, (3, envs[0].single_action_space.shape[0])))
        try:
            outs = [e.step(a) for e in envs]
        except Exception as exc:  # noqa: BLE001 -- no C++ toolchain for inductor on this machine
            if "compiler" in str(exc).lower() or "InductorError" in type(exc).__name__:
                pytest.skip(f"torch.compile unavailable here: {type(exc).__name__}")
            raise
        assert float((outs[0][0] - outs[1][0]).abs().max()) < 1e-10
        assert float((outs[0][1] - outs[1][1]).abs().max()) < 1e-10
        t0, t1 = envs[0]._terrain, envs[1]._terrain
        assert torch.equal(t0.active, t1.active)
        assert float((t0.anchor - t1.anchor).abs().max()) < 1e-10
        touched |= t0.active.any(dim=0).numpy()
    F = len(layout.kinds)                     # slots ordered (rod, feature, slot)
    assert touched.reshape(-1, F, 3).any(axis=(0, 2)).all()       # every part touched


FIXED = {"plane": {"slope_deg": 6.0, "uphill_deg": 30.0},
         "boxes": [{"center": [0.05, 0.0, 0.0], "size": [0.2, 2.0, 0.08]}]}


def test_device_resets_on_a_fixed_terrain():
    """``reset_sampling="device"`` on a fixed terrain: every start clear of the terrain (the node
    caps above its top surface, the lowest touching where the start was lifted), the contact
    state let go, a randomised friction written to every part of the terrain, the same seed the
    same rollout."""
    from tensegrity_gym.physics.geometry import node_positions
    mk = dict(num_envs=6, vectorization_mode="vector_entry_point", backend="torch", device="cpu", dtype="float64",
              terrain=FIXED, reset_sampling="device", reset_noise_scale=0.05, randomize={"friction": 0.5})
    obs = []
    for _ in range(2):
        env = gym.make_vec(ID, **mk)
        o, _ = env.reset(seed=7)
        ten = env.unwrapped if hasattr(env, "unwrapped") else env
        task = ten.task
        terrain = task.terrains[0]
        q = ten.q.numpy()
        nodes = node_positions(task.model, q)
        gap = nodes[..., 2] - task.contact.radius - terrain.height_at(nodes[..., 0], nodes[..., 1])
        assert (gap.min(axis=1) > -1e-9).all()
        assert (np.abs(gap.min(axis=1)) < 1e-9).any()        # the lifted copies touch with their lowest cap
        assert not ten._terrain.active.any() and not ten._terrain.anchor.any()
        fr = ten._terrain_prm[:, :, 4].numpy()
        assert np.ptp(fr[:, 0]) > 0 and np.array_equal(fr[:, 0], fr[:, 1])     # per copy, every part alike
        rng = np.random.default_rng(0)
        for _ in range(10):
            o, r, te, tr, info = env.step(torch.as_tensor(rng.uniform(-1, 1, (6,) + env.single_action_space.shape)))
        assert torch.isfinite(o).all()
        obs.append(o.numpy())
    assert np.array_equal(obs[0], obs[1])


def test_level_ground_runs_no_terrain_code():
    _, ten = _pair(2)
    assert ten._terrain is None and not hasattr(ten, "_terrain_prm")


def test_partial_reset_redraws_only_those_copies_terrains():
    """``reset(options={"env_idx": [1]})`` after a curriculum change: copy 1 gets a new (level)
    terrain and a released contact state, copies 0 and 2 keep theirs; the NumPy vector env does
    the same."""
    N = 3
    ref, ten = _pair(N, terrain=STEPS)
    ref.reset(seed=5)
    ten.reset(seed=5)
    a = np.zeros((N, ref.single_action_space.shape[0]))
    for _ in range(3):
        ref.step(a)
        ten.step(torch.as_tensor(a))
    geom0 = ten._terrain.geom.clone()
    state0 = [x.clone() for x in (ten._terrain.anchor, ten._terrain.eta0, ten._terrain.active)]
    assert state0[2][1].any()
    for env in (ref, ten):
        env.unwrapped.task.set_terrain_difficulty(0.0)
    o1, _ = ref.reset(options={"env_idx": [1]})
    o2, _ = ten.reset(options={"env_idx": [1]})
    _close_obs(o1, o2)
    geom = ten._terrain.geom
    keep = [0, 2]
    assert torch.equal(geom[keep], geom0[keep]) and not torch.equal(geom[1], geom0[1])
    np.testing.assert_array_equal(geom.numpy(), ref.unwrapped.task.terrain_geom)
    assert ref.unwrapped.task.terrains[1].height_at(1.0, 0.0) == 0.0       # difficulty 0: level steps
    for now, before in zip((ten._terrain.anchor, ten._terrain.eta0, ten._terrain.active), state0):
        assert torch.equal(now[keep], before[keep])
        assert not now[1].any()
    assert not ten.active[1].any()
    for _ in range(3):
        o1, *_ = ref.step(a)
        o2, *_ = ten.step(torch.as_tensor(a))
        _close_obs(o1, o2)


def test_float32_on_terrain_close_to_float64():
    envs = [gym.make_vec(ID, num_envs=2, vectorization_mode="vector_entry_point", backend="torch", device="cpu",
                         dtype=d, terrain={"generator": "slope"}) for d in ("float32", "float64")]
    outs = [e.reset(seed=1)[0] for e in envs]
    assert envs[0]._terrain.geom.dtype == torch.float32
    rng = np.random.default_rng(2)
    for _ in range(10):
        a = rng.uniform(-1, 1, (2, 9))
        outs = [e.step(torch.as_tensor(a, dtype=torch.float32))[0] for e in envs]
    assert outs[0].dtype == torch.float32
    err = (outs[0].double() - outs[1]).abs().max().item()
    assert 0 < err < 1e-3, err


def test_device_drawn_rough_ground_is_the_same_drawn_in_chunks(monkeypatch):
    """A device reset draws rough ground DRAW_CHUNK grid points at a time: chunks of two envs give
    the heights, rows and starts of one draw of all five."""
    import tensegrity_gym.envs.torch_terrain as TT
    mk = dict(num_envs=5, vectorization_mode="vector_entry_point", backend="torch", device="cpu", dtype="float64",
              terrain={"generator": "rough", "size": 2.0}, reset_sampling="device")
    out = []
    for chunk in (TT.DRAW_CHUNK, 41 * 41 * 2):      # a 2 m grid of 5 cm cells: 41 x 41 points
        monkeypatch.setattr(TT, "DRAW_CHUNK", chunk)
        env = gym.make_vec(ID, **mk)
        env.reset(seed=3)
        out.append((env._terrain.hf.clone(), env._terrain.geom.clone(), env.q.clone()))
    assert all(torch.equal(a, b) for a, b in zip(*out))
    assert not torch.equal(out[0][0][0], out[0][0][1])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("compile", [False, True])
def test_terrain_device_resets_and_steps_on_cuda_equal_cpu(compile):
    """On a GPU: device resets drawing the steps generator's terrains and the steps on them (eager
    or compiled) equal the eager CPU env's to round-off (one compile: the CUDA env's)."""
    kw = dict(num_envs=6, vectorization_mode="vector_entry_point", backend="torch", dtype="float64",
              reset_sampling="device", randomize_goal=True, terrain=STEPS)
    envs = [gym.make_vec(ID, device=d, compile=c, **kw) for d, c in (("cpu", False), ("cuda", compile))]
    outs = [e.reset(seed=4)[0] for e in envs]
    assert float((envs[0]._terrain.geom - envs[1]._terrain.geom.cpu()).abs().max()) < 1e-12
    assert float((outs[0] - outs[1].cpu()).abs().max()) < 1e-12
    rng = np.random.default_rng(0)
    for _ in range(5):
        a = rng.uniform(-1, 1, (6, envs[0].single_action_space.shape[0]))
        outs = [e.step(torch.as_tensor(a, device=e.device))[0] for e in envs]
    assert float((outs[0] - outs[1].cpu()).abs().max()) < 1e-8
