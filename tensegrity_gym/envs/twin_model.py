"""The MuJoCo side of the twins (:mod:`tensegrity_gym.envs.roll_mujoco`, whose module doc says how
the twin models the robot): the scene compiled with the twin's contact, the damping of the rods'
spin and the bound MuJoCo's ``RK4`` puts on it, the robot settled on MuJoCo's ground, and MuJoCo's
state read in the project's terms (rod coordinates, end-cap contacts, tendon tensions). The env
holds the task and the Gym API. SI units (m, kg, s, N).
"""
from __future__ import annotations

import numpy as np

__all__ = ["RK4_DAMPING_BOUND", "compile_scene", "rk4_spin_damping_max", "spin_damping_for", "settle",
           "rod_state", "contact_flags", "tendon_tension"]

#: classical RK4's stability bound on the negative real axis: a damping rate c / I integrates
#: stably for dt c / I up to this
RK4_DAMPING_BOUND = 2.785


def compile_scene(mujoco, xml: str, timeconst: float, dampratio: float):
    """The ``MjModel`` of ``xml`` with the twin's contact: elliptic friction cone, ``solref`` of
    every geom ``(timeconst (s), dampratio)``."""
    m = mujoco.MjModel.from_xml_string(xml)
    m.opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    m.geom_solref[:] = (timeconst, dampratio)
    return m


def rk4_spin_damping_max(model, body: np.ndarray, dt: float) -> float:
    """The largest spin damping (N m s) the twin takes with MuJoCo's ``RK4`` at step ``dt`` (s): half
    of the explicit bound ``RK4_DAMPING_BOUND * I / dt`` (I the smallest axial inertia of the rod
    bodies ``body``, kg m^2; the half leaves room for randomised rod masses)."""
    axial = float(model.body_inertia[body, 2].min())
    return 0.5 * RK4_DAMPING_BOUND * axial / dt


def spin_damping_for(value, integrator: str, rk4_max: float, dt: float) -> float:
    """``spin_damping`` (N m s) for ``integrator``: ``value`` (with ``RK4``, checked against
    ``rk4_max``, :func:`rk4_spin_damping_max` at step ``dt`` (s)), or the default (None: 1.0, with
    ``RK4`` ``rk4_max``)."""
    if integrator != "RK4":
        return 1.0 if value is None else float(value)
    if value is None:
        return rk4_max
    if value > rk4_max:
        raise ValueError(f"spin_damping: {value!r} N m s is beyond what mj_integrator='RK4' integrates "
                         f"stably at dt = {dt} s (RK4 integrates joint damping explicitly; at most "
                         f"{rk4_max:.4g} N m s for the rods' axial inertia); pass spin_damping <= {rk4_max:.4g} or "
                         f"use mj_integrator 'implicitfast', 'implicit' or 'Euler'")
    return float(value)


def settle(mujoco, model, data, qpos: np.ndarray, rod_mass_max: float, dof: np.ndarray, spin_damping: float,
           duration: float, dt: float) -> None:
    """Let the robot settle on MuJoCo's ground from ``qpos``: ``duration`` (s) of steps ``dt`` (s)
    with viscous drag on the rods (4 ``rod_mass_max`` (kg) per s, as the project's tasks settle
    it; with ``RK4``, whose damping is explicit, the spin's drag held to ``spin_damping``); then the
    drag removed, each rod's spin damped by ``spin_damping`` (N m s; ``dof``: the first dof of each
    rod's free joint) and the velocities zeroed."""
    mujoco.mj_resetData(model, data)
    data.qpos[:] = qpos
    drag = 4.0 * rod_mass_max
    model.dof_damping[:] = drag   # N s/m (N m s on the rotations)
    if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
        model.dof_damping[dof + 5] = min(drag, spin_damping)
    for _ in range(int(round(duration / dt))):
        mujoco.mj_step(model, data)
    model.dof_damping[:] = 0.0
    model.dof_damping[dof + 5] = spin_damping   # free joint dof 5: rotation about the body z = rod axis
    data.qvel[:] = 0.0
    mujoco.mj_forward(model, data)


def rod_state(data, body: np.ndarray, dof: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's state ``data`` as the project's rod coordinates: ``q`` (1, k, 6) = [r (m), b (unit)],
    ``qd`` (1, k, 6) = [r' (m/s), b' (1/s)] (r: the rod body's origin = its centre of mass; ``body``
    the rod bodies' ids, ``dof`` the first dof of each one's free joint)."""
    R = data.xmat[body].reshape(-1, 3, 3)
    b = R[:, :, 2]
    v = data.qvel[dof[:, None] + np.arange(6)]
    omega = np.einsum("kij,kj->ki", R, v[:, 3:])        # body-frame angular velocity -> world
    q = np.concatenate([data.xpos[body], b], axis=1)[None]
    qd = np.concatenate([v[:, :3], np.cross(omega, b)], axis=1)[None]
    return q, qd


def contact_flags(data, q: np.ndarray, rod_of_geom: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """(2k,) bool: end cap touching the ground in MuJoCo's current contacts (rod 0 end a, rod 0
    end c, ...); a contact belongs to the end of its rod nearest to its point. ``q`` (k, 6) the rod
    coordinates, ``rod_of_geom`` (ngeom,) each geom's rod (-1: none), ``eta`` (k, 2) the ends' offsets
    from the reference point, m."""
    out = np.zeros(2 * len(q), bool)
    n = data.ncon
    if n:
        geom = data.contact.geom[:n]
        rod = np.maximum(rod_of_geom[geom[:, 0]], rod_of_geom[geom[:, 1]])
        ok = (rod >= 0) & (data.contact.dist[:n] <= 0.0)
        pos, rod = data.contact.pos[:n][ok], rod[ok]
        along = np.einsum("ci,ci->c", pos - q[rod, :3], q[rod, 3:])
        end = (np.abs(along - eta[rod, 1]) < np.abs(along - eta[rod, 0])).astype(int)
        out[2 * rod + end] = True
    return out


def tendon_tension(model, data) -> np.ndarray:
    """(m,) force each tendon applies as MuJoCo computes it, N (positive: pulling): ``k (L - l0)``
    above the rest length, 0 below it (dead band), plus ``c L'`` at any length."""
    L, spring = data.ten_length, model.tendon_lengthspring
    stretch = np.maximum(L - spring[:, 1], 0.0) - np.maximum(spring[:, 0] - L, 0.0)
    return model.tendon_stiffness * stretch + model.tendon_damping * data.ten_velocity
