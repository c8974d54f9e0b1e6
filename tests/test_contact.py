"""Ground contact (tensegrity_gym.physics.contact): friction with a stick phase, slopes, penetration,
energy, and the NumPy / numba kernels agreeing. SI units. The figures and the 10 s creep
measurement are in scripts/figures/contact_figures.py (docs/contact.md)."""
import math

import numpy as np
import pytest

from tensegrity_gym.core import builders
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.physics.contact import (PRM_FIELDS, ContactState, GroundContact, contact_energy, contact_forces,
                                            init_contact_state, stable_step)
from tensegrity_gym.physics.pipeline import contact_step
from tensegrity_gym.physics.geometry import center_of_mass, energy, linear_momentum, node_positions
from tensegrity_gym.core.structure import Structure

import oracle_numpy as oracle

G = 9.81
DT = 1e-3


def flat_rod(v0=0.0, gravity=(0.0, 0.0, -G), length=0.4, mass=0.2, radius=0.02, along=(1.0, 0.0, 0.0)):
    """A lone rod lying flat on the ground (both caps touching), moving at v0 along x."""
    a = np.asarray(along, float)
    n0 = np.array([0.0, 0.0, radius])
    nodes = [n0, n0 + length * a]
    vel = [[v0, 0.0, 0.0], [v0, 0.0, 0.0]]
    s = Structure(nodes, [[0, 1]], np.zeros((0, 2), int), bar_mass=mass, gravity=gravity, velocities=vel)
    return compile_model(s)


def run(model, contact, T, dt=DT, every=1, state=None, cstate=None):
    st = initial_state(model, 1) if state is None else state
    cs = init_contact_state(model, 1) if cstate is None else cstate
    ts, com, vel = [], [], []
    n = int(round(T / dt))
    for i in range(n):
        if i % every == 0:
            ts.append(st.t)
            com.append(center_of_mass(model, st.q)[0])
            vel.append(linear_momentum(model, st.qd)[0] / model.mass.sum())
        st, cs = contact_step(model, contact, st, cs, dt)
    return np.array(ts), np.array(com), np.array(vel), st, cs


def resting_prism(drop=0.0, damping=2.0):
    s = builders.prism(3, radius=0.15, height=0.25, bar_mass=0.2, stiffness=1000.0, prestress=20.0,
                       damping=damping, gravity=(0.0, 0.0, -G))
    nodes = s.nodes.copy()
    nodes[:, 2] += 0.02 + drop
    return compile_model(s.replace(nodes=nodes))


@pytest.mark.parametrize("v0", [0.5, 1.0])
def test_sliding_rod_decelerates_at_mu_g_and_stops(v0):
    mu = 0.5
    c = GroundContact(friction=mu)
    m = flat_rod(v0)
    t, x, v, st, cs = run(m, c, T=v0 / (mu * G) + 0.3)
    vx = v[:, 0]
    sel = (vx < 0.8 * v0) & (vx > 0.2 * v0)
    a = -np.polyfit(t[sel], vx[sel], 1)[0]
    assert abs(a / (mu * G) - 1) < 0.02, a
    # stops, at the distance v0^2 / (2 mu g), and stays stopped (stick)
    assert abs(vx[-1]) < 1e-3
    d = x[-1, 0] - x[0, 0]
    assert abs(d / (v0 ** 2 / (2 * mu * G)) - 1) < 0.02, d
    t2, x2, _, _, _ = run(m, c, T=1.0, state=st, cstate=cs)
    assert np.abs(x2[:, :2] - x2[0, :2]).max() < 1e-5


@pytest.mark.parametrize("along", [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0)])
def test_slope_steeper_than_atan_mu_slides_shallower_stays(along):
    mu = 0.5
    c = GroundContact(friction=mu)
    crit = math.atan(mu)
    for theta, slides in ((crit + math.radians(5), True), (crit - math.radians(5), False)):
        grav = (G * math.sin(theta), 0.0, -G * math.cos(theta))   # slope emulated by tilted gravity
        m = flat_rod(0.0, gravity=grav, along=along)
        t, x, v, _, _ = run(m, c, T=1.0)
        disp = x[-1, 0] - x[0, 0]
        if slides:
            a_th = G * (math.sin(theta) - mu * math.cos(theta))
            sel = t > 0.2
            a = np.polyfit(t[sel], v[sel, 0], 1)[0]
            assert abs(a / a_th - 1) < 0.02, (a, a_th)
            assert disp > 0.3 * a_th
        else:
            assert abs(disp) < 1e-4, disp   # elastic offset of the stick spring only: no creep


def test_resting_prism_does_not_creep():
    """A prestressed prism on the ground under gravity: after settling (1 s), its caps move less
    than 1 mm over the next 3 s (scripts/figures/contact_figures.py measures 10 s)."""
    m = resting_prism()
    c = GroundContact()
    st = initial_state(m, 1)
    cs = init_contact_state(m, 1)
    st, cs = contact_step(m, c, st, cs, DT, n_steps=1000)
    n0 = node_positions(m, st.q)[0]
    st, cs = contact_step(m, c, st, cs, DT, n_steps=3000)
    n1 = node_positions(m, st.q)[0]
    assert np.abs(n1 - n0).max() < 1e-3
    assert np.abs(n1[:3, :2] - n0[:3, :2]).max() < 1e-4   # the caps on the ground stick
    assert cs.active[0].sum() == 3   # resting on the three bottom caps


def test_penetration_bounded_and_energy_only_decreases():
    """Drop from 5 cm: penetration < 2 mm (impact), ~W/k at rest; the total energy (mechanical +
    contact springs) never rises by more than the integrator's O(dt) error, which shrinks with dt."""
    excess = {}
    for dt in (1e-3, 2.5e-4):
        m = resting_prism(drop=0.05)
        c = GroundContact()
        st = initial_state(m, 1)
        cs = init_contact_state(m, 1)
        E, pen = [], []
        for i in range(int(round(0.6 / dt))):
            E.append(energy(m, st.q, st.qd)[0] + contact_energy(c, m, st.q, cs)[0])
            pen.append(c.radius - node_positions(m, st.q)[0, :, 2].min())
            st, cs = contact_step(m, c, st, cs, dt)
        E = np.array(E)
        assert max(pen) < 2e-3
        assert E[-1] < E[0] - 0.05          # impact + damping dissipate energy
        excess[dt] = float(np.max(E - np.minimum.accumulate(E)))
        assert excess[dt] < 5e-3 * E[0], excess
    assert excess[2.5e-4] < 0.5 * excess[1e-3], excess   # integration error, not energy creation


def test_normal_force_never_pulls_and_is_continuous():
    c = GroundContact()
    m = flat_rod(0.0)
    st = initial_state(m, 1)
    cs = init_contact_state(m, 1)
    # caps slightly in the ground but flying up fast: the damping term would pull; clipped at 0
    q = st.q.copy()
    q[..., 2] -= 1e-4
    qd = np.zeros_like(st.qd)
    qd[..., 2] = 5.0
    W, _, _ = contact_forces(c, m, q, qd, cs)
    assert np.all(W[..., 2] == 0.0)
    # just touching: zero force (Hunt-Crossley: no impulse at touch-down)
    q = st.q.copy()
    qd[..., 2] = -2.0
    W, _, _ = contact_forces(c, m, q, qd, cs)
    assert np.abs(W).max() < 1e-9


def test_numba_kernel_agrees_with_numpy_oracle():
    rng = np.random.default_rng(0)
    m = resting_prism()
    st = initial_state(m, 8)
    q = st.q + rng.normal(0, 0.01, st.q.shape)
    q[..., 2] -= 0.03
    qd = rng.normal(0, 0.5, st.q.shape)
    cs = ContactState(rng.normal(0, 0.01, (8, 6, 2)), rng.random((8, 6)) < 0.5)
    a = GroundContact(friction=0.3, max_damping=30.0)   # cap engaged for deep contacts
    W1, anchor1, active1, sl1 = oracle.contact_forces(a, m, q, qd, cs.anchor, cs.active)
    W2, s2, sl2 = contact_forces(a, m, q, qd, cs)
    assert sl1.any() and (~sl1 & active1).any()     # both slip and stick exercised
    np.testing.assert_allclose(W1, W2, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(anchor1[active1], s2.anchor[s2.active], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(active1, s2.active)
    np.testing.assert_array_equal(sl1, sl2)
    # per-copy parameters
    prm = a.per_copy(8)
    prm[:, PRM_FIELDS.index("friction")] = np.linspace(0.1, 1.0, 8)            # friction per copy
    W1, _, _, _ = oracle.contact_forces(a, m, q, qd, cs.anchor, cs.active, prm)
    W2, _, _ = contact_forces(a, m, q, qd, cs, prm=prm)
    np.testing.assert_allclose(W1, W2, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="backend: 'numpy' is no longer a backend"):
        GroundContact(backend="numpy")


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_contact_steps_agree_with_numpy_oracle(integrator):
    """pipeline.step with ground contact (the compiled contact loop) against the oracle's Python
    loop of NumPy contact forces and NumPy steps: 300 steps of a prism dropped on the ground with
    rest-length controls, friction and per-copy contact parameters."""
    from tensegrity_gym.physics.pipeline import step
    rng = np.random.default_rng(4)
    m = resting_prism(drop=0.01)
    B = 5
    st = initial_state(m, B)
    st = State(st.q + rng.normal(0, 0.005, st.q.shape), rng.normal(0, 0.2, st.q.shape), 0.0)
    g = GroundContact(friction=0.4)
    prm = g.per_copy(B)
    prm[:, PRM_FIELDS.index("stiffness")] *= rng.uniform(0.8, 1.2, B)           # stiffness per copy
    l0 = m.rest_length * rng.uniform(0.97, 1.02, (B, m.n_strings))
    cs = init_contact_state(m, B)
    s1, c1 = step(m, st, DT, integrator, n_steps=300, contact=g, cstate=cs, contact_params=prm,
                  rest_length=l0)
    s2, c2 = oracle.contact_step(m, g, st, cs, DT, integrator, n_steps=300, contact_params=prm, rest_length=l0)
    assert c1.active.any() and np.abs(s1.q - st.q).max() > 1e-3
    assert np.abs(s1.q - s2.q).max() < 1e-10 and np.abs(s1.qd - s2.qd).max() < 1e-8, \
        (np.abs(s1.q - s2.q).max(), np.abs(s1.qd - s2.qd).max())
    np.testing.assert_array_equal(c1.active, c2.active)


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="stiffness"):
        GroundContact(stiffness=-1.0)
    with pytest.raises(ValueError, match="friction"):
        GroundContact(friction=float("nan"))
    with pytest.raises(ValueError, match="exponent"):
        GroundContact(exponent=0.5)
    with pytest.raises(ValueError, match="backend"):
        GroundContact(backend="gpu")


def test_stable_step_estimate():
    m = resting_prism()
    est = stable_step(GroundContact(), m)
    assert est["omega_contact"] == pytest.approx(math.sqrt(1e4 / 0.05))
    assert 1e-3 < est["semi_implicit_euler"] < 5e-3


def test_fast_impact_stays_stable_with_capped_damping():
    """A rod falling flat onto the ground at 5 m/s: with the Hunt-Crossley damping coefficient
    capped at m_eff/dt (as TensegrityRoll-v0 does) the explicit step stays stable, nothing
    flies off and the rod comes to rest on its caps."""
    m = flat_rod(0.0)
    st = initial_state(m, 1)
    qd = st.qd.copy()
    qd[..., 2] = -5.0
    st = State(st.q + np.array([0, 0, 0.01, 0, 0, 0]), qd, 0.0)
    c = GroundContact(max_damping=0.2 / 4 / DT)
    cs = init_contact_state(m, 1)
    zmax, pen = 0.0, 0.0
    for _ in range(500):
        st, cs = contact_step(m, c, st, cs, DT)
        z = node_positions(m, st.q)[0, :, 2]
        zmax, pen = max(zmax, z.max()), max(pen, c.radius - z.min())
    assert np.all(np.isfinite(st.q))
    assert zmax < 0.5 and pen < 0.02
    assert np.abs(st.qd).max() < 1e-2 and cs.active.all()


@pytest.mark.parametrize("B, ext_rows", [(1, 1), (6, 6), (64, 64), (900, 1), (900, 900)])
def test_contact_steps_with_external_force_compiled_equal_python_loop(monkeypatch, B, ext_rows):
    """pipeline.step with ground contact and an external force (shared or per copy): the one
    compiled contact loop (serial for 1, 6 and 64 copies, the parallel chunks for 900) gives the bits
    of the Python loop (contact forces + external, then one integrator step, per sub-step)."""
    from tensegrity_gym.physics.pipeline import step
    from tensegrity_gym.backends.numba import api as numba_api
    from tensegrity_gym.physics import pipeline as physics_pipeline
    rng = np.random.default_rng(3)
    m = resting_prism(drop=0.01)
    st = initial_state(m, B)
    st = State(st.q + rng.normal(0, 0.005, st.q.shape), rng.normal(0, 0.2, st.q.shape), 0.0)
    cs = init_contact_state(m, B)
    ext = rng.normal(0, 2.0, (ext_rows, m.n_nodes, 3))
    g = GroundContact(friction=0.4)
    calls = []
    for name in ("_contact_loop", "_contact_loop_simd", "_contact_parallel"):
        monkeypatch.setattr(numba_api, name, lambda *a, _f=getattr(numba_api, name), _n=name: calls.append(_n) or _f(*a))
    s1, c1 = step(m, st, DT, n_steps=20, contact=g, cstate=cs, external=ext)
    assert calls == ["_contact_parallel" if B >= 900 else "_contact_loop_simd" if B >= 16 else "_contact_loop"]
    monkeypatch.setattr(physics_pipeline, "_contact_compiled", lambda *a: False)
    s2, c2 = step(m, st, DT, n_steps=20, contact=g, cstate=cs, external=ext)
    assert np.array_equal(s1.q, s2.q) and np.array_equal(s1.qd, s2.qd)
    assert np.array_equal(c1.anchor, c2.anchor) and np.array_equal(c1.active, c2.active)
    assert c1.active.any()            # the caps touch: contact forces were exercised
    s3, _ = step(m, st, DT, n_steps=20, contact=g, cstate=cs)
    assert not np.array_equal(s1.q, s3.q)   # the external force acted
