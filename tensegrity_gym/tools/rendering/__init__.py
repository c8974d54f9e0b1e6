"""Headless rendering of tensegrity structures: MuJoCo's OpenGL renderer, matplotlib fallback.

Structure-agnostic: both renderers draw whatever node positions, rods and strings they are
given, through the same ``render(nodes, rods, strings, tensions, ...)`` call. Used by every
env's ``render()`` (through :func:`make_renderer`); usable on its own::

    from tensegrity_gym.tools.rendering import make_renderer   # = tensegrity_gym.tools.rendering
    r = make_renderer(width=480, height=480, title="prism")   # MuJoCo if it works, else matplotlib
    frame = r.render(nodes, rods, strings, tensions=T, targets=target_nodes)  # (480, 480, 3) uint8

Backends
--------
* :class:`MujocoRenderer` (``backend="mujoco"``): a real 3-D renderer (MuJoCo's offscreen
  OpenGL renderer: shaded capsules for rods, strings as thin capsules coloured by tension, a
  checkered ground, lighting and shadows, title, caption and a colour-bar legend drawn by
  MuJoCo's own text overlay); much faster than matplotlib (frame rates: ``scripts/bench/bench_render.py``).
  Needs ``mujoco`` (``pip install tensegrity_gym[mujoco]``) and an
  OpenGL backend; without a display it uses EGL (Debian: ``libegl1 libegl-mesa0``, Mesa's
  software rasteriser is enough) or OSMesa (``libosmesa6``). The backend comes from
  ``MUJOCO_GL`` when set (``egl``, ``osmesa``, ``glfw``), else the first of egl, osmesa,
  glfw (only with a ``DISPLAY``) that creates a context; :class:`RendererUnavailable` says
  what was tried and which package to install.
* :class:`Renderer` (``backend="matplotlib"``): the matplotlib 3-D renderer (Agg canvas);
  always available.

``make_renderer(backend="auto")`` (the env default; ``TENSEGRITY_RENDERER=matplotlib`` or
``mujoco`` in the environment forces one) takes MuJoCo when it works and otherwise falls back
to matplotlib with one warning.

Drawing conventions
-------------------
* rods: thick dark lines; nodes: small dots;
* strings: thin lines coloured by tension (N) on a blue -> red ("turbo") scale from 0 to
  ``tension_max`` (default: the largest tension in the frame); slack strings (tension 0 or
  ``slack`` flag) drawn grey and dashed;
* ``targets`` (t, 3): hollow green circles (e.g. a shape target);
* ``ground_z``: a grey plane at that height; ``path`` (p, 3): a line (e.g. the
  trajectory of the centre of mass); ``goal`` (3,): a green star.

All coordinates in m, tensions in N. The axes keep equal scale; ``limits`` fixes them
((3, 2) array of [min, max] per axis), otherwise they follow the first rendered frame's
nodes and targets with a margin (so a moving structure moves in a fixed frame) and
grow if the structure leaves them.

Modules: :mod:`.scene` (shared pieces), :mod:`.matplotlib_renderer`, :mod:`.mujoco_renderer`,
:mod:`.factory` (:func:`make_renderer`), :mod:`.video`, :mod:`.browser_viewer`,
:mod:`.window_viewer`, :mod:`.view` (:func:`view_trajectory`).
"""
from .browser_viewer import BrowserViewer
from .factory import make_renderer
from .matplotlib_renderer import Renderer, render_frame
from .mujoco_renderer import MujocoRenderer, gl_backend
from .scene import RendererUnavailable
from .video import render_video, write_video
from .view import view_trajectory
from .window_viewer import WindowViewer

__all__ = ["Renderer", "MujocoRenderer", "RendererUnavailable", "make_renderer", "render_frame", "write_video",
           "render_video", "view_trajectory", "BrowserViewer", "WindowViewer", "gl_backend"]
