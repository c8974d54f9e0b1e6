#!/usr/bin/env python
"""Rough-ground table: rolling speed of trained TensegrityRoll-v0 policies (one run folder per
training seed) and of the rolling gait against the bump height of the ``rough`` terrain generator.

    python -m scripts.eval.eval_rough runs/ppo_roll_s0 [runs/ppo_roll_s1 ...] --out results/rough \
        [--amplitudes 0 0.01 0.02 0.03 0.04] [--episodes 8] [--seed 30000] [--model final] [--wavelength 0.4]

Per amplitude a (m): each run's mean speed along the goal over ``--episodes`` episodes of 20 s
(the registered time limit) from reset seeds ``--seed``, ``--seed`` + 1, ... (default 30000), on a
``rough`` terrain of bumps in [0, a] m (``wavelength`` m, a new field per episode from the reset
seed; the robot starts on its level pad and rolls onto the bumps); a = 0 is the level ground
itself (``terrain=None``). The seeds must be clear of every seed a run used (its training envs
``seed + i``, its evaluation env during training ``seed + 10000 + i``): an overlap is refused,
exit status 2 (:mod:`agents.heldout`). Per training seed: the mean with a 95 % bootstrap interval
over its episodes (``agents.summary.mean_interval``). Across runs: IQM with a 95 % bootstrap
interval (``agents.summary.iqm_interval``) and each amplitude's IQM as a fraction of the
flat-ground IQM. Writes ``rough.json`` and ``rough.csv`` into ``--out``.
"""
from __future__ import annotations

import csv
import json
import sys

import numpy as np

from tensegrity_gym_agents.evaluate import run_episodes
from tensegrity_gym.io.atomic import write_atomic
from tensegrity_gym.tools.baselines import RollingGait

from scripts.eval._policy_table import held_out, iqm_row, parse_table_args, seed_row, table_parser, trained_policies

ENV_ID = "TensegrityRoll-v0"
#: default first held-out reset seed
SEED0 = 30000


def speeds(policy_factory, amplitude: float, seeds: list[int], wavelength: float, env_kwargs: dict) -> np.ndarray:
    """(episodes,) mean speed along the goal, m/s, of the episodes from reset seeds ``seeds`` on
    bumps up to ``amplitude`` m (0: level ground)."""
    kw = dict(env_kwargs)
    if amplitude > 0:
        kw["terrain"] = {"generator": "rough", "amplitude": float(amplitude), "wavelength": float(wavelength)}
    eps = run_episodes(ENV_ID, kw, policy_factory, seeds)
    return np.array([e["final"]["distance_rolled"] / (e["length"] * e["dt"]) for e in eps])


def main(argv=None) -> int:
    ap = table_parser(__doc__, SEED0)
    ap.add_argument("--amplitudes", type=float, nargs="+", default=[0.0, 0.01, 0.02, 0.03, 0.04])
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--wavelength", type=float, default=0.4)
    args, env_kwargs = parse_table_args(ap, argv)
    if args.episodes < 1:
        print(f"error: --episodes: must be >= 1, got {args.episodes}", file=sys.stderr)
        return 2
    seeds = held_out(args, args.episodes)
    amps = args.amplitudes
    per_run = {}
    for run, policy, model_path in trained_policies(args.runs, args.model):
        stats = [seed_row(speeds(lambda env: policy, a, seeds, args.wavelength, env_kwargs)) for a in amps]
        v = [r["mean"] for r in stats]
        per_run[str(run)] = {"model": str(model_path), "speed_m_s": v, "ci95_m_s": [r["ci95"] for r in stats]}
        print(f"{run}: " + " ".join(f"{a * 100:g}cm:{r['mean']:.3f} [{r['ci95'][0]:.3f}, {r['ci95'][1]:.3f}]"
                                    for a, r in zip(amps, stats)), flush=True)
    gait = None
    if not args.no_baseline and env_kwargs.get("structure", "prism") == "prism":
        gait = [float(speeds(lambda env: RollingGait(env), a, seeds, args.wavelength, env_kwargs).mean())
                for a in amps]
        print("rolling gait: " + " ".join(f"{a * 100:g}cm:{x:.3f}" for a, x in zip(amps, gait)), flush=True)
    table, flat = [], None
    for j, a in enumerate(amps):
        row = {"amplitude_m": a}
        vals = [r["speed_m_s"][j] for r in per_run.values()]
        if vals:
            row.update(iqm_row(vals))
            flat = row["iqm_m_s"] if (a == 0 and flat is None) else flat
            if flat:
                row["fraction_of_flat"] = row["iqm_m_s"] / flat
        if gait is not None:
            row["gait_m_s"] = gait[j]
        table.append(row)
    out = {"env_id": ENV_ID, "env_kwargs": env_kwargs, "model": args.model, "episodes": args.episodes,
           "wavelength_m": args.wavelength, "reset_seeds": [seeds[0], seeds[-1]],
           "per_seed_interval": "mean over the episodes, 95 % percentile bootstrap (scipy.stats.bootstrap, "
                                "2000 resamples, seed 0)", "runs": per_run,
           "table": table, "command": " ".join(["python", "-m", "scripts.eval.eval_rough"] + (argv or sys.argv[1:]))}
    payload = json.dumps(out, indent=1).encode()
    write_atomic(args.out / "rough.json", lambda f: f.write(payload))
    with open(args.out / "rough.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["amplitude_m", "iqm_m_s", "ci95_low", "ci95_high", "fraction_of_flat", "gait_m_s"])
        for r in table:
            w.writerow([r["amplitude_m"], r.get("iqm_m_s", ""), *(r.get("ci95_m_s") or ["", ""]),
                        r.get("fraction_of_flat", ""), r.get("gait_m_s", "")])
    for r in table:
        print(f"{r['amplitude_m'] * 100:4.1f} cm  " + (f"IQM {r['iqm_m_s']:.3f} m/s [{r['ci95_m_s'][0]:.3f}, "
                                                      f"{r['ci95_m_s'][1]:.3f}]  " if "iqm_m_s" in r else "")
              + (f"{r['fraction_of_flat']:.0%} of flat  " if "fraction_of_flat" in r else "")
              + (f"gait {r['gait_m_s']:.3f} m/s" if "gait_m_s" in r else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
