"""scripts/replay_terrain_kernel.py: the terrain kernel calls of an env run recorded and replayed
(the replay leaves the recorded inputs as they were, and the env's kernels are put back)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from tensegrity_gym.backends.numba import terrain_steps as TS

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "replay_terrain_kernel.py"


def _load():
    spec = importlib.util.spec_from_file_location("replay_terrain_kernel", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


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
