"""A recording's rods (:class:`RecordingGeometry`, a part of
:class:`~tensegrity_gym.io.recording.Recording`): each point's place along its rod, the rods'
end points fitted per frame and the node trajectory of a structure. SI units."""
from __future__ import annotations

import numpy as np

__all__ = ["RecordingGeometry"]


class RecordingGeometry:
    """The rods of a recording (a mixin: the recording holds ``t``, ``points``, ``point_rod``,
    ``point_along``, ``along`` and ``rod_lengths``)."""

    @property
    def n_rods(self) -> int:
        return int(self.rod_lengths.size)

    def fractions(self) -> np.ndarray:
        """(P,) each point's position along its rod as a fraction (0 at node a, 1 at node b)."""
        if self.along == "fraction":
            return np.array(self.point_along)
        return self.point_along / self.rod_lengths[self.point_rod]

    def rod_unposed(self) -> np.ndarray:
        """(F, k) True where a rod has fewer than two distinct points in a frame (its end points
        cannot be told from the tracked points)."""
        seen = ~np.isnan(self.points[..., 0])
        return np.stack([seen[:, self.point_rod == r].sum(axis=1) < 2 for r in range(self.n_rods)], axis=1)

    def end_points(self) -> np.ndarray:
        """(F, k, 2, 3) each rod's node a and node b, m, fitted by least squares to its points in
        each frame (exact for two points); NaN where :meth:`rod_unposed`. The fitted end points
        keep the tracked points' spacing, so they are not forced to the rod's length."""
        F, k = self.t.size, self.n_rods
        out = np.full((F, k, 2, 3), np.nan)
        s = self.fractions()
        for r in range(k):
            idx = np.flatnonzero(self.point_rod == r)
            x = self.points[:, idx]                              # (F, p, 3)
            v = ~np.isnan(x[..., 0])
            w0, w1 = np.where(v, 1.0 - s[idx], 0.0), np.where(v, s[idx], 0.0)
            a00, a01, a11 = (w0 * w0).sum(1), (w0 * w1).sum(1), (w1 * w1).sum(1)
            xz = np.where(v[..., None], x, 0.0)
            r0, r1 = (w0[..., None] * xz).sum(1), (w1[..., None] * xz).sum(1)
            det = a00 * a11 - a01 * a01
            ok = v.sum(1) >= 2
            with np.errstate(divide="ignore", invalid="ignore"):
                a = (a11[:, None] * r0 - a01[:, None] * r1) / det[:, None]
                b = (a00[:, None] * r1 - a01[:, None] * r0) / det[:, None]
            out[ok, r, 0], out[ok, r, 1] = a[ok], b[ok]
        return out

    def node_trajectory(self, bars, n_nodes: int | None = None):
        """``(t, nodes, mask)`` for a structure whose rod ``r`` joins nodes ``bars[r]`` (a, b):
        ``t`` (S,) the distinct time stamps, s; ``nodes`` (S, n, 3) the rods' end points, m
        (:meth:`end_points`), frames sharing a time stamp averaged over the rods seen in them;
        ``mask`` (S, n) True where a node is known. NaN where unknown; nothing is interpolated."""
        bars = np.asarray(bars, dtype=np.int64)
        if bars.shape != (self.n_rods, 2):
            raise ValueError(f"bars: shape {bars.shape}; the recording has {self.n_rods} rods, expected "
                             f"({self.n_rods}, 2) node indices")
        n = int(bars.max()) + 1 if n_nodes is None else int(n_nodes)
        if bars.min() < 0 or bars.max() >= n:
            raise ValueError(f"bars: node indices must be in 0..{n - 1}")
        ep = self.end_points()
        t, inv = np.unique(self.t, return_inverse=True)
        per = np.full((self.t.size, n, 3), np.nan)
        per[:, bars[:, 0]], per[:, bars[:, 1]] = ep[:, :, 0], ep[:, :, 1]
        known = ~np.isnan(per[..., 0])
        total = np.zeros((t.size, n, 3))
        count = np.zeros((t.size, n))
        np.add.at(total, inv, np.where(known[..., None], per, 0.0))
        np.add.at(count, inv, known)
        with np.errstate(invalid="ignore", divide="ignore"):
            nodes = total / count[..., None]
        return t, nodes, count > 0
