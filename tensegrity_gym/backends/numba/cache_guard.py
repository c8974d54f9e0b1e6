"""Ties each cached numba kernel to the sources of its module and of every module it imports.

numba keys a cached kernel on the content of its own source file only, while the cached machine
code of a kernel holds the code of every kernel it inlines or calls, and every global constant
it reads, from any module, as they were when it was compiled. After an edit of ``terrain.py``
the cached kernels of ``terrain_loops.py`` would go on running the old contact forces without
a word (a checkout of another version does the same).

So every cached function of this package gets the *closure digest* of its module in its
cache stamp: one SHA-256 digest of the module's source and of the source of every module of the
package it imports, transitively (:func:`closure`, :func:`closure_digest`). numba stores the
stamp in each function's cache index and ignores an index whose stamp differs from the one the
running sources give: a kernel compiles again exactly when its module, or a module it depends
on, changed, and kernels of modules that depend on neither load from the cache as before. The
stamp is taken when the function is decorated, from the sources the process has just imported,
so a long-running process that compiles a kernel after its sources were edited saves it under
the stamp of the sources it ran, never under the new one.

The dependency graph is derived from the import statements of the modules (no list to keep):
``from .x import f``, ``from . import x``, ``import tensegrity_gym.x`` and their absolute and
relative forms, found by a regular expression (a test checks it finds every import Python's
parser finds, in every module of the package). The modules that define numba functions need
no list either: every cached function of the package passes through :class:`ClosureLocator`
(:func:`install`, run at ``tensegrity_gym``'s import before any module that compiles). Python
modules in the closure count too: a constant a kernel reads may come from one.

The cache directories stay numba's own choice for each file (beside the module in
``__pycache__``, or under ``NUMBA_CACHE_DIR`` or the user's cache directory where that one is
not writable); a stale index is overwritten by the next compile of its function.
"""
from __future__ import annotations

import functools
import hashlib
import os
import re
from pathlib import Path

__all__ = ["PACKAGE", "module_name", "imports_of", "closure", "closure_digest", "ClosureLocator", "install"]

#: the tensegrity_gym directory
PACKAGE = Path(__file__).resolve().parents[2]

# an import statement at the start of a line (a docstring line that reads like one only adds an
# edge): group 1 the dots and module of ``from M import ...``, group 2 its names (parenthesised
# over several lines, or up to the end of the line), group 3 the modules of ``import a.b, c``
_LINE = r"[^\n\\]*(?:\\\n[^\n\\]*)*"        # to the end of the line, over backslash continuations
_IMPORT = re.compile(rf"^[ \t]*(?:from[ \t]+(\.*[\w.]*)[ \t]+import[ \t]+(\([^)]*\)|{_LINE})|import[ \t]+({_LINE}))",
                     re.M)
_NAME = re.compile(r"[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*")


def module_name(path, package: Path = PACKAGE) -> str | None:
    """The dotted module name of the file ``path`` inside ``package`` (``<package>.x.y``), None
    for a file outside it."""
    try:
        rel = Path(path).resolve().relative_to(package)
    except ValueError:
        return None
    parts = (package.name,) + rel.with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@functools.lru_cache(maxsize=None)
def _module_file(name: str, package: Path) -> Path | None:
    """The source file of the dotted module ``name`` inside ``package`` (a resolved directory),
    None if it has none."""
    parts = name.split(".")
    if parts[0] != package.name:
        return None
    folder = package.joinpath(*parts[1:-1])
    if len(parts) == 1:
        return package / "__init__.py" if "__init__.py" in _entries(package) else None
    if parts[-1] + ".py" in _entries(folder):
        return folder / (parts[-1] + ".py")
    if "__init__.py" in _entries(folder / parts[-1]):
        return folder / parts[-1] / "__init__.py"
    return None


@functools.lru_cache(maxsize=None)
def _entries(folder: Path) -> frozenset:
    try:
        return frozenset(os.listdir(folder))
    except OSError:
        return frozenset()


def imports_of(path, text: str, package: Path = PACKAGE) -> set:
    """The modules of ``package`` (their files, resolved) that the source ``text`` of the module
    at ``path`` imports: for ``from M import n``, the submodule ``M.n`` where there is one, else
    ``M``; for ``import M``, ``M``; relative imports resolved against ``path``'s package."""
    name = module_name(path, package)
    if name is None:
        return set()
    here = name.split(".") if Path(path).name == "__init__.py" else name.split(".")[:-1]
    out = set()

    def add(mod: str) -> bool:
        f = _module_file(mod, package)
        if f is not None:
            out.add(f)
        return f is not None

    for m in _IMPORT.finditer(text):
        src, names, plain = m.groups()
        if plain is not None:
            for mod in _NAME.findall(plain.split("#", 1)[0]):
                add(mod)
            continue
        dots = len(src) - len(src.lstrip("."))
        if dots:
            base = here[:len(here) - dots + 1] if dots > 1 else here
            mod = ".".join(base + ([src[dots:]] if src[dots:] else []))
        else:
            mod = src
        # ``from P import n``: the submodule P.n where there is one, else P's own namespace
        wanted = [n for n in _NAME.findall(re.sub(r"#[^\n]*", "", names)) if n != "as"]
        if not all([add(f"{mod}.{n}") for n in wanted]) or not wanted:
            add(mod)
    return out


@functools.lru_cache(maxsize=None)
def _scan(path: str, mtime_ns: int, size: int, package: Path):
    """(SHA-256 digest, imported files) of one source file; memoised on its stamp, as numba does."""
    data = Path(path).read_bytes()
    return hashlib.sha256(data).digest(), frozenset(imports_of(path, data.decode("utf-8", "replace"), package))


def _scan_file(f: Path, package: Path):
    st = os.stat(f)
    return _scan(str(f), st.st_mtime_ns, st.st_size, package)


def closure(path, package: Path = PACKAGE) -> list:
    """The source files (resolved, sorted) of the module at ``path`` and of every module of
    ``package`` it imports, transitively."""
    seen, todo = set(), [Path(path).resolve()]
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        seen.add(f)
        todo.extend(_scan_file(f, package)[1] - seen)
    return sorted(seen)


def closure_digest(path, package: Path = PACKAGE) -> str:
    """SHA-256 (hex) of the package-relative names and the contents of :func:`closure` (``path``)."""
    h = hashlib.sha256()
    for f in closure(path, package):
        h.update(f.relative_to(package).as_posix().encode() + b"\0")
        h.update(_scan_file(f, package)[0])
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def _module_digest(py_file: str, package: Path) -> str:
    """:func:`closure_digest` once per module and process (its functions are decorated at its
    import, from the sources just imported; a digest kept from then can only be older than the
    files, which makes a later process compile again, never load stale code)."""
    return closure_digest(py_file, package)


def _caching():
    from numba.core import caching
    return caching


def _impl_class():
    c = _caching()
    return getattr(c, "CacheImpl", None) or getattr(c, "_CacheImpl")      # its name varies between versions


def _other_locators() -> list:
    """The locator classes numba would use without this module's, in its order of preference."""
    from numba.core import config
    c = _caching()
    if getattr(config, "CACHE_LOCATOR_CLASSES", None):
        import importlib
        out = []
        for item in config.CACHE_LOCATOR_CLASSES.split(","):
            item = item.strip()
            if "." in item:
                mod, cls = item.rsplit(".", 1)
                found = getattr(importlib.import_module(mod), cls)
            else:
                found = getattr(c, item)
            if not _ours(found):
                out.append(found)
        return out
    return [cls for cls in _impl_class()._locator_classes if not _ours(cls)]


def _ours(cls) -> bool:
    return isinstance(cls, type) and issubclass(cls, ClosureLocator)


class ClosureLocator:
    """A numba cache locator for the functions of the files under :attr:`package`: numba's own
    locator for the file (the same cache directory and file names), with the file's
    :func:`closure_digest` added to its source stamp. Functions of other files are left to
    numba's locators."""

    #: the package directory whose files this locator claims
    package = PACKAGE

    def __init__(self, inner, py_file):
        self._inner = inner
        self._py_file = py_file
        self._stamp = (inner.get_source_stamp(), _module_digest(str(py_file), self.package))

    @classmethod
    def from_function(cls, py_func, py_file):
        if module_name(py_file, cls.package) is None:
            return None
        for other in _other_locators():
            inner = other.from_function(py_func, py_file)
            if inner is not None:
                return cls(inner, py_file)
        return None

    def ensure_cache_path(self):
        return self._inner.ensure_cache_path()

    def get_cache_path(self):
        return self._inner.get_cache_path()

    def get_source_stamp(self):
        return self._stamp

    def get_disambiguator(self):
        return self._inner.get_disambiguator()

    def __getattr__(self, name):            # anything else numba asks of a locator: the inner one's
        return getattr(self._inner, name)


def install(locator=ClosureLocator) -> None:
    """Put ``locator`` (a :class:`ClosureLocator`) first among numba's cache locators (once);
    numba picks a function's locator when the function is decorated, so this runs before any
    module of the package that compiles is imported."""
    from numba.core import config
    classes = _impl_class()._locator_classes
    if locator not in classes:
        classes.insert(0, locator)
    own = f"{locator.__module__}.{locator.__qualname__}"
    user = getattr(config, "CACHE_LOCATOR_CLASSES", None)
    if user and own not in user:            # a user's list of locators replaces numba's: ours goes first
        config.CACHE_LOCATOR_CLASSES = f"{own},{user}"
