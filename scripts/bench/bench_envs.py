#!/usr/bin/env python
"""Env-steps per second of the tensegrity envs under each way of running N copies.

For N = 1, 16, 256, 4096 (``--n-envs``) and ``TensegrityShape-v0`` (default) or
``TensegrityRoll-v0`` (``--env roll`` / ``--env all``) it measures, in one process, wall clock:

``batched``       ``gymnasium.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")``:
                  our batched vector env (one batched physics call per step for all N);
``batched_sb3``   the same env through our SB3 adapter ``make_sb3_vec_env`` (a SB3 ``VecEnv``);
``sync``          ``gymnasium.vector.SyncVectorEnv`` of N single envs (``gymnasium.make(id)``);
``async``         ``gymnasium.vector.AsyncVectorEnv`` of N single envs (one process per env,
                  shared memory); only for N <= ``--max-procs``, otherwise 'skipped (why)';
``sb3_dummy``     SB3 ``DummyVecEnv`` of N single envs;
``sb3_subproc``   SB3 ``SubprocVecEnv`` of N single envs (one process per env, same cap);
``mujoco_sync``   a minimal ``gymnasium.Env`` around MuJoCo's model of the *free* 3-bar prism
                  (the MJCF builder :func:`bench_dynamics.mjcf`, imported, not copied), same
                  ``dt`` and ``frame_skip`` as our env, actions change each tendon's rest length
                  (``tendon_lengthspring``) like our ``rest_length`` mode, stepped with ``SyncVectorEnv``;
``mujoco_async``  the same with ``AsyncVectorEnv`` (N <= ``--max-procs``).

Each cell is env-steps/s = N x vector steps / seconds over a window of ``--seconds`` after a
warm-up (numba kernels compiled or loaded, envs reset, a few vector steps). Actions are drawn
from the action space before timing (``action_space.sample()``, a pool of 16 batches cycled):
sampling is not timed. Episode ends met inside the window (autoresets) are timed: they are
part of the throughput. The column ``batched / best other`` divides the batched env by the
best of sync, async, sb3_dummy, sb3_subproc, mujoco_sync and mujoco_async at that N.

Single envs of ``sync`` and ``sb3_dummy`` are deep copies of one ``gymnasium.make(id)`` env
that was reset with seed 0 (cheap to build at N = 4096; ``make`` + ``reset`` per env would
cost N x the per-env time printed in the setup column of N = 1); the process-based methods
build and reset each env in its own worker.

It also times, for N = 1, the single env's ``step()`` (``env.unwrapped.step`` and through the
wrappers of ``gymnasium.make``) against the physics it runs: the integrator call(s) the env
makes for ``frame_skip`` physics steps, with the same arguments, from the same state (see
``physics_callables``); target step() / physics <= 2.

Usage::

    .venv/bin/python -m scripts.bench.bench_envs                     # shape env, ~3-4 min, writes results/bench_envs.*
    .venv/bin/python -m scripts.bench.bench_envs --env all           # both envs (~7 min)
    .venv/bin/python -m scripts.bench.bench_envs --quick             # CI-size smoke run (N = 1, 16; short windows; no files)
    .venv/bin/python -m scripts.bench.bench_envs --n-envs 1 256 --seconds 1 --out runs/b

Targets: batched vector env >= 10x the best of the others at N = 4096; single-env
step() <= 2x its physics.
"""
from __future__ import annotations

import argparse
import copy
import csv
import functools
import json
import math
import os
import platform
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

import gymnasium as gym  # noqa: E402
from gymnasium import spaces  # noqa: E402

import tensegrity_gym  # noqa: E402,F401  (registers the env ids)
from tensegrity_gym.core import builders  # noqa: E402
from tensegrity_gym.backends.numba.api import step_inplace  # noqa: E402
from tensegrity_gym.core.model import State, compile_model  # noqa: E402
from tensegrity_gym.core.errors import StabilityWarning  # noqa: E402
from scripts._bench import interleaved_windows, mjcf  # noqa: E402  (MJCF of the free prism, shared with bench_dynamics)
from tensegrity_gym.integrations.sb3 import make_sb3_vec_env  # noqa: E402

ENV_IDS = {"shape": "TensegrityShape-v0", "roll": "TensegrityRoll-v0"}
METHODS = {
    "batched": "batched vector env (make_vec, vector_entry_point)",
    "batched_sb3": "batched env via make_sb3_vec_env (SB3 VecEnv)",
    "sync": "gymnasium SyncVectorEnv of single envs",
    "async": "gymnasium AsyncVectorEnv of single envs (shared memory, 1 process/env)",
    "sb3_dummy": "SB3 DummyVecEnv of single envs",
    "sb3_subproc": "SB3 SubprocVecEnv of single envs (1 process/env)",
    "mujoco_sync": "MuJoCo free prism env, SyncVectorEnv",
    "mujoco_async": "MuJoCo free prism env, AsyncVectorEnv (1 process/env)",
}
OTHERS = ("sync", "async", "sb3_dummy", "sb3_subproc", "mujoco_sync", "mujoco_async")
PROCESS_METHODS = ("async", "sb3_subproc", "mujoco_async")
ACTION_POOL = 16


# ---------------------------------------------------------------------------- helpers
def _make_single(env_id: str):
    """``gymnasium.make(env_id)`` (module-level so that worker processes can unpickle it)."""
    import gymnasium
    import tensegrity_gym  # noqa: F401  (registers the ids in a fresh worker)
    return gymnasium.make(env_id)


def presample(single_space: spaces.Box, n: int, k: int = ACTION_POOL, seed: int = 0) -> list[np.ndarray]:
    """``k`` batches of ``n`` actions drawn from the (batched) action space before timing."""
    space = gym.vector.utils.batch_space(single_space, n)
    space.seed(seed)
    return [np.ascontiguousarray(space.sample()) for _ in range(k)]


def time_window(step, actions, seconds: float) -> tuple[int, float]:
    """Call ``step(action)`` with the pre-sampled actions (cycled) for at least ``seconds`` s
    and at least once. Returns (vector steps, elapsed s)."""
    n, k = 0, len(actions)
    t0 = time.perf_counter()
    while True:
        step(actions[n % k])
        n += 1
        el = time.perf_counter() - t0
        if el >= seconds:
            return n, el


def warm(step, actions, n_warm: int, budget: float) -> float:
    """Up to ``n_warm`` untimed vector steps, stopping once ``budget`` s is spent. Returns the
    duration of the last one (s), an estimate of one vector step."""
    last = 0.0
    t_start = time.perf_counter()
    for i in range(n_warm):
        t0 = time.perf_counter()
        step(actions[i % len(actions)])
        last = time.perf_counter() - t0
        if time.perf_counter() - t_start > budget:
            break
    return last


def proc_mem_mb(pid: int) -> float | None:
    """Proportional set size (MB) of a process (shared pages split between sharers); RSS if
    smaps_rollup is unavailable; None if unreadable."""
    try:
        text = Path(f"/proc/{pid}/smaps_rollup").read_text()
        for line in text.splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def self_rss_mb() -> float | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


# ---------------------------------------------------------------------------- MuJoCo env
class MujocoPrismEnv(gym.Env):
    """Minimal ``gymnasium.Env``: MuJoCo's free 3-bar prism (``bench_dynamics.mjcf``: rods as
    free bodies, strings as spatial tendons with a dead band ``springlength = [0, l0]``, no
    gravity, no damping, no contact), semi-implicit Euler at ``dt`` s, ``frame_skip`` ``mj_step``
    substeps per control step (one ``mj_step(m, d, nstep=frame_skip)`` call).

    Action: ``Box(-1, 1, (m,))``, one per string: rest length l0_i += a_i ``max_speed`` dt
    frame_skip (m), clipped to [0.8, 1.1] x the nominal rest length (as our ``rest_length``
    action mode). Observation (float32): qpos (7 per rod), qvel (6 per rod), rest lengths (m).
    Reward: -0.01 |a|^2. No termination (the time limit comes from a ``TimeLimit`` wrapper).
    """

    metadata = {"render_modes": []}

    def __init__(self, xml: str, rest_length, dt: float, frame_skip: int, max_speed: float = 0.1,
                 bounds=(0.8, 1.1)):
        import mujoco
        self.model = mujoco.MjModel.from_xml_string(xml)
        if abs(self.model.opt.timestep - dt) > 1e-15:
            raise ValueError(f"dt: the MJCF timestep {self.model.opt.timestep} s differs from dt = {dt} s")
        self.data = mujoco.MjData(self.model)
        self.frame_skip = int(frame_skip)
        self.l0 = np.asarray(rest_length, float).copy()
        self.low, self.high = bounds[0] * self.l0, bounds[1] * self.l0
        self.rate = max_speed * dt * self.frame_skip
        m = self.l0.size
        self.action_space = spaces.Box(-1.0, 1.0, (m,), np.float32)
        nobs = self.model.nq + self.model.nv + m
        self.observation_space = spaces.Box(-np.inf, np.inf, (nobs,), np.float32)
        self._qpos0 = self.data.qpos.copy()
        self.rest = self.l0.copy()

    def _obs(self):
        d = self.data
        return np.concatenate([d.qpos, d.qvel, self.rest]).astype(np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        import mujoco
        mujoco.mj_resetData(self.model, self.data)
        self.data.qvel[:] = self.np_random.uniform(-5e-3, 5e-3, self.model.nv)
        self.rest = self.l0.copy()
        self.model.tendon_lengthspring[:, 1] = self.rest
        mujoco.mj_forward(self.model, self.data)
        return self._obs(), {}

    def step(self, action):
        a = np.clip(np.asarray(action, np.float64), -1.0, 1.0)
        self.rest = np.clip(self.rest + a * self.rate, self.low, self.high)
        self.model.tendon_lengthspring[:, 1] = self.rest
        import mujoco
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        return self._obs(), float(-0.01 * (a @ a)), False, False, {}


def _make_mujoco(xml, rest_length, dt, frame_skip, max_episode_steps):
    """The MuJoCo env with the wrappers ``gymnasium.make`` adds to ours (checker, order, time limit)."""
    from gymnasium.wrappers import OrderEnforcing, PassiveEnvChecker, TimeLimit
    env = MujocoPrismEnv(xml, rest_length, dt, frame_skip)
    return TimeLimit(OrderEnforcing(PassiveEnvChecker(env)), max_episode_steps)


def mujoco_factory(env_id: str):
    """``(env_fn, description)`` of the MuJoCo baseline with our env's dt, frame_skip and time limit."""
    probe = gym.make(env_id)
    task = probe.unwrapped.task
    dt, fs = task.dt, task.frame_skip
    mes = probe.spec.max_episode_steps or 1000
    probe.close()
    model = compile_model(builders.prism(3))
    xml = mjcf(model, "Euler", dt=dt)
    fn = functools.partial(_make_mujoco, xml, model.rest_length.copy(), dt, fs, mes)
    desc = (f"free 3-bar prism (builders.prism(3): {model.n_bars} rods, {model.n_strings} strings), MJCF from "
            f"bench_dynamics.mjcf, integrator Euler, dt = {dt} s, frame_skip = {fs}, time limit {mes} steps; "
            "no gravity, no string damping, no node drag, no contact")
    return fn, desc


# ---------------------------------------------------------------------------- one cell
class Skip(Exception):
    pass


def _copies(env_fn, n: int, seed: int = 0):
    """``n`` deep copies of one env built by ``env_fn`` and reset with ``seed``."""
    proto = env_fn()
    proto.reset(seed=seed)
    envs = [copy.deepcopy(proto) for _ in range(n)]
    proto.close()
    return envs


def run_cell(method: str, env_id: str, n: int, args, ctx: dict) -> dict:
    """Build, warm up and time one (method, N) cell. Returns a row dict."""
    row = dict(env_id=env_id, method=method, n_envs=n, status="ok", env_steps_per_s=None, vector_steps=None,
               seconds=None, setup_s=None, reset_s=None, reset_estimated=False, env_steps_per_s_with_resets=None,
               note="")
    t_setup = time.perf_counter()
    venv = None
    try:
        single_t = ctx.get("single_step_s")
        if method in PROCESS_METHODS and n > args.max_procs:
            mem = ctx.get("worker_mb")
            memtxt = f", ~{mem:.0f} MB each (PSS measured at N = 1)" if mem else ""
            if n >= 1024:
                raise Skip(f"not feasible: one process per env = {n} processes on {os.cpu_count()} cores"
                           f"{memtxt}")
            raise Skip(f"{n} processes (one per env) on {os.cpu_count()} cores{memtxt}; cap --max-procs = "
                       f"{args.max_procs}")
        if method in ("sync", "sb3_dummy") and single_t and n * single_t > args.max_step_s:
            raise Skip(f"one vector step would take ~{n * single_t:.0f} s (> --max-step-s {args.max_step_s})")
        if method == "mujoco_async" or method == "mujoco_sync":
            mj_fn = ctx["mujoco_fn"]
        if method == "batched":
            venv = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
            venv.reset(seed=0)
            space, step = venv.single_action_space, venv.step
        elif method == "batched_sb3":
            inner = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
            venv = make_sb3_vec_env(inner)
            venv.seed(0)
            venv.reset()
            space, step = venv.action_space, venv.step
        elif method == "sync":
            envs = _copies(functools.partial(_make_single, env_id), n)
            venv = gym.vector.SyncVectorEnv([(lambda e=e: e) for e in envs])
            space, step = venv.single_action_space, venv.step
        elif method == "sb3_dummy":
            from stable_baselines3.common.vec_env import DummyVecEnv
            envs = _copies(functools.partial(_make_single, env_id), n)
            venv = DummyVecEnv([(lambda e=e: e) for e in envs])
            space, step = venv.action_space, venv.step
        elif method == "async":
            venv = gym.vector.AsyncVectorEnv([functools.partial(_make_single, env_id)] * n, shared_memory=True,
                                             context=args.mp_context)
            venv.reset(seed=0)
            space, step = venv.single_action_space, venv.step
        elif method == "sb3_subproc":
            from stable_baselines3.common.vec_env import SubprocVecEnv
            venv = SubprocVecEnv([functools.partial(_make_single, env_id)] * n, start_method=args.mp_context)
            venv.seed(0)
            venv.reset()
            space, step = venv.action_space, venv.step
        elif method == "mujoco_sync":
            envs = _copies(mj_fn, n)
            venv = gym.vector.SyncVectorEnv([(lambda e=e: e) for e in envs])
            space, step = venv.single_action_space, venv.step
        elif method == "mujoco_async":
            venv = gym.vector.AsyncVectorEnv([mj_fn] * n, shared_memory=True, context=args.mp_context)
            venv.reset(seed=0)
            space, step = venv.single_action_space, venv.step
        else:
            raise ValueError(f"method: unknown {method!r}")
        actions = presample(space, n)
        last = warm(step, actions, args.warm_steps, budget=max(args.seconds, 1.0))
        row["setup_s"] = time.perf_counter() - t_setup
        if last > args.max_step_s:
            raise Skip(f"one vector step took {last:.1f} s (> --max-step-s {args.max_step_s})")
        if method in ("async", "sb3_subproc") and n == 1 and "worker_mb" not in ctx:
            procs = getattr(venv, "processes", [])
            mems = [m for m in (proc_mem_mb(p.pid) for p in procs) if m is not None]
            if mems:
                ctx["worker_mb"] = float(np.mean(mems))
        steps, el = time_window(step, actions, args.seconds)
        row.update(env_steps_per_s=n * steps / el, vector_steps=steps, seconds=el)
        # cost of resetting all N envs once (what one episode end of every env costs), untimed above
        if method in ("sync", "sb3_dummy") and n > 16:
            row.update(reset_s=n * ctx["single_reset_s"], reset_estimated=True)     # a Python loop of N resets
        else:
            t0 = time.perf_counter()
            venv.reset() if method.startswith(("batched_sb3", "sb3")) else venv.reset(seed=1)
            row["reset_s"] = time.perf_counter() - t0
        E = ctx["episode_steps"]
        row["env_steps_per_s_with_resets"] = n * E / (E * el / steps + row["reset_s"])
        if method == "batched" and n == 1:
            ctx["batched1_step_s"] = el / steps
        if method == "sync" and n == 1:
            ctx["single_step_s"] = el / steps
        if method == "sync" and n > 1:
            row["note"] = "envs are deep copies of one reset env"
    except Skip as e:
        row.update(status="skipped", note=str(e))
        if row["setup_s"] is None:
            row["setup_s"] = time.perf_counter() - t_setup
    finally:
        if venv is not None:
            try:
                venv.close()
            except Exception as e:  # pragma: no cover - report, do not hide
                row["note"] += f" (close failed: {e!r})"
    return row


# ---------------------------------------------------------------------------- step() vs physics
class _Recorder:
    """Spies on the physics entry points (``physics.integrate.step``, ``backends.numba.api.step``,
    ``api.step_inplace``, ``physics.pipeline.run_steps``: integrator calls;
    ``physics.contact.forces_inplace``: force evaluation)
    while the env runs ONE control step, recording each outermost call. Arrays and contact
    states passed to them are recorded by identity, with a snapshot taken the first time each
    is seen (before any recorded call changed it), so a replay can recreate the same buffers,
    shared between calls exactly as the env shares them. The patches live only in this process
    and are removed on exit."""

    SPIED = (("integrate", "step", "integrator"), ("api", "step", "integrator"),
             ("api", "step_inplace", "integrator"), ("contact", "forces_inplace", "force"),
             ("pipeline", "run_steps", "integrator"))    # the env pipeline's in-place steps (contact inside)

    def __init__(self):
        from tensegrity_gym.backends.numba import api
        from tensegrity_gym.physics import contact, integrate, pipeline
        self.modules = {"integrate": integrate, "api": api, "contact": contact, "pipeline": pipeline}
        self.calls: list = []
        self.buffers: dict = {}          # id -> (original object kept alive, snapshot)
        self._depth = 0
        self._saved = []

    def __enter__(self):
        for mod_name, fn_name, kind in self.SPIED:
            mod = self.modules[mod_name]
            orig = getattr(mod, fn_name)
            self._saved.append((mod, fn_name, orig))
            setattr(mod, fn_name, self._wrap(orig, f"{mod_name}.{fn_name}", kind))
        return self

    def __exit__(self, *exc):
        for mod, fn_name, orig in reversed(self._saved):
            setattr(mod, fn_name, orig)
        return False

    def _ref(self, x):
        if isinstance(x, np.ndarray) or (hasattr(x, "anchor") and hasattr(x, "active")):
            if id(x) not in self.buffers:
                self.buffers[id(x)] = (x, copy.deepcopy(x))
            return ("buf", id(x))
        if isinstance(x, State):     # physics.integrate.step never modifies its input state
            return ("val", State(np.array(x.q, copy=True), np.array(x.qd, copy=True), x.t))
        return ("val", x)                # models, parameter objects, scalars, strings, None

    def _wrap(self, orig, label, kind):
        def spy(*args, **kwargs):
            if self._depth == 0:
                self.calls.append((orig, label, kind, [self._ref(v) for v in args],
                                   {k: self._ref(v) for k, v in kwargs.items()}, kwargs.get("n_steps", 1)))
            self._depth += 1
            try:
                return orig(*args, **kwargs)
            finally:
                self._depth -= 1
        return spy

    def replayer(self, kinds):
        """A callable that refills every recorded buffer from its snapshot once, then redoes the
        recorded calls of ``kinds`` in order on those buffers (same work as the env's control
        step; the refill is a few tiny array copies)."""
        work, refill = {}, []
        for key, (_, snapv) in self.buffers.items():
            w = copy.deepcopy(snapv)
            work[key] = w
            if isinstance(w, np.ndarray):
                refill.append((w, snapv))
            else:
                refill += [(w.anchor, snapv.anchor), (w.active, snapv.active)]
        plan = []
        for orig, label, kind, args, kwargs, _ in self.calls:
            if kind in kinds:
                a = tuple(work[v] if t == "buf" else v for t, v in args)
                kw = {k: (work[v] if t == "buf" else v) for k, (t, v) in kwargs.items()}
                plan.append((orig, a, kw))

        def replay():
            for w, v in refill:
                np.copyto(w, v)
            for orig, a, kw in plan:
                orig(*a, **kw)
        return replay


def physics_callables(env) -> tuple[dict, str]:
    """Callables that redo the physics of one control step of the single env ``env`` exactly as
    its task runs it, found by recording the calls the env makes during one ``step`` (see
    :class:`_Recorder`; the env is then put back to its pre-step state):

    ``integrator``   only the recorded integrator call(s) (``integrate.step`` /
                     ``api.step_inplace`` / ``pipeline.run_steps``, whose contact steps
                     are inside it), same arguments, same input states;
    ``with_forces``  all recorded calls in order, force evaluations (``contact.forces_inplace``)
                     included;
    ``kernel_floor`` one compiled-kernel call ``backends.numba.api.step_inplace(..., n_steps=frame_skip)``
                     of the same model and controls without external forces.
    """
    task = env.unwrapped.task
    model, dt, fs, name = task.model, task.dt, task.frame_skip, task.integrator
    snap = {k: copy.deepcopy(v) for k, v in vars(task).items() if isinstance(v, np.ndarray) or
            (hasattr(v, "anchor") and hasattr(v, "active"))}
    a = np.zeros(env.action_space.shape, np.float32)
    with _Recorder() as rec:
        env.unwrapped.step(a)
    for k, v in snap.items():                 # put the env back where it was
        setattr(task, k, v)
    if not rec.calls:
        raise RuntimeError(f"{type(task).__name__}: no integrator call recorded during step(); the benchmark "
                           "does not know this env's physics path")
    counts: dict = {}
    for _, label, _, _, _, n_steps in rec.calls:
        key = label + (f"(n_steps={n_steps})" if n_steps != 1 else "")
        counts[key] = counts.get(key, 0) + 1
    desc = " + ".join(f"{n} x {k}" for k, n in counts.items()) + " per control step"
    out = {"integrator": rec.replayer(("integrator",)), "with_forces": rec.replayer(("integrator", "force"))}
    inputs = task.actuation.physics_inputs(task.ctrl)
    kin = {k: v for k, v in inputs.items() if v is not None}
    q0, qd0 = task.q.copy(), task.qd.copy()
    qf, qdf = q0.copy(), qd0.copy()

    def floor():
        np.copyto(qf, q0)
        np.copyto(qdf, qd0)
        step_inplace(model, qf, qdf, dt, name, n_steps=fs, **kin)
    out["kernel_floor"] = floor
    return out, desc


def best_mean(fn, seconds: float, repeats: int = 3) -> float:
    """Best over ``repeats`` windows of the mean wall time (s) of one call of ``fn``."""
    fn()
    best = math.inf
    for _ in range(repeats):
        n, t0 = 0, time.perf_counter()
        while True:
            fn()
            n += 1
            el = time.perf_counter() - t0
            if el >= seconds / repeats:
                break
        best = min(best, el / n)
    return best


def stepper(env, actions):
    """A callable that steps ``env`` once with the next pre-sampled action and returns the
    duration of the ``step`` call (s); an episode end is followed by an untimed reset."""
    state = {"i": 0}

    def fn():
        a = actions[state["i"] % len(actions)]
        state["i"] += 1
        t0 = time.perf_counter()
        _, _, term, trunc, _ = env.step(a)
        el = time.perf_counter() - t0
        if term or trunc:
            env.reset()
        return el
    return fn


def step_vs_physics(env_id: str, seconds: float) -> dict:
    env = gym.make(env_id)
    env.reset(seed=0)
    actions = [a[0] for a in presample(env.action_space, 1)]
    for a in actions[:5]:
        env.step(a)                                  # warm-up (kernels, checker)
    try:
        calls, desc = physics_callables(env)
    except RuntimeError as e:       # the shape env's fused compiled step calls no recordable integrator
        env.close()
        print(f"  {env_id}: step() vs physics not measured here ({e}); scripts/bench/bench_step_overhead.py measures it")
        return {"env_id": env_id, "skipped": str(e)}
    fns = {"step_unwrapped": stepper(env.unwrapped, actions), "step_wrapped": stepper(env, actions), **calls}
    t = interleaved_windows(fns, seconds)
    task = env.unwrapped.task
    res = dict(env_id=env_id, physics_path=desc, frame_skip=task.frame_skip, dt=task.dt,
               integrator=task.integrator, step_unwrapped_s=t["step_unwrapped"], step_wrapped_s=t["step_wrapped"],
               physics_integrator_s=t["integrator"], physics_with_forces_s=t["with_forces"],
               kernel_floor_s=t["kernel_floor"],
               ratio_step_over_integrator=t["step_unwrapped"] / t["integrator"],
               ratio_step_over_physics_with_forces=t["step_unwrapped"] / t["with_forces"],
               ratio_step_over_kernel_floor=t["step_unwrapped"] / t["kernel_floor"],
               ratio_wrapped_over_integrator=t["step_wrapped"] / t["integrator"])
    res["target_step_le_2x_physics_met"] = res["ratio_step_over_integrator"] <= 2.0
    env.close()
    return res


# ---------------------------------------------------------------------------- report
def fmt_rate(row, key="env_steps_per_s") -> str:
    if row is None:
        return "-"
    if row["status"] != "ok":
        return "skipped"
    return f"{row[key]:,.0f}"


def best_other(rows, env_id, n, key="env_steps_per_s", others=OTHERS):
    cand = [r for r in rows if r["env_id"] == env_id and r["n_envs"] == n and r["method"] in others
            and r["status"] == "ok" and r[key] is not None]
    return max(cand, key=lambda r: r[key]) if cand else None


def ratio_cell(rows, env_id, n, key, others) -> str:
    b = next((r for r in rows if r["env_id"] == env_id and r["n_envs"] == n and r["method"] == "batched"), None)
    o = best_other(rows, env_id, n, key, others)
    if b is None or b["status"] != "ok" or o is None:
        return "-"
    return f"{b[key] / o[key]:.1f}x ({o['method']})"


def table(rows, env_id, ns, methods, key="env_steps_per_s") -> list[str]:
    """Markdown table: one row per N, one column per method, then batched / best other (all
    others) and batched / best other that runs our single env (MuJoCo excluded)."""
    cols = list(methods) + ["batched / best other", "batched / best of ours-single"]
    lines = ["| N | " + " | ".join(cols) + " |", "|---:|" + "---:|" * len(cols)]
    ours_single = tuple(m for m in OTHERS if not m.startswith("mujoco"))
    for n in ns:
        get = {r["method"]: r for r in rows if r["env_id"] == env_id and r["n_envs"] == n}
        cells = [fmt_rate(get.get(m), key) for m in methods]
        cells.append(ratio_cell(rows, env_id, n, key, OTHERS))
        cells.append(ratio_cell(rows, env_id, n, key, ours_single))
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    return lines


def machine_info(args) -> dict:
    import numba
    info = dict(date=time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()), python=platform.python_version(),
                platform=platform.platform(), machine=platform.machine(), cores=os.cpu_count(),
                numpy=np.__version__, numba=numba.__version__, numba_threads=numba.get_num_threads(),
                gymnasium=gym.__version__)
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu"] = line.split(":", 1)[1].strip()
                break
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                info["mem_total_gb"] = round(int(line.split()[1]) / 2 ** 20, 1)
    except OSError:
        pass
    for mod in ("stable_baselines3", "torch", "mujoco"):
        try:
            info[mod] = __import__(mod).__version__
        except Exception as e:  # record, do not fail: the cells that need it will fail loudly
            info[mod] = f"unavailable ({type(e).__name__})"
    try:
        info["git_commit"] = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                                            text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, timeout=10).stdout
        info["git_dirty"] = bool(dirty.strip())
        info["git_modified_files"] = [ln[3:] for ln in dirty.splitlines() if ln.strip()]  # uncommitted changes
    except Exception:
        pass
    info["command"] = " ".join([Path(sys.executable).name, "-m", "scripts.bench.bench_envs"] + sys.argv[1:])
    info["mp_context"] = args.mp_context
    return info


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", default="shape",
                    help="shape, roll, all, or an env id (default shape = TensegrityShape-v0)")
    ap.add_argument("--n-envs", type=int, nargs="+", default=None, help="N values (default 1 16 256 4096)")
    ap.add_argument("--seconds", type=float, default=None, help="timed window per cell, s (default 2; --quick 0.3)")
    ap.add_argument("--quick", action="store_true", help="CI-size run: N = 1 16, short windows, 4 processes max, "
                    "no files written unless --out is given")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--max-procs", type=int, default=None,
                    help="largest N run with one process per env (default 16; --quick 4)")
    ap.add_argument("--max-step-s", type=float, default=30.0,
                    help="skip a cell whose single vector step takes longer than this, s (default 30)")
    ap.add_argument("--warm-steps", type=int, default=3, help="untimed vector steps before each window")
    ap.add_argument("--mp-context", default="forkserver", choices=("forkserver", "spawn", "fork"),
                    help="multiprocessing start method of the process-based vector envs (default forkserver, "
                    "SB3's default; fork is unsafe once numba's parallel kernel has run)")
    ap.add_argument("--out", default=None,
                    help="output prefix: writes PREFIX.csv and PREFIX.json (default results/bench_envs; "
                    "none with --quick)")
    args = ap.parse_args(argv)
    if args.env == "all":
        env_ids = list(ENV_IDS.values())
    else:
        env_ids = [ENV_IDS.get(args.env, args.env)]
    for e in env_ids:
        if e not in gym.registry:
            ap.error(f"--env: unknown env {e!r}; choose shape, roll, all or a registered id")
    ns = args.n_envs or ([1, 16] if args.quick else [1, 16, 256, 4096])
    if any(n < 1 for n in ns):
        ap.error(f"--n-envs: values must be >= 1, got {ns}")
    if args.seconds is None:
        args.seconds = 0.3 if args.quick else 2.0
    if not args.seconds > 0:
        ap.error(f"--seconds: must be > 0, got {args.seconds}")
    if args.max_procs is None:
        args.max_procs = 4 if args.quick else 16
    out = args.out if args.out is not None else (None if args.quick else str(ROOT / "results" / "bench_envs"))
    warnings.simplefilter("ignore", category=StabilityWarning)

    t_all = time.perf_counter()
    info = machine_info(args)
    info["load_average_start"] = os.getloadavg()
    print(f"# bench_envs {info['date']}: {info.get('cpu', info['machine'])}, {info['cores']} cores, "
          f"python {info['python']}, numpy {info['numpy']}, numba {info['numba']} ({info['numba_threads']} threads), "
          f"gymnasium {info['gymnasium']}, SB3 {info['stable_baselines3']}, mujoco {info['mujoco']}")
    print(f"# load average at start {tuple(round(x, 2) for x in info['load_average_start'])}; window "
          f"{args.seconds} s per cell; N = {ns}; process cap {args.max_procs}; start method {args.mp_context}")
    print("# env-steps/s = N x vector steps / s; actions pre-sampled (sampling not timed); warm-up untimed; "
          "autoresets inside the window timed", flush=True)

    rows, overhead, mujoco_desc, episode_steps = [], [], {}, {}
    methods = [m for m in METHODS if m in args.methods]
    for env_id in env_ids:
        ctx: dict = {}
        if any(m.startswith("mujoco") for m in methods):
            ctx["mujoco_fn"], mujoco_desc[env_id] = mujoco_factory(env_id)
        # compile / load the env's kernels (B = 1 path) before the first cell
        # (each cell's own untimed warm-up steps then cover its batch size)
        t0 = time.perf_counter()
        e1 = gym.make(env_id)
        e1.reset(seed=0)
        for a in presample(e1.action_space, 1, 3):
            e1.step(a[0])
        ctx["episode_steps"] = episode_steps[env_id] = e1.spec.max_episode_steps
        ctx["single_reset_s"] = best_mean(lambda: e1.reset(), max(0.3, min(args.seconds, 1.0)), 2)
        e1.close()
        print(f"\n## {env_id}  (warm-up: kernels and envs, {time.perf_counter() - t0:.1f} s; single-env reset "
              f"{ctx['single_reset_s'] * 1e3:.2f} ms; episode = {ctx['episode_steps']} control steps)")
        if "mujoco_fn" in ctx:
            print(f"MuJoCo baseline: {mujoco_desc[env_id]}")
        print(f"{'N':>5s} {'method':13s} {'env-steps/s':>13s} {'steps':>7s} {'s':>6s} {'setup s':>8s} "
              f"{'reset s':>8s} {'w/ resets':>11s}  note")
        for n in ns:
            for m in methods:
                r = run_cell(m, env_id, n, args, ctx)
                rows.append(r)
                rate = "skipped" if r["status"] != "ok" else f"{r['env_steps_per_s']:,.0f}"
                steps = "" if r["vector_steps"] is None else str(r["vector_steps"])
                secs = "" if r["seconds"] is None else f"{r['seconds']:.2f}"
                rs = "" if r["reset_s"] is None else f"{r['reset_s']:.3f}" + ("~" if r["reset_estimated"] else "")
                wr = "" if r["env_steps_per_s_with_resets"] is None else f"{r['env_steps_per_s_with_resets']:,.0f}"
                print(f"{n:5d} {m:13s} {rate:>13s} {steps:>7s} {secs:>6s} {r['setup_s']:8.2f} {rs:>8s} {wr:>11s}  "
                      f"{r['note']}", flush=True)
        ov = step_vs_physics(env_id, max(0.5, min(args.seconds, 2.0)))
        overhead.append(ov)
        if "skipped" in ov:       # the shape env: scripts/bench/bench_step_overhead.py measures it
            continue
        print(f"\nN = 1 single env step() vs its physics ({ov['physics_path']}):")
        print(f"  env.unwrapped.step {ov['step_unwrapped_s'] * 1e6:9.1f} us   gymnasium.make env .step "
              f"{ov['step_wrapped_s'] * 1e6:9.1f} us")
        print(f"  physics: integrator call(s) {ov['physics_integrator_s'] * 1e6:9.1f} us   + per-substep force "
              f"evaluation {ov['physics_with_forces_s'] * 1e6:9.1f} us   one-call kernel floor (no external "
              f"force) {ov['kernel_floor_s'] * 1e6:9.1f} us")
        print(f"  step()/integrator calls = {ov['ratio_step_over_integrator']:.2f}  (target <= 2: "
              f"{'MET' if ov['target_step_le_2x_physics_met'] else 'MISSED'}); step()/(forces + integrator) = "
              f"{ov['ratio_step_over_physics_with_forces']:.2f}; step()/kernel floor = "
              f"{ov['ratio_step_over_kernel_floor']:.1f}; wrapped step()/integrator = "
              f"{ov['ratio_wrapped_over_integrator']:.2f}", flush=True)

    info["load_average_end"] = os.getloadavg()
    info["total_runtime_s"] = time.perf_counter() - t_all
    info["rss_mb_end"] = self_rss_mb()
    targets = {}
    print()
    for env_id in env_ids:
        print(f"### {env_id}: env-steps/s over the timed window")
        for line in table(rows, env_id, ns, methods):
            print(line)
        print(f"\n### {env_id}: env-steps/s counting one reset of every env per episode of "
              f"{episode_steps[env_id]} steps")
        for line in table(rows, env_id, ns, methods, key="env_steps_per_s_with_resets"):
            print(line)
        print()
        big = max(ns)
        b = next((r for r in rows if r["env_id"] == env_id and r["n_envs"] == big and r["method"] == "batched"), None)
        o = best_other(rows, env_id, big)
        if b is not None and b["status"] == "ok" and o is not None:
            ratio = b["env_steps_per_s"] / o["env_steps_per_s"]
            o2 = best_other(rows, env_id, big, "env_steps_per_s_with_resets")
            ratio2 = b["env_steps_per_s_with_resets"] / o2["env_steps_per_s_with_resets"]
            targets[f"{env_id}: batched >= 10x best other at N = {big}"] = dict(
                ratio=ratio, best_other=o["method"], met=ratio >= 10.0, n_envs=big, checked_at_4096=big == 4096,
                ratio_with_resets=ratio2, best_other_with_resets=o2["method"], met_with_resets=ratio2 >= 10.0)
        ov = next(x for x in overhead if x["env_id"] == env_id)
        if "skipped" in ov:
            continue
        targets[f"{env_id}: single step() <= 2x its physics"] = dict(
            ratio=ov["ratio_step_over_integrator"], met=ov["target_step_le_2x_physics_met"])
    print("## Targets" + ("  [--quick: short run, not the real check]" if args.quick else ""))
    for k, v in targets.items():
        extra = (f" (best other: {v['best_other']}); with resets {v['ratio_with_resets']:.2f} "
                 f"(best other: {v['best_other_with_resets']}, {'met' if v['met_with_resets'] else 'missed'})"
                 if "best_other" in v else "")
        print(f"  [{'MET ' if v['met'] else 'MISS'}] {k}: {v['ratio']:.2f}{extra}")
    print(f"load average start {tuple(round(x, 2) for x in info['load_average_start'])}, end "
          f"{tuple(round(x, 2) for x in info['load_average_end'])}; total {info['total_runtime_s']:.0f} s")

    if out:
        prefix = Path(out)
        prefix.parent.mkdir(parents=True, exist_ok=True)
        fields = ["env_id", "n_envs", "method", "status", "env_steps_per_s", "vector_steps", "seconds", "setup_s",
                  "reset_s", "reset_estimated", "env_steps_per_s_with_resets", "note"]
        tmp = prefix.with_name(prefix.name + ".csv.tmp")
        with open(tmp, "w", newline="") as f:
            wr = csv.DictWriter(f, fieldnames=fields)
            wr.writeheader()
            for r in rows:
                wr.writerow({k: ("" if r[k] is None else (f"{r[k]:.6g}" if isinstance(r[k], float) else r[k]))
                             for k in fields})
        tmp.replace(prefix.with_name(prefix.name + ".csv"))
        doc = dict(info=info, settings=dict(seconds=args.seconds, n_envs=ns, max_procs=args.max_procs,
                                            max_step_s=args.max_step_s, warm_steps=args.warm_steps,
                                            action_pool=ACTION_POOL, quick=args.quick),
                   methods=METHODS, mujoco_baseline=mujoco_desc, rows=rows, step_vs_physics=overhead,
                   targets=targets)
        tmp = prefix.with_name(prefix.name + ".json.tmp")
        tmp.write_text(json.dumps(doc, indent=1, default=float))
        tmp.replace(prefix.with_name(prefix.name + ".json"))
        print(f"wrote {prefix}.csv and {prefix}.json")
    return rows, overhead, targets


if __name__ == "__main__":
    main()
