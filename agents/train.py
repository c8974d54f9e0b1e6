"""Train a Stable-Baselines3 agent on a tensegrity_gym (or any Gymnasium) env.

Usage (from the repository root)::

    python -m agents.train --algo ppo --env TensegrityShape-v0 --env-kwargs action_mode:rest_length \\
        --n-timesteps 1e6 --seed 0 --log-dir results/ppo_shape_rest_length
    python -m agents.train --algo sac --env TensegrityRoll-v0 --hyperparams learning_rate=1e-3 batch_size=512
    python -m agents.train --resume results/ppo_shape_rest_length            # continue an interrupted run
    python -m agents.train --resume results/ppo_shape_rest_length --n-timesteps 2e6   # or extend it

Hyperparameters come from ``agents/hyperparams/<algo>.yml`` keyed by env id, in
rl-baselines3-zoo's format, so the same file also works with
``python -m rl_zoo3.train --gym-packages tensegrity_gym --algo ppo --env TensegrityShape-v0
--conf-file agents/hyperparams/ppo.yml``. ``--hyperparams key=value ...`` overrides entries;
``--env-kwargs key:value ...`` (or one JSON object) are merged over the file's ``env_kwargs``.
Values are parsed as JSON / Python literals (never ``eval``).

Environments: when the env id has a ``vector_entry_point`` (the tensegrity envs do), the
``n_envs`` copies are ONE batched vector env (one physics call per step) wrapped for SB3 by
:func:`tensegrity_gym.envs.common.make_sb3_vec_env`; otherwise SB3's ``make_vec_env``
(``--vec-env dummy|subproc`` forces one). Env i of the training env is seeded ``seed + i``;
the evaluation env used during training is seeded ``seed + 10_000 + i`` (the final evaluation
in :mod:`agents.evaluate` uses other, held-out seeds).

Run directory (``--log-dir``, default ``runs/<algo>_<env>_s<seed>``, git-ignored)::

    model.zip, vecnormalize.pkl        final (or interrupted) model and normalisation statistics
    best_model.zip, best_vecnormalize.pkl   best model on the evaluation env (EvalCallback)
    checkpoints/                        rl_model_<steps>_steps.zip (+ vecnormalize / replay buffer)
    eval/evaluations.npz                EvalCallback results (timesteps, returns, lengths, successes)
    monitor/train_<segment>.monitor.csv episodes of the training env (return, length, info keys)
    tb/                                 TensorBoard: SB3 scalars + info/reward_* means + episode_end/*
    config.yaml, command.txt, versions.json, state.json

Ctrl-C (KeyboardInterrupt) saves ``model.zip``, ``vecnormalize.pkl`` (and the replay buffer of
off-policy algorithms) before exiting; ``--resume RUN_DIR`` reloads the latest of the
interrupted model and the checkpoints, the VecNormalize statistics and the replay buffer, and
continues with ``reset_num_timesteps=False`` up to the total ``n_timesteps`` (steps count on).
"""
from __future__ import annotations

import argparse
import glob
import os
import re
import sys
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

if __package__ in (None, ""):  # run as a script: python agents/train.py
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    __package__ = "agents"

from agents import common  # noqa: E402

EVAL_SEED_OFFSET = 10_000


# ---------------------------------------------------------------------- callbacks
def _callbacks():
    from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

    class InfoLoggerCallback(BaseCallback):
        """Logs to TensorBoard the means of ``info["reward_*"]`` over the last ``window`` env steps
        (``info/reward_<name>``) and the means of every scalar info key at the last step of
        episodes (``episode_end/<key>``, e.g. final tracking error, distance rolled, is_success)."""

        def __init__(self, reward_keys, end_keys, window: int = 2000):
            super().__init__()
            self.reward_keys = list(reward_keys)
            self.end_keys = list(end_keys)
            self.step_sums = {k: deque(maxlen=window) for k in self.reward_keys}
            self.end_vals = {k: deque(maxlen=100) for k in self.end_keys}

        def _on_step(self) -> bool:
            infos = self.locals.get("infos") or []
            dones = self.locals.get("dones")
            if self.reward_keys and infos:
                for k in self.reward_keys:
                    vals = [float(i[k]) for i in infos if k in i]
                    if vals:
                        self.step_sums[k].append(float(np.mean(vals)))
            if dones is not None and np.any(dones):
                for i in np.flatnonzero(dones):
                    info = infos[i]
                    for k in self.end_keys:
                        if k in info:
                            self.end_vals[k].append(float(info[k]))
            return True

        def _on_rollout_end(self) -> None:
            for k, d in self.step_sums.items():
                if d:
                    self.logger.record(f"info/{k}", float(np.mean(d)))
            for k, d in self.end_vals.items():
                if d:
                    self.logger.record(f"episode_end/{k}", float(np.mean(d)))

    class SaveVecNormalizeOnBest(BaseCallback):
        """Called by EvalCallback on a new best model: saves the matching VecNormalize statistics."""

        def __init__(self, path: str):
            super().__init__()
            self.path = path

        def _on_step(self) -> bool:
            venv = self.model.get_vec_normalize_env()
            if venv is not None:
                venv.save(self.path)
            return True

    class ResumableEvalCallback(EvalCallback):
        """EvalCallback that, on resume, keeps the earlier evaluations and best reward."""

        def load_previous(self, npz_path: str, best_reward: float | None):
            if os.path.exists(npz_path):
                d = np.load(npz_path)
                self.evaluations_timesteps = list(d["timesteps"])
                self.evaluations_results = [list(r) for r in d["results"]]
                self.evaluations_length = [list(r) for r in d["ep_lengths"]]
                if "successes" in d.files:
                    self.evaluations_successes = [list(r) for r in d["successes"]]
            if best_reward is not None:
                self.best_mean_reward = float(best_reward)

        def _on_step(self) -> bool:
            ok = super()._on_step()
            if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0 and self.best_model_save_path:
                st = Path(self.best_model_save_path) / "state.json"
                if st.exists():
                    import json
                    s = json.loads(st.read_text())
                    s["best_mean_reward"] = float(self.best_mean_reward)
                    common.write_json(st, s)
            return ok

    class InterruptAt(BaseCallback):
        """Raises KeyboardInterrupt once ``num_timesteps >= at`` (used by tests to emulate Ctrl-C)."""

        def __init__(self, at: int):
            super().__init__()
            self.at = int(at)

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.at:
                raise KeyboardInterrupt
            return True

    class StopAfterWallTime(BaseCallback):
        """Stops training (as finished, status ``time_limit``) after ``seconds`` of wall time."""

        def __init__(self, seconds: float):
            super().__init__()
            self.seconds = float(seconds)
            self.t0 = None
            self.hit = False

        def _on_training_start(self) -> None:
            self.t0 = time.time()

        def _on_step(self) -> bool:
            if time.time() - self.t0 > self.seconds:
                self.hit = True
                return False
            return True

    return InfoLoggerCallback, SaveVecNormalizeOnBest, ResumableEvalCallback, InterruptAt, StopAfterWallTime


# ---------------------------------------------------------------------- argument parsing
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m agents.train", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--algo", default="ppo", help=f"algorithm: {', '.join(common.algo_names())} (default ppo)")
    p.add_argument("--env", default="TensegrityShape-v0", help="registered Gymnasium env id")
    p.add_argument("--env-kwargs", nargs="*", metavar="KEY:VALUE",
                   help="env constructor arguments as key:value pairs or one JSON object")
    p.add_argument("--n-timesteps", "-n", type=float, default=None,
                   help="total env steps (default: the hyperparameter file's n_timesteps)")
    p.add_argument("--n-envs", type=int, default=None, help="parallel envs (default: the file's n_envs)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--log-dir", "-f", default=None, help="run directory (default runs/<algo>_<env>_s<seed>)")
    p.add_argument("--hyperparams", "-params", nargs="*", metavar="KEY=VALUE",
                   help="hyperparameter overrides, e.g. learning_rate=3e-4 n_steps=512 "
                        "policy_kwargs='dict(net_arch=[64, 64])'")
    p.add_argument("--conf-file", "-conf", default=None,
                   help="hyperparameter file (default agents/hyperparams/<algo>.yml)")
    p.add_argument("--resume", metavar="RUN_DIR", default=None,
                   help="continue the run in RUN_DIR from its latest checkpoint / interrupted model")
    p.add_argument("--vec-env", default="auto", choices=["auto", "batched", "dummy", "subproc"])
    p.add_argument("--eval-freq", type=int, default=None,
                   help="evaluate every this many env steps (default n_timesteps/20; <= 0 disables)")
    p.add_argument("--eval-episodes", type=int, default=20)
    p.add_argument("--n-eval-envs", type=int, default=None, help="default min(eval episodes, 10)")
    p.add_argument("--save-freq", type=int, default=None,
                   help="checkpoint every this many env steps (default n_timesteps/10; <= 0 disables)")
    p.add_argument("--save-replay-buffer", action="store_true",
                   help="also checkpoint the replay buffer of off-policy algorithms (large)")
    p.add_argument("--num-threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--device", default="cpu", help="torch device (default cpu; MLP policies gain nothing on GPU)")
    p.add_argument("--no-progress-bar", action="store_true")
    p.add_argument("--gym-packages", nargs="*", default=[],
                   help="extra modules to import (to register their envs); tensegrity_gym always is")
    p.add_argument("--max-wall-time", type=float, default=None, metavar="SECONDS",
                   help="stop training after this many seconds (saved as usual; status time_limit)")
    p.add_argument("--verbose", type=int, default=0)
    return p


# ---------------------------------------------------------------------- training
def _latest_checkpoint(run_dir: Path) -> tuple[int, Path | None]:
    best_steps, best = -1, None
    for f in glob.glob(str(run_dir / "checkpoints" / "rl_model_*_steps.zip")):
        m = re.search(r"rl_model_(\d+)_steps\.zip$", f)
        if m and int(m.group(1)) > best_steps:
            best_steps, best = int(m.group(1)), Path(f)
    return best_steps, best


def _install_interrupt_handlers():
    """Ctrl-C (SIGINT, even where a shell started us with SIGINT ignored) and SIGTERM raise
    KeyboardInterrupt, so that the model is saved before exiting."""
    import signal
    import threading
    if threading.current_thread() is not threading.main_thread():
        return

    def _raise(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _raise)


def train(argv: list[str] | None = None, extra_callbacks: list | None = None) -> Path:
    """Run training from command-line arguments; returns the run directory.

    ``extra_callbacks``: additional SB3 callbacks (tests use one to emulate Ctrl-C).
    """
    args = build_parser().parse_args(argv)
    import yaml
    import torch

    common.import_env_packages(["tensegrity_gym"] + list(args.gym_packages))
    torch.set_num_threads(max(1, args.num_threads))

    resume_dir = Path(args.resume) if args.resume else None
    if resume_dir is not None:
        cfg_path = resume_dir / "config.yaml"
        if not cfg_path.exists():
            raise FileNotFoundError(f"--resume {resume_dir}: no config.yaml there (not a run directory)")
        cfg = yaml.safe_load(cfg_path.read_text())
        run_dir = resume_dir
        algo, env_id, seed = cfg["algo"], cfg["env"], int(cfg["seed"])
        env_kwargs = cfg["env_kwargs"]
        raw_hp = cfg["hyperparams_raw"]
        n_envs = int(cfg["n_envs"])
        n_timesteps = int(args.n_timesteps) if args.n_timesteps is not None else int(cfg["n_timesteps"])
        vec_mode = cfg.get("vec_env", "auto")
        eval_freq, save_freq = cfg["eval_freq"], cfg["save_freq"]
        eval_episodes, n_eval_envs = cfg["eval_episodes"], cfg["n_eval_envs"]
    else:
        algo = args.algo.lower()
        common.get_algo(algo)
        env_id = args.env
        common.check_env_id(env_id)
        file_hp, source = common.hyperparams_for(algo, env_id, args.conf_file)
        overrides = common.parse_kv_list(args.hyperparams, "=", "--hyperparams")
        raw_hp = {**file_hp, **overrides}
        cli_env_kwargs = common.parse_kv_list(args.env_kwargs, ":", "--env-kwargs")
        env_kwargs = {**dict(raw_hp.get("env_kwargs") or {}), **cli_env_kwargs}
        raw_hp["env_kwargs"] = env_kwargs
        seed = args.seed
        n_timesteps = int(args.n_timesteps) if args.n_timesteps is not None else \
            int(float(raw_hp.get("n_timesteps", 1e5)))
        n_envs = args.n_envs if args.n_envs is not None else int(raw_hp.get("n_envs", 1))
        if n_envs < 1:
            raise ValueError(f"--n-envs: must be >= 1, got {n_envs}")
        vec_mode = args.vec_env
        eval_freq = args.eval_freq if args.eval_freq is not None else max(n_timesteps // 20, 1)
        save_freq = args.save_freq if args.save_freq is not None else max(n_timesteps // 10, 1)
        eval_episodes = args.eval_episodes
        n_eval_envs = args.n_eval_envs or max(1, min(eval_episodes, 10))
        run_dir = Path(args.log_dir) if args.log_dir else Path("runs") / f"{algo}_{env_id}_s{seed}"
        if (run_dir / "config.yaml").exists():
            raise FileExistsError(f"--log-dir {run_dir} already holds a run; use --resume {run_dir} to continue "
                                  "it or choose another --log-dir")
    if n_timesteps < 1:
        raise ValueError(f"--n-timesteps: must be >= 1, got {n_timesteps}")

    hp = common.resolve_hyperparams(algo, raw_hp)
    Algo = common.get_algo(algo)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "checkpoints").mkdir(exist_ok=True)

    from stable_baselines3.common.vec_env import VecNormalize
    from stable_baselines3.common.callbacks import CheckpointCallback, CallbackList, ProgressBarCallback
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
    InfoLoggerCallback, SaveVecNormalizeOnBest, ResumableEvalCallback, _, StopAfterWallTime = _callbacks()

    info_keys, reward_keys = common.probe_info_keys(env_id, env_kwargs)
    segment = len(glob.glob(str(run_dir / "monitor" / "train_*.monitor.csv")))
    env, vec_used = common.make_vec(env_id, n_envs, seed, env_kwargs, vec_mode,
                                    monitor_file=str(run_dir / "monitor" / f"train_{segment}"),
                                    info_keywords=tuple(k for k in info_keys if not k.startswith("reward_")))
    eval_env = None
    if eval_freq and eval_freq > 0:
        eval_env, _ = common.make_vec(env_id, n_eval_envs, seed + EVAL_SEED_OFFSET, env_kwargs, vec_mode)
    norm = hp["normalize"]
    if norm is not None:
        env = VecNormalize(env, **norm)
        if eval_env is not None:
            eval_env = VecNormalize(eval_env, training=False, norm_reward=False,
                                    **{k: v for k, v in norm.items() if k not in ("norm_reward", "training")})

    # ---------------------------------------------------------------- config + metadata
    config = {
        "algo": algo, "env": env_id, "env_kwargs": env_kwargs, "seed": seed, "n_timesteps": n_timesteps,
        "n_envs": n_envs, "vec_env": vec_used, "eval_freq": eval_freq, "save_freq": save_freq,
        "eval_episodes": eval_episodes, "n_eval_envs": n_eval_envs, "eval_seed": seed + EVAL_SEED_OFFSET,
        "hyperparams_raw": common.to_yaml_safe(raw_hp),
        "hyperparams_resolved": common.to_yaml_safe({**hp["model_kwargs"], "policy": hp["policy"],
                                                     "normalize": hp["normalize"], "noise": hp["noise"]}),
        "info_keys": info_keys,
    }
    if resume_dir is None:
        config["hyperparams_source"] = source
        (run_dir / "config.yaml").write_text(yaml.safe_dump(common.to_yaml_safe(config), sort_keys=False))
    else:
        old = yaml.safe_load((run_dir / "config.yaml").read_text())
        old["n_timesteps"] = n_timesteps
        (run_dir / "config.yaml").write_text(yaml.safe_dump(old, sort_keys=False))
    with open(run_dir / "command.txt", "a") as f:
        f.write(f"# {time.strftime('%Y-%m-%d %H:%M:%S %Z')} cwd={os.getcwd()}\n{common.command_line(argv)}\n")
    common.write_json(run_dir / "versions.json", common.package_versions())

    # ---------------------------------------------------------------- model
    model_kwargs = dict(hp["model_kwargs"])
    if hp["noise"] is not None:
        kind, std = hp["noise"]
        nact = env.action_space.shape[0]
        if kind == "normal":
            model_kwargs["action_noise"] = NormalActionNoise(np.zeros(nact), std * np.ones(nact))
        elif kind == "ornstein-uhlenbeck":
            model_kwargs["action_noise"] = OrnsteinUhlenbeckActionNoise(np.zeros(nact), std * np.ones(nact))
        else:
            raise ValueError(f"noise_type: unknown {kind!r}; choose normal or ornstein-uhlenbeck")
    state_path = run_dir / "state.json"
    prev_state = {}
    if resume_dir is not None:
        import json
        prev_state = json.loads(state_path.read_text()) if state_path.exists() else {}
        ck_steps, ck_path = _latest_checkpoint(run_dir)
        final = run_dir / "model.zip"
        fin_steps = int(prev_state.get("num_timesteps", -1)) if final.exists() else -1
        if fin_steps >= ck_steps and final.exists():
            load_path, vn_path, rb_path = final, run_dir / "vecnormalize.pkl", run_dir / "replay_buffer.pkl"
        elif ck_path is not None:
            load_path = ck_path
            vn_path = run_dir / "checkpoints" / f"rl_model_vecnormalize_{ck_steps}_steps.pkl"
            rb_path = run_dir / "checkpoints" / f"rl_model_replay_buffer_{ck_steps}_steps.pkl"
        else:
            raise FileNotFoundError(f"--resume {run_dir}: neither model.zip nor checkpoints/rl_model_*_steps.zip")
        if norm is not None:
            if not vn_path.exists():
                raise FileNotFoundError(f"--resume: normalisation statistics {vn_path} are missing")
            env = VecNormalize.load(str(vn_path), env.venv)
            env.training = True
        model = Algo.load(str(load_path), env=env, device=args.device,
                          tensorboard_log=str(run_dir / "tb"))
        if hasattr(model, "replay_buffer"):
            if rb_path.exists():
                model.load_replay_buffer(str(rb_path))
            else:
                print(f"warning: no replay buffer {rb_path.name} (saved on Ctrl-C, or in checkpoints with "
                      "--save-replay-buffer): continuing with an empty buffer")
        print(f"resuming {run_dir} from {load_path.name} at {model.num_timesteps} steps "
              f"(target {n_timesteps})")
    else:
        model = Algo(hp["policy"], env, seed=seed, device=args.device, verbose=args.verbose,
                     tensorboard_log=str(run_dir / "tb"), **model_kwargs)

    # ---------------------------------------------------------------- callbacks
    cbs: list = [InfoLoggerCallback(reward_keys, info_keys)]
    if save_freq and save_freq > 0:
        cbs.append(CheckpointCallback(max(save_freq // n_envs, 1), str(run_dir / "checkpoints"),
                                      save_vecnormalize=norm is not None,
                                      save_replay_buffer=bool(args.save_replay_buffer and algo in common.OFF_POLICY)))
    if eval_env is not None:
        ecb = ResumableEvalCallback(
            eval_env, n_eval_episodes=eval_episodes, eval_freq=max(eval_freq // n_envs, 1),
            log_path=str(run_dir / "eval"), best_model_save_path=str(run_dir), deterministic=True,
            verbose=args.verbose, warn=False,
            callback_on_new_best=SaveVecNormalizeOnBest(str(run_dir / "best_vecnormalize.pkl")))
        if resume_dir is not None:
            ecb.load_previous(str(run_dir / "eval" / "evaluations.npz"), prev_state.get("best_mean_reward"))
        cbs.append(ecb)
    if not args.no_progress_bar:
        cbs.append(ProgressBarCallback())
    stopper = None
    if args.max_wall_time is not None:
        stopper = StopAfterWallTime(args.max_wall_time)
        cbs.append(stopper)
    cbs.extend(extra_callbacks or [])

    _install_interrupt_handlers()
    remaining = n_timesteps - model.num_timesteps
    status = "finished"
    t0 = time.time()
    steps0 = model.num_timesteps
    common.write_json(state_path, {**prev_state, "status": "running", "num_timesteps": int(model.num_timesteps)})
    try:
        if remaining > 0:
            model.learn(total_timesteps=remaining, callback=CallbackList(cbs), tb_log_name="run",
                        reset_num_timesteps=resume_dir is None, progress_bar=False)
        else:
            print(f"nothing to do: {model.num_timesteps} steps >= n_timesteps {n_timesteps}")
    except KeyboardInterrupt:
        status = "interrupted"
        print(f"\ninterrupted at {model.num_timesteps} steps: saving model and statistics to {run_dir}")
    finally:
        model.save(str(run_dir / "model.zip"))
        venv_norm = model.get_vec_normalize_env()
        if venv_norm is not None:
            venv_norm.save(str(run_dir / "vecnormalize.pkl"))
        if hasattr(model, "replay_buffer") and status == "interrupted":
            model.save_replay_buffer(str(run_dir / "replay_buffer.pkl"))
        elapsed = time.time() - t0
        best = prev_state.get("best_mean_reward")
        if eval_env is not None:
            best = float(ecb.best_mean_reward) if np.isfinite(ecb.best_mean_reward) else None
        if stopper is not None and stopper.hit and status == "finished":
            status = "time_limit"
        state = {"status": status, "num_timesteps": int(model.num_timesteps), "target_timesteps": n_timesteps,
                 "best_mean_reward": best,
                 "wall_time_s": float(prev_state.get("wall_time_s", 0.0)) + elapsed,
                 "steps_per_s_last_segment": (model.num_timesteps - steps0) / max(elapsed, 1e-9)}
        common.write_json(state_path, state)
        env.close()
        if eval_env is not None:
            eval_env.close()
    print(f"{state['status']}: {model.num_timesteps} steps in {elapsed:.1f} s -> {run_dir}")
    return run_dir


def main(argv: list[str] | None = None) -> int:
    import json
    try:
        run_dir = train(argv)
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    state = json.loads((run_dir / "state.json").read_text())
    return 130 if state.get("status") == "interrupted" else 0


if __name__ == "__main__":
    sys.exit(main())
