#!/usr/bin/env python
"""Where a control step of the torch device env goes: its wall time (synchronised), the
operations it dispatches from the host, and on CUDA the kernels it launches, their summed device
time and the host waits. A step whose kernels keep the device busy for far less than the step's
wall time is bound by launches and host work, not by the device.

    python -m scripts.bench.profile_torch_env --device cuda --num-envs 8192 [--compile] [--cuda-graph] [--no-eager] \
        [--env TensegrityRoll-v0] [--steps 20] [--json out.json]

Variants: eager (unless ``--no-eager``), ``compile=True`` (``--compile``), ``compile=True,
cuda_graph=True`` (``--cuda-graph``: the physics of a control step replayed as one CUDA graph).

Rows (per control step, after ``--warmup`` steps that compile and warm up, random actions in
[-1, 1], same-step autoreset, device resets where the env takes them):
``ms/step`` wall time of ``--steps`` steps over their number, synchronised before and after;
``host ops`` the aten operations dispatched (views included); ``compiled calls`` the calls of
``torch.compile``'d code; ``host reads`` the scalar reads of device values (``.item()``,
``bool(tensor)``: ``aten::_local_scalar_dense``), each a wait for the device on CUDA;
``kernels`` (CUDA) the device kernels run, ``device ms`` their summed time, ``host waits`` the
host's synchronisations with the device (any ``cuda*Synchronize`` call, the synchronising
copies' included).
"""
from __future__ import annotations

import argparse
import json
import time
from collections import Counter

import gymnasium as gym
import numpy as np
import torch

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym_agents.common import cpu_model

from scripts._bench import sync


def make_env(env_id: str, n: int, device: str, compile_: bool, dtype: str, cuda_graph: bool = False):
    kw = dict(num_envs=n, vectorization_mode="vector_entry_point", backend="torch", device=device, dtype=dtype,
              compile=compile_, autoreset_mode="same_step", cuda_graph=cuda_graph)
    try:
        return gym.make_vec(env_id, reset_sampling="device", **kw)
    except (TypeError, ValueError):          # an env whose resets are drawn on the host only
        return gym.make_vec(env_id, **kw)


def profile_steps(env, steps: int, warmup: int, seed: int = 0) -> dict:
    """The rows of the module doc for ``env`` (reset with ``seed``)."""
    dev = env.device if isinstance(env.device, torch.device) else torch.device(env.device)
    cuda = dev.type == "cuda"
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    shape = (warmup + 2 * steps, env.num_envs) + env.single_action_space.shape
    acts = torch.as_tensor(rng.uniform(-1, 1, shape), dtype=env.dtype, device=dev)
    for a in acts[:warmup]:
        env.step(a)
    sync(dev)
    t0 = time.perf_counter()
    for a in acts[warmup:warmup + steps]:
        env.step(a)
    sync(dev)
    ms = (time.perf_counter() - t0) / steps * 1e3
    from torch.profiler import ProfilerActivity, profile
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    with profile(activities=activities) as prof:
        for a in acts[warmup + steps:]:
            env.step(a)
        sync(dev)
    names, kernels, device_us = Counter(), 0, 0.0
    for e in prof.events():
        if cuda and e.device_type == torch.autograd.DeviceType.CUDA:
            kernels += 1
            device_us += e.device_time_total if hasattr(e, "device_time_total") else e.cuda_time_total
        else:
            names[e.name] += 1
    row = {"ms_per_step": ms,
           "host_ops": sum(v for k, v in names.items() if k.startswith("aten::")) / steps,
           "compiled_calls": names.get("Torch-Compiled Region", 0) / steps
           + sum(v for k, v in names.items() if k.startswith("Torch-Compiled Region:")) / steps,
           "host_reads": names.get("aten::_local_scalar_dense", 0) / steps}
    if cuda:
        row["kernels"] = kernels / steps
        row["device_ms"] = device_us / steps / 1e3
        row["host_waits"] = sum(v for k, v in names.items() if "Synchronize" in k) / steps
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="TensegrityRoll-v0")
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--num-envs", type=int, nargs="+", default=[64, 8192])
    p.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    p.add_argument("--compile", action="store_true", help="also with compile=True (after its compile)")
    p.add_argument("--no-eager", action="store_true", help="leave out the eager env (with --compile / --cuda-graph)")
    p.add_argument("--cuda-graph", action="store_true",
                   help="also with compile=True, cuda_graph=True (a CUDA device; the physics as one graph)")
    p.add_argument("--steps", type=int, default=20, help="control steps timed, and as many profiled")
    p.add_argument("--warmup", type=int, default=5, help="control steps before the timing (the compile)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    p.add_argument("--json", default=None, help="write the rows here")
    args = p.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    dev = torch.device(args.device)
    machine = torch.cuda.get_device_name(dev) if dev.type == "cuda" else cpu_model()
    rows = []
    cols = ["ms_per_step", "host_ops", "compiled_calls", "host_reads"] + (
        ["kernels", "device_ms", "host_waits"] if dev.type == "cuda" else [])
    print(f"{args.env} on {machine} ({args.device}, {args.dtype}, torch {torch.__version__}); per control step:")
    print(f"{'N':>8} {'compiled':>9} {'graph':>6}" + "".join(f"{c:>15}" for c in cols), flush=True)
    variants = ([] if args.no_eager else [(False, False)]) + ([(True, False)] if args.compile else []) + (
        [(True, True)] if args.cuda_graph else [])
    if not variants:
        p.error("--no-eager leaves nothing to profile: add --compile or --cuda-graph")
    for n in args.num_envs:
        for comp, graph in variants:
            env = make_env(args.env, n, args.device, comp, args.dtype, graph)
            row = {"num_envs": n, "compiled": comp, "cuda_graph": graph,
                   **profile_steps(env, args.steps, args.warmup)}
            env.close()
            rows.append(row)
            print(f"{n:>8} {str(comp):>9} {str(graph):>6}" + "".join(f"{row[c]:>15.2f}" for c in cols), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"env": args.env, "device": args.device, "device_name": machine, "dtype": args.dtype,
                       "torch": torch.__version__, "cpu": cpu_model(), "threads": torch.get_num_threads(),
                       "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
