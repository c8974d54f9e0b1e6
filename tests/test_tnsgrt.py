"""tnsgrt import: hand-made fixtures in tnsgrt's layout (always run) and real tnsgrt objects
(skipped when tnsgrt cannot be imported)."""
import json

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.structure import StructureError
from tensegrity_gym.io.tnsgrt import from_tnsgrt, to_tnsgrt_dict


def _prism_fixture(with_stiffness=True):
    """Our prestressed 3-prism written in tnsgrt 0.6's layout: strings first (bottom, top,
    vertical), then bars, as tnsgrt's Prism orders them; force densities lambda_ in N/m."""
    s = tg.prism(3, prestress=100.0)
    L = s.string_lengths
    lam = s.initial_tensions() / L
    members = np.hstack([s.strings.T, s.bars.T])
    m, k = s.n_strings, s.n_bars
    props = {
        "lambda_": list(lam) + [-1.0] * k,               # bars: compression (ignored: rigid rods)
        "stiffness": list(s.stiffness) + [0.0] * k if with_stiffness else [0.0] * (m + k),
        "rest_length": list(s.rest_length) + [0.0] * k if with_stiffness else [0.0] * (m + k),
        "mass": [1.0] * m + [2.5] * k,
        # E A / L = 1000 N/m for a string of length L: E = 1000 L / A
        "modulus": list(1000.0 * L / (np.pi * 0.005 ** 2)) + [200e9] * k,
        "radius": [0.005] * m + [0.01] * k,
        "inner_radius": [0.0] * (m + k),
    }
    d = {"label": "hand-made prism", "nodes": s.nodes.T.tolist(), "members": members.tolist(),
         "member_tags": {"string": list(range(m)), "bar": list(range(m, m + k)), "bottom": [0, 1, 2]},
         "member_properties": props}
    return s, d


@pytest.mark.parametrize("with_stiffness", [True, False])
def test_dict_fixture_prism(with_stiffness):
    ours, d = _prism_fixture(with_stiffness)
    s = from_tnsgrt(d)
    assert s.name == "hand-made prism"
    np.testing.assert_array_equal(s.nodes, ours.nodes)
    np.testing.assert_array_equal(s.bars, ours.bars)
    np.testing.assert_array_equal(s.strings, ours.strings)
    np.testing.assert_allclose(s.bar_mass, 2.5)
    np.testing.assert_allclose(s.stiffness, 1000.0, rtol=1e-12)
    np.testing.assert_allclose(s.rest_length, ours.rest_length, rtol=1e-12)
    # still the prestressed equilibrium
    m = tg.compile_model(s)
    st = tg.initial_state(m)
    acc = tg.physics.accelerations(m, st.q, st.qd)
    assert np.abs(acc).max() < 1e-9


def test_dataframe_object_and_json(tmp_path):
    pd = pytest.importorskip("pandas")
    ours, d = _prism_fixture(False)

    class Constraint:              # tnsgrt NodeConstraint: normal is 3 x p, dof = 3 - p
        def __init__(self, normal, dof):
            self.normal, self.dof = normal, dof

    class FakeTnsgrt:              # duck-typed like tnsgrt.structure.Structure
        label = "object prism"
        nodes = np.asarray(d["nodes"])
        members = np.asarray(d["members"])
        member_tags = {k: np.asarray(v) for k, v in d["member_tags"].items()}
        member_properties = pd.DataFrame(d["member_properties"])
        node_properties = pd.DataFrame({"constraint": [Constraint(None, 0), None,
                                                       Constraint(np.array([[0.0], [0.0], [1.0]]), 2),
                                                       None, None, None]})

    s = from_tnsgrt(FakeTnsgrt(), gravity=(0, 0, -9.81), damping=1.0)
    assert s.name == "object prism" and set(s.node_constraints) == {0, 2}
    np.testing.assert_array_equal(s.node_constraints[0], np.eye(3))
    np.testing.assert_array_equal(s.node_constraints[2], [[0.0, 0.0, 1.0]])
    np.testing.assert_allclose(s.damping, 1.0)
    # dict form round trip through JSON
    p = tmp_path / "prism_tnsgrt.json"
    p.write_text(json.dumps(to_tnsgrt_dict(FakeTnsgrt())))
    s2 = from_tnsgrt(p, gravity=(0, 0, -9.81), damping=1.0)
    np.testing.assert_allclose(s2.rest_length, s.rest_length, rtol=1e-12)
    assert s2.node_constraints.keys() == s.node_constraints.keys()


def test_stiffness_override_keeps_prestress():
    ours, d = _prism_fixture(True)
    s = from_tnsgrt(d, stiffness=5000.0)
    np.testing.assert_allclose(s.initial_tensions(), ours.initial_tensions(), rtol=1e-9)


@pytest.mark.parametrize("mutate, msg", [
    (lambda d: d.pop("members"), "needs 'nodes'"),
    (lambda d: d.update(nodes=[[0, 0], [1, 1]]), "3 x n"),
    (lambda d: d["member_tags"].update(bar=[9, 10]), "neither 'bar' nor 'string'"),
    (lambda d: d["member_tags"].update(bar=[0, 10, 11]), "both bar and string"),
    (lambda d: d["member_properties"].update(stiffness=["1000"] * 12), "expected a number"),
    (lambda d: d["member_properties"].update(lambda_=[5000.0] * 12), "rest length"),
])
def test_bad_input_names_the_field(mutate, msg):
    _, d = _prism_fixture(False)   # stiffness from E A / L, rest length from lambda_
    mutate(d)
    with pytest.raises(StructureError, match=msg):
        from_tnsgrt(d)


def _import_tnsgrt():
    if not hasattr(np, "float_"):
        np.float_ = np.float64            # NumPy-2 shim for tnsgrt 0.6 (documented in tensegrity_gym.io.tnsgrt)
    pytest.importorskip("tnsgrt.prism", exc_type=ImportError)
    from tnsgrt.prism import Prism
    return Prism


def test_real_tnsgrt_prism_and_tower():
    Prism = _import_tnsgrt()
    p = Prism(3)
    s = from_tnsgrt(p, stiffness=1000.0)
    assert (s.n_bars, s.n_strings, s.n_nodes) == (3, 9, 6)
    m = tg.compile_model(s)
    st = tg.initial_state(m)
    assert np.abs(tg.physics.accelerations(m, st.q, st.qd)).max() < 1e-6   # tnsgrt's equilibrium
    # a two-stage tower: a second prism on top, tied by saddle strings
    t = Prism(3)
    top = Prism(3)
    top.translate(np.array([0.0, 0.0, 0.8]))
    t.merge(top)
    n = p.get_number_of_nodes()
    saddle = np.array([[3, 4, 5, 3, 4, 5], [n + 0, n + 1, n + 2, n + 1, n + 2, n + 0]])
    t.add_members(saddle, number_of_strings=6)
    tw = from_tnsgrt(t, stiffness=1000.0)
    assert (tw.n_bars, tw.n_strings, tw.n_nodes) == (6, 24, 12)
