"""Hyperparameter searches and multi-seed repeats of :mod:`agents.train` on Ray Tune.

Usage::

    python -m agents.tune smoke.yml                     # embedded local Ray
    python -m agents.tune sweep1.yml --storage runs_tune --max-concurrent 16
    python -m agents.tune CONFIG.yml --address auto                   # an existing Ray cluster
    python -m agents.tune CONFIG.yml --summary-only                   # table + plot of a finished sweep

A shipped sweep (``agents/sweeps/``) is named by its file name, installed or in a checkout; any
other argument is the path of a config of your own.

A config (YAML) has a ``name``, the ``train`` arguments shared by every trial, and either

* ``variants``: named runs (each a set of ``train`` arguments merged over the shared ones), each
  repeated over ``seeds`` (a multi-seed repeat; a variant may give its own ``seeds``), or
* ``search``: a search space over ``hyperparams`` / ``env_kwargs`` entries sampled ``num_samples``
  times by Optuna (``search_alg: optuna``) or at random (``random``), optionally with ASHA early
  stopping (``scheduler: asha``) on the evaluation ``metric``; each sample is repeated over
  ``seeds``.

``train`` keys are the options of ``python -m agents.train`` with ``_`` for ``-``
(``algo``, ``env``, ``n_timesteps``, ``n_envs``, ``eval_freq``, ``eval_episodes``, ``save_freq``,
``max_wall_time``, ...), ``env_kwargs`` and ``hyperparams`` as mappings. See agents/README.md.

Every trial is one ``agents.train`` run (1 CPU, torch and numba threads 1) in
``<storage>/<name>/runs/<trial>/``; it reports each evaluation to Tune (``eval_return``,
``eval_success``, ``timesteps``). Concurrency is capped at the CPUs Ray has (the machine's cores
by default, ``--max-concurrent`` to lower it). Tune's experiment state and the trial results live
in ``<storage>/<name>/``; running the same command again after an interrupt resumes the sweep
(``Tuner.restore``): finished trials are kept, unfinished ones continue from their run
directory's latest model (``agents.train --resume``).

At the end: ``summary.md`` / ``summary.json`` (per variant: final evaluation return and success
rate per seed, the IQM over seeds with a 95 % percentile-bootstrap interval from
``scipy.stats.bootstrap`` -- rliable's estimator, computed without rliable, whose dependency
``arch`` does not import with pandas 3) and ``summary.png`` (evaluation curves, IQM over seeds
with the interval as a band).
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import sys
import time
from pathlib import Path

from . import common, envs, hyperparameters, parsing
from .summary import METRIC_MEANING, final_metrics, summarize

#: the sweep configs shipped with the package: the config argument names one relative to this folder
SWEEPS_DIR = Path(__file__).resolve().parent / "sweeps"
SEARCH_KINDS = ("uniform", "loguniform", "randint", "choice", "quniform")
TRAIN_KEYS = {"algo", "env", "n_timesteps", "n_envs", "eval_freq", "eval_episodes", "n_eval_envs", "save_freq",
              "save_replay_buffer", "max_wall_time", "vec_env", "env_kwargs", "hyperparams", "device", "conf_file",
              "gym_packages"}


# ---------------------------------------------------------------------- config
def load_config(path: str | Path) -> dict:
    """Read and validate a sweep config (errors name the field and the value): a file of the
    user's own (a path), else a shipped one named relative to :data:`SWEEPS_DIR` (``smoke.yml``)."""
    path = parsing.find_file(path, SWEEPS_DIR, "sweep config")
    cfg = parsing.read_yaml(path) or {}
    if not isinstance(cfg, dict):
        raise ValueError(f"{path}: expected a mapping")
    unknown = set(cfg) - {"name", "train", "variants", "search", "seeds", "metric", "mode", "max_concurrent",
                          "description"}
    if unknown:
        raise ValueError(f"{path}: unknown keys {sorted(unknown)}")
    cfg.setdefault("name", path.stem)
    cfg.setdefault("train", {})
    cfg.setdefault("seeds", [0])
    cfg.setdefault("metric", "eval_return")
    cfg.setdefault("mode", "max")
    if cfg["metric"] not in METRIC_MEANING:
        raise ValueError(f"{path}: metric must be one of {sorted(METRIC_MEANING)} (what each trial reports), "
                         f"got {cfg['metric']!r}")
    if cfg["mode"] not in ("max", "min"):
        raise ValueError(f"{path}: mode must be max or min, got {cfg['mode']!r}")
    if not isinstance(cfg["seeds"], list) or not cfg["seeds"] or not all(isinstance(s, int) for s in cfg["seeds"]):
        raise ValueError(f"{path}: seeds must be a non-empty list of integers, got {cfg['seeds']!r}")
    _check_train(cfg["train"], f"{path}: train")
    if ("variants" in cfg) == ("search" in cfg):
        raise ValueError(f"{path}: give exactly one of 'variants' (named runs x seeds) or 'search'")
    if "variants" in cfg:
        names = set()
        for i, v in enumerate(cfg["variants"]):
            if not isinstance(v, dict) or "name" not in v:
                raise ValueError(f"{path}: variants[{i}] must be a mapping with a 'name', got {v!r}")
            if v["name"] in names:
                raise ValueError(f"{path}: variants[{i}]: duplicate name {v['name']!r}")
            names.add(v["name"])
            _check_train({k: x for k, x in v.items() if k not in ("name", "seeds")}, f"{path}: variants[{i}]")
            if "seeds" in v and (not isinstance(v["seeds"], list) or not v["seeds"]):
                raise ValueError(f"{path}: variants[{i}].seeds must be a non-empty list, got {v['seeds']!r}")
    else:
        s = cfg["search"]
        s.setdefault("num_samples", 8)
        s.setdefault("search_alg", "optuna")
        s.setdefault("scheduler", "none")
        if s["search_alg"] not in ("optuna", "random"):
            raise ValueError(f"{path}: search.search_alg must be optuna or random, got {s['search_alg']!r}")
        if s["scheduler"] not in ("asha", "none"):
            raise ValueError(f"{path}: search.scheduler must be asha or none, got {s['scheduler']!r}")
        s.setdefault("time_attr", "timesteps")
        if s["time_attr"] not in ("timesteps", "wall_time_s"):
            raise ValueError(f"{path}: search.time_attr must be timesteps (env steps) or wall_time_s (training "
                             f"wall clock, s), got {s['time_attr']!r}")
        if s["time_attr"] == "wall_time_s" and cfg["train"].get("max_wall_time") is None:
            raise ValueError(f"{path}: search.time_attr wall_time_s needs train.max_wall_time (ASHA's max_t)")
        if not isinstance(s.get("space"), dict) or not s["space"]:
            raise ValueError(f"{path}: search.space must map 'hyperparams.<key>' / 'env_kwargs.<key>' to a "
                             "distribution")
        for key, dist in s["space"].items():
            if not key.startswith(("hyperparams.", "env_kwargs.")):
                raise ValueError(f"{path}: search.space key {key!r} must start with hyperparams. or env_kwargs.")
            if not isinstance(dist, dict) or len(dist) != 1 or next(iter(dist)) not in SEARCH_KINDS:
                raise ValueError(f"{path}: search.space.{key}: expected one of {SEARCH_KINDS} as "
                                 f"{{kind: [args]}}, got {dist!r}")
    return cfg


def _check_train(d: dict, where: str) -> None:
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected a mapping of agents.train options, got {d!r}")
    bad = set(d) - TRAIN_KEYS
    if bad:
        raise ValueError(f"{where}: unknown agents.train options {sorted(bad)} (known: {sorted(TRAIN_KEYS)}; "
                         "log_dir, seed and resume are set by agents.tune)")


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if k in ("env_kwargs", "hyperparams") and isinstance(v, dict):
            out[k] = {**out.get(k, {}), **v}
        else:
            out[k] = v
    return out


def train_argv(opts: dict, seed: int, log_dir: str | Path) -> list[str]:
    """``agents.train`` command-line arguments of one trial."""
    argv = ["--seed", str(int(seed)), "--log-dir", str(log_dir), "--no-progress-bar", "--num-threads", "1"]
    for k, v in opts.items():
        if k in ("env_kwargs", "hyperparams"):
            if v:
                argv += [f"--{k.replace('_', '-')}", json.dumps(parsing.to_yaml_safe(v))] if k == "env_kwargs" else \
                    ["--hyperparams"] + [f"{hk}={_hp_text(hv)}" for hk, hv in v.items()]
        elif k == "gym_packages":
            argv += ["--gym-packages", *v]
        elif isinstance(v, bool):
            if v:
                argv.append(f"--{k.replace('_', '-')}")
        else:
            argv += [f"--{k.replace('_', '-')}", str(v)]
    return argv


def _hp_text(v) -> str:
    """A hyperparameter value as ``--hyperparams`` parses it (JSON / Python literal / zoo string)."""
    if isinstance(v, str):
        return v
    return json.dumps(parsing.to_yaml_safe(v))


def trial_list(cfg: dict) -> list[dict]:
    """The runs of a ``variants`` config: one dict per (variant, seed)."""
    runs = []
    for v in cfg["variants"]:
        opts = _merge(cfg["train"], {k: x for k, x in v.items() if k not in ("name", "seeds")})
        for seed in v.get("seeds", cfg["seeds"]):
            runs.append({"variant": v["name"], "seed": int(seed), "opts": opts})
    return runs


def search_space(cfg: dict) -> dict:
    from ray import tune
    space = {}
    for key, dist in cfg["search"]["space"].items():
        kind, args = next(iter(dist.items()))
        args = list(args) if isinstance(args, (list, tuple)) else [args]
        space[key] = getattr(tune, kind)(*args) if kind != "choice" else tune.choice(args)
    return space


# ---------------------------------------------------------------------- the trainable
def run_trial(config: dict) -> None:
    """One Tune trial: an ``agents.train`` run in ``<experiment>/runs/<trial>/``, resumed from its
    latest model when the trial is restored."""
    from ray import tune
    from . import train as train_mod
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("MPLBACKEND", "Agg")
    opts = copy.deepcopy(config["opts"])
    for key, val in config.items():  # sampled values: "hyperparams.<k>" / "env_kwargs.<k>"
        if "." in key:
            group, name = key.split(".", 1)
            opts.setdefault(group, {})[name] = val
    ctx = tune.get_context()
    name = config.get("variant") or f"trial_{ctx.get_trial_id()}"
    run_dir = Path(config["runs_dir"]) / f"{name}_s{config['seed']}"
    if (run_dir / "config.yaml").exists():  # a restored trial (or a re-run sweep): continue that run
        # Tune runs this only for a trial it wants continued (a trial it stopped, e.g. by ASHA, stays
        # stopped), so a run stopped by an interrupted sweep ("stopped", "interrupted") continues too
        state = json.loads((run_dir / "state.json").read_text()) if (run_dir / "state.json").exists() else {}
        left = None
        if opts.get("max_wall_time") is not None:  # the wall-time budget counts the earlier segments
            left = float(opts["max_wall_time"]) - float(state.get("wall_time_s", 0.0))
        if state.get("status") == "finished" or (state.get("status") == "time_limit" and (left or 0) <= 1.0):
            tune.report(final_metrics(run_dir, config))
            return
        argv = ["--resume", str(run_dir), "--no-progress-bar", "--num-threads", "1"]
        if left is not None:
            argv += ["--max-wall-time", str(max(left, 1.0))]
    else:
        argv = train_argv(opts, config["seed"], run_dir)

    def report(metrics):
        tune.report({**metrics, "variant": name, "seed": int(config["seed"])})

    train_mod.train(argv, report=report)
    tune.report(final_metrics(run_dir, {**config, "variant": name}))


# ---------------------------------------------------------------------- driver
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"python -m {common.PACKAGE}.tune", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", help="sweep config (YAML): a shipped one by its name in agents/sweeps/ (smoke.yml), or a path")
    p.add_argument("--storage", default="runs_tune", help="folder of experiments (default runs_tune/)")
    p.add_argument("--address", default=None,
                   help="address of an existing Ray cluster ('auto' or host:port); default: start an embedded "
                        "local Ray (nothing to set up)")
    p.add_argument("--num-cpus", type=int, default=None,
                   help="CPUs of the embedded local Ray (default: this machine's cores)")
    p.add_argument("--max-concurrent", type=int, default=None,
                   help="at most this many trials at once (default: the config's max_concurrent, else the CPUs "
                        "Ray has; each trial uses 1 CPU)")
    p.add_argument("--fresh", action="store_true",
                   help="refuse to resume: error if the experiment folder already exists")
    p.add_argument("--summary-only", action="store_true", help="only (re)write the summary of an experiment")
    return p


def tune_main(argv: list[str] | None = None) -> dict:
    args = build_parser().parse_args(argv)
    cfg = load_config(args.config)
    storage = Path(args.storage).resolve()
    exp_dir = storage / cfg["name"]
    if args.summary_only:
        return summarize(exp_dir, cfg["metric"])
    try:
        import ray
        from ray import tune
    except ImportError:
        raise ValueError("agents.tune needs Ray Tune: pip install 'tensegrity_gym[tune]' (or 'ray[tune]')") from None
    for v in ([cfg["train"]] + [dict(x) for x in cfg.get("variants", [])]):
        if "algo" in v:
            hyperparameters.get_algo(v["algo"])
    envs.import_env_packages(["tensegrity_gym"])
    env_ids = {v.get("env", cfg["train"].get("env")) for v in cfg.get("variants", [cfg["train"]])}
    for e in env_ids:
        if e is None:
            raise ValueError(f"{args.config}: train.env (or each variant's env) is required")
        envs.check_env_id(e)

    if not ray.is_initialized():
        if args.address:
            ray.init(address=args.address, log_to_driver=False)
        else:
            # the driver's import path reaches the workers (repository checkout or installed package)
            pkg_root = str(Path(common.__file__).resolve().parent.parent)
            pp = os.pathsep.join([pkg_root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])
            ray.init(num_cpus=args.num_cpus or os.cpu_count() or 1, include_dashboard=False, log_to_driver=False,
                     runtime_env={"env_vars": {"PYTHONPATH": pp, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                                               "MKL_NUM_THREADS": "1", "MPLBACKEND": "Agg"}})
    cpus = int(ray.cluster_resources().get("CPU", 1))
    max_conc = args.max_concurrent or cfg.get("max_concurrent") or cpus
    max_conc = max(1, min(int(max_conc), cpus))
    exp_dir.mkdir(parents=True, exist_ok=True)
    base = {"runs_dir": str(exp_dir / "runs")}

    if "variants" in cfg:
        runs = trial_list(cfg)
        param_space = {"run": tune.grid_search(runs), **base}
        tune_cfg = tune.TuneConfig(max_concurrent_trials=max_conc, num_samples=1,
                                   trial_name_creator=lambda t: f"{t.config['run']['variant']}_s{t.config['run']['seed']}",
                                   trial_dirname_creator=lambda t: f"{t.config['run']['variant']}_s{t.config['run']['seed']}")
        trainable_fn = tune.with_resources(run_variant, {"cpu": 1})
    else:
        s = cfg["search"]
        seeds = cfg["seeds"]
        param_space = {"opts": cfg["train"], "seed": tune.grid_search(seeds) if len(seeds) > 1 else seeds[0],
                       **search_space(cfg), **base}
        search_alg = None
        if s["search_alg"] == "optuna":
            if len(seeds) > 1:
                raise ValueError(f"{args.config}: search_alg optuna samples one seed per trial; give one seed (and "
                                 "repeat the best sample over seeds with a variants config) or use search_alg random")
            from ray.tune.search.optuna import OptunaSearch
            search_alg = OptunaSearch(seed=int(s.get("seed", 0)))
        scheduler = None
        if s["scheduler"] == "asha":
            from ray.tune.schedulers import ASHAScheduler
            if s["time_attr"] == "wall_time_s":   # rungs in seconds of training wall clock
                n = int(float(cfg["train"]["max_wall_time"]))
            else:                                   # rungs in env steps
                n = int(float(cfg["train"].get("n_timesteps", 1e5)))
            scheduler = ASHAScheduler(time_attr=s["time_attr"], max_t=n,
                                      grace_period=int(float(s.get("grace_period", max(n // 8, 1)))),
                                      reduction_factor=int(s.get("reduction_factor", 3)))
        tune_cfg = tune.TuneConfig(metric=cfg["metric"], mode=cfg["mode"], search_alg=search_alg, scheduler=scheduler,
                                   num_samples=int(s["num_samples"]), max_concurrent_trials=max_conc)
        trainable_fn = tune.with_resources(run_trial, {"cpu": 1})

    run_cfg = tune.RunConfig(name=cfg["name"], storage_path=str(storage), verbose=1,
                             failure_config=tune.FailureConfig(max_failures=0))
    if tune.Tuner.can_restore(str(exp_dir)):
        if args.fresh:
            raise FileExistsError(f"{exp_dir} holds a sweep; drop --fresh to resume it or choose another --storage")
        print(f"resuming the sweep in {exp_dir}")
        tuner = tune.Tuner.restore(str(exp_dir), trainable_fn, resume_unfinished=True, resume_errored=True,
                                   param_space=param_space)
    else:
        tuner = tune.Tuner(trainable_fn, param_space=param_space, tune_config=tune_cfg, run_config=run_cfg)
    t0 = time.time()
    grid = tuner.fit()
    summary = summarize(exp_dir, cfg["metric"], sweep={
        "sweep_wall_time_s": time.time() - t0, "max_concurrent": max_conc,
        "errors": [str(r.error) for r in grid if r.error is not None]})
    print((exp_dir / "summary.md").read_text())
    print(f"summary: {exp_dir / 'summary.md'}, {exp_dir / 'summary.png'} ({summary['sweep_wall_time_s']:.0f} s, "
          f"{max_conc} trials at a time)")
    return summary


def run_variant(config: dict) -> None:
    """Trainable of a ``variants`` config: each run is ``config["run"]`` (variant, seed, options)."""
    run = config["run"]
    run_trial({"variant": run["variant"], "seed": run["seed"], "opts": run["opts"], "runs_dir": config["runs_dir"]})


def main(argv: list[str] | None = None) -> int:
    try:
        summary = tune_main(argv)
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 1 if summary.get("errors") else 0


if __name__ == "__main__":
    sys.exit(main())
