"""Recorded trajectories to video files (imageio): :func:`render_video` and its atomic form :func:`write_video`."""
from __future__ import annotations

import numpy as np

from ...io.atomic import close_after_error, write_atomic
from .factory import make_renderer
from .scene import RendererUnavailable


def write_video(path, structure, nodes, tensions=None, times=None, **kw) -> int:
    """Render a recorded trajectory to a video file (``.mp4`` via imageio-ffmpeg, or ``.gif``),
    written atomically (:func:`tensegrity_gym.io.atomic.write_atomic`: a temporary file in the
    same folder renamed when complete). Arguments as :func:`render_video`; returns the number of
    frames written."""
    frames = []
    write_atomic(path, fill=lambda tmp: frames.append(render_video(tmp, structure, nodes, tensions, times, **kw)))
    return frames[0]


def render_video(path, structure, nodes, tensions=None, times=None, *, fps: float = 30.0, width: int = 480,
                 height: int = 480, title: str | None = None, ground_z=None, backend: str | None = None,
                 terrain=None) -> int:
    """Render a recorded trajectory straight into the video file ``path`` (its suffix picks the
    format: ``.mp4``, ``.gif``, ...; :func:`write_video` is the atomic form).

    ``nodes`` (S, n, 3) m; ``tensions`` (S, m) N or None; ``times`` (S,) s: records are picked
    so that the video plays in real time at ``fps`` frames/s (all records if ``times`` is None).
    ``terrain``: a :class:`~tensegrity_gym.core.terrain.Terrain` drawn under the structure (instead
    of the level ground at ``ground_z``, by default the lowest node of a structure with gravity).
    Returns the number of frames written."""
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
    if ground_z is None and structure.gravity is not None and terrain is None:
        ground_z = float(nodes[..., 2].min())
    tmax = None
    if tensions is not None:
        tensions = np.asarray(tensions, float)
        tmax = max(float(np.nanmax(tensions, initial=0.0)), 1e-9)   # one colour scale for the whole video
    try:
        kw = {"fps": fps} if suffix != ".gif" else {"duration": 1000.0 / fps, "loop": 0}
        if suffix == ".mp4":
            kw.update(codec="libx264", quality=7, macro_block_size=8)
        w = imageio.get_writer(str(path), **kw)
        try:
            for i in idx:
                cap = None if times is None else f"t = {times[i]:.2f} s"
                T = None if tensions is None else tensions[i]
                w.append_data(r.render(nodes[i], structure.bars, structure.strings, T, ground_z=ground_z,
                                       caption=cap, tension_max=tmax, terrain=terrain))
        except BaseException:
            close_after_error(w)   # the writer's own error on close (ffmpeg's pipe) would hide this one
            raise
        w.close()
    finally:
        r.close()
    return len(idx)
