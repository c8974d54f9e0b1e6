#!/usr/bin/env python
"""Sim-to-sim transfer on terrain: the same policies on this project's physics and on its MuJoCo
twin, with the same terrain or course and the same reset seeds.

    python -m scripts.eval.eval_transfer_terrain runs/ppo_navigate_s0 [runs/... | gait] --out results/transfer_terrain/navigate.json \
        [--courses 20] [--seed 20000] [--model final] [--env-kwargs '{}']
    python -m scripts.eval.eval_transfer_terrain runs/ppo_rough_s0 gait --terrain '{"generator": "rough"}' \
        --out results/transfer_terrain/rough.json [--episodes 8] [--steps 1000]
    python -m scripts.eval.eval_transfer_terrain results/climb/seed_0 [...] gait --slopes 0 10 20 26 \
        --out results/transfer_terrain/climb.json [--episodes 8] [--steps 1000] \
        [--twin-kwargs '{"contact_dampratio": 2.0}']

Each policy (a run folder of ``agents.train``, loaded by ``agents.evaluate.load_trained``, or
``gait``: :class:`tensegrity_gym.tools.baselines.RollingGait`) acts unchanged, with deterministic
actions, on

* navigation (default): ``TensegrityNavigate-v0`` and its twin ``TensegrityNavigateMuJoCo-v0``,
  one episode on each of ``--courses`` held-out courses (reset seeds 20000, 20001, ..., the
  courses of ``scripts/eval/eval_navigate.py``; the course is drawn from the reset seed, so both
  simulators get the same walls, rough patches and goals), 60 s (the registered time limit).
  Metric: the success rate (all goals reached).
* a terrain (``--terrain``: a terrain JSON file, or a JSON object: a terrain or a generator, see
  ``docs/terrain.md``): ``TensegrityRoll-v0`` and its twin ``TensegrityRollMuJoCo-v0`` with that
  terrain, ``--episodes`` episodes from reset seeds 30000, 30001, ... (those of
  ``scripts/eval/eval_rough.py``; a generator draws the same terrain for a seed on both),
  ``--steps`` control steps each (default the registered 1000, 20 s).
  Metric: the mean speed along the goal, m/s (an episode's ``distance_rolled`` over its duration).
* climbing (``--slopes``: slopes in degrees): ``TensegrityClimb-v0`` and its twin
  ``TensegrityClimbMuJoCo-v0`` on each slope (``slope_deg``; a run's ``slope_range`` is dropped),
  ``--episodes`` episodes from reset seeds 40000, 40001, ... (those of ``scripts/eval/eval_climb.py``),
  ``--steps`` control steps each (default 1000, 20 s). Metric, per slope: the mean uphill speed,
  m/s (the distance climbed along the slope over the episode's duration); per policy, the mean
  over the slopes of the ratio twin / project, and the ratio of the speeds averaged over the slopes.

``--seed`` sets the first reset seed of any mode. The seeds must be clear of every seed a policy's
run used (its training envs ``seed + i``, its evaluation env during training ``seed + 10000 + i``):
an overlap is refused, exit status 2, naming the run and the seeds (:mod:`agents.heldout`).

The env arguments are a run's own (its ``config.yaml``: observation, actuation, course settings)
without the robot it was trained on (``randomize``, ``params``: both simulators run the nominal
robot) and with the evaluation's scene (``--terrain``'s terrain, or each slope); then
``--env-kwargs``; the twin's also ``--twin-kwargs`` (the twin's own settings, which the project
env does not take: ``contact_dampratio``, ``spin_damping``, ``mj_integrator``), to measure the
transfer's sensitivity to them. Prints one line per policy (and slope) and writes JSON
(``--out``, atomically) with the per-episode numbers and the ratio twin / project of each metric
(None where the project's is 0).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym_agents import common
from tensegrity_gym_agents.evaluate import load_trained, run_episodes
from tensegrity_gym_agents.heldout import script_heldout_seeds
from tensegrity_gym.envs.climb import MAX_SLOPE_DEG
from tensegrity_gym.tools.baselines import RollingGait

#: (project env, MuJoCo twin) of each mode
ENVS = {"navigate": ("TensegrityNavigate-v0", "TensegrityNavigateMuJoCo-v0"),
        "terrain": ("TensegrityRoll-v0", "TensegrityRollMuJoCo-v0"),
        "climb": ("TensegrityClimb-v0", "TensegrityClimbMuJoCo-v0")}
#: default first reset seed of each mode (those of eval_navigate.py, eval_rough.py, eval_climb.py)
SEED0 = {"navigate": 20000, "terrain": 30000, "climb": 40000}
#: the metric of each mode, as the JSON names it
METRIC = {"navigate": "success_rate", "terrain": "mean_speed_m_s", "climb": "mean_uphill_speed_m_s"}
#: a run's env arguments that describe the robot it was trained on, not what it senses
ROBOT_KEYS = ("randomize", "params")


def load_policy(spec: str, which: str):
    """(policy factory ``env -> policy``, the run's env arguments) of ``spec``: ``gait`` or a run folder."""
    if spec == "gait":
        return (lambda env: RollingGait(env)), {}
    path = Path(spec)
    if not (path / "config.yaml").is_file():
        raise SystemExit(f"policy: {spec!r} is neither 'gait' nor a run folder of agents.train (no config.yaml)")
    cfg, policy, _, _ = load_trained(path, which)
    return (lambda env: policy), dict(cfg.get("env_kwargs") or {})


def parse_terrain(value: str | None):
    """``--terrain`` as the envs' ``terrain`` argument: a JSON file's path, or a JSON object."""
    if value is None:
        return None
    text = value.strip()
    if text.startswith("{"):
        try:
            return json.loads(text)
        except json.JSONDecodeError as e:
            raise SystemExit(f"--terrain: not a JSON object ({e.msg})") from None
    if not Path(value).is_file():
        raise SystemExit(f"--terrain: no such file {value!r} (give a terrain JSON file or a JSON object)")
    return value


def json_object(option: str, text: str) -> dict:
    """The JSON object ``text`` of ``option``; SystemExit naming the option otherwise."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as e:
        raise SystemExit(f"{option}: not JSON ({e.msg})") from None
    if not isinstance(value, dict):
        raise SystemExit(f"{option}: expected a JSON object, got {text!r}")
    return value


def env_kwargs_for(run_kwargs: dict, scene: dict, extra: dict) -> dict:
    """The env arguments of one policy's evaluation on ``scene`` (the evaluation's own env
    arguments: its terrain, or its slope) (see the module doc)."""
    kw = {k: v for k, v in run_kwargs.items() if k not in ROBOT_KEYS}
    kw.update(scene)
    kw.update(extra)
    return kw


def check_arguments(envs: tuple[str, str], kw: dict, twin_kw: dict) -> None:
    """Each env made once with a policy's arguments on the first scene (the twin's plus
    ``twin_kw``) and closed: an argument either refuses (its error names it) ends the script
    with that message before the policy's episodes run (the scenes differ in the slope only,
    checked in range before)."""
    for env_id, k in ((envs[0], kw), (envs[1], dict(kw, **twin_kw))):
        try:
            gym.make(env_id, **k).close()
        except (TypeError, ValueError) as e:
            raise SystemExit(f"error: {env_id}: {e}") from None


def compare(mode: str, envs: tuple[str, str], kw: dict, factory, seeds: list[int], steps: int | None,
            twin_kw: dict) -> dict:
    """One policy on the project env and on its twin with arguments ``kw`` (the twin's plus
    ``twin_kw``): both results and the ratio twin / project of the metric (None where the
    project's is 0)."""
    project = evaluate(mode, envs[0], kw, factory, seeds, steps)
    twin = evaluate(mode, envs[1], dict(kw, **twin_kw), factory, seeds, steps)
    ratio = twin["metric"] / project["metric"] if project["metric"] else None
    return {"project": project, "twin": twin, "ratio_twin_project": ratio}


def line(label: str, envs: tuple[str, str], row: dict, unit: str) -> str:
    """One printed line of a comparison ``row`` (:func:`compare`); it names the episodes that
    diverged (their metric counts the motion up to the divergence)."""
    r = row["ratio_twin_project"]
    text = (f"{label}: {envs[0]} {row['project']['metric']:.4g}, {envs[1]} {row['twin']['metric']:.4g} ({unit}), "
            f"twin/project {'-' if r is None else f'{r:.3f}'}")
    bad = {env: sum(row[side]["diverged"]) for env, side in zip(envs, ("project", "twin"))
           if any(row[side]["diverged"])}
    if bad:
        n = len(row["project"]["diverged"])
        text += "; DIVERGED: " + ", ".join(f"{env} {k} of {n} episodes" for env, k in bad.items())
    return text


def evaluate(mode: str, env_id: str, env_kwargs: dict, factory, seeds: list[int], steps: int | None) -> dict:
    """Per-episode numbers and the metric of one policy on ``env_id``."""
    kw = dict(env_kwargs) if steps is None else dict(env_kwargs, max_episode_steps=steps)
    eps = run_episodes(env_id, kw, factory, seeds)
    diverged = [bool(e["final"].get("diverged", 0.0)) for e in eps]
    if mode == "navigate":
        success = np.array([bool(e["final"]["success"]) for e in eps])
        goals = [int(e["final"]["goals_reached"]) for e in eps]
        return {"metric": float(success.mean()), "success": success.tolist(), "goals_reached": goals,
                "mean_goals_reached": float(np.mean(goals)), "diverged": diverged}
    speed = np.array([e["final"]["distance_rolled"] / (e["length"] * e["dt"]) for e in eps])
    return {"metric": float(speed.mean()), "speed_m_s": speed.tolist(), "std_m_s": float(speed.std()),
            "diverged": diverged}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("policies", nargs="+", help="run folders of agents.train, or 'gait' (the rolling gait)")
    ap.add_argument("--out", type=Path, required=True, help="JSON output path")
    ap.add_argument("--terrain", default=None,
                    help="evaluate rolling on this terrain (a JSON file or object) instead of navigation")
    ap.add_argument("--slopes", type=float, nargs="+", default=None,
                    help="evaluate climbing on these slopes (degrees) instead of navigation")
    ap.add_argument("--courses", type=int, default=20, help="navigation: held-out courses (reset seeds 20000+)")
    ap.add_argument("--episodes", type=int, default=8,
                    help="terrain, climbing: episodes (reset seeds 30000+, 40000+)")
    ap.add_argument("--seed", type=int, default=None,
                    help="first held-out reset seed (default per mode: navigation 20000, terrain 30000, climbing "
                         "40000); must be clear of every run's own seeds")
    ap.add_argument("--steps", type=int, default=None,
                    help="control steps per episode (default: the registered time limit)")
    ap.add_argument("--model", default="final", help="best, final or a model .zip of each run")
    ap.add_argument("--env-kwargs", default="{}", help="JSON object of extra env arguments (both simulators)")
    ap.add_argument("--twin-kwargs", default="{}",
                    help="JSON object of extra arguments of the twin only (e.g. contact_dampratio, spin_damping)")
    a = ap.parse_args(argv)
    if a.terrain is not None and a.slopes is not None:
        print("error: --terrain and --slopes: give one (rolling on a terrain, or climbing)", file=sys.stderr)
        return 2
    mode = "terrain" if a.terrain is not None else "climb" if a.slopes is not None else "navigate"
    n = a.courses if mode == "navigate" else a.episodes
    if n < 1 or (a.steps is not None and a.steps < 1):
        print(f"error: --courses / --episodes and --steps must be >= 1 (got {n}, {a.steps})", file=sys.stderr)
        return 2
    extra = json_object("--env-kwargs", a.env_kwargs)
    twin_kw = json_object("--twin-kwargs", a.twin_kwargs)
    if mode == "climb" and not all(0.0 <= s <= MAX_SLOPE_DEG for s in a.slopes):
        print(f"error: --slopes must be in [0, {MAX_SLOPE_DEG:g}] degrees (got {a.slopes})", file=sys.stderr)
        return 2
    terrain = parse_terrain(a.terrain)
    envs = ENVS[mode]
    seeds = list(script_heldout_seeds(SEED0[mode] if a.seed is None else a.seed, n,
                                      [p for p in a.policies if p != "gait"]))
    unit = {"navigate": "success", "terrain": "m/s along the goal", "climb": "m/s uphill"}[mode]
    results, t0 = {}, time.time()
    # the evaluation's scenes: one terrain (or flat ground, or the courses), or each slope, fixed
    # per evaluation (a run's slope_range would override it)
    scenes = ([{"slope_deg": s, "slope_range": None} for s in a.slopes] if mode == "climb"
              else [{} if terrain is None else {"terrain": terrain}])
    for spec in a.policies:
        factory, run_kwargs = load_policy(spec, a.model)
        check_arguments(envs, env_kwargs_for(run_kwargs, scenes[0], extra), twin_kw)
        if mode != "climb":
            kw = env_kwargs_for(run_kwargs, scenes[0], extra)
            results[spec] = {"env_kwargs": kw, **compare(mode, envs, kw, factory, seeds, a.steps, twin_kw)}
            print(line(spec, envs, results[spec], unit), flush=True)
            continue
        per_slope = {}
        for slope, scene in zip(a.slopes, scenes):
            kw = env_kwargs_for(run_kwargs, scene, extra)
            per_slope[f"{slope:g}"] = row = {"env_kwargs": kw,
                                             **compare(mode, envs, kw, factory, seeds, a.steps, twin_kw)}
            print(line(f"{spec} at {slope:g} deg", envs, row, unit), flush=True)
        ratios = [r["ratio_twin_project"] for r in per_slope.values() if r["ratio_twin_project"] is not None]
        mean = float(np.mean(ratios)) if ratios else None
        speeds = {side: float(np.mean([r[side]["metric"] for r in per_slope.values()])) for side in ("project", "twin")}
        results[spec] = {"slopes": per_slope, "mean_ratio_twin_project": mean, "mean_speed_m_s": speeds,
                         "ratio_of_mean_speeds": speeds["twin"] / speeds["project"] if speeds["project"] else None}
        print(f"{spec}: mean twin/project over the slopes {'-' if mean is None else f'{mean:.3f}'}", flush=True)
    data = {"command": "python -m scripts.eval.eval_transfer_terrain " + " ".join(sys.argv[1:] if argv is None else argv),
            "mode": mode, "metric": METRIC[mode], "project_env": envs[0], "twin_env": envs[1],
            "terrain": a.terrain, "slopes_deg": a.slopes, "model": a.model, "twin_kwargs": twin_kw,
            "reset_seeds": [seeds[0], seeds[-1]], "steps": a.steps, "results": results,
            "wall_time_s": time.time() - t0}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    common.write_json(a.out, data)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
