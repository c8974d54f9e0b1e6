#!/usr/bin/env python
"""Throughput of the torch backend (tensegrity_gym.backends.torch) beside the numba backend, same run.

An env-step is one physics step of one env (as in ``scripts/bench/bench_dynamics.py``): semi-implicit
Euler, dt = 1 ms, for

* ``prism``: the free 3-bar prism (``builders.prism(3)``), released with small random velocities;
* ``roll_prism``: the TensegrityRoll-v0 robot (``envs.roll.robot_prism`` on the ground,
  ``place_on_ground``, gravity, string damping) with ground contact and friction, per step
  contact forces then one integrator step (torch: :func:`backends.torch.contact.contact_step`; numba:
  ``contact.forces_inplace`` + ``backends.numba.api.step_inplace``, the env's own path);
* ``icosahedron``: the 6-bar icosahedron (``builders.icosahedron()``);
* ``tower30``: a 30-stage prism tower (``builders.tower(30)``: 90 rods).

For each scene and batch size B: torch float32 and float64 on ``--device`` (default: cuda if
available, else cpu) and numba float64 on all CPU cores (``physics.step(backend="numba")``
on the same B copies), env-steps/s, the ratio torch / numba, and memory: the process's peak
resident set (CPU) or ``torch.cuda.max_memory_allocated`` (CUDA). A B whose torch run raises
out-of-memory is reported as such (the largest B that fits is the last one that ran).

``--env`` times the vector envs of TensegrityRoll-v0 with their task logic (action check,
cable motor, contact physics, divergence check, observation, rewards, time limit): the
device-resident torch env (``gymnasium.make_vec(..., backend="torch", device=--device)``,
float32 and float64; ``--env-compile`` adds both with ``compile=True``, and the largest
observation difference of the compiled env from the eager one after 5 control steps) against the
NumPy/numba vector env (``make_vec`` default) at B in ``--env-batch``, random actions in the
box (drawn once per B, on the env's device), reported as control steps x B per second and
as physics env-steps/s (x ``frame_skip`` = 20).

``--env-reset`` times resets of the same envs: ``reset()`` of all B envs, and control steps
with a time limit of ``--env-reset-episode`` steps (so every env resets on every 11th step by
default, as when a whole batch reaches its time limit together), for the NumPy/numba env and the
torch env in float32 with ``reset_sampling="host"`` (drawn per env on the host, rows copied) and
``"device"`` (drawn and applied on the device, :mod:`tensegrity_gym.envs.torch_reset`);
``--env-terrain JSON`` runs ``--env`` and ``--env-reset`` on a terrain (e.g. a generator's,
drawn at every reset).

``--compile`` also times the prism step wrapped in ``torch.compile`` (inductor) at the
largest B. ``--agreement`` runs the 1 s RK4 (dt = 1e-4) agreement of torch float64 and float32
with numba on the prism, the icosahedron and the constrained prism (node error, m).

Usage::

    .venv/bin/python -m scripts.bench.bench_gpu --quick                       # ~1-2 min on 2 CPU cores
    .venv/bin/python -m scripts.bench.bench_gpu --batch 1024 4096 16384 --agreement --compile \\
        --out results/bench_gpu_cpu.json --label "2-core CPU, no GPU"
    .venv/bin/python -m scripts.bench.bench_gpu --device cuda --batch 1024 16384 262144 1048576
    .venv/bin/python -m scripts.bench.bench_gpu --scenes --env --env-batch 256 1024 4096 --threads 1
    .venv/bin/python -m scripts.bench.bench_gpu --scenes --env-reset --env-batch 256 1024 4096 16384 --threads 1
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import time
from pathlib import Path

import numba
import numpy as np
import torch

from scripts import _bench
from tensegrity_gym.core import builders
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.physics.evaluate import project
from tensegrity_gym.physics.integrate import step
from tensegrity_gym.physics.geometry import node_positions
from tensegrity_gym.backends.numba.api import step_inplace
from tensegrity_gym.physics.contact import GroundContact, init_contact_state
from tensegrity_gym.physics.contact import forces_inplace as contact_forces_inplace
from tensegrity_gym.backends.torch.model import resolve_device, resolve_dtype, torch_model, torch_params
from tensegrity_gym.backends.torch import contact as torch_contact
from tensegrity_gym.backends.torch.driver import step_once
from tensegrity_gym.envs import roll
from tensegrity_gym.io.atomic import write_atomic  # noqa: E402

DT = 1e-3


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def roll_scene():
    s = roll.robot_prism()
    rod_com = (s.nodes[s.bars[:, 0]] * (1 - s.com_fraction)[:, None] + s.nodes[s.bars[:, 1]] * s.com_fraction[:, None])
    com = s.bar_mass @ rod_com / s.bar_mass.sum()
    axis = s.nodes[3:].mean(0) - s.nodes[:3].mean(0)
    contact = GroundContact(radius=0.02, max_damping=float(s.bar_mass.min()) / 4.0 / DT)
    nodes, _ = roll.place_on_ground(s.nodes, com, contact.radius, exclude_axis=axis)
    return compile_model(s.replace(nodes=nodes)), contact


def scenes():
    return {"prism": (compile_model(builders.prism(3)), None), "roll_prism": roll_scene(),
            "icosahedron": (compile_model(builders.icosahedron()), None),
            "tower30": (compile_model(builders.tower(30)), None)}


def released(model, B, scale=0.01, seed=0):
    rng = np.random.default_rng(seed)
    st = initial_state(model, B)
    q, qd = project(model, st.q, st.qd + scale * rng.normal(size=st.qd.shape))
    return np.ascontiguousarray(q), np.ascontiguousarray(qd)


def time_loop(fn, n_steps, min_time, dev):
    """Seconds per step: one warm-up call, then calls of ``n_steps`` steps until ``min_time`` s."""
    fn(n_steps)
    _bench.sync(dev)
    calls, t0 = 0, time.perf_counter()
    while True:
        fn(n_steps)
        _bench.sync(dev)
        calls += 1
        el = time.perf_counter() - t0
        if el >= min_time:
            return el / (calls * n_steps)


def bench_torch(model, contact, q0, qd0, dtype, dev, n_steps, min_time, compiled=False, batch=None):
    """Env-steps/s of the torch backend from the states ``q0``, ``qd0`` (B, k, 6); with ``batch``,
    ``q0``, ``qd0`` are one copy (1, k, 6), repeated ``batch`` times on the device."""
    if batch is None:
        B = q0.shape[0]
        q = torch.as_tensor(q0, device=dev).to(dtype)
        qd = torch.as_tensor(qd0, device=dev).to(dtype)
    else:
        B = batch
        q = torch.as_tensor(q0, device=dev).to(dtype).expand(B, -1, -1).contiguous()
        qd = torch.as_tensor(qd0, device=dev).to(dtype).expand(B, -1, -1).contiguous()
    state = [q, qd]
    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats()
    if contact is None:
        tm = torch_model(model, dev, dtype)
        prm = torch_params(tm, None, B)
        one = (lambda a, b: step_once(tm, a, b, DT, "semi_implicit_euler", prm, None, None, None, True))
        if compiled:
            one = torch.compile(one, dynamic=False)

        def fn(n):
            with torch.no_grad():
                a, b = state
                for _ in range(n):
                    a, b = one(a, b)
                state[0], state[1] = a, b
    else:
        anchor, active = torch_contact.init_contact_state(model, B, dev, dtype)
        cs = [anchor, active]
        sub = torch.compile(torch_contact.contact_substep, dynamic=False) if compiled else None

        def fn(n):
            with torch.no_grad():
                state[0], state[1], cs[0], cs[1] = torch_contact.contact_step(model, contact, state[0], state[1], cs[0], cs[1],
                                                                   DT, n_steps=n, substep=sub)
    t0 = time.perf_counter()
    sec = time_loop(fn, n_steps, min_time, dev)
    ok = bool(torch.isfinite(state[0]).all())
    mem = torch.cuda.max_memory_allocated() / 2**20 if dev.type == "cuda" else peak_rss_mb()
    return {"steps_per_s": B / sec, "finite": ok, "memory_mb": mem, "wall_s": time.perf_counter() - t0}


def bench_numba(model, contact, q0, qd0, n_steps, min_time):
    B = q0.shape[0]
    q, qd = q0.copy(), qd0.copy()
    if contact is None:
        st = [State(q, qd)]

        def fn(n):
            st[0] = step(model, st[0], DT, "semi_implicit_euler", n_steps=n, backend="numba")
    else:
        cs = init_contact_state(model, B)
        W = np.zeros((B, model.n_nodes, 3))
        slip = np.zeros((B, 2 * model.n_bars), bool)

        def fn(n):
            for _ in range(n):
                contact_forces_inplace(contact, model, q, qd, cs, W, slip)
                step_inplace(model, q, qd, DT, "semi_implicit_euler", external=W)
    sec = time_loop(fn, n_steps, min_time, torch.device("cpu"))
    return {"steps_per_s": B / sec}


def bench_mujoco(model, q0, qd0, min_time):
    """Env-steps/s of ``mujoco.rollout`` on all CPU cores over B copies of copy 0's state, the
    scene translated by ``scripts/_bench.mjcf`` (the package MJCF writer) (free rods, tension-only tendons; as in
    ``scripts/bench/bench_dynamics.py``). None when MuJoCo is not installed."""
    try:
        import mujoco
        from mujoco import rollout
    except ImportError:
        return None
    mm = mujoco.MjModel.from_xml_string(_bench.mjcf(model, "Euler", dt=DT))
    d = mujoco.MjData(mm)
    _bench.mj_set_state(mujoco, mm, d, model, q0[0], qd0[0])
    t = _bench.mujoco_rollout_time(mujoco, rollout, mm, d, q0.shape[0], target=min_time / 3, repeats=2)
    return None if t is None else 1.0 / t


def probe_largest_batch(model, contact, dtype, dev, start, limit):
    """The largest B (doubling from ``start`` up to ``limit``) for which one physics step in
    ``dtype`` on ``dev`` runs without running out of memory; returns (B, peak memory MB at B)."""
    best, mem, B = None, None, start
    q0, qd0 = released(model, 1)
    while B <= limit:
        try:
            r = bench_torch(model, contact, q0, qd0, dtype, dev, 1, 0.0, batch=B)
            best, mem = B, r["memory_mb"]
        except torch.OutOfMemoryError:
            break
        finally:
            if dev.type == "cuda":
                torch.cuda.empty_cache()
        B *= 2
    return best, mem


def bench_env(B, dev, dtype, min_time, compile_=False, terrain=None):
    """Control steps x B per second of TensegrityRoll-v0's vector env: NumPy/numba (``dtype``
    None) or the torch env on ``dev`` in ``dtype``; the time limit is off (no resets timed);
    ``terrain`` the env's ``terrain`` argument (None: level ground)."""
    import gymnasium as gym
    import tensegrity_gym  # noqa: F401  (registers the ids)
    kw = {} if dtype is None else {"backend": "torch", "device": str(dev), "dtype": dtype, "compile": compile_}
    if terrain is not None:
        kw["terrain"] = terrain
    env = gym.make_vec("TensegrityRoll-v0", num_envs=B, vectorization_mode="vector_entry_point",
                       max_episode_steps=None, **kw)
    env.reset(seed=0)
    na = env.single_action_space.shape[0]
    rng = np.random.default_rng(0)
    if dtype is None:
        acts = [rng.uniform(-1, 1, (B, na)) for _ in range(4)]
    else:
        acts = [torch.as_tensor(rng.uniform(-1, 1, (B, na)), device=dev).to(resolve_dtype(dtype)) for _ in range(4)]
    t0 = time.perf_counter()

    def fn(n):
        for i in range(n):
            env.step(acts[i % 4])
    first = time.perf_counter()
    fn(1)
    first = time.perf_counter() - first
    sec = time_loop(fn, 2, min_time, dev if dtype is not None else torch.device("cpu"))
    obs = env.step(acts[0])[0]
    ok = bool(np.isfinite(np.asarray(obs.cpu() if dtype is not None else obs)).all())
    out = {"control_steps_per_s": B / sec, "env_steps_per_s": B * env.unwrapped.task.frame_skip / sec,
           "finite": ok, "first_step_s": first, "wall_s": time.perf_counter() - t0}
    if compile_:   # the compiled step against eager ones: same seed, same actions, 5 control steps
        obs = {}
        for name, dt_, c in (("eager", dtype, False), ("compiled", dtype, True), ("eager_f64", "float64", False)):
            e = gym.make_vec("TensegrityRoll-v0", num_envs=B, vectorization_mode="vector_entry_point",
                             max_episode_steps=None, **{**kw, "dtype": dt_, "compile": c})
            e.reset(seed=1)
            for i in range(5):
                o = e.step(acts[i % 4].to(resolve_dtype(dt_)))[0]
            obs[name] = o.double()
        for a, b in (("compiled", "eager"), ("eager", "eager_f64"), ("compiled", "eager_f64")):
            d = (obs[a] - obs[b]).abs().amax(dim=1)   # per env, largest observation entry difference
            key = f"{a}_vs_{b}"
            out[key] = {"max": float(d.max()), "median": float(d.median()),
                        "p99": float(torch.quantile(d.float().cpu(), 0.99)), "envs_over_1e-2": int((d > 1e-2).sum())}
        out["compiled_vs_eager_max_obs_diff"] = out["compiled_vs_eager"]["max"]
    return out


def bench_env_resets(B, dev, dtype, sampling, min_time, episode, terrain=None):
    """TensegrityRoll-v0's vector env with resets: the NumPy/numba env (``dtype`` None) or the torch
    env on ``dev`` with ``reset_sampling=sampling``. Times ``reset()`` of all B envs (s per call,
    after a first seeded reset) and control steps with a time limit of ``episode`` steps (every
    env resets on every ``episode + 1``-th step; the steps are timed in whole cycles); ``terrain``
    the env's ``terrain`` argument (None: level ground)."""
    import gymnasium as gym
    import tensegrity_gym  # noqa: F401  (registers the ids)
    kw = {} if dtype is None else {"backend": "torch", "device": str(dev), "dtype": dtype, "reset_sampling": sampling}
    if terrain is not None:
        kw["terrain"] = terrain
    env = gym.make_vec("TensegrityRoll-v0", num_envs=B, vectorization_mode="vector_entry_point",
                       max_episode_steps=episode, **kw)
    sdev = dev if dtype is not None else torch.device("cpu")
    env.reset(seed=0)
    reset_s = time_loop(lambda n: [env.reset() for _ in range(n)], 1, min_time, sdev)
    na = env.single_action_space.shape[0]
    a = np.random.default_rng(0).uniform(-1, 1, (B, na))
    act = a if dtype is None else torch.as_tensor(a, device=dev).to(resolve_dtype(dtype))
    env.reset(seed=1)
    cycle = episode + 1          # episode steps, then the autoreset step

    def fn(n):
        for _ in range(n * cycle):
            env.step(act)
    sec = time_loop(fn, 1, min_time, sdev) / cycle
    return {"reset_all_s": reset_s, "reset_per_env_us": reset_s / B * 1e6, "episode_steps": episode,
            "control_steps_per_s_with_resets": B / sec}


def agreement(dev):
    """1 s of RK4 at dt = 1e-4: torch float64 and float32 against numba (max node error, m)."""
    out = {}
    for name, s in (("prism", builders.prism(3, prestress=100)), ("icosahedron", builders.icosahedron()),
                    ("constrained_prism", builders.constrained_prism())):
        model = compile_model(s)
        q, qd = released(model, 2, scale=0.2, seed=1)
        st = State(q, qd)
        ref = step(model, st, 1e-4, "rk4", n_steps=10000, backend="numba")
        Nref = node_positions(model, ref.q)
        row = {}
        for label, dtype in (("float64", "float64"), ("float32", "float32")):
            t0 = time.perf_counter()
            out_ = step(model, st, 1e-4, "rk4", n_steps=10000, backend="torch", device=dev, dtype=dtype)
            row[label + "_node_error_m"] = float(np.abs(node_positions(model, out_.q) - Nref).max())
            row[label + "_wall_s"] = time.perf_counter() - t0
        row["moved_m"] = float(np.abs(Nref - node_positions(model, q)).max())
        out[name] = row
        print(f"agreement {name:18s} 1 s RK4 dt=1e-4: float64 {row['float64_node_error_m']:.2e} m, "
              f"float32 {row['float32_node_error_m']:.2e} m (nodes moved up to {row['moved_m']:.3f} m)", flush=True)
    return out


def markdown(result) -> str:
    """Markdown tables of a saved result (``--table FILE.json``)."""
    info = result["info"]
    lines = [f"Machine: {info.get('label') or info['device']}; device {info['device']}, torch {info['torch']} "
             f"({info['torch_threads']} threads), numba on {info['numba_threads']} threads; "
             f"{info['integrator']}, dt = {info['dt_s'] * 1e3:g} ms; env-steps/s (one physics step of one env).", ""]
    if result.get("rows"):
        rows = result["rows"]
        comp = any(r.get("torch_f32_compiled") or r.get("torch_f32_compiled_error") for r in rows)
        mj = any("mujoco_f64" in r for r in rows)

        def f(x):
            return "OOM" if x is None else f"{x:,.0f}"

        def rt(x):
            return "-" if x is None else f"{x:.3f}x"
        head = "| scene | B | numba f64 | torch f32 | ratio | torch f64 | ratio |"
        sep = "|---|---:|---:|---:|---:|---:|---:|"
        if comp:
            head, sep = head + " torch f32 compiled | ratio |", sep + "---:|---:|"
        if mj:
            head, sep = head + " MuJoCo rollout f64 | numba / MuJoCo |", sep + "---:|---:|"
        lines += [head + " peak memory f64 (MB) |", sep + "---:|"]
        for r in rows:
            line = (f"| {r['scene']} | {r['B']} | {f(r['numba_f64'])} | {f(r['torch_f32'])} | "
                    f"{rt(r['torch_f32_ratio_vs_numba'])} | {f(r['torch_f64'])} | {rt(r['torch_f64_ratio_vs_numba'])} |")
            if comp:
                c = r.get("torch_f32_compiled")
                line += (f" {f(c)} | {rt(r.get('torch_f32_compiled_ratio_vs_numba'))} |" if c
                         else (" error |  - |" if r.get("torch_f32_compiled_error") else " - | - |"))
            if mj:
                m = r.get("mujoco_f64")
                line += f" {f(m)} | {rt(r.get('numba_ratio_vs_mujoco'))} |" if m else " - | - |"
            lines.append(line + f" {r['torch_f64_memory_mb'] or 0:.0f} |")
    if result.get("largest_batch"):
        lines += ["", "Largest B whose float32 step ran (doubling from the largest B above):", ""]
        for name, v in result["largest_batch"].items():
            cap = " (the probe's limit)" if v["float32_B"] == v["limit"] else ""
            lines.append(f"* {name}: {v['float32_B']:,}{cap}, peak {v['memory_mb'] or 0:,.0f} MB")
    if result.get("env"):
        lines += ["", "TensegrityRoll-v0 vector env with its task logic (one control step = 20 physics steps; "
                  "env-steps/s = physics steps x B per second):", "",
                  "| B | env | control steps x B / s | physics env-steps/s | ratio vs NumPy/numba env |",
                  "|---:|---|---:|---:|---:|"]
        for r in result["env"]:
            extra = ""
            if "compiled_vs_eager_max_obs_diff" in r:
                extra = (f" (first step incl. compilation {r['first_step_s']:.0f} s; obs vs eager after 5 steps "
                         f"{r['compiled_vs_eager_max_obs_diff']:.1e})")
            lines.append(f"| {r['B']} | {r['env']}{extra} | {r['control_steps_per_s']:,.0f} | {r['env_steps_per_s']:,.0f} | "
                         f"{r['ratio_vs_numpy']:.3f}x |")
        diffs = [(r, k) for r in result["env"] for k in ("compiled_vs_eager", "eager_vs_eager_f64", "compiled_vs_eager_f64")
                 if k in r]
        if diffs:
            lines += ["", "Observations after 5 control steps (same seed and actions), per env the largest entry "
                      "difference (m, m/s, rad/s, -), then over the B envs:", "",
                      "| B | env | pair | max | median | 99th percentile | envs over 1e-2 |", "|---:|---|---|---:|---:|---:|---:|"]
            for r, k in diffs:
                v = r[k]
                lines.append(f"| {r['B']} | {r['env']} | {k.replace('_vs_', ' vs ')} | {v['max']:.1e} | {v['median']:.1e} | "
                             f"{v['p99']:.1e} | {v['envs_over_1e-2']} |")
    if result.get("env_resets"):
        rr = result["env_resets"]
        lines += ["", f"TensegrityRoll-v0 vector env with resets: `reset()` of all B envs, and control steps with a "
                  f"time limit of {rr[0]['episode_steps']} steps (every env resets on every "
                  f"{rr[0]['episode_steps'] + 1}th step; the step that resets counts as a control step):", "",
                  "| B | env | reset of all B envs (ms) | per env (us) | control steps x B / s with resets | "
                  "ratio vs NumPy/numba env |", "|---:|---|---:|---:|---:|---:|"]
        for r in rr:
            lines.append(f"| {r['B']} | {r['env']} | {r['reset_all_s'] * 1e3:,.1f} | {r['reset_per_env_us']:.2f} | "
                         f"{r['control_steps_per_s_with_resets']:,.0f} | {r['ratio_vs_numpy']:.3f}x |")
    if result.get("compile"):
        c = result["compile"]
        lines += ["", f"torch.compile (inductor), free prism, B = {c['B']}:", ""]
        for k in ("float32", "float64"):
            v = c.get(k, {})
            if "error" in v:
                lines.append(f"* {k}: eager {v['eager']:,.0f}/s; compile failed: {v['error']}")
            elif v:
                lines.append(f"* {k}: eager {v['eager']:,.0f}/s, compiled {v['compiled']:,.0f}/s "
                             f"({v['speedup']:.2f}x; first call incl. compilation {v['first_call_incl_compile_s']:.0f} s)")
    if result.get("agreement"):
        lines += ["", "Agreement with numba, 1 s of RK4 at dt = 1e-4 (10,000 steps), 2 copies released with random "
                  "node velocities (0.2 m/s):", "",
                  "| scene | torch float64: max node error (m) | torch float32 (m) | nodes moved (m) |", "|---|---:|---:|---:|"]
        for name, a in result["agreement"].items():
            lines.append(f"| {name} | {a['float64_node_error_m']:.2e} | {a['float32_node_error_m']:.2e} | {a['moved_m']:.3f} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--batch", type=int, nargs="+", default=[1024, 4096, 16384])
    ap.add_argument("--scenes", nargs="*", default=["prism", "roll_prism", "icosahedron", "tower30"],
                    help="scenes to time (none: only --agreement / --compile)")
    ap.add_argument("--steps", type=int, default=20, help="physics steps per timed call")
    ap.add_argument("--min-time", type=float, default=1.0, help="seconds timed per entry")
    ap.add_argument("--quick", action="store_true", help="B = 1024, 4096; 0.3 s per entry")
    ap.add_argument("--compile", action="store_true",
                    help="also time torch.compile (inductor) of the physics step, float32, per scene at "
                         "the B of --compile-batch")
    ap.add_argument("--compile-batch", type=int, nargs="+", default=None,
                    help="B of --compile (default: the largest --batch)")
    ap.add_argument("--mujoco", action="store_true",
                    help="also time mujoco.rollout on all CPU cores (contact-free scenes, B <= --mujoco-max-batch)")
    ap.add_argument("--mujoco-max-batch", type=int, default=65536)
    ap.add_argument("--probe", action="store_true",
                    help="per scene, the largest B (doubling from the largest --batch) whose float32 step fits "
                         "in memory")
    ap.add_argument("--probe-limit", type=int, default=1 << 27, help="largest B --probe tries")
    ap.add_argument("--work", type=float, default=2e7,
                    help="rod-steps per timed call: steps per call = clamp(work / (B x rods), 1, --steps)")
    ap.add_argument("--agreement", action="store_true", help="1 s RK4 agreement with numba (float64, float32)")
    ap.add_argument("--env", action="store_true", help="time the TensegrityRoll-v0 vector envs (torch vs NumPy/numba)")
    ap.add_argument("--env-batch", type=int, nargs="+", default=[256, 1024, 4096], help="B of --env")
    ap.add_argument("--env-compile", action="store_true", help="--env also with compile=True (float32, float64)")
    ap.add_argument("--env-reset", action="store_true",
                    help="time resets of the TensegrityRoll-v0 vector envs: NumPy/numba, torch with reset_sampling "
                         "'host' and 'device' (float32), at B in --env-batch")
    ap.add_argument("--env-reset-episode", type=int, default=10, help="time limit (control steps) of --env-reset")
    ap.add_argument("--env-terrain", default=None,
                    help="--env and --env-reset on this terrain: the env's terrain argument as JSON, e.g. "
                         "'{\"generator\": \"rough\"}' (a terrain drawn per reset)")
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    ap.add_argument("--label", default=None, help="machine label written into the output")
    ap.add_argument("--out", default=None, help="write JSON here")
    ap.add_argument("--table", default=None, help="print the markdown tables of a saved JSON result and exit")
    args = ap.parse_args(argv)
    if args.table:
        print(markdown(json.loads(Path(args.table).read_text())))
        return 0
    if args.quick:
        args.batch, args.min_time = [1024, 4096], 0.3
    terrain = json.loads(args.env_terrain) if args.env_terrain else None
    dev = resolve_device(args.device)
    if args.threads:
        torch.set_num_threads(args.threads)
    info = {"label": args.label, "device": str(dev), "cpu_count": os.cpu_count(), "torch": torch.__version__,
            "torch_threads": torch.get_num_threads(), "numba_threads": numba.get_num_threads(),
            "platform": platform.platform(), "dt_s": DT,
            "integrator": "semi_implicit_euler", "env_terrain": args.env_terrain,
            "gpu": torch.cuda.get_device_name(dev) if dev.type == "cuda" else None}
    print(json.dumps(info), flush=True)
    sc = scenes()
    rows = []
    result = {"info": info, "rows": rows}
    for name in args.scenes:
        model, contact = sc[name]
        for B in args.batch:
            q0, qd0 = released(model, B)
            steps = int(min(max(args.work // (B * model.n_bars), 1), args.steps))
            row = {"scene": name, "B": B, "rods": model.n_bars, "strings": model.n_strings, "steps_per_call": steps}
            row["numba_f64"] = bench_numba(model, contact, q0, qd0, steps, args.min_time)["steps_per_s"]
            variants = [("torch_f32", torch.float32, False), ("torch_f64", torch.float64, False)]
            if args.compile and B in (args.compile_batch or [max(args.batch)]):
                variants.append(("torch_f32_compiled", torch.float32, True))
            for label, dtype, comp in variants:
                t0 = time.perf_counter()
                try:
                    r = bench_torch(model, contact, q0, qd0, dtype, dev, steps, args.min_time, compiled=comp)
                except torch.OutOfMemoryError:
                    r = {"steps_per_s": None, "oom": True}
                except Exception as exc:  # inductor needs a C++ compiler (CPU) or Triton (CUDA)
                    if not comp:
                        raise
                    r = {"steps_per_s": None, "error": f"{type(exc).__name__}: {exc}"[:300]}
                if dev.type == "cuda":
                    torch.cuda.empty_cache()
                row[label] = r["steps_per_s"]
                row[label + "_memory_mb"] = r.get("memory_mb")
                row[label + "_finite"] = r.get("finite")
                row[label + "_ratio_vs_numba"] = None if r["steps_per_s"] is None else r["steps_per_s"] / row["numba_f64"]
                if comp:
                    row[label + "_wall_incl_compile_s"] = time.perf_counter() - t0
                    if "error" in r:
                        row[label + "_error"] = r["error"]
            if args.mujoco and contact is None and B <= args.mujoco_max_batch:
                row["mujoco_f64"] = bench_mujoco(model, q0, qd0, args.min_time)
                row["numba_ratio_vs_mujoco"] = (None if not row["mujoco_f64"] else row["numba_f64"] / row["mujoco_f64"])
            rows.append(row)
            extra = "".join(f"  {k} {row[k]:,.0f}" for k in ("torch_f32_compiled", "mujoco_f64") if row.get(k))
            print(f"{name:12s} B={B:8d}  numba f64 {row['numba_f64']:12,.0f}  torch f32 {row['torch_f32'] or 0:12,.0f} "
                  f"({row['torch_f32_ratio_vs_numba'] or 0:.2f}x)  torch f64 {row['torch_f64'] or 0:12,.0f} "
                  f"({row['torch_f64_ratio_vs_numba'] or 0:.2f}x){extra}  env-steps/s  peak mem "
                  f"{row['torch_f64_memory_mb'] or 0:.0f} MB", flush=True)
            save(args.out, result)   # after every row: an interrupted run keeps what it measured
        if args.probe:
            big, mem = probe_largest_batch(model, contact, torch.float32, dev, max(args.batch), args.probe_limit)
            result.setdefault("largest_batch", {})[name] = {"float32_B": big, "memory_mb": mem,
                                                            "limit": args.probe_limit}
            print(f"{name:12s} largest float32 B that ran one step: {big} ({mem or 0:,.0f} MB; tried up to "
                  f"{args.probe_limit})", flush=True)
            save(args.out, result)
    if args.env:
        envrows = result["env"] = []
        for B in args.env_batch:
            variants = [("numpy/numba f64", None, False), (f"torch {dev.type} f32", "float32", False),
                        (f"torch {dev.type} f64", "float64", False)]
            if args.env_compile:
                variants += [(f"torch {dev.type} f32 compiled", "float32", True),
                             (f"torch {dev.type} f64 compiled", "float64", True)]
            base = None
            for label, dtype, comp in variants:
                r = bench_env(B, dev, dtype, args.min_time, comp, terrain)
                base = r["control_steps_per_s"] if base is None else base
                envrows.append({"B": B, "env": label, **r, "ratio_vs_numpy": r["control_steps_per_s"] / base})
                print(f"env B={B:6d} {label:28s} {r['control_steps_per_s']:10,.0f} control steps x B/s "
                      f"{r['env_steps_per_s']:12,.0f} env-steps/s ({r['control_steps_per_s'] / base:.3f}x; "
                      f"first step {r['first_step_s']:.1f} s"
                      + (f"; compiled vs eager obs {r['compiled_vs_eager_max_obs_diff']:.1e}"
                         if "compiled_vs_eager_max_obs_diff" in r else "") + ")", flush=True)
                for k in ("compiled_vs_eager", "eager_vs_eager_f64", "compiled_vs_eager_f64"):
                    if k in r:
                        print(f"    obs after 5 control steps, {k} (per-env largest entry): {r[k]}", flush=True)
                save(args.out, result)
    if args.env_reset:
        rrows = result["env_resets"] = []
        for B in args.env_batch:
            base = None
            for label, dtype, sampling in (("numpy/numba f64", None, None),
                                           (f"torch {dev.type} f32, host resets", "float32", "host"),
                                           (f"torch {dev.type} f32, device resets", "float32", "device")):
                r = bench_env_resets(B, dev, dtype, sampling, args.min_time, args.env_reset_episode, terrain)
                base = r["control_steps_per_s_with_resets"] if base is None else base
                rrows.append({"B": B, "env": label, **r, "ratio_vs_numpy": r["control_steps_per_s_with_resets"] / base})
                print(f"env resets B={B:6d} {label:32s} reset all {r['reset_all_s'] * 1e3:9.1f} ms "
                      f"({r['reset_per_env_us']:.2f} us/env); with resets {r['control_steps_per_s_with_resets']:10,.0f} "
                      f"control steps x B/s ({r['control_steps_per_s_with_resets'] / base:.3f}x)", flush=True)
                save(args.out, result)
    if args.compile and not args.scenes:   # no scene timed: the eager/compiled pair on the prism alone
        model, _ = sc["prism"]
        B = max(args.batch)
        q0, qd0 = released(model, B)
        comp = {}
        for label, dtype in (("float32", torch.float32), ("float64", torch.float64)):
            eager = bench_torch(model, None, q0, qd0, dtype, dev, args.steps, args.min_time)["steps_per_s"]
            t0 = time.perf_counter()
            try:
                c = bench_torch(model, None, q0, qd0, dtype, dev, args.steps, args.min_time, compiled=True)
                comp[label] = {"eager": eager, "compiled": c["steps_per_s"], "speedup": c["steps_per_s"] / eager,
                               "first_call_incl_compile_s": time.perf_counter() - t0}
            except Exception as exc:  # inductor needs a C++ compiler (CPU) or Triton (CUDA)
                comp[label] = {"eager": eager, "error": f"{type(exc).__name__}: {exc}"[:300]}
            print(f"torch.compile prism B={B} {label}: {comp[label]}", flush=True)
        result["compile"] = {"B": B, **comp}
    if args.agreement:
        result["agreement"] = agreement(dev)
    save(args.out, result)
    if args.out:
        print(f"wrote {args.out}")
    return 0


def save(path, result):
    """Write ``result`` as JSON atomically (temporary file in the same folder, fsync, rename)."""
    if not path:
        return
    text = json.dumps(result, indent=1)
    write_atomic(path, lambda f: f.write(text.encode()))


if __name__ == "__main__":
    sys.exit(main())
