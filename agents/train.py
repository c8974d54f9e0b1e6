"""Train a Stable-Baselines3 agent on a tensegrity_gym (or any Gymnasium) env.

Usage (from any directory once the package is installed; from the repository root otherwise)::

    python -m agents.train --algo ppo --env TensegrityShape-v0 --env-kwargs action_mode:rest_length \\
        --n-timesteps 1e6 --seed 0 --log-dir results/ppo_shape_rest_length
    python -m agents.train --algo sac --env TensegrityRoll-v0 --hyperparams learning_rate=1e-3 batch_size=512
    python -m agents.train --resume results/ppo_shape_rest_length            # continue an interrupted run
    python -m agents.train --resume results/ppo_shape_rest_length --n-timesteps 2e6   # or extend it

Hyperparameters come from ``agents/hyperparams/<algo>.yml`` keyed by env id, in
rl-baselines3-zoo's format, so the zoo uses the same file:
``python -m rl_zoo3.train --gym-packages tensegrity_gym.integrations.zoo --algo ppo --env TensegrityShape-v0``
reads it without ``--conf-file`` (:mod:`tensegrity_gym.integrations.zoo`). ``--hyperparams key=value ...`` overrides entries;
``--env-kwargs key:value ...`` (or one JSON object) are merged over the file's ``env_kwargs``.
Values are parsed as JSON / Python literals (never ``eval``).

Environments: when the env id has a ``vector_entry_point`` (the tensegrity envs do), the
``n_envs`` copies are ONE batched vector env (one physics call per step) wrapped for SB3 by
:func:`tensegrity_gym.integrations.sb3.make_sb3_vec_env`; otherwise SB3's ``make_vec_env``
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
    .lock                               while a training runs in it: its pid, host and start time

Every file is written atomically (temporary file in the same folder, fsync, rename), so no
interrupt, crash or kill destroys the last good model; a crash is recorded in ``state.json`` as
``crashed`` with the error; a run that failed before saving any model can be started again in the
same folder; checkpoints and evaluations follow the run's step count, so ``--resume`` keeps their
schedule. Ctrl-C (KeyboardInterrupt) saves ``model.zip``, ``vecnormalize.pkl`` (and the replay buffer of
off-policy algorithms) before exiting (a second Ctrl-C waits for the save); ``--resume RUN_DIR`` reloads the latest of the
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

import numpy as np

from . import common, warm_start
from .progress import progress_callback
from tensegrity_gym.core.checks import check_count, check_positive
from tensegrity_gym.io.atomic import OutputError
from tensegrity_gym.io.claim import Claim

common.passive_openmp_wait()     # before torch loads its OpenMP runtime (see the function)

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

    class ScheduledCheckpoint(BaseCallback):
        """Checkpoints every ``save_freq`` env steps counted from step 0 of the run (so a resumed run
        keeps its schedule), each file written atomically: ``rl_model_vecnormalize_<N>_steps.pkl``,
        ``rl_model_replay_buffer_<N>_steps.pkl`` (optional), then ``rl_model_<N>_steps.zip``
        (the zip last: a checkpoint whose zip exists has its statistics)."""

        def __init__(self, save_freq: int, save_path: str, save_vecnormalize: bool, save_replay_buffer: bool,
                     run_state=None):
            super().__init__()
            self.save_freq = int(save_freq)
            self.save_path = Path(save_path)
            self.save_vecnormalize = save_vecnormalize
            self.save_replay_buffer = save_replay_buffer
            self.run_state = run_state
            self._last_k = 0
            self.elapsed = 0.0   # s spent writing checkpoints (TimeSplit)

        def _on_training_start(self) -> None:
            self._last_k = self.model.num_timesteps // self.save_freq

        def _on_step(self) -> bool:
            k = self.num_timesteps // self.save_freq
            if k > self._last_k:
                t0 = time.perf_counter()
                self._last_k = k
                self.save_path.mkdir(parents=True, exist_ok=True)
                n = self.num_timesteps
                vn = self.model.get_vec_normalize_env()
                if self.save_vecnormalize and vn is not None:
                    common.save_pickle_atomic(vn, self.save_path / f"rl_model_vecnormalize_{n}_steps.pkl")
                if self.save_replay_buffer and hasattr(self.model, "replay_buffer"):
                    common.save_replay_buffer_atomic(self.model, self.save_path / f"rl_model_replay_buffer_{n}_steps.pkl")
                common.save_model_atomic(self.model, self.save_path / f"rl_model_{n}_steps.zip")
                if self.run_state is not None:
                    self.run_state.update(last_checkpoint_timesteps=int(n), num_timesteps=int(n))
                self.elapsed += time.perf_counter() - t0
            return True

    class ResumableEvalCallback(EvalCallback):
        """EvalCallback that evaluates every ``every`` env steps counted from step 0 of the run (a
        resumed run keeps its schedule), keeps the earlier evaluations and best reward on resume,
        and writes ``eval/evaluations.npz``, ``best_model.zip`` and ``best_vecnormalize.pkl``
        atomically (statistics first, then the model)."""

        def __init__(self, eval_env, every: int, run_dir: Path, run_state=None, report=None, **kw):
            super().__init__(eval_env, eval_freq=1, log_path=str(run_dir / "eval"), best_model_save_path=None,
                             **kw)
            self.every = int(every)
            self.run_dir = Path(run_dir)
            self.run_state = run_state
            self.report = report
            self.npz_path = self.run_dir / "eval" / "evaluations.npz"
            self.elapsed = 0.0   # s spent evaluating and saving the best model (TimeSplit)
            # EvalCallback's own np.savez (not atomic) goes to a scratch file; the real file is written below
            self.log_path = str(self.run_dir / "eval" / ".evaluations_scratch")
            self._last_k = 0

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

        def _on_training_start(self) -> None:
            super()._on_training_start()
            self._last_k = self.model.num_timesteps // self.every

        def _on_step(self) -> bool:
            t0 = time.perf_counter()
            try:
                return self._step()
            finally:
                self.elapsed += time.perf_counter() - t0

        def _step(self) -> bool:
            k = self.num_timesteps // self.every
            due = k > self._last_k
            if due:
                self._last_k = k
            self.eval_freq = 1 if due else 0  # EvalCallback evaluates when eval_freq > 0 and n_calls % 1 == 0
            best_before = self.best_mean_reward
            ok = super()._on_step()
            self.eval_freq = 1
            if not due:
                return ok
            kw = {}
            if self.evaluations_successes:
                kw["successes"] = np.asarray(self.evaluations_successes)
            arrays = dict(timesteps=np.asarray(self.evaluations_timesteps), results=np.asarray(self.evaluations_results),
                          ep_lengths=np.asarray(self.evaluations_length), **kw)
            common.atomic_write(self.npz_path, lambda f: np.savez(f, **arrays))
            if self.best_mean_reward > best_before:
                vn = self.model.get_vec_normalize_env()
                if vn is not None:
                    common.save_pickle_atomic(vn, self.run_dir / "best_vecnormalize.pkl")
                common.save_model_atomic(self.model, self.run_dir / "best_model.zip")
            if self.run_state is not None:
                self.run_state.update(best_mean_reward=float(self.best_mean_reward),
                                      num_timesteps=int(self.num_timesteps))
            if self.report is not None:
                self.report(evaluation_metrics(self.evaluations_timesteps, self.evaluations_results,
                                               self.evaluations_successes))
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

    class TimeSplit(BaseCallback):
        """Where a training segment's wall time goes (``state.json`` ``time_split_last_segment_s``): ``rollout``
        (collecting experience: env steps, policy inference, normalisation, buffer writes),
        ``learner`` (gradient updates: from the end of one collection to the start of the next),
        and ``evaluation_and_checkpoints`` (the ``timed`` callbacks' own ``elapsed`` time, spent
        inside collection and subtracted from ``rollout``). Works for on-policy algorithms (one
        collection per update) and off-policy ones (one per ``train_freq``) alike."""

        def __init__(self, timed=()):
            super().__init__()
            self.timed = [c for c in timed if c is not None]
            self.rollout = self.learner = 0.0
            self._t, self._phase = None, None

        def _on_training_start(self) -> None:
            self._t, self._phase = time.perf_counter(), None

        def _on_rollout_start(self) -> None:
            now = time.perf_counter()
            if self._phase == "learn":
                self.learner += now - self._t
            self._t, self._phase = now, "rollout"

        def _on_rollout_end(self) -> None:
            now = time.perf_counter()
            self.rollout += now - self._t
            self._t, self._phase = now, "learn"

        def _on_training_end(self) -> None:
            if self._phase == "learn":
                self.learner += time.perf_counter() - self._t
            self._phase = None

        def _on_step(self) -> bool:
            return True

        def split(self) -> dict:
            ev = sum(c.elapsed for c in self.timed)
            return {"rollout": max(self.rollout - ev, 0.0), "learner": self.learner, "evaluation_and_checkpoints": ev}

    return InfoLoggerCallback, ScheduledCheckpoint, ResumableEvalCallback, InterruptAt, StopAfterWallTime, TimeSplit


# ---------------------------------------------------------------------- argument parsing
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"python -m {common.PACKAGE}.train", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--algo", default="ppo", help=f"algorithm: {', '.join(common.algo_names())} (default ppo)")
    p.add_argument("--env", default="TensegrityShape-v0", help="registered Gymnasium env id")
    p.add_argument("--env-kwargs", nargs="*", metavar="KEY:VALUE",
                   help="env constructor arguments as key:value pairs or one JSON object")
    p.add_argument("--n-timesteps", "-n", type=common.arg_type(lambda v: check_count(v, "--n-timesteps", 1)), default=None,
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
    p.add_argument("--warm-start", metavar="RUN_DIR", default=None,
                   help="start from that run's final policy and normalisation (same algorithm and network; "
                        "observation blocks matched by name, new ones start with zero weight: agents/warm_start.py)")
    p.add_argument("--vec-env", default="auto", choices=["auto", "batched", "torch", "dummy", "subproc"],
                   help="torch: the device-resident torch vector env (--env-device, --env-dtype) for training; "
                        "the evaluation env stays the NumPy/numba one")
    p.add_argument("--env-device", default=None, help="--vec-env torch: env device (default cuda if available, "
                                                      "else cpu)")
    p.add_argument("--env-dtype", default=None, choices=["float32", "float64"],
                   help="--vec-env torch: env dtype (default float32)")
    p.add_argument("--env-reset-sampling", default=None, choices=["host", "device"],
                   help="--vec-env torch: draw resets on the host (default; the NumPy env's numbers) or on the "
                        "device (per-env counter-based streams, no host loop; TensegrityRoll-v0)")
    p.add_argument("--eval-freq", type=int, default=None,
                   help="evaluate every this many env steps (default n_timesteps/20; <= 0 disables)")
    p.add_argument("--eval-episodes", type=common.arg_type(lambda v: check_count(v, "--eval-episodes", 1)), default=20)
    p.add_argument("--n-eval-envs", type=int, default=None, help="default min(eval episodes, 10)")
    p.add_argument("--save-freq", type=int, default=None,
                   help="checkpoint every this many env steps (default n_timesteps/10; <= 0 disables)")
    p.add_argument("--save-replay-buffer", action="store_true",
                   help="also checkpoint the replay buffer of off-policy algorithms (large)")
    p.add_argument("--num-threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--device", default="cpu", help="torch device (default cpu; MLP policies gain nothing on GPU)")
    p.add_argument("--no-progress-bar", action="store_true",
                   help="no progress lines (by default one every 10 s: steps, speed, ETA, last evaluation)")
    p.add_argument("--gym-packages", nargs="*", default=[],
                   help="extra modules to import (to register their envs); tensegrity_gym always is")
    p.add_argument("--steal-lock", action="store_true",
                   help="take over the run folder's lock left by a training that no longer runs here (or "
                        "runs on another host); --resume takes over a killed run's lock by itself")
    p.add_argument("--max-wall-time", type=common.arg_type(lambda v: check_positive(v, "--max-wall-time", "s")),
                   default=None, metavar="SECONDS",
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


#: signals turned into KeyboardInterrupt by the handlers below, in order
_SIGNALS_RECEIVED: list = []


def _install_interrupt_handlers():
    """Ctrl-C (SIGINT, even where a shell started us with SIGINT ignored) and SIGTERM raise
    KeyboardInterrupt, so that the model is saved before exiting."""
    import signal
    import threading
    if threading.current_thread() is not threading.main_thread():
        return

    def _raise(signum, frame):
        _SIGNALS_RECEIVED.append(signum)   # main() exits 128 + the signal (SIGTERM 143, as the CLI)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _raise)


class _DeferInterrupts:
    """While saving: a second Ctrl-C / SIGTERM prints a note and is ignored, so the save completes
    (every file is written atomically anyway: a SIGKILL leaves the previous good files)."""

    def __enter__(self):
        import signal
        import threading
        self.old = None
        if threading.current_thread() is threading.main_thread():
            def _note(signum, frame):
                print("\nstill saving the model: wait a moment (the files are written atomically)",
                      file=sys.stderr, flush=True)
            self.old = {sig: signal.signal(sig, _note) for sig in (signal.SIGINT, signal.SIGTERM)}
        return self

    def __exit__(self, *exc):
        import signal
        if self.old:
            for sig, h in self.old.items():
                signal.signal(sig, h)
        return False


class RunState:
    """``state.json`` of a run, rewritten atomically on every update."""

    def __init__(self, path: Path, initial: dict):
        self.path = Path(path)
        self.data = dict(initial)
        self._clock = None

    def start_clock(self, wall_before: float, t0: float) -> None:
        """From now on every update records ``wall_time_s`` = ``wall_before`` (s, earlier segments)
        + the time since ``t0``: a segment killed without a final update keeps its time up to
        its last checkpoint or evaluation for ``--resume``."""
        self._clock = (float(wall_before), float(t0))

    def update(self, **kw):
        if self._clock is not None and "wall_time_s" not in kw:
            kw["wall_time_s"] = self._clock[0] + time.time() - self._clock[1]
        self.data.update(kw)
        common.write_json(self.path, self.data)


def _read_state(run_dir: Path) -> dict:
    import json
    p = run_dir / "state.json"
    if not p.exists():
        return {}
    try:
        state = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ValueError(f"{p}: damaged run state ({type(e).__name__}: {' '.join(str(e).split())[:120]}); "
                         "repair or delete it to use this run directory") from None
    if not isinstance(state, dict):
        raise ValueError(f"{p}: damaged run state (a JSON {type(state).__name__}, not an object); "
                         "repair or delete it to use this run directory")
    return state


def _has_saved_model(run_dir: Path) -> bool:
    return (run_dir / "model.zip").exists() or _latest_checkpoint(run_dir)[1] is not None


def _clear_failed_start(run_dir: Path) -> None:
    """A run that failed before saving any model: drop its monitor / evaluation files so that a
    restart in the same folder starts clean (config.yaml and command.txt are rewritten / appended)."""
    for f in list((run_dir / "monitor").glob("*.monitor.csv")) + [run_dir / "eval" / "evaluations.npz"]:
        try:
            f.unlink()
        except OSError:
            pass


def evaluation_metrics(timesteps, results, successes=None) -> dict:
    """Metrics of the latest evaluation: ``timesteps``, ``eval_return`` (mean episode return),
    ``eval_return_std``, ``eval_success`` (success rate, when the env reports ``is_success``),
    ``best_eval_return`` and ``n_evaluations``."""
    if not len(timesteps):
        return {"n_evaluations": 0}
    r = np.asarray(results[-1], float)
    out = {"timesteps": int(timesteps[-1]), "eval_return": float(r.mean()), "eval_return_std": float(r.std()),
           "best_eval_return": float(max(np.mean(x) for x in results)), "n_evaluations": len(timesteps)}
    if successes is not None and len(successes):
        out["eval_success"] = float(np.mean(successes[-1]))
    return out


def train(argv: list[str] | None = None, extra_callbacks: list | None = None, report=None) -> Path:
    """Run training from command-line arguments; returns the run directory.

    ``extra_callbacks``: additional SB3 callbacks (tests use one to emulate Ctrl-C).
    ``report``: called with :func:`evaluation_metrics` and ``wall_time_s`` (the run's wall time so
    far, s, earlier segments included) after every evaluation (``agents.tune`` passes Ray Tune's
    ``tune.report``).

    The run folder is claimed before anything is written into it (its ``.lock`` names this
    process: :class:`tensegrity_gym.io.claim.Claim`); a second training into it is refused at once
    (``FileExistsError`` naming the holder's pid, host and start time) and the lock is removed when
    the training ends.
    """
    claims = []
    try:
        return _train(argv, extra_callbacks, report, claims)
    finally:
        for c in claims:
            c.release()


def _claim_run_dir(run_dir: Path, args, flag: str, resume: bool):
    """Claim ``run_dir`` for this training (``--resume`` takes over the lock of a killed run)."""
    return Claim(run_dir, folder=True, label=flag, steal=args.steal_lock, take_over_dead=resume)


def _train(argv, extra_callbacks, report, claims: list) -> Path:
    args = build_parser().parse_args(argv)
    import yaml
    import torch

    common.import_env_packages(["tensegrity_gym"] + list(args.gym_packages))
    torch.set_num_threads(max(1, args.num_threads))

    resume_dir = Path(args.resume) if args.resume else None
    if resume_dir is not None and args.warm_start:
        raise ValueError("--warm-start: a new run only; --resume continues a run from its own model")
    warm = None
    fresh_restart = False  # a run directory whose first attempt failed before saving any model
    if resume_dir is not None:
        cfg_path = resume_dir / "config.yaml"
        if not cfg_path.exists():
            raise FileNotFoundError(f"--resume {resume_dir}: no config.yaml there (not a run directory)")
        claims.append(_claim_run_dir(resume_dir, args, "--resume", resume=True))
        _read_state(resume_dir)          # a damaged state.json is named before anything else
        cfg = common.read_run_config(cfg_path)
        run_dir = resume_dir
        fresh_restart = not _has_saved_model(run_dir)
        algo, env_id, seed = cfg["algo"], cfg["env"], int(cfg["seed"])
        env_kwargs = cfg["env_kwargs"]
        raw_hp = cfg["hyperparams_raw"]
        source = cfg.get("hyperparams_source", "config.yaml")
        n_envs = int(cfg["n_envs"])
        n_timesteps = int(args.n_timesteps) if args.n_timesteps is not None else int(cfg["n_timesteps"])
        vec_mode = cfg.get("vec_env", "auto")
        env_device, env_dtype = cfg.get("env_device"), cfg.get("env_dtype", "float32")
        env_reset_sampling = cfg.get("env_reset_sampling", "host")
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
        seed = common.check_seed(args.seed)
        n_timesteps = int(args.n_timesteps) if args.n_timesteps is not None else \
            common.check_hp_count(raw_hp.get("n_timesteps", 1e5), "n_timesteps", 1)
        n_envs = args.n_envs if args.n_envs is not None else int(raw_hp.get("n_envs", 1))
        if n_envs < 1:
            raise ValueError(f"--n-envs: must be >= 1, got {n_envs}")
        vec_mode = args.vec_env
        env_device, env_dtype, env_reset_sampling = args.env_device, args.env_dtype, args.env_reset_sampling
        for flag, value in (("--env-device", env_device), ("--env-dtype", env_dtype),
                            ("--env-reset-sampling", env_reset_sampling)):
            if vec_mode != "torch" and value is not None:
                raise ValueError(f"{flag}: only with --vec-env torch")
        if vec_mode == "torch":
            import torch
            env_device = env_device or ("cuda" if torch.cuda.is_available() else "cpu")
            env_dtype = env_dtype or "float32"
            env_reset_sampling = env_reset_sampling or "host"
        eval_freq = args.eval_freq if args.eval_freq is not None else max(n_timesteps // 20, 1)
        save_freq = args.save_freq if args.save_freq is not None else max(n_timesteps // 10, 1)
        eval_episodes = args.eval_episodes
        n_eval_envs = args.n_eval_envs or max(1, min(eval_episodes, 10))
        run_dir = Path(args.log_dir) if args.log_dir else Path("runs") / f"{algo}_{env_id}_s{seed}"
        warm = warm_start.check_source(args.warm_start, algo) if args.warm_start else None
        claims.append(_claim_run_dir(run_dir, args, "--log-dir", resume=False))
        if (run_dir / "config.yaml").exists():
            st = _read_state(run_dir)
            if _has_saved_model(run_dir):
                raise FileExistsError(f"--log-dir {run_dir} already holds a run; use --resume {run_dir} to "
                                      "continue it or choose another --log-dir")
            print(f"note: {run_dir} holds a run that stopped before saving any model "
                  f"(status {st.get('status', 'unknown')}): starting it again")
            fresh_restart = True
    if n_timesteps < 1:
        raise ValueError(f"--n-timesteps: must be >= 1, got {n_timesteps}")

    hp = common.resolve_hyperparams(algo, raw_hp)
    Algo = common.get_algo(algo)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "checkpoints").mkdir(exist_ok=True)
    common.remove_stale_tmp(run_dir)
    if fresh_restart:
        _clear_failed_start(run_dir)

    from stable_baselines3.common.vec_env import VecNormalize
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
    InfoLoggerCallback, ScheduledCheckpoint, ResumableEvalCallback, _, StopAfterWallTime, TimeSplit = _callbacks()

    import socket
    state_path = run_dir / "state.json"
    prev_state = _read_state(run_dir) if (resume_dir is not None and not fresh_restart) else {}
    run_state = RunState(state_path, {
        **prev_state, "status": "starting", "pid": os.getpid(), "host": socket.gethostname(),
        "machine": common.machine(),     # the CPU of this segment: wall times depend on it
        "num_timesteps": int(prev_state.get("num_timesteps", 0)), "target_timesteps": n_timesteps})
    _install_interrupt_handlers()   # a SIGTERM during start-up is recorded (status interrupted), not left "starting"
    t0 = time.time()
    env = eval_env = model = None
    try:
        run_state.update()          # inside: a SIGTERM just after "starting" is written is recorded below
        info_keys, reward_keys = common.probe_info_keys(env_id, env_kwargs)
        segment = len(glob.glob(str(run_dir / "monitor" / "train_*.monitor.csv")))
        env, vec_used = common.make_vec(env_id, n_envs, seed, env_kwargs, vec_mode,
                                        monitor_file=str(run_dir / "monitor" / f"train_{segment}"),
                                        info_keywords=tuple(k for k in info_keys if not k.startswith("reward_")),
                                        env_device=env_device, env_dtype=env_dtype, info_keys=info_keys,
                                        env_reset_sampling=env_reset_sampling)
        if eval_freq and eval_freq > 0:
            eval_env, _ = common.make_vec(env_id, n_eval_envs, seed + EVAL_SEED_OFFSET, env_kwargs,
                                          "batched" if vec_mode == "torch" else vec_mode)
        norm = hp["normalize"]
        if norm is not None:
            env = VecNormalize(env, **norm)
            if eval_env is not None:
                eval_env = VecNormalize(eval_env, training=False, norm_reward=False,
                                        **{k: v for k, v in norm.items() if k not in ("norm_reward", "training")})

        # ------------------------------------------------------------ config + metadata
        config = {
            "algo": algo, "env": env_id, "env_kwargs": env_kwargs, "seed": seed, "n_timesteps": n_timesteps,
            "n_envs": n_envs, "vec_env": vec_used, "eval_freq": eval_freq, "save_freq": save_freq,
            **({"env_device": env_device, "env_dtype": env_dtype, "env_reset_sampling": env_reset_sampling}
               if vec_used == "torch" else {}),
            "eval_episodes": eval_episodes, "n_eval_envs": n_eval_envs, "eval_seed": seed + EVAL_SEED_OFFSET,
            "hyperparams_raw": common.to_yaml_safe(raw_hp),
            "hyperparams_resolved": common.to_yaml_safe({**hp["model_kwargs"], "policy": hp["policy"],
                                                         "normalize": hp["normalize"], "noise": hp["noise"]}),
            "info_keys": info_keys,
        }
        if resume_dir is None:
            config["hyperparams_source"] = source
            common.write_text(run_dir / "config.yaml", yaml.safe_dump(common.to_yaml_safe(config), sort_keys=False))
        else:
            old = common.read_yaml(run_dir / "config.yaml")
            old["n_timesteps"] = n_timesteps
            common.write_text(run_dir / "config.yaml", yaml.safe_dump(old, sort_keys=False))
        with open(run_dir / "command.txt", "a") as f:
            f.write(f"# {time.strftime('%Y-%m-%d %H:%M:%S %Z')} cwd={os.getcwd()}\n{common.command_line(argv)}\n")
        common.write_json(run_dir / "versions.json", common.package_versions())

        # ------------------------------------------------------------ model
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
        if resume_dir is not None and not fresh_restart:
            ck_steps, ck_path = _latest_checkpoint(run_dir)
            final = run_dir / "model.zip"
            fin_steps = int(prev_state.get("model_num_timesteps", prev_state.get("num_timesteps", -1))) \
                if final.exists() else -1
            if fin_steps >= ck_steps and final.exists():
                load_path, vn_path, rb_path = final, run_dir / "vecnormalize.pkl", run_dir / "replay_buffer.pkl"
            else:
                load_path = ck_path
                vn_path = run_dir / "checkpoints" / f"rl_model_vecnormalize_{ck_steps}_steps.pkl"
                rb_path = run_dir / "checkpoints" / f"rl_model_replay_buffer_{ck_steps}_steps.pkl"
            if norm is not None:
                if not vn_path.exists():
                    raise FileNotFoundError(f"--resume: normalisation statistics {vn_path} are missing")
                env = common.load_vecnormalize_file(vn_path, env.venv)
                env.training = True
            model = common.load_model_file(Algo, load_path, env=env, device=args.device,
                                           tensorboard_log=str(run_dir / "tb"))
            if hasattr(model, "replay_buffer"):
                if rb_path.exists():
                    model.load_replay_buffer(str(rb_path))
                else:
                    print(f"warning: no replay buffer {rb_path.name} (saved on Ctrl-C or --max-wall-time, or in "
                          "checkpoints with --save-replay-buffer): continuing with an empty buffer")
            print(f"resuming {run_dir} from {load_path.name} at {model.num_timesteps} steps "
                  f"(target {n_timesteps})")
        else:
            try:
                model = Algo(hp["policy"], env, seed=seed, device=args.device, verbose=args.verbose,
                             tensorboard_log=str(run_dir / "tb"), **model_kwargs)
            except (AssertionError, TypeError, ValueError, RuntimeError) as e:   # SB3's checks: one line
                raise ValueError(f"--hyperparams: {Algo.__name__} refused them: {type(e).__name__}: "
                                 f"{' '.join(str(e).split())}") from e
            if warm is not None:
                config["warm_start"] = common.to_yaml_safe(warm_start.warm_start(model, env, warm, env_id,
                                                                                 env_kwargs, seed))
                common.write_text(run_dir / "config.yaml", yaml.safe_dump(common.to_yaml_safe(config), sort_keys=False))
                print(f"warm start from {warm['model']} ({config['warm_start']['model_num_timesteps']} steps; "
                      f"{len(config['warm_start']['new_observations'])} new observations start at zero weight)")
    except BaseException as e:  # failed before the first step: record it; the folder can be started again
        run_state.update(status="crashed" if not isinstance(e, KeyboardInterrupt) else "interrupted",
                         error=f"{type(e).__name__}: {e}", failed_before_first_step=True,
                         wall_time_s=float(prev_state.get("wall_time_s", 0.0)) + time.time() - t0)
        for v in (env, eval_env):
            if v is not None:
                v.close()
        raise

    # ---------------------------------------------------------------- callbacks
    cbs: list = [InfoLoggerCallback(reward_keys, info_keys)]
    ckpt = None
    if save_freq and save_freq > 0:
        ckpt = ScheduledCheckpoint(save_freq, str(run_dir / "checkpoints"), save_vecnormalize=norm is not None,
                                       save_replay_buffer=bool(args.save_replay_buffer and algo in common.OFF_POLICY),
                                       run_state=run_state)
        cbs.append(ckpt)
    ecb = None
    if eval_env is not None:
        report_fn = None
        if report is not None:   # each evaluation's metrics plus the run's wall time so far (earlier segments too)
            wall0 = float(prev_state.get("wall_time_s", 0.0))

            def _report(metrics):
                report({**metrics, "wall_time_s": wall0 + time.time() - t0})
            report_fn = _report
        ecb = ResumableEvalCallback(eval_env, eval_freq, run_dir, run_state=run_state, report=report_fn,
                                    n_eval_episodes=eval_episodes, deterministic=True, verbose=args.verbose,
                                    warn=False)
        if resume_dir is not None and not fresh_restart:
            ecb.load_previous(str(run_dir / "eval" / "evaluations.npz"), prev_state.get("best_mean_reward"))
        cbs.append(ecb)
    if not args.no_progress_bar:   # a line every 10 s: readable on a terminal and in a log alike
        cbs.append(progress_callback(n_timesteps, max_wall_time=args.max_wall_time, eval_callback=ecb))
    stopper = None
    if args.max_wall_time is not None:
        stopper = StopAfterWallTime(args.max_wall_time)
        cbs.append(stopper)
    cbs.extend(extra_callbacks or [])
    timer = TimeSplit([ckpt, ecb])
    cbs.append(timer)

    _install_interrupt_handlers()
    remaining = n_timesteps - model.num_timesteps
    status = "finished"
    error = None
    steps0 = model.num_timesteps
    run_state.data.pop("error", None)
    run_state.data.pop("traceback", None)
    run_state.data.pop("failed_before_first_step", None)
    run_state.start_clock(float(prev_state.get("wall_time_s", 0.0)), t0)
    run_state.update(status="running", num_timesteps=int(model.num_timesteps))
    try:
        if remaining > 0:
            model.learn(total_timesteps=remaining, callback=CallbackList(cbs), tb_log_name="run",
                        reset_num_timesteps=resume_dir is None or fresh_restart, progress_bar=False)
        else:
            print(f"nothing to do: {model.num_timesteps} steps >= n_timesteps {n_timesteps}")
    except KeyboardInterrupt:
        status = "interrupted"
        print(f"\ninterrupted at {model.num_timesteps} steps: saving model and statistics to {run_dir}",
              flush=True)
    except SystemExit as e:  # sys.exit from a callback, e.g. Ray Tune stopping a trial: saved, then re-raised
        status, error = ("stopped" if e.code in (0, None) else "crashed"), e
        if status == "crashed":
            run_state.data["error"] = f"SystemExit: {e.code}"
    except BaseException as e:  # noqa: BLE001 -- recorded, then re-raised
        import traceback
        status, error = "crashed", e
        run_state.data["error"] = f"{type(e).__name__}: {e}"
        run_state.data["traceback"] = traceback.format_exc()[-4000:]
    finally:
        with _DeferInterrupts():
            if stopper is not None and stopper.hit and status == "finished":
                status = "time_limit"
            _save_final(model, run_dir, status, run_state)
            elapsed = time.time() - t0
            best = prev_state.get("best_mean_reward")
            if ecb is not None and np.isfinite(ecb.best_mean_reward):
                best = float(ecb.best_mean_reward)
            split = timer.split()
            run_state.update(status=status, num_timesteps=int(model.num_timesteps), target_timesteps=n_timesteps,
                             best_mean_reward=best,
                             wall_time_s=float(prev_state.get("wall_time_s", 0.0)) + elapsed,
                             steps_per_s_last_segment=(model.num_timesteps - steps0) / max(elapsed, 1e-9),
                             time_split_last_segment_s={k: round(v, 3) for k, v in split.items()})
            scratch = run_dir / "eval" / ".evaluations_scratch.npz"
            if scratch.exists():
                scratch.unlink()
            env.close()
            if eval_env is not None:
                eval_env.close()
    print(f"{status}: {model.num_timesteps} steps in {elapsed:.1f} s -> {run_dir} (" +
          ", ".join(f"{k} {v:.1f} s" for k, v in split.items()) + ")")
    if error is not None:
        raise error
    return run_dir


def _save_final(model, run_dir: Path, status: str, run_state: RunState) -> None:
    """Save the model at the end of a segment, every file atomically, statistics before the model.

    finished / interrupted / time_limit: ``vecnormalize.pkl``, (``replay_buffer.pkl`` when
    interrupted or stopped by ``--max-wall-time``, off-policy: the segments ``--resume`` continues;
    a stale buffer of an earlier segment would otherwise be loaded), ``model.zip``. crashed: the last good ``model.zip`` and checkpoints
    are kept; the crashing model goes to ``crashed_model.zip`` (+ ``crashed_vecnormalize.pkl``)
    for inspection only (``--resume`` does not use it)."""
    prefix = "crashed_" if status == "crashed" else ""
    try:
        vn = model.get_vec_normalize_env()
        if vn is not None:
            common.save_pickle_atomic(vn, run_dir / f"{prefix}vecnormalize.pkl")
        if hasattr(model, "replay_buffer") and status in ("interrupted", "time_limit"):
            common.save_replay_buffer_atomic(model, run_dir / "replay_buffer.pkl")
        common.save_model_atomic(model, run_dir / f"{prefix}model.zip")
        if not prefix:
            run_state.data["model_num_timesteps"] = int(model.num_timesteps)
    except Exception as e:  # noqa: BLE001 -- a crashed model may not be savable; the old files stay
        if not prefix:
            raise
        print(f"warning: could not save the crashed model: {e}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    import json
    try:
        run_dir = train(argv)
    except (ValueError, OSError, OutputError) as e:   # OSError: a read-only --log-dir, ... (FileNotFound/Exists included)
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:   # Ctrl-C / SIGTERM before the first step: state.json says interrupted
        print("interrupted during start-up (no model saved)", file=sys.stderr)
        return interrupted_exit_code()
    state = json.loads((run_dir / "state.json").read_text())
    return interrupted_exit_code() if state.get("status") == "interrupted" else 0


def interrupted_exit_code() -> int:
    """128 + the signal that interrupted the training (SIGTERM: 143, as the CLI), 130 for Ctrl-C."""
    import signal
    return 143 if signal.SIGTERM in _SIGNALS_RECEIVED else 130


def _exit(code: int) -> None:
    """Exit with ``code``. After a SIGTERM, directly (streams flushed): a KeyboardInterrupt that
    the handler raised inside ``eval()`` of a string (namedtuple and dataclass creation in a
    module imported during start-up) leaves CPython's "unhandled KeyboardInterrupt" flag set
    although :func:`main` handled it, and the interpreter then exits by SIGINT (status -2), not
    with 143."""
    import os
    import signal
    if signal.SIGTERM in _SIGNALS_RECEIVED:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    _exit(main())
