"""Export a trained policy as one file a robot can run, with its spec beside it.

Usage (from the repository root)::

    python -m agents.export results/ppo_shape_rest_length --format onnx
    python -m agents.export RUN_DIR --format torchscript --out deploy/policy.pt
    python -m agents.export RUN_DIR --format npz --model best --force

``RUN_DIR`` is a run folder of :mod:`agents.train` (``config.yaml``, ``model.zip`` +
``vecnormalize.pkl``; ``--model best`` takes ``best_model.zip`` + ``best_vecnormalize.pkl``).
The file (``--out``, default ``RUN_DIR/policy.<onnx|pt|npz>``) maps a raw observation (float32,
SI units) to the action the env takes, with everything between folded in: the VecNormalize
observation normalisation (``clip((obs - mean) / sqrt(var + epsilon), -clip_obs, clip_obs)``),
the actor network and the action scaling of Stable-Baselines3's ``predict(deterministic=True)``
(PPO/A2C: the Gaussian mean clipped to the action space; SAC/TQC: the tanh-squashed mean mapped
to it; TD3/DDPG: the actor's tanh output mapped to it).

Formats: ``onnx`` (needs the ``onnx`` package to write, ``onnxruntime`` to run), ``torchscript``
(``.pt``, runs with torch) and ``npz`` (weights, activations and normalisation as arrays plus a
JSON program; runs on NumPy alone). ``<file>.json`` beside it is the spec: observation layout
with units, action meaning, control rate, the action delay it was trained with, env id and
arguments, sizes, format and the SHA-256 of the file. Run both with
:class:`tensegrity_gym.integrations.policy_runner.PolicyRunner` (``docs/deployment.md``).

Before anything is written, the exported file is checked: ``--check-steps`` observations of real
env steps (the run's env and arguments, seed ``--seed``, the trained policy acting) go through
the file and through ``model.predict(vecnormalize.normalize_obs(obs), deterministic=True)``; the
largest absolute action difference is printed and recorded in the spec, and an export that
differs by more than 1e-5 is refused. Both outputs are written together (or neither), each
atomically; an existing one is kept unless ``--force``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

from . import common, envs, hyperparameters, parsing
from .export_program import actor_program, check_writer, serialize
from tensegrity_gym.core.checks import check_count
from tensegrity_gym.integrations import policy_runner
from tensegrity_gym.integrations.torch_threads import num_threads_arg, passive_openmp_wait, set_torch_threads
from tensegrity_gym.io.atomic import OutputError
from tensegrity_gym.io.claim import Transaction

passive_openmp_wait()     # before torch loads its OpenMP runtime (see the function)

#: the check's first env seed: the held-out seeds of agents.evaluate
CHECK_SEED = 1_000_000
#: largest action difference (action-space units) an export may have from SB3's predict
TOLERANCE = 1e-5

def _env_facts(env_id: str, env_kwargs: dict, obs_size: int) -> tuple[dict, dict, dict, dict]:
    """(observation, action, control, latency) sections of the spec from the env itself."""
    env = envs.make_env(env_id, env_kwargs)
    try:
        base = env.unwrapped
        task = getattr(base, "task", None)
        if env.observation_space.shape != (obs_size,):
            raise ValueError(f"{env_id} with the run's env_kwargs observes shape {env.observation_space.shape}, the "
                             f"policy ({obs_size},): the env changed since the training")
        observation: dict = {"size": obs_size, "dtype": "float32"}
        layout = task.observation_layout() if task is not None and hasattr(task, "observation_layout") else None
        if layout:
            reading = max(sl.stop for _, sl, _ in layout)
            observation.update(
                mode=getattr(task, "observation_mode", "state"), reading_size=reading,
                history=obs_size // reading,
                layout=[{"name": name, "start": sl.start, "stop": sl.stop, "unit": unit} for name, sl, unit in layout])
            if obs_size // reading > 1:
                observation["history_order"] = ("the newest reading first (layout above), then the older readings, "
                                                "newest to oldest, in the same layout")
        else:
            observation["layout"] = [{"name": "observation", "start": 0, "stop": obs_size, "unit": None}]
        space = env.action_space
        action: dict = {"size": int(space.shape[0]), "dtype": "float32", "low": space.low.tolist(),
                        "high": space.high.tolist()}
        control: dict = {"control_dt": None, "rate_hz": None}
        latency: dict = {"action_delay_steps": 0, "action_delay_s": 0.0}
        dt = getattr(task, "control_dt", None) if task is not None else getattr(base, "dt", None)
        if dt is not None:
            control = {"control_dt": float(dt), "rate_hz": 1.0 / float(dt)}
        if task is not None:
            control.update(physics_dt=float(task.dt), frame_skip=int(task.frame_skip))
            delay = int(getattr(task, "action_delay", 0))
            latency = {"action_delay_steps": delay, "action_delay_s": delay * float(dt),
                       "meaning": "the env applied each action this many control steps after the policy gave it "
                                  "(zero actions at the start of an episode): the actuation latency the "
                                  "policy was trained with"}
            act = getattr(task, "actuation", None)
            if act is not None:
                strings = task.structure.strings if hasattr(task, "structure") else None
                unit = act.unit if hasattr(act, "unit") else ("m" if act.mode == "rest_length" else "N/m")
                rate = act.max_rate
                if act.max_accel is None:
                    meaning = (f"a[i] in [-1, 1] changes control i ({act.mode}, {unit}) by a[i] * max_rate[i] * "
                               f"control_dt per control step; the control is then clipped to "
                               f"[control_low, control_high]")
                else:
                    meaning = (f"a[i] in [-1, 1] commands the rate a[i] * max_rate[i] ({unit}/s) of control i "
                               f"({act.mode}, {unit}); the motor's rate moves toward it by at most max_accel * "
                               f"control_dt per control step, the control by rate * control_dt, clipped to "
                               f"[control_low, control_high] (the rate stops at a bound)")
                action.update(
                    action_mode=act.mode, unit=unit, rate_unit=f"{unit}/s", meaning=meaning,
                    max_accel=None if act.max_accel is None else float(act.max_accel),
                    max_accel_unit=f"{unit}/s^2", clip_actions=bool(getattr(task, "clip_actions", True)),
                    actuated=[{"string": int(s), "nodes": None if strings is None else [int(x) for x in strings[s]],
                               "control_low": float(act.low[i]), "control_high": float(act.high[i]),
                               "max_rate": float(rate[i]), "nominal": float(act.nominal[i])}
                              for i, s in enumerate(act.actuated)])
        return observation, action, control, latency
    finally:
        env.close()


def build_spec(fmt: str, file_name: str, digest: str, cfg: dict, model, model_path: Path, program: dict,
               argv: list[str] | None) -> dict:
    """The JSON spec written beside the exported file."""
    observation, action, control, latency = _env_facts(cfg["env"], cfg["env_kwargs"] or {}, program["obs_size"])
    norm = program["normalize"]
    observation["normalization"] = ("none" if norm is None else
                                    {"folded_in": True, "epsilon": norm["epsilon"], "clip": norm["clip"],
                                     "formula": "clip((obs - mean) / sqrt(var + epsilon), -clip, clip)"})
    out = program["output"]
    action["policy_output"] = (
        ("tanh of the actor's output, " if out["squash"] else "the actor's output (the Gaussian mean), ")
        + ("mapped from [-1, 1] to [low, high]" if out["rescale"] == "unscale" else "clipped to [low, high]"))
    versions = common.package_versions()
    return {
        "format": fmt, "format_version": policy_runner.FORMAT_VERSION, "file": file_name, "sha256": digest,
        "input": {"name": "obs", "shape": ["batch", program["obs_size"]], "dtype": "float32"},
        "output": {"name": "action", "shape": ["batch", program["action_size"]], "dtype": "float32"},
        "env": {"id": cfg["env"], "kwargs": cfg["env_kwargs"] or {}},
        "observation": observation, "action": action, "control": control, "latency": latency,
        "training": {"algo": cfg["algo"], "seed": cfg["seed"], "model": model_path.name,
                     "num_timesteps": int(model.num_timesteps)},
        "export_command": common.command_line(sys.argv[1:] if argv is None else argv, module=f"{common.PACKAGE}.export"),
        "versions": {k: versions.get(k) for k in ("tensegrity_gym", "stable_baselines3", "torch", "numpy",
                                                   "git_commit")},
    }


# ---------------------------------------------------------------------- the check
def check_observations(env_id: str, env_kwargs: dict, reference, n: int, seed: int) -> np.ndarray:
    """(n, obs_size) float32 observations of real env steps: the env reset with ``seed`` (then
    ``seed + 1``, ... after each episode), stepped with ``reference(obs)`` (the trained policy)."""
    env = envs.make_env(env_id, env_kwargs)
    try:
        out = []
        obs, _ = env.reset(seed=seed)
        episode = 0
        while len(out) < n:
            out.append(np.asarray(obs, np.float32))
            obs, _, term, trunc, _ = env.step(reference(obs))
            if term or trunc:
                episode += 1
                obs, _ = env.reset(seed=seed + episode)
        return np.stack(out)
    finally:
        env.close()


# ---------------------------------------------------------------------- main
def build_parser():
    p = argparse.ArgumentParser(prog=f"python -m {common.PACKAGE}.export", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", help="run directory written by agents.train")
    p.add_argument("--format", required=True, help="onnx, torchscript or npz")
    p.add_argument("--model", default="final", help="final (default: model.zip), best (best_model.zip), or a "
                                                    "path to a model zip")
    p.add_argument("--out", default=None, help="the exported file (default RUN_DIR/policy.<onnx|pt|npz>); its "
                                               "spec is <out>.json")
    p.add_argument("--force", action="store_true", help="overwrite an existing file and spec")
    p.add_argument("--check-steps", type=parsing.arg_type(lambda v: check_count(v, "--check-steps", 0)), default=50,
                   help="env steps whose observations check the export against SB3's predict (default 50; 0 skips)")
    p.add_argument("--seed", type=int, default=CHECK_SEED, help=f"first env seed of the check (default {CHECK_SEED})")
    p.add_argument("--num-threads", type=num_threads_arg, default=1)
    return p


def export(argv: list[str] | None = None) -> dict:
    """Export as the command line ``argv`` says; returns the spec written."""
    from .evaluate import load_vecnormalize, resolve_model

    args = build_parser().parse_args(argv)
    fmt = str(args.format).lower()
    if fmt not in policy_runner.FORMATS:
        raise ValueError(f"--format: unknown {args.format!r}; choose onnx, torchscript or npz")
    check_writer(fmt)
    envs.check_seed(args.seed)
    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"{run_dir}: no such run folder")
    if not (run_dir / "config.yaml").is_file():
        raise FileNotFoundError(f"{run_dir}: no config.yaml (not a run folder of agents.train)")
    cfg = common.read_run_config(run_dir / "config.yaml")
    model_path, vn_path = resolve_model(run_dir, args.model)
    if cfg["hyperparams_resolved"].get("normalize") is not None and vn_path is None:
        raise FileNotFoundError(f"{run_dir}: trained with VecNormalize, but the statistics beside {model_path.name} "
                                "are missing")
    out = Path(args.out) if args.out else run_dir / f"policy{policy_runner.FORMATS[fmt][0]}"
    spec_out = policy_runner.spec_path(out)
    set_torch_threads(args.num_threads)
    envs.import_env_packages(["tensegrity_gym"])
    with Transaction([(out, "--out"), (spec_out, "--out (spec)")], force=args.force) as tx:
        Algo = hyperparameters.get_algo(cfg["algo"])
        model = common.load_model_file(Algo, model_path, device="cpu")
        vn = load_vecnormalize(vn_path) if vn_path is not None else None
        program, arrays = actor_program(model, vn)
        data = serialize(fmt, program, arrays)
        tx.stage(out, lambda f: f.write(data))
        digest = hashlib.sha256(data).hexdigest()
        spec = build_spec(fmt, out.name, digest, cfg, model, model_path, program, argv)

        def reference(obs):
            o = np.asarray(obs, np.float32)
            if vn is not None and vn.norm_obs:
                o = vn.normalize_obs(o)
            return model.predict(o, deterministic=True)[0]

        check = None
        if args.check_steps:
            obs = check_observations(cfg["env"], cfg["env_kwargs"] or {}, reference, args.check_steps, args.seed)
            expected = np.stack([reference(o) for o in obs])
            try:
                backend, exported = policy_runner.open_policy(tx.staged[out], fmt)
            except ImportError as e:
                print(f"note: the check is skipped: {e}")
            else:
                got = np.asarray(exported(obs), np.float32)
                err = float(np.max(np.abs(got.astype(np.float64) - expected.astype(np.float64))))
                check = {"observations": int(len(obs)), "env_seed": int(args.seed), "backend": backend,
                         "max_abs_action_error": err, "tolerance": TOLERANCE}
                print(f"check: max |action - SB3 predict| = {err:.3g} over {len(obs)} observations of {cfg['env']} "
                      f"steps (seed {args.seed}, {backend})")
                if not err <= TOLERANCE:
                    raise ValueError(f"the exported {fmt} policy differs from SB3's predict by {err:.3g} "
                                     f"(> {TOLERANCE:g}); nothing was written")
        spec["check"] = check
        text = json.dumps(parsing.to_yaml_safe(spec), indent=2) + "\n"
        tx.stage(spec_out, lambda f: f.write(text.encode()))
        tx.commit()
    print(f"wrote {out} ({len(data) / 1e3:.1f} kB, {fmt}) and {spec_out}")
    return spec


def main(argv: list[str] | None = None) -> int:
    return common.run_cli(export, argv, errors=(ValueError, OSError, OutputError, ImportError))


if __name__ == "__main__":
    sys.exit(main())
