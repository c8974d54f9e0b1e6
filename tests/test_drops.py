"""Drops and impacts never create energy: a robot dropped onto a plane, a box face, a box edge,
a slot between boxes and a heightfield, from 1 m to 20 m, with the contact the envs and the
command line run (normal damping capped for the time step,
``physics.contact.impact_damping_cap``); resting contact is unchanged by the cap; the command
line's ``simulate --ground`` drop keeps its energy. The full matrix: ``python -m
scripts.eval.drop_matrix`` (results/drops)."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from tensegrity_gym.core.builders import load_structure
from tensegrity_gym.core.terrain import Terrain
from tensegrity_gym.tools.drops import drop, drop_terrains

ROBOT = load_structure("prism_robot")


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("name", list(drop_terrains()))
def test_drops_never_gain_energy_and_never_tunnel(name, integrator):
    t = drop_terrains()[name]
    for h in (1.0, 5.0, 20.0):
        r = drop(ROBOT, t, h, integrator, after=0.5)
        assert r.energy_ratio <= 1.0 + 1e-9, (name, integrator, h, r.energy_ratio)
        assert r.energy[-1] < 0.5 * r.energy[0]           # the impacts dissipated most of it
        if name in ("plane", "box_face", "plate_2cm"):    # never through the surface (z = 0)
            assert r.lowest.min() > -0.02, (name, integrator, h, r.lowest.min())


def test_without_the_cap_a_fast_impact_gains_energy():
    """What the cap prevents: uncapped Hunt-Crossley damping at 10 m (14 m/s)."""
    r = drop(ROBOT, Terrain(), 10.0, "semi_implicit_euler", after=0.5, max_damping=math.inf)
    assert r.energy_ratio > 2.0


def test_the_cap_leaves_resting_contact_unchanged():
    a = drop(ROBOT, Terrain(), 0.0, "semi_implicit_euler", after=1.0, max_damping=math.inf)
    b = drop(ROBOT, Terrain(), 0.0, "semi_implicit_euler", after=1.0)
    np.testing.assert_array_equal(a.energy, b.energy)
    np.testing.assert_array_equal(a.lowest, b.lowest)


def test_cli_drop_onto_the_ground_keeps_its_energy(tmp_path):
    s = json.loads(json.dumps(ROBOT.to_dict()))
    s["nodes"] = (np.asarray(s["nodes"], float) + [0.0, 0.0, 5.0]).tolist()
    f = tmp_path / "high.json"
    f.write_text(json.dumps(s))
    out = tmp_path / "drop.npz"
    p = subprocess.run([sys.executable, "-m", "tensegrity_gym", "simulate", str(f), "--ground", "--duration", "2",
                        "--integrator", "semi_implicit_euler", "--no-progress", "--out", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    E = np.load(out)["energy"]
    assert E.max() <= E[0] * (1 + 1e-9) and E[-1] < 0.5 * E[0]
