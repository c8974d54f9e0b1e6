"""Malformed structure files: every case ends in a StructureError whose message
names the key, the index and the value; valid files load exactly as before.

CASES lists the hand-written cases (a change to the valid 3-prism's JSON, or raw file text/bytes)
with the message each must give; the hypothesis tests below mutate valid structures at random
and assert "StructureError or a valid, finite structure", nothing else."""
from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

import tensegrity_gym as tg
from tensegrity_gym import Structure, StructureError, from_dict, load_json
from tensegrity_gym.core.structure import SCHEMA_PATH, schema, validate_dict

BASE = json.loads(json.dumps(tg.prism(3).to_dict()))          # a valid file's contents
PINNED = json.loads(json.dumps(tg.pinned_rod().to_dict()))    # with gravity, constraint, anchors
LUMPED = dict(BASE, mass_points=[[[0.0, 0.5], [1.0, 0.5]], None, None])


def _ragged_nodes():
    d = copy.deepcopy(BASE)
    d["nodes"][4] = d["nodes"][4][:2]
    return d


def _set(path, value, base=BASE):
    d = copy.deepcopy(base)
    target = d
    for p in path[:-1]:
        target = target[p]
    target[path[-1]] = value
    return d


# (id, file contents: dict, str or bytes, regex the message must match)
CASES = [
    # wrong types: no string-as-number, no bool-as-number, no null, no objects
    ("stiffness-string", dict(BASE, stiffness="1000"), r'stiffness: expected a number or a list, got the string "1000"'),
    ("stiffness-item-string", _set(["stiffness", 3], "1000"), r'stiffness\[3\] \(string 3\): expected a number, got the string "1000"'),
    ("bar_mass-true", dict(BASE, bar_mass=True), r"bar_mass: expected a number or a list, got true"),
    ("bar_mass-item-false", _set(["bar_mass", 1], False), r"bar_mass\[1\] \(bar 1\): expected a number, got false"),
    ("bar-index-true", _set(["bars", 0, 1], True), r"bars\[0\]\[1\] \(bar 0\): expected an integer, got true"),
    ("string-index-true", _set(["strings", 2, 0], True), r"strings\[2\]\[0\] \(string 2\): expected an integer, got true"),
    ("coordinate-string", _set(["nodes", 2, 1], "0.5"), r'nodes\[2\]\[1\] \(node 2\): expected a number, got the string "0.5"'),
    ("coordinate-null", _set(["nodes", 0, 0], None), r"nodes\[0\]\[0\] \(node 0\): expected a number, got null"),
    ("coordinate-list", _set(["nodes", 0, 0], [1]), r"nodes\[0\]\[0\] \(node 0\): expected a number, got a list of 1 item"),
    ("index-float", _set(["bars", 1, 0], 1.5), r"bars\[1\]\[0\] \(bar 1\): expected an integer, got 1.5"),
    ("index-string", _set(["strings", 0, 1], "1"), r'strings\[0\]\[1\] \(string 0\): expected an integer, got the string "1"'),
    ("damping-string", dict(BASE, damping="0"), r'damping: expected a number or a list, got the string "0"'),
    ("damping-null", dict(BASE, damping=None), r"damping: expected a number or a list, got null"),
    ("rest_length-string", _set(["rest_length", 8], "1"), r'rest_length\[8\] \(string 8\): expected a number, got the string "1"'),
    ("gravity-string", dict(BASE, gravity="down"), r'gravity: expected null or a list, got the string "down"'),
    ("gravity-two", dict(BASE, gravity=[0, -9.81]), r"gravity: expected 3 items, got a list of 2 items"),
    ("gravity-item-bool", dict(BASE, gravity=[0, 0, True]), r"gravity\[2\]: expected a number, got true"),
    ("name-number", dict(BASE, name=5), r"name: expected a string, got 5"),
    ("velocities-string", dict(BASE, velocities="0"), r'velocities: expected null or a list, got the string "0"'),
    # shapes: ragged, wrong pair lengths, empty
    ("nodes-ragged", _ragged_nodes(), r"nodes\[4\] \(node 4\): expected 3 items, got a list of 2 items"),
    ("nodes-4d", _set(["nodes", 1], [0, 0, 0, 1]), r"nodes\[1\] \(node 1\): expected 3 items, got a list of 4 items"),
    ("nodes-flat", dict(BASE, nodes=[0.0, 1.0, 2.0]), r"nodes\[0\] \(node 0\): expected a list, got 0.0"),
    ("nodes-empty", dict(BASE, nodes=[]), r"nodes: expected at least 1 item, got a list of 0 items"),
    ("nodes-object", dict(BASE, nodes={"0": [0, 0, 0]}), r"nodes: expected a list, got an object with 1 key"),
    ("bars-triple", _set(["bars", 2], [0, 1, 2]), r"bars\[2\] \(bar 2\): expected 2 items, got a list of 3 items"),
    ("bars-empty", dict(BASE, bars=[]), r"bars: expected at least 1 item, got a list of 0 items"),
    ("strings-number", dict(BASE, strings=5), r"strings: expected a list, got 5"),
    ("velocities-ragged", dict(BASE, velocities=[[0, 0, 0]] * 5 + [[0, 0]]), r"velocities\[5\] \(node 5\): expected 3 items"),
    ("velocities-count", dict(BASE, velocities=[[0, 0, 0]] * 5), r"velocities: expected shape \(6, 3\), got \(5, 3\)"),
    ("stiffness-count", dict(BASE, stiffness=[1000.0] * 8), r"stiffness: expected a number or a list of 9 values \(one per string\)"),
    ("bar_mass-count", dict(BASE, bar_mass=[1.0, 1.0]), r"bar_mass: expected a number or a list of 3 values \(one per bar\)"),
    ("bar_mass-nested", dict(BASE, bar_mass=[[1.0], [1.0], [1.0]]), r"bar_mass\[0\] \(bar 0\): expected a number, got a list of 1 item"),
    # node_constraints and mass_points given in the wrong form
    ("node_constraints-list", dict(PINNED, node_constraints=[[1, 0, 0]]), r"node_constraints: expected null or an object, got a list of 1 item"),
    ("node_constraints-key", dict(PINNED, node_constraints={"x": [[1, 0, 0]]}), r"node_constraints\['x'\] \(node x\): key 'x' is not a node index"),
    ("node_constraints-negative-key", dict(PINNED, node_constraints={"-1": [[1, 0, 0]]}), r"key '-1' is not a node index"),
    ("node_constraints-four-rows", dict(PINNED, node_constraints={"0": [[1, 0, 0]] * 4}), r"node_constraints\['0'\] \(node 0\): expected 1 to 3 items, got a list of 4 items"),
    ("node_constraints-row-short", dict(PINNED, node_constraints={"0": [[1, 0]]}), r"node_constraints\['0'\]\[0\] \(node 0\): expected 3 items, got a list of 2 items"),
    ("node_constraints-string", dict(PINNED, node_constraints={"0": "pinned"}), r"node_constraints\['0'\] \(node 0\): expected a list, got the string \"pinned\""),
    ("node_constraints-rank", dict(PINNED, node_constraints={"0": [[1, 0, 0], [2, 0, 0]]}), r"node_constraints of node 0: D has 2 rows but rank 1"),
    ("node_constraints-anchor", dict(PINNED, node_constraints={"3": [[1, 0, 0]]}), r"node_constraints: node 3 is on no rod"),
    ("node_constraints-missing-node", dict(PINNED, node_constraints={"99": [[1, 0, 0]]}), r"node_constraints: node 99 does not exist \(there are 5 nodes\)"),
    ("mass_points-5", dict(BASE, mass_points=5), r"mass_points: expected null or a list, got 5"),
    ("mass_points-count", dict(BASE, mass_points=[None, None]), r"mass_points: expected 3 entries \(one per bar\), got 2"),
    ("mass_points-entry-number", dict(BASE, mass_points=[0.5, None, None]), r"mass_points\[0\] \(bar 0\): expected null or a list, got 0.5"),
    ("mass_points-mu", _set(["mass_points", 0, 1, 0], 1.5, LUMPED), r"mass_points\[0\]\[1\]\[0\] \(bar 0\): 1.5 is above the accepted maximum 1"),
    ("mass_points-mass-bool", _set(["mass_points", 0, 0, 1], True, LUMPED), r"mass_points\[0\]\[0\]\[1\] \(bar 0\): expected a number, got true"),
    ("mass_points-one-point", dict(BASE, mass_points=[[[0.5, 1.0]], None, None]), r"mass_points of bar 0: all mass at one point"),
    ("mass_points-empty", dict(BASE, mass_points=[[], None, None]), r"mass_points\[0\] \(bar 0\): expected at least 1 item, got a list of 0 items"),
    # non-finite and out-of-range values
    ("node-huge-int", _set(["nodes", 0, 0], 10 ** 400), r"nodes\[0\]\[0\] \(node 0\): an integer of 401 digits \(1000...00\) is above the accepted maximum 1e\+06"),
    ("index-huge-int", _set(["bars", 0, 0], 10 ** 400), r"bars\[0\]\[0\] \(bar 0\): an integer of 401 digits .* is above the accepted maximum 1e\+09"),
    ("stiffness-1e300", dict(BASE, stiffness=1e300), r"stiffness: 1e\+300 is above the accepted maximum 1e\+12"),
    ("stiffness-zero", dict(BASE, stiffness=0), r"stiffness: 0 is below the accepted minimum 1e-06"),
    ("stiffness-negative", _set(["stiffness", 8], -1.0), r"stiffness\[8\] \(string 8\): -1.0 is below the accepted minimum 1e-06"),
    ("bar_mass-1e-300", dict(BASE, bar_mass=1e-300), r"bar_mass: 1e-300 is below the accepted minimum 1e-09"),
    ("bar_mass-zero", _set(["bar_mass", 2], 0.0), r"bar_mass\[2\] \(bar 2\): 0.0 is below the accepted minimum 1e-09"),
    ("bar_mass-1e300", dict(BASE, bar_mass=1e300), r"bar_mass: 1e\+300 is above the accepted maximum 1e\+09"),
    ("rest_length-negative", _set(["rest_length", 0], -0.1), r"rest_length\[0\] \(string 0\): -0.1 is below the accepted minimum 0"),
    ("damping-negative", dict(BASE, damping=-1), r"damping: -1 is below the accepted minimum 0"),
    ("damping-huge", dict(BASE, damping=1e10), r"damping: 1e\+10 is above the accepted maximum 1e\+09"),
    ("node-1e7", _set(["nodes", 3, 2], 1e7), r"nodes\[3\]\[2\] \(node 3\): 1e\+07 is above the accepted maximum 1e\+06"),
    ("gravity-huge", dict(BASE, gravity=[0, 0, -1e5]), r"gravity\[2\]: -100000 is below the accepted minimum -10000"),
    ("velocity-huge", dict(PINNED, velocities=[[0, 0, 0], [0, 1e5, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]), r"velocities\[1\]\[1\] \(node 1\): 100000.0 is above the accepted maximum 10000"),
    ("nan-in-dict", _set(["nodes", 0, 0], float("nan")), r"nodes\[0\]\[0\] \(node 0\): expected a finite number, got nan"),
    ("inf-in-dict", dict(BASE, stiffness=float("inf")), r"stiffness: expected a finite number, got inf"),
    # combinations: in range one by one, absurd together (stable step below 1e-9 s)
    ("stiff-and-light", dict(BASE, stiffness=1e12, bar_mass=1e-9), r"stiffness of string \d+ \(nodes \d+, \d+\): 1e\+12 N/m with effective end masses .* allows an explicit step of only .* s, below the accepted 1e-09 s"),
    ("damped-and-light", dict(BASE, damping=1e9, bar_mass=1e-9), r"damping of string \d+ .*damping rate .* below the accepted 1e-09 s"),
    # topology (checks across keys, with the schema's description cited)
    ("missing-node", _set(["strings", 0, 1], 6), r"string 0 \(nodes 0, 6\): node 6 does not exist \(there are 6 nodes\) \(schema, strings:"),
    ("node-on-two-rods", dict(BASE, bars=[[0, 4], [4, 5], [2, 3]]), r"bar 1 \(nodes 4, 5\): node 4 is already on bar 0"),
    ("zero-length-rod", _set(["nodes", 4], BASE["nodes"][0]), r"bar 0 \(nodes 0, 4\): zero length"),
    ("duplicate-string", dict(BASE, strings=BASE["strings"] + [BASE["strings"][0]]), r"string 9 .*duplicate of string 0"),
    ("missing-bars", {k: v for k, v in BASE.items() if k != "bars"}, r"missing required key 'bars'"),
    ("unknown-key", dict(BASE, colour="red"), r"unknown key\(s\) \['colour'\]"),
    # the file itself
    ("not-json", "{nodes: [", r"f.json: not valid JSON"),
    ("empty-file", "", r"f.json: not valid JSON"),
    ("top-level-list", "[1, 2, 3]", r"f.json: top level must be a JSON object"),
    ("NaN-literal", json.dumps(BASE).replace('"bar_mass": [', '"bar_mass": [NaN, '), r"not valid JSON \(NaN is not a JSON number"),
    ("Infinity-literal", json.dumps(BASE).replace('"bar_mass": [', '"bar_mass": [-Infinity, '), r"not valid JSON \(-Infinity is not a JSON number"),
    ("1e400", json.dumps(BASE).replace('"bar_mass": [', '"bar_mass": [1e400, '), r"not valid JSON \(the number 1e400 is too large for a double"),
    ("duplicate-key", json.dumps(BASE)[:-1] + ', "bars": [[0, 4]]}', r"not valid JSON \(duplicate key 'bars'"),
    ("invalid-utf8", b'{"name": "\xff\xfe", "nodes": []}', r"f.json: not UTF-8 text \(byte 0xff at offset 10\)"),
    ("latin1", '{"name": "caf\u00e9"}'.encode("latin-1"), r"not UTF-8 text \(byte 0xe9"),
    ("deep-nesting", "[" * 100000 + "]" * 100000, r"f.json: not valid JSON"),
]
IDS = [c[0] for c in CASES]
DICT_ONLY = {"nan-in-dict", "inf-in-dict"}
assert len(set(IDS)) == len(IDS)


def _write(tmp_path, contents):
    p = tmp_path / "f.json"
    if isinstance(contents, bytes):
        p.write_bytes(contents)
    elif isinstance(contents, str):
        p.write_text(contents, encoding="utf-8")
    else:
        p.write_text(json.dumps(contents, allow_nan=True), encoding="utf-8")
    return p


@pytest.mark.parametrize("case_id, contents, pattern", CASES, ids=IDS)
def test_malformed_file_gives_clear_error(tmp_path, case_id, contents, pattern):
    if case_id not in DICT_ONLY:        # JSON has no NaN/Infinity: those two are dict-only cases
        p = _write(tmp_path, contents)
        with pytest.raises(StructureError, match=pattern) as e:
            load_json(p)
        assert "\n" not in str(e.value)
    if isinstance(contents, dict):          # the same message from a dict (no file)
        with pytest.raises(StructureError, match=pattern.replace("f.json: ", "")):
            from_dict(contents)


def test_directory_and_unreadable(tmp_path):
    with pytest.raises(StructureError, match=r"is a directory, not a structure file"):
        load_json(tmp_path)
    with pytest.raises(FileNotFoundError):
        load_json(tmp_path / "missing.json")


def test_schema_messages_cite_the_description():
    with pytest.raises(StructureError) as e:
        from_dict(dict(BASE, stiffness="1000"))
    assert schema()["properties"]["stiffness"]["description"] in str(e.value)


def test_python_constructor_rejects_the_same():
    """The Structure constructor (Python API) applies the type and range checks too."""
    s = tg.prism(3)
    for change, pattern in [(dict(stiffness="1000"), r"stiffness: expected a number, got the string"),
                            (dict(bar_mass=[1.0, True, 1.0]), r"bar_mass\[1\] \(bar 1\): expected a number, got true"),
                            (dict(bar_mass=1e-300), r"bar_mass\[0\] \(bar 0\): 1e-300 kg is outside the accepted range"),
                            (dict(stiffness=1e300), r"stiffness\[0\] \(string 0\): 1e\+300 N/m is outside"),
                            (dict(nodes=[[0, 0, 0], [1, 0]]), r"nodes\[1\] \(node 1\): ragged list: expected a list of 3 items like item 0, got a list of 2 items"),
                            (dict(node_constraints=[[0, 0, 1]]), r"node_constraints: expected an object"),
                            (dict(mass_points=5), r"mass_points: expected a list with one entry per bar"),
                            (dict(gravity=np.array([False, False, True])), r"gravity\[0\]: expected a number, got false"),
                            (dict(nodes=np.array([["0", "0", "0"]] * 6)), r"nodes\[0\]\[0\] \(node 0\): expected a number, got the string \"0\"")]:
        with pytest.raises(StructureError, match=pattern):
            s.replace(**change)


@pytest.mark.parametrize("name", sorted(tg.core.builders.BUILDERS))
def test_valid_structures_load_unchanged(tmp_path, name):
    """Nothing valid changes: every built-in structure passes the schema and round-trips exactly."""
    s = tg.build(name)
    d = json.loads(json.dumps(s.to_dict()))
    validate_dict(d)
    p = tmp_path / "s.json"
    tg.save_json(s, p)
    t = load_json(p)
    assert t.to_dict() == s.to_dict()


def test_readme_limits_are_the_schema():
    """The accepted ranges the module docstring states are the schema's."""
    d = schema()["$defs"]
    assert (d["mass"]["minimum"], d["mass"]["maximum"]) == (1e-9, 1e9)
    assert (d["stiffness"]["minimum"], d["stiffness"]["maximum"]) == (1e-6, 1e12)
    assert d["coordinate"]["maximum"] == 1e6 and d["damping"]["maximum"] == 1e9


def test_schema_is_valid_json_schema_and_agrees_with_jsonschema():
    jsonschema = pytest.importorskip("jsonschema")
    sch = json.loads(SCHEMA_PATH.read_text())
    jsonschema.Draft202012Validator.check_schema(sch)
    v = jsonschema.Draft202012Validator(sch)
    for case_id, contents, _ in CASES:
        if not isinstance(contents, dict) or any(isinstance(x, float) and not math.isfinite(x)
                                                 for x in _leaves(contents)):
            continue
        ours = _schema_ok(contents)
        theirs = v.is_valid(contents)
        assert ours == theirs, case_id
    for name in tg.core.builders.BUILDERS:
        assert v.is_valid(json.loads(json.dumps(tg.build(name).to_dict())))


def _leaves(x):
    if isinstance(x, dict):
        for v in x.values():
            yield from _leaves(v)
    elif isinstance(x, list):
        for v in x:
            yield from _leaves(v)
    else:
        yield x


def _schema_ok(d) -> bool:
    try:
        validate_dict(d)
        return True
    except StructureError:
        return False


# ---------------------------------------------------------------------- property-based
_junk = st.one_of(st.none(), st.booleans(), st.integers(-10 ** 30, 10 ** 30), st.text(max_size=5),
                  st.floats(allow_nan=True, allow_infinity=True), st.lists(st.integers(-3, 9), max_size=4),
                  st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


def _paths(x, prefix=()):
    yield prefix
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _paths(v, prefix + (i,))


def _assert_clear_or_finite(d):
    try:
        s = from_dict(d)
    except StructureError as e:
        msg = str(e)
        assert msg and "\n" not in msg and "Traceback" not in msg
        return
    for arr in (s.nodes, s.bar_mass, s.stiffness, s.rest_length, s.damping, s.velocities):
        assert np.all(np.isfinite(arr))
    # a structure that loads gives finite accelerations
    from tensegrity_gym.core.model import compile_model, initial_state
    m = compile_model(s)
    st0 = initial_state(m)
    assert np.all(np.isfinite(tg.physics.accelerations(m, st0.q, st0.qd)))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(base=st.sampled_from([BASE, PINNED, LUMPED]), data=st.data(), junk=_junk)
def test_random_replacement_gives_error_or_valid_structure(base, data, junk):
    """Replace any value anywhere in a valid structure by junk: a StructureError or a valid one."""
    d = copy.deepcopy(base)
    paths = [p for p in _paths(d) if p]
    path = data.draw(st.sampled_from(paths))
    target = d
    for p in path[:-1]:
        target = target[p]
    target[path[-1]] = junk
    _assert_clear_or_finite(d)


@settings(max_examples=60, deadline=None)
@given(data=st.data(), scale=st.sampled_from([1e-300, 1e-12, 1e-9, 1e-3, 1e3, 1e9, 1e12, 1e300]))
def test_random_scaling_gives_error_or_valid_structure(data, scale):
    """Scale one physical quantity by an extreme factor: an error naming it, or a finite structure."""
    key = data.draw(st.sampled_from(["bar_mass", "stiffness", "damping", "rest_length", "nodes", "gravity"]))
    d = copy.deepcopy(PINNED)
    d[key] = (np.asarray(d[key], float) * scale + (1.0 if key == "damping" else 0.0) * scale).tolist()
    _assert_clear_or_finite(d)


@settings(max_examples=60, deadline=None)
@given(text=st.one_of(st.text(max_size=60), st.binary(max_size=60).map(lambda b: b.decode("latin-1")),
                      st.sampled_from([json.dumps(BASE)]).flatmap(
                          lambda s: st.integers(0, len(s) - 1).map(lambda i: s[:i]))))
def test_random_text_gives_error_or_structure(tmp_path_factory, text):
    p = tmp_path_factory.mktemp("h") / "r.json"
    p.write_text(text, encoding="utf-8")
    try:
        s = load_json(p)
    except StructureError as e:
        assert "\n" not in str(e)
    else:
        assert isinstance(s, Structure)
