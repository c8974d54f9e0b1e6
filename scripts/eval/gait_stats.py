#!/usr/bin/env python
"""Is a TensegrityRoll-v0 policy rolling? Gait statistics of one or more episodes.

    python -m scripts.eval.gait_stats runs/sac_roll                       # trained policy (best model)
    python -m scripts.eval.gait_stats runs/sac_roll --model final --seeds 3
    python -m scripts.eval.gait_stats gait --steps 5000                   # the RollingGait baseline, 100 s
    python -m scripts.eval.gait_stats runs/sac_roll --out results/sac_roll/gait_stats.json

For each episode (held-out reset seeds from ``--seed``, default 1,000,000, clear of the run's own
seeds, else refused with exit status 2 (:mod:`agents.heldout`); deterministic actions, the run's
env kwargs):

* ``speed_m_s``: centre-of-mass progress along the goal per second (m/s);
* ``body_rotations``: net rotation of the body, in turns, about the horizontal axis
  perpendicular to the goal (the axis a forward roll turns about): the best-fit rigid rotation
  of the nodes from one control step to the next (Kabsch), its rotation vector projected on
  that axis and summed. A prism that rolls forward turns by about one turn per perimeter of
  its rolling cross-section; one that crawls or slides stays near 0;
* ``distance_per_turn_m``: distance / body_rotations (a rolling prism: about its perimeter);
* ``turns_about_goal_across_vertical``: the same net rotation about the three axes (along the
  goal: sideways rolling; across it: forward rolling; vertical: turning), and
  ``total_rotation_turns``: the summed rotation angle whatever its axis (vibration adds to it
  without adding to the net turns);
* ``action_sign_changes_per_s``: how often each action component changes sign (mean over
  components; at 50 Hz control the most is 50): bang-bang chatter shows up here;
* ``com_height_m``: min / mean / max height of the centre of mass.

SI units. Writes JSON with ``--out``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


import gymnasium as gym  # noqa: E402

import tensegrity_gym  # noqa: E402,F401
from tensegrity_gym.physics.geometry import node_positions  # noqa: E402
from tensegrity_gym.tools.baselines import RollingGait  # noqa: E402
from scripts._bench import rotation_vectors  # noqa: E402,F401  (shared with gait_search)

ENV_ID = "TensegrityRoll-v0"
#: default first held-out reset seed
HELD_OUT = 1_000_000


def episode_stats(env, policy, seed: int, steps: int) -> dict:
    obs, _ = env.reset(seed=seed)
    task = env.unwrapped.task
    goal = np.append(task.goal[0], 0.0)
    axis = np.cross([0.0, 0.0, 1.0], goal)          # horizontal, perpendicular to the goal; a
    axis /= np.linalg.norm(axis)                    # forward roll turns positively about it

    def nodes():
        N = node_positions(task.model, task.q)[0]
        return N - N.mean(axis=0)

    prev = nodes()
    frame = np.stack([goal, axis, [0.0, 0.0, 1.0]])   # rows: along the goal, across it, vertical
    turned = np.zeros(3)
    total = 0.0
    acts, heights = [], []
    state, start = None, np.ones(1, bool)
    info = {}
    for _ in range(steps):
        a, state = policy.predict(obs[None], state=state, episode_start=start, deterministic=True)
        start = np.zeros(1, bool)
        a = np.asarray(a, dtype=np.float64).reshape(-1)
        obs, _, term, trunc, info = env.step(a)
        acts.append(a)
        heights.append(float(info["com_position"][2]))
        cur = nodes()
        rv = rotation_vectors(prev[None], cur[None])[0]
        turned += frame @ rv
        total += float(np.linalg.norm(rv))
        prev = cur
        if term or trunc:
            break
    acts = np.array(acts)
    T = len(acts) * env.unwrapped.dt
    flips = (np.diff(np.sign(acts), axis=0) != 0).sum(axis=0) / T
    dist = float(info["distance_rolled"])
    turns = float(turned[1]) / (2 * np.pi)
    return {"seed": seed, "duration_s": T, "distance_m": dist, "speed_m_s": dist / T,
            "body_rotations": turns, "distance_per_turn_m": dist / turns if abs(turns) > 1e-9 else None,
            "turns_about_goal_across_vertical": (turned / (2 * np.pi)).tolist(),
            "total_rotation_turns": total / (2 * np.pi),
            "action_sign_changes_per_s": float(flips.mean()),
            "com_height_m": [float(np.min(heights)), float(np.mean(heights)), float(np.max(heights))]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="run directory of agents.train, or 'gait' for the RollingGait baseline")
    p.add_argument("--model", default="best")
    p.add_argument("--seeds", type=int, default=2, help="episodes (reset seeds)")
    p.add_argument("--seed", type=int, default=HELD_OUT,
                   help=f"first held-out reset seed (default {HELD_OUT}); must be clear of the run's own seeds")
    p.add_argument("--steps", type=int, default=1000, help="control steps per episode (1000 = 20 s)")
    p.add_argument("--env-kwargs", nargs="*", metavar="KEY:VALUE", help="override env kwargs (e.g. "
                   "max_cable_acceleration:None for a policy trained before the motor model)")
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    if args.seeds < 1:
        print(f"error: --seeds: must be >= 1, got {args.seeds}", file=sys.stderr)
        return 2
    from tensegrity_gym_agents.heldout import script_heldout_seeds
    seeds = script_heldout_seeds(args.seed, args.seeds, [] if args.run == "gait" else [args.run])
    from tensegrity_gym_agents.parsing import parse_kv_list
    extra = parse_kv_list(args.env_kwargs, ":", "--env-kwargs")
    if args.run == "gait":
        env_kwargs = extra
        env = gym.make(ENV_ID, max_episode_steps=args.steps, **env_kwargs)
        policy = RollingGait(env)
    else:
        from tensegrity_gym_agents import evaluate
        cfg, policy, _, _ = evaluate.load_trained(Path(args.run), args.model)
        if cfg["env"] != ENV_ID:
            raise SystemExit(f"error: {args.run} is a run on {cfg['env']}, not {ENV_ID}")
        env_kwargs = {**cfg["env_kwargs"], **extra}
        env = gym.make(ENV_ID, max_episode_steps=args.steps, **env_kwargs)
    rows = [episode_stats(env, policy, s, args.steps) for s in seeds]
    env.close()
    for r in rows:
        h = r["com_height_m"]
        g, a, v = r["turns_about_goal_across_vertical"]
        print(f"seed {r['seed']}: {r['speed_m_s']:.3f} m/s over {r['duration_s']:.0f} s, net turns about "
              f"goal/across/vertical {g:+.2f}/{a:+.2f}/{v:+.2f} (total {r['total_rotation_turns']:.1f}), "
              f"{r['action_sign_changes_per_s']:.1f} action sign "
              f"changes/s, centre of mass {h[0]:.3f}..{h[2]:.3f} m high")
    if args.out:
        Path(args.out).write_text(json.dumps({"run": args.run, "model": args.model, "env_kwargs": env_kwargs,
                                              "reset_seeds": [seeds[0], seeds[-1]], "episodes": rows},
                                             indent=1) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
