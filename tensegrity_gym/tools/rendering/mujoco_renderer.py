"""MuJoCo's offscreen OpenGL renderer (:class:`MujocoRenderer`) and the choice of its OpenGL backend."""
from __future__ import annotations

import numpy as np

from .matplotlib_renderer import Renderer
from .scene import RendererUnavailable, _check_terrain, _scene_arrays


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
{terrain_assets}
  </asset>
  <worldbody>
    <light name="sun" directional="true" castshadow="{cast}" pos="0 0 10" dir="0.35 0.45 -1" diffuse=".6 .6 .6" specular=".2 .2 .2"/>
    <geom name="ground" type="plane" size="20 20 2" material="grid" rgba="1 1 1 0"/>
{terrain_geoms}
  </worldbody>
</mujoco>
"""


class MujocoRenderer:
    """3-D frames of a tensegrity with MuJoCo's offscreen OpenGL renderer (same ``render`` call
    as the matplotlib :class:`Renderer`; SI units, tensions in N).

    Rods: shaded dark capsules with node spheres; strings: thin capsules coloured by tension on
    the "turbo" scale from 0 to ``tension_max`` (default: the largest tension in the frame),
    slack strings thinner and grey; targets: translucent green spheres; path: an orange
    polyline; goal: a green sphere; ground: a checkered plane at ``ground_z``; ``terrain``: its
    plane (checkered), boxes and heightfield as MuJoCo geoms (the scene is rebuilt when a new
    terrain object is given, then reused). Overlays: the
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
        self._xml_args = dict(w=max(self.width, 64), h=max(self.height, 64), shadow=2048 if shadows else 0,
                              samples=int(samples), cast="true" if shadows else "false")
        self._ctx = cls(max(self.width, 64), max(self.height, 64))
        self._ctx.make_current()
        self._font_scale = mujoco.mjtFontScale.mjFONTSCALE_150 if min(self.width, self.height) >= 400 else \
            mujoco.mjtFontScale.mjFONTSCALE_100
        self._con = None
        self._load_scene(None)
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
    def _load_scene(self, terrain) -> None:
        """(Re)build the MuJoCo scene model with ``terrain``'s geoms (the MJCF export's own mapping,
        :func:`tensegrity_gym.io.mjcf.terrain_xml`: plane, boxes, heightfield) and its render context.
        Runs once per terrain object: frames of one terrain reuse it."""
        from ...io.mjcf import terrain_xml
        mujoco = self._mj
        assets, geoms = ([], []) if terrain is None else terrain_xml(terrain)
        xml = _SCENE_XML.format(terrain_assets="\n".join(assets), terrain_geoms="\n".join(geoms), **self._xml_args)
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self._ctx.make_current()
        if self._con is not None:
            self._con.free()
        self._con = mujoco.MjrContext(self.model, self._font_scale)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        self._scn = mujoco.MjvScene(self.model, maxgeom=1000)
        self._terrain = terrain

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
               path=None, goal=None, tension_max=None, caption: str | None = None, terrain=None) -> np.ndarray:
        """Draw one frame and return it as an (height, width, 3) uint8 array (arguments as
        :meth:`Renderer.render`; ``terrain`` replaces the checkered ground of ``ground_z``)."""
        mj = self._mj
        if _check_terrain(terrain) is not self._terrain:
            self._load_scene(terrain)
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
        if terrain is not None:
            self.model.geom_rgba[gid, 3] = 0.0
        elif ground_z is not None:
            self.model.geom_pos[gid, 2] = float(ground_z)
            self.model.geom_rgba[gid, 3] = 1.0
        else:
            self.model.geom_rgba[gid, 3] = 0.0
        # camera
        lo, hi = self.limits[:, 0], self.limits[:, 1]
        half = 0.5 * float(np.max(hi - lo))
        self._cam.lookat[:] = 0.5 * (lo + hi)
        if ground_z is not None and terrain is None:
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
