"""Geometry and energies of a batch of configurations (pure NumPy, SI units): node positions
and velocities ((5.17): ``N = Q Psi^T + Y``), string vectors, lengths and rates, kinetic and
potential energy, momenta, centre of mass, constraint drift, the configuration matrix and the
string connectivity. ``q``, ``qd`` (B, k, 6) = ``[r, b]``, ``[r', b']`` (m, 1, m/s, 1/s).
"""
from __future__ import annotations

import numpy as np

from ..core.model import Model

__all__ = ["kabsch", "node_positions", "node_velocities", "string_state", "kinetic_energy", "potential_energy", "energy",
           "linear_momentum", "angular_momentum", "center_of_mass", "rod_length_drift", "constraint_violation",
           "configuration_matrix", "connectivity"]


def node_positions(model: Model, q: np.ndarray, params=None) -> np.ndarray:
    """(B, n, 3) node positions, m, from q (B, k, 6) (anchors from ``params`` if given)."""
    B = q.shape[0]
    r, b = q[..., :3], q[..., 3:]
    N = np.empty((B, model.n_nodes, 3))
    N[:, model.rod_a] = r + model.eta[None, :, 0, None] * b
    N[:, model.rod_c] = r + model.eta[None, :, 1, None] * b
    if model.anchor_idx.size:
        N[:, model.anchor_idx] = model.anchor_pos if params is None else params.anchor_pos
    return N


def node_velocities(model: Model, qd: np.ndarray) -> np.ndarray:
    """(B, n, 3) node velocities, m/s (anchors: 0)."""
    B = qd.shape[0]
    rd, bd = qd[..., :3], qd[..., 3:]
    V = np.zeros((B, model.n_nodes, 3))
    V[:, model.rod_a] = rd + model.eta[None, :, 0, None] * bd
    V[:, model.rod_c] = rd + model.eta[None, :, 1, None] * bd
    return V


def string_state(model: Model, q: np.ndarray, qd: np.ndarray | None = None, params=None):
    """String vectors ``s`` (B, m, 3) = n_j - n_i, lengths (B, m) and, if ``qd`` is
    given, length rates d|s|/dt (B, m) in m/s (else None)."""
    N = node_positions(model, q, params)
    S = N[:, model.str_j] - N[:, model.str_i]
    L = np.sqrt(np.einsum("bmi,bmi->bm", S, S))
    Ld = None
    if qd is not None:
        V = node_velocities(model, qd)
        Sd = V[:, model.str_j] - V[:, model.str_i]
        with np.errstate(divide="ignore", invalid="ignore"):
            Ld = np.where(L > 0, np.einsum("bmi,bmi->bm", S, Sd) / np.where(L > 0, L, 1.0), 0.0)
    return S, L, Ld



# ---------------------------------------------------------------------- diagnostics
def kinetic_energy(model: Model, qd: np.ndarray, params=None) -> np.ndarray:
    """(B,) kinetic energy, J: sum of m|r'|^2/2 + f r'.b' + J|b'|^2/2."""
    p = model if params is None else params
    rd, bd = qd[..., :3], qd[..., 3:]
    return np.sum(0.5 * p.mass * np.einsum("bki,bki->bk", rd, rd)
                  + p.f * np.einsum("bki,bki->bk", rd, bd)
                  + 0.5 * p.J * np.einsum("bki,bki->bk", bd, bd), axis=-1)


def potential_energy(model: Model, q: np.ndarray, rest_length=None, params=None) -> np.ndarray:
    """(B,) string potential sum k max(0, |s| - l0)^2 / 2 plus gravity potential, J.
    Active strings (no stiffness) store no energy."""
    p = model if params is None else params
    l0 = p.rest_length if rest_length is None else rest_length
    _, L, _ = string_state(model, q, None, params)
    V = 0.5 * np.sum(p.stiffness * np.maximum(L - l0, 0.0) ** 2, axis=-1)
    if p.has_gravity:
        N = node_positions(model, q, params)
        if params is None:
            V = V - np.einsum("bni,ni->b", N, model.W0)
        else:
            V = V - np.einsum("bni,bni->b", N, np.broadcast_to(params.W0, N.shape))
    return V


def energy(model: Model, q, qd, rest_length=None, params=None) -> np.ndarray:
    """(B,) total mechanical energy, J (``params``: per-copy values, default the model's)."""
    return kinetic_energy(model, qd, params) + potential_energy(model, q, rest_length, params)


def linear_momentum(model: Model, qd: np.ndarray, params=None) -> np.ndarray:
    """(B, 3) linear momentum sum m r' + f b', kg m/s."""
    p = model if params is None else params
    rd, bd = qd[..., :3], qd[..., 3:]
    return np.sum(p.mass[..., None] * rd + p.f[..., None] * bd, axis=-2)


def angular_momentum(model: Model, q: np.ndarray, qd: np.ndarray, about=None, params=None) -> np.ndarray:
    """(B, 3) angular momentum about ``about`` (3,) or (B, 3) (default: origin), kg m^2/s.

    Per rod: m (r - o) x r' + f ((r - o) x b' + b x r') + J b x b'."""
    r, b = q[..., :3], q[..., 3:]
    rd, bd = qd[..., :3], qd[..., 3:]
    if about is not None:
        r = r - np.asarray(about)[..., None, :] if np.ndim(about) == 2 else r - about
    p = model if params is None else params
    m, f, J = (x[..., None] for x in (p.mass, p.f, p.J))
    L = m * np.cross(r, rd) + f * (np.cross(r, bd) + np.cross(b, rd)) + J * np.cross(b, bd)
    return L.sum(axis=-2)


def center_of_mass(model: Model, q: np.ndarray, params=None) -> np.ndarray:
    """(B, 3) centre of mass of the rods, m (rod masses from ``params`` if given)."""
    r, b = q[..., :3], q[..., 3:]
    com = r + model.com_eta[None, :, None] * b
    if params is None:
        return np.einsum("k,bki->bi", model.mass, com) / model.mass.sum()
    m = np.broadcast_to(params.mass, com.shape[:2])
    return np.einsum("bk,bki->bi", m, com) / m.sum(axis=1)[:, None]


def rod_length_drift(model: Model, q: np.ndarray) -> np.ndarray:
    """(B,) max over rods of | |b| - 1 | (relative rod-length error)."""
    return np.max(np.abs(np.linalg.norm(q[..., 3:], axis=-1) - 1.0), axis=-1)


def constraint_violation(model: Model, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """(B,) largest violation among |b| = 1 (1), b.b' = 0 (1/s) and the node constraints (m)."""
    b, bd = q[..., 3:], qd[..., 3:]
    v = np.maximum(rod_length_drift(model, q), np.max(np.abs(np.einsum("bki,bki->bk", b, bd)), axis=-1))
    if model.constrained.any():
        r = q[..., :3]
        resid = r - model.offset - np.einsum("kij,bkj->bki", model.proj, r)
        v = np.maximum(v, np.max(np.abs(resid), axis=(-1, -2)))
    return v


def configuration_matrix(model: Model, q: np.ndarray):
    """The seed's notation: ``Q`` (B, 3, 2k) = [R B], ``Psi`` (n, 2k), ``Y`` (3, n) with
    ``N^T = Q Psi^T + Y`` (nodes as columns, (5.17)). For a free rod, R holds its centre
    of mass; for a constrained rod, its constrained node."""
    k = model.n_bars
    Q = np.concatenate([q[..., :3], q[..., 3:]], axis=1).transpose(0, 2, 1)
    Psi = np.zeros((model.n_nodes, 2 * k))
    Psi[model.rod_a, np.arange(k)] = 1.0
    Psi[model.rod_c, np.arange(k)] = 1.0
    Psi[model.rod_a, k + np.arange(k)] = model.eta[:, 0]
    Psi[model.rod_c, k + np.arange(k)] = model.eta[:, 1]
    Y = np.zeros((3, model.n_nodes))
    if model.anchor_idx.size:
        Y[:, model.anchor_idx] = model.anchor_pos.T
    return Q, Psi, Y


# ---------------------------------------------------------------------- sparse connectivity
def connectivity(model: Model):
    """The string connectivity ``C_S`` (m, n) of the seed ((5.21); +1 at ``str_j``, -1 at ``str_i``)
    as a ``scipy.sparse.csr_matrix`` (built on demand; the dynamics use the index arrays)."""
    import scipy.sparse as sp
    m = model.n_strings
    rows = np.concatenate([np.arange(m), np.arange(m)])
    cols = np.concatenate([model.str_j, model.str_i])
    vals = np.concatenate([np.ones(m), -np.ones(m)])
    return sp.csr_matrix((vals, (rows, cols)), shape=(m, model.n_nodes))


def kabsch(src, dst):
    """The rigid fit of point set ``src`` (P, 3) to ``dst`` (P, 3), m (Kabsch): the rotation R, the
    centroid of ``dst`` and the centroid of ``src``, with dst ~ (src - c_src) R^T + c_dst in the
    least-squares sense."""
    cs, cd = src.mean(0), dst.mean(0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T, cd, cs
