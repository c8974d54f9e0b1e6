"""Claims of outputs and run folders, and the outputs of one command written all or none.

* :class:`Claim`: an exclusive claim of an output path or of a run folder, taken BEFORE the work
  by creating a lock file (``.<name>.lock`` beside a file, ``.lock`` inside a folder) that names
  the holder (pid, host, start time, process start, command). The lock appears whole or not at
  all (it is hard-linked from a filled temporary file). A second claim is refused at once
  (:class:`OutputBusy`, naming the holder); a lock left by a process that no longer runs on this
  host (or whose pid now belongs to another process) is a :class:`StaleClaim`, taken over only
  when asked (``steal=True``, the ``--steal-lock`` option).
* :class:`Transaction`: several outputs of one command, claimed together before the work,
  staged as temporary files during it (:func:`tensegrity_gym.io.atomic.stage`), and published
  together by :meth:`Transaction.commit`: a target that appeared or changed since the claim is
  refused unless ``force`` (nothing is published then), SIGINT / SIGTERM are held back during
  the renames, and :attr:`Transaction.written` says exactly which files were published if a
  rename fails.
"""
from __future__ import annotations

import json
import os
import signal
import socket
import sys
import threading
import time
from pathlib import Path

from .atomic import (OutputChanged, OutputError, OutputExists, _unlink, check_writable, link_exclusive, pid_alive,
                     publish, remove_stale_tmp_of, stage)

LOCK_SUFFIX = ".lock"

__all__ = ["Claim", "Transaction", "OutputBusy", "StaleClaim", "TransactionIncomplete", "holder_record",
           "holder_alive", "describe_holder", "read_lock", "LOCK_SUFFIX"]


class OutputBusy(OutputError, FileExistsError):
    """Another live process holds the claim; :attr:`holder` is its lock record (pid, host, started)."""

    def __init__(self, message: str, holder: dict | None = None):
        super().__init__(message)
        self.holder = holder or {}


class StaleClaim(OutputBusy):
    """The lock was left by a process that no longer runs; pass ``steal=True`` to take it over."""


class TransactionIncomplete(OutputError):
    """Publishing several outputs failed part way; :attr:`written` lists the published paths."""

    def __init__(self, message: str, written: list):
        super().__init__(message)
        self.written = list(written)


def _process_start(pid: int) -> str | None:
    """The kernel's start time of ``pid`` (clock ticks since boot, Linux) or None: tells a live
    holder from a new process that reuses its pid."""
    try:
        with open(f"/proc/{int(pid)}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[19].decode()
    except (OSError, IndexError, ValueError):
        return None


def holder_record() -> dict:
    """This process as a lock holder: pid, host, start time (UTC ISO 8601), command line."""
    return {"pid": os.getpid(), "host": socket.gethostname(),
            "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "process_start": _process_start(os.getpid()), "command": " ".join(sys.argv)[:500]}


def holder_alive(holder: dict) -> bool | None:
    """True / False whether the holder still runs; None when it cannot be told (another host)."""
    if holder.get("host") != socket.gethostname():
        return None
    pid = holder.get("pid")
    if not pid_alive(pid):
        return False
    start = holder.get("process_start")
    return start is None or _process_start(pid) in (None, start)


def describe_holder(holder: dict) -> str:
    return (f"pid {holder.get('pid', '?')} on host {holder.get('host', '?')}, started "
            f"{holder.get('started', '?')}")


def _identity(path: Path):
    """What identifies the file at ``path`` now (device, inode, size, mtime), or None if absent."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return None
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def read_lock(lock: str | Path) -> dict:
    """The holder record in a lock file ({} if unreadable)."""
    try:
        data = json.loads(Path(lock).read_text())
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


class Claim:
    """An exclusive claim of ``path`` (a file to write, or with ``folder=True`` a run folder).

    Taken at construction (or :meth:`acquire`): the lock file is created exclusively. Refused with
    :class:`OutputExists` if the file exists and not ``force``; :class:`OutputBusy` naming the
    holder if another live process holds it (or one on another host: ``steal`` overrides that);
    :class:`StaleClaim` if its holder no longer runs, unless ``steal`` or ``take_over_dead`` (which
    takes over only a holder known dead on this host: what resuming a killed run does). A file
    claim removes the temporary files that writers of the path which no longer run left beside
    it (:func:`~tensegrity_gym.io.atomic.remove_stale_tmp_of`; listed in :attr:`removed_tmp`).
    :meth:`release` (or leaving the ``with`` block) removes the lock if it is still this claim's,
    and a claimed folder that it created if the folder is still empty.
    """

    def __init__(self, path: str | Path, *, force: bool = False, steal: bool = False, label: str = "--out",
                 folder: bool = False, create_folders: bool = True, take_over_dead: bool = False):
        self.path = Path(path)
        self.force, self.steal, self.label, self.folder = force, steal, label, folder
        self.take_over_dead = take_over_dead
        self.created = False
        self.lock = (self.path / LOCK_SUFFIX) if folder else self.path.with_name(f".{self.path.name}{LOCK_SUFFIX}")
        self.record = holder_record()
        self.took_over: dict | None = None    # the stale holder's record, when one was taken over
        self.removed_tmp: list[Path] = []     # temporary files of dead writers removed when claimed
        self.held = False
        if not folder:
            check_writable(self.path, label, create_folders=create_folders)
        self.acquire()

    def acquire(self) -> None:
        if self.folder:
            if self.path.exists() and not self.path.is_dir():
                raise OutputError(f"{self.label} {str(self.path)!r} is a file, not a folder")
            self.created = not self.path.exists()
            try:
                self.path.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise OutputError(f"{self.label} {str(self.path)!r}: cannot create the folder ({e.strerror or e})") \
                    from None
        else:
            if self.path.exists() and not self.force:
                raise OutputExists(f"{self.label} {str(self.path)!r} exists; pass --force to overwrite it")
            top = self.path.parent
            while not top.parent.exists() and top.parent != top:
                top = top.parent
            self.created = not top.exists()
            self._top = top
            try:
                self.lock.parent.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                self.release()
                raise OutputError(f"{self.label} {str(self.path)!r}: cannot create the folder "
                                  f"{str(e.filename or self.path.parent)!r} ({e.strerror or e})") from None
        try:
            tmp = stage(self.lock, lambda f: f.write(json.dumps(self.record).encode()))
        except OSError as e:
            self.release()
            raise OutputError(f"{self.label} {str(self.path)!r}: cannot write in the folder "
                              f"{str(self.lock.parent)!r} ({e.strerror or e})") from None
        try:
            for _ in range(3):
                try:
                    link_exclusive(tmp, self.lock)
                    break
                except FileExistsError:
                    self._refuse_or_take_over()
            else:
                raise OutputBusy(f"{self.label} {str(self.path)!r}: could not take its lock {str(self.lock)!r}")
        finally:
            _unlink(tmp)
        self.held = True
        self.identity = None if self.folder else _identity(self.path)
        if not self.folder:     # the claim is ours: temporary files of killed writers of this path go
            self.removed_tmp = remove_stale_tmp_of(self.path) + remove_stale_tmp_of(self.lock)

    def _refuse_or_take_over(self) -> None:
        holder = read_lock(self.lock)
        alive = holder_alive(holder) if holder else False
        if alive:
            raise OutputBusy(f"{self.label} {str(self.path)!r} is in use by another run ({describe_holder(holder)}; "
                             f"lock {str(self.lock)!r}); wait for it or choose another path", holder)
        if not (self.steal or (self.take_over_dead and alive is False and holder)):
            why = ("it runs on another host and cannot be checked from here" if alive is None else
                   "it no longer runs" if holder else "the lock is unreadable")
            cls = OutputBusy if alive is None else StaleClaim
            raise cls(f"{self.label} {str(self.path)!r} is locked by {describe_holder(holder)}, but {why} "
                      f"(lock {str(self.lock)!r}); pass --steal-lock to take it over", holder)
        self.took_over = holder
        _unlink(self.lock)

    def changed(self) -> bool:
        """True if the file appeared, disappeared or changed since the claim."""
        return _identity(self.path) != self.identity

    def release(self) -> None:
        if self.held and read_lock(self.lock).get("pid") == self.record["pid"]:
            _unlink(self.lock)
        self.held = False
        if self.created:    # remove the folders made for the claim if still empty (nothing was written)
            folder = self.path if self.folder else self.path.parent
            top = self.path if self.folder else self._top
            while True:
                try:
                    folder.rmdir()
                except OSError:
                    break
                if folder == top:
                    break
                folder = folder.parent
            self.created = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()
        return False


class _HoldSignals:
    """Hold SIGINT / SIGTERM back for a few renames (main thread only), then deliver them."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __enter__(self):
        self.pending, self.old = [], {}
        if threading.current_thread() is threading.main_thread():
            for s in self.SIGNALS:
                self.old[s] = signal.signal(s, lambda n, f: self.pending.append((n, f)))
        return self

    def __exit__(self, *exc):
        for s, h in self.old.items():
            signal.signal(s, h)
        for n, f in self.pending:
            h = self.old.get(n)
            if callable(h):
                h(n, f)
            elif h == signal.SIG_DFL and n == signal.SIGINT:
                raise KeyboardInterrupt
            elif h == signal.SIG_DFL:
                os.kill(os.getpid(), n)
        return False


class Transaction:
    """The outputs of one command, written all or none.

    ``Transaction([(path, label), ...], force=, steal=)`` claims every path before the work
    (releasing those already claimed if one is refused). During the work :meth:`stage` /
    :meth:`stage_file` write temporary files; :meth:`commit` publishes them all. Leaving the
    ``with`` block removes unpublished temporary files and the locks; :attr:`written` lists the
    published paths in order (for the message of an interrupted command).
    """

    def __init__(self, outputs, *, force: bool = False, steal: bool = False, create_folders: bool = True):
        self.force = force
        self.claims: dict[Path, Claim] = {}
        self.staged: dict[Path, Path] = {}
        self.written: list[Path] = []
        try:
            for path, label in outputs:
                path = Path(path)
                if path in self.claims:
                    raise OutputError(f"{label} {str(path)!r} is also another output of this command")
                self.claims[path] = Claim(path, force=force, steal=steal, label=label,
                                          create_folders=create_folders)
        except BaseException:
            self.release()
            raise

    def stage(self, path, writer) -> None:
        """Write the claimed ``path``'s content (``writer(f)``, binary file object) to a temporary file."""
        self._put(Path(path), stage(path, writer))

    def stage_file(self, path, fill) -> None:
        """As :meth:`stage` for writers that take a file name: ``fill(tmp_name)``."""
        self._put(Path(path), stage(path, fill=fill))

    def _put(self, path: Path, tmp: Path) -> None:
        if path not in self.claims:
            _unlink(tmp)
            raise KeyError(f"{path} was not claimed by this transaction")
        old = self.staged.pop(path, None)
        if old is not None:
            _unlink(old)
        self.staged[path] = tmp

    def commit(self) -> list[Path]:
        """Publish every staged file; returns the published paths. Refuses (publishing nothing)
        if a target appeared or changed since the claim and ``force`` was not given."""
        if not self.force:
            moved = [p for p in self.staged if self.claims[p].changed()]
            if moved:
                raise OutputChanged("; ".join(
                    f"{self.claims[p].label} {str(p)!r} was created or changed by someone else during this run"
                    for p in moved) + "; nothing was written (pass --force to overwrite)")
        with _HoldSignals():
            for path in list(self.staged):
                tmp = self.staged.pop(path)
                try:
                    publish(tmp, path, exclusive=not self.force, label=self.claims[path].label)
                except OSError as e:
                    left = [str(p) for p in self.staged]
                    raise TransactionIncomplete(
                        f"writing {str(path)!r} failed ({e.strerror or e}); " + self.report()
                        + (f"; not written: {', '.join(left)}" if left else ""), self.written) from None
                self.written.append(path)
        return list(self.written)

    def report(self) -> str:
        """One phrase: which outputs were written ("no output file was changed" if none)."""
        if not self.written:
            return "no output file was changed"
        return "wrote " + ", ".join(str(p) for p in self.written)

    def release(self) -> None:
        for tmp in self.staged.values():
            _unlink(tmp)
        self.staged.clear()
        for c in reversed(list(self.claims.values())):   # the last claims first: folders made empty
            c.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()
        return False
