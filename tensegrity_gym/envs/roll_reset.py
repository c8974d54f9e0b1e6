"""The rolling task's record and reset (:class:`RollReset`, a part of
:class:`~tensegrity_gym.envs.roll.RollTask`): the record's functions (:mod:`tensegrity_gym.tasks.state`)
and the reset written once over a record, for the NumPy task and the torch device env. SI units."""
from __future__ import annotations

import numpy as np

from ..physics import geometry
from ..physics.evaluate import project
from ..tasks.roll import perturbed_start
from ..tasks.terrain import start_lift
from ..tasks.xp import namespace

__all__ = ["RollReset"]


class RollReset:
    """The record and reset of :class:`~tensegrity_gym.envs.roll.RollTask` (a mixin: the task
    holds the state it writes)."""

    @property
    def anchor(self) -> np.ndarray:
        """(B, 2k, 2) contact anchors, m (the contact state's)."""
        return self.cstate.anchor

    @property
    def active(self) -> np.ndarray:
        """(B, 2k) bool contact flags (the contact state's)."""
        return self.cstate.active

    @property
    def rod_length(self) -> np.ndarray:
        """(k,) rod lengths, m."""
        return self.model.length

    def project_state(self, q, qd):
        """``(q, qd)`` projected onto the rod constraints (unit axes)."""
        return project(self.model, q, qd)

    def node_positions(self, q):
        """(B, n, 3) node positions of the robots ``q`` (B, k, 6), m."""
        return geometry.node_positions(self.model, q)

    @property
    def first_draws(self) -> int:
        """Uniforms per copy a task built on this one draws first at each reset
        (:meth:`reset_first`; here none)."""
        return 0

    @property
    def reset_draws(self) -> int:
        """Uniforms per copy :meth:`reset_start` reads: the task's first draws, the initial-state
        noise (4 x k x 3 with ``reset_noise_scale`` > 0), the goal angle (``randomize_goal``)."""
        return (self.first_draws + (12 * self.model.n_bars if self.reset_noise_scale > 0 else 0)
                + (1 if self.randomize_goal else 0))

    def reset_first(self, rec, rows, u) -> None:
        """The first step of a reset of copies ``rows`` on the record ``rec``, from their uniforms
        ``u`` (r, :attr:`first_draws`) in [0, 1): for a task built on this one (a slope)."""

    def reset_start(self, rec, rows, u) -> tuple:
        """The start of copies ``rows`` on the record ``rec`` from their uniforms ``u`` (r,
        :attr:`reset_draws`) in [0, 1), as NumPy's ``uniform`` maps the same draws: the task's
        first draws (:meth:`reset_first`), then the resting robot plus U(-s, s) noise on the rod
        centres (m) and velocities (m/s) and, divided by the rod lengths, on the axes and their
        rates, projected (unit axes) and lifted so that no node is below the resting robot's
        lowest; the goal, an angle U(0, 2 pi) with ``randomize_goal``. Returns ``(q, qd, goal)``
        (r, k, 6), (r, k, 6), (r, 2) in the record's dtype (not yet written)."""
        xp = namespace(u)
        n0 = self.first_draws
        if n0:
            self.reset_first(rec, rows, u[:, :n0])
            u = u[:, n0:]
        r, k, s = u.shape[0], self.model.n_bars, self.reset_noise_scale
        used = 0
        if s > 0:
            x = xp.to_float(-s + (s - -s) * u[:, :12 * k], rec.q).reshape(r, 4, k, 3)
            used = 12 * k
        else:
            x = xp.zeros((r, 4, k, 3), rec.q)
        q, qd = perturbed_start(rec.q_nominal, rec.rod_length[:, None], x)
        if self.randomize_goal:
            th = 0.0 + (2.0 * np.pi - 0.0) * u[:, used]
            goal = xp.to_float(xp.stack([xp.cos(th), xp.sin(th)], axis=1), rec.q)
        else:
            goal = xp.repeat_rows(rec.goal_direction, r)
        q, qd = rec.project_state(q, qd)
        # no node below the ground plus cap: lift the copy if the noise pushed one in
        zmin = xp.amin(rec.node_positions(q)[..., 2], 1)
        q[..., 2] += xp.maximum(self.z_floor - zmin, 0.0)[:, None]
        return q, qd, goal

    def reset_write(self, rec, rows, q, qd, goal) -> None:
        """Copies ``rows`` of the record ``rec`` start from ``q``, ``qd`` with the goal ``goal``: no
        contact anchors, the start control, cable speeds 0."""
        rec.q[rows], rec.qd[rows] = q, qd
        rec.anchor[rows] = 0.0
        rec.active[rows] = False
        rec.ctrl[rows] = rec.start_control
        rec.speed[rows] = 0.0
        rec.goal[rows] = goal

    def reset_info(self, rec, rows) -> dict:
        """Reset infos of copies ``rows`` beyond the rolling task's, from the record ``rec``."""
        return {}

    def reset_idx(self, idx, rngs, options=None) -> dict:
        idx = np.asarray(idx, dtype=int)
        r = idx.size
        n = self.reset_draws     # each copy's generator: its uniforms, then a terrain generator's draws
        q, qd, goal = self.reset_start(self, idx, np.array([rngs[j].random(n) for j in range(r)]).reshape(r, n))
        if self.terrain_contact is not None:     # on a terrain: its own draws, then clear of it
            self._reset_terrain(idx, rngs, goal)
            nodes = geometry.node_positions(self.model, q)
            for j, i in enumerate(idx):
                q[j, :, 2] += start_lift(self.terrains[i], nodes[j:j + 1], self.contact.radius)[0]
        self.reset_write(self, idx, q, qd, goal)
        self.elapsed[idx] = 0
        com = geometry.center_of_mass(self.model, q, None if self.params is None else self.params.take(
            idx if self.params.batch_size > 1 else np.zeros(len(idx), int)))
        self.start[idx] = com
        if self.sensors is not None:
            self.sensors.reset_reading(self, idx, rngs, goal, self.speed[idx], self.cstate.active[idx])
        if self.record_path:
            for j, i in enumerate(idx):
                self.paths[int(i)] = [com[j].copy()]
        info = {"com_position": com, "com_velocity": np.zeros((r, 3)), "distance_rolled": np.zeros(r),
                "goal_direction": goal.copy()}
        info.update(self.reset_info(self, idx))
        return info
