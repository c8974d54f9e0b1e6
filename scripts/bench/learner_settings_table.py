#!/usr/bin/env python
"""The SB3 PPO learner's time per sample under different thread / oneDNN / MKL / minibatch settings,
each in its own process (environment variables such as MKL_ENABLE_INSTRUCTIONS act only at start),
the settings interleaved over ``--repeats`` rounds so that a change in the machine's load touches
every setting alike. Runs ``scripts/bench/profile_learner.py --json`` and prints one markdown table
(median and range over the repeats) with the CPU model and the load.

    python -m scripts.bench.learner_settings_table --recipe shape_1min --rollouts 10 --repeats 3 --out learner.jsonl
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

#: (label, extra arguments of profile_learner.py, environment variables, pin to one CPU?)
SETTINGS = (
    ("1 torch thread, pinned to one CPU", ["--threads", "1"], {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}, True),
    ("1 torch thread, not pinned", ["--threads", "1"], {}, False),
    ("2 torch threads, not pinned", ["--threads", "2"], {}, False),
    ("1 thread, pinned, oneDNN off", ["--threads", "1", "--no-mkldnn"],
     {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}, True),
    ("1 thread, pinned, MKL_ENABLE_INSTRUCTIONS=AVX2", ["--threads", "1"],
     {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1", "MKL_ENABLE_INSTRUCTIONS": "AVX2"}, True),
    ("1 thread, pinned, ONEDNN_MAX_CPU_ISA=AVX2", ["--threads", "1"],
     {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1", "ONEDNN_MAX_CPU_ISA": "AVX2"}, True),
    ("1 thread, pinned, minibatch 512", ["--threads", "1", "--batch-size", "512"],
     {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}, True),
    ("2 threads, not pinned, minibatch 512", ["--threads", "2", "--batch-size", "512"], {}, False),
    ("2 torch threads, not pinned, OMP_WAIT_POLICY=PASSIVE", ["--threads", "2"], {"OMP_WAIT_POLICY": "PASSIVE"}, False),
    ("1 torch thread and 1 numba thread, not pinned", ["--threads", "1"], {"NUMBA_NUM_THREADS": "1"}, False),
)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--recipe", default="shape_1min", choices=("main", "shape_1min"))
    p.add_argument("--rollouts", type=int, default=10)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--cpu", type=int, default=None, help="the CPU to pin to (default: the last one available)")
    p.add_argument("--only", nargs="*", type=int, default=None, help="indices of SETTINGS to run (default all)")
    p.add_argument("--out", required=True, help="JSON lines, one per process (appended)")
    a = p.parse_args(argv)
    cpus = sorted(os.sched_getaffinity(0))
    cpu = a.cpu if a.cpu is not None else cpus[-1]
    chosen = [s for i, s in enumerate(SETTINGS) if a.only is None or i in a.only]
    for r in range(a.repeats):
        for label, extra, env_add, pin in chosen:
            env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS")}
            env.update(env_add)
            env["PROFILE_LABEL"] = label
            cmd = [sys.executable, str(HERE / "profile_learner.py"), "--recipe", a.recipe, "--rollouts",
                   str(a.rollouts), "--json", a.out, *extra]
            if pin:
                cmd = ["taskset", "-c", str(cpu), *cmd]
            print(f"round {r + 1}: {label}", flush=True)
            subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
    rows = [json.loads(line) for line in Path(a.out).read_text().splitlines() if line.strip()]
    import numpy as np
    print(f"\nCPU: {rows[0].get('cpu_model')}; recipe {a.recipe}; {a.rollouts} rollouts of 4096 samples per process; "
          f"load (1 min) {min(r['load_1min'] for r in rows)}-{max(r['load_1min'] for r in rows)}\n")
    print("| setting | learner, us per sample (median [min, max]) | ms per update | rollout, us per sample | runs |")
    print("|---|---:|---:|---:|---:|")
    for label, *_ in chosen:
        rs = [r for r in rows if r.get("label") == label and r["recipe"] == a.recipe]
        if not rs:
            continue
        v = np.array([r["learner_us_per_sample"] for r in rs])
        u = np.array([r["ms_per_update"] for r in rs])
        ro = np.array([r["rollout_us_per_sample"] for r in rs])
        print(f"| {label} | {np.median(v):.1f} [{v.min():.1f}, {v.max():.1f}] | {np.median(u):.2f} | "
              f"{np.median(ro):.1f} | {len(rs)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
