"""Shared pytest configuration. tests/ is put on sys.path so that test files can
``import reference`` (the independent node-coordinate simulation) whatever the import mode."""
import sys
from pathlib import Path

_TESTS = str(Path(__file__).resolve().parent)
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)

import os  # noqa: E402

import pytest  # noqa: E402


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs_in_tmp(tmp_path_factory):
    """SB3 models made without a log folder write an (empty) ``SB3-<date>`` folder into the
    system's temporary directory on every ``learn()``; keep those inside pytest's own temporary
    directory (subprocesses inherit the variable)."""
    if "SB3_LOGDIR" not in os.environ:
        os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3_logs"))
        yield
        os.environ.pop("SB3_LOGDIR", None)
    else:
        yield
