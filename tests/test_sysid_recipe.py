"""The system-identification recipe of docs/sysid.md, run as written: its four commands recover the
true robot's stiffness and damping from a noisy recording. They run in an empty folder: nothing
is read from the checkout but the package (on PYTHONPATH, as an install would put it)."""
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _recipe_commands() -> list[str]:
    text = (ROOT / "docs" / "sysid.md").read_text()
    block = text.split("## Recipe")[1].split("```")[1]
    lines = block.replace("\\\n", " ").splitlines()
    return [ln.strip() for ln in lines if ln.strip() and not ln.strip().startswith("#")]


def test_recipe_runs_and_recovers_the_true_robot(tmp_path):
    cmds = _recipe_commands()
    assert len(cmds) == 4 and cmds[-1].startswith("python -m tensegrity_gym identify")
    env = {"TENSEGRITY_GYM_QUIET": "1", "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg",
           "PATH": "/usr/bin:/bin"}
    for cmd in cmds:
        argv = [sys.executable] + cmd.split()[1:]
        r = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, env=env, timeout=600)
        assert r.returncode == 0, f"{cmd}\n{r.stdout}\n{r.stderr}"
    fit = json.loads((tmp_path / "sysid_demo" / "fit.json").read_text())
    k, c = np.array(fit["values"]["stiffness"]), np.array(fit["values"]["damping"])
    np.testing.assert_allclose(k, 1200.0, rtol=0.02)
    np.testing.assert_allclose(c, 0.5, rtol=0.2)
    # without the start value: exit status 3 (bad input), the command-line remedy, no Python syntax
    argv = [sys.executable] + re.sub(r"--initial \S+ ", "", cmds[-1]).split()[1:]
    r = subprocess.run(argv + ["--force"], cwd=tmp_path, capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 3
    assert "start it with --initial damping=VALUE (N s/m)" in r.stderr and "initial={" not in r.stderr
