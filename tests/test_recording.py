"""Recordings of a real robot (tensegrity_gym.io.recording): the .npz format's round trip, what a
real recording legitimately holds (irregular time stamps, tracking noise, missing frames, repeated
stamps: accepted and reported, never interpolated), each malformed recording refused with the
frame and the field named, and the Rutgers/Yale JSON importer on synthetic files written here in
that layout (made-up numbers) through the command line."""
import json
import warnings

import numpy as np
import pytest

from tensegrity_gym.io.recording import GAP_FACTOR, Recording, RecordingWarning, load_recording, save_recording
from tensegrity_gym.io.recording_rutgers import RUTGERS_SCALE, import_rutgers
from tensegrity_gym.tools.cli import main

L_ROD = 0.325           # m, end-cap centre to end-cap centre
BARS = np.array([[0, 1], [2, 3], [4, 5]])


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _end_points(t):
    """(F, 3, 2, 3) end points of three rods of length L_ROD tumbling and drifting, m."""
    base = [np.array([1.0, 0.1, 0.3]), np.array([-0.2, 1.0, 0.5]), np.array([0.3, -0.4, 1.0])]
    out = np.zeros((t.size, 3, 2, 3))
    for i, ti in enumerate(t):
        R = _rot([0.3, 1.0, 0.2], 0.8 * ti)
        for r, d in enumerate(base):
            c = np.array([0.2 * ti, 0.05 * r, 0.15]) + 0.05 * np.array([np.cos(r), np.sin(r), 0.0])
            u = R @ (d / np.linalg.norm(d))
            out[i, r] = c - 0.5 * L_ROD * u, c + 0.5 * L_ROD * u
    return out


def _synthetic(F=40, noise=0.0, seed=0, irregular=True, mid_marker=True, **kw):
    """A recording of three rods: end caps (fractions 0, 1) and, with ``mid_marker``, a marker 0.1 m
    from node a of rod 1; irregular frame times, six actuators with rest-length and motor commands
    at their own times, IMU and encoder readings."""
    rng = np.random.default_rng(seed)
    dt = rng.uniform(0.02, 0.05, F - 1) if irregular else np.full(F - 1, 0.03)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    ep = _end_points(t)
    rod, along = [0, 0, 1, 1, 2, 2], [0.0, 1.0, 0.0, 1.0, 0.0, 1.0]
    pts = [ep[:, 0, 0], ep[:, 0, 1], ep[:, 1, 0], ep[:, 1, 1], ep[:, 2, 0], ep[:, 2, 1]]
    if mid_marker:
        rod.append(1)
        along.append(0.1 / L_ROD)
        pts.append(ep[:, 1, 0] + 0.1 / L_ROD * (ep[:, 1, 1] - ep[:, 1, 0]))
    pts = np.stack(pts, axis=1) + noise * rng.standard_normal((F, len(rod), 3))
    C = 5
    args = dict(t=t, points=pts, point_rod=rod, point_along=along, rod_lengths=[L_ROD] * 3,
                actuators=tuple(f"cable_{j}" for j in range(6)),
                command_t=np.sort(rng.uniform(0, t[-1], C)),
                commands={"rest_length": rng.uniform(0.1, 0.2, (C, 6)), "motor": rng.uniform(-1, 1, (C, 6))},
                imu_t=t[::2], imu_accel=rng.standard_normal((t[::2].size, 3, 3)),
                imu_gyro=rng.standard_normal((t[::2].size, 3, 3)),
                encoder_t=t[::3], encoder=rng.uniform(0.1, 0.2, (t[::3].size, 6)),
                metadata={"robot": "synthetic 3-bar", "source": "tests"})
    args.update(kw)
    return Recording(**args), ep


def _refused(match_frame, match_field, **kw):
    with pytest.raises(ValueError) as e:
        _synthetic(**kw)
    msg = str(e.value)
    if match_frame is not None:
        assert f"frame {match_frame}," in msg, msg
    assert f"field '{match_field}'" in msg, msg
    return msg


# ---------------------------------------------------------------------- the format
def test_round_trip(tmp_path):
    rec, _ = _synthetic()
    path = tmp_path / "rec.npz"
    save_recording(path, rec)
    with warnings.catch_warnings():
        warnings.simplefilter("error")      # a clean recording loads without a warning
        back = load_recording(path)
    for k in ("t", "points", "point_rod", "point_along", "rod_lengths", "command_t", "imu_t", "imu_accel",
              "imu_gyro", "encoder_t", "encoder"):
        np.testing.assert_array_equal(getattr(back, k), getattr(rec, k), err_msg=k)
    assert back.along == "fraction" and back.actuators == rec.actuators
    assert set(back.commands) == {"rest_length", "motor"}
    for k in rec.commands:
        np.testing.assert_array_equal(back.commands[k], rec.commands[k])
    assert back.metadata == rec.metadata
    assert back.metadata["robot"] == "synthetic 3-bar"
    assert back.metadata["units"]["points"] == "m" and back.metadata["command_units"]["rest_length"] == "m"
    assert dict(back.report) == dict(rec.report)
    with pytest.raises((AttributeError, TypeError)):
        back.t = np.zeros(3)                              # frozen
    with pytest.raises(ValueError):
        back.points[0, 0, 0] = 1.0                        # read-only arrays


def test_distances_along_the_rod_in_metres(tmp_path):
    rec, ep = _synthetic(mid_marker=True)
    m = Recording(t=rec.t, points=rec.points, point_rod=rec.point_rod,
                  point_along=rec.point_along * L_ROD, rod_lengths=rec.rod_lengths, along="m")
    np.testing.assert_allclose(m.fractions(), rec.fractions(), atol=1e-15)
    save_recording(tmp_path / "m.npz", m)
    assert load_recording(tmp_path / "m.npz").along == "m"
    np.testing.assert_allclose(m.end_points(), ep, atol=1e-12)


def test_irregular_time_stamps_are_kept_as_recorded():
    rec, ep = _synthetic(irregular=True)
    dt = np.diff(rec.t)
    assert dt.std() > 0.005                       # really irregular
    assert rec.report["gaps"] == [] and rec.report["duplicate_times"] == []
    assert rec.report["median_interval_s"] == pytest.approx(np.median(dt))
    np.testing.assert_allclose(rec.end_points(), ep, atol=1e-12)
    t, nodes, mask = rec.node_trajectory(BARS)
    np.testing.assert_array_equal(t, rec.t)
    assert mask.all()
    np.testing.assert_allclose(nodes.reshape(-1, 3, 2, 3), ep, atol=1e-12)


def test_tracking_noise_is_accepted_and_end_points_are_least_squares():
    rec, ep = _synthetic(noise=0.003, seed=3)
    err = np.linalg.norm(rec.end_points() - ep, axis=-1)
    assert err.max() < 0.02 and err.mean() < 0.006
    # rod 1's third marker: its end points are the least-squares line through the three points
    r1 = rec.end_points()[:, 1]
    s = rec.fractions()[rec.point_rod == 1]
    x = rec.points[:, rec.point_rod == 1]
    A = np.stack([1 - s, s], axis=1)
    for i in (0, 7):
        sol, *_ = np.linalg.lstsq(A, x[i], rcond=None)
        np.testing.assert_allclose(r1[i], sol, atol=1e-12)


def test_gaps_and_missing_points_are_reported_not_interpolated(tmp_path):
    rec, _ = _synthetic(irregular=False)
    t = rec.t.copy()
    t[20:] += 0.5                                            # a 0.53 s pause of the tracker after frame 19
    pts = rec.points.copy()
    pts[5] = np.nan                                          # frame 5 dropped
    pts[8, 2] = np.nan                                       # rod 1's node a lost in frame 8 ...
    pts[9, [2, 3]] = np.nan                                  # ... and rod 1's end caps in frame 9
    pts[9, 6] = np.nan                                       # (and its marker): no rod-1 pose there
    gap = Recording(t=t, points=pts, point_rod=rec.point_rod, point_along=rec.point_along,
                    rod_lengths=rec.rod_lengths, metadata={"robot": "gappy"})
    rep = gap.report
    assert rep["gaps"] == [{"after_frame": 19, "t_s": pytest.approx(t[19]), "length_s": pytest.approx(0.53)}]
    assert rep["dropped_frames"] == [5]
    assert rep["missing_points"] == 7 + 1 + 3
    assert rep["frames_with_missing_points"] == 3
    assert rep["frames_without_rod_pose"] == [1, 2, 1]       # rod 1 in frames 5 and 9 (frame 8 has two points)
    assert any("gap" in w for w in rep["warnings"]) and any("missing" in w for w in rep["warnings"])
    assert 0.53 > GAP_FACTOR * rep["median_interval_s"]
    save_recording(tmp_path / "gap.npz", gap)
    with pytest.warns(RecordingWarning) as caught:
        back = load_recording(tmp_path / "gap.npz")
    said = " ".join(str(w.message) for w in caught)
    assert "gap" in said and "missing point" in said
    assert np.isnan(back.points[5]).all()                    # nothing filled in
    ep = back.end_points()
    assert np.isnan(ep[5]).all() and np.isnan(ep[9, 1]).all() and np.isfinite(ep[8, 1]).all()
    tt, nodes, mask = back.node_trajectory(BARS)
    assert tt.size == t.size and not mask[5].any() and not mask[9, 2:4].any() and mask[9, [0, 1, 4, 5]].all()
    assert np.isnan(nodes[~mask]).all()


def test_repeated_time_stamps_are_reported_and_merged_only_on_request():
    rec, _ = _synthetic(irregular=False)
    t = rec.t.copy()
    t[11] = t[10]                                        # two cameras' frames with one stamp
    dup = Recording(t=t, points=rec.points, point_rod=rec.point_rod, point_along=rec.point_along,
                    rod_lengths=rec.rod_lengths)
    assert dup.report["duplicate_times"] == [{"frames": [10, 11], "t_s": pytest.approx(t[10])}]
    assert any("repeated time stamp" in w for w in dup.report["warnings"])
    assert dup.t.size == rec.t.size                      # both frames kept
    tt, nodes, mask = dup.node_trajectory(BARS)
    assert tt.size == t.size - 1 and mask.all()
    ep = dup.end_points()
    np.testing.assert_allclose(nodes[10], 0.5 * (ep[10] + ep[11]).reshape(6, 3), atol=1e-12)


# ---------------------------------------------------------------------- refusals
def test_refuses_a_point_on_a_rod_that_does_not_exist():
    msg = _refused(None, "point_rod", point_rod=[0, 0, 1, 1, 2, 3, 1])
    assert "point 5 is on rod 3" in msg and "3 rods" in msg


def test_refuses_a_rod_without_tracked_points():
    rec, _ = _synthetic(mid_marker=False)
    with pytest.raises(ValueError, match=r"field 'point_rod': rod 2 has no tracked point"):
        Recording(t=rec.t, points=rec.points[:, :4], point_rod=[0, 0, 1, 1], point_along=[0, 1, 0, 1],
                  rod_lengths=rec.rod_lengths)


def test_refuses_infinite_points_but_takes_nan_as_missing():
    rec, _ = _synthetic()
    pts = rec.points.copy()
    pts[12, 3, 1] = np.inf
    msg = _refused(12, "points", points=pts)
    assert "point 3 (rod 1)" in msg and "inf" in msg
    pts[12, 3] = np.nan                                  # NaN in all three: missing, accepted
    _synthetic(points=pts)
    pts[12, 3, 0] = 1.0                                  # NaN in some only: refused
    _refused(12, "points", points=pts)


def test_refuses_time_going_backwards():
    rec, _ = _synthetic()
    t = rec.t.copy()
    t[17] = t[15]
    msg = _refused(17, "t", t=t)
    assert "backwards" in msg
    t = rec.t.copy()
    t[3] = np.nan
    _refused(3, "t", t=t)
    ct = rec.command_t.copy()[::-1]
    _refused(1, "command_t", command_t=ct)


@pytest.mark.parametrize("factor, how", [(1.5, "farther apart"), (0.5, "closer")])
def test_refuses_end_points_a_rod_cannot_have(factor, how):
    rec, _ = _synthetic(mid_marker=False)
    pts = rec.points.copy()
    c = 0.5 * (pts[21, 4] + pts[21, 5])
    pts[21, 5] = c + factor * (pts[21, 5] - c)           # rod 2 stretched / shrunk by 25 %
    msg = _refused(21, "points", points=pts, mid_marker=False)
    assert "points 4 and 5 of rod 2" in msg and how in msg and "tolerance 10%" in msg
    pts[21, 5] = c + 1.05 * (pts[21, 5] - c) / factor    # 2.5 %: within the tolerance
    _synthetic(points=pts, mid_marker=False)
    with pytest.raises(ValueError, match="frame 21"):    # unless the tolerance is tightened
        _synthetic(points=pts, mid_marker=False, length_tolerance=0.02)


def test_refuses_a_marker_off_its_place_along_the_rod():
    rec, _ = _synthetic()
    pts = rec.points.copy()
    pts[30, 6] = pts[30, 3]                              # rod 1's marker reported at node b
    msg = _refused(30, "points", points=pts)
    assert "rod 1" in msg


def test_refuses_commands_of_the_wrong_length():
    rec, _ = _synthetic()
    rows = [list(r) for r in rec.commands["motor"]]
    rows[3] = rows[3][:5]
    msg = _refused(3, "commands.motor", commands={"motor": rows})
    assert "5 values, expected 6" in msg
    _refused(0, "commands.rest_length", commands={"rest_length": np.zeros((5, 4))})
    _refused(None, "commands.motor", commands={"motor": np.zeros((4, 6))})        # not one row per time stamp
    bad = rec.commands["motor"].copy()
    bad[2, 1] = np.nan
    _refused(2, "commands.motor", commands={"motor": bad})
    _refused(None, "commands.torque", commands={"torque": np.zeros((5, 6))})      # a channel without a unit
    ok, _ = _synthetic(commands={"torque": np.zeros((5, 6))}, metadata={"command_units": {"torque": "N m"}})
    assert ok.metadata["command_units"] == {"torque": "N m"}


def test_refuses_bad_sensor_readings():
    rec, _ = _synthetic()
    acc = rec.imu_accel.copy()
    acc[4, 2, 0] = -np.inf
    _refused(4, "imu_accel", imu_accel=acc)
    _refused(None, "encoder", encoder=np.zeros((rec.encoder_t.size, 5)))
    acc[4, 2, 0] = np.nan                                # a missing reading
    _synthetic(imu_accel=acc)


def test_load_refuses_a_tampered_file_naming_file_frame_and_field(tmp_path):
    rec, _ = _synthetic()
    arrays = dict(rec.arrays())
    t = arrays["t"].copy()
    t[9] = t[8] - 0.1
    arrays["t"] = t
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match=r"bad\.npz: frame 9, field 't': time goes backwards"):
        load_recording(tmp_path / "bad.npz")
    np.savez(tmp_path / "traj.npz", t=t, nodes=np.zeros((t.size, 6, 3)))
    with pytest.raises(ValueError, match="not a recording"):
        load_recording(tmp_path / "traj.npz")


# ---------------------------------------------------------------------- Rutgers / Yale
def _quat_from_axis(u):
    """The processed files' rod quaternion (w, x, y, z) turning z onto ``u``."""
    q = np.array([1 + u[2], -u[1], u[0], 0.0])
    return q / np.linalg.norm(q)


def _rutgers_frames(n=30, seed=1, t0=1.6e9 + 0.125):
    """Frames in the layout of the Rutgers/Yale processed JSON (made-up motion, upscaled x10):
    ``time`` Unix s, ``pos`` (centre and quaternion per rod), ``rod_XY_end_pt1/2``,
    ``target_gaits``, ``controls``; ``pid`` and ``init_act_lengths`` on the first frame only."""
    rng = np.random.default_rng(seed)
    t = t0 + np.concatenate([[0.0], np.cumsum(np.round(rng.uniform(0.001, 0.12, n - 1), 3))])
    ep = _end_points(t - t0) * RUTGERS_SCALE + 0.002 * rng.standard_normal((n, 3, 2, 3))
    frames = []
    for i in range(n):
        gait = [0.1, 0.0, 0.1, 0.0, 0.0, 0.0] if i < n // 2 else [1.0, 0.1, 1.0, 0.0, 0.0, 0.0]
        fr = {"time": round(float(t[i]), 3), "pos": []}
        for r, name in enumerate(("01", "23", "45")):
            a, b = ep[i, r]
            u = (b - a) / np.linalg.norm(b - a)
            fr["pos"] += list(0.5 * (a + b)) + list(_quat_from_axis(u))
            fr[f"rod_{name}_end_pt1"], fr[f"rod_{name}_end_pt2"] = list(a), list(b)
        fr["target_gaits"] = gait
        fr["controls"] = list(np.round(rng.uniform(-1, 1, 6), 3))
        if i == 0:
            fr["pid"] = {"min_length": 0.9, "RANGE": 1.2, "tol": 0.1, "motor_speed": 0.7}
            fr["init_act_lengths"] = list(rng.uniform(0.7, 1.0, 6))
        frames.append(fr)
    return frames, t, ep


def _write(tmp_path, frames, name="rutgers.json"):
    p = tmp_path / name
    p.write_text(json.dumps(frames))
    return p


def test_rutgers_import_through_the_command_line(tmp_path, capsys):
    frames, t, ep = _rutgers_frames()
    src, out = _write(tmp_path, frames), tmp_path / "rec.npz"
    assert main(["import-recording", str(src), "--format", "rutgers", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "30 frames" in printed and "3 rods" in printed and "divided by 10" in printed
    rec = load_recording(out)
    np.testing.assert_allclose(rec.t, np.round(t, 3) - np.round(t[0], 3), atol=1e-6)
    assert rec.t[0] == 0 and rec.metadata["time_origin_unix_s"] == pytest.approx(round(t[0], 3))
    np.testing.assert_allclose(rec.points.reshape(-1, 3, 2, 3), ep / RUTGERS_SCALE, atol=1e-12)
    np.testing.assert_allclose(rec.rod_lengths, L_ROD, atol=1e-3)       # medians of the noisy distances
    np.testing.assert_array_equal(rec.point_rod, [0, 0, 1, 1, 2, 2])
    np.testing.assert_array_equal(rec.point_along, [0, 1, 0, 1, 0, 1])
    assert rec.metadata["rod_names"] == ["01", "23", "45"]
    assert rec.actuators == tuple(f"spring_{j}" for j in range(6))
    np.testing.assert_array_equal(rec.command_t, rec.t)
    np.testing.assert_array_equal(rec.commands["target_gait"], [f["target_gaits"] for f in frames])
    np.testing.assert_array_equal(rec.commands["motor"], [f["controls"] for f in frames])
    gait = np.array([f["target_gaits"] for f in frames])
    np.testing.assert_allclose(rec.commands["target_length"], (0.9 + 1.2 * gait) / 10, atol=1e-15)
    assert rec.metadata["pid"]["min_length_m"] == pytest.approx(0.09)
    assert rec.metadata["pid"]["range_m"] == pytest.approx(0.12)
    assert rec.metadata["pid"]["motor_speed"] == 0.7
    np.testing.assert_allclose(rec.metadata["initial_actuation_length_m"],
                               np.array(frames[0]["init_act_lengths"]) / 10)
    # an existing output needs --force; --json prints the report
    assert main(["import-recording", str(src), "--out", str(out)]) == 4
    assert "--force" in capsys.readouterr().err
    assert main(["import-recording", str(src), "--out", str(out), "--force", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 30


def test_rutgers_gaps_and_repeated_stamps_are_reported(tmp_path, capsys):
    frames, t, _ = _rutgers_frames(n=40, seed=2)
    frames[12]["time"] = frames[11]["time"]                     # a repeated stamp
    for f in frames[25:]:
        f["time"] += 2.0                                        # the tracker paused 2 s
    frames[30]["rod_23_end_pt2"] = None                         # an end cap not tracked
    frames[31]["rod_45_end_pt1"] = [float("nan")] * 3
    out = tmp_path / "rec.npz"
    assert main(["import-recording", str(_write(tmp_path, frames)), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "gap" in err and "repeated time stamp" in err and "missing point" in err
    rec = import_rutgers(_write(tmp_path, frames))
    assert rec.report["duplicate_times"][0]["frames"] == [11, 12]
    assert [g["after_frame"] for g in rec.report["gaps"]] == [24]
    assert rec.report["missing_points"] == 2 and np.isnan(rec.points[30, 3]).all()


@pytest.mark.parametrize("edit, frame, field", [
    (lambda fr: fr[7].pop("rod_23_end_pt1"), 7, "rod_23_end_pt1"),                     # a rod missing
    (lambda fr: fr[9].__setitem__("rod_01_end_pt2", [1.0, float("inf"), 0.0]), 9, "rod_01_end_pt2"),
    (lambda fr: fr[14].__setitem__("time", fr[13]["time"] - 0.05), 14, "time"),          # time backwards
    (lambda fr: fr[5].__setitem__("rod_45_end_pt2",                                     # rod 2 too long
                                  list(np.array(fr[5]["rod_45_end_pt1"]) + [4.5, 0, 0])), 5, "points"),
    (lambda fr: fr[5].__setitem__("rod_45_end_pt2", fr[5]["rod_45_end_pt1"]), 5, "points"),   # too short
    (lambda fr: fr[11].__setitem__("controls", [0.0] * 5), 11, "controls"),               # wrong length
    (lambda fr: fr[4].__setitem__("target_gaits", [0.0] * 7), 4, "target_gaits"),
    (lambda fr: fr[6].__setitem__("rod_67_end_pt1", [0.0, 0.0, 0.0]), 6, "rod_67_end_pt1"),   # a rod frame 0 lacks
])
def test_rutgers_refusals_name_frame_and_field(tmp_path, capsys, edit, frame, field):
    frames, _, _ = _rutgers_frames()
    edit(frames)
    out = tmp_path / "rec.npz"
    assert main(["import-recording", str(_write(tmp_path, frames)), "--out", str(out)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: import-recording: ")
    assert f"frame {frame}, field '{field}'" in err, err
    if field == "points":
        assert "fields 'rod_45_end_pt1' and 'rod_45_end_pt2'" in err
    assert not out.exists()


def test_rutgers_bad_files(tmp_path, capsys):
    assert main(["import-recording", str(tmp_path / "none.json"), "--out", str(tmp_path / "r.npz")]) == 3
    p = tmp_path / "x.json"
    p.write_text("{not json")
    assert main(["import-recording", str(p), "--out", str(tmp_path / "r.npz")]) == 3
    p.write_text(json.dumps({"time": 0}))
    assert main(["import-recording", str(p), "--out", str(tmp_path / "r.npz")]) == 3
    assert "list of frames" in capsys.readouterr().err
    frames, _, _ = _rutgers_frames()
    src = _write(tmp_path, frames)
    assert main(["import-recording", str(src), "--out", str(tmp_path / "r.npz"), "--scale", "-1"]) == 2
    assert main(["import-recording", str(src), "--out", str(tmp_path / "r.npz"), "--scale", "1"]) == 0
    assert load_recording(tmp_path / "r.npz").rod_lengths == pytest.approx([3.25] * 3, abs=0.01)
    # a given rod length far from the measured one: the end points are refused
    assert main(["import-recording", str(src), "--out", str(tmp_path / "q.npz"), "--rod-length", "0.36"]) == 0
    assert main(["import-recording", str(src), "--out", str(tmp_path / "q.npz"), "--force",
                 "--rod-length", "0.25"]) == 3
    assert "frame 0, field 'points'" in capsys.readouterr().err


# ---------------------------------------------------------------------- identify from a recording
def test_identify_takes_a_recording_at_a_fixed_rate(tmp_path, capsys):
    """A prism recorded as a lab would: end caps and a marker per rod, a dropped frame and frames
    left out (gap): identify places the frames on their sample grid (skipped ones untracked) and
    recovers the stiffness as from the node trajectory itself; irregular stamps are refused."""
    import tensegrity_gym as tg
    from tensegrity_gym.io.trajectory import load_trajectory
    from tests.test_sysid import _record
    s = tg.prism(3, damping=2.0)
    model = tg.compile_model(s)
    _, t, nodes = _record(s, {"stiffness": model.stiffness * 1.1}, T=0.42, seed=6)
    keep = np.setdiff1d(np.arange(t.size), np.arange(300, 340))          # 20 ms the tracker missed
    a, b = nodes[:, s.bars[:, 0]], nodes[:, s.bars[:, 1]]
    pts = np.concatenate([a, b, a + 0.3 * (b - a)], axis=1)[keep]      # (F, 9, 3)
    pts[100] = np.nan                                                  # a dropped frame
    rec = Recording(t=t[keep], points=pts, point_rod=np.tile(np.arange(3), 3),
                    point_along=np.repeat([0.0, 1.0, 0.3], 3), rod_lengths=s.bar_lengths,
                    metadata={"robot": "prism3, simulated"})
    save_recording(tmp_path / "rec.npz", rec)
    with pytest.warns(RecordingWarning) as caught:
        tt, nn, _, mask = load_trajectory(tmp_path / "rec.npz", model.n_nodes, bars=s.bars)
    said = " ".join(str(w.message) for w in caught)
    assert "gap" in said and "1 frame(s) with no point at all" in said
    np.testing.assert_allclose(tt, t, atol=1e-12)
    assert not mask[100].any() and not mask[300:340].any() and mask.sum() == (t.size - 41) * 6
    np.testing.assert_allclose(nn[mask], nodes[mask], atol=1e-12)
    st, out = tmp_path / "prism.json", tmp_path / "fit.json"
    tg.save_json(s, st)
    assert main(["identify", str(st), str(tmp_path / "rec.npz"), "--fit", "stiffness", "--scale", "--stride", "4",
                 "--out", str(out)]) == 0
    assert json.loads(out.read_text())["scale"]["stiffness"] == pytest.approx(1.1, rel=1e-3)
    jitter = rec.t + np.where(np.arange(rec.t.size) == 50, 1e-4, 0.0)
    save_recording(tmp_path / "irr.npz", Recording(t=jitter, points=rec.points, point_rod=rec.point_rod,
                                                   point_along=rec.point_along, rod_lengths=rec.rod_lengths))
    capsys.readouterr()
    assert main(["identify", str(st), str(tmp_path / "irr.npz"), "--fit", "stiffness", "--out", str(out),
                 "--force"]) == 3
    assert "not on a fixed grid" in capsys.readouterr().err
