"""Memory needed by a structure, and a refusal *before* the work when it cannot fit.

Every array of the compiled model, of a step and of the stability estimate is linear in the
structure's size (k rods, n nodes, m strings; :mod:`tensegrity_gym.core.model` has no m x n or
6k x 6k dense array above ~20 rods), so the memory is estimated from the three counts with
per-item byte costs that bound what the NumPy path allocates (measured with ``tracemalloc``
on towers of 30 to 1000 stages, then rounded up):

* compile + one step of B copies (the RK4 step of the NumPy path keeps the most temporaries):
  ``8 (40 k + 12 m + 12 n) + B 8 (160 k + 64 m + 32 n)`` bytes;
* the stability estimate of one state (:func:`tensegrity_gym.physics.stability.stable_step_estimate`,
  sparse path): the finite-difference Jacobians ``K``, ``D`` have ``72`` entries per coupled
  rod pair (``k + 2 m`` pairs at most) at ~40 bytes each while they are assembled, the
  finite-difference batch is evaluated in chunks of :data:`FD_CHUNK_BYTES`, and Arnoldi keeps
  ~40 vectors of length 12 k;
* ``records`` recorded states (``simulate``): ``8 (12 k + 3 n)`` bytes each.

:func:`check_size` compares the estimate with the memory the operating system reports as
available and raises :class:`StructureTooLarge` (a :class:`MemoryError` whose message names
the structure's size, the estimate and what is available) at once -- never after minutes of
allocation and swapping.
"""
from __future__ import annotations

import os

__all__ = ["StructureTooLarge", "memory_estimate", "stability_bytes", "available_memory", "check_size",
           "FD_CHUNK_BYTES"]

#: bytes of working memory per chunk of the batched finite-difference evaluation (sparse Jacobian)
FD_CHUNK_BYTES = 64 * 2 ** 20


class StructureTooLarge(MemoryError):
    """The structure (or the requested batch / recording) does not fit in the available memory."""


def memory_estimate(n_bars: int, n_nodes: int, n_strings: int, batch_size: int = 1, records: int = 0,
                    stability: bool = True) -> int:
    """Estimated peak bytes to compile a structure of ``n_bars`` rods, ``n_nodes`` nodes and
    ``n_strings`` strings, take one step of ``batch_size`` copies, keep ``records`` recorded
    states and (``stability``) estimate its stable step. See the module doc for the terms."""
    k, n, m, B = int(n_bars), int(n_nodes), int(n_strings), max(int(batch_size), 1)
    total = 8 * (40 * k + 12 * m + 12 * n) + B * 8 * (160 * k + 64 * m + 32 * n)
    total += max(int(records), 0) * B * 8 * (12 * k + 3 * n)
    if stability:
        total += stability_bytes(k, m)
    return int(total)


def stability_bytes(n_bars: int, n_strings: int) -> int:
    """Estimated peak bytes of the sparse stable-step estimate (see the module doc): K, D entries
    of ``k + 2 m`` coupled rod pairs, one finite-difference chunk and the Arnoldi vectors."""
    k, m = int(n_bars), int(n_strings)
    return 72 * (k + 2 * m) * 40 + 40 * 12 * k * 8 + FD_CHUNK_BYTES


def available_memory() -> int | None:
    """Bytes the operating system reports as available (``MemAvailable`` of /proc/meminfo, else
    free physical pages); None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def _gib(x: float) -> str:
    return f"{x / 2 ** 30:.3g} GiB"


def check_size(structure, batch_size: int = 1, records: int = 0, stability: bool = True,
               available: int | None = None) -> int:
    """Raise :class:`StructureTooLarge` unless :func:`memory_estimate` of ``structure`` fits in
    ``available`` bytes (default: :func:`available_memory`; unknown -> no check). Returns the
    estimate (bytes). Cost: O(1)."""
    s = structure
    est = memory_estimate(s.n_bars, s.n_nodes, s.n_strings, batch_size, records, stability)
    avail = available_memory() if available is None else int(available)
    if avail is not None and est > avail:
        what = f"{batch_size} copies" if batch_size > 1 else "one copy"
        rec = f" and {records} recorded states" if records else ""
        raise StructureTooLarge(
            f"structure {getattr(s, 'name', '?')!r} is too large for this machine's memory: {s.n_bars} rods, "
            f"{s.n_nodes} nodes, {s.n_strings} strings need about {_gib(est)} to compile, step {what}"
            f"{rec}{' and estimate the stable step' if stability else ''}, but only {_gib(avail)} is available")
    return est
