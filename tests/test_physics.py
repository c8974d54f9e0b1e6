"""Physics validation of the configuration-matrix dynamics (NumPy backend).

Checks against an independent node-coordinate formulation (tests/reference.py:
consistent rod mass matrices, rod lengths and node constraints held by Lagrange
multipliers, DOP853 at 1e-12) and against known physics: energy, momenta,
constraint drift, convergence order, prestressed equilibria, stability limit.
All quantities in SI units.
"""
from __future__ import annotations

import functools
import warnings

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.physics.geometry import (angular_momentum, center_of_mass, configuration_matrix,
                                             constraint_violation, energy, linear_momentum, node_positions,
                                             node_velocities, rod_length_drift)
from tensegrity_gym.physics.evaluate import nodal_forces
from tensegrity_gym.physics.stability import stable_step_estimate
from tensegrity_gym.physics.rollout import simulate
from tensegrity_gym.physics.integrate import step
from tensegrity_gym.core.errors import SimulationDiverged
from tensegrity_gym.core.structure import StructureError

import oracle_numpy as oracle
from reference import NodeReference, rigid_perturbation

GRAVITY = (0.0, 0.0, -9.81)


# ---------------------------------------------------------------------- helpers
def lumped_prism():
    """3-prism whose rods carry lumped masses off the midpoint (f != 0 about the midpoint)."""
    return tg.prism(3, prestress=100.0).replace(
        mass_points=[((0.0, 0.3), (0.4, 0.5), (1.0, 0.2)), None, ((0.1, 0.6), (0.9, 0.1))],
        name="lumped_prism")


def lumped_pinned_rod():
    """Pinned rod (constrained, f != 0) with lumped masses."""
    return tg.pinned_rod().replace(mass_points=[((0.2, 0.3), (0.7, 0.5), (1.0, 0.4))],
                                   name="lumped_pinned_rod")


def hanging_rod():
    """A free rod hanging from four fixed anchors by damped strings, under gravity."""
    nodes = [[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [-0.7, 0.3, 1.0], [-0.7, -0.3, 1.0], [0.7, 0.3, 1.0],
             [0.7, -0.2, 1.1]]
    strings = [[0, 2], [0, 3], [1, 4], [5, 1]]
    L = np.linalg.norm(np.subtract([nodes[b] for _, b in strings], [nodes[a] for a, _ in strings]), axis=1)
    return tg.Structure(nodes, [[0, 1]], strings, bar_mass=2.0, stiffness=[800, 900, 1000, 1100],
                        rest_length=0.9 * L, damping=1.0, gravity=GRAVITY, name="hanging_rod")


def reversed_lumped_pinned_rod():
    """Pinned rod whose pinned node is the rod's node c (reference point at sigma = 1)."""
    return tg.pinned_rod().replace(bars=[[1, 0]], mass_points=[((0.0, 0.4), (0.5, 0.3), (0.8, 0.5))],
                                   name="reversed_lumped_pinned_rod")


def reversed_constrained_prism():
    """constrained_prism with every rod reversed (constrained nodes are nodes c), one rod with
    lumped masses, damped strings."""
    s = tg.constrained_prism(damping=1.0)
    return s.replace(bars=s.bars[:, ::-1], mass_points=[None, ((0.0, 0.7), (1.0, 0.4)), None],
                     name="reversed_constrained_prism")


# name -> (structure factory, perturbation seed, perturbation kwargs, horizon T in s, tolerance m)
CASES = {
    "free_prism_slack": (lambda: tg.prism(3, prestress=30.0), 1,
                         dict(pos=0.03, rot=0.05, vel=0.3, omega=1.0), 0.3, 1e-8),
    "damped_prism_gravity": (lambda: tg.prism(3, damping=5.0, gravity=GRAVITY), 0,
                             dict(vel=0.3), 1.0, 1e-9),
    "pinned_rod": (tg.pinned_rod, 0, dict(vel=0.0, omega=3.0), 1.0, 1e-9),
    "constrained_prism": (tg.constrained_prism, 0, dict(pos=0.02, rot=0.05, vel=0.2, omega=1.0), 1.0, 1e-9),
    "lumped_prism": (lumped_prism, 0, dict(), 1.0, 1e-9),
    "lumped_pinned_rod": (lumped_pinned_rod, 2, dict(vel=0.0, omega=3.0), 1.0, 1e-9),
    "icosahedron": (tg.icosahedron, 0, dict(), 1.0, 1e-9),
    "hanging_rod": (hanging_rod, 0, dict(vel=0.3, omega=2.0), 0.5, 1e-9),
    "reversed_lumped_pinned_rod": (reversed_lumped_pinned_rod, 1, dict(vel=0.0, omega=3.0), 1.0, 1e-9),
    "reversed_constrained_prism": (reversed_constrained_prism, 0, dict(pos=0.02, rot=0.05, vel=0.2, omega=1.0),
                                   0.5, 1e-9),
}
N_REC = 51


def twist_angles(nodes, p):
    """(p,) angle (rad) from bottom node i to top node i about the prism's axis, measured
    from node positions in the prism's own frame (independent of rigid motion)."""
    bot, top = nodes[:p], nodes[p:2 * p]
    cb, ct = bot.mean(0), top.mean(0)
    e = (ct - cb) / np.linalg.norm(ct - cb)
    out = []
    for i in range(p):
        u = bot[i] - cb
        u = u - e * (u @ e)
        v = top[i] - ct
        v = v - e * (v @ e)
        out.append(np.arctan2(np.cross(u, v) @ e, u @ v))
    return np.array(out)


@functools.lru_cache(maxsize=None)
def case_data(name):
    """Initial condition, independent reference trajectory and dop853 trajectory of a case."""
    factory, seed, kw, T, tol = CASES[name]
    s = factory()
    nodes0, vel0 = rigid_perturbation(s, np.random.default_rng(seed), **kw)
    t = np.linspace(0.0, T, N_REC)
    ref = NodeReference(s)
    X_ref, V_ref = ref.simulate(nodes0, vel0, t)
    model = compile_model(s)
    st = initial_state(model, nodes=nodes0, velocities=vel0)
    ts, q, qd = simulate(model, st, T / (N_REC - 1), N_REC - 1, "dop853", rtol=1e-12, atol=1e-12)
    X = np.stack([node_positions(model, qq)[0] for qq in q])
    V = np.stack([node_velocities(model, qq)[0] for qq in qd])
    return dict(s=s, ref=ref, model=model, state=st, nodes0=nodes0, vel0=vel0, t=ts, q=q, qd=qd,
                X=X, V=V, X_ref=X_ref, V_ref=V_ref, tol=tol)


def slack_counts(s, X):
    S = X[:, s.strings[:, 1]] - X[:, s.strings[:, 0]]
    return (np.linalg.norm(S, axis=-1) <= s.rest_length).sum(axis=1)


def energies(model, q, qd):
    return np.array([energy(model, a, b)[0] for a, b in zip(q, qd)])


def smooth_case(damping=0.0, seed=3):
    """A prestressed prism slightly off equilibrium: every string stays taut (smooth RHS)."""
    s = tg.prism(3, damping=damping)
    nodes0, vel0 = rigid_perturbation(s, np.random.default_rng(seed), pos=0.01, rot=0.02, vel=0.1, omega=0.5)
    model = compile_model(s)
    return s, model, initial_state(model, nodes=nodes0, velocities=vel0)


# ---------------------------------------------------------------------- agreement with the reference
def test_reference_consistency():
    """The reference itself: its mass matrix integrates a uniform rod exactly, and the
    perturbed initial conditions respect rod lengths and constraints."""
    from reference import rod_mass_matrix
    mu = (np.arange(20000) + 0.5) / 20000      # midpoint rule for a uniform rod of 2 kg
    Mc, gw = rod_mass_matrix(2.0, [(x, 2.0 / mu.size) for x in mu])
    Mu, gu = rod_mass_matrix(2.0)
    np.testing.assert_allclose(Mc, Mu, rtol=1e-8)
    np.testing.assert_allclose(gw, gu, rtol=1e-12)
    s = tg.constrained_prism()
    nodes, vel = rigid_perturbation(s, np.random.default_rng(0), pos=0.05, rot=0.2, vel=1.0, omega=2.0)
    d = nodes[s.bars[:, 1]] - nodes[s.bars[:, 0]]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), s.bar_lengths, rtol=1e-13)
    np.testing.assert_allclose(np.einsum("ki,ki->k", d, vel[s.bars[:, 1]] - vel[s.bars[:, 0]]), 0, atol=1e-13)
    for node, D in s.node_constraints.items():
        np.testing.assert_allclose(D @ nodes[node], D @ s.nodes[node], atol=1e-14)
        np.testing.assert_allclose(D @ vel[node], 0, atol=1e-14)
    # the reference holds its constraints along its own trajectory
    data = case_data("constrained_prism")
    X = data["X_ref"]
    dref = X[:, s.bars[:, 1]] - X[:, s.bars[:, 0]]
    assert np.abs(np.linalg.norm(dref, axis=-1) - s.bar_lengths).max() < 1e-10
    for node, D in s.node_constraints.items():
        assert np.abs(X[:, node] @ D.T - D @ s.nodes[node]).max() < 1e-10


@pytest.mark.parametrize("name", list(CASES))
def test_trajectory_agrees_with_node_reference(name):
    """Node positions (and velocities) of the configuration-matrix dynamics follow the
    independent node-coordinate DAE over the whole horizon."""
    d = case_data(name)
    err_x = np.abs(d["X"] - d["X_ref"]).max()
    err_v = np.abs(d["V"] - d["V_ref"]).max()
    motion = np.abs(d["X_ref"] - d["X_ref"][0]).max()
    assert motion > 0.04, f"{name}: the test scene barely moves ({motion:.3g} m), it would prove little"
    assert err_x < d["tol"], f"{name}: node positions differ by {err_x:.3g} m from the reference"
    assert err_v < 100 * d["tol"], f"{name}: node velocities differ by {err_v:.3g} m/s from the reference"


def test_slack_case_really_goes_slack():
    d = case_data("free_prism_slack")
    n_slack = slack_counts(d["s"], d["X_ref"])
    # strings go slack and taut again during the run
    assert n_slack.max() >= 2 and n_slack.min() == 0, f"slack strings over time: {n_slack}"


STRUCTURES_FOR_ACC = {
    "prism3_damped_gravity": lambda: tg.prism(3, damping=3.0, gravity=GRAVITY),
    "prism6_low_prestress": lambda: tg.prism(6, prestress=5.0, damping=1.0),
    "pinned_rod": tg.pinned_rod,
    "constrained_prism_damped": lambda: tg.constrained_prism(damping=2.0),
    "lumped_prism_gravity": lambda: lumped_prism().replace(gravity=GRAVITY, damping=1.0),
    "lumped_pinned_rod": lumped_pinned_rod,
    "icosahedron_gravity": lambda: tg.icosahedron(gravity=GRAVITY),
    "tower3": lambda: tg.tower(3, gravity=GRAVITY, damping=0.5),
    "hanging_rod": hanging_rod,
    "reversed_lumped_pinned_rod": reversed_lumped_pinned_rod,
    "reversed_constrained_prism": reversed_constrained_prism,
}


@pytest.mark.parametrize("name", list(STRUCTURES_FOR_ACC))
def test_node_accelerations_agree_with_reference(name):
    """At random states (large perturbations: many strings slack) the node accelerations
    r'' + eta b'' equal the reference's KKT accelerations."""
    s = STRUCTURES_FOR_ACC[name]()
    model = compile_model(s)
    ref = NodeReference(s)
    rng = np.random.default_rng(11)
    n_slack = 0
    for _ in range(4):
        nodes, vel = rigid_perturbation(s, rng, pos=0.05, rot=0.2, vel=1.0, omega=3.0)
        st = initial_state(model, nodes=nodes, velocities=vel)
        a = tg.physics.accelerations(model, st.q, st.qd)
        acc = node_velocities(model, a)[0]          # linear map: node accelerations
        acc_ref = ref.node_accelerations(nodes, vel)
        scale = np.abs(acc_ref).max()
        assert np.abs(acc - acc_ref).max() < 1e-10 * scale + 1e-12, \
            f"{name}: node accelerations differ by {np.abs(acc - acc_ref).max():.3g} m/s^2 (scale {scale:.3g})"
        n_slack += int(slack_counts(s, nodes[None])[0])
    if "low_prestress" in name:
        assert n_slack > 0


@pytest.mark.parametrize("name", ["prism6_low_prestress", "constrained_prism_damped", "hanging_rod"])
def test_controls_and_batch_agree_with_reference(name):
    """Rest lengths, controller force densities (which enter linearly, clipped so that no
    string pushes) and external nodal forces, for a batch of B different states at once."""
    s = STRUCTURES_FOR_ACC[name]()
    model = compile_model(s)
    rng = np.random.default_rng(7)
    B, m, n = 3, s.n_strings, s.n_nodes
    states = [rigid_perturbation(s, rng, pos=0.03, rot=0.1, vel=0.5, omega=2.0) for _ in range(B)]
    nodes = np.stack([x for x, _ in states])
    vels = np.stack([v for _, v in states])
    st = initial_state(model, nodes=nodes, velocities=vels)
    rest = s.rest_length * rng.uniform(0.9, 1.05, (B, m))
    u = rng.uniform(-20.0, 20.0, (B, m))
    ext = rng.normal(0.0, 5.0, (B, n, 3))
    acc = node_velocities(model, tg.physics.accelerations(model, st.q, st.qd, rest_length=rest,
                                                    force_density=u, external=ext))
    for i in range(B):
        ref = NodeReference(s, rest_length=rest[i], force_density=u[i], external=ext[i])
        acc_ref = ref.node_accelerations(nodes[i], vels[i])
        scale = np.abs(acc_ref).max()
        assert np.abs(acc[i] - acc_ref).max() < 1e-10 * scale, (name, i, np.abs(acc[i] - acc_ref).max())
    # force densities enter linearly where no clipping happens (all taut, u > 0 small)
    F0, g0 = nodal_forces(model, st.q, st.qd, rest_length=0.5 * s.rest_length)
    du = np.abs(rng.normal(0.0, 1.0, m))
    F1, g1 = nodal_forces(model, st.q, st.qd, rest_length=0.5 * s.rest_length, force_density=du)
    F2, g2 = nodal_forces(model, st.q, st.qd, rest_length=0.5 * s.rest_length, force_density=2 * du)
    np.testing.assert_allclose(g1 - g0, np.broadcast_to(du, g0.shape), atol=1e-9)
    np.testing.assert_allclose(F2 - F0, 2 * (F1 - F0), atol=1e-9)


# ---------------------------------------------------------------------- energy
def test_energy_matches_node_formula():
    """physics.geometry.energy equals kinetic (consistent mass) + string + gravity energy in node form."""
    for name in ("damped_prism_gravity", "lumped_prism", "constrained_prism"):
        d = case_data(name)
        for i in (0, N_REC // 2, N_REC - 1):
            e_gym = energy(d["model"], d["q"][i], d["qd"][i])[0]
            e_ref = d["ref"].energy(d["X"][i], d["V"][i])
            assert abs(e_gym - e_ref) < 1e-11 * max(1.0, abs(e_ref)), (name, e_gym, e_ref)


def test_energy_conserved_with_slack_strings_dop853():
    d = case_data("free_prism_slack")
    E = energies(d["model"], d["q"], d["qd"])
    drift = np.abs(E - E[0]).max() / abs(E[0])
    assert slack_counts(d["s"], d["X"]).max() >= 2
    assert drift < 1e-9, f"dop853: relative energy drift {drift:.3g} with slack strings"


def test_energy_conserved_rk4_and_symplectic_euler():
    # smooth case, RK4, small dt: essentially exact
    s, model, st = smooth_case()
    ts, q, qd = simulate(model, st, 2e-4, 1000, "rk4", record_every=50)
    E = energies(model, q, qd)
    drift_smooth = np.abs(E - E[0]).max() / abs(E[0])
    assert drift_smooth < 1e-10, f"rk4 dt=2e-4: relative energy drift {drift_smooth:.3g}"
    # slack strings: the string force has a kink at each slack transition, where RK4 loses
    # order (observed ~2.7), but the energy error stays small
    d = case_data("free_prism_slack")
    ts, q, qd = simulate(d["model"], d["state"], 2e-4, 1500, "rk4", record_every=30)
    E = energies(d["model"], q, qd)
    drift = np.abs(E - E[0]).max() / abs(E[0])
    assert slack_counts(d["s"], np.stack([node_positions(d["model"], a)[0] for a in q])).max() >= 2
    assert drift < 1e-5, f"rk4 dt=2e-4 with slack strings: relative energy drift {drift:.3g}"
    # symplectic Euler: bounded oscillating energy error, no secular growth
    ts, q, qd = simulate(d["model"], d["state"], 2e-4, 3000, "semi_implicit_euler", record_every=25)
    E = energies(d["model"], q, qd)
    err = np.abs(E - E[0]) / abs(E[0])
    half = err.size // 2
    assert err.max() < 1e-2, f"semi-implicit Euler energy error {err.max():.3g}"
    assert err[half:].max() < 3 * err[:half].max(), "semi-implicit Euler energy error grows"


def test_energy_only_decreases_with_damping():
    d = case_data("damped_prism_gravity")
    E = energies(d["model"], d["q"], d["qd"])
    dE = np.diff(E)
    assert dE.max() < 1e-10 * np.abs(E).max(), f"energy increased by {dE.max():.3g} J with damping"
    assert E[-1] < E[0] - 1e-3, "damping dissipated nothing"
    # strong damping with slack strings (the clipped damper), sampled every step
    s = tg.prism(3, prestress=30.0, damping=20.0)
    model = compile_model(s)
    nodes0, vel0 = rigid_perturbation(s, np.random.default_rng(5), pos=0.03, rot=0.1, vel=0.5, omega=2.0)
    st = initial_state(model, nodes=nodes0, velocities=vel0)
    ts, q, qd = simulate(model, st, 5e-4, 600, "rk4")
    E = energies(model, q, qd)
    assert slack_counts(s, np.stack([node_positions(model, a)[0] for a in q])).max() >= 1
    assert np.diff(E).max() < 1e-9 * np.abs(E).max(), f"energy increased by {np.diff(E).max():.3g} J"
    assert E[-1] < 0.5 * E[0]


# ---------------------------------------------------------------------- momenta
def test_momentum_conserved_free_structure():
    """Free structure, no gravity, no anchors: linear momentum and angular momentum about
    the centre of mass are constant, and equal the node-coordinate values."""
    for name in ("free_prism_slack", "lumped_prism", "icosahedron"):
        d = case_data(name)
        model, ref = d["model"], d["ref"]
        assert model.anchor_idx.size == 0 and not model.has_gravity
        P, L = [], []
        for i in range(N_REC):
            q, qd = d["q"][i], d["qd"][i]
            com = center_of_mass(model, q)
            p_gym = linear_momentum(model, qd)[0]
            l_gym = angular_momentum(model, q, qd, about=com)[0]
            p_ref, l_ref = ref.momenta(d["X"][i], d["V"][i])
            np.testing.assert_allclose(p_gym, p_ref, atol=1e-12)
            np.testing.assert_allclose(l_gym, l_ref, atol=1e-12)
            P.append(p_ref)
            L.append(l_ref)
        P, L = np.array(P), np.array(L)
        assert np.abs(P[0]).max() > 0.05 and np.abs(L[0]).max() > 0.01, "momenta too small to test"
        assert np.abs(P - P[0]).max() < 1e-10, f"{name}: linear momentum drift {np.abs(P - P[0]).max():.3g}"
        assert np.abs(L - L[0]).max() < 1e-9, f"{name}: angular momentum drift {np.abs(L - L[0]).max():.3g}"
    # fixed steps: linear momentum is kept to round-off by every method; angular momentum
    # (quadratic) to round-off by semi-implicit Euler without projection, to O(dt^4) by RK4
    d = case_data("lumped_prism")
    model = d["model"]

    def momenta(q, qd):
        P = np.array([linear_momentum(model, b)[0] for b in qd])
        L = np.array([angular_momentum(model, a, b, about=center_of_mass(model, a))[0]
                      for a, b in zip(q, qd)])
        return np.abs(P - P[0]).max(), np.abs(L - L[0]).max()

    ts, q, qd = simulate(model, d["state"], 1e-3, 300, "rk4", record_every=30)
    dP, dL = momenta(q, qd)
    assert dP < 1e-13 and dL < 1e-7, ("rk4", dP, dL)
    ts, q, qd = simulate(model, d["state"], 1e-3, 300, "semi_implicit_euler", record_every=30,
                         project=False)
    dP, dL = momenta(q, qd)
    assert dP < 1e-13 and dL < 1e-13, ("semi_implicit_euler", dP, dL)


# ---------------------------------------------------------------------- constraint drift
def test_rod_length_drift_projection():
    d = case_data("free_prism_slack")
    model, st = d["model"], d["state"]
    out = {}
    for name in ("rk4", "semi_implicit_euler"):
        for proj in (True, False):
            ts, q, qd = simulate(model, st, 1e-3, 500, name, project=proj, record_every=50)
            drift = max(rod_length_drift(model, a)[0] for a in q)
            viol = max(constraint_violation(model, a, b)[0] for a, b in zip(q, qd))
            X = node_positions(model, q[-1])[0]
            node_drift = np.abs(np.linalg.norm(X[d["s"].bars[:, 1]] - X[d["s"].bars[:, 0]], axis=1)
                                - d["s"].bar_lengths).max()
            out[name, proj] = (drift, viol, node_drift)
    for name in ("rk4", "semi_implicit_euler"):
        drift, viol, node_drift = out[name, True]
        assert drift <= 1e-14 and viol <= 1e-13 and node_drift <= 1e-14, (name, out[name, True])
        drift_np, viol_np, node_np = out[name, False]
        assert drift_np > 1e3 * max(drift, 1e-16), f"{name}: no drift without projection? {out[name, False]}"
    # measured bounds without projection at dt = 1 ms over 0.5 s
    assert out["rk4", False][0] < 5e-7, out["rk4", False]
    assert out["semi_implicit_euler", False][0] < 1e-2, out["semi_implicit_euler", False]


def test_constrained_examples_keep_constraints():
    for name in ("constrained_prism", "pinned_rod", "lumped_pinned_rod"):
        d = case_data(name)
        s, model = d["s"], d["model"]
        # adaptive, no projection: drift set by the tolerance
        viol = max(constraint_violation(model, a, b)[0] for a, b in zip(d["q"], d["qd"]))
        assert viol < 1e-9, f"{name}: dop853 constraint violation {viol:.3g}"
        # fixed step with projection: exact
        ts, q, qd = simulate(model, d["state"], 1e-3, 500, "rk4", record_every=50)
        viol = max(constraint_violation(model, a, b)[0] for a, b in zip(q, qd))
        assert viol < 1e-13, f"{name}: rk4+projection constraint violation {viol:.3g}"
        for X in (node_positions(model, a)[0] for a in q):
            for node, D in s.node_constraints.items():
                assert np.abs(D @ X[node] - D @ s.nodes[node]).max() < 1e-13
            assert np.abs(np.linalg.norm(X[s.bars[:, 1]] - X[s.bars[:, 0]], axis=1) - s.bar_lengths).max() < 1e-13
            np.testing.assert_array_equal(X[s.anchors], s.nodes[s.anchors])
        # and it really moves along its constraints
        assert np.abs(node_positions(model, q[-1])[0] - node_positions(model, q[0])[0]).max() > 0.01


# ---------------------------------------------------------------------- convergence order
@pytest.mark.parametrize("integrator,dts,order", [
    ("semi_implicit_euler", (2e-3, 1e-3, 5e-4), 1.0),
    ("rk4", (4e-3, 2e-3, 1e-3), 4.0),
])
@pytest.mark.parametrize("project", [True, False])
def test_convergence_order(integrator, dts, order, project):
    s, model, st = smooth_case(damping=2.0)
    T = 0.2
    ref = step(model, st, T, "dop853", rtol=1e-13, atol=1e-13)
    N_ref = node_positions(model, ref.q)
    errs = []
    for dt in dts:
        out = step(model, st, dt, integrator, n_steps=int(round(T / dt)), project=project)
        errs.append(np.abs(node_positions(model, out.q) - N_ref).max())
    errs = np.array(errs)
    observed = np.log2(errs[:-1] / errs[1:])
    assert errs[-1] > 1e-10, "error too close to the reference's own error to measure an order"
    assert np.all(np.abs(observed - order) < 0.3), f"{integrator}: errors {errs}, observed orders {observed}"


@pytest.mark.parametrize("integrator", ["dop853", "radau"])
def test_adaptive_methods_converge_with_tolerance(integrator):
    """The adaptive methods approach the independent reference as their tolerance shrinks."""
    s, model, st = smooth_case(damping=2.0)
    T = 0.2
    X_ref, _ = NodeReference(s).simulate(node_positions(model, st.q)[0], node_velocities(model, st.qd)[0],
                                         [0.0, T])
    errs = []
    for rtol in (1e-5, 1e-8):
        out = step(model, st, T, integrator, rtol=rtol, atol=1e-2 * rtol)
        errs.append(np.abs(node_positions(model, out.q)[0] - X_ref[-1]).max())
    assert errs[1] < 1e-9 and errs[1] < errs[0], f"{integrator}: errors {errs} m at rtol 1e-5, 1e-8"


# ---------------------------------------------------------------------- prisms: statics
@pytest.mark.parametrize("p", [3, 4, 6])
def test_prestressed_prism_has_zero_acceleration(p):
    s = tg.prism(p)
    model = compile_model(s)
    st = initial_state(model)
    acc = node_velocities(model, tg.physics.accelerations(model, st.q, st.qd))[0]
    scale = s.initial_tensions().max() / s.bar_mass.min()     # m/s^2
    assert np.abs(acc).max() < 1e-9 * scale, f"prism{p}: |a| = {np.abs(acc).max():.3g} m/s^2"
    np.testing.assert_allclose(twist_angles(s.nodes, p), np.pi / 2 - np.pi / p, atol=1e-12)
    # a wrong rest length breaks the equilibrium: the check can fail
    rl = s.rest_length.copy()
    rl[-1] *= 0.99
    acc2 = node_velocities(model, tg.physics.accelerations(model, st.q, st.qd, rest_length=rl))[0]
    assert np.abs(acc2).max() > 1e-3 * scale


@pytest.mark.parametrize("p", [3, 4, 6])
def test_damped_prism_settles_at_equilibrium_twist(p):
    """Released off equilibrium (rod-wise rigid perturbation, at rest), with string damping
    and a viscous drag on the nodes, the prism settles back at twist pi/2 - pi/p.

    (String damping alone cannot do it quickly: the prism's infinitesimal mechanism does not
    stretch any string to first order, so viscous string damping leaves it undamped at
    linear order; the drag damps every mode.)"""
    s = tg.prism(p, damping=10.0)
    model = compile_model(s)
    nodes0, _ = rigid_perturbation(s, np.random.default_rng(p), pos=0.03, rot=0.1, vel=0.0, omega=0.0)
    target = np.pi / 2 - np.pi / p
    dev0 = np.abs(twist_angles(nodes0, p) - target).max()
    assert dev0 > 0.03
    st = initial_state(model, nodes=nodes0, velocities=np.zeros_like(nodes0))

    def drag(q, qd, t):
        return -3.0 * node_velocities(model, qd)

    out = step(model, st, 1e-2, "rk4", n_steps=700, external=drag)
    X = node_positions(model, out.q)[0]
    dev = np.abs(twist_angles(X, p) - target).max()
    assert dev < 1e-6, f"prism{p}: twist {twist_angles(X, p)} rad, expected {target}"
    # and it is the prestressed equilibrium again: string lengths back to the initial ones
    L = np.linalg.norm(X[s.strings[:, 1]] - X[s.strings[:, 0]], axis=1)
    assert np.abs(L - s.string_lengths).max() < 1e-5


def test_string_damping_alone_dissipates_and_oscillates_about_equilibrium_twist():
    s = tg.prism(3, damping=10.0)
    model = compile_model(s)
    nodes0, _ = rigid_perturbation(s, np.random.default_rng(3), pos=0.03, rot=0.1, vel=0.0, omega=0.0)
    st = initial_state(model, nodes=nodes0, velocities=np.zeros_like(nodes0))
    eq = initial_state(model)
    E_eq = energy(model, eq.q, eq.qd)[0]
    ts, q, qd = simulate(model, st, 4e-3, 750, "rk4", record_every=3)
    E = energies(model, q, qd) - E_eq
    assert np.diff(E).max() < 1e-9 and E[-1] < 0.01 * E[0]
    tw = np.array([twist_angles(node_positions(model, a)[0], 3).mean() for a in q[len(q) // 2:]])
    assert abs(tw.mean() - np.pi / 6) < 2e-3 and np.abs(tw - np.pi / 6).max() < 0.03


def test_prism_at_wrong_twist_with_prestress_is_rejected():
    with pytest.raises(StructureError, match="self-stress"):
        tg.prism(3, twist=0.3)
    with pytest.raises(StructureError, match="self-stress"):
        tg.prism(4, twist=np.pi / 4 + 0.2)
    # without prestress any twist is allowed
    s = tg.prism(3, twist=0.3, prestress=None)
    np.testing.assert_allclose(twist_angles(s.nodes, 3), 0.3, atol=1e-12)


# ---------------------------------------------------------------------- configuration matrix
@pytest.mark.parametrize("factory", [tg.prism, tg.pinned_rod, tg.constrained_prism, lumped_prism,
                                     lambda: tg.tower(2)])
def test_configuration_matrix(factory):
    s = factory()
    model = compile_model(s)
    nodes0, vel0 = rigid_perturbation(s, np.random.default_rng(0), pos=0.02, rot=0.1)
    st = initial_state(model, batch_size=1, nodes=nodes0, velocities=vel0)
    Q, Psi, Y = configuration_matrix(model, st.q)
    k, n = s.n_bars, s.n_nodes
    assert Q.shape == (1, 3, 2 * k) and Psi.shape == (n, 2 * k) and Y.shape == (3, n)
    N = Q[0] @ Psi.T + Y
    np.testing.assert_allclose(N.T, nodes0, atol=1e-14)
    # B columns are unit rod vectors a -> c
    bvec = nodes0[s.bars[:, 1]] - nodes0[s.bars[:, 0]]
    np.testing.assert_allclose(Q[0][:, k:].T, bvec / np.linalg.norm(bvec, axis=1)[:, None], atol=1e-14)
    # (5.17) for free uniform rods described at the centre: +-l/2 in the B columns
    for j, (a, c) in enumerate(s.bars):
        free = a not in s.node_constraints and c not in s.node_constraints
        if free and (s.mass_points is None or s.mass_points[j] is None):
            l = s.bar_lengths[j]
            assert Psi[a, j] == 1 and Psi[c, j] == 1
            np.testing.assert_allclose([Psi[a, k + j], Psi[c, k + j]], [-l / 2, l / 2], rtol=1e-14)
    # anchors only in Y, rod nodes have zero columns in Y
    on_rod = np.zeros(n, bool)
    on_rod[s.bars.ravel()] = True
    assert np.all(Y[:, on_rod] == 0)
    np.testing.assert_array_equal(Y[:, ~on_rod].T, s.nodes[~on_rod])


# ---------------------------------------------------------------------- stable step estimate
@pytest.mark.parametrize("factory", [tg.prism, tg.constrained_prism])
def test_stable_step_estimate(factory):
    s = factory()
    model = compile_model(s)
    est = stable_step_estimate(model)
    assert np.isfinite(est["omega_max"]) and est["omega_max"] > 0
    nodes0, vel0 = rigid_perturbation(s, np.random.default_rng(0), pos=0.002, rot=0.005, vel=0.01, omega=0.05)
    st = initial_state(model, nodes=nodes0, velocities=vel0)
    E0 = energy(model, st.q, st.qd)[0]
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        ts, q, qd = simulate(model, st, 0.5 * est["semi_implicit_euler"], 400, "semi_implicit_euler")
        E = energies(model, q, qd)
        assert np.abs(E - E0).max() < 1e-2 * abs(E0), "unstable at half the estimated step"
        try:
            ts, q, qd = simulate(model, st, 1.5 * est["semi_implicit_euler"], 400, "semi_implicit_euler")
            E = energies(model, q, qd)
            blew_up = not np.all(np.isfinite(E)) or np.nanmax(np.abs(E - E0)) > 1e3 * abs(E0)
        except SimulationDiverged:
            blew_up = True
    assert blew_up, "semi-implicit Euler at 1.5x the estimated stable step did not blow up"


# ---------------------------------------------------------------------- spinning bodies
def test_semi_implicit_euler_spinning_prism_no_secular_drift():
    s = tg.prism(3)
    vel = np.cross([1.0, 2.0, 4.0], s.nodes - s.nodes.mean(axis=0))
    model = compile_model(s)
    st = initial_state(model, velocities=vel)
    ts, q, qd = simulate(model, st, 1e-3, 2000, "semi_implicit_euler", record_every=500)
    E = energies(model, q, qd)
    L = np.array([np.linalg.norm(angular_momentum(model, a, b, about=center_of_mass(model, a))[0])
                  for a, b in zip(q, qd)])
    assert np.abs(E / E[0] - 1).max() < 5e-4, f"energy drift {E / E[0] - 1}"
    assert np.abs(L / L[0] - 1).max() < 1e-4, f"angular momentum drift {L / L[0] - 1}"
    # the string kicks and the great-circle drift of b both keep b x b' and r x r': the angular
    # momentum about the centre of mass is kept to round-off (the old normalised Euler update
    # lost 0.68 %/s here)
    Lv = np.stack([angular_momentum(model, a, b, about=center_of_mass(model, a))[0] for a, b in zip(q, qd)])
    assert np.abs(Lv - Lv[0]).max() < 1e-12 * np.linalg.norm(Lv[0]), np.abs(Lv - Lv[0]).max()
    assert max(constraint_violation(model, a, b)[0] for a, b in zip(q, qd)) < 1e-13


def test_semi_implicit_euler_rotates_free_rod_exactly():
    """A free rod with no force spins at constant rate: with projection, semi-implicit Euler
    turns b by exactly |b'| dt per step (great circle), also for large angles per step."""
    s = tg.Structure([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [[0, 1]], np.zeros((0, 2), int), bar_mass=1.0,
                     name="free_rod")
    model = compile_model(s)
    w, dt, n = 3.0, 0.1, 7                            # 0.3 rad per step
    vel = np.array([[0.0, -0.5 * w, 0.0], [0.0, 0.5 * w, 0.0]])
    st = initial_state(model, velocities=vel)
    out = step(model, st, dt, "semi_implicit_euler", n_steps=n)
    ang = w * dt * n
    np.testing.assert_allclose(out.q[0, 0, 3:], [np.cos(ang), np.sin(ang), 0.0], atol=1e-14)
    np.testing.assert_allclose(out.qd[0, 0, 3:], [-w * np.sin(ang), w * np.cos(ang), 0.0], atol=1e-13)
    np.testing.assert_allclose(out.q[0, 0, :3], st.q[0, 0, :3], atol=1e-15)


def test_stable_step_estimate_accounts_for_damping():
    s = tg.prism(3, damping=50.0)
    model = compile_model(s)
    est = stable_step_estimate(model)
    nodes0, vel0 = rigid_perturbation(s, np.random.default_rng(0), pos=0.002, rot=0.005, vel=0.01, omega=0.05)
    st = initial_state(model, nodes=nodes0, velocities=vel0)
    E0 = energy(model, st.q, st.qd)[0]
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        for name in ("semi_implicit_euler", "rk4"):
            try:
                ts, q, qd = simulate(model, st, 0.5 * est[name], 200, name)
                E = energies(model, q, qd)
                ok = np.all(np.isfinite(E)) and E.max() <= E0 * (1 + 1e-6)
            except SimulationDiverged:
                ok = False
            assert ok, f"{name} diverges at half the estimated stable step {est[name]:.3g} s"
            # and the estimate is not merely conservative: 1.5x it gains energy (unstable)
            ts, q, qd = simulate(model, st, 1.5 * est[name], 400, name)
            E = energies(model, q, qd)
            assert not (np.all(np.isfinite(E)) and E.max() <= E0 * (1 + 1e-3)), \
                f"{name} still stable at 1.5x the estimated step {est[name]:.3g} s"
    undamped = stable_step_estimate(model, damping=False)
    assert est["lambda_max"] > 5 * est["omega_max"] and undamped["lambda_max"] == pytest.approx(undamped["omega_max"], rel=1e-12)
    for name in ("semi_implicit_euler", "rk4"):
        assert est[name] < 0.2 * undamped[name], (est, undamped)


# ---------------------------------------------------------------------- node damping in the model
def _drag_scene(name):
    if name == "constrained_prism":       # the shape env's default scene: gravity, string damping
        s = tg.constrained_prism(damping=0.5)
    elif name == "hanging_rod":           # anchors (no drag on them), damped strings, gravity
        s = hanging_rod()
    else:                                 # free lumped prism, slack strings
        s = lumped_prism().replace(rest_length=1.02 * lumped_prism().string_lengths)
    c = np.random.default_rng(4).uniform(0.5, 3.0, s.n_nodes)    # per-node coefficients, N s/m
    nodes0, vel0 = rigid_perturbation(s, np.random.default_rng(1), pos=0.02, rot=0.05, vel=0.5, omega=2.0)
    return s, c, nodes0, vel0


@pytest.mark.parametrize("name", ["constrained_prism", "hanging_rod", "lumped_prism"])
def test_node_damping_in_model_equals_external_drag(name):
    """``compile_model(node_damping=c)`` with ONE call of n_steps equals the old path (drag
    ``-c v`` passed as an external force recomputed every step, one call per step) to round-off
    for semi-implicit Euler; for RK4 it equals the drag re-evaluated at every stage (the NumPy
    oracle's RK4 with the callable drag)."""
    backend = "numba"
    s, c, nodes0, vel0 = _drag_scene(name)
    plain = compile_model(s)
    damped = compile_model(s, node_damping=c)
    assert damped.has_node_damping and not plain.has_node_damping
    B = 3
    st = initial_state(plain, B, nodes=nodes0, velocities=vel0)
    st = State(st.q, st.qd * np.array([1.0, 0.5, -1.0])[:, None, None], 0.0)   # different copies
    dt, n = 1e-3, 40

    def drag(q, qd, t=0.0):
        return -c[:, None] * node_velocities(plain, qd)

    old = st
    for _ in range(n):
        old = step(plain, old, dt, "semi_implicit_euler", external=drag(old.q, old.qd), backend=backend)
    new = step(damped, st, dt, "semi_implicit_euler", n_steps=n, backend=backend)
    scale = np.abs(old.qd).max()
    assert np.abs(new.q - old.q).max() < 1e-13 and np.abs(new.qd - old.qd).max() < 1e-12 * scale, \
        (np.abs(new.q - old.q).max(), np.abs(new.qd - old.qd).max())
    undamped = step(plain, st, dt, "semi_implicit_euler", n_steps=n, backend=backend)
    assert np.abs(undamped.qd - new.qd).max() > 1e-3 * scale        # the drag really acts
    ref = oracle.step(plain, st, dt, "rk4", n_steps=n, external=drag)   # callable: every stage
    out = step(damped, st, dt, "rk4", n_steps=n, backend=backend)
    assert np.abs(out.q - ref.q).max() < 1e-13 and np.abs(out.qd - ref.qd).max() < 1e-12 * scale
    # the accelerations themselves, and node drag combined with an external force
    ext = np.random.default_rng(0).normal(size=(B, s.n_nodes, 3))
    np.testing.assert_allclose(tg.physics.accelerations(damped, st.q, st.qd, external=ext),
                               tg.physics.accelerations(plain, st.q, st.qd, external=ext + drag(st.q, st.qd)),
                               rtol=0, atol=1e-12 * np.abs(tg.physics.accelerations(plain, st.q, st.qd)).max())


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_node_damping_energy_decreases_monotonically(integrator):
    """No strings: a spinning, translating free rod and a pinned rod swinging under gravity lose
    energy at every recorded step (10 ms) with node drag, and keep it without (to the integrator's
    bounded error: semi-implicit Euler's oscillates by 0.3 % on the pendulum at 1 ms)."""
    free = tg.Structure([[0.0, 0.0, 0.0], [1.0, 0.2, 0.1]], [[0, 1]], np.zeros((0, 2), int), bar_mass=1.5,
                        velocities=[[0.3, -1.0, 0.5], [0.1, 0.0, 0.5]], name="free_rod")
    pend = tg.Structure([[0.0, 0.0, 0.0], [0.6, 0.0, 0.8]], [[0, 1]], np.zeros((0, 2), int), bar_mass=1.0,
                        gravity=GRAVITY, node_constraints={0: np.eye(3)}, velocities=[[0, 0, 0], [0, 1.0, 0]],
                        name="pendulum")
    for s in (free, pend):
        for c in (2.0, 0.0):
            model = compile_model(s, node_damping=c)
            st = initial_state(model)
            ts, q, qd = simulate(model, st, 1e-3, 3000, integrator, record_every=10)
            E = energies(model, q, qd)
            if c > 0:
                assert np.diff(E).max() < 0, f"{s.name}: energy rose by {np.diff(E).max():.3g} J with node drag"
                assert E[-1] < E[0] - 0.1, f"{s.name}: node drag dissipated only {E[0] - E[-1]:.3g} J"
            else:
                assert np.abs(E - E[0]).max() < 5e-3 * abs(E[0]), f"{s.name}: no drag, energy error {np.abs(E - E[0]).max():.3g} J"


def test_node_damping_rejects_bad_values():
    s = tg.prism(3)
    with pytest.raises(ValueError, match="node_damping"):
        compile_model(s, node_damping=-1.0)
    with pytest.raises(ValueError, match="node_damping"):
        compile_model(s, node_damping=np.ones(s.n_nodes + 1))
    with pytest.raises(ValueError, match="node_damping.*nan"):
        compile_model(s, node_damping=np.full(s.n_nodes, np.nan))
    m = compile_model(s, node_damping=0.0)
    assert not m.has_node_damping and m.node_velocity_free


# ---------------------------------------------------------------------- figures
def _rel_drift(E):
    return np.abs(E - E[0]).max() / abs(E[0])


def print_figures():
    """Print the figures these tests check: ``python tests/test_physics.py``."""
    warnings.simplefilter("ignore")
    for name in CASES:
        d = case_data(name)
        print(f"agreement {name:28s} T = {d['t'][-1]:.1f} s: positions {np.abs(d['X'] - d['X_ref']).max():.2e} m, "
              f"velocities {np.abs(d['V'] - d['V_ref']).max():.2e} m/s")
    d = case_data("free_prism_slack")
    print(f"energy drift, dop853 rtol 1e-12, slack prism 0.3 s: {_rel_drift(energies(d['model'], d['q'], d['qd'])):.2e}")
    s, model, st = smooth_case()
    ts, q, qd = simulate(model, st, 2e-4, 1000, "rk4", record_every=50)
    print(f"energy drift, rk4 dt 2e-4, taut prism 0.2 s: {_rel_drift(energies(model, q, qd)):.2e}")
    ts, q, qd = simulate(d["model"], d["state"], 2e-4, 1500, "rk4", record_every=30)
    print(f"energy drift, rk4 dt 2e-4, slack prism 0.3 s: {_rel_drift(energies(d['model'], q, qd)):.2e}")
    ts, q, qd = simulate(d["model"], d["state"], 2e-4, 3000, "semi_implicit_euler", record_every=25)
    print(f"energy error, semi-implicit Euler dt 2e-4, slack prism 0.6 s: {_rel_drift(energies(d['model'], q, qd)):.2e}")
    for name in ("rk4", "semi_implicit_euler"):
        for proj in (True, False):
            ts, q, qd = simulate(d["model"], d["state"], 1e-3, 500, name, project=proj, record_every=50)
            drift = max(rod_length_drift(d["model"], a)[0] for a in q)
            print(f"rod-length drift, {name} dt 1e-3, 0.5 s, project={proj}: {drift:.2e}")
    s, model, st = smooth_case(damping=2.0)
    ref = node_positions(model, step(model, st, 0.2, "dop853", rtol=1e-13, atol=1e-13).q)
    for integrator, dts in (("semi_implicit_euler", (2e-3, 1e-3, 5e-4)), ("rk4", (4e-3, 2e-3, 1e-3))):
        errs = np.array([np.abs(node_positions(model, step(model, st, dt, integrator,
                                                           n_steps=int(round(0.2 / dt))).q) - ref).max()
                         for dt in dts])
        print(f"order {integrator}: errors {errs} m at dt {dts} s, observed orders {np.log2(errs[:-1] / errs[1:])}")


if __name__ == "__main__":
    print_figures()


# ---------------------------------------------------------------------- the public in-place step
@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4", "implicit_euler"])
@pytest.mark.parametrize("inputs", ["none", "controls", "params", "callable"])
def test_public_step_inplace_equals_step(integrator, inputs):
    """physics.step_inplace writes exactly what physics.step returns into the state's own arrays
    (bit for bit, every integrator, with controls, per-copy parameters or a callable external
    force), returns the same time, and leaves the input of step untouched."""
    from tensegrity_gym import physics
    model = compile_model(tg.prism(3, damping=2.0, gravity=GRAVITY))
    B, rng = 3, np.random.default_rng(11)
    st0 = initial_state(model, B)
    st0 = State(st0.q + rng.normal(0, 0.01, st0.q.shape), rng.normal(0, 0.1, st0.q.shape), 0.25)
    kw = {}
    if inputs == "controls":
        kw = dict(rest_length=model.rest_length * (1.0 + 0.02 * rng.uniform(-1, 1, (B, model.n_strings))),
                  external=rng.normal(0, 0.5, (B, model.n_nodes, 3)))
    elif inputs == "params":
        from tensegrity_gym.core.params import default_params
        kw = dict(params=default_params(model, B).replace(mass=model.mass * rng.uniform(0.9, 1.1, (B, 3))))
    elif inputs == "callable":
        kw = dict(external=lambda q, qd, t: -0.3 * node_velocities(model, qd))
    q0, qd0 = st0.q.copy(), st0.qd.copy()
    out = physics.step(model, st0, 1e-3, integrator, n_steps=7, **kw)
    np.testing.assert_array_equal(st0.q, q0)
    st = State(q0.copy(), qd0.copy(), st0.t)
    t = physics.step_inplace(model, st, 1e-3, integrator, n_steps=7, **kw)
    assert t == out.t and st.t == 0.25
    if inputs == "none":        # again: the call that reuses the first call's checks
        t2 = physics.step_inplace(model, State(st.q, st.qd, t), 1e-3, integrator, n_steps=7)
        out = physics.step(model, out, 1e-3, integrator, n_steps=7)
        assert t2 == out.t
        np.testing.assert_array_equal(st.q, out.q)
        np.testing.assert_array_equal(st.qd, out.qd)
    np.testing.assert_array_equal(st.q, out.q)
    np.testing.assert_array_equal(st.qd, out.qd)


def test_public_step_inplace_refuses_arrays_it_cannot_write_and_bad_input():
    """ValueError naming the field for a state it cannot write in place (float32, read-only,
    strided), a non-finite state, a bad dt or n_steps; the arrays are left as they were."""
    from tensegrity_gym import physics
    model = compile_model(tg.prism(3))
    st = initial_state(model, 2)
    physics.step_inplace(model, State(st.q.copy(), st.qd.copy(), 0.0), 1e-3)   # later calls reuse its checks
    with pytest.raises(ValueError, match="state.q and state.qd must be writable C-contiguous float64"):
        physics.step_inplace(model, State(st.q.astype(np.float32), st.qd, 0.0), 1e-3)
    ro = st.q.copy()
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="writable"):
        physics.step_inplace(model, State(ro, st.qd.copy(), 0.0), 1e-3)
    wide = np.zeros((2, 3, 12))
    with pytest.raises(ValueError, match="C-contiguous"):
        physics.step_inplace(model, State(wide[..., ::2], st.qd.copy(), 0.0), 1e-3)
    bad = st.q.copy()
    bad[1, 2, 4] = np.nan
    with pytest.raises(ValueError, match=r"state.q"):
        physics.step_inplace(model, State(bad, st.qd.copy(), 0.0), 1e-3)
    q, qd = st.q.copy(), st.qd.copy()
    for dt, n in ((0.0, 1), (float("nan"), 1), (1e-3, 0), (1e-3, 1.5)):
        with pytest.raises(ValueError, match="dt|n_steps"):
            physics.step_inplace(model, State(q, qd, 0.0), dt, n_steps=n)
    np.testing.assert_array_equal(q, st.q)
    np.testing.assert_array_equal(qd, st.qd)
