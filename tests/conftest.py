"""Shared pytest configuration. tests/ is put on sys.path so that test files can
``import reference`` (the independent node-coordinate simulation) whatever the import mode, and
the repository root so that they can import the scripts as ``scripts.<group>.<name>`` (as
``python -m scripts.<group>.<name>`` run from the root does)."""
import sys
from pathlib import Path

_TESTS = str(Path(__file__).resolve().parent)
_ROOT = str(Path(__file__).resolve().parents[1])
for _p in (_ROOT, _TESTS):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import os  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402

_SB3_LOGDIR = None


def pytest_configure(config):
    """SB3 models made without a log folder write an (empty) ``SB3-<date>`` folder into the
    system's temporary directory on every ``learn()``: point them (and the subprocesses, whose
    environments the test modules copy at import) at one folder removed at the end."""
    global _SB3_LOGDIR
    # numba's compile progress (stderr, from a background thread, only when a kernel really
    # compiles: a cold cache in CI) would interleave with the one-line errors the CLI tests read;
    # tests/test_compile_watch.py runs its processes without this
    os.environ.setdefault("TENSEGRITY_GYM_QUIET", "1")
    if "SB3_LOGDIR" not in os.environ:
        _SB3_LOGDIR = tempfile.mkdtemp(prefix="tensegrity_gym_tests_sb3_")
        os.environ["SB3_LOGDIR"] = _SB3_LOGDIR


def pytest_unconfigure(config):
    if _SB3_LOGDIR is not None:
        os.environ.pop("SB3_LOGDIR", None)
        shutil.rmtree(_SB3_LOGDIR, ignore_errors=True)
