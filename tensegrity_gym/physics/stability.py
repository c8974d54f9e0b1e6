"""Stability of the explicit fixed-step methods: the stable-step estimate of a structure
(:func:`stable_step_estimate`, from the eigenvalues of its linearised dynamics), its per-model
cache (:func:`stability_limit`), the once-per-(model, integrator, dt) :class:`StabilityWarning`
(:func:`check_stability`) and the diagnosis of a diverged run (:func:`divergence_cause`).
"""
from __future__ import annotations

import contextlib
import warnings
import weakref

import numpy as np

from ..core.errors import StabilityWarning
from ..core.integrators import EXPLICIT, IntegratorInfo
from ..core.model import Model, State, initial_state
from .geometry import string_state
from .jacobian import acceleration_jacobians, acceleration_jacobians_sparse

__all__ = ["stable_step_estimate", "stability_limit", "check_stability", "divergence_cause",
           "DENSE_STABILITY_MAX_RODS"]


def _jacobians_fd(model: Model, q, qd, rest_length=None, with_velocity=True):
    """Central-difference Jacobians ``K = da/dq`` (1/s^2) and ``D = da/dq'`` (1/s) of the
    accelerations of ONE state ``q``, ``qd`` (1, k, 6), in one batched call (24 k states):
    :func:`tensegrity_gym.physics.jacobian.acceleration_jacobians`, step ``1e-6 max(1, |q|_inf)``.
    ``D`` is None when ``with_velocity`` is False."""
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

    1. ``K``, ``D`` as sparse matrices (:func:`tensegrity_gym.physics.jacobian.acceleration_jacobians_sparse`:
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


_LIMIT_CACHE: "weakref.WeakKeyDictionary[Model, dict]" = weakref.WeakKeyDictionary()


def stability_limit(model: Model) -> dict:
    """Largest stable step (s) of the explicit methods for ``model`` at its initial state,
    computed once per model and cached: :func:`stable_step_estimate`
    (``{"omega_max": rad/s, "lambda_max": 1/s, "semi_implicit_euler": s, "rk4": s}``), which
    accounts for string damping (it lowers the explicit limits, by 6x for 50 N s/m on the
    default prism)."""
    est = _LIMIT_CACHE.get(model)
    if est is None:
        try:
            est = dict(stable_step_estimate(model))
        except Exception:  # pragma: no cover - an estimate must never break a simulation
            est = {"omega_max": float("nan"), "lambda_max": float("nan"), "semi_implicit_euler": float("inf"),
                   "rk4": float("inf")}
        _LIMIT_CACHE[model] = est
    return est


def check_stability(model: Model, info: IntegratorInfo, dt: float, stacklevel: int = 3) -> None:
    """Warn once per (model, integrator, dt) if an explicit method's dt is above its limit.
    The (integrator, dt) pairs already checked live in the model's own ``__dict__`` (the frozen
    dataclass allows it; nothing else reads it), so a repeated call costs one set lookup."""
    seen = model.__dict__.get("_stability_checked")
    if seen is None:
        seen = model.__dict__.setdefault("_stability_checked", set())
    key = (info.name, dt)
    if key in seen:
        return
    seen.add(key)
    if info.name not in EXPLICIT:
        return
    limit = stability_limit(model)[info.name]
    if dt > limit:
        warnings.warn(StabilityWarning(
            f"{info.name}: dt = {dt:.4g} s is above the estimated stability limit {limit:.4g} s of this "
            f"structure (highest natural frequency {stability_limit(model)['omega_max']:.4g} rad/s); "
            f"use dt <= {limit:.3g} s or integrator='implicit_euler'"),
            stacklevel=stacklevel)


def divergence_cause(model: Model, info: IntegratorInfo, dt: float, last: State, rest_length) -> str:
    """A short diagnosis of why a fixed-step run went non-finite, from the last finite state."""
    if info.name in EXPLICIT:
        est = stability_limit(model)
        limit = est[info.name]
        if dt > limit:
            return (f"dt = {dt:g} s is above the estimated stability limit {limit:.3g} s of {info.name} "
                    f"(highest natural frequency {est['omega_max']:.4g} rad/s): reduce dt or use "
                    "integrator='implicit_euler'")
    parts = []
    try:
        l0 = model.rest_length if rest_length is None else rest_length
        _, L, _ = string_state(model, last.q)
        strain = np.where(l0 > 0, (L - l0) / np.where(l0 > 0, l0, 1.0), 0.0)
        i = np.unravel_index(int(np.nanargmax(strain)), strain.shape)[-1]
        parts.append(f"largest string strain {float(np.nanmax(strain)):.3g} (string {i}, "
                     f"stiffness {model.stiffness[i]:.3g} N/m)")
        parts.append(f"largest speed {float(np.nanmax(np.abs(last.qd[..., :3]))):.3g} m/s")
    except Exception:  # pragma: no cover
        pass
    what = ", ".join(parts)
    return ("a string far too stiff for this step, a huge external/control force or a rod rotating "
            f"more than about one radian per step (last finite state at t = {last.t:.6g} s: {what})")

