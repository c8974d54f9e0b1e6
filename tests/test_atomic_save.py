"""Training loses nothing: atomic saves, kills mid-save, crash status, restart, resume schedule.

Every training here is tiny (Pendulum-v1 or the shape env, a few hundred steps).
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("yaml")

from agents import common, train  # noqa: E402
from tensegrity_gym.io import atomic, claim  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
PPO_TINY = ["--algo", "ppo", "--env", "Pendulum-v1", "--n-envs", "2", "--no-progress-bar",
            "--hyperparams", "n_steps=16", "batch_size=32", "n_epochs=1", "normalize=true",
            "policy_kwargs=dict(net_arch=[16])"]


# ---------------------------------------------------------------------- the atomic writer
def test_atomic_write_keeps_old_file_when_writer_fails(tmp_path):
    p = tmp_path / "f.bin"
    common.atomic_write(p, lambda f: f.write(b"good"))

    def bad(f):
        f.write(b"half")
        raise KeyboardInterrupt  # an interrupt in the middle of writing

    with pytest.raises(KeyboardInterrupt):
        common.atomic_write(p, bad)
    assert p.read_bytes() == b"good"
    assert [x.name for x in tmp_path.iterdir()] == ["f.bin"]  # the temporary file is gone


def test_stale_tmp_files_of_dead_processes_are_removed(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    stale = tmp_path / f".model.zip{common.TMP_TAG}{dead}"
    stale.write_bytes(b"x")
    mine = tmp_path / f".state.json{common.TMP_TAG}{os.getpid()}"
    mine.write_bytes(b"x")
    assert common.remove_stale_tmp(tmp_path) == [stale]
    assert mine.exists()


# ---------------------------------------------------------------------- claims and transactions
def _dead_pid() -> int:
    return int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True).stdout)


def test_two_threads_claiming_one_output_exactly_one_wins(tmp_path):
    """Threads of one process race for a claim: exactly one holds it, the others are refused at once."""
    import threading
    target = tmp_path / "out.npz"
    barrier = threading.Barrier(8)
    results = []

    def take():
        barrier.wait(timeout=30)
        try:
            results.append(claim.Claim(target))
        except claim.OutputBusy as e:
            results.append(e)

    threads = [threading.Thread(target=take) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    won = [r for r in results if isinstance(r, claim.Claim)]
    assert len(results) == 8 and len(won) == 1
    assert all(f"pid {os.getpid()}" in str(r) for r in results if not isinstance(r, claim.Claim))
    won[0].release()
    assert list(tmp_path.iterdir()) == []


def test_stale_lock_is_detected_and_taken_over_only_when_asked(tmp_path):
    target = tmp_path / "fit.json"
    lock = tmp_path / ".fit.json.lock"
    dead = _dead_pid()
    lock.write_text(json.dumps({**claim.holder_record(), "pid": dead, "process_start": None}))
    with pytest.raises(claim.StaleClaim, match=f"pid {dead} .*no longer runs.*--steal-lock"):
        claim.Claim(target)
    c = claim.Claim(target, steal=True)
    assert c.took_over["pid"] == dead and claim.read_lock(lock)["pid"] == os.getpid()
    c.release()
    assert not lock.exists()


def test_a_reused_pid_does_not_keep_a_lock_alive(tmp_path):
    """The lock records the holder's process start time: a live process that reuses the pid is not the holder."""
    run = tmp_path / "run"
    run.mkdir()
    rec = claim.holder_record()
    if rec["process_start"] is None:
        pytest.skip("no /proc: process start times unknown")
    (run / ".lock").write_text(json.dumps({**rec, "process_start": "1"}))   # this pid, another process
    with pytest.raises(claim.StaleClaim):
        claim.Claim(run, folder=True)
    claim.Claim(run, folder=True, take_over_dead=True).release()
    # a holder on another host cannot be checked: take_over_dead does not take it, steal does
    (run / ".lock").write_text(json.dumps({**rec, "host": "elsewhere"}))
    with pytest.raises(claim.OutputBusy, match="another host"):
        claim.Claim(run, folder=True, take_over_dead=True)
    claim.Claim(run, folder=True, steal=True).release()


def test_transaction_publishes_all_or_none(tmp_path):
    a, b = tmp_path / "a.npz", tmp_path / "b.png"
    with claim.Transaction([(a, "--out"), (b, "--plot")]) as tx:
        tx.stage(a, lambda f: f.write(b"A"))
        tx.stage(b, lambda f: f.write(b"B"))
        b.write_bytes(b"someone else's")          # appears at an output during the run
        with pytest.raises(atomic.OutputChanged, match="--plot .*b.png.* during this run; nothing was written"):
            tx.commit()
        assert not a.exists() and b.read_bytes() == b"someone else's" and tx.report() == "no output file was changed"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.png"]   # temporary files and locks are gone
    b.unlink()
    with claim.Transaction([(a, "--out"), (b, "--plot")]) as tx:
        tx.stage(a, lambda f: f.write(b"A"))
        tx.stage(b, lambda f: f.write(b"B"))
        assert tx.commit() == [a, b] and tx.report() == f"wrote {a}, {b}"
    assert a.read_bytes() == b"A" and b.read_bytes() == b"B"
    with pytest.raises(atomic.OutputExists, match="--plot .* exists; pass --force"):   # claimed before any work
        claim.Transaction([(tmp_path / "c", "--out"), (b, "--plot")])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz", "b.png"]
    with claim.Transaction([(a, "--out")], force=True) as tx:         # --force replaces, also a file changed since
        tx.stage(a, lambda f: f.write(b"A2"))
        a.write_bytes(b"changed")
        tx.commit()
    assert a.read_bytes() == b"A2"


def test_exclusive_write_never_replaces_a_file(tmp_path):
    p = tmp_path / "x"
    atomic.write_atomic(p, lambda f: f.write(b"1"), exclusive=True)
    with pytest.raises(atomic.OutputChanged):
        atomic.write_atomic(p, lambda f: f.write(b"2"), exclusive=True)
    assert p.read_bytes() == b"1" and [q.name for q in tmp_path.iterdir()] == ["x"]


# ---------------------------------------------------------------------- two trainings into one folder
def test_two_trainings_started_a_second_apart_into_one_log_dir(tmp_path):
    """Two ``agents.train`` runs into one --log-dir, started a second apart: one holds the folder
    and goes on, the other exits at once (status 2) naming the holder's pid."""
    run = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "agents.train", "--log-dir", str(run), "--n-timesteps", "1000000",
           "--save-freq", "-1", "--eval-freq", "-1", *PPO_TINY]
    procs = []
    try:
        for _ in range(2):
            procs.append(subprocess.Popen(cmd, cwd=str(ROOT), env=env, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.PIPE, text=True))
            time.sleep(1.0)
        t_end = time.time() + 240
        while all(p.poll() is None for p in procs) and time.time() < t_end:
            time.sleep(0.1)
        done = [p for p in procs if p.poll() is not None]
        assert len(done) == 1, "neither run was refused: both train into one folder"
        refused, holder = done[0], next(p for p in procs if p is not done[0])
        err = refused.stderr.read()
        assert refused.returncode == 2 and f"pid {holder.pid}" in err and "Traceback" not in err, err
        time.sleep(1.0)
        assert holder.poll() is None        # the holder goes on
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait(timeout=60)
    # the killed holder left its lock: a new run is refused as stale until --steal-lock
    with pytest.raises(FileExistsError, match=f"pid {holder.pid} .*no longer runs.*--steal-lock"):
        train.train(["--log-dir", str(run), "--n-timesteps", "64", *PPO_TINY])


# ---------------------------------------------------------------------- kills in the middle of saves
_SLOW_RUNNER = textwrap.dedent("""
    import os, sys, time
    from agents import common, train
    real = common.atomic_write
    def slow(path, writer):
        def w(f):
            writer(f)
            f.flush()
            time.sleep(float(os.environ["SLOW_SAVE_S"]))  # a slow disk: the kill lands mid-save
        return real(path, w)
    common.atomic_write = slow
    sys.exit(train.main(sys.argv[1:]))
""")


def _env(slow_s):
    return {**os.environ, "SLOW_SAVE_S": str(slow_s), "PYTHONPATH": str(ROOT) + os.pathsep +
            os.environ.get("PYTHONPATH", "")}


def _start(run, extra, slow_s=0.05):
    return subprocess.Popen([sys.executable, "-c", _SLOW_RUNNER, "--log-dir", str(run), *PPO_TINY, *extra],
                            cwd=str(ROOT), env=_env(slow_s), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


def _check_loadable(run: Path) -> dict:
    """Every model / statistics file under its final name loads; returns {name: num_timesteps}."""
    from stable_baselines3 import PPO
    from agents.evaluate import load_vecnormalize
    out = {}
    zips = [run / "model.zip", run / "best_model.zip"] + sorted((run / "checkpoints").glob("rl_model_*_steps.zip"))
    for z in zips:
        if z.exists():
            out[z.name] = PPO.load(z, device="cpu").num_timesteps
    for p in [run / "vecnormalize.pkl", run / "best_vecnormalize.pkl"] + \
            sorted((run / "checkpoints").glob("rl_model_vecnormalize_*.pkl")):
        if p.exists():
            assert load_vecnormalize(p).obs_rms.count > 0
    for j in ("state.json", "versions.json"):
        if (run / j).exists():
            json.loads((run / j).read_text())
    ev = run / "eval" / "evaluations.npz"
    if ev.exists():
        np.load(ev)["timesteps"]
    # every checkpoint zip has its statistics (the statistics are written first)
    for z in (run / "checkpoints").glob("rl_model_*_steps.zip"):
        n = z.name.split("_")[2]
        assert (run / "checkpoints" / f"rl_model_vecnormalize_{n}_steps.pkl").exists(), z.name
    return out


@pytest.mark.slow
def test_sigkill_at_random_moments_never_destroys_the_last_good_model(tmp_path):
    """A run saves every 32 steps through a slow writer; SIGKILL lands at random moments (many of
    them inside a save); after each kill every file under its final name loads, and --resume
    continues from the newest one."""
    rng = np.random.default_rng(0)
    run = tmp_path / "run"
    p = _start(run, ["--n-timesteps", "100000", "--save-freq", "32", "--eval-freq", "64", "--eval-episodes", "1"])
    try:
        # wait for the first checkpoint, then kill at a random moment
        t_end = time.time() + 120
        while not list((run / "checkpoints").glob("rl_model_*_steps.zip")) and time.time() < t_end:
            time.sleep(0.05)
        time.sleep(float(rng.uniform(0.0, 1.0)))
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait()
    saved = _check_loadable(run)
    assert saved, "no model was saved before the kill"
    for k in range(3):  # resume and kill again, each time at a random moment
        p = subprocess.Popen([sys.executable, "-c", _SLOW_RUNNER, "--resume", str(run), "--no-progress-bar"],
                             cwd=str(ROOT), env=_env(0.05),
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        time.sleep(float(rng.uniform(4.0, 7.0)))
        p.send_signal(signal.SIGKILL)
        out = p.communicate()[0]
        saved2 = _check_loadable(run)
        assert max(saved2.values()) >= max(saved.values()), out[-2000:]
        saved = saved2
    common.remove_stale_tmp(run)  # what --resume does first: no temporary file is left after it
    assert not [f for f in run.rglob(f"*{common.TMP_TAG}*")]


@pytest.mark.slow
def test_second_ctrl_c_during_the_save_does_not_lose_the_model(tmp_path):
    run = tmp_path / "run"
    p = _start(run, ["--n-timesteps", "100000", "--save-freq", "-1", "--eval-freq", "-1"], slow_s=1.0)
    t_end = time.time() + 120
    while time.time() < t_end:
        st = json.loads((run / "state.json").read_text()) if (run / "state.json").exists() else {}
        if st.get("status") == "running":
            break
        time.sleep(0.1)
    time.sleep(1.0)
    p.send_signal(signal.SIGINT)          # first Ctrl-C: saves (slowly)
    time.sleep(0.5)
    p.send_signal(signal.SIGINT)          # second Ctrl-C in the middle of the save
    out = p.communicate(timeout=120)[0]
    assert p.returncode == 130, out[-3000:]
    assert "still saving" in out
    st = json.loads((run / "state.json").read_text())
    assert st["status"] == "interrupted"
    assert _check_loadable(run)["model.zip"] == st["num_timesteps"] == st["model_num_timesteps"]


# ---------------------------------------------------------------------- crash, restart, resume schedule
def test_crash_is_recorded_and_keeps_the_last_good_model(tmp_path):
    from stable_baselines3.common.callbacks import BaseCallback

    class Boom(BaseCallback):
        def _on_step(self):
            if self.num_timesteps >= 96:
                raise RuntimeError("simulated crash")
            return True

    run = tmp_path / "run"
    with pytest.raises(RuntimeError, match="simulated crash"):
        train.train(["--log-dir", str(run), "--n-timesteps", "512", "--save-freq", "64", "--eval-freq", "-1",
                     *PPO_TINY], extra_callbacks=[Boom()])
    st = json.loads((run / "state.json").read_text())
    assert st["status"] == "crashed"
    assert "RuntimeError: simulated crash" in st["error"] and "Traceback" in st["traceback"]
    assert not (run / "model.zip").exists()           # no model was finished: nothing overwritten
    assert (run / "crashed_model.zip").exists()
    assert _check_loadable(run)["rl_model_64_steps.zip"] == 64
    # --resume continues from the last checkpoint
    train.train(["--resume", str(run), "--no-progress-bar"])
    st = json.loads((run / "state.json").read_text())
    assert st["status"] == "finished" and st["num_timesteps"] >= 512 and "error" not in st


def test_a_run_that_failed_before_its_first_step_restarts_in_the_same_folder(tmp_path):
    run = tmp_path / "run"
    # PPO's constructor rejects it (agents.hyperparameters' own checks do not know it): fails before the first step
    bad = PPO_TINY[:-1] + ["policy_kwargs=dict(no_such_option=1)"]
    with pytest.raises(ValueError, match="PPO refused them"):
        train.train(["--log-dir", str(run), "--n-timesteps", "64", "--save-freq", "-1", "--eval-freq", "-1",
                     *bad])
    st = json.loads((run / "state.json").read_text())
    assert st["status"] == "crashed" and st["failed_before_first_step"]
    # the same folder, fixed arguments: starts again (no FileExistsError) ...
    train.train(["--log-dir", str(run), "--n-timesteps", "64", "--save-freq", "-1", "--eval-freq", "-1",
                 *PPO_TINY])
    st = json.loads((run / "state.json").read_text())
    assert st["status"] == "finished" and "failed_before_first_step" not in st
    # ... and now that it holds a model, a new run there is refused
    with pytest.raises(FileExistsError, match="--resume"):
        train.train(["--log-dir", str(run), "--n-timesteps", "64", *PPO_TINY])


def test_resume_keeps_the_checkpoint_and_evaluation_schedule(tmp_path):
    run = tmp_path / "run"
    from agents.callbacks import InterruptAt
    args = ["--log-dir", str(run), "--n-timesteps", "512", "--save-freq", "128", "--eval-freq", "128",
            "--eval-episodes", "1", *PPO_TINY]
    train.train(args, extra_callbacks=[InterruptAt(200)])
    assert json.loads((run / "state.json").read_text())["status"] == "interrupted"
    train.train(["--resume", str(run), "--no-progress-bar"])
    ck = sorted(int(p.name.split("_")[2]) for p in (run / "checkpoints").glob("rl_model_*_steps.zip"))
    assert ck == [128, 256, 384, 512]   # not 200 + 128 k
    ev = np.load(run / "eval" / "evaluations.npz")["timesteps"].tolist()
    assert ev == [128, 256, 384, 512]
    assert not (run / "eval" / ".evaluations_scratch.npz").exists()


def test_exclusive_publish_without_hard_links(tmp_path, monkeypatch):
    """A file system without hard links: the exclusive publish still never replaces a file."""
    import errno

    def no_links(src, dst):
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "link", no_links)
    p = tmp_path / "x"
    atomic.write_atomic(p, lambda f: f.write(b"1"), exclusive=True)
    with pytest.raises(atomic.OutputChanged):
        atomic.write_atomic(p, lambda f: f.write(b"2"), exclusive=True)
    assert p.read_bytes() == b"1" and [q.name for q in tmp_path.iterdir()] == ["x"]
    with claim.Claim(tmp_path / "y") as c:
        assert claim.read_lock(c.lock)["pid"] == os.getpid()
        with pytest.raises(claim.OutputBusy):
            claim.Claim(tmp_path / "y")
    assert [q.name for q in tmp_path.iterdir()] == ["x"]
