"""The NumPy reference of the physics equations: the test oracle of the numba kernels.

Each equation is written once per backend and the NumPy path is a test oracle: the package computes every step, projection, rod acceleration and contact force with
the numba kernels (:mod:`tensegrity_gym.backends.numba`, :mod:`tensegrity_gym.physics.pipeline`; torch in
:mod:`tensegrity_gym.backends.torch`). This module keeps the vectorised NumPy formulation they
were written from, so the tests can check the kernels against a second, independent transcription
of the same equations (the node-coordinate model in ``tests/reference.py`` checks the
formulation itself):

* :func:`rod_accelerations` -- free rod (5.37)/(5.40) and the reduced form of constrained rods
  (5.49)-(5.51) (Sherman-Morrison), from the nodal forces of :func:`nodal_forces`;
* :func:`force_densities`, :func:`nodal_forces` -- the string force equation (tension over
  length, slack strings and pushing dampers carry nothing, the force-density control) and the
  nodal forces ``W - C_S^T Gamma C_S N`` with gravity, node drag and external forces;
* :func:`accelerations`, :func:`project`;
* :func:`step` -- semi-implicit Euler (with the great-circle drift :func:`sphere_drift` when
  projecting) and RK4, a callable ``external`` evaluated at every stage;
* :func:`contact_forces` and :func:`contact_step` -- the ground contact (Hunt-Crossley normal
  force, stick/slip Coulomb friction) and its sub-step loop;
* :func:`rod_contact_forces` (with :func:`segment_closest`) -- rod-rod contact between capsules;
* the bookkeeping of a control step that the package compiles: :func:`actuation_apply` and
  :func:`actuation_apply_motor` (rate limits, the cable motor), :func:`diverged`,
  :func:`roll_observation`.

SI units; shapes as the package's functions take them. Not installed with the package.
"""
from __future__ import annotations

import contextlib

import numpy as np

from tensegrity_gym.physics.geometry import node_velocities, string_state
from tensegrity_gym.core.integrators import resolve
from tensegrity_gym.physics.integrate import rk4_update
from tensegrity_gym.physics.contact import PRM_FIELDS, ContactState
from tensegrity_gym.core.model import State
from tensegrity_gym.core.params import check_params
from tensegrity_gym.physics.integrate import _as_batch


# ---------------------------------------------------------------------- string forces
def force_densities(model, q: np.ndarray, qd: np.ndarray, rest_length=None, force_density=None,
                    params=None):
    """NumPy string force densities gamma (B, m), N/m (tension / length, >= 0), the string vectors
    S (B, m, 3) and lengths L (B, m) (:func:`tensegrity_gym.physics.evaluate.force_densities`).
    ``params``: a :class:`~tensegrity_gym.core.params.Params` (P = 1 or B copies) whose stiffness,
    damping, rest lengths, ... replace the model's (default None: the model's)."""
    p = model if params is None else params
    l0 = p.rest_length if rest_length is None else rest_length
    S, L, Ld = string_state(model, q, qd if p.has_damping else None, params)
    taut = L > l0
    safeL = np.where(taut, L, 1.0)
    tension = p.stiffness * (L - l0)
    if p.has_damping:
        tension = tension + p.damping * Ld
    gamma = np.where(taut, np.maximum(tension, 0.0) / safeL, 0.0)
    if force_density is not None:
        gamma = np.maximum(gamma + force_density, 0.0)
    return gamma, S, L


def nodal_forces(model, q, qd, rest_length=None, force_density=None, external=None, params=None):
    """Total nodal forces W - N C_S^T Gamma C_S (B, n, 3), N, and gamma (B, m). ``W``: gravity
    loads, node drag ``-c v`` (if the model has ``node_damping``) and ``external``.
    ``params``: per-copy physical values (see :func:`force_densities`)."""
    gamma, S, _ = force_densities(model, q, qd, rest_length, force_density, params)
    # -C^T (gamma s), scattered by the string index arrays (cost linear in B m, no m x n product):
    # node j of string i gets -gamma_i s_i, node i gets +gamma_i s_i
    return add_loads(model, _scatter_string_forces(model, gamma[..., None] * S), qd, external, params), gamma


def add_loads(model, F, qd, external=None, params=None):
    """``F`` (B, n, 3) plus the loads ``W``: gravity, node drag ``-c v`` and ``external``, N."""
    p = model if params is None else params
    if p.has_gravity:
        F = F + p.W0
    if p.has_node_damping:
        F = F - p.node_damping[..., None] * node_velocities(model, qd)
    if external is not None:
        F = F + external
    return F


def _scatter_string_forces(model, X: np.ndarray) -> np.ndarray:
    """(B, n, 3) nodal forces ``-C_S^T X`` of per-string vectors X (B, m, 3) = gamma s (N): node
    ``str_i`` of string i gets ``+X_i``, node ``str_j`` gets ``-X_i``. ``np.add.at`` for a few
    strings (lowest call overhead), else one ``np.bincount`` per component (fast for large B m).
    Both sum each node's ``+X`` terms and its ``-X`` terms separately, in string order, and
    subtract: the same operations, so a copy's forces do not depend on the batch size."""
    B, n = X.shape[0], model.n_nodes
    if B * model.n_strings <= 128:
        Fi = np.zeros((B, n, 3))
        Fj = np.zeros((B, n, 3))
        np.add.at(Fi, (slice(None), model.str_i), X)
        np.add.at(Fj, (slice(None), model.str_j), X)
        return Fi - Fj
    base = (np.arange(B) * n)[:, None]
    ii = (base + model.str_i).ravel()
    jj = (base + model.str_j).ravel()
    F = np.empty((B, n, 3))
    for c in range(3):
        xc = X[..., c].ravel()
        F[..., c] = (np.bincount(ii, xc, minlength=B * n) - np.bincount(jj, xc, minlength=B * n)).reshape(B, n)
    return F


# ---------------------------------------------------------------------- rod equations
def rod_accelerations(model, q, qd, F, params=None):
    b, bd = q[..., 3:], qd[..., 3:]
    Fa, Fc = F[:, model.rod_a], F[:, model.rod_c]
    fr = Fa + Fc
    fb = model.eta[None, :, 0, None] * Fa + model.eta[None, :, 1, None] * Fc
    bb = np.einsum("bki,bki->bk", b, b)[..., None]
    w = np.einsum("bki,bki->bk", bd, bd)[..., None] / bb
    Pfb = fb - b * np.einsum("bki,bki->bk", b, fb)[..., None] / bb
    p = model if params is None else params
    f = p.f[..., None]
    J = p.J[..., None]
    m = p.mass[..., None]
    h = fr - (f / J) * Pfb + f * w * b
    # A h with A = (Pi - beta u u^T/(alpha + beta |u|^2)) / alpha, u = Pi b / |b|
    alpha = m - f * f / J
    beta = f * f / J
    Pi = model.proj
    u = np.einsum("kij,bkj->bki", Pi, b) / np.sqrt(bb)
    Pih = np.einsum("kij,bkj->bki", Pi, h)
    uu = np.einsum("bki,bki->bk", u, u)[..., None]
    uh = np.einsum("bki,bki->bk", u, h)[..., None]
    rdd = (Pih - beta * u * uh / (alpha + beta * uu)) / alpha
    Prdd = rdd - b * np.einsum("bki,bki->bk", b, rdd)[..., None] / bb
    bdd = Pfb / J - (f / J) * Prdd - w * b
    return np.concatenate([rdd, bdd], axis=-1)


def accelerations(model, q: np.ndarray, qd: np.ndarray, rest_length=None, force_density=None,
                  external=None, params=None) -> np.ndarray:
    """NumPy ``[r'', b'']`` (B, k, 6), m/s^2 and 1/s^2: :func:`rod_accelerations` of the nodal forces
    of :func:`nodal_forces`; arguments as :func:`tensegrity_gym.physics.evaluate.accelerations`."""
    F, _ = nodal_forces(model, q, qd, rest_length, force_density, external, params)
    return rod_accelerations(model, q, qd, F, params)


def project(model, q: np.ndarray, qd: np.ndarray):
    """Project onto the constraint manifold: ``|b| = 1``, ``b . b' = 0``, the constrained
    nodes back on their line/plane/point (and their velocity tangent to it).
    Returns new ``(q, qd)``; free rods' reference points are untouched."""
    r, b = q[..., :3], q[..., 3:]
    rd, bd = qd[..., :3], qd[..., 3:]
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    bd = bd - b * np.einsum("bki,bki->bk", b, bd)[..., None]
    if model.constrained.any():
        r = model.offset + np.einsum("kij,bkj->bki", model.proj, r)
        rd = np.einsum("kij,bkj->bki", model.proj, rd)
    return np.concatenate([r, b], axis=-1), np.concatenate([rd, bd], axis=-1)


_project = project   # step's keyword ``project`` (a flag) shadows the function inside it

_SINC_SMALL = 1e-4   # the numba backend's value: below this angle per step sin(x)/x = 1 - x^2/6 to round-off


def sphere_drift(q, qd, dt):
    """Drift half of semi-implicit Euler with ``project=True``: ``r += dt r'`` and each rod
    direction moved along its great circle (the exact geodesic flow on the unit sphere).

    With ``b`` normalised, ``b'`` made tangent (``b' -= b (b . b')``), ``w = |b'|`` (1/s) and
    ``x = w dt``: ``b <- b cos x + b' sin(x)/w``, ``b' <- -b w sin x + b' cos x``. This keeps
    ``|b| = 1``, ``b . b' = 0``, ``|b'|`` and ``b x b'`` exactly, so a freely spinning rod
    neither gains energy nor angular momentum (the Euler update ``b += dt b'`` followed by a
    normalisation shrinks ``b'`` relative to the rotation and does). The radial part of
    ``b''`` (the centripetal term ``-|b'|^2 b``) is what the great circle replaces. Operation
    order mirrored by ``backends/numba/equations._drift_rod`` (round-off agreement)."""
    r, b = q[..., :3], q[..., 3:]
    rd, bd = qd[..., :3], qd[..., 3:]
    r = r + dt * rd
    b = b * (1.0 / np.sqrt(np.einsum("bki,bki->bk", b, b)))[..., None]
    bd = bd - b * np.einsum("bki,bki->bk", b, bd)[..., None]
    w = np.sqrt(np.einsum("bki,bki->bk", bd, bd))[..., None]
    x = w * dt
    small = x < _SINC_SMALL
    xs = np.where(small, 1.0, x)
    sinc = np.where(small, 1.0 - x * x / 6.0, np.sin(xs) / xs)   # sin(x)/x
    c = np.cos(x)
    bn = b * c + bd * (dt * sinc)
    bdn = bd * c - b * (w * (x * sinc))                          # w sin x = w x sinc
    return np.concatenate([r, bn], axis=-1), np.concatenate([rd, bdn], axis=-1)


def contact_forces(c, model, q, qd, anchor, active, prm=None):
    B = q.shape[0]
    # parameters: (1, 1) or (B, 1) columns of the per-copy array (the contact's own values by default)
    P = c._prm if prm is None else prm
    col = {f: P[:, i:i + 1] for i, f in enumerate(PRM_FIELDS)}
    height, radius, kn, dn, friction = col["height"], col["radius"], col["stiffness"], col["damping"], col["friction"]
    kt, ct, cmax = col["tangential_stiffness"], col["tangential_damping"], col["max_damping"]
    k = model.n_bars
    r, b = q[..., :3], q[..., 3:]
    rd, bd = qd[..., :3], qd[..., 3:]
    eta = model.eta  # (k, 2)
    # contact positions / velocities (B, k, 2, 3) -> (B, 2k, 3), order rod j end a, end c
    Pc = (r[:, :, None, :] + eta[None, :, :, None] * b[:, :, None, :]).reshape(B, 2 * k, 3)
    V = (rd[:, :, None, :] + eta[None, :, :, None] * bd[:, :, None, :]).reshape(B, 2 * k, 3)
    delta = height + radius - Pc[..., 2]
    touch = delta > 0.0
    dpos = np.where(touch, delta, 0.0)
    de = dpos if c.exponent == 1.0 else dpos ** c.exponent
    kd = kn * de
    cn = np.minimum(kd * dn, cmax)
    Fn = np.where(touch, np.maximum(kd - cn * V[..., 2], 0.0), 0.0)
    pt = Pc[..., :2]
    anchor = np.where((touch & ~active)[..., None], pt, anchor)
    xi = pt - anchor
    Ft = -kt[..., None] * xi - ct[..., None] * V[..., :2]
    norm = np.sqrt(np.einsum("bci,bci->bc", Ft, Ft))
    lim = friction * Fn
    slip = touch & (norm > lim)
    scale = np.where(slip, lim / np.where(slip, norm, 1.0), 1.0)
    Ft = Ft * scale[..., None]
    anchor = np.where(slip[..., None], pt + Ft / kt[..., None], anchor)
    Ft = np.where(touch[..., None], Ft, 0.0)
    Fc = np.concatenate([Ft, Fn[..., None]], axis=-1)  # (B, 2k, 3)
    W = np.zeros((B, model.n_nodes, 3))
    W[:, model.rod_a] = Fc[:, 0::2]
    W[:, model.rod_c] = Fc[:, 1::2]
    return W, anchor, touch, slip


def segment_closest(d1, d2, r):
    """``(s, t)`` (...,) in [0, 1]: the parameters of the closest points ``P1 + s d1``, ``P2 + t d2``
    of two segments (``r = P1 - P2``; (..., 3) arrays): the lines' closest points clamped and
    corrected once each way; parallel segments (sin^2 of the angle below 1e-12): the middle of
    the overlap of the second's projection on the first, or the first's end nearest to it."""
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    b = np.einsum("...i,...i->...", d1, d2)
    c = np.einsum("...i,...i->...", d1, r)
    f = np.einsum("...i,...i->...", d2, r)
    denom = a * e - b * b
    general = denom > 1e-12 * a * e
    with np.errstate(divide="ignore", invalid="ignore"):
        s_gen = np.clip((b * f - c * e) / np.where(general, denom, 1.0), 0.0, 1.0)
    s0 = -c / a
    s1 = s0 + b / a
    lo = np.maximum(np.minimum(s0, s1), 0.0)
    hi = np.minimum(np.maximum(s0, s1), 1.0)
    s_par = np.where(lo <= hi, 0.5 * (lo + hi), np.where(hi < 0.0, 0.0, 1.0))
    s = np.where(general, s_gen, s_par)
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    return s, t


def rod_contact_forces(rc, model, q, qd):
    """(B, n, 3) N: the rod-rod contact forces (``tensegrity_gym.physics.rod_contact``) of every
    pair i < j: capsules of ``rc.radius``, the normal spring-damper on the overlap of the closest
    points, regularised Coulomb friction, both damping coefficients capped, each force split
    between a rod's nodes by its closest-point parameter."""
    B, k = q.shape[0], model.n_bars
    eta = model.eta
    r, b, rd, bd = q[..., :3], q[..., 3:], qd[..., :3], qd[..., 3:]
    A = r + eta[None, :, 0, None] * b          # (B, k, 3) node a
    C = r + eta[None, :, 1, None] * b          # node c
    VA = rd + eta[None, :, 0, None] * bd
    VC = rd + eta[None, :, 1, None] * bd
    R, kn, cn, mu, cmax, veps = (rc.radius, rc.stiffness, min(rc.damping, rc.max_damping), rc.friction,
                                 rc.max_damping, rc.friction_speed)
    W = np.zeros((B, model.n_nodes, 3))
    for i in range(k - 1):
        for j in range(i + 1, k):
            d1, d2 = C[:, i] - A[:, i], C[:, j] - A[:, j]
            s, t = segment_closest(d1, d2, A[:, i] - A[:, j])
            nv = (A[:, i] + s[:, None] * d1) - (A[:, j] + t[:, None] * d2)
            dist = np.linalg.norm(nv, axis=1)
            delta = 2.0 * R - dist
            # the axes meet: the normal of their plane (a perpendicular of rod i if parallel),
            # pointing from rod j's centre to rod i's
            x = np.cross(d1, d2)
            nx = np.linalg.norm(x, axis=1)
            perp = np.stack([d1[:, 1], -d1[:, 0], np.zeros(B)], axis=1)
            vert = perp[:, 0] ** 2 + perp[:, 1] ** 2 < 1e-6 * np.einsum("bi,bi->b", d1, d1)
            perp = np.where(vert[:, None], np.stack([np.zeros(B), d1[:, 2], -d1[:, 1]], axis=1), perp)
            x = np.where((nx > 1e-12 * np.linalg.norm(d1, axis=1) * np.linalg.norm(d2, axis=1))[:, None], x, perp)
            x = x / np.linalg.norm(x, axis=1, keepdims=True)
            g = r[:, i] - r[:, j]
            x = np.where((np.einsum("bi,bi->b", x, g) < 0.0)[:, None], -x, x)
            with np.errstate(divide="ignore", invalid="ignore"):
                n = np.where((dist > 1e-12)[:, None], nv / dist[:, None], x)
            v = (VA[:, i] + s[:, None] * (VC[:, i] - VA[:, i])) - (VA[:, j] + t[:, None] * (VC[:, j] - VA[:, j]))
            vn = np.einsum("bi,bi->b", v, n)
            fn = np.maximum(kn * delta - cn * vn, 0.0)
            vt = v - vn[:, None] * n
            speed = np.linalg.norm(vt, axis=1)
            ct = np.minimum(mu * fn / np.maximum(speed, veps), cmax) if mu > 0 else np.zeros(B)
            F = fn[:, None] * n - ct[:, None] * vt
            F = np.where((delta > 0.0)[:, None], F, 0.0)
            W[:, model.rod_a[i]] += (1.0 - s)[:, None] * F
            W[:, model.rod_c[i]] += s[:, None] * F
            W[:, model.rod_a[j]] -= (1.0 - t)[:, None] * F
            W[:, model.rod_c[j]] -= t[:, None] * F
    return W


def step(model, state, dt, integrator="semi_implicit_euler", *, rest_length=None, force_density=None,
         external=None, project=True, n_steps=1, params=None):
    """``n_steps`` fixed steps of ``dt`` s (``integrator`` "semi_implicit_euler" or "rk4"),
    inputs as :func:`tensegrity_gym.physics.integrate.step` takes them (``external`` an array held
    over the step or a callable ``external(q, qd, t)`` evaluated at every stage). Returns a new
    State; ``t`` summed step by step."""
    name = resolve(integrator).name
    if name not in ("semi_implicit_euler", "rk4"):
        raise ValueError(f"the oracle steps semi_implicit_euler and rk4, not {name!r}")
    B, m = state.batch_size, model.n_strings
    rest_length = _as_batch(rest_length, B, m, "rest_length")
    force_density = _as_batch(force_density, B, m, "force_density")
    if params is not None:
        params = check_params(model, params, B)

    def acc(q, qd, t):
        ext = external(q, qd, t) if callable(external) else external
        return accelerations(model, q, qd, rest_length, force_density, ext, params)

    q, qd, t = state.q, state.qd, state.t
    for _ in range(int(n_steps)):
        if name == "semi_implicit_euler":
            qd = qd + dt * acc(q, qd, t)
            if project:
                q, qd = sphere_drift(q, qd, dt)
            else:
                q = q + dt * qd
        else:   # the RK4 combination of stages (four lines of arithmetic) is the package's
            q, qd = rk4_update(acc, q, qd, t, dt)
        if project:
            q, qd = _project(model, q, qd)
        t = t + dt
    return State(q=q, qd=qd, t=t)


def contact_step(model, contact, state, cstate, dt, integrator="semi_implicit_euler", n_steps=1, external=None,
                 contact_params=None, **inputs):
    """``n_steps`` steps with ground contact, as :func:`tensegrity_gym.physics.pipeline.step` with
    ``contact``: per step the contact forces of the whole batch from the state at the step's
    start (anchors updated), then one :func:`step` with those forces (plus ``external``) held.
    Returns ``(State, ContactState)``, new objects."""
    anchor, active = cstate.anchor.copy(), cstate.active.copy()
    st = state
    for _ in range(int(n_steps)):
        W, anchor, active, _ = contact_forces(contact, model, st.q, st.qd, anchor, active, contact_params)
        if external is not None:
            W = W + external
        st = step(model, st, dt, integrator, external=W, **inputs)
    return st, ContactState(anchor, active)


# ---------------------------------------------------------------------- bookkeeping of the control step
# (compiled once in the package: backends.numba.actuation.apply_controls / apply_motor, backends.numba.divergence.bad_copies, envs.compiled.roll_observe)
def actuation_apply(act, ctrl, action):
    """New control (B, na) of :class:`tensegrity_gym.physics.actuation.Actuation` without a motor model:
    ``clip(ctrl + action * max_rate * control_dt, low, high)``."""
    return np.clip(ctrl + action * act._rate, act.low, act.high)


def actuation_apply_motor(act, ctrl, speed, action):
    """``(new control, new rate)`` (B, na) of the motor model: the rate moves toward ``action *
    max_rate`` by at most ``max_accel * control_dt``, the control by ``rate * control_dt`` within
    its bounds, and the rate drops to 0 where the control sits on a bound it pushes against."""
    dv = act._dv[:, None]
    v = speed + np.clip(action * act.rate_rows - speed, -dv, dv)
    new = np.clip(ctrl + v * act.control_dt, act.low, act.high)
    stop = ((new <= act.low) & (v < 0.0)) | ((new >= act.high) & (v > 0.0))
    return new, np.where(stop, 0.0, v)


def diverged(q, qd, center, limit, local=False):
    """(B,) bool of :func:`tensegrity_gym.physics.pipeline.diverged`: a non-finite entry, or a reference
    point farther than ``limit`` (per coordinate) from ``center`` (with ``local``: from its copy's
    mean reference point, that mean's height checked against ``center[2]``)."""
    with np.errstate(all="ignore"):
        q, qd = np.asarray(q), np.asarray(qd)
        finite = np.isfinite(q).all(axis=(1, 2)) & np.isfinite(qd).all(axis=(1, 2))
        r = np.where(np.isfinite(q[..., :3]), q[..., :3], 0.0)
        if local:
            m = r.mean(axis=1, keepdims=True)
            far = ~((np.abs(r - m).max(axis=(1, 2)) <= limit) & (np.abs(m[:, 0, 2] - center[2]) <= limit))
        else:
            far = ~(np.abs(r - np.asarray(center)).max(axis=(1, 2)) <= limit)
        return ~finite | far


def roll_observation(task):
    """The state observation of TensegrityRoll-v0 (``RollObservation.observe``), float32 (B, size):
    node positions relative to the centre of mass, node velocities, controls, contact flags, goal
    direction, centre-of-mass height, cable speeds."""
    q, qd, B = task.q, task.qd, task.num_envs
    rod, e = task._node_rod_i64, task._node_eta_1d[None, :, None]   # node i at r + e_i b of rod rod[i]
    N = q[:, rod, :3] + e * q[:, rod, 3:]
    V = qd[:, rod, :3] + e * qd[:, rod, 3:]
    com = task._com(q)
    na, nc = task.ctrl.shape[1], task.n_contacts
    obs = np.empty((B, task.observation_size), np.float32)
    n3 = N.shape[1] * 3
    obs[:, :n3] = (N - com[:, None, :]).reshape(B, -1)
    obs[:, n3:2 * n3] = V.reshape(B, -1)
    i = 2 * n3
    obs[:, i:i + na] = task.ctrl
    i += na
    obs[:, i:i + nc] = task.cstate.active
    i += nc
    obs[:, i:i + 2] = task.goal
    obs[:, i + 2] = com[:, 2]
    obs[:, i + 3:] = task.speed
    return obs


def _ref_update_rate(act, ctrl, action):
    new = actuation_apply(act, ctrl, action)
    return new, act.physics_inputs(new)


def _ref_update_motor(act, ctrl, speed, action):
    if act.max_accel is None:
        raise ValueError("update_motor: this Actuation has no max_accel (use update_rate)")
    new, v = actuation_apply_motor(act, ctrl, speed, action)
    return new, v, act.physics_inputs(new)


def _ref_roll_observe(task):
    if task.sensors is not None:
        return task._readings.reshape(task.num_envs, -1).astype(np.float32)
    return roll_observation(task)


@contextlib.contextmanager
def reference_paths():
    """Inside the block the envs run the NumPy references above instead of the package's compiled
    bookkeeping: the control update (``Actuation.update_rate`` / ``update_motor``), the divergence
    check (``pipeline.diverged``), the roll observation, the action check (always the reference
    ``checks.check_action``); a shape task made inside the block tracks its nodes with the NumPy
    observation and takes no fused step (``compiled.node_sources`` says none applies)."""
    import pytest
    from tensegrity_gym.physics import pipeline as physics_pipeline
    from tensegrity_gym.physics.actuation import Actuation
    from tensegrity_gym.core import checks as core_checks
    from tensegrity_gym.envs import compiled
    from tensegrity_gym.envs.roll_obs import RollObservation
    with pytest.MonkeyPatch.context() as m:
        m.setattr(Actuation, "update_rate", _ref_update_rate)
        m.setattr(Actuation, "update_motor", _ref_update_motor)
        m.setattr(physics_pipeline, "diverged", diverged)
        m.setattr(RollObservation, "observe", _ref_roll_observe)
        m.setattr(core_checks, "_clip_in_place", lambda a, clip, tol: False)   # the NumPy action check
        m.setattr(compiled, "node_sources", lambda model, nodes: (None, None))
        yield
