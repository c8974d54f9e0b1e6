"""Helpers shared by the benchmark and analysis scripts (``scripts/*.py``, which import it as a
sibling module: ``from _bench import timeit``): timing, MuJoCo state and rollout timing, and rod
rotation vectors. Not part of the installed package.

* :func:`timeit` -- best wall time (s) of one call, calls batched to about ``target`` s;
* :func:`timed` -- wall time of one run (best of 3 when the run is short);
* :func:`sync` -- wait for the work queued on a torch device (CUDA), before a host clock is read;
* :func:`quat_z_to` -- the quaternion of a rod body; :func:`mjcf` -- the MJCF of a structure
  (:func:`tensegrity_gym.io.mjcf.to_mjcf`);
* :func:`mj_set_state`, :func:`mujoco_rollout_time` -- our state into MjData, and the
  per-env-step time of ``mujoco.rollout`` on all cores;
* :func:`rotation_vectors` -- best-fit rigid rotation between two node sets (Kabsch).
"""
from __future__ import annotations

import time

import numpy as np

from tensegrity_gym.io.mjcf import to_mjcf

__all__ = ["timeit", "timed", "sync", "quat_z_to", "mjcf", "mj_set_state", "mujoco_rollout_time", "rotation_vectors"]


# ---------------------------------------------------------------------------- timing
def timeit(fn, target=0.15, repeats=3, max_single=2.0):
    """Best wall time (s) of one call of ``fn`` over ``repeats`` runs of about ``target`` s each.
    Returns None when one call takes longer than ``max_single`` s (too slow to time)."""
    t0 = time.perf_counter()
    fn()                                      # warm up (compilation, caches)
    first = time.perf_counter() - t0
    if first > max_single:
        return None
    n = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        el = time.perf_counter() - t0
        if el >= target / 5 or n >= 1 << 22:
            break
        n *= 4
    n = max(1, int(n * target / max(el, 1e-9)))
    best = el / max(n, 1) if n == 1 else float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def timed(fn, wall_min=0.2):
    """Run ``fn`` (returns its result); wall time in s, best of 3 when a run is shorter than
    ``wall_min`` s (noise of a shared machine). Returns (result of the first run, wall time)."""
    t0 = time.perf_counter()
    out = fn()
    wall = time.perf_counter() - t0
    if wall < wall_min:
        for _ in range(2):
            t0 = time.perf_counter()
            fn()
            wall = min(wall, time.perf_counter() - t0)
    return out, wall


# ---------------------------------------------------------------------------- MuJoCo
def sync(device) -> None:
    """Wait for the work queued on the torch ``device`` (a CUDA device; a CPU runs its work as it
    is called), so that a host clock read after it times that work."""
    import torch
    d = torch.device(device)
    if d.type == "cuda":
        torch.cuda.synchronize(d)


def quat_z_to(z):
    """Unit quaternion (w, x, y, z) rotating the z axis onto the unit vector ``z``."""
    zz = np.array([0.0, 0.0, 1.0])
    c = float(zz @ np.asarray(z, float))
    if c < -1 + 1e-12:
        return np.array([0.0, 1.0, 0.0, 0.0])
    v = np.cross(zz, z)
    q = np.array([1.0 + c, *v])
    return q / np.linalg.norm(q)


def mjcf(model, integrator="Euler", dt=1e-3) -> str:
    """MJCF of the structure of ``model`` in its built configuration: the package's one MJCF
    writer (:func:`tensegrity_gym.io.mjcf.to_mjcf`: a free rod is a body at its centre of mass
    with z along the rod, sites ``node<i>`` at the rod ends, a tension-only tendon per string)."""
    return to_mjcf(model.structure, timestep=dt, integrator=integrator)


def mj_set_state(mujoco, mm, d, model, q, qd):
    """Put our configuration q, qd (k, 6) of one copy into MjData (free joints)."""
    for j in range(model.n_bars):
        adr, vadr = mm.jnt_qposadr[j], mm.jnt_dofadr[j]
        r, b = q[j, :3], q[j, 3:]
        rd, bd = qd[j, :3], qd[j, 3:]
        d.qpos[adr:adr + 3] = r
        d.qpos[adr + 3:adr + 7] = quat_z_to(b / np.linalg.norm(b))
        R = _quat_to_mat(d.qpos[adr + 3:adr + 7])
        omega_world = np.cross(b, bd)                   # b' = omega x b with omega . b = 0
        d.qvel[vadr:vadr + 3] = rd
        d.qvel[vadr + 3:vadr + 6] = R.T @ omega_world   # free joint: angular velocity in body frame
    mujoco.mj_forward(mm, d)


def _quat_to_mat(qt):
    w, x, y, z = qt
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def mujoco_rollout_time(mujoco, rollout, mm, d, B, target=0.15, repeats=3, nthread=None, nstep=4):
    """Seconds per env-step of ``mujoco.rollout`` (MuJoCo's fastest batched CPU path) stepping B
    copies of ``d``'s state ``nstep`` steps with one MjData per thread (``nthread``: default all
    cores), timed with :func:`timeit`; None when one call is too slow to time."""
    import os
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    x0 = np.empty(mujoco.mj_stateSize(mm, spec))
    mujoco.mj_getState(mm, d, x0, spec)
    datas = [mujoco.MjData(mm) for _ in range(nthread or os.cpu_count() or 1)]
    init = np.tile(x0, (B, 1))
    out_state = np.empty((B, nstep, x0.size))
    t = timeit(lambda: rollout.rollout(mm, datas, init, nstep=nstep, state=out_state, persistent_pool=True),
               target, repeats)
    return None if t is None else t / (B * nstep)


# ---------------------------------------------------------------------------- rigid rotations
def rotation_vectors(prev: np.ndarray, cur: np.ndarray) -> np.ndarray:
    """Rotation vectors (B, 3), rad, of the best-fit rotations ``R`` with ``cur[b] ~ prev[b] @ R.T``
    (Kabsch; ``prev``, ``cur`` (B, n, 3) node positions about their centroids, m)."""
    from scipy.spatial.transform import Rotation
    U, _, Vt = np.linalg.svd(np.einsum("bni,bnj->bij", prev, cur))
    V, Ut = np.swapaxes(Vt, 1, 2), np.swapaxes(U, 1, 2)
    D = np.tile(np.eye(3), (len(prev), 1, 1))
    D[:, 2, 2] = np.sign(np.linalg.det(V @ Ut))      # a rotation, not a reflection
    return Rotation.from_matrix(V @ D @ Ut).as_rotvec()
