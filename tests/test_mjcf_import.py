"""MJCF import (tensegrity_gym.io.mjcf.from_mjcf): a 3-bar written here in the field's style
(capsule rods with end-cap spheres and a motor geom, sites, default classes and childclass, six
passive strings with the "0 l0" dead band, three cables driven by `general` actuators with filter
dynamics and an affine bias), our own export read back, MuJoCo free flight against ours, and the
refusals of what is not class-1.

Measured agreement of node positions (tools.mjcf_check.free_flight: RK4, dt = 1e-4 s on both
sides, no gravity, no contact, largest difference over 20 times in 0.2 s;
``pytest tests/test_mjcf_import.py -k free_flight -s`` prints them): our export read back
2e-14 to 4e-14 m; the 3-bar with its sites on the rod axes 1.5e-13 m; the same 3-bar with every
site 1 cm off its axis 1.7e-2 m, as large as the motion itself (the nodes move up to 2.6e-2 m):
off-axis sites twist MuJoCo's rods about their axes, which a class-1 rod cannot do (docs/mjcf.md).
"""
import json
import math

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.rod_mass import mass_moments
from tensegrity_gym.io.mjcf import from_mjcf, to_mjcf
from tensegrity_gym.tools.mjcf_check import free_flight

#: the 3-bar: {o} each site's distance from its rod's axis (m), {b0} the cables' bias (N), {motor}
#: the motor geom's type and size
THREE_BAR = """<mujoco model="three_bar">
  <compiler angle="degree" inertiafromgeom="true" autolimits="true"/>
  <option timestep="0.001" gravity="0 0 -9.81" integrator="RK4"/>
  <default>
    <geom contype="1" conaffinity="1" condim="3" friction="0.8 0.005 0.0001" density="1000"/>
    <site type="sphere" size="0.008"/>
    <tendon width="0.004" rgba="0.9 0.3 0.2 1"/>
    <default class="rod">
      <geom type="capsule" size="0.012" mass="0.4" rgba="0.2 0.2 0.2 1"/>
      <default class="cap">
        <geom type="sphere" size="0.035" mass="0.1"/>
      </default>
      <default class="motor">
        <geom {motor}/>
      </default>
    </default>
    <default class="passive">
      <tendon stiffness="1000" damping="5"/>
    </default>
    <default class="cable">
      <tendon stiffness="0" damping="0"/>
      {cable}
    </default>
  </default>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1"/>
    <geom name="floor" type="plane" size="5 5 0.1" friction="0.9 0.005 0.0001"/>
    <body name="rod0" pos="0.033494 0.125 0.5" quat="0.927161 -0.09697 -0.361897 0" childclass="rod">
      <freejoint name="rod0"/>
      <geom name="rod0" fromto="0 0 -0.695 0 0 0.695"/>
      <geom name="cap0a" class="cap" pos="0 0 -0.695"/>
      <geom name="cap0b" class="cap" pos="0 0 0.695"/>
      <geom name="motor0" class="motor" pos="0 0 0.45"/>
      <site name="n0_b01" pos="{o} 0 -0.68"/>
      <site name="n0_b20" pos="0 {o} -0.68"/>
      <site name="n0_v03" pos="-{o} 0 -0.68"/>
      <site name="n4_t34" pos="{o} 0 0.68"/>
      <site name="n4_t45" pos="0 {o} 0.68"/>
      <site name="n4_v14" pos="-{o} 0 0.68"/>
    </body>
    <body name="rod1" pos="-0.125 -0.033494 0.5" quat="0.927161 0.361897 0.09697 0" childclass="rod">
      <freejoint name="rod1"/>
      <geom name="rod1" fromto="0 0 -0.695 0 0 0.695"/>
      <geom name="cap1a" class="cap" pos="0 0 -0.695"/>
      <geom name="cap1b" class="cap" pos="0 0 0.695"/>
      <geom name="motor1" class="motor" pos="0 0 0.45"/>
      <site name="n1_b01" pos="{o} 0 -0.68"/>
      <site name="n1_b12" pos="0 {o} -0.68"/>
      <site name="n1_v14" pos="-{o} 0 -0.68"/>
      <site name="n5_t45" pos="{o} 0 0.68"/>
      <site name="n5_t53" pos="0 {o} 0.68"/>
      <site name="n5_v25" pos="-{o} 0 0.68"/>
    </body>
    <body name="rod2" pos="0.091506 -0.091506 0.5" quat="0.927161 -0.264927 0.264927 0" childclass="rod">
      <freejoint name="rod2"/>
      <geom name="rod2" fromto="0 0 -0.695 0 0 0.695"/>
      <geom name="cap2a" class="cap" pos="0 0 -0.695"/>
      <geom name="cap2b" class="cap" pos="0 0 0.695"/>
      <geom name="motor2" class="motor" pos="0 0 0.45"/>
      <site name="n2_b12" pos="{o} 0 -0.68"/>
      <site name="n2_b20" pos="0 {o} -0.68"/>
      <site name="n2_v25" pos="-{o} 0 -0.68"/>
      <site name="n3_t34" pos="{o} 0 0.68"/>
      <site name="n3_t53" pos="0 {o} 0.68"/>
      <site name="n3_v03" pos="-{o} 0 0.68"/>
    </body>
  </worldbody>
  <tendon>
    <spatial name="b01" class="passive" springlength="0 0.8"><site site="n0_b01"/><site site="n1_b01"/></spatial>
    <spatial name="b12" class="passive" springlength="0 0.8"><site site="n1_b12"/><site site="n2_b12"/></spatial>
    <spatial name="b20" class="passive" springlength="0 0.8"><site site="n2_b20"/><site site="n0_b20"/></spatial>
    <spatial name="t34" class="passive" springlength="0 0.8"><site site="n3_t34"/><site site="n4_t34"/></spatial>
    <spatial name="t45" class="passive" springlength="0 0.8"><site site="n4_t45"/><site site="n5_t45"/></spatial>
    <spatial name="t53" class="passive" springlength="0 0.8"><site site="n5_t53"/><site site="n3_t53"/></spatial>
    <spatial name="v03" class="cable"><site site="n0_v03"/><site site="n3_v03"/></spatial>
    <spatial name="v14" class="cable"><site site="n1_v14"/><site site="n4_v14"/></spatial>
    <spatial name="v25" class="cable"><site site="n2_v25"/><site site="n5_v25"/></spatial>
  </tendon>
  <actuator>
    <general name="m03" class="cable" tendon="v03"/>
    <general name="m14" class="cable" tendon="v14"/>
    <general name="m25" class="cable" tendon="v25"/>
  </actuator>
</mujoco>
"""
#: the cables' actuator default: rest length (760 + 800 u) / 800 m = 0.95 + u, u filtered (0.05 s)
GENERAL = ('<general dyntype="filter" dynprm="0.05" gainprm="800" biastype="affine" biasprm="760 -800 -20" '
           'ctrlrange="-0.3 0.1" forcerange="-300 0"/>')
CYLINDER = 'type="cylinder" size="0.03 0.04" mass="0.15"'


def three_bar(o=0.0, cable=GENERAL, motor=CYLINDER):
    return THREE_BAR.format(o=o, cable=cable, motor=motor)


def _line_of(text, snippet):
    lines = [i + 1 for i, line in enumerate(text.splitlines()) if snippet in line]
    assert len(lines) == 1, snippet
    return lines[0]


def test_three_bar_fixture():
    s, r = from_mjcf(three_bar(o=0.02))
    assert (s.n_nodes, s.n_bars, s.n_strings) == (6, 3, 9)
    assert r.rods == ["rod0", "rod1", "rod2"] and r.strings[6:] == ["v03", "v14", "v25"]
    np.testing.assert_allclose(s.rest_length[:6], 0.8)               # the "0 l0" dead band: rest length l0
    np.testing.assert_allclose(s.rest_length[6:], 0.95)              # the cables at u = 0
    np.testing.assert_allclose(s.stiffness, [1000.0] * 6 + [800.0] * 3)
    np.testing.assert_allclose(s.damping, [5.0] * 6 + [20.0] * 3)
    np.testing.assert_allclose(s.bar_mass, 0.75)                     # 0.4 + 2 x 0.1 + 0.15 kg
    np.testing.assert_allclose(s.bar_lengths, 1.36, atol=1e-12)      # between the sites' axis points
    assert s.mass_points is not None and s.com_fraction[0] > 0.5     # the motor sits off-centre
    assert r.actuated_strings == [6, 7, 8]
    a = r.actuated[0]
    assert (a.actuator, a.tendon, a.time_constant, a.max_tension) == ("m03", "v03", 0.05, 300.0)
    np.testing.assert_allclose(a.rest_length_range, (0.65, 1.05))
    assert a.per_ctrl == pytest.approx(1.0)
    assert math.isclose(r.max_axis_offset, 0.02, rel_tol=1e-9) and r.max_axial_shift < 1e-12
    assert r.cap_radius == 0.035 and r.timestep == 0.001 and r.gravity == (0.0, 0.0, -9.81)
    assert r.floor["friction"] == 0.9 and r.floor["normal"] == [0.0, 0.0, 1.0]
    assert r.dropped == [] and r.notes == []
    json.dumps(r.to_dict())


mujoco = pytest.importorskip("mujoco")


@pytest.mark.parametrize("motor", [CYLINDER, 'type="box" size="0.03 0.03 0.04" density="800"',
                                   'type="ellipsoid" size="0.03 0.03 0.05" mass="0.2"',
                                   'type="capsule" size="0.02 0.04" density="2000"', 'type="sphere" size="0.03"'])
def test_masses_and_inertia_as_mujoco_computes_them(motor):
    xml = three_bar(motor=motor)
    s, r = from_mjcf(xml)
    M = mujoco.MjModel.from_xml_string(xml)
    D = mujoco.MjData(M)
    mujoco.mj_forward(M, D)
    for j, name in enumerate(r.rods):
        b = mujoco.mj_name2id(M, mujoco.mjtObj.mjOBJ_BODY, name)
        a, c = s.bars[j]
        L, sig = s.bar_lengths[j], s.com_fraction[j]
        J = mass_moments(L, s.bar_mass[j], sig, None if s.mass_points is None else s.mass_points[j])[1]
        assert s.bar_mass[j] == pytest.approx(M.body_mass[b], rel=1e-12)
        assert sorted(M.body_inertia[b])[1:] == pytest.approx([J, J], rel=1e-9)
        np.testing.assert_allclose(s.nodes[a] + sig * (s.nodes[c] - s.nodes[a]), D.xipos[b], atol=1e-12)


def test_free_flight_of_the_three_bar_agrees_with_mujoco():
    """RK4, dt = 1e-4 s on both sides, 0.2 s, no gravity, no contact (tools.mjcf_check)."""
    f = free_flight(three_bar())
    print(f"3-bar, sites on the axes: nodes moved {f['moved']:.3g} m, |ours - MuJoCo| {f['error']:.3g} m")
    assert f["moved"] > 5e-3 and f["error"] < 1e-9                    # measured 1.5e-13 m
    # sites 1 cm off the axes: the axis mapping changes the motion (measured 1.7e-2 m)
    f = free_flight(three_bar(o=0.01))
    print(f"3-bar, sites 1 cm off the axes: nodes moved {f['moved']:.3g} m, |ours - MuJoCo| {f['error']:.3g} m")
    assert 1e-3 < f["error"] < 3e-2


def _prism_mass_points():
    return tg.prism(3, prestress=100, gravity=(0, 0, -9.81)).replace(
        mass_points=[[(0.0, 0.2), (0.7, 0.8)], None, [(0.1, 0.5), (1.0, 0.5)]])


def _prism_with_anchor():
    """A prism hung from a fixed anchor node by two taut, undamped strings."""
    p = tg.prism(3, prestress=100)
    nodes = np.vstack([p.nodes, [[0.0, 0.0, 2.0]]])
    hang = np.linalg.norm(nodes[[3, 4]] - nodes[6], axis=1)
    return tg.Structure(nodes, p.bars, np.vstack([p.strings, [[3, 6], [4, 6]]]), bar_mass=[1.0, 2.0, 3.0],
                        stiffness=np.r_[p.stiffness, 50.0, 60.0], rest_length=np.r_[p.rest_length, 0.9 * hang])


ROUND_TRIP = {"prism": lambda: tg.prism(3, prestress=100, damping=1.5),
              "icosahedron": lambda: tg.icosahedron(gravity=(0, 0, -9.81)),
              "mass_points": _prism_mass_points, "anchor": _prism_with_anchor}


@pytest.mark.parametrize("name", sorted(ROUND_TRIP))
def test_export_then_import_gives_the_same_structure(name):
    s = ROUND_TRIP[name]()
    t, r = from_mjcf(to_mjcf(s))
    np.testing.assert_array_equal(t.bars, s.bars)
    np.testing.assert_array_equal(t.strings, s.strings)
    for f in ("nodes", "stiffness", "rest_length", "damping", "bar_mass", "com_fraction"):
        np.testing.assert_allclose(getattr(t, f), getattr(s, f), rtol=0, atol=1e-9, err_msg=f)
    J = lambda x, j: mass_moments(x.bar_lengths[j], x.bar_mass[j], x.com_fraction[j],
                                  None if x.mass_points is None else x.mass_points[j])[1]
    np.testing.assert_allclose([J(t, j) for j in range(t.n_bars)], [J(s, j) for j in range(s.n_bars)], atol=1e-9)
    assert (t.gravity is None) == (s.gravity is None) and (s.mass_points is None) == (t.mass_points is None)
    assert r.max_axis_offset < 1e-12 and r.actuated == [] and r.notes == []


@pytest.mark.parametrize("name", ["mass_points", "anchor"])
def test_free_flight_of_our_export_read_back(name):
    s = ROUND_TRIP[name]()
    on_rod = np.isin(np.arange(s.n_nodes), s.bars.ravel())[:, None]     # released off equilibrium
    s = s.replace(nodes=s.nodes + 0.02 * on_rod * np.random.default_rng(0).standard_normal(s.nodes.shape),
                  rest_length=s.rest_length)
    f = free_flight(to_mjcf(s))
    print(f"our export of {name}: nodes moved {f['moved']:.3g} m, |ours - MuJoCo| {f['error']:.3g} m")
    assert f["moved"] > 1e-3 and f["error"] < 1e-9                    # measured ~1e-13 m


ORIENTATIONS = [("degree", "xyz", 'quat="0.9 0.1 -0.3 0.2"'), ("degree", "xyz", 'axisangle="1 2 3 40"'),
                ("radian", "xyz", 'axisangle="1 2 3 0.7"'), ("degree", "xyz", 'euler="10 -20 30"'),
                ("radian", "ZYX", 'euler="0.1 -0.2 0.3"'), ("degree", "xYz", 'euler="15 25 -35"'),
                ("degree", "xyz", 'xyaxes="1 1 0 -1 1 0.3"'), ("degree", "xyz", 'zaxis="0.3 -1 0.5"')]


@pytest.mark.parametrize("angle, seq, orient", ORIENTATIONS)
@pytest.mark.parametrize("geom", ['size="0.01" fromto="0 0 -0.5 0 0 0.5"', 'size="0.01 0.5" quat="0 1 0 0"'])
def test_frames_as_mujoco_reads_them(angle, seq, orient, geom):
    xml = f"""<mujoco><compiler angle="{angle}" eulerseq="{seq}"/><option gravity="0 0 0"/><worldbody>
      <body name="a" pos="0.1 0.2 0.3" {orient}><freejoint/><geom type="cylinder" {geom}/>
        <site name="a0" pos="0 0 -0.4"/><site name="a1" pos="0 0 0.4"/></body>
      <body name="b" pos="0.5 0 0.3"><freejoint/><geom type="capsule" size="0.01" fromto="-0.3 0 0 0.3 0 0"/>
        <site name="b0" pos="-0.3 0 0"/><site name="b1" pos="0.3 0 0"/></body></worldbody>
      <tendon><spatial stiffness="10"><site site="a1"/><site site="b0"/></spatial>
        <spatial stiffness="10"><site site="a0"/><site site="b1"/></spatial></tendon></mujoco>"""
    s, r = from_mjcf(xml)
    M = mujoco.MjModel.from_xml_string(xml)
    D = mujoco.MjData(M)
    mujoco.mj_forward(M, D)
    for i, sites in enumerate(r.node_sites):
        np.testing.assert_allclose(s.nodes[i], D.site_xpos[mujoco.mj_name2id(M, mujoco.mjtObj.mjOBJ_SITE, sites[0])],
                                   atol=1e-12)


@pytest.mark.parametrize("cable, check", [
    ('<position kp="800" kv="20" ctrlrange="0.6 1.1" forcerange="-300 0"/>',
     lambda s, r: r.actuated[0].rest_length_range == pytest.approx((0.6, 1.1)) and s.rest_length[6] == 0.6
     and s.damping[6] == 20.0 and r.actuated[0].per_ctrl == 1.0),
    ('<intvelocity kp="800" ctrlrange="-0.1 0.1" actrange="0.6 1.1"/>',
     lambda s, r: r.actuated[0].rate_range == pytest.approx((-0.1, 0.1)) and "push" in " ".join(r.notes)),
    ('<motor ctrlrange="-50 0"/>',
     lambda s, r: s.n_strings == 6 and r.actuated == [] and any("force actuators" in d for d in r.dropped)
     and any("no spring" in d for d in r.dropped)),
])
def test_actuator_shortcuts(cable, check):
    s, r = from_mjcf(three_bar(cable=cable))
    assert check(s, r), r.summary()


def test_single_springlength_and_parallel_tendons_are_reported():
    xml = three_bar().replace('springlength="0 0.8"><site site="n0_b01"/>', 'springlength="0.8"><site site="n0_b01"/>')
    xml = xml.replace("</tendon>", '  <spatial name="b01bis" class="passive" springlength="0 0.7">'
                                   '<site site="n1_b01"/><site site="n0_b01"/></spatial>\n  </tendon>')
    s, r = from_mjcf(xml)
    assert s.n_strings == 9 and s.stiffness[0] == 2000.0 and s.rest_length[0] == pytest.approx(0.75)
    assert r.strings[0] == "b01+b01bis"
    assert any("'b01'" in n and "pushes below" in n for n in r.notes)
    assert any("springs in parallel" in n for n in r.notes)


REFUSALS = [
    ("hinge", '<freejoint name="rod1"/>', '<joint name="knee" type="hinge" axis="0 1 0"/>', "joint", "knee"),
    ("slide", '<freejoint name="rod1"/>', '<joint name="rail" type="slide"/>', "joint", "rail"),
    ("equality", "</actuator>", '</actuator>\n  <equality>\n    <connect name="glue" body1="rod0" body2="rod1" '
     'anchor="0 0 0"/>\n  </equality>', "connect", "glue"),
    ("3-site tendon", '<spatial name="v03" class="cable"><site site="n0_v03"/>',
     '<spatial name="v03" class="cable"><site site="n0_v03"/><site site="n1_v14"/>', "spatial", "v03"),
    ("pulley", '<site site="n0_v03"/><site site="n3_v03"/>',
     '<site site="n0_v03"/>\n<pulley name="wheel" divisor="2"/><site site="n3_v03"/>', "pulley", "wheel"),
    ("nested body", '<geom name="motor0" class="motor" pos="0 0 0.45"/>', '<body name="arm"><geom size="0.01"/></body>',
     "body", "arm"),
    ("welded body", '<freejoint name="rod2"/>', "", "body", "rod2"),
]


@pytest.mark.parametrize("what, old, new, tag, name", REFUSALS, ids=[r[0] for r in REFUSALS])
def test_refusals_name_the_element_and_its_line(what, old, new, tag, name):
    xml = three_bar().replace(old, new, 1)
    line = _line_of(xml, f'<{tag} name="{name}"')
    with pytest.raises(ValueError) as e:
        from_mjcf(xml)
    msg = str(e.value)
    assert f"line {line}:" in msg and f"<{tag} name='{name}'>" in msg, msg


def test_bad_files(tmp_path):
    with pytest.raises(ValueError, match="line 3: not well-formed XML"):
        from_mjcf("<mujoco>\n<worldbody>\n</mujoco>")
    with pytest.raises(ValueError, match="not <mujoco>"):
        from_mjcf("<robot/>")
    xml = three_bar().replace('mass="0.4"', 'mass="heavy"')
    line = _line_of(xml, '<geom name="rod0"')
    with pytest.raises(ValueError, match=rf"line {line}: <geom name='rod0'>: mass='heavy' \(from its default class\) "
                                         "is not a list of numbers"):
        from_mjcf(xml)
    with pytest.raises(ValueError, match="default class 'kap' is not defined"):
        from_mjcf(three_bar().replace('name="cap0a" class="cap"', 'name="cap0a" class="kap"'))
    with pytest.raises(ValueError, match="site 'nowhere' does not exist"):
        from_mjcf(three_bar().replace('<site site="n0_v03"/>', '<site site="nowhere"/>'))
    with pytest.raises(ValueError, match="cannot include files"):
        from_mjcf('<mujoco><include file="parts.xml"/></mujoco>')
    with pytest.raises(FileNotFoundError):
        from_mjcf(tmp_path / "missing.xml")


def test_includes_resolved_from_the_model_folder(tmp_path):
    xml = three_bar()
    start, end = xml.index("\n  <default>") + 1, xml.index("\n  </default>\n") + len("\n  </default>\n")
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "defaults.xml").write_text("<mujoco>\n" + xml[start:end] + "</mujoco>\n")
    main = tmp_path / "robot.xml"
    main.write_text(xml[:start] + '  <include file="parts/defaults.xml"/>\n' + xml[end:])
    s, r = from_mjcf(main)
    t, _ = from_mjcf(xml)
    np.testing.assert_array_equal(s.rest_length, t.rest_length)
    main.write_text(xml[:start] + '  <include file="parts/none.xml"/>\n' + xml[end:])
    with pytest.raises(ValueError, match=r"robot.xml line 4: <include file='parts/none.xml'>: cannot be read"):
        from_mjcf(main)


def test_cli_import_and_structure_paths(tmp_path, capsys):
    from tensegrity_gym.tools.cli import main
    path = tmp_path / "robot.xml"
    path.write_text(three_bar(o=0.02))
    out, rep = tmp_path / "robot.json", tmp_path / "report.json"
    assert main(["import", str(path), "--out", str(out), "--report", str(rep)]) == 0
    printed = capsys.readouterr().out
    assert "actuated string 6 (v03) by m03" in printed and "offset from a rod axis 0.02 m" in printed
    s = tg.load_json(out)
    assert s.n_strings == 9 and json.loads(rep.read_text())["actuated"][0]["tendon"] == "v03"
    assert main(["import", str(path), "--out", str(out)]) == 4                  # exists, no --force
    bad = tmp_path / "hinge.xml"
    bad.write_text(three_bar().replace('<freejoint name="rod1"/>', '<joint name="knee" type="hinge"/>'))
    assert main(["import", str(bad), "--out", str(tmp_path / "h.json")]) == 3
    err = capsys.readouterr().err
    line = _line_of(bad.read_text(), 'name="knee"')
    assert f"line {line}: <joint name='knee'>: a hinge joint is not class-1" in err and "Traceback" not in err
    assert main(["import", str(tmp_path / "none.xml"), "--out", str(tmp_path / "n.json")]) == 3
    # wherever a structure path is accepted
    np.testing.assert_array_equal(tg.load_structure(str(path)).nodes, s.nodes)
    import gymnasium as gym
    env = gym.make("TensegrityRoll-v0", structure=str(path))
    obs, _ = env.reset(seed=0)
    assert np.all(np.isfinite(obs))
    env.close()
