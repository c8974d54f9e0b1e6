"""The actuation update on tensors: the cable motor (:func:`update_motor`), the rate-limited
update (:func:`update_rate`) and the physics inputs of the controls (:func:`physics_inputs`).
Same operations as :class:`tensegrity_gym.physics.actuation.Actuation`.
"""
from __future__ import annotations

import weakref

import numpy as np

from .model import _torch

__all__ = ["update_motor", "update_rate", "physics_inputs"]

_ACTS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _act_tensors(actuation, like) -> dict:
    """The constants of an :class:`~tensegrity_gym.physics.actuation.Actuation` as tensors on ``like``'s
    device and dtype (cached per actuation, device and dtype: no host copy per call):
    ``low``, ``high``, ``max_rate`` (na,), ``base`` (m,) rest lengths, ``idx`` (na,) int64."""
    torch = _torch()
    per = _ACTS.setdefault(actuation, {})
    key = (str(like.device), str(like.dtype))
    c = per.get(key)
    if c is None:
        def T(x):
            return torch.as_tensor(np.array(x, dtype=float), dtype=like.dtype, device=like.device)
        c = per[key] = {"low": T(actuation.low), "high": T(actuation.high), "max_rate": T(actuation.max_rate),
                        "base": T(actuation.base_rest_length),
                        "idx": torch.as_tensor(np.array(actuation.actuated, dtype=np.int64), device=like.device)}
    return c


def update_motor(actuation, ctrl, speed, action, max_rate=None, max_accel=None):
    """The cable motor (``Actuation.update_motor``) on tensors (B, na): rate toward the command
    ``action * max_rate`` by at most ``max_accel * control_dt``, control moved by
    ``rate * control_dt`` and clipped to [low, high], rate zeroed at an end stop. Returns
    ``(new control, new rate)``. ``max_rate`` (P, na) unit/s and ``max_accel`` (P, 1) unit/s^2:
    per-copy limits as tensors (``Actuation.set_copy_limits``); None: the actuation's nominal ones."""
    torch = _torch()
    if actuation.max_accel is None:
        raise ValueError("motor: this Actuation has no max_accel (no motor model)")
    c = _act_tensors(actuation, ctrl)
    low, high = c["low"], c["high"]
    rate = c["max_rate"] if max_rate is None else max_rate
    if max_accel is None:
        dv = actuation.max_accel * actuation.control_dt
        v = speed + torch.clamp(action * rate - speed, -dv, dv)
    else:
        dv = max_accel * actuation.control_dt
        v = speed + torch.minimum(torch.maximum(action * rate - speed, -dv), dv)
    new = torch.minimum(torch.maximum(ctrl + v * actuation.control_dt, low), high)
    stop = ((new <= low) & (v < 0.0)) | ((new >= high) & (v > 0.0))
    v = torch.where(stop, torch.zeros_like(v), v)
    return new, v


def update_rate(actuation, ctrl, action, max_rate=None):
    """The control update without a motor model (``Actuation.update_rate``): ``clip(ctrl + action *
    max_rate * control_dt, low, high)`` on tensors (B, na); ``max_rate`` (P, na) per-copy rate
    limits (unit/s) or None (the nominal ones)."""
    torch = _torch()
    c = _act_tensors(actuation, ctrl)
    rate = (c["max_rate"] if max_rate is None else max_rate) * actuation.control_dt
    return torch.minimum(torch.maximum(ctrl + action * rate, c["low"]), c["high"])


def physics_inputs(actuation, ctrl) -> dict:
    """``rest_length`` (B, m) or ``force_density`` (B, m) tensors from the actuated controls
    (B, na) (``Actuation.physics_inputs``), differentiable in ``ctrl``."""
    c = _act_tensors(actuation, ctrl)
    B = ctrl.shape[0]
    if actuation.mode == "rest_length":
        return {"rest_length": c["base"].expand(B, -1).index_copy(1, c["idx"], ctrl)}
    fd = ctrl.new_zeros((B, actuation.n_strings)).index_copy(1, c["idx"], ctrl)
    return {"rest_length": None, "force_density": fd}


