"""Evaluate the rolling gait (tensegrity_gym.tools.baselines.RollingGait) on TensegrityRoll-v0.

Runs the gait for 100 s of simulated time (5000 control steps at 50 Hz) on flat ground for
several reset seeds (one batched vector env, no time limit) and reports the speed of the
centre of mass along the goal in m/s and in body lengths per second (body length = rod
length, 0.383 m for the default prism), in three settings: the default gait with the goal +x,
the default gait with random goals (``randomize_goal=True``), and the same wave without its
heading feedback (``steer=0``: purely open loop, goal +x). Also the env's throughput (env steps
per second of a single env and of the batched vector env, measured here, on this machine).

Writes ``results/roll_baseline.json``. Run: ``python -m scripts.eval.eval_roll_baseline [--seeds 8] [--time 100]``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

import gymnasium as gym  # noqa: E402

import tensegrity_gym  # noqa: E402,F401
from tensegrity_gym.tools.baselines import RollingGait  # noqa: E402
from tensegrity_gym.envs.roll import TensegrityRollVectorEnv  # noqa: E402


def evaluate(seeds: int, T: float, randomize_goal: bool = False, **gait_kwargs) -> dict:
    """RollingGait (``gait_kwargs`` override its defaults) for ``T`` s on ``seeds`` reset seeds;
    speed along the goal (``info["distance_rolled"]`` / T) and its time course."""
    venv = TensegrityRollVectorEnv(num_envs=seeds, max_episode_steps=None, randomize_goal=randomize_goal)
    gait = RollingGait(venv, **gait_kwargs)
    obs, _ = venv.reset(seed=0)
    task = venv.task
    n = int(round(T / task.control_dt))
    every = int(round(10.0 / task.control_dt))
    every_s = int(round(1.0 / task.control_dt))
    state = None
    x_hist = []
    path, last = np.zeros(seeds), task.start[:, :2].copy()
    for i in range(n):
        a, state = gait.predict(obs, state)
        obs, r, term, trunc, info = venv.step(a)
        if (i + 1) % every == 0:
            x_hist.append(info["distance_rolled"].copy())
        if (i + 1) % every_s == 0:    # path over the ground, centre of mass sampled once a second
            path += np.linalg.norm(info["com_position"][:, :2] - last, axis=1)
            last = info["com_position"][:, :2].copy()
        assert not info["diverged"].any()
    d = info["distance_rolled"]
    x_hist = np.array(x_hist).T
    off = info["com_position"][:, :2] - task.start[:, :2]
    goal = task.goal
    lateral = goal[:, 0] * off[:, 1] - goal[:, 1] * off[:, 0]
    L = task.body_length
    speed = d / T
    out = {"simulated_time_s": T, "seeds": list(range(seeds)), "randomize_goal": randomize_goal,
           "reset_noise_scale_m": task.reset_noise_scale, "body_length_m": L,
           "gait": {k: np.asarray(getattr(gait, k)).tolist() for k in RollingGait.DEFAULT},
           "distance_m": d.tolist(), "lateral_drift_m": lateral.tolist(),
           "speed_m_s": {"mean": float(speed.mean()), "std": float(speed.std()), "min": float(speed.min()),
                         "max": float(speed.max())},
           "speed_body_lengths_s": {"mean": float(speed.mean() / L), "std": float(speed.std() / L)},
           "ground_speed_m_s": {"mean": float(path.mean() / T), "min": float(path.min() / T),
                                "note": "length of the centre of mass's path over the ground (sampled "
                                        "once a second) / time, whatever its direction"},
           "distance_every_10s_m": x_hist.tolist()}
    if T > 20.0 + 1e-9:   # after the first 20 s (turning toward the goal)
        k20 = int(round(20.0 / 10.0)) - 1
        late = (d - x_hist[:, k20]) / (T - 20.0)
        out["speed_after_20s_m_s"] = {"mean": float(late.mean()), "min": float(late.min())}
        out["speed_after_20s_body_lengths_s"] = float(late.mean() / L)
    return out


def throughput() -> dict:
    out = {}
    env = gym.make("TensegrityRoll-v0")
    env.reset(seed=0)
    a = np.zeros(env.action_space.shape, np.float32)
    for _ in range(50):
        env.step(a)
    n = 2000
    t0 = time.perf_counter()
    for i in range(n):
        _, _, te, tr, _ = env.step(env.action_space.sample())
        if te or tr:
            env.reset()
    out["single_env_steps_per_s"] = n / (time.perf_counter() - t0)
    for N in (16, 256):
        venv = gym.make_vec("TensegrityRoll-v0", num_envs=N, vectorization_mode="vector_entry_point")
        venv.reset(seed=0)
        acts = venv.action_space.sample()
        venv.step(acts)
        steps = max(20, 4000 // N)
        t0 = time.perf_counter()
        for _ in range(steps):
            venv.step(acts)
        out[f"vector_env_{N}_env_steps_per_s"] = N * steps / (time.perf_counter() - t0)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--time", type=float, default=100.0, help="simulated seconds")
    ap.add_argument("--no-bench", action="store_true", help="skip the throughput measurement")
    args = ap.parse_args()
    t0 = time.time()
    res = evaluate(args.seeds, args.time)
    res["random_goals"] = evaluate(args.seeds, args.time, randomize_goal=True)
    res["open_loop_steer_0"] = evaluate(args.seeds, args.time, steer=0.0)
    res["wall_s"] = time.time() - t0
    if not args.no_bench:
        res["throughput"] = throughput()
        res["throughput"]["note"] = ("measured on the machine that ran this script (2 shared cores in "
                                     "development): control step = 20 physics steps of 1 ms with contact")
    out = ROOT / "results" / "roll_baseline.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=2))
    L = res["body_length_m"]
    print(f"RollingGait on TensegrityRoll-v0, {args.time:g} s simulated, {args.seeds} seeds, "
          f"body length {L:.3f} m")
    print("| setting | speed along goal, m/s (min) | body lengths/s | after the first 20 s, m/s | "
          "over the ground, m/s | lateral drift, m |\n|---|---|---|---|---|---|")
    for label, r in (("default gait, goal +x", res), ("default gait, random goals", res["random_goals"]),
                     ("open loop (steer=0), goal +x", res["open_loop_steer_0"])):
        s = r["speed_m_s"]
        late = r.get("speed_after_20s_m_s", {}).get("mean", float("nan"))
        print(f"| {label} | {s['mean']:.3f} ({s['min']:.3f}) | {r['speed_body_lengths_s']['mean']:.3f} | "
              f"{late:.3f} | {r['ground_speed_m_s']['mean']:.3f} | {np.mean(np.abs(r['lateral_drift_m'])):.2f} |")
    if "throughput" in res:
        print("\n| throughput (this machine) | env steps/s |\n|---|---|")
    for k, v in res.get("throughput", {}).items():
        if k != "note":
            print(f"| {k} | {v:.0f} |")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
