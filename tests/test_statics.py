"""Statics: equilibria under gravity and prestress, their linearity in the force densities, errors."""
import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.model import compile_model, initial_state
from tensegrity_gym.physics.evaluate import force_densities, project
from tensegrity_gym.physics import statics


@pytest.fixture(scope="module")
def prism():
    return tg.constrained_prism()


@pytest.fixture(scope="module")
def eq(prism):
    return statics.equilibrium(prism)


def test_equilibrium_has_zero_accelerations_and_is_stable(prism, eq):
    model = compile_model(prism)
    st = initial_state(model, 1, nodes=eq.nodes)
    acc = tg.physics.accelerations(model, st.q, np.zeros_like(st.qd))
    assert np.abs(acc).max() < 1e-8                       # m/s^2, from ~10 m/s^2 of gravity
    assert eq.residual < 1e-9
    assert eq.min_stiffness > 10.0                        # N/m: stable
    # gravity makes it sag: the top nodes move down, by less than a few cm with 100 N of prestress
    dz = eq.nodes[3:, 2] - prism.nodes[3:, 2]
    assert np.all(dz < 0) and np.all(dz > -0.05)
    # constrained nodes stay on their point / line / plane
    assert np.allclose(eq.nodes[0], 0.0, atol=1e-12)
    assert abs(eq.nodes[1, 1]) < 1e-12 and abs(eq.nodes[1, 2]) < 1e-12 and abs(eq.nodes[2, 2]) < 1e-12
    # total vertical reaction balances the weight: sum of string forces on the rods is internal,
    # so check tensions positive and finite
    assert np.all(eq.tension > 0)


def test_without_gravity_the_prestressed_prism_is_its_own_equilibrium():
    s = tg.constrained_prism(gravity=None)
    e = statics.equilibrium(s, relax_steps=0)
    assert np.abs(e.nodes - s.nodes).max() < 1e-10
    assert np.allclose(e.tension, s.initial_tensions(), rtol=1e-9)


def test_relaxation_from_far_reaches_the_same_equilibrium(prism, eq):
    nodes = prism.nodes.copy()
    nodes[3:] += np.array([0.05, -0.03, 0.04])     # move the top (rod lengths change; re-normalised)
    e2 = statics.equilibrium(prism, nodes=nodes, relax_steps=20000)
    assert e2.relax_steps > 0
    assert np.abs(e2.nodes - eq.nodes).max() < 1e-8


def test_residual_is_linear_in_force_densities(prism, eq):
    model = compile_model(prism)
    rng = np.random.default_rng(0)
    q = eq.q[None] + 0.01 * rng.standard_normal((1, 3, 6))
    q, _ = project(model, q, np.zeros_like(q))
    A, w = statics.equilibrium_matrix(model, q)
    gamma, _, _ = force_densities(model, q, np.zeros_like(q))
    R = statics.generalized_residual(model, q)
    assert np.abs(A[0] @ gamma[0] + w[0] - R[0]).max() < 1e-10 * np.abs(R).max()
    # at the equilibrium the equilibrium force densities solve A g = -w exactly
    A, w = statics.equilibrium_matrix(model, eq.q[None])
    assert np.abs(A[0] @ eq.force_density + w[0]).max() < 1e-8


def test_force_density_equilibrium_matches_rest_length_equilibrium(prism, eq):
    """Holding the equilibrium force densities in active strings gives the same equilibrium."""
    act = [0, 4, 8]
    fd = np.zeros(prism.n_strings)
    fd[act] = eq.force_density[act]
    e2 = statics.equilibrium(prism, force_density=fd, active_strings=act, relax_steps=0, require_stable=False)
    assert np.abs(e2.nodes - eq.nodes).max() < 1e-9
    assert np.allclose(e2.force_density, eq.force_density, rtol=1e-8)


def test_stiffness_is_symmetric_at_equilibrium(prism, eq):
    model = compile_model(prism)
    K = statics.stiffness_matrix(model, eq.q[None])[0]
    assert np.abs(K - K.T).max() < 1e-4 * np.abs(K).max()


def test_error_all_strings_slack(prism):
    with pytest.raises(statics.EquilibriumError, match="slack|collapsed"):
        statics.equilibrium(prism, rest_length=prism.string_lengths * 1.5, relax_steps=3000)


def test_error_mechanism_for_a_free_structure():
    with pytest.raises(statics.EquilibriumError, match="mechanism"):
        statics.equilibrium(tg.prism(3), relax_steps=0)


def test_error_no_convergence(prism):
    with pytest.raises(statics.EquilibriumError, match="no convergence|collapsed|unstable"):
        statics.equilibrium(prism, rest_length=prism.rest_length * 0.5, relax_steps=0, max_iter=1)


def test_bad_inputs_name_the_problem(prism):
    with pytest.raises(ValueError, match="rest_length: expected 9"):
        statics.equilibrium(prism, rest_length=[1.0, 2.0])
    bad = prism.rest_length.copy()
    bad[4] = np.nan
    with pytest.raises(ValueError, match="string 4"):
        statics.equilibrium(prism, rest_length=bad)


def test_batched_solve_matches_single(prism):
    model = compile_model(prism)
    rng = np.random.default_rng(1)
    rl = prism.rest_length * (1 + rng.uniform(-0.05, 0.05, (3, prism.n_strings)))
    q0 = np.repeat(statics.equilibrium(model).q[None], 3, 0)
    res = statics.solve_equilibria(model, q0, rl)
    assert np.all(res["status"] == statics.OK)
    for i in range(3):
        e = statics.equilibrium(model, rest_length=rl[i], relax_steps=0)
        assert np.abs(e.nodes - res["nodes"][i]).max() < 1e-9
