"""The README's snippets and command-line block run as a newcomer would paste them.

Each ```python block runs alone in a fresh interpreter (no block may rely on an earlier one), and
the "Command line" ```bash block runs line by line, in order, in an empty folder. The set-up
commands (venv, pip, the main job, the test suite) are not run here: CI runs them.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg", "TENSEGRITY_GYM_QUIET": "1"}


def _blocks(lang: str, text: str = README) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


def _section(title: str) -> str:
    a = README.index(title)
    b = README.find("\n## ", a + len(title))
    return README[a: b if b > 0 else len(README)]


def test_readme_has_what_a_newcomer_needs():
    lines = README.count("\n")
    assert lines <= 180, f"README.md has {lines} lines: keep it short, move details to docs/"
    for title in ("## Install", "## Quick start", "## Environments", "## Command line"):
        assert title in README
    assert "../shared" not in README and "EQUATIONS.md" not in README   # nothing outside the repository
    for link in re.findall(r"\]\(([^)#]+)\)", README):
        if not link.startswith("http"):
            assert (ROOT / link).exists(), f"README links to {link}, which does not exist"


def test_environment_table_lists_every_registered_id():
    import gymnasium
    import tensegrity_gym  # noqa: F401  (registers the envs)
    table = {m for m in re.findall(r"^\| `(Tensegrity[\w-]+)` \|", _section("## Environments"), flags=re.M)}
    registered = {k for k in gymnasium.registry
                  if k.startswith("Tensegrity") and gymnasium.registry[k].entry_point.startswith("tensegrity_gym.")}
    assert table == registered, f"README's table lacks {sorted(registered - table)}, lists unknown {sorted(table - registered)}"


@pytest.mark.parametrize("i", range(len(_blocks("python"))))
def test_python_snippet_runs_alone(i, tmp_path):
    code = _blocks("python")[i]
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=ENV, capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, f"README python block {i} failed:\n{code}\n{r.stderr[-3000:]}"


def test_command_line_block_runs_in_order(tmp_path):
    (block,) = _blocks("bash", _section("## Command line"))
    cmds = [ln.split("  #")[0].strip() for ln in block.strip().splitlines() if ln.strip()]
    assert cmds and all(c.startswith("python -m tensegrity_gym ") for c in cmds)
    for c in cmds:
        argv = [sys.executable] + c.split()[1:]
        r = subprocess.run(argv, cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, f"README command failed: {c}\n{r.stderr[-3000:]}"
