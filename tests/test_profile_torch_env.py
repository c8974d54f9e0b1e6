"""scripts/bench/profile_torch_env.py: a control step of the torch device env profiled on the CPU (its
rows and the JSON it writes)."""
from __future__ import annotations

import importlib
import json

import pytest

pytest.importorskip("torch")


def test_profile_rows(tmp_path, capsys):
    mod = importlib.import_module("scripts.bench.profile_torch_env")
    out = tmp_path / "p.json"
    assert mod.main(["--device", "cpu", "--num-envs", "3", "--steps", "2", "--warmup", "1", "--threads", "1",
                     "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["device"] == "cpu" and r["env"] == "TensegrityRoll-v0" and len(r["rows"]) == 1
    row = r["rows"][0]
    assert row["num_envs"] == 3 and row["compiled"] is False and row["compiled_calls"] == 0
    # an eager control step dispatches thousands of operations and reads one or two flags back
    assert row["ms_per_step"] > 0 and row["host_ops"] > 1000 and 1 <= row["host_reads"] <= 2
    assert "per control step" in capsys.readouterr().out
