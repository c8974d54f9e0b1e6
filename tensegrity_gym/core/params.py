"""Physical parameters with a leading batch axis: one row per copy of a structure.

A compiled :class:`~tensegrity_gym.core.model.Model` holds the *topology* of a structure (which
nodes a rod or a string joins, rod lengths and reference points, node-constraint projectors,
which strings are force-density actuated) and its nominal physical values. A :class:`Params`
holds every physical number a robot could differ in, with a leading batch axis ``P``: ``P = 1``
(one set shared by every copy of a batch) or ``P = B`` (copy ``b`` uses row ``b``). Every
integrator and backend reads the physics from it when it is passed
(``physics.step(model, state, dt, integrator, params=params)``).

=================  =============  =========  ==========================================================
field              shape          unit       meaning
=================  =============  =========  ==========================================================
``mass``           (P, k)         kg         rod mass
``f``              (P, k)         kg m       first mass moment about the rod's reference point
                                             (0 for a free rod, described at its centre of mass)
``J``              (P, k)         kg m^2     second mass moment about the reference point
``stiffness``      (P, m)         N/m        string stiffness (0 for force-density-actuated strings)
``damping``        (P, m)         N s/m      string damping (acts only while the string is taut)
``rest_length``    (P, m)         m          string rest lengths (a ``rest_length`` control passed to
                                             ``step`` replaces them for that call)
``node_damping``   (P, n)         N s/m      viscous drag ``-c v`` on each node
``gravity``        (P, 3)         m/s^2      gravitational acceleration (zeros: no gravity code runs)
``anchor_pos``     (P, na, 3)     m          positions of the fixed anchor nodes
``W0``             (P, n, 3)      N          derived: the rods' weights as nodal loads (read-only)
=================  =============  =========  ==========================================================

Replacing ``mass`` alone keeps each rod's mass distribution (uniform, or its lumped masses scaled
in proportion) and recomputes ``f`` and ``J`` from it, with the operations of ``compile_model``
(so a copy equals a structure compiled with those rod masses); pass ``f``/``J`` too to set them
yourself. Every array is read-only; a new
:class:`Params` comes from :meth:`Params.replace`.

When all copies share their values (``P = 1``) the compiled kernels run exactly as with no
``params`` (same buffers, same code); per-copy values (``P = B``) run a per-copy loop.
"""
from __future__ import annotations

import weakref

import numpy as np

from .param_table import nominal_default, params_fields, skipped_fields
from .rod_mass import mass_moments

__all__ = ["Params", "default_params", "nominal_params", "nominal_values", "PARAM_FIELDS"]

#: field -> (what its second axis counts, unit, constraint) for validation and messages
#: (a view of the parameter table, tensegrity_gym.core.param_table)
PARAM_FIELDS: dict[str, tuple[str, str, str]] = params_fields()
#: the fields with a ``has_<field>`` flag (the equations skip their term where it is 0)
_SKIPPED = frozenset(skipped_fields())
#: the arrays a Params holds: its fields and the derived nodal loads W0
_ARRAYS = frozenset(PARAM_FIELDS) | {"W0"}


class Params:
    """Per-copy physical parameters (see the module doc for the fields, shapes and units): one
    read-only array attribute per physics row of the parameter table
    (:func:`tensegrity_gym.core.param_table.physics_fields`) plus ``W0``, and ``has_<field>``
    for each field whose term the equations skip where it is 0
    (:func:`~tensegrity_gym.core.param_table.skipped_fields`).

    Build one with :func:`default_params` and change it with :meth:`replace`; the constructor
    does not validate (``replace`` and ``default_params`` do)."""

    def __init__(self, model=None, parent=None, changed_rows=None, **arrays):
        if arrays.keys() != _ARRAYS:
            raise TypeError(f"Params: expected the fields {sorted(_ARRAYS)}, got {sorted(arrays)}")
        d = self.__dict__
        d.update(arrays)
        d["model"] = model   # the Model these values belong to (topology: rod nodes, com fractions)
        # set by set_rows: the Params this one was made from (weak) and the rows that differ from it,
        # so that compiled backends can update their packed copy of the parent instead of repacking
        d["parent"] = parent
        d["changed_rows"] = changed_rows

    def __setattr__(self, name, value):
        raise AttributeError(f"Params is read-only: use replace({name}=...) for a new one")

    def __getattr__(self, name):
        if name.startswith("has_") and name[4:] in _SKIPPED:
            return self.may_be_nonzero(name[4:])
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __repr__(self):
        return f"Params(batch_size={self.batch_size}, fields={list(PARAM_FIELDS)})"

    @property
    def batch_size(self) -> int:
        """P: 1 (shared by every copy) or the number of copies."""
        return self.mass.shape[0]

    def may_be_nonzero(self, name: str) -> bool:
        """Whether some value of field ``name`` is not 0 (the equations skip a term of a
        :func:`~tensegrity_gym.core.param_table.skipped_fields` field otherwise)."""
        return bool(np.any(getattr(self, name) != 0))

    def take(self, idx) -> "Params":
        """The copies ``idx`` (int array or slice) as a new Params (P = len(idx))."""
        idx = np.arange(self.batch_size)[idx] if isinstance(idx, slice) else np.asarray(idx, dtype=int)
        if self.batch_size == 1:
            idx = np.zeros_like(idx)
        return _frozen(self.model, **{k: getattr(self, k)[idx] for k in PARAM_FIELDS},
                       W0=self.W0[idx])

    def broadcast(self, batch_size: int) -> "Params":
        """The same values repeated to ``batch_size`` rows (P must be 1 or batch_size)."""
        if self.batch_size == batch_size:
            return self
        if self.batch_size != 1:
            raise ValueError(f"params: cannot broadcast {self.batch_size} copies to {batch_size}")
        return self.take(np.zeros(batch_size, dtype=int))

    def set_rows(self, idx, **values) -> "Params":
        """A new Params equal to this one except rows ``idx`` (int array of copies), whose named
        fields take ``values`` (each a number, a per-item array or an (len(idx), ...) array;
        ``mass`` alone recomputes ``f``, ``J``). Validated like :meth:`replace`. Only the changed
        rows are repacked by the compiled kernels (an env resetting a few copies of a large batch
        pays for those copies only)."""
        idx = np.asarray(idx, dtype=int).reshape(-1)
        if idx.size and (idx.min() < 0 or idx.max() >= self.batch_size):
            raise ValueError(f"params.set_rows: copy index out of range 0..{self.batch_size - 1}: {idx.tolist()}")
        sub = self.take(idx).replace(**values)
        out = {}
        for k in tuple(PARAM_FIELDS) + ("W0",):
            a = np.array(getattr(self, k))
            a[idx] = _rows(getattr(sub, k), idx.size)
            out[k] = a
        return _frozen(self.model, parent=weakref.ref(self), changed_rows=idx, **out)

    def replace(self, **values) -> "Params":
        """A new Params with the named fields replaced and validated.

        Each value may be a number (every copy, every item), a per-item array (``(k,)`` for a
        rod field, ``(m,)`` string, ``(n,)`` node, ``(3,)`` gravity, ``(na, 3)`` anchors) or a
        per-copy array with a leading axis of 1 or B. Fields not given keep their values
        (repeated to the new batch size). ``mass`` alone recomputes ``f`` and ``J`` from the rod's mass distribution.
        Raises ValueError naming the field, the copy, the item and the value."""
        model = self.model
        unknown = sorted(set(values) - set(PARAM_FIELDS))
        if unknown:
            raise ValueError(f"params: unknown field(s) {unknown}; fields are {sorted(PARAM_FIELDS)}")
        new = {k: _shape(model, k, v) for k, v in values.items()}
        P = {a.shape[0] for a in new.values()} | {self.batch_size}
        P.discard(1)
        if len(P) > 1:
            raise ValueError(f"params: fields have different numbers of copies {sorted(P)}; "
                             "give 1 or the same B for every field")
        B = P.pop() if P else 1
        cur = {k: _rows(getattr(self, k), B) for k in PARAM_FIELDS}
        if "mass" in new and "f" not in new and "J" not in new:
            cur["f"], cur["J"] = _moments(model, _rows(new["mass"], B))
        for k, v in new.items():
            cur[k] = _rows(v, B)
        _validate(model, cur)
        W0 = _rows(self.W0, B)
        if "mass" in new or "gravity" in new or "f" in new:
            W0 = _weights(model, cur["mass"], cur["gravity"])
        return _frozen(model, **cur, W0=W0)


def rod_moments(model, mass: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, k) first and second mass moments of rods of mass ``mass`` (P, k) kg with the
    structure's mass distribution (uniform, or its lumped masses scaled to ``mass``), computed
    as :func:`~tensegrity_gym.core.model.compile_model` does (the same operations: a copy equals
    a structure compiled with that rod mass to the last bit)."""
    s = model.structure
    L, sig = model.length, model.sigma
    with np.errstate(all="ignore"):
        f = mass * L * (1.0 - 2.0 * sig) / 2.0
        J = mass * L ** 2 * (1.0 - 3.0 * sig + 3.0 * sig ** 2) / 3.0
    for j, pts in enumerate(s.mass_points or ()):
        if pts is None:
            continue
        total = sum(mk for _, mk in pts)
        for b in range(mass.shape[0]):
            f[b, j], J[b, j] = mass_moments(L[j], mass[b, j], sig[j], [(mu, mk * mass[b, j] / total) for mu, mk in pts])
    f = np.where(np.asarray(model.constrained)[None], f, 0.0)   # free rods: f = 0 at the centre of mass
    return f, J


def _rows(a: np.ndarray, B: int) -> np.ndarray:
    return a if a.shape[0] == B else np.repeat(a, B, axis=0)


def _counts(model) -> dict[str, tuple]:
    return {"rod": (model.n_bars,), "string": (model.n_strings,), "node": (model.n_nodes,),
            "component": (3,), "anchor": (len(model.anchor_idx), 3)}


def _shape(model, name: str, value) -> np.ndarray:
    """``value`` as a (P, ...) float array for field ``name`` (P = 1 for a number / per-item value)."""
    what, unit, _ = PARAM_FIELDS[name]
    item = _counts(model)[what]
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"params.{name}: expected numbers ({unit}), got {value!r:.80}") from None
    if a.ndim == 0 and what != "anchor":
        a = np.full((1,) + item, float(a))
    elif a.shape == item:
        a = a[None]
    if a.ndim != len(item) + 1 or a.shape[1:] != item:
        raise ValueError(f"params.{name}: expected a number, shape {item} (one per {what}) or (B,) + {item} "
                         f"(one row per copy), got shape {a.shape}")
    return a


def _validate(model, cur: dict) -> None:
    for name, a in cur.items():
        what, unit, rule = PARAM_FIELDS[name]
        if rule == "positive":
            bad = ~(np.isfinite(a) & (a > 0))
            need = "finite and > 0"
        elif rule == "nonnegative":
            bad = ~(np.isfinite(a) & (a >= 0))
            need = "finite and >= 0"
        else:
            bad = ~np.isfinite(a)
            need = "finite"
        if bad.any():
            pos = np.argwhere(bad)[0]
            raise ValueError(f"params.{name}: copy {pos[0]}, {what} {pos[1]}: must be {need} {unit}, "
                             f"got {float(a[tuple(pos)])!r}")
    free = ~np.asarray(model.constrained)
    bad = (cur["f"] != 0) & free[None]
    if bad.any():
        b, j = np.argwhere(bad)[0]
        raise ValueError(f"params.f: copy {b}, rod {j}: a free rod is described at its centre of mass, so its "
                         f"first mass moment must be 0 kg m, got {float(cur['f'][b, j])!r}")
    alpha = cur["mass"] - cur["f"] ** 2 / cur["J"]
    bad = ~(alpha > 0)
    if bad.any():
        b, j = np.argwhere(bad)[0]
        raise ValueError(f"params.mass/f/J: copy {b}, rod {j}: m - f^2/J must be > 0 (Lemma 5.1), got "
                         f"m = {float(cur['mass'][b, j])!r} kg, f = {float(cur['f'][b, j])!r} kg m, "
                         f"J = {float(cur['J'][b, j])!r} kg m^2")
    act = np.asarray(model.active)
    for name in ("stiffness", "damping"):
        bad = (cur[name] != 0) & act[None]
        if bad.any():
            b, i = np.argwhere(bad)[0]
            raise ValueError(f"params.{name}: copy {b}, string {i}: string {i} is force-density actuated (no "
                             f"elastic part), its {name} must be 0, got {float(cur[name][b, i])!r}")


def _weights(model, mass: np.ndarray, gravity: np.ndarray) -> np.ndarray:
    """(P, n, 3) nodal loads of the rods' weights (each at its centre of mass), N; the same
    operations as :func:`tensegrity_gym.core.model.compile_model` per copy."""
    P = mass.shape[0]
    W0 = np.zeros((P, model.n_nodes, 3))
    com = model.structure.com_fraction
    for b in range(P):
        W0[b, model.rod_a] += ((1.0 - com) * mass[b])[:, None] * gravity[b]
        W0[b, model.rod_c] += (com * mass[b])[:, None] * gravity[b]
    return W0


def _frozen(model, parent=None, changed_rows=None, **arrays) -> Params:
    out = {}
    for k, a in arrays.items():
        a = np.array(a, dtype=float, order="C")   # own copy, then read-only
        a.setflags(write=False)
        out[k] = a
    return Params(model=model, parent=parent, changed_rows=changed_rows, **out)


def default_params(model, batch_size: int = 1) -> Params:
    """The structure's own values (the model's nominal values, ``model.nominal``, set by
    :func:`~tensegrity_gym.core.model.compile_model`), repeated to ``batch_size`` rows (default 1:
    shared by every copy)."""
    if int(batch_size) != batch_size or batch_size < 1:
        raise ValueError(f"batch_size: must be a positive integer, got {batch_size!r}")
    B = int(batch_size)
    nom = model.nominal
    return _frozen(model, **{k: np.repeat(getattr(nom, k), B, axis=0) for k in tuple(PARAM_FIELDS) + ("W0",)})


def nominal_values(model, computed: dict, table=None) -> dict:
    """Physics field -> its nominal per-item array: the fields ``computed`` (field -> per-item
    array) as given, every other physics row of ``table`` (default the parameter table) its row's
    ``nominal`` value for every item (:func:`~tensegrity_gym.core.param_table.nominal_default`)."""
    counts = _counts(model)
    out = {}
    for fld, (what, _, _) in params_fields(table).items():
        v = computed.get(fld)
        out[fld] = np.full(counts[what], nominal_default(fld, table)) if v is None else np.asarray(v, dtype=float)
    return out


def nominal_params(model, computed: dict) -> Params:
    """The one-row :class:`Params` of a model's nominal values (:func:`nominal_values`; ``computed``
    holds ``W0`` too). Its ``model`` is None (the model holds it: no reference cycle);
    :func:`default_params` gives the model's."""
    values = {k: v[None] for k, v in nominal_values(model, computed).items()}
    return _frozen(None, W0=np.asarray(computed["W0"], dtype=float)[None], **values)


def check_params(model, params: Params, batch_size: int) -> Params:
    """``params`` checked against ``model`` and a state of ``batch_size`` copies (P = 1 or B)."""
    if not isinstance(params, Params):
        raise TypeError(f"params: expected a tensegrity_gym.core.params.Params (from default_params(model)), "
                        f"got {type(params).__name__}")
    if params.model is not model:
        c = _counts(model)
        for k in PARAM_FIELDS:
            a = getattr(params, k)
            if a.shape[1:] != c[PARAM_FIELDS[k][0]]:
                raise ValueError(f"params.{k}: shape {a.shape} does not fit this model (expected (P,) + "
                                 f"{c[PARAM_FIELDS[k][0]]})")
    if params.batch_size not in (1, batch_size):
        raise ValueError(f"params: {params.batch_size} copies for a state of {batch_size} copies; "
                         "give 1 (shared) or one per copy")
    return params


_moments = rod_moments   # the name the per-copy code of this module calls
