"""Sim-to-sim transfer table of a rolling policy.

Evaluates one policy object with the SB3 interface ``predict(obs, state, episode_start)`` --
the rolling gait (:class:`tensegrity_gym.tools.baselines.RollingGait`, ``--policy gait``), a training
run folder of ``agents.train`` (``--policy results/sac_roll_motor``: model + VecNormalize
statistics) or a Stable-Baselines3 model zip (``--policy PATH.zip --algo SAC``) -- unchanged, on

(a) ``TensegrityRoll-v0``, the nominal robot (N reset seeds from ``--seed``, default 1,000,000),
(b) N held-out randomised robots of ``TensegrityRoll-v0`` (``randomize``: every listed
    parameter drawn per robot, relative U(1 - s, 1 + s) x nominal; the same seeds), and
(c) the MuJoCo twin ``TensegrityRollMuJoCo-v0`` (N reset seeds, the same reset noise as (a)),
(d) with ``--twin-randomised``, also N randomised MuJoCo twins (row ``mujoco_twin_randomised``:
    the twin with the same ``randomize`` and seeds as (b), so twin i is robot i of (b), with the
    same drawn parameters, run by MuJoCo; see the twin's module doc for how each maps),

each for ``--time`` s (no time limit), and prints a table of the speed of the centre of mass
along the goal (``info["distance_rolled"] / T``: m/s and body lengths/s, body length = the
longest rod). Writes the numbers as JSON (``--out``, atomically). The seeds must be clear of every
seed the policy's training run used (its training envs ``seed + i``, its evaluation env during
training ``seed + 10000 + i``; a model zip: the run folder it lies in): an overlap is refused,
exit status 2, naming the run and the seeds (:mod:`agents.heldout`).

Run (with the package importable, e.g. ``PYTHONPATH=.``):
``python -m scripts.eval.eval_transfer --policy gait --robots 20 --time 20 --out results/transfer/gait.json``
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym_agents import common
from tensegrity_gym_agents.heldout import script_heldout_seeds
from tensegrity_gym.tools.baselines import RollingGait
from tensegrity_gym.envs.roll import TensegrityRollVectorEnv
from tensegrity_gym.envs.roll_mujoco import TensegrityRollMuJoCoEnv

#: default first held-out reset seed
SEED0 = 1_000_000
RANDOMIZE = {"rod_mass": 0.2, "stiffness": 0.2, "damping": 0.2, "friction": 0.2, "ground_stiffness": 0.2,
             "ground_damping": 0.2, "max_cable_speed": 0.2, "max_cable_acceleration": 0.2}


def make_policy(spec: str, algo: str | None, env):
    """The policy object: RollingGait built for ``env``; a training run folder of ``agents.train``
    (its ``model.zip`` + ``vecnormalize.pkl``, via ``agents.evaluate.load_trained``); or an SB3
    model zip (``--algo``; a ``vecnormalize.pkl`` beside it is applied to the observations)."""
    if spec == "gait":
        return RollingGait(env)
    path = Path(spec)
    if path.is_dir():
        from tensegrity_gym_agents.evaluate import load_trained
        if not (path / "config.yaml").is_file():
            raise SystemExit(f"--policy: {spec!r} is a folder without config.yaml (not a training run)")
        return load_trained(path, "final")[1]
    if not path.is_file():
        raise SystemExit(f"--policy: no such file {spec!r} (give 'gait', a run folder or an SB3 model .zip)")
    if not algo:
        raise SystemExit("--algo: needed with a model zip (PPO, SAC, TD3, A2C, DDPG)")
    import stable_baselines3 as sb3
    from tensegrity_gym_agents.evaluate import TrainedPolicy, load_vecnormalize, resolve_model
    cls = getattr(sb3, algo, None)
    if cls is None:
        raise SystemExit(f"--algo: unknown SB3 algorithm {algo!r}")
    _, vn = resolve_model(path.parent, str(path))
    return TrainedPolicy(cls.load(str(path), device="cpu"), None if vn is None else load_vecnormalize(vn))


#: env arguments of a training run that describe the robot the policy was trained on, not what it
#: senses: the evaluation sets the robots itself ((a) nominal, (b) randomised, (c) twin)
ROBOT_KEYS = ("randomize", "params", "goal_direction")


def run_env_kwargs(policy_spec: str) -> dict:
    """The env arguments a training run folder's policy needs to act (its observation and
    actuation settings: ``observation_mode``, ``history``, ``sensor_noise``, ``action_mode``, ...),
    from the run's ``config.yaml``; the robot (``randomize`` / ``params``) is the evaluation's."""
    path = Path(policy_spec)
    if policy_spec == "gait" or not (path / "config.yaml").is_file():
        return {}
    import yaml
    cfg = yaml.safe_load((path / "config.yaml").read_text()) or {}
    return {k: v for k, v in (cfg.get("env_kwargs") or {}).items() if k not in ROBOT_KEYS}


def run_vector(policy_spec, algo, n, T, seed0: int = SEED0, **env_kwargs):
    """Speeds (n,) m/s along the goal on n copies of TensegrityRoll-v0 (reset seeds seed0 + i)."""
    venv = TensegrityRollVectorEnv(num_envs=n, max_episode_steps=None, **env_kwargs)
    policy = make_policy(policy_spec, algo, venv)
    obs, info = venv.reset(seed=seed0)
    state, start = None, np.ones(n, bool)
    steps = int(round(T / venv.task.control_dt))
    for _ in range(steps):
        a, state = policy.predict(obs, state, episode_start=start, deterministic=True)
        start[:] = False
        obs, _, _, trunc, inf = venv.step(a)
        if np.any(inf["diverged"]):
            raise RuntimeError(f"diverged copies {np.flatnonzero(inf['diverged']).tolist()}")
    params = info.get("params")
    return inf["distance_rolled"] / T, venv.task.body_length, params


def run_twin(policy_spec, algo, n, T, seed0: int = SEED0, **env_kwargs):
    """Speeds (n,) m/s along the goal on the MuJoCo twin, reset seeds seed0 + i; with
    ``randomize`` in ``env_kwargs`` also the parameters each twin drew (name -> (n, ...))."""
    env = TensegrityRollMuJoCoEnv(**env_kwargs)
    policy = make_policy(policy_spec, algo, env)
    out, drawn = [], []
    steps = int(round(T / env.dt))
    for i in range(n):
        obs, info = env.reset(seed=seed0 + i)
        drawn.append(info.get("params", {}))
        state = None
        for k in range(steps):
            a, state = policy.predict(obs, state, episode_start=np.array([k == 0]), deterministic=True)
            obs, _, _, trunc, inf = env.step(a)
            if trunc:
                raise RuntimeError(f"twin diverged (seed {seed0 + i}, step {k})")
        out.append(inf["distance_rolled"] / T)
    params = {k: np.array([p[k] for p in drawn]) for k in drawn[0]}
    return np.array(out), env.task.body_length, params


def summary(v, L):
    return {"mean_m_s": float(v.mean()), "std_m_s": float(v.std()), "min_m_s": float(v.min()),
            "max_m_s": float(v.max()), "mean_body_lengths_s": float(v.mean() / L), "per_robot_m_s": v.tolist()}


def write_json(path: Path, data: dict) -> None:
    """``data`` as JSON at ``path`` (folder created), atomically (:func:`agents.common.write_json`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    common.write_json(path, data)


def table(paths: list[Path]) -> str:
    """Markdown table of several policies' transfer JSON files (one row per policy): speed in m/s
    and its share of the policy's own nominal speed on each robot set."""
    sets = ("nominal", "randomised", "mujoco_twin", "mujoco_twin_randomised")
    head = "| policy | trained on | observation | " + " | ".join(sets) + " |"
    lines = [head, "|---|---|---|" + "---:|" * len(sets)]
    for path in paths:
        d = json.loads(Path(path).read_text())
        kw = d.get("policy_env_kwargs", {})
        trained = "?"
        cfg = Path(d["policy"]) / "config.yaml"
        if cfg.is_file():
            import yaml
            ek = (yaml.safe_load(cfg.read_text()) or {}).get("env_kwargs") or {}
            rz = ek.get("randomize") or {}
            if not rz:
                trained = "nominal"
            elif len(set(rz.values())) == 1:
                trained = f"randomised +-{100 * next(iter(rz.values())):g} % ({len(rz)} parameters)"
            else:
                trained = "randomised (" + ", ".join(f"{k} {v:g}" for k, v in rz.items()) + ")"
        obs = kw.get("observation_mode", "state") + (f", history {kw['history']}" if kw.get("history", 1) != 1 else "")
        cells = []
        for k in sets:
            r = d["results"].get(k)
            cells.append("-" if r is None else f"{r['mean_m_s']:.3f} m/s ({100 * r['fraction_of_nominal']:.0f} %)")
        lines.append(f"| `{d['policy']}` | {trained} | {obs} | " + " | ".join(cells) + " |")
    ds = [json.loads(Path(p).read_text()) for p in paths]
    n = sorted({d["robots"] for d in ds})
    nt = sorted({d.get("twin_robots", d["robots"]) for d in ds})
    return "\n".join(lines) + (f"\n\n{'/'.join(map(str, n))} robots on our physics, {'/'.join(map(str, nt))} on the "
                                f"twin, {ds[0]['simulated_time_s']:g} s each; speed of the centre of mass "
                                "along the goal; (x %) = share of the same policy's nominal speed.\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--table", type=Path, nargs="+", default=None, metavar="JSON",
                    help="only print (and with --out write) the markdown table of these result files")
    ap.add_argument("--policy", default="gait", help="'gait' (RollingGait), a training run folder or an SB3 model .zip")
    ap.add_argument("--algo", default=None, help="SB3 algorithm of the zip (PPO, SAC, ...)")
    ap.add_argument("--robots", type=int, default=20, help="N: reset seeds / randomised robots / twin episodes")
    ap.add_argument("--seed", type=int, default=SEED0,
                    help=f"first held-out reset seed (default {SEED0}); must be clear of the policy run's own seeds")
    ap.add_argument("--twin-robots", type=int, default=None,
                    help="episodes on the MuJoCo twin (default --robots; the twin steps one robot at a time)")
    ap.add_argument("--time", type=float, default=20.0, help="simulated seconds per episode")
    ap.add_argument("--goal", type=float, nargs=2, default=(1.0, 0.0), metavar=("X", "Y"),
                    help="goal direction in the ground plane (default +x)")
    ap.add_argument("--twin-randomised", action="store_true",
                    help="also run the MuJoCo twin on the N randomised robots of (b) (row mujoco_twin_randomised)")
    ap.add_argument("--out", type=Path, default=None, help="JSON output path")
    a = ap.parse_args(argv)
    if a.table:
        md = table(a.table)
        print(md)
        if a.out is not None:
            a.out.parent.mkdir(parents=True, exist_ok=True)
            common.write_text(a.out, md)
        return 0
    if a.twin_robots is not None and a.twin_robots < 1:
        print(f"error: --twin-robots must be >= 1 (got {a.twin_robots})", file=sys.stderr)
        return 2
    if a.robots < 1 or not (np.isfinite(a.time) and a.time > 0):
        print(f"error: --robots must be >= 1 and --time > 0 (got {a.robots}, {a.time})", file=sys.stderr)
        return 2
    if not (np.all(np.isfinite(a.goal)) and np.hypot(*a.goal) > 0):
        print(f"error: --goal must be a non-zero finite vector, got {a.goal}", file=sys.stderr)
        return 2
    nt = a.robots if a.twin_robots is None else a.twin_robots
    seeds = script_heldout_seeds(a.seed, max(a.robots, nt), [] if a.policy == "gait" else [a.policy])
    rows, t0, kw = {}, time.time(), {"goal_direction": tuple(a.goal), **run_env_kwargs(a.policy)}
    v, L, _ = run_vector(a.policy, a.algo, a.robots, a.time, a.seed, **kw)
    rows["nominal"] = summary(v, L)
    v, L, params = run_vector(a.policy, a.algo, a.robots, a.time, a.seed, randomize=RANDOMIZE, **kw)
    rows["randomised"] = summary(v, L)
    v, L, _ = run_twin(a.policy, a.algo, nt, a.time, a.seed, **kw)
    rows["mujoco_twin"] = summary(v, L)
    twin_params = None
    if a.twin_randomised:
        v, L, twin_params = run_twin(a.policy, a.algo, nt, a.time, a.seed, randomize=RANDOMIZE, **kw)
        rows["mujoco_twin_randomised"] = summary(v, L)
    nominal = rows["nominal"]["mean_m_s"]
    print(f"policy {a.policy}, goal {tuple(a.goal)}, {a.robots} robots x {a.time:g} s, body length {L:.3f} m")
    print(f"{'setting':<22} {'speed m/s':>10} {'std':>7} {'min':>8} {'body len/s':>10} {'of nominal':>10}")
    for name, r in rows.items():
        frac = r["mean_m_s"] / nominal if nominal else float("nan")
        r["fraction_of_nominal"] = frac
        print(f"{name:<22} {r['mean_m_s']:>10.4f} {r['std_m_s']:>7.4f} {r['min_m_s']:>8.4f} "
              f"{r['mean_body_lengths_s']:>10.3f} {frac:>10.2f}")
    data = {"command": "python -m scripts.eval.eval_transfer " + " ".join(sys.argv[1:] if argv is None else argv),
            "policy": a.policy, "algo": a.algo, "policy_env_kwargs": {k: v for k, v in kw.items() if k != "goal_direction"},
            "goal_direction": list(a.goal), "robots": a.robots, "twin_robots": nt, "simulated_time_s": a.time,
            "seeds": f"{a.seed} .. {a.seed + a.robots - 1}", "reset_seeds": [seeds[0], seeds[-1]],
            "randomize": RANDOMIZE,
            "randomised_params_drawn": {k: np.asarray(p).tolist() for k, p in (params or {}).items()},
            **({"twin_randomised_params_drawn": {k: p.tolist() for k, p in twin_params.items()}}
               if twin_params is not None else {}),
            "results": rows, "wall_time_s": time.time() - t0,
            "machine": f"{platform.machine()}, {os.cpu_count()} CPUs visible, {platform.python_version()}"}
    if a.out is not None:
        write_json(a.out, data)
        print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
