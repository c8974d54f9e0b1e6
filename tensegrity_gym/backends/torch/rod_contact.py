"""Rod-rod contact on tensors: the capsule contact of :mod:`tensegrity_gym.physics.rod_contact`
(the numba backend's :mod:`tensegrity_gym.backends.numba.rod_contact`), every rod pair at once.
Out-of-place operations only (differentiable; at a switch the gradient of the branch taken, as
the ground contact's). SI units.
"""
from __future__ import annotations

from .contact import contact_forces
from .driver import step_once
from .model import TorchModel, _torch, torch_model
from .terrain import _forces as terrain_forces_prepared

__all__ = ["rod_contact_forces", "segment_closest", "rod_contact_substep", "rod_terrain_substep"]

#: segments whose sin^2 of the angle between them is below this are treated as parallel (the numba backend's)
PARALLEL_SIN2 = 1e-12


def _dot(x, y):
    return (x * y).sum(-1)


def segment_closest(d1, d2, r):
    """``(s, t)`` in [0, 1]: the parameters of the closest points ``P1 + s d1``, ``P2 + t d2`` of
    two segments (``r = P1 - P2``; (..., 3) tensors of nonzero lengths), as the numba backend's
    ``closest_params``: the lines' closest points clamped and corrected once each way; parallel
    segments: the middle of the overlap, or the first's end nearest to the second."""
    torch = _torch()
    a, e, b = _dot(d1, d1), _dot(d2, d2), _dot(d1, d2)
    c, f = _dot(d1, r), _dot(d2, r)
    denom = a * e - b * b
    general = denom > PARALLEL_SIN2 * a * e
    s_gen = torch.clamp((b * f - c * e) / torch.where(general, denom, torch.ones_like(denom)), 0.0, 1.0)
    s0 = -c / a
    s1 = s0 + b / a
    lo = torch.clamp(torch.minimum(s0, s1), min=0.0)
    hi = torch.clamp(torch.maximum(s0, s1), max=1.0)
    s_par = torch.where(lo <= hi, 0.5 * (lo + hi), torch.where(hi < 0.0, torch.zeros_like(hi), torch.ones_like(hi)))
    s = torch.where(general, s_gen, s_par)
    t = (b * s + f) / e
    s = torch.where(t < 0.0, torch.clamp(-c / a, 0.0, 1.0), torch.where(t > 1.0, torch.clamp((b - c) / a, 0.0, 1.0), s))
    return s, torch.clamp(t, 0.0, 1.0)


def _fallback_normal(d1, d2, g):
    """Unit normal where two axes meet: the normal of their plane (a perpendicular of the first
    where they are parallel too), pointing along ``g`` (centre of rod i minus centre of rod j)."""
    torch = _torch()
    x = torch.cross(d1, d2, dim=-1)
    nx = torch.sqrt(_dot(x, x))
    zero = torch.zeros_like(d1[..., 0])
    perp = torch.stack([d1[..., 1], -d1[..., 0], zero], dim=-1)
    vert = perp[..., 0] ** 2 + perp[..., 1] ** 2 < 1e-6 * _dot(d1, d1)
    perp = torch.where(vert[..., None], torch.stack([zero, d1[..., 2], -d1[..., 1]], dim=-1), perp)
    ok = nx > 1e-12 * torch.sqrt(_dot(d1, d1) * _dot(d2, d2))
    x = torch.where(ok[..., None], x, perp)
    x = x / torch.sqrt(_dot(x, x))[..., None]
    return torch.where((_dot(x, g) < 0.0)[..., None], -x, x)


def rod_contact_forces(rc, model, q, qd):
    """(B, n, 3) N: the rod-rod contact forces at ``q``, ``qd`` (B, k, 6) tensors (m, m/s), as
    :func:`tensegrity_gym.physics.rod_contact.rod_contact_forces` (``rc`` a
    :class:`~tensegrity_gym.physics.rod_contact.RodContact`; ``model`` a Model or a
    :class:`TorchModel` on ``q``'s device and dtype): every pair i < j, the force at a closest
    point split between the rod's nodes by its parameter."""
    torch = _torch()
    tm = model if isinstance(model, TorchModel) else torch_model(model, q.device, q.dtype)
    k = tm.k
    I, J = torch.triu_indices(k, k, 1, device=q.device)
    r, b, rd, bd = q[..., :3], q[..., 3:], qd[..., :3], qd[..., 3:]
    A, C = r + tm.eta_a * b, r + tm.eta_c * b                 # (B, k, 3)
    VA, VC = rd + tm.eta_a * bd, rd + tm.eta_c * bd
    d1, d2 = C[:, I] - A[:, I], C[:, J] - A[:, J]              # (B, P, 3)
    s, t = segment_closest(d1, d2, A[:, I] - A[:, J])
    nv = (A[:, I] + s[..., None] * d1) - (A[:, J] + t[..., None] * d2)
    dist2 = _dot(nv, nv)
    dist = torch.sqrt(torch.where(dist2 > 0, dist2, torch.ones_like(dist2))) * (dist2 > 0)
    delta = 2.0 * rc.radius - dist
    touch = delta > 0.0
    far = dist > 1e-12
    n = torch.where(far[..., None], nv / torch.where(far, dist, torch.ones_like(dist))[..., None],
                    _fallback_normal(d1, d2, r[:, I] - r[:, J]))
    v = (VA[:, I] + s[..., None] * (VC[:, I] - VA[:, I])) - (VA[:, J] + t[..., None] * (VC[:, J] - VA[:, J]))
    vn = _dot(v, n)
    cn = min(rc.damping, rc.max_damping)
    fn = torch.clamp(rc.stiffness * delta - cn * vn, min=0.0)
    F = fn[..., None] * n
    if rc.friction > 0:
        vt = v - vn[..., None] * n
        sp2 = _dot(vt, vt)
        speed = torch.sqrt(torch.where(sp2 > 0, sp2, torch.ones_like(sp2))) * (sp2 > 0)
        ct = torch.clamp(rc.friction * fn / torch.clamp(speed, min=rc.friction_speed), max=rc.max_damping)
        F = F - ct[..., None] * vt
    F = torch.where(touch[..., None], F, torch.zeros_like(F))
    zero = torch.zeros_like(A)
    Fa = zero.index_add(1, I, (1.0 - s)[..., None] * F).index_add(1, J, -(1.0 - t)[..., None] * F)
    Fc = zero.index_add(1, I, s[..., None] * F).index_add(1, J, -t[..., None] * F)
    return tm.gather_nodes(Fa, Fc)


def rod_contact_substep(rc):
    """A replacement for :func:`tensegrity_gym.backends.torch.contact.contact_substep` (same
    signature) that adds the rod-rod contact forces of ``rc`` (a
    :class:`~tensegrity_gym.physics.rod_contact.RodContact`) after the ground's and the external
    force, as the numba loop driver does: what the device env runs with ``rod_contact``."""
    def substep(tm, contact, q, qd, anchor, active, dt, name, prm, rl, fd, ext, contact_prm, project_):
        W, anchor, active, _ = contact_forces(contact, tm, q, qd, anchor, active, contact_prm)
        if ext is not None:
            W = W + ext
        W = W + rod_contact_forces(rc, tm, q, qd)
        q, qd = step_once(tm, q, qd, dt, name, prm, rl, fd, W, project_)
        return q, qd, anchor, active
    return substep


def rod_terrain_substep(rc):
    """:func:`rod_contact_substep` for terrain contact: a replacement for
    :func:`tensegrity_gym.backends.torch.terrain.terrain_substep` (same signature)."""
    def substep(tm, layout, geom, prm, H, lips, q, qd, anchor, eta0, active, dt, name, p, rl, fd, ext, project_):
        W, anchor, eta0, active, _ = terrain_forces_prepared(tm, layout, geom, prm, H, lips, q, qd, anchor, eta0,
                                                             active)
        if ext is not None:
            W = W + ext
        W = W + rod_contact_forces(rc, tm, q, qd)
        q, qd = step_once(tm, q, qd, dt, name, p, rl, fd, W, project_)
        return q, qd, anchor, eta0, active
    return substep
