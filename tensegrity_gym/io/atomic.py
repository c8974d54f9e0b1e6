"""The one atomic file writer: staged writes published by rename (or by hard link, never
replacing a file).

:func:`write_atomic` ``(path, writer)``: ``writer(f)`` fills a temporary file beside ``path``
(``.<name>.tmp-<pid>-<n><suffix>``, :func:`stage`), which is fsynced, given the user's umask and
moved onto ``path`` (:func:`publish`); the folder is fsynced. An interrupt, crash or kill at any
moment leaves the old file or the new one, never a partial one. ``exclusive=True`` publishes
with a hard link, so an existing file is never replaced (:class:`OutputChanged`). Only a regular
file is ever replaced: a device, a FIFO, a socket, a folder or a symbolic link at the path is
refused (:func:`check_output_kind`), even with ``force``. A run folder's
own files (checkpoints, ``state.json``) are written this way by the run that claimed the folder.

Claims and multi-file transactions (claim an output before the work, publish several outputs
together) are :mod:`tensegrity_gym.io.claim`, built on :func:`stage` and :func:`publish`.
"""
from __future__ import annotations

import errno
import os
import re
import stat
from pathlib import Path

TMP_TAG = ".tmp-"
_TMP_PID = re.compile(re.escape(TMP_TAG) + r"(\d+)")
_COUNTER = iter(range(1 << 62))

__all__ = ["close_after_error", "write_atomic", "stage", "publish", "link_exclusive", "tmp_path", "remove_stale_tmp",
           "remove_stale_tmp_of", "check_writable", "check_output_kind", "pid_alive", "OutputError", "OutputExists",
           "OutputChanged", "TMP_TAG"]


# ---------------------------------------------------------------------- errors
class OutputError(OSError):
    """An output cannot be claimed or written; the message names the path and the option."""


class OutputExists(OutputError, FileExistsError):
    """The output exists when it is claimed and ``force`` was not given."""


class OutputChanged(OutputError, FileExistsError):
    """The output appeared or changed after it was claimed; not replaced without ``force``."""


def pid_alive(pid) -> bool:
    """True if a process ``pid`` exists on this host (one owned by another user counts)."""
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except (OSError, ValueError, TypeError, OverflowError):
        return False
    return True


# ---------------------------------------------------------------------- files
def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable (no-op where a folder cannot be opened)."""
    try:
        fd = os.open(str(folder), os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)




def tmp_path(path: str | Path) -> Path:
    """A fresh temporary name beside ``path`` (``.<name>.tmp-<pid>-<n><suffix>``; the suffix is
    kept so that writers choosing a format by extension, such as imageio, see it)."""
    path = Path(path)
    return path.with_name(f".{path.name}{TMP_TAG}{os.getpid()}-{next(_COUNTER)}{path.suffix}")


def _unlink(p) -> None:
    try:
        os.unlink(p)
    except OSError:
        pass


def stage(path: str | Path, writer=None, *, fill=None) -> Path:
    """Write a temporary file beside ``path`` and return its name (nothing is published):
    ``writer(f)`` fills it through a binary file object, or ``fill(tmp)`` writes it by name.
    The file is fsynced and given the user's umask; it is removed if the writer fails."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_path(path)
    try:
        if fill is not None:
            fill(tmp)
        else:
            with open(tmp, "xb") as f:
                writer(f)   # may close f (SB3's save_to_pkl does)
        fd = os.open(str(tmp), os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.chmod(tmp, 0o666 & ~_umask())
    except BaseException:
        _unlink(tmp)
        raise
    return tmp


def link_exclusive(src: Path, dst: Path) -> None:
    """Give the file ``src`` the second name ``dst``, failing with FileExistsError if ``dst``
    exists (a hard link: atomic and exclusive). Where the file system has no hard links, the
    name is checked, then the file renamed (a window of a few microseconds)."""
    try:
        os.link(src, dst)
    except FileExistsError:
        raise
    except OSError as e:
        if e.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK, errno.ENOSYS):
            raise
        if os.path.lexists(dst):
            raise FileExistsError(errno.EEXIST, "File exists", str(dst)) from None
        fd = os.open(str(dst), os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)   # the name, exclusively
        os.close(fd)
        os.replace(src, dst)


def publish(tmp: Path, path: str | Path, *, exclusive: bool = False, label: str = "output") -> None:
    """Move the staged ``tmp`` onto ``path``: renamed over it, or with ``exclusive`` hard-linked
    (fails with :class:`OutputChanged` if ``path`` exists: never replaces a file) then unlinked."""
    path = Path(path)
    try:
        if exclusive:
            try:
                link_exclusive(tmp, path)
            except FileExistsError:
                raise OutputChanged(f"{label} {str(path)!r} was created by someone else during this run; "
                                    "not replaced (pass --force to overwrite it)") from None
            _unlink(tmp)
        else:
            check_output_kind(path, label)      # never replace a device, FIFO, socket, link or folder
            os.replace(tmp, path)
    except BaseException:
        _unlink(tmp)
        raise
    _fsync_dir(path.parent)


def write_atomic(path: str | Path, writer=None, *, fill=None, exclusive: bool = False) -> Path:
    """Write ``path`` atomically (:func:`stage` then :func:`publish`); returns ``path``."""
    path = Path(path)
    publish(stage(path, writer, fill=fill), path, exclusive=exclusive)
    return path


def remove_stale_tmp(folder: str | Path) -> list[Path]:
    """Remove the temporary files of :func:`stage` left in ``folder`` (and its sub-folders) by
    processes that no longer run; returns the removed paths."""
    removed = []
    for p in Path(folder).rglob(f".*{TMP_TAG}*"):
        m = _TMP_PID.search(p.name)
        if m is None:
            continue
        pid = int(m.group(1))
        if pid != os.getpid() and not pid_alive(pid):
            try:
                p.unlink()
                removed.append(p)
            except OSError:
                pass
    return removed


_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISSOCK, "a socket"))


def check_output_kind(path: str | Path, label: str = "--out") -> None:
    """Fail (:class:`OutputError`) unless ``path`` is absent or a regular file: an output never
    replaces a directory, a device (``--force`` on ``/dev/null`` would replace the device node), a
    FIFO, a socket or a symbolic link. Links are not followed either (a dangling one would be
    refused only at the end of the run): the message names the link's target to give instead."""
    path = Path(path)
    try:
        st = os.lstat(path)
    except (FileNotFoundError, NotADirectoryError):     # a new name (a folder that is a file: check_writable)
        return
    except OSError as e:
        raise OutputError(f"{label} {str(path)!r} cannot be checked ({e.strerror or e})") from None
    mode = st.st_mode
    if stat.S_ISREG(mode):
        return
    if stat.S_ISLNK(mode):
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        dangling = "" if path.exists() else ", which does not exist"
        raise OutputError(f"{label} {str(path)!r} is a symbolic link (to {target!r}{dangling}); outputs are not "
                          "written through links nor replace them: give the target's path or remove the link")
    if stat.S_ISDIR(mode):
        raise OutputError(f"{label} {str(path)!r} is a directory; give a file name")
    kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
    raise OutputError(f"{label} {str(path)!r} is {kind}, not a regular file; an output replaces only a regular file "
                      "(even with --force)")


def remove_stale_tmp_of(path: str | Path) -> list[Path]:
    """Remove the temporary files of :func:`stage` for ``path`` (``.<name>.tmp-<pid>-<n><suffix>``
    beside it) left by processes that no longer run (a run killed with SIGKILL cannot remove
    them); only regular files are removed. Returns the removed paths."""
    path = Path(path)
    name = re.compile(re.escape(f".{path.name}{TMP_TAG}") + r"(\d+)-\d+" + re.escape(path.suffix))
    removed = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    for e in entries:
        m = name.fullmatch(e.name)
        if m is None or int(m.group(1)) == os.getpid() or pid_alive(int(m.group(1))):
            continue
        try:
            if e.is_file(follow_symlinks=False):
                os.unlink(e.path)
                removed.append(Path(e.path))
        except OSError:
            pass
    return removed


def check_writable(path: str | Path, label: str = "--out", *, create_folders: bool = True) -> Path:
    """Fail (:class:`OutputError`) if ``path`` cannot be a file written here: anything but a
    regular file or a new name (:func:`check_output_kind`), a folder that is a file or is not
    writable, or (``create_folders`` False) a missing folder."""
    path = Path(path)
    if not create_folders and not path.parent.is_dir():
        raise OutputError(f"{label} {str(path)!r}: folder {str(path.parent)!r} does not exist")
    check_output_kind(path, label)
    folder = path.parent
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir():
        raise OutputError(f"{label} {str(path)!r}: {str(folder)!r} is a file, not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"{label} {str(path)!r}: folder {str(folder)!r} is not writable")
    return path


def close_after_error(resource) -> None:
    """``resource.close()`` on an error path: an error of the close itself (a full disk, a broken
    pipe to a dead encoder) is dropped, so that the error being handled is the one reported."""
    try:
        resource.close()
    except Exception:  # noqa: BLE001 -- the original error propagates
        pass
