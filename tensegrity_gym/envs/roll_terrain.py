"""The rolling task's terrain (:class:`RollTerrain`, a part of
:class:`~tensegrity_gym.envs.roll.RollTask`): level ground, a fixed terrain or one drawn per
episode, its contact rows per copy and its reset. SI units."""
from __future__ import annotations

import numpy as np

from ..core.terrain import Terrain
from ..physics import terrain
from ..tasks.terrain import generate, resolve_terrain
from .validate import check_positive, check_stable_dt

__all__ = ["RollTerrain"]


class RollTerrain:
    """The terrain of :class:`~tensegrity_gym.envs.roll.RollTask` (a mixin: the task holds the
    state it reads)."""

    def _init_terrain(self, tcfg, allow_unstable_dt, friction, stiffness, damping, tangential_stiffness, tangential_damping,
                      max_damping) -> None:
        """The terrain (``tcfg``: :class:`~tensegrity_gym.envs.config.TerrainConfig`): None keeps the
        level ground (its fast path, no terrain code); a terrain or a generator replaces it with
        terrain contact of the same contact law (the rods' capsules of ``cap_radius``)."""
        self.set_terrain_difficulty(tcfg.terrain_difficulty)
        self._surface = surface = dict(friction=friction, stiffness=stiffness, damping=damping)
        spec = self._terrain_source(tcfg, surface)
        self.terrain_generator = None if spec is None or isinstance(spec, Terrain) else spec
        if spec is None:
            self.terrains = None
            return
        B = self.num_envs
        first = spec if self.terrain_generator is None else \
            self._draw_terrain(0, np.random.default_rng(0), self.goal_direction)
        self.terrains = [first] * B
        self._terrain_kw = dict(radius=self.contact.radius, tangential_stiffness=tangential_stiffness,
                                tangential_damping=tangential_damping, max_damping=max_damping)
        tc = self.terrain_contact = self._contact_of(self.terrains[0])
        self.tstate = terrain.init_terrain_state(tc, self.model, B)
        self._terrain_slip = np.zeros(self.tstate.active.shape, bool)
        # per-copy rows (one terrain per copy: a generator's differ in numbers, not in shape)
        self.terrain_geom = np.repeat(tc.geom, B, axis=0)
        self.terrain_prm = np.repeat(tc.prm, B, axis=0)
        self.terrain_hf = np.repeat(tc.hf, B, axis=0) if self.terrains[0].heightfield is not None else None
        limit = terrain.stable_step(tc, self.model)["semi_implicit_euler"]
        if self.integrator in ("semi_implicit_euler", "rk4"):
            check_stable_dt(self.model, limit, self.dt, self.integrator, allow_unstable_dt,
                            "this robot's strings and terrain contact")

    def _terrain_source(self, tcfg, surface: dict):
        """None (level ground), a fixed ``Terrain``, or a source of terrains drawn per episode by
        :meth:`_draw_terrain` (here a ``TerrainGenerator``) from the ``terrain`` argument."""
        return resolve_terrain(tcfg.terrain, surface)

    def _draw_terrain(self, i: int, rng: np.random.Generator, goal) -> Terrain:
        """Copy ``i``'s terrain this episode, drawn from ``rng`` (goal: its unit goal direction)."""
        return generate(self.terrain_generator, rng, goal, self.terrain_difficulty)

    def set_terrain_difficulty(self, difficulty: float) -> None:
        """The curriculum hook: terrains drawn from the next resets on are scaled by
        ``difficulty`` in [0, 1] (a generator's slope, step height or bump amplitude)."""
        d = check_positive(difficulty, "terrain_difficulty", allow_zero=True)
        if d > 1:
            raise ValueError(f"terrain_difficulty: must be in [0, 1], got {difficulty!r}")
        self.terrain_difficulty = d

    def _contact_of(self, t) -> "terrain.TerrainContact":
        try:
            return terrain.TerrainContact(t, **self._terrain_kw)
        except ValueError as e:
            raise ValueError(f"terrain: {e}") from None

    def _reset_terrain(self, idx, rngs, goal) -> None:
        """Copies ``idx`` on their terrain: a generator draws each copy's from its generator (after
        the start's noise and goal); stick/slip state released."""
        if self.terrain_generator is not None:
            for j, i in enumerate(idx):
                t = self._draw_terrain(int(i), rngs[j], goal[j])
                tc = self._contact_of(t)
                if tc.geom.shape[1:] != self.terrain_geom.shape[1:] or tc.hf.shape[1:] != self.terrain_contact.hf.shape[1:]:
                    raise RuntimeError("terrain generator: a drawn terrain changed its number of parts")
                self.terrains[i] = t
                self.terrain_geom[i] = tc.geom[0]
                if self.terrain_hf is not None:
                    self.terrain_hf[i] = tc.hf[0]
        self.tstate.anchor[idx] = 0.0
        self.tstate.eta0[idx] = 0.0
        self.tstate.active[idx] = False

    def terrain_height(self, x, y) -> np.ndarray:
        """(B, m) the height of each copy's ground under the points ``x``, ``y`` (B, m) m: its
        terrain's top (:meth:`~tensegrity_gym.core.terrain.Terrain.height_at`), or the level
        ground's plane (the record's ``terrain_height``, :mod:`tensegrity_gym.tasks.state`)."""
        if self.terrains is None:
            return np.full(np.shape(x), self.contact.height)
        return np.stack([t.height_at(x[i], y[i]) for i, t in enumerate(self.terrains)])
