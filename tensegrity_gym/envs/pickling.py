"""Pickling an env: renderers (a window, a GL context) are left out and made again at the next
``render()``; modules an env holds are pickled by name."""
from __future__ import annotations

import importlib
import types

__all__ = ["picklable_state", "restore_state"]


class _ModuleRef:
    """A module held by an env, pickled by name (modules do not pickle)."""

    def __init__(self, name: str):
        self.name = name


def picklable_state(state: dict) -> dict:
    """An env's ``__dict__`` for pickling: renderers (a window, a GL context: not picklable, and
    made again at the next ``render()``) left out, modules held by name."""
    out = dict(state)
    for k, v in state.items():
        if k == "_renderer":
            out[k] = None
        elif k == "_renderers":
            out[k] = {}
        elif isinstance(v, types.ModuleType):
            out[k] = _ModuleRef(v.__name__)
    return out


def restore_state(obj, state: dict) -> None:
    """Inverse of :func:`picklable_state`: ``obj.__dict__`` from ``state``, modules imported again."""
    obj.__dict__.update({k: importlib.import_module(v.name) if isinstance(v, _ModuleRef) else v
                         for k, v in state.items()})
