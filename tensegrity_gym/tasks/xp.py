"""The array operations a task uses, one namespace for NumPy arrays and one for torch tensors.

A task (observation, reward terms, sensors, reset draws) is written once as functions of an
array namespace ``xp`` taken from its inputs (:func:`namespace`), so that the same code runs on
NumPy for the CPU envs and on torch for the device envs. The two namespaces have the same
names; each maps to its library's own operation, chosen so that the NumPy results are the ones
NumPy code written directly gives (the NumPy envs' numbers do not depend on this layer):

=================================  ===================================  ======================================
name                               NumPy                                torch
=================================  ===================================  ======================================
``concat(parts, axis)``            ``np.concatenate``                   ``torch.cat``
``stack(parts, axis)``             ``np.stack``                         ``torch.stack``
``where(c, a, b)``                 ``np.where``                         ``torch.where`` (scalars as tensors)
``einsum(spec, *ops)``             ``np.einsum``                        ``torch.einsum``
``norm(x, keepdims)``              ``np.linalg.norm(axis=-1)``          ``torch.linalg.vector_norm(dim=-1)``
``cross(a, b)``                    ``np.cross`` (last axis)             ``torch.linalg.cross(dim=-1)``
``exp``, ``sqrt``, ``cos``,        ``np.exp`` ...                       ``torch.exp`` ...
``sin``
``sum_squares(x)``                 :func:`tensegrity_gym.rewards        ``(x * x).sum(-1)``
                                   .sum_squares`
``mean_max(d)``                    ``add.reduce / n``, ``max``          ``sum / n``, ``amax``
``any(x, axis)``                   ``x.any(axis=axis)``                 ``x.any(dim=axis)``
``to_float(x, like)``              ``x.astype(like.dtype)``             ``x.to(like.dtype)``
``const(values, like)``            a float array of ``like``'s dtype    a tensor on ``like``'s device and dtype
``zeros_like``                     ``np.zeros_like``                    ``torch.zeros_like``
``hypot``, ``isfinite``, ``rint``  ``np.hypot`` ...                     ``torch.hypot`` ..., ``torch.round``
                                                                        (both round half to even)
``minimum(a, b)``                  ``np.minimum``                       ``torch.minimum`` (scalars as tensors)
``clip(x, lo, hi)``                ``np.minimum(np.maximum(x, lo),      ``x.clamp(lo, hi)`` (scalar bounds)
                                   hi)`` (``np.clip``'s values)
``argmin(x, axis)``                ``x.argmin(axis=axis)``              ``x.argmin(dim=axis)`` (both: the first)
``arange(n, like)``                ``np.arange(n)``                     ``torch.arange(n)`` on ``like``'s device
``to_index(x)``                    ``x.astype(int)``                    ``x.long()``
``cumsum(x, axis)``                ``np.cumsum``                        ``torch.cumsum``
``amin``, ``amax(x, axis)``        ``x.min``, ``x.max``                 ``x.amin``, ``x.amax`` (axis: int or tuple)
``maximum(a, b)``                  ``np.maximum``                       ``torch.maximum`` (scalars as tensors)
``multiply(a, b, out)``            ``np.multiply(a, b, out=out)``       ``torch.mul(a, b, out=out)``
``copy(x)``                        ``x.copy()``                         ``x.clone()``
``float32(x)``                     ``x.astype(np.float32)``             ``x.to(torch.float32)``
``arctan2(y, x)``                  ``np.arctan2``                       ``torch.atan2``
``repeat_rows(v, r)``              ``np.tile(v, (r, 1))``               ``v.expand(r, -1)`` (a view)
``zeros(shape, like)``             ``np.zeros(shape, like.dtype)``      ``torch.zeros`` on ``like``'s device
=================================  ===================================  ======================================

Reductions and products run along the last axis unless an ``axis`` is named. torch is imported
only when a torch tensor is met (it is an optional dependency of the NumPy envs).
"""
from __future__ import annotations

import numpy as np

from ..rewards import sum_squares as _np_sum_squares

__all__ = ["NUMPY", "namespace", "torch_namespace"]


class _NumPyOps:
    """The namespace of NumPy arrays (see the module doc)."""

    name = "numpy"
    where = staticmethod(np.where)
    einsum = staticmethod(np.einsum)
    exp = staticmethod(np.exp)
    sqrt = staticmethod(np.sqrt)
    cos = staticmethod(np.cos)
    sin = staticmethod(np.sin)
    zeros_like = staticmethod(np.zeros_like)
    sum_squares = staticmethod(_np_sum_squares)

    @staticmethod
    def concat(parts, axis: int = 0):
        return np.concatenate(parts, axis=axis)

    @staticmethod
    def stack(parts, axis: int = 0):
        return np.stack(parts, axis=axis)

    @staticmethod
    def norm(x, keepdims: bool = False):
        return np.linalg.norm(x, axis=-1, keepdims=keepdims)

    @staticmethod
    def cross(a, b):
        return np.cross(a, b)

    @staticmethod
    def mean_max(d):
        """(mean, max) over the last axis (``add.reduce / n``: bit-identical to ``mean``)."""
        return np.add.reduce(d, axis=-1) / d.shape[-1], np.maximum.reduce(d, axis=-1)

    @staticmethod
    def any(x, axis: int):
        return x.any(axis=axis)

    @staticmethod
    def to_float(x, like):
        return x.astype(like.dtype)

    @staticmethod
    def const(values, like):
        return np.asarray(values, dtype=like.dtype)

    hypot = staticmethod(np.hypot)
    isfinite = staticmethod(np.isfinite)
    rint = staticmethod(np.rint)
    minimum = staticmethod(np.minimum)

    @staticmethod
    def clip(x, lo, hi):
        return np.minimum(np.maximum(x, lo), hi)

    @staticmethod
    def argmin(x, axis: int):
        return x.argmin(axis=axis)

    @staticmethod
    def arange(n: int, like):
        return np.arange(n)

    @staticmethod
    def to_index(x):
        return x.astype(int)

    @staticmethod
    def cumsum(x, axis: int):
        return np.cumsum(x, axis=axis)

    @staticmethod
    def amin(x, axis):
        return x.min(axis=axis)

    @staticmethod
    def amax(x, axis):
        return x.max(axis=axis)

    maximum = staticmethod(np.maximum)

    @staticmethod
    def multiply(a, b, out):
        return np.multiply(a, b, out=out)

    @staticmethod
    def copy(x):
        return x.copy()

    @staticmethod
    def float32(x):
        return x.astype(np.float32)

    arctan2 = staticmethod(np.arctan2)

    @staticmethod
    def repeat_rows(v, r: int):
        return np.tile(v, (r, 1))

    @staticmethod
    def zeros(shape, like):
        return np.zeros(shape, like.dtype)


class _TorchOps:
    """The namespace of torch tensors (see the module doc)."""

    name = "torch"

    def __init__(self, torch):
        self.torch = torch
        self.einsum = torch.einsum
        self.exp, self.sqrt, self.cos, self.sin = torch.exp, torch.sqrt, torch.cos, torch.sin
        self.zeros_like = torch.zeros_like

    def concat(self, parts, axis: int = 0):
        return self.torch.cat(parts, dim=axis)

    def stack(self, parts, axis: int = 0):
        return self.torch.stack(parts, dim=axis)

    def where(self, c, a, b):
        t = self.torch
        like = a if isinstance(a, t.Tensor) else b
        if not isinstance(a, t.Tensor):
            a = t.as_tensor(a, dtype=like.dtype, device=like.device)
        if not isinstance(b, t.Tensor):
            b = t.as_tensor(b, dtype=like.dtype, device=like.device)
        return t.where(c, a, b)

    def norm(self, x, keepdims: bool = False):
        return self.torch.linalg.vector_norm(x, dim=-1, keepdim=keepdims)

    def cross(self, a, b):
        return self.torch.linalg.cross(a, b, dim=-1)

    @staticmethod
    def sum_squares(x):
        return (x * x).sum(dim=-1)

    @staticmethod
    def mean_max(d):
        return d.sum(dim=-1) / d.shape[-1], d.amax(dim=-1)

    @staticmethod
    def any(x, axis: int):
        return x.any(dim=axis)

    @staticmethod
    def to_float(x, like):
        return x.to(like.dtype)

    def const(self, values, like):
        a = np.asarray(values, dtype=float)
        if not a.flags.writeable:       # a cached read-only array: torch would share it
            a = a.copy()
        return self.torch.as_tensor(a, dtype=like.dtype, device=like.device)

    def hypot(self, a, b):
        return self.torch.hypot(a, b)

    def isfinite(self, x):
        return self.torch.isfinite(x)

    def rint(self, x):
        return self.torch.round(x)

    def minimum(self, a, b):
        t = self.torch
        if not isinstance(b, t.Tensor):
            b = t.as_tensor(b, dtype=a.dtype, device=a.device)
        return t.minimum(a, b)

    @staticmethod
    def clip(x, lo, hi):
        return x.clamp(lo, hi)

    @staticmethod
    def argmin(x, axis: int):
        return x.argmin(dim=axis)

    def arange(self, n: int, like):
        return self.torch.arange(n, device=like.device)

    @staticmethod
    def to_index(x):
        return x.long()

    def cumsum(self, x, axis: int):
        return self.torch.cumsum(x, dim=axis)

    @staticmethod
    def amin(x, axis):
        return x.amin(dim=axis)

    @staticmethod
    def amax(x, axis):
        return x.amax(dim=axis)

    def maximum(self, a, b):
        t = self.torch
        if not isinstance(b, t.Tensor):
            b = t.as_tensor(b, dtype=a.dtype, device=a.device)
        return t.maximum(a, b)

    def multiply(self, a, b, out):
        return self.torch.mul(a, b, out=out)

    @staticmethod
    def copy(x):
        return x.clone()

    def float32(self, x):
        return x.to(self.torch.float32)

    def arctan2(self, y, x):
        return self.torch.atan2(y, x)

    @staticmethod
    def repeat_rows(v, r: int):
        return v.reshape(1, -1).expand(r, -1)

    def zeros(self, shape, like):
        return self.torch.zeros(shape, dtype=like.dtype, device=like.device)


NUMPY = _NumPyOps()
_TORCH: list = []


def torch_namespace() -> _TorchOps:
    """The torch namespace (imports torch on first use)."""
    if not _TORCH:
        import torch   # optional dependency, reached only with torch tensors
        _TORCH.append(_TorchOps(torch))
    return _TORCH[0]


def namespace(x):
    """The namespace of ``x``: :data:`NUMPY` for a NumPy array or number, the torch one for a
    torch tensor."""
    if isinstance(x, (np.ndarray, np.generic, float, int)):
        return NUMPY
    return torch_namespace()
