"""The numba cache guard: a cached kernel is tied to the sources of its module and of every module
it imports, so an edit recompiles exactly the modules that depend on the edited one (numba itself
notices an edit of a kernel's own module only)."""
import ast
import importlib
import os
import subprocess
import sys
import textwrap
from pathlib import Path

from numba.core.dispatcher import Dispatcher

import tensegrity_gym
from tensegrity_gym.backends.numba import cache_guard as G

PACKAGE = Path(tensegrity_gym.__file__).resolve().parent
_COMPILERS = {"njit", "jit", "vectorize", "guvectorize", "cfunc", "stencil", "generated_jit"}


def _parsed_imports(path: Path, package: Path) -> set:
    """The package modules ``path`` imports, by Python's parser (the scanner's reference)."""
    name = G.module_name(path, package)
    here = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            mods = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = here[:len(here) - node.level + 1] if node.level else []
            mod = ".".join(base + ([node.module] if node.module else []))
            subs = [f"{mod}.{a.name}" for a in node.names]
            found = [G._module_file(m, package) for m in subs]
            mods = subs if all(found) else subs + [mod]
        else:
            continue
        out |= {f.resolve() for f in map(lambda m: G._module_file(m, package), mods) if f is not None}
    return out


def _compiling_modules() -> list:
    """The package's modules that call a numba compiler (``njit(...)``, ``@numba.jit``, ...)."""
    def name(e):
        return e.id if isinstance(e, ast.Name) else e.attr if isinstance(e, ast.Attribute) else None

    found = []
    for p in sorted(PACKAGE.rglob("*.py")):
        nodes = list(ast.walk(ast.parse(p.read_text())))
        exprs = [n.func for n in nodes if isinstance(n, ast.Call)]
        exprs += [d for n in nodes if isinstance(n, ast.FunctionDef) for d in n.decorator_list]
        if any(name(e) in _COMPILERS for e in exprs):
            found.append(p)
    return found


def test_the_import_scanner_finds_every_import_the_parser_finds():
    for p in sorted(PACKAGE.rglob("*.py")):
        missing = _parsed_imports(p, PACKAGE) - G.imports_of(p, p.read_text(), PACKAGE)
        assert not missing, (p, sorted(missing))


def test_every_cached_function_of_the_package_carries_its_closure_digest():
    modules = _compiling_modules()
    assert PACKAGE / "backends/numba/terrain.py" in modules and PACKAGE / "core/checks.py" in modules
    for path in modules:
        mod = importlib.import_module(G.module_name(path))
        cached = [v for v in vars(mod).values() if isinstance(v, Dispatcher) and v.py_func.__module__ == mod.__name__
                  and v._cache.__class__.__name__ != "NullCache"]
        assert cached, f"{mod.__name__}: no cached numba function found"
        for d in cached:
            loc = d._cache._impl.locator
            assert isinstance(loc, G.ClosureLocator), (mod.__name__, d.py_func.__name__)
            assert loc.get_source_stamp()[1] == G.closure_digest(path)


def _tree(root: Path, files: dict) -> Path:
    pkg = root / "pkg"
    for rel, text in files.items():
        f = pkg / rel
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(textwrap.dedent(text))
    return pkg


_FILES = {
    "__init__.py": "",
    "leaf.py": "A = 1\n",
    "mid.py": "from .leaf import A\n",
    "top.py": "from .mid import (\n    A,   # a comment\n)\n",
    "other.py": "B = 2\n",
    "sub/__init__.py": "",
    "sub/deep.py": "from .. import leaf\nimport pkg.other as o\n",
    "lazy.py": "def f():\n    from pkg.top import A\n    return A\n",
}


def _digests(pkg: Path) -> dict:
    return {f.relative_to(pkg).as_posix(): G.closure_digest(f, pkg) for f in sorted(pkg.rglob("*.py"))}


def test_an_edit_changes_the_digests_of_exactly_the_modules_that_import_it(tmp_path):
    pkg = _tree(tmp_path, _FILES)
    assert [f.relative_to(pkg).as_posix() for f in G.closure(pkg / "top.py", pkg)] == ["leaf.py", "mid.py", "top.py"]
    assert [f.relative_to(pkg).as_posix() for f in G.closure(pkg / "sub/deep.py", pkg)] == [
        "leaf.py", "other.py", "sub/deep.py"]
    before = _digests(pkg)
    (pkg / "leaf.py").write_text("A = 10\n")         # another length: a new stamp even within one clock tick
    after = _digests(pkg)
    assert {k for k in before if before[k] != after[k]} == {"leaf.py", "mid.py", "top.py", "sub/deep.py", "lazy.py"}
    (pkg / "other.py").write_text("B = 20\n")
    again = _digests(pkg)
    assert {k for k in after if after[k] != again[k]} == {"other.py", "sub/deep.py"}
    (pkg / "top.py").write_text("from .mid import A\nC = 3\n")
    last = _digests(pkg)
    assert {k for k in again if again[k] != last[k]} == {"top.py", "lazy.py"}


_DRIVER = """
import importlib.util, sys
from pathlib import Path
spec = importlib.util.spec_from_file_location("cache_guard", sys.argv[2])     # the guard alone, not the package
G = importlib.util.module_from_spec(spec)
spec.loader.exec_module(G)
class Locator(G.ClosureLocator):
    package = Path(sys.argv[1]).resolve()
G.install(Locator)
sys.path.insert(0, str(Locator.package.parent))
from pkg import top, other
print(top.g(), other.h(), sum(top.g.stats.cache_hits.values()), sum(other.h.stats.cache_hits.values()))
"""


def test_an_edited_dependency_recompiles_its_dependents_and_only_them(tmp_path):
    pkg = _tree(tmp_path, {"__init__.py": "",
                           "leaf.py": "from numba import njit\n@njit(cache=True)\ndef f():\n    return 1\n",
                           "top.py": "from numba import njit\nfrom .leaf import f\n@njit(cache=True)\n"
                                     "def g():\n    return f() + 10\n",
                           "other.py": "from numba import njit\n@njit(cache=True)\ndef h():\n    return 5\n"})
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))

    def run():
        r = subprocess.run([sys.executable, "-c", _DRIVER, str(pkg), G.__file__], capture_output=True, text=True, env=env,
                           cwd=tmp_path)
        assert r.returncode == 0, r.stderr[-2000:]
        g, h, g_hits, h_hits = map(int, r.stdout.split())
        return g, h, g_hits > 0, h_hits > 0

    assert run() == (11, 5, False, False)          # cold
    assert run() == (11, 5, True, True)            # all from the cache
    (pkg / "leaf.py").write_text("from numba import njit\n@njit(cache=True)\ndef f():\n    return 2\n")
    assert run() == (12, 5, False, True)           # top.g inlined the old f: compiled again; other.h loaded
    assert run() == (12, 5, True, True)


def test_an_unknown_file_is_left_to_numba(tmp_path):
    assert G.module_name(tmp_path / "x.py") is None
    assert G.ClosureLocator.from_function(None, str(tmp_path / "x.py")) is None


def test_a_users_list_of_locators_keeps_the_guard_first(monkeypatch):
    from numba.core import caching, config
    monkeypatch.setattr(config, "CACHE_LOCATOR_CLASSES", "InTreeCacheLocator", raising=False)
    G.install()
    assert config.CACHE_LOCATOR_CLASSES == "tensegrity_gym.backends.numba.cache_guard.ClosureLocator,InTreeCacheLocator"
    assert G._other_locators() == [caching.InTreeCacheLocator]
    G.install()                             # once
    assert config.CACHE_LOCATOR_CLASSES.count("ClosureLocator") == 1
