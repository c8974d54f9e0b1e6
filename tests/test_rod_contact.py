"""Rod-rod contact (tensegrity_gym.physics.rod_contact): the closest points of two segments, the
forces of the numba kernel against the NumPy oracle and the torch twin, free rods driven into
each other (head-on, crossing, skew, end to end, sliding) that never pass through, an impact
without damping that creates no energy, and the option in the rolling envs (off by default:
no rod-rod code runs; on: the compiled loop equals the Python loop and no rods cross)."""
from __future__ import annotations

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.model import State
from tensegrity_gym.core.structure import Structure
from tensegrity_gym.physics import geometry, pipeline
from tensegrity_gym.physics.rod_contact import (RodContact, pair_distances, resolve_option, rod_contact_energy,
                                                rod_contact_forces)

import oracle_numpy as oracle

ROD_MASS, ROD_LENGTH, RADIUS = 0.2, 0.38, 0.02
#: the laws the free rods are tested with: the defaults (1 cm rods) driven at up to 2.5 m/s each
#: (5 m/s relative), and capsules of the end caps' size with the ground's stiffness at up to 5 m/s each
LAWS = {"default": (RodContact(), (1.0, 2.5)), "cap_sized": (RodContact(radius=RADIUS, stiffness=1e4), (1.0, 5.0))}


def _two_rods(gravity=None):
    """Two free rods (0.2 kg, 0.38 m), no strings: along x at z = 0 and along y at z = 0.2."""
    L = ROD_LENGTH / 2
    nodes = np.array([[-L, 0, 0], [L, 0, 0], [0, -L, 0.2], [0, L, 0.2]], float)
    s = Structure(nodes, [[0, 1], [2, 3]], np.zeros((0, 2), int), bar_mass=ROD_MASS, gravity=gravity)
    return tg.compile_model(s)


def _state(model, centres, axes, velocities, spins=None):
    """(q, qd) (1, k, 6) from rod centres, axes (normalised here), centre velocities and axis rates."""
    axes = np.asarray(axes, float)
    axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    q = np.concatenate([np.asarray(centres, float), axes], axis=1)[None]
    bd = np.zeros_like(axes) if spins is None else np.asarray(spins, float)
    qd = np.concatenate([np.asarray(velocities, float), bd], axis=1)[None]
    return q, qd


def _random_configs(model, B, spread, rng):
    k = model.n_bars
    q = np.zeros((B, k, 6))
    q[..., :3] = rng.uniform(-spread, spread, (B, k, 3))
    b = rng.normal(size=(B, k, 3))
    q[..., 3:] = b / np.linalg.norm(b, axis=-1, keepdims=True)
    q[: B // 8, 1, 3:] = q[: B // 8, 0, 3:]                       # parallel pairs
    q[B // 8: B // 4, 1, 3:] = -q[B // 8: B // 4, 0, 3:]           # antiparallel
    qd = rng.normal(size=(B, k, 6))
    return q, qd


def _special_configs(model):
    """Two rods: crossing (perpendicular, axes 1 cm apart and exactly meeting), parallel side by
    side (overlapping, shifted, apart), skew, end to end (collinear, touching and overlapping)."""
    L = ROD_LENGTH
    cases = [((0, 0, 0), (1, 0, 0), (0, 0, 0.01), (0, 1, 0)),          # crossing, 1 cm
             ((0, 0, 0), (1, 0, 0), (0, 0, 0.0), (0, 1, 0)),           # axes meet
             ((0, 0, 0), (1, 0, 0), (0.05, 0.03, 0), (1, 0, 0)),       # parallel, overlapping
             ((0, 0, 0), (1, 0, 0), (0.3, 0.03, 0), (-1, 0, 0)),       # antiparallel, shifted
             ((0, 0, 0), (1, 0, 0), (0.6, 0.03, 0), (1, 0, 0)),        # parallel, apart
             ((0, 0, 0), (1, 0, 0), (0.1, 0.02, 0.01), (1, 1, 0.3)),   # skew
             ((0, 0, 0), (1, 0, 0), (L + 0.05, 0, 0), (1, 0, 0)),      # end to end, 5 cm apart
             ((0, 0, 0), (1, 0, 0), (L - 0.01, 0, 0), (1, 0, 0)),      # end to end, overlapping
             ((0, 0, 0), (0, 0, 1), (0, 0.03, 0.1), (0, 0, 1)),        # vertical, parallel
             ((0, 0, 0), (0, 0, 1), (0, 0, 0.1), (0, 0, 1))]           # vertical, collinear overlap
    rng = np.random.default_rng(5)
    q = np.array([np.r_[c1, np.array(a1) / np.linalg.norm(a1), c2, np.array(a2) / np.linalg.norm(a2)]
                  for c1, a1, c2, a2 in cases]).reshape(len(cases), 2, 6)
    qd = rng.normal(size=q.shape)
    return q, qd


def test_closest_points_are_the_closest():
    """pair_distances (the kernels' closest points) against a dense sampling of both segments:
    never above the sampled minimum, and within the sampling's resolution of it."""
    model = _two_rods()
    rng = np.random.default_rng(0)
    q, _ = _random_configs(model, 64, 0.3, rng)
    qs, _ = _special_configs(model)
    q = np.concatenate([q, qs])
    D = pair_distances(model, q)[:, 0]
    u = np.linspace(0.0, 1.0, 401)
    N = geometry.node_positions(model, q)
    P1 = N[:, 0, None] + u[None, :, None] * (N[:, 1] - N[:, 0])[:, None]
    P2 = N[:, 2, None] + u[None, :, None] * (N[:, 3] - N[:, 2])[:, None]
    sampled = np.linalg.norm(P1[:, :, None] - P2[:, None, :], axis=-1).min(axis=(1, 2))
    assert np.all(D <= sampled + 1e-12)
    assert np.all(sampled - D <= ROD_LENGTH / 400 + 1e-12)
    assert D[len(D) - len(qs) + 1] == 0.0           # axes that meet


@pytest.mark.parametrize("structure", ["two_rods", "prism3", "icosahedron"])
def test_forces_numba_oracle_torch_agree(structure):
    """The numba kernel, the NumPy oracle and the torch twin (float64) give the same nodal forces
    on random configurations (parallel and antiparallel pairs included) and on the special ones."""
    torch = pytest.importorskip("torch")
    from tensegrity_gym.backends.torch.rod_contact import rod_contact_forces as torch_forces
    model = _two_rods() if structure == "two_rods" else tg.compile_model(tg.build(structure))
    rng = np.random.default_rng(1)
    size = float(np.max(model.length))
    q, qd = _random_configs(model, 200, 0.4 * size, rng)
    if structure == "two_rods":
        qs, qds = _special_configs(model)
        q, qd = np.concatenate([q, qs]), np.concatenate([qd, qds])
    for rc in (RodContact(radius=0.05 * size), RodContact(radius=0.05 * size, friction=0.0, damping=0.0),
               RodContact(radius=0.05 * size, max_damping=3.0, friction_speed=0.5)):
        W = rod_contact_forces(rc, model, q, qd)
        scale = np.abs(W).max()
        assert (np.abs(W).sum(axis=(1, 2)) > 0).sum() > 20        # many configurations touch
        np.testing.assert_allclose(oracle.rod_contact_forces(rc, model, q, qd), W, rtol=0, atol=1e-11 * scale)
        Wt = torch_forces(rc, model, torch.tensor(q), torch.tensor(qd)).numpy()
        np.testing.assert_allclose(Wt, W, rtol=0, atol=1e-11 * scale)


def test_forces_balance_and_act_at_the_closest_points():
    """Without friction the nodal forces of a pair sum to zero and so do their moments about the
    origin (the force acts along the line of the closest points: the linear split to the nodes
    is the force at the closest point, exactly)."""
    model = _two_rods()
    q, qd = _special_configs(model)
    rc = RodContact(radius=RADIUS, friction=0.0)
    W = rod_contact_forces(rc, model, q, qd)
    N = geometry.node_positions(model, q)
    assert np.abs(W.sum(axis=1)).max() < 1e-9
    assert np.abs(np.cross(N, W).sum(axis=1)).max() < 1e-9
    touching = np.abs(W).sum(axis=(1, 2)) > 0
    assert touching[[0, 1, 2, 5, 7, 8, 9]].all() and not touching[[4, 6]].any()


def _run(model, q, qd, rc, dt, steps):
    """The rods' states after each of ``steps`` steps of ``dt`` s with rod contact ``rc``."""
    st = State(q=q, qd=qd)
    qs, qds = [q[0]], [qd[0]]
    for _ in range(steps):
        st = pipeline.step(model, st, dt, rods=rc)
        qs.append(st.q[0])
        qds.append(st.qd[0])
    return np.array(qs), np.array(qds)


# name -> (centres, axes, velocities, n): rod 0 and rod 1, each driven towards the other; n the
# side of rod 1 that rod 0 starts on
_DRIVES = {
    "head_on_side_by_side": ([(0, -0.1, 0), (0, 0.1, 0)], [(1, 0, 0), (1, 0, 0)], [(0, 1, 0), (0, -1, 0)], (0, -1, 0)),
    "crossing_perpendicular": ([(0, 0, -0.1), (0, 0, 0.1)], [(1, 0, 0), (0, 1, 0)], [(0, 0, 1), (0, 0, -1)],
                               (0, 0, -1)),
    "crossing_skew": ([(0.05, 0, -0.1), (0, 0.03, 0.1)], [(1, 0.2, 0), (0.4, 1, 0.2)], [(0, 0, 1), (-0.1, 0, -1)],
                      (0, 0, -1)),
    "end_to_end": ([(-0.25, 0, 0), (0.25, 0, 0)], [(1, 0, 0), (1, 0, 0)], [(1, 0, 0), (-1, 0, 0)], (-1, 0, 0)),
    "end_on_side": ([(-0.3, 0, 0), (0, 0, 0)], [(1, 0, 0), (0, 1, 0)], [(1, 0, 0), (0, 0, 0)], (-1, 0, 0)),
    "sliding": ([(0.15, -0.03, 0), (-0.15, 0.03, 0)], [(1, 0, 0), (1, 0, 0)], [(-1, 0.2, 0), (1, -0.2, 0)],
                (0, -1, 0)),
}


@pytest.mark.parametrize("fast", [False, True])
@pytest.mark.parametrize("law", sorted(LAWS))
@pytest.mark.parametrize("case", sorted(_DRIVES))
def test_free_rods_never_pass_through(case, law, fast):
    """Two free rods (no gravity) driven into each other at 1 m/s each and fast (the default law:
    2.5 m/s each, 5 m/s relative; capsules of the end caps' size: 5 m/s each, 10 m/s relative;
    sliding: along their axes, closing sideways at a fifth of it): at every step of
    1e-4 s (a tenth of the envs' step, at most 1 mm of relative travel) the distance between their
    axes stays above zero, the line between their closest points never flips (no tunnelling
    between samples), and they are no longer pressed together at the end."""
    model = _two_rods()
    centres, axes, vel, n = _DRIVES[case]
    rc, speeds = LAWS[law]
    q, qd = _state(model, centres, axes, speeds[int(fast)] * np.asarray(vel, float))
    qs, qds = _run(model, q, qd, rc, 1e-4, 3000)
    D = pair_distances(model, qs)[:, 0]
    assert D.min() > 0.2 * rc.radius, (case, D.min())
    assert D.min() < 2 * rc.radius, "the rods never touched"
    # no tunnelling between samples: the vector between the closest points never turns by more
    # than 90 degrees from one step to the next (crossing flips it), and the first one points along n
    N = geometry.node_positions(model, qs)
    d1, d2 = N[:, 1] - N[:, 0], N[:, 3] - N[:, 2]
    s_, t_ = oracle.segment_closest(d1, d2, N[:, 0] - N[:, 2])
    g = (N[:, 0] + s_[:, None] * d1) - (N[:, 2] + t_[:, None] * d2)
    assert np.all(np.einsum("ti,ti->t", g[1:], g[:-1]) > 0), case
    assert g[0] @ np.asarray(n, float) > 0
    assert D[-1] > 1.9 * rc.radius, "still pressed together at the end"


@pytest.mark.parametrize("case", ["crossing_skew", "end_to_end"])
def test_impact_without_damping_creates_no_energy(case):
    """An impact at 5 m/s each (10 m/s relative) with no damping and no friction: at dt = 1e-4 s
    the kinetic plus contact energy stays within 2 % of the initial during the impact (the step's
    shadow-energy swing) and within 0.1 % after the rods part; at the envs' 1e-3 s, within 3 %
    after (the held force's error at touch-down and lift-off: 1.0-1.7 % measured)."""
    model = _two_rods()
    centres, axes, vel, _ = _DRIVES[case]
    q, qd = _state(model, centres, axes, 5.0 * np.asarray(vel, float))
    rc = RodContact(radius=RADIUS, stiffness=1e4, damping=0.0, friction=0.0)
    for dt, steps, during, after in ((1e-4, 3000, 0.02, 0.001), (1e-3, 300, 0.2, 0.03)):
        qs, qds = _run(model, q, qd, rc, dt, steps)
        E = geometry.kinetic_energy(model, qds) + rod_contact_energy(rc, model, qs)
        E0 = E[0]
        assert rod_contact_energy(rc, model, qs).max() > 0.05 * E0       # a real impact
        assert E.max() <= E0 * (1 + during), (dt, E.max() / E0)
        assert abs(E[-1] / E0 - 1.0) < after, (dt, E[-1] / E0)
        assert pair_distances(model, qs[-1:])[0, 0] > 2 * RADIUS


def test_option_values():
    """``rod_contact``: None / False off, True the defaults with the task's damping cap, a dict
    of fields; anything else a ValueError naming the argument."""
    assert resolve_option(None, 25.0) is None and resolve_option(False, 25.0) is None
    rc = resolve_option(True, 25.0)
    assert rc.radius == 0.005 and rc.max_damping == 25.0 and rc.stiffness == 5e4
    rc = resolve_option({"friction": 0.2, "radius": 0.01}, 25.0)
    assert rc.friction == 0.2 and rc.radius == 0.01 and rc.max_damping == 25.0
    for bad, msg in (("abc", "rod_contact: expected None, True"), ({"x": 1}, "rod_contact: unknown field 'x'"),
                     ({"radius": -1.0}, "rod_contact: radius: must be positive"),
                     ({"stiffness": float("nan")}, "rod_contact: stiffness"), (1.0, "rod_contact: expected")):
        with pytest.raises(ValueError, match=msg):
            resolve_option(bad, 25.0)


def _rollout(env, steps, seed=3):
    rng = np.random.default_rng(7)
    o, _ = env.reset(seed=seed)
    obs = [o]
    for _ in range(steps):
        o, *_ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        obs.append(o)
    return np.array(obs)


def test_off_by_default_runs_no_rod_code(monkeypatch):
    """Without ``rod_contact`` (or with None / False) the roll env's compiled contact loop gets no
    rod tuple (the driver instance without rod-rod code) and the observations are bit-identical."""
    import gymnasium as gym
    from tensegrity_gym.backends.numba import api as numba_api
    seen = []
    f = numba_api._contact_loop
    monkeypatch.setattr(numba_api, "_contact_loop", lambda *a: seen.append(a[-1]) or f(*a))
    ref = _rollout(gym.make("TensegrityRoll-v0"), 5)
    for value in (None, False):
        assert np.array_equal(_rollout(gym.make("TensegrityRoll-v0", rod_contact=value), 5), ref)
    assert seen and all(r is None for r in seen)
    env = gym.make("TensegrityRoll-v0")
    assert env.unwrapped.task.rod_contact is None


@pytest.mark.parametrize("env_id", ["TensegrityRoll-v0", "TensegrityClimb-v0", "TensegrityNavigate-v0"])
def test_rod_contact_in_the_compiled_loop_equals_the_python_loop(monkeypatch, env_id):
    """With ``rod_contact=True`` the loop driver (ground, plane and terrain instances) gives the
    bits of the Python loop (ground or terrain forces, then the rod forces, then one step)."""
    import gymnasium as gym
    from tensegrity_gym.physics import terrain as physics_terrain
    fused, loop = gym.make(env_id, rod_contact=True), gym.make(env_id, rod_contact=True)
    assert fused.unwrapped.task.rod_contact is not None
    r1 = _rollout(fused, 4)
    monkeypatch.setattr(pipeline, "_contact_compiled", lambda *x: False)
    monkeypatch.setattr(physics_terrain, "terrain_steps", lambda *x: False)
    r2 = _rollout(loop, 4)
    assert np.array_equal(r1, r2)


def test_prism_rolls_with_rod_contact_and_no_rods_cross():
    """TensegrityRoll-v0 with rod contact under the rolling gait: it rolls (more than 0.5 m in
    6 s) and the rods' axes stay apart at every control step."""
    from tensegrity_gym.envs.roll import TensegrityRollEnv
    from tensegrity_gym.tools.baselines import RollingGait
    env = TensegrityRollEnv(rod_contact=True)
    task = env.unwrapped.task
    gait = RollingGait(env)
    obs, _ = env.reset(seed=0)
    x0 = geometry.center_of_mass(task.model, task.q)[0]
    dmin, state = np.inf, None
    for _ in range(300):
        action, state = gait.predict(obs, state)
        obs, *_ = env.step(action)
        dmin = min(dmin, float(pair_distances(task.model, task.q).min()))
    x1 = geometry.center_of_mass(task.model, task.q)[0]
    assert np.linalg.norm((x1 - x0)[:2]) > 0.5
    assert dmin > 0.0


@pytest.mark.parametrize("kw", [dict(), dict(terrain={"plane": {"slope_deg": 10.0}})])
def test_torch_device_env_matches_the_numpy_env(kw):
    """The torch device vector env (float64, CPU) with ``rod_contact`` follows the NumPy vector env
    to round-off on level ground and on a terrain, with capsules thick enough (3 cm) to touch at
    rest, so that rod-rod forces act at every step."""
    torch = pytest.importorskip("torch")
    import gymnasium as gym
    rc = {"radius": 0.03}
    N = 2
    ref = gym.make_vec("TensegrityRoll-v0", num_envs=N, vectorization_mode="vector_entry_point", rod_contact=rc, **kw)
    ten = gym.make_vec("TensegrityRoll-v0", num_envs=N, vectorization_mode="vector_entry_point", backend="torch",
                       device="cpu", dtype="float64", rod_contact=rc, **kw)
    task = ref.unwrapped.task
    assert np.abs(rod_contact_forces(task.rod_contact, task.model, task.q_nominal, 0 * task.q_nominal)).max() > 1.0
    o1, _ = ref.reset(seed=1)
    o2, _ = ten.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(15):
        a = rng.uniform(-1, 1, (N, ref.single_action_space.shape[0]))
        o1, *_ = ref.step(a)
        o2, *_ = ten.step(torch.as_tensor(a))
    assert np.abs(task.q - ten.q.numpy()).max() <= 1e-9


@pytest.mark.parametrize("rod_contact", [False, True])
def test_mjcf_rods_collide_with_each_other_only_with_rod_contact(rod_contact):
    """MJCF export: rods are capsules with ``conaffinity`` 0 (the ground only) by default and 1 with
    ``rod_contact=True``; in MuJoCo two rods driven across each other at 2 m/s each then bounce
    (their axes' vertical order kept) instead of passing through."""
    mujoco = pytest.importorskip("mujoco")
    from tensegrity_gym.io.mjcf import to_mjcf
    model = _two_rods()
    xml = to_mjcf(model.structure, rod_radius=RADIUS, timestep=1e-4, rod_contact=rod_contact)
    assert xml.count(f'conaffinity="{int(rod_contact)}"') == 2
    M = mujoco.MjModel.from_xml_string(xml)
    D = mujoco.MjData(M)
    # rod 0 along x at z = 0, rod 1 along y at z = 0.2 (as built): drive them together along z
    D.qvel[2], D.qvel[8] = 2.0, -2.0
    z = []
    for _ in range(2000):
        mujoco.mj_step(M, D)
        z.append(D.qpos[9] - D.qpos[2])      # rod 1's centre height above rod 0's
    assert (min(z) > 0) == rod_contact
