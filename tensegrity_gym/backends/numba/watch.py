"""Progress on stderr while numba compiles this package's kernels.

The first process after an install (or an update) compiles the kernels; later ones load them
from numba's on-disk cache (``__pycache__`` beside the modules) and print nothing. A compile
takes from seconds to minutes on a small machine, so that a silent one looks like a hang. This
module listens to numba's ``numba:compile`` event, which numba raises only for a real compile
(a cache miss), and prints:

* one line when the first compile of the process starts;
* a heartbeat every ``HEARTBEAT_S`` seconds while compiling, naming the kernel being compiled;
* a "done" line when no compile has run for ``IDLE_S`` seconds, with the elapsed time.

Only functions of ``tensegrity_gym`` count. ``TENSEGRITY_GYM_QUIET=1`` silences it.
"""
from __future__ import annotations

import os
import sys
import threading
import time

from numba.core import event

__all__ = ["install", "HEARTBEAT_S", "IDLE_S", "POLL_S"]

HEARTBEAT_S = 10.0   #: seconds between two heartbeat lines while compiling
IDLE_S = 1.5         #: seconds without a compile that end a compile session
POLL_S = 0.25        #: seconds between two looks of the reporting thread


def _say(message: str) -> None:
    if os.environ.get("TENSEGRITY_GYM_QUIET"):
        return
    try:
        print(f"tensegrity_gym: {message}", file=sys.stderr, flush=True)
    except (OSError, ValueError):   # pragma: no cover - stderr closed
        pass


class _Watch(event.Listener):
    """Counts the compiles in flight and reports on them from a daemon thread."""

    def __init__(self):
        self.lock = threading.Lock()
        self.depth = 0              # compiles in flight (numba compiles callees inside callers)
        self.current = ""           # the outermost function being compiled
        self.session_t0 = None      # start of the current compile session (None: idle)
        self.last_end = 0.0
        self.kernels = 0            # functions compiled in this compile session
        self.sessions = 0
        self.thread = None

    @staticmethod
    def _name(ev) -> str | None:
        disp = (ev.data or {}).get("dispatcher")
        fn = getattr(disp, "py_func", None)
        mod = getattr(fn, "__module__", "") or ""
        if not mod.startswith("tensegrity_gym"):
            return None
        return f"{mod.removeprefix('tensegrity_gym.')}.{fn.__name__}"

    def on_start(self, ev) -> None:
        name = self._name(ev)
        if name is None:
            return
        with self.lock:
            now = time.monotonic()
            if self.session_t0 is None:
                self.session_t0, self.kernels, self.next_beat = now, 0, now + HEARTBEAT_S
                self.sessions += 1
                if self.sessions == 1:
                    _say("compiling the numba kernels (once after install or an update; cached in __pycache__ "
                         "for later runs; progress every 10 s) ...")
            if self.depth == 0:
                self.current = name
            self.depth += 1
            if self.thread is None:
                self.thread = threading.Thread(target=self._run, name="tensegrity_gym-compile-watch", daemon=True)
                self.thread.start()

    def on_end(self, ev) -> None:
        if self._name(ev) is None:
            return
        with self.lock:
            self.depth = max(self.depth - 1, 0)
            self.kernels += 1
            self.last_end = time.monotonic()

    def _run(self) -> None:
        while True:
            time.sleep(POLL_S)
            with self.lock:
                if self.session_t0 is None:
                    continue
                now = time.monotonic()
                took = now - self.session_t0
                if self.depth > 0 and now >= self.next_beat:
                    _say(f"still compiling ({self.current}), {took:.0f} s so far ...")
                    self.next_beat = now + HEARTBEAT_S
                elif self.depth == 0 and now - self.last_end >= IDLE_S:
                    took = self.last_end - self.session_t0
                    if self.sessions == 1 or took >= 2.0:
                        _say(f"compiled {self.kernels} numba functions in {took:.0f} s (cached for later runs)")
                    self.session_t0 = None


_WATCH = None


def install() -> None:
    """Start listening (idempotent); called when the numba backend is imported."""
    global _WATCH
    if _WATCH is None:
        _WATCH = _Watch()
        event.register("numba:compile", _WATCH)
