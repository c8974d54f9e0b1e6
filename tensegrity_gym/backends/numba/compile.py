"""Compile management of the numba backend: the threading layer, the chunk count of the
parallel loops, and the one-line notice on stderr when numba really compiles.

The first compiled call after an install (or after the package's source changed) compiles the
numba kernels; later processes load them from numba's on-disk cache (``__pycache__/*.nbi`` /
``*.nbc`` beside the modules) in well under a second. :mod:`~tensegrity_gym.backends.numba.watch`
prints the progress of a real compile.
"""
from __future__ import annotations

import os

import numba

from .entries import (_run_acc, _run_copies_serial, _run_forces, _run_lean, _run_parallel, _run_project, _run_serial,
                      _run_serial_simd, _SIG, _SIG_ACC, _SIG_COPIES, _SIG_FORCES, _SIG_LEAN, _SIG_PROJECT)
from .layout import _RK4

if "NUMBA_THREADING_LAYER" not in os.environ and numba.config.THREADING_LAYER == "default":
    # numba's default picks GNU OpenMP here; on a machine with more runnable threads than cores
    # (other jobs, or torch's own OpenMP pool during training) each parallel call then waits
    # ~12-16 ms for a descheduled worker, measured on the 2-core benchmark machine, against
    # ~0.1 ms with numba's own workqueue pool. Set NUMBA_THREADING_LAYER to choose otherwise.
    numba.config.THREADING_LAYER = "workqueue"

NCHUNK = 4 * numba.get_num_threads()   # chunks of the parallel batch loops


def compile_signatures(pairs) -> None:
    """Compile (or load from the disk cache) ``(dispatcher, signature)`` pairs. Progress of a real
    compile (a cache miss) is printed by :mod:`~tensegrity_gym.backends.numba.watch`."""
    for d, sig in pairs:
        d.compile(sig)


#: a call runs the multi-threaded kernel when B * n_steps * (strings + rods) * (4 for RK4, else 1)
#: reaches this (about 0.3 ms of single-core work: below it, waking threads costs more than they save,
#: and much more on a loaded machine). B < 8 is always serial.
PARALLEL_MIN_WORK = 10_000


#: each entry kernel with its one signature, compiled at its first use (a scene compiles only what it runs)
_ENTRIES = {"lean": ((_run_lean, _SIG_LEAN),), "serial": ((_run_serial, _SIG),),
            "serial_simd": ((_run_serial_simd, _SIG),), "copies": ((_run_copies_serial, _SIG_COPIES),),
            "forces": ((_run_forces, _SIG_FORCES),), "parallel": ((_run_parallel, _SIG_COPIES),),
            "acc": ((_run_acc, _SIG_ACC),), "project": ((_run_project, _SIG_PROJECT),)}
_READY = {name: False for name in _ENTRIES}


def _compile(which: str) -> None:
    """Compile (or load from numba's on-disk cache) the entry kernel ``which`` (a key of
    ``_ENTRIES``) for its single signature, then forbid further compilation: an argument of
    another type raises TypeError (handled by converting it) instead of compiling a new variant."""
    pairs = _ENTRIES[which]
    compile_signatures(pairs)
    for disp, _ in pairs:
        disp.disable_compile()
    _READY[which] = True


#: the work of one terrain contact slot per sub-step, in the units of PARALLEL_MIN_WORK (a string
#: or a rod), for a terrain with boxes or a heightfield (the general terrain instance, whose slots
#: cost the prism robot more than its whole flat-ground step; a terrain that is one plane counts
#: none, as the ground contact): with this weight the prism on such a terrain goes threaded from 53
#: copies, where the threaded terrain loop ran faster than the serial one on 2 cores
#: (``scripts/bench/bench_terrain.py``)
TERRAIN_SLOT_WORK = 20


def _parallel(p, B, n_steps, flags, compile_kernel=True, extra_cost=0):
    """True if this call should run the multi-threaded kernel (see PARALLEL_MIN_WORK; ``extra_cost``
    the work per copy and step beyond the model's, as terrain contact's); compiles ``_run_parallel``
    then unless ``compile_kernel`` is False (a caller with its own parallel kernel)."""
    try:
        work = B * int(n_steps) * (p.cost + extra_cost) * (4 if flags & _RK4 else 1)
    except (TypeError, ValueError):
        return False
    if work < PARALLEL_MIN_WORK:
        return False
    if compile_kernel and not _READY["parallel"]:
        _compile("parallel")
    return True


