"""Compiled (numba) bookkeeping of the environments: observations, error statistics
and the fused step of the shape task.

At B = 1 a control step of physics is one ~20 us kernel call, and each NumPy call on a tiny
array costs ~1 us, so the bookkeeping around the physics (action check, control update,
physics inputs, divergence check, node positions, errors, observation) dominated ``step()``.
These loops fuse that work into a handful of compiled calls. They compute exactly what the
NumPy reference code in :mod:`tensegrity_gym.envs.validate` / :mod:`tensegrity_gym.envs.shape` /
:mod:`tensegrity_gym.envs.roll` computes, element by element in the same order (no fast-math,
so no reassociation or fused multiply-adds): results are bit-identical, which
``tests/test_fast_paths.py`` checks. Sums are only done here where NumPy's order is strictly
sequential (fewer than 8 terms); longer ones are left to NumPy by the callers.

:func:`shape_step` fuses one control step of the shape task: the control update
(:func:`tensegrity_gym.backends.numba.actuation.apply_controls`), the physics
(:func:`tensegrity_gym.backends.numba.entries.run_plan`: the serial kernel ``physics.step``
runs, from compiled code, so no ``State`` wrappers), the divergence check
(:func:`tensegrity_gym.backends.numba.divergence.state_ok`), the observation, the errors and
the tracking term in ONE compiled call per ``step()``. Everything physical is a call into the
numba backend's compiled entry points (imported from their own modules, so that this module's
cached kernels depend on those modules only); nothing here knows the kernels' flags or buffer
layout.

numba is a required dependency: these helpers always run where they apply; the NumPy paths of the
envs remain for what they do not cover (a tracked node that is an anchor, robot observations).
"""
from __future__ import annotations

import numba
import numpy as np
from numba import njit

from ..backends.numba.actuation import apply_controls as _apply_controls
from ..backends.numba.divergence import state_ok as _state_ok
from ..backends.numba.entries import run_plan as _run_plan, run_plan_simd as _run_plan_simd

__all__ = ["shape_observe", "mean_max", "roll_observe", "shape_step", "shape_step_simd", "SHAPE_STEP_SIG",
           "node_sources"]


def node_sources(model, nodes: np.ndarray):
    """``(rod, eta)`` of the compiled observations: node ``nodes[t]`` sits at ``r + eta[t] b`` of
    rod ``rod[t]`` (int64, float64 (t,)), exactly as ``physics.geometry.node_positions`` writes it (rod_c
    after rod_a, so the last rod wins); ``(None, None)`` (the NumPy path) when a node is an
    anchor or on no rod."""
    if np.isin(nodes, model.anchor_idx).any():
        return None, None
    src_rod = np.full(model.n_nodes, -1)
    src_eta = np.zeros(model.n_nodes)
    for col, ends in ((0, model.rod_a), (1, model.rod_c)):
        src_rod[ends] = np.arange(model.n_bars)
        src_eta[ends] = model.eta[:, col]
    if not np.all(src_rod[nodes] >= 0):
        return None, None
    return (np.ascontiguousarray(src_rod[nodes], dtype=np.int64),
            np.ascontiguousarray(src_eta[nodes], dtype=np.float64))


@njit(cache=True, nogil=True)
def shape_observe(q, qd, rod, eta, ctrl, target, obs, dist):
    """Observation of the shape task (see ``ShapeTask.observe``) into ``obs`` (B, 12 nt + na)
    float32 and the node errors |target - N| into ``dist`` (B, nt) float64. Tracked node
    ``t`` sits at ``r + eta[t] b`` of rod ``rod[t]`` (as ``physics.geometry.node_positions``)."""
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


def _shape_step_py(q, qd, ctrl, action, target, plan, offset, fcon, icon, qo, qdo, ctrl_out, obs, dist, stats, success,
                   elapsed, simd):
    """One control step of the shape task in ONE compiled call (``ShapeTask.step``'s fast
    path): the control update (``apply_controls``), the physics of a
    :class:`tensegrity_gym.backends.numba.plans.Plan` (``buf``, ``dt``, ``n_steps``, ``flags``:
    ``run_plan``), the divergence check (``state_ok``), the observation and
    node errors (:func:`shape_observe`) and the error statistics (:func:`mean_max`; ``stats``
    (4, B): mean error, max error, the proximity term's exponent ``-0.5 t^2`` of
    ``rewards.tolerance`` (NaN inside the tolerance; the exp itself is left to NumPy, whose
    exp may differ from LLVM's in the last bit) and the tracking term
    ``-tracking_weight * mean error``), ``success`` (B,) bool (max error within the
    tolerance) and ``elapsed`` (B,) int64 incremented (both only when mean/max are done
    here)).

    ``offset`` (P, m): rest-length offsets (m) added to the physics input in rest-length mode
    (P = 1 shared, P = B per copy, P = 0 none), as ``BatchedTask.with_offset`` adds them.
    ``fcon``: divergence limit, centre (3), tolerance, margin, gaussian scale,
    -tracking_weight, then per actuated string rate, low, high, base rest lengths (m), then
    eta (nt). ``icon``: fill_base, na, m, nt, then actuated (na), rod (nt).
    Inputs are only read; results go to the fresh output arrays. Returns 0 (all done), 2
    (done but mean/max left to NumPy: nt >= 8), 1 (physics done, state diverged: outputs
    ``qo``, ``qdo``, ``ctrl_out`` valid, the rest not computed) or -1 (shapes do not fit:
    nothing valid, the caller runs the reference path, which raises the right error).
    ``plan``: the tuple (buf, dt, n_steps, flags) of :func:`shape_step`'s arguments. ``simd``:
    None for the instance :func:`shape_step` (the plan's ``simd`` False), True for
    :func:`shape_step_simd`."""
    fill_base, na, m, nt = icon[0] != 0, icon[1], icon[2], icon[3]
    B = q.shape[0]
    if (ctrl.shape[0] != B or ctrl.shape[1] != na or action.shape[0] != B or action.shape[1] != na
            or target.shape[0] != B or target.shape[1] != nt or target.shape[2] != 3
            or qo.shape[0] != B or ctrl_out.shape[0] != B or ctrl_out.shape[1] != na
            or obs.shape[0] != B or obs.shape[1] != 12 * nt + na or dist.shape[0] != B
            or dist.shape[1] != nt or stats.shape[0] != 4 or stats.shape[1] != B
            or success.shape[0] != B or elapsed.shape[0] != B):
        return -1
    o = 8
    phys = np.empty((B, m))
    _apply_controls(ctrl, action, fcon[o:o + na].reshape((1, na)), fcon[o + na:o + 2 * na],
                    fcon[o + 2 * na:o + 3 * na], icon[4:4 + na], fcon[o + 3 * na:o + 3 * na + m], fill_base,
                    ctrl_out, phys)
    if fill_base and offset.shape[0] > 0:      # rest_length + rest_offset (with_offset)
        if offset.shape[1] != m or (offset.shape[0] != 1 and offset.shape[0] != B):
            return -1
        per = offset.shape[0] > 1
        for b in range(B):
            for j in range(m):
                phys[b, j] = phys[b, j] + offset[b if per else 0, j]
    buf, dt, n_steps, flags = plan
    if simd is None:       # a compile-time constant: each instance holds one physics kernel
        err = _run_plan(q, qd, qo, qdo, buf, phys, dt, n_steps, flags)
    else:
        err = _run_plan_simd(q, qd, qo, qdo, buf, phys, dt, n_steps, flags)
    if err:
        return -1
    if not _state_ok(qo, qdo, fcon[1:4], fcon[0]):
        return 1
    shape_observe(qo, qdo, icon[4 + na:4 + na + nt], fcon[o + 3 * na + m:o + 3 * na + m + nt], ctrl_out,
                  target, obs, dist)
    done = mean_max(dist, stats[0], stats[1])
    if done:
        tol, margin, scale, neg_w = fcon[4], fcon[5], fcon[6], fcon[7]
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


_shape_step_inline = njit(inline="always", cache=True)(_shape_step_py)


@njit(cache=True)   # holds the GIL: the physics kernel uses the scratch inside buf
def shape_step(q, qd, ctrl, action, target, buf, dt, n_steps, flags, offset, fcon, icon, qo, qdo, ctrl_out, obs,
               dist, stats, success, elapsed):
    """:func:`_shape_step_py` for a plan run one copy at a time (``plan.simd`` False)."""
    return _shape_step_inline(q, qd, ctrl, action, target, (buf, dt, n_steps, flags), offset, fcon, icon, qo, qdo,
                              ctrl_out, obs, dist, stats, success, elapsed, None)


@njit(cache=True)   # holds the GIL: the physics kernel uses the scratch inside buf
def shape_step_simd(q, qd, ctrl, action, target, buf, dt, n_steps, flags, offset, fcon, icon, qo, qdo, ctrl_out,
                    obs, dist, stats, success, elapsed):
    """:func:`_shape_step_py` for a plan run in SIMD blocks (``plan.simd`` True)."""
    return _shape_step_inline(q, qd, ctrl, action, target, (buf, dt, n_steps, flags), offset, fcon, icon, qo, qdo,
                              ctrl_out, obs, dist, stats, success, elapsed, True)


_c1 = "C"
_F8, _I8 = numba.types.float64, numba.types.int64
SHAPE_STEP_SIG = _I8(*[numba.types.Array(_F8, d, _c1) for d in (3, 3, 2, 2, 3, 1)], _F8, _I8, _I8,
                     numba.types.Array(_F8, 2, _c1), numba.types.Array(_F8, 1, _c1),
                     numba.types.Array(_I8, 1, _c1),
                     *[numba.types.Array(_F8, d, _c1) for d in (3, 3, 2)],
                     numba.types.Array(numba.types.float32, 2, _c1),
                     *[numba.types.Array(_F8, d, _c1) for d in (2, 2)],
                     numba.types.Array(numba.types.boolean, 1, _c1), numba.types.Array(_I8, 1, _c1))
