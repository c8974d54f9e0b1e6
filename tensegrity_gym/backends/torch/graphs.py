"""CUDA graphs of the physics: a pure function of tensors captured once per input layout and
replayed, so that a control step's hundreds of kernel launches (``frame_skip`` compiled physics
sub-steps of about 25 kernels each) cost one graph launch and a few copies.

:class:`CapturedCall` wraps any such function (:func:`~tensegrity_gym.backends.torch.contact.contact_step`,
:func:`~tensegrity_gym.backends.torch.terrain.terrain_step`, :func:`~tensegrity_gym.backends.torch.driver.step`);
the device envs use it with ``cuda_graph=True``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from .model import _torch

__all__ = ["CapturedCall", "cuda_capture", "SYNC_OPS"]

#: aten operations that read device values on the host (or size outputs by them): each waits for
#: the device, and a CUDA graph capture refuses them
SYNC_OPS = frozenset({"aten::_local_scalar_dense", "aten::item", "aten::nonzero", "aten::nonzero_static",
                      "aten::masked_select", "aten::unique", "aten::_unique", "aten::_unique2",
                      "aten::unique_consecutive", "aten::repeat_interleave", "aten::is_nonzero",
                      "aten::equal", "aten::allclose", "aten::masked_scatter"})


def cuda_capture(fn: Callable, args: tuple, kwargs: dict, warmup: int):
    """Capture ``fn(*args, **kwargs)`` as a CUDA graph on the current device: ``warmup`` runs on
    a side stream first (compiles, lazy initialisation, allocator warm-up), then one under
    capture. Returns ``(replay, outputs)``: ``replay()`` runs the recorded kernels again on the
    same input and output buffers (nothing runs until the first replay)."""
    torch = _torch()
    side = torch.cuda.Stream()
    side.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(side):
        for _ in range(warmup):
            fn(*args, **kwargs)
    torch.cuda.current_stream().wait_stream(side)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        out = fn(*args, **kwargs)
    return graph.replay, out


@dataclass
class _Entry:
    leaves: list           # the layout's non-tensor leaves (kept alive: keys by identity)
    static: list           # the input buffers, in leaf order
    replay: Callable[[], Any]
    outputs: Any


class CapturedCall:
    """``fn(*args, **kwargs)`` replayed from a CUDA graph.

    Each distinct layout of the arguments is captured once (:func:`cuda_capture`): the nesting
    of tuples, lists and dicts, every tensor's shape, dtype and device, and every other value
    (by equality when hashable, else by identity: the same object with changed contents is not
    noticed). A call copies its tensors into the layout's input buffers, replays its graph and
    returns clones of the outputs (a tensor, or tuples/lists of tensors), so a result stays
    valid after later calls. ``fn`` must be pure (its outputs depend on its inputs only; it
    writes nothing else) and must not read device values on the host (``.item()``,
    ``bool(tensor)``, outputs sized by data: :data:`SYNC_OPS`); a capture that fails raises a
    RuntimeError naming the function and the cause.
    The capture runs without autograd (no gradients flow through a replay) and outside
    inference mode, so calls under ``torch.inference_mode()`` and ``torch.no_grad()`` share it.

    ``capture``: the capturing function (default :func:`cuda_capture`; tests pass one that
    re-runs ``fn`` on the buffers). ``warmup``: runs before each capture (default 2).
    """

    def __init__(self, fn: Callable, capture: Callable | None = None, warmup: int = 2):
        if not callable(fn):
            raise TypeError(f"fn: expected a callable, got {type(fn).__name__}")
        self.fn = fn
        self.warmup = int(warmup)
        self._capture = cuda_capture if capture is None else capture
        self._entries: dict = {}

    @property
    def captures(self) -> int:
        """How many layouts have been captured (one graph each)."""
        return len(self._entries)

    def __call__(self, *args, **kwargs):
        torch = _torch()
        tensors, leaves, key = [], [], []
        layout = _flatten((args, kwargs), tensors, leaves, key, torch)
        key = tuple(key)
        entry = self._entries.get(key)
        if entry is None:
            # plain tensors (not inference tensors) that a later call under any grad mode may write
            with torch.inference_mode(False), torch.no_grad():
                static = [t.detach().clone() for t in tensors]
                s_args, s_kwargs = _build(layout, iter(static))
                try:
                    replay, outputs = self._capture(self.fn, s_args, s_kwargs, self.warmup)
                except RuntimeError as e:     # e.g. a host read or a host-to-device copy under capture
                    name = getattr(self.fn, "__qualname__", repr(self.fn))
                    raise RuntimeError(f"cuda_graph: capturing {name} failed ({type(e).__name__}: {e}); the "
                                       "function must be pure and read nothing back from the device; run "
                                       "without the graph (cuda_graph=False)") from e
            entry = self._entries[key] = _Entry(leaves, static, replay, outputs)
        else:
            for s, t in zip(entry.static, tensors):
                s.copy_(t)
        entry.replay()
        return _clone(entry.outputs, torch)


def _flatten(x, tensors: list, leaves: list, key: list, torch):
    """The layout of ``x`` (its containers, with ``_TENSOR`` where a tensor goes and ``_Leaf``
    around any other value); the tensors are appended to ``tensors``, the other values to
    ``leaves`` and the layout's hashable description to ``key``."""
    if isinstance(x, torch.Tensor):
        tensors.append(x)
        key.append(("T", tuple(x.shape), x.dtype, x.device))
        return _TENSOR
    if isinstance(x, dict):
        key.append(("D", tuple(x)))
        return {k: _flatten(v, tensors, leaves, key, torch) for k, v in x.items()}
    if type(x) in (tuple, list) or (isinstance(x, tuple) and hasattr(x, "_fields")):
        key.append((type(x), len(x)))
        return _like(x, [_flatten(v, tensors, leaves, key, torch) for v in x])
    leaves.append(x)
    try:
        hash(x)
        key.append(("V", type(x), x))
    except TypeError:
        key.append(("I", id(x)))
    return _Leaf(x)


class _Leaf:
    __slots__ = ("value",)

    def __init__(self, value):
        self.value = value


_TENSOR = object()


def _build(layout, static):
    """``layout`` with its tensors taken in order from the iterator ``static``."""
    if layout is _TENSOR:
        return next(static)
    if isinstance(layout, _Leaf):
        return layout.value
    if isinstance(layout, dict):
        return {k: _build(v, static) for k, v in layout.items()}
    return _like(layout, [_build(v, static) for v in layout])


def _clone(out, torch):
    if isinstance(out, torch.Tensor):
        return out.clone()
    if isinstance(out, (tuple, list)):
        return _like(out, [_clone(v, torch) for v in out])
    return out


def _like(x, items: list):
    """``items`` in a container of ``x``'s kind: a list, the same named tuple, or a tuple."""
    if isinstance(x, list):
        return items
    return type(x)(*items) if hasattr(x, "_fields") else tuple(items)
