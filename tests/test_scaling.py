"""Cost linear in structure size: sparse string connectivity, the sparse finite-difference
Jacobian and stability estimate, and the up-front memory refusal (SI units throughout)."""
from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.physics.evaluate import force_densities, nodal_forces
from tensegrity_gym.core.model import compile_model, initial_state
from tensegrity_gym.physics.geometry import connectivity
from tensegrity_gym.physics.stability import stable_step_estimate
from tensegrity_gym.physics import jacobian as jac
from tensegrity_gym.core import sizing
from tensegrity_gym.physics import stability
from tensegrity_gym.core.builders import tower

import oracle_numpy as oracle
from reference import rigid_perturbation


def _dense_connectivity(model):
    """The seed's C_S (m, n) as a dense matrix (+1 at node j, -1 at node i): the test oracle."""
    C = np.zeros((model.n_strings, model.n_nodes))
    C[np.arange(model.n_strings), model.str_j] += 1.0
    C[np.arange(model.n_strings), model.str_i] -= 1.0
    return C


def _dense_nodal_forces(model, q, qd, rest_length=None, force_density=None, external=None, params=None):
    """The explicit formula W - N C_S^T Gamma C_S with the dense C (oracle)."""
    gamma, S, _ = force_densities(model, q, qd, rest_length, force_density, params)
    F = -np.einsum("mn,bmi->bni", _dense_connectivity(model), gamma[..., None] * S)
    return oracle.add_loads(model, F, qd, external, params), gamma


def _scenes():
    hanging = tg.Structure([[0, 0, 1.0], [0, 0, 0.0], [0.3, 0, 0.5], [-0.3, 0, 0.5]],
                           [[2, 3]], [[0, 2], [0, 3], [1, 2], [1, 3]], bar_mass=0.5, stiffness=300.0,
                           rest_length=0.4, damping=2.0, gravity=(0, 0, -9.81),
                           name="anchored_rod")
    return [
        ("prism3", compile_model(tg.prism(3)), 1, None),                        # add.at branch
        ("prism3 B=64 active", compile_model(tg.prism(3, damping=3.0), active_strings=[0, 4]), 64,
         np.random.default_rng(9).uniform(0, 20, (64, 9))),
        ("constrained_prism", compile_model(tg.constrained_prism(damping=0.5), node_damping=1.5), 7, None),
        ("anchored_rod", compile_model(hanging), 40, None),
        ("tower10 gravity", compile_model(tower(10, damping=1.0, gravity=(0, 0, -9.81))), 5, None),
    ]


@pytest.mark.parametrize("name, model, B, fd", _scenes(), ids=[s[0] for s in _scenes()])
def test_nodal_forces_equal_dense_connectivity_formula(name, model, B, fd):
    rng = np.random.default_rng(3)
    s = model.structure
    nodes = s.nodes + 0.05 * rng.standard_normal((B,) + s.nodes.shape)
    vel = rng.standard_normal((B,) + s.nodes.shape)
    st = initial_state(model, B, nodes=nodes, velocities=vel)
    rl = model.rest_length * rng.uniform(0.9, 1.1, (B, model.n_strings))
    ext = rng.standard_normal((B, s.n_nodes, 3))
    from tensegrity_gym.core.params import default_params
    params = default_params(model, B).replace(
        stiffness=model.stiffness * rng.uniform(0.8, 1.2, (B, model.n_strings)),
        gravity=np.array([0.0, 0.0, -9.81]) * rng.uniform(0.5, 1.5, (B, 1)))
    for kw in ({}, {"rest_length": rl, "force_density": fd, "external": ext}, {"params": params}):
        F, gamma = nodal_forces(model, st.q, st.qd, **kw)
        F0, gamma0 = _dense_nodal_forces(model, st.q, st.qd, **kw)
        np.testing.assert_array_equal(gamma, gamma0)
        scale = np.abs(F0).max()
        np.testing.assert_allclose(F, F0, rtol=0, atol=1e-13 * scale)
    assert F.shape == (B, s.n_nodes, 3)


def test_connectivity_is_the_sparse_C_S():
    model = compile_model(tower(4))
    C = connectivity(model)
    assert C.shape == (model.n_strings, model.n_nodes) and C.nnz == 2 * model.n_strings
    np.testing.assert_array_equal(C.toarray(), _dense_connectivity(model))


def test_model_has_no_dense_string_by_node_array():
    """tower300 (900 rods, 4494 strings, 1800 nodes): every array of the model is linear in size."""
    s = tower(300)
    model = compile_model(s)
    k, n, m = s.n_bars, s.n_nodes, s.n_strings
    assert not hasattr(model, "C")
    for f in dataclasses.fields(model):
        a = getattr(model, f.name)
        if isinstance(a, np.ndarray):
            assert a.size <= 9 * max(k, n, m), (f.name, a.shape)
            assert a.ndim < 2 or a.shape[:2] not in ((m, n), (n, m)), (f.name, a.shape)


def test_info_tower300_allocates_no_dense_matrix(monkeypatch):
    """The whole `info` summary of tower300 (compile, accelerations, stable-step estimate) peaks
    far below one dense m x n float array (65 MB) or one dense 6k x 6k Jacobian (233 MB)."""
    from tensegrity_gym.tools.cli import structure_summary
    monkeypatch.setattr(sizing, "FD_CHUNK_BYTES", 8 * 2 ** 20)
    s = tower(300)
    structure_summary(tower(12))          # imports and first-call allocations outside the measurement
    tracemalloc.start()
    try:
        d = structure_summary(s)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    dense_mn = 8 * s.n_strings * s.n_nodes
    assert peak < 0.6 * dense_mn, f"peak {peak / 2 ** 20:.1f} MiB"
    assert np.isfinite(d["stable_dt_s"]["rk4"]) and d["omega_max_rad_per_s"] > 0


def test_distance2_colouring_is_valid():
    model = compile_model(tower(30))
    A = jac.rod_coupling(model)
    colour = jac.distance2_colouring(A)
    A2 = (A @ A).tocoo()
    clash = (colour[A2.row] == colour[A2.col]) & (A2.row != A2.col)
    assert not clash.any()
    assert colour.max() + 1 <= 20          # bounded whatever the height: O(colours) evaluations


def test_grouped_fd_rejects_an_invalid_grouping():
    with pytest.raises(ValueError, match="share a row"):
        jac.fd_jacobian_grouped(lambda Z: Z ** 2, np.ones(2), 1e-6, np.array([0, 0]), np.array([0, 0]),
                                np.array([0, 1]), 1)


@pytest.mark.parametrize("scene", ["constrained_prism", "tower4_damped_moving"])
def test_sparse_jacobian_equals_dense(scene):
    if scene == "constrained_prism":
        s = tg.constrained_prism(damping=0.5)
        model = compile_model(s, node_damping=0.3)
    else:
        s = tower(4, damping=2.0)
        model = compile_model(s)
    nodes, vel = rigid_perturbation(s, np.random.default_rng(2), pos=0.01, rot=0.05, vel=0.2, omega=1.0)
    st = initial_state(model, nodes=nodes, velocities=vel)
    Ks, Ds = jac.acceleration_jacobians_sparse(model, st.q, st.qd)
    _, K, D = jac.acceleration_jacobians(model, st.q, st.qd, central=True, rel_step=1e-6)
    for sp, dense in ((Ks, K[0]), (Ds, D[0])):
        full = sp.toarray()
        np.testing.assert_allclose(full, dense, rtol=0, atol=1e-7 * np.abs(dense).max())
        outside = np.ones(dense.shape, bool)
        outside[sp.nonzero()] = False
        assert np.all(dense[outside] == 0.0)     # the pattern holds every dependence


def test_dense_stability_path_kept_for_small_structures():
    m = compile_model(tg.prism(3))
    est = stable_step_estimate(m)
    assert est["method"] == "dense"
    assert stable_step_estimate(compile_model(tower(7)))["method"] == "sparse"     # 21 rods
    with pytest.raises(ValueError, match="method"):
        stable_step_estimate(m, method="lanczos")


@pytest.mark.parametrize("scene", ["tower8", "tower8_damped", "tower8_moving", "icosahedron_drag"])
def test_sparse_stability_estimate_is_conservative(scene):
    """Mid-size structures where both run: the sparse estimate's omega/lambda equal the dense
    ones (to Arnoldi's tolerance), its steps are never above the dense ones and at most the stated
    factor below (2.5 semi-implicit Euler, 1.12 RK4: the docstring of physics.stability._stable_step_sparse)."""
    st = None
    if scene == "tower8":
        m = compile_model(tower(8))
    elif scene == "tower8_damped":
        m = compile_model(tower(8, damping=5.0))
    elif scene == "tower8_moving":
        s = tower(8)
        m = compile_model(s)
        nodes, vel = rigid_perturbation(s, np.random.default_rng(5), pos=0.01, rot=0.02, vel=0.3, omega=2.0)
        st = initial_state(m, nodes=nodes, velocities=vel)
    else:
        m = compile_model(tg.icosahedron(damping=1.0), node_damping=2.0)
    d = stable_step_estimate(m, st, method="dense")
    sp = stable_step_estimate(m, st, method="sparse")
    assert sp["method"] == "sparse" and d["method"] == "dense"
    assert sp["omega_max"] == pytest.approx(d["omega_max"], rel=1e-4)
    assert sp["lambda_max"] == pytest.approx(d["lambda_max"], rel=1e-4)
    for name, factor in (("semi_implicit_euler", 2.5), ("rk4", 1.12)):
        assert sp[name] <= d[name] * (1 + 1e-6), (name, sp[name], d[name])
        assert sp[name] >= d[name] / factor, (name, sp[name], d[name])
    if scene == "tower8":     # undamped at rest: the top mode limits, equal but for the 2e-3 margin
        assert sp["semi_implicit_euler"] == pytest.approx(d["semi_implicit_euler"], rel=2.5e-3)
        assert sp["rk4"] == pytest.approx(d["rk4"], rel=2.5e-3)


def test_sparse_estimate_fallback_bound_is_rigorous(monkeypatch):
    """Arnoldi not converging: the Collatz-Wielandt bound is above every |eigenvalue|, and the
    steps from it stay below the dense ones."""
    from scipy.sparse.linalg import ArpackNoConvergence
    m = compile_model(tower(8, damping=1.0))
    d = stable_step_estimate(m, method="dense")

    def fail(A, nev):
        raise ArpackNoConvergence("no convergence (test)", np.array([]), np.array([]))

    monkeypatch.setattr(stability, "_top_eigenvalues", fail)
    sp = stable_step_estimate(m, method="sparse")
    assert sp["lambda_max"] >= d["lambda_max"] and sp["omega_max"] >= d["omega_max"]
    assert sp["lambda_max"] < 3 * d["lambda_max"]
    for name in ("semi_implicit_euler", "rk4"):
        assert 0 < sp[name] <= d[name]


def test_memory_estimate_is_linear_and_refusal_names_the_size(monkeypatch):
    e0 = sizing.memory_estimate(0, 0, 0)
    e1 = sizing.memory_estimate(900, 1800, 4494)
    e2 = sizing.memory_estimate(1800, 3600, 8988)
    assert e2 - e1 == e1 - e0 > 0                         # linear in the counts
    assert sizing.memory_estimate(900, 1800, 4494, batch_size=4) > e1
    s = tower(30)
    with pytest.raises(sizing.StructureTooLarge, match=r"90 rods, 180 nodes, 444 strings") as e:
        sizing.check_size(s, available=10 ** 6)
    assert "GiB" in str(e.value) and "tower30" in str(e.value)
    monkeypatch.setattr(sizing, "available_memory", lambda: 10 ** 6)
    with pytest.raises(MemoryError, match="too large"):
        compile_model(s)
    assert sizing.check_size(s, available=2 ** 40) > 0


def test_cli_refuses_a_structure_too_large_at_once(monkeypatch, capsys):
    from tensegrity_gym.tools import cli
    monkeypatch.setattr(sizing, "available_memory", lambda: 10 ** 6)
    assert cli.main(["info", "tower30"]) != 0
    err = capsys.readouterr().err
    assert "too large" in err and "90 rods" in err and "Traceback" not in err


def test_grouped_fd_in_chunks_equals_one_batch(monkeypatch):
    """Memory-bounded chunks (here 2 states per call) give the same sparse Jacobian as one batch."""
    s = tower(5, damping=1.0)
    model = compile_model(s)
    nodes, vel = rigid_perturbation(s, np.random.default_rng(7), pos=0.01, rot=0.02, vel=0.1, omega=0.5)
    st = initial_state(model, nodes=nodes, velocities=vel)
    K1, D1 = jac.acceleration_jacobians_sparse(model, st.q, st.qd)
    monkeypatch.setattr(sizing, "FD_CHUNK_BYTES", 1)
    K2, D2 = jac.acceleration_jacobians_sparse(model, st.q, st.qd)
    assert (K1 != K2).nnz == 0 and (D1 != D2).nnz == 0


def test_nodal_forces_of_a_copy_do_not_depend_on_the_batch_size():
    """The index scatter takes one path for small batches and another for large ones; both must
    give each copy the same bits (a vector env's targets, solved in a batch, equal a single env's)."""
    model = tg.compile_model(tg.tower(3))
    rng = np.random.default_rng(0)
    st = tg.initial_state(model, 40)
    q = st.q + 1e-3 * rng.standard_normal(st.q.shape)
    qd = 0.1 * rng.standard_normal(st.q.shape)
    F, _ = nodal_forces(model, q, qd)
    for b in (0, 7, 39):
        assert np.array_equal(F[b], nodal_forces(model, q[b:b + 1], qd[b:b + 1])[0][0])
