"""Shared pieces of the command line (:mod:`tensegrity_gym.tools.cli`): exit codes, the one-line
error, request limits, structure loading, number parsing and the claimed outputs of a command."""
from __future__ import annotations

import argparse
import os
import re
import threading

import numpy as np

from ..core.builders import load_structure
from ..core.builders import BUILDERS
from ..io.atomic import OutputError
from ..io.claim import Transaction
from ..core.sizing import memory_estimate
from ..core.structure import StructureError


PROGRESS_MIN_STEPS = 20000
DEFAULT_MAX_STEPS = 1e9
#: adaptive methods (dop853, radau) may evaluate the accelerations this many times per --max-steps step
#: (dop853 takes 12 per accepted step, radau a few Newton iterations of 3 stages) before exit code 5
ADAPTIVE_EVALUATIONS_PER_STEP = 20
EXIT_OK, EXIT_USAGE, EXIT_STRUCTURE, EXIT_OUTPUT, EXIT_TOO_LARGE, EXIT_DIVERGED = 0, 2, 3, 4, 5, 6
EXIT_INTERRUPTED, EXIT_PIPE, EXIT_TERMINATED = 130, 141, 143
CHUNK_STEPS = 200_000          # a fixed-step run is integrated in chunks of about this many steps
ENERGY_BLOWUP = 1e6            # energy growth (x its scale) that flags an unstable run


class CLIError(Exception):
    """A known error: ``message`` goes to stderr as one line, ``code`` is the exit status."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code


class _Terminated(BaseException):
    """Raised by the SIGTERM handler so that ``finally`` blocks remove temporary files."""


#: set by the SIGTERM handler as well: Python ignores an exception raised while it runs a weakref
#: callback or ``__del__`` (matplotlib's transforms have such callbacks), so a SIGTERM that lands
#: there would let the command run on; :func:`_commit` and the end of ``main`` check this instead
TERMINATED = threading.Event()


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _default_max_memory_gib() -> float:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 / 2**30
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return 4.0


def _gib(nbytes: float) -> str:
    return f"{nbytes / 2**30:.3g} GiB"


def _require_memory(nbytes: float, args, what: str) -> None:
    limit = args.max_memory * 2**30
    if not nbytes <= limit:
        raise CLIError(EXIT_TOO_LARGE, f"{what} needs about {_gib(nbytes)} of memory, above the limit of "
                                       f"{_gib(limit)} (--max-memory)")


# --------------------------------------------------------------------------- structure
_SIZED = {"prism": lambda p: (2 * p, p, 3 * p),
          "tower": lambda q: (6 * q, 3 * q, 15 * q - 6)}


def _builder_bytes(n: int, k: int, m: int) -> float:
    """Memory of a built-in builder's self-stress: the (6k x m) equilibrium matrix, its
    (n, 3, m) columns and the full SVD (6k x 6k and m x m), 8 bytes each."""
    return 8.0 * (3 * n * m + 6 * k * m + (6 * k) ** 2 + m * m)


def _load(spec: str, args):
    mt = re.fullmatch(r"(prism|tower)(\d+)", spec)
    if mt and not os.path.exists(spec) and spec not in BUILDERS:
        size = int(mt.group(2)) if len(mt.group(2)) < 12 else 10 ** 12
        n, k, m = _SIZED[mt.group(1)](size)
        if mt.group(1) == "prism":
            _require_memory(_builder_bytes(n, k, m), args,
                            f"building {spec!r} ({n} nodes, {k} rods, {m} strings; SVD of its {6 * k} x {m} "
                            "equilibrium matrix)")
        else:   # tower: no SVD (uniform strain); compile + a step + the stable-step estimate, linear
            _require_memory(memory_estimate(k, n, m), args, f"{spec!r} ({n} nodes, {k} rods, {m} strings: "
                            "compile, one step and the stable-step estimate)")
    try:
        return load_structure(spec)
    except FileNotFoundError:
        raise CLIError(EXIT_STRUCTURE, f"structure file {spec!r} not found") from None
    except IsADirectoryError:
        raise CLIError(EXIT_STRUCTURE, f"structure {spec!r} is a directory, not a structure file") from None
    except PermissionError as e:
        raise CLIError(EXIT_STRUCTURE, f"structure file {spec!r} cannot be read ({e.strerror})") from None
    except StructureError as e:
        raise CLIError(EXIT_STRUCTURE, f"structure {spec!r}: {e}") from None


# --------------------------------------------------------------------------- output files
def _claim(args, outputs, create_folders: bool = True) -> Transaction:
    """Claim a command's outputs ``[(path, flag), ...]`` before any work (one transaction, kept in
    ``args.outputs`` so that :func:`tensegrity_gym.tools.cli.main` reports truthfully what an interrupt left written)."""
    try:
        tx = Transaction(outputs, force=args.force, steal=args.steal_lock, create_folders=create_folders)
    except OutputError as e:
        raise CLIError(EXIT_OUTPUT, str(e)) from None
    args.outputs = tx
    return tx


def _stage(tx: Transaction, path, writer=None, *, fill=None) -> None:
    try:
        if fill is not None:
            tx.stage_file(path, fill)
        else:
            tx.stage(path, writer)
    except OSError as e:
        raise CLIError(EXIT_OUTPUT, f"cannot write {str(path)!r}: {e.strerror or e}; {tx.report()}") from None


def _commit(tx: Transaction) -> None:
    if TERMINATED.is_set():     # a SIGTERM whose exception was swallowed: publish nothing
        raise _Terminated()
    try:
        tx.commit()
    except OutputError as e:
        raise CLIError(EXIT_OUTPUT, str(e)) from None


def _number(kind, what: str, ok, rule: str):
    """An argparse type: ``kind(text)`` if it parses as ``what`` and ``ok(value)``, else an error
    naming the rule and the text."""
    def parse(text):
        try:
            v = kind(text)
        except (ValueError, OverflowError):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not ok(v):
            raise argparse.ArgumentTypeError(f"{rule}, got {text!r}")
        return v
    return parse


def _positive(kind):
    return _number(kind, "a number", lambda v: np.isfinite(v) and v > 0, "must be positive and finite")


_non_negative = _number(float, "a number", lambda v: np.isfinite(v) and v >= 0, "must be >= 0 and finite")
_seed = _number(int, "an integer", lambda v: v >= 0, "must be >= 0")
_port = _number(int, "an integer", lambda v: 0 <= v <= 65535, "must be a TCP port in 0..65535 (0: any free port)")


def _n_steps(duration: float, dt: float, args) -> int:
    ratio = duration / dt
    if not ratio <= args.max_steps:
        raise CLIError(EXIT_TOO_LARGE, f"--duration {duration:g} s at --dt {dt:g} s is {ratio:.3g} steps, above "
                                       f"the limit of {args.max_steps:.3g} (--max-steps)")
    n_steps = int(round(ratio))
    if n_steps < 1:
        raise CLIError(EXIT_USAGE, f"--duration {duration} s is shorter than one step of --dt {dt} s")
    return n_steps


def _trajectory_bytes(model, n_records: int) -> float:
    """Recorded q, qd (6 k each), nodes (3 n), energy and time per record, twice (temporaries)."""
    return 2.0 * 8.0 * n_records * (12 * model.n_bars + 3 * model.n_nodes + 2)
