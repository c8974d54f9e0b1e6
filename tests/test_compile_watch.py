"""The compile watcher: a start line, heartbeats naming the kernel while numba compiles, a done line;
nothing for other packages' functions and nothing on a cache hit."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

_SCRIPT = textwrap.dedent("""
    import time
    import numba
    from tensegrity_gym.backends.numba import watch
    watch.HEARTBEAT_S, watch.IDLE_S, watch.POLL_S = 0.05, 0.5, 0.01
    watch.install()

    def slow(x):
        s = 0.0
        for i in range(x):
            s += i ** 0.5
        return s
    slow.__module__ = MODULE
    f = numba.njit(slow)
    t0 = time.time()
    f(10)                       # compiles (no cache, ~0.2 s): a heartbeat at 0.05 s (the watcher looks every 0.01 s)
    f(11)                       # same signature: no compile
    time.sleep(1.0)             # the watcher's idle time passes: the done line
""")


def _run(module: str) -> str:
    code = _SCRIPT.replace("MODULE", repr(module))
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300,
                       env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr
    return r.stderr


def test_heartbeat_and_done_line_for_package_kernels():
    err = _run("tensegrity_gym.fake_kernels")
    lines = [ln for ln in err.splitlines() if ln.startswith("tensegrity_gym:")]
    assert lines[0].startswith("tensegrity_gym: compiling the numba kernels")
    assert any("still compiling (fake_kernels.slow)" in ln for ln in lines), err
    assert lines[-1].startswith("tensegrity_gym: compiled 1 numba functions in"), err


def test_other_packages_compiles_are_not_reported():
    assert "tensegrity_gym:" not in _run("someone_elses_module")
