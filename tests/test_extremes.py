"""Stability at the extremes (fast versions of scripts/figures/stability_table.py).

Stiffness 1..1e7 N/m x rod mass 1e-3..1e2 kg (stable or warned), ballistic flight with all
strings slack (exact), a string through zero length (no NaN, no numpy warning), rest lengths
at their bounds, a long run (energy bounded, no growth of rod-length drift with projection),
the StabilityWarning (names the limit, computed once, cheap afterwards) and the
SimulationDiverged message (names time and cause)."""
import warnings

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym import Structure, StructureError
from tensegrity_gym.physics import evaluate, implicit
from tensegrity_gym.physics.stability import stability_limit, stable_step_estimate
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.physics.integrate import step
from tensegrity_gym.physics.geometry import (center_of_mass, energy, linear_momentum, node_positions, rod_length_drift,
                                             string_state)
from tensegrity_gym.physics.rollout import simulate
from tensegrity_gym.core.errors import SimulationDiverged, StabilityWarning
from tensegrity_gym.physics import stability

FIXED = ("semi_implicit_euler", "rk4", "implicit_euler")
RAISE = dict(divide="raise", over="raise", invalid="raise")   # underflow is harmless (scipy uses it)


def _kicked(model, scale, seed=0):
    st = initial_state(model)
    rng = np.random.default_rng(seed)
    q, qd = evaluate.project(model, st.q, scale * rng.normal(size=st.qd.shape))
    return State(q=q, qd=qd, t=0.0)


# ----------------------------------------------------------------------------- stiffness x mass
@pytest.mark.parametrize("integrator", FIXED)
def test_stiffness_mass_grid_stable_or_warned(integrator):
    n = 100
    for k in (1.0, 1e3, 1e5, 1e7):
        for mass in (1e-3, 1.0, 1e2):
            m = compile_model(tg.prism(stiffness=k, bar_mass=mass, prestress=0.01 * k))
            st = _kicked(m, 0.05)
            E0 = energy(m, st.q, st.qd)[0]
            with warnings.catch_warnings(record=True) as caught, np.errstate(all="ignore"):
                warnings.simplefilter("always")
                try:
                    _, q, qd = simulate(m, st, 1e-3, n, integrator, record_every=10)
                    E = energy(m, q.reshape(-1, 3, 6), qd.reshape(-1, 3, 6))
                    stable = bool(np.all(np.isfinite(E)) and E.max() < 1.5 * E0)
                except SimulationDiverged:
                    stable = False
            warned = any(issubclass(w.category, StabilityWarning) for w in caught)
            cell = f"{integrator} k={k:g} N/m, m={mass:g} kg"
            if integrator == "implicit_euler":
                assert stable and not warned, cell
                assert E.max() <= E0 * (1 + 1e-9), cell          # dissipative, never gains energy
            else:
                assert stable or warned, cell + ": unstable without a StabilityWarning"
            if k == 1e7 and mass == 1e-3 and integrator != "implicit_euler":
                assert warned, cell                              # omega dt ~ 365 at 1 ms


# ----------------------------------------------------------------------------- all strings slack
def _slack_prism():
    s = tg.prism(prestress=None)
    return s.replace(rest_length=1e3 * s.string_lengths)   # rest lengths far above any length


def _analytic(model, st, t):
    r0, b0 = st.q[0, :, :3], st.q[0, :, 3:]
    v0, bd0 = st.qd[0, :, :3], st.qd[0, :, 3:]
    w = np.linalg.norm(bd0, axis=1, keepdims=True)
    q = np.concatenate([r0 + v0 * t, b0 * np.cos(w * t) + bd0 / w * np.sin(w * t)], axis=1)[None]
    return node_positions(model, q)[0]


def test_all_strings_slack_is_exact_ballistic_flight():
    m = compile_model(_slack_prism())
    st = _kicked(m, 1.0, seed=4)
    T = 0.25
    exact = _analytic(m, st, T)
    err = {}
    for integ, dt in (("rk4", 1e-3), ("dop853", 1e-3), ("semi_implicit_euler", 1e-3), ("semi_implicit_euler", 5e-4),
                      ("implicit_euler", 1e-3), ("implicit_euler", 5e-4)):
        kw = dict(rtol=1e-12, atol=1e-12) if integ == "dop853" else {}
        with np.errstate(**RAISE):
            end = step(m, st, dt, integ, n_steps=int(round(T / dt)), **kw)
        err[integ, dt] = np.linalg.norm(node_positions(m, end.q)[0] - exact, axis=1).max()
        # the centre of mass flies uniformly, to round-off, for every method
        com = center_of_mass(m, end.q)[0] - center_of_mass(m, st.q)[0]
        np.testing.assert_allclose(com, T * st.qd[0, :, :3].mean(axis=0), atol=1e-13)
        np.testing.assert_allclose(linear_momentum(m, end.qd), linear_momentum(m, st.qd), atol=1e-13)
    assert err["rk4", 1e-3] < 1e-10 and err["dop853", 1e-3] < 1e-9
    # semi-implicit Euler with projection moves each b along its great circle at the (constant)
    # spin rate: exact for torque-free rods, to round-off, at any dt
    assert err["semi_implicit_euler", 1e-3] < 1e-12 and err["semi_implicit_euler", 5e-4] < 1e-12, err
    # implicit Euler is first order: halving dt halves the error
    assert err["implicit_euler", 1e-3] < 5e-3
    assert 1.8 < err["implicit_euler", 1e-3] / err["implicit_euler", 5e-4] < 2.2, err


def test_ballistic_flight_under_gravity():
    m = compile_model(_slack_prism().replace(gravity=(0.0, 0.0, -9.81)))
    st = _kicked(m, 1.0, seed=5)
    T = 0.5
    exact = _analytic(m, st, T) + 0.5 * np.array([0, 0, -9.81]) * T ** 2
    end = step(m, st, 1e-3, "rk4", n_steps=500)
    assert np.linalg.norm(node_positions(m, end.q)[0] - exact, axis=1).max() < 1e-10


# ----------------------------------------------------------------------------- zero length
def _crossing(l0):
    nodes = [[-0.05, 0, 0], [-0.05, 0, 1], [0.05, 0, 0], [0.05, 0, -1]]
    return Structure(nodes, [[0, 1], [2, 3]], [[0, 2]], stiffness=100.0, rest_length=[l0])


def _at_zero(m, vx=0.3):
    """Both rods moved so that string 0 (nodes 0 and 2) has length exactly 0, moving apart."""
    nodes = m.structure.nodes.copy()
    nodes[:, 0] = 0.0
    vel = np.zeros_like(nodes)
    vel[[0, 1], 0], vel[[2, 3], 0] = -vx, vx
    return initial_state(m, nodes=nodes, velocities=vel)


@pytest.mark.parametrize("l0", [0.0, 0.05])
def test_string_of_zero_length_everything_finite(l0):
    m = compile_model(_crossing(l0))
    st = _at_zero(m)
    _, L, _ = string_state(m, st.q, st.qd)
    assert L[0, 0] == 0.0
    with warnings.catch_warnings(), np.errstate(**RAISE):
        warnings.simplefilter("error")
        S, L, Ld = string_state(m, st.q, st.qd)
        gamma, _, _ = evaluate.force_densities(m, st.q, st.qd)
        a = tg.physics.accelerations(m, st.q, st.qd)
        E = energy(m, st.q, st.qd)
        a0, K, D = implicit.jacobians(m, st.q, st.qd)
        est = stable_step_estimate(m, st)
        md = compile_model(_crossing(l0).replace(damping=3.0))   # damped: d|s|/dt at |s| = 0
        ad = tg.physics.accelerations(md, st.q, st.qd)
    for x in (S, L, Ld, gamma, a, E, a0, K, D, ad):
        assert np.all(np.isfinite(x))
    assert np.isfinite(est["omega_max"])
    np.testing.assert_array_equal(gamma, 0.0)      # zero length carries no force (never NaN)
    np.testing.assert_array_equal(a, 0.0)


@pytest.mark.parametrize("integrator", FIXED + ("dop853",))
@pytest.mark.parametrize("l0", [0.0, 0.05])
def test_string_through_zero_length_trajectory(integrator, l0):
    """Start at length 0 moving apart; with l0 = 0 (rest length at its lower bound: a
    zero-length spring, always taut) the string pulls the nodes back through 0 repeatedly."""
    m = compile_model(_crossing(l0))
    st = _at_zero(m)
    E0 = energy(m, st.q, st.qd)[0]
    with warnings.catch_warnings(), np.errstate(**RAISE):
        warnings.simplefilter("error")
        _, q, qd = simulate(m, st, 1e-3, 800, integrator)
    q, qd = q.reshape(-1, 2, 6), qd.reshape(-1, 2, 6)
    S, L, _ = string_state(m, q)
    E = energy(m, q, qd)
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(E))
    if l0 == 0.0:
        x = S[:, 0, 0]                                   # the nodes cross: x-separation changes sign
        assert np.sum(np.diff(np.sign(x[1:])) != 0) >= 2
    tol = {"rk4": 1e-6, "dop853": 1e-6, "semi_implicit_euler": 2e-2, "implicit_euler": 0.5}[integrator]
    if l0 > 0 and integrator == "rk4":
        tol = 1e-4            # the slack -> taut switch is a kink in the force: RK4 drops to low order there
    assert np.max(np.abs(E - E0)) / E0 < tol
    if integrator == "implicit_euler":
        assert E.max() <= E0 * (1 + 1e-9)


# ----------------------------------------------------------------------------- rest-length bounds
def test_rest_length_bounds():
    s = tg.prism(prestress=None)
    with pytest.raises(StructureError, match="rest_length of string 2"):
        s.replace(rest_length=np.where(np.arange(s.n_strings) == 2, -0.1, s.string_lengths))
    # rest length 0 (lower bound): every string a zero-length spring; energy kept by RK4
    m = compile_model(s.replace(rest_length=np.zeros(s.n_strings)))
    st = _kicked(m, 0.1, seed=6)
    E0 = energy(m, st.q, st.qd)[0]
    with np.errstate(**RAISE):
        _, q, qd = simulate(m, st, 1e-3, 300, "rk4", record_every=30)
    E = energy(m, q.reshape(-1, 3, 6), qd.reshape(-1, 3, 6))
    assert np.max(np.abs(E - E0)) / E0 < 1e-5        # the prism collapses at ~30 m/s: RK4 at 1 ms
    # very large rest lengths: no force at all (exactly zero accelerations at rest)
    big = compile_model(s.replace(rest_length=np.full(s.n_strings, 1e9)))
    st = initial_state(big)
    np.testing.assert_array_equal(tg.physics.accelerations(big, st.q, st.qd), 0.0)
    assert energy(big, st.q, st.qd)[0] == 0.0


# ----------------------------------------------------------------------------- long run
def _long(n, project, chunks=4):
    m = compile_model(tg.prism())
    st = _kicked(m, 0.3)
    E0 = energy(m, st.q, st.qd)[0]
    per = n // chunks
    dE, drift = [], []
    for _ in range(chunks):
        _, q, qd = simulate(m, st, 1e-3, per, "semi_implicit_euler", record_every=per // 100, project=project)
        q2, qd2 = q.reshape(-1, 3, 6), qd.reshape(-1, 3, 6)
        dE.append(np.max(np.abs(energy(m, q2, qd2) - E0)) / E0)
        drift.append(np.max(rod_length_drift(m, q2)))
        st = State(q[-1], qd[-1], st.t + per * 1e-3)
    return np.array(dE), np.array(drift)


def test_long_run_energy_bounded_and_drift_not_growing():
    dE, drift = _long(20_000, project=True)
    assert dE.max() < 2e-3                            # small: no blow-up over 2e4 steps
    assert dE[-1] < 1.5 * dE[0] + 1e-4                # slow drift only (see docs/stability.md, section 5)
    assert drift.max() < 1e-14                        # projection: round-off only, not growing
    dE_np, drift_np = _long(20_000, project=False)
    assert drift_np[-1] > 2 * drift_np[0] > 0         # without projection the rod length drifts


# ----------------------------------------------------------------------------- warning, divergence
def test_stability_warning_names_limit_once_and_is_cached(monkeypatch):
    m = compile_model(tg.prism(stiffness=1e6, bar_mass=0.1))
    st = initial_state(m)
    calls = []
    real = stable_step_estimate
    monkeypatch.setattr(stability, "stable_step_estimate", lambda *a, **k: calls.append(1) or real(*a, **k))
    with warnings.catch_warnings(record=True) as caught, np.errstate(all="ignore"):
        warnings.simplefilter("always")
        for _ in range(5):
            step(m, st, 1e-3, "semi_implicit_euler")
        step(m, st, 1e-3, "rk4")
        step(m, st, 1e-5, "semi_implicit_euler")     # below the limit
        step(m, st, 1e-3, "implicit_euler")                          # never warns
    msgs = [str(w.message) for w in caught if issubclass(w.category, StabilityWarning)]
    lim = stability_limit(m)
    assert len(msgs) == 2, msgs                        # once per (model, integrator, dt)
    assert f"{lim['semi_implicit_euler']:.4g} s" in msgs[0] and "semi_implicit_euler" in msgs[0]
    assert f"{lim['rk4']:.4g} s" in msgs[1] and "rk4" in msgs[1]
    assert len(calls) == 1                             # the estimate is computed once per model
    assert not issubclass(StabilityWarning, RuntimeWarning)   # not hidden by numpy-warning filters


@pytest.mark.parametrize("backend", ["numba", "auto"])
def test_divergence_names_time_and_cause(backend):
    m = compile_model(tg.prism(stiffness=1e6, bar_mass=0.1))
    st = _kicked(m, 0.1, seed=7)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        with pytest.raises(SimulationDiverged) as e:
            simulate(m, st, 1e-3, 2000, "semi_implicit_euler", record_every=10, backend=backend)
    msg = str(e.value)
    assert "between t = " in msg and "dt = 0.001 s" in msg
    assert "above the estimated stability limit" in msg and "implicit_euler" in msg


def test_warning_accounts_for_string_damping():
    """Damped strings lower the explicit limits (prism, 50 N s/m: ~6x): the warning must know."""
    m = compile_model(tg.prism(damping=50.0))
    undamped = stable_step_estimate(m, damping=False)
    lim = stability_limit(m)
    st = _kicked(m, 0.01)
    E0 = energy(m, st.q, st.qd)[0]
    for name in ("semi_implicit_euler", "rk4"):
        assert lim[name] < 0.5 * undamped[name]
        with warnings.catch_warnings(record=True) as caught, np.errstate(all="ignore"):
            warnings.simplefilter("always")
            try:   # half the undamped estimate: diverges, and is warned about
                _, q, qd = simulate(m, st, 0.5 * undamped[name], 400, name, record_every=40)
                E = energy(m, q.reshape(-1, 3, 6), qd.reshape(-1, 3, 6))
                unstable = not np.all(np.isfinite(E)) or E.max() > 1.5 * E0
            except SimulationDiverged:
                unstable = True
        assert unstable and any(issubclass(w.category, StabilityWarning) for w in caught), name
        _, q, qd = simulate(m, st, 0.9 * lim[name], 400, name, record_every=40)
        E = energy(m, q.reshape(-1, 3, 6), qd.reshape(-1, 3, 6))
        assert np.all(np.isfinite(E)) and E.max() <= E0 * (1 + 1e-9), name   # damped: energy only falls
