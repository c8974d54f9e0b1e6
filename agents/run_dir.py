"""A run directory of :mod:`agents.train`: its ``state.json`` (:class:`RunState`), checkpoints,
the files saved at the end of a segment and the metrics of its evaluations.
"""
from __future__ import annotations

import glob
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

from . import common


def latest_checkpoint(run_dir: Path) -> tuple[int, Path | None]:
    """(steps, path) of the latest ``checkpoints/rl_model_<steps>_steps.zip``; (-1, None) if none."""
    best_steps, best = -1, None
    for f in glob.glob(str(run_dir / "checkpoints" / "rl_model_*_steps.zip")):
        m = re.search(r"rl_model_(\d+)_steps\.zip$", f)
        if m and int(m.group(1)) > best_steps:
            best_steps, best = int(m.group(1)), Path(f)
    return best_steps, best


def resume_files(run_dir: Path, prev_state: dict) -> tuple[Path, Path, Path]:
    """(model, VecNormalize statistics, replay buffer) that ``--resume`` continues from: the final
    (or interrupted) ``model.zip`` if it holds at least as many steps as the latest checkpoint,
    else that checkpoint's files."""
    ck_steps, ck_path = latest_checkpoint(run_dir)
    final = run_dir / "model.zip"
    fin_steps = int(prev_state.get("model_num_timesteps", prev_state.get("num_timesteps", -1))) \
        if final.exists() else -1
    if fin_steps >= ck_steps and final.exists():
        return final, run_dir / "vecnormalize.pkl", run_dir / "replay_buffer.pkl"
    return (ck_path, run_dir / "checkpoints" / f"rl_model_vecnormalize_{ck_steps}_steps.pkl",
            run_dir / "checkpoints" / f"rl_model_replay_buffer_{ck_steps}_steps.pkl")


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


def read_state(run_dir: Path) -> dict:
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


def has_saved_model(run_dir: Path) -> bool:
    return (run_dir / "model.zip").exists() or latest_checkpoint(run_dir)[1] is not None


def clear_failed_start(run_dir: Path) -> None:
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


def save_final(model, run_dir: Path, status: str, run_state: RunState) -> None:
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

