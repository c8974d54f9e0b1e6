#!/usr/bin/env python
"""Cold compile: ``gym.make`` + ``reset`` + first ``step()`` of each env in a fresh process with an
empty numba cache (a fresh install's first run), its peak memory, and which kernels it compiled.

    python -m scripts.bench.bench_compile [--envs TensegrityShape-v0 TensegrityRoll-v0] [--repeats 1] [--json OUT]
    python -m scripts.bench.bench_compile --envs TensegrityRoll-v0 --num-envs 16 256   # the batched (vector) envs
    PYTHONPATH=<other checkout> python -m scripts.bench.bench_compile ...   # the same for another version

Each measurement runs in its own process with ``NUMBA_CACHE_DIR`` set to a new empty folder, so
nothing is loaded from the cache of this checkout; the time includes importing the package. The
kernels are those numba compiled at the top level (the time of each includes the functions it
compiled inside it); ``--own N`` also prints the N functions that took longest to compile by
themselves (without the functions they compiled inside them). ``--num-envs N`` measures the
NumPy/numba vector env of N copies (``gym.make_vec(..., vectorization_mode="vector_entry_point")``)
instead of the single env: its batched kernels (SIMD lanes from 16 copies, the multi-threaded
ones for a large batch). The peak memory is the child's peak resident set size; its CPU time (user + system, all
threads) is steadier than the wall clock on a busy machine. Run it on an
otherwise idle machine (the load average is printed): the compile is CPU-bound and a loaded core
stretches it; ``NUMBA_NUM_THREADS`` is passed on (the threaded kernels compile the same either way).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile

CHILD = r"""
import json, resource, sys, time
from numba.core import event as ev
top, own, stack = {}, {}, []
class L(ev.Listener):
    def on_start(self, e):
        d = e.data.get("dispatcher") if e.data else None
        stack.append([getattr(getattr(d, "py_func", None), "__qualname__", "?"), time.perf_counter(), 0.0])
    def on_end(self, e):
        name, t0, inner = stack.pop()
        dt = time.perf_counter() - t0
        own[name] = own.get(name, 0.0) + dt - inner      # without the functions it compiled inside it
        if stack:
            stack[-1][2] += dt
        else:
            top[name] = top.get(name, 0.0) + dt
ev.register("numba:compile", L())
t0 = time.perf_counter()
import gymnasium as gym
import tensegrity_gym  # noqa: F401
n = int(sys.argv[2])
if n:
    env = gym.make_vec(sys.argv[1], num_envs=n, vectorization_mode="vector_entry_point")
else:
    env = gym.make(sys.argv[1])
env.reset(seed=0)
t1 = time.perf_counter()
env.step(env.action_space.sample())
t2 = time.perf_counter()
ru = resource.getrusage(resource.RUSAGE_SELF)
rss = ru.ru_maxrss / 2**20      # kB -> GiB (Linux)
print(json.dumps({"make_reset_s": t1 - t0, "first_step_s": t2 - t1, "total_s": t2 - t0, "peak_rss_gib": rss,
                  "cpu_s": ru.ru_utime + ru.ru_stime,
                  "kernels_s": top, "own_s": own, "package": tensegrity_gym.__file__}))
"""


def cold(env_id: str, num_envs: int = 0) -> dict:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, TENSEGRITY_GYM_QUIET="1")
        # cwd: the empty folder, so that the child imports the package PYTHONPATH names, not the one
        # in the current directory
        r = subprocess.run([sys.executable, "-c", CHILD, env_id, str(num_envs)], capture_output=True, text=True, env=env, cwd=cache)
    if r.returncode:
        raise SystemExit(f"{env_id} (num_envs {num_envs}): the measurement failed:\n{r.stderr[-2000:]}")
    row = json.loads(r.stdout.strip().splitlines()[-1])
    row["package"] = os.path.relpath(row["package"])      # recorded relative to where the script runs
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--envs", nargs="+", default=["TensegrityShape-v0", "TensegrityRoll-v0"])
    ap.add_argument("--num-envs", nargs="+", type=int, default=[0], metavar="N",
                    help="copies of the vector env to measure (0: the single env, the default)")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--own", type=int, default=0, metavar="N",
                    help="also print the N functions with the longest compile time of their own")
    ap.add_argument("--json", default=None, help="write the measurements here")
    args = ap.parse_args(argv)
    if args.json and os.path.exists(args.json):
        ap.error(f"--json {args.json}: exists; give a new file")
    import tensegrity_gym
    out = {"package": os.path.relpath(os.path.dirname(tensegrity_gym.__file__)), "cpu": platform.processor() or platform.machine(),
           "load_avg": os.getloadavg(), "runs": {}}
    print(f"cold compile of {out['package']} (NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', '-')})")
    print("| env | copies | make + reset (s) | first step (s) | total (s) | CPU (s) | peak RSS (GiB) "
          "| load avg (1 min, before) | kernels compiled (s, top level) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---|")
    for env_id in args.envs:
        for n in args.num_envs:
            key = env_id if n == 0 else f"{env_id} x{n}"
            runs = []
            for _ in range(args.repeats):
                load = os.getloadavg()[0]
                r = cold(env_id, n)
                r["load_avg_before"] = load
                runs.append(r)
                ks = ", ".join(f"{k} {v:.1f}" for k, v in sorted(r["kernels_s"].items(), key=lambda kv: -kv[1])
                               if v >= 0.5)
                assert r["package"].startswith(out["package"]), (r["package"], out["package"])
                print(f"| {env_id} | {n or 'single'} | {r['make_reset_s']:.1f} | {r['first_step_s']:.1f} | "
                      f"{r['total_s']:.1f} | {r['cpu_s']:.1f} | {r['peak_rss_gib']:.2f} | {load:.2f} | {ks} |", flush=True)
            out["runs"][key] = runs
    if args.own > 0:
        print(f"\n| env | the {args.own} longest compiles of their own (s) |\n|---|---|")
        for env_id, runs in out["runs"].items():
            for r in runs:
                longest = sorted(r["own_s"].items(), key=lambda kv: -kv[1])[:args.own]
                print(f"| {env_id} | " + ", ".join(f"{k} {v:.1f}" for k, v in longest) + " |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
