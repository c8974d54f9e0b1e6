"""scripts/bench/replay_terrain_kernel.py: the terrain kernel calls of an env run recorded and replayed
(the replay leaves the recorded inputs as they were, and the env's kernels are put back)."""
from __future__ import annotations

import importlib

import numpy as np

from tensegrity_gym.backends.numba import terrain_steps as TS


def _load():
    return importlib.import_module("scripts.bench.replay_terrain_kernel")


def test_record_and_replay(capsys):
    mod = _load()
    kernels = {name: getattr(TS, name) for name in mod.KERNELS}
    calls = mod.record("steps", 2, 3)
    assert {name for name, _ in calls} == {"terrain_loop"} and len(calls) == 3
    assert all(getattr(TS, name) is fn for name, fn in kernels.items())
    q0 = calls[0][1][0].copy()
    assert mod.replay(calls, 3) > 0
    assert np.array_equal(calls[0][1][0], q0)          # replays run on copies
    mod.main(["--scene", "steps", "--envs", "2", "--steps", "2", "--replays", "1"])
    out = capsys.readouterr().out
    assert "steps, N = 2: 2 kernel calls over 2 env steps" in out and "| terrain_loop |" in out


def test_save_and_load(tmp_path, capsys):
    """``--save`` keeps the calls (inputs equal to the call before's kept once) and ``--load``
    replays them without recording; a saved file is not overwritten, a bad one is named."""
    import pickle

    import pytest
    mod = _load()
    path = tmp_path / "calls.pkl"
    mod.main(["--scene", "rough", "--envs", "2", "--steps", "3", "--replays", "1", "--save", str(path)])
    saved = pickle.loads(path.read_bytes())
    assert (saved["scene"], saved["envs"], saved["steps"], len(saved["calls"])) == ("rough", 2, 3, 3)
    a, b = saved["calls"][1][1], saved["calls"][2][1]
    assert any(x is y for x, y in zip(a, b) if isinstance(x, np.ndarray) and x.size > 1000)   # the heights once
    assert not np.array_equal(saved["calls"][0][1][0], saved["calls"][2][1][0])               # the state per call
    capsys.readouterr()
    mod.main(["--load", str(path), "--replays", "1"])
    assert "rough, N = 2: 3 kernel calls over 3 env steps" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        mod.main(["--scene", "rough", "--envs", "2", "--steps", "1", "--replays", "1", "--save", str(path)])
    assert "File exists" in capsys.readouterr().err
    (tmp_path / "bad.pkl").write_bytes(b"not a pickle")
    with pytest.raises(SystemExit):
        mod.main(["--load", str(tmp_path / "bad.pkl")])
    assert "--load" in capsys.readouterr().err
