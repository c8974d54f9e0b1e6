"""Local coordinates of a class-1 tensegrity's configuration space (statics, system identification).

Pure NumPy, batched over a leading axis B, SI units (m, N).

A configuration ``q`` (B, k, 6) = ``[r, b]`` (see :mod:`tensegrity_gym.core.model`) is charted
around a point ``(r0, b0)`` by the local coordinates ``x = (z, u)`` with ``r = r0 + E z`` and
``b = normalize(b0 + T u / l)`` (both in m): ``E_j`` (3, d_j) spans the allowed motion of rod
j's reference point (d = 3 free rod, 2 on a plane, 1 on a line, 0 pinned) and ``T_j`` (3, 2)
(:func:`tangent_basis`) spans the plane normal to ``b_j``, so ``nx = sum_j (d_j + 2)``. The chart
has no singularity at the point it is built on and keeps ``|b| = 1`` and the node constraints
exactly, which is why the equilibrium solver and the system identification's window states
work in it. :class:`ReducedCoordinates` maps local coordinates (and rates) to configurations
(and states) and nodal forces (N) to the generalized forces conjugate to ``x``.
"""
from __future__ import annotations

import numpy as np

from ..core.model import Model

__all__ = ["ReducedCoordinates", "tangent_basis"]


def tangent_basis(b: np.ndarray) -> np.ndarray:
    """(..., 3, 2) orthonormal basis of the plane normal to each rod direction ``b`` (..., 3)
    (any length): ``t1 = b x e / |b x e|`` with ``e`` the axis along b's smallest component,
    ``t2 = b x t1``. The one chart of the rods' directions (statics, stability, sysid)."""
    bn = b / np.linalg.norm(b, axis=-1, keepdims=True)
    helper = np.zeros_like(bn)
    ax = np.argmin(np.abs(bn), axis=-1)
    np.put_along_axis(helper, ax[..., None], 1.0, axis=-1)
    t1 = np.cross(bn, helper)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    t2 = np.cross(bn, t1)
    return np.stack([t1, t2], axis=-1)


class ReducedCoordinates:
    """Local coordinates ``x = (z, u)`` of a model's configuration space (see the module doc)."""

    def __init__(self, model: Model):
        self.model = model
        E_rows, z_rod = [], []
        for j in range(model.n_bars):
            w, V = np.linalg.eigh(model.proj[j])
            for c in range(3):
                if w[c] > 0.5:
                    E_rows.append(V[:, c])
                    z_rod.append(j)
        self.E = np.array(E_rows, float).reshape(-1, 3)       # (dz, 3)
        self.z_rod = np.array(z_rod, dtype=int)               # (dz,)
        self.dz = len(z_rod)
        self.nx = self.dz + 2 * model.n_bars

    tangent_basis = staticmethod(tangent_basis)   # the module's chart, as rc.tangent_basis

    def retract(self, q: np.ndarray, T: np.ndarray, dx: np.ndarray) -> np.ndarray:
        """Configuration at local coordinates ``dx`` (B, nx) around ``q`` (B, k, 6), chart ``T``."""
        m = self.model
        r = q[..., :3].copy()
        if self.dz:
            np.add.at(r, (slice(None), self.z_rod), dx[:, : self.dz, None] * self.E[None])
        u = dx[:, self.dz:].reshape(q.shape[0], m.n_bars, 2) / m.length[None, :, None]
        b = q[..., 3:] + np.einsum("bkid,bkd->bki", T, u)
        b /= np.linalg.norm(b, axis=-1, keepdims=True)
        return np.concatenate([r, b], axis=-1)

    def perturb(self, q: np.ndarray, dx: np.ndarray, dv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State ``(q, qd)`` (B, k, 6) at local coordinates ``dx`` (B, nx) around ``q`` moving at the
        local rates ``dv`` (B, nx) (m and m/s: ``z`` along the free directions of constrained
        reference points, ``u`` the rod ends' sideways offsets), before projection."""
        m = self.model
        T = self.tangent_basis(q[..., 3:])
        qn = self.retract(q, T, dx)
        qd = np.zeros_like(qn)
        if self.dz:
            np.add.at(qd[..., :3], (slice(None), self.z_rod), dv[:, : self.dz, None] * self.E[None])
        u = dv[:, self.dz:].reshape(q.shape[0], m.n_bars, 2) / m.length[None, :, None]
        qd[..., 3:] = np.einsum("bkid,bkd->bki", T, u)
        return qn, qd

    def project_forces(self, q: np.ndarray, F: np.ndarray, T: np.ndarray | None = None) -> np.ndarray:
        """Generalized forces (B, nx), N, of nodal forces F (B, n, 3) (or (B, n, 3, c) -> (B, nx, c))."""
        m = self.model
        if T is None:
            T = self.tangent_basis(q[..., 3:])
        Fa, Fc = F[:, m.rod_a], F[:, m.rod_c]
        extra = F.shape[3:]
        shp = (1, m.n_bars, 1) + (1,) * len(extra)
        fr = Fa + Fc
        fb = (m.eta[:, 0].reshape(shp) * Fa + m.eta[:, 1].reshape(shp) * Fc) / m.length.reshape(shp)
        # exact conjugate force of the chart b = normalize(b0 + T u / l): T^T P(b) f_b (P(b) matters
        # when T belongs to a nearby b0, as in the finite-difference Jacobian: the rods' axial force
        # then gives the geometric-stiffness term)
        bn = q[..., 3:] / np.linalg.norm(q[..., 3:], axis=-1, keepdims=True)
        bn = bn.reshape(bn.shape + (1,) * len(extra))
        fb = fb - bn * np.sum(bn * fb, axis=2, keepdims=True)
        if extra:
            Rz = np.einsum("zi,bzi...->bz...", self.E, fr[:, self.z_rod])
            Rt = np.einsum("bkid,bki...->bkd...", T, fb).reshape((F.shape[0], 2 * m.n_bars) + extra)
        else:
            Rz = np.einsum("zi,bzi->bz", self.E, fr[:, self.z_rod])
            Rt = np.einsum("bkid,bki->bkd", T, fb).reshape(F.shape[0], 2 * m.n_bars)
        return np.concatenate([Rz, Rt], axis=1)


def _coords(model: Model, cache={}) -> ReducedCoordinates:  # noqa: B006 - per-model cache
    key = id(model)
    rc = cache.get(key)
    if rc is None or rc.model is not model:
        rc = ReducedCoordinates(model)
        cache.clear() if len(cache) > 64 else None
        cache[key] = rc
    return rc
