"""The renderer choice: :func:`make_renderer` (MuJoCo if it works, else matplotlib)."""
from __future__ import annotations

import warnings

from . import mujoco_renderer
from .matplotlib_renderer import Renderer
from .mujoco_renderer import MujocoRenderer
from .scene import RendererUnavailable


def make_renderer(width: int = 480, height: int = 480, *, backend: str | None = None, **kw):
    """A renderer: ``backend`` "mujoco" (:class:`MujocoRenderer`, raises
    :class:`RendererUnavailable` if it cannot run), "matplotlib" (:class:`Renderer`) or "auto"
    (MuJoCo if it works, else matplotlib with one warning). Default: the environment variable
    ``TENSEGRITY_RENDERER`` or "auto". Other keywords go to the renderer (``elev``, ``azim``,
    ``limits``, ``title``)."""
    import os
    backend = (backend or os.environ.get("TENSEGRITY_RENDERER") or "auto").strip().lower()
    if backend not in ("auto", "mujoco", "matplotlib"):
        raise ValueError(f"backend: one of 'auto', 'mujoco', 'matplotlib', got {backend!r}")
    if backend == "matplotlib":
        return Renderer(width, height, **kw)
    if backend == "mujoco":
        return MujocoRenderer(width, height, **kw)
    try:
        return MujocoRenderer(width, height, **kw)
    except RendererUnavailable as exc:
        if not mujoco_renderer._GL_CACHE.get("warned"):
            warnings.warn(f"{exc}. Falling back to the matplotlib renderer (slower).", stacklevel=2)
            mujoco_renderer._GL_CACHE["warned"] = True
        return Renderer(width, height, **kw)
