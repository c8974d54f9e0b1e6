"""The package's module layout: every module lives in a subpackage (core, physics, backends, tasks,
envs, io, tools, integrations); the top level holds only ``__init__``, ``__main__`` and
``rewards``, nothing refers to the flat module paths the package once had, and every module of
this package that a committed model or normalisation pickle names still imports."""
from __future__ import annotations

import base64
import importlib.util
import io
import json
import pickletools
import re
import subprocess
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "tensegrity_gym"

#: the flat module paths removed in 0.2.0 (their code lives in the subpackages)
REMOVED = ("_compile_notice", "_kernels", "actuation", "baselines", "builders", "checks", "cli", "contact",
           "dynamics", "implicit", "integrators", "jacobian", "mjcf", "params", "pipeline", "rendering", "sb3",
           "sizing", "statics", "structure", "sysid", "tnsgrt", "torch_backend", "zoo")


def _git_files() -> list[str]:
    p = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip("not a git checkout")
    return [f for f in p.stdout.splitlines() if f]


def test_top_level_holds_only_init_main_and_rewards():
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert top == ["__init__.py", "__main__.py", "rewards.py"], (
        f"tensegrity_gym/ top level: {top}; a new module belongs in a subpackage (docs/architecture.md)")


def test_no_file_refers_to_a_removed_module_path():
    """Source, docs, configs and scripts name the real modules (``tensegrity_gym.core.structure``,
    not ``tensegrity_gym.structure``). The changelog, which lists the removal, and the recorded
    outputs under ``results/`` are left out."""
    names = "|".join(REMOVED)
    pattern = re.compile(rf"tensegrity_gym\.({names})\b(?!\.schema\.json)|tensegrity_gym/({names})\.py\b"
                         rf"|from tensegrity_gym import [^\n]*\b({names})\b")
    this = Path(__file__).resolve().relative_to(ROOT).as_posix()
    hits = []
    for f in _git_files():
        if f in ("CHANGELOG.md", this) or f.startswith("results/") or not f.endswith(
                (".py", ".md", ".toml", ".yml", ".yaml", ".txt", ".cfg", ".json", ".sh")):
            continue
        path = ROOT / f
        if not path.is_file():
            continue
        text = path.read_text(errors="replace")
        for m in pattern.finditer(text):
            hits.append(f"{f}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)}")
    assert not hits, "removed module paths still named:\n" + "\n".join(hits[:40])


def _pickled_modules(blob: bytes) -> set[str]:
    """The modules a pickle names (its GLOBAL / STACK_GLOBAL opcodes), read without unpickling."""
    mods, recent, memo = set(), [], {}
    strings = ("SHORT_BINUNICODE", "BINUNICODE", "BINUNICODE8", "UNICODE", "SHORT_BINSTRING", "BINSTRING")
    for op, arg, _ in pickletools.genops(io.BytesIO(blob)):
        name = op.name
        if name in ("GLOBAL", "INST"):
            mods.add(arg.split(" ")[0])
            recent.append(None)
        elif name in strings:
            recent.append(arg)
        elif name == "MEMOIZE":
            memo[len(memo)] = recent[-1] if recent else None
        elif name in ("PUT", "BINPUT", "LONG_BINPUT"):
            memo[int(arg)] = recent[-1] if recent else None
        elif name in ("GET", "BINGET", "LONG_BINGET"):
            recent.append(memo.get(int(arg)))
        elif name == "STACK_GLOBAL":
            if len(recent) >= 2 and isinstance(recent[-2], str):
                mods.add(recent[-2])
            recent.append(None)
        elif name not in ("PROTO", "FRAME", "STOP"):
            recent.append(None)
    return mods


def _committed_pickles():
    files = [f for f in _git_files() if f.startswith("results/") and f.endswith((".zip", ".pkl"))]
    for f in files:
        path = ROOT / f
        if not path.is_file():
            continue
        if f.endswith(".pkl"):
            yield f, path.read_bytes()
            continue
        with zipfile.ZipFile(path) as z:
            if "data" not in z.namelist():
                continue
            stack = [json.loads(z.read("data"))]
            while stack:                       # SB3's data: JSON with base64 pickles under ":serialized:"
                x = stack.pop()
                if isinstance(x, dict):
                    for k, v in x.items():
                        if k == ":serialized:" and isinstance(v, str):
                            yield f, base64.b64decode(v)
                        else:
                            stack.append(v)
                elif isinstance(x, list):
                    stack.extend(x)


def test_committed_pickles_name_only_importable_package_modules():
    """A committed model (SB3 zip) or normalisation (VecNormalize pickle) that named a module of
    this package that no longer exists would fail to load: every such name must import."""
    seen, missing = set(), []
    n = 0
    for f, blob in _committed_pickles():
        n += 1
        for mod in _pickled_modules(blob):
            if mod.split(".")[0] != "tensegrity_gym":
                continue
            seen.add(mod)
            if importlib.util.find_spec(mod) is None:
                missing.append(f"{f}: {mod}")
    if n == 0:
        pytest.skip("no committed models")
    assert not missing, "\n".join(missing)
