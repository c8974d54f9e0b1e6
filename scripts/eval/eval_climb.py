#!/usr/bin/env python
"""Climbing table: uphill speed against slope for trained TensegrityClimb-v0 policies (one run
folder per training seed) and for the non-learning rolling gait, on held-out reset seeds.

    python -m scripts.eval.eval_climb runs/ppo_climb_s0 [runs/ppo_climb_s1 ...] --out results/climb \
        [--slopes 0 5 10 15 20 24 26 28 30] [--episodes 8] [--seed 40000] [--start-spread] \
        [--model final] [--env-kwargs '{"structure": "prism"}']

Per slope: each run's mean uphill speed over ``--episodes`` episodes of 20 s (the registered time
limit) from reset seeds ``--seed``, ``--seed`` + 1, ... (default 40000). They must be clear of
every seed a run used (its training envs ``seed + i`` for i < n_envs, its evaluation env during
training ``seed + 10000 + i`` for i < n_eval_envs): an overlap is refused, exit status 2, naming
the run and the seeds (:mod:`agents.heldout`). The speed of an episode is its distance climbed
along the slope divided by its duration (m/s, and body lengths/s with the robot's longest rod).

Per training seed: the mean over its episodes with a 95 % bootstrap interval over the episodes
(``agents.summary.mean_interval``). Across runs: IQM with a 95 % bootstrap interval
(``agents.summary.iqm_interval``), min and max; ``runs_climbing`` counts the runs whose mean is
above 0, ``runs_climbing_ci`` those whose whole interval is.

On a fixed slope the env's reset seed changes only its start noise (``reset_noise_scale``, 1 mm),
so the episodes of one run are nearly the same episode. ``--start-spread`` varies the starts: each
episode's robot is turned about the plane's normal (through its rods' mean centre) by a yaw drawn
U(-``--start-yaw-deg``, ``--start-yaw-deg``) (default 180 degrees) from the episode's reset seed,
and the start noise is ``--start-noise`` (``reset_noise_scale``, m on the rod centres and m/s on
their velocities, default 0.01) unless ``--env-kwargs`` sets it. The turned start is written
through the env's own reset (contact state, centre of mass, sensors and observation follow it).
No position offset: the plane is uniform and the observation is relative to the centre of mass,
so a shifted start is the same episode.

``--episode-seconds T`` runs episodes of T s; ``--sustained`` measures each episode's speed over its
last half only, so that a start-up transient (a shape change that gains some height, then stops)
is not counted as climbing.

Writes ``climb.json``, ``climb.csv`` (per slope), ``climb_per_seed.csv`` (per run and slope) and
``climb.png`` into ``--out``.
"""
from __future__ import annotations

import csv
import json
import math
import sys

import numpy as np

from tensegrity_gym_agents.evaluate import run_episodes
from tensegrity_gym.io.atomic import write_atomic
from tensegrity_gym.tools.baselines import RollingGait

from scripts.eval._policy_table import (held_out, iqm_row, parse_table_args, seed_row, table_parser,
                                        trained_policies)

ENV_ID = "TensegrityClimb-v0"
#: default first held-out reset seed: clear of the training and evaluation seeds of agents.train
#: runs with small seeds (10000 + i: their evaluation env during training); the check names any overlap
SEED0 = 40000


class StartSpread:
    """Varied starts of ``TensegrityClimb-v0`` (see the module doc): installed on an env (single
    or vector) before its first reset, each start the task draws (``RollTask.reset_start``) is
    turned about the plane's normal, z in the plane frame, by a yaw U(-``yaw_deg``, ``yaw_deg``)
    degrees drawn from the copy's own generator after the env's draws; the env then writes that
    start as its own. The turn keeps every node's height, so the start stays clear of the plane."""

    def __init__(self, yaw_deg: float):
        if not (math.isfinite(yaw_deg) and 0.0 <= yaw_deg <= 180.0):
            raise ValueError(f"--start-yaw-deg: must be in [0, 180] degrees, got {yaw_deg!r}")
        self.yaw_deg = float(yaw_deg)

    def install(self, env) -> None:
        task = env.unwrapped.task
        reset_idx, reset_start = task.reset_idx, task.reset_start
        rngs: list = []

        def reset_idx_turned(idx, copy_rngs, options=None):
            rngs[:] = copy_rngs           # the generators of the copies being reset, in row order
            try:
                return reset_idx(idx, copy_rngs, options)
            finally:
                rngs.clear()

        def reset_start_turned(rec, rows, u):
            q, qd, goal = reset_start(rec, rows, u)
            yaw = np.radians(self.yaw_deg) * (2.0 * np.array([g.random() for g in rngs]) - 1.0)
            if self.yaw_deg == 0.0:       # no turn: the env's own start, bit for bit
                return q, qd, goal
            return (*turn_about_normal(q, qd, yaw), goal)

        task.reset_idx, task.reset_start = reset_idx_turned, reset_start_turned

    def wrap(self, policy_factory):
        """A policy factory that installs the spread on the env it is given, then builds the policy
        (``run_episodes`` calls it once per env, before the first reset)."""
        def factory(env):
            self.install(env)
            return policy_factory(env)
        return factory


def turn_about_normal(q, qd, yaw):
    """``(q, qd)`` (r, k, 6) (rod centre and axis; their rates) turned about z through each copy's
    mean rod centre by ``yaw`` (r,) radians; new arrays of the same dtype."""
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]

    def turn(v):                      # (r, k, 2) xy components
        return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)

    q, qd = np.array(q, copy=True), np.array(qd, copy=True)
    centre = q[..., :2].mean(axis=1, keepdims=True)
    q[..., 0:2] = centre + turn(q[..., 0:2] - centre)
    q[..., 3:5] = turn(q[..., 3:5])
    qd[..., 0:2] = turn(qd[..., 0:2])
    qd[..., 3:5] = turn(qd[..., 3:5])
    return q, qd


def episode_speeds(policy_factory, slope: float, seeds: list[int], env_kwargs: dict,
                   spread: StartSpread | None = None, sustained: bool = False) -> np.ndarray:
    """(episodes,) uphill speed, m/s, of each held-out episode (reset seeds ``seeds``) on a slope of
    ``slope`` degrees, with varied starts when ``spread`` is given: the distance climbed over the
    whole episode, or with ``sustained`` over its last half only (the start-up transient left
    out), divided by that time."""
    factory = policy_factory if spread is None else spread.wrap(policy_factory)
    eps = run_episodes(ENV_ID, dict(env_kwargs, slope_deg=float(slope)), factory, seeds,
                       record_keys=("distance_rolled",) if sustained else ())
    if not sustained:
        return np.array([e["final"]["distance_rolled"] / (e["length"] * e["dt"]) for e in eps])
    out = []
    for e in eps:
        d = np.asarray(e["trace"]["distance_rolled"], float)
        h = d.size // 2
        out.append((d[-1] - d[h - 1]) / ((d.size - h) * e["dt"]))
    return np.array(out)


def build_parser():
    ap = table_parser(__doc__, SEED0, env_kwargs_help="JSON object of extra env arguments (the robot)")
    ap.add_argument("--slopes", type=float, nargs="+", default=[0, 5, 10, 15, 20, 24, 26, 28, 30])
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--start-spread", action="store_true",
                    help="varied starts: a yaw about the plane's normal and larger start noise (module doc)")
    ap.add_argument("--start-yaw-deg", type=float, default=180.0,
                    help="with --start-spread: yaw drawn in [-this, this] degrees (default 180)")
    ap.add_argument("--start-noise", type=float, default=0.01,
                    help="with --start-spread: reset_noise_scale, m and m/s (default 0.01)")
    ap.add_argument("--episode-seconds", type=float, default=None,
                    help="episode length, s (default: the registered 20 s)")
    ap.add_argument("--sustained", action="store_true",
                    help="speed over the last half of each episode (the start-up transient left out)")
    return ap


def main(argv=None) -> int:
    args, env_kwargs = parse_table_args(build_parser(), argv)
    if args.episodes < 1:
        print(f"error: --episodes: must be >= 1, got {args.episodes}", file=sys.stderr)
        return 2
    seeds = held_out(args, args.episodes)
    spread = None
    if args.start_spread:
        try:
            spread = StartSpread(args.start_yaw_deg)
        except ValueError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        if not (math.isfinite(args.start_noise) and args.start_noise >= 0):
            print(f"error: --start-noise: must be a finite number >= 0 (m, m/s), got {args.start_noise!r}",
                  file=sys.stderr)
            return 2
        env_kwargs.setdefault("reset_noise_scale", float(args.start_noise))
    import gymnasium as gym
    probe = gym.make(ENV_ID, **env_kwargs).unwrapped
    body = float(np.max(probe.task.structure.bar_lengths))
    if args.episode_seconds is not None:
        if not (math.isfinite(args.episode_seconds) and args.episode_seconds >= 2 * probe.task.control_dt):
            print(f"error: --episode-seconds: must be a finite time of at least two control steps, got "
                  f"{args.episode_seconds!r}", file=sys.stderr)
            return 2
        env_kwargs["max_episode_steps"] = int(round(args.episode_seconds / probe.task.control_dt))
    rows, per_run, seed_rows = [], {}, []
    for run, policy, model_path in trained_policies(args.runs, args.model):
        eps = [episode_speeds(lambda env: policy, s, seeds, env_kwargs, spread, args.sustained) for s in args.slopes]
        stats = [seed_row(v) for v in eps]
        per_run[str(run)] = {"model": str(model_path), "speed_m_s": [r["mean"] for r in stats],
                             "ci95_m_s": [r["ci95"] for r in stats],
                             "episode_speeds_m_s": [v.tolist() for v in eps]}
        seed_rows += [[str(run), sl, r["mean"], *r["ci95"], len(v)] for sl, r, v in zip(args.slopes, stats, eps)]
        print(f"{run}: " + " ".join(f"{sl:g}:{r['mean']:.3f} [{r['ci95'][0]:.3f}, {r['ci95'][1]:.3f}]"
                                    for sl, r in zip(args.slopes, stats)), flush=True)
    baseline = None
    if not args.no_baseline and env_kwargs.get("structure", "prism") == "prism":
        baseline = [float(episode_speeds(lambda env: RollingGait(env), s, seeds, env_kwargs, spread,
                                            args.sustained).mean())
                    for s in args.slopes]
        print("rolling gait: " + " ".join(f"{s:g}:{v:.3f}" for s, v in zip(args.slopes, baseline)), flush=True)
    table = []
    for j, s in enumerate(args.slopes):
        vals = [r["speed_m_s"][j] for r in per_run.values()]
        row = {"slope_deg": s}
        if vals:
            row.update(iqm_row(vals))
            row.update(iqm_body_lengths_s=row["iqm_m_s"] / body, runs_climbing=int(sum(v > 0 for v in vals)),
                       runs_climbing_ci=int(sum(r["ci95_m_s"][j][0] > 0 for r in per_run.values())))
        if baseline is not None:
            row["gait_m_s"] = baseline[j]
        table.append(row)
        rows.append([s] + ([row["iqm_m_s"], *row["ci95_m_s"], row["min_m_s"], row["max_m_s"],
                            row["iqm_body_lengths_s"]] if vals else [""] * 6) + [row.get("gait_m_s", "")])
    out = {"env_id": ENV_ID, "env_kwargs": env_kwargs, "model": args.model, "episodes": args.episodes,
           "speed": "over the last half of each episode" if args.sustained else "over the whole episode",
           "reset_seeds": [seeds[0], seeds[-1]],
           "start_spread": None if spread is None else {"yaw_deg": spread.yaw_deg,
                                                        "reset_noise_scale": env_kwargs["reset_noise_scale"]},
           "per_seed_interval": "mean over the episodes, 95 % percentile bootstrap (scipy.stats.bootstrap, "
                                "2000 resamples, seed 0)",
           "body_length_m": body, "runs": per_run,
           "table": table, "command": " ".join(["python", "-m", "scripts.eval.eval_climb"] + (argv or sys.argv[1:]))}
    payload = json.dumps(out, indent=1).encode()
    write_atomic(args.out / "climb.json", lambda f: f.write(payload))
    with open(args.out / "climb.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["slope_deg", "iqm_m_s", "ci95_low", "ci95_high", "min_m_s", "max_m_s", "iqm_body_lengths_s",
                    "gait_m_s"])
        w.writerows(rows)
    with open(args.out / "climb_per_seed.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["run", "slope_deg", "mean_m_s", "ci95_low", "ci95_high", "episodes", "first_reset_seed",
                    "last_reset_seed"])
        w.writerows(r + [seeds[0], seeds[-1]] for r in seed_rows)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    if per_run:
        ax.plot(args.slopes, [r["iqm_m_s"] for r in table], "o-", label=f"PPO, IQM of {len(per_run)} seeds")
        ax.fill_between(args.slopes, [r["ci95_m_s"][0] for r in table], [r["ci95_m_s"][1] for r in table], alpha=0.3)
    if baseline is not None:
        ax.plot(args.slopes, baseline, "s--", label="rolling gait (no learning)")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.axvline(24.0, color="gray", ls=":", label="24 deg: hardware record")
    ax.set_xlabel("slope (degrees)")
    ax.set_ylabel("uphill speed (m/s)")
    ax.set_title(f"{ENV_ID}: uphill speed against slope")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out / "climb.png", dpi=100)
    for r in table:
        print(f"{r['slope_deg']:5.1f} deg  " + (f"IQM {r['iqm_m_s']:.3f} m/s [{r['ci95_m_s'][0]:.3f}, "
                                                f"{r['ci95_m_s'][1]:.3f}]  " if "iqm_m_s" in r else "")
              + (f"climbing: {r['runs_climbing']} of {len(per_run)} runs ({r['runs_climbing_ci']} with the "
                 f"interval above 0)  " if "iqm_m_s" in r else "")
              + (f"gait {r['gait_m_s']:.3f} m/s" if "gait_m_s" in r else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
