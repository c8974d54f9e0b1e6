"""The module map of docs/architecture.md: one line per module of the package (its docstring's first
sentence), leaving out the old flat import paths that only re-export.

    python -m scripts.tools.module_map            # print the map
    python -m scripts.tools.module_map --write    # replace the map in docs/architecture.md
    python -m scripts.tools.module_map --check    # exit 1 (naming the lines) if the doc's map is not current
"""
from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "tensegrity_gym"
DOC = ROOT / "docs" / "architecture.md"
WIDTH = 107
_SHIM = re.compile(r"^(Re-export|Old import path|``tensegrity_gym\.[\w.]+`` is :mod:)")


def module_lines() -> list[str]:
    """``path  first sentence`` of every module that is not a re-export shim, sorted by path."""
    out = []
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG).as_posix()
        if "__pycache__" in rel:
            continue
        doc = ast.get_docstring(ast.parse(path.read_text())) or ""
        first = " ".join(doc.split("\n\n")[0].split())
        if not first or _SHIM.match(first):
            continue
        m = re.search(r"(?<!e\.g)(?<!i\.e)\.(\s+[A-Z`(:]|$)", first)
        sentence = first[:m.start() + 1] if m else first
        if len(sentence) > WIDTH:
            sentence = sentence[:WIDTH].rstrip() + "..."
        out.append(f"{rel:<34}{sentence}")
    return out


def _doc_block(text: str) -> tuple[int, int]:
    """(start, end) character offsets of the map's code block in the architecture doc."""
    head = text.index("## Module map")
    start = text.index("```\n", head) + 4
    return start, text.index("```", start)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--write", action="store_true", help="replace the map in docs/architecture.md")
    g.add_argument("--check", action="store_true", help="exit 1 if docs/architecture.md's map is not current")
    args = ap.parse_args(argv)
    lines = module_lines()
    block = "\n".join(lines) + "\n"
    if not (args.write or args.check):
        sys.stdout.write(block)
        return 0
    text = DOC.read_text()
    start, end = _doc_block(text)
    if args.write:
        DOC.write_text(text[:start] + block + text[end:])
        return 0
    have = text[start:end].splitlines()
    missing = [x for x in lines if x not in have]
    stale = [x for x in have if x not in lines]
    for x in missing:
        print(f"docs/architecture.md module map lacks: {x}")
    for x in stale:
        print(f"docs/architecture.md module map has a stale line: {x}")
    if missing or stale:
        print("run: python -m scripts.tools.module_map --write")
    return 1 if (missing or stale) else 0


if __name__ == "__main__":
    raise SystemExit(main())
