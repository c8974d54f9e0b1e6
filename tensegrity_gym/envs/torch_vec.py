"""Device-resident vector envs of ``TensegrityRoll-v0`` and ``TensegrityShape-v0`` on the torch backend (SI units).

``gymnasium.make_vec("TensegrityRoll-v0", num_envs=N, vectorization_mode="vector_entry_point",
backend="torch", device="cuda", dtype="float32")`` returns a :class:`TorchRollVectorEnv`: a
``gymnasium.vector.VectorEnv`` whose ``step`` takes an action tensor (N, na) and returns
``(obs, reward, terminated, truncated, info)`` as torch tensors on ``device`` (obs (N, obs_size)
and reward (N,) in ``dtype``, terminated / truncated (N,) bool; ``info`` a dict of (N, ...)
tensors with Gymnasium's ``"_key"`` masks as bool tensors), as ManiSkill / Isaac Lab do. Without
``backend="torch"`` the registered id builds the NumPy/numba
:class:`~tensegrity_gym.envs.roll.TensegrityRollVectorEnv`, unchanged.

One task, two backends
----------------------
The task is :class:`~tensegrity_gym.envs.roll.RollTask`'s: this env builds a ``RollTask`` with
the same keyword arguments (robot, actuation, contact, rewards, limits, ``params=`` /
``randomize=`` / ``action_delay`` / ``start_rest_length_offset``) and uses it

* as the configuration (model, contact, actuation, weights, divergence limit), and
* **on the host at reset only** (``reset_sampling="host"``, the default): ``RollTask.reset``
  draws each reset env's robot parameters, initial-state noise and goal from that env's own
  NumPy generator (exactly the numbers the NumPy vector env draws: env i seeded ``seed + i``);
  the reset rows are then copied to the device once (state, control, goal, start, and the
  per-copy parameters when randomised).

With ``reset_sampling="device"`` (``TensegrityRoll-v0``) the reset runs on the device too: the
same draws (noise, goal, randomised parameters; same distributions, same order) from per-env
counter-based streams keyed by the same seeding rule, applied to the device tensors with no host
loop and no copy (:mod:`tensegrity_gym.envs.torch_reset`: what the numbers depend on, and the
test that a host reset fed them gives the same state). An autoreset then reads nothing from the
host but the 3 flags of every step. ``TensegrityShape-v0`` refuses it (its targets are Newton
equilibria with rejection, solved on the host).

The step loop runs on the device: the cable motor / control update
(:func:`tensegrity_gym.torch_backend.motor` / :func:`~tensegrity_gym.torch_backend.advance`),
the physics inputs, ``frame_skip`` physics steps with ground contact
(:func:`tensegrity_gym.torch_backend.contact_step`: per-copy ``Params`` and contact
parameters), the divergence check and restore, the observation, the reward terms and the time
limit. Per ``step`` the host reads ONE small tensor (3 bools: an action entry non-finite, one
out of the box with ``clip_actions=False``, an env to autoreset) to raise a clear error and to
know whether to reset; when an env finished, with host resets its mask (N bools) is read and its
reset drawn on the host as above (with device resets, nothing more). Nothing else crosses
between host and device in a step.

Matching the NumPy env: in float64 on CPU the observations, reward terms and infos equal the
NumPy vector env's to round-off (``tests/test_torch_env.py``: 50 control steps, autoreset,
``randomize``, ``params``, ``action_delay``, force-density mode). The NumPy env's observation
is float32; this env returns ``dtype`` (float64 gives the float64 numbers before that cast).

``TensegrityShape-v0`` (:class:`TorchShapeVectorEnv`) works the same way on
:class:`~tensegrity_gym.envs.shape.ShapeTask`: targets and initial states drawn on the host at
reset, the control update, the physics (with the model's node drag), the divergence check, the
tracking errors, the ``tracking`` / ``proximity`` / ``ctrl`` reward terms and the observation on
the device; it equals the NumPy vector env to round-off in the same tests.

``observation_mode="robot"`` (what a lab robot senses, :mod:`tensegrity_gym.envs.sensors`) is
computed on the device by :class:`~tensegrity_gym.envs.torch_sensors.TorchSensors`; its
``sensor_noise`` comes from per-env counter-based streams on the device keyed by ``reset(seed=...)`` (that module's doc).
Not supported here (``ValueError`` at construction): ``render_mode`` (use the NumPy env to
render), the implicit integrators (the torch backend has ``semi_implicit_euler`` and ``rk4``).

``compile=True`` wraps the physics step (roll: with contact,
:func:`tensegrity_gym.torch_backend.contact_substep`; shape:
:func:`tensegrity_gym.torch_backend.step_once`) in ``torch.compile``: the first steps
compile (10-35 s on a 2-core CPU, 7-17 s on an H100), then a control step ran 2-8x faster than
eager on CPU, and 4.5-6.1x on an H100 at N = 65,536 (roll: 74-123M physics env-steps/s), in
``scripts/bench_gpu.py --env --env-compile`` (``docs/bench_gpu.md``). Reset sampling on the host
costs a Python loop over the reset envs (14-35 us per env on a 2-core CPU, the same as the
NumPy env's reset), paid when envs finish; ``reset_sampling="device"`` took 1.7-1.9 us per env
on the same CPU at B = 1,024-16,384 (``scripts/bench_gpu.py --env-reset``, ``docs/bench_gpu.md``).

Autoreset and seeding are those of :class:`~tensegrity_gym.envs.common.TaskVectorEnv`:
``AutoresetMode.NEXT_STEP``; ``reset(seed=s)`` seeds env i with ``s + i`` (with device resets:
keys env i's stream with ``s + i``; ``np_random_list`` then holds host generators the env does
not read); ``reset(options=
{"reset_mask": mask})`` resets the envs where the (N,) bool mask (NumPy or tensor) is true;
``max_episode_steps`` (``make_vec`` passes the registered 1000) truncates every env.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import gymnasium as gym
from gymnasium import spaces
from gymnasium.utils import seeding

from .. import torch_backend as tb
from ..checks import check_action_tensor
from .shells import VectorSeeding, episode_limit, reseed
from ..hardening_checks import check_autoreset_mode, check_reset_called
from .torch_reset import RESET_SAMPLING, CounterStreams, TorchDomain
from .torch_sensors import TorchSensors

__all__ = ["TorchRollVectorEnv", "TorchShapeVectorEnv", "roll_vector_env", "shape_vector_env"]


def _no_torch_kwargs(kwargs):
    for name in ("device", "dtype", "compile", "reset_sampling"):
        if name in kwargs:
            raise ValueError(f"{name}: only with backend='torch' (got backend={kwargs.get('backend', 'auto')!r})")


def roll_vector_env(num_envs: int = 1, **kwargs):
    """``vector_entry_point`` of ``TensegrityRoll-v0``: :class:`TorchRollVectorEnv` when
    ``backend="torch"``, else :class:`~tensegrity_gym.envs.roll.TensegrityRollVectorEnv` with
    the arguments passed through untouched (the default path is unchanged)."""
    if kwargs.get("backend") == "torch":
        from .torch_tasks import TorchRollVectorEnv
        return TorchRollVectorEnv(num_envs=num_envs, **kwargs)
    _no_torch_kwargs(kwargs)
    from .roll import TensegrityRollVectorEnv
    return TensegrityRollVectorEnv(num_envs=num_envs, **kwargs)


def shape_vector_env(num_envs: int = 1, **kwargs):
    """``vector_entry_point`` of ``TensegrityShape-v0``: :class:`TorchShapeVectorEnv` when
    ``backend="torch"``, else :class:`~tensegrity_gym.envs.shape.TensegrityShapeVectorEnv`
    (arguments passed through untouched)."""
    if kwargs.get("backend") == "torch":
        from .torch_tasks import TorchShapeVectorEnv
        return TorchShapeVectorEnv(num_envs=num_envs, **kwargs)
    _no_torch_kwargs(kwargs)
    from .shape import TensegrityShapeVectorEnv
    return TensegrityShapeVectorEnv(num_envs=num_envs, **kwargs)


class _TorchTaskVectorEnv(VectorSeeding, gym.vector.VectorEnv):
    """A batched task (:class:`~tensegrity_gym.envs.common.BatchedTask`) stepped on a torch
    device: seeding, resets on the host, Gymnasium vector infos, action checks, next-step
    autoreset. Subclasses set ``ENV_ID`` and implement ``_make_task``, ``_init_state``,
    ``_upload_rows``, ``_act`` and ``_observe``.

    Arguments: those of the id's env plus ``device`` (``"cpu"``, ``"cuda"``, ``"cuda:1"``; ValueError when it does not exist),
    ``dtype`` (``"float64"`` default or ``"float32"``; anything else is a ValueError) and
    ``max_episode_steps`` (control steps; ``"registered"``: the id's 1000; None: no limit) and
    ``compile`` (default False: wrap the task's physics step in ``torch.compile``; the
    first steps then compile for tens of seconds; measured in ``docs/bench_gpu.md``) and
    ``reset_sampling`` (``"host"`` default: resets drawn from the per-env NumPy generators, the
    NumPy env's numbers; ``"device"``: drawn and applied on the device from per-env counter-based
    streams, :mod:`tensegrity_gym.envs.torch_reset`; tasks with ``DEVICE_RESET``).
    """

    #: the task can reset on the device (``reset_sampling="device"``): it implements
    #: ``_reset_draws`` and ``_device_reset_rows``
    DEVICE_RESET = False
    _NO_DEVICE_RESET = ""     # why not, for the error message

    metadata = {"render_modes": [], "render_fps": 50, "autoreset_mode": gym.vector.AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, max_episode_steps="registered", device=None, dtype=None,
                 backend: str = "torch", render_mode: str | None = None, compile: bool = False,
                 reset_sampling: str = "host", **kwargs):
        torch = tb._torch()
        kwargs = check_autoreset_mode(kwargs)
        if reset_sampling not in RESET_SAMPLING:
            raise ValueError(f"reset_sampling: expected one of {RESET_SAMPLING}, got {reset_sampling!r}")
        if reset_sampling == "device" and not self.DEVICE_RESET:
            raise ValueError(f"reset_sampling: 'device' is not available for {self.ENV_ID} ({self._NO_DEVICE_RESET}); "
                             "use reset_sampling='host'")
        if backend != "torch":
            raise ValueError(f"backend: {type(self).__name__} runs backend='torch', got {backend!r}")
        if render_mode is not None:
            raise ValueError(f"render_mode: {render_mode!r} is not supported by backend='torch' (render the "
                             f"NumPy env: gymnasium.make({self.ENV_ID!r}, render_mode='rgb_array'))")
        self.device = tb.resolve_device(device)
        self.dtype = tb.resolve_dtype(dtype)
        task = self._make_task(num_envs, kwargs)
        tb._integrator_name(task.integrator)          # ValueError for an implicit method
        self.task = task
        self.num_envs = N = task.num_envs
        self.max_episode_steps = episode_limit(max_episode_steps, self.ENV_ID)
        self.render_mode = None
        self.metadata = dict(self.metadata)
        self.metadata["render_fps"] = int(round(1.0 / task.control_dt))
        np_dtype = np.float64 if self.dtype == torch.float64 else np.float32
        self.single_action_space = spaces.Box(-1.0, 1.0, (task.action_size,), np.float32)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (task.observation_size,), np_dtype)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, N)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, N)
        self._rngs: list[np.random.Generator] = [seeding.np_random(None)[0] for _ in range(N)]

        dev, dt = self.device, self.dtype
        self.tm = tb.torch_model(task.model, dev, dt)
        self._node_prm = tb.torch_params(self.tm, None)          # model defaults (anchor positions)
        self._init_state()
        sens = getattr(task, "sensors", None)      # observation_mode="robot": the readings on the device
        self._sens = None if sens is None else TorchSensors(sens, self)
        self.elapsed = torch.zeros(N, dtype=torch.int64, device=dev)
        self._autoreset = torch.zeros(N, dtype=torch.bool, device=dev)
        self._queue = torch.zeros((N, task.action_delay, task.action_size), dtype=dt, device=dev)
        if not isinstance(compile, (bool, np.bool_)):
            raise ValueError(f"compile: expected True or False, got {compile!r}")
        # compile: the one physics step each task repeats (with contact: contact forces + integrator step)
        one = tb.contact_substep if getattr(task, "contact", None) is not None else tb.step_once
        self._substep = torch.compile(one, dynamic=False) if compile else None
        # per-copy parameters (domain): uploaded whole here, by reset rows when randomised
        self._upload_domain(None)
        self.reset_sampling = reset_sampling
        self._streams = self._tdomain = None
        if reset_sampling == "device":     # envs/torch_reset.py: per-env counter-based streams on the device
            self._streams = CounterStreams(N, dev)
            self._tdomain = TorchDomain(self) if task.domain.enabled else None

    # ------------------------------------------------------------------ host <-> device
    def _T(self, x):
        torch = tb._torch()
        return torch.as_tensor(np.array(x, dtype=float), dtype=self.dtype, device=self.device)

    def _upload_domain(self, idx) -> None:
        """Copy the host task's parameter rows to the device: all (``idx`` None) or rows ``idx``
        (a randomised domain after a reset)."""
        task = self.task
        if idx is not None and not task.domain.randomized:
            return
        torch = tb._torch()
        idx_t = None if idx is None else torch.as_tensor(idx, dtype=torch.int64, device=self.device)

        def rows(cur, host):      # the whole array, or rows idx written into the device tensor
            if idx_t is None or cur is None or cur.shape[0] != host.shape[0] or host.shape[0] == 1:
                return self._T(host)
            cur[idx_t] = self._T(host[idx])
            return cur

        def put(name, host):
            setattr(self, name, None if host is None else rows(getattr(self, name, None), host))
        prm = task.params
        if prm is None:
            self._params = None
        else:
            self._params = getattr(self, "_params", None) or {}
            fields = ["mass", "f", "J", "stiffness", "damping", "rest_length", "gravity"]
            if prm.has_node_damping:
                fields.append("node_damping")
            for f in fields:
                self._params[f] = rows(self._params.get(f), np.asarray(getattr(prm, f), float))
        put("_rest_offset", None if task.rest_offset is None else np.asarray(task.rest_offset, float))
        put("_contact_prm", getattr(task, "_contact_prm", None))
        act = task.actuation
        put("_max_rate", act.rate_rows)
        put("_max_accel", None if act.accel_rows is None else np.asarray(act.accel_rows, float)[:, None])
        if hasattr(task, "_mass_frac"):
            mf = np.asarray(task._mass_frac, float)
            put("_mass_frac", mf if mf.ndim == 2 else mf[None])

    def _reset_envs(self, mask, options) -> dict:
        """Reset the envs where ``mask`` (N,) bool (a device tensor) is true: drawn on the host
        (one upload of their rows) or on the device (``reset_sampling``); infos as (N,) tensors."""
        torch = tb._torch()
        task = self.task
        if self._streams is not None:
            task.check_reset_options(options)
            it = mask.nonzero()[:, 0]
            self.elapsed[it] = 0          # (before the reset reading: its noise is step 0's)
            info = self._device_reset(it)
        else:
            idx = np.flatnonzero(mask.cpu().numpy())
            info = task.reset(idx, [self._rngs[i] for i in idx], options)
            self._upload_domain(idx)
            it = torch.as_tensor(idx, dtype=torch.int64, device=self.device)
            self._upload_rows(it, idx)
            if self._sens is not None:
                self._sens.upload_reset(it, task._readings[idx])
        self.elapsed[it] = 0
        self._autoreset[it] = False
        if self._queue.shape[1]:
            self._queue[it] = 0.0
        return self._full_info(info, it)

    def _device_reset(self, it) -> dict:
        """Reset envs ``it`` (int64 index tensor) on the device: their uniforms
        (:class:`~tensegrity_gym.envs.torch_reset.CounterStreams`: the task's draws, then the
        domain's), the randomised parameters applied first, then the task's rows
        (``_device_reset_rows``); (r, ...) infos, ``params`` when the domain is set."""
        n_task = self._reset_draws()
        dom = self._tdomain
        n_dom = dom.size if dom is not None else 0
        u = self._streams.uniform(it, n_task + n_dom)
        if n_dom:
            dom.apply(it, dom.sample(it, u[:, n_task:]))
        info = self._device_reset_rows(it, u[:, :n_task])
        if dom is not None:
            info["params"] = dom.report(it)
        return info

    def _full_info(self, info: dict, it) -> dict:
        """(r, ...) infos of envs ``it`` (host arrays or device tensors) -> (N, ...) device
        tensors (zeros elsewhere)."""
        torch = tb._torch()
        out = {}
        for k, v in info.items():
            if isinstance(v, dict):
                out[k] = self._full_info(v, it)
                continue
            if isinstance(v, torch.Tensor):
                t = v
            else:
                v = np.asarray(v)
                t = (torch.as_tensor(v, device=self.device) if v.dtype == np.bool_ else self._T(v))
            arr = torch.zeros((self.num_envs,) + tuple(t.shape[1:]), dtype=t.dtype, device=self.device)
            arr[it] = t
            out[k] = arr
        return out

    def _vector_info(self, infos: dict, mask, out: dict | None = None) -> dict:
        """Gymnasium's vector info dict (tensors): values where ``mask``, zeros elsewhere, ``"_key"`` masks."""
        torch = tb._torch()
        out = {} if out is None else out
        for k, v in infos.items():
            if isinstance(v, dict):
                out[k] = self._vector_info(v, mask, out.get(k))
                out["_" + k] = mask.clone() if "_" + k not in out else out["_" + k] | mask
                continue
            m = mask.reshape((-1,) + (1,) * (v.ndim - 1))
            if k in out:
                out[k] = torch.where(m, v, out[k])
                out["_" + k] = out["_" + k] | mask
            else:
                out[k] = torch.where(m, v, torch.zeros_like(v))
                out["_" + k] = mask.clone()
        return out

    def _delayed(self, action):
        """``action_delay`` (``BatchedTask.act``): the action given that many steps earlier."""
        torch = tb._torch()
        if not self._queue.shape[1]:
            return action
        out = self._queue[:, 0]
        self._queue = torch.cat([self._queue[:, 1:], action[:, None]], dim=1)
        return out

    def _advance(self, fn, state):
        """``frame_skip`` physics steps ``fn(n, *state) -> state`` (``state[1]``: the velocities);
        with robot sensors as ``frame_skip - 1`` steps, then 1 (the same arithmetic), keeping the
        velocities before the last physics step (what the IMUs read), as ``BatchedTask.simulate``
        does. Returns ``(state, qd_prev)`` (``qd_prev`` None without sensors)."""
        n = self.task.frame_skip
        if self._sens is None:
            return fn(n, *state), None
        mid = fn(n - 1, *state)
        return fn(1, *mid), mid[1]

    def _physics_inputs(self):
        """``rest_length`` / ``force_density`` (N, m) of the current controls, the cables'
        rest-length offsets added (``BatchedTask.with_offset``)."""
        inputs = tb.physics_inputs(self.task.actuation, self.ctrl)
        if self._rest_offset is not None and inputs.get("rest_length") is not None:
            inputs["rest_length"] = inputs["rest_length"] + self._rest_offset
        return inputs

    def _check_actions(self, actions):
        """``(actions clipped to the box, any env to autoreset)`` after ONE small device -> host
        read (:func:`tensegrity_gym.checks.check_action_tensor`)."""
        return check_action_tensor(actions, (self.num_envs, self.task.action_size), self.device, self.dtype,
                                   self.task.clip_actions, self._autoreset.any())

    # ------------------------------------------------------------------ VectorEnv API
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        torch = tb._torch()
        super().reset(seed=None)
        mask, options = self._reset_mask(options)
        if self._streams is not None:
            self._streams.seed(seed, mask)
        else:
            reseed(self._rngs, seed, mask)
        if self._sens is not None:
            self._sens.seed(seed, mask)
        mask_t = torch.as_tensor(mask, device=self.device)
        info = self._reset_envs(mask_t, options or None)
        self._reset_called = True
        return self._observe(), self._vector_info(info, mask_t)

    def step(self, actions):
        check_reset_called(self)
        torch = tb._torch()
        a, any_reset = self._check_actions(actions)
        reset_now = self._autoreset.clone()
        if any_reset:
            a = torch.where(reset_now[:, None], torch.zeros_like(a), a)
        terms, infos = self._act(a)
        reward = None
        for v in terms.values():                      # rewards.combine: the terms in order
            reward = v if reward is None else reward + v
        diverged = infos["diverged"]
        terminated = torch.zeros_like(diverged)      # neither task terminates
        truncated = diverged.clone()
        if self.max_episode_steps is not None:
            truncated = truncated | (self.elapsed >= self.max_episode_steps)
        all_infos = dict(infos)
        for name, v in terms.items():
            all_infos[f"reward_{name}"] = v
        out = self._vector_info(all_infos, ~reset_now)
        if any_reset:
            rinfo = self._reset_envs(reset_now, None)
            self._vector_info(rinfo, reset_now, out)
            reward = torch.where(reset_now, torch.zeros_like(reward), reward)
            terminated = terminated & ~reset_now
            truncated = truncated & ~reset_now
        self._autoreset = terminated | truncated
        return self._observe(), reward, terminated, truncated, out

    def close_extras(self, **kwargs):
        pass


def __getattr__(name):   # the task envs live in torch_tasks.py (imported on first use)
    if name in ("TorchRollVectorEnv", "TorchShapeVectorEnv"):
        from . import torch_tasks
        return getattr(torch_tasks, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
