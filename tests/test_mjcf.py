"""MJCF export: MuJoCo's RK4 trajectory of the exported model matches ours.

Tolerance 1e-9 m in node positions over 0.5 s (RK4, dt = 1e-4 s on both sides); measured
agreement is ~1e-14 m (round-off), see tensegrity_gym/io/mjcf.py.
"""
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.physics.evaluate import force_densities
from tensegrity_gym.physics.geometry import node_positions
from tensegrity_gym.io.mjcf import export, to_mjcf

mujoco = pytest.importorskip("mujoco")

DT, T, REC = 1e-4, 0.5, 10
TOL = 1e-9  # m


def _ours(s):
    m = tg.compile_model(s)
    n = int(round(T / DT))
    _, q, qd = tg.simulate(m, tg.initial_state(m), DT, n, "rk4", record_every=n // REC)
    return np.array([node_positions(m, qq)[0] for qq in q]), m, q, qd


def _mujoco(s, **kw):
    M = mujoco.MjModel.from_xml_string(to_mjcf(s, timestep=DT, **kw))
    D = mujoco.MjData(M)
    mujoco.mj_resetDataKeyframe(M, D, 0)
    mujoco.mj_forward(M, D)
    ids = [mujoco.mj_name2id(M, mujoco.mjtObj.mjOBJ_SITE, f"node{i}") for i in range(s.n_nodes)]
    assert min(ids) >= 0
    out = [D.site_xpos[ids].copy()]
    n = int(round(T / DT))
    for _ in range(REC):
        mujoco.mj_step(M, D, n // REC)
        mujoco.mj_forward(M, D)
        out.append(D.site_xpos[ids].copy())
    assert math.isclose(D.time, T, rel_tol=1e-9)
    return np.array(out)


def _spin(s, w=(0.3, -0.5, 1.2), v0=(0.1, 0.0, 0.2)):
    """Initial node velocities of a rigid motion (keeps rod lengths)."""
    return np.cross(np.asarray(w), s.nodes - s.nodes.mean(0)) + np.asarray(v0)


def _prism_off_equilibrium():
    p = tg.prism(3, prestress=100)
    rng = np.random.default_rng(0)
    return p.replace(nodes=p.nodes + 0.02 * rng.standard_normal(p.nodes.shape), rest_length=p.rest_length)


CASES = {
    # free: released off equilibrium (perturbed nodes, same rest lengths), no gravity
    "prism_off_equilibrium": _prism_off_equilibrium,
    # free, spinning and translating, gravity, damped strings that stay taut (checked below)
    "prism_spinning_damped": lambda: (lambda p: p.replace(
        velocities=_spin(p), rest_length=p.rest_length * np.r_[1, 1, 1, 1, 1, 1, .99, .99, .99]))(
        tg.prism(3, prestress=100, damping=2.0, gravity=(0, 0, -9.81))),
    "icosahedron_spinning": lambda: (lambda s: s.replace(velocities=_spin(s)))(
        tg.icosahedron(gravity=(0, 0, -9.81))),
    # constrained: pinned node (ball joint) swinging with an initial angular velocity
    "pinned_rod_spinning": lambda: (lambda s: s.replace(velocities=np.vstack(
        [np.zeros(3), np.cross([0.3, -0.5, 1.2], s.nodes[1]), np.zeros((3, 3))])))(tg.pinned_rod()),
    # constrained: pinned, line (slide + ball) and plane (2 slides + ball) nodes, released off equilibrium
    "constrained_prism": tg.constrained_prism,
    # lumped masses (mass_points): centre of mass off the middle
    "prism_mass_points": lambda: tg.prism(3, prestress=100, gravity=(0, 0, -9.81)).replace(
        mass_points=[[(0.0, 0.2), (0.7, 0.8)], None, [(0.1, 0.5), (1.0, 0.5)]]),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_mujoco_rk4_matches_ours(name):
    s = CASES[name]()
    ours, m, q, qd = _ours(s)
    theirs = _mujoco(s)
    err = np.abs(ours - theirs).max()
    moved = np.abs(ours[-1] - ours[0]).max()
    print(f"{name}: max |node difference| MuJoCo RK4 vs ours over {T} s = {err:.2e} m (moved {moved:.3g} m)")
    assert moved > 1e-3, f"{name}: the test must move (moved {moved} m)"
    assert err < TOL, f"{name}: max node difference {err:.3g} m over {T} s"
    if np.any(s.damping > 0):
        # MuJoCo's tendon damping acts also when slack; agreement needs taut strings throughout
        gamma, _, L = force_densities(m, q.reshape(-1, *q.shape[2:]), qd.reshape(-1, *qd.shape[2:]))
        assert np.all(L > m.rest_length) and np.all(gamma > 0)


def test_axial_inertia_has_no_effect():
    s = CASES["icosahedron_spinning"]()
    a = _mujoco(s, rod_radius=1e-3)
    b = _mujoco(s, rod_radius=0.2)
    assert np.abs(a - b).max() < 1e-12


def test_model_layout_and_ground():
    s = tg.pinned_rod()
    xml = to_mjcf(s, ground=True)
    root = ET.fromstring(xml)
    M = mujoco.MjModel.from_xml_string(xml)
    assert M.nbody == 2 and M.ntendon == 3 and M.nsite == 5
    assert [M.jnt_type[i] for i in range(M.njnt)] == [mujoco.mjtJoint.mjJNT_BALL]
    np.testing.assert_allclose(M.opt.gravity, s.gravity)
    for i in range(3):
        np.testing.assert_allclose(M.tendon_lengthspring[i], [0.0, s.rest_length[i]])
        assert M.tendon_stiffness[i] == s.stiffness[i]
    # anchors are world sites at their positions
    for i in s.anchors:
        sid = mujoco.mj_name2id(M, mujoco.mjtObj.mjOBJ_SITE, f"node{i}")
        assert M.site_bodyid[sid] == 0
        np.testing.assert_allclose(M.site_pos[sid], s.nodes[i])
    assert root.find("worldbody/geom[@name='ground']") is not None
    assert "contact" not in (root.find("option/flag").attrib if root.find("option/flag") is not None else {})
    # constrained prism: pinned, line, plane -> 0, 1, 2 slides
    M = mujoco.MjModel.from_xml_string(to_mjcf(tg.constrained_prism()))
    types = list(M.jnt_type)
    assert types.count(mujoco.mjtJoint.mjJNT_SLIDE) == 3 and types.count(mujoco.mjtJoint.mjJNT_BALL) == 3
    # no ground: contact disabled
    assert ET.fromstring(to_mjcf(tg.prism(3))).find("option/flag").get("contact") == "disable"


def test_slack_string_dead_band():
    """A string shorter than its rest length pulls nothing (springlength dead band)."""
    s = tg.prism(3, prestress=None)
    s = s.replace(rest_length=s.rest_length * 1.5)   # all slack
    M = mujoco.MjModel.from_xml_string(to_mjcf(s, timestep=DT))
    D = mujoco.MjData(M)
    mujoco.mj_resetDataKeyframe(M, D, 0)
    mujoco.mj_step(M, D, 100)
    assert np.abs(D.qvel).max() == 0.0


def test_export_writes_atomically(tmp_path):
    out = export(tg.icosahedron(), tmp_path / "ico.xml", ground=True)
    assert out.read_text().startswith("<mujoco")
    assert [p.name for p in tmp_path.iterdir()] == ["ico.xml"]
    mujoco.MjModel.from_xml_path(str(out))


@pytest.mark.parametrize("kw, msg", [({"timestep": 0}, "timestep"), ({"rod_radius": -1}, "rod_radius"),
                                     ({"integrator": "rk45"}, "integrator"), ({"friction": -1}, "friction")])
def test_bad_arguments(kw, msg):
    with pytest.raises(ValueError, match=msg):
        to_mjcf(tg.prism(3), **kw)


def test_cli_export(tmp_path, capsys):
    from tensegrity_gym.tools.cli import main
    out = tmp_path / "model.xml"
    assert main(["export", "constrained_prism", "--format", "mjcf", "--out", str(out), "--ground"]) == 0
    M = mujoco.MjModel.from_xml_path(str(out))
    assert M.ntendon == 9 and M.ngeom == 4
    # no silent overwrite; --force overwrites
    assert main(["export", "prism3", "--out", str(out)]) == 4      # exit codes: tensegrity_gym.tools.cli
    assert "exists" in capsys.readouterr().err
    assert main(["export", "prism3", "--out", str(out), "--force"]) == 0
    assert mujoco.MjModel.from_xml_path(str(out)).nbody == 4
    # a directory, a missing folder
    assert main(["export", "prism3", "--out", str(tmp_path)]) == 4
    assert main(["export", "prism3", "--out", str(tmp_path / "no" / "m.xml")]) == 4
    err = capsys.readouterr().err
    assert err.count("error: export:") == 2 and "Traceback" not in err
    # JSON out, and a tnsgrt dict in
    js = tmp_path / "p.json"
    assert main(["export", "prism3", "--format", "json", "--out", str(js)]) == 0
    assert tg.load_json(js).n_strings == 9
    from tensegrity_gym.io.tnsgrt import to_tnsgrt_dict
    import json
    s = tg.prism(3)
    tn = {"nodes": s.nodes.T.tolist(), "members": np.hstack([s.strings.T, s.bars.T]).tolist(),
          "member_tags": {"string": list(range(9)), "bar": [9, 10, 11]},
          "member_properties": {"stiffness": [1000.0] * 12, "rest_length": list(s.rest_length) + [0] * 3}}
    (tmp_path / "tn.json").write_text(json.dumps(tn))
    assert main(["export", str(tmp_path / "tn.json"), "--from", "tnsgrt", "--out", str(tmp_path / "tn.xml")]) == 0
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"nodes": [[0, 1]], "members": []}))
    assert main(["export", str(bad), "--from", "tnsgrt", "--out", str(tmp_path / "b.xml")]) == 3
    assert "tnsgrt nodes" in capsys.readouterr().err


def test_ground_catches_a_falling_prism():
    """With ground=True the rods (capsules of rod_radius) land on the plane and stay above it
    (MuJoCo's own contact model: agreement with ours is qualitative)."""
    s = tg.prism(3, gravity=(0, 0, -9.81), damping=5.0)
    s = s.replace(nodes=s.nodes + [0.0, 0.0, 0.2])
    M = mujoco.MjModel.from_xml_string(to_mjcf(s, ground=True, timestep=1e-3, rod_radius=0.01))
    D = mujoco.MjData(M)
    mujoco.mj_resetDataKeyframe(M, D, 0)
    ids = [mujoco.mj_name2id(M, mujoco.mjtObj.mjOBJ_SITE, f"node{i}") for i in range(s.n_nodes)]
    mujoco.mj_step(M, D, 1000)
    z = D.site_xpos[ids][:, 2]
    assert np.all(np.isfinite(D.qpos)) and D.ncon >= 3
    assert 0.0 < z.min() < 0.03 and abs(z.max() - 1.0) < 0.05
