"""System identification: fit physical parameters so that simulated motion matches a recorded one.

:func:`identify` fits named :class:`~tensegrity_gym.core.params.Params` fields of a structure (string
``stiffness`` N/m, string ``damping`` N s/m, rod ``mass`` kg, ``node_damping`` N s/m) to a
recorded trajectory: times ``t`` (S,) in s and node positions ``nodes`` (S, n, 3) in m, with
the strings' rest lengths ``rest_length`` (S, m) in m when the cables were actuated, and a
``node_mask`` when only some nodes were tracked (motion capture).

Method: multiple shooting with variable projection
--------------------------------------------------
The record is cut into W windows of K consecutive samples (``window`` seconds each; windows do
not share samples, so every sample is counted once). Each window is simulated from its own
initial state with the fit's ``integrator`` and step ``dt`` (which divides the sample spacing),
so an error in the parameters cannot accumulate over the whole record: short windows keep the
problem close to linear and well conditioned, long enough windows (about one period of the
slowest mode you want to see) keep the parameters observable.

The initial state of each window (rod positions *and* velocities) is an unknown of the fit,
not read off the record. It starts from the recorded node positions of the window's first
sample and velocities from a local quadratic fit to its first samples (untracked nodes: the
structure's reference shape rigidly aligned to the tracked ones), then is fitted together with
the parameters. Why unknowns rather than finite differences: with 1 mm of position noise a
finite-difference velocity at 1 kHz is off by ~0.1 m/s, and a noisy initial state is an
errors-in-variables bias in every window; untracked nodes have no recorded state at all. As
unknowns, each window's state is set by all K samples of the window (a maximum-likelihood fit
for Gaussian position noise). Per rod the state has ``2 d + 4`` coordinates (``d`` = 3 for a
free rod, fewer for a rod with a constrained node: position and velocity of its reference
point in the allowed directions, 2 tangent directions of ``b`` and 2 of ``b'``).

The state unknowns are eliminated by *variable projection*: for given parameters ``theta`` each
window's state is fitted by a batched Levenberg-Marquardt (all windows in one call), and
:func:`scipy.optimize.least_squares` minimises the remaining residual over ``theta`` alone with
the Jacobian ``(I - J_x J_x^+) J_theta`` per window (Kaufman's projection; ``J_x``: window
state, ``J_theta``: parameters). Every Jacobian is a forward finite difference, and all its
columns, for every window, are ONE batched :func:`~tensegrity_gym.physics.integrate.step` call: copy
``c`` carries its own physical values through per-copy :class:`~tensegrity_gym.core.params.Params`
(W x (1 + p + n_state) copies). Positive quantities are fitted in log space:
``theta = log(value / initial)``, so a step of 0.01 is a 1 % change, the fit cannot make a
value negative, and ``mode="scale"`` fits one ``log`` factor per field.

Standard errors
---------------
``cov(theta) = sigma^2 (J^T J)^-1`` with the projected Jacobian ``J`` (the parameter block of
the inverse of the full normal matrix, i.e. the window states' uncertainty is accounted for)
and ``sigma^2 = SSR / (N_obs - p - W n_state)``, the residual variance per observed coordinate.
They are the 1-sigma errors of a locally linear, unbiased fit with independent Gaussian
position noise of the same size on every coordinate: they say how well the *record*
determines the values, not how wrong the *model* is (integrator error, unmodelled friction).
Standard errors in SI are ``value * se(theta)`` (first order). A parameter with a (near) zero
direction of ``J^T J`` (singular value of the column-scaled Jacobian below ``rank_rtol`` times
the largest, e.g. the damping of a string that never goes taut, anything when nothing moves)
is flagged ``identifiable = False`` with an infinite standard error, and the result is not
``ok``; a fit that stops without meeting its tolerances is ``converged = False``. Both also
raise a :class:`SysIdWarning`. A weak pull towards the starting values (rows
``rank_rtol |J| theta``) keeps the optimiser from wandering along such a flat direction; when
every direction turns out determined, the fit is polished without it (no bias).

Mass, stiffness and damping: string forces scale with stiffness and damping, weight and
inertia with mass, so a robot with all three scaled by one factor moves identically (gravity
and supports do not break this). Motion fixes the ratios; pass the weighed total rod mass
(``total_mass``, kg) and the rod masses are held to sum to it (their ratios are fitted).
Without it such a fit is flagged.

Ground contact: with ``contact`` (a :class:`~tensegrity_gym.physics.contact.GroundContact`) the
windows are simulated on that ground, and its Coulomb coefficient ``friction``, normal stiffness
``ground_stiffness`` (N/m) and Hunt-Crossley damping ``ground_damping`` (s/m) can be fitted like
the other fields (log space, one value each; per-copy contact rows in the same batched
Jacobian). Friction is seen only while caps slide, stiffness and damping only while caps
are pressed into the ground (impacts, resting weight). The record does not hold the stick/slip
state (anchors of sticking caps): each window starts from the one the previous window's
simulation hands on (:meth:`_Problem.carry`), and the fit is repeated three times with it.

Units: SI throughout (s, m, kg, N/m, N s/m). ``jacobian="torch"`` computes the outer residual
Jacobian by forward-mode autograd through the torch backend's rollout instead
(:meth:`_Problem.torch_jacobian`, exact to round-off); the default stays the batched forward
differences (exact to ~1e-7 relative, one numba call per Jacobian), which are faster on CPU.
"""
from __future__ import annotations

import time
import warnings

import numpy as np

from ..core.model import compile_model
from ..core.checks import check_real
from ..core.builders import load_structure
from ..core.model import Model
from ..core.errors import SimulationDiverged
from ..core.integrators import resolve
from ..physics.contact import PRM_FIELDS
from ..io.trajectory import load_csv, load_trajectory
from .sysid_inputs import StartValueError, _check_above_ground, _check_record, _parse_contact, _parse_fit
from .sysid_problem import _THETA_MAX, _Problem
from .sysid_result import (CONTACT_FIELDS, FITTABLE, MISFIT_FLOOR, MISFIT_MOTION, MISFIT_NOISE, SysIdResult,
                           SysIdWarning)
from .sysid_result import _ALIASES, _UNITS  # noqa: F401  (the command line reads them here)

__all__ = ["identify", "SysIdResult", "SysIdWarning", "StartValueError", "FITTABLE", "CONTACT_FIELDS", "load_csv",
           "load_trajectory"]


# ----------------------------------------------------------------------------- the structure
def _model_of(structure_or_model) -> Model:
    if isinstance(structure_or_model, Model):
        return structure_or_model
    return compile_model(load_structure(structure_or_model))


# ----------------------------------------------------------------------------- main entry
def identify(structure_or_model, t, nodes, fit=("stiffness", "damping", "mass"), mode: str = "per_member", *,
             rest_length=None, node_mask=None, window: float | None = None, integrator: str | None = None, dt=None,
             stride: int = 1, initial=None, total_mass=None, max_nfev: int = 60, rank_rtol: float = 1e-4,
             verbose: int = 0, jacobian: str = "fd", contact=None) -> SysIdResult:
    """Fit physical parameters so that simulated motion matches a recorded one (see module doc).

    Parameters
    ----------
    structure_or_model : Structure, built-in name, JSON path or compiled Model. Its values are
        the starting point of the fit (and the fixed values of everything not fitted).
    t : (S,) sample times, s, strictly increasing and evenly spaced.
    nodes : (S, n, 3) recorded node positions, m (NaN allowed where ``node_mask`` is False).
    fit : names of the fitted fields: ``"stiffness"`` (per string, N/m), ``"damping"`` (per
        string, N s/m), ``"mass"`` (alias ``"rod_mass"``; per rod, kg), ``"node_damping"``
        (per node, N s/m); with ``contact``: ``"friction"`` (Coulomb coefficient, 1),
        ``"ground_stiffness"`` (normal, N/m) and ``"ground_damping"`` (Hunt-Crossley, s/m), one
        value each. Force-density-actuated strings and anchors are never fitted.
    mode : ``"per_member"`` (one value per string / rod / node) or ``"scale"`` (one factor
        per field multiplying the starting values).
    rest_length : (S, m) recorded rest lengths, m, for actuated cables; held constant over each
        sample interval at the interval's first value. Default: the structure's.
    node_mask : tracked nodes: node indices, a bool (n,) array or a bool (S, n) array (dropped
        frames). Default: every node, every sample.
    window : shooting window length, s (default 0.2 s; 0.05 s with contact, where impacts and
        stick/slip make the motion strongly nonlinear in the parameters and longer windows end
        in local minima). integrator : ``"rk4"`` (default without contact),
        ``"semi_implicit_euler"`` (default with contact: it takes the contact forces, held over a
        step, exactly) or ``"implicit_euler"``. dt : fit step, s, rounded so that it divides the
        sample spacing (default: ``0.2 / omega_max`` of the structure, with contact at most half
        the contact's stable step (:func:`~tensegrity_gym.physics.contact.stable_step`), or the
        spacing). With contact the fit's step is part of the model: give the step the recording
        was simulated with (a recorded robot: a step well below the stable one).
    stride : fit every ``stride``-th sample only (the fit step is unchanged).
    initial : {field: value or per-item array} starting values replacing the structure's (and the
        contact's: ``{"friction": 0.8, "ground_stiffness": 5e3}``).
    total_mass : the structure's weighed total rod mass, kg. Motion alone cannot tell a robot
        from one with every mass, stiffness and damping scaled by the same factor (weight scales
        with mass too), so fitting ``mass`` together with ``stiffness``/``damping`` needs one
        absolute number: with ``total_mass`` the fitted rod masses are held to sum to it (their
        ratios are fitted). Without it such a fit is flagged unidentifiable.
    max_nfev : most evaluations of the outer least-squares problem.
    rank_rtol : singular values of the (column-scaled) projected Jacobian below ``rank_rtol``
        times the largest mark the directions as unidentifiable.
    jacobian : how the outer problem's residual Jacobian (parameters and window states) is
        computed: ``"fd"`` (default: batched forward differences, one numba call) or ``"torch"``
        (forward-mode autograd through the torch backend's float64 rollout, exact to round-off;
        needs PyTorch and ``integrator`` ``"rk4"`` or ``"semi_implicit_euler"``). The two agree
        to ~1e-6 relative; fd stays the default because it is faster on CPU
        (``docs/sysid.md``). The inner window-state fits use forward differences either way.
    contact : the ground the motion was recorded on: a GroundContact or a dict of its fields
        (``friction``, ``stiffness`` N/m, ``damping`` s/m, ``radius`` m, ``height`` m, ...); its
        values start the fit of the contact fields and hold the others. A tangential stiffness
        equal to the normal one (the default) follows the fitted ``ground_stiffness``. Every
        tracked node must lie above ``height`` (caps on, not in, the ground).

    Returns a :class:`SysIdResult`. Raises ValueError naming the field for bad input.
    """
    from scipy.optimize import least_squares
    t0 = time.perf_counter()
    model = _model_of(structure_or_model)
    check_real(t, "t", "sample times, s")          # before anything else: NumPy would drop the imaginary part
    check_real(nodes, "nodes", "node positions, m")
    names, items, init, base = _parse_fit(model, fit, mode, initial)
    contact, tie = _parse_contact(names, contact, initial)
    for g in names:
        if g in CONTACT_FIELDS:      # one value per ground
            items[g], init[g] = np.zeros(1, int), np.array([float(getattr(contact, CONTACT_FIELDS[g]))])
    t, rec, mask, rl, h = _check_record(model, t, nodes, rest_length, node_mask)
    if contact is not None:
        _check_above_ground(contact, t, rec, mask)
    if integrator is None:
        integrator = "rk4" if contact is None else "semi_implicit_euler"
    if window is None:
        window = 0.2 if contact is None else 0.05
    if total_mass is not None:
        if "mass" not in names:
            raise ValueError("total_mass: only used when 'mass' is fitted")
        if not (np.isfinite(total_mass) and total_mass > 0):
            raise ValueError(f"total_mass: must be a positive mass in kg, got {total_mass!r}")
        total_mass = float(total_mass)
    if jacobian not in ("fd", "torch"):
        raise ValueError(f"jacobian: expected 'fd' or 'torch', got {jacobian!r}")
    if jacobian == "torch" and contact is not None:
        raise ValueError("jacobian: 'torch' has no ground contact; use jacobian='fd'")
    if jacobian == "torch":
        try:
            import torch  # noqa: F401
        except ImportError:
            raise ValueError("jacobian: 'torch' needs PyTorch (pip install 'tensegrity_gym[torch]'); "
                             "use jacobian='fd'") from None
        if resolve(integrator).name not in ("rk4", "semi_implicit_euler"):
            raise ValueError(f"jacobian: 'torch' supports integrator 'rk4' or 'semi_implicit_euler', "
                             f"got {resolve(integrator).name!r}; use jacobian='fd'")
    pb = _Problem(model, t, rec, mask, rl, h, names, items, init, base, mode, float(window), integrator, dt, stride,
                  total_mass, contact, tie)
    if jacobian == "torch":
        pb.jacobian = "torch"
    q0, qd0 = pb.guess()
    cache = {"key": None}

    def solve(theta):
        key = theta.tobytes()
        if cache["key"] != key:
            q, qd = cache.get("q", q0), cache.get("qd", qd0)
            q, qd, res, ok = pb.fit_states(theta, q, qd, Jx_old=cache.get("Jx"))
            if not np.isfinite(res).all():   # a trial step that blew up: restart states from the data
                q, qd, res, ok = pb.fit_states(theta, q0, qd0)
            cache.update(key=key, q=q, qd=qd, res=res, ok=ok)
            pb.nfev += 1
        return cache

    reg = {"lam": 0.0}

    def fun(theta):
        c = solve(theta)
        r = c["res"].ravel()
        return np.concatenate([np.where(np.isfinite(r), r, 1e3),   # a diverged copy: large, finite
                               reg["lam"] * theta])

    def jac(theta):
        c = solve(theta)
        if c.get("Jp_key") != c["key"]:
            sim = pb.simulate(c["q"], c["qd"], pb.physics(theta), np.arange(pb.W))
            Jp, Jx = pb.full_jacobian(theta, c["q"], c["qd"], sim)
            pb.njev += 1
            c.update(Jp=Jp, Jp_key=c["key"])
            cache["Jx"] = Jx
        J = np.where(np.isfinite(c["Jp"]), c["Jp"], 0.0).reshape(-1, pb.p)
        return np.concatenate([J, reg["lam"] * np.eye(pb.p)])

    theta0 = np.zeros(pb.p)
    r0 = fun(theta0)[:-pb.p]
    if not np.isfinite(cache["res"].reshape(pb.W, -1)).all(axis=1).any():
        # every window blows up with the starting values: no fit can start from there
        def span(v):
            lo, hi = float(np.min(v)), float(np.max(v))
            return f"{lo:.3g}" if lo == hi else f"{lo:.3g}..{hi:.3g}"
        start = ", ".join(f"{g}={span(init[g])} {_UNITS[g]}" for g in names)
        raise SimulationDiverged(f"the starting values {start} blow the simulation up in every window of "
                                 f"{(pb.K - 1) * pb.h:g} s (dt {pb.dt:g} s)")
    rms0 = float(np.sqrt(np.sum(r0 ** 2) / max(pb.n_obs, 1)))
    # a weak pull towards the starting values (rows lam * theta, lam = rank_rtol x the largest
    # column norm): it keeps a flat (unidentifiable) direction where it started instead of letting
    # the optimiser wander along it. When the fit then finds every direction determined, it is
    # polished without the pull (which would shift a parameter of relative singular value s by
    # ~(rank_rtol / s)^2 of its change).
    reg["lam"] = rank_rtol * float(np.linalg.norm(jac(theta0)[:-pb.p], axis=0).max())
    warn_list = []

    # contact forces switch (touch-down, stick/slip): the residual has kinks where LM's steps stall
    # at ~1e-7 relative, so a contact fit stops at 1e-6 (far below its standard errors)
    tol = (1e-10, 1e-8) if pb.contact is None else (1e-8, 1e-6)

    def run(theta_start):
        try:
            # 'lm' (MINPACK): its QR of the tall Jacobian runs in its own loops, not in threaded BLAS
            # (trf's SVD of the same matrix is much slower on a loaded machine)
            sol = least_squares(fun, theta_start, jac=jac, method="lm", x_scale=1.0, ftol=tol[0], xtol=tol[1],
                                gtol=1e-10, max_nfev=max_nfev, verbose=verbose)
            return sol.x, sol.status, sol.message
        except (np.linalg.LinAlgError, ValueError) as e:
            return theta_start, -1, f"optimiser failed: {e}"

    def assess(theta):
        """Projected Jacobian at ``theta`` and which parameters it determines (log coordinates)."""
        solve(theta)
        jac(theta)
        Jp = cache["Jp"].reshape(-1, pb.p)
        Jf = np.where(np.isfinite(Jp), Jp, 0.0)        # a diverged copy's column: no information (not converged)
        G = Jf.T @ Jf
        colnorm = np.sqrt(np.diag(G))
        scale = np.where(colnorm > 0, colnorm, 1.0)
        ev, V = np.linalg.eigh(G / np.outer(scale, scale))     # singular values^2 of the column-scaled Jacobian
        sv = np.sqrt(np.clip(ev, 0, None))
        smax = sv.max() if sv.size and sv.max() > 0 else 0.0
        null = (sv <= rank_rtol * smax) if smax > 0 else np.ones_like(sv, bool)
        ident = np.ones(pb.p, bool)
        ident[colnorm <= 1e-12 * max(colnorm.max(), 1e-300)] = False
        for v in V.T[null]:
            u = v / scale                      # the flat direction in log coordinates (relative changes)
            ident[np.abs(u) > 0.01 * np.abs(u).max()] = False
        return Jp, ident

    theta = theta0
    for _ in range(3 if pb.contact is not None else 1):
        if pb.contact is not None:
            # each window's starting stick/slip state comes from the previous window's simulation at
            # the current fit (Problem.carry), then the fit is repeated with it: a fixed point
            c0 = solve(theta)
            pb.carry(theta, c0["q"], c0["qd"])
            cache.update(key=None, Jp_key=None, Jx=None)
        theta, status, message = run(theta)
    Jp, ident = assess(theta)
    if status > 0 and ident.all():
        # every direction is determined: polish without the pull, so it biases nothing
        reg["lam"] = 0.0
        theta, status, message = run(theta)
        Jp, ident = assess(theta)
    c = cache
    inner_ok = bool(c["ok"])
    res = c["res"]
    ssr = float(np.sum(res ** 2))
    rms = float(np.sqrt(ssr / pb.n_obs))
    converged = bool(status > 0 and inner_ok and np.isfinite(res).all() and np.isfinite(Jp).all())
    if not inner_ok:
        message += "; the window-state fits did not all converge"
    sigma2 = ssr / pb.dof
    cov = np.full((pb.p, pb.p), np.inf)
    if ident.any():
        Ji = np.where(np.isfinite(Jp), Jp, 0.0)[:, ident]
        cov_i = sigma2 * np.linalg.pinv(Ji.T @ Ji, rcond=rank_rtol ** 2, hermitian=True)
        ii = np.flatnonzero(ident)
        cov[np.ix_(ii, ii)] = cov_i
    vals = pb.values(theta)
    LJ = pb.log_jacobian(theta)
    covf = np.where(np.isfinite(cov), cov, 0.0)
    # a value at the search bound: the residual no longer depends on it there (its derivative is
    # 0, not "determined"): the record does not fix it within the range searched
    bound = pb.at_bound(theta)
    values, std, rel, idf, scl, scl_se = {}, {}, {}, {}, {}, {}
    for g in names:
        values[g] = vals[g]
        Gg = LJ[g]                                  # (n_items, p): d log value / d theta
        dep = np.abs(Gg) > 1e-9
        idf[g] = ~np.any(dep & ~ident[None], axis=1) & ~bound[g]
        var = np.einsum("ip,pq,iq->i", Gg, covf, Gg)
        rel[g] = np.where(idf[g], np.sqrt(np.abs(var)), np.inf)
        std[g] = values[g] * rel[g]
        if mode == "scale":
            scl[g] = float(values[g][0] / init[g][0])
            scl_se[g] = float(scl[g] * rel[g][0])
    pinned = [f"{g} {FITTABLE[g]} {i}" for g in names for i, b in zip(items[g], bound[g]) if b]
    if pinned:
        warn_list.append(f"at the search bound (a factor of {np.exp(_THETA_MAX):.0f} from its starting value; not "
                         "identifiable, infinite standard error): the record does not fix it in that range; check "
                         "that it was recorded from this structure, and the starting values: " + ", ".join(pinned))
    bad = [f"{g} {FITTABLE[g]} {i}" for g in names for i, ok, b in zip(items[g], idf[g], bound[g]) if not ok and not b]
    if bad:
        warn_list.append("not identifiable from this record (flat or degenerate directions of the residual; "
                         "infinite standard error): " + ", ".join(bad))
    noise, motion = pb.record_scales()
    misfit = bool(rms > max(MISFIT_NOISE * noise, MISFIT_MOTION * motion, MISFIT_FLOOR))
    if misfit:
        warn_list.append(f"the fitted model misses the record: RMS error {rms * 1e3:.3g} mm is above {MISFIT_NOISE:g} x "
                         f"the record's noise ({noise * 1e3:.3g} mm) and {MISFIT_MOTION:g} x its motion "
                         f"({motion * 1e3:.3g} mm RMS); was it recorded from this structure, with the same gravity, "
                         "ground and actuation?")
    if not converged:
        warn_list.append(f"the fit did not converge: {message}")
    for w_ in warn_list:
        warnings.warn(w_, SysIdWarning, stacklevel=2)
    fitted = pb.physics(theta)
    fitted_contact = None
    if contact is not None:            # the contact the fitted motion ran with
        row, f = fitted[1][0], PRM_FIELDS
        fitted_contact = contact.replace(**{k: float(row[f.index(k)]) for k in
                                            ("friction", "stiffness", "damping", "tangential_stiffness")})
    sim = pb.simulate(c["q"], c["qd"], fitted, np.arange(pb.W))
    err = np.linalg.norm(sim - pb.rec, axis=-1)[pb.mask]
    return SysIdResult(
        fields=tuple(names), mode=mode, items={g: items[g].copy() for g in names}, values=values, initial=init,
        std_errors=std, rel_std_errors=rel, identifiable=idf, scale=scl, scale_std_errors=scl_se,
        converged=converged, rms_m=rms, rms_initial_m=rms0, max_error_m=float(err.max()) if err.size else 0.0,
        message=str(message), warnings=warn_list, n_windows=pb.W, samples_per_window=pb.K,
        window_s=(pb.K - 1) * pb.h, sample_dt_s=pb.h, dt_s=pb.dt, n_substeps=pb.n_sub, integrator=pb.integrator,
        n_observations=pb.n_obs, n_state_unknowns=pb.W * pb.ns, nfev=pb.nfev, njev=pb.njev,
        wall_s=time.perf_counter() - t0, params=fitted[0], contact=fitted_contact,
        _plot={"t": pb.t, "recorded": pb.rec, "fitted": sim, "mask": pb.mask},
        at_bound=bound, noise_m=noise, motion_rms_m=motion, misfit=misfit)
