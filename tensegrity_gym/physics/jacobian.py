"""Finite-difference Jacobians, written once: implicit Euler, statics and the stability estimate.

Pure NumPy (+ ``scipy.sparse`` for the sparse form), no gymnasium import.

* :func:`fd_jacobian` -- dense Jacobians of a batched function at B points in **one** call of
  the function: the perturbed copies are stacked perturbation-major along a new leading axis
  (forward differences: ``n`` (+1) copies, central: ``2 n``).
* :func:`fd_jacobian_grouped` -- a sparse Jacobian of one point with column grouping
  (Curtis-Powell-Reid): columns that share no nonzero row are perturbed together, so the cost
  is ``2 G`` evaluations for ``G`` groups instead of ``2 n``; the result is a
  ``scipy.sparse.csr_matrix`` with exactly the given sparsity pattern.
* :func:`acceleration_jacobians` -- ``K = da/dq`` (1/s^2) and ``D = da/dq'`` (1/s) of
  :func:`tensegrity_gym.physics.accelerations` (dense, batched).
* :func:`acceleration_jacobians_sparse` -- the same for one state as sparse matrices: a rod's
  accelerations depend only on its own coordinates and on those of the rods it shares a string
  with, so the rods are coloured (distance-2 greedy colouring of the rod coupling graph) and
  the cost is ``O(colours)`` acceleration evaluations of the whole structure, i.e. linear in
  its size (a tower has ~15-20 colours whatever its height).
"""
from __future__ import annotations

import numpy as np

from ..core import sizing
from .evaluate import accelerations

__all__ = ["fd_jacobian", "fd_jacobian_grouped", "acceleration_jacobians", "acceleration_jacobians_sparse",
           "rod_coupling", "distance2_colouring"]


def fd_jacobian(fun, x: np.ndarray, h, *, central: bool = False, f0: np.ndarray | None = None):
    """Dense finite-difference Jacobians of ``fun`` at B points, one batched call of ``fun``.

    Parameters
    ----------
    fun : callable mapping stacked points ``Z`` (P, B, n) to values (P, B, r).
    x : (B, n) points.
    h : steps, broadcastable to (B, n) (column j of point b is perturbed by ``h[b, j]``).
    central : central differences ``(f(x + h e_j) - f(x - h e_j)) / 2h`` (P = 2n copies), else
        forward differences ``(f(x + h e_j) - f(x)) / h`` (P = n copies, plus the unperturbed
        point as copy 0 unless ``f0`` is given).
    f0 : (B, r) ``fun(x)`` if already known (forward differences only).

    Returns ``(f0, J)``: ``f0`` (B, r) (None for central differences) and ``J`` (B, r, n).
    """
    x = np.asarray(x, dtype=float)
    B, n = x.shape
    h = np.broadcast_to(np.asarray(h, dtype=float), (B, n))
    idx = np.arange(n)
    hT = h.T                                                   # (n, B): step of column j at point b
    if central:
        Z = np.broadcast_to(x, (2 * n, B, n)).copy()
        Z[idx, :, idx] += hT
        Z[n + idx, :, idx] -= hT
        F = fun(Z)
        J = ((F[:n] - F[n:]) / (2.0 * hT[..., None])).transpose(1, 2, 0)
        return None, J
    lead = 0 if f0 is not None else 1
    Z = np.broadcast_to(x, (n + lead, B, n)).copy()
    Z[lead + idx, :, idx] += hT
    F = fun(Z)
    if f0 is None:
        f0 = F[0]
    J = ((F[lead:] - f0[None]) / hT[..., None]).transpose(1, 2, 0)
    return f0, J


def fd_jacobian_grouped(fun, x: np.ndarray, h, groups: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                        n_rows: int, chunk: int | None = None, check: bool = True):
    """Sparse central-difference Jacobian (``n_rows`` x n) of ``fun`` at ONE point ``x`` (n,).

    ``rows``, ``cols``: the sparsity pattern (entries that may be nonzero); ``groups`` (n,): the
    group of each column -- columns of one group must share no row of the pattern (checked
    unless ``check`` is False, for callers whose grouping guarantees it by construction).
    ``fun`` maps stacked points (P, n) to values (P, n_rows); it is called on ``2 G`` points
    (G groups), in chunks of at most ``chunk`` points (default: all at once).
    Returns a ``scipy.sparse.csr_matrix``."""
    import scipy.sparse as sp
    x = np.asarray(x, dtype=float)
    n = x.size
    h = np.broadcast_to(np.asarray(h, dtype=float), (n,))
    groups = np.asarray(groups)
    rows, cols = np.asarray(rows), np.asarray(cols)
    G = int(groups.max()) + 1 if n else 0
    if check and np.unique(groups[cols].astype(np.int64) * n_rows + rows).size != rows.size:
        raise ValueError("fd_jacobian_grouped: two columns of one group share a row of the sparsity pattern")
    step = max((2 * G if chunk is None else max(int(chunk), 2)) // 2, 1)     # groups per chunk
    ge = groups[cols]                                   # group of each pattern entry
    order = np.argsort(ge, kind="stable")
    bounds = np.searchsorted(ge[order], np.arange(G + 1))
    colgroups = np.argsort(groups, kind="stable")        # columns sorted by group
    cbounds = np.searchsorted(groups[colgroups], np.arange(G + 1))
    vals = np.empty(rows.size)
    for g0 in range(0, G, step):                        # memory: O(step n) per chunk, never O(G n)
        g1 = min(G, g0 + step)
        cs = colgroups[cbounds[g0]:cbounds[g1]]
        Z = np.broadcast_to(x, (2 * (g1 - g0), n)).copy()
        Z[groups[cs] - g0, cs] += h[cs]
        Z[g1 - g0 + groups[cs] - g0, cs] -= h[cs]
        F = fun(Z)
        e = order[bounds[g0]:bounds[g1]]
        vals[e] = (F[ge[e] - g0, rows[e]] - F[g1 - g0 + ge[e] - g0, rows[e]]) / (2.0 * h[cols[e]])
    return sp.csr_matrix((vals, (rows, cols)), shape=(n_rows, n))


def _split(model, Z, q, qd, with_velocity: bool):
    """Stacked (P, B, 12k) or (P, B, 6k) coordinates -> (P B, k, 6) q and qd."""
    P, B = Z.shape[:2]
    k = model.n_bars
    n = 6 * k
    Q = Z[..., :n].reshape(P * B, k, 6)
    V = Z[..., n:].reshape(P * B, k, 6) if with_velocity else np.broadcast_to(qd, (P,) + qd.shape).reshape(P * B, k, 6)
    return Q, V


def _tile(x, P: int, B: int):
    """Broadcast a per-batch array (B, ...) to the stacked batch (P B, ...); (m,) arrays and
    arrays shared by the batch ((n, 3) external forces) pass unchanged."""
    if x is None or np.ndim(x) <= 1:
        return x
    x = np.asarray(x)
    if x.shape[0] != B:
        return x
    return np.broadcast_to(x, (P,) + x.shape).reshape((P * B,) + x.shape[1:])


def acceleration_jacobians(model, q: np.ndarray, qd: np.ndarray, rest_length=None, force_density=None,
                           external=None, params=None, *, with_velocity: bool = True, central: bool = False,
                           rel_step: float = 1.5e-8, backend: str = "auto"):
    """Accelerations and their Jacobians at B states by finite differences, one batched call of
    :func:`tensegrity_gym.physics.evaluate.accelerations` (``backend``: numba unless "numpy"; with
    per-copy ``params`` one call per perturbation, each on the B copies).

    Parameters
    ----------
    q, qd : (B, k, 6) configuration ``[r, b]`` (m, 1) and its rate (m/s, 1/s).
    rest_length, force_density : (m,) or (B, m) (m, N/m); external : (B, n, 3) or (n, 3) N or None.
    params : per-copy physical values (:class:`tensegrity_gym.core.params.Params`, 1 or B copies) or None.
    with_velocity : also ``D = da/dq'`` (else None).
    central : central differences (error O(h^2), 2 copies per column) instead of forward ones.
    rel_step : step ``rel_step * max(1, |q_b|_inf)`` for the q columns of state b, likewise with
        ``|qd_b|_inf`` for the qd columns.

    Returns ``(a0, K, D)``: a0 (B, 6k) accelerations (None for central differences), K (B, 6k, 6k)
    in 1/s^2, D (B, 6k, 6k) in 1/s (None unless ``with_velocity``).
    """
    B, k, _ = q.shape
    n = 6 * k
    x = q.reshape(B, n)
    v = qd.reshape(B, n)
    hq = rel_step * np.maximum(1.0, np.abs(x).max(axis=1))   # (B,)
    hv = rel_step * np.maximum(1.0, np.abs(v).max(axis=1))
    if with_velocity:
        z = np.concatenate([x, v], axis=1)
        h = np.concatenate([np.broadcast_to(hq[:, None], (B, n)), np.broadcast_to(hv[:, None], (B, n))], axis=1)
    else:
        z, h = x, np.broadcast_to(hq[:, None], (B, n))

    def fun(Z):
        P = Z.shape[0]
        Q, V = _split(model, Z, q, qd, with_velocity)
        if params is not None and params.batch_size == B and B > 1:   # copy b of every perturbation: params b
            return np.stack([accelerations(model, Q[i * B:(i + 1) * B], V[i * B:(i + 1) * B], rest_length,
                                           force_density, external, params, backend) for i in range(P)]).reshape(P, B, n)
        A = accelerations(model, Q, V, _tile(rest_length, P, B), _tile(force_density, P, B),
                          _tile(external, P, B), params, backend)
        return A.reshape(P, B, n)

    a0, J = fd_jacobian(fun, z, h, central=central)
    K = J[:, :, :n]
    D = J[:, :, n:] if with_velocity else None
    return a0, K, D


def rod_coupling(model):
    """Closed neighbourhoods of the rods: (k, k) ``scipy.sparse.csr_matrix`` (bool pattern) with
    an entry (s, r) when rod s's accelerations may depend on rod r's coordinates: r = s, or a
    string joins a node of r to a node of s (anchors and non-rod nodes couple nothing)."""
    import scipy.sparse as sp
    k = model.n_bars
    owner = np.full(model.n_nodes, -1, dtype=np.int64)
    owner[model.rod_a] = np.arange(k)
    owner[model.rod_c] = np.arange(k)
    a, c = owner[model.str_i], owner[model.str_j]
    keep = (a >= 0) & (c >= 0)
    a, c = a[keep], c[keep]
    rows = np.concatenate([np.arange(k), a, c])
    cols = np.concatenate([np.arange(k), c, a])
    A = sp.csr_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)), shape=(k, k))
    A.sum_duplicates()
    A.data[:] = 1
    return A


def distance2_colouring(A) -> np.ndarray:
    """Greedy colouring (k,) of the rods such that two rods of one colour have no common closed
    neighbour in ``A`` (:func:`rod_coupling`): perturbing all rods of one colour together changes
    every rod's accelerations through at most one of them. Cost O(k d^2) for degree d."""
    A2 = (A @ A).tocsr()
    k = A2.shape[0]
    colour = np.full(k, -1, dtype=np.int64)
    indptr, indices = A2.indptr, A2.indices
    for r in range(k):
        used = set(colour[indices[indptr[r]:indptr[r + 1]]].tolist())
        c = 0
        while c in used:
            c += 1
        colour[r] = c
    return colour


def acceleration_jacobians_sparse(model, q: np.ndarray, qd: np.ndarray, rest_length=None, *,
                                  with_velocity: bool = True, rel_step: float = 1e-6):
    """Central-difference ``K = da/dq`` (1/s^2) and ``D = da/dq'`` (1/s, None unless
    ``with_velocity``) of ONE state ``q``, ``qd`` (1, k, 6) as sparse (6k, 6k) csr matrices.

    Same steps and differences as the dense central form (``rel_step * max(1, |q|_inf)``), with
    the rods coloured by :func:`distance2_colouring`: ``2 * 6 * colours`` (twice that with
    velocity) acceleration evaluations of the whole structure, in chunks of
    :data:`tensegrity_gym.core.sizing.FD_CHUNK_BYTES`. Equal to the dense Jacobian's entries
    inside the pattern to round-off; outside it the dense Jacobian is exactly zero. The
    accelerations: :func:`tensegrity_gym.physics.evaluate.accelerations` (numba when installed)."""
    k = model.n_bars
    n = 6 * k
    x = q.reshape(n).astype(float)
    v = qd.reshape(n).astype(float)
    hq = rel_step * max(1.0, float(np.abs(x).max()))
    hv = rel_step * max(1.0, float(np.abs(v).max()))
    coupling = rod_coupling(model)
    colour = distance2_colouring(coupling)
    A = coupling.tocoo()
    nc = int(colour.max()) + 1
    # entry (row rod s, coord i) x (column rod r, coord c) for every coupled pair (s, r)
    s_, r_ = A.row.astype(np.int64), A.col.astype(np.int64)
    ii, cc = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
    rows = (6 * s_[:, None] + ii.ravel()[None]).ravel()
    cols = (6 * r_[:, None] + cc.ravel()[None]).ravel()
    groups = (6 * colour[:, None] + np.arange(6)[None]).ravel()       # column (r, c) -> 6 colour_r + c
    if with_velocity:
        z = np.concatenate([x, v])
        h = np.concatenate([np.full(n, hq), np.full(n, hv)])
        groups = np.concatenate([groups, groups + 6 * nc])
        rows, cols = np.concatenate([rows, rows]), np.concatenate([cols, cols + n])
    else:
        z, h = x, np.full(n, hq)
    per_state = 8 * (60 * k + 30 * model.n_strings + 20 * model.n_nodes)
    chunk = max(2, sizing.FD_CHUNK_BYTES // max(per_state, 1))

    def fun(Z):
        P = Z.shape[0]
        Q = Z[:, :n].reshape(P, k, 6)
        V = Z[:, n:].reshape(P, k, 6) if with_velocity else np.broadcast_to(qd, (P, k, 6))
        return accelerations(model, Q, V, rest_length).reshape(P, n)

    # the distance-2 colouring makes the grouping valid by construction (tested against the check)
    J = fd_jacobian_grouped(fun, z, h, groups, rows, cols, n, chunk=chunk, check=False)
    if not with_velocity:
        return J, None
    return J[:, :n].tocsr(), J[:, n:].tocsr()
