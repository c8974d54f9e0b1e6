"""System identification of ground contact: friction, normal stiffness and Hunt-Crossley damping
of a prism robot (gravity) dropped tilted onto the ground while sliding and spinning are
recovered from a 0.4 s record sampled every 10 ms; the command line's ``simulate --ground`` ->
``identify --ground`` round trip; bad input refused with one line."""
import json
import warnings

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.model import State
from tensegrity_gym.physics.evaluate import project
from tensegrity_gym.physics.geometry import node_positions
from tensegrity_gym.tools.cli import main
from tensegrity_gym.physics import contact as C
from tensegrity_gym.physics import pipeline
from tensegrity_gym.tools.sysid import SysIdWarning, identify

TRUE = {"friction": 0.6, "stiffness": 5e3, "damping": 5.0}          # 1, N/m, s/m
START = {"friction": 0.84, "stiffness": 3.25e3, "damping": 7.5}     # +40 %, -35 %, +50 %
FIT = ("friction", "ground_stiffness", "ground_damping")
NAMES = {"friction": "friction", "ground_stiffness": "stiffness", "ground_damping": "damping"}
DT, EVERY, T = 1e-3, 10, 0.4      # physics step s, steps per sample (10 ms), record length s
#: the damping cap of the command line and the envs at DT (physics.contact.impact_damping_cap, 0.2 kg rods)
CAP = C.impact_damping_cap([0.2], DT)


def _robot():
    """Prism robot (0.2 kg rods, gravity) tilted 12 degrees, its lowest cap 2 cm above the ground,
    moving at 0.8 m/s along x and spinning at 2 rad/s about z: it lands on one cap, tips onto the
    others and slides (impacts for the stiffness and damping, sliding for the friction)."""
    s = tg.prism(3, radius=0.15, height=0.25, bar_mass=0.2, stiffness=1000.0, prestress=20.0, damping=2.0,
                 gravity=(0, 0, -9.81))
    a = np.radians(12.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    x = (s.nodes - s.nodes.mean(0)) @ R.T
    x[:, 2] += 0.02 + 0.02 - x[:, 2].min()
    v = np.array([0.8, 0.0, 0.0]) + np.cross([0.0, 0.0, 2.0], x - x.mean(0))
    return s.replace(nodes=x, velocities=v)


@pytest.fixture(scope="module")
def record():
    s = _robot()
    model = tg.compile_model(s)
    st = tg.initial_state(model)
    st = State(*project(model, st.q, st.qd))
    gc, cs = C.GroundContact(radius=0.02, max_damping=CAP, **TRUE), C.init_contact_state(model, 1)
    out = [node_positions(model, st.q)[0]]
    for _ in range(int(round(T / (DT * EVERY)))):
        st, cs = pipeline.step(model, st, DT, "semi_implicit_euler", n_steps=EVERY, contact=gc, cstate=cs)
        out.append(node_positions(model, st.q)[0])
    nodes = np.array(out)
    return s, model, np.arange(len(out)) * DT * EVERY, nodes


def test_recovers_friction_stiffness_and_damping(record):
    """Noise-free: from start values 35-50 % off, friction and stiffness to 1 %, damping (seen in a
    few impacts sampled every 10 ms) to 5 %."""
    _, model, t, nodes = record
    assert nodes[..., 2].min() < 0.02 < nodes[0, :, 2].min()      # it lands
    with warnings.catch_warnings():
        warnings.simplefilter("error", SysIdWarning)
        r = identify(model, t, nodes, fit=FIT, dt=DT, contact=C.GroundContact(radius=0.02, max_damping=CAP, **START))
    assert r.ok, r.message
    assert r.integrator == "semi_implicit_euler" and r.window_s == pytest.approx(0.05)
    err = {g: float(r.values[g][0] / TRUE[NAMES[g]] - 1) for g in FIT}
    assert abs(err["friction"]) < 0.01 and abs(err["ground_stiffness"]) < 0.01, err
    assert abs(err["ground_damping"]) < 0.05, err
    assert r.rms_m < 0.1 * r.rms_initial_m
    assert r.contact.friction == r.values["friction"][0]
    assert r.contact.tangential_stiffness == r.contact.stiffness     # it followed the normal stiffness
    d = r.to_dict()
    assert d["units"]["ground_stiffness"] == "N/m" and d["contact"]["damping"] == r.values["ground_damping"][0]


def test_recovers_contact_with_noise(record):
    """0.5 mm of position noise: each value within 3 standard errors of the truth, friction to 3 %."""
    _, model, t, nodes = record
    noisy = nodes + 5e-4 * np.random.default_rng(0).standard_normal(nodes.shape)
    r = identify(model, t, noisy, fit=FIT, dt=DT, contact={"radius": 0.02, "max_damping": CAP, **START})
    assert r.ok, r.message
    for g in FIT:
        v, se = r.values[g][0], r.std_errors[g][0]
        assert abs(v - TRUE[NAMES[g]]) < 3 * se, (g, v, se)
    assert abs(r.values["friction"][0] / TRUE["friction"] - 1) < 0.03


def test_contact_input_errors(record):
    _, model, t, nodes = record
    with pytest.raises(ValueError, match="'friction' is a ground contact parameter"):
        identify(model, t, nodes, fit=("friction",))
    with pytest.raises(ValueError, match="contact: unknown field 'mu'"):
        identify(model, t, nodes, fit=("friction",), contact={"mu": 0.5})
    sunk = nodes.copy()
    sunk[3, 1, 2] = -0.001
    with pytest.raises(ValueError, match=r"sample 3 .* node 1 is at z = -0.001 m, below the ground"):
        identify(model, t, sunk, fit=("friction",), contact={})
    with pytest.raises(ValueError, match="starts at 0.0"):
        identify(model, t, nodes, fit=("ground_damping",), contact={"damping": 0.0})
    with pytest.raises(ValueError, match="no ground contact"):
        identify(model, t, nodes, fit=("friction",), contact={}, jacobian="torch")


def test_cli_round_trip_and_errors(record, tmp_path, capsys):
    s = record[0]
    robot = tmp_path / "robot.json"
    tg.save_json(s, robot)
    rec = tmp_path / "rec.npz"
    assert main(["simulate", str(robot), "--ground", "--friction", "0.6", "--ground-stiffness", "5000",
                 "--ground-damping", "5", "--duration", str(T), "--dt", str(DT), "--record-every", str(EVERY),
                 "--integrator", "semi_implicit_euler", "--out", str(rec), "--no-progress"]) == 0
    np.testing.assert_allclose(np.load(rec)["nodes"], record[3], atol=1e-9)    # the same motion
    out = tmp_path / "fit.json"
    base = ["identify", str(robot), str(rec), "--out", str(out), "--dt", str(DT)]
    code = main(base + ["--ground", "--fit", *FIT, "--initial", "friction=0.84", "--ground-stiffness", "3250",
                        "--ground-damping", "7.5"])
    assert code == 0, capsys.readouterr()
    d = json.loads(out.read_text())
    assert d["ok"] and d["integrator"] == "semi_implicit_euler"
    assert d["initial"]["friction"] == [0.84] and d["initial"]["ground_stiffness"] == [3250.0]
    assert d["values"]["friction"][0] == pytest.approx(0.6, rel=0.01)
    assert d["values"]["ground_stiffness"][0] == pytest.approx(5e3, rel=0.01)
    assert d["values"]["ground_damping"][0] == pytest.approx(5.0, rel=0.05)
    assert "friction     ground" in capsys.readouterr().out
    # bad input: one line, no traceback
    base += ["--force"]
    for argv, code, msg in (
            (base + ["--fit", "friction"], 2, "--fit friction: a ground contact parameter; add --ground"),
            (base + ["--initial", "ground_damping=3"], 2, "--initial ground_damping: a ground contact parameter"),
            (base + ["--friction", "0.5"], 2, "--friction: a terrain contact option; add --ground"),
            (base + ["--ground", "--fit", "friction", "--initial", "friction=0,1"], 2, "is one number"),
            (base + ["--terrain", "x.json", "--fit", "friction"], 2, "unrecognized arguments: --terrain")):
        assert _exit(argv) == code
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err, err
    sunk = dict(np.load(rec))
    sunk["nodes"] = sunk["nodes"] - 0.06            # a recording in another frame: caps below z = 0
    np.savez(tmp_path / "sunk.npz", **sunk)
    argv = ["identify", str(robot), str(tmp_path / "sunk.npz"), "--out", str(out), "--force", "--ground",
            "--fit", "friction"]
    assert main(argv) == 3
    err = capsys.readouterr().err
    assert "sample 0 (t = 0 s), node" in err and "below the ground (z = 0 m)" in err and err.count("\n") == 1


def _exit(argv):
    """main's exit status, also where the argument parser exits."""
    try:
        return main(argv)
    except SystemExit as e:
        return e.code
