"""Compiled (numba) helpers for the Python-side work around one env step.

At B = 1 a control step of physics is one ~20 us kernel call, and each NumPy call on a tiny
array costs ~1 us, so the bookkeeping around the physics (action check, control update,
physics inputs, divergence check, node positions, errors, observation) dominated ``step()``.
These loops fuse that work into a handful of compiled calls. They compute exactly what the
NumPy reference code in :mod:`tensegrity_gym.envs.common` / :mod:`tensegrity_gym.envs.shape`
computes, element by element in the same order (no fast-math, so no reassociation or fused
multiply-adds): results are bit-identical, which ``tests/test_fast_paths.py`` checks. Sums
are only done here where NumPy's order is strictly sequential (fewer than 8 terms); longer
ones are left to NumPy by the callers.

:func:`shape_step` goes further for the shape task: the control update, the physics kernel
itself (``_kernels._run_serial``, called from compiled code, so no ``integrators.step`` /
``State`` wrappers), the divergence check, the observation, the errors and the tracking term
in ONE compiled call per ``step()``. (numba's on-disk cache does not notice edits of
``_kernels.py``: clear ``__pycache__`` after changing the kernels.)

``AVAILABLE`` is False without numba; callers then run their NumPy reference path.
"""
from __future__ import annotations

import numpy as np

try:  # pragma: no cover - exercised by the import itself
    import numba
    from numba import njit
    AVAILABLE = True
except Exception:  # pragma: no cover - numba missing or broken
    AVAILABLE = False

__all__ = ["AVAILABLE", "clip_action", "apply_controls", "apply_motor", "state_ok", "shape_observe", "mean_max",
           "roll_observe", "shape_step", "SHAPE_STEP_SIG"]

if AVAILABLE:
    @njit(cache=True, nogil=True)
    def clip_action(a, clip, tol):
        """``a``: 1-d float64 (the raveled action, modified in place). Returns False (and leaves
        ``a`` partly clipped) if an entry is non-finite, or with ``clip`` False beyond ``1 + tol``
        of the box: the caller then runs the reference check, which raises the right error.
        Otherwise clips ``a`` to [-1, 1] in place (``np.clip`` semantics) and returns True."""
        for i in range(a.size):
            v = a[i]
            if not np.isfinite(v):
                return False
            if not clip and abs(v) > 1.0 + tol:
                return False
            if v < -1.0:
                a[i] = -1.0
            elif v > 1.0:
                a[i] = 1.0
        return True

    @njit(inline="always", cache=True, nogil=True)
    def _physics_row(phys_out, b, base, fill_base, m):
        """Row ``b`` of the physics input before its actuated columns are set: ``base`` (m,)
        (rest lengths) when ``fill_base``, zeros (force densities of the passive strings) otherwise."""
        if fill_base:
            for j in range(m):
                phys_out[b, j] = base[j]
        else:
            for j in range(m):
                phys_out[b, j] = 0.0

    @njit(cache=True, nogil=True)
    def apply_controls(ctrl, action, rate, low, high, actuated, base, fill_base, ctrl_out, phys_out):
        """``ctrl_out = clip(ctrl + action * rate, low, high)`` (B, na) and the physics input
        ``phys_out`` (B, m): ``base`` (m,) (rest lengths; zeros for force densities when
        ``fill_base`` is False) with the actuated columns set to ``ctrl_out``. ``rate`` (P, na):
        one row shared by every copy (P = 1) or one per copy (P = B)."""
        B, na = ctrl.shape
        m = phys_out.shape[1]
        per_copy = rate.shape[0] > 1
        for b in range(B):
            _physics_row(phys_out, b, base, fill_base, m)
            rb = b if per_copy else 0
            for i in range(na):
                v = ctrl[b, i] + action[b, i] * rate[rb, i]
                # np.clip(v, lo, hi) == minimum(maximum(v, lo), hi), NaN propagating
                if v < low[i]:
                    v = low[i]
                if v > high[i]:
                    v = high[i]
                ctrl_out[b, i] = v
                phys_out[b, actuated[i]] = v

    @njit(cache=True, nogil=True)
    def apply_motor(ctrl, speed, action, max_rate, dv, dt, low, high, actuated, base, fill_base,
                    ctrl_out, speed_out, phys_out):
        """Motor model of ``Actuation.apply_motor``: ``v = speed + clip(action * max_rate - speed,
        -dv, dv)``, ``ctrl_out = clip(ctrl + v * dt, low, high)``, ``v = 0`` where the control
        sits on a bound and ``v`` pushes beyond it (``speed_out``), and the physics input
        ``phys_out`` as :func:`apply_controls`. ``max_rate`` (P, na) and ``dv`` (P,): one row
        shared (P = 1) or one per copy (P = B)."""
        B, na = ctrl.shape
        m = phys_out.shape[1]
        per_copy = max_rate.shape[0] > 1
        for b in range(B):
            _physics_row(phys_out, b, base, fill_base, m)
            rb = b if per_copy else 0
            dvb = dv[rb]
            for i in range(na):
                d = action[b, i] * max_rate[rb, i] - speed[b, i]
                if d < -dvb:
                    d = -dvb
                if d > dvb:
                    d = dvb
                v = speed[b, i] + d
                x = ctrl[b, i] + v * dt
                if x < low[i]:
                    x = low[i]
                if x > high[i]:
                    x = high[i]
                if (x <= low[i] and v < 0.0) or (x >= high[i] and v > 0.0):
                    v = 0.0
                ctrl_out[b, i] = x
                speed_out[b, i] = v
                phys_out[b, actuated[i]] = x

    @njit(cache=True, nogil=True)
    def state_ok_local(q, qd, center_z, limit):
        """Like :func:`state_ok` for a robot that travels: every entry of ``q``, ``qd`` (B, k, 6)
        finite, every reference point within ``limit`` (per coordinate) of its copy's mean
        reference point, and that mean's height within ``limit`` of ``center_z``. Horizontal
        travel is not limited."""
        B, k, _ = q.shape
        for b in range(B):
            m0 = 0.0
            m1 = 0.0
            m2 = 0.0
            for j in range(k):
                for c in range(6):
                    if not (np.isfinite(q[b, j, c]) and np.isfinite(qd[b, j, c])):
                        return False
                m0 += q[b, j, 0]
                m1 += q[b, j, 1]
                m2 += q[b, j, 2]
            m0 /= k
            m1 /= k
            m2 /= k
            if not (abs(m2 - center_z) <= limit):
                return False
            for j in range(k):
                if not (abs(q[b, j, 0] - m0) <= limit and abs(q[b, j, 1] - m1) <= limit
                        and abs(q[b, j, 2] - m2) <= limit):
                    return False
        return True

    @njit(cache=True, nogil=True)
    def state_ok(q, qd, center, limit):
        """True if every entry of ``q``, ``qd`` (B, k, 6) is finite and every reference point is
        within ``limit`` (per coordinate) of ``center`` (3,)."""
        B, k, _ = q.shape
        for b in range(B):
            for j in range(k):
                for c in range(6):
                    if not (np.isfinite(q[b, j, c]) and np.isfinite(qd[b, j, c])):
                        return False
                for c in range(3):
                    if not (abs(q[b, j, c] - center[c]) <= limit):
                        return False
        return True

    @njit(cache=True, nogil=True)
    def shape_observe(q, qd, rod, eta, ctrl, target, obs, dist):
        """Observation of the shape task (see ``ShapeTask.observe``) into ``obs`` (B, 12 nt + na)
        float32 and the node errors |target - N| into ``dist`` (B, nt) float64. Tracked node
        ``t`` sits at ``r + eta[t] b`` of rod ``rod[t]`` (as ``dynamics.node_positions``)."""
        B = q.shape[0]
        nt = rod.size
        na = ctrl.shape[1]
        o_v = 3 * nt
        o_c = 6 * nt
        o_t = 6 * nt + na
        o_e = 9 * nt + na
        for b in range(B):
            for t in range(nt):
                j = rod[t]
                e = eta[t]
                s = 0.0
                for c in range(3):
                    x = q[b, j, c] + e * q[b, j, 3 + c]
                    v = qd[b, j, c] + e * qd[b, j, 3 + c]
                    g = target[b, t, c]
                    d = x - g
                    obs[b, 3 * t + c] = np.float32(x)
                    obs[b, o_v + 3 * t + c] = np.float32(v)
                    obs[b, o_t + 3 * t + c] = np.float32(g)
                    obs[b, o_e + 3 * t + c] = np.float32(g - x)
                    if c == 0:
                        s = d * d
                    else:
                        s = s + d * d
                dist[b, t] = np.sqrt(s)
            for i in range(na):
                obs[b, o_c + i] = np.float32(ctrl[b, i])

    @njit(cache=True, nogil=True)
    def mean_max(dist, mean, mx):
        """Row means and maxima of ``dist`` (B, nt) into ``mean``, ``mx`` (B,), exactly as
        ``np.add.reduce(dist, 1) / nt`` and ``np.maximum.reduce(dist, 1)``: NumPy sums fewer than
        8 numbers strictly left to right (its pairwise summation starts unrolling at 8), so this
        returns False, computing nothing, when nt >= 8; the caller then uses NumPy."""
        B, nt = dist.shape
        if nt >= 8 or nt == 0:
            return False
        for b in range(B):
            s = dist[b, 0]
            m = dist[b, 0]
            for t in range(1, nt):
                v = dist[b, t]
                s = s + v
                if m == m and (v != v or v > m):   # NaN propagates, as in np.maximum
                    m = v
            mean[b] = s / nt
            mx[b] = m
        return True

    @njit(cache=True, nogil=True)
    def roll_observe(q, qd, rod, eta, com, ctrl, active, goal, speed, obs):
        """Observation of the roll task (see ``RollTask.observe``) into ``obs`` (B, size) float32:
        node positions relative to ``com`` (B, 3), node velocities, controls, contact flags,
        goal direction, centre-of-mass height, then the cable speeds ``speed`` (B, ns) (ns = 0
        without the motor model). Node ``i`` sits at ``r + eta[i] b`` of rod ``rod[i]``."""
        B = q.shape[0]
        n = rod.size
        na = ctrl.shape[1]
        nc = active.shape[1]
        n3 = 3 * n
        for b in range(B):
            for i in range(n):
                j = rod[i]
                e = eta[i]
                for c in range(3):
                    x = q[b, j, c] + e * q[b, j, 3 + c]
                    obs[b, 3 * i + c] = np.float32(x - com[b, c])
                    obs[b, n3 + 3 * i + c] = np.float32(qd[b, j, c] + e * qd[b, j, 3 + c])
            o = 2 * n3
            for i in range(na):
                obs[b, o + i] = np.float32(ctrl[b, i])
            o += na
            for i in range(nc):
                obs[b, o + i] = np.float32(1.0) if active[b, i] else np.float32(0.0)
            o += nc
            obs[b, o] = np.float32(goal[b, 0])
            obs[b, o + 1] = np.float32(goal[b, 1])
            obs[b, o + 2] = np.float32(com[b, 2])
            o += 3
            for i in range(speed.shape[1]):
                obs[b, o + i] = np.float32(speed[b, i])

    from .. import _kernels

    @njit(cache=True)   # holds the GIL: the physics kernel uses the scratch inside buf
    def shape_step(q, qd, ctrl, action, target, buf, fcon, icon, qo, qdo, ctrl_out, obs, dist, stats, success,
                   elapsed):
        """One control step of the shape task in ONE compiled call (``ShapeTask.step``'s fast
        path): the control update (:func:`apply_controls`), the physics (``_kernels._run_serial``,
        the very kernel ``integrators.step`` runs, ``icon[0]`` steps of ``fcon[0]`` s, flags
        ``icon[1]``), the divergence check (:func:`state_ok`), the observation and node errors
        (:func:`shape_observe`) and the error statistics (:func:`mean_max`; ``stats`` (4, B):
        mean error, max error, the proximity term's exponent ``-0.5 t^2`` of
        ``rewards.tolerance`` (NaN inside the tolerance; the exp itself is left to NumPy, whose
        exp may differ from LLVM's in the last bit) and the tracking term
        ``-tracking_weight * mean error``), ``success`` (B,) bool (max error within the
        tolerance) and ``elapsed`` (B,) int64 incremented (both only when mean/max are done
        here)).

        ``fcon``: dt, divergence limit, centre (3), tolerance, margin, gaussian scale,
        -tracking_weight, then per
        actuated string rate, low, high, base rest lengths (m), then eta (nt). ``icon``:
        n_steps, flags, fill_base, na, m, nt, then actuated (na), rod (nt).
        Inputs are only read; results go to the fresh output arrays. Returns 0 (all done), 2
        (done but mean/max left to NumPy: nt >= 8), 1 (physics done, state diverged: outputs
        ``qo``, ``qdo``, ``ctrl_out`` valid, the rest not computed) or -1 (shapes do not fit:
        nothing valid, the caller runs the reference path, which raises the right error)."""
        n_steps, flags, fill_base, na, m, nt = icon[0], icon[1], icon[2] != 0, icon[3], icon[4], icon[5]
        B = q.shape[0]
        if (ctrl.shape[0] != B or ctrl.shape[1] != na or action.shape[0] != B or action.shape[1] != na
                or target.shape[0] != B or target.shape[1] != nt or target.shape[2] != 3
                or qo.shape[0] != B or ctrl_out.shape[0] != B or ctrl_out.shape[1] != na
                or obs.shape[0] != B or obs.shape[1] != 12 * nt + na or dist.shape[0] != B
                or dist.shape[1] != nt or stats.shape[0] != 4 or stats.shape[1] != B
                or success.shape[0] != B or elapsed.shape[0] != B):
            return -1
        o = 9
        phys = np.empty((B, m))
        apply_controls(ctrl, action, fcon[o:o + na].reshape((1, na)), fcon[o + na:o + 2 * na],
                       fcon[o + 2 * na:o + 3 * na],
                       icon[6:6 + na], fcon[o + 3 * na:o + 3 * na + m], fill_base, ctrl_out, phys)
        # rest-length mode: phys is rest_length; force-density mode (flags carry _L0DEF | _FD):
        # phys is force_density; the external-force argument is never read (no _EXT)
        err = _kernels._run_serial(q, qd, qo, qdo, buf, phys, phys, q, fcon[0], n_steps, flags)
        if err:
            return -1
        if not state_ok(qo, qdo, fcon[2:5], fcon[1]):
            return 1
        shape_observe(qo, qdo, icon[6 + na:6 + na + nt], fcon[o + 3 * na + m:o + 3 * na + m + nt], ctrl_out,
                      target, obs, dist)
        done = mean_max(dist, stats[0], stats[1])
        if done:
            tol, margin, scale, neg_w = fcon[5], fcon[6], fcon[7], fcon[8]
            for b in range(B):
                stats[3, b] = neg_w * stats[0, b]
                x = stats[1, b]
                success[b] = x <= tol
                if 0.0 <= x and x <= tol:
                    stats[2, b] = np.nan
                else:
                    t = ((0.0 - x if x < 0.0 else x - tol) / margin) * scale
                    stats[2, b] = -0.5 * (t * t)
        if not done:
            return 2
        for b in range(B):
            elapsed[b] += 1
        return 0

    _c1 = "C"
    _F8, _I8 = numba.types.float64, numba.types.int64
    SHAPE_STEP_SIG = _I8(*[numba.types.Array(_F8, d, _c1) for d in (3, 3, 2, 2, 3, 1, 1)],
                         numba.types.Array(_I8, 1, _c1),
                         *[numba.types.Array(_F8, d, _c1) for d in (3, 3, 2)],
                         numba.types.Array(numba.types.float32, 2, _c1),
                         *[numba.types.Array(_F8, d, _c1) for d in (2, 2)],
                         numba.types.Array(numba.types.boolean, 1, _c1), numba.types.Array(_I8, 1, _c1))
else:  # pragma: no cover
    clip_action = apply_controls = apply_motor = state_ok = shape_observe = mean_max = roll_observe = None
    shape_step = SHAPE_STEP_SIG = None
