"""Interactive trajectory viewer in a matplotlib window: :class:`WindowViewer`."""
from __future__ import annotations

import numpy as np

from .factory import make_renderer


def _has_display() -> bool:
    import os
    import sys
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class WindowViewer:
    """Interactive window (matplotlib widgets) showing frames of a recorded trajectory drawn by
    :func:`make_renderer`: a time slider and a play/pause button; ``terrain`` (a
    :class:`~tensegrity_gym.core.terrain.Terrain`) drawn under the structure. Needs a display."""

    def __init__(self, structure, nodes, tensions=None, times=None, *, width: int = 640, height: int = 640,
                 ground_z=None, title: str | None = None, terrain=None):
        import matplotlib.pyplot as plt
        from matplotlib.widgets import Button, Slider
        self.nodes = np.asarray(nodes, float)
        S = len(self.nodes)
        self.times = np.arange(S, dtype=float) if times is None else np.asarray(times, float)
        self.tensions = None if tensions is None else np.asarray(tensions, float)
        self.structure = structure
        if ground_z is None and structure.gravity is not None and terrain is None:
            ground_z = float(self.nodes[..., 2].min())
        self.ground_z, self.terrain = ground_z, terrain
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
                                    ground_z=self.ground_z, terrain=self.terrain, tension_max=self.tmax,
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
