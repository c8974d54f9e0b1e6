"""Per-copy physical parameters (tensegrity_gym.core.params): copy b of a batch stepped with
``params`` equals a one-copy model compiled from a structure that carries copy b's values,
for every integrator, free and constrained rods, gravity, damping, node drag and anchors."""
import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.physics.evaluate import project
from tensegrity_gym.core.model import State
from tensegrity_gym.physics.geometry import energy, linear_momentum
from tensegrity_gym.core.params import Params, default_params

B = 4


def _scenes():
    # free prism with gravity and string damping; a pinned rod with anchors (constrained);
    # the constrained prism (line/plane constrained nodes)
    yield "prism", tg.prism(3, prestress=100.0).replace(gravity=np.array([0.0, 0.0, -9.81]),
                                                          damping=2.0), 0.0
    yield "pinned_rod", tg.pinned_rod(damping=1.0), 0.5
    yield "constrained_prism", tg.constrained_prism(damping=0.5), 1.5


def _random_params(model, rng):
    k, m, n = model.n_bars, model.n_strings, model.n_nodes
    p = default_params(model, B)
    na = len(model.anchor_idx)
    return p.replace(
        mass=model.mass * rng.uniform(0.8, 1.2, (B, k)),
        stiffness=model.stiffness * rng.uniform(0.8, 1.2, (B, m)),
        damping=model.damping * rng.uniform(0.5, 1.5, (B, m)),
        rest_length=model.rest_length * rng.uniform(0.97, 1.03, (B, m)),
        gravity=np.array([0.0, 0.0, -9.81]) * rng.uniform(0.5, 1.5, (B, 1)),
        anchor_pos=model.anchor_pos + rng.uniform(-0.01, 0.01, (B, na, 3)),
    )


def _copy_model(model, params, b, node_damping):
    """A one-copy model compiled from a structure carrying copy b's values."""
    s = model.structure
    nodes = s.nodes.copy()
    nodes[model.anchor_idx] = params.anchor_pos[b]
    s_b = s.replace(nodes=nodes, bar_mass=params.mass[b], stiffness=params.stiffness[b],
                    damping=params.damping[b], rest_length=params.rest_length[b], gravity=params.gravity[b])
    return tg.compile_model(s_b, node_damping=node_damping)


def _moving_state(model, rng, n=B):
    st = tg.initial_state(model, n)
    qd = st.qd + 0.05 * rng.standard_normal(st.qd.shape)
    q, qd = project(model, st.q, qd)
    return State(q=q, qd=qd)


CASES = [("semi_implicit_euler", "numba", 1e-3, 200), ("rk4", "numba", 1e-3, 200), ("implicit_euler", "auto", 1e-3, 10),
         ("dop853", "auto", 1e-3, 20), ("radau", "auto", 1e-3, 5)]


@pytest.mark.parametrize("name,structure,drag", list(_scenes()), ids=[c[0] for c in _scenes()])
@pytest.mark.parametrize("integrator,backend,dt,n", CASES, ids=[f"{c[0]}-{c[1]}" for c in CASES])
def test_copy_equals_model_compiled_with_its_values(name, structure, drag, integrator, backend, dt, n):
    rng = np.random.default_rng(hash((name, integrator)) % 2**32)
    model = tg.compile_model(structure, node_damping=drag)
    params = _random_params(model, rng)
    if drag:
        params = params.replace(node_damping=drag * rng.uniform(0.5, 1.5, (B, model.n_nodes)))
    st = _moving_state(model, rng)
    out = tg.step(model, st, dt, integrator, n_steps=n, backend=backend, params=params)
    for b in range(B):
        mb = _copy_model(model, params, b, params.node_damping[b])
        one = tg.step(mb, State(q=st.q[b:b + 1], qd=st.qd[b:b + 1]), dt, integrator, n_steps=n,
                      backend=backend)
        scale = max(1.0, float(np.abs(one.q).max()))
        assert np.abs(out.q[b] - one.q[0]).max() <= 1e-12 * scale, (b, np.abs(out.q[b] - one.q[0]).max())
        vs = max(1.0, float(np.abs(one.qd).max()))
        assert np.abs(out.qd[b] - one.qd[0]).max() <= 1e-12 * vs
    # the copies really differ (the test would pass vacuously otherwise)
    assert np.abs(out.q[0] - out.q[1]).max() > 1e-6


@pytest.mark.parametrize("backend", ["numba", "auto"])
@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_shared_params_are_bit_identical_to_no_params(backend, integrator):
    model = tg.compile_model(tg.constrained_prism(damping=0.5), node_damping=0.3)
    st = _moving_state(model, np.random.default_rng(1), 20)   # >= 16: the SIMD loop too
    ref = tg.step(model, st, 1e-3, integrator, n_steps=30, backend=backend)
    for p in (default_params(model), default_params(model, 20)):
        out = tg.step(model, st, 1e-3, integrator, n_steps=30, backend=backend, params=p)
        assert np.array_equal(out.q, ref.q) and np.array_equal(out.qd, ref.qd)


def test_parallel_per_copy_kernel_matches_serial():
    from tensegrity_gym.backends.numba import compile as _compile
    model = tg.compile_model(tg.prism(3, prestress=100.0))
    rng = np.random.default_rng(3)
    n = 64
    params = default_params(model, n).replace(stiffness=model.stiffness * rng.uniform(0.5, 1.5, (n, model.n_strings)))
    st = _moving_state(model, rng, n)
    big = tg.step(model, st, 1e-3, "rk4", n_steps=200, params=params)      # above PARALLEL_MIN_WORK
    assert n * 200 * (model.n_strings + model.n_bars) * 4 >= _compile.PARALLEL_MIN_WORK
    for b in (0, 17, 63):
        one = tg.step(model, State(q=st.q[b:b + 1], qd=st.qd[b:b + 1]), 1e-3, "rk4", n_steps=200,
                      params=params.take([b]))
        assert np.array_equal(big.q[b], one.q[0])


def test_step_inplace_per_copy_and_diagnostics():
    from tensegrity_gym.backends.numba import api
    model = tg.compile_model(tg.prism(3, prestress=100.0).replace(gravity=np.array([0, 0, -9.81])))
    rng = np.random.default_rng(4)
    params = _random_params(model, rng)
    st = _moving_state(model, rng)
    q, qd = st.q.copy(), st.qd.copy()
    api.step_inplace(model, q, qd, 1e-3, "rk4", n_steps=10, params=params)
    ref = tg.step(model, st, 1e-3, "rk4", n_steps=10, params=params)
    assert np.array_equal(q, ref.q)
    # diagnostics read the copy's values: energy of copy b equals its own model's
    E = energy(model, ref.q, ref.qd, params=params)
    for b in range(B):
        mb = _copy_model(model, params, b, None)
        np.testing.assert_allclose(E[b], energy(mb, ref.q[b:b + 1], ref.qd[b:b + 1])[0], rtol=1e-13)
        np.testing.assert_allclose(linear_momentum(model, ref.qd, params=params)[b],
                                   linear_momentum(mb, ref.qd[b:b + 1])[0], rtol=1e-13, atol=1e-15)


def test_energy_conserved_per_copy_without_damping():
    model = tg.compile_model(tg.prism(3, prestress=100.0))
    rng = np.random.default_rng(5)
    params = default_params(model, 3).replace(mass=rng.uniform(0.5, 2.0, (3, 3)),
                                              stiffness=rng.uniform(500, 2000, (3, model.n_strings)))
    st = _moving_state(model, rng, 3)
    E0 = energy(model, st.q, st.qd, params=params)
    out = tg.step(model, st, 1e-4, "rk4", n_steps=2000, params=params)
    E1 = energy(model, out.q, out.qd, params=params)
    assert np.all(np.abs(E1 - E0) <= 1e-9 * np.abs(E0))
    assert np.ptp(E0) > 0   # the copies differ


def test_replace_mass_scales_moments_and_weights():
    model = tg.compile_model(tg.pinned_rod())
    p = default_params(model).replace(mass=2.0 * model.mass)
    np.testing.assert_allclose(p.f[0], 2 * model.f)
    np.testing.assert_allclose(p.J[0], 2 * model.J)
    np.testing.assert_allclose(p.W0[0], 2 * model.W0)
    assert isinstance(p, Params) and p.batch_size == 1
    assert not p.mass.flags.writeable


@pytest.mark.parametrize("field,value,match", [
    ("mass", lambda m: np.where(np.arange(8)[:, None] == 7, -1.0, m.mass[None].repeat(8, 0)),
     r"params\.mass: copy 7, rod 0: must be finite and > 0 kg, got -1\.0"),
    ("stiffness", lambda m: np.full((8, m.n_strings), np.nan),
     r"params\.stiffness: copy 0, string 0: must be finite and >= 0 N/m, got nan"),
    ("stiffness", lambda m: np.ones((8, 5)), r"params\.stiffness: expected .*shape \(9,\).*got shape \(8, 5\)"),
    ("gravity", lambda m: "down", r"params\.gravity: expected numbers"),
    ("friction", lambda m: 1.0, r"unknown field"),
])
def test_bad_params_name_field_copy_and_value(field, value, match):
    model = tg.compile_model(tg.prism(3, prestress=100.0))
    with pytest.raises(ValueError, match=match):
        default_params(model).replace(**{field: value(model)})


def test_params_batch_must_match_state():
    model = tg.compile_model(tg.prism(3, prestress=100.0))
    with pytest.raises(ValueError, match="3 copies for a state of 2"):
        tg.step(model, tg.initial_state(model, 2), 1e-3, params=default_params(model, 3))
    with pytest.raises(TypeError, match="Params"):
        tg.step(model, tg.initial_state(model, 2), 1e-3, params={"stiffness": 1.0})
    with pytest.raises(ValueError, match="free rod"):
        default_params(model).replace(f=0.1)


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("n_copies", [B, 20])
def test_repeated_calls_keep_each_copys_anchors(integrator, n_copies):
    """Per-copy anchor positions over several calls (one copy at a time below 16 copies, SIMD
    blocks from 16): copy 0 keeps its own anchors. Before the fix the one-copy-at-a-time loop
    left the last copy's anchors in copy 0's buffer, so from the second call on copy 0 swung
    about them (0.35 mm after 10 steps of the pinned rod)."""
    rng = np.random.default_rng(7)
    model = tg.compile_model(tg.pinned_rod(damping=1.0))
    na = len(model.anchor_idx)
    params = default_params(model, n_copies).replace(
        anchor_pos=model.anchor_pos + rng.uniform(-0.01, 0.01, (n_copies, na, 3)))
    st = _moving_state(model, rng, n_copies)
    out = st
    for _ in range(3):
        out = tg.step(model, out, 1e-3, integrator, n_steps=5, params=params)
    for b in (0, 1, n_copies - 1):
        one = tg.step(_copy_model(model, params, b, None), State(q=st.q[b:b + 1], qd=st.qd[b:b + 1]), 1e-3,
                      integrator, n_steps=15)
        assert np.abs(out.q[b] - one.q[0]).max() <= 1e-12 * max(1.0, float(np.abs(one.q).max())), b
        assert np.abs(out.qd[b] - one.qd[0]).max() <= 1e-12 * max(1.0, float(np.abs(one.qd).max())), b
