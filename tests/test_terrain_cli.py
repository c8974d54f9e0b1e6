"""Terrain on the command line: ``simulate --terrain/--ground`` (placement, contact, overrides,
errors), ``export --terrain`` (MJCF geoms checked with MuJoCo's ray), and the placement helper.

The physics runs use planes and boxes only; heightfields appear in the export, which needs no
contact physics."""
import json
import re

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.model import compile_model, initial_state
from tensegrity_gym.physics.geometry import node_positions
from tensegrity_gym.tools.cli import main
from tensegrity_gym.core.placement import place_on_terrain, terrain_lift
from tensegrity_gym.core.terrain import Terrain
from tensegrity_gym.physics.rollout import simulate
from tensegrity_gym.physics import terrain as T

RAMP = {"friction": 0.8, "plane": {"slope_deg": 10.0, "uphill_deg": 0.0}}


def _prism_file(tmp_path):
    """A squat prism robot (0.2 kg rods) with gravity and damped strings, standing on z = 0."""
    s = tg.prism(3, radius=0.15, height=0.25, bar_mass=0.2, stiffness=1000.0, prestress=20.0,
                          damping=2.0, gravity=(0.0, 0.0, -9.81))
    path = tmp_path / "prism_g.json"
    tg.save_json(s, path)
    return s, path


def _write(tmp_path, name, d):
    p = tmp_path / name
    p.write_text(json.dumps(d))
    return p


def _sim(args, tmp_path, name="t.npz"):
    out = tmp_path / name
    code = main(["simulate", *map(str, args), "--out", str(out), "--no-progress", "--force"])
    return code, (np.load(out) if code == 0 else None)


# ---------------------------------------------------------------------- placement
def test_placement_lifts_onto_plane_box_and_leaves_a_floating_structure():
    s = tg.prism(3)
    r = 0.02
    # level ground: a structure standing on z = 0 rises by the cap radius
    s2, lift = place_on_terrain(s, Terrain(), r)
    assert lift == pytest.approx(r, abs=1e-9)
    np.testing.assert_allclose(s2.nodes - s.nodes, np.broadcast_to([0, 0, lift], s.nodes.shape))
    # a ramp and a box under the middle of the rods: every rod point clears by the radius, one touches
    ramp = {"slope_deg": 25.0, "uphill_deg": 40.0}
    ter = Terrain.from_dict({"plane": ramp, "boxes": [{"center": [0.0, 0.0, 0.3], "size": [3.0, 0.1, 0.4],
                                                       "yaw_deg": 30}]})
    _, ramp_lift = place_on_terrain(s, Terrain.from_dict({"plane": ramp}), r)
    s3, lift = place_on_terrain(s, ter, r)
    assert lift > ramp_lift + 1e-3        # the box under the rods sets it, not the ramp
    a, c = s3.nodes[s3.bars[:, 0]], s3.nodes[s3.bars[:, 1]]
    pts = (a[:, None] + np.linspace(0, 1, 101)[None, :, None] * (c - a)[:, None]).reshape(-1, 3)
    d, _ = ter.closest(pts)
    assert d.min() >= r - r / 8 - 1e-9 and d.min() < r + 1e-3
    # already above the terrain: not moved
    up = s.replace(nodes=s.nodes + [0, 0, 1.0])
    assert terrain_lift(Terrain(), up.nodes, up.bars, r) == 0.0


# ---------------------------------------------------------------------- simulate
def test_default_simulate_is_the_plain_run(tmp_path):
    """Neither --terrain nor --ground: the output is the plain simulation's, bit for bit."""
    s, path = _prism_file(tmp_path)
    code, d = _sim([path, "--duration", "0.05", "--dt", "1e-3", "--integrator", "semi_implicit_euler"], tmp_path)
    assert code == 0
    model = compile_model(s)
    _, q, _ = simulate(model, initial_state(model), 1e-3, 50, "semi_implicit_euler")
    assert np.array_equal(d["nodes"], node_positions(model, q[:, 0]))
    assert d["nodes"][-1, :, 2].min() < -1e-3          # it falls through z = 0: there is no ground


def test_ground_is_the_terrain_physics_on_a_lifted_structure(tmp_path, capsys):
    s, path = _prism_file(tmp_path)
    args = [path, "--duration", "0.3", "--dt", "1e-3", "--integrator", "semi_implicit_euler", "--record-every", "10"]
    code, d = _sim(args + ["--ground"], tmp_path)
    assert code == 0
    out = capsys.readouterr().out
    assert "lifted 0.02 m" in out and "--ground" in out
    # the same run through the public physics API
    lifted, lift = place_on_terrain(s, Terrain(), 0.02)
    model = compile_model(lifted)
    tc = T.TerrainContact(Terrain(), radius=0.02)
    st, ts = initial_state(model), T.init_terrain_state(tc, model)
    nodes = [node_positions(model, st.q)[0]]
    for _ in range(30):
        st, ts = T.step(model, st, 1e-3, tc, ts, "semi_implicit_euler", n_steps=10)
        nodes.append(node_positions(model, st.q)[0])
    assert np.array_equal(d["nodes"], np.array(nodes))
    np.testing.assert_allclose(d["t"], 0.01 * np.arange(31), atol=1e-12)
    # it rests on the ground: the caps sink at most a few mm (k = 1e4 N/m), never through
    assert d["nodes"][:, :, 2].min() > 0.02 - 0.01
    # a file holding {} is the same level plane
    code, d2 = _sim(args + ["--terrain", _write(tmp_path, "flat.json", {})], tmp_path, "t2.npz")
    assert code == 0 and np.array_equal(d2["nodes"], d["nodes"])


def test_ramp_holds_and_friction_override_slides(tmp_path):
    """Placed on a 10-degree ramp the prism lands on it and, once settled (after 0.8 s), holds with
    friction 0.8 and slides downhill (-x) with --friction 0.05 (g (sin a - mu cos a) = 1.2 m/s^2);
    a box across the ramp lifts the robot placed over it."""
    s, path = _prism_file(tmp_path)
    ramp = _write(tmp_path, "ramp.json", RAMP)
    args = [path, "--terrain", ramp, "--duration", "1.5", "--dt", "1e-3", "--integrator", "semi_implicit_euler",
            "--record-every", "100"]
    code, hold = _sim(args, tmp_path, "hold.npz")
    assert code == 0
    code, slide = _sim(args + ["--friction", "0.05"], tmp_path, "slide.npz")
    assert code == 0
    dx_hold = hold["nodes"][15, :, 0].mean() - hold["nodes"][8, :, 0].mean()
    dx_slide = slide["nodes"][15, :, 0].mean() - slide["nodes"][8, :, 0].mean()
    assert abs(dx_hold) < 2e-3 and dx_slide < -0.3, (dx_hold, dx_slide)
    ter = Terrain.from_dict(RAMP)
    for d in (hold, slide):
        # every node stays out of the ramp by about its cap radius (small penetration under load)
        dist, _ = ter.closest(d["nodes"].reshape(-1, 3))
        assert dist.min() > 0.02 - 0.01
    # a box under the robot: placed on top of it
    boxed = _write(tmp_path, "box.json", dict(RAMP, boxes=[{"center": [0, 0, 0.1], "size": [3, 3, 0.2]}]))
    code, d = _sim([path, "--terrain", boxed, "--duration", "0.01"], tmp_path, "box.npz")
    assert code == 0 and d["nodes"][0, :, 2].min() == pytest.approx(0.2 + 0.02, abs=1e-6)


def test_schedules_run_with_terrain(tmp_path):
    """Command schedules hold their rows over the steps with terrain contact as without: a schedule of
    the structure's own rest lengths with a change in the middle of a record gives the plain run."""
    s, path = _prism_file(tmp_path)
    sched = tmp_path / "rl.csv"
    rows = np.vstack([np.r_[0.0, s.rest_length], np.r_[0.013, s.rest_length]])
    np.savetxt(sched, rows, delimiter=",", header="t," + ",".join(f"l{i}" for i in range(9)))
    args = [path, "--ground", "--duration", "0.05", "--integrator", "semi_implicit_euler", "--record-every", "5"]
    code, a = _sim(args, tmp_path, "a.npz")
    code2, b = _sim(args + ["--rest-length", sched], tmp_path, "b.npz")
    assert code == code2 == 0
    np.testing.assert_allclose(b["nodes"], a["nodes"], atol=1e-12, rtol=0)
    assert b["rest_length"].shape == (11, 9)


def test_terrain_errors_are_one_line(tmp_path, capsys):
    _, path = _prism_file(tmp_path)
    out = str(tmp_path / "x.npz")
    cases = [
        (["--terrain", str(tmp_path / "missing.json")], 3, r"--terrain '.*missing.json': terrain file: cannot read"),
        (["--terrain", _write(tmp_path, "b1.json", {"boxes": [{"center": [0, 0, 0], "size": [1, -0.1, 1]}]})], 3,
         r"boxes\[0\]\.size\[1\]: must be > 0, got -0.1"),
        (["--terrain", _write(tmp_path, "b2.json", {"plane": {"slope_deg": 95}})], 3,
         r"plane\.slope_deg: must be < 90, got 95"),
        (["--terrain", _write(tmp_path, "b3.json", {"hills": 1})], 3, r"unknown key 'hills'"),
        (["--friction", "0.5"], 2, r"--friction: a terrain contact option; add --terrain"),
        (["--ground", "--cap-radius", "0"], 2, r"--cap-radius: must be positive"),
        (["--ground", "--ground-damping", "nan"], 2, r"--ground-damping: must be >= 0 and finite"),
        (["--ground", "--terrain", "x.json"], 2, r"not allowed with argument"),
        (["--ground", "--integrator", "dop853"], 2, r"--ground: terrain contact runs fixed-step methods"),
        (["--ground", "--backend", "torch"], 2, r"--ground: terrain contact runs on the numba kernels"),
    ]
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    cases.append((["--terrain", str(bad)], 3, r"terrain file: not valid JSON"))
    for extra, code, pattern in cases:
        assert main(["simulate", str(path), "--out", out, "--force", *map(str, extra)]) == code, extra
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err, err
        assert re.search(pattern, err), (pattern, err)
    assert not (tmp_path / "x.npz").exists()


def test_unstable_contact_step_and_no_gravity_warn(tmp_path, capsys):
    _, path = _prism_file(tmp_path)
    code, _ = _sim([path, "--ground", "--ground-stiffness", "1e8", "--duration", "0.001",
                    "--integrator", "semi_implicit_euler"], tmp_path)
    err = capsys.readouterr().err
    assert code == 0 and re.search(r"warning: terrain contact: --dt 0.001 s is above its estimated stable step", err)
    code, _ = _sim(["prism3", "--ground", "--duration", "0.002"], tmp_path)
    assert code == 0 and "has no gravity" in capsys.readouterr().err


# ---------------------------------------------------------------------- export
mujoco = None


def _mj():
    return pytest.importorskip("mujoco")


def _ray_height(mj, M, D, x, y):
    """Height of the first surface MuJoCo's ray meets going down from z = 50 m at (x, y)."""
    gid = np.zeros(1, np.int32)
    dist = mj.mj_ray(M, D, np.array([x, y, 50.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, gid)
    return 50.0 - dist if dist >= 0 else -np.inf


def _mixed_terrain(tmp_path):
    x = np.arange(9) * 0.25 - 1.0
    y = np.arange(7) * 0.25 + 2.0
    H = 0.3 + 0.2 * np.sin(1.3 * x)[None, :] * np.cos(0.9 * (y - 2.0))[:, None]
    np.save(tmp_path / "h.npy", H)
    d = {"friction": 0.7,
         "plane": {"slope_deg": 12.0, "uphill_deg": 30.0, "friction": 0.4},
         "boxes": [{"center": [2.0, 0.0, 0.5], "size": [0.6, 0.4, 0.3], "yaw_deg": 35.0},
                   {"center": [-2.0, -3.0, 0.5], "size": [1.0, 0.5, 0.4]}],
         "heightfield": {"file": "h.npy", "cell": 0.25, "origin": [-3.0, -1.0]}}
    return _write(tmp_path, "mixed.json", d)


def test_mjcf_terrain_geoms_and_heights(tmp_path):
    mj = _mj()
    from tensegrity_gym.io.mjcf import to_mjcf
    ter = Terrain.from_file(_mixed_terrain(tmp_path))
    s = tg.prism(3)
    s = s.replace(nodes=s.nodes + [40.0, 40.0, 30.0])     # out of the rays' way
    M = mj.MjModel.from_xml_string(to_mjcf(s, terrain=ter))
    D = mj.MjData(M)
    mj.mj_forward(M, D)
    G = mj.mjtGeom
    names = [mj.mj_id2name(M, mj.mjtObj.mjOBJ_GEOM, i) for i in range(M.ngeom)]
    world = [i for i in range(M.ngeom) if M.geom_bodyid[i] == 0]
    assert [names[i] for i in world] == ["terrain_plane", "terrain_box0", "terrain_box1", "terrain_hfield"]
    assert [M.geom_type[i] for i in world] == [G.mjGEOM_PLANE, G.mjGEOM_BOX, G.mjGEOM_BOX, G.mjGEOM_HFIELD]
    assert M.ngeom == 4 + s.n_bars and M.nhfield == 1
    assert (M.hfield_nrow[0], M.hfield_ncol[0]) == (7, 9)
    # the plane's normal, the boxes' half sizes, centres and yaw, the friction of each part
    np.testing.assert_allclose(D.geom_xmat[world[0]].reshape(3, 3)[:, 2], ter.plane.normal, atol=1e-12)
    for i, b in zip(world[1:3], ter.boxes):
        np.testing.assert_allclose(M.geom_size[i], b.size / 2)
        np.testing.assert_allclose(D.geom_xpos[i], b.center)
        np.testing.assert_allclose(D.geom_xmat[i].reshape(3, 3), b.rotation, atol=1e-12)
    np.testing.assert_allclose(M.geom_friction[world, 0], [0.4, 0.7, 0.7, 0.7])
    # contact is on: rods (contype 1) against the terrain (conaffinity 1)
    assert not (M.opt.disableflags & mj.mjtDisableBit.mjDSBL_CONTACT)
    # MuJoCo's surface height equals Terrain.height_at: plane, box tops (one yawed), heightfield (grid
    # points and points inside cells, where MuJoCo's triangles and our bilinear patches differ by
    # about h'' cell^2 / 8). Points beyond the grid are where the heightfield's held edge values are
    # below the plane or a box top: MuJoCo's hfield ends at the grid.
    pts = [(3.0, 1.0), (4.0, -1.0), (2.5, 2.0),                           # plane
           (2.0, 0.0), (2.1, 0.1), (-2.3, -3.1), (-1.6, -2.8),           # box tops
           (-3.0, -1.0), (-2.0, -0.5), (-1.0, 0.5), (-2.37, -0.39), (-1.45, 0.3)]   # heightfield
    rng = np.random.default_rng(0)
    pts += [(x, y) for x, y in zip(rng.uniform(-2.95, -1.05, 6), rng.uniform(-0.95, 0.45, 6))]
    for x, y in pts:
        want = float(ter.height_at(x, y))
        got = _ray_height(mj, M, D, x, y)
        assert abs(got - want) < 3e-3, (x, y, got, want)


def test_mjcf_flat_heightfield_and_plane_only(tmp_path):
    mj = _mj()
    from tensegrity_gym.io.mjcf import to_mjcf
    s = tg.prism(3).replace(nodes=tg.prism(3).nodes + [30.0, 0.0, 0.0])
    ter = Terrain.from_dict({"plane": None, "heightfield": {"heights": [[0.25, 0.25], [0.25, 0.25]], "cell": 1.0}})
    M = mj.MjModel.from_xml_string(to_mjcf(s, terrain=ter))
    D = mj.MjData(M)
    mj.mj_forward(M, D)
    assert abs(_ray_height(mj, M, D, 0.5, 0.5) - 0.25) < 1e-6
    with pytest.raises(ValueError, match="ground, terrain"):
        to_mjcf(s, ground=True, terrain=ter)
    with pytest.raises(ValueError, match="terrain"):
        to_mjcf(s, terrain={"plane": {}})


def test_cli_export_terrain(tmp_path, capsys):
    mj = _mj()
    out = tmp_path / "m.xml"
    path = _mixed_terrain(tmp_path)
    assert main(["export", "constrained_prism", "--terrain", str(path), "--friction", "0.3", "--out", str(out)]) == 0
    assert "lifted" in capsys.readouterr().out
    M = mj.MjModel.from_xml_path(str(out))
    D = mj.MjData(M)
    mj.mj_resetDataKeyframe(M, D, 0)
    mj.mj_forward(M, D)
    assert M.ngeom == 4 + 3 and np.all(M.geom_friction[M.geom_bodyid == 0, 0] == 0.3)
    # the exported structure rests on the terrain: no rod capsule inside it at the start
    assert D.ncon == 0 or np.all(np.array([D.contact[i].dist for i in range(D.ncon)]) > -1e-6)
    ter = Terrain.from_file(path)
    sites = np.array([D.site_xpos[mj.mj_name2id(M, mj.mjtObj.mjOBJ_SITE, f"node{i}")] for i in range(6)])
    assert (ter.closest(sites)[0] >= 0.01 * tg.constrained_prism().bar_lengths.max() - 1e-6).all()
    # --ground keeps today's model; a terrain with --format json, or a bad file, is refused in one line
    assert main(["export", "prism3", "--ground", "--friction", "0.4", "--out", str(tmp_path / "g.xml")]) == 0
    assert 'friction="0.4 ' in (tmp_path / "g.xml").read_text()
    assert main(["export", "prism3", "--terrain", str(path), "--format", "json", "--out", str(tmp_path / "j")]) == 2
    bad = _write(tmp_path, "bad.json", {"heightfield": {"cell": 0.1}})
    assert main(["export", "prism3", "--terrain", str(bad), "--out", str(tmp_path / "b.xml")]) == 3
    err = capsys.readouterr().err
    assert "applies to --format mjcf" in err and "heightfield: give exactly one of 'file'" in err
    assert "Traceback" not in err


def test_docs_command_line_block_runs(tmp_path):
    """docs/terrain.md's "Command line" block, pasted into a shell, runs and writes what it says."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    section = (root / "docs" / "terrain.md").read_text().split("## Command line", 1)[1]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    env = dict(os.environ, PYTHONPATH=str(root), PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    r = subprocess.run(["bash", "-e", "-c", block], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "warning" not in r.stderr
    hold, slide = np.load(tmp_path / "ramp.npz")["nodes"], np.load(tmp_path / "slide.npz")["nodes"]
    assert abs(hold[-1, :, 0].mean() - hold[1000, :, 0].mean()) < 2e-3       # holds on the ramp
    assert slide[-1, :, 0].mean() < -0.3                                      # slides down onto the step
    for name in ("flat.npz", "ramp.xml", "bumps.xml"):
        assert (tmp_path / name).stat().st_size > 0
