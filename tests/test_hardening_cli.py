"""Command line hardening: every case ends in a documented exit code and,
when it fails, exactly one ``error: ...`` line on stderr (warnings, if any, one line each before
it), never a traceback.

CASES lists the cases run in-process through ``cli.main``; a few need a real process (module
entry point, ``| head``, SIGTERM, umask) and run below them; a hypothesis test throws random
argument lists at the parser."""
from __future__ import annotations

import json
import os
import re
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import tensegrity_gym as tg
from tensegrity_gym.tools import cli
from tensegrity_gym.io import atomic
from tensegrity_gym.tools.cli import main

ROOT = Path(__file__).resolve().parents[1]
BASE = json.loads(json.dumps(tg.prism(3).to_dict()))


def _files(tmp: Path) -> None:
    """Files the cases refer to as {tmp}/NAME."""
    (tmp / "existing.npz").write_bytes(b"keep me")
    (tmp / "a_dir").mkdir()
    (tmp / "plain_file").write_text("x")
    (tmp / "bad.json").write_text('{"nodes": [[0, 0, 0], }')
    (tmp / "utf8.json").write_bytes(b'{"name": "\xff"}')
    (tmp / "stiff_str.json").write_text(json.dumps(dict(BASE, stiffness="1000")))
    (tmp / "ragged.json").write_text(json.dumps(dict(BASE, nodes=BASE["nodes"][:5] + [[0, 1]])))
    (tmp / "nc_list.json").write_text(json.dumps(dict(BASE, node_constraints=[[0, 0, 1]])))
    (tmp / "mp5.json").write_text(json.dumps(dict(BASE, mass_points=5)))
    (tmp / "bigint.json").write_text(json.dumps(BASE).replace('"nodes": [[', '"nodes": [[' + "9" * 400 + ", ", 1)
                                     .replace("9" * 400 + ", ", "9" * 400 + ".0, 0, 0], [", 1))
    (tmp / "light.json").write_text(json.dumps(dict(BASE, bar_mass=1e-300)))
    rod = tg.Structure([[0, 0, 0], [1, 0, 0]], [[0, 1]], np.zeros((0, 2), int), gravity=(0, 0, -9.81), name="lone_rod")
    tg.save_json(rod, tmp / "no_strings.json")
    s = tg.prism(3)
    tg.save_json(s.replace(velocities=np.cross([0, 0, 2.0], s.nodes - s.nodes.mean(0))), tmp / "spin.json")
    (tmp / "demo_exists").mkdir()
    (tmp / "demo_exists" / "demo_summary.json").write_text("{}")
    np.save(tmp / "one_array.npy", np.zeros((3, 10)))
    (tmp / "text.npz").write_text("t,rest_length\n")


S = ["simulate", "prism3", "--duration", "0.01", "--no-progress"]
# (id, argv with {tmp}, exit code, regex that the LAST stderr line must match; stdout regex for code 0)
CASES = [
    ("ok-info", ["info", "prism3"], 0, r"nodes/bars/strings 6 / 3 / 9"),
    ("ok-info-json", ["info", "constrained_prism", "--json"], 0, r'"constrained_nodes"'),
    ("ok-info-no-strings", ["info", "{tmp}/no_strings.json"], 0, r"stiffness        no strings"),
    ("ok-info-no-stable-step", ["info", "tower3", "--no-stable-step"], 0, r"stable step      not estimated"),
    ("ok-simulate", S + ["--out", "{tmp}/new.npz"], 0, r"prism3: 10 steps of 0.001 s with rk4"),
    ("ok-simulate-force", S + ["--out", "{tmp}/existing.npz", "--force"], 0, r"11 records"),
    ("ok-simulate-new-folder", S + ["--out", "{tmp}/sub/dir/t.npz"], 0, r"11 records"),
    ("ok-no-strings-simulate", ["simulate", "{tmp}/no_strings.json", "--duration", "0.01", "--out", "{tmp}/r.npz"], 0,
     r"lone_rod: 10 steps"),
    # bad arguments: exit 2
    ("no-command", [], 2, r"^error: python -m tensegrity_gym: the following arguments are required: command \(see --help\)$"),
    ("unknown-command", ["explode"], 2, r"argument command: invalid choice: 'explode'"),
    ("unknown-option", ["info", "prism3", "--colour"], 2, r"unrecognized arguments: --colour"),
    ("dt-negative", ["simulate", "prism3", "--dt", "-1"], 2, r"argument --dt: must be positive and finite, got '-1'"),
    ("dt-nan", ["simulate", "prism3", "--dt", "nan"], 2, r"argument --dt: must be positive and finite, got 'nan'"),
    ("dt-text", ["simulate", "prism3", "--dt", "fast"], 2, r"argument --dt: expected a number, got 'fast'"),
    ("duration-zero", ["simulate", "prism3", "--duration", "0"], 2, r"argument --duration: must be positive"),
    ("duration-inf", ["simulate", "prism3", "--duration", "inf"], 2, r"argument --duration: must be positive and finite, got 'inf'"),
    ("record-every-zero", ["simulate", "prism3", "--record-every", "0"], 2, r"argument --record-every: must be positive"),
    ("record-every-float", ["simulate", "prism3", "--record-every", "1.5"], 2, r"argument --record-every: expected a number, got '1.5'"),
    ("integrator-unknown", ["simulate", "prism3", "--integrator", "euler"], 2, r"argument --integrator: invalid choice: 'euler'"),
    ("backend-unknown", ["simulate", "prism3", "--backend", "gpu"], 2, r"argument --backend: invalid choice: 'gpu'"),
    ("missing-structure", ["simulate"], 2, r"the following arguments are required: structure"),
    ("shorter-than-dt", ["simulate", "prism3", "--duration", "1e-5", "--out", "{tmp}/x.npz"], 2,
     r"--duration 1e-05 s is shorter than one step of --dt 0.001 s"),
    ("demo-damping-negative", ["demo", "--damping", "-1"], 2, r"argument --damping: must be >= 0 and finite, got '-1'"),
    ("demo-seed-negative", ["demo", "--seed", "-3"], 2, r"argument --seed: must be >= 0, got '-3'"),
    ("demo-perturbation-nan", ["demo", "--perturbation", "nan"], 2, r"argument --perturbation: must be >= 0 and finite"),
    ("max-memory-zero", ["info", "prism3", "--max-memory", "0"], 2, r"argument --max-memory: must be positive"),
    # bad structure: exit 3
    ("structure-missing-file", ["info", "{tmp}/missing.json"], 3, r"^error: structure file '.*missing.json' not found$"),
    ("structure-unknown-name", ["info", "prism"], 3, r"unknown structure 'prism'"),
    ("structure-directory", ["info", "{tmp}/a_dir"], 3, r"a_dir: is a directory, not a structure file"),
    ("structure-not-json", ["info", "{tmp}/bad.json"], 3, r"bad.json: not valid JSON"),
    ("structure-not-utf8", ["info", "{tmp}/utf8.json"], 3, r"not UTF-8 text \(byte 0xff at offset 10\)"),
    ("structure-stiffness-string", ["info", "{tmp}/stiff_str.json"], 3, r'stiffness: expected a number or a list, got the string "1000"'),
    ("structure-ragged", ["info", "{tmp}/ragged.json"], 3, r"nodes\[5\] \(node 5\): expected 3 items, got a list of 2 items"),
    ("structure-constraints-list", ["info", "{tmp}/nc_list.json"], 3, r"node_constraints: expected null or an object"),
    ("structure-mass-points-5", ["info", "{tmp}/mp5.json"], 3, r"mass_points: expected null or a list, got 5"),
    ("structure-400-digits", ["info", "{tmp}/bigint.json"], 3, r"not valid JSON|above the accepted maximum"),
    ("structure-mass-1e-300", ["simulate", "{tmp}/light.json", "--out", "{tmp}/l.npz"], 3, r"bar_mass: 1e-300 is below the accepted minimum 1e-09"),
    ("structure-builder-fails", ["info", "prism100"], 3, r"structure 'prism100': string \d+: force density"),
    ("structure-tower0", ["info", "tower0"], 3, r"tower: q must be an integer >= 1, got 0"),
    # output problems, found before simulating: exit 4
    ("out-exists", S + ["--out", "{tmp}/existing.npz"], 4, r"--out '.*existing.npz' exists; pass --force to overwrite it"),
    ("out-directory", S + ["--out", "{tmp}/a_dir"], 4, r"--out '.*a_dir' is a directory; give a file name"),
    ("out-under-file", S + ["--out", "{tmp}/plain_file/t.npz"], 4, r"plain_file' is a file, not a folder"),
    ("demo-out-file", ["demo", "--out", "{tmp}/plain_file"], 4, r"--out '.*plain_file' is a file; give a folder"),
    ("demo-out-exists", ["demo", "--out", "{tmp}/demo_exists"], 4, r"demo_summary.json' exists; pass --force"),
    ("video-exists", S + ["--out", "{tmp}/v.npz", "--video", "{tmp}/existing.npz"], 4,
     r"--video '.*existing.npz' exists; pass --force"),
    ("export-exists", ["export", "prism3", "--out", "{tmp}/existing.npz"], 4, r"export: --out '.*existing.npz' exists"),
    ("export-missing-folder", ["export", "prism3", "--out", "{tmp}/nope/m.xml"], 4, r"folder '.*nope' does not exist"),
    ("export-bad-structure", ["export", "{tmp}/mp5.json", "--out", "{tmp}/m.xml"], 3, r"mass_points: expected null"),
    ("view-missing", ["view", "{tmp}/missing.npz"], 3, r"view: .*missing.npz: not a simulate output"),
    ("view-not-npz", ["view", "{tmp}/bad.json"], 3, r"view: .*bad.json: not a NumPy .npz archive \(expected a simulate output"),
    ("view-npy", ["view", "{tmp}/one_array.npy"], 3, r"view: .*one_array.npy: a single NumPy array \(.npy\), not an .npz archive"),
    ("view-no-key", ["view", "{tmp}/existing.npz"], 3, r"view: .*existing.npz: not a NumPy .npz archive"),
    ("schedule-npy", S + ["--rest-length", "{tmp}/one_array.npy", "--out", "{tmp}/x.npz"], 3,
     r"--rest-length .*one_array.npy: a single NumPy array \(.npy\), not an .npz archive .*expected arrays t \(C,\) s "
     r"and rest_length \(C, 9\) m"),
    ("schedule-text", S + ["--rest-length", "{tmp}/text.npz", "--out", "{tmp}/x.npz"], 3,
     r"--rest-length .*text.npz: not a NumPy .npz archive"),
    ("identify-npy", ["identify", "prism3", "{tmp}/one_array.npy"], 3, r"one_array.npy: a single NumPy array"),
    ("identify-json", ["identify", "prism3", "{tmp}/bad.json"], 3, r"bad.json: not a NumPy .npz archive \(expected t \(S,\)"),
    # too large: exit 5, with the estimate
    ("duration-1e308", ["simulate", "prism3", "--duration", "1e308", "--out", "{tmp}/x.npz"], 5,
     r"--duration 1e\+308 s at --dt 0.001 s is inf steps, above the limit of 1e\+09 \(--max-steps\)"),
    ("dt-1e-13", ["simulate", "prism3", "--dt", "1e-13", "--out", "{tmp}/x.npz"], 5,
     r"--duration 1 s at --dt 1e-13 s is 1e\+13 steps, above the limit"),
    ("info-prism100000", ["info", "prism100000"], 5,
     r"building 'prism100000' \(200000 nodes, 100000 rods, 300000 strings; .*\) needs about .* GiB of memory, above the limit"),
    ("records-memory", ["simulate", "tower30", "--duration", "10", "--max-memory", "0.01", "--out", "{tmp}/x.npz"], 5,
     r"recording 10001 states of 180 nodes needs about 0.\d+ GiB of memory, above the limit of 0.01 GiB"),
    ("info-eigen-memory", ["info", "tower30", "--max-memory", "0.001"], 5,
     r"the stable-step estimate of 90 rods \(sparse Jacobians and Arnoldi; --no-stable-step skips it\) needs about"),
    ("demo-too-long", ["demo", "--duration", "1e300", "--out", "{tmp}/d"], 5, r"is 1e\+303 steps, above the limit"),
    # diverged: exit 6, trajectory up to the divergence kept and flagged
    ("diverged-nonfinite", ["simulate", "prism3", "--dt", "0.2", "--duration", "20", "--integrator", "semi_implicit_euler",
                            "--out", "{tmp}/d.npz"], 6,
     # the prism starts at rest in equilibrium: the unstable step amplifies round-off, so the step at
     # which it overflows moves with the last bit of the initial state (4.0 s or 4.2 s)
     r"simulation diverged: semi_implicit_euler: state became non-finite between t = (3.8 s and t = 4|4 s and t = 4.2) s .*; wrote (20|21) records"),
    ("diverged-energy", ["simulate", "{tmp}/spin.json", "--dt", "0.025", "--integrator", "semi_implicit_euler",
                         "--out", "{tmp}/e.npz"], 6, r"the energy grew from 22.6 J to .* J by t = .* s \(dt = 0.025 s\)"),
    ("diverged-dop853", ["simulate", "prism3", "--integrator", "dop853", "--dt", "1", "--duration", "1e6", "--rtol", "1e-14",
                         "--atol", "1e-300", "--out", "{tmp}/f.npz"], 6,
     r"dop853 failed in its first step from t = 0 s: Required step size is less than spacing between numbers"),
]
IDS = [c[0] for c in CASES]
assert len(set(IDS)) == len(IDS)


@pytest.fixture
def tmp(tmp_path):
    _files(tmp_path)
    return tmp_path


def run_main(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("case_id, argv, code, pattern", CASES, ids=IDS)
def test_cli_case(tmp, capsys, case_id, argv, code, pattern):
    argv = [a.replace("{tmp}", str(tmp)) for a in argv]
    got, out, err = run_main(argv, capsys)
    assert got == code, (got, out, err)
    lines = err.splitlines()
    assert "Traceback" not in err
    if code == 0:
        assert re.search(pattern, out), out
        return
    assert lines and all(x.startswith(("error: ", "warning: ")) for x in lines), err
    assert sum(x.startswith("error: ") for x in lines) == 1 and lines[-1].startswith("error: "), err
    assert re.search(pattern, lines[-1]), lines[-1]
    if code in (2, 3, 4, 5):   # refused before any output was written
        assert not (tmp / "x.npz").exists() and not (tmp / "d").exists()
        assert (tmp / "existing.npz").read_bytes() == b"keep me"
    if case_id.startswith("diverged"):
        out_path = Path(argv[argv.index("--out") + 1])
        d = np.load(out_path)
        assert bool(d["diverged"]) and str(d["message"])
        if case_id == "diverged-nonfinite":
            assert d["t"].shape in ((20,), (21,)) and np.all(np.isfinite(d["nodes"]))


def test_no_leftover_temporary_files(tmp, capsys):
    for case_id, argv, code, _ in CASES:
        if code in (0, 4, 6) and argv and argv[0] == "simulate":
            main([a.replace("{tmp}", str(tmp)) for a in argv] + ["--force"])
    capsys.readouterr()
    assert not [p for p in tmp.rglob("*.tmp")]


def test_output_mode_follows_umask(tmp_path, capsys):
    for name, mask, mode in (("u.npz", 0o027, 0o640), ("v.npz", 0o022, 0o644)):
        old = os.umask(mask)
        try:
            assert main(S + ["--out", str(tmp_path / name)]) == 0
        finally:
            os.umask(old)
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == mode


def test_interrupt_inside_write_leaves_no_temp_file(tmp_path):
    """A signal arriving while the output is written (SIGTERM raises _Terminated there): the
    temporary file is removed and an existing output is untouched."""
    target = tmp_path / "t.npz"
    target.write_bytes(b"old")

    def writer(f):
        f.write(b"partial")
        raise cli._Terminated()
    with pytest.raises(cli._Terminated):
        atomic.write_atomic(target, writer)
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["t.npz"]


def test_unwritable_folder(tmp_path, capsys):
    if os.geteuid() == 0:
        pytest.skip("root can write into a read-only folder")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        code, out, err = run_main(S + ["--out", str(ro / "t.npz")], capsys)
    finally:
        ro.chmod(0o700)
    assert code == 4 and re.search(r"folder '.*ro' is not writable", err)


def test_version_and_help_defaults(capsys):
    with pytest.raises(SystemExit) as e:
        cli.build_parser().parse_args(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"python -m tensegrity_gym {tg.__version__}"
    assert main(["--version"]) == 0
    capsys.readouterr()
    assert main(["simulate", "--help"]) == 0
    text = capsys.readouterr().out
    assert "(default: 0.001)" in text and "(default: rk4)" in text and "(default: traj.npz)" in text


def _proc(args, **kw):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "tensegrity_gym", *args], capture_output=True, text=True,
                          cwd=kw.pop("cwd", ROOT), env=env, timeout=300, **kw)


def test_module_entry_point_prog_name_and_exit_code(tmp_path):
    r = _proc(["info", "prism"])
    assert r.returncode == 3 and r.stderr.strip().splitlines() == [
        "error: structure 'prism': unknown structure 'prism' (did you mean prism6, prism4, prism3, prism_robot?); "
        "built-in names: ['constrained_prism', 'icosahedron', 'icosahedron_robot', 'pinned_rod', 'prism3', 'prism4', "
        "'prism6', 'prism_robot', 'tower3', 'tower30'] (or prism<p>, tower<q>), or a path to a JSON file"]
    r = _proc(["simulate", "prism3", "--dt", "x"])
    assert r.returncode == 2
    assert r.stderr == ("error: python -m tensegrity_gym simulate: argument --dt: expected a number, got 'x' "
                        "(see --help)\n")


def test_broken_pipe_no_traceback():
    """Output into a closed pipe (``| head``, here ``| true``, which reads nothing): exit quietly."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = f"{sys.executable} -m tensegrity_gym info prism3 --json | true; echo ${{PIPESTATUS[0]}}"
    r = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
    assert r.stderr == "", r.stderr
    assert r.stdout.strip() in ("0", "141")     # 0 if the pipe closed only after python wrote all


def test_sigterm_exits_143_without_temp_files(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen([sys.executable, "-m", "tensegrity_gym", "simulate", "prism3", "--duration", "1e5",
                          "--record-every", "1000", "--out", str(tmp_path / "t.npz")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    first = p.stderr.read(1)                    # the progress bar: the handler is installed, the run started
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=120)
    err = (first + err).decode()
    assert p.returncode == 143, err
    assert err.splitlines()[-1] == "error: terminated (SIGTERM); no output file was changed"
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------- outputs never lost
def test_a_file_created_at_the_output_during_the_run_is_not_overwritten(tmp_path, monkeypatch, capsys):
    """Someone creates the output file while the simulation runs (here: just before the result is
    written): it is kept and the run exits 4 naming it; with --force it is replaced."""
    out = tmp_path / "t.npz"
    real = np.savez

    def savez_after_someone_else(f, **arrays):
        if not out.exists():
            out.write_bytes(b"someone else's")
        real(f, **arrays)

    monkeypatch.setattr(np, "savez", savez_after_someone_else)
    code, _, err = run_main(S + ["--out", str(out)], capsys)
    assert code == 4 and "was created or changed by someone else during this run" in err, err
    assert out.read_bytes() == b"someone else's"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.npz"]
    code, _, err = run_main(S + ["--out", str(out), "--force"], capsys)
    assert code == 0, err
    assert set(np.load(out)) >= {"t", "nodes", "energy"}


def test_a_second_cli_run_to_one_output_is_refused_at_once_naming_the_first(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = tmp_path / "t.npz"
    first = subprocess.Popen([sys.executable, "-m", "tensegrity_gym", "simulate", "prism3", "--duration", "1e5",
                              "--record-every", "1000", "--out", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        assert first.stderr.read(1)                 # the progress bar: the output is claimed, the run started
        r = _proc(["simulate", "prism3", "--duration", "0.01", "--out", str(out)], cwd=tmp_path)
        assert r.returncode == 4, r.stderr
        assert re.fullmatch(rf"error: --out '.*t.npz' is in use by another run \(pid {first.pid} on host \S+, "
                            r"started \S+; lock .*\); wait for it or choose another path\n", r.stderr), r.stderr
        assert not out.exists()
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=120)
    assert first.returncode == 143 and list(tmp_path.iterdir()) == []


def test_sigterm_between_two_outputs_reports_truthfully(tmp_path):
    """SIGTERM while ``simulate --video`` renders its video, after the trajectory was computed: the
    message says exactly what was written; here nothing, so the old trajectory is untouched."""
    pytest.importorskip("imageio")
    env = dict(os.environ, PYTHONPATH=str(ROOT), TENSEGRITY_RENDERER="matplotlib")
    out, video = tmp_path / "t.npz", tmp_path / "v.gif"
    out.write_bytes(b"the old trajectory")
    p = subprocess.Popen([sys.executable, "-m", "tensegrity_gym", "simulate", "prism3", "--duration", "20",
                          "--out", str(out), "--video", str(video), "--force", "--no-progress"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        t_end = time.time() + 240
        while time.time() < t_end and p.poll() is None:   # the trajectory is written (or staged): the video is next
            if out.read_bytes() != b"the old trajectory" or any(
                    q.name.startswith(".t.npz") and not q.name.endswith(".lock") for q in tmp_path.iterdir()):
                break
            time.sleep(0.005)
        time.sleep(0.5)                                  # well inside the rendering of 600 frames
        assert p.poll() is None, p.communicate()[1].decode()
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    err = err.decode()
    assert p.returncode == 143, err
    last = err.splitlines()[-1]
    if last == "error: terminated (SIGTERM); no output file was changed":
        assert out.read_bytes() == b"the old trajectory" and not video.exists()
    else:     # the signal landed while the outputs were published: they were written, and the message says so
        assert last == f"error: terminated (SIGTERM); wrote {out}, {video}", last
        assert set(np.load(out)) >= {"t", "nodes"} and video.stat().st_size > 0
    assert sorted(q.name for q in tmp_path.iterdir()) in (["t.npz"], ["t.npz", "v.gif"])


# ---------------------------------------------------------------------- property-based
_value = st.one_of(st.sampled_from(["0", "-1", "nan", "inf", "-inf", "1e308", "1e-300", "abc", "", "1.5", "3",
                                    "0.001", "1e-13", "10"]),
                   st.floats(allow_nan=True).map(repr), st.integers(-10, 10 ** 6).map(str))
_option = st.one_of(
    st.tuples(st.sampled_from(["--duration", "--dt", "--record-every", "--rtol", "--atol", "--max-memory",
                               "--integrator", "--backend"]), _value).map(list),
    st.sampled_from([["--no-project"], ["--integrator", "semi_implicit_euler"], ["--integrator", "radau"],
                     ["--backend", "numba"], ["--backend", "numpy"], ["--json"], ["--bogus"], ["-h"]]))


@settings(max_examples=60, deadline=None)
@given(cmd=st.sampled_from(["simulate", "info", "frobnicate"]),
       structure=st.sampled_from(["prism3", "pinned_rod", "prism", "tower0", "missing.json", "-", "prism10000000"]),
       options=st.lists(_option, max_size=4))
def test_random_arguments_give_a_code_and_one_line(tmp_path_factory, cmd, structure, options):
    out = tmp_path_factory.mktemp("cli") / "o.npz"
    argv = [cmd, structure] + [x for o in options for x in o]
    if cmd == "simulate":
        argv += ["--out", str(out), "--no-progress", "--max-steps", "1000"]   # bounded: fast or refused (adaptive: 20k evaluations)
    import contextlib
    import io
    err, std = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std):
        code = main(argv)
    lines = err.getvalue().splitlines()
    assert code in (0, 2, 3, 4, 5, 6), (argv, code)
    assert "Traceback" not in err.getvalue()
    if code != 0:
        assert sum(x.startswith("error: ") for x in lines) == 1 and lines[-1].startswith("error: "), (argv, lines)
        assert all(x.startswith(("error: ", "warning: ")) for x in lines), (argv, lines)
    elif cmd == "simulate" and "-h" not in argv:
        d = np.load(out)
        assert np.all(np.isfinite(d["nodes"])) and np.all(np.isfinite(d["energy"]))


def test_adaptive_solver_is_bounded_by_max_steps(tmp_path, capsys):
    """An adaptive run that would take long (100 s of a stiff rod at rtol 1e-10 with 1000 records)
    stops after ADAPTIVE_EVALUATIONS_PER_STEP x --max-steps evaluations with exit code 5 (not a
    hang); one with tolerances at the round-off floor, whose Jacobian goes non-finite, is reported
    as diverged (exit 6), never a traceback."""
    import time
    t0 = time.perf_counter()
    code = main(["simulate", "pinned_rod", "--integrator", "dop853", "--duration", "100", "--dt", "0.1",
                 "--max-steps", "3000", "--out", str(tmp_path / "x.npz"), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 5 and err[-1].startswith("error: dop853: the adaptive solver needed more than 60000"), err
    assert not (tmp_path / "x.npz").exists()
    code = main(["simulate", "pinned_rod", "--integrator", "radau", "--duration", "3", "--atol", "1e-300",
                 "--rtol", "1e-13", "--max-steps", "3000", "--out", str(tmp_path / "y.npz"), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code in (5, 6) and sum(x.startswith("error: ") for x in err) == 1, (code, err)
    assert time.perf_counter() - t0 < 120


def test_sigterm_swallowed_by_a_callback_still_publishes_nothing(tmp_path, monkeypatch, capsys):
    """Python ignores an exception raised inside a weakref callback or ``__del__``; a SIGTERM landing
    there (matplotlib's transforms have such callbacks) must still stop the command before it
    publishes anything, and exit 143."""
    from tensegrity_gym.tools import cli_common, cli_simulate
    out = tmp_path / "t.npz"
    out.write_bytes(b"the old trajectory")
    real = cli_common._commit

    def commit_after_a_swallowed_sigterm(tx):
        cli_common.TERMINATED.set()          # what the handler does before its exception is lost
        return real(tx)
    monkeypatch.setattr(cli_simulate, "_commit", commit_after_a_swallowed_sigterm)
    code = main(["simulate", "prism3", "--duration", "0.01", "--out", str(out), "--force", "--no-progress"])
    assert code == 143
    assert out.read_bytes() == b"the old trajectory"
    assert "terminated (SIGTERM); no output file was changed" in capsys.readouterr().err
