"""Statics of (constrained) class-1 tensegrity structures: equilibria under gravity and prestress.

Pure NumPy (no gymnasium), batched over a leading axis B, SI units (m, N, N/m).

A configuration is an equilibrium when its generalized forces ``R`` vanish and a stable one when
the tangent stiffness ``K = -dR/dx`` is positive definite (both defined in
:mod:`tensegrity_gym.physics.generalized_forces`, in the local coordinates ``x`` of
:mod:`tensegrity_gym.physics.reduced_coordinates`). This module finds them.

Solver (:func:`equilibrium`, batched :func:`solve_equilibria`)
-------------------------------------------------------------
1. optional dynamic relaxation with kinetic damping (the project's semi-implicit Euler,
   velocities zeroed whenever the kinetic energy passes a peak) from the start nodes,
   which moves towards a *stable* equilibrium from far away;
2. damped Newton (Levenberg-Marquardt) on ``R(x) = 0`` with a finite-difference
   Jacobian, to machine precision;
3. classification: converged + ``K`` positive definite -> stable; otherwise a clear
   :class:`EquilibriumError` naming the reason (all strings slack, mechanism / zero
   stiffness mode, unstable, collapsed or no convergence).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.model import Model, State, compile_model, initial_state
from ..core.structure import Structure
from .evaluate import force_densities, nodal_forces, project
from .generalized_forces import _jacobian, equilibrium_matrix, generalized_residual, stiffness_matrix
from .geometry import kinetic_energy, node_positions, string_state
from .integrate import step
from .reduced_coordinates import ReducedCoordinates, _coords, tangent_basis

__all__ = ["EquilibriumError", "Equilibrium", "ReducedCoordinates", "equilibrium", "solve_equilibria",
           "equilibrium_matrix", "generalized_residual", "stiffness_matrix", "tangent_basis"]

# status codes of solve_equilibria
OK, NOT_CONVERGED, SLACK, MECHANISM, UNSTABLE, DIVERGED = 0, 1, 2, 3, 4, 5
STATUS_NAMES = {OK: "ok", NOT_CONVERGED: "not converged", SLACK: "all strings slack", MECHANISM: "mechanism",
                UNSTABLE: "unstable", DIVERGED: "collapsed or flew apart"}


class EquilibriumError(ValueError):
    """No (stable) static equilibrium was found; the message names the reason."""


@dataclass(frozen=True)
class Equilibrium:
    """A static equilibrium of one structure (SI units).

    nodes (n, 3) m; q (k, 6) configuration; force_density (m,) N/m; tension (m,) N;
    string_length (m,) m; residual: largest generalized force left, N;
    min_stiffness: smallest eigenvalue of the tangent stiffness K, N/m (> 0: stable);
    iterations: Newton iterations; relax_steps: dynamic-relaxation steps used.
    """

    nodes: np.ndarray
    q: np.ndarray
    force_density: np.ndarray
    tension: np.ndarray
    string_length: np.ndarray
    residual: float
    min_stiffness: float
    iterations: int
    relax_steps: int

    @property
    def slack(self) -> np.ndarray:
        """(m,) bool: strings carrying no force."""
        return self.force_density <= 0


def _force_scale(model: Model, rest_length, force_density, q) -> np.ndarray:
    F, gamma = nodal_forces(model, q, np.zeros_like(q), rest_length, force_density)
    _, L, _ = string_state(model, q)
    tens = np.max(gamma * L, axis=1) if model.n_strings else np.zeros(q.shape[0])
    w = float(np.abs(model.W0).sum()) if model.has_gravity else 0.0
    return np.maximum(np.maximum(tens, w), 1.0)


def _relax(model: Model, q: np.ndarray, rest_length, force_density, steps: int, tol: np.ndarray,
           size: float, check_every: int = 50):
    """Kinetic-damping dynamic relaxation (semi-implicit Euler, NumPy path); returns q, steps used."""
    rc = _coords(model)
    B = q.shape[0]
    # step from an upper bound of the highest frequency: K at the start over the smallest nodal mass
    K = stiffness_matrix(model, q, rest_length, force_density)
    kmax = np.max(np.abs(np.linalg.eigvalsh(0.5 * (K + np.swapaxes(K, 1, 2)))), axis=1)
    # a string's own axial stiffness bounds the frequency too (and counts when strings are slack now)
    kmax = np.maximum(kmax, 2.0 * float(np.max(model.stiffness, initial=0.0)))
    kmax = np.maximum(kmax, 1e-9)
    m_min = float(np.min(model.mass)) / 4.0
    dt = float(0.5 * 2.0 / np.sqrt(np.max(kmax) / m_min + 1e-12))
    qd = np.zeros_like(q)
    ke_prev = np.zeros(B)
    used = 0
    center = q[..., :3].mean(axis=1, keepdims=True)
    for s in range(1, steps + 1):
        with np.errstate(all="ignore"):
            st = step(model, State(q, qd, 0.0), dt, "semi_implicit_euler",
                      rest_length=rest_length, force_density=force_density)
        q, qd = st.q, st.qd
        with np.errstate(all="ignore"):
            ke = kinetic_energy(model, qd)
        peak = ke < ke_prev
        qd = np.where(peak[:, None, None], 0.0, qd)
        ke_prev = np.where(peak, 0.0, ke)
        used = s
        if s % check_every == 0:
            if not np.all(np.isfinite(q)) or np.any(np.abs(q[..., :3] - center).max(axis=(1, 2)) > 100 * size):
                break
            R = generalized_residual(model, q, rest_length, force_density)
            if np.all(np.abs(R).max(axis=1) < tol):
                break
    return q, used


def solve_equilibria(model: Model, q0: np.ndarray, rest_length=None, force_density=None, *,
                     relax_steps: int = 0, max_iter: int = 50, rtol: float = 1e-11,
                     stability_rtol: float = 1e-9) -> dict:
    """Batched equilibrium solve (never raises on a failed copy; see ``status``).

    Parameters
    ----------
    model : compiled model (``active_strings`` in it take ``force_density`` as their force density).
    q0 : (B, k, 6) start configurations.
    rest_length : (m,) or (B, m) rest lengths, m (default the model's).
    force_density : (m,) or (B, m) force densities added to the strings, N/m (active strings: theirs).
    relax_steps : dynamic-relaxation steps before Newton (0: Newton from ``q0``).
    max_iter : Newton iterations. rtol : converged when the largest generalized force is below
        ``rtol`` times the force scale (largest tension or total weight, >= 1 N).
    stability_rtol : K's smallest eigenvalue must exceed this times its largest to count as stable.

    Returns a dict of arrays: ``q`` (B, k, 6), ``nodes`` (B, n, 3), ``force_density`` (B, m),
    ``residual`` (B,) N, ``min_stiffness`` (B,) N/m, ``status`` (B,) int (0 ok, 1 not converged,
    2 all strings slack, 3 mechanism, 4 unstable, 5 collapsed), ``iterations``, ``relax_steps``.
    """
    rc = _coords(model)
    q = np.array(q0, dtype=float, copy=True)
    B = q.shape[0]
    size = float(np.max(np.ptp(model.structure.nodes, axis=0))) or 1.0
    scale = _force_scale(model, rest_length, force_density, q)
    tol = rtol * scale
    used_relax = 0
    if relax_steps > 0:
        q, used_relax = _relax(model, q, rest_length, force_density, int(relax_steps), 1e-3 * scale, size)
    q, _ = project(model, q, np.zeros_like(q))
    R = generalized_residual(model, q, rest_length, force_density)
    err = np.abs(R).max(axis=1)
    lam = np.full(B, 1e-6)
    it = 0
    active = np.isfinite(err) & (err >= tol)
    for it in range(1, max_iter + 1):
        if not active.any():
            it -= 1
            break
        ia = np.flatnonzero(active)
        qa = q[ia]
        rl = None if rest_length is None or np.ndim(rest_length) == 1 else rest_length[ia]
        rl = rest_length if rest_length is not None and np.ndim(rest_length) == 1 else rl
        fd = None if force_density is None or np.ndim(force_density) == 1 else force_density[ia]
        fd = force_density if force_density is not None and np.ndim(force_density) == 1 else fd
        T = rc.tangent_basis(qa[..., 3:])
        Jm, Ra = _jacobian(model, rc, qa, T, rl, fd, 1e-7 * size, R[ia])
        JtJ = np.einsum("bij,bik->bjk", Jm, Jm)
        g = np.einsum("bij,bi->bj", Jm, Ra)
        diag = np.maximum(np.einsum("bii->bi", JtJ), 1e-300)
        errs_a = err[ia]
        best_q, best_R, best_err = qa.copy(), Ra.copy(), errs_a.copy()
        lam_a = lam[ia]
        improved = np.zeros(ia.size, bool)
        for _ in range(8):   # Levenberg-Marquardt damping search
            Amat = JtJ + (lam_a[:, None] * diag)[:, :, None] * np.eye(rc.nx)[None]
            try:
                dx = -np.linalg.solve(Amat, g[..., None])[..., 0]
            except np.linalg.LinAlgError:
                dx = -np.einsum("bij,bj->bi", np.linalg.pinv(Amat), g)
            qn = rc.retract(qa, T, dx)
            qn, _ = project(model, qn, np.zeros_like(qn))
            with np.errstate(all="ignore"):
                Rn = generalized_residual(model, qn, rl, fd)
            en = np.abs(Rn).max(axis=1)
            ok = np.isfinite(en) & (en < best_err) & ~improved
            best_q[ok], best_R[ok], best_err[ok] = qn[ok], Rn[ok], en[ok]
            improved |= ok
            lam_a = np.where(ok, np.maximum(lam_a * 0.1, 1e-12), np.where(improved, lam_a, lam_a * 10.0))
            if improved.all():
                break
        q[ia], R[ia], err[ia], lam[ia] = best_q, best_R, best_err, lam_a
        active[ia] = improved & (best_err >= tol[ia])
    # classification
    gamma, _, L = force_densities(model, q, np.zeros_like(q), rest_length, force_density)
    K = stiffness_matrix(model, q, rest_length, force_density)
    Ks = 0.5 * (K + np.swapaxes(K, 1, 2))
    with np.errstate(all="ignore"):
        eig = np.linalg.eigvalsh(np.where(np.isfinite(Ks), Ks, 0.0))
    kmin, kmax = eig[:, 0], np.abs(eig).max(axis=1)
    status = np.full(B, OK)
    far = ~np.isfinite(q).all(axis=(1, 2)) | (np.abs(q[..., :3]).max(axis=(1, 2)) > 100 * size
                                                + np.abs(model.structure.nodes).max())
    conv = err < tol
    # near-zero modes: below the stability threshold; a finite-difference K is accurate to ~1e-7 relative
    zero_mode = np.abs(kmin) <= max(stability_rtol, 1e-6) * kmax
    status[conv & zero_mode] = MECHANISM
    status[conv & ~zero_mode & (kmin < 0)] = UNSTABLE
    status[~conv] = NOT_CONVERGED
    all_slack = ~np.any(gamma > 0, axis=1)
    status[all_slack & ~conv] = SLACK
    status[all_slack & conv & (status != OK)] = SLACK
    status[far] = DIVERGED
    status[all_slack & ~conv] = SLACK
    return {"q": q, "nodes": node_positions(model, q), "force_density": gamma, "string_length": L,
            "residual": err, "min_stiffness": kmin, "status": status, "iterations": it,
            "relax_steps": used_relax, "force_scale": scale}


def equilibrium(structure: Structure | Model, rest_length=None, force_density=None, active_strings=None, *,
                nodes=None, relax_steps: int = 20000, max_iter: int = 50, rtol: float = 1e-11,
                require_stable: bool = True) -> Equilibrium:
    """Static equilibrium of a structure under gravity (if it has gravity) and prestress.

    Parameters
    ----------
    structure : a :class:`Structure` (or a compiled ``Model``).
    rest_length : (m,) rest lengths, m (default: the structure's).
    force_density : (m,) force densities, N/m, of the ``active_strings`` (controlled strings with no
        elastic part; entries of other strings are *added* to their elastic force densities).
    active_strings : indices of force-density-controlled strings (ignored when a Model is given).
    nodes : (n, 3) start positions, m (default: the structure's nodes).
    relax_steps : at most this many dynamic-relaxation steps before the Newton polish
        (0: Newton from ``nodes`` directly; it then converges to the nearest equilibrium,
        which may be unstable -- see ``require_stable``).
    max_iter, rtol : Newton iterations and relative tolerance on the generalized forces.
    require_stable : raise unless the tangent stiffness is positive definite.

    Returns an :class:`Equilibrium`. Raises :class:`EquilibriumError` naming the reason:
    all strings slack, mechanism (a zero-stiffness mode: rigid-body motion not removed by
    ``node_constraints`` or an unstressed infinitesimal mechanism), unstable, collapsed /
    flew apart (no equilibrium under this load), or no convergence (with the residual).
    """
    model = structure if isinstance(structure, Model) else compile_model(structure, active_strings)
    m = model.n_strings
    for nm, arr in (("rest_length", rest_length), ("force_density", force_density)):
        if arr is not None:
            a = np.asarray(arr, float)
            if a.shape != (m,):
                raise ValueError(f"{nm}: expected {m} values (one per string), got shape {a.shape}")
            bad = np.flatnonzero(~np.isfinite(a) | (a < 0))
            if bad.size:
                raise ValueError(f"{nm} of string {bad[0]}: {a[bad[0]]!r} is negative or not finite")
    rl = None if rest_length is None else np.asarray(rest_length, float)[None]
    fd = None if force_density is None else np.asarray(force_density, float)[None]
    st = initial_state(model, 1, nodes=None if nodes is None else np.asarray(nodes, float))
    res = solve_equilibria(model, st.q, rl, fd, relax_steps=relax_steps, max_iter=max_iter, rtol=rtol)
    status = int(res["status"][0])
    name = model.structure.name
    if status == SLACK:
        raise EquilibriumError(f"{name}: no equilibrium -- all strings are slack (rest lengths too long or "
                               "force densities zero), nothing holds the rods")
    if status == DIVERGED:
        raise EquilibriumError(f"{name}: no equilibrium -- the structure collapsed or flew apart during "
                               "relaxation (a mechanism under this load, or strings too weak for gravity)")
    if status == NOT_CONVERGED:
        raise EquilibriumError(f"{name}: no convergence -- largest generalized force {res['residual'][0]:.3g} N "
                               f"after {res['relax_steps']} relaxation steps and {res['iterations']} Newton "
                               f"iterations (tolerance {rtol * res['force_scale'][0]:.3g} N); try more "
                               "relax_steps or other start nodes")
    if require_stable and status == MECHANISM:
        raise EquilibriumError(f"{name}: mechanism -- the equilibrium has a zero-stiffness mode (smallest "
                               f"stiffness eigenvalue {res['min_stiffness'][0]:.3g} N/m): rigid-body motion not "
                               "removed by node_constraints, or an unstressed infinitesimal mechanism")
    if require_stable and status == UNSTABLE:
        raise EquilibriumError(f"{name}: the equilibrium found is unstable (smallest stiffness eigenvalue "
                               f"{res['min_stiffness'][0]:.3g} N/m)")
    gamma = res["force_density"][0]
    L = res["string_length"][0]
    return Equilibrium(nodes=res["nodes"][0], q=res["q"][0], force_density=gamma, tension=gamma * L,
                       string_length=L, residual=float(res["residual"][0]),
                       min_stiffness=float(res["min_stiffness"][0]), iterations=int(res["iterations"]),
                       relax_steps=int(res["relax_steps"]))
