"""The compiled terrain sub-steps (backends/numba/terrain_steps.py: the terrain forces inside the
loop driver's lanes) equal the Python loop of physics.terrain.advance bit for bit: the same
kernels in the same order, per batch size (one copy at a time, SIMD blocks, chunks on all
threads) and with shared or per-copy physical parameters and heights."""
import numpy as np
import pytest

from tensegrity_gym.core import builders
from tensegrity_gym.core.model import compile_model, default_params, initial_state
from tensegrity_gym.core.terrain import Box, Plane, Terrain
from tensegrity_gym.physics import terrain as T


@pytest.fixture(scope="module")
def prism():
    s = builders.prism(3, radius=0.15, height=0.25, bar_mass=0.2, stiffness=1000.0, prestress=20.0, damping=2.0,
                       gravity=(0.0, 0.0, -9.81))
    nodes = s.nodes.copy()
    nodes[:, 2] += 0.02
    return compile_model(s.replace(nodes=nodes))


@pytest.mark.parametrize("B", [1, 3, 20])
@pytest.mark.parametrize("per_copy", [False, True])
def test_compiled_terrain_loop_is_the_python_loop(prism, B, per_copy):
    m = prism
    tc = T.TerrainContact(Terrain(plane=Plane(10.0), boxes=[Box([0.1, 0, 0.0], [0.2, 1, 0.06]),
                                                           Box([-0.2, 0.1, 0.02], [0.2, 0.2, 0.1], 30.0)]))
    rng = np.random.default_rng(B)
    st = initial_state(m, B)
    q, qd = np.array(st.q), np.array(st.qd)
    q[..., :3] += rng.normal(0.0, 0.01, q[..., :3].shape)
    params = default_params(m, B) if per_copy else None
    ext = rng.normal(0.0, 0.1, (B, m.n_nodes, 3))
    out = []
    for compiled in (False, True):
        qq, qqd, ts = q.copy(), qd.copy(), T.init_terrain_state(tc, m, B)
        touched = False
        for _ in range(40):      # contact seen at every 5th step (the prism starts in box 0 and may bounce off)
            T.advance(tc, m, qq, qqd, 1e-3, "semi_implicit_euler", ts, n_steps=5, params=params, external=ext,
                      compiled=compiled)
            touched |= bool(ts.active.any())
        out.append((qq, qqd, ts.anchor, ts.eta0, ts.active))
    assert touched
    for a, b in zip(*out):
        assert np.array_equal(a, b)


def _peak_under_rod(m, q, h, cell):
    """A heightfield grid origin m that puts grid point (10, 10) of the heights ``h`` under the
    middle of rod 0 of copy 0, raised (in place) to 3 mm inside the contact radius (0.02 m) there:
    a peak that the rod's interior touches, deeper than its ends."""
    mid = q[0, 0, :3] + float(np.mean(m.eta[0])) * q[0, 0, 3:]
    h[10, 10] = mid[2] - 0.017
    return [mid[0] - 10 * cell, mid[1] - 10 * cell]


@pytest.mark.parametrize("B, per_copy_hf", [(1, False), (20, True), (900, False)])
def test_compiled_heightfield_loop_is_the_python_loop(prism, B, per_copy_hf):
    """A heightfield (shared heights, or one field per copy with the slope bound computed per
    copy, and per-copy contact parameters: the cap radius and friction, which the SIMD blocks
    read per lane); 900 copies reach the multi-threaded kernel (``terrain_parallel``)."""
    from tensegrity_gym.backends.numba.compile import PARALLEL_MIN_WORK
    from tensegrity_gym.core.terrain import Heightfield
    m = prism
    rng = np.random.default_rng(B)
    h = 0.03 * rng.random((20, 20))
    st = initial_state(m, B)
    q, qd = np.array(st.q), np.array(st.qd)
    q[..., :3] += rng.normal(0.0, 0.01, q[..., :3].shape)
    q[..., 2] += 0.02
    origin = _peak_under_rod(m, q, h, 0.05)
    tc = T.TerrainContact(Terrain(plane=None, heightfield=Heightfield(heights=h, cell=0.05, origin=origin)))
    hf = prm = None
    if per_copy_hf:
        hf = h[None] * rng.uniform(0.5, 1.5, (B, 1, 1))
        hf[:, 10, 10] = h[10, 10]
        prm = tc.per_copy(B)
        prm[:, 0, T.PRM_FIELDS.index("radius")] *= rng.uniform(0.8, 1.2, B)
        prm[:, 0, T.PRM_FIELDS.index("friction")] = rng.uniform(0.1, 1.0, B)
    if B == 900:
        assert B * (m.n_strings + m.n_bars) >= PARALLEL_MIN_WORK
    out = []
    for compiled in (False, True):
        qq, qqd, ts = q.copy(), qd.copy(), T.init_terrain_state(tc, m, B)
        W = np.empty((B, m.n_nodes, 3))
        nodes = interior = False
        for _ in range(30):
            T.advance(tc, m, qq, qqd, 1e-3, "semi_implicit_euler", ts, n_steps=5, hf=hf, prm=prm, forces=W,
                      compiled=compiled)
            act = ts.active.reshape(B, -1, 3)
            nodes |= bool(act[..., :2].any())
            interior |= bool(act[..., 2].any())
        out.append((qq, qqd, ts.anchor, ts.eta0, ts.active, W))
    assert nodes and interior       # nodes and an interior point of a rod (over the peak) touched
    for a, b in zip(*out):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("B", [1, 20])
@pytest.mark.parametrize("plane", [False, True])
def test_compiled_heightfield_after_other_features_is_the_python_loop(prism, B, plane):
    """A heightfield listed after a box (and a plane), as a navigation course's ground after its
    walls: the compiled loop adds the heightfield's forces after the other features', in the
    Python loop's order."""
    from tensegrity_gym.core.terrain import Heightfield
    m = prism
    rng = np.random.default_rng(7)
    h = 0.03 * rng.random((20, 20))
    if plane:
        h[:] = -0.05          # the heightfield under the plane, which the nodes then touch, but for the peak
    st = initial_state(m, B)
    q, qd = np.array(st.q), np.array(st.qd)
    q[..., :3] += rng.normal(0.0, 0.01, q[..., :3].shape)
    q[..., 2] += 0.03
    qd[..., 0] += 0.3
    origin = _peak_under_rod(m, q, h, 0.05)
    tc = T.TerrainContact(Terrain(plane=Plane(0.0) if plane else None,
                                  boxes=[Box([0.12, 0.0, 0.0], [0.1, 1.0, 0.05])],
                                  heightfield=Heightfield(heights=h, cell=0.05, origin=origin)))
    out = []
    for compiled in (False, True):
        qq, qqd, ts = q.copy(), qd.copy(), T.init_terrain_state(tc, m, B)
        W = np.empty((B, m.n_nodes, 3))
        seen, interior = np.zeros(tc.geom.shape[1], bool), False
        for _ in range(30):
            T.advance(tc, m, qq, qqd, 1e-3, "semi_implicit_euler", ts, n_steps=5, forces=W, compiled=compiled)
            act = ts.active.reshape(B, m.n_bars, -1, 3)
            seen |= act.any(axis=(0, 1, 3))
            interior |= bool(act[:, :, -1, 2].any())
        out.append((qq, qqd, ts.anchor, ts.eta0, ts.active, W))
    assert seen.all() and interior      # every feature touched, the heightfield at a rod's interior too
    for a, b in zip(*out):
        assert np.array_equal(a, b)


def test_heightfield_slope_bound_is_the_kernels_own(prism):
    """The slope bound a heightfield row carries (computed once per terrain) is the kernel's own
    scan of the heights: forces with the row's bound equal forces with it cleared (computed per call)."""
    from tensegrity_gym.core.terrain import Heightfield
    from tensegrity_gym.backends.numba.terrain_kinds import hf_bound
    rng = np.random.default_rng(0)
    h = 0.03 * rng.random((30, 30))
    tc = T.TerrainContact(Terrain(plane=None, heightfield=Heightfield(heights=h, cell=0.05, origin=[-0.75, -0.75])))
    k = int(np.flatnonzero(tc.geom[0, :, 0] == 2.0)[0])
    assert tc.geom[0, k, 6] == hf_bound(h, 0.05) > 1.0
    # the bound's definition: the largest grid step along x and along y over the cell
    mx, my = np.abs(np.diff(h, axis=1)).max(), np.abs(np.diff(h, axis=0)).max()
    assert hf_bound(h, 0.05) == pytest.approx(np.sqrt(1.0 + (mx * mx + my * my) / 0.05 ** 2), rel=1e-15)
    cleared = tc.geom.copy()
    cleared[0, k, 6] = 0.0
    B = 4
    st = initial_state(prism, B)
    q = np.array(st.q)
    q[..., 2] += rng.uniform(-0.01, 0.05, (B, 1))
    out = [T.contact_forces(tc, prism, q, np.zeros_like(q), T.init_terrain_state(tc, prism, B), geom=g)[0]
           for g in (tc.geom, cleared)]
    assert np.abs(out[0]).sum() > 0 and np.array_equal(out[0], out[1])


@pytest.mark.parametrize("B, power", [(1, False), (20, False), (900, False), (20, True)])
def test_compiled_plane_loop_is_the_python_loop(prism, B, power):
    """A terrain that is one plane runs the driver's plane instance (its own forces loop, node
    slots in lane scratch): per-copy slopes and friction, an external force, one copy, SIMD
    blocks with pad lanes (20 copies) and the threaded kernel (900): the Python loop's bits.
    ``power``: a force exponent of 1.5 in every other copy (the law's power in the loop, which
    then runs without SIMD code)."""
    m = prism
    tc = T.TerrainContact(Terrain(plane=Plane(15.0, 30.0)))
    assert tc.plane_only
    rng = np.random.default_rng(B)
    st = initial_state(m, B)
    q, qd = np.array(st.q), np.array(st.qd)
    q[..., :3] += rng.normal(0.0, 0.01, q[..., :3].shape)
    geom = np.repeat(tc.geom, B, axis=0)
    for c in range(B):
        geom[c] = T.TerrainContact(Terrain(plane=Plane(rng.uniform(0.0, 30.0), rng.uniform(0, 360)))).geom[0]
    prm = tc.per_copy(B)
    prm[:, 0, T.PRM_FIELDS.index("friction")] = rng.uniform(0.1, 1.0, B)
    if power:
        prm[::2, 0, T.PRM_FIELDS.index("exponent")] = 1.5
    ext = rng.normal(0.0, 0.1, (B, m.n_nodes, 3))
    out = []
    for compiled in (False, True):
        qq, qqd, ts = q.copy(), qd.copy(), T.init_terrain_state(tc, m, B)
        touched = False
        for _ in range(30):
            T.advance(tc, m, qq, qqd, 1e-3, "semi_implicit_euler", ts, n_steps=10, external=ext, prm=prm,
                      geom=geom, compiled=compiled)
            touched |= bool(ts.active.any())
        out.append((qq, qqd, ts.anchor, ts.eta0, ts.active))
    assert touched
    for a, b in zip(*out):
        assert np.array_equal(a, b)


def test_plane_rows_that_are_not_one_plane_run_the_general_loop(prism):
    """A plane's contact given per-copy rows of another kind (a box) is stepped as those rows
    say: the plane instance refuses them and the general one runs, as the Python loop."""
    m = prism
    tc = T.TerrainContact(Terrain(plane=Plane(0.0)))
    box = T.TerrainContact(Terrain(plane=None, boxes=[Box([0.0, 0.0, -0.5], [2.0, 2.0, 1.0])]))
    B = 3
    geom = np.repeat(tc.geom, B, axis=0)
    geom[1] = box.geom[0]
    st = initial_state(m, B)
    out = []
    for compiled in (False, True):
        qq, qqd, ts = np.array(st.q), np.array(st.qd), T.init_terrain_state(tc, m, B)
        for _ in range(20):
            T.advance(tc, m, qq, qqd, 1e-3, "semi_implicit_euler", ts, n_steps=10, geom=geom, compiled=compiled)
        out.append((qq, qqd, ts.anchor, ts.eta0, ts.active))
    assert out[1][4][1].any()      # copy 1 rests on its box
    for a, b in zip(*out):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("B", [1, 20])
def test_box_reached_within_one_call_is_the_python_loop(prism, B):
    """A box out of every rod's reach at a call's first sub-step is passed over while no rod end
    has moved by its clearance: robots thrown at walls at 3 m/s reach them after about 63
    sub-steps of one call of 90 (the ground plane, listed first, runs in the driver's lanes);
    the compiled loop keeps the Python loop's bits through the approach and the impact."""
    m = prism
    walls = [Box([0.35, 0.0, 0.2], [0.04, 1.0, 0.4]), Box([-0.35, 0.0, 0.2], [0.04, 1.0, 0.4], 20.0),
             Box([0.0, 0.6, 0.2], [1.0, 0.04, 0.4])]
    tc = T.TerrainContact(Terrain(plane=Plane(0.0), boxes=walls))
    rng = np.random.default_rng(B)
    st = initial_state(m, B)
    q, qd = np.array(st.q), np.array(st.qd)
    q[..., 2] += 0.005
    qd[..., 0] = rng.choice([-3.0, 3.0], (B, 1))         # toward the wall at +x or the yawed one at -x
    out = []
    for compiled in (False, True):
        qq, qqd, ts = q.copy(), qd.copy(), T.init_terrain_state(tc, m, B)
        T.advance(tc, m, qq, qqd, 1e-3, "semi_implicit_euler", ts, n_steps=90, compiled=compiled)
        out.append((qq, qqd, ts.anchor, ts.eta0, ts.active))
    # ground friction alone leaves about 2 m/s after 90 ms: every copy was stopped by its wall
    assert np.all(np.abs(out[0][1][..., 0].mean(axis=1)) < 1.0)
    for a, b in zip(*out):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("B", [1, 20])
def test_compiled_heightfield_rod_lying_flat_is_the_python_loop(B):
    """A lone rod rising 1 cm per m over 0.1 mm bumps: its gap is monotone along it (the field's
    slope bound is about 0.003) and both its caps touch, so the compiled loop must look up its
    upper end too (the gap rises only 4 mm along the rod)."""
    from tensegrity_gym.core.terrain import Heightfield
    from tensegrity_gym.core.structure import Structure
    m = compile_model(Structure(np.array([[0.0, 0.0, 0.012], [0.4, 0.0, 0.016]]), [[0, 1]], np.zeros((0, 2), int),
                                bar_mass=0.2, gravity=(0.0, 0.0, -9.81)))
    rng = np.random.default_rng(11)
    h = 1e-4 * rng.random((30, 30))
    tc = T.TerrainContact(Terrain(plane=None, heightfield=Heightfield(heights=h, cell=0.05, origin=[-0.75, -0.75])))
    st = initial_state(m, B)
    q, qd = np.array(st.q), np.array(st.qd)
    q[..., :2] += rng.normal(0.0, 0.01, q[..., :2].shape)
    qd[..., 0] += 0.1
    out = []
    for compiled in (False, True):
        qq, qqd, ts = q.copy(), qd.copy(), T.init_terrain_state(tc, m, B)
        W = np.empty((B, m.n_nodes, 3))
        both = False
        for _ in range(30):
            T.advance(tc, m, qq, qqd, 1e-3, "semi_implicit_euler", ts, n_steps=5, forces=W, compiled=compiled)
            both |= bool((ts.active[:, 0] & ts.active[:, 1]).any())
        out.append((qq, qqd, ts.anchor, ts.eta0, ts.active, W))
    assert both
    for a, b in zip(*out):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("B", [20, 900])
def test_compiled_boxes_in_the_lanes_are_the_python_loop(prism, B):
    """Boxes after a ground plane run in the driver's lanes (node slots over SIMD lanes, interior
    slots one lane at a time): per-copy boxes (a small yawed block under the middle of rod 0, 3 mm
    inside the cap radius, so that the rod's interior touches it deeper than both ends, and a step
    that some copies' lower nodes rest on), per-copy cap radius, friction and, in every third copy, a
    force exponent of 1.5, with SIMD blocks and pad lanes (20 copies) and the threaded kernel (900):
    the Python loop's bits, interior and node slots touching."""
    m = prism
    rng = np.random.default_rng(B)
    st = initial_state(m, B)
    q, qd = np.array(st.q), np.array(st.qd)
    q[..., :3] += rng.normal(0.0, 0.003, q[..., :3].shape)
    rows = []
    for c in range(B):
        mid = q[c, 0, :3] + float(np.mean(m.eta[0])) * q[c, 0, 3:]
        block = Box([mid[0], mid[1], mid[2] - 0.017 - 0.03], [0.04, 0.04, 0.06], rng.uniform(0.0, 90.0))
        step = Box([rng.uniform(-0.3, 0.3), 0.0, -0.03 + 0.032 * (c % 2)], [0.3, 1.0, 0.06], rng.uniform(0.0, 30.0))
        rows.append(T.TerrainContact(Terrain(plane=Plane(0.0), boxes=[block, step])).geom[0])
    tc = T.TerrainContact(Terrain(plane=Plane(0.0), boxes=[Box([0, 0, -1], [0.1, 0.1, 0.1]),
                                                           Box([0, 0, -2], [0.1, 0.1, 0.1])]))
    geom = np.stack(rows)
    prm = tc.per_copy(B)
    prm[:, 1:, T.PRM_FIELDS.index("friction")] = rng.uniform(0.2, 1.0, (B, 2))
    prm[:, 1:, T.PRM_FIELDS.index("radius")] = rng.uniform(0.018, 0.022, (B, 1))
    prm[::3, 1:, T.PRM_FIELDS.index("exponent")] = 1.5
    out, interior, node = [], False, False
    for compiled in (False, True):
        qq, qqd, ts = q.copy(), qd.copy(), T.init_terrain_state(tc, m, B)
        for _ in range(20):
            T.advance(tc, m, qq, qqd, 1e-3, "semi_implicit_euler", ts, n_steps=8, prm=prm, geom=geom,
                      compiled=compiled)
            act = ts.active.reshape(B, m.n_bars, 3, 3)      # (copy, rod, feature, slot)
            interior |= bool(act[:, 0, 1, 2].any())
            node |= bool(act[:, :, 2, :2].any())
        out.append((qq, qqd, ts.anchor, ts.eta0, ts.active))
    assert interior and node
    for a, b in zip(*out):
        assert np.array_equal(a, b)
