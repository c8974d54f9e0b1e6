"""Generalized forces of a class-1 tensegrity at rest: the equilibrium residual, the equilibrium
matrix and the tangent stiffness, in the local coordinates of
:mod:`tensegrity_gym.physics.reduced_coordinates`.

Pure NumPy, batched over a leading axis B, SI units (m, N, N/m).

A configuration ``q`` (B, k, 6) = ``[r, b]`` (see :mod:`tensegrity_gym.core.model`) is an
equilibrium iff, with the nodal forces ``F = W - N C_S^T Gamma C_S`` at zero velocity, every rod has

    E_j^T (F_a + F_c) = 0              (force along the allowed directions of its reference point)
    T_j^T (eta_a F_a + eta_c F_c) / l_j = 0   (moment about the reference point, 2 components)

where ``E_j`` (3, d_j) spans the allowed motion of rod j's reference point (d = 3 free rod,
2 on a plane, 1 on a line, 0 pinned) and ``T_j`` (3, 2) spans the plane normal to ``b_j``.
These are the generalized forces conjugate to the local coordinates ``x = (z, u)`` with
``r = r0 + E z`` and ``b = normalize(b0 + T u / l)`` (both in m), so the residual vector
``R(x)`` (B, nx), ``nx = sum_j (d_j + 2)``, is minus the gradient of the potential energy and
``K = -dR/dx`` (N/m) is the tangent stiffness matrix: the equilibrium is stable iff ``K`` is
positive definite. ``R`` is linear in the force densities (the seed's key point):
``R = A(q) gamma + w(q)`` (:func:`equilibrium_matrix`).
"""
from __future__ import annotations

import numpy as np

from ..core.model import Model
from .evaluate import nodal_forces
from .geometry import node_positions
from .jacobian import fd_jacobian
from .reduced_coordinates import _coords

__all__ = ["generalized_residual", "equilibrium_matrix", "stiffness_matrix"]


def generalized_residual(model: Model, q: np.ndarray, rest_length=None, force_density=None,
                         T: np.ndarray | None = None) -> np.ndarray:
    """Generalized forces R (B, nx), N, at rest (zero velocity) -- zero at an equilibrium."""
    F, _ = nodal_forces(model, q, np.zeros_like(q), rest_length, force_density)
    return _coords(model).project_forces(q, F, T)


def equilibrium_matrix(model: Model, q: np.ndarray):
    """``A`` (B, nx, m), ``w`` (B, nx) with generalized forces ``R = A gamma + w`` at ``q``
    for string force densities ``gamma`` (B, m) in N/m (all strings' total force densities;
    ``w`` is the gravity load). Linear in gamma: the seed's key property."""
    rc = _coords(model)
    N = node_positions(model, q)
    S = N[:, model.str_j] - N[:, model.str_i]                     # (B, m, 3)
    B, n, m = q.shape[0], model.n_nodes, model.n_strings
    G = np.zeros((B, n, 3, m))
    ar = np.arange(m)
    # force on node j of string i is -gamma_i s_i, on node i it is +gamma_i s_i
    St = S.transpose(1, 0, 2)          # advanced indices around a slice index as (m, B, 3)
    np.add.at(G, (slice(None), model.str_j, slice(None), ar), -St)
    np.add.at(G, (slice(None), model.str_i, slice(None), ar), St)
    T = rc.tangent_basis(q[..., 3:])
    A = rc.project_forces(q, G, T)
    W = np.broadcast_to(model.W0, (B, n, 3)) if model.has_gravity else np.zeros((B, n, 3))
    w = rc.project_forces(q, np.ascontiguousarray(W), T)
    return A, w


def stiffness_matrix(model: Model, q: np.ndarray, rest_length=None, force_density=None, eps: float = 1e-7):
    """Tangent stiffness ``K = -dR/dx`` (B, nx, nx), N/m, by finite differences (symmetric at an
    equilibrium; its smallest eigenvalue > 0 means stable)."""
    rc = _coords(model)
    T = rc.tangent_basis(q[..., 3:])
    return -_jacobian(model, rc, q, T, rest_length, force_density, eps)[0]


def _tile(x, reps: int, B: int):
    """(m,) stays; (B, m) -> (reps * B, m) (perturbation-major)."""
    if x is None or np.ndim(x) == 1:
        return x
    return np.tile(np.asarray(x), (reps, 1))


def _jacobian(model, rc, q, T, rest_length, force_density, eps, R0=None):
    """Forward-difference dR/dx (B, nx, nx) in the local coordinates x (step ``eps``, m) around
    ``q``, all nx perturbations in one batched evaluation (:func:`tensegrity_gym.physics.jacobian.fd_jacobian`)."""
    B, nx = q.shape[0], rc.nx
    if R0 is None:
        R0 = generalized_residual(model, q, rest_length, force_density, T)

    def fun(dx):                                   # (P, B, nx) local coordinates -> (P, B, nx) forces
        P = dx.shape[0]
        qc = rc.retract(np.tile(q, (P, 1, 1)), np.tile(T, (P, 1, 1, 1)), dx.reshape(P * B, nx))
        R = generalized_residual(model, qc, _tile(rest_length, P, B), _tile(force_density, P, B),
                                 np.tile(T, (P, 1, 1, 1)))
        return R.reshape(P, B, nx)

    _, Jm = fd_jacobian(fun, np.zeros((B, nx)), eps, f0=R0)
    return Jm, R0
