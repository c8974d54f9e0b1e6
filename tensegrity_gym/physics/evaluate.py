"""Quantities of a batch of states without a step: accelerations ``[r'', b'']``, string force
densities and nodal forces, the projection onto the constraints. Each is computed by a
backend's own equations (the ones every step runs); the NumPy reference is the test oracle
``tests/oracle_numpy.py``.
"""
from __future__ import annotations

import numpy as np

from ..backends.numba import api as numba_api
from ..core.integrators import numba_backend
from ..core.model import Model
from .geometry import node_positions

__all__ = ["accelerations", "project", "string_forces", "force_densities", "nodal_forces", "external_forces"]


def external_forces(external, q, qd, t):
    """The external nodal forces (B, n, 3), N, at ``(q, qd, t)``: ``external`` itself (an array
    or None) or, for a callable, ``external(q, qd, t)``."""
    if external is None:
        return None
    if callable(external):
        return external(q, qd, t)
    return external


def force_densities(model: Model, q: np.ndarray, qd: np.ndarray, rest_length=None, force_density=None,
                    params=None):
    """``(gamma, S, L)``: string force densities gamma (B, m), N/m (tension / length, >= 0: the
    tension ``k (L - l0) + c dL/dt`` while the string is longer than its rest length and pulls,
    else 0, plus the ``force_density`` control, clipped at 0), string vectors S (B, m, 3) =
    n_j - n_i, m, and lengths L (B, m), m, of the states ``q``, ``qd`` (B, k, 6).
    ``rest_length`` (m,) or (B, m), m, and ``force_density`` (m,) or (B, m), N/m, as
    :func:`accelerations` takes them; ``params``: a :class:`~tensegrity_gym.core.params.Params`
    (P = 1 or B copies) whose stiffness, damping, rest lengths, ... replace the model's.
    Computed by the numba kernels' own string-force equation (the one every step evaluates:
    :func:`string_forces`); its NumPy reference is the test oracle
    ``tests/oracle_numpy.py``."""
    gamma, L, _ = numba_api.string_forces(model, q, qd, rest_length, force_density, None, params)
    N = node_positions(model, np.asarray(q, dtype=np.float64).reshape(-1, model.n_bars, 6), params)
    return gamma, N[:, model.str_j] - N[:, model.str_i], L


def nodal_forces(model: Model, q, qd, rest_length=None, force_density=None, external=None, params=None):
    """Total nodal forces ``W - N C_S^T Gamma C_S`` (B, n, 3), N, and the force densities gamma
    (B, m), N/m (:func:`force_densities`). ``W``: gravity loads, node drag ``-c v`` (if the model
    has ``node_damping``) and ``external`` ((n, 3) or (B, n, 3), N). ``params``: per-copy
    physical values. Computed by the numba kernels' force equations
    (:func:`string_forces`; NumPy reference: ``tests/oracle_numpy.py``)."""
    gamma, _, F = numba_api.string_forces(model, q, qd, rest_length, force_density, external, params)
    return F, gamma


def accelerations(model: Model, q: np.ndarray, qd: np.ndarray, rest_length=None, force_density=None,
                  external=None, params=None, backend: str = "auto") -> np.ndarray:
    """Second derivatives (B, k, 6) ``[r'', b'']`` of the configuration (m/s^2, 1/s^2).

    ``rest_length``: (m,) or (B, m) string rest lengths, m (default the model's).
    ``force_density``: (m,) or (B, m) force densities added by a controller, N/m.
    ``external``: (B, n, 3) or (n, 3) external nodal forces, N (gravity is added
    by the model itself when the structure has it).
    ``params``: a :class:`~tensegrity_gym.core.params.Params` with 1 or B rows: copy b's masses,
    stiffnesses, damping, rest lengths, node drag, gravity and anchors (default: the model's).
    ``backend``: "auto" or "numba". What the adaptive and implicit methods and the
    finite-difference Jacobians evaluate: the numba kernels' equations (the ones every fixed step
    runs); the NumPy reference is the test oracle ``tests/oracle_numpy.py``."""
    numba_backend(backend)
    return numba_api.accelerations(model, q, qd, rest_length, force_density, external, params)


def project(model: Model, q: np.ndarray, qd: np.ndarray):
    """Project onto the constraint manifold: ``|b| = 1``, ``b . b' = 0``, the constrained
    nodes back on their line/plane/point (and their velocity tangent to it).
    ``q``, ``qd`` (B, k, 6) or (k, 6); returns new ``(q, qd)`` of the same shape; free rods'
    reference points are untouched. Computed by the numba kernels' own projection (the one
    every fixed step ends with: :func:`tensegrity_gym.backends.numba.api.project`); its NumPy reference
    is the test oracle ``tests/oracle_numpy.py``."""
    return numba_api.project(model, q, qd)



def string_forces(model: Model, q: np.ndarray, qd: np.ndarray, rest_length=None, force_density=None,
                  external=None, params=None):
    """``(gamma, L, F)`` of the states ``q``, ``qd`` (B, k, 6): string force densities gamma
    (B, m), N/m (tension / length, >= 0), string lengths L (B, m), m, and total nodal forces F
    (B, n, 3), N (strings, gravity, node drag, ``external`` (n, 3) or (B, n, 3), N). Inputs as
    :func:`accelerations`; the equations every step evaluates, no step taken."""
    return numba_api.string_forces(model, q, qd, rest_length, force_density, external, params)
