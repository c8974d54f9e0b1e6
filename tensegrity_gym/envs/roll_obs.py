"""The state observation of TensegrityRoll-v0 (a mixin of :class:`~tensegrity_gym.envs.roll.RollTask`):
node positions relative to the centre of mass, node velocities, controls, contact flags, goal,
height and cable speeds, in one compiled pass (:func:`tensegrity_gym.envs.compiled.roll_observe`;
its NumPy reference is the test oracle ``tests/oracle_numpy.py``). SI units."""
from __future__ import annotations

import numpy as np

from ..core.model import Model
from ..physics import geometry
from ..tasks.roll import center_of_mass
from . import compiled

__all__ = ["RollObservation"]


class RollObservation:
    """``observe``, ``observation_layout`` and the centre of mass of the roll task; the task sets
    ``q``, ``qd``, ``ctrl``, ``speed``, ``goal``, ``cstate``, ``sensors`` and the sizes."""

    def _init_observation(self, model: Model) -> None:
        """node -> (rod, signed distance from the rod's reference point) maps, the rods' mass fractions."""
        n, k = model.n_nodes, model.n_bars
        self._node_rod_i64 = np.empty(n, np.int64)
        self._node_rod_i64[model.rod_a] = np.arange(k)
        self._node_rod_i64[model.rod_c] = np.arange(k)
        self._node_eta_1d = np.empty(n)
        self._node_eta_1d[model.rod_a] = model.eta[:, 0]
        self._node_eta_1d[model.rod_c] = model.eta[:, 1]
        self._com_at_r = bool(np.all(model.com_eta == 0.0))
        self._mass_frac = model.mass / model.mass.sum()

    def com(self, q) -> np.ndarray:
        """(B, 3) centre of mass of the robots ``q`` (B, k, 6), m (= physics.geometry.center_of_mass,
        one matrix product; the record's ``com``, :mod:`tensegrity_gym.tasks.state`)."""
        if self._com_at_r:
            return center_of_mass(q, self._mass_frac)
        return geometry.center_of_mass(self.model, q, self.params)

    _com = com

    def observe(self) -> np.ndarray:
        B = self.num_envs
        if self.sensors is not None:
            return self._readings.reshape(B, -1).astype(np.float32)
        obs = np.empty((B, self._state_size), np.float32)
        compiled.roll_observe(self.q, self.qd, self._node_rod_i64, self._node_eta_1d, self._com(self.q), self.ctrl,
                              self.cstate.active, self.goal, self.speed, obs)
        return self.observe_task(self, obs)

    def observation_layout(self) -> list[tuple[str, slice, str]]:
        """(name, slice, unit) of each block of the observation vector (robot mode: of the newest
        reading; the ``history - 1`` older readings follow it in the same layout)."""
        if self.sensors is not None:
            return self.sensors.layout()
        n, na = self.model.n_nodes, self.actuated.size
        blocks = [("node_position_rel_com", 3 * n, "m"), ("node_velocity", 3 * n, "m/s"),
                  ("control", na, self.actuation.unit), ("contact", self.n_contacts, "1"),
                  ("goal_direction", 2, "1"), ("com_height", 1, "m")]
        if self.n_speed:
            blocks.append(("cable_speed", self.n_speed, "m/s"))
        out, i = [], 0
        for name, sz, unit in blocks:
            out.append((name, slice(i, i + sz), unit))
            i += sz
        return out
