"""The batched task base class: B copies of one compiled structure, one pipeline call per control
step, divergence handling and robot parameters (:mod:`tensegrity_gym.envs.domain`). SI units.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..core.model import Model, State, initial_state
from ..core.integrators import INTEGRATORS, numba_backend, resolve
from ..physics import pipeline
from ..core.params import default_params
from ..physics import terrain
from ..core.param_table import env_fields
from ..tasks.terrain import rod_end_contacts
from .domain import Domain, physics_nominal, write_copies
from ..core.checks import check_array, check_count, check_flag, check_options
from .validate import check_positive

__all__ = ["BatchedTask", "fixed_step"]

#: robot parameters (envs/domain.py) that are Params fields of the physics (tensegrity_gym.core.params):
#: a view of the parameter table (tensegrity_gym.core.param_table)
_PHYSICS_FIELDS = env_fields("physics")


def _contact_arrays(cs) -> tuple:
    """The per-copy arrays of a contact state (ground ``ContactState`` or ``TerrainState``)."""
    return (cs.anchor, cs.active) if not hasattr(cs, "eta0") else (cs.anchor, cs.eta0, cs.active)


def fixed_step(integrator: str) -> str:
    """The resolved name of a fixed-step integrator (envs step a fixed ``dt``); ValueError for an
    unknown name or an adaptive method."""
    name = resolve(integrator).name
    if INTEGRATORS[name].adaptive:
        raise ValueError(f"integrator: {integrator!r} is adaptive; envs need a fixed-step method "
                         f"({[k for k, v in INTEGRATORS.items() if not v.adaptive]})")
    return name


class BatchedTask:
    """Base class of a batched task on B copies of one compiled structure.

    Subclasses set in ``__init__`` (after calling :meth:`_init_physics`): ``action_size``,
    ``observation_size``, ``obs_low``/``obs_high`` (optional, default +-inf) and implement

    * ``reset_idx(idx (r,) int array, rngs: list of r np.random.Generator, options) -> dict``
      of reset infos ((r,) arrays) -- all randomness of copy ``idx[j]`` from ``rngs[j]``,
      drawn in a per-copy order so that B copies equal B single tasks;
    * ``step(action (B, na) validated) -> (terms: dict of (B,), terminated (B,) bool, infos)``
      which must call :meth:`simulate` exactly once;
    * ``observe() -> (B, obs_size) float32``;
    * ``render_data(i) -> dict`` of keyword arguments for :meth:`tensegrity_gym.tools.rendering.Renderer.render`
      (``nodes``, ``rods``, ``strings``, ``tensions``, ``targets``, ``ground_z``, ``path``, ``goal``, ``caption``).
    """

    action_size: int
    observation_size: int
    #: ground contact (tensegrity_gym.physics.contact.GroundContact) of the task, or None: no contact code runs
    contact = None
    #: terrain contact (tensegrity_gym.physics.terrain.TerrainContact) in place of the level ground, or
    #: None; with it ``tstate`` (its stick/slip state), ``terrain_geom`` / ``terrain_prm`` /
    #: ``terrain_hf`` (per-copy feature rows) and ``cstate.active`` the rod ends' contact flags
    terrain_contact = None
    #: rod-rod contact (tensegrity_gym.physics.rod_contact.RodContact) of the task, or None: rods pass
    #: through each other and no rod-rod code runs
    rod_contact = None
    #: divergence measured from each copy's own centre (a robot that travels), not from the start's
    travels = False
    #: keep the velocities before the last physics step of a control step (``_qd_prev``; IMUs)
    track_last_velocity = False
    #: (B, na) cable speeds of the actuation's motor model (unit/s); None: no motor state
    speed = None
    #: the keys ``reset(options=...)`` takes (none: the tasks draw everything from the seed)
    RESET_OPTIONS: tuple = ()
    #: True when the env shell renders (set by the shells): a task may then record what it draws
    record_path: bool = False
    #: the task's record (:mod:`tensegrity_gym.tasks.state`): its per-copy state arrays and the
    #: arrays its record functions read; ``StateField`` rows
    STATE: tuple = ()
    CONSTANTS: tuple = ()
    #: the torch env can draw and apply this task's resets on the device (``reset_sampling="device"``);
    #: where not, why (for the error message)
    DEVICE_RESET = False
    NO_DEVICE_RESET = ""
    #: the curriculum hooks a vector env's ``set_attr(name, value)`` forwards to the task: name ->
    #: the task's method that validates and sets it (acting from the next resets)
    CURRICULUM_HOOKS: dict = {}

    def _init_physics(self, model: Model, num_envs: int, integrator: str, dt: float, frame_skip: int,
                      backend: str = "auto", divergence_limit: float | None = None, clip_actions: bool = True):
        self.num_envs = check_count(num_envs, "num_envs", 1, "copies")
        self.model = model
        info = INTEGRATORS.get(integrator)   # the task passes the name it resolved (fixed_step)
        self.integrator = integrator if info is not None and not info.adaptive else fixed_step(integrator)
        self.dt = check_positive(dt, "dt", "s")
        self.frame_skip = check_count(frame_skip, "frame_skip", 1, "physics steps per action")
        if backend == "torch":
            raise ValueError("backend='torch' runs the batch on a torch device as a vector env: "
                             "gymnasium.make_vec(id, num_envs=N, vectorization_mode='vector_entry_point', "
                             "backend='torch', device=...) (docs/bench_gpu.md); this NumPy/numba task takes "
                             "backend 'auto' or 'numba'")
        numba_backend(backend)   # "auto"/"numba"; ValueError naming "backend" otherwise
        self.backend = backend
        self._kernels_run = pipeline.compiled_physics(self.integrator, backend)   # the numba kernels step it
        self.clip_actions = check_flag(clip_actions, "clip_actions")
        nodes0 = model.structure.nodes
        self.center0 = nodes0.mean(axis=0)
        size = float(np.max(np.linalg.norm(nodes0 - self.center0, axis=1)))
        self.divergence_limit = (100.0 * max(size, 1e-3) if divergence_limit is None
                                 else check_positive(divergence_limit, "divergence_limit", "m"))
        B = self.num_envs
        st = initial_state(model, B)
        self.q = st.q.copy()
        self.qd = st.qd.copy()
        self.elapsed = np.zeros(B, dtype=np.int64)
        self.params = None        # tensegrity_gym.core.params.Params of the copies; None: the model's own values
        self.rest_offset = None   # (P, m) true minus commanded rest lengths, m (rest_length_offset)
        self.action_delay = 0

    # ------------------------------------------------------------------ robot parameters (envs/domain.py)
    def _init_domain(self, params=None, randomize=None, action_delay: int = 0, start_rest_length_offset=None,
                     extra_nominal: dict | None = None):
        """Fixed / randomised physical parameters (:mod:`tensegrity_gym.envs.domain`), actuation
        latency (``action_delay`` control steps: the physics receives the action given that many
        steps earlier; zeros at the start of an episode) and the slack start
        (``start_rest_length_offset``, m: the actuated cables start at their nominal rest length
        plus this, rest-length mode). Call at the end of the task's ``__init__``."""
        model, B = self.model, self.num_envs
        nominal = physics_nominal(model)
        nominal.update(extra_nominal or {})
        self.domain = Domain(nominal, B, params, randomize)
        self.action_delay = check_count(action_delay, "action_delay", 0, "control steps")
        self._action_queue = np.zeros((B, self.action_delay, self.action_size))
        act = self.actuation
        self.start_control = act.nominal.copy()
        if start_rest_length_offset is not None:
            if act.mode != "rest_length":
                raise ValueError("start_rest_length_offset: only with action_mode='rest_length'")
            off = start_rest_length_offset      # m: one number, or one per actuated cable
            shape = () if np.ndim(off) == 0 else act.nominal.shape
            off = np.broadcast_to(check_array(off, shape, "start_rest_length_offset"), act.nominal.shape)
            start = act.nominal + off
            bad = ~np.isfinite(start) | (start < act.low) | (start > act.high)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(f"start_rest_length_offset: actuated cable {int(act.actuated[i])} would start at "
                                 f"{start[i]:.6g} m, outside its bounds [{act.low[i]:.6g}, {act.high[i]:.6g}] m")
            self.start_control = start
        physics = env_fields("physics")
        phys_names = set(self.domain.names) & set(physics)
        # Params: one row when fixed, one per copy when randomised (per-copy kernel; P = B also when B = 1)
        self._physics_per_copy = bool(phys_names & set(self.domain.spread))
        if phys_names:
            self.params = default_params(model, B if self._physics_per_copy else 1)
        if self.domain.enabled:
            self._apply_domain(np.arange(B) if self.domain.randomized else np.zeros(1, int), init=True)

    @property
    def draws_physics(self) -> bool:
        """Whether a reset draws new per-copy physics values (a device env then copies the reset
        rows of the parameters to the device)."""
        return self.domain.randomized

    def _apply_domain(self, idx: np.ndarray, init: bool = False) -> None:
        """Copies ``idx`` take the domain's current values (:func:`~tensegrity_gym.envs.domain.write_copies`).
        ``self.params`` has one row (set once, at ``init``) when no physics parameter is
        randomised, else one per copy (set per reset). The other containers (contact, motor
        limits): copies ``idx`` take their own rows when anything is randomised, else every copy
        row 0."""
        v, B = self.domain.values, self.num_envs
        physics = env_fields("physics")
        phys = [name for name in v if name in physics]
        if phys and (self._physics_per_copy or init):
            rows = idx if self._physics_per_copy else np.zeros(1, int)
            write_copies(self, rows, {name: v[name][rows] for name in phys})
        rest = [name for name in v if name not in physics]
        if rest:
            rows, src = (idx, idx) if self.domain.randomized else (np.arange(B), np.zeros(B, int))
            write_copies(self, rows, {name: v[name][src] for name in rest})
        self._apply_task_domain(idx)

    # the per-copy containers, as write_copies writes them (the NumPy side)
    def nominal(self, field: str) -> np.ndarray:
        """The model's nominal value of a ``Params`` field."""
        return getattr(self.model, field)

    @property
    def no_elastic_part(self) -> np.ndarray:
        """(m,) bool: the force-density-actuated strings (no stiffness, no damping)."""
        return self.model.active

    @staticmethod
    def zero_where(mask, v):
        return np.where(mask, 0.0, v)

    def write_physics(self, rows, fields: dict, offsets: dict) -> None:
        """``Params`` rows ``rows`` (one row when not per copy) take ``fields``; ``offsets``
        (``rest_length``) become the copies' rest-length offsets (:meth:`with_offset`)."""
        if "rest_length" in offsets:
            off = offsets["rest_length"]
            if self._physics_per_copy:
                if self.rest_offset is None:
                    self.rest_offset = np.zeros((self.num_envs,) + off.shape[1:])
                self.rest_offset[rows] = off
            else:
                self.rest_offset = off
        if fields:
            self.params = (self.params.set_rows(rows, **fields) if self._physics_per_copy
                           else self.params.replace(**fields))

    def write_contact(self, rows, columns: dict) -> None:
        raise ValueError(f"params / randomize: {sorted(columns)}: this task has no ground contact")

    def write_actuation(self, rows, fields: dict) -> None:
        raise ValueError(f"params / randomize: {sorted(fields)}: this task has no motor limits to set per copy")

    def write_params(self, rows, values: dict) -> None:
        """Copies ``rows`` take the env parameter values ``values`` (name -> (r, ...) values;
        :func:`~tensegrity_gym.envs.domain.write_copies`): the record's writer of per-copy
        parameters (:mod:`tensegrity_gym.tasks.state`)."""
        write_copies(self, rows, values)

    def _apply_task_domain(self, idx: np.ndarray) -> None:
        """Task-specific values derived from the parameters of copies ``idx``; see RollTask."""

    def with_offset(self, inputs: dict) -> dict:
        """Physics inputs with the cables' rest-length offsets added (``rest_length_offset``)."""
        if self.rest_offset is not None and inputs.get("rest_length") is not None:
            inputs["rest_length"] = inputs["rest_length"] + self.rest_offset
        return inputs

    def check_reset_options(self, options: dict | None) -> None:
        """ValueError naming any key of ``options`` that is not one of :attr:`RESET_OPTIONS`."""
        unknown = sorted(set(check_options(options)) - set(self.RESET_OPTIONS))
        if unknown:
            takes = f"only {list(self.RESET_OPTIONS)}" if self.RESET_OPTIONS else "no options"
            raise ValueError(f"options: unknown key(s) {unknown}; this env's reset takes {takes} (a vector env "
                             "also 'reset_mask'); the robot, goal and noise come from the constructor and the seed")

    def reset(self, idx: np.ndarray, rngs: Sequence[np.random.Generator], options: dict | None = None) -> dict:
        """Reset copies ``idx``: robot parameters drawn first (if randomised), then the task's
        :meth:`reset_idx`; ``info["params"]`` reports the parameters when any are set.
        ``options``: the keys of :attr:`RESET_OPTIONS` only (ValueError naming any other: an
        option that would be silently ignored)."""
        self.check_reset_options(options)
        dom = self.domain
        if dom.randomized:
            dom.sample(idx, rngs)
            self._apply_domain(idx)
        if self.action_delay:
            self._action_queue[idx] = 0.0
        info = self.reset_idx(idx, rngs, options)
        if dom.enabled:
            info["params"] = dom.report(idx if dom.randomized else np.zeros(len(idx), int))
        return info

    def act(self, action: np.ndarray):
        """:meth:`step` with the action delayed by ``action_delay`` control steps."""
        if self.action_delay:
            queue = self._action_queue
            out = queue[:, 0].copy()     # (a view would be overwritten by the shift below)
            queue[:, :-1] = queue[:, 1:]
            queue[:, -1] = action
            action = out
        return self.step(action)

    @property
    def control_dt(self) -> float:
        """Duration of one control step, s (``dt * frame_skip``)."""
        return self.dt * self.frame_skip

    def simulate(self, action: np.ndarray | None = None, **inputs) -> np.ndarray:
        """Advance all B copies by one control step (``frame_skip`` steps of ``dt``) through the
        pipeline (:mod:`tensegrity_gym.physics.pipeline`), as :func:`tensegrity_gym.physics.pipeline.control_step`
        does: with ``action`` (B, na) validated, the task's ``actuation`` updates ``ctrl`` (and
        the motor's ``speed``) and gives the physics inputs (``Actuation.update``, the robots'
        rest-length offsets added); without it, ``inputs`` ``rest_length`` / ``force_density``
        as :func:`tensegrity_gym.physics.integrate.step` takes them (the offsets added here). Without
        ``contact``: ONE ``pipeline.step`` of ``frame_skip`` steps for the whole batch. With the
        task's ``contact``: ``pipeline.advance`` in place, contact forces and one integrator step
        per physics step (``contact_params`` per copy, the stick/slip state in ``cstate``).

        Returns ``diverged`` (B,) bool (:func:`tensegrity_gym.physics.pipeline.diverged`, once per control
        step; ``travels``: measured from each copy's own centre); diverged copies get their
        pre-step state back (see the module doc). Increments ``elapsed``.
        """
        if action is not None:
            self.ctrl, self.speed, inputs = self.actuation.update(self.ctrl, action, self.speed, self.rest_offset)
        else:
            inputs = self.with_offset(inputs)
        if self.contact is not None:
            return self._simulate_contact(inputs)
        q0, qd0 = self.q, self.qd
        kw = dict(backend=self.backend, params=self.params, **inputs)
        model, dt, name, n = self.model, self.dt, self.integrator, self.frame_skip
        if self.track_last_velocity:
            # the frame_skip steps as two calls (n - 1, then 1; the same per-step arithmetic) to keep
            # the velocities before the last physics step (what IMUs read)
            with np.errstate(all="ignore"):
                st = State(q0, qd0, 0.0)
                if n > 1:
                    st = pipeline.step(model, st, dt, name, n_steps=n - 1, **kw)
                qd_prev = np.array(st.qd, dtype=float)
                st = pipeline.step(model, st, dt, name, n_steps=1, **kw)
            diverged = self._settle_divergence(q0, qd0, st.q, st.qd)
            qd_prev[diverged] = self.qd[diverged]
            self._qd_prev = qd_prev
            return diverged
        if self._kernels_run:
            # the compiled kernel raises no floating-point warnings: no np.errstate
            st = pipeline.step(model, State(q0, qd0, 0.0), dt, name, n_steps=n, **kw)
        else:
            with np.errstate(all="ignore"):
                st = pipeline.step(model, State(q0, qd0, 0.0), dt, name, n_steps=n, **kw)
        return self._settle_divergence(q0, qd0, st.q, st.qd)

    def _simulate_contact(self, inputs: dict) -> np.ndarray:
        """:meth:`simulate` with contact, in place on ``q``, ``qd``, ``cstate``; with
        ``track_last_velocity`` the velocities before the last physics step are kept in
        ``_qd_prev`` (what IMUs read)."""
        q, qd = self.q, self.qd
        tc = self.terrain_contact
        cs = self.cstate if tc is None else self.tstate
        saved = [q.copy(), qd.copy()] + [a.copy() for a in _contact_arrays(cs)]
        model, dt, name, n = self.model, self.dt, self.integrator, self.frame_skip
        if tc is None:
            kw = dict(backend=self.backend, params=self.params, contact=self.contact, cstate=cs,
                      contact_params=self._contact_prm, forces=self._W, slip=self._slip,
                      compiled=self._kernels_run, rods=self.rod_contact, **inputs)
            run, args = pipeline.run_steps, (model, q, qd, dt, name)
        else:
            prm, geom, hf = self._terrain_views()
            kw = dict(backend=self.backend, params=self.params, prm=prm, geom=geom, hf=hf, forces=self._W,
                      slip=self._terrain_slip, compiled=self._kernels_run, rods=self.rod_contact, **inputs)
            run, args = terrain.advance, (tc, model, q, qd, dt, name, cs)
        with np.errstate(all="ignore"):
            if self.track_last_velocity:
                run(*args, n_steps=n - 1, **kw)
                self._qd_prev = qd.copy()
                run(*args, n_steps=1, **kw)
            else:
                run(*args, n_steps=n, **kw)
        diverged = pipeline.diverged(q, qd, self.center0, self.divergence_limit, self.travels)
        if diverged.any():
            for now, before in zip([q, qd] + list(_contact_arrays(cs)), saved):
                now[diverged] = before[diverged]
            if self.track_last_velocity:
                self._qd_prev[diverged] = qd[diverged]
        if tc is not None:      # the rod ends' flags (what the observation reports) from the terrain's slots
            rod_end_contacts(cs.active, q.shape[1], out=self.cstate.active)
        self.elapsed += 1
        return diverged

    def _terrain_views(self) -> tuple:
        """Read-only views of ``terrain_prm``, ``terrain_geom``, ``terrain_hf`` (None stays None), as
        the kernels take them: made once and kept while they view those arrays (a copied or
        unpickled env makes its own), so that writes to the rows show through."""
        views = self.__dict__.get("_terrain_ro")
        hf = self.terrain_hf
        if (views is None or views[0].base is not self.terrain_prm or views[1].base is not self.terrain_geom
                or (views[2] is None) != (hf is None) or (hf is not None and views[2].base is not hf)):
            views = self._terrain_ro = (terrain.read_only(self.terrain_prm), terrain.read_only(self.terrain_geom),
                                        None if hf is None else terrain.read_only(hf))
        return views

    def _settle_divergence(self, q0, qd0, q, qd) -> np.ndarray:
        """Divergence check (:func:`tensegrity_gym.physics.pipeline.diverged`) and state update of
        :meth:`simulate`: diverged copies take ``q0``, ``qd0`` back. Increments ``elapsed``."""
        diverged = pipeline.diverged(q, qd, self.center0, self.divergence_limit, self.travels)
        if diverged.any():
            q = np.where(diverged[:, None, None], q0, q)
            qd = np.where(diverged[:, None, None], qd0, qd)
        self.q, self.qd = q, qd
        self.elapsed += 1
        return diverged

    # -- to implement
    def reset_idx(self, idx: np.ndarray, rngs: Sequence[np.random.Generator], options: dict | None = None) -> dict:
        raise NotImplementedError

    def step(self, action: np.ndarray):
        raise NotImplementedError

    def observe(self) -> np.ndarray:
        raise NotImplementedError

    def render_data(self, i: int) -> dict:
        raise NotImplementedError

