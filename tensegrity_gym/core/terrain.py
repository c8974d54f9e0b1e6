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

__all__ = ["Terrain", "Plane", "Box", "Heightfield", "SCHEMA_PATH", "SURFACE_KEYS"]

#: the JSON Schema (draft 2020-12) of the terrain file format, shipped with the package
SCHEMA_PATH = Path(__file__).parent.parent / "terrain.schema.json"
#: contact parameters a terrain gives and each part may override
SURFACE_KEYS = ("friction", "stiffness", "damping")


# ---------------------------------------------------------------------- checks
def _number(v, name: str, lo=None, hi=None, lo_open=False, hi_open=False) -> float:
    """``float(v)`` if a finite real number within the bounds, else ValueError naming ``name``."""
    if isinstance(v, (str, bytes, bool, np.bool_)) or v is None:
        raise ValueError(f"{name}: expected a number, got {v!r}")
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {v!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{name}: must be finite, got {v!r}")
    if lo is not None and (x <= lo if lo_open else x < lo):
        raise ValueError(f"{name}: must be {'>' if lo_open else '>='} {lo:g}, got {v!r}")
    if hi is not None and (x >= hi if hi_open else x > hi):
        raise ValueError(f"{name}: must be {'<' if hi_open else '<='} {hi:g}, got {v!r}")
    return x


def _vector(v, n: int, name: str, positive=False) -> np.ndarray:
    """(n,) read-only float array of finite numbers (> 0 with ``positive``), ValueError naming
    ``name[i]`` and the value otherwise."""
    if isinstance(v, (str, bytes)) or np.ndim(v) != 1 or len(v) != n:
        raise ValueError(f"{name}: expected a list of {n} numbers, got {v!r}")
    out = np.array([_number(x, f"{name}[{i}]", lo=0.0 if positive else None, lo_open=positive)
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


@dataclass(frozen=True, eq=False)
class Box(SurfaceContact):
    """A solid box: ``center`` (3,) m, ``size`` (3,) full edge lengths m (> 0), ``yaw_deg``
    about the vertical; contact overrides optional."""

    center: np.ndarray
    size: np.ndarray
    yaw_deg: float = 0.0
    def __post_init__(self):
        s = object.__setattr__
        s(self, "center", _vector(self.center, 3, "center"))
        s(self, "size", _vector(self.size, 3, "size", positive=True))
        s(self, "yaw_deg", _number(self.yaw_deg, "yaw_deg"))
        _surface(self)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) box axes in world coordinates (columns)."""
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class Heightfield(SurfaceContact):
    """The solid below ``z = h(x, y)``: ``heights`` (ny, nx) m (at least 2 x 2, finite) on a grid of
    ``cell`` m from ``origin`` (x0, y0) m; bilinear, edge values held outside the grid."""

    heights: np.ndarray
    cell: float
    origin: np.ndarray = field(default_factory=lambda: np.zeros(2))
    def __post_init__(self):
        s = object.__setattr__
        try:
            h = np.array(self.heights, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"heights: expected a 2-D array of numbers (m), got {type(self.heights).__name__}") \
                from None
        if h.ndim != 2 or min(h.shape) < 2:
            raise ValueError(f"heights: expected a 2-D array of at least 2 x 2 heights (m), got shape {h.shape}")
        bad = ~np.isfinite(h)
        if bad.any():
            j, i = np.argwhere(bad)[0]
            raise ValueError(f"heights[{j}, {i}]: must be finite (m), got {float(h[j, i])!r}")
        h.setflags(write=False)
        s(self, "heights", h)
        s(self, "cell", _number(self.cell, "cell", lo=0.0, lo_open=True))
        s(self, "origin", _vector(self.origin, 2, "origin"))
        _surface(self)

    def height_at(self, x, y) -> np.ndarray:
        """Bilinear height (m) at (x, y) (arrays of the same shape, m)."""
        return self._interp(np.asarray(x, float), np.asarray(y, float))[0]

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


def _part(cls, d, path: str, keys: tuple, required: tuple = (), base_dir=None):
    """A part from its dict ``d`` at ``path`` (errors prefixed with ``path.``)."""
    if not isinstance(d, dict):
        raise ValueError(f"{path}: expected an object, got {d!r}")
    for key in required:
        if key not in d:
            raise ValueError(f"{path}: missing required key {key!r}")
    unknown = sorted(set(d) - set(keys) - set(SURFACE_KEYS))
    if unknown:
        raise ValueError(f"{path}: unknown key {unknown[0]!r} (expected some of {list(keys) + list(SURFACE_KEYS)})")
    kw = dict(d)
    if cls is Heightfield:
        kw = _heightfield_kwargs(kw, path, base_dir)
    try:
        return cls(**kw)
    except ValueError as e:
        raise ValueError(f"{path}.{e}") from None


def _heightfield_kwargs(kw, path, base_dir):
    """``file`` (a .npy 2-D array, relative to ``base_dir``) or inline ``heights`` -> ``heights``."""
    if ("file" in kw) == ("heights" in kw):
        raise ValueError(f"{path}: give exactly one of 'file' (a .npy array) and 'heights' (a list of rows)")
    if "file" in kw:
        name = kw.pop("file")
        if not isinstance(name, str) or not name:
            raise ValueError(f"{path}.file: expected a file name, got {name!r}")
        p = Path(name) if base_dir is None else Path(base_dir) / name
        if not p.is_file():
            raise ValueError(f"{path}.file: no such file {str(p)!r}")
        try:
            arr = np.load(p, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise ValueError(f"{path}.file: not a NumPy .npy array ({str(p)!r}: {e})") from None
        if not isinstance(arr, np.ndarray) or arr.ndim != 2:
            raise ValueError(f"{path}.file: expected a 2-D array of heights, got shape {np.shape(arr)} "
                             f"in {str(p)!r}")
        kw["heights"] = arr
    return kw


@dataclass(frozen=True)
class Terrain:
    """A terrain: ``plane`` (default a level plane at z = 0; None: no plane), ``boxes`` (a
    sequence of :class:`Box`), ``heightfield`` (optional), and the contact parameters shared by
    the parts: ``friction`` (>= 0), ``stiffness`` (N/m, > 0), ``damping`` (s/m, >= 0)."""

    plane: Plane | None = field(default_factory=Plane)
    boxes: tuple = ()
    heightfield: Heightfield | None = None
    friction: float = 1.0
    stiffness: float = 1e4
    damping: float = 10.0

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
        s(self, "friction", _number(self.friction, "friction", lo=0.0))
        s(self, "stiffness", _number(self.stiffness, "stiffness", lo=0.0, lo_open=True))
        s(self, "damping", _number(self.damping, "damping", lo=0.0))

    # ------------------------------------------------------------------ files
    @classmethod
    def from_dict(cls, d, base_dir=None) -> "Terrain":
        """A terrain from the file format's dict (see the module doc); ``base_dir``: where a
        heightfield ``file`` is looked up (default: the working directory)."""
        if not isinstance(d, dict):
            raise ValueError(f"terrain: expected an object, got {d!r}")
        keys = ("plane", "boxes", "heightfield") + SURFACE_KEYS
        unknown = sorted(set(d) - set(keys))
        if unknown:
            raise ValueError(f"terrain: unknown key {unknown[0]!r} (expected some of {list(keys)})")
        kw = {k: d[k] for k in SURFACE_KEYS if k in d}
        if "plane" in d:
            kw["plane"] = None if d["plane"] is None else _part(Plane, d["plane"], "plane",
                                                                ("slope_deg", "uphill_deg"))
        boxes = d.get("boxes", [])
        if not isinstance(boxes, list):
            raise ValueError(f"boxes: expected a list of boxes, got {boxes!r}")
        kw["boxes"] = tuple(_part(Box, b, f"boxes[{i}]", ("center", "size", "yaw_deg"),
                                     ("center", "size")) for i, b in enumerate(boxes))
        if d.get("heightfield") is not None:
            kw["heightfield"] = _part(Heightfield, d["heightfield"], "heightfield",
                                      ("file", "heights", "cell", "origin"), ("cell",), base_dir)
        return cls(**kw)

    @classmethod
    def from_file(cls, path, defaults: dict | None = None) -> "Terrain":
        """A terrain from a JSON file (a heightfield ``file`` relative to the JSON file's folder);
        ``defaults``: top-level keys (e.g. contact values) taken where the file has none."""
        p = Path(path)
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except OSError as e:
            raise ValueError(f"terrain file: cannot read {str(p)!r}: {e.strerror or e}") from None
        except json.JSONDecodeError as e:
            raise ValueError(f"terrain file: not valid JSON ({str(p)!r}, line {e.lineno}: {e.msg})") from None
        if defaults and isinstance(d, dict):
            d = {**defaults, **d}
        return cls.from_dict(d, base_dir=p.parent)

    def surface(self, part) -> tuple:
        """(friction, stiffness N/m, damping s/m) of ``part``: its overrides, else the terrain's."""
        return tuple(getattr(self, k) if getattr(part, k) is None else getattr(part, k) for k in SURFACE_KEYS)

    # ------------------------------------------------------------------ geometry
    def height_at(self, x, y) -> np.ndarray:
        """Height of the terrain's top surface (m) at (x, y) m (arrays of one shape): the highest of
        the plane, the tops of the boxes over (x, y) and the heightfield; -inf where none is."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        h = np.full(x.shape, -np.inf)
        if self.plane is not None:
            n = self.plane.normal
            h = np.maximum(h, -(n[0] * x + n[1] * y) / n[2])
        for b in self.boxes:
            R = b.rotation
            dx, dy = x - b.center[0], y - b.center[1]
            u, v = R[0, 0] * dx + R[1, 0] * dy, R[0, 1] * dx + R[1, 1] * dy
            inside = (np.abs(u) <= b.size[0] / 2) & (np.abs(v) <= b.size[1] / 2)
            h = np.where(inside, np.maximum(h, b.center[2] + b.size[2] / 2), h)
        if self.heightfield is not None:
            h = np.maximum(h, self.heightfield.height_at(x, y))
        return h

    def parts(self) -> list:
        """The solids in the physics' feature order: the plane (if any), then the boxes, then the heightfield."""
        return ([] if self.plane is None else [self.plane]) + list(self.boxes) + \
            ([] if self.heightfield is None else [self.heightfield])

    def closest(self, points, per_part: bool = False):
        """Signed distance (m; < 0 inside a solid) of ``points`` (..., 3) m to the terrain and the
        outward unit normal there (..., 3): the nearest of the parts (``per_part=True``: each
        part's, with a leading axis in :meth:`parts` order). Exact for the plane and the boxes;
        for the heightfield the vertical gap times the cosine of the local slope, with the
        normal of the bilinear patch under the point (exact on a locally planar patch; the
        contact measures the vertical gap itself, :meth:`Heightfield.gap`)."""
        p = np.asarray(points, float)
        ds, ns = [], []
        for part in self.parts():
            d, n = _closest_part(part, p)
            ds.append(d)
            ns.append(n)
        if not ds:
            return np.full(p.shape[:-1], np.inf), np.zeros(p.shape)
        D, N = np.stack(ds), np.stack(ns)
        if per_part:
            return D, N
        i = np.argmin(D, axis=0)
        return np.take_along_axis(D, i[None], 0)[0], np.take_along_axis(N, i[None, ..., None], 0)[0]


def _closest_part(part, p):
    """Signed distance and outward normal of ``p`` (..., 3) to one part."""
    if isinstance(part, Plane):
        n = part.normal
        return p @ n, np.broadcast_to(n, p.shape).copy()
    if isinstance(part, Box):
        R, h = part.rotation, part.size / 2
        loc = (p - part.center) @ R                 # box coordinates
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
    h, gx, gy = part._interp(p[..., 0], p[..., 1])
    c = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    return (p[..., 2] - h) * c, np.stack([-gx * c, -gy * c, c], axis=-1)
