"""Compiled actuation updates of the numba backend: new controls (rest lengths, m, or force
densities, N/m) from actions in [-1, 1] with rate limits (:func:`apply_controls`) or the cable
motor model (:func:`apply_motor`), and the physics input row of every copy. Bit-identical to the
NumPy reference methods of :class:`tensegrity_gym.physics.actuation.Actuation`.
"""
from __future__ import annotations

from numba import njit

@njit(inline="always", cache=True, nogil=True)
def _update(ctrl, speed, action, rate, dv, dt, low, high, actuated, base, fill_base, motor, ctrl_out,
            speed_out, phys_out):
    B, na = ctrl.shape
    m = phys_out.shape[1]
    per_copy = rate.shape[0] > 1
    for b in range(B):
        if fill_base:            # the physics row before its actuated columns are set
            for j in range(m):
                phys_out[b, j] = base[j]
        else:
            for j in range(m):
                phys_out[b, j] = 0.0
        rb = b if per_copy else 0
        for i in range(na):
            v = 0.0
            if motor:
                d = action[b, i] * rate[rb, i] - speed[b, i]
                if d < -dv[rb]:
                    d = -dv[rb]
                if d > dv[rb]:
                    d = dv[rb]
                v = speed[b, i] + d
                x = ctrl[b, i] + v * dt
            else:
                x = ctrl[b, i] + action[b, i] * rate[rb, i]
            # np.clip(x, lo, hi) == minimum(maximum(x, lo), hi), NaN propagating
            if x < low[i]:
                x = low[i]
            if x > high[i]:
                x = high[i]
            if motor:
                if (x <= low[i] and v < 0.0) or (x >= high[i] and v > 0.0):
                    v = 0.0
                speed_out[b, i] = v
            ctrl_out[b, i] = x
            phys_out[b, actuated[i]] = x

@njit(cache=True, nogil=True)
def apply_controls(ctrl, action, rate, low, high, actuated, base, fill_base, ctrl_out, phys_out):
    """``ctrl_out = clip(ctrl + action * rate, low, high)`` (B, na) and the physics input
    ``phys_out`` (B, m): ``base`` (m,) (rest lengths; zeros for force densities when
    ``fill_base`` is False) with the actuated columns set to ``ctrl_out``. ``rate`` (P, na):
    one row shared by every copy (P = 1) or one per copy (P = B)."""
    _update(ctrl, ctrl, action, rate, low, 0.0, low, high, actuated, base, fill_base, False, ctrl_out,
            ctrl_out, phys_out)

@njit(cache=True, nogil=True)
def apply_motor(ctrl, speed, action, max_rate, dv, dt, low, high, actuated, base, fill_base,
                ctrl_out, speed_out, phys_out):
    """Motor model of ``Actuation.update_motor``: ``v = speed + clip(action * max_rate - speed,
    -dv, dv)``, ``ctrl_out = clip(ctrl + v * dt, low, high)``, ``v = 0`` where the control
    sits on a bound and ``v`` pushes beyond it (``speed_out``), and the physics input
    ``phys_out`` as :func:`apply_controls`. ``max_rate`` (P, na) and ``dv`` (P,): one row
    shared (P = 1) or one per copy (P = B)."""
    _update(ctrl, speed, action, max_rate, dv, dt, low, high, actuated, base, fill_base, True, ctrl_out,
            speed_out, phys_out)
