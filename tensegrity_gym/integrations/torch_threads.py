"""torch's CPU threads for a training process: the one setting of ``agents.train``, the examples
and ``python -m tensegrity_gym.integrations.rsl_rl``.

By default torch takes one thread per core. PPO's learner runs many small operations, each ending
at an OpenMP barrier; on a machine whose cores are shared with other work (the env's own kernels
included) the team waits for its slowest thread: on a loaded 2-core machine the examples ran 6x
slower with torch's default threads than with one thread, to the same numbers. :func:`set_torch_threads` therefore sets one thread unless asked
for more, and lets idle OpenMP threads sleep instead of spin (:func:`passive_openmp_wait`).
"""
from __future__ import annotations

import argparse
import os
import sys

from ..core.checks import check_count


def passive_openmp_wait() -> bool:
    """Let idle OpenMP threads sleep instead of spin (``OMP_WAIT_POLICY=PASSIVE``), unless the
    variable is set already or torch (whose OpenMP runtime reads it when it loads) is imported.

    With more than one torch thread, each of PPO's many small operations ends at an OpenMP
    barrier; waiting threads spin there by default. On a machine whose cores are shared with other
    work, a spinning thread takes the core from the thread the barrier waits for: on 2 shared
    cores (load 4) the learner ran 13x slower per sample with 2 threads than with 2 threads that
    sleep (``docs/time_to_policy.md``). With one thread there is no team and nothing changes.
    Returns True if it set the variable."""
    if "OMP_WAIT_POLICY" in os.environ or "torch" in sys.modules:
        return False
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    return True


def set_torch_threads(n: int = 1) -> int:
    """Use ``n`` torch CPU threads (an integer >= 1, or an integral float such as ``2.0``; default
    1), after :func:`passive_openmp_wait` (effective only if torch is not imported yet). Returns the
    thread count set. ValueError naming ``n`` and the value for anything else (0, a negative
    number, a bool, ``2.5``, a string), before torch is touched."""
    n = check_count(n, "n", 1, "torch CPU threads")
    passive_openmp_wait()
    import torch   # optional dependency of the package: imported only by training code
    torch.set_num_threads(n)
    return n


def num_threads_arg(text: str) -> int:
    """argparse ``type=`` of the command lines' ``--num-threads``: ``text`` as a thread count (an
    integer >= 1); otherwise argparse's one-line usage error (exit code 2), not a traceback."""
    try:
        return check_count(int(text), "--num-threads", 1)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1 (torch CPU threads), got {text!r}") from None
