"""The torch device roll env's terrain: its rows and contact state on the device, stepped there.

:class:`~tensegrity_gym.envs.torch_tasks.TorchRollVectorEnv` with ``terrain=`` steps the torch
terrain contact (:func:`tensegrity_gym.backends.torch.terrain.terrain_step`). SI units.

The host :class:`~tensegrity_gym.envs.roll.RollTask` keeps doing what is drawn: at a reset it
draws each reset copy's terrain from that copy's generator, lifts the start clear of it and
releases its stick/slip state (``RollTask.reset_idx``); this class copies those rows to the
device (the geometry and heights only where a generator draws them per copy). Resets drawn on
the device (``reset_sampling="device"``) draw a generator's terrains there
(:meth:`TorchTerrain.draw`: :func:`tensegrity_gym.tasks.terrain.drawn_values`, the host's
draw, on the device's uniforms), lift the start and release the contact state here
(:meth:`TorchTerrain.start_lift`, :meth:`TorchTerrain.release`); the host task's ``terrains``
then keep the host's last draws. Each control step
then runs on the device: ``frame_skip`` terrain contact steps, the divergence restore of the
terrain's contact state, and the rod ends' contact flags from its slots
(:func:`tensegrity_gym.tasks.terrain.rod_end_contacts`, the NumPy env's function)."""
from __future__ import annotations

import math

from ..backends.torch.model import torch_module
from ..backends.torch import divergence
from ..backends.torch.heightfield import hf_lipschitz
from ..backends.torch.terrain import terrain_layout, terrain_step, top_height
from ..tasks.terrain import STEP_SPAN, drawn_values, rod_end_contacts, step_extents

__all__ = ["TorchTerrain", "DRAW_CHUNK"]

#: grid points of rough ground drawn at once at a device reset (bounds the draw's temporaries)
DRAW_CHUNK = 1 << 24


class TorchTerrain:
    """The terrain of ``env``'s task on ``env``'s device: geometry ``geom`` (1 or N, F, 10),
    heightfield heights ``hf`` (1 or N, ny, nx) m or None, and the contact state ``anchor``
    (N, S, 3) m, ``eta0`` (N, S) m, ``active`` (N, S) bool (S = 3 k F slots). A fixed terrain
    keeps one row of geometry and heights; a generator's terrains one per copy. The contact
    parameters are the env's ``_terrain_prm`` (the task's ``terrain_prm`` rows, uploaded with
    the other per-copy parameters). ``layout``: what the steps branch on
    (:func:`~tensegrity_gym.backends.torch.terrain.terrain_layout` of the host's rows, the same
    for every terrain a generator draws)."""

    def __init__(self, env):
        torch = torch_module()
        task = env.task
        self.per_copy = task.terrain_generator is not None
        rows = slice(None) if self.per_copy else slice(0, 1)
        self.geom = env._T(task.terrain_geom[rows])
        self.hf = None if task.terrain_hf is None else env._T(task.terrain_hf[rows])
        ts = task.tstate
        self.anchor = env._T(ts.anchor)
        self.eta0 = env._T(ts.eta0)
        self.active = torch.as_tensor(ts.active, device=env.device)
        self.layout = terrain_layout(task.terrain_geom, task.terrain_prm, task.model)

    def upload_rows(self, env, it, idx) -> None:
        """Envs ``it`` (device index tensor) take the host task's rows ``idx`` after its reset:
        their released contact state and, with a generator, their terrain."""
        torch = torch_module()
        task = env.task
        ts = task.tstate
        self.anchor[it] = env._T(ts.anchor[idx])
        self.eta0[it] = env._T(ts.eta0[idx])
        self.active[it] = torch.as_tensor(ts.active[idx], device=env.device)
        if self.per_copy:
            self.geom[it] = env._T(task.terrain_geom[idx])
            if self.hf is not None:
                self.hf[it] = env._T(task.terrain_hf[idx])

    def release(self, it) -> None:
        """Envs ``it`` (device index tensor) let go of the terrain: no slot active, anchors and
        anchored points zero (a device reset, as the host task's reset)."""
        self.anchor[it] = 0.0
        self.eta0[it] = 0.0
        self.active[it] = False

    def draw(self, env, it, u, goal) -> None:
        """Envs ``it`` (device index tensor) take new terrains of the task's generator drawn from
        their uniforms ``u`` (r, :func:`~tensegrity_gym.tasks.terrain.terrain_draws`) float64,
        rising along their unit goal directions ``goal`` (r, 2), at the task's
        ``terrain_difficulty``: the host's :func:`~tensegrity_gym.tasks.terrain.terrain_from`
        written into the kernels' rows (a slope's plane normal; the steps' box centres, half
        sizes and yaw; rough ground's heights and slope bound, column 6). Rough ground is drawn
        ``DRAW_CHUNK`` grid points at a time (its float64 temporaries: 16M points, 128 MB each)."""
        hf = self.hf
        chunk = len(it) if hf is None else max(1, DRAW_CHUNK // (hf.shape[1] * hf.shape[2]))
        for i in range(0, len(it), chunk):
            self._draw_rows(env, it[i:i + chunk], u[i:i + chunk], goal[i:i + chunk])

    def _draw_rows(self, env, it, u, goal) -> None:
        """:meth:`draw` for the envs ``it``."""
        torch = torch_module()
        task = env.task
        gen = task.terrain_generator
        vals = drawn_values(gen, u, task.terrain_difficulty)
        g = self.geom[it].to(u.dtype)
        gx, gy = goal[:, 0].to(u.dtype), goal[:, 1].to(u.dtype)
        yaw = torch.atan2(gy, gx)
        if gen.kind == "slope":                     # Plane.normal
            a = vals * (math.pi / 180.0)
            g[:, 0, 1:4] = torch.stack([-torch.sin(a) * torch.cos(yaw), -torch.sin(a) * torch.sin(yaw),
                                        torch.cos(a)], dim=1)
        elif gen.kind == "steps":                   # the plane, then one box per step (terrain_from's)
            for i, (along, depth) in enumerate(step_extents(gen)):
                top = vals[:, i]
                height = top + 1.0
                g[:, 1 + i, 1:9] = torch.stack([along * gx, along * gy, top - height / 2,
                                                torch.full_like(top, depth / 2), torch.full_like(top, STEP_SPAN / 2),
                                                height / 2, torch.cos(yaw), torch.sin(yaw)], dim=1)
        else:
            H = vals.to(self.hf.dtype)
            self.hf[it] = H
            g[:, 0, 6] = hf_lipschitz(g[:, 0], vals)[:, 0]
        self.geom[it] = g.to(self.geom.dtype)

    def start_lift(self, nodes, radius: float, it=None):
        """(r,) height (m) to raise each of r copies' ``nodes`` (r, n, 3) m by so that every node's
        cap of ``radius`` m clears the terrain's top surface under it (0 where it already does):
        the host's :func:`tensegrity_gym.tasks.terrain.start_lift` on the device, on a fixed
        terrain or, with a generator, on the terrains of envs ``it``."""
        torch = torch_module()
        geom, hf = self.geom, self.hf
        if self.per_copy:
            geom, hf = geom[it], None if hf is None else hf[it]
        ground = top_height(geom, hf, nodes[..., 0], nodes[..., 1], self.layout.kinds)
        gap = (nodes[..., 2] - radius) - ground
        return torch.clamp(-gap.amin(dim=1), min=0.0)

    def advance(self, env, q0, qd0, inputs: dict):
        """One control step of the physics on the terrain from ``q0``, ``qd0`` (N, k, 6):
        returns ``(q, qd, qd_prev, diverged)`` with the diverged copies' states (and contact
        state) restored; ``env.active`` becomes the rod ends' contact flags."""
        torch = torch_module()
        task = env.task
        geom, prm, hf = self.geom, env._terrain_prm, self.hf
        kw = dict(rest_length=inputs.get("rest_length"), force_density=inputs.get("force_density"),
                  params=env._params, hf=hf, layout=self.layout, substep=env._substep)
        state0 = (q0, qd0, self.anchor, self.eta0, self.active)
        run = env._physics_call(terrain_step)
        (q, qd, anchor, eta0, active), qd_prev = env._advance(
            lambda n, *s: run(env.tm, geom, prm, *s, task.dt, task.integrator, n, **kw), state0)
        diverged = divergence.diverged(q, qd, task.center0, task.divergence_limit, local=True)
        d1, d2 = diverged[:, None], diverged[:, None, None]
        q, qd = torch.where(d2, q0, q), torch.where(d2, qd0, qd)
        self.anchor = torch.where(d2, state0[2], anchor)
        self.eta0 = torch.where(d1, state0[3], eta0)
        self.active = torch.where(d1, state0[4], active)
        env.active = rod_end_contacts(self.active, q.shape[1])
        return q, qd, qd_prev, diverged
