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


# ---------------------------------------------------------------------- terrain
def _check_terrain(terrain):
    """``terrain`` if None or a :class:`~tensegrity_gym.core.terrain.Terrain`; ValueError otherwise."""
    from ...core.terrain import Terrain
    if terrain is not None and not isinstance(terrain, Terrain):
        raise ValueError(f"terrain: expected a tensegrity_gym.core.terrain.Terrain or None, got "
                         f"{type(terrain).__name__}")
    return terrain


def _plane_height(plane, x, y):
    """Height (m) of a terrain plane at (x, y) m (the plane alone: :meth:`Terrain.height_at`)."""
    from ...core.terrain import Terrain
    return Terrain(plane=plane).height_at(x, y)


def _box_faces(box) -> np.ndarray:
    """(6, 4, 3) corner points (m) of the faces of a terrain box, from its centre, half sizes and
    :attr:`~tensegrity_gym.core.terrain.Box.rotation`."""
    s = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                  [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], float)
    corners = box.center + (s * box.size / 2) @ box.rotation.T
    faces = [(0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    return corners[np.array(faces)]


def _heightfield_grid(hf, max_points: int = 80):
    """``(X, Y, Z)`` (ny', nx') of a heightfield's grid (m), every stride-th point so that no side
    has more than ``max_points`` (the last row and column kept)."""
    ny, nx = hf.heights.shape
    iy = np.unique(np.r_[np.arange(0, ny, max(1, -(-ny // max_points))), ny - 1])
    ix = np.unique(np.r_[np.arange(0, nx, max(1, -(-nx // max_points))), nx - 1])
    X, Y = np.meshgrid(hf.origin[0] + ix * hf.cell, hf.origin[1] + iy * hf.cell)
    return X, Y, hf.heights[np.ix_(iy, ix)]


def _heightfield_mesh(hf, max_points: int = 200):
    """``(vertices (V, 3) m, faces (F, 3) int)``: two triangles per cell of :func:`_heightfield_grid`."""
    X, Y, Z = _heightfield_grid(hf, max_points)
    ny, nx = X.shape
    v = np.stack([X, Y, Z], axis=-1).reshape(-1, 3)
    i = (np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([i, i + 1, i + nx + 1], 1), np.stack([i, i + nx + 1, i + nx], 1)])
    return v, faces.astype(np.int32)
