"""Drops this package's numba disk caches when any of its compiled sources changed.

numba keys a cached kernel on the stamp of its own source file only, and the cached machine
code of a kernel holds the code of every kernel it inlines or calls, from any module, as it was
when it was compiled. After an edit of ``terrain.py`` the cached ``terrain_steps`` kernels would
go on running the old contact forces without a word (a checkout of another version does the
same). So: one SHA-256 digest of every source file of the package that defines numba functions
(:data:`SOURCES`) is kept in each of their cache directories (``STAMP``); where it differs from
the sources', that directory's cache files of those modules are deleted before any kernel is
loaded, and the kernels compile again, as after an install.

The cache directories are numba's own choice for each file (beside the module in
``__pycache__``, or under ``NUMBA_CACHE_DIR`` or the user's cache directory where that one is
not writable). A directory that cannot be read or written is left as it is.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["SOURCES", "STAMP", "sources_digest", "drop_stale_caches"]

_PACKAGE = Path(__file__).resolve().parents[2]     # the tensegrity_gym directory

#: the package's modules that define numba functions (relative to ``tensegrity_gym``); a test
#: checks that every module calling ``njit`` is listed
SOURCES = ("backends/numba/actuation.py", "backends/numba/contact.py", "backends/numba/divergence.py",
           "backends/numba/driver.py", "backends/numba/entries.py", "backends/numba/equations.py",
           "backends/numba/heightfield.py", "backends/numba/layout.py", "backends/numba/terrain.py",
           "backends/numba/terrain_steps.py", "core/checks.py", "envs/compiled.py")

#: the digest's file name in a cache directory
STAMP = "tensegrity_gym-numba-sources.sha256"


def sources_digest(files) -> str:
    """SHA-256 (hex) of the files' names and contents, in the order given."""
    h = hashlib.sha256()
    for f in files:
        h.update(Path(f).name.encode())
        h.update(Path(f).read_bytes())
    return h.hexdigest()


def _cache_dir(py_file: Path) -> Path | None:
    """The directory numba caches ``py_file``'s functions in (its first locator that applies)."""
    from numba.core import caching

    def probe():        # the locators read a function's first line number only
        pass

    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)   # its name varies
    for cls in getattr(impl, "_locator_classes", ()):
        try:
            loc = cls.from_function(probe, str(py_file))
        except Exception:       # noqa: BLE001 - a locator of another numba version: try the next
            continue
        if loc is not None:
            return Path(loc.get_cache_path())
    return None


def drop_stale_caches(files=None, cache_dir=_cache_dir) -> list:
    """Delete the numba cache files (``.nbi``, ``.nbc``) of ``files`` (default :data:`SOURCES`,
    absolute paths) in each of their cache directories (``cache_dir(file)``) whose stamp
    differs from the files' digest, then write the digest there. Returns the paths deleted."""
    files = [_PACKAGE / f for f in SOURCES] if files is None else [Path(f) for f in files]
    try:
        digest = sources_digest(files)
    except OSError:
        return []
    by_dir: dict = {}
    for f in files:
        d = cache_dir(f)
        if d is not None:
            by_dir.setdefault(d, []).append(f.stem)
    dropped = []
    for d, stems in by_dir.items():
        stamp = d / STAMP
        try:
            if stamp.read_text().strip() == digest:
                continue
        except OSError:
            pass                # no stamp yet: caches of unknown sources
        try:
            for p in d.iterdir():
                # numba's names: <module>.<function>-<line>.py<ver>.nbi, .<n>.nbc
                if p.suffix in (".nbi", ".nbc") and p.name.split(".", 1)[0] in stems:
                    p.unlink(missing_ok=True)
                    dropped.append(p)
            tmp = d / f"{STAMP}.{os.getpid()}"
            tmp.write_text(digest + "\n")
            os.replace(tmp, stamp)
        except OSError:
            continue
    return dropped
