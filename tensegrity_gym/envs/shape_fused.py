"""The fused step of TensegrityShape-v0 (a mixin of :class:`~tensegrity_gym.envs.shape.ShapeTask`):
one compiled call per control step (:func:`tensegrity_gym.envs.compiled.shape_step`) that runs
the control update, the pipeline's physics (an opaque :func:`tensegrity_gym.physics.pipeline.compiled_plan`),
the divergence check, the observation, the errors and the tracking term; bit-identical to
``ShapeTask.step``'s reference path (``tests/test_fast_paths.py``). SI units."""
from __future__ import annotations

import numpy as np

from ..physics.pipeline import compiled_plan
from ..rewards import sum_squares
from ..tasks.shape import GAUSS_SCALE, shape_step_terms
from ..tasks.xp import NUMPY
from . import compiled

__all__ = ["FusedShapeStep"]


class FusedShapeStep:
    """``_fused_setup`` (decided once per task, at its first step) and ``_fused_step`` of the
    shape task; the task provides the state, actuation, targets and ``_finish_step``."""

    def _fused_setup(self):
        """Constants of the fused compiled step (:func:`tensegrity_gym.envs.compiled.shape_step`
        running a :func:`tensegrity_gym.physics.pipeline.compiled_plan`), or False when it does not apply:
        an implicit integrator, an anchored tracked node, or a batch large
        enough for the parallel kernel (then the pipeline runs it). Decided once per task, at its
        first step."""
        fz = False
        act = self.actuation
        plan = None
        if self._obs_rod is not None and self._kernels_run:
            plan = compiled_plan(self.model, self.integrator, self.dt, self.frame_skip, self.num_envs,
                                 act.mode, self.backend)
        if plan is not None:
            tol = self.success_tolerance
            scale = GAUSS_SCALE     # tasks.shape.proximity's gaussian, value 0.1 at the margin
            fcon = np.concatenate([[self.divergence_limit], self.center0, [tol, 10.0 * tol, scale, -self.tracking_weight],
                                   act._rate[0], act.low, act.high, act.base_rest_length, self._obs_eta])
            icon = np.concatenate([[int(act.mode == "rest_length"), act.size, act.n_strings, self.tracked.size],
                                   act.actuated, self._obs_rod]).astype(np.int64)
            disp = compiled.shape_step_simd if plan.simd else compiled.shape_step
            if not disp.signatures:
                disp.compile(compiled.SHAPE_STEP_SIG)
                disp.disable_compile()     # another argument type raises TypeError: reference path
            self._fused_dist = np.empty((self.num_envs, self.tracked.size))
            self._no_offset = np.zeros((0, act.n_strings))
            fz = (disp, plan, (plan.buf, plan.dt, plan.n_steps, plan.flags), np.ascontiguousarray(fcon, np.float64),
                  icon, self.num_envs, self.action_size, self.observation_size, self.tracked.size)
        self._fused = fz
        return fz

    def _fused_step(self, fz, action):
        """:meth:`step` in one compiled call (see :meth:`_fused_setup`); None when it does not
        apply to these arrays (nothing changed then: the caller runs the reference path)."""
        disp, plan, (buf, dt, n_steps, flags), fcon, icon, B, na, nobs, nt = fz
        if self.params is not None:
            buf = plan.buffer(self.params)     # the robot's own values: the shared buffer of its Params
            if buf is None:
                return None
        offset = self._no_offset if self.rest_offset is None else self.rest_offset
        q0, qd0 = self.q, self.qd
        qo = np.empty(q0.shape)
        qdo = np.empty(q0.shape)
        ctrl = np.empty((B, na))
        obs = np.empty((B, nobs), np.float32)
        d = self._fused_dist               # scratch: read below only before the next call
        st = np.empty((4, B))
        success = np.empty(B, bool)
        try:
            rc = disp(q0, qd0, self.ctrl, action, self.target, buf, dt, n_steps, flags, offset, fcon, icon, qo, qdo, ctrl,
                      obs, d, st, success, self.elapsed)
        except TypeError:    # an array of another type or layout: the reference path converts it
            return None
        if rc < 0:
            return None
        self.ctrl = ctrl
        self._last_action = action
        if rc == 1:      # diverged: the reference divergence handling and observation
            diverged = self._settle_divergence(q0, qd0, qo, qdo)
            return self._finish_step(action, diverged)
        self.q, self.qd = qo, qdo
        self._obs, self._obs_of, self._N = obs, (qo, qdo, ctrl, self.target), None
        if rc == 2:      # mean/max left to NumPy (nt >= 8); elapsed not incremented
            self.elapsed += 1
            err, emax = NUMPY.mean_max(d)
            terms, infos = shape_step_terms(err, emax, action, self.success_tolerance, self.tracking_weight,
                                            self.proximity_weight, self.ctrl_cost_weight)
            infos["diverged"] = np.zeros(B, bool)
            return terms, np.zeros(B, bool), infos
        # the compiled step's err, emax, exponent y of tasks.shape.proximity (NaN inside the
        # tolerance) and -tracking_weight * err
        err, emax, y, tracking = st[0], st[1], st[2], st[3]
        if B == 1:
            prox = np.ones(1) if y[0] != y[0] else np.exp(y)
        else:
            prox = np.where(y != y, 1.0, np.exp(y))
        terms = {
            "tracking": tracking,
            "proximity": self.proximity_weight * prox,
            "ctrl": -self.ctrl_cost_weight * sum_squares(action),  # quadratic_cost
        }
        infos = {"tracking_error": err, "max_node_error": emax, "is_success": success,
                 "diverged": np.zeros(B, bool)}
        return terms, np.zeros(B, bool), infos
