"""Ground contact on tensors: Hunt-Crossley normal force with stick-slip Coulomb friction
(:func:`contact_forces`), and the contact sub-steps (:func:`contact_step`,
:func:`contact_substep`). SI units.
"""
from __future__ import annotations

from ...core.param_table import contact_columns
from .driver import prepare_steps, step_once
from .model import TorchModel, _torch, torch_model

__all__ = ["init_contact_state", "contact_forces", "contact_step", "contact_substep"]


#: the columns of the contact parameter rows (tensegrity_gym.core.param_table.contact_columns)
PRM_FIELDS = contact_columns()

def init_contact_state(tm_or_model, batch_size: int, device=None, dtype=None):
    """``(anchor (B, 2k, 2) m, active (B, 2k) bool)``: no contact active."""
    torch = _torch()
    tm = tm_or_model if isinstance(tm_or_model, TorchModel) else torch_model(tm_or_model, device, dtype)
    nc = 2 * tm.k
    return (torch.zeros((batch_size, nc, 2), dtype=tm.dtype, device=tm.device),
            torch.zeros((batch_size, nc), dtype=torch.bool, device=tm.device))


def contact_forces(contact, model, q, qd, anchor, active, prm=None):
    """Ground contact forces as the numba backend's ``_point_force`` (Hunt-Crossley normal force, Coulomb
    friction with a stick anchor): returns ``(W (B, n, 3) N, anchor, active, slip)``, the
    contact state as new tensors. ``contact``: a :class:`tensegrity_gym.physics.contact.GroundContact`.
    ``prm``: None (the contact's own numbers) or a (P, 9) tensor of per-copy parameters in the
    columns of :data:`tensegrity_gym.physics.contact.PRM_FIELDS` (as ``GroundContact.per_copy``; P = 1
    or B; the exponent stays the contact's)."""
    torch = _torch()
    tm = model if isinstance(model, TorchModel) else torch_model(model, q.device, q.dtype)
    B, k = q.shape[0], tm.k
    if prm is None:
        height, radius, kn, dn = contact.height, contact.radius, contact.stiffness, contact.damping
        friction, kt, ct, cmax = contact.friction, contact.tangential_stiffness, contact.tangential_damping, \
            contact.max_damping
    else:
        if not isinstance(prm, torch.Tensor) or prm.device != q.device:
            raise ValueError(f"prm: expected a (P, 9) tensor on {str(q.device)!r} (contact.PRM_FIELDS columns)")
        if prm.ndim != 2 or prm.shape[1] != 9 or prm.shape[0] not in (1, B):
            raise ValueError(f"prm: expected shape (1, 9) or ({B}, 9), got {tuple(prm.shape)}")
        prm = prm.to(q.dtype)
        col = {f: prm[:, i:i + 1] for i, f in enumerate(PRM_FIELDS)}
        height, radius, kn, dn = col["height"], col["radius"], col["stiffness"], col["damping"]
        friction, kt, ct, cmax = col["friction"], col["tangential_stiffness"], col["tangential_damping"], \
            col["max_damping"]
    r, b = q[..., :3], q[..., 3:]
    rd, bd = qd[..., :3], qd[..., 3:]
    # (B, k, 2, 3) -> (B, 2k, 3): rod j end a, rod j end c
    P = torch.stack([r + tm.eta_a * b, r + tm.eta_c * b], dim=2).reshape(B, 2 * k, 3)
    V = torch.stack([rd + tm.eta_a * bd, rd + tm.eta_c * bd], dim=2).reshape(B, 2 * k, 3)
    delta = height + radius - P[..., 2]
    touch = delta > 0.0
    zero = torch.zeros_like(delta)
    dpos = torch.where(touch, delta, zero)
    de = dpos if contact.exponent == 1.0 else dpos ** contact.exponent
    kd = kn * de
    cn = torch.minimum(kd * dn, torch.as_tensor(cmax, dtype=q.dtype, device=q.device))
    Fn = torch.where(touch, torch.clamp(kd - cn * V[..., 2], min=0.0), zero)
    pt = P[..., :2]
    anchor = torch.where((touch & ~active)[..., None], pt, anchor)
    xi = pt - anchor
    kt_, ct_ = (kt, ct) if prm is None else (kt[..., None], ct[..., None])
    Ft = -kt_ * xi - ct_ * V[..., :2]
    nn = Ft[..., 0] * Ft[..., 0] + Ft[..., 1] * Ft[..., 1]
    pos = nn > 0
    norm = torch.where(pos, torch.sqrt(torch.where(pos, nn, torch.ones_like(nn))), zero)
    lim = friction * Fn
    slip = touch & (norm > lim)
    scale = torch.where(slip, lim / torch.where(slip, norm, torch.ones_like(norm)), torch.ones_like(norm))
    Ft = Ft * scale[..., None]
    anchor = torch.where(slip[..., None], pt + Ft / kt_, anchor)
    Ft = torch.where(touch[..., None], Ft, torch.zeros_like(Ft))
    Fc = torch.cat([Ft, Fn[..., None]], dim=-1).reshape(B, k, 2, 3)
    W = tm.gather_nodes(Fc[:, :, 0], Fc[:, :, 1])
    return W, anchor, touch, slip


def contact_step(model, contact, q, qd, anchor, active, dt: float, integrator: str = "semi_implicit_euler",
                 n_steps: int = 1, rest_length=None, force_density=None, params=None, project: bool = True,
                 external=None, contact_prm=None, substep=None):
    """``n_steps`` physics steps with ground contact (as :func:`tensegrity_gym.physics.pipeline.contact_step`):
    per step, contact forces from the state at its start, held over one integrator step
    (:func:`contact_substep`). ``contact_prm``: per-copy contact parameters (``prm`` of
    :func:`contact_forces`). ``substep``: a replacement for :func:`contact_substep` with its
    signature (e.g. ``torch.compile(contact_substep)``). Returns ``(q, qd, anchor, active)``."""
    name, dt, tm, prm, rl, fd, ext = prepare_steps(model, q, integrator, dt, params, rest_length, force_density,
                                                   external)
    one = contact_substep if substep is None else substep
    for _ in range(int(n_steps)):
        q, qd, anchor, active = one(tm, contact, q, qd, anchor, active, dt, name, prm, rl, fd, ext, contact_prm,
                                    project)
    return q, qd, anchor, active


def contact_substep(tm, contact, q, qd, anchor, active, dt, name, prm, rl, fd, ext, contact_prm, project_):
    """One physics step with ground contact on prepared inputs (``tm``: :class:`TorchModel`,
    ``prm``: :func:`torch_params`' dict, ``name``: a resolved integrator name): contact forces
    from the state at the step's start (plus ``ext``), then one integrator step."""
    W, anchor, active, _ = contact_forces(contact, tm, q, qd, anchor, active, contact_prm)
    if ext is not None:
        W = W + ext
    q, qd = step_once(tm, q, qd, dt, name, prm, rl, fd, W, project_)
    return q, qd, anchor, active

