"""SB3 callbacks of :mod:`agents.train`: TensorBoard logging of the env's info keys, checkpoints
and evaluations on the run's own step schedule (kept by ``--resume``) written atomically, the
wall-time limit, the split of a segment's wall time, and an interrupt at a given step (tests).
"""
from __future__ import annotations

import os
import time
from collections import deque
from pathlib import Path

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

from . import common
from .run_dir import evaluation_metrics


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
