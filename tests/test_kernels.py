"""The compiled (numba) kernels reproduce the NumPy reference path.

Every case integrates many steps with both backends from the same state and compares
q and qd to ~1e-12 relative (round-off level: the kernels use the same formulas, with
reciprocals where NumPy divides). Each scene is chosen to exercise a branch of the
kernel (slack strings, damping, gravity, constrained rods, anchors, active strings,
clipped force densities, external forces, the parallel batch loop); the tests check
that the branch is really exercised, and that the comparison can fail.
"""
from __future__ import annotations

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core import builders
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.physics import evaluate
from tensegrity_gym.physics.integrate import step
from tensegrity_gym.physics.stability import stability_limit
from tensegrity_gym.physics.geometry import node_velocities, string_state

import oracle_numpy as oracle

from tensegrity_gym.backends.numba import api as K, compile as KC, layout as KL, pack as KP

RTOL = 1e-12
DT = 1e-3
N_STEPS = 300


def _rel_err(a, b):
    """max |a - b| relative to the largest entry of a, for q and qd."""
    eq = np.abs(a.q - b.q).max() / max(np.abs(a.q).max(), 1e-300)
    eqd = np.abs(a.qd - b.qd).max() / max(np.abs(a.qd).max(), 1e-300)
    return max(eq, eqd)


def _perturbed(model, B, seed, scale=0.2):
    """B copies with random node-velocity perturbations (consistent with the rods and constraints)."""
    rng = np.random.default_rng(seed)
    st = initial_state(model, B)
    qd = st.qd + scale * rng.normal(size=st.qd.shape)
    q, qd = evaluate.project(model, st.q, qd)
    return State(q=np.ascontiguousarray(q), qd=np.ascontiguousarray(qd), t=0.25)


def _scene(name, B, seed=0):
    """(model, state, controls dict) of each test scene, B copies."""
    rng = np.random.default_rng(seed + 100)
    if name == "prism_slack":
        # free prism, no prestress kept: rest lengths per copy up to 8% longer than the strings, so
        # several strings are slack at the start and go taut/slack along the run
        model = compile_model(builders.prism(3))
        st = _perturbed(model, B, seed, scale=1.0)
        l0 = model.rest_length * (1.0 + rng.uniform(-0.05, 0.08, size=(B, model.n_strings)))
        return model, st, dict(rest_length=l0)
    if name == "prism_damped_gravity":
        model = compile_model(builders.prism(3, damping=3.0, gravity=(0.0, 0.0, -9.81)))
        st = _perturbed(model, B, seed)
        ext = rng.normal(scale=2.0, size=(B, model.n_nodes, 3))
        return model, st, dict(external=ext)
    if name == "constrained_prism":
        model = compile_model(builders.constrained_prism(damping=0.5))
        st = _perturbed(model, B, seed)
        fd = rng.normal(scale=60.0, size=(B, model.n_strings))     # some gamma + u < 0: clipped
        return model, st, dict(force_density=fd)
    if name == "pinned_rod":
        model = compile_model(builders.pinned_rod())
        st = _perturbed(model, B, seed)
        l0 = model.rest_length * (1.0 + rng.uniform(-0.03, 0.03, size=(B, model.n_strings)))
        ext = rng.normal(size=(model.n_nodes, 3))                  # (n, 3): same for every copy
        return model, st, dict(rest_length=l0, external=ext)
    if name == "icosahedron_active":
        model = compile_model(builders.icosahedron(), active_strings=[0, 5, 11])
        st = _perturbed(model, B, seed)
        fd = np.zeros((B, model.n_strings))
        fd[:, [0, 5, 11]] = rng.uniform(0.0, 80.0, size=(B, 3))      # actuation through active strings
        fd[:, 7] = -1e3                                              # a clipped (slack) passive string
        return model, st, dict(force_density=fd, rest_length=model.rest_length * 1.01)
    raise KeyError(name)


SCENES = ["prism_slack", "prism_damped_gravity", "constrained_prism", "pinned_rod", "icosahedron_active"]


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("project", [True, False])
@pytest.mark.parametrize("B", [1, 5])
def test_numba_matches_numpy(scene, integrator, project, B):
    model, st, ctl = _scene(scene, B)
    ref = oracle.step(model, st, DT, integrator, project=project, n_steps=N_STEPS, **ctl)
    q0, qd0 = st.q.copy(), st.qd.copy()
    out = K.step(model, st, DT, integrator, project=project, n_steps=N_STEPS, **ctl)
    assert np.all(np.isfinite(ref.q)) and np.abs(ref.q - st.q).max() > 1e-3, "the scene must move"
    assert _rel_err(ref, out) < RTOL, f"{scene} {integrator}: numba deviates by {_rel_err(ref, out):.3g}"
    assert out.t == ref.t
    np.testing.assert_array_equal(st.q, q0)       # the input state is not modified
    np.testing.assert_array_equal(st.qd, qd0)
    # the dispatcher of physics.step takes the same kernel
    via = step(model, st, DT, integrator, project=project, n_steps=N_STEPS, backend="numba", **ctl)
    np.testing.assert_array_equal(via.q, out.q)


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_simd_batch_loop_matches_numpy(scene, integrator):
    """B >= 16 runs the structure-of-arrays (SIMD) loop; 19 copies also exercise the padded lanes."""
    B = 19
    assert B >= KL._SOA_MIN_BATCH
    model, st, ctl = _scene(scene, B, seed=5)
    ref = oracle.step(model, st, DT, integrator, n_steps=100, **ctl)
    out = K.step(model, st, DT, integrator, n_steps=100, **ctl)
    assert _rel_err(ref, out) < RTOL
    one = K.step(model, State(st.q[7:8], st.qd[7:8], st.t), DT, integrator, n_steps=100,
                 **{k: (v[7:8] if np.ndim(v) >= 2 and np.shape(v)[0] == B else v) for k, v in ctl.items()})
    np.testing.assert_array_equal(one.q[0], out.q[7])     # same bits as the one-environment loop


def test_branches_are_exercised():
    """The scenes above really have slack strings, clipped force densities and taut strings."""
    model, st, ctl = _scene("prism_slack", 5)
    slack_seen = taut_seen = 0
    s = st
    for _ in range(30):
        s = oracle.step(model, s, DT, "semi_implicit_euler", n_steps=10, **ctl)
        _, L, _ = string_state(model, s.q)
        slack_seen += int(np.sum(L <= ctl["rest_length"]))
        taut_seen += int(np.sum(L > ctl["rest_length"]))
    assert slack_seen > 0 and taut_seen > 0
    model, st, ctl = _scene("constrained_prism", 5)
    gamma, _, _ = evaluate.force_densities(model, st.q, st.qd)
    assert np.any(gamma + ctl["force_density"] < 0) and np.any(gamma + ctl["force_density"] > 0)
    assert model.has_damping and model.has_gravity and model.constrained.all()


def test_comparison_can_fail():
    """A 1e-9 relative change of one rest length is seen by the comparison (it is not vacuous)."""
    model, st, ctl = _scene("prism_slack", 5)
    ref = oracle.step(model, st, DT, "rk4", n_steps=N_STEPS, **ctl)
    l0 = ctl["rest_length"].copy()
    l0[2, 4] *= 1.0 + 1e-9
    out = K.step(model, st, DT, "rk4", n_steps=N_STEPS, rest_length=l0)
    assert _rel_err(ref, out) > 100 * RTOL


@pytest.mark.parametrize("min_work", [0, None])
def test_parallel_batch_matches_numpy(monkeypatch, min_work):
    """The multi-threaded kernel (forced with PARALLEL_MIN_WORK = 0, and chosen by the default rule
    for this amount of work) matches NumPy; per-copy controls stay with their copy."""
    if min_work is not None:
        monkeypatch.setattr(KC, "PARALLEL_MIN_WORK", min_work)
    B = 37
    model, st, ctl = _scene("prism_damped_gravity", B, seed=3)
    assert K._parallel(K._CACHE.get(id(model)) or KP._pack(model), B, 50, 0)
    stability_limit(model)   # cached now: its Jacobian's acceleration calls are not counted below
    calls = []
    real = K._run_parallel
    monkeypatch.setattr(K, "_run_parallel", lambda *a: calls.append(1) or real(*a))
    l0 = model.rest_length * (1.0 + np.linspace(-0.02, 0.05, B))[:, None]
    for integrator in ("semi_implicit_euler", "rk4"):
        ref = oracle.step(model, st, DT, integrator, n_steps=50, rest_length=l0, **ctl)
        out = K.step(model, st, DT, integrator, n_steps=50, rest_length=l0, **ctl)
        assert _rel_err(ref, out) < RTOL
        q, qd = st.q.copy(), st.qd.copy()
        K.step_inplace(model, q, qd, DT, integrator, n_steps=50, rest_length=l0, **ctl)
        np.testing.assert_array_equal(q, out.q)
        np.testing.assert_array_equal(qd, out.qd)
    assert len(calls) == 4
    if min_work is None:      # the default rule keeps a small call serial
        assert not K._parallel(K._CACHE[id(model)], 2, 1, 0)


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_step_inplace_equals_step(integrator):
    model, st, ctl = _scene("icosahedron_active", 3)
    out = K.step(model, st, DT, integrator, n_steps=40, **ctl)
    q, qd = st.q.copy(), st.qd.copy()
    K.step_inplace(model, q, qd, DT, integrator, n_steps=40, **ctl)
    np.testing.assert_array_equal(q, out.q)
    np.testing.assert_array_equal(qd, out.qd)
    # and without controls (the lean single-env path), one step at a time
    model = compile_model(builders.prism(3))
    st = _perturbed(model, 1, 7)
    ref = oracle.step(model, st, DT, integrator, n_steps=25)
    q, qd = st.q.copy(), st.qd.copy()
    for _ in range(25):
        K.step_inplace(model, q, qd, DT, integrator)
    assert _rel_err(ref, State(q, qd)) < RTOL


def test_odd_inputs_are_converted():
    """float32, strided, read-only and 1-D inputs give the same result as clean float64 arrays."""
    model, st, ctl = _scene("pinned_rod", 4)
    ref = K.step(model, st, DT, "rk4", n_steps=20, **ctl)
    big = np.zeros((8,) + st.q.shape[1:])
    big[::2] = st.q
    strided = State(q=big[::2], qd=st.qd, t=st.t)
    ro_l0 = ctl["rest_length"].copy()
    ro_l0.setflags(write=False)
    out = K.step(model, strided, DT, "rk4", n_steps=20, rest_length=ro_l0, external=ctl["external"])
    np.testing.assert_array_equal(out.q, ref.q)
    out32 = K.step(model, st, DT, "rk4", n_steps=20, rest_length=ctl["rest_length"],
                   external=ctl["external"].astype(np.float32))
    ext32 = ctl["external"].astype(np.float32).astype(np.float64)
    ref32 = K.step(model, st, DT, "rk4", n_steps=20, rest_length=ctl["rest_length"], external=ext32)
    np.testing.assert_array_equal(out32.q, ref32.q)
    one = State(q=st.q[:1], qd=st.qd[:1], t=0.0)
    a = K.step(model, one, DT, "semi_implicit_euler", rest_length=ctl["rest_length"][0], n_steps=5)
    b = K.step(model, one, DT, "semi_implicit_euler", rest_length=ctl["rest_length"][:1], n_steps=5)
    np.testing.assert_array_equal(a.q, b.q)


def test_bad_shapes_raise_clear_errors():
    model, st, ctl = _scene("prism_slack", 2)
    m, n = model.n_strings, model.n_nodes
    with pytest.raises(ValueError, match="rest_length"):
        K.step(model, st, DT, "rk4", rest_length=np.ones((3, m)))
    with pytest.raises(ValueError, match="rest_length"):
        K.step(model, st, DT, "rk4", rest_length=np.ones(m + 1))
    with pytest.raises(ValueError, match="force_density"):
        K.step(model, st, DT, "rk4", force_density=np.ones((2, m - 1)))
    with pytest.raises(ValueError, match="external"):
        K.step(model, st, DT, "rk4", external=np.ones((2, n + 1, 3)))
    with pytest.raises(ValueError, match="q"):
        K.step(model, State(st.q[:, :2], st.qd[:, :2]), DT, "rk4")
    with pytest.raises(ValueError, match="integrator"):
        K.step(model, st, DT, "dop853")
    with pytest.raises(TypeError, match="callable"):
        K.step(model, st, DT, "rk4", external=lambda q, qd, t: 0.0)
    q32 = st.q.astype(np.float32)
    with pytest.raises(ValueError, match="C-contiguous float64"):
        K.step_inplace(model, q32, st.qd.copy(), DT)


def test_model_cache_follows_model_lifetime():
    import gc
    model = compile_model(tg.build("prism3"))
    K.step(model, initial_state(model), DT, "semi_implicit_euler")
    key = id(model)
    assert key in K._CACHE
    del model
    gc.collect()
    assert key not in K._CACHE


@pytest.mark.parametrize("B", [2, 17])
def test_great_circle_drift_matches_numpy(B):
    """Semi-implicit Euler with projection moves b along great circles: numba agrees with NumPy
    for copies at rest (rotation angle per step below the sin(x)/x series threshold) and copies
    spinning fast (0.05-0.1 rad per step), in the one-environment and the SIMD loops."""
    model = compile_model(builders.prism(3))
    st = initial_state(model, B)
    s = model.structure
    omega = np.random.default_rng(3).normal(size=(B, 3)) * 40.0
    omega[0] = 0.0                                        # copy 0: the prestressed prism at rest
    vel = np.cross(omega[:, None, :], (s.nodes - s.nodes.mean(axis=0))[None])
    st = initial_state(model, nodes=np.broadcast_to(s.nodes, (B,) + s.nodes.shape), velocities=vel)
    ref = oracle.step(model, st, 2e-3, "semi_implicit_euler", n_steps=200)
    out = K.step(model, st, 2e-3, "semi_implicit_euler", n_steps=200)
    step_angle = np.linalg.norm(st.qd[..., 3:], axis=-1).max() * 2e-3
    assert step_angle > 0.05 and np.linalg.norm(st.qd[0, :, 3:], axis=-1).max() * 2e-3 < KL._SINC_SMALL
    # 200 steps of a fast spin: numba's and NumPy's sin/cos/sqrt may differ in the last bit and
    # the difference grows with the (string-coupled) motion; 1e-10 still rules out any other change
    assert _rel_err(ref, out) < 1e-10, _rel_err(ref, out)
    # the unprojected update (plain q += dt qd) takes a visibly different path
    plain = oracle.step(model, st, 2e-3, "semi_implicit_euler", n_steps=200,
                             project=False)
    assert np.abs(plain.q - ref.q).max() > 1e-4


@pytest.mark.parametrize("B", [3, 19])
@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_node_damping_matches_numpy(B, integrator, monkeypatch):
    """Per-node drag in the model (compile_model(node_damping=c)): the one-environment loop, the
    SIMD loop (B = 19) and the parallel kernel agree with NumPy, with controls and an external
    force on top; the drag changes the result (the comparison is not vacuous)."""
    s = builders.constrained_prism(damping=0.5)
    c = np.linspace(0.5, 4.0, s.n_nodes)
    model = compile_model(s, node_damping=c)
    st = _perturbed(model, B, 9)
    rng = np.random.default_rng(2)
    ctl = dict(rest_length=model.rest_length * rng.uniform(0.97, 1.02, (B, model.n_strings)),
               external=rng.normal(size=(B, model.n_nodes, 3)))
    ref = oracle.step(model, st, DT, integrator, n_steps=100, **ctl)
    out = K.step(model, st, DT, integrator, n_steps=100, **ctl)
    assert _rel_err(ref, out) < RTOL, _rel_err(ref, out)
    lean = K.step(model, st, DT, integrator, n_steps=100)               # no controls: the lean entry point
    assert _rel_err(oracle.step(model, st, DT, integrator, n_steps=100), lean) < RTOL
    no_drag = K.step(compile_model(s), st, DT, integrator, n_steps=100, **ctl)
    assert _rel_err(out, no_drag) > 1e-6
    monkeypatch.setattr(KC, "PARALLEL_MIN_WORK", 0)
    if B >= 8:
        par = K.step(model, st, DT, integrator, n_steps=100, **ctl)
        np.testing.assert_array_equal(par.q, out.q)


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("B", [1, 5, 40])
def test_accelerations_entry_matches_numpy(scene, B):
    """``backends.numba.api.accelerations`` (the loop driver's force and rod equations, no step) equals
    ``physics.accelerations`` to round-off: one copy at a time (B < 16) and SIMD blocks (B = 40)."""
    model, st, ctrl = _scene(scene, B)
    a_ref = oracle.accelerations(model, st.q, st.qd, **ctrl)
    a = K.accelerations(model, st.q, st.qd, **ctrl)
    assert a.shape == st.q.shape
    assert np.abs(a - a_ref).max() <= RTOL * np.abs(a_ref).max()
    assert np.abs(a_ref).max() > 1.0                     # a real comparison (nonzero accelerations)


def test_accelerations_entry_parallel_params_and_shapes(monkeypatch):
    """The parallel kernel, per-copy Params, an unbatched (k, 6) state and bad shapes."""
    from tensegrity_gym.core.params import default_params
    model, st, ctrl = _scene("constrained_prism", 24)
    ref = oracle.accelerations(model, st.q, st.qd, **ctrl)
    monkeypatch.setattr(KC, "PARALLEL_MIN_WORK", 1)
    assert np.abs(K.accelerations(model, st.q, st.qd, **ctrl) - ref).max() <= RTOL * np.abs(ref).max()
    monkeypatch.undo()
    rng = np.random.default_rng(5)
    prm = default_params(model, 24).replace(stiffness=model.stiffness * rng.uniform(0.8, 1.2, (24, model.n_strings)),
                                            mass=model.mass * rng.uniform(0.8, 1.2, (24, model.n_bars)))
    ref_p = oracle.accelerations(model, st.q, st.qd, params=prm, **ctrl)
    assert np.abs(ref_p - ref).max() > 1e-3 * np.abs(ref).max()     # the parameters matter
    a_p = K.accelerations(model, st.q, st.qd, params=prm, **ctrl)
    assert np.abs(a_p - ref_p).max() <= RTOL * np.abs(ref_p).max()
    one = K.accelerations(model, st.q[3], st.qd[3], force_density=ctrl["force_density"][3])
    assert one.shape == (model.n_bars, 6)
    np.testing.assert_allclose(one, ref[3], rtol=0, atol=RTOL * np.abs(ref).max())
    with pytest.raises(ValueError, match="force_density"):
        K.accelerations(model, st.q, st.qd, force_density=np.zeros((24, model.n_strings + 1)))
    with pytest.raises(ValueError, match="qd"):
        K.accelerations(model, st.q, st.qd[:, :2])


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("B", [1, 5])
def test_string_forces_entry_matches_numpy(scene, B):
    """``backends.numba.api.string_forces`` (the loop driver's own string and nodal force equations, which
    ``physics.evaluate.force_densities`` / ``nodal_forces`` return to observations, rendering and statics)
    equals the NumPy oracle to round-off: slack strings, damping, gravity, node drag, anchors,
    force-density controls (some clipped at 0), external forces, per-copy parameters."""
    from tensegrity_gym.core.params import default_params
    model, st, ctrl = _scene(scene, B)
    fd_kw = {k: v for k, v in ctrl.items() if k != "external"}
    g_ref, S_ref, L_ref = oracle.force_densities(model, st.q, st.qd, **fd_kw)
    F_ref, _ = oracle.nodal_forces(model, st.q, st.qd, **ctrl)
    gamma, L, F = K.string_forces(model, st.q, st.qd, **ctrl)
    assert gamma.shape == (B, model.n_strings) and L.shape == gamma.shape and F.shape == (B, model.n_nodes, 3)
    assert np.abs(gamma - g_ref).max() <= RTOL * np.abs(g_ref).max()
    assert np.abs(L - L_ref).max() <= RTOL * np.abs(L_ref).max()
    assert np.abs(F - F_ref).max() <= RTOL * np.abs(F_ref).max()
    assert (gamma == 0).any() == (g_ref == 0).any() and np.array_equal(gamma > 0, g_ref > 0)
    g2, S2, L2 = evaluate.force_densities(model, st.q, st.qd, **fd_kw)      # the package's entry: the kernel
    assert np.array_equal(g2, gamma) and np.array_equal(L2, L) and np.abs(S2 - S_ref).max() < 1e-14
    F2, g3 = evaluate.nodal_forces(model, st.q, st.qd, **ctrl)
    assert np.array_equal(F2, F) and np.array_equal(g3, gamma)
    rng = np.random.default_rng(9)
    prm = default_params(model, B).replace(stiffness=model.stiffness * rng.uniform(0.7, 1.3, (B, model.n_strings)),
                                           damping=model.damping * rng.uniform(0.5, 1.5, (B, model.n_strings)))
    g_ref, _, _ = oracle.force_densities(model, st.q, st.qd, params=prm, **fd_kw)
    F_ref, _ = oracle.nodal_forces(model, st.q, st.qd, params=prm, **ctrl)
    gamma, _, F = K.string_forces(model, st.q, st.qd, params=prm, **ctrl)
    assert np.abs(gamma - g_ref).max() <= RTOL * np.abs(g_ref).max()
    assert np.abs(F - F_ref).max() <= RTOL * np.abs(F_ref).max()
    with pytest.raises(ValueError, match="rest_length"):
        K.string_forces(model, st.q, st.qd, rest_length=np.ones(model.n_strings + 1))


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("B", [1, 5, 40])
def test_project_entry_matches_numpy(scene, B, monkeypatch):
    """``backends.numba.api.project`` (the loop driver's ``_project``, no step) equals
    ``physics.project`` to round-off on states off the constraint manifold (|b| != 1,
    b . b' != 0, constrained points off their line/plane), serial, SIMD and parallel; a (k, 6)
    state keeps its shape; the input arrays are not modified."""
    model, st, _ = _scene(scene, B)
    rng = np.random.default_rng(7)
    q = st.q + 0.05 * rng.normal(size=st.q.shape)
    qd = st.qd + rng.normal(size=st.qd.shape)
    q0, qd0 = q.copy(), qd.copy()
    ref = oracle.project(model, q, qd)
    for min_work in (KC.PARALLEL_MIN_WORK, 1):
        monkeypatch.setattr(KC, "PARALLEL_MIN_WORK", min_work)
        out = K.project(model, q, qd)
        assert np.abs(out[0] - ref[0]).max() <= 1e-14 and np.abs(out[1] - ref[1]).max() <= RTOL * np.abs(qd).max()
    np.testing.assert_array_equal(q, q0)
    np.testing.assert_array_equal(qd, qd0)
    assert np.abs(np.linalg.norm(out[0][..., 3:], axis=-1) - 1).max() < 1e-15
    assert np.abs(np.einsum("bki,bki->bk", out[0][..., 3:], out[1][..., 3:])).max() < 1e-13 * np.abs(qd).max()
    assert np.abs(out[0] - q).max() > 1e-3                 # it did project
    one = K.project(model, q[0], qd[0])
    assert one[0].shape == (model.n_bars, 6)
    np.testing.assert_array_equal(one[0], K.project(model, q[:1], qd[:1])[0][0])


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("scene", ["prism_damped_gravity", "constrained_prism"])
def test_callable_external_runs_on_the_kernels(scene, integrator, monkeypatch):
    """A callable ``external(q, qd, t)`` on the numba backend: Python calls it (once per step
    for semi-implicit Euler, at each RK4 stage), the kernels do the physics. A callable
    returning a constant array gives the array's result bit for bit; a state- and
    time-dependent one agrees with the NumPy oracle to round-off."""
    model, st, ctl = _scene(scene, 3)
    E = np.random.default_rng(3).normal(scale=2.0, size=(3, model.n_nodes, 3))
    ctl = {k: v for k, v in ctl.items() if k != "external"}

    def f(q, qd, t):
        return E * np.sin(5.0 * t) - 0.5 * node_velocities(model, qd)

    ref_const = step(model, st, DT, integrator, n_steps=60, external=E, **ctl)
    ref = oracle.step(model, st, DT, integrator, n_steps=60, external=f, **ctl)
    const = step(model, st, DT, integrator, n_steps=60, external=lambda q, qd, t: E, **ctl)
    np.testing.assert_array_equal(const.q, ref_const.q)
    np.testing.assert_array_equal(const.qd, ref_const.qd)
    out = step(model, st, DT, integrator, n_steps=60, external=f, **ctl)
    assert _rel_err(ref, out) < RTOL
    assert out.t == pytest.approx(st.t + 60 * DT)
    assert _rel_err(out, const) > 1e-6                  # the time- and state-dependence mattered
