"""Interactive trajectory viewer in a web browser (viser, WebGL): :class:`BrowserViewer`."""
from __future__ import annotations

import numpy as np

from ...core.terrain_kinds import require
from .scene import RendererUnavailable, _check_terrain, _heightfield_mesh, _plane_height, _tension_rgb


class BrowserViewer:
    """Interactive 3-D view of a recorded trajectory in a web browser (viser, WebGL): rods,
    strings coloured by tension, nodes, the ground or a ``terrain`` (a
    :class:`~tensegrity_gym.core.terrain.Terrain`: plane, boxes, heightfield); a time slider,
    play/pause, a speed choice.

    Works on a headless machine: open the printed URL (forward the port over ssh if remote).
    ``nodes`` (S, n, 3) m, ``tensions`` (S, m) N or None, ``times`` (S,) s (default 0, 1, 2, ...).
    """

    def __init__(self, structure, nodes, tensions=None, times=None, *, host: str = "127.0.0.1",
                 port: int = 8080, ground_z=None, title: str | None = None, terrain=None):
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
        if ground_z is None and structure.gravity is not None and terrain is None:
            ground_z = float(self.nodes[..., 2].min())
        if _check_terrain(terrain) is not None:
            self._add_terrain(sc, terrain, ext)
        elif ground_z is not None:
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

    def _add_terrain(self, sc, terrain, ext: float) -> None:
        """The terrain's parts, each by its kind's row of :data:`TERRAIN_ADD` (ValueError naming a
        kind without a row)."""
        c = self.nodes[0].mean(axis=0)
        count = {}
        for part in terrain.parts():
            add = require(TERRAIN_ADD, part, "the browser viewer (TERRAIN_ADD)")
            count[add] = count.get(add, -1) + 1
            add(sc, part, count[add], c, ext)

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


def _add_plane(sc, plane, i, c, ext):
    """A grid tilted onto the plane around the structure's centre ``c`` (m), ``ext`` its size (m)."""
    from ...io.mjcf import _quat_z_to
    z = float(_plane_height(plane, c[0], c[1]))
    sc.add_grid("/terrain/plane", width=20 * ext, height=20 * ext, cell_size=ext / 4,
                wxyz=tuple(_quat_z_to(plane.normal)), position=(float(c[0]), float(c[1]), z))


def _add_box(sc, b, i, c, ext):
    """The i-th box."""
    yaw = np.radians(b.yaw_deg)
    sc.add_box(f"/terrain/box{i}", color=(158, 143, 122), dimensions=tuple(b.size),
               wxyz=(float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))), position=tuple(b.center))


def _add_heightfield(sc, hf, i, c, ext):
    """The heightfield as a mesh."""
    v, f = _heightfield_mesh(hf)
    sc.add_mesh_simple("/terrain/heightfield", v, f, color=(140, 160, 120), side="double")


#: terrain kind name (:mod:`tensegrity_gym.core.terrain_kinds`) -> ``add(scene, part, i, centre, ext)``
TERRAIN_ADD = {"plane": _add_plane, "box": _add_box, "heightfield": _add_heightfield}
