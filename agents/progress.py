"""Training progress as plain lines: readable on a terminal and in a log file alike.

One line every ``interval`` seconds (and one at the end) with the steps done out of the budget,
the speed, the elapsed time, an ETA that honours a wall-time cap, and the latest evaluation::

    [train] 350,208/1,200,000 steps (29 %) | 5,840 steps/s | 1:00 elapsed | ETA 2:25 | eval @300,032: return -55.2, success 85 %

A progress bar redraws one line in place, so redirected to a file (CI, ``nohup``) it shows
nothing until the end, and its ETA ignores ``--max-wall-time``; these lines do neither.
"""
from __future__ import annotations

import sys
import time

import numpy as np


def clock(seconds: float) -> str:
    """``h:mm:ss`` (or ``m:ss`` below an hour) of a duration in seconds."""
    s = int(round(max(seconds, 0.0)))
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def progress_line(steps: int, total: int, elapsed: float, speed: float, wall_left: float | None = None,
                  evaluation: str = "") -> str:
    """One progress line. ``steps`` of ``total`` env steps done in ``elapsed`` s, at ``speed`` env
    steps/s lately (0: not measured yet, no ETA); ``wall_left``: seconds left under a wall-time cap
    (None: no cap)."""
    frac = steps / total if total > 0 else 1.0
    parts = [f"[train] {steps:,}/{total:,} steps ({100 * frac:.0f} %)",
             f"{speed:,.0f} steps/s" if speed > 0 else "measuring speed", f"{clock(elapsed)} elapsed"]
    eta = (total - steps) / speed if speed > 0 else float("inf")
    capped = wall_left is not None and wall_left < eta
    if capped:
        parts.append(f"ETA {clock(wall_left)} (wall-time cap, about {steps + int(speed * wall_left):,} steps)")
    elif np.isfinite(eta):
        parts.append(f"ETA {clock(eta)}")
    if evaluation:
        parts.append(evaluation)
    return " | ".join(parts)


def evaluation_summary(eval_callback) -> str:
    """``eval @STEPS: return R, success S %`` of an EvalCallback's latest evaluation ('' before one)."""
    if eval_callback is None or not getattr(eval_callback, "evaluations_timesteps", None):
        return ""
    t = eval_callback.evaluations_timesteps[-1]
    r = float(np.mean(eval_callback.evaluations_results[-1]))
    out = f"eval @{int(t):,}: return {r:.1f}"
    succ = getattr(eval_callback, "evaluations_successes", None)
    if succ:
        out += f", success {100 * float(np.mean(succ[-1])):.0f} %"
    return out


def progress_callback(total_timesteps: int, interval: float = 10.0, max_wall_time: float | None = None,
                      eval_callback=None, stream=None):
    """An SB3 callback printing :func:`progress_line` every ``interval`` s of wall time and once at
    the end. ``total_timesteps``: the run's step budget (counting steps of earlier segments);
    ``max_wall_time``: the segment's wall-time cap in s (None: none)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class ProgressLines(BaseCallback):
        def __init__(self):
            super().__init__()
            self.stream = stream if stream is not None else sys.stdout
            self.t0 = self.last = 0.0
            self.last_steps = self.lines = 0

        def _emit(self) -> None:
            # the speed of the last interval: the first one holds the one-time compile and warm-up
            now = time.time()
            elapsed, dt = now - self.t0, now - self.last
            steps = int(self.num_timesteps)
            speed = (steps - self.last_steps) / dt if dt > 0 and self.lines else 0.0
            wall_left = None if max_wall_time is None else max(max_wall_time - elapsed, 0.0)
            print(progress_line(steps, int(total_timesteps), elapsed, speed, wall_left,
                                evaluation_summary(eval_callback)), file=self.stream, flush=True)
            self.last, self.last_steps, self.lines = now, steps, self.lines + 1

        def _on_training_start(self) -> None:
            self.t0 = self.last = time.time()
            self.last_steps, self.lines = int(self.num_timesteps), 0

        def _on_step(self) -> bool:
            if time.time() - self.last >= interval:
                self._emit()
            return True

        def _on_training_end(self) -> None:
            self._emit()

    return ProgressLines()
