"""The device-resident vector env shell: a batched task stepped on a torch device (seeding,
resets on the host or the device, Gymnasium vector infos, action checks, selectable autoreset).
What runs where: :mod:`tensegrity_gym.envs.torch_vec`; the two tasks:
:mod:`tensegrity_gym.envs.torch_tasks`. SI units."""
from __future__ import annotations

from typing import Sequence

import numpy as np
import gymnasium as gym
from gymnasium import spaces
from gymnasium.utils import seeding

from ..backends.torch.model import resolve_device, resolve_dtype, torch_model, torch_module, torch_params
from ..backends.torch.driver import integrator_name, step_once
from ..backends.torch.actuation import physics_inputs
from ..backends.torch.contact import contact_substep
from ..backends.torch.rod_contact import rod_contact_substep
from ..backends.torch.graphs import CapturedCall
from ..core.checks import check_action_tensor
from .vector_rules import check_reset_called
from .shells import VectorSeeding, episode_limit, reseed
from .torch_reset import RESET_SAMPLING, CounterStreams, TorchDomain
from .torch_record import TorchRecord
from .torch_sensors import TorchSensors

__all__ = ["TorchTaskVectorEnv"]


class TorchTaskVectorEnv(TorchRecord, VectorSeeding, gym.vector.VectorEnv):
    """A batched task (:class:`~tensegrity_gym.envs.common.BatchedTask`) stepped on a torch
    device: seeding, resets on the host, Gymnasium vector infos, action checks, autoreset as
    the NumPy vector env's ``autoreset_mode`` (``"next_step"`` default, ``"same_step"``: then
    ``info["final_obs"]`` is an (N, obs_size) tensor, valid where ``info["_final_obs"]``, and
    ``info["final_info"]`` a vector info dict of tensors; ``"disabled"``).

    The env is the task's record on the device (:mod:`tensegrity_gym.tasks.state`): one tensor
    attribute per field of the task's ``STATE`` and ``CONSTANTS``, built here from the host task
    and copied row by row after each host reset. Subclasses set ``ENV_ID`` and ``TASK`` (the
    task class) and implement ``_init_device`` (the physics' own device arrays), ``_act``
    (``-> (terms, terminated or None, infos)``) and ``_observe``.

    Arguments: those of the id's env plus ``device`` (``"cpu"``, ``"cuda"``, ``"cuda:1"``; ValueError when it does not exist),
    ``dtype`` (``"float64"`` default or ``"float32"``; anything else is a ValueError) and
    ``max_episode_steps`` (control steps; ``"registered"``: the id's 1000; None: no limit) and
    ``compile`` (default False: wrap the task's physics step in ``torch.compile``; the
    first steps then compile for tens of seconds; measured in ``docs/bench_gpu.md``) and
    ``reset_sampling`` (``"host"`` default: resets drawn from the per-env NumPy generators, the
    NumPy env's numbers; ``"device"``: drawn and applied on the device from per-env counter-based
    streams, :mod:`tensegrity_gym.envs.torch_reset`; tasks with ``DEVICE_RESET``) and
    ``cuda_graph`` (default False; True on a CUDA device with ``compile=True``: each control
    step's physics, ``frame_skip`` compiled sub-steps, is captured once as a CUDA graph and
    replayed, :class:`~tensegrity_gym.backends.torch.graphs.CapturedCall`: one graph launch
    instead of hundreds of kernel launches; the graph holds its own compile of the physics,
    whose float32 results can differ from ``compile=True``'s alone in the last bits).
    """

    #: the task can reset on the device (``reset_sampling="device"``): it implements
    #: ``_reset_draws`` and ``_device_reset_rows``
    DEVICE_RESET = False
    _NO_DEVICE_RESET = ""     # why not, for the error message

    metadata = {"render_modes": [], "render_fps": 50, "autoreset_mode": gym.vector.AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, max_episode_steps="registered", device=None, dtype=None,
                 backend: str = "torch", render_mode: str | None = None, compile: bool = False,
                 reset_sampling: str = "host", autoreset_mode="next_step", cuda_graph: bool = False, **kwargs):
        torch = torch_module()
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
        self.device = resolve_device(device)
        self.dtype = resolve_dtype(dtype)
        task = self.TASK(num_envs=num_envs, **kwargs)
        integrator_name(task.integrator)          # ValueError for an implicit method
        self.task = task
        self.num_envs = N = task.num_envs
        self.max_episode_steps = episode_limit(max_episode_steps, self.ENV_ID)
        self.render_mode = None
        self.metadata = dict(self.metadata)
        self.metadata["render_fps"] = int(round(1.0 / task.control_dt))
        self._init_autoreset(autoreset_mode)
        np_dtype = np.float64 if self.dtype == torch.float64 else np.float32
        self.single_action_space = spaces.Box(-1.0, 1.0, (task.action_size,), np.float32)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (task.observation_size,), np_dtype)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, N)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, N)
        self._rngs: list[np.random.Generator] = [seeding.np_random(None)[0] for _ in range(N)]

        dev, dt = self.device, self.dtype
        self.tm = torch_model(task.model, dev, dt)
        self._node_prm = torch_params(self.tm, None)          # model defaults (anchor positions)
        self._init_state()
        sens = getattr(task, "sensors", None)      # observation_mode="robot": the readings on the device
        self._sens = None if sens is None else TorchSensors(sens, self)
        self.elapsed = torch.zeros(N, dtype=torch.int64, device=dev)
        self._autoreset = torch.zeros(N, dtype=torch.bool, device=dev)
        self._queue = torch.zeros((N, task.action_delay, task.action_size), dtype=dt, device=dev)
        if not isinstance(compile, (bool, np.bool_)):
            raise ValueError(f"compile: expected True or False, got {compile!r}")
        # compile: the one physics step each task repeats (with contact: contact forces + integrator step)
        one, options = self._physics_substep()
        # with rod-rod contact the substep adds its forces (backends.torch.rod_contact), compiled or not
        self._substep = torch.compile(one, dynamic=False, options=options) if compile else \
            (one if getattr(task, "rod_contact", None) is not None else None)
        if not isinstance(cuda_graph, (bool, np.bool_)):
            raise ValueError(f"cuda_graph: expected True or False, got {cuda_graph!r}")
        if cuda_graph and self.device.type != "cuda":
            raise ValueError(f"cuda_graph: needs a CUDA device, got device={str(self.device)!r}")
        if cuda_graph and not compile:
            raise ValueError("cuda_graph: needs compile=True (the eager physics launches thousands of kernels per "
                             "control step and reads back from the device on terrain)")
        self._graphs = {} if cuda_graph else None     # physics function -> its CapturedCall
        # per-copy parameters (domain): uploaded whole here, by reset rows when randomised
        self._upload_domain(None)
        self.reset_sampling = reset_sampling
        self._streams = self._tdomain = None
        if reset_sampling == "device":     # envs/torch_reset.py: per-env counter-based streams on the device
            self._streams = CounterStreams(N, dev)
            self._tdomain = TorchDomain(self) if task.domain.enabled else None

    def _physics_substep(self):
        """``(the one physics step the task repeats, inductor options or None)``: what
        ``compile=True`` wraps and how. With ground contact
        :func:`~tensegrity_gym.backends.torch.contact.contact_substep`, without
        :func:`~tensegrity_gym.backends.torch.driver.step_once`; default options. With ground and
        rod-rod contact :func:`~tensegrity_gym.backends.torch.rod_contact.rod_contact_substep`."""
        if getattr(self.task, "rod_contact", None) is not None and getattr(self.task, "contact", None) is not None:
            return rod_contact_substep(self.task.rod_contact), None
        return (contact_substep if getattr(self.task, "contact", None) is not None
                else step_once), None

    def _physics_call(self, fn):
        """``fn`` (a physics loop of :mod:`tensegrity_gym.backends.torch`), or with ``cuda_graph=True``
        its :class:`~tensegrity_gym.backends.torch.graphs.CapturedCall` (one per function)."""
        if self._graphs is None:
            return fn
        call = self._graphs.get(fn)
        if call is None:
            call = self._graphs[fn] = CapturedCall(fn)
        return call

    # ------------------------------------------------------------------ resets and infos
    def _reset_envs(self, mask, options) -> dict:
        """Reset the envs where ``mask`` (N,) bool (a device tensor) is true: drawn on the host
        (one upload of their rows) or on the device (``reset_sampling``); infos as (N,) tensors."""
        torch = torch_module()
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
        torch = torch_module()
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
        torch = torch_module()
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
        torch = torch_module()
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
        inputs = physics_inputs(self.task.actuation, self.ctrl)
        if self._rest_offset is not None and inputs.get("rest_length") is not None:
            inputs["rest_length"] = inputs["rest_length"] + self._rest_offset
        return inputs

    def _check_actions(self, actions):
        """``(actions clipped to the box, any env to autoreset)`` after ONE small device -> host
        read (:func:`tensegrity_gym.core.checks.check_action_tensor`)."""
        return check_action_tensor(actions, (self.num_envs, self.task.action_size), self.device, self.dtype,
                                   self.task.clip_actions, self._autoreset.any())

    # ------------------------------------------------------------------ VectorEnv API
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        torch = torch_module()
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
        torch = torch_module()
        a, any_reset = self._check_actions(actions)
        mode = self.autoreset_mode
        if any_reset and mode is gym.vector.AutoresetMode.DISABLED:
            ended = self._autoreset.nonzero()[:, 0].tolist()
            raise gym.error.ResetNeeded(f"autoreset_mode='disabled': envs {ended} ended; reset them "
                                        "(reset(options={'env_idx': idx}) or {'reset_mask': mask}) before stepping them")
        reset_now = self._autoreset.clone()
        if any_reset:
            a = torch.where(reset_now[:, None], torch.zeros_like(a), a)
        terms, terminated, infos = self._act(a)
        reward = None
        for v in terms.values():                      # rewards.combine: the terms in order
            reward = v if reward is None else reward + v
        diverged = infos["diverged"]
        terminated = torch.zeros_like(diverged) if terminated is None else terminated.clone()
        truncated = diverged.clone()
        if self.max_episode_steps is not None:
            truncated = truncated | (self.elapsed >= self.max_episode_steps)
        all_infos = dict(infos)
        for name, v in terms.items():
            all_infos[f"reward_{name}"] = v
        if mode is gym.vector.AutoresetMode.SAME_STEP:
            return self._same_step(reward, terminated, truncated, all_infos)
        out = self._vector_info(all_infos, ~reset_now)
        if any_reset:
            rinfo = self._reset_envs(reset_now, None)
            self._vector_info(rinfo, reset_now, out)
            reward = torch.where(reset_now, torch.zeros_like(reward), reward)
            terminated = terminated & ~reset_now
            truncated = truncated & ~reset_now
        self._autoreset = terminated | truncated
        return self._observe(), reward, terminated, truncated, out

    def _same_step(self, reward, terminated, truncated, all_infos):
        """SAME_STEP: the envs that ended are reset in this step (one more small device -> host
        read: whether any ended); ``info["final_obs"]`` (N, obs_size) holds the observation
        before the reset, ``info["final_info"]`` that step's infos, both masked by ``done``."""
        done = terminated | truncated
        obs = self._observe()
        if not bool(done.any()):
            return obs, reward, terminated, truncated, self._vector_info(all_infos, ~done)
        out = self._vector_info(all_infos, ~done)
        out["final_obs"], out["_final_obs"] = obs.clone(), done.clone()
        out["final_info"], out["_final_info"] = self._vector_info(all_infos, done), done.clone()
        rinfo = self._reset_envs(done, None)
        self._vector_info(rinfo, done, out)
        return self._observe(), reward, terminated, truncated, out

    def render(self):
        """None with a warning (the torch env does not render; render the NumPy env); a trainer
        that renders every step (skrl's default) runs on."""
        gym.logger.warn(f"render(): backend='torch' does not render; render the NumPy env "
                        f"(gymnasium.make({self.ENV_ID!r}, render_mode='rgb_array'))")
        return None

    def close_extras(self, **kwargs):
        if self._graphs:
            self._graphs.clear()      # the graphs' buffers and memory pools
