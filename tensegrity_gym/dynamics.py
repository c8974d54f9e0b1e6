"""Class-1 tensegrity dynamics in configuration-matrix form (pure NumPy reference path).

This module never imports gymnasium. Everything is in SI units (m, kg, s, N).

Coordinates
-----------
Each rod j has a *reference point* ``r_j`` (m) and a unit vector ``b_j`` pointing from
its node a to its node c. The reference point sits at fraction ``sigma_j`` from node a:

* a free rod is described at its centre of mass (``sigma`` = mass-weighted centre,
  first mass moment ``f = 0``), exactly the seed's Theorem 5.1 with ``Q = [R B]``;
* a rod with a constrained end node (``D n = const``) is described at that node
  (``sigma = 0`` or ``1``), the seed's section 5.4 reduced form with
  ``r = D^+ rbar + E z``.

Nodes are linear in the configuration (5.17, 5.42):
``n_a = r + eta_a b``, ``n_c = r + eta_c b`` with ``eta_a = -sigma l``, ``eta_c = (1 - sigma) l``;
i.e. ``N = Q Psi^T + Y`` with anchors in ``Y``.

The state of a batch of B copies of one structure is ``q`` (B, k, 6) = ``[r, b]`` and
``qd`` (B, k, 6) = ``[r', b']`` (m, 1, m/s, 1/s).

Equations of motion (per rod; (5.49)-(5.51) of the seed, which reduce to (5.37)/(5.40)
for a free rod described at its centre of mass)::

    f_r = F_a + F_c                         (sum of nodal forces, N)
    f_b = eta_a F_a + eta_c F_c             (generalized force on b, N m)
    w   = |b'|^2 / |b|^2,   P = I - b b^T / |b|^2
    r'' = A(b) [ f_r - (f/J) P f_b + f w b ]
    b'' = P f_b / J - (f/J) P r'' - w b

with ``A = E (m I - f^2/J E^T P E)^{-1} E^T`` written branch-free through the projector
``Pi = E E^T`` onto the allowed directions of the reference point and Sherman-Morrison:
``A = (Pi - beta u u^T / (alpha + beta |u|^2)) / alpha``, ``u = Pi b/|b|``,
``alpha = m - f^2/J > 0`` (Lemma 5.1), ``beta = f^2/J``. For a free rod ``A = I/m``; for a
pinned rod ``A = 0``.

Strings are tension-only (5.20)::

    gamma_i = max(0, k_i (|s_i| - l0_i)/|s_i| + c_i (d|s_i|/dt)/|s_i|)   if |s_i| > l0_i, else 0
    gamma_i <- max(0, gamma_i + u_i)          (u: force density added by a controller, N/m)

so a string never pushes, damping included, and a slack string carries no force
(a controller may still pull through it with ``u > 0``). Force densities enter the
generalized forces linearly (5.21): ``F_Q = [W - N C_S^T Gamma C_S] Psi``.

Strings listed as *active* in :func:`compile_model` have no elastic part: their force
density is the control input ``u`` alone (clipped at 0: a cable cannot push).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Iterable

import numpy as np

from .checks import check_finite, is_integer
from .structure import Structure, mass_moments
from .params import Params, default_params

__all__ = ["Model", "State", "compile_model", "Params", "default_params", "initial_state", "node_positions", "node_velocities",
           "string_state", "force_densities", "nodal_forces", "accelerations", "project", "energy",
           "kinetic_energy", "potential_energy", "linear_momentum", "angular_momentum", "rod_length_drift",
           "configuration_matrix", "constraint_violation", "stable_step_estimate"]


@dataclass(frozen=True, eq=False)
class Model:
    """Compiled, immutable arrays of one structure topology (SI units).

    Shapes: k rods, n nodes, m strings, na anchors.
    """

    structure: Structure
    n_nodes: int
    n_bars: int
    n_strings: int
    rod_a: np.ndarray          # (k,) node a of each rod
    rod_c: np.ndarray          # (k,) node c of each rod
    length: np.ndarray         # (k,) rod length, m
    sigma: np.ndarray          # (k,) reference point as fraction from node a
    mass: np.ndarray           # (k,) kg
    f: np.ndarray              # (k,) first mass moment about the reference point, kg m
    J: np.ndarray              # (k,) second mass moment about the reference point, kg m^2
    eta: np.ndarray            # (k, 2) signed distance of nodes a, c from the reference point, m
    proj: np.ndarray           # (k, 3, 3) projector Pi = E E^T onto allowed reference-point motion
    offset: np.ndarray         # (k, 3) fixed part (I - Pi) n0 of the reference point, m
    constrained: np.ndarray    # (k,) bool: rod has a constrained node
    anchor_idx: np.ndarray     # (na,) anchor node indices
    anchor_pos: np.ndarray     # (na, 3) anchor positions, m
    str_i: np.ndarray          # (m,) first node of each string
    str_j: np.ndarray          # (m,) second node (s = n_j - n_i); C_S = :func:`connectivity`
    stiffness: np.ndarray      # (m,) N/m (0 for active strings)
    damping: np.ndarray        # (m,) N s/m (0 for active strings)
    rest_length: np.ndarray    # (m,) default rest lengths, m
    active: np.ndarray         # (m,) bool: force-density-controlled strings
    W0: np.ndarray             # (n, 3) constant external nodal loads (gravity), N
    gravity: np.ndarray | None
    has_gravity: bool
    has_damping: bool
    com_eta: np.ndarray = field(default=None)  # (k,) signed distance of centre of mass from ref. point, m
    node_damping: np.ndarray = field(default=None)  # (n,) viscous drag coefficient per node, N s/m
    has_node_damping: bool = False

    @property
    def node_velocity_free(self) -> bool:
        """True if no string is damped and no node has drag (forces then need no node velocities)."""
        return not (self.has_damping or self.has_node_damping)


@dataclass(frozen=True, eq=False)
class State:
    """Batched state. ``q``, ``qd``: (B, k, 6) arrays ``[r, b]``, ``[r', b']``; ``t``: s."""

    q: np.ndarray
    qd: np.ndarray
    t: float = 0.0

    @property
    def batch_size(self) -> int:
        return self.q.shape[0]

    def replace(self, **kw) -> "State":
        return replace(self, **kw)


def compile_model(structure: Structure, active_strings: Iterable[int] | None = None,
                  node_damping=None) -> Model:
    """Compile a :class:`Structure` into the arrays the dynamics use.

    ``active_strings``: indices of strings whose force density is a control input
    (no elastic part). Default: none (all strings elastic).

    ``node_damping``: viscous drag coefficient ``c`` (N s/m, >= 0), a number for every node or
    an (n,) array: node ``i`` feels ``-c_i v_i`` (``v_i`` its velocity; anchors do not move),
    added to the nodal forces ``W`` like any external force (so it enters ``f_r`` and ``f_b``
    by (5.21)). Default None / all zero: no drag, and no drag code runs."""
    s = structure
    k, n, m = s.n_bars, s.n_nodes, s.n_strings
    from .sizing import check_size
    check_size(s)   # refuse at once (naming the size) what cannot fit in memory
    rod_a = s.bars[:, 0].copy()
    rod_c = s.bars[:, 1].copy()
    length = s.bar_lengths
    mp = s.mass_points or (None,) * k
    sigma = s.com_fraction.copy()
    proj = np.tile(np.eye(3), (k, 1, 1))
    offset = np.zeros((k, 3))
    constrained = np.zeros(k, bool)
    for j in range(k):
        for end, node in ((0, rod_a[j]), (1, rod_c[j])):
            if node in s.node_constraints:
                D = s.node_constraints[node]
                sigma[j] = float(end)
                # projector onto the null space of D (allowed motion)
                Pi = np.eye(3) - D.T @ np.linalg.solve(D @ D.T, D)
                Pi[np.abs(Pi) < 1e-15] = 0.0
                proj[j] = Pi
                offset[j] = (np.eye(3) - Pi) @ s.nodes[node]
                constrained[j] = True
    f = np.zeros(k)
    J = np.zeros(k)
    for j in range(k):
        fj, Jj = mass_moments(length[j], s.bar_mass[j], sigma[j], mp[j])
        f[j] = 0.0 if not constrained[j] else fj   # free rods: f = 0 exactly at the centre of mass
        J[j] = Jj
    eta = np.stack([-sigma * length, (1.0 - sigma) * length], axis=1)
    com_eta = (s.com_fraction - sigma) * length
    active = np.zeros(m, bool)
    if active_strings is not None:
        idx = np.asarray(list(active_strings), dtype=int)
        if idx.size and (idx.min() < 0 or idx.max() >= m):
            bad = idx[(idx < 0) | (idx >= m)][0]
            raise ValueError(f"active_strings: string {bad} does not exist (there are {m} strings)")
        active[idx] = True
    stiffness = np.where(active, 0.0, s.stiffness)
    damping = np.where(active, 0.0, s.damping)
    W0 = np.zeros((n, 3))
    if s.gravity is not None:
        # a rod's weight m g acts at its centre of mass: equivalent loads at its two nodes
        com = s.com_fraction
        W0[rod_a] += ((1.0 - com) * s.bar_mass)[:, None] * s.gravity
        W0[rod_c] += (com * s.bar_mass)[:, None] * s.gravity
    if node_damping is None:
        cn = np.zeros(n)
    else:
        cn = np.array(np.broadcast_to(np.asarray(node_damping, dtype=float), (n,))) \
            if np.ndim(node_damping) == 0 else np.asarray(node_damping, dtype=float).copy()
        if cn.shape != (n,):
            raise ValueError(f"node_damping: expected a number or an array of shape ({n},) (N s/m per node), "
                             f"got shape {cn.shape}")
        bad = ~(np.isfinite(cn) & (cn >= 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"node_damping: must be finite and >= 0 N s/m, got {cn[i]} at node {i}")
    anchor_idx = s.anchors
    arrays = dict(rod_a=rod_a, rod_c=rod_c, length=length, sigma=sigma, mass=s.bar_mass.copy(), f=f, J=J,
                  eta=eta, proj=proj, offset=offset, constrained=constrained, anchor_idx=anchor_idx,
                  anchor_pos=s.nodes[anchor_idx].copy(), str_i=s.strings[:, 0].copy(),
                  str_j=s.strings[:, 1].copy(), stiffness=stiffness, damping=damping,
                  rest_length=s.rest_length.copy(), active=active, W0=W0, com_eta=com_eta, node_damping=cn)
    for a in arrays.values():
        a.setflags(write=False)
    return Model(structure=s, n_nodes=n, n_bars=k, n_strings=m, gravity=s.gravity,
                 has_gravity=s.gravity is not None and bool(np.any(s.gravity != 0)),
                 has_damping=bool(np.any(damping > 0)), has_node_damping=bool(np.any(cn > 0)), **arrays)


def initial_state(model: Model, batch_size: int = 1, nodes: np.ndarray | None = None,
                  velocities: np.ndarray | None = None) -> State:
    """State from node positions (n, 3) or (B, n, 3) m and velocities (n, 3) or (B, n, 3) m/s
    (default: the structure's), ``batch_size`` copies of (n, 3) inputs.

    Rod lengths are taken from the model; ``b`` is normalised. ValueError naming the argument for
    a batch size that is not a positive integer, a wrong shape, a NaN/inf entry or a rod whose
    two nodes coincide."""
    if not is_integer(batch_size) or batch_size < 1:
        raise ValueError(f"batch_size: must be a positive integer (copies), got {batch_size!r}")
    s = model.structure
    n = model.n_nodes
    nodes = s.nodes if nodes is None else np.asarray(nodes, float)
    vel = s.velocities if velocities is None else np.asarray(velocities, float)
    for x, name in ((nodes, "nodes"), (vel, "velocities")):
        if x.shape[-2:] != (n, 3) or x.ndim not in (2, 3):
            raise ValueError(f"{name}: expected shape ({n}, 3) or (B, {n}, 3), got {x.shape}")
        check_finite(x, name)
    if nodes.ndim == 2:
        nodes = np.broadcast_to(nodes, (batch_size,) + nodes.shape)
    if vel.ndim == 2:
        vel = np.broadcast_to(vel, (nodes.shape[0],) + vel.shape)
    elif vel.shape[0] != nodes.shape[0]:
        raise ValueError(f"velocities: {vel.shape[0]} copies for {nodes.shape[0]} copies of nodes")
    na, nc = nodes[:, model.rod_a], nodes[:, model.rod_c]
    d = nc - na
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    if not (length > 0).all():
        b, j, _ = (int(i) for i in np.argwhere(~(length > 0))[0])
        raise ValueError(f"nodes: rod {j} (nodes {model.rod_a[j]} and {model.rod_c[j]}) has zero length in copy {b}")
    va, vc = vel[:, model.rod_a], vel[:, model.rod_c]
    b = d / length
    L = model.length[None, :, None]
    bd = (vc - va) / L
    sig = model.sigma[None, :, None]
    r = na + sig * L * b
    rd = va + sig * L * bd
    q = np.concatenate([r, b], axis=-1)
    qd = np.concatenate([rd, bd], axis=-1)
    return State(q=np.ascontiguousarray(q), qd=np.ascontiguousarray(qd), t=0.0)


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


def force_densities(model: Model, q: np.ndarray, qd: np.ndarray, rest_length=None, force_density=None,
                    params=None):
    """``(gamma, S, L)``: string force densities gamma (B, m), N/m (tension / length, >= 0: the
    tension ``k (L - l0) + c dL/dt`` while the string is longer than its rest length and pulls,
    else 0, plus the ``force_density`` control, clipped at 0), string vectors S (B, m, 3) =
    n_j - n_i, m, and lengths L (B, m), m, of the states ``q``, ``qd`` (B, k, 6).
    ``rest_length`` (m,) or (B, m), m, and ``force_density`` (m,) or (B, m), N/m, as
    :func:`accelerations` takes them; ``params``: a :class:`~tensegrity_gym.params.Params`
    (P = 1 or B copies) whose stiffness, damping, rest lengths, ... replace the model's.
    Computed by the numba kernels' own string-force equation (the one every step evaluates:
    :func:`tensegrity_gym._kernels.string_forces`); its NumPy reference is the test oracle
    ``tests/oracle_numpy.py``."""
    from . import _kernels
    gamma, L, _ = _kernels.string_forces(model, q, qd, rest_length, force_density, None, params)
    N = node_positions(model, np.asarray(q, dtype=np.float64).reshape(-1, model.n_bars, 6), params)
    return gamma, N[:, model.str_j] - N[:, model.str_i], L


def nodal_forces(model: Model, q, qd, rest_length=None, force_density=None, external=None, params=None):
    """Total nodal forces ``W - N C_S^T Gamma C_S`` (B, n, 3), N, and the force densities gamma
    (B, m), N/m (:func:`force_densities`). ``W``: gravity loads, node drag ``-c v`` (if the model
    has ``node_damping``) and ``external`` ((n, 3) or (B, n, 3), N). ``params``: per-copy
    physical values. Computed by the numba kernels' force equations
    (:func:`tensegrity_gym._kernels.string_forces`; NumPy reference: ``tests/oracle_numpy.py``)."""
    from . import _kernels
    gamma, _, F = _kernels.string_forces(model, q, qd, rest_length, force_density, external, params)
    return F, gamma


def accelerations(model: Model, q: np.ndarray, qd: np.ndarray, rest_length=None, force_density=None,
                  external=None, params=None) -> np.ndarray:
    """Second derivatives (B, k, 6) ``[r'', b'']`` of the configuration (m/s^2, 1/s^2).

    ``rest_length``: (m,) or (B, m) string rest lengths, m (default the model's).
    ``force_density``: (m,) or (B, m) force densities added by a controller, N/m.
    ``external``: (B, n, 3) or (n, 3) external nodal forces, N (gravity is added
    by the model itself when the structure has it).
    ``params``: a :class:`~tensegrity_gym.params.Params` with 1 or B rows: copy b's masses,
    stiffnesses, damping, rest lengths, node drag, gravity and anchors (default: the model's).
    Computed by the numba kernels (:func:`tensegrity_gym.integrators.accelerations`: the
    equations every step runs); the NumPy reference is the test oracle ``tests/oracle_numpy.py``."""
    from .integrators import accelerations as kernel_accelerations
    return kernel_accelerations(model, q, qd, rest_length, force_density, external, params)


def project(model: Model, q: np.ndarray, qd: np.ndarray):
    """Project onto the constraint manifold: ``|b| = 1``, ``b . b' = 0``, the constrained
    nodes back on their line/plane/point (and their velocity tangent to it).
    ``q``, ``qd`` (B, k, 6) or (k, 6); returns new ``(q, qd)`` of the same shape; free rods'
    reference points are untouched. Computed by the numba kernels' own projection (the one
    every fixed step ends with: :func:`tensegrity_gym._kernels.project`); its NumPy reference
    is the test oracle ``tests/oracle_numpy.py``."""
    from . import _kernels
    return _kernels.project(model, q, qd)


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


def _jacobians_fd(model: Model, q, qd, rest_length=None, with_velocity=True):
    """Central-difference Jacobians ``K = da/dq`` (1/s^2) and ``D = da/dq'`` (1/s) of the
    accelerations of ONE state ``q``, ``qd`` (1, k, 6), in one batched call (24 k states):
    :func:`tensegrity_gym.jacobian.acceleration_jacobians`, step ``1e-6 max(1, |q|_inf)``.
    ``D`` is None when ``with_velocity`` is False."""
    from .jacobian import acceleration_jacobians
    _, K, D = acceleration_jacobians(model, q, qd, rest_length, with_velocity=with_velocity, central=True,
                                     rel_step=1e-6)
    return K[0], (None if D is None else D[0])


def _rk4_limit(lam: np.ndarray) -> float:
    """Largest dt (s) with ``|1 + z + z^2/2 + z^3/6 + z^4/24| <= 1`` for all ``z = dt lam``
    (bisection; the region is star-shaped about 0: 2.785/|lam| on the real axis, 2.828/|lam|
    on the imaginary axis)."""
    def ok(dt):
        z = dt * lam
        return bool(np.all(np.abs(1 + z + z * z / 2 + z ** 3 / 6 + z ** 4 / 24) <= 1 + 1e-9))

    lo, hi = 0.0, 2.9 / float(np.abs(lam).max())
    if ok(hi):
        return hi
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def _sie_modal(lam: np.ndarray) -> float:
    """Semi-implicit Euler's modal step limit (s) of the eigenvalues ``lam`` (closed left
    half-plane, 1/s): ``(sqrt(c^2 + 4 w0^2) - c) / w0^2`` per complex pair, ``0.8/|lam|`` per
    real one (see :func:`_sie_limit`)."""
    cplx = lam[np.abs(lam.imag) > 1e-9 * np.abs(lam)]
    real = lam[np.abs(lam.imag) <= 1e-9 * np.abs(lam)].real
    sie = float("inf")
    if cplx.size:
        w0 = np.abs(cplx)
        c = np.maximum(-2.0 * cplx.real, 0.0)
        sie = float(np.min((np.sqrt(c * c + 4 * w0 * w0) - c) / (w0 * w0)))
    if real.size:
        sie = min(sie, float(0.8 / np.abs(real).max()))
    return sie


def _sie_limit(lam: np.ndarray, K: np.ndarray, D: np.ndarray, sigma: float = 0.0) -> float:
    """Largest stable dt (s) of semi-implicit Euler (``v += dt (K x + D v)``, ``x += dt v``).

    Modal bound from the eigenvalues ``lam`` (closed left half-plane): a complex pair is a
    damped oscillator ``x'' = -w0^2 x - c x'`` (``w0 = |lam|``, ``c = -2 Re lam``), stable for
    ``w0^2 dt^2 + 2 c dt <= 4``, i.e. ``dt <= (sqrt(c^2 + 4 w0^2) - c) / w0^2`` (``2/w0``
    undamped); a real ``lam < 0`` belongs to an overdamped pair whose partner is unknown: the
    pair's limit is between ``0.828/|lam|`` (critical damping) and ``2/|lam|`` (strongly
    overdamped, the explicit-Euler limit), so ``0.8/|lam|`` is used. For up to 120
    coordinates (20 rods) the bound is then refined to the exact limit of the linearised step
    (to 0.1 %), by bisection on the spectral radius of the step matrix
    ``[[I + dt^2 K, dt I + dt^2 D], [dt K, I + dt D]]``, allowing the growth ``1 + 2 sigma dt``
    of physically unstable modes (``sigma`` >= 0: their largest growth rate, 1/s)."""
    sie = _sie_modal(lam)
    n = K.shape[0]
    if n > 120 or not np.isfinite(sie):
        return sie
    I_ = np.eye(n)
    lmax = float(np.abs(lam).max())

    def ok(dt):
        M = np.block([[I_ + dt * dt * K, dt * I_ + dt * dt * D], [dt * K, I_ + dt * D]])
        return bool(np.abs(np.linalg.eigvals(M)).max() <= 1.0 + 2.0 * sigma * dt + 1e-3 * dt * lmax)

    if not ok(sie):
        return sie
    lo, hi = sie, 4.0 * sie
    while hi > 1.001 * lo:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


#: structures with at most this many rods get the exact dense stability estimate (cheap there)
DENSE_STABILITY_MAX_RODS = 20
#: radius of the largest half-disk {|z| <= R, Re z <= 0} inside RK4's stability region (the
#: region's boundary comes closest to 0 at arg z ~ 0.8 pi: 2.6156; on the axes it is 2.785/2.828)
_RK4_HALF_DISK = 2.615
#: eigenvalues computed by Arnoldi in the sparse stability estimate, and their relative tolerance
_ARNOLDI_NEV = 6
_ARNOLDI_TOL = 1e-3


def stable_step_estimate(model: Model, state: State | None = None, rest_length=None, damping: bool = True,
                         method: str = "auto") -> dict:
    """Estimate the largest stable time step (s) of the explicit integrators at ``state``
    (default: the structure's initial state; the first copy of a batch).

    The first-order system ``x' = v``, ``v' = a(x, v)`` is linearised there (central-difference
    Jacobians ``K = da/dq``, ``D = da/dq'``; ``D`` holds the string damping and node drag, and
    the gyroscopic terms if the state moves) and the eigenvalues ``lam`` of ``[[0, I], [K, D]]`` are placed
    in the stability regions of the methods: RK4 exactly (bisection on its stability
    polynomial; 2.785/|lam| on the real axis, 2.828/|lam| on the imaginary one), semi-implicit
    Euler from the damped-oscillator limit of each mode, refined to the exact limit of the
    linearised step for small structures (:func:`_sie_limit`). Rigid-body and near-zero modes
    (``|lam| < 1e-6 max |lam|``) do not limit the step; a positive real part (a physically
    unstable mode, or difference noise) is treated as zero. ``damping=False`` ignores ``D``
    (the undamped estimate, ``2/omega_max`` and ``2.828/omega_max``).

    Returns ``{"omega_max": rad/s, "lambda_max": 1/s, "semi_implicit_euler": s, "rk4": s}``:
    ``omega_max`` the highest undamped natural frequency ``sqrt(max |eig K|)``, ``lambda_max``
    the largest ``|lam|`` (equal to ``omega_max`` without damping). Cost: one batched call of
    :func:`accelerations` on ``24 k`` states and a few eigenvalue problems of size ``12 k``
    (a few ms for the 3-bar prism).

    ``method``: ``"dense"`` (the above), ``"sparse"`` (:func:`_stable_step_sparse`: sparse
    Jacobians by column grouping and Arnoldi for the largest eigenvalues; cost about linear in
    the structure's size, ~1 s for a 300-stage tower; conservative: never above the dense
    estimate) or ``"auto"`` (dense up to
    :data:`DENSE_STABILITY_MAX_RODS` rods, else sparse). The result also holds ``"method"``."""
    st = initial_state(model) if state is None else State(state.q[:1], state.qd[:1], state.t)
    q0, qd0 = np.ascontiguousarray(st.q, dtype=float), np.ascontiguousarray(st.qd, dtype=float)
    inf = float("inf")
    n = q0.size
    if n == 0:
        return {"omega_max": 0.0, "lambda_max": 0.0, "semi_implicit_euler": inf, "rk4": inf}
    with_v = damping and (model.has_damping or model.has_node_damping or bool(np.any(qd0 != 0)))
    if method not in ("auto", "dense", "sparse"):
        raise ValueError(f"method: unknown {method!r}; choose 'auto', 'dense' or 'sparse'")
    if method == "sparse" or (method == "auto" and model.n_bars > DENSE_STABILITY_MAX_RODS):
        return _stable_step_sparse(model, q0, qd0, rest_length, with_v)
    K, D = _jacobians_fd(model, q0, qd0, rest_length, with_v)
    if D is None:
        D = np.zeros_like(K)
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D))):
        return {"omega_max": float("nan"), "lambda_max": float("nan"), "semi_implicit_euler": inf, "rk4": inf,
                "method": "dense"}
    omega = float(np.sqrt(np.abs(np.linalg.eigvals(K)).max()))
    lam = np.linalg.eigvals(np.block([[np.zeros((n, n)), np.eye(n)], [K, D]]))
    lmax = float(np.abs(lam).max())
    lam = lam[np.abs(lam) > 1e-6 * lmax] if lmax > 0 else lam[:0]
    sigma = float(max(lam.real.max(), 0.0)) if lam.size else 0.0
    lam = np.minimum(lam.real, 0.0) + 1j * lam.imag
    if lam.size == 0:
        return {"omega_max": omega, "lambda_max": lmax, "semi_implicit_euler": inf, "rk4": inf, "method": "dense"}
    return {"omega_max": omega, "lambda_max": lmax, "semi_implicit_euler": _sie_limit(lam, K, D, sigma),
            "rk4": _rk4_limit(lam), "method": "dense"}


def _top_eigenvalues(A, nev: int) -> np.ndarray:
    """Approximations (relative tolerance :data:`_ARNOLDI_TOL`) of the ``nev`` largest-magnitude
    eigenvalues of the sparse square matrix ``A``: implicitly restarted Arnoldi (ARPACK via
    ``scipy.sparse.linalg.eigs``) with a fixed start vector (reproducible). The loose tolerance is
    what makes the cost linear: the top of a long tower's spectrum is a dense band (its 10 largest
    frequencies within 0.03 % for tower300), whose single eigenvalues Arnoldi resolves only slowly,
    while a Ritz value within the band converges fast. Raises ``ArpackNoConvergence``."""
    from scipy.sparse.linalg import eigs
    try:   # optional: ARPACK's BLAS-1/2 work on a few vectors gains nothing from threads, and
        from threadpoolctl import threadpool_limits     # spinning BLAS threads on a busy machine cost 20x
        limit = threadpool_limits(1, user_api="blas")
    except ImportError:  # pragma: no cover - threadpoolctl missing
        import contextlib
        limit = contextlib.nullcontext()
    n = A.shape[0]
    v0 = np.random.default_rng(0).standard_normal(n)
    with limit:
        return eigs(A, k=nev, which="LM", v0=v0, ncv=min(n, max(2 * nev + 1, 30)), tol=_ARNOLDI_TOL,
                    maxiter=1000, return_eigenvectors=False)


def _perron_bound(A, iters: int = 100) -> float:
    """Rigorous upper bound of the spectral radius of the sparse matrix ``A``: the Collatz-Wielandt
    bound ``max_i (|A| x)_i / x_i`` (>= the Perron root of ``|A|`` >= ``rho(A)``) of power
    iterates ``x > 0`` of ``|A|``."""
    B = abs(A).tocsr()
    x = np.ones(B.shape[0])
    best = float("inf")
    for _ in range(iters):
        y = B @ x + 1e-300
        best = min(best, float(np.max(y / x)))
        x = y / np.max(y)
    return best


def _stable_step_sparse(model: Model, q0, qd0, rest_length, with_v: bool) -> dict:
    """:func:`stable_step_estimate` for large structures, linear in their size (no dense matrix).

    1. ``K``, ``D`` as sparse matrices (:func:`tensegrity_gym.jacobian.acceleration_jacobians_sparse`:
       the same central differences as the dense path, with column grouping).
    2. Arnoldi (:func:`_top_eigenvalues`) for the :data:`_ARNOLDI_NEV` largest-magnitude eigenvalues
       of ``K`` (``omega_max``; without ``D`` the system's eigenvalues are ``lam = +-sqrt(mu)``, ``mu``
       those of K) and, with ``D``, of the sparse first-order operator ``[[0, I], [K, D]]``:
       ``lambda_max``. Both are the dense path's values to ~1e-5 (tolerance :data:`_ARNOLDI_TOL`).
    3. Step limits from the frequency bound ``L = (1 + 2 tol) lambda_max >= |lam|`` of EVERY mode:
       RK4 is stable for every ``z = dt lam`` in the half-disk ``|z| <= 2.615``
       (:data:`_RK4_HALF_DISK`), so ``dt = 2.615 / L`` is safe (``2 sqrt 2 / L`` without ``D``: the
       modes are then ``+-sqrt(mu)``, oscillations on the imaginary axis). Semi-implicit Euler's
       limit decreases with ``|lam|`` and with the damping rate ``c = -2 Re lam``; ``c`` is at most
       ``c_D = min(|D|_1, |D|_inf)`` (a bound of D's spectral radius: the rates of string damping and
       node drag) and at most ``2 |lam|``, giving ``(sqrt(c^2 + 4 L^2) - c) / L^2`` (``2 / L``
       undamped, ``0.8 / L`` once ``c_D >= 2 L``). The computed top modes' own modal limits (the
       dense path's formulas) are taken too if smaller. An upper bound on the frequency gives a
       conservative step: the result is never above the dense modal estimate (beyond the
       tolerance); it equals it within ``2 tol`` when the top mode limits the step (undamped:
       ``2/omega_max`` and ``2.828/omega_max``) and is below it by at most ``1.002 * 2.9/2.615 =
       1.12`` (RK4 with damping: the dense path allows up to 2.9 between the axes) or
       ``2/0.8 = 2.5`` (semi-implicit Euler, heavily damped). Unlike the
       dense path (<= 20 rods) it has no refinement on the exact step matrix.
    If Arnoldi does not converge (1000 restarts), the rigorous Collatz-Wielandt bound of the
    spectral radius of ``|[[0, I], [K, D]]|`` (:func:`_perron_bound`; 1.3x omega_max on the towers)
    is used as ``L``, with ``0.8 / L`` and ``2.615 / L``."""
    from scipy.sparse import bmat, identity
    from scipy.sparse.linalg import ArpackNoConvergence, norm as spnorm
    from .jacobian import acceleration_jacobians_sparse
    inf = float("inf")
    K, D = acceleration_jacobians_sparse(model, q0, qd0, rest_length, with_velocity=with_v)
    if not (np.all(np.isfinite(K.data)) and (D is None or np.all(np.isfinite(D.data)))):
        return {"omega_max": float("nan"), "lambda_max": float("nan"), "semi_implicit_euler": inf, "rk4": inf,
                "method": "sparse"}
    if D is not None and not np.any(D.data != 0):
        D = None
    n = K.shape[0]
    nev = max(1, min(_ARNOLDI_NEV, n - 2))
    cD = 0.0 if D is None else float(min(spnorm(D, 1), spnorm(D, np.inf)))
    Phi = None if D is None else bmat([[None, identity(n)], [K, D]], format="csr")
    try:
        mu = _top_eigenvalues(K, nev)
        omega = float(np.sqrt(np.abs(mu).max()))
        if D is None:
            lam = np.concatenate([np.sqrt(mu.astype(complex)), -np.sqrt(mu.astype(complex))])
            lmax = omega
        else:
            lam = _top_eigenvalues(Phi, nev)
            lmax = float(np.abs(lam).max())
    except ArpackNoConvergence:
        L = _perron_bound(bmat([[None, identity(n)], [K, None]], format="csr") if Phi is None else Phi)
        out = {"omega_max": float(np.sqrt(_perron_bound(K))), "lambda_max": L, "method": "sparse"}
        out.update({"semi_implicit_euler": 0.8 / L, "rk4": _RK4_HALF_DISK / L} if L > 0
                   else {"semi_implicit_euler": inf, "rk4": inf})
        return out
    if lmax <= 0:
        return {"omega_max": omega, "lambda_max": lmax, "semi_implicit_euler": inf, "rk4": inf, "method": "sparse"}
    lam = lam[np.abs(lam) > 1e-6 * lmax]          # rigid-body and near-zero modes do not limit the step
    lam = np.minimum(lam.real, 0.0) + 1j * lam.imag
    L = (1.0 + 2.0 * _ARNOLDI_TOL) * lmax
    c = min(cD, 2.0 * L)
    sie = (np.sqrt(c * c + 4.0 * L * L) - c) / (L * L)
    if cD >= 2.0 * L:
        sie = min(sie, 0.8 / L)
    rk4 = (2.0 * np.sqrt(2.0) if D is None else _RK4_HALF_DISK) / L
    return {"omega_max": omega, "lambda_max": lmax, "semi_implicit_euler": min(_sie_modal(lam), float(sie)),
            "rk4": min(_rk4_limit(lam), float(rk4)), "method": "sparse"}
