"""The book's equations on tensors (batched over a leading axis B, differentiable): nodes
linear in the configuration (5.17), string state and tension-only force densities (5.20),
generalized forces (5.21), rod accelerations ((5.37)/(5.40), reduced form (5.49)-(5.51)), the
projection onto the constraints and the great-circle drift. SI units.
"""
from __future__ import annotations

from .model import TorchModel, _torch

__all__ = ["node_positions", "node_velocities", "string_state", "force_densities", "nodal_forces", "project",
           "sphere_drift", "torch_stack3"]

_SINC_SMALL = 1e-4   # rad: below this rotation per step sin(x)/x = 1 - x^2/6 (as the numba backend's _SINC_SMALL)


def _dot(a, b):
    """Dot product over the last axis (of length 3), written out: torch's reduction over a
    length-3 axis is ~10x slower than three products on CPU."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _proj_apply(Pi, x):
    """``Pi @ x`` per rod: Pi (k, 3, 3), x (B, k, 3) -> (B, k, 3) (elementwise, no bmm)."""
    return torch_stack3(
        _dot(Pi[:, 0], x), _dot(Pi[:, 1], x), _dot(Pi[:, 2], x))


def torch_stack3(a, b, c):
    return _torch().stack([a, b, c], dim=-1)


# ---------------------------------------------------------------------- dynamics
def node_positions(tm: TorchModel, q, prm):
    """(B, n, 3) node positions, m."""
    r, b = q[..., :3], q[..., 3:]
    return tm.gather_nodes(r + tm.eta_a * b, r + tm.eta_c * b, prm["anchor_pos"])



def node_velocities(tm: TorchModel, qd):
    """(B, n, 3) node velocities, m/s (anchors 0)."""
    rd, bd = qd[..., :3], qd[..., 3:]
    return tm.gather_nodes(rd + tm.eta_a * bd, rd + tm.eta_c * bd)


def string_state(tm: TorchModel, q, qd, prm, with_rate: bool):
    """String vectors (B, m, 3), lengths (B, m) m, length rates (B, m) m/s or None."""
    torch = _torch()
    N = node_positions(tm, q, prm)
    S = N.index_select(1, tm.str_j) - N.index_select(1, tm.str_i)
    L = torch.sqrt(_dot(S, S))
    Ld = None
    if with_rate:
        V = node_velocities(tm, qd)
        Sd = V.index_select(1, tm.str_j) - V.index_select(1, tm.str_i)
        pos = L > 0
        Ld = torch.where(pos, _dot(S, Sd) / torch.where(pos, L, torch.ones_like(L)), torch.zeros_like(L))
    return S, L, Ld


def force_densities(tm: TorchModel, q, qd, prm, rest_length=None, force_density=None):
    """gamma (B, m) N/m, string vectors and lengths; tension-only, damping only while taut,
    controls clipped at 0 (see :func:`tensegrity_gym.physics.geometry.force_densities`)."""
    torch = _torch()
    l0 = prm["rest_length"] if rest_length is None else rest_length
    S, L, Ld = string_state(tm, q, qd, prm, prm["has_damping"])
    taut = L > l0
    safeL = torch.where(taut, L, torch.ones_like(L))
    tension = prm["stiffness"] * (L - l0)
    if prm["has_damping"]:
        tension = tension + prm["damping"] * Ld
    gamma = torch.where(taut, torch.clamp(tension, min=0.0) / safeL, torch.zeros_like(L))
    if force_density is not None:
        gamma = torch.clamp(gamma + force_density, min=0.0)
    return gamma, S, L


def nodal_forces(tm: TorchModel, q, qd, prm, rest_length=None, force_density=None, external=None):
    """Total nodal forces (B, n, 3) N (strings, gravity, node drag, ``external``) and gamma (B, m)."""
    gamma, S, _ = force_densities(tm, q, qd, prm, rest_length, force_density)
    gS = gamma[..., None] * S
    F = gS.new_zeros((S.shape[0], tm.n, 3)).index_add(1, tm.str_i, gS).index_add(1, tm.str_j, -gS)
    if prm["has_gravity"]:
        F = F + prm["W0"]
    if prm["has_node_damping"]:
        F = F - prm["node_damping"][..., None] * node_velocities(tm, qd)
    if external is not None:
        F = F + external
    return F, gamma


def _rod_accelerations(tm: TorchModel, q, qd, F, prm):
    """The branch-free Sherman-Morrison form of the numba backend's ``_rod_acc`` (free and
    constrained rods alike)."""
    torch = _torch()
    b = q[..., 3:]
    bd = qd[..., 3:]
    Fa, Fc = F.index_select(1, tm.rod_a), F.index_select(1, tm.rod_c)
    fr = Fa + Fc
    fb = tm.eta_a * Fa + tm.eta_c * Fc
    bb = _dot(b, b)[..., None]
    w = _dot(bd, bd)[..., None] / bb
    Pfb = fb - b * _dot(b, fb)[..., None] / bb
    f = prm["f"][..., None]
    J = prm["J"][..., None]
    m = prm["mass"][..., None]
    h = fr - (f / J) * Pfb + f * w * b
    alpha = m - f * f / J
    beta = f * f / J
    Pi = tm.proj
    if tm.any_constrained:
        u = _proj_apply(Pi, b) / torch.sqrt(bb)
        Pih = _proj_apply(Pi, h)
    else:   # every Pi = I (free rods): the same numbers without the products
        u = b / torch.sqrt(bb)
        Pih = h
    uu = _dot(u, u)[..., None]
    uh = _dot(u, h)[..., None]
    rdd = (Pih - beta * u * uh / (alpha + beta * uu)) / alpha
    Prdd = rdd - b * _dot(b, rdd)[..., None] / bb
    bdd = Pfb / J - (f / J) * Prdd - w * b
    return torch.cat([rdd, bdd], dim=-1)


def _accel(tm, q, qd, prm, rest_length, force_density, external):
    F, _ = nodal_forces(tm, q, qd, prm, rest_length, force_density, external)
    return _rod_accelerations(tm, q, qd, F, prm)


def project(tm: TorchModel, q, qd):
    """``|b| = 1``, ``b . b' = 0`` and the constrained reference points back on their set
    (as :func:`tensegrity_gym.physics.geometry.project`)."""
    torch = _torch()
    r, b = q[..., :3], q[..., 3:]
    rd, bd = qd[..., :3], qd[..., 3:]
    b = b / torch.sqrt(_dot(b, b))[..., None]
    bd = bd - b * _dot(b, bd)[..., None]
    if tm.any_constrained:
        r = tm.offset + _proj_apply(tm.proj, r)
        rd = _proj_apply(tm.proj, rd)
    return torch.cat([r, b], dim=-1), torch.cat([rd, bd], dim=-1)


def sphere_drift(q, qd, dt):
    """Drift half of semi-implicit Euler with projection: ``r += dt r'`` and each ``b`` along its
    great circle (as the numba backend's ``_drift_rod``; no square root of zero, so its gradient is
    finite at ``b' = 0``)."""
    torch = _torch()
    r, b = q[..., :3], q[..., 3:]
    rd, bd = qd[..., :3], qd[..., 3:]
    r = r + dt * rd
    b = b * (1.0 / torch.sqrt(_dot(b, b)))[..., None]
    bd = bd - b * _dot(b, bd)[..., None]
    ww = _dot(bd, bd)[..., None]
    pos = ww > 0
    w = torch.where(pos, torch.sqrt(torch.where(pos, ww, torch.ones_like(ww))), torch.zeros_like(ww))
    x = w * dt
    small = x < _SINC_SMALL
    xs = torch.where(small, torch.ones_like(x), x)
    sinc = torch.where(small, 1.0 - x * x / 6.0, torch.sin(xs) / xs)
    c = torch.cos(x)
    bn = b * c + bd * (dt * sinc)
    bdn = bd * c - b * (w * (x * sinc))
    return torch.cat([r, bn], dim=-1), torch.cat([rd, bdn], dim=-1)


