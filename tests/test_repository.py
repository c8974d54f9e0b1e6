"""The repository itself: no machine paths, issue numbers or work-period narration in its tracked
text files, and no import cycle inside the package."""
import ast
import graphlib
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "tensegrity_gym"

EXEMPT = {"tests/test_repository.py"}     # its patterns and the samples they must catch

FORBIDDEN = {
    # an absolute path on a developer's or a build machine (``/dev/null``, ``/proc``, ``/usr/bin``
    # and the like are legitimate)
    "machine path": re.compile(r"(?<![\w.~$-])/(?:work|root|home|tmp|mnt|opt|Users)/"),
    "issue number": re.compile(r"(?i)\bissues? ?#?\d+\b|\bissue-\d+|(?:^|[\s(\[])#\d{1,4}\b(?![\w-])"),
    "work-period narration": re.compile(r"(?i)\bsessions? \d+\b"),
}


def _tracked_text_files():
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    for name in out.decode().split("\0"):
        path = ROOT / name
        if not name or name in EXEMPT or not path.is_file():
            continue
        data = path.read_bytes()
        if b"\0" in data:
            continue
        try:
            yield name, data.decode("utf-8")
        except UnicodeDecodeError:
            continue


def test_no_machine_paths_issue_numbers_or_history_in_tracked_text():
    found = []
    for name, text in _tracked_text_files():
        for lineno, line in enumerate(text.splitlines(), 1):
            for what, pattern in FORBIDDEN.items():
                m = pattern.search(line)
                if m:
                    found.append(f"{name}:{lineno}: {what}: {m.group(0).strip()!r} in {line.strip()[:120]!r}")
    assert not found, f"{len(found)} line(s):\n" + "\n".join(found[:50])


@pytest.mark.parametrize("line, what", [
    ("see issue 12", "issue number"), ("fixed in (#34)", "issue number"), ("Issue #7: crash", "issue number"),
    # the two samples below are joined at run time, so that this file's own text names no machine path or period
    ("cwd=/" + "work/main", "machine path"), ("--out /tmp/x", "machine path"), ("in session " + "21", "work-period narration"),
])
def test_the_scan_catches_each_kind(line, what):
    assert FORBIDDEN[what].search(line)


@pytest.mark.parametrize("line", [
    "PATH=/usr/bin:/bin", "open('/dev/null')", "/proc/cpuinfo", "color '#1f77b4'", "results/tmp/",
    "$PWD/.site", "a compile session", "1. first item",
])
def test_the_scan_passes_legitimate_text(line):
    assert not any(p.search(line) for p in FORBIDDEN.values())


RUN_BY_PATH = re.compile(r"\bpython3?\s+scripts/")
SCRIPT_REFERENCE = re.compile(r"-m scripts\.(\w+)\.(\w+)|\bscripts/(\w+)/(\w+)\.py\b|\bscripts/(\w+)\.py\b")


def test_every_script_named_in_the_repository_exists():
    """``python -m scripts.<group>.<name>`` and ``scripts/<group>/<name>.py`` name a file that exists
    (the scripts moved into groups; a stale path in a doc or a recorded command fails here)."""
    missing = set()
    for name, text in _tracked_text_files():
        if RUN_BY_PATH.search(text):     # the scripts import scripts._bench: they run as modules
            missing.add(f"{name}: runs a script by its path, not as python -m scripts.<group>.<name>")
        for m in SCRIPT_REFERENCE.finditer(text):
            group, script = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
            path = f"scripts/{group}/{script}.py" if group else f"scripts/{m.group(5)}.py"
            if not (ROOT / path).is_file():
                missing.add(f"{name}: {m.group(0)}")
    assert not missing, "\n".join(sorted(missing))


def _module_name(path):
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_no_import_cycle_in_the_package():
    """Module- and function-level imports between the package's modules form no cycle (a package's
    ``__init__`` importing its own submodules, and a submodule importing its package, excepted)."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}

    def resolve(name):
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name

    graph = {}
    for name, path in modules.items():
        is_pkg = path.name == "__init__.py"
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = name.split(".") if is_pkg else name.split(".")[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                targets = [f"{target}.{a.name}" if f"{target}.{a.name}" in modules else target for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            for t in map(resolve, targets):
                if not t or t == name:
                    continue
                if is_pkg and t.startswith(name + "."):
                    continue
                if modules[t].name == "__init__.py" and name.startswith(t + "."):
                    continue
                deps.add(t)
        graph[name] = deps
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as err:
        pytest.fail(f"import cycle: {' -> '.join(err.args[1])}")
