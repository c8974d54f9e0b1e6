"""The terrain kinds of the torch backend, one row each of :data:`KINDS` (keyed by the kind codes of
the geom rows, :mod:`tensegrity_gym.backends.numba.terrain_kinds`): a kind's contact measure and
outward normal on tensors and the height of its top, plus the boxes' interior search and its lower
bound (the numba :mod:`tensegrity_gym.backends.numba.terrain_box` on tensors). A kind code without
a row is refused with an error naming it (:func:`check_kinds`, when a layout is read). SI units.
"""
from __future__ import annotations

import math

import numpy as np

from ..numba.heightfield import LEVEL_TOL
from ..numba.terrain_box import BOUND_CUTS, BOUND_SLACK, GOLDEN_ITERS
from ..numba.terrain_kinds import BOX, HFIELD, PLANE
from .heightfield import hf_patch
from .model import _torch

__all__ = ["KINDS", "check_kinds", "top_height"]

_GR = 0.6180339887498949


def _host(x):
    """``x`` (an array or a tensor) as a NumPy array on the host."""
    torch = _torch()
    return np.asarray(x.detach().cpu()) if isinstance(x, torch.Tensor) else np.asarray(x, dtype=float)


class _Part:
    """Terrain parts of one kind: their geom rows ``g`` (G, f, 10) (f feature columns, every row
    of one column of the part's kind), the heightfield heights ``H``, the ``kind`` and grid
    ``crossings`` (of the :class:`TerrainLayout`); the columns shaped once per rank of the
    points they meet (the box search evaluates the distance ~90 times a step; the heightfield's
    functions in :mod:`tensegrity_gym.backends.torch.heightfield` take the part too). With f > 1
    (boxes searched together) the points have the axes (copies, rods, features, ...)."""

    def __init__(self, g, H, kind: float, crossings=(0, 0)):
        self.g, self.H, self.kind, self.crossings = g, H, kind, crossings
        self._cols: dict = {}

    def col(self, i: int, like):
        """Column i, shaped to broadcast against the points ``like`` (leading axis: the copies;
        with f > 1 features, the third their features)."""
        key = (i, like.ndim)
        c = self._cols.get(key)
        if c is None:
            f = self.g.shape[1]
            shape = (-1,) + (1,) * (like.ndim - 1) if f == 1 else (-1, 1, f) + (1,) * (like.ndim - 3)
            c = self._cols[key] = self.g[:, :, i].reshape(shape)
        return c


def _box(p0, p1, p2, cols, normal: bool = True):
    """Signed distance and outward normal of points (p0, p1, p2) to the boxes of the geom columns
    1-8 ``cols`` (centre, half sizes, yaw cosine and sine; rows broadcast against the points'
    leading axis) (as the numba ``_box_closest``); the distance alone with ``normal=False`` (the
    same number)."""
    torch = _torch()
    cx, cy, cz, hx, hy, hz, c, s = cols
    dx, dy, dz = p0 - cx, p1 - cy, p2 - cz
    l0 = c * dx + s * dy
    l1 = (-s) * dx + c * dy
    l2 = dz
    q0, q1, q2 = l0.abs() - hx, l1.abs() - hy, l2.abs() - hz
    o0, o1, o2 = q0.clamp(min=0.0), q1.clamp(min=0.0), q2.clamp(min=0.0)
    dout = torch.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
    out = dout > 0.0
    # inside: the nearest face, the first of the largest q (numba's sequential comparisons)
    a1 = q1 > q0
    d = torch.where(a1, q1, q0)
    a2 = q2 > d
    d = torch.where(a2, q2, d)
    if not normal:
        return torch.where(out, dout, d)
    one = torch.ones_like(l0)
    s0, s1, s2 = (torch.where(x >= 0.0, one, -one) for x in (l0, l1, l2))
    safe = torch.where(out, dout, one)
    zero = torch.zeros_like(l0)
    n0 = torch.where(out, s0 * o0 / safe, torch.where(a1 | a2, zero, s0))
    n1 = torch.where(out, s1 * o1 / safe, torch.where(a1 & ~a2, s1, zero))
    n2 = torch.where(out, s2 * o2 / safe, torch.where(a2, s2, zero))
    d = torch.where(out, dout, d)
    return d, c * n0 - s * n1, s * n0 + c * n1, n2


def _hf_normal(gx, gy):
    """The unit normal of a surface of height gradient (gx, gy) and the length of its
    unnormalised normal ``|(-gx, -gy, 1)|``, the gradient of the vertical gap (the numba
    ``_hf_normal``)."""
    w = _torch().sqrt(1.0 + gx * gx + gy * gy)
    return -gx / w, -gy / w, 1.0 / w, w


def _plane_closest(p0, p1, p2, part, normal: bool = True):
    """A plane's signed distance (the solid ``n.p <= offset``) and outward normal."""
    torch = _torch()
    nx, ny, nz, off = (part.col(i, p0) for i in range(1, 5))
    d = nx * p0 + ny * p1 + nz * p2 - off
    return (d, nx.expand_as(p0), ny.expand_as(p0), nz.expand_as(p0), torch.ones_like(p0)) if normal else d


def _box_closest(p0, p1, p2, part, normal: bool = True):
    """The boxes' signed distance and outward normal (:func:`_box`)."""
    cols = tuple(part.col(i, p0) for i in range(1, 9))
    if not normal:
        return _box(p0, p1, p2, cols, False)
    return _box(p0, p1, p2, cols) + (_torch().ones_like(p0),)


def _hf_closest(p0, p1, p2, part, normal: bool = True):
    """The heightfield's vertical gap and the normal of the bilinear patch."""
    h, gx, gy = hf_patch(p0, p1, part)
    if not normal:
        return p2 - h
    return (p2 - h,) + _hf_normal(gx, gy)


def _plane_top(x, y, part):
    n0, n1, n2, off = (part.col(i, x) for i in range(1, 5))
    return (off - (n0 * x + n1 * y)) / n2


def _box_top(x, y, part):
    torch = _torch()
    cx, cy, cz, hx, hy, hz, c, s = (part.col(i, x) for i in range(1, 9))
    dx, dy = x - cx, y - cy
    inside = ((c * dx + s * dy).abs() <= hx) & (((-s) * dx + c * dy).abs() <= hy)
    return torch.where(inside, cz + hz, torch.full_like(x, -math.inf))


def _hf_top(x, y, part):
    return hf_patch(x, y, part)[0]


#: kind code (:mod:`tensegrity_gym.backends.numba.terrain_kinds`, the geom rows are the numba
#: backend's) -> (name, contact measure ``closest(p0, p1, p2, part, normal)``, ``top(x, y, part)``)
KINDS = {PLANE: ("plane", _plane_closest, _plane_top), BOX: ("box", _box_closest, _box_top),
         HFIELD: ("heightfield", _hf_closest, _hf_top)}


def check_kinds(kinds) -> None:
    """ValueError naming the first feature whose kind code is not a row of :data:`KINDS`."""
    for f, kind in enumerate(kinds):
        if kind not in KINDS:
            have = ", ".join(f"{c:g} {v[0]}" for c, v in KINDS.items())
            raise ValueError(f"geom[:, {f}, 0]: unknown terrain kind code {kind!r} (the torch backend's kinds: {have})")


def _closest(p0, p1, p2, part, normal: bool = True):
    """Contact measure of points against the terrain part ``part`` (:class:`_Part`): (signed
    distance or a heightfield's vertical gap, outward unit normal, w), the measure's gradient
    ``w n`` (the numba ``_closest``), by the part's row of :data:`KINDS`; the measure alone with
    ``normal=False`` (the same number)."""
    return KINDS[part.kind][1](p0, p1, p2, part, normal)


def _interior(ea, ec, r, b, part):
    """The interior contact point of every rod against the boxes ``part``, (eta, deeper) (B, k,
    f): the numba ``_interior`` on tensors (golden section, then the middle of the level set, its
    two ends bisected together). ``ea``, ``ec`` (B, k, f), ``r``, ``b`` (B, k, 1, 3)."""
    torch = _torch()

    rb = [r[..., i] for i in range(3)] + [b[..., i] for i in range(3)]     # (B, k, 1), taken once

    def sd(e):
        x = rb if e.ndim == 3 else [v[..., None] for v in rb]
        return _closest(x[0] + e * x[3], x[1] + e * x[4], x[2] + e * x[5], part, normal=False)
    fa, fc = sd(ea), sd(ec)
    lo, hi = ea, ec
    x1 = hi - _GR * (hi - lo)
    x2 = lo + _GR * (hi - lo)
    f1, f2 = sd(x1), sd(x2)
    for _ in range(GOLDEN_ITERS):
        c = f1 <= f2
        hi_n = torch.where(c, x2, hi)
        lo_n = torch.where(c, lo, x1)
        x1_n = torch.where(c, hi_n - _GR * (hi_n - lo_n), x2)
        x2_n = torch.where(c, x1, lo_n + _GR * (hi_n - lo_n))
        fe = sd(torch.where(c, x1_n, x2_n))
        f1, f2 = torch.where(c, fe, f2), torch.where(c, f1, fe)
        lo, hi, x1, x2 = lo_n, hi_n, x1_n, x2_n
    em = 0.5 * (lo + hi)
    fm = sd(em)
    deeper = fm < torch.minimum(fa, fc) - LEVEL_TOL
    level = (fm + LEVEL_TOL)[..., None]
    # the level set's ends: [ea, em] where the distance falls to the level, [em, ec] where it rises
    a, bb = torch.stack([ea, em], dim=-1), torch.stack([em, ec], dim=-1)
    rising = torch.tensor([False, True], device=ea.device)
    for _ in range(GOLDEN_ITERS):
        mid = 0.5 * (a + bb)
        right = (sd(mid) > level) ^ rising
        a, bb = torch.where(right, mid, a), torch.where(right, bb, mid)
    return torch.where(deeper, 0.5 * (bb[..., 0] + a[..., 1]), em), deeper


def _passed_over(ea, ec, r, b, part, radius):
    """Where no interior point of a rod can touch the boxes ``part`` (B, k, f): the numba
    ``_box_dip_bound`` on tensors (the ends' tangent lines of the convex distance and
    ``BOUND_CUTS`` cutting-plane steps give a lower bound of the distance along the rod, above
    ``min(radius, sd_a - LEVEL_TOL, sd_c - LEVEL_TOL)``: the search would find no point that
    touches). ``ea``, ``ec`` (B, k, f), ``r``, ``b`` (B, k, 1, 3), ``radius`` (P, 1, f) m."""
    torch = _torch()
    r0, r1, r2, b0, b1, b2 = (x[..., i] for x in (r, b) for i in range(3))

    def at(e):                                   # distance and slope along the rod at eta e
        d, n0, n1, n2, _ = _closest(r0 + e * b0, r1 + e * b1, r2 + e * b2, part)
        return d, n0 * b0 + n1 * b1 + n2 * b2
    fa, sa = at(ea)
    fc, sc = at(ec)
    level = torch.minimum(radius, torch.minimum(fa, fc) - LEVEL_TOL) + BOUND_SLACK
    at_end = (sa >= 0.0) | (sc <= 0.0)
    ul, fl, sl, ur, fr, sr = torch.zeros_like(fa), fa, sa, ec - ea, fc, sc
    best = torch.full_like(fa, -math.inf)
    found = torch.zeros_like(at_end)
    for it in range(BOUND_CUTS + 1):
        den = torch.where(at_end, torch.ones_like(sr), sr - sl)
        u = torch.minimum(torch.maximum((fl - fr + sr * ur - sl * ul) / den, ul), ur)
        best = torch.maximum(best, torch.maximum(fl + sl * (u - ul), fr + sr * (u - ur)))
        if it == BOUND_CUTS:
            break
        fm, sm = at(ea + u)
        found = found | (fm <= level)
        right = sm >= 0.0
        ur, fr, sr = torch.where(right, u, ur), torch.where(right, fm, fr), torch.where(right, sm, sr)
        ul, fl, sl = torch.where(right, ul, u), torch.where(right, fl, fm), torch.where(right, sl, sm)
    bound = torch.where(sa >= 0.0, fa, torch.where(sc <= 0.0, fc, best))
    return (bound > level) & (at_end | ~found)


def top_height(geom, H, x, y, kinds=None):
    """Height (m) of the terrain's top surface at (x, y) m (tensors (r, ...), leading axis the
    copies): the highest of its parts' tops (each kind's row of :data:`KINDS`); -inf where none is
    (:meth:`tensegrity_gym.core.terrain.Terrain.height_at` on the kernels' rows). ``geom`` (1 or r,
    F, 10), ``H`` (1 or r, ny, nx) m or None, ``kinds`` each feature's kind (a layout's; None: read
    from ``geom``)."""
    torch = _torch()
    h = torch.full_like(x, -math.inf)
    if kinds is None:
        kinds = tuple(float(v) for v in _host(geom[0, :, 0]))
    check_kinds(kinds)
    for f, kind in enumerate(kinds):
        h = torch.maximum(h, KINDS[kind][2](x, y, _Part(geom[:, f:f + 1], H, kind)))
    return h
