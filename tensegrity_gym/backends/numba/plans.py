"""Plans of the numba backend: the packed buffer, flags, step and step count of a fixed-step call,
built once so that a caller repeats the call without the entry points' checks.

SI units: ``dt`` in s. :class:`Plan` is what a compiled caller (an env's fused njit step,
:func:`.entries.run_plan`) needs to run the serial step kernel from its own njit code;
:func:`lean_plan` is the compiled call that :func:`.api.step_inplace` makes for a call with no
control arrays, which :func:`tensegrity_gym.physics.step_inplace` keeps per model and repeats;
:func:`packed` exposes the cached packed buffers. This module keeps no cache of its own:
every buffer comes from :mod:`.pack`'s per-model cache.
"""
from __future__ import annotations

import numpy as np

from .compile import _READY, _compile, _parallel
from .entries import _run_lean
from .layout import _FD, _L0DEF, _SOA_MIN_BATCH
from .pack import _CACHE, _flags, _pack, _pack_params

__all__ = ["Plan", "make_plan", "lean_plan", "packed"]


class Plan:
    """What a compiled caller needs to run the serial step kernel from its own
    njit code (:func:`.entries.run_plan`): ``buf`` (the packed model), ``flags`` (integrator, projection,
    control mode), ``dt`` (s), ``n_steps`` and ``simd`` (the batch is run by
    :func:`.entries.run_plan_simd`, in SIMD blocks, instead of :func:`.entries.run_plan`, one copy
    at a time). Opaque: build it with :func:`make_plan`."""
    __slots__ = ("model", "buf", "flags", "dt", "n_steps", "simd")

    def buffer(self, params=None) -> np.ndarray | None:
        """The packed buffer for ``params`` (one shared row) or the model's own (None); None
        when ``params`` has one row per copy (the per-copy kernels do not fuse)."""
        if params is None:
            return self.buf
        if params.batch_size != 1:
            return None
        return _pack_params(self.model, params).buf


def make_plan(model, name: str, dt: float, n_steps: int, batch_size: int, control: str = "rest_length"):
    """A :class:`Plan` for ``n_steps`` projected steps of the fixed-step method ``name`` (a
    resolved name) on ``batch_size`` copies whose control is ``control`` per string
    (``"rest_length"``, m, or ``"force_density"``, N/m, with the model's rest lengths), or None
    when the batch is large enough for the parallel kernel (then :func:`step` runs it)."""
    p = _CACHE.get(id(model)) or _pack(model)
    flags = _flags(p, name, True)
    if batch_size >= 8 and _parallel(p, batch_size, n_steps, flags):
        return None
    if control == "force_density":
        flags |= _L0DEF | _FD
    elif control != "rest_length":
        raise ValueError(f"control: unknown {control!r}; choose 'rest_length' or 'force_density'")
    plan = Plan()
    plan.model, plan.buf, plan.flags, plan.dt, plan.n_steps = model, p.buf, int(flags), float(dt), int(n_steps)
    plan.simd = batch_size >= _SOA_MIN_BATCH     # run by run_plan_simd (SIMD blocks), else run_plan
    return plan


def lean_plan(model, name: str, project: bool = True):
    """``(kernel, buf, flags)``: the compiled call that :func:`step_inplace` makes for ``model``
    stepped by the fixed-step method ``name`` (a resolved name) with no control arrays and no
    per-copy parameters on fewer than 8 copies: ``kernel(q, qd, q, qd, buf, dt, n_steps, flags)``
    steps ``q``, ``qd`` (B, k, 6) in place and returns the error code (0: done; the arrays are
    untouched otherwise). It raises TypeError for arrays it does not take as they are (another
    dtype, layout or a read-only array): :func:`step_inplace` converts or refuses those."""
    p = _CACHE.get(id(model)) or _pack(model)
    if not _READY["lean"]:
        _compile("lean")
    return _run_lean, p.buf, _flags(p, name, project)


def packed(model, params=None):
    """The packed buffer(s) of ``model`` (or of ``params``, a :class:`~tensegrity_gym.core.params.Params`
    of it), cached for their lifetime: an object with ``buf`` (len,) shared by every copy, or
    ``bufs`` (B, len) one per copy. What a step reuses from call to call."""
    return (_CACHE.get(id(model)) or _pack(model)) if params is None else _pack_params(model, params)
