"""The matplotlib 3-D renderer (Agg canvas; always available): :class:`Renderer`, :func:`render_frame`."""
from __future__ import annotations

import warnings

import numpy as np

from ...core.terrain_kinds import require
from .scene import _box_faces, _check_terrain, _heightfield_grid, _plane_height, _scene_arrays


class Renderer:
    """Reusable matplotlib renderer (one figure kept between frames).

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

    def _draw_terrain(self, terrain) -> None:
        """The terrain's parts, each by its kind's row of :data:`TERRAIN_DRAW` (in its layers:
        planes, then heightfields, then boxes); ValueError naming a kind without a row."""
        rows = [(require(TERRAIN_DRAW, p, "the matplotlib renderer (TERRAIN_DRAW)"), p) for p in terrain.parts()]
        for (_, draw), part in sorted(rows, key=lambda r: r[0][0]):
            draw(self, part)

    def _draw_plane(self, plane) -> None:
        """A patch of the plane over the view."""
        X, Y = np.meshgrid(self.limits[0], self.limits[1])
        self.ax.plot_surface(X, Y, _plane_height(plane, X, Y), color="0.85", alpha=0.5, zorder=0)

    def _draw_heightfield(self, hf) -> None:
        """The heightfield's surface over the view."""
        X, Y, Z = _heightfield_grid(hf, 40)
        # the part over the view (matplotlib's 3-D axes do not clip what lies beyond their limits)
        (x0, x1), (y0, y1) = self.limits[0], self.limits[1]
        c = (X[0] >= x0 - hf.cell) & (X[0] <= x1 + hf.cell)
        r = (Y[:, 0] >= y0 - hf.cell) & (Y[:, 0] <= y1 + hf.cell)
        if c.sum() >= 2 and r.sum() >= 2:
            X, Y, Z = (A[np.ix_(r, c)] for A in (X, Y, Z))
            self.ax.plot_surface(X, Y, Z, cmap="summer", alpha=0.75, linewidth=0.2, edgecolor="0.45", zorder=0)

    def _draw_box(self, b) -> None:
        """A shaded solid box."""
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection
        self.ax.add_collection3d(Poly3DCollection(list(_box_faces(b)), facecolor=(.62, .56, .48, .85),
                                                  edgecolor="0.3", linewidths=0.6))

    def render(self, nodes, rods, strings, tensions=None, *, slack=None, targets=None, ground_z=None,
               path=None, goal=None, tension_max=None, caption: str | None = None, terrain=None) -> np.ndarray:
        """Draw one frame and return it as an (height, width, 3) uint8 array.

        nodes (n, 3) m; rods (k, 2) and strings (m, 2) node-index pairs; tensions (m,) N or None;
        slack (m,) bool or None (default: tension <= 0); targets (t, 3) m; ground_z m;
        path (p, 3) m; goal (3,) m; tension_max N (colour-scale top); caption: text;
        terrain: a :class:`~tensegrity_gym.core.terrain.Terrain` (plane, boxes, heightfield) drawn
        instead of the level ground of ``ground_z``.
        """
        import matplotlib
        terrain = _check_terrain(terrain)
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
        if terrain is not None:
            self._draw_terrain(terrain)
        elif ground_z is not None:
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


#: terrain kind name (:mod:`tensegrity_gym.core.terrain_kinds`) -> (layer, ``draw(renderer, part)``):
#: the lower layers drawn first
TERRAIN_DRAW = {"plane": (0, Renderer._draw_plane), "heightfield": (1, Renderer._draw_heightfield),
                "box": (2, Renderer._draw_box)}
