"""The numba packed layout, the flag bits and the nominal values are generated from the parameter
table (tensegrity_gym.core.param_table): each row lands in a slot of its own, the kernels read
it there, and a row added to a copy of the table gets its slot, flag and nominal value with no
other edit (the worked example of docs/adding_a_parameter.md, taken from the doc itself)."""
import dataclasses
import pathlib
import re

import numpy as np
import pytest

from oracle_numpy import accelerations as oracle_accelerations
from tensegrity_gym.backends.numba import layout, pack
from tensegrity_gym.backends.numba.api import accelerations as numba_accelerations
from tensegrity_gym.core import builders, param_table as pt, params as core_params
from tensegrity_gym.core.model import compile_model, initial_state

DOC = pathlib.Path(__file__).resolve().parents[1] / "docs" / "adding_a_parameter.md"
#: the kernels' flag bits that are not a parameter's
OTHER_BITS = (layout._RK4, layout._FD, layout._EXT, layout._PROJ, layout._CONS, layout._L0DEF)


def _model():
    """A damped, gravity-loaded prism with node drag and one pinned node (every physics row non-zero)."""
    return compile_model(builders.constrained_prism(damping=2.0), node_damping=0.3)


def _check_layout(packed, table):
    """Each non-own physics row has one slot of its own inside its block; each skip_zero row one
    flag bit of its own, clear of the other bits and of the chunk count."""
    rows = [r for r in pt.physics_rows(table) if r.field not in layout.OWN_PACKING]
    assert sorted(f for ax in pt.ITEM_AXES for f in packed[ax]) == sorted(r.field for r in rows)
    for ax, fixed, stride in (("rod", layout.ROD_FIXED, packed["rod_stride"]),
                              ("string", layout.STR_FIXED, packed["string_stride"])):
        slots = sorted(packed[ax].values())
        assert slots == list(range(fixed, stride)), ax       # distinct, contiguous, after the fixed slots
    assert sorted(packed["node"].values()) == list(range(packed["node_rows"]))
    assert tuple(packed["bits"]) == pt.skipped_fields(table)
    bits = list(packed["bits"].values()) + list(OTHER_BITS)
    assert len(set(bits)) == len(bits) and all(b & (b - 1) == 0 and b < 1 << layout._CHUNK_SHIFT for b in bits)


def test_the_layout_is_the_tables():
    _check_layout(layout.PACKED, None)
    assert (layout._ROD, layout._STR, layout._NODE_ROWS) == (layout.PACKED["rod_stride"],
                                                             layout.PACKED["string_stride"],
                                                             layout.PACKED["node_rows"])
    # every physics row is packed by the table's layout or by the backend's own packing, never dropped
    with pytest.raises(ValueError, match="axis one of"):
        layout.packed_layout(pt.PARAMS + (pt.ParamSpec("wind", "physics", "wind", "vector", "m/s", "finite", "doc",
                                                        nominal=0.0),))


def _distinct(model, P=2):
    """A Params of P copies whose every table row holds values no other row or copy holds."""
    p = core_params.default_params(model, P)
    vals = {}
    for i, r in enumerate(pt.physics_rows()):
        if r.field in layout.OWN_PACKING:
            continue
        a = np.array(getattr(p, r.field))
        a = (1.0 + i) + 0.01 * np.arange(a[0].size) + 0.001 * np.arange(P)[:, None]
        vals[r.field] = np.where(model.active, 0.0, a) if r.write == "elastic" else a
    return p.replace(**vals), vals


def test_pack_puts_each_row_where_the_kernels_copy_it():
    """Packed per copy, each table row reads back from its slot (read_packed), and the loop
    driver's lane copy (the kernels' readback, _lane_physics) carries exactly those slots."""
    from tensegrity_gym.backends.numba.driver import _lane_physics
    model = _model()
    p, vals = _distinct(model)
    pk = pack._pack_params(model, p)
    k, m, n = model.n_bars, model.n_strings, model.n_nodes
    L = layout._layout(k, m, n)
    for b in range(2):
        buf = pk.bufs[b]
        for fld, v in vals.items():
            assert np.array_equal(pack.read_packed(buf, model, fld), v[b]), fld
        PC = np.full((L[9], 1), np.nan)
        _lane_physics(PC, np.zeros((n, 3, 1)), buf, L, k, m, n, 0)
        for fld, v in vals.items():
            got = pack.read_packed(PC[:, 0], model, fld)
            assert np.array_equal(got, v[b]), fld
    # the flag bits: a skipped field's bit is set exactly where the field may be non-zero
    for fld, bit in layout.PACKED["bits"].items():
        assert pack._physics_flags(model, p) & bit
        zero = p.replace(**{fld: 0.0})
        assert not pack._physics_flags(model, zero) & bit, fld


def test_the_kernels_read_each_row():
    """Per row: a copy with that row changed gives the NumPy oracle's accelerations (the law reads
    the row's slot), and differs from a copy without the change."""
    model = _model()
    st = initial_state(model, 2)
    rng = np.random.default_rng(0)
    q, qd = st.q, st.qd + 0.05 * rng.standard_normal(st.qd.shape)
    base = core_params.default_params(model, 2)
    for r in pt.physics_rows():
        if r.write == "derived" or r.axis == "anchor":
            continue
        a = np.array(getattr(base, r.field))
        a[1] = a[1] * 1.5 + (0.7 if r.write != "elastic" else 0.0)
        if r.write == "elastic":
            a[1] = np.where(model.active, 0.0, a[1])
        p = base.replace(**{r.field: a})
        got = numba_accelerations(model, q, qd, params=p)
        want = oracle_accelerations(model, q, qd, params=p)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-10 * np.abs(want).max(), err_msg=r.field)
        ref = numba_accelerations(model, q, qd, params=base)
        assert np.array_equal(got[0], ref[0]) and not np.array_equal(got[1], ref[1]), r.field


def _doc_row():
    """The row of the worked example, as docs/adding_a_parameter.md shows it."""
    text = DOC.read_text()
    block = re.search(r"```python\n(ParamSpec\(\"rod_drag\".*?)\n```", text, re.S)
    assert block, "docs/adding_a_parameter.md: the worked example's row is missing"
    return eval(block.group(1).rstrip(","), {"ParamSpec": pt.ParamSpec})


def test_a_new_row_regenerates_layout_flags_and_nominal():
    """The doc's example: one row added to a copy of the table gets a slot in each rod's block, a
    flag bit, its nominal value and the Params views; a buffer packed with it holds each copy's
    value where a law reading the slot finds it; the module's own layout is untouched."""
    row = _doc_row()
    table = pt.PARAMS + (row,)
    packed = layout.packed_layout(table)
    _check_layout(packed, table)
    assert packed["rod"][row.field] == layout.PACKED["rod_stride"]
    assert packed["rod_stride"] == layout.PACKED["rod_stride"] + 1
    assert row.field in packed["bits"] and row.field in pt.skipped_fields(table)
    assert pt.params_fields(table)[row.field] == ("rod", row.unit, row.valid)
    model = _model()
    nominal = core_params.nominal_values(model, {f: getattr(model, f) for f in core_params.PARAM_FIELDS}, table)
    assert np.array_equal(nominal[row.field], np.full(model.n_bars, row.nominal))
    # a copy set holding the new field, packed with the new layout
    base = core_params.default_params(model, 2)
    drag = np.array([[0.0, 0.0, 0.0], [0.4, 0.5, 0.6]])
    fields = {f: getattr(base, f) for f in core_params.PARAM_FIELDS}
    rows = type("Rows", (), {**fields, "W0": base.W0, row.field: drag,
                             "may_be_nonzero": lambda self, f: bool(np.any(getattr(self, f) != 0))})()
    k, m, n = model.n_bars, model.n_strings, model.n_nodes
    L = layout._layout(k, m, n, packed["rod_stride"], packed["string_stride"], packed["node_rows"])
    for b in range(2):
        buf = np.zeros(L[9])
        pack._fill_physics(buf, model, rows, b, packed)
        law = np.array([-buf[L[0] + packed["rod_stride"] * j + packed["rod"][row.field]] for j in range(k)])
        assert np.array_equal(law, -drag[b])                                  # the law sees each copy's value
        for fld in core_params.PARAM_FIELDS:                                 # and the other rows are where they were
            if fld in packed["rod"] or fld in packed["string"] or fld in packed["node"]:
                assert np.array_equal(pack.read_packed(buf, model, fld, packed), getattr(base, fld)[b]), fld
    assert pack._physics_flags(model, rows, packed) & packed["bits"][row.field]
    # the module's table and layout are untouched
    assert row.field not in layout.PACKED["rod"] and row not in pt.PARAMS
    assert dataclasses.replace(row, skip_zero=False).field not in pt.skipped_fields()


def test_cached_kernels_see_an_edit_of_the_table():
    """The kernels freeze the layout's constants; the numba cache guard stamps each cached kernel
    with the digest of its module's closure, and the layout module imports the parameter table,
    so an edit of the table recompiles every kernel that reads the layout."""
    from tensegrity_gym.backends.numba import cache_guard
    table = cache_guard.PACKAGE / "core" / "param_table.py"
    for mod in ("layout.py", "equations.py", "driver.py", "entries.py"):
        assert table in cache_guard.closure(cache_guard.PACKAGE / "backends" / "numba" / mod), mod
