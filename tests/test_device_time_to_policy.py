"""scripts/eval/device_time_to_policy.py: a few iterations of rsl_rl's PPO on the torch device env (CPU),
and the fields of the JSON result."""
from __future__ import annotations

import importlib
import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("rsl_rl")
pytest.importorskip("tensordict")


def _script():
    return importlib.import_module("scripts.eval.device_time_to_policy")


@pytest.mark.parametrize("target, reached", [(0.345, False), (-1.0, True)])
def test_tiny_run_writes_the_result(tmp_path, capsys, target, reached):
    out = tmp_path / "r.json"
    rc = _script().main(["--device", "cpu", "--num-envs", "8", "--steps-per-env", "4", "--max-iterations", "3",
                         "--eval-every-iterations", "2", "--eval-envs", "2", "--eval-episode-steps", "5",
                         "--threads", "1", "--target", str(target), "--seed", "3", "--out", str(out)])
    assert rc == 0
    r = json.loads(out.read_text())
    for key in ("device", "device_name", "cpu_model", "torch", "rsl_rl", "seed", "target_speed_m_s", "budget_s",
                "settings", "reached", "time_to_target_s", "env_steps_to_target", "training_wall_s", "env_steps",
                "evaluations", "best_speed_m_s", "command"):
        assert key in r, key
    assert r["device"] == "cpu" and r["device_name"] == r["cpu_model"] and r["seed"] == 3
    assert r["reached"] is reached and r["stopped"] == ("target reached" if reached else "budget")
    # rollouts and updates of the timed iterations: within the training time, both spent
    assert 0 < r["collection_wall_s"] and 0 < r["update_wall_s"]
    assert r["collection_wall_s"] + r["update_wall_s"] <= r["training_wall_s"] + 0.02
    assert _script().main(["--table", str(out)]) == 0
    row = capsys.readouterr().out.strip().splitlines()[-1]
    end = "| yes | target reached |" if reached else "| no | budget |"
    assert row.startswith("| r.json | ") and row.endswith(end)
    evals = r["evaluations"]
    assert evals and all({"training_wall_s", "env_steps", "iterations", "speed_m_s"} <= set(e) for e in evals)
    if reached:      # stops at the first evaluation at or above the target
        assert len(evals) == 1 and r["time_to_target_s"] == evals[0]["training_wall_s"] > 0
        assert r["env_steps_to_target"] == evals[0]["env_steps"] == 2 * 8 * 4
    else:            # ran to --max-iterations: evaluated at iteration 2 and at the end
        assert r["time_to_target_s"] is None and r["env_steps_to_target"] is None
        assert [e["iterations"] for e in evals] == [2, 3] and r["env_steps"] == 3 * 8 * 4
        assert r["best_speed_m_s"] == max(e["speed_m_s"] for e in evals) < 0.345


def test_an_interrupted_run_keeps_its_evaluations(tmp_path):
    """Ctrl-C during the second evaluation: the JSON holds the first and says it was interrupted."""
    mod = _script()
    calls = []

    def speed(*a):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return 0.1
    mod.evaluate_speed = speed
    out = tmp_path / "r.json"
    rc = mod.main(["--device", "cpu", "--num-envs", "4", "--steps-per-env", "4", "--max-iterations", "5",
                   "--eval-every-iterations", "2", "--eval-envs", "2", "--threads", "1", "--out", str(out)])
    r = json.loads(out.read_text())
    assert rc == 0 and r["stopped"] == "interrupted" and not r["reached"]
    assert [e["speed_m_s"] for e in r["evaluations"]] == [0.1] and r["evaluations"][0]["iterations"] == 2


@pytest.mark.parametrize("extra, message", [(["--cuda-graph"], "--cuda-graph needs --compile"),
                                            (["--cuda-graph", "--compile", "--env-backend", "numpy"],
                                             "--cuda-graph needs --env-backend torch")])
def test_cuda_graph_needs_the_compiled_torch_env(tmp_path, capsys, extra, message):
    with pytest.raises(SystemExit) as e:
        _script().main(["--device", "cpu", "--out", str(tmp_path / "r.json")] + extra)
    assert e.value.code == 2 and message in capsys.readouterr().err
