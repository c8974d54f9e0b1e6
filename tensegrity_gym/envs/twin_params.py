"""How the robot parameters of ``TensegrityRoll-v0`` reach the MuJoCo twin's ``MjModel``
(:mod:`tensegrity_gym.envs.roll_mujoco`). SI units.

The twin's :class:`~tensegrity_gym.envs.roll.RollTask` draws or fixes the values
(:mod:`tensegrity_gym.envs.domain`, ``params=`` / ``randomize=``), exactly as ``TensegrityRoll-v0``.
A twin built with ``params=`` set to the reported values runs the same trajectory as the
randomised one. At each reset, before the state is set, :meth:`TwinParams.apply` writes the values
into the ``MjModel`` (then ``mj_setConst``, so MuJoCo's constants that depend on the masses follow):

==========================  ===============================================================
name (SI unit)              MuJoCo field
==========================  ===============================================================
``rod_mass`` (kg)           ``body_mass`` of the rod; ``body_inertia`` scaled by the same
                            factor (the mass distribution keeps its shape); the contact's
                            effective mass m_eff (below) follows the lightest rod
``stiffness`` (N/m)         ``tendon_stiffness``
``damping`` (N s/m)         ``tendon_damping`` (acts slack or taut: :mod:`~tensegrity_gym.envs.roll_mujoco`)
``rest_length_offset`` (m)  added to ``tendon_lengthspring[:, 1]``: the nominal rest length
                            of passive strings, the motor's rest length of actuated ones
                            (rewritten every control step)
``gravity`` (m/s^2)         ``opt.gravity``
``friction`` (1)            ``geom_friction[:, 0]`` of every geom (rods and every terrain part)
``ground_stiffness`` (N/m)  ``geom_solref[:, 0]`` = timeconst = ``sqrt(m_eff / k)`` (floored at
                            2 steps), m_eff = a quarter of the lightest rod mass
``ground_damping`` (s/m)    ``geom_solref[:, 1]`` = dampratio = ``contact_dampratio`` x
                            ``ground_damping`` / the env's nominal ``ground_damping``: the
                            Hunt-Crossley damping ratio at a given penetration is proportional
                            to it, MuJoCo's has no penetration dependence, so only the
                            relative change is carried (refused if the nominal value is 0)
``max_cable_speed`` (m/s),  the cable motor model (:class:`~tensegrity_gym.physics.actuation.Actuation`,
``max_cable_acceleration``  shared with ``TensegrityRoll-v0``), not MuJoCo
==========================  ===============================================================

``node_damping`` is refused (ValueError): MuJoCo damps the DOFs of a rod's free joint (centre of
mass translation, body-frame rotation), not its end nodes; a viscous force at each end node on
the axis has no exact counterpart.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.param_table import twin_params, twin_refusals

__all__ = ["TWIN_PARAMS", "NOT_REPRESENTABLE", "check_twin_kwargs", "contact_timeconst", "TwinParams"]

#: robot parameters (envs/domain.py SPECS) the twin represents (module doc: the MuJoCo fields), and
#: those it refuses, with the reason: views of the parameter table (its ``mujoco`` / ``no_mujoco``)
TWIN_PARAMS = twin_params()
NOT_REPRESENTABLE = twin_refusals()


def check_twin_kwargs(kwargs: dict, env_id: str) -> None:
    """ValueError naming ``params[name]`` / ``randomize[name]`` for a parameter the twin cannot represent."""
    refused = twin_refusals()
    for arg in ("params", "randomize"):
        d = kwargs.get(arg)
        for name in (d if isinstance(d, dict) else ()):
            if name in refused:
                raise ValueError(f"{arg}[{name!r}]: {env_id} cannot represent it ({refused[name]}); "
                                 f"it takes {list(twin_params())}")


def contact_timeconst(rod_mass_min: float, ground_stiffness: float, dt: float) -> float:
    """MuJoCo ``solref`` time constant, s: ``sqrt(m_eff / k)`` with m_eff = a quarter of the lightest
    rod mass (kg), k the ground stiffness (N/m), floored at 2 steps of ``dt`` (MuJoCo's safety limit)."""
    return max(math.sqrt(rod_mass_min / 4.0 / ground_stiffness), 2.0 * dt)


class TwinParams:
    """The nominal ``MjModel`` fields of the rod bodies ``body`` and of the tendons, and the writer
    of one episode's values into the model (module doc: the mapping).

    ``contact``: the task's :class:`~tensegrity_gym.physics.contact.GroundContact` (nominal friction, ground
    stiffness and damping); ``dampratio``: the twin's nominal contact damping ratio;
    ``carries_ground_damping``: whether ``params`` / ``randomize`` set ``ground_damping`` (refused
    when the nominal ground damping is 0: only its relative change is carried)."""

    def __init__(self, m, body: np.ndarray, contact, dt: float, dampratio: float, env_id: str,
                 carries_ground_damping: bool = False):
        if contact.damping == 0 and carries_ground_damping:
            raise ValueError(f"ground_damping: {env_id} carries it as a change relative to the env's nominal "
                             f"ground_damping, which is 0 here")
        self.body, self.contact, self.dt, self.dampratio = body, contact, float(dt), float(dampratio)
        self.mass, self.inertia = m.body_mass[body].copy(), m.body_inertia[body].copy()
        self.stiffness, self.damping = m.tendon_stiffness.copy(), m.tendon_damping.copy()
        self.rest_length, self.gravity = m.tendon_lengthspring[:, 1].copy(), m.opt.gravity.copy()

    def apply(self, mujoco, m, data, values: dict) -> tuple[np.ndarray, float]:
        """Write ``values`` (name -> one copy's value, SI) into ``m``, then ``mj_setConst``.
        Returns (the tendons' rest-length offsets (m,), m; the contact time constant, s)."""
        c = self.contact
        mass = np.asarray(values.get("rod_mass", self.mass), float)
        m.body_mass[self.body] = mass
        m.body_inertia[self.body] = self.inertia * (mass / self.mass)[:, None]
        m.tendon_stiffness[:] = values.get("stiffness", self.stiffness)
        m.tendon_damping[:] = values.get("damping", self.damping)
        offset = np.asarray(values.get("rest_length_offset", np.zeros(m.ntendon)), float)
        m.tendon_lengthspring[:, 1] = self.rest_length + offset
        m.opt.gravity[:] = values.get("gravity", self.gravity)
        if "friction" in values:   # else each geom keeps its own (a terrain's parts may differ)
            m.geom_friction[:, 0] = float(values["friction"])
        tc = contact_timeconst(float(mass.min()), float(values.get("ground_stiffness", c.stiffness)), self.dt)
        ratio = float(values["ground_damping"]) / c.damping if "ground_damping" in values else 1.0
        m.geom_solref[:] = (tc, self.dampratio * ratio)
        mujoco.mj_setConst(m, data)
        return offset, tc
