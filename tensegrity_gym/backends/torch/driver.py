"""Stepping on the torch backend: :func:`accelerations`, one step on prepared inputs
(:func:`step_once`), ``n_steps`` steps (:func:`step`), and NumPy ``State`` in and out
(:func:`step_state`, :func:`simulate`). SI units.
"""
from __future__ import annotations

import math

import numpy as np

from ...core.errors import SimulationDiverged
from ...core.integrators import fixed_step_name
from ...core.model import State
from .equations import _accel, project, sphere_drift
from .model import TorchModel, _torch, resolve_device, resolve_dtype, torch_model, torch_params

__all__ = ["accelerations", "step_once", "step", "step_state", "simulate", "integrator_name", "prepare_steps"]


def _setup(model, q, params, rest_length, force_density):
    """TorchModel and parameter dict for tensors ``q`` (device/dtype from ``q``)."""
    torch = _torch()
    if not isinstance(q, torch.Tensor):
        raise TypeError(f"q: expected a torch.Tensor (B, k, 6), got {type(q).__name__}; "
                        "for NumPy states use step_state or physics.step(..., backend='torch')")
    if q.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"dtype: {q.dtype} is not supported; use float32 or float64")
    tm = model if isinstance(model, TorchModel) else torch_model(model, q.device, q.dtype)
    if q.ndim != 3 or q.shape[1:] != (tm.k, 6):
        raise ValueError(f"q: expected shape (B, {tm.k}, 6), got {tuple(q.shape)}")
    B = q.shape[0]
    prm = torch_params(tm, params, B)
    rest_length = _control(tm, rest_length, B, "rest_length")
    force_density = _control(tm, force_density, B, "force_density")
    return tm, prm, rest_length, force_density


def _control(tm, x, B, name):
    torch = _torch()
    if x is None:
        return None
    if isinstance(x, torch.Tensor):
        if x.device != tm.device:
            raise ValueError(f"{name}: tensor on device {str(x.device)!r}, but the state is on {str(tm.device)!r}")
        x = x.to(tm.dtype)
    else:
        x = torch.as_tensor(np.array(x, dtype=float), dtype=tm.dtype, device=tm.device)
    if tuple(x.shape) not in ((tm.m,), (B, tm.m), (1, tm.m)):
        raise ValueError(f"{name}: expected shape ({tm.m},) or ({B}, {tm.m}), got {tuple(x.shape)}")
    return x


def _check_external(tm, external, B):
    torch = _torch()
    if external is None:
        return None
    if not isinstance(external, torch.Tensor):
        external = torch.as_tensor(np.array(external, dtype=float), dtype=tm.dtype, device=tm.device)
    elif external.device != tm.device:
        raise ValueError(f"external: tensor on device {str(external.device)!r}, but the state is on "
                         f"{str(tm.device)!r}")
    if tuple(external.shape) not in ((tm.n, 3), (B, tm.n, 3), (1, tm.n, 3)):
        raise ValueError(f"external: expected shape ({B}, {tm.n}, 3) or ({tm.n}, 3) (N), got {tuple(external.shape)}")
    return external.to(tm.dtype)


def accelerations(model, q, qd, rest_length=None, force_density=None, external=None, params=None):
    """``[r'', b'']`` (B, k, 6) of torch tensors ``q``, ``qd`` (B, k, 6) (as
    :func:`tensegrity_gym.physics.geometry.accelerations`; ``params``: see the module doc)."""
    tm, prm, rl, fd = _setup(model, q, params, rest_length, force_density)
    return _accel(tm, q, qd, prm, rl, fd, _check_external(tm, external, q.shape[0]))




def integrator_name(integrator) -> str:
    """The resolved name of a method the torch backend runs (``semi_implicit_euler`` or ``rk4``);
    ValueError naming ``integrator`` otherwise."""
    return fixed_step_name(integrator, "torch")


def prepare_steps(model, q, integrator, dt, params, rest_length, force_density, external):
    """``(name, dt, tm, prm, rl, fd, ext)`` of a stepping loop on ``q`` (B, k, 6): the resolved
    integrator name, ``dt`` as a float (ValueError naming it unless positive and finite, s), the
    model, parameters and controls as tensors (:func:`_setup`) and the checked external nodal
    forces (B or 1, n, 3) N or None."""
    name = integrator_name(integrator)
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a positive finite time step in seconds, got {dt}")
    tm, prm, rl, fd = _setup(model, q, params, rest_length, force_density)
    return name, dt, tm, prm, rl, fd, _check_external(tm, external, q.shape[0])


def step_once(tm, q, qd, dt, name, prm, rl, fd, ext, project_):
    """One integrator step on prepared inputs (``tm``: :class:`TorchModel`, ``prm``:
    :func:`torch_params`' dict, ``name``: a resolved integrator name, ``rl`` / ``fd`` / ``ext``:
    controls and nodal forces or None): the unit :func:`step` repeats, and what ``torch.compile``
    wraps (``step(..., substep=torch.compile(step_once))``). Returns ``(q, qd)``."""
    if name == "semi_implicit_euler":
        qd = qd + dt * _accel(tm, q, qd, prm, rl, fd, ext)
        if project_:
            q, qd = sphere_drift(q, qd, dt)
        else:
            q = q + dt * qd
    else:
        h = 0.5 * dt
        a1 = _accel(tm, q, qd, prm, rl, fd, ext)
        q2, qd2 = q + h * qd, qd + h * a1
        a2 = _accel(tm, q2, qd2, prm, rl, fd, ext)
        q3, qd3 = q + h * qd2, qd + h * a2
        a3 = _accel(tm, q3, qd3, prm, rl, fd, ext)
        q4, qd4 = q + dt * qd3, qd + dt * a3
        a4 = _accel(tm, q4, qd4, prm, rl, fd, ext)
        q = q + dt / 6.0 * (qd + 2.0 * qd2 + 2.0 * qd3 + qd4)
        qd = qd + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    if project_:
        q, qd = project(tm, q, qd)
    return q, qd


def step(model, q, qd, dt: float, integrator: str = "semi_implicit_euler", n_steps: int = 1, rest_length=None,
         force_density=None, params=None, project: bool = True, external=None, substep=None):
    """Advance torch tensors ``q``, ``qd`` (B, k, 6) by ``n_steps`` fixed steps of ``dt`` s.

    ``integrator``: ``"semi_implicit_euler"`` (great-circle drift when ``project``) or
    ``"rk4"``; ``rest_length`` / ``force_density``: (m,) or (B, m) held over the steps (m, N/m);
    ``external``: (B, n, 3) or (n, 3) nodal forces, N, held; ``params``: per-copy parameters
    (module doc); ``substep``: a replacement for :func:`step_once` with its signature (e.g.
    ``torch.compile(step_once)``). Returns new ``(q, qd)``; differentiable with respect to every
    tensor input."""
    name = integrator_name(integrator)
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a positive finite time step in seconds, got {dt}")
    if int(n_steps) != n_steps or n_steps < 0:
        raise ValueError(f"n_steps: must be a non-negative integer, got {n_steps}")
    tm, prm, rl, fd = _setup(model, q, params, rest_length, force_density)
    if qd.shape != q.shape or qd.device != q.device or qd.dtype != q.dtype:
        raise ValueError(f"qd: expected shape {tuple(q.shape)}, dtype {q.dtype} on {q.device}, got "
                         f"{tuple(qd.shape)}, {qd.dtype} on {qd.device}")
    ext = _check_external(tm, external, q.shape[0])
    one = step_once if substep is None else substep
    for _ in range(int(n_steps)):
        q, qd = one(tm, q, qd, dt, name, prm, rl, fd, ext, project)
    return q, qd


# ---------------------------------------------------------------------- ground contact


def step_state(model, state, dt, integrator="semi_implicit_euler", *, rest_length=None, force_density=None,
               external=None, project=True, n_steps=1, device=None, dtype=None, params=None):
    """:func:`tensegrity_gym.physics.step` contract on a NumPy :class:`~tensegrity_gym.core.model.State`: the state is
    copied to ``device`` / ``dtype`` (default CPU, float64), stepped by :func:`step`, and copied
    back as float64 NumPy arrays. ``external`` must be an array (a callable is not supported)."""
    torch = _torch()
    if callable(external):
        raise ValueError("external: a callable is not supported by backend='torch'; pass a (B, n, 3) array")
    dev, dty = resolve_device(device), resolve_dtype(dtype)
    q = torch.as_tensor(np.array(state.q, dtype=float), device=dev).to(dty)
    qd = torch.as_tensor(np.array(state.qd, dtype=float), device=dev).to(dty)
    with torch.no_grad():
        q, qd = step(model, q, qd, dt, integrator, n_steps, rest_length, force_density, params, project, external)
    t = state.t
    for _ in range(int(n_steps)):
        t = t + dt
    return State(q=q.to(torch.float64).cpu().numpy(), qd=qd.to(torch.float64).cpu().numpy(), t=t)


def simulate(model, state, dt, n_steps, integrator="rk4", *, record_every=1, rest_length=None,
             force_density=None, project=True, device=None, dtype=None, params=None):
    """:func:`tensegrity_gym.physics.simulate` on the torch backend: ``(t (S,), q, qd (S, B, k, 6))`` as NumPy
    float64, the state kept on the device between records. Raises
    :class:`~tensegrity_gym.core.errors.SimulationDiverged` when the state stops being finite."""
    torch = _torch()
    if int(n_steps) != n_steps or n_steps < 0:
        raise ValueError(f"n_steps: must be a non-negative integer, got {n_steps}")
    if int(record_every) != record_every or record_every < 1:
        raise ValueError(f"record_every: must be a positive integer, got {record_every}")
    dev, dty = resolve_device(device), resolve_dtype(dtype)
    n_rec = n_steps // record_every
    ts = state.t + dt * record_every * np.arange(n_rec + 1)
    q = torch.as_tensor(np.array(state.q, dtype=float), device=dev).to(dty)
    qd = torch.as_tensor(np.array(state.qd, dtype=float), device=dev).to(dty)
    qs = np.empty((n_rec + 1,) + tuple(state.q.shape))
    qds = np.empty_like(qs)
    qs[0], qds[0] = state.q, state.qd
    with torch.no_grad():
        for i in range(1, n_rec + 1):
            q, qd = step(model, q, qd, dt, integrator, record_every, rest_length, force_density, params, project)
            qs[i], qds[i] = q.to(torch.float64).cpu().numpy(), qd.to(torch.float64).cpu().numpy()
            if not (np.all(np.isfinite(qs[i])) and np.all(np.isfinite(qds[i]))):
                raise SimulationDiverged(f"{integrator}: state became non-finite between t = {ts[i - 1]:.6g} s and "
                                         f"t = {ts[i]:.6g} s (dt = {dt:g} s, torch backend)")
    return ts, qs, qds
