"""Command line and README example checks."""
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tensegrity_gym import from_dict
from tensegrity_gym.tools.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_simulate_writes_trajectory(tmp_path):
    out = tmp_path / "traj.npz"
    assert main(["simulate", "prism3", "--duration", "0.05", "--dt", "1e-3", "--integrator", "rk4",
                 "--out", str(out), "--no-progress"]) == 0
    d = np.load(out)
    assert d["t"].shape == (51,)
    assert d["nodes"].shape == (51, 6, 3)
    assert d["energy"].shape == (51,)
    np.testing.assert_allclose(d["t"][-1], 0.05)
    # prestressed prism at rest: energy constant, nodes fixed
    assert np.ptp(d["energy"]) < 1e-9 * abs(d["energy"][0])
    assert np.abs(d["nodes"] - d["nodes"][0]).max() < 1e-9


def test_simulate_record_every_and_json_file(tmp_path):
    from tensegrity_gym import pinned_rod, save_json
    js = tmp_path / "rod.json"
    save_json(pinned_rod(), js)
    out = tmp_path / "rod.npz"
    assert main(["simulate", str(js), "--duration", "0.1", "--dt", "1e-3", "--record-every", "10",
                 "--integrator", "semi_implicit_euler", "--out", str(out)]) == 0
    d = np.load(out)
    assert d["nodes"].shape == (11, 5, 3)
    # node 0 is pinned at the origin
    assert np.abs(d["nodes"][:, 0]).max() < 1e-12
    # the rod falls under gravity: node 1 moves
    assert np.abs(d["nodes"][-1, 1] - d["nodes"][0, 1]).max() > 1e-4


def test_simulate_adaptive(tmp_path):
    out = tmp_path / "a.npz"
    assert main(["simulate", "pinned_rod", "--duration", "0.05", "--integrator", "dop853", "--out", str(out)]) == 0
    assert np.load(out)["nodes"].shape == (51, 5, 3)


def test_info_prints_summary(capsys):
    assert main(["info", "constrained_prism"]) == 0
    text = capsys.readouterr().out
    assert "node 0: pinned" in text and "node 1: line" in text and "node 2: plane" in text
    assert "stable step" in text
    assert main(["info", "prism3", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["bars"] == 3 and d["strings"] == 9 and d["slack_strings"] == []
    assert 0 < d["stable_dt_s"]["semi_implicit_euler"] < d["stable_dt_s"]["rk4"]


def test_bad_inputs_give_clear_errors(tmp_path, capsys):
    # one line on stderr and a documented exit code (tests/test_hardening_cli.py has the full list)
    assert main(["info", str(tmp_path / "missing.json")]) == 3
    assert re.fullmatch(r"error: structure file '.*missing.json' not found\n", capsys.readouterr().err)
    assert main(["info", "prism"]) == 3
    assert "unknown structure 'prism'" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"nodes": [[0, 0, 0], [1, 0, 0]], "bars": [[0, 1]], "strings": [[0, 2]]}))
    assert main(["info", str(bad)]) == 3
    assert re.search(r"string 0 .*node 2 does not exist", capsys.readouterr().err)
    assert main(["simulate", "prism3", "--dt", "-1"]) == 2
    assert "--dt: must be positive and finite, got '-1'" in capsys.readouterr().err


def test_module_entry_point():
    r = subprocess.run([sys.executable, "-m", "tensegrity_gym", "info", "pinned_rod"], capture_output=True,
                       text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "pinned_rod" in r.stdout


def test_docs_json_example_loads():
    text = (ROOT / "docs" / "structures.md").read_text()
    block = re.search(r"# Structure JSON format\s+```json\n(.*?)```", text, re.S).group(1)
    s = from_dict(json.loads(block))
    assert s.n_bars == 1 and s.n_strings == 3 and 0 in s.node_constraints
    assert s.gravity is not None and s.damping[0] == 2.0
