"""Structure validation (every error names its item), JSON round trip, load_structure."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym import Structure, StructureError, load_json, save_json, from_dict, load_structure


def base(**changes):
    """A valid free 3-prism with no prestress (6 nodes, 3 rods, 9 strings) plus changes."""
    s = tg.prism(3, prestress=None)
    d = dict(nodes=s.nodes, bars=s.bars, strings=s.strings, bar_mass=1.0, stiffness=1000.0,
             rest_length=None, damping=0.0)
    d.update(changes)
    return Structure(**d)


def with_anchor(**changes):
    """Pinned rod (node 0 pinned, nodes 2..4 anchors) plus changes."""
    return tg.pinned_rod().replace(**changes)


def test_base_is_valid():
    s = base()
    assert (s.n_nodes, s.n_bars, s.n_strings) == (6, 3, 9)
    np.testing.assert_allclose(s.rest_length, s.string_lengths)
    for arr in (s.nodes, s.bars, s.strings, s.bar_mass, s.stiffness, s.rest_length, s.damping, s.velocities):
        assert not arr.flags.writeable


# ---------------------------------------------------------------------- topology
def test_node_on_two_rods():
    bars = base().bars.copy()
    bars[1] = [bars[0, 1], 5]     # rod 1 shares rod 0's node
    bars = bars[:2]
    with pytest.raises(StructureError, match=rf"bar 1 \(nodes {bars[1, 0]}, 5\): node {bars[0, 1]} "
                                             r"is already on bar 0.*class-1"):
        base(bars=bars)


def test_member_refers_to_missing_node():
    s = base()
    with pytest.raises(StructureError, match=r"bar 2 \(nodes 2, 6\): node 6 does not exist \(there are 6 nodes\)"):
        base(bars=[[0, 4], [1, 5], [2, 6]])
    strings = s.strings.copy()
    strings[4] = [3, 9]
    with pytest.raises(StructureError, match=r"string 4 \(nodes 3, 9\): node 9 does not exist"):
        base(strings=strings)
    strings[4] = [-1, 3]
    with pytest.raises(StructureError, match=r"string 4 \(nodes -1, 3\): node -1 does not exist"):
        base(strings=strings)


def test_member_with_same_node_twice():
    strings = base().strings.copy()
    strings[2] = [1, 1]
    with pytest.raises(StructureError, match=r"string 2 \(nodes 1, 1\): both ends are the same node"):
        base(strings=strings)


def test_zero_length_rod_and_string():
    s = base()
    nodes = s.nodes.copy()
    a, c = s.bars[1]
    nodes[c] = nodes[a]
    with pytest.raises(StructureError, match=rf"bar 1 \(nodes {a}, {c}\): zero length"):
        base(nodes=nodes)
    # two nodes of different rods at the same place, joined by string 0 (nodes 0, 1)
    nodes = s.nodes.copy()
    nodes[1] = nodes[0]
    with pytest.raises(StructureError, match=r"string 0 \(nodes 0, 1\): zero length"):
        base(nodes=nodes)


def test_duplicate_members():
    strings = base().strings.tolist()
    strings.append(strings[3][::-1])
    with pytest.raises(StructureError, match=rf"string 9 \(nodes {strings[3][1]}, {strings[3][0]}\): "
                                             r"duplicate of string 3"):
        base(strings=strings, rest_length=None)
    bars = base().bars.tolist() + [base().bars.tolist()[0]]
    with pytest.raises(StructureError, match=r"bar 3 .*duplicate of bar 0"):
        base(bars=bars)


def test_bad_nodes_and_member_arrays():
    with pytest.raises(StructureError, match=r"nodes: expected an \(n, 3\) array"):
        base(nodes=np.zeros((6, 2)))
    nodes = base().nodes.copy()
    nodes[3, 1] = np.nan
    with pytest.raises(StructureError, match=r"nodes: node 3 has a non-finite coordinate"):
        base(nodes=nodes)
    with pytest.raises(StructureError, match=r"bars: node indices must be integers"):
        base(bars=[[0, 4.5], [1, 5], [2, 3]])
    with pytest.raises(StructureError, match=r"strings: expected a list of \[a, b\] node pairs"):
        base(strings=[[0, 1, 2]])
    with pytest.raises(StructureError, match=r"bars: a structure needs at least one rod"):
        base(bars=[])


# ---------------------------------------------------------------------- masses and strings
@pytest.mark.parametrize("value", [0.0, -1.0, math.nan, math.inf])
def test_bad_bar_mass(value):
    with pytest.raises(StructureError, match=r"bar_mass of bar 1: .* kg is not positive and finite"):
        base(bar_mass=[1.0, value, 1.0])


def test_bar_mass_wrong_count():
    with pytest.raises(StructureError, match=r"bar_mass: expected a number or a list of 3 values \(one per bar\)"):
        base(bar_mass=[1.0, 2.0])


@pytest.mark.parametrize("value", [0.0, -5.0, math.nan, math.inf])
def test_bad_stiffness(value):
    k = np.full(9, 1000.0)
    k[7] = value
    s = base()
    a, b = s.strings[7]
    with pytest.raises(StructureError, match=rf"stiffness of string 7 \(nodes {a}, {b}\): .* N/m is not positive and finite"):
        base(stiffness=k)


@pytest.mark.parametrize("value", [-0.1, math.nan])
def test_bad_rest_length(value):
    rl = base().string_lengths.copy()
    rl[1] = value
    with pytest.raises(StructureError, match=r"rest_length of string 1 \(nodes .*\): .* m is negative or not finite"):
        base(rest_length=rl)


def test_rest_length_wrong_count():
    with pytest.raises(StructureError, match=r"rest_length: expected a number or a list of 9 values \(one per string\)"):
        base(rest_length=[1.0] * 8)


@pytest.mark.parametrize("value", [-1.0, math.inf])
def test_bad_damping(value):
    c = np.zeros(9)
    c[3] = value
    with pytest.raises(StructureError, match=r"damping of string 3 \(nodes .*\): .* N s/m is negative or not finite"):
        base(damping=c)


def test_zero_rest_length_and_damping_are_fine():
    s = base(rest_length=np.zeros(9), damping=np.zeros(9))
    assert np.all(s.rest_length == 0)


def test_bad_mass_points():
    with pytest.raises(StructureError, match=r"mass_points of bar 1: position 1.5 is not in \[0, 1\]"):
        base(mass_points=[None, ((0.0, 1.0), (1.5, 1.0)), None])
    with pytest.raises(StructureError, match=r"mass_points of bar 0: mass -1.0 kg is not positive"):
        base(mass_points=[((0.0, 1.0), (1.0, -1.0)), None, None])
    with pytest.raises(StructureError, match=r"mass_points of bar 2: all mass at one point"):
        base(mass_points=[None, None, ((0.5, 1.0), (0.5, 2.0))])
    with pytest.raises(StructureError, match=r"mass_points: expected 3 entries \(one per bar\)"):
        base(mass_points=[None])
    s = base(mass_points=[None, ((0.0, 1.0), (1.0, 3.0)), None])
    assert s.bar_mass[1] == 4.0
    np.testing.assert_allclose(s.com_fraction, [0.5, 0.75, 0.5])


def test_bad_gravity():
    with pytest.raises(StructureError, match=r"gravity: expected 3 finite numbers"):
        base(gravity=[0.0, -9.81])
    with pytest.raises(StructureError, match=r"gravity: expected 3 finite numbers"):
        base(gravity=[0.0, 0.0, math.nan])


# ---------------------------------------------------------------------- constraints
def test_both_ends_of_rod_constrained():
    a, c = base().bars[0]
    with pytest.raises(StructureError, match=rf"bar 0 \(nodes {a}, {c}\): both ends are constrained"):
        base(node_constraints={int(a): np.eye(3), int(c): [[0.0, 0.0, 1.0]]})


@pytest.mark.parametrize("D", [np.zeros((4, 3)), np.eye(2), np.zeros((0, 3)), np.ones((2, 3, 1))])
def test_constraint_matrix_bad_shape(D):
    with pytest.raises(StructureError, match=r"node_constraints of node 0: D must have shape \(p, 3\) with p in 1..3"):
        base(node_constraints={0: D})


@pytest.mark.parametrize("D", [[[1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]],
                               [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]]])
def test_constraint_matrix_bad_rank(D):
    p = len(D)
    with pytest.raises(StructureError, match=rf"node_constraints of node 0: D has {p} rows but rank {p - 1}"):
        base(node_constraints={0: D})


def test_constraint_matrix_non_finite():
    with pytest.raises(StructureError, match=r"node_constraints of node 0: D has non-finite entries"):
        base(node_constraints={0: [[math.nan, 0.0, 1.0]]})


def test_constraint_on_anchor_or_missing_node():
    with pytest.raises(StructureError, match=r"node_constraints: node 3 is on no rod.*anchors"):
        with_anchor(node_constraints={0: np.eye(3), 3: [[0.0, 0.0, 1.0]]})
    with pytest.raises(StructureError, match=r"node_constraints: node 9 does not exist \(there are 6 nodes\)"):
        base(node_constraints={9: [[0.0, 0.0, 1.0]]})
    with pytest.raises(StructureError, match=r"node_constraints: key 'x' is not a node index"):
        base(node_constraints={"x": [[0.0, 0.0, 1.0]]})


def test_constraint_ranks_accepted_and_string_keys():
    s = base(node_constraints={"0": [0.0, 0.0, 1.0], 1: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], 2: np.eye(3)})
    assert sorted(s.node_constraints) == [0, 1, 2]
    assert [s.node_constraints[i].shape for i in range(3)] == [(1, 3), (2, 3), (3, 3)]


# ---------------------------------------------------------------------- velocities
def rigid_velocities(s, omega=(0.3, -0.2, 0.5), v=(0.1, 0.0, -0.2)):
    """A rigid-body velocity field of the whole structure (keeps every rod length)."""
    return np.asarray(v) + np.cross(np.asarray(omega), s.nodes)


def test_velocities_that_stretch_a_rod():
    s = base()
    vel = rigid_velocities(s)
    base(velocities=vel)                      # a rigid motion is fine
    a, c = s.bars[2]
    vel[c] += 0.1 * (s.nodes[c] - s.nodes[a])
    with pytest.raises(StructureError, match=rf"velocities of bar 2 \(nodes {a}, {c}\): the rod would stretch"):
        base(velocities=vel)


def test_velocities_that_break_a_constraint():
    cons = {0: [[0.0, 0.0, 1.0]]}            # node 0 slides on a horizontal plane
    s = base()
    vel = rigid_velocities(s, omega=(0.0, 0.0, 0.4), v=(0.1, 0.2, 0.0))
    base(node_constraints=cons, velocities=vel)
    vel = rigid_velocities(s, omega=(0.0, 0.0, 0.4), v=(0.1, 0.2, 0.3))   # lifts node 0
    with pytest.raises(StructureError, match=r"velocities of node 0: breaks its constraint D v = 0"):
        base(node_constraints=cons, velocities=vel)


def test_velocities_that_move_an_anchor():
    s = tg.pinned_rod()
    vel = np.zeros_like(s.nodes)
    vel[1] = [0.0, 0.3, 0.0]                  # rod tip moves perpendicular to the rod: fine
    s.replace(velocities=vel)
    vel[3] = [0.0, 0.0, 0.1]
    with pytest.raises(StructureError, match=r"velocities of node 3: node is a fixed anchor"):
        s.replace(velocities=vel)


def test_velocities_bad_shape_or_value():
    with pytest.raises(StructureError, match=r"velocities: expected shape \(6, 3\)"):
        base(velocities=np.zeros((5, 3)))
    vel = np.zeros((6, 3))
    vel[2, 0] = math.inf
    with pytest.raises(StructureError, match=r"velocities: non-finite entries"):
        base(velocities=vel)


def test_replace_revalidates():
    s = tg.prism(3)
    with pytest.raises(StructureError, match=r"bar_mass of bar 0"):
        s.replace(bar_mass=-1.0)
    s2 = s.replace(damping=2.0)
    assert np.all(s2.damping == 2.0) and np.all(s.damping == 0.0)


# ---------------------------------------------------------------------- JSON
def assert_same_structure(a: Structure, b: Structure):
    for f in ("nodes", "bars", "strings", "bar_mass", "stiffness", "rest_length", "damping", "velocities"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.shape == y.shape and x.dtype.kind == y.dtype.kind and np.array_equal(x, y), f
    assert (a.gravity is None) == (b.gravity is None)
    if a.gravity is not None:
        assert np.array_equal(a.gravity, b.gravity)
    assert sorted(a.node_constraints) == sorted(b.node_constraints)
    for k in a.node_constraints:
        assert np.array_equal(a.node_constraints[k], b.node_constraints[k])
    assert a.mass_points == b.mass_points
    assert a.name == b.name


def rich_structure():
    """Per-item masses, stiffness, damping, gravity, a constraint, velocities, lumped masses."""
    s = tg.prism(3)
    rng = np.random.default_rng(0)
    vel = np.asarray((0.1, -0.2, 0.05)) + np.cross(np.asarray((0.0, 0.0, 0.7)), s.nodes)
    a = s.bars[0, 0]
    vel -= vel[a] * np.array([0, 0, 1.0])     # keep node a on its plane (v_z = 0 is already true)
    return s.replace(bar_mass=[1.0, 2.0, 3.0], stiffness=rng.uniform(500, 1500, 9),
                     damping=rng.uniform(0, 3, 9), gravity=(0.0, 0.0, -9.81),
                     node_constraints={int(a): [[0.0, 0.0, 1.0]]}, velocities=vel,
                     mass_points=[None, ((0.0, 0.5), (0.3, 1.0), (1.0, 0.5)), None],
                     name="rich")


@pytest.mark.parametrize("factory", [rich_structure, tg.constrained_prism, tg.pinned_rod, tg.icosahedron,
                                     lambda: tg.tower(2)])
def test_json_round_trip(factory, tmp_path):
    s = factory()
    path = tmp_path / "s.json"
    save_json(s, path)
    t = load_json(path)
    assert_same_structure(s, t)
    # the file is plain JSON with the documented keys
    d = json.loads(path.read_text())
    assert {"nodes", "bars", "strings", "bar_mass", "stiffness", "rest_length"} <= set(d)
    # and a second round trip is byte-identical
    save_json(t, tmp_path / "t.json")
    assert (tmp_path / "t.json").read_text() == path.read_text()


def test_json_minimal_keys_and_scalars(tmp_path):
    s = base()
    d = {"nodes": s.nodes.tolist(), "bars": s.bars.tolist(), "strings": s.strings.tolist(),
         "bar_mass": 2.0, "stiffness": 800.0, "rest_length": (0.9 * s.string_lengths).tolist(),
         "damping": 0.5, "gravity": [0, 0, -9.81], "node_constraints": {"0": [[0, 0, 1]]},
         "velocities": np.zeros((6, 3)).tolist()}
    (tmp_path / "m.json").write_text(json.dumps(d))
    t = load_json(tmp_path / "m.json")
    assert np.all(t.bar_mass == 2.0) and np.all(t.stiffness == 800.0) and np.all(t.damping == 0.5)
    assert t.node_constraints[0].shape == (1, 3)


def test_json_errors(tmp_path):
    d = tg.prism(3).to_dict()
    bad = dict(d, colour="red")
    (tmp_path / "u.json").write_text(json.dumps(bad))
    with pytest.raises(StructureError, match=r"unknown key\(s\) \['colour'\]"):
        load_json(tmp_path / "u.json")
    missing = {k: v for k, v in d.items() if k != "bars"}
    with pytest.raises(StructureError, match=r"missing required key 'bars'"):
        from_dict(missing)
    (tmp_path / "b.json").write_text('{"nodes": [[0, 0, 0], }')
    with pytest.raises(StructureError, match=r"b.json: not valid JSON"):
        load_json(tmp_path / "b.json")
    (tmp_path / "l.json").write_text("[1, 2, 3]")
    with pytest.raises(StructureError, match=r"l.json: top level must be a JSON object"):
        load_json(tmp_path / "l.json")
    # a validation error inside a file names the item
    d2 = dict(d, stiffness=[1000.0] * 8 + [-1.0])
    with pytest.raises(StructureError, match=r"stiffness\[8\] \(string 8\): -1.0 is below the accepted minimum"):
        from_dict(d2)


def test_load_structure_accepts_names_paths_and_objects(tmp_path):
    s = tg.constrained_prism()
    assert load_structure(s) is s
    p = tmp_path / "c.json"
    save_json(s, p)
    assert_same_structure(load_structure(p), s)
    assert_same_structure(load_structure(str(p)), s)
    other = tmp_path / "no_suffix"
    save_json(s, other)
    assert_same_structure(load_structure(other), s)
    t = load_structure("prism3")
    assert isinstance(t, Structure) and t.name == "prism3" and t.n_bars == 3
    assert load_structure("icosahedron").n_strings == 24
    with pytest.raises(StructureError, match=r"unknown structure 'no_such_thing'"):
        load_structure("no_such_thing")
    with pytest.raises(ValueError, match=r"structure: expected a Structure, a builder name, a JSON path or an MJCF"):
        load_structure(42)
    with pytest.raises((FileNotFoundError, StructureError)):
        load_structure(str(tmp_path / "missing.json"))
