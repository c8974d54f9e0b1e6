"""Evaluate a trained run beside the non-learning baselines and a random policy.

Usage (from the repository root)::

    python -m agents.evaluate results/ppo_shape_rest_length                  # 100 held-out episodes
    python -m agents.evaluate RUN_DIR --model final --n-episodes 50 --gif --out RUN_DIR/eval_final
    python -m agents.evaluate RUN_DIR --no-baselines --no-random

``RUN_DIR`` is a directory written by :mod:`agents.train` (``config.yaml`` gives the env id and
its kwargs; ``best_model.zip`` + ``best_vecnormalize.pkl`` or ``model.zip`` +
``vecnormalize.pkl`` the policy and its observation normalisation).

Episodes run on **held-out seeds** ``--seed`` (default 1_000_000) + i, i < ``--n-episodes``,
checked disjoint from every reset seed the run used (training envs ``seed + i``, its evaluation
env during training ``seed + 10_000 + i``; the rule: :mod:`agents.heldout`): an overlap is refused
(exit status 2) naming the run and the seeds. Every policy sees the same seeds, hence the same
targets / starts.
When the env has a batched vector env, the episodes of one policy run as one batch (env i
reset with seed ``--seed + i``, which equals a single env reset with that seed); otherwise one
single env after another. Actions are deterministic for the trained policy.

Printed table (and ``metrics.json``): mean and std of the return, success rate
(``info["is_success"]`` at the last step), episode length; for ``TensegrityShape-v0`` the final
mean and max node error in m and the median final max error as a fraction of the structure's
height; for ``TensegrityRoll-v0`` the speed (distance rolled / episode duration) in m/s and body
lengths per second. Figures: ``learning_curve.png`` (evaluation returns and success rate vs
env steps from ``eval/evaluations.npz``, training episode returns from ``monitor/``),
``episodes.png`` (shape: error vs time, per-episode final errors; roll: centre-of-mass paths),
``rollout.gif`` with ``--gif``.
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from pathlib import Path

import numpy as np

from . import common, envs, heldout, hyperparameters, parsing
from .episode_metrics import format_table, scene_scales, summarize
from .figures import plot_episodes, plot_learning_curve, write_gif
from tensegrity_gym.core.checks import check_count
from tensegrity_gym.integrations.torch_threads import num_threads_arg, passive_openmp_wait, set_torch_threads

passive_openmp_wait()     # before torch loads its OpenMP runtime (see the function)

HELD_OUT_SEED = 1_000_000

# non-learning baselines per env id: (label, "module:Class"); constructed as Class(env)
BASELINES = {
    "TensegrityShape-v0": [("nnls", "tensegrity_gym.tools.baselines:NNLSShapeController")],
    "TensegrityRoll-v0": [("gait", "tensegrity_gym.tools.baselines:RollingGait")],
}


# ---------------------------------------------------------------------- policies
class TrainedPolicy:
    """An SB3 model plus its (frozen) VecNormalize observation statistics; ``predict`` like SB3."""

    def __init__(self, model, vecnormalize=None):
        self.model = model
        self.vn = vecnormalize

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        o = np.asarray(obs, np.float32)
        if self.vn is not None and getattr(self.vn, "norm_obs", False):
            o = self.vn.normalize_obs(o)
        return self.model.predict(o, state=state, episode_start=episode_start, deterministic=deterministic)


class RandomPolicy:
    """Uniform random actions in the Box, from its own seeded generator."""

    def __init__(self, action_space, seed: int):
        self.low, self.high = action_space.low, action_space.high
        self.rng = np.random.default_rng(seed)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(obs)
        shape = self.low.shape if obs.ndim == 1 else (obs.shape[0],) + self.low.shape
        return self.rng.uniform(self.low, self.high, shape).astype(np.float32), state


def load_vecnormalize(path: Path):
    """VecNormalize statistics from a pickle (no env needed: only ``normalize_obs`` is used)."""
    vn = common.load_vecnormalize_file(path)
    vn.training = False
    return vn


def resolve_model(run_dir: Path, which: str) -> tuple[Path, Path | None]:
    """(model zip, vecnormalize pkl or None) of ``which`` = best | final | a path to a zip."""
    if which == "best":
        m, v = run_dir / "best_model.zip", run_dir / "best_vecnormalize.pkl"
        if not m.exists():
            print(f"note: {m} missing (no evaluation during training); using model.zip")
            return resolve_model(run_dir, "final")
    elif which == "final":
        m, v = run_dir / "model.zip", run_dir / "vecnormalize.pkl"
    else:
        m = Path(which)
        v = m.with_name(m.name.replace("model", "vecnormalize").replace(".zip", ".pkl"))
        if "rl_model_" in m.name:  # a checkpoint
            v = m.with_name(m.name.replace("rl_model_", "rl_model_vecnormalize_").replace(".zip", ".pkl"))
    if not m.exists():
        raise FileNotFoundError(f"--model: {m} does not exist" + ("" if which in ("best", "final") else
                                " (choose best, final, or the path of a model .zip)"))
    return m, (v if v.exists() else None)


def load_trained(run_dir: Path, which: str, device: str = "cpu"):
    cfg = common.read_run_config(run_dir / "config.yaml")
    model_path, vn_path = resolve_model(run_dir, which)
    if cfg["hyperparams_resolved"].get("normalize") is not None and vn_path is None:
        raise FileNotFoundError(f"{run_dir}: trained with VecNormalize but its statistics beside {model_path.name} "
                                "are missing")
    Algo = hyperparameters.get_algo(cfg["algo"])
    model = common.load_model_file(Algo, model_path, device=device)
    vn = load_vecnormalize(vn_path) if vn_path is not None else None
    return cfg, TrainedPolicy(model, vn), model_path, model


# ---------------------------------------------------------------------- rollouts
def _scalar_infos(info: dict, i: int | None, keys) -> dict:
    out = {}
    for k in keys:
        if k in info:
            v = info[k] if i is None else info[k][i]
            out[k] = float(np.asarray(v))
    return out


def run_episodes(env_id: str, env_kwargs: dict, policy_factory, seeds: list[int], record_keys=(),
                 batched: bool | None = None) -> list[dict]:
    """Roll out one episode per seed. ``policy_factory(env)`` builds the policy for that env.

    Returns per-episode dicts: ``return``, ``length``, ``final`` (scalar info keys at the last
    step), ``trace`` (dict key -> (T,) values of ``record_keys`` over the episode, plus ``com``
    (T, 3) if the info has ``com_position``), ``dt`` (control step, s).
    """
    import gymnasium as gym
    if batched is None:
        batched = envs.has_vector_entry_point(env_id)
    n = len(seeds)
    if batched:
        env = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **env_kwargs)
        policy = policy_factory(env)
        obs, _ = env.reset(seed=[int(s) for s in seeds])
        dt = float(getattr(env, "dt", np.nan))
        ret = np.zeros(n)
        length = np.zeros(n, int)
        active = np.ones(n, bool)
        final: list[dict] = [{} for _ in range(n)]
        traces: list[dict] = [{k: [] for k in record_keys} | {"com": []} for _ in range(n)]
        pstate, start = None, np.ones(n, bool)
        while active.any():
            act, pstate = policy.predict(obs, state=pstate, episode_start=start, deterministic=True)
            start = np.zeros(n, bool)
            obs, rew, term, trunc, info = env.step(act)
            keys = [k for k in info if not k.startswith("_") and np.ndim(info[k]) == 1]
            for i in np.flatnonzero(active):
                ret[i] += float(rew[i])
                length[i] += 1
                for k in record_keys:
                    if k in info:
                        traces[i][k].append(float(info[k][i]))
                if "com_position" in info:
                    traces[i]["com"].append(np.asarray(info["com_position"][i], float).tolist())
                if term[i] or trunc[i]:
                    final[i] = _scalar_infos(info, i, keys)
                    active[i] = False
        env.close()
        return [{"seed": int(seeds[i]), "return": float(ret[i]), "length": int(length[i]), "final": final[i],
                 "trace": traces[i], "dt": dt} for i in range(n)]
    out = []
    env = gym.make(env_id, **env_kwargs)
    policy = policy_factory(env)
    dt = float(getattr(env.unwrapped, "dt", np.nan))
    for s in seeds:
        obs, _ = env.reset(seed=int(s))
        done, R, L = False, 0.0, 0
        trace = {k: [] for k in record_keys} | {"com": []}
        pstate, start = None, np.ones(1, bool)
        while not done:
            act, pstate = policy.predict(obs, state=pstate, episode_start=start, deterministic=True)
            start = np.zeros(1, bool)
            obs, r, term, trunc, info = env.step(act)
            R += float(r)
            L += 1
            for k in record_keys:
                if k in info:
                    trace[k].append(float(info[k]))
            if "com_position" in info:
                trace["com"].append(np.asarray(info["com_position"], float).tolist())
            done = term or trunc
        keys = [k for k, v in info.items() if np.ndim(v) == 0 and not isinstance(v, (str, dict))]
        out.append({"seed": int(s), "return": R, "length": L, "final": _scalar_infos(info, None, keys),
                    "trace": trace, "dt": dt})
    env.close()
    return out


# ---------------------------------------------------------------------- main
def build_parser():
    p = argparse.ArgumentParser(prog=f"python -m {common.PACKAGE}.evaluate", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", help="run directory written by agents.train")
    p.add_argument("--model", default="best", help="best (default), final, or a path to a model zip")
    p.add_argument("--n-episodes", type=parsing.arg_type(lambda v: check_count(v, "--n-episodes", 1)), default=100)
    p.add_argument("--seed", type=int, default=HELD_OUT_SEED,
                   help="first held-out reset seed (default 1000000); must be clear of the run's own seeds")
    p.add_argument("--out", default=None, help="output directory (default RUN_DIR/evaluation)")
    p.add_argument("--no-baselines", action="store_true", help="skip the non-learning baselines")
    p.add_argument("--no-random", action="store_true", help="skip the random policy")
    p.add_argument("--baseline-episodes", type=int, default=None,
                   help="episodes for the baselines/random (default = --n-episodes)")
    p.add_argument("--gif", action="store_true", help="write rollout.gif of the trained policy (seed --seed)")
    p.add_argument("--gif-size", type=int, default=256, help="GIF frame width and height, pixels (default 256)")
    p.add_argument("--env-kwargs", nargs="*", metavar="KEY:VALUE",
                   help="override env kwargs for evaluation (e.g. backend:numpy)")
    p.add_argument("--copy-run-files", action="store_true",
                   help="copy the run's config.yaml, command.txt, versions.json, state.json, its evaluations "
                        "during training (eval/evaluations.npz: agents.multiseed draws learning curves from it) "
                        "and the evaluated model (+ VecNormalize statistics, if under 5 MB) into --out (for "
                        "committed results)")
    p.add_argument("--num-threads", type=num_threads_arg, default=1)
    return p


def evaluate(argv=None) -> dict:
    args = build_parser().parse_args(argv)
    set_torch_threads(args.num_threads)
    envs.import_env_packages(["tensegrity_gym"])
    run_dir = Path(args.run_dir)
    if not (run_dir / "config.yaml").exists():
        raise FileNotFoundError(f"{run_dir}: no config.yaml (not a run directory of agents.train)")
    if args.n_episodes < 1:
        raise ValueError(f"--n-episodes: must be >= 1, got {args.n_episodes}")
    if not 16 <= args.gif_size <= 2048:
        raise ValueError(f"--gif-size: must be in [16, 2048] pixels, got {args.gif_size}")
    seeds = list(heldout.heldout_seeds(args.seed, args.n_episodes))
    # refused when the run (or the run of a --model file) trained or selected on one of them
    heldout.check_heldout(seeds, [run_dir] + ([] if args.model in ("best", "final") else [args.model]))
    cfg, trained, model_path, model = load_trained(run_dir, args.model)
    env_id = cfg["env"]
    env_kwargs = {**cfg["env_kwargs"], **parsing.parse_kv_list(args.env_kwargs, ":", "--env-kwargs")}
    nb = args.baseline_episodes or args.n_episodes
    envs.make_env(env_id, env_kwargs).close()     # an unknown --env-kwargs key: named, no traceback
    out = Path(args.out) if args.out else run_dir / "evaluation"
    out.mkdir(parents=True, exist_ok=True)
    record = ("tracking_error", "max_node_error", "distance_rolled")
    scales = scene_scales(env_id, env_kwargs)

    policies = {f"{cfg['algo']} (trained)": (lambda env: trained, seeds)}
    if not args.no_baselines:
        for label, spec in BASELINES.get(env_id, []):
            mod, cls = spec.split(":")
            try:
                C = getattr(importlib.import_module(mod), cls)
                import gymnasium as gym
                probe = gym.make(env_id, **env_kwargs)
                try:
                    C(probe)  # raises ValueError if the baseline does not fit this scene / action mode
                finally:
                    probe.close()
            except (ImportError, AttributeError, ValueError) as e:
                print(f"note: baseline {label} ({spec}) not evaluated: {e}")
                continue
            policies[label] = ((lambda C: (lambda env: C(env)))(C), seeds[:nb])
    if not args.no_random:
        policies["random"] = (lambda env: RandomPolicy(env.single_action_space if hasattr(env, "single_action_space")
                                                      else env.action_space, args.seed), seeds[:nb])
    all_eps, results, timings = {}, {}, {}
    for name, (factory, sd) in policies.items():
        t0 = time.time()
        eps = run_episodes(env_id, env_kwargs, factory, sd, record)
        timings[name] = time.time() - t0
        all_eps[name] = eps
        results[name] = summarize(eps, scales)
        print(f"  {name}: {len(sd)} episodes in {timings[name]:.1f} s")

    state = json.loads((run_dir / "state.json").read_text()) if (run_dir / "state.json").exists() else {}
    table = format_table(results)
    print(f"\n{env_id} {env_kwargs}  model {model_path} ({model.num_timesteps} training steps)\n"
          f"held-out seeds {seeds[0]}..{seeds[-1]}\n")
    print(table)
    metrics = {
        "env": env_id, "env_kwargs": env_kwargs, "algo": cfg["algo"], "run_dir": str(run_dir),
        "model": str(model_path), "model_num_timesteps": int(model.num_timesteps),
        "training_wall_time_s": state.get("wall_time_s"), "training_status": state.get("status"),
        # the CPU the training ran on (its wall time depends on it); "CPU not recorded" for runs
        # older than this field
        "training_cpu_model": (state.get("machine") or {}).get("cpu_model") or "CPU not recorded",
        "held_out_seeds": [seeds[0], seeds[-1]], "scales": scales, "results": results,
        "eval_wall_time_s": timings,
        "train_command": (run_dir / "command.txt").read_text().strip().splitlines()[-1]
        if (run_dir / "command.txt").exists() else None,
        "evaluate_command": " ".join(["python", "-m", f"{common.PACKAGE}.evaluate"] + (argv if argv is not None else sys.argv[1:])),
        "versions": common.package_versions(),
    }
    common.write_json(out / "metrics.json", metrics)
    (out / "table.md").write_text(table + "\n")
    per_ep = {name: [{"seed": e["seed"], "return": e["return"], "length": e["length"], "final": e["final"]}
                     for e in eps] for name, eps in all_eps.items()}
    common.write_json(out / "episodes.json", per_ep)
    title = f"{env_id} {cfg['algo'].upper()} " + ",".join(f"{k}={v}" for k, v in env_kwargs.items()
                                                          if k in ("action_mode", "structure"))
    if plot_learning_curve(run_dir, out / "learning_curve.png", title, scales.get("success_tolerance")):
        print(f"wrote {out / 'learning_curve.png'}")
    if plot_episodes(all_eps, scales, out / "episodes.png", title):
        print(f"wrote {out / 'episodes.png'}")
    if args.gif:
        n = write_gif(env_id, env_kwargs, trained, seeds[0], out / "rollout.gif", size=args.gif_size)
        print(f"wrote {out / 'rollout.gif'} ({n} frames)")
    if args.copy_run_files and out.resolve() != run_dir.resolve():
        import shutil
        for f in ("config.yaml", "command.txt", "versions.json", "state.json", "eval/evaluations.npz"):
            if (run_dir / f).exists():
                (out / f).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(run_dir / f, out / f)
        vn = resolve_model(run_dir, args.model)[1]
        if model_path.stat().st_size < 5e6:
            shutil.copy2(model_path, out / "model.zip")
            if vn is not None:
                shutil.copy2(vn, out / "vecnormalize.pkl")
            print(f"copied the run files and the model ({model_path.stat().st_size / 1e6:.1f} MB) to {out}")
        else:
            print(f"copied the run files to {out} (model {model_path.stat().st_size / 1e6:.1f} MB: not copied)")
    print(f"wrote {out / 'metrics.json'}")
    return metrics


def main(argv=None) -> int:
    return common.run_cli(evaluate, argv, errors=(ValueError, OSError))   # OSError: a read-only --out, ...


if __name__ == "__main__":
    sys.exit(main())
