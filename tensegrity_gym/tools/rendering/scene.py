"""Pieces shared by the renderers and viewers: scene arrays, tension colours, the unavailability error."""
from __future__ import annotations

import numpy as np


class RendererUnavailable(RuntimeError):
    """No OpenGL backend (or no ``mujoco``) for :class:`MujocoRenderer`; the message says what was
    tried and what to install."""


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


def _tension_rgb(T: np.ndarray, tmax: float) -> np.ndarray:
    import matplotlib
    c = matplotlib.colormaps["turbo"](0.1 + 0.8 * np.clip(T / tmax, 0.0, 1.0))[:, :3]
    c[T <= 0] = (0.55, 0.56, 0.58)
    return (255 * c).astype(np.uint8)
