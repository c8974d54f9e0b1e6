"""Signals during training: Ctrl-C and SIGTERM become KeyboardInterrupt (so that the model is
saved), a second one is ignored while saving, and the exit status names the signal.
"""
from __future__ import annotations

import os
import signal
import sys
import threading

#: signals turned into KeyboardInterrupt by the handlers below, in order
SIGNALS_RECEIVED: list = []


def install_interrupt_handlers():
    """Ctrl-C (SIGINT, even where a shell started us with SIGINT ignored) and SIGTERM raise
    KeyboardInterrupt, so that the model is saved before exiting."""
    if threading.current_thread() is not threading.main_thread():
        return

    def _raise(signum, frame):
        SIGNALS_RECEIVED.append(signum)   # main() exits 128 + the signal (SIGTERM 143, as the CLI)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _raise)


class DeferInterrupts:
    """While saving: a second Ctrl-C / SIGTERM prints a note and is ignored, so the save completes
    (every file is written atomically anyway: a SIGKILL leaves the previous good files)."""

    def __enter__(self):
        self.old = None
        if threading.current_thread() is threading.main_thread():
            def _note(signum, frame):
                print("\nstill saving the model: wait a moment (the files are written atomically)",
                      file=sys.stderr, flush=True)
            self.old = {sig: signal.signal(sig, _note) for sig in (signal.SIGINT, signal.SIGTERM)}
        return self

    def __exit__(self, *exc):
        if self.old:
            for sig, h in self.old.items():
                signal.signal(sig, h)
        return False


def interrupted_exit_code() -> int:
    """128 + the signal that interrupted the training (SIGTERM: 143, as the CLI), 130 for Ctrl-C."""
    return 143 if signal.SIGTERM in SIGNALS_RECEIVED else 130


def exit_with(code: int) -> None:
    """Exit with ``code``. After a SIGTERM, directly (streams flushed): a KeyboardInterrupt that
    the handler raised inside ``eval()`` of a string (namedtuple and dataclass creation in a
    module imported during start-up) leaves CPython's "unhandled KeyboardInterrupt" flag set
    although :func:`main` handled it, and the interpreter then exits by SIGINT (status -2), not
    with 143."""
    if signal.SIGTERM in SIGNALS_RECEIVED:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)
