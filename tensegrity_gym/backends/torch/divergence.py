"""Divergence check on tensors: which copies went non-finite or far."""
from __future__ import annotations

from .model import _torch

__all__ = ["diverged"]


def diverged(q, qd, center, limit: float, local: bool = False):
    """(B,) bool, :func:`tensegrity_gym.physics.diverged` in torch: copy b has a non-finite entry
    in ``q``/``qd`` (B, k, 6), or a rod reference point farther than ``limit`` m (per
    coordinate) from ``center`` (3,) m (a tensor on q's device and dtype); with ``local`` (a
    robot that travels) from its copy's mean reference point instead, that mean's height checked
    against ``float(center[2])`` (horizontal travel is not limited)."""
    torch = _torch()
    finite = torch.isfinite(q).all(dim=2).all(dim=1) & torch.isfinite(qd).all(dim=2).all(dim=1)
    r = q[..., :3]
    r = torch.where(torch.isfinite(r), r, torch.zeros_like(r))
    if local:
        m = r.mean(dim=1, keepdim=True)
        far = ~(((r - m).abs().amax(dim=(1, 2)) <= limit) & ((m[:, 0, 2] - float(center[2])).abs() <= limit))
    else:
        far = ~((r - center).abs().amax(dim=(1, 2)) <= limit)
    return ~finite | far


