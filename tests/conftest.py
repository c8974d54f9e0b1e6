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
import threading  # noqa: E402
import time  # noqa: E402

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
    if getattr(config.option, "numprocesses", None) and not hasattr(config, "workerinput"):
        config.pluginmanager.register(StillRunning(config), "tensegrity_gym_still_running")


def pytest_unconfigure(config):
    if _SB3_LOGDIR is not None:
        os.environ.pop("SB3_LOGDIR", None)
        shutil.rmtree(_SB3_LOGDIR, ignore_errors=True)


class StillRunning:
    """On the pytest-xdist controller: every ``EVERY_S`` seconds, one line per test that has been
    running for longer than that, naming it and for how long (``-q`` prints a test's dot only
    when it ends, so a suite's last, longest tests would otherwise run for minutes without
    output). The workers report the start and the end of each test to the controller; the
    controller runs no test itself, so its terminal is free to write to."""

    EVERY_S = 120.0

    def __init__(self, config):
        self.config = config
        self.reporter = None
        self.started: dict[str, float] = {}
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="still-running", daemon=True)

    def pytest_sessionstart(self, session):
        self.reporter = self.config.pluginmanager.get_plugin("terminalreporter")
        self.thread.start()

    def pytest_sessionfinish(self, session):
        self.stop.set()

    def pytest_runtest_logstart(self, nodeid, location):
        with self.lock:
            self.started[nodeid] = time.monotonic()

    def pytest_runtest_logfinish(self, nodeid, location):
        with self.lock:
            self.started.pop(nodeid, None)

    def _run(self):
        while not self.stop.wait(self.EVERY_S):
            now = time.monotonic()
            with self.lock:
                long = sorted((now - t0, nodeid) for nodeid, t0 in self.started.items() if now - t0 >= self.EVERY_S)
            if long and self.reporter is not None:
                self.reporter.write_line("still running: " + "; ".join(f"{n} ({s / 60:.0f} min)" for s, n in long))
