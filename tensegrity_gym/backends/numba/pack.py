"""Packing for the numba backend: a model, or a :class:`~tensegrity_gym.core.params.Params`,
into ONE float64 buffer (integers as int64 bit patterns, then the serial scratch; see
:func:`.layout._layout`), cached by ``id`` and dropped when the model or params is garbage
collected (every array argument of a numba call costs ~0.1 us at the boundary, so the kernels
index flat buffers with computed offsets instead); the flag bits of a call; the conversion of
inputs at the kernel boundary.
"""
from __future__ import annotations

import weakref

import numpy as np

from ...core.integrators import fixed_step_name
from .layout import _CONS, _PROJ, _RK4, _ROD, _STR, PACKED, _layout, _soa_width

_CACHE: dict = {}
#: the kernels' flag bits of each fixed-step method (the names of core.integrators.EXPLICIT)
_STEPPERS = {"semi_implicit_euler": 0, "rk4": _RK4}


def clear_cache() -> None:
    """Forget the packed per-model arrays (they are rebuilt on the next call)."""
    _CACHE.clear()


class _Packed:
    """Packed buffer(s) of one model or one Params: ``buf`` (len,) for values shared by every
    copy, or ``bufs`` (B, len) one per copy (then ``buf`` is None)."""
    __slots__ = ("buf", "bufs", "lanes", "l0", "fd", "ext", "flags", "cost", "__weakref__")


def _fill_physics(buf, model, p, b, packed=PACKED):
    """Write the physical values of row ``b`` of ``p`` (a :class:`~tensegrity_gym.core.params.Params`)
    into the packed buffer ``buf`` (see ``_layout``): the backend's own packings
    (:data:`.layout.OWN_PACKING`), then every table row at its slot (``packed``: default
    :data:`.layout.PACKED`, the parameter table's)."""
    k, n, m = model.n_bars, model.n_nodes, model.n_strings
    rod, string = packed["rod_stride"], packed["string_stride"]
    o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end = _layout(k, m, n, rod, string, packed["node_rows"])
    mass_, f_, J_ = p.mass[b], p.f[b], p.J[b]
    for j in range(k):
        rj = o_rod + rod * j
        mass, f, J = float(mass_[j]), float(f_[j]), float(J_[j])
        alpha = mass - f * f / J
        buf[rj + 5:rj + 12] = (1.0 / mass, 1.0 / J, f / J, f * f / J, alpha, 1.0 / alpha, f)
    buf[o_l0:o_l0 + m] = p.rest_length[b]
    buf[o_W0:o_W0 + 3 * n] = p.W0[b].reshape(-1)
    for a, pos in zip(model.anchor_idx, p.anchor_pos[b]):   # anchor rows of the node scratch
        buf[o_N + 3 * a:o_N + 3 * a + 3] = pos
    if packed["rod"]:
        pr = o_rod + rod * np.arange(k)
        for fld, slot in packed["rod"].items():
            buf[pr + slot] = getattr(p, fld)[b]
    if packed["string"]:
        ps = o_str + string * np.arange(m)
        for fld, slot in packed["string"].items():
            buf[ps + slot] = getattr(p, fld)[b]
    for fld, row in packed["node"].items():
        o = o_cn + 3 * n * row
        buf[o:o + 3 * n] = np.repeat(getattr(p, fld)[b], 3)


def read_packed(buf, model, field, packed=PACKED):
    """The per-item values of the table row ``field`` in the packed buffer ``buf`` (one copy's):
    where the kernels read them (the unpacker the layout test checks against the kernels)."""
    k, n, m = model.n_bars, model.n_nodes, model.n_strings
    rod, string = packed["rod_stride"], packed["string_stride"]
    o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end = _layout(k, m, n, rod, string, packed["node_rows"])
    if field in packed["rod"]:
        return buf[o_rod + rod * np.arange(k) + packed["rod"][field]]
    if field in packed["string"]:
        return buf[o_str + string * np.arange(m) + packed["string"][field]]
    if field in packed["node"]:
        o = o_cn + 3 * n * packed["node"][field]
        return buf[o:o + 3 * n:3]
    raise KeyError(f"{field!r} is not a table row of the packed layout (packed in the backend's own form, or unknown)")


def _physics_flags(model, p, packed=PACKED):
    """The flag bits of ``p`` (a Params): a skipped field's bit where it may be non-zero, and
    whether a rod is constrained."""
    flags = _CONS if bool(np.any(model.constrained)) else 0
    for fld, bit in packed["bits"].items():
        if p.may_be_nonzero(fld):
            flags |= bit
    return flags


def _pack(model):
    """Pack the model into one float64 buffer (see ``_layout``) plus default control arrays;
    cached by id(model) for the model's lifetime."""
    k, n, m = model.n_bars, model.n_nodes, model.n_strings
    o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end = _layout(k, m, n)
    buf = np.zeros(end)
    ib = buf.view(np.int64)
    ib[0:3] = (k, m, n)
    for j in range(k):
        rj = o_rod + _ROD * j
        ib[rj:rj + 3] = (model.rod_a[j], model.rod_c[j], int(bool(model.constrained[j])))
        buf[rj + 3:rj + 5] = (model.eta[j, 0], model.eta[j, 1])
        buf[rj + 12:rj + 21] = model.proj[j].reshape(-1)
        buf[rj + 21:rj + 24] = model.offset[j]
    for s in range(m):
        ps = o_str + _STR * s
        ib[ps:ps + 2] = (model.str_i[s], model.str_j[s])
    _fill_physics(buf, model, model.nominal, 0)
    p = _Packed()
    p.buf = buf
    p.bufs = None
    p.lanes = _NO_LANES
    p.l0 = np.array(model.rest_length, dtype=np.float64).reshape(1, m)
    p.fd = np.zeros((1, m))
    p.ext = np.zeros((1, n, 3))
    p.cost = m + k
    p.flags = _physics_flags(model, model.nominal)
    key = id(model)
    _CACHE[key] = p
    weakref.finalize(model, _CACHE.pop, key, None)
    return p


def _pack_params(model, params):
    """The packed buffers of ``params`` (a :class:`~tensegrity_gym.core.params.Params` of this
    model): one shared buffer when it has one row (then the kernels run exactly as for the
    model), else one buffer per copy. Cached by id(params) for the params' lifetime."""
    key = ("params", id(params), id(model))
    p = _CACHE.get(key)
    if p is not None:
        return p
    base = _CACHE.get(id(model)) or _pack(model)
    P = params.batch_size
    parent = params.parent() if params.parent is not None else None
    pp = None if parent is None else _CACHE.get(("params", id(parent), id(model)))
    if pp is not None and pp.bufs is not None and pp.bufs.shape[0] == P:
        bufs = pp.bufs.copy()            # Params.set_rows: only its changed rows differ from the parent
        rows = params.changed_rows
    else:
        bufs = np.repeat(base.buf[None], P, axis=0)
        rows = range(P)
    for b in rows:
        _fill_physics(bufs[b], model, params, b)
    p = _Packed()
    p.buf, p.bufs = (bufs[0], None) if P == 1 else (None, bufs)
    p.lanes = _NO_LANES if P == 1 else _lanes(bufs, model.n_bars)
    p.l0 = np.array(params.rest_length[:1], dtype=np.float64)
    p.fd, p.ext, p.cost = base.fd, base.ext, base.cost
    p.flags = _physics_flags(model, params)
    _CACHE[key] = p
    weakref.finalize(params, _CACHE.pop, key, None)
    return p


_NO_LANES = np.empty((0, 1, 1))   # no per-copy lane blocks: the SIMD loop takes the shared buffer's constants


def _lanes(bufs, k):
    """(ceil(P/E), len, E): the per-copy buffers ``bufs`` (P, len) in blocks of E copies, lane
    e of block c holding copy c E + e (the SIMD loop reads its lane constants from it in place);
    the pad lanes of the last block repeat its first copy, as the SIMD loop's pad lanes do."""
    P, size = bufs.shape
    E = _soa_width(k)
    nb = -(-P // E)
    idx = np.arange(nb * E)
    idx = np.where(idx < P, idx, (idx // E) * E)
    return np.ascontiguousarray(bufs[idx].reshape(nb, E, size).transpose(0, 2, 1))


def _array(x, ndim, what):
    """A C-contiguous, writable float64 copy/view of x with a leading batch axis added if needed."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == ndim - 1:
        x = x[None]
    if x.ndim != ndim:
        raise ValueError(f"{what}: expected a {ndim - 1}- or {ndim}-dimensional array, got shape {x.shape}")
    if not (x.flags.c_contiguous and x.flags.writeable):
        x = np.array(x, dtype=np.float64, order="C")
    return x



def _flags(p, name, project):
    bits = _STEPPERS.get(name)
    if bits is None:     # an alias, or a method the kernels lack (ValueError naming it)
        bits = _STEPPERS[fixed_step_name(name, "numba")]
    flags = p.flags | bits
    return flags | _PROJ if project else flags
