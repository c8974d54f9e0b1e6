"""The table of terrain kinds: one row per kind of terrain part (a plane, a box, a heightfield, ...),
which every consumer of a :class:`~tensegrity_gym.core.terrain.Terrain` iterates.

A row (:class:`TerrainKind`) gives the kind's ``name``, its part class (a frozen dataclass with the
contact overrides of :class:`~tensegrity_gym.core.terrain.SurfaceContact`, whose methods
``closest(points)`` (signed distance m and outward unit normal) and ``top(x, y)`` (height m of its
top surface, -inf where it has none) are the kind's NumPy geometry, the oracle of the compiled
kernels), its key in the terrain file and whether the file holds one part or a list of them. The
consumers keep tables of their own keyed by the kind's name (the numba kernels' codes,
:mod:`tensegrity_gym.backends.numba.terrain_kinds`; the torch backend's,
:mod:`tensegrity_gym.backends.torch.terrain_kinds`; the MJCF geoms, :mod:`tensegrity_gym.io.mjcf`;
the renderers' drawings, :mod:`tensegrity_gym.tools.rendering.scene`), and refuse a part of a kind
without a row there with an error naming the kind (:func:`require`): a new kind is never dropped
without a word.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SurfaceContact", "TerrainKind", "KINDS", "SURFACE_KEYS", "register", "kind_of", "require", "load_part"]

#: contact parameters a terrain gives and each part may override
SURFACE_KEYS = ("friction", "stiffness", "damping")
#: the largest coordinate, length or height a terrain takes, m (|x| <= 1000 km: beyond any
#: robot's world, and far enough inside a float's range that the contact's arithmetic stays finite)
MAX_EXTENT = 1e6


# ------------------------------------------------------------ what every kind's part shares
def _as_float(v, name: str) -> float:
    """``float(v)`` of a real number (not a bool, string, complex or None), ValueError naming
    ``name`` otherwise (an integer too large for a float included)."""
    if isinstance(v, (str, bytes, bool, np.bool_, complex, np.complexfloating)) or v is None:
        raise ValueError(f"{name}: expected a real number, got {v!r:.80}")
    try:
        return float(v)
    except OverflowError:
        raise ValueError(f"{name}: must be finite, got an integer of {int(v).bit_length()} bits "
                         "(too large for a float)") from None
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {v!r:.80}") from None


def _number(v, name: str, lo=None, hi=None, lo_open=False, hi_open=False, limit=None, unit: str = "") -> float:
    """``float(v)`` if a finite real number within the bounds (and ``|v| <= limit`` where given),
    else ValueError naming ``name``, the bound and the value (``unit``: of the limit)."""
    x = _as_float(v, name)
    if not math.isfinite(x):
        raise ValueError(f"{name}: must be finite, got {v!r}")
    u = f" {unit}" if unit else ""
    if lo is not None and (x <= lo if lo_open else x < lo):
        raise ValueError(f"{name}: must be {'>' if lo_open else '>='} {lo:g}, got {v!r}")
    if hi is not None and (x >= hi if hi_open else x > hi):
        raise ValueError(f"{name}: must be {'<' if hi_open else '<='} {hi:g}, got {v!r}")
    if limit is not None and abs(x) > limit:
        raise ValueError(f"{name}: must be within +-{limit:g}{u} (a terrain's physical extent), got {v!r}")
    return x


def _vector(v, n: int, name: str, positive=False, limit=None, unit: str = "") -> np.ndarray:
    """(n,) read-only float array of finite numbers (> 0 with ``positive``, ``|x| <= limit``
    where given), ValueError naming ``name[i]`` and the value otherwise."""
    if isinstance(v, (str, bytes)) or np.ndim(v) != 1 or len(v) != n:
        raise ValueError(f"{name}: expected a list of {n} numbers, got {v!r:.80}")
    out = np.array([_number(x, f"{name}[{i}]", lo=0.0 if positive else None, lo_open=positive, limit=limit, unit=unit)
                    for i, x in enumerate(v)], float)
    out.setflags(write=False)
    return out


def _surface(obj, prefix: str = "") -> None:
    """Checks the optional contact overrides (None = the terrain's value) of a part."""
    s = object.__setattr__
    for key in SURFACE_KEYS:
        v = getattr(obj, key)
        if v is not None:
            s(obj, key, _number(v, prefix + key, lo=0.0, lo_open=(key == "stiffness")))


@dataclass(frozen=True, kw_only=True)
class SurfaceContact:
    """Contact overrides of one terrain part (None: the terrain's own): ``friction`` (1),
    ``stiffness`` (N/m), ``damping`` (s/m)."""

    friction: float | None = None
    stiffness: float | None = None
    damping: float | None = None


@dataclass(frozen=True)
class TerrainKind:
    """One kind of terrain part: ``name`` (the consumers' key), ``part`` (its class), ``key`` (its
    key in the terrain file and the JSON Schema), ``many`` (the file holds a list of such parts,
    else one or null), ``keys`` (the part's file keys besides the contact overrides), ``required``
    (those it must give), ``load`` (optional ``load(d, path, base_dir) -> dict``: the part's
    constructor arguments from its file dict, where they differ from the dict itself)."""

    name: str
    part: type
    key: str
    many: bool
    keys: tuple
    required: tuple = ()
    load: object = None


#: kind name -> row, in the terrain's feature order (the file's blocks are read in this order)
KINDS: dict = {}


def register(kind: TerrainKind) -> TerrainKind:
    """Add ``kind`` to the table (ValueError where its name, class or file key is taken)."""
    for k in KINDS.values():
        if kind.name == k.name or kind.part is k.part or kind.key == k.key:
            raise ValueError(f"terrain kind {kind.name!r}: name, part class or file key {kind.key!r} already "
                             f"registered by kind {k.name!r}")
    KINDS[kind.name] = kind
    return kind


def kind_of(part) -> TerrainKind:
    """The row of ``part``'s class; ValueError naming the class where it has none."""
    for k in KINDS.values():
        if type(part) is k.part:
            return k
    raise ValueError(f"terrain part {type(part).__name__}: not a terrain kind (registered kinds: {sorted(KINDS)}; "
                     f"tensegrity_gym.core.terrain_kinds.register adds one)")


def require(table: dict, part, where: str):
    """``table[kind name]`` of ``part``: a consumer's entry for its kind; ValueError naming the
    kind and the consumer ``where`` when the consumer has none."""
    name = kind_of(part).name
    if name not in table:
        raise ValueError(f"terrain kind {name!r}: {where} cannot handle it (no entry for it; it handles "
                         f"{sorted(table)})")
    return table[name]


def load_part(kind: TerrainKind, d, path: str, base_dir=None):
    """A part of ``kind`` from its dict ``d`` at ``path`` (errors prefixed with ``path.``)."""
    if not isinstance(d, dict):
        raise ValueError(f"{path}: expected an object, got {d!r}")
    for key in kind.required:
        if key not in d:
            raise ValueError(f"{path}: missing required key {key!r}")
    unknown = sorted(set(d) - set(kind.keys) - set(SURFACE_KEYS))
    if unknown:
        raise ValueError(f"{path}: unknown key {unknown[0]!r} (expected some of "
                         f"{list(kind.keys) + list(SURFACE_KEYS)})")
    kw = dict(d) if kind.load is None else kind.load(dict(d), path, base_dir)
    try:
        return kind.part(**kw)
    except ValueError as e:
        raise ValueError(f"{path}.{e}") from None
