"""Builders: counts, exact prestressed equilibria (checked by statics, independent of the
dynamics), constrained examples, the name registry."""
from __future__ import annotations

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym import Structure, StructureError
from tensegrity_gym.core.builders import BUILDERS, build, rest_lengths_for_force_densities, self_stress


def rod_residuals(s: Structure, gravity=False):
    """Per rod: net force (N) and net moment about its midpoint (N m) from string tensions
    k max(0, L - l0) (and gravity m g, if asked) at the structure's own nodes; and the
    tension scale (N)."""
    S = s.nodes[s.strings[:, 1]] - s.nodes[s.strings[:, 0]]
    L = np.linalg.norm(S, axis=1)
    T = s.stiffness * np.maximum(L - s.rest_length, 0.0)
    F = np.zeros_like(s.nodes)
    np.add.at(F, s.strings[:, 0], (T / L)[:, None] * S)
    np.add.at(F, s.strings[:, 1], -(T / L)[:, None] * S)
    out = []
    for j, (a, c) in enumerate(s.bars):
        mid = 0.5 * (s.nodes[a] + s.nodes[c])
        f = F[a] + F[c]
        mom = np.cross(s.nodes[a] - mid, F[a]) + np.cross(s.nodes[c] - mid, F[c])
        if gravity and s.gravity is not None:
            f = f + s.bar_mass[j] * s.gravity
        out.append((f, mom))
    return out, T.max()


def assert_self_equilibrium(s: Structure, rel=1e-10):
    res, scale = rod_residuals(s)
    L = s.bar_lengths.max()
    for j, (f, mom) in enumerate(res):
        assert np.abs(f).max() < rel * scale, f"{s.name}: rod {j} net force {f} N"
        assert np.abs(mom).max() < rel * scale * L, f"{s.name}: rod {j} net moment {mom} N m"


@pytest.mark.parametrize("p", [3, 4, 5, 6, 8])
def test_prism_counts_and_layout(p):
    s = tg.prism(p)
    assert (s.n_nodes, s.n_bars, s.n_strings) == (2 * p, p, 3 * p)
    assert s.name == f"prism{p}" and len(s.anchors) == 0 and not s.node_constraints and s.gravity is None
    # bottom 0..p-1 at z = 0, top p..2p-1 at z = height; strings bottom, top, vertical
    np.testing.assert_allclose(s.nodes[:p, 2], 0.0)
    np.testing.assert_allclose(s.nodes[p:, 2], 1.0)
    np.testing.assert_allclose(np.linalg.norm(s.nodes[:, :2], axis=1), 0.5)
    assert np.all(s.strings[:p] < p) and np.all(s.strings[p:2 * p] >= p)
    assert np.all(s.strings[2 * p:, 0] < p) and np.all(s.strings[2 * p:, 1] >= p)
    assert np.all(s.bars[:, 0] < p) and np.all(s.bars[:, 1] >= p)


@pytest.mark.parametrize("p", [3, 4, 5, 6, 8])
def test_prestressed_prism_is_in_exact_equilibrium(p):
    s = tg.prism(p, prestress=120.0, stiffness=2000.0)
    assert_self_equilibrium(s)
    T = s.initial_tensions()
    assert np.all(T > 0), "every string of the prestressed prism must be taut"
    np.testing.assert_allclose(T[2 * p:], 120.0, rtol=1e-12)            # vertical strings carry the prestress
    # symmetry: bottom and top strings carry equal tensions
    np.testing.assert_allclose(T[:p], T[0], rtol=1e-10)
    np.testing.assert_allclose(T[p:2 * p], T[0], rtol=1e-10)
    # the check can fail: a changed rest length breaks it
    rl = s.rest_length.copy()
    rl[0] *= 0.999
    res, scale = rod_residuals(s.replace(rest_length=rl))
    assert max(np.abs(f).max() for f, _ in res) > 1e-5 * scale


def test_prism_twist_and_errors():
    for p in (3, 4, 6):
        s = tg.prism(p)
        # angle from bottom node i to top node i about z
        ang = np.arctan2(s.nodes[p:, 1], s.nodes[p:, 0]) - np.arctan2(s.nodes[:p, 1], s.nodes[:p, 0])
        np.testing.assert_allclose(np.mod(ang, 2 * np.pi), np.pi / 2 - np.pi / p, atol=1e-12)
    with pytest.raises(StructureError, match="self-stress"):
        tg.prism(3, twist=np.pi / 3)
    with pytest.raises(StructureError, match=r"prism: p must be an integer >= 3"):
        tg.prism(2)
    with pytest.raises(StructureError, match=r"prism: radius must be positive"):
        tg.prism(3, radius=-1.0)
    with pytest.raises(StructureError, match=r"prism: prestress must be positive"):
        tg.prism(3, prestress=-5.0)
    with pytest.raises(StructureError, match=r"string .*needs stiffness above"):
        tg.prism(3, prestress=1e6, stiffness=10.0)


def test_icosahedron():
    s = tg.icosahedron()
    assert (s.n_nodes, s.n_bars, s.n_strings) == (12, 6, 24)
    # every node carries 4 strings; rods come in 3 parallel pairs along x, y, z
    deg = np.bincount(s.strings.ravel(), minlength=12)
    assert np.all(deg == 4)
    b = s.nodes[s.bars[:, 1]] - s.nodes[s.bars[:, 0]]
    b /= np.linalg.norm(b, axis=1)[:, None]
    axes = np.argmax(np.abs(b), axis=1)
    assert sorted(axes.tolist()) == [0, 0, 1, 1, 2, 2] and np.allclose(np.abs(b).max(axis=1), 1.0)
    np.testing.assert_allclose(s.bar_lengths, 1.0)
    # all strings have the same length and the same tension (the prestress)
    np.testing.assert_allclose(s.string_lengths, s.string_lengths[0], rtol=1e-12)
    np.testing.assert_allclose(s.initial_tensions(), 50.0, rtol=1e-12)
    assert_self_equilibrium(s)
    s2 = tg.icosahedron(length=2.0, prestress=200.0, stiffness=5000.0)
    assert_self_equilibrium(s2)
    np.testing.assert_allclose(s2.bar_lengths, 2.0)


def test_pinned_rod():
    s = tg.pinned_rod()
    assert (s.n_nodes, s.n_bars, s.n_strings) == (5, 1, 3)
    assert list(s.anchors) == [2, 3, 4]
    assert list(s.node_constraints) == [0] and np.linalg.matrix_rank(s.node_constraints[0]) == 3
    np.testing.assert_allclose(s.nodes[0], 0.0)
    assert np.all(s.initial_tensions() > 0) and s.gravity is not None


def test_constrained_prism():
    s = tg.constrained_prism(gravity=None)
    assert (s.n_nodes, s.n_bars, s.n_strings) == (6, 3, 9)
    ranks = {k: int(np.linalg.matrix_rank(D)) for k, D in s.node_constraints.items()}
    assert ranks == {0: 3, 1: 2, 2: 1}
    # node 0 at the origin (pinned), node 1 on the +x axis (line), node 2 on z = 0 (plane)
    np.testing.assert_allclose(s.nodes[0], 0.0, atol=1e-15)
    assert s.nodes[1, 0] > 0 and abs(s.nodes[1, 1]) < 1e-14 and abs(s.nodes[1, 2]) < 1e-14
    assert abs(s.nodes[2, 2]) < 1e-14
    np.testing.assert_allclose(s.node_constraints[1] @ [1.0, 0.0, 0.0], 0.0)          # free along x
    np.testing.assert_allclose(s.node_constraints[2] @ [1.0, 0.0, 0.0], 0.0)          # free in x, y
    np.testing.assert_allclose(s.node_constraints[2] @ [0.0, 1.0, 0.0], 0.0)
    # one constrained node per rod, the prestressed prism rigidly moved: still in equilibrium
    for a, c in s.bars:
        assert (a in s.node_constraints) + (c in s.node_constraints) == 1
    assert_self_equilibrium(s)
    np.testing.assert_allclose(np.sort(s.string_lengths), np.sort(tg.prism(3).string_lengths), rtol=1e-12)
    assert tg.constrained_prism().gravity is not None


@pytest.mark.parametrize("q", [1, 2, 3, 30])
def test_tower_counts(q):
    s = tg.tower(q)
    p = 3
    assert (s.n_nodes, s.n_bars, s.n_strings) == (2 * p * q, p * q, 3 * p * q + 2 * p * (q - 1))
    assert s.name == f"tower{q}"
    np.testing.assert_allclose(s.rest_length, 0.98 * s.string_lengths)
    assert len(s.anchors) == 0


def test_tower_errors():
    with pytest.raises(StructureError, match=r"tower: q must be an integer >= 1"):
        tg.tower(0)


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_build_every_name(name):
    s = build(name)
    assert isinstance(s, Structure)
    assert s.name == name
    assert s.n_bars >= 1
    # and each is valid input for the dynamics
    from tensegrity_gym.core.model import compile_model, initial_state
    model = compile_model(s)
    st = initial_state(model)
    assert np.all(np.isfinite(tg.physics.accelerations(model, st.q, st.qd)))


def test_build_patterns_and_unknown_name():
    assert build("prism5").n_bars == 5
    assert build("tower4").n_bars == 12
    for bad in ("prism", "pyramid", "tower-1", ""):
        with pytest.raises(StructureError, match=rf"unknown structure '{bad}'.*built-in names"):
            build(bad)


def test_self_stress_and_rest_lengths():
    s = tg.prism(3, prestress=None)
    gamma, resid = self_stress(s.nodes, s.bars, s.strings)
    assert resid < 1e-12 and np.all(gamma > 0)
    np.testing.assert_allclose(np.linalg.norm(gamma), 1.0)
    L = s.string_lengths
    l0 = rest_lengths_for_force_densities(L, 10 * gamma, 1000.0)
    np.testing.assert_allclose(1000.0 * (L - l0) / L, 10 * gamma, rtol=1e-12)
    assert_self_equilibrium(s.replace(rest_length=l0))
    with pytest.raises(StructureError, match=r"string 0: force density .*needs stiffness above"):
        rest_lengths_for_force_densities([1.0], [2000.0], [1000.0])


def test_roll_robots_are_built_in_structures():
    """TensegrityRoll-v0's robots load by name everywhere a structure is taken (CLI info/export,
    load_structure), equal to the env's builders: users can export the exact robot the policies
    were trained on."""
    from tensegrity_gym import load_structure
    from tensegrity_gym.envs import roll_scene
    for name, ref in (("prism_robot", roll_scene.robot_prism()), ("icosahedron_robot", roll_scene.robot_icosahedron())):
        s = load_structure(name)
        for field in ("nodes", "bars", "strings", "bar_mass", "stiffness", "rest_length", "damping"):
            np.testing.assert_array_equal(getattr(s, field), getattr(ref, field), err_msg=f"{name}.{field}")
        np.testing.assert_array_equal(s.gravity, [0.0, 0.0, -9.81])
