"""Terrain: a sloped plane, boxes and a heightfield (pure data, validation and NumPy geometry).

SI units: m, degrees for angles in the file and the constructors, N/m, s/m. The physics of
contact with a terrain lives in :mod:`tensegrity_gym.physics.terrain`; this module only
describes the ground and answers geometric queries (:meth:`Terrain.height_at`,
:meth:`Terrain.closest`), which the tests use as the oracle of the compiled kernels.

The terrain is the union of solids:

* ``plane``: the half-space below a plane through the origin, ``slope_deg`` in (-90, 90) from
  the horizontal, rising fastest along the compass direction ``uphill_deg`` measured from +x
  towards +y. Height ``z = tan(slope) (x cos(uphill) + y sin(uphill))``. Absent from a file
  (or ``Plane()``): a level plane at z = 0; ``"plane": null`` (or ``plane=None``): no plane.
* ``boxes``: solid boxes, ``center`` (3,) m, ``size`` (3,) full edge lengths m, rotated by
  ``yaw_deg`` about the vertical through their centre.
* ``heightfield``: the solid below ``z = h(x, y)``, ``heights`` (ny, nx) m at
  ``x = x0 + i cell``, ``y = y0 + j cell`` (row j, column i), bilinear between grid points and
  the edge values held constant outside the grid (flat across the edge).

Contact parameters: ``friction`` (Coulomb coefficient), ``stiffness`` (normal, N/m),
``damping`` (Hunt-Crossley, s/m) are the terrain's, and each plane, box or heightfield may
override any of them with its own keys of the same names.

File format (JSON; every block optional, ``{}`` = a level plane at z = 0)::

    {"friction": 0.8, "stiffness": 1e4, "damping": 10,
     "plane": {"slope_deg": 20.0, "uphill_deg": 0.0},
     "boxes": [{"center": [x, y, z], "size": [sx, sy, sz], "yaw_deg": 0.0}],
     "heightfield": {"file": "h.npy", "cell": 0.05, "origin": [x0, y0]}}

Its JSON Schema is ``tensegrity_gym/terrain.schema.json`` (:data:`SCHEMA_PATH`). Wrong input
raises ValueError naming the field, the index and the value
(``boxes[2].size[1]: must be > 0, got -0.1``).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .checks import load_npy, read_bounded
from .terrain_kinds import (KINDS, MAX_EXTENT, SURFACE_KEYS, SurfaceContact, TerrainKind, _as_float, _number, _surface,
                            _vector, kind_of, load_part, register)

__all__ = ["Terrain", "Plane", "Box", "Heightfield", "SCHEMA_PATH", "SURFACE_KEYS", "MAX_EXTENT", "MAX_TERRAIN_BYTES",
           "MAX_HEIGHTFIELD_BYTES"]

#: largest terrain JSON file read, bytes (counted while reading; a large grid belongs in a .npy file)
MAX_TERRAIN_BYTES = 64 * 2**20
#: largest heightfield .npy file read, bytes (a 11585 x 11585 grid of float64 heights)
MAX_HEIGHTFIELD_BYTES = 2**30

#: the JSON Schema (draft 2020-12) of the terrain file format, shipped with the package
SCHEMA_PATH = Path(__file__).parent.parent / "terrain.schema.json"


@dataclass(frozen=True)
class Plane(SurfaceContact):
    """The half-space below a plane through the origin: slope (deg, in (-90, 90)) rising along
    the compass direction ``uphill_deg`` (deg from +x towards +y); contact overrides optional."""

    slope_deg: float = 0.0
    uphill_deg: float = 0.0
    def __post_init__(self):
        s = object.__setattr__
        s(self, "slope_deg", _number(self.slope_deg, "slope_deg", -90.0, 90.0, True, True))
        s(self, "uphill_deg", _number(self.uphill_deg, "uphill_deg"))
        _surface(self)

    @property
    def normal(self) -> np.ndarray:
        """(3,) outward unit normal (pointing out of the solid, up the z axis)."""
        a, p = math.radians(self.slope_deg), math.radians(self.uphill_deg)
        return np.array([-math.sin(a) * math.cos(p), -math.sin(a) * math.sin(p), math.cos(a)])

    def closest(self, p):
        """Signed distance (m) of ``p`` (..., 3) m and the outward normal there (..., 3)."""
        n = self.normal
        return p @ n, np.broadcast_to(n, p.shape).copy()

    def top(self, x, y):
        """Height (m) of the plane at (x, y) m."""
        n = self.normal
        return -(n[0] * x + n[1] * y) / n[2]


@dataclass(frozen=True, eq=False)
class Box(SurfaceContact):
    """A solid box: ``center`` (3,) m, ``size`` (3,) full edge lengths m (> 0), ``yaw_deg``
    about the vertical; contact overrides optional."""

    center: np.ndarray
    size: np.ndarray
    yaw_deg: float = 0.0
    def __post_init__(self):
        s = object.__setattr__
        s(self, "center", _vector(self.center, 3, "center", limit=MAX_EXTENT, unit="m"))
        s(self, "size", _vector(self.size, 3, "size", positive=True, limit=MAX_EXTENT, unit="m"))
        s(self, "yaw_deg", _number(self.yaw_deg, "yaw_deg"))
        _surface(self)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) box axes in world coordinates (columns)."""
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def closest(self, p):
        """Signed distance (m; < 0 inside) of ``p`` (..., 3) m and the outward normal (..., 3): the
        nearest face's inside, the direction to the nearest surface point outside."""
        R, h = self.rotation, self.size / 2
        loc = (p - self.center) @ R                 # box coordinates
        q = np.abs(loc) - h
        outside = np.maximum(q, 0.0)
        dout = np.linalg.norm(outside, axis=-1)
        inside = np.max(q, axis=-1) < 0
        ax = np.argmax(q, axis=-1)
        sgn = np.where(loc >= 0, 1.0, -1.0)
        face = sgn * (np.arange(3) == ax[..., None])
        with np.errstate(invalid="ignore", divide="ignore"):
            nout = sgn * outside / dout[..., None]
        nloc = np.where(inside[..., None] | (dout[..., None] == 0), face, nout)
        d = np.where(inside, np.max(q, axis=-1), dout)
        return d, nloc @ R.T

    def top(self, x, y):
        """Height (m) of the box's top at (x, y) m, -inf beside it."""
        R = self.rotation
        dx, dy = x - self.center[0], y - self.center[1]
        u, v = R[0, 0] * dx + R[1, 0] * dy, R[0, 1] * dx + R[1, 1] * dy
        inside = (np.abs(u) <= self.size[0] / 2) & (np.abs(v) <= self.size[1] / 2)
        return np.where(inside, self.center[2] + self.size[2] / 2, -np.inf)


@dataclass(frozen=True, eq=False)
class Heightfield(SurfaceContact):
    """The solid below ``z = h(x, y)``: ``heights`` (ny, nx) m (at least 2 x 2, finite) on a grid of
    ``cell`` m from ``origin`` (x0, y0) m; bilinear, edge values held outside the grid."""

    heights: np.ndarray
    cell: float
    origin: np.ndarray = field(default_factory=lambda: np.zeros(2))
    def __post_init__(self):
        s = object.__setattr__
        h = _heights(self.heights)
        bad = ~np.isfinite(h)
        if bad.any():
            j, i = np.argwhere(bad)[0]
            raise ValueError(f"heights[{j}, {i}]: must be finite (m), got {float(h[j, i])!r}")
        bad = np.abs(h) > MAX_EXTENT
        if bad.any():
            j, i = np.argwhere(bad)[0]
            raise ValueError(f"heights[{j}, {i}]: must be within +-{MAX_EXTENT:g} m (a terrain's physical "
                             f"extent), got {float(h[j, i])!r}")
        h.setflags(write=False)
        s(self, "heights", h)
        s(self, "cell", _number(self.cell, "cell", lo=0.0, lo_open=True, limit=MAX_EXTENT, unit="m"))
        s(self, "origin", _vector(self.origin, 2, "origin", limit=MAX_EXTENT, unit="m"))
        _surface(self)

    def height_at(self, x, y) -> np.ndarray:
        """Bilinear height (m) at (x, y) (arrays of the same shape, m)."""
        return self._interp(np.asarray(x, float), np.asarray(y, float))[0]

    def top(self, x, y):
        """Height (m) at (x, y) m (:meth:`height_at`)."""
        return self.height_at(x, y)

    def closest(self, p):
        """The vertical gap times the cosine of the local slope (m) of ``p`` (..., 3) m and the
        normal of the bilinear patch under it (..., 3): exact on a locally planar patch (the
        contact measures the vertical gap itself, :meth:`gap`)."""
        h, gx, gy = self._interp(p[..., 0], p[..., 1])
        c = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
        return (p[..., 2] - h) * c, np.stack([-gx * c, -gy * c, c], axis=-1)

    def gap(self, points):
        """The contact measure of ``points`` (..., 3) m: the vertical gap ``z - h(x, y)`` m and its
        gradient, the unnormalised outward normal ``(-h_x, -h_y, 1)`` (..., 3) of the bilinear patch
        under each point (NumPy oracle of the compiled kernels)."""
        p = np.asarray(points, float)
        h, gx, gy = self._interp(p[..., 0], p[..., 1])
        return p[..., 2] - h, np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)

    def _interp(self, x, y):
        """Height and its gradient (dh/dx, dh/dy) at (x, y); outside the grid the held edge is
        flat across the edge (that gradient component is 0)."""
        ny, nx = self.heights.shape
        u = (x - self.origin[0]) / self.cell
        v = (y - self.origin[1]) / self.cell
        out_u, out_v = (u < 0) | (u > nx - 1), (v < 0) | (v > ny - 1)
        u = np.clip(u, 0.0, nx - 1)
        v = np.clip(v, 0.0, ny - 1)
        i = np.minimum(np.floor(u).astype(int), nx - 2)
        j = np.minimum(np.floor(v).astype(int), ny - 2)
        fu, fv = u - i, v - j
        H = self.heights
        h00, h10, h01, h11 = H[j, i], H[j, i + 1], H[j + 1, i], H[j + 1, i + 1]
        h = (1 - fu) * (1 - fv) * h00 + fu * (1 - fv) * h10 + (1 - fu) * fv * h01 + fu * fv * h11
        gx = np.where(out_u, 0.0, ((1 - fv) * (h10 - h00) + fv * (h11 - h01)) / self.cell)
        gy = np.where(out_v, 0.0, ((1 - fu) * (h01 - h00) + fu * (h11 - h10)) / self.cell)
        return h, gx, gy


def _heights(v) -> np.ndarray:
    """``v`` as a new 2-D float array of at least 2 x 2 heights (m): an array of integers or
    floats, or rows of real numbers; ValueError naming ``heights`` (the entry where one is a bool,
    a complex number, a string or an integer too large for a float) otherwise."""
    if isinstance(v, np.ndarray) and v.dtype.kind in "iuf":
        h = v.astype(float)
    elif isinstance(v, np.ndarray) and v.dtype.kind != "O":
        raise ValueError(f"heights: expected an array of real numbers (m), got dtype {v.dtype}")
    else:
        try:
            obj = np.array(v, dtype=object)
        except (TypeError, ValueError):
            obj = None
        if obj is None or obj.ndim != 2:
            raise ValueError(f"heights: expected a 2-D array of numbers (m), got "
                             f"{type(v).__name__}{'' if obj is None else f' of shape {obj.shape}'}")
        h = np.empty(obj.shape)
        for (j, i), x in np.ndenumerate(obj):
            h[j, i] = _as_float(x, f"heights[{j}, {i}]")
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValueError(f"heights: expected a 2-D array of at least 2 x 2 heights (m), got shape {h.shape}")
    return h


def _heightfield_kwargs(kw, path, base_dir):
    """``file`` (a .npy 2-D array, relative to ``base_dir``) or inline ``heights`` -> ``heights``."""
    if ("file" in kw) == ("heights" in kw):
        raise ValueError(f"{path}: give exactly one of 'file' (a .npy array) and 'heights' (a list of rows)")
    if "file" in kw:
        name = kw.pop("file")
        if not isinstance(name, str) or not name:
            raise ValueError(f"{path}.file: expected a file name, got {name!r}")
        p = Path(name) if base_dir is None else Path(base_dir) / name
        if not p.exists():
            raise ValueError(f"{path}.file: no such file {str(p)!r}")
        try:        # a FIFO, a device, an empty or truncated file: refused naming the file
            arr = load_npy(p, "a 2-D array of heights", "heightfield file", MAX_HEIGHTFIELD_BYTES)
        except OSError as e:
            raise ValueError(f"{path}.file: cannot read {str(p)!r}: {e.strerror or e}") from None
        except ValueError as e:
            raise ValueError(f"{path}.file: {e}") from None
        if not isinstance(arr, np.ndarray) or arr.ndim != 2:
            raise ValueError(f"{path}.file: expected a 2-D array of heights, got shape {np.shape(arr)} "
                             f"in {str(p)!r}")
        kw["heights"] = arr
    return kw


@dataclass(frozen=True)
class Terrain:
    """A terrain: ``plane`` (default a level plane at z = 0; None: no plane), ``boxes`` (a
    sequence of :class:`Box`), ``heightfield`` (optional), ``extra`` (parts of the other kinds of
    :data:`~tensegrity_gym.core.terrain_kinds.KINDS`, after those in feature order), and the
    contact parameters shared by the parts: ``friction`` (>= 0), ``stiffness`` (N/m, > 0),
    ``damping`` (s/m, >= 0). :meth:`parts` is the list every consumer iterates."""

    plane: Plane | None = field(default_factory=Plane)
    boxes: tuple = ()
    heightfield: Heightfield | None = None
    friction: float = 1.0
    stiffness: float = 1e4
    damping: float = 10.0
    extra: tuple = ()

    def __post_init__(self):
        s = object.__setattr__
        if self.plane is not None and not isinstance(self.plane, Plane):
            raise ValueError(f"plane: expected a Plane or None, got {self.plane!r}")
        boxes = tuple(self.boxes)
        for i, b in enumerate(boxes):
            if not isinstance(b, Box):
                raise ValueError(f"boxes[{i}]: expected a Box, got {b!r}")
        s(self, "boxes", boxes)
        if self.heightfield is not None and not isinstance(self.heightfield, Heightfield):
            raise ValueError(f"heightfield: expected a Heightfield or None, got {self.heightfield!r}")
        extra = tuple(self.extra)
        for i, part in enumerate(extra):
            kind = kind_of(part)
            if kind.key in _FIELDS:
                raise ValueError(f"extra[{i}]: a part of kind {kind.name!r} goes in the field {kind.key!r}")
        s(self, "extra", extra)
        s(self, "friction", _number(self.friction, "friction", lo=0.0))
        s(self, "stiffness", _number(self.stiffness, "stiffness", lo=0.0, lo_open=True))
        s(self, "damping", _number(self.damping, "damping", lo=0.0))

    @classmethod
    def from_parts(cls, parts, **contact) -> "Terrain":
        """A terrain of ``parts`` (any kinds of the table, in feature order within each field: a
        kind whose file key is a field of Terrain goes there, any other in ``extra``) and the
        ``contact`` keywords (friction, stiffness, damping)."""
        kw, extra = {"plane": None}, []
        for part in parts:
            kind = kind_of(part)
            if kind.key not in _FIELDS:
                extra.append(part)
            elif kind.many:
                kw[kind.key] = kw.get(kind.key, ()) + (part,)
            elif kw.get(kind.key) is not None:
                raise ValueError(f"terrain: more than one part of kind {kind.name!r}")
            else:
                kw[kind.key] = part
        return cls(**kw, extra=tuple(extra), **contact)

    # ------------------------------------------------------------------ files
    @classmethod
    def from_dict(cls, d, base_dir=None) -> "Terrain":
        """A terrain from the file format's dict (see the module doc), each kind of the table read
        from its key; ``base_dir``: where a heightfield ``file`` is looked up (default: the working
        directory)."""
        if not isinstance(d, dict):
            raise ValueError(f"terrain: expected an object, got {d!r}")
        keys = tuple(k.key for k in KINDS.values()) + SURFACE_KEYS
        unknown = sorted(set(d) - set(keys))
        if unknown:
            raise ValueError(f"terrain: unknown key {unknown[0]!r} (expected some of {list(keys)})")
        kw = {k: d[k] for k in SURFACE_KEYS if k in d}
        extra = []
        for kind in KINDS.values():
            if kind.key not in d:
                continue
            v = d[kind.key]
            if kind.many:
                if not isinstance(v, list):
                    raise ValueError(f"{kind.key}: expected a list of {kind.key}, got {v!r}")
                got = tuple(load_part(kind, x, f"{kind.key}[{i}]", base_dir) for i, x in enumerate(v))
            else:
                got = None if v is None else load_part(kind, v, kind.key, base_dir)
            if kind.key in _FIELDS:
                kw[kind.key] = got
            else:
                extra.extend(got if kind.many else [got] if got is not None else [])
        return cls(**kw, extra=tuple(extra))

    @classmethod
    def from_file(cls, path, defaults: dict | None = None) -> "Terrain":
        """A terrain from a JSON file (a heightfield ``file`` relative to the JSON file's folder);
        ``defaults``: top-level keys (e.g. contact values) taken where the file has none."""
        p = Path(path)
        try:        # bounded; a FIFO or a device is refused before it is opened
            text = read_bounded(p, MAX_TERRAIN_BYTES, "terrain file")
        except OSError as e:
            raise ValueError(f"terrain file: cannot read {str(p)!r}: {e.strerror or e}") from None
        except ValueError as e:
            raise ValueError(f"terrain file: {e}") from None
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise ValueError(f"terrain file: not valid JSON ({str(p)!r}, line {e.lineno}: {e.msg})") from None
        except ValueError as e:       # not UTF-8, or an integer of more than 4300 digits
            raise ValueError(f"terrain file: not valid JSON ({str(p)!r}: {e})") from None
        if defaults and isinstance(d, dict):
            d = {**defaults, **d}
        return cls.from_dict(d, base_dir=p.parent)

    def surface(self, part) -> tuple:
        """(friction, stiffness N/m, damping s/m) of ``part``: its overrides, else the terrain's."""
        return tuple(getattr(self, k) if getattr(part, k) is None else getattr(part, k) for k in SURFACE_KEYS)

    # ------------------------------------------------------------------ geometry
    def height_at(self, x, y) -> np.ndarray:
        """Height of the terrain's top surface (m) at (x, y) m (arrays of one shape): the highest of
        its parts' tops over (x, y) (each kind's ``top``); -inf where none is."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        h = np.full(x.shape, -np.inf)
        for part in self.parts():
            h = np.maximum(h, part.top(x, y))
        return h

    def parts(self) -> list:
        """The solids in the physics' feature order: the plane (if any), then the boxes, then the
        heightfield, then ``extra``."""
        return ([] if self.plane is None else [self.plane]) + list(self.boxes) + \
            ([] if self.heightfield is None else [self.heightfield]) + list(self.extra)

    def closest(self, points, per_part: bool = False):
        """Signed distance (m; < 0 inside a solid) of ``points`` (..., 3) m to the terrain and the
        outward unit normal there (..., 3): the nearest of the parts (``per_part=True``: each
        part's, with a leading axis in :meth:`parts` order), each kind's ``closest``. Exact for the
        plane and the boxes; for the heightfield the vertical gap times the cosine of the local
        slope (:meth:`Heightfield.closest`)."""
        p = np.asarray(points, float)
        parts = self.parts()
        if not parts:
            return np.full(p.shape[:-1], np.inf), np.zeros(p.shape)
        if per_part:
            ds, ns = zip(*(part.closest(p) for part in parts))
            return np.stack(ds), np.stack(ns)
        # the nearest part kept as the parts are visited: memory of a few arrays of the points'
        # size, not (parts x points) (10^5 boxes and 10^3 points would need gigabytes); the
        # first of equal distances wins and NaN counts as the smallest, as np.argmin picks them
        best_d = best_n = None
        for part in parts:
            d, n = part.closest(p)
            d, n = np.asarray(d, float), np.asarray(n, float)
            if best_d is None:
                best_d, best_n = d.copy(), n.copy()
                continue
            take = (d < best_d) | (np.isnan(d) & ~np.isnan(best_d))
            best_d = np.where(take, d, best_d)
            best_n = np.where(take[..., None], n, best_n)
        return best_d, best_n


#: the fields of :class:`Terrain` that hold parts of the built-in kinds (their file keys)
_FIELDS = ("plane", "boxes", "heightfield")

register(TerrainKind("plane", Plane, "plane", False, ("slope_deg", "uphill_deg")))
register(TerrainKind("box", Box, "boxes", True, ("center", "size", "yaw_deg"), ("center", "size")))
register(TerrainKind("heightfield", Heightfield, "heightfield", False, ("file", "heights", "cell", "origin"),
                     ("cell",), _heightfield_kwargs))
