"""Helpers shared by the benchmark and analysis scripts (``scripts/*.py``): timing, the MuJoCo
translation of a free class-1 structure, and rod rotation vectors. Private: no API promise.

* :func:`timeit` -- best wall time (s) of one call, calls batched to about ``target`` s;
* :func:`timed` -- wall time of one run (best of 3 when the run is short);
* :func:`quat_z_to`, :func:`mj_float`, :func:`mjcf_rods`, :func:`mjcf` -- MJCF of free rods
  (one free body per rod, a site per node, one tension-only spatial tendon per string);
* :func:`mj_set_state`, :func:`mujoco_rollout_time` -- our state into MjData, and the
  per-env-step time of ``mujoco.rollout`` on all cores;
* :func:`rotation_vectors` -- best-fit rigid rotation between two node sets (Kabsch).
"""
from __future__ import annotations

import time

import numpy as np

__all__ = ["timeit", "timed", "quat_z_to", "mj_float", "mjcf_rods", "mjcf", "mj_set_state", "mujoco_rollout_time",
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


# ---------------------------------------------------------------------------- MuJoCo
def quat_z_to(z):
    """Unit quaternion (w, x, y, z) rotating the z axis onto the unit vector ``z``."""
    zz = np.array([0.0, 0.0, 1.0])
    c = float(zz @ np.asarray(z, float))
    if c < -1 + 1e-12:
        return np.array([0.0, 1.0, 0.0, 0.0])
    v = np.cross(zz, z)
    q = np.array([1.0 + c, *v])
    return q / np.linalg.norm(q)


def mj_float(x) -> str:
    """Shortest exact decimal form of a float for MJCF."""
    return repr(float(x))


def mjcf_rods(model, centres, axes, ends, dt, integrator="Euler", axial_inertia=1e-6, capsules=False,
              contact=True) -> str:
    """MJCF of the rods of ``model`` as free bodies without gravity: rod j at ``centres[j]`` (m),
    body z axis along the unit vector ``axes[j]``, thin-rod inertia (``model.J``, axial
    ``J * axial_inertia``), sites ``n<node>`` at body z = ``ends[j]`` (m, the two rod ends);
    one spatial tendon per string with ``springlength="0 l0"`` (tension only, no damping).
    ``capsules``: add a massless, non-colliding capsule per rod (for viewing); ``contact=False``
    disables MuJoCo's contact pass."""
    f = mj_float
    bodies = []
    for j in range(model.n_bars):
        a, c = int(model.rod_a[j]), int(model.rod_c[j])
        ctr, qt = centres[j], quat_z_to(axes[j])
        m, J = float(model.mass[j]), float(model.J[j])
        za, zc = float(ends[j][0]), float(ends[j][1])
        geom = (f'<geom type="capsule" fromto="0 0 {f(za)} 0 0 {f(zc)}" size="0.01" mass="0" '
                f'contype="0" conaffinity="0"/>') if capsules else ""
        bodies.append(
            f'<body name="rod{j}" pos="{f(ctr[0])} {f(ctr[1])} {f(ctr[2])}" '
            f'quat="{f(qt[0])} {f(qt[1])} {f(qt[2])} {f(qt[3])}"><freejoint/>'
            f'<inertial pos="0 0 0" mass="{f(m)}" diaginertia="{f(J)} {f(J)} {f(J * axial_inertia)}"/>'
            f'{geom}<site name="n{a}" pos="0 0 {f(za)}"/><site name="n{c}" pos="0 0 {f(zc)}"/></body>')
    tendons = []
    for i in range(model.n_strings):
        tendons.append(
            f'<spatial name="s{i}" stiffness="{f(float(model.stiffness[i]))}" damping="0" '
            f'springlength="0 {f(float(model.rest_length[i]))}"><site site="n{int(model.str_i[i])}"/>'
            f'<site site="n{int(model.str_j[i])}"/></spatial>')
    option = f'<option timestep="{f(dt)}" integrator="{integrator}" gravity="0 0 0"'
    option += '/>' if contact else '><flag contact="disable"/></option>'

    return (f'<mujoco>{option}<worldbody>{"".join(bodies)}</worldbody>'
            f'<tendon>{"".join(tendons)}</tendon></mujoco>')


def mjcf(model, integrator="Euler", dt=1e-3, axial_inertia=1e-6):
    """MJCF of a free class-1 structure (no anchors, no node constraints, no gravity, no damping)
    in its built configuration: each rod's body at its centre of mass (``sigma``), sites at the
    rod ends (``eta``), a viewing capsule per rod (see :func:`mjcf_rods`)."""
    if model.anchor_idx.size or model.constrained.any() or model.has_gravity or model.has_damping:
        raise ValueError("mjcf(): only free, undamped structures without gravity are translated")
    s = model.structure
    centres, axes, ends = [], [], []
    for j in range(model.n_bars):
        pa, pc = s.nodes[int(model.rod_a[j])], s.nodes[int(model.rod_c[j])]
        L = float(np.linalg.norm(pc - pa))
        centres.append(pa + model.sigma[j] * (pc - pa))
        axes.append((pc - pa) / L)
        ends.append((float(model.eta[j, 0]), float(model.eta[j, 1])))
    return mjcf_rods(model, centres, axes, ends, dt, integrator, axial_inertia, capsules=True)


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
