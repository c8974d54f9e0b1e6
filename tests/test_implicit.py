"""Tests of the stiff-capable integrator ``implicit_euler`` (tensegrity_gym/physics/implicit.py)."""
import warnings

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym import Structure
from tensegrity_gym.physics import implicit
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.physics.evaluate import project
from tensegrity_gym.core.integrators import INTEGRATORS
from tensegrity_gym.physics.integrate import step
from tensegrity_gym.physics.geometry import constraint_violation, energy, linear_momentum, node_positions
from tensegrity_gym.physics.stability import stability_limit
from tensegrity_gym.physics.rollout import simulate
from tensegrity_gym.core.errors import SimulationDiverged, StabilityWarning


def _kicked(model, scale, seed=0, B=1):
    st = initial_state(model, batch_size=B)
    rng = np.random.default_rng(seed)
    q, qd = project(model, st.q, scale * rng.normal(size=st.qd.shape))
    return State(q=q, qd=qd, t=0.0)


def _oscillator(k=400.0, m=1.0):
    """A rod between two zero-rest-length springs to anchors on its axis: its sideways
    translation x is a linear oscillator with omega^2 = 2 k / m (the rod does not rotate)."""
    nodes = [[0, 0, -0.5], [0, 0, 0.5], [0, 0, -1.5], [0, 0, 1.5]]
    return Structure(nodes, [[0, 1]], [[0, 2], [1, 3]], bar_mass=m, stiffness=k, rest_length=[0.0, 0.0])


def test_registered_and_dispatched():
    assert "implicit_euler" in INTEGRATORS
    info = INTEGRATORS["implicit_euler"]
    assert info.order == 1 and not info.adaptive
    m = compile_model(tg.prism())
    st = _kicked(m, 0.1)
    # backend "auto" must not send the implicit method to the compiled explicit kernels
    a = step(m, st, 1e-3, "implicit_euler", n_steps=3)
    b = implicit.step(m, st, 1e-3, n_steps=3)
    np.testing.assert_array_equal(a.q, b.q)
    assert a.t == pytest.approx(3e-3)


def test_jacobian_of_linear_oscillator():
    k, mass = 400.0, 2.0
    m = compile_model(_oscillator(k, mass))
    st = initial_state(m)
    a, K, D = implicit.jacobians(m, st.q, st.qd)
    # row/column 0 is r_x: d(r_x'')/d(r_x) = -2 k / m
    assert K[0, 0, 0] == pytest.approx(-2 * k / mass, rel=1e-6)
    np.testing.assert_allclose(D, 0.0, atol=1e-6)   # no damping, no rotation: no velocity dependence
    np.testing.assert_allclose(a, 0.0, atol=1e-9)


def test_energy_decay_matches_backward_euler_theory():
    """Backward Euler multiplies a linear mode's energy by 1/(1 + (omega dt)^2) per step."""
    k, mass, dt, n = 400.0, 1.0, 2e-3, 50
    m = compile_model(_oscillator(k, mass))
    nodes = m.structure.nodes.copy()
    nodes[:2, 0] += 0.01                              # sideways offset of the rod
    st = initial_state(m, nodes=nodes)
    E_eq = energy(m, initial_state(m).q, initial_state(m).qd)[0]
    E0 = energy(m, st.q, st.qd)[0] - E_eq
    implicit.STATS.update(steps=0, newton_iterations=0)
    end = step(m, st, dt, "implicit_euler", n_steps=n)
    E = energy(m, end.q, end.qd)[0] - E_eq
    omega = np.sqrt(2 * k / mass)
    assert E / E0 == pytest.approx((1 + (omega * dt) ** 2) ** -n, rel=1e-5)
    assert implicit.STATS["newton_iterations"] == 0     # linear: the first Newton iterate is exact


def test_first_order_convergence():
    s = tg.prism(stiffness=100.0, prestress=5.0)
    m = compile_model(s)
    st = _kicked(m, 0.2, seed=1)
    T = 0.2
    ref = node_positions(m, step(m, st, T, "dop853", rtol=1e-12, atol=1e-12).q)
    errs = []
    for dt in (4e-4, 2e-4, 1e-4):
        end = step(m, st, dt, "implicit_euler", n_steps=int(round(T / dt)))
        errs.append(np.abs(node_positions(m, end.q) - ref).max())
    r1, r2 = errs[0] / errs[1], errs[1] / errs[2]
    assert 1.7 < r1 < 2.3 and 1.7 < r2 < 2.3, errs


@pytest.mark.parametrize("k", [1e5, 1e6])
def test_stable_at_1ms_with_stiff_cables_where_explicit_diverges(k):
    m = compile_model(tg.prism(stiffness=k, bar_mass=0.1))
    st = _kicked(m, 0.1, seed=2)
    lim = stability_limit(m)
    assert lim["semi_implicit_euler"] < 1e-3 and lim["rk4"] < 1e-3   # the explicit ones cannot take 1 ms
    E0 = energy(m, st.q, st.qd)[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")                     # no StabilityWarning, no numpy warning
        t, q, qd = simulate(m, st, 1e-3, 300, "implicit_euler", record_every=30)
    E = energy(m, q[:, 0], qd[:, 0])
    assert np.all(np.isfinite(q))
    assert np.all(np.diff(E) <= 1e-9 * E0)               # backward Euler only loses energy here
    assert np.abs(node_positions(m, q[-1]) - node_positions(m, st.q)).max() < 0.05
    for integ in ("semi_implicit_euler", "rk4"):
        # warned, then either non-finite (SimulationDiverged) or energy blown up by orders of
        # magnitude (tension-only strings can saturate the instability: rods fly apart)
        with pytest.warns(StabilityWarning, match="stability limit"):
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                try:
                    _, q, qd = simulate(m, st, 1e-3, 300, integ, record_every=10)
                    blown_up = energy(m, q[-1], qd[-1])[0] > 100 * E0
                except SimulationDiverged:
                    blown_up = True
        assert blown_up, integ


def test_newton_handles_slack_taut_switching():
    """1e7 N/m strings on 1 g rods kicked at 1 m/s: strings snap slack/taut every step. The
    Newton iterations keep the energy from growing (the linearly implicit step does not)."""
    m = compile_model(tg.prism(stiffness=1e7, bar_mass=1e-3))
    st = _kicked(m, 1.0, seed=1)
    E0 = energy(m, st.q, st.qd)[0]
    implicit.STATS.update(steps=0, newton_iterations=0)
    s = st
    Es = []
    for _ in range(10):
        s = step(m, s, 1e-3, "implicit_euler")
        Es.append(energy(m, s.q, s.qd)[0])
    assert implicit.STATS["newton_iterations"] > 0
    assert max(Es) <= E0 * (1 + 1e-6)
    lin = implicit.step(m, st, 1e-3, max_newton=0, n_steps=10)
    assert energy(m, lin.q, lin.qd)[0] > 10 * E0        # why the Newton iterations are there


def test_batch_equals_single_runs():
    m = compile_model(tg.prism(damping=2.0))
    st = _kicked(m, 0.2, seed=3, B=3)
    rng = np.random.default_rng(0)
    l0 = m.rest_length * (1 + 0.05 * rng.uniform(-1, 1, size=(3, m.n_strings)))
    fd = rng.uniform(0, 5, size=(3, m.n_strings))
    batch = step(m, st, 2e-3, "implicit_euler", rest_length=l0, force_density=fd, n_steps=5)
    for i in range(3):
        one = step(m, State(st.q[i:i + 1], st.qd[i:i + 1], 0.0), 2e-3, "implicit_euler",
                   rest_length=l0[i], force_density=fd[i], n_steps=5)
        np.testing.assert_allclose(batch.q[i], one.q[0], atol=1e-12)
        np.testing.assert_allclose(batch.qd[i], one.qd[0], atol=1e-10)


def test_constrained_damped_gravity_prism():
    m = compile_model(tg.constrained_prism(damping=5.0))
    st = _kicked(m, 0.2, seed=4)
    T, dt = 0.2, 2.5e-4
    ref = step(m, st, T, "dop853", rtol=1e-11, atol=1e-11)
    end = step(m, st, dt, "implicit_euler", n_steps=int(round(T / dt)))
    assert constraint_violation(m, end.q, end.qd)[0] < 1e-12
    err = np.abs(node_positions(m, end.q) - node_positions(m, ref.q)).max()
    assert err < 5e-3
    # damping: energy decreases faster than without it
    E0 = energy(m, st.q, st.qd)[0]
    assert energy(m, end.q, end.qd)[0] < E0


def test_constant_external_force_moves_momentum_exactly():
    m = compile_model(tg.prism())
    st = _kicked(m, 0.1, seed=5)
    F = np.zeros((1, m.n_nodes, 3))
    F[0, :, 0] = 2.0                                   # 2 N on every node along x
    p0 = linear_momentum(m, st.qd)[0]
    T, dt = 0.05, 1e-3
    end = step(m, st, dt, "implicit_euler", external=F, n_steps=50)
    p = linear_momentum(m, end.qd)[0]
    np.testing.assert_allclose(p - p0, [2.0 * m.n_nodes * T, 0, 0], atol=1e-10)
    # a callable external is evaluated at the start of each step: same result for a constant force
    end2 = step(m, st, dt, "implicit_euler", external=lambda q, qd, t: F, n_steps=50)
    np.testing.assert_allclose(end2.q, end.q, atol=1e-14)


def test_bad_method_name():
    m = compile_model(tg.prism())
    with pytest.raises(ValueError, match="implicit method"):
        implicit.step(m, initial_state(m), 1e-3, "implicit_trapezoid")
