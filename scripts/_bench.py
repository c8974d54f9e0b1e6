"""Helpers shared by the benchmark and analysis scripts (``scripts/<group>/*.py``, run from the
repository root as ``python -m scripts.<group>.<name>``, which import ``from scripts._bench import
timeit``): the one benchmark harness (timing, torch device sync), MuJoCo state and rollout timing, and rod
rotation vectors. Not part of the installed package.

* :func:`timeit` -- best wall time (s) of one call, calls batched to about ``target`` s;
* :func:`timed` -- wall time of one run (best of 3 when the run is short);
* :func:`best_of` -- least wall time of ``repeats`` runs of a call (optional untimed setup);
* :func:`interleaved_reps`, :func:`interleaved_windows` -- best time per call of several callables
  timed in turn, round by round (fixed call counts, or time windows), so that a load change on a
  shared machine hits them alike;
* :func:`sync` -- wait for the work queued on a torch device (CUDA), before a host clock is read;
* :func:`mjcf` -- the MJCF of a structure (:func:`tensegrity_gym.io.mjcf.to_mjcf`);
* :func:`mj_set_state`, :func:`mj_node_positions`, :func:`mujoco_rollout_time` -- our state into
  MjData (the package's mapping), MuJoCo's node positions, and the per-env-step time of
  ``mujoco.rollout`` on all cores;
* :func:`rotation_vectors` -- best-fit rigid rotation between two node sets (Kabsch).
"""
from __future__ import annotations

import time

import numpy as np

from tensegrity_gym.io.mjcf import initial_qpos_qvel, to_mjcf
from tensegrity_gym.physics.geometry import node_positions, node_velocities

__all__ = ["timeit", "timed", "best_of", "interleaved_reps", "interleaved_windows", "sync", "mjcf", "mj_set_state", "mj_node_positions", "mujoco_rollout_time",
           "rotation_vectors"]


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


def best_of(fn, repeats, setup=None, calls=1, warmup=True):
    """Least wall time (s) per call of ``fn`` over ``repeats`` runs of ``calls`` calls each (after one
    untimed warm-up call). With ``setup``, each run first calls ``setup()`` (untimed) and passes its
    result to every call of ``fn``."""
    if warmup:
        fn(setup()) if setup is not None else fn()
    best = float("inf")
    for _ in range(repeats):
        args = () if setup is None else (setup(),)
        t0 = time.perf_counter()
        for _ in range(calls):
            fn(*args)
        best = min(best, (time.perf_counter() - t0) / calls)
    return best


def interleaved_reps(fns: dict, rounds: int) -> dict:
    """Best seconds per call of each zero-argument function (``{name: (fn, calls per round)}``),
    the functions timed in turn, round by round."""
    best = {k: float("inf") for k in fns}
    for _ in range(rounds):
        for k, (fn, reps) in fns.items():
            t0 = time.perf_counter()
            for _ in range(reps):
                fn()
            best[k] = min(best[k], (time.perf_counter() - t0) / reps)
    return best


def interleaved_windows(fns: dict, seconds: float, rounds: int = 5) -> dict:
    """Mean time (s) per call of each callable: ``rounds`` rounds, each giving every callable a
    window of ``seconds / rounds`` in turn; the best round of each is kept. A callable may return
    the duration of its own timed part (s); otherwise the wall time of the call counts."""
    for fn in fns.values():
        fn()
    best = {k: float("inf") for k in fns}
    win = seconds / rounds
    for _ in range(rounds):
        for k, fn in fns.items():
            tot, n = 0.0, 0
            while tot < win:
                t0 = time.perf_counter()
                r = fn()
                tot += (time.perf_counter() - t0) if r is None else r
                n += 1
            best[k] = min(best[k], tot / n)
    return best


# ---------------------------------------------------------------------------- MuJoCo
def sync(device) -> None:
    """Wait for the work queued on the torch ``device`` (a CUDA device; a CPU runs its work as it
    is called), so that a host clock read after it times that work."""
    import torch
    d = torch.device(device)
    if d.type == "cuda":
        torch.cuda.synchronize(d)


def mjcf(model, integrator="Euler", dt=1e-3) -> str:
    """MJCF of the structure of ``model`` in its built configuration: the package's one MJCF
    writer (:func:`tensegrity_gym.io.mjcf.to_mjcf`: a free rod is a body at its centre of mass
    with z along the rod, sites ``node<i>`` at the rod ends, a tension-only tendon per string)."""
    return to_mjcf(model.structure, timestep=dt, integrator=integrator)


def mj_set_state(mujoco, mm, d, model, q, qd):
    """Put our configuration q, qd (k, 6) of one copy into MjData of :func:`mjcf`'s model: the
    package's mapping (:func:`tensegrity_gym.io.mjcf.initial_qpos_qvel` at our node positions and
    velocities)."""
    N = node_positions(model, np.asarray(q)[None])[0]
    V = node_velocities(model, np.asarray(qd)[None])[0]
    d.qpos[:], d.qvel[:] = initial_qpos_qvel(model.structure.replace(nodes=N, velocities=V))
    mujoco.mj_forward(mm, d)


def mj_node_positions(mujoco, mm, d, n_nodes):
    """(n, 3) node positions, m, of :func:`mjcf`'s model in ``d`` (its sites ``node<i>``)."""
    return np.array([d.site(f"node{i}").xpos for i in range(n_nodes)])


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
