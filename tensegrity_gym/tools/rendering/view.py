"""Open the interactive trajectory viewer that fits the machine: :func:`view_trajectory`."""
from __future__ import annotations

from .browser_viewer import BrowserViewer
from .scene import RendererUnavailable
from .window_viewer import WindowViewer, _has_display


def view_trajectory(structure, nodes, tensions=None, times=None, *, mode: str = "auto", block: bool = True,
                    **kw):
    """Open an interactive view of a recorded trajectory with a time slider and play/pause.

    ``mode``: "window" (matplotlib window, needs a display and an interactive backend),
    "browser" (viser web viewer: prints its URL; works headless) or "auto" (window where
    there is a display, else browser). ``block``: wait until the window is closed / Ctrl-C.
    ``terrain=`` (a :class:`~tensegrity_gym.core.terrain.Terrain`), ``ground_z=``, ``title=`` and
    the viewer's own keywords go to the viewer.
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
