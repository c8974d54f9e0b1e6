"""One line on stderr, once per process, when numba is about to compile tensegrity_gym's kernels.

The first compiled call after an install (or after the package's source changed) compiles the
numba kernels: 25-27 s of CPU (48-57 s wall on a busy 2-core machine) for the shape env's first ``step()`` (see the
README's "First step" figures); later processes load them from numba's on-disk cache
(``__pycache__/*.nbi`` / ``*.nbc`` beside the modules) in well under a second. Loading from the
cache prints nothing. Set ``TENSEGRITY_GYM_QUIET=1`` to silence the message.
"""
from __future__ import annotations

import os
import sys
import time

_said = False


def cached(dispatcher) -> bool:
    """True if numba's on-disk cache holds a current entry for ``dispatcher`` (its index file
    exists and its source stamp matches the module); True as well when that cannot be told
    (then :func:`compile_with_notice` reports after a slow compile instead)."""
    if dispatcher.signatures:               # already compiled or loaded in this process
        return True
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:                       # numba internals changed, or caching disabled
        return True


def say(message: str) -> None:
    """Print ``message`` to stderr once per process (the first call only)."""
    global _said
    if _said or os.environ.get("TENSEGRITY_GYM_QUIET"):
        return
    _said = True
    try:
        print(message, file=sys.stderr, flush=True)
    except (OSError, ValueError):           # pragma: no cover - stderr closed
        pass


def compile_with_notice(pairs, what: str) -> None:
    """Compile ``(dispatcher, signature)`` pairs (``signature`` None: nothing to compile here,
    the first call will) announcing a cold compile up front and a slow unannounced one after."""
    cold = not all(cached(d) for d, _ in pairs)
    if cold:
        say(f"tensegrity_gym: compiling the numba {what} (once after install or an update, about "
            "1.5-2 min on 2 cores; cached in __pycache__ for later runs) ...")
    t0 = time.perf_counter()
    for d, sig in pairs:
        if sig is not None:
            d.compile(sig)
    took = time.perf_counter() - t0
    if not cold and took > 5.0:
        say(f"tensegrity_gym: compiled the numba {what} in {took:.0f} s (cached for later runs)")
