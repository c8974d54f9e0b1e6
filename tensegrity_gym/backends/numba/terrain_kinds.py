"""The terrain kinds of the numba backend, one row each: the kind's code (column 0 of a ``geom``
row) and the packing of a part of that kind into its ``geom`` row. The kernels dispatch on the
code (:func:`.terrain._closest`, :func:`.terrain.rows_forces`); a part of a kind without a row
here, or a ``geom`` array with a code that is not a row's, is refused on the host with an error
naming the kind (:func:`geom_row`, :func:`check_codes`): a numba kernel does not raise, and a code
the dispatch does not know must never reach it. SI units: m.

Arrays (built by :mod:`tensegrity_gym.physics.terrain`):

* ``geom`` (G, F, 10), G = 1 (shared) or B (one terrain per copy): feature f's kind code in
  column 0 (:data:`PLANE` = 0: outward normal (1:4) and offset (4), the solid is
  ``n.p <= offset``; :data:`BOX` = 1: centre (1:4) m, half sizes (4:7) m, cos and sin of the
  yaw (7:9); :data:`HFIELD` = 2: grid origin x0, y0 (1:3) m, cell size (3) m, grid rows ny
  and columns nx (4:6), ``sqrt(1 + L^2)`` (6) for L the steepest slope of its heights (the
  "too far to touch" bound; 0: computed from ``hf`` at each call), the rest 0).
* ``hf`` (H, ny, nx), H = 1 (shared) or B: the heightfield's heights m, ``hf[., j, i]`` at
  ``x = x0 + i cell``, ``y = y0 + j cell``, bilinear in between, the edge values held outside
  the grid (:meth:`tensegrity_gym.core.terrain.Heightfield.gap` is the NumPy oracle). At most
  one heightfield per terrain; without one, a (1, 1, 1) array that nothing reads.
* ``prm`` (P, F, 8), P = 1 or B: per feature the contact parameters ``radius`` m, ``kn``
  N/m^e, ``dn`` s/m, exponent ``e``, ``mu``, ``kt`` N/m, ``ct`` N s/m, ``cmax`` N s/m.
"""
from __future__ import annotations

import math

import numpy as np

from ...core.terrain_kinds import kind_of

__all__ = ["PLANE", "BOX", "HFIELD", "KINDS", "geom_row", "check_codes", "hf_bound"]

#: kind codes (column 0 of ``geom``)
PLANE = 0.0
BOX = 1.0
HFIELD = 2.0


def _plane_row(part, row):
    row[1:4] = part.normal


def _box_row(part, row):
    yaw = math.radians(part.yaw_deg)
    row[1:4] = part.center
    row[4:7] = part.size / 2
    row[7:9] = math.cos(yaw), math.sin(yaw)


def _hfield_row(part, row):
    row[1:3] = part.origin
    row[3] = part.cell
    row[4:6] = part.heights.shape
    row[6] = hf_bound(part.heights, part.cell)
    return part.heights[None]           # the kernel's hf: read-only, as the Heightfield's own


#: kind name (:mod:`tensegrity_gym.core.terrain_kinds`) -> (code, packer): the packer writes a
#: part's geometry into columns 1.. of its geom row and returns its heights (1, ny, nx) or None
KINDS = {"plane": (PLANE, _plane_row), "box": (BOX, _box_row), "heightfield": (HFIELD, _hfield_row)}


def geom_row(part):
    """``(row (10,), heights or None)``: the geom row of a terrain part; ValueError naming the
    part's kind where this backend has no row for it."""
    name = kind_of(part).name
    if name not in KINDS:
        raise ValueError(f"terrain kind {name!r}: the numba backend has no contact for it (no row in "
                         f"tensegrity_gym.backends.numba.terrain_kinds.KINDS; it has {sorted(KINDS)})")
    code, pack = KINDS[name]
    row = np.zeros(10)
    row[0] = code
    return row, pack(part, row)


def check_codes(geom, name: str = "geom") -> None:
    """ValueError naming the first feature of ``geom`` (G, F, 10) whose kind code (column 0) is
    not a row of :data:`KINDS`, its index and value."""
    k = np.asarray(geom)[..., 0]
    known = np.zeros(k.shape, bool)
    for code, _ in KINDS.values():
        known |= k == code
    if not known.all():
        idx = tuple(int(i) for i in np.argwhere(~known)[0])
        codes = ", ".join(f"{c:g} {n}" for n, (c, _) in KINDS.items())
        raise ValueError(f"{name}[{', '.join(map(str, idx))}, 0]: unknown terrain kind code {float(k[idx])!r} "
                         f"(the numba backend's kinds: {codes})")


def hf_bound(heights: np.ndarray, cell: float) -> float:
    """``sqrt(1 + L^2)``, L bounding the slope of the bilinear heightfield ``heights`` (ny, nx) m on
    a grid of ``cell`` m (largest step along x and along y over the cell): column 6 of its geom row,
    the bound of the kernel's "too far to touch" test (the kernel's own ``hf_lipschitz``, one
    pass over the heights)."""
    from .heightfield import hf_lipschitz
    h = np.ascontiguousarray(heights, dtype=np.float64)
    row = np.zeros(10)
    row[0], row[3], row[4], row[5] = HFIELD, cell, h.shape[0], h.shape[1]
    return float(hf_lipschitz(row, h))
