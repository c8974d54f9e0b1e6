"""Heightfield geometry of the torch terrain contact (:mod:`tensegrity_gym.backends.torch.terrain`),
batched: the bilinear height and gradient, the slope bound and the lowest point of every rod's
axis above the surface. The numba module :mod:`tensegrity_gym.backends.numba.heightfield` on
tensors, with its arithmetic (see there for the contact measure, the vertical gap, and the exact
search over the cells a rod crosses). SI units: m.
"""
from __future__ import annotations

from ..numba.heightfield import LEVEL_TOL
from .model import _torch

__all__ = ["hf_at", "hf_patch", "hf_lipschitz", "hf_lowest"]


def hf_at(p0, p1, r0, r1, part):
    """Bilinear height (m) at points (p0, p1) of the cells holding the reference points (r0, r1)
    (leading axis the copies), the gradient (dh/dx, dh/dy) and the twist (1/m), 0 across a held
    edge: the numba ``hf_at``. ``part`` the heightfield part
    (:class:`tensegrity_gym.backends.torch.terrain_kinds._Part`: geom rows ``g`` (G, 10), heights ``H``
    (1 or B, ny, nx), its columns shaped by ``col``)."""
    torch = _torch()
    H = part.H
    x0, y0, cell = part.col(1, p0), part.col(2, p0), part.col(3, p0)
    ny, nx = H.shape[1], H.shape[2]
    ur = (r0 - x0) / cell
    vr = (r1 - y0) / cell
    out_u = (ur < 0.0) | (ur > nx - 1)
    out_v = (vr < 0.0) | (vr > ny - 1)
    i = torch.floor(ur.clamp(0.0, nx - 1.0)).clamp(max=nx - 2)
    j = torch.floor(vr.clamp(0.0, ny - 1.0)).clamp(max=ny - 2)
    u = ((p0 - x0) / cell).clamp(0.0, nx - 1.0)
    v = ((p1 - y0) / cell).clamp(0.0, ny - 1.0)
    fu, fv = u - i, v - j
    gu, gv = 1 - fu, 1 - fv
    idx = j.long() * nx + i.long()
    if H.shape[0] == 1:
        flat = H[0].reshape(-1)

        def take(o):
            return flat[idx + o]
    else:
        flat = H.reshape(H.shape[0], -1)
        rows = idx.reshape(idx.shape[0], -1)

        def take(o):
            return torch.gather(flat, 1, rows + o).reshape(idx.shape)
    h00, h10, h01, h11 = take(0), take(1), take(nx), take(nx + 1)
    h = gu * gv * h00 + fu * gv * h10 + gu * fv * h01 + fu * fv * h11
    zero = torch.zeros_like(h)
    gx = torch.where(out_u, zero, (gv * (h10 - h00) + fv * (h11 - h01)) / cell)
    gy = torch.where(out_v, zero, (gu * (h01 - h00) + fu * (h11 - h10)) / cell)
    tw = torch.where(out_u | out_v, zero, (h11 - h10 - h01 + h00) / (cell * cell))
    return h, gx, gy, tw


def hf_patch(p0, p1, part):
    """Bilinear height (m) and gradient at points (p0, p1), the cell under each point."""
    h, gx, gy, _ = hf_at(p0, p1, p0, p1, part)
    return h, gx, gy


def hf_lipschitz(g, H):
    """``sqrt(1 + L^2)`` per copy row (G or B, 1): the numba ``hf_lipschitz`` (largest height
    step between grid neighbours along x and along y, over the cell)."""
    torch = _torch()
    mx = (H[:, :, 1:] - H[:, :, :-1]).abs().amax(dim=(1, 2))
    my = (H[:, 1:, :] - H[:, :-1, :]).abs().amax(dim=(1, 2))
    cell = g[:, 3]
    return torch.sqrt(1.0 + (mx * mx + my * my) / (cell * cell)).reshape(-1, 1)


def _crossings(a, c, n, origin, cell, r, b, ea, ec, most: int):
    """Rod coordinates (B, k, M) of the crossings of grid lines 0..n-1 strictly between the grid
    coordinates a and c (the numba ``hf_lines`` and ``hf_cross``), ``ec`` past each rod's count:
    M the most any rod has (one device read) or, under ``torch.compile``, ``most`` (the
    layout's bound: no rod has more)."""
    torch = _torch()
    up, down = c > a, c < a
    m0 = torch.where(up, (torch.floor(a) + 1).clamp(min=0), (torch.ceil(a) - 1).clamp(max=n - 1))
    count = torch.where(up, (torch.ceil(c) - 1).clamp(max=n - 1) - m0 + 1,
                        m0 - (torch.floor(c) + 1).clamp(min=0) + 1).clamp(min=0)
    count = torch.where(up | down, count, torch.zeros_like(count))
    step = torch.where(up, torch.ones_like(a), -torch.ones_like(a))
    M = most if torch.compiler.is_compiling() else (int(count.max()) if count.numel() else 0)
    t = torch.arange(M, dtype=a.dtype, device=a.device)
    m = m0[..., None] + step[..., None] * t
    e = torch.minimum(torch.maximum((origin[..., None] + m * cell[..., None] - r[..., None]) / b[..., None],
                                    ea[..., None]), ec[..., None])
    return torch.where(t < count[..., None], e, ec[..., None].expand_as(e))


def hf_lowest(ea, ec, r, b, part):
    """The lowest point of every rod axis ``r + eta b`` (r, b (B, k, 3)), eta in [ea, ec] (B, k),
    above the heightfield ``part`` (as :func:`hf_at` takes it, with its ``crossings`` bound): the
    numba ``hf_lowest`` on tensors (every breakpoint, stationary point and level run at once).
    Returns ``(eta, deeper, gx, gy)`` (B, k)."""
    torch = _torch()
    r0, r1, r2 = r[..., 0], r[..., 1], r[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    x0, y0, cell = part.col(1, r0), part.col(2, r0), part.col(3, r0)
    ny, nx = part.H.shape[1], part.H.shape[2]
    em = 0.5 * (ea + ec)
    X = _crossings((r0 + ea * b0 - x0) / cell, (r0 + ec * b0 - x0) / cell, nx, x0.expand_as(r0),
                   cell.expand_as(r0), r0, b0, ea, ec, part.crossings[0])
    Y = _crossings((r1 + ea * b1 - y0) / cell, (r1 + ec * b1 - y0) / cell, ny, y0.expand_as(r0),
                   cell.expand_as(r0), r1, b1, ea, ec, part.crossings[1])
    E = torch.cat([ea[..., None], torch.sort(torch.cat([X, Y], -1), -1).values, ec[..., None]], -1)
    R0, R1, R2 = r0[..., None], r1[..., None], r2[..., None]
    B0, B1, B2 = b0[..., None], b1[..., None], b2[..., None]

    def gap(e, ref=None):
        px, py = R0 + e * B0, R1 + e * B1
        h, gx, gy, tw = hf_at(px, py, px, py, part) if ref is None else hf_at(px, py, R0 + ref * B0,
                                                                                R1 + ref * B1, part)
        return R2 + e * B2 - h, gx, gy, tw
    gE = gap(E)[0]
    lo, hi = E[..., :-1], E[..., 1:]
    K = lo.shape[-1]
    nondeg = hi > lo
    mid = 0.5 * (lo + hi)
    gmid, gxm, gym, tw = gap(mid)
    curv = -2.0 * tw * B0 * B1
    pos = curv > 0.0
    s = mid - (B2 - gxm * B0 - gym * B1) / torch.where(pos, curv, torch.ones_like(curv))
    ok = nondeg & pos & (lo < s) & (s < hi)
    s = torch.where(ok, s, mid)
    gs, gxs, gys, _ = gap(s, mid)
    inf = torch.full_like(gs, float("inf"))
    cand = torch.cat([torch.stack([gE[..., :-1], torch.where(ok, gs, inf)], -1).flatten(-2), gE[..., -1:]], -1)
    c = cand.argmin(-1, keepdim=True)
    fmin = cand.gather(-1, c)
    deeper = fmin[..., 0] < torch.minimum(gE[..., 0], gE[..., -1]) - LEVEL_TOL
    # the level run around the lowest candidate (the numba _level_run)
    level = torch.maximum(gE[..., :-1], torch.maximum(gmid, gE[..., 1:])) <= fmin + LEVEL_TOL
    P = torch.arange(K, device=E.device)
    il, ir = c // 2, (c + 1) // 2
    pl = torch.where(~level & (P < il), P + 1, torch.zeros_like(P)).amax(-1, keepdim=True)
    pr = torch.where(~level & (P >= ir), P, torch.full_like(P, K)).amin(-1, keepdim=True)
    left, right = E.gather(-1, pl), E.gather(-1, pr)
    i = il.clamp(max=K - 1)
    odd = (c % 2 == 1)
    alone = odd & ~level.gather(-1, i)                          # a stationary point, not in a level run
    e = torch.where(alone, s.gather(-1, i), 0.5 * (left + right))
    # the gradient: the cell's at a stationary point, the kink's combination at a breakpoint,
    # the cell's under the middle of a level run
    Ei = E.gather(-1, il)
    q = torch.where(nondeg & (P >= il), P, torch.full_like(P, K - 1)).amin(-1, keepdim=True)
    _, gxl, gyl, _ = gap(Ei, mid.gather(-1, (il - 1).clamp(min=0)))
    _, gxr, gyr, _ = gap(Ei, mid.gather(-1, q))
    dl = B2 - gxl * B0 - gyl * B1
    dr = B2 - gxr * B0 - gyr * B1
    lam = torch.where(dr > dl, (-dl / torch.where(dr > dl, dr - dl, torch.ones_like(dl))).clamp(0.0, 1.0),
                      torch.full_like(dl, 0.5))
    gx = torch.where(odd, gxs.gather(-1, i), gxl + lam * (gxr - gxl))
    gy = torch.where(odd, gys.gather(-1, i), gyl + lam * (gyr - gyl))
    run = left < right
    _, gxe, gye = hf_patch(R0 + e * B0, R1 + e * B1, part)
    gx = torch.where(run, gxe, gx)[..., 0]
    gy = torch.where(run, gye, gy)[..., 0]
    return torch.where(deeper, e[..., 0], em), deeper, gx, gy
