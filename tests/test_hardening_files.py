"""Files a hostile user names: outputs that are devices, FIFOs, links or folders that cannot be
made; input files that are FIFOs, devices or empty; temporary files left by a killed run; and the
memory of export's terrain path. Each is one line and an exit code, before the work starts.

A case that hung or read without end before it was fixed runs in a subprocess with a time and
memory limit, so that a regression fails instead of stalling the suite."""
from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from tensegrity_gym.io import claim
from tensegrity_gym.tools.cli import main

ROOT = Path(__file__).resolve().parent.parent
SIM = ["simulate", "prism3", "--duration", "0.002", "--dt", "1e-3", "--no-progress"]


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert "Traceback" not in err and lines and lines[-1].startswith("error: "), err
    assert sum(x.startswith("error: ") for x in lines) == 1, err
    return lines[-1]


def _limit_memory():       # a subprocess that reads /dev/zero fails with MemoryError, not the machine
    import resource
    resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30))


def _run(code: str, cwd, timeout: float = 120) -> subprocess.CompletedProcess:
    """``code`` run by a fresh Python in ``cwd``; a run that blocks (a FIFO opened) times out."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    try:
        return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd, env=env, capture_output=True,
                              text=True, timeout=timeout, preexec_fn=_limit_memory)
    except subprocess.TimeoutExpired:
        pytest.fail(f"blocked for {timeout} s (an input FIFO was opened): {code}")


def _cli(args, cwd) -> tuple[int, str]:
    """``python -m tensegrity_gym ARGS`` in a subprocess: (exit code, the last stderr line)."""
    r = _run(f"import sys\nfrom tensegrity_gym.tools.cli import main\nsys.exit(main({list(map(str, args))!r}))", cwd)
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert "Traceback" not in r.stderr and lines and lines[-1].startswith("error: "), r.stderr
    return r.returncode, lines[-1]


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


# ---------------------------------------------------------------- outputs that are not files
def test_force_never_replaces_a_character_device(tmp_path, capsys):
    dev = tmp_path / "null"
    try:
        os.mknod(dev, stat.S_IFCHR | 0o600, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("creating a device node needs root")
    assert main(SIM + ["--out", str(dev), "--force"]) == 4
    assert f"--out '{dev}' is a character device, not a regular file" in _one_error_line(capsys)
    assert stat.S_ISCHR(os.lstat(dev).st_mode)


def test_force_never_replaces_a_fifo_or_a_link(tmp_path, capsys):
    fifo = tmp_path / "pipe.npz"
    os.mkfifo(fifo)
    assert main(SIM + ["--out", str(fifo), "--force"]) == 4
    assert "is a FIFO, not a regular file" in _one_error_line(capsys)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    # the writer itself refuses it too (an output made a FIFO after its claim)
    from tensegrity_gym.io.atomic import OutputError, write_atomic
    with pytest.raises(OutputError, match="is a FIFO"):
        write_atomic(fifo, lambda f: f.write(b"x"))
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and [p.name for p in tmp_path.iterdir()] == ["pipe.npz"]
    target = tmp_path / "real.npz"
    target.write_bytes(b"keep")
    link = tmp_path / "link.npz"
    link.symlink_to(target)
    assert main(SIM + ["--out", str(link), "--force"]) == 4
    assert "is a symbolic link (to " in _one_error_line(capsys)
    assert link.is_symlink() and target.read_bytes() == b"keep"


def test_dangling_symlink_out_is_refused_before_the_run(tmp_path, capsys):
    link = tmp_path / "traj.npz"
    link.symlink_to(tmp_path / "nowhere" / "t.npz")
    # a structure that does not exist: exit 4 naming the link shows that the output was checked first
    assert main(["simulate", str(tmp_path / "missing.json"), "--out", str(link)]) == 4
    line = _one_error_line(capsys)
    assert f"--out '{link}' is a symbolic link" in line and "which does not exist" in line, line
    assert "someone else" not in line and link.is_symlink()


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc")
@pytest.mark.parametrize("args, flag", [
    (SIM + ["--out", "/proc/nope/x.npz"], "--out '/proc/nope/x.npz'"),
    (SIM + ["--out", "/sys/nope/x.npz"], "--out '/sys/nope/x.npz'"),
    (["demo", "--out", "/proc/nope/demo", "--duration", "0.01"], "--out '/proc/nope/demo/"),
    # the recording does not exist: the plot is refused before anything is read or fitted
    (["identify", "prism3", "no_such_recording.npz", "--fit", "stiffness", "--out", "{tmp}/fit.json",
      "--plot", "/proc/nope/x.png"], "--plot '/proc/nope/x.png'"),
])
def test_outputs_under_proc_and_sys_are_one_line(tmp_path, capsys, args, flag):
    if "/sys/" in " ".join(args) and not os.path.isdir("/sys"):
        pytest.skip("needs /sys")
    assert main([a.replace("{tmp}", str(tmp_path)) for a in args]) == 4
    line = _one_error_line(capsys)
    assert flag in line and "cannot create the folder" in line, line
    assert not list(tmp_path.iterdir())      # nothing claimed or written


# ---------------------------------------------------------------- temporary files of a killed run
def test_claim_after_a_kill_removes_the_dead_runs_temporary_files(tmp_path, capsys):
    out = tmp_path / "v.npz"
    dead = _dead_pid()
    stale = [tmp_path / f".v.npz.tmp-{dead}-2.npz", tmp_path / f"..v.npz.lock.tmp-{dead}-0.lock"]
    live = tmp_path / ".v.npz.tmp-1-3.npz"          # pid 1 runs: its file is kept
    other = tmp_path / f".w.npz.tmp-{dead}-4.npz"    # not this output's: kept
    for p in stale + [live, other]:
        p.write_bytes(b"partial")
    (tmp_path / ".v.npz.lock").write_text(json.dumps({**claim.holder_record(), "pid": dead, "process_start": None,
                                                      "host": socket.gethostname()}))
    assert main(SIM + ["--out", str(out)]) == 4          # the stale lock: refused until --steal-lock
    assert "--steal-lock" in _one_error_line(capsys)
    assert main(SIM + ["--out", str(out), "--steal-lock"]) == 0
    assert not any(p.exists() for p in stale)
    assert live.exists() and other.exists() and out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, other.name, "v.npz"])


# ---------------------------------------------------------------- inputs: FIFOs, devices, empty files
def test_terrain_fifo_device_and_link_to_a_device_are_refused_unread(tmp_path):
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    link = tmp_path / "zero.json"
    link.symlink_to("/dev/zero")
    out = tmp_path / "o.npz"
    for path, kind in ((fifo, "a FIFO"), ("/dev/zero", "a character device"), (link, "a character device")):
        code, line = _cli(SIM + ["--terrain", path, "--out", out], tmp_path)
        assert code == 3 and f"--terrain '{path}'" in line and f"is {kind}, not a regular file" in line, line
    hf = tmp_path / "hf.json"
    hf.write_text(json.dumps({"heightfield": {"file": "fifo.json", "cell": 0.1}}))
    code, line = _cli(SIM + ["--terrain", hf, "--out", out], tmp_path)
    assert code == 3 and "heightfield.file" in line and "is a FIFO" in line, line
    assert not out.exists()


def test_env_terrain_fifo_is_refused_unread(tmp_path):
    os.mkfifo(tmp_path / "fifo.json")
    r = _run("""
        from tensegrity_gym.tasks.terrain import resolve_terrain
        try:
            resolve_terrain("fifo.json", {})
        except ValueError as e:
            print("refused:", e)
        """, tmp_path)
    assert r.returncode == 0 and "refused: terrain file: fifo.json is a FIFO, not a regular file" in r.stdout, r


def test_identify_recording_and_schedule_fifos_are_refused_unread(tmp_path):
    os.mkfifo(tmp_path / "rec.npz")
    os.mkfifo(tmp_path / "cmd.csv")
    code, line = _cli(["identify", "prism3", "rec.npz", "--fit", "stiffness", "--out", "fit.json"], tmp_path)
    assert code == 3 and "trajectory 'rec.npz'" in line and "is a FIFO" in line, line
    code, line = _cli(SIM + ["--rest-length", "cmd.csv", "--out", "o.npz"], tmp_path)
    assert code == 3 and "--rest-length 'cmd.csv'" in line and "is a FIFO" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cmd.csv", "rec.npz"]


def test_empty_heightfield_npy_is_one_line(tmp_path, capsys):
    (tmp_path / "h.npy").write_bytes(b"")
    terrain = tmp_path / "hf.json"
    terrain.write_text(json.dumps({"heightfield": {"file": "h.npy", "cell": 0.1}}))
    assert main(SIM + ["--terrain", str(terrain), "--out", str(tmp_path / "o.npz")]) == 3
    line = _one_error_line(capsys)
    assert "heightfield.file" in line and "h.npy: not a NumPy .npy array" in line and "empty" in line, line


# ---------------------------------------------------------------- memory of export --terrain
def test_nearest_terrain_part_needs_memory_of_the_points_only():
    from tensegrity_gym.core.terrain import Box, Terrain
    rng = np.random.default_rng(0)
    boxes = [Box(center=(float(x), float(y), 0.01), size=(0.02, 0.02, 0.02))
             for x, y in rng.uniform(-5, 5, (2000, 2))]
    t = Terrain(boxes=boxes)
    pts = rng.uniform(-5, 5, (1000, 3))
    tracemalloc.start()
    try:
        d, n = t.closest(pts)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20, f"{peak / 2**20:.0f} MiB for 2001 parts x 1000 points"   # stacked: 128 MiB
    D, N = t.closest(pts, per_part=True)        # the same nearest part as argmin over every part
    i = np.argmin(D, axis=0)
    assert np.array_equal(d, D[i, np.arange(len(pts))]) and np.array_equal(n, N[i, np.arange(len(pts))])


def test_export_terrain_applies_max_memory_before_claiming(tmp_path, capsys):
    terrain = tmp_path / "hf.json"
    terrain.write_text(json.dumps({"heightfield": {"heights": np.zeros((200, 200)).tolist(), "cell": 0.05,
                                                   "origin": [-5, -5]}}))
    out = tmp_path / "p.xml"
    args = ["export", "prism3", "--format", "mjcf", "--terrain", str(terrain), "--out", str(out)]
    assert main(args + ["--max-memory", "0.001"]) == 5
    line = _one_error_line(capsys)
    assert f"--terrain '{terrain}'" in line and "--max-memory" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hf.json"]     # no output, no lock
