#!/usr/bin/env python
"""Which sensors does a robot-observation rolling policy rely on? (the transfer gap)

Runs a trained ``TensegrityRoll-v0`` policy with ``observation_mode="robot"`` on N robots of its
own training distribution (the run's ``env_kwargs``, reset seeds ``--seed`` (default 1,000,000) ...
+ N - 1, clear of the run's own seeds (:mod:`agents.heldout`, else exit status 2), 20 s) and
corrupts one sensor block per row before the policy sees it:

* ``unchanged``;
* ``imu_accel_noise_5`` / ``imu_gyro_noise_0.33``: extra white Gaussian noise (m/s^2, rad/s) through
  the env's own ``sensor_noise`` (the size of the measured difference between this project's
  physics and the MuJoCo twin: ``results/transfer/README.md``);
* ``contact_zero``: every contact switch of every stacked reading reads 0;
* ``contact_flip_P``: each switch of each stacked reading is flipped with probability P.

Prints and writes (``--out``) the mean speed along the goal, m/s, and its share of the unchanged
row. Usage::

    python -m scripts.eval.probe_robot_observation results/sac_roll_rand_robot --out results/transfer/probe_sac_roll_rand_robot.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import tensegrity_gym  # noqa: F401  (registers the ids)
from tensegrity_gym_agents import common, evaluate
from tensegrity_gym_agents.heldout import script_heldout_seeds

#: default first held-out reset seed
HELD_OUT = 1_000_000
ROWS = ("unchanged", "imu_accel_noise_5", "imu_gyro_noise_0.33", "contact_zero", "contact_flip_0.1",
        "contact_flip_0.3")


def run_row(policy, env_kwargs: dict, row: str, n: int, seconds: float, seed0: int = HELD_OUT) -> np.ndarray:
    """Speeds (n,) m/s along each robot's goal over ``seconds`` with the corruption of ``row``."""
    kw = dict(env_kwargs)
    if row.startswith("imu_"):
        block = "imu_accel" if row.startswith("imu_accel") else "imu_gyro"
        kw["sensor_noise"] = {**(kw.get("sensor_noise") or {}), block: float(row.rsplit("_", 1)[1])}
    env = gym.make_vec("TensegrityRoll-v0", num_envs=n, vectorization_mode="vector_entry_point",
                       max_episode_steps=None, **kw)
    task = env.unwrapped.task
    sens = task.sensors
    if sens is None:
        raise ValueError("the policy's env has observation_mode='state'; this probe needs 'robot'")
    cs = dict((name, sl) for name, sl, _ in sens.layout())["contact"]
    F, H = sens.frame_size, sens.history
    cols = np.concatenate([np.arange(h * F + cs.start, h * F + cs.stop) for h in range(H)])
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=list(range(seed0, seed0 + n)))
    start = task._com(task.q).copy()
    for _ in range(int(round(seconds / task.control_dt))):
        o = obs.copy()
        if row == "contact_zero":
            o[:, cols] = 0.0
        elif row.startswith("contact_flip"):
            flip = rng.random((n, cols.size)) < float(row.rsplit("_", 1)[1])
            o[:, cols] = np.where(flip, 1.0 - o[:, cols], o[:, cols])
        obs, *_ = env.step(policy.predict(o)[0])
    disp = (task._com(task.q) - start)[:, :2]
    return np.einsum("bi,bi->b", disp, task.goal) / seconds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", help="training run folder of a robot-observation roll policy (agents.train)")
    ap.add_argument("--model", default="final", help="best or final (default final)")
    ap.add_argument("--robots", type=int, default=20)
    ap.add_argument("--seed", type=int, default=HELD_OUT,
                    help=f"first held-out reset seed (default {HELD_OUT}); must be clear of the run's own seeds")
    ap.add_argument("--time", type=float, default=20.0, help="simulated seconds")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    if args.robots < 1:
        print(f"error: --robots: must be >= 1, got {args.robots}", file=sys.stderr)
        return 2
    seeds = script_heldout_seeds(args.seed, args.robots, [args.run])
    cfg, policy, model_path, _ = evaluate.load_trained(Path(args.run), args.model)
    out = {"run": args.run, "model": str(model_path), "robots": args.robots, "seconds": args.time,
           "reset_seeds": [seeds[0], seeds[-1]],
           "env_kwargs": cfg["env_kwargs"], "rows": {}, "command": " ".join(["python", *sys.argv])}
    t0 = time.perf_counter()
    for row in ROWS:
        v = run_row(policy, cfg["env_kwargs"], row, args.robots, args.time, args.seed)
        base = out["rows"].get("unchanged", {}).get("speed_mean_m_s", float(v.mean()))
        out["rows"][row] = {"speed_mean_m_s": float(v.mean()), "speed_std_m_s": float(v.std()),
                            "share_of_unchanged": float(v.mean() / base)}
        print(f"{row:22s} {v.mean():6.3f} +- {v.std():.3f} m/s ({100 * v.mean() / base:5.1f} %)", flush=True)
    out["wall_s"] = time.perf_counter() - t0
    if args.out:
        common.write_text(Path(args.out), json.dumps(out, indent=1))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(common.run_cli(main))
