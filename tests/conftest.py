"""Shared pytest configuration. tests/ is put on sys.path so that test files can
``import reference`` (the independent node-coordinate simulation) whatever the import mode."""
import sys
from pathlib import Path

_TESTS = str(Path(__file__).resolve().parent)
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)
