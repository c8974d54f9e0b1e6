"""Headless rendering of tensegrity structures: MuJoCo's OpenGL renderer, matplotlib fallback.

Structure-agnostic: both renderers draw whatever node positions, rods and strings they are
given, through the same ``render(nodes, rods, strings, tensions, ...)`` call. Used by every
env's ``render()`` (through :func:`make_renderer`); usable on its own::

    from tensegrity_gym.rendering import make_renderer
    r = make_renderer(width=480, height=480, title="prism")   # MuJoCo if it works, else matplotlib
    frame = r.render(nodes, rods, strings, tensions=T, targets=target_nodes)  # (480, 480, 3) uint8

Backends
--------
* :class:`MujocoRenderer` (``backend="mujoco"``): a real 3-D renderer (MuJoCo's offscreen
  OpenGL renderer: shaded capsules for rods, strings as thin capsules coloured by tension, a
  checkered ground, lighting and shadows, title, caption and a colour-bar legend drawn by
  MuJoCo's own text overlay). Several hundred frames/s at 480 x 480 on a CPU
  (``scripts/bench_render.py``). Needs ``mujoco`` (``pip install tensegrity_gym[mujoco]``) and an
  OpenGL backend; without a display it uses EGL (Debian: ``libegl1 libegl-mesa0``, Mesa's
  software rasteriser is enough) or OSMesa (``libosmesa6``). The backend comes from
  ``MUJOCO_GL`` when set (``egl``, ``osmesa``, ``glfw``), else the first of egl, osmesa,
  glfw (only with a ``DISPLAY``) that creates a context; :class:`RendererUnavailable` says
  what was tried and which package to install.
* :class:`Renderer` (``backend="matplotlib"``): the original matplotlib 3-D renderer (Agg
  canvas), about 10-40 frames/s; always available.

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
"""
from __future__ import annotations

import warnings

import numpy as np

from .hardening_checks import close_after_error

__all__ = ["Renderer", "MujocoRenderer", "RendererUnavailable", "make_renderer", "render_frame", "write_video",
           "view_trajectory", "BrowserViewer", "WindowViewer",
           "gl_backend"]



def _scene_arrays(nodes, rods, strings, targets, goal):
    """Checked arrays of one frame, shared by the renderers: nodes (n, 3) m (non-finite rows
    drawn at the origin), rods and strings (., 2) node pairs,
    targets (t, 3) m or None, and ``pts``: the points the view must hold."""
    nodes = np.asarray(nodes, float)
    if nodes.ndim != 2 or nodes.shape[1] != 3:
        raise ValueError(f"nodes: expected an (n, 3) array, got shape {nodes.shape}")
    rods = np.asarray(rods, int).reshape(-1, 2)
    strings = np.asarray(strings, int).reshape(-1, 2)
    ok = np.all(np.isfinite(nodes), axis=1)
    nodes = np.where(ok[:, None], nodes, 0.0)
    pts = [nodes]
    if targets is not None:
        targets = np.asarray(targets, float).reshape(-1, 3)
        pts.append(targets)
    if goal is not None:
        pts.append(np.asarray(goal, float).reshape(1, 3))
    return nodes, rods, strings, targets, pts

class Renderer:
    """Reusable matplotlib renderer (one figure kept between frames: about 20-40 ms a frame).

    Parameters
    ----------
    width, height : frame size in pixels.
    elev, azim : camera elevation and azimuth in degrees.
    limits : optional (3, 2) axis limits in m.
    title : optional text drawn on top (e.g. the env name); ``render`` may add a per-frame caption.
    """

    def __init__(self, width: int = 480, height: int = 480, elev: float = 20.0, azim: float = -60.0,
                 limits=None, title: str | None = None):
        if int(width) < 16 or int(height) < 16:
            raise ValueError(f"width, height: must be at least 16 pixels, got {width} x {height}")
        from matplotlib.figure import Figure
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        self.width, self.height = int(width), int(height)
        dpi = 100
        self.fig = Figure(figsize=(self.width / dpi, self.height / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_axes([0, 0, 1, 1], projection="3d")
        self.elev, self.azim = elev, azim
        self.limits = None if limits is None else np.asarray(limits, float).reshape(3, 2)
        self._auto_limits = self.limits is None
        self.title = title
        self._human_fig = None

    # ------------------------------------------------------------------ frames
    def _update_limits(self, pts: np.ndarray) -> None:
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if self.limits is None:
            c = 0.5 * (lo + hi)
            half = 0.5 * float(np.max(hi - lo)) * 1.25 + 0.05
            self.limits = np.stack([c - half, c + half], axis=1)
        elif self._auto_limits and (np.any(lo < self.limits[:, 0]) or np.any(hi > self.limits[:, 1])):
            c = 0.5 * (lo + hi)
            half = max(0.5 * float(np.max(hi - lo)) * 1.25 + 0.05,
                       0.5 * float(np.max(self.limits[:, 1] - self.limits[:, 0])))
            self.limits = np.stack([c - half, c + half], axis=1)

    def render(self, nodes, rods, strings, tensions=None, *, slack=None, targets=None, ground_z=None,
               path=None, goal=None, tension_max=None, caption: str | None = None) -> np.ndarray:
        """Draw one frame and return it as an (height, width, 3) uint8 array.

        nodes (n, 3) m; rods (k, 2) and strings (m, 2) node-index pairs; tensions (m,) N or None;
        slack (m,) bool or None (default: tension <= 0); targets (t, 3) m; ground_z m;
        path (p, 3) m; goal (3,) m; tension_max N (colour-scale top); caption: text.
        """
        import matplotlib
        nodes, rods, strings, targets, pts = _scene_arrays(nodes, rods, strings, targets, goal)
        self._update_limits(np.concatenate(pts))
        ax = self.ax
        ax.cla()
        ax.set_xlim(*self.limits[0])
        ax.set_ylim(*self.limits[1])
        ax.set_zlim(*self.limits[2])
        try:
            ax.set_box_aspect((1, 1, 1))
        except Exception:  # pragma: no cover - very old matplotlib
            pass
        ax.view_init(elev=self.elev, azim=self.azim)
        ax.set_xlabel("x (m)", fontsize=7)
        ax.set_ylabel("y (m)", fontsize=7)
        ax.set_zlabel("z (m)", fontsize=7)
        ax.tick_params(labelsize=6)
        if ground_z is not None:
            (x0, x1), (y0, y1) = self.limits[0], self.limits[1]
            X, Y = np.meshgrid([x0, x1], [y0, y1])
            ax.plot_surface(X, Y, np.full_like(X, float(ground_z)), color="0.85", alpha=0.5, zorder=0)
        m = len(strings)
        if m:
            T = np.zeros(m) if tensions is None else np.nan_to_num(np.asarray(tensions, float).reshape(m))
            sl = (T <= 0) if slack is None else np.asarray(slack, bool).reshape(m)
            tmax = float(tension_max) if tension_max is not None else max(float(T.max(initial=0.0)), 1e-9)
            cmap = matplotlib.colormaps["turbo"]
            for i, (a, b) in enumerate(strings):
                seg = nodes[[a, b]]
                if sl[i]:
                    ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color="0.6", lw=0.8, ls="--")
                else:
                    ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color=cmap(0.1 + 0.8 * min(T[i] / tmax, 1.0)), lw=1.4)
        for a, b in rods:
            seg = nodes[[a, b]]
            ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color="0.15", lw=4.0, solid_capstyle="round")
        ax.scatter(nodes[:, 0], nodes[:, 1], nodes[:, 2], color="k", s=8, depthshade=False)
        if targets is not None and len(targets):
            ax.scatter(targets[:, 0], targets[:, 1], targets[:, 2], facecolors="none", edgecolors="tab:green",
                       s=60, linewidths=1.5, depthshade=False)
        if path is not None:
            path = np.asarray(path, float).reshape(-1, 3)
            if len(path) > 1:
                ax.plot(path[:, 0], path[:, 1], path[:, 2], color="tab:orange", lw=1.0)
        if goal is not None:
            g = np.asarray(goal, float).reshape(3)
            ax.scatter([g[0]], [g[1]], [g[2]], marker="*", color="tab:green", s=120, depthshade=False)
        text = " | ".join(t for t in (self.title, caption) if t)
        if text:
            ax.text2D(0.02, 0.97, text, transform=ax.transAxes, fontsize=8, va="top")
        self.canvas.draw()
        buf = np.asarray(self.canvas.buffer_rgba())
        return np.ascontiguousarray(buf[: self.height, : self.width, :3]).astype(np.uint8)

    # ------------------------------------------------------------------ human mode
    def show(self, frame: np.ndarray, fps: float | None = None) -> None:
        """Display a frame in a window (``render_mode="human"``). Without an interactive
        matplotlib backend (headless), warns once and does nothing."""
        import matplotlib
        backend = matplotlib.get_backend().lower()
        if "agg" in backend or "inline" in backend or backend in ("pdf", "svg", "ps", "cairo", "template"):
            if not getattr(self, "_warned", False):
                warnings.warn(f"render_mode='human': matplotlib backend {backend!r} cannot open a window "
                              "(headless); frames are not shown. Use render_mode='rgb_array'.", stacklevel=3)
                self._warned = True
            return
        import matplotlib.pyplot as plt
        if self._human_fig is None or not plt.fignum_exists(self._human_fig.number):
            self._human_fig = plt.figure(figsize=(self.width / 100, self.height / 100))
            self._human_img = self._human_fig.add_axes([0, 0, 1, 1]).imshow(frame)
            self._human_fig.axes[0].set_axis_off()
        else:
            self._human_img.set_data(frame)
        plt.pause(1.0 / fps if fps else 0.001)

    def close(self) -> None:
        if self._human_fig is not None:
            import matplotlib.pyplot as plt
            plt.close(self._human_fig)
            self._human_fig = None


def render_frame(nodes, rods, strings, tensions=None, *, width: int = 480, height: int = 480, **kw) -> np.ndarray:
    """One-off frame (creates a :class:`Renderer`; reuse a Renderer for animations).
    Keyword arguments as :meth:`Renderer.render` plus ``elev``, ``azim``, ``limits``, ``title``."""
    init = {k: kw.pop(k) for k in ("elev", "azim", "limits", "title") if k in kw}
    return Renderer(width, height, **init).render(nodes, rods, strings, tensions, **kw)


# ====================================================================== MuJoCo (OpenGL) renderer
class RendererUnavailable(RuntimeError):
    """No OpenGL backend (or no ``mujoco``) for :class:`MujocoRenderer`; the message says what was
    tried and what to install."""


_GL_CACHE: dict = {}
_INSTALL_HINT = ("install the package with the mujoco extra (pip install 'tensegrity_gym[mujoco]') and an "
                 "OpenGL library: on Debian/Ubuntu 'apt-get install -y libegl1 libegl-mesa0' (EGL, no display "
                 "needed; Mesa's software rasteriser suffices) or 'apt-get install -y libosmesa6' with "
                 "MUJOCO_GL=osmesa")


def _context_class(name: str):
    if name == "egl":
        from mujoco.egl import GLContext
    elif name == "osmesa":
        from mujoco.osmesa import GLContext
    elif name == "glfw":
        from mujoco.glfw import GLContext
    else:
        raise RendererUnavailable(f"MUJOCO_GL={name!r}: unknown OpenGL backend; use egl, osmesa or glfw")
    return GLContext


def gl_backend() -> tuple[str, type]:
    """``(name, GLContext class)`` of the first OpenGL backend that creates a context (cached).

    ``MUJOCO_GL`` (``egl``, ``osmesa``, ``glfw``) when set, else egl, osmesa, then glfw when a
    ``DISPLAY`` is set. Raises :class:`RendererUnavailable` listing each failure."""
    import os
    if "result" in _GL_CACHE:
        return _GL_CACHE["result"]
    if "error" in _GL_CACHE:
        raise RendererUnavailable(_GL_CACHE["error"])
    try:
        import mujoco  # noqa: F401
    except ImportError as exc:
        _GL_CACHE["error"] = f"MuJoCo renderer: mujoco is not installed ({exc}); {_INSTALL_HINT}"
        raise RendererUnavailable(_GL_CACHE["error"]) from None
    env = os.environ.get("MUJOCO_GL", "").strip().lower()
    if env:
        names = [env]
    else:
        names = ["egl", "osmesa"] + (["glfw"] if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") else [])
    errors = []
    for name in names:
        try:
            cls = _context_class(name)
            ctx = cls(16, 16)
            ctx.make_current()
            ctx.free()
        except RendererUnavailable:
            raise
        except Exception as exc:  # noqa: BLE001 - any failure means "this backend does not work here"
            errors.append(f"{name}: {type(exc).__name__}: {str(exc).strip().splitlines()[0] if str(exc).strip() else ''}")
            continue
        _GL_CACHE["result"] = (name, cls)
        return name, cls
    _GL_CACHE["error"] = ("MuJoCo renderer: no OpenGL backend works here (tried " + "; ".join(errors)
                          + f"); {_INSTALL_HINT}")
    raise RendererUnavailable(_GL_CACHE["error"])


_SCENE_XML = """<mujoco model="tensegrity_view">
  <visual>
    <global offwidth="{w}" offheight="{h}" fovy="40"/>
    <quality shadowsize="{shadow}" offsamples="{samples}"/>
    <headlight ambient=".35 .35 .35" diffuse=".45 .45 .45" specular=".1 .1 .1"/>
    <map znear="0.01" zfar="200" haze="0"/>
    <rgba haze=".88 .91 .95 1"/>
  </visual>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1=".95 .97 1" rgb2=".70 .78 .88" width="8" height="8"/>
    <texture name="grid" type="2d" builtin="checker" rgb1=".86 .87 .88" rgb2=".76 .78 .80" width="32" height="32" mark="edge" markrgb=".6 .62 .65"/>
    <material name="grid" texture="grid" texrepeat="1 1" texuniform="true" reflectance="0"/>
  </asset>
  <worldbody>
    <light name="sun" directional="true" castshadow="{cast}" pos="0 0 10" dir="0.35 0.45 -1" diffuse=".6 .6 .6" specular=".2 .2 .2"/>
    <geom name="ground" type="plane" size="20 20 2" material="grid" rgba="1 1 1 0"/>
  </worldbody>
</mujoco>
"""


class MujocoRenderer:
    """3-D frames of a tensegrity with MuJoCo's offscreen OpenGL renderer (same ``render`` call
    as the matplotlib :class:`Renderer`; SI units, tensions in N).

    Rods: shaded dark capsules with node spheres; strings: thin capsules coloured by tension on
    the "turbo" scale from 0 to ``tension_max`` (default: the largest tension in the frame),
    slack strings thinner and grey; targets: translucent green spheres; path: an orange
    polyline; goal: a green sphere; ground: a checkered plane at ``ground_z``. Overlays: the
    title and caption (top left), a colour bar with its range in N (right), the time-independent
    legend (rod, slack). The camera looks at the centre of the first frame's bounding box (it
    re-frames if the structure leaves it), from ``elev`` degrees above the horizon and azimuth
    ``azim`` degrees (matplotlib's convention).

    Parameters: ``width``, ``height`` in pixels; ``shadows``: cast shadows (off by default: on a
    software rasteriser they cost 3-5x the frame time);
    ``samples``: multisampling (0 = off; 4 looks smoother, 2-3x slower on a software rasteriser).
    """

    def __init__(self, width: int = 480, height: int = 480, elev: float = 20.0, azim: float = -60.0,
                 limits=None, title: str | None = None, *, shadows: bool = False, samples: int = 0,
                 follow: bool = False):
        if int(width) < 16 or int(height) < 16:
            raise ValueError(f"width, height: must be at least 16 pixels, got {width} x {height}")
        name, cls = gl_backend()
        import mujoco
        self._mj = mujoco
        self.backend = name
        self.width, self.height = int(width), int(height)
        self.elev, self.azim, self.title, self.follow = float(elev), float(azim), title, bool(follow)
        self.limits = None if limits is None else np.asarray(limits, float).reshape(3, 2)
        self._auto_limits = self.limits is None
        xml = _SCENE_XML.format(w=max(self.width, 64), h=max(self.height, 64), shadow=2048 if shadows else 0,
                                samples=int(samples), cast="true" if shadows else "false")
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self._ctx = cls(max(self.width, 64), max(self.height, 64))
        self._ctx.make_current()
        scale = mujoco.mjtFontScale.mjFONTSCALE_150 if min(self.width, self.height) >= 400 else \
            mujoco.mjtFontScale.mjFONTSCALE_100
        self._con = mujoco.MjrContext(self.model, scale)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        self._scn = mujoco.MjvScene(self.model, maxgeom=1000)
        self._opt = mujoco.MjvOption()
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._rgb = np.empty((self.height, self.width, 3), np.uint8)
        import matplotlib
        self._lut = np.asarray(matplotlib.colormaps["turbo"](np.linspace(0.1, 0.9, 256)), np.float32)
        self._eye = np.eye(3).ravel()
        self._size = None
        self._font = None
        self._human = None

    # ------------------------------------------------------------------ helpers
    def _update_limits(self, pts: np.ndarray) -> None:
        Renderer._update_limits(self, pts)

    def _add(self, gtype, size, pos, rgba, frm=None, to=None, width=None):
        mj, scn = self._mj, self._scn
        if scn.ngeom >= scn.maxgeom:
            return
        g = scn.geoms[scn.ngeom]
        mj.mjv_initGeom(g, gtype, np.asarray(size, float), np.asarray(pos, float), self._eye,
                        np.asarray(rgba, np.float32))
        if frm is not None:
            mj.mjv_connector(g, gtype, width, np.asarray(frm, float), np.asarray(to, float))
        scn.ngeom += 1

    def render(self, nodes, rods, strings, tensions=None, *, slack=None, targets=None, ground_z=None,
               path=None, goal=None, tension_max=None, caption: str | None = None) -> np.ndarray:
        """Draw one frame and return it as an (height, width, 3) uint8 array (arguments as
        :meth:`Renderer.render`)."""
        mj = self._mj
        nodes, rods, strings, targets, pts = _scene_arrays(nodes, rods, strings, targets, goal)
        if self.follow and self._auto_limits and self.limits is not None:
            half = 0.5 * float(np.max(self.limits[:, 1] - self.limits[:, 0]))
            c = nodes.mean(axis=0)
            self.limits = np.stack([c - half, c + half], axis=1)
        self._update_limits(np.concatenate(pts))
        if self._size is None:
            lens = np.linalg.norm(nodes[rods[:, 1]] - nodes[rods[:, 0]], axis=1) if len(rods) else np.ones(1)
            scale = float(np.median(lens)) if len(lens) else 1.0
            scale = min(scale, float(np.max(self.limits[:, 1] - self.limits[:, 0])))
            self._size = (0.022 * scale, 0.007 * scale, 0.032 * scale)   # rod, string, node radii (m)
        r_rod, r_str, r_node = self._size
        # ground
        gid = 0
        if ground_z is not None:
            self.model.geom_pos[gid, 2] = float(ground_z)
            self.model.geom_rgba[gid, 3] = 1.0
        else:
            self.model.geom_rgba[gid, 3] = 0.0
        # camera
        lo, hi = self.limits[:, 0], self.limits[:, 1]
        half = 0.5 * float(np.max(hi - lo))
        self._cam.lookat[:] = 0.5 * (lo + hi)
        if ground_z is not None:
            self._cam.lookat[2] = max(self._cam.lookat[2], float(ground_z) + 0.3 * half)
        self._cam.distance = 3.5 * half
        self._cam.elevation = -self.elev
        self._cam.azimuth = self.azim + 90.0
        self._ctx.make_current()
        mj.mjv_updateScene(self.model, self.data, self._opt, None, self._cam, mj.mjtCatBit.mjCAT_ALL, self._scn)
        CAP, SPH, LINE = mj.mjtGeom.mjGEOM_CAPSULE, mj.mjtGeom.mjGEOM_SPHERE, mj.mjtGeom.mjGEOM_LINE
        # strings
        m = len(strings)
        tmax = 1.0
        if m:
            T = np.zeros(m) if tensions is None else np.nan_to_num(np.asarray(tensions, float).reshape(m))
            sl = (T <= 0) if slack is None else np.asarray(slack, bool).reshape(m)
            tmax = float(tension_max) if tension_max is not None else max(float(T.max(initial=0.0)), 1e-9)
            idx = np.clip((T / tmax * 255).astype(int), 0, 255)
            for i, (a, b) in enumerate(strings):
                if sl[i]:
                    self._add(CAP, (0, 0, 0), (0, 0, 0), (.55, .56, .58, 1), nodes[a], nodes[b], 0.6 * r_str)
                else:
                    self._add(CAP, (0, 0, 0), (0, 0, 0), self._lut[idx[i]], nodes[a], nodes[b], r_str)
        # rods and nodes
        for a, b in rods:
            self._add(CAP, (0, 0, 0), (0, 0, 0), (.16, .18, .22, 1), nodes[a], nodes[b], r_rod)
        for p in nodes:
            self._add(SPH, (r_node, r_node, r_node), p, (.1, .1, .12, 1))
        if targets is not None:
            for p in targets:
                self._add(SPH, (1.5 * r_node,) * 3, p, (.1, .75, .2, .45))
        if path is not None:
            path = np.asarray(path, float).reshape(-1, 3)
            if len(path) > 1:
                step = max(1, len(path) // 300)
                pp = path[::step]
                if ground_z is not None:
                    pp = pp.copy()
                    pp[:, 2] = float(ground_z) + 0.002 * half
                for p0, p1 in zip(pp[:-1], pp[1:]):
                    if np.linalg.norm(p1 - p0) > 1e-9:
                        self._add(LINE, (0, 0, 0), (0, 0, 0), (1, .5, .05, 1), p0, p1, 3.0)
        if goal is not None:
            self._add(SPH, (2 * r_node,) * 3, np.asarray(goal, float).reshape(3), (.1, .75, .2, 1))
        mj.mjr_render(self._rect, self._scn, self._con)
        # overlays: title + caption, colour bar legend
        text = "\n".join(t for t in (self.title, caption) if t)
        if text:
            mj.mjr_overlay(mj.mjtFont.mjFONT_NORMAL, mj.mjtGridPos.mjGRID_TOPLEFT, self._rect, text, "", self._con)
        mj.mjr_readPixels(self._rgb, None, self._rect, self._con)
        img = np.ascontiguousarray(self._rgb[::-1])
        if m:
            img = self._legend(img, tmax, bool(np.any(sl)))
        return img

    def _legend(self, img: np.ndarray, tmax: float, any_slack: bool) -> np.ndarray:
        """Colour bar (0 .. tmax N) and slack swatch at the right edge, drawn into ``img``."""
        from PIL import Image, ImageDraw
        W, H = self.width, self.height
        if self._font is None:
            from PIL import ImageFont
            from matplotlib import font_manager
            size = max(9, int(round(min(W, H) / 34)))
            try:
                self._font = ImageFont.truetype(font_manager.findfont("DejaVu Sans"), size)
            except OSError:  # pragma: no cover - font file missing
                self._font = ImageFont.load_default()
        bw, bh = max(6, W // 36), int(0.36 * H)
        x0, y0 = W - bw - max(8, W // 50), int(0.2 * H)     # top of the bar (image rows grow down)
        img[y0 - 1:y0 + bh + 1, x0 - 1:x0 + bw + 1] = 40
        col = (self._lut[np.linspace(255, 0, bh).astype(int), :3] * 255).astype(np.uint8)
        img[y0:y0 + bh, x0:x0 + bw] = col[:, None, :]
        if any_slack:
            ys = y0 + bh + int(0.05 * H)
            img[ys:ys + bw, x0:x0 + bw] = (140, 143, 148)
        pil = Image.fromarray(img)
        d = ImageDraw.Draw(pil)
        f = self._font
        right = x0 - 5

        def text(s, y, anchor="rm"):
            d.text((right, y), s, fill=(20, 20, 25), font=f, anchor=anchor)

        d.text((x0 + bw, y0 - 6), "tension", fill=(20, 20, 25), font=f, anchor="rb")
        text(f"{tmax:.3g} N", y0 + 4)
        text("0 N", y0 + bh - 4)
        if any_slack:
            text("slack", ys + bw // 2)
        return np.asarray(pil)

    def show(self, frame: np.ndarray, fps: float | None = None) -> None:
        """Display a frame in a window (matplotlib; ``render_mode="human"``); headless: warns once."""
        if self._human is None:
            self._human = Renderer.__new__(Renderer)
            self._human._human_fig = None
            self._human.width, self._human.height = self.width, self.height
        Renderer.show(self._human, frame, fps)

    def close(self) -> None:
        if getattr(self, "_human", None) is not None:
            Renderer.close(self._human)
            self._human = None
        if getattr(self, "_con", None) is not None:
            try:
                self._ctx.make_current()
                self._con.free()
            except Exception:  # noqa: BLE001 - best effort at interpreter exit
                pass
            self._con = None
        if getattr(self, "_ctx", None) is not None:
            try:
                self._ctx.free()
            except Exception:  # noqa: BLE001
                pass
            self._ctx = None

    def __del__(self):
        self.close()


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
        if not _GL_CACHE.get("warned"):
            warnings.warn(f"{exc}. Falling back to the matplotlib renderer (slower).", stacklevel=2)
            _GL_CACHE["warned"] = True
        return Renderer(width, height, **kw)


def write_video(path, structure, nodes, tensions=None, times=None, *, fps: float = 30.0, width: int = 480,
                height: int = 480, title: str | None = None, ground_z=None, backend: str | None = None) -> int:
    """Render a recorded trajectory to a video file (``.mp4`` via imageio-ffmpeg, or ``.gif``).

    ``nodes`` (S, n, 3) m; ``tensions`` (S, m) N or None; ``times`` (S,) s: records are picked
    so that the video plays in real time at ``fps`` frames/s (all records if ``times`` is None).
    The file is written to a temporary name in the same folder and renamed when complete.
    Returns the number of frames written."""
    import os
    import tempfile
    from pathlib import Path
    try:
        import imageio.v2 as imageio
    except ImportError:
        raise RendererUnavailable("write_video needs imageio (pip install 'tensegrity_gym[mujoco]')") from None
    nodes = np.asarray(nodes, float)
    if nodes.ndim != 3 or nodes.shape[2] != 3 or len(nodes) == 0:
        raise ValueError(f"nodes: expected an (S, n, 3) trajectory, got shape {nodes.shape}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps: must be positive, got {fps}")
    idx = np.arange(len(nodes))
    if times is not None:
        times = np.asarray(times, float)
        want = np.arange(times[0], times[-1] + 0.5 / fps, 1.0 / fps)
        idx = np.unique(np.clip(np.searchsorted(times, want - 1e-12), 0, len(times) - 1))
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".mp4", ".gif", ".webm", ".mkv", ".avi", ".mov"):
        raise ValueError(f"video path {str(path)!r}: use a .mp4 or .gif file name")
    r = make_renderer(width, height, backend=backend, title=title or structure.name)
    if ground_z is None and structure.gravity is not None:
        ground_z = float(nodes[..., 2].min())
    tmax = None
    if tensions is not None:
        tensions = np.asarray(tensions, float)
        tmax = max(float(np.nanmax(tensions, initial=0.0)), 1e-9)   # one colour scale for the whole video
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix, dir=path.parent if str(path.parent) else ".")
    os.close(fd)
    try:
        kw = {"fps": fps} if suffix != ".gif" else {"duration": 1000.0 / fps, "loop": 0}
        if suffix == ".mp4":
            kw.update(codec="libx264", quality=7, macro_block_size=8)
        w = imageio.get_writer(tmp, **kw)
        try:
            for i in idx:
                cap = None if times is None else f"t = {times[i]:.2f} s"
                T = None if tensions is None else tensions[i]
                w.append_data(r.render(nodes[i], structure.bars, structure.strings, T, ground_z=ground_z,
                                       caption=cap, tension_max=tmax))
        except BaseException:
            close_after_error(w)   # the writer's own error on close (ffmpeg's pipe) would hide this one
            raise
        w.close()
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        r.close()
        if os.path.exists(tmp):
            os.remove(tmp)
    return len(idx)


# ====================================================================== interactive trajectory viewer
def _has_display() -> bool:
    import os
    import sys
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _tension_rgb(T: np.ndarray, tmax: float) -> np.ndarray:
    import matplotlib
    c = matplotlib.colormaps["turbo"](0.1 + 0.8 * np.clip(T / tmax, 0.0, 1.0))[:, :3]
    c[T <= 0] = (0.55, 0.56, 0.58)
    return (255 * c).astype(np.uint8)


class BrowserViewer:
    """Interactive 3-D view of a recorded trajectory in a web browser (viser, WebGL): rods,
    strings coloured by tension, nodes, the ground; a time slider, play/pause, a speed choice.

    Works on a headless machine: open the printed URL (forward the port over ssh if remote).
    ``nodes`` (S, n, 3) m, ``tensions`` (S, m) N or None, ``times`` (S,) s (default 0, 1, 2, ...).
    """

    def __init__(self, structure, nodes, tensions=None, times=None, *, host: str = "127.0.0.1",
                 port: int = 8080, ground_z=None, title: str | None = None):
        try:
            import viser
        except ImportError:
            raise RendererUnavailable("the browser viewer needs viser (pip install 'tensegrity_gym[viewer]')") from None
        import threading
        self.nodes = np.asarray(nodes, float)
        if self.nodes.ndim != 3 or self.nodes.shape[2] != 3 or len(self.nodes) == 0:
            raise ValueError(f"nodes: expected an (S, n, 3) trajectory, got shape {self.nodes.shape}")
        S = len(self.nodes)
        self.times = np.arange(S, dtype=float) if times is None else np.asarray(times, float)
        if self.times.shape != (S,):
            raise ValueError(f"times: expected {S} values, got shape {self.times.shape}")
        m = structure.n_strings
        self.tensions = np.zeros((S, m)) if tensions is None else np.asarray(tensions, float).reshape(S, m)
        self.tmax = max(float(np.nanmax(self.tensions, initial=0.0)), 1e-9)
        self.rods, self.strings = structure.bars, structure.strings
        self.server = viser.ViserServer(host=host, port=int(port), verbose=False)
        self.url = f"http://{host}:{self.server.get_port()}"
        sc, gui = self.server.scene, self.server.gui
        ext = float(np.ptp(self.nodes[0], axis=0).max()) or 1.0
        if ground_z is None and structure.gravity is not None:
            ground_z = float(self.nodes[..., 2].min())
        if ground_z is not None:
            c = self.nodes[0].mean(axis=0)
            sc.add_grid("/ground", width=20 * ext, height=20 * ext, cell_size=ext / 4,
                        position=(float(c[0]), float(c[1]), float(ground_z)))
        self._rods = sc.add_line_segments("/rods", self._segments(0, self.rods), (40, 44, 52), thickness=0.025 * ext)
        self._strings = sc.add_line_segments("/strings", self._segments(0, self.strings), self._colors(0),
                                             thickness=0.008 * ext)
        self._points = sc.add_point_cloud("/nodes", self.nodes[0], (20, 20, 25), point_size=0.04 * ext,
                                          point_shape="circle")
        gui.add_markdown(f"**{title or structure.name}** - strings coloured by tension, "
                         f"blue 0 N to red {self.tmax:.3g} N, grey slack")
        self._slider = gui.add_slider("time (s)", float(self.times[0]), float(self.times[-1]),
                                      float(np.min(np.diff(self.times))) if S > 1 else 1.0, float(self.times[0]))
        self._button = gui.add_button("play / pause")
        self._speed = gui.add_dropdown("speed", ("0.25x", "0.5x", "1x", "2x", "4x"), initial_value="1x")
        self.index = 0
        self.playing = False
        self._lock = threading.Lock()
        self._slider.on_update(lambda _: self.set_time(self._slider.value, from_slider=True))
        self._button.on_click(lambda _: self.pause() if self.playing else self.play())
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _segments(self, i, pairs):
        N = self.nodes[i]
        return np.stack([N[pairs[:, 0]], N[pairs[:, 1]]], axis=1) if len(pairs) else np.zeros((0, 2, 3))

    def _colors(self, i):
        c = _tension_rgb(self.tensions[i], self.tmax)
        return np.repeat(c[:, None, :], 2, axis=1)

    def set_frame(self, i: int) -> None:
        """Show record ``i``."""
        i = int(np.clip(i, 0, len(self.nodes) - 1))
        with self._lock:
            self.index = i
            self._rods.points = self._segments(i, self.rods)
            if len(self.strings):
                self._strings.points = self._segments(i, self.strings)
                self._strings.colors = self._colors(i)
            self._points.points = self.nodes[i]

    def set_time(self, t: float, from_slider: bool = False) -> None:
        i = int(np.clip(np.searchsorted(self.times, float(t) - 1e-12), 0, len(self.times) - 1))
        if i != self.index or from_slider:
            self.set_frame(i)
        if not from_slider:
            self._slider.value = float(self.times[i])

    def play(self) -> None:
        self.playing = True

    def pause(self) -> None:
        self.playing = False

    def _loop(self) -> None:
        dt_frame = 1.0 / 30.0
        t = float(self.times[self.index])
        while not self._stop.wait(dt_frame):
            if not self.playing:
                t = float(self.times[self.index])
                continue
            speed = float(self._speed.value.rstrip("x"))
            t += speed * dt_frame
            if t > self.times[-1]:
                t = float(self.times[0])
            self.set_time(t)

    def wait(self) -> None:
        """Block until Ctrl-C."""
        try:
            while not self._stop.wait(0.5):
                pass
        except KeyboardInterrupt:
            pass
        finally:
            self.close()

    def close(self) -> None:
        self._stop.set()
        self.server.stop()


class WindowViewer:
    """Interactive window (matplotlib widgets) showing frames of a recorded trajectory drawn by
    :func:`make_renderer`: a time slider and a play/pause button. Needs a display."""

    def __init__(self, structure, nodes, tensions=None, times=None, *, width: int = 640, height: int = 640,
                 ground_z=None, title: str | None = None):
        import matplotlib.pyplot as plt
        from matplotlib.widgets import Button, Slider
        self.nodes = np.asarray(nodes, float)
        S = len(self.nodes)
        self.times = np.arange(S, dtype=float) if times is None else np.asarray(times, float)
        self.tensions = None if tensions is None else np.asarray(tensions, float)
        self.structure = structure
        if ground_z is None and structure.gravity is not None:
            ground_z = float(self.nodes[..., 2].min())
        self.ground_z = ground_z
        self.renderer = make_renderer(width, height, title=title or structure.name)
        self.tmax = None if self.tensions is None else max(float(self.tensions.max()), 1e-9)
        self.fig = plt.figure(figsize=(width / 100, height / 100 + 0.6))
        ax = self.fig.add_axes([0, 0.1, 1, 0.9])
        ax.set_axis_off()
        self.img = ax.imshow(self._frame(0))
        self.slider = Slider(self.fig.add_axes([0.22, 0.03, 0.6, 0.04]), "t (s)", float(self.times[0]),
                             float(self.times[-1]), valinit=float(self.times[0]))
        self.button = Button(self.fig.add_axes([0.02, 0.02, 0.12, 0.06]), "play")
        self.playing = False
        self.index = 0
        self.slider.on_changed(self._on_slider)
        self.button.on_clicked(self._toggle)
        self.timer = self.fig.canvas.new_timer(interval=33)
        self.timer.add_callback(self._tick)
        self.timer.start()

    def _frame(self, i):
        T = None if self.tensions is None else self.tensions[i]
        return self.renderer.render(self.nodes[i], self.structure.bars, self.structure.strings, T,
                                    ground_z=self.ground_z, tension_max=self.tmax,
                                    caption=f"t = {self.times[i]:.2f} s")

    def _on_slider(self, t):
        i = int(np.clip(np.searchsorted(self.times, t - 1e-12), 0, len(self.times) - 1))
        if i != self.index:
            self.index = i
            self.img.set_data(self._frame(i))
            self.fig.canvas.draw_idle()

    def _toggle(self, _):
        self.playing = not self.playing
        self.button.label.set_text("pause" if self.playing else "play")

    def _tick(self):
        if self.playing:
            t = self.slider.val + 0.033
            self.slider.set_val(float(self.times[0]) if t > self.times[-1] else t)

    def wait(self) -> None:
        import matplotlib.pyplot as plt
        plt.show()


def view_trajectory(structure, nodes, tensions=None, times=None, *, mode: str = "auto", block: bool = True,
                    **kw):
    """Open an interactive view of a recorded trajectory with a time slider and play/pause.

    ``mode``: "window" (matplotlib window, needs a display and an interactive backend),
    "browser" (viser web viewer: prints its URL; works headless) or "auto" (window where
    there is a display, else browser). ``block``: wait until the window is closed / Ctrl-C.
    Returns the viewer (:class:`WindowViewer` or :class:`BrowserViewer`)."""
    if mode not in ("auto", "window", "browser"):
        raise ValueError(f"mode: one of 'auto', 'window', 'browser', got {mode!r}")
    if mode == "auto":
        import matplotlib
        interactive = "agg" not in matplotlib.get_backend().lower()
        mode = "window" if _has_display() and interactive else "browser"
    if mode == "window":
        if not _has_display():   # a window on a headless machine would show nothing and return at once
            raise RendererUnavailable("mode 'window': no display (DISPLAY / WAYLAND_DISPLAY unset); use mode "
                                      "'browser' (the web viewer works headless)")
        v = WindowViewer(structure, nodes, tensions, times, **kw)
    else:
        v = BrowserViewer(structure, nodes, tensions, times, **kw)
        print(f"trajectory viewer: open {v.url} in a browser (Ctrl-C to stop)")
    if block:
        v.wait()
    return v
