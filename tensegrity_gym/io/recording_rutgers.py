"""The Rutgers/Yale processed recording of a real 3-bar robot as a
:class:`~tensegrity_gym.io.recording.Recording` (:func:`import_rutgers`; docs/recordings.md):
lengths divided by its upscaling, times from its first frame, commands per frame. SI units."""
from __future__ import annotations

import json
import math
import re

import numpy as np

from ..core.checks import read_bounded
from .recording import LENGTH_TOLERANCE, Recording
from .recording_checks import check_times

__all__ = ["import_rutgers", "RUTGERS_SCALE"]

#: the Rutgers/Yale 3-bar data are ten times the robot's size: their lengths divided by this are m
RUTGERS_SCALE = 10.0
#: largest Rutgers JSON read, bytes
MAX_JSON_BYTES = 256 << 20

_RUTGERS_KEY = re.compile(r"rod_(\w+?)_end_pt([12])\Z")


def _rutgers_point(frame: dict, i: int, key: str, scale: float) -> list:
    if key not in frame:
        raise ValueError(f"frame {i}, field {key!r}: missing (the rod's end point; null marks a point not tracked)")
    v = frame[key]
    if v is None:
        return [math.nan] * 3
    if not isinstance(v, list) or len(v) != 3:
        raise ValueError(f"frame {i}, field {key!r}: {v!r}; expected [x, y, z]")
    try:
        xyz = [float(c) for c in v]
    except (TypeError, ValueError):
        raise ValueError(f"frame {i}, field {key!r}: {v!r}; expected three numbers") from None
    if any(math.isinf(c) for c in xyz):
        raise ValueError(f"frame {i}, field {key!r}: {v!r}; NaN or null marks a missing point, inf is an error")
    return [c / scale for c in xyz]


def _rutgers_row(frame: dict, i: int, key: str, width: int) -> list:
    if key not in frame:
        raise ValueError(f"frame {i}, field {key!r}: missing (one value per actuated cable)")
    v = frame[key]
    if not isinstance(v, list) or len(v) != width:
        n = f"{len(v)} values" if isinstance(v, list) else repr(v)
        raise ValueError(f"frame {i}, field {key!r}: {n}, expected {width} (one per actuated cable)")
    try:
        row = [float(c) for c in v]
    except (TypeError, ValueError):
        raise ValueError(f"frame {i}, field {key!r}: {v!r}; expected numbers") from None
    bad = [j for j, c in enumerate(row) if not math.isfinite(c)]
    if bad:
        raise ValueError(f"frame {i}, field {key!r}: value {bad[0]} is {row[bad[0]]!r}; commands must be finite")
    return row


def import_rutgers(path, *, rod_lengths=None, scale: float = RUTGERS_SCALE,
                   length_tolerance: float = LENGTH_TOLERANCE) -> Recording:
    """A :class:`Recording` from the Rutgers/Yale processed JSON (a list of frames, each with
    ``time`` (Unix s), ``rod_<name>_end_pt1`` / ``_end_pt2`` (end-cap centres, x ``scale``),
    ``target_gaits`` and ``controls`` (one per actuated cable) and, on the first frame, ``pid`` and
    ``init_act_lengths``; docs/recordings.md).

    Lengths are divided by ``scale`` (the data are ten times the robot's size); times start at 0
    (the first frame's Unix time is ``metadata["time_origin_unix_s"]``). Rods are numbered in the
    order their names first appear; the tracked points are their end-cap centres (fractions 0 and
    1). ``rod_lengths`` (m) defaults to each rod's median measured end-point distance. Commands:
    ``target_gait`` and ``motor`` (``controls``) per frame, and ``target_length`` (m, the PID's
    target cable length ``min_length + range * gait``) when ``pid`` gives them. ValueError naming
    the frame and the field for a malformed file."""
    p = str(path)
    try:
        data = json.loads(read_bounded(p, MAX_JSON_BYTES, "Rutgers JSON recording"))
    except json.JSONDecodeError as e:
        raise ValueError(f"{p}: not JSON ({e})") from None
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale: {scale!r}; expected a positive number")
    try:
        return _rutgers(data, p, rod_lengths, float(scale), length_tolerance)
    except ValueError as e:
        raise ValueError(f"{p}: {e}") from None


def _rutgers(data, p: str, rod_lengths, scale: float, tol: float) -> Recording:
    if not isinstance(data, list) or not data:
        raise ValueError("expected a JSON list of frames (objects with time, rod_*_end_pt1/2, target_gaits, controls)")
    for i, fr in enumerate(data):
        if not isinstance(fr, dict):
            raise ValueError(f"frame {i}: {type(fr).__name__}, expected an object")
    names = []
    for key in data[0]:
        m = _RUTGERS_KEY.match(key)
        if m and m.group(1) not in names:
            names.append(m.group(1))
    if not names:
        raise ValueError("frame 0: no rod_<name>_end_pt1 / rod_<name>_end_pt2 fields")
    keys = [f"rod_{n}_end_pt{e}" for n in names for e in (1, 2)]
    for i, fr in enumerate(data):
        extra = sorted({m.group(1) for m in map(_RUTGERS_KEY.match, fr) if m} - set(names))
        if extra:
            raise ValueError(f"frame {i}, field 'rod_{extra[0]}_end_pt1': rod {extra[0]!r} is not in frame 0 "
                             f"(rods {names})")
    t = []
    for i, fr in enumerate(data):
        v = fr.get("time")
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"frame {i}, field 'time': {v!r}; expected a time stamp (s)")
        t.append(float(v))
    t = np.array(t)
    t0 = t[0]
    t = check_times(t - t0 if np.isfinite(t0) else t, "time")
    pts = np.array([[_rutgers_point(fr, i, k, scale) for k in keys] for i, fr in enumerate(data)], dtype=float)
    rod = np.repeat(np.arange(len(names)), 2)
    along = np.tile([0.0, 1.0], len(names))
    if rod_lengths is None:
        d = np.linalg.norm(pts[:, 1::2] - pts[:, 0::2], axis=2)
        L = np.array([np.median(c[np.isfinite(c)]) if np.isfinite(c).any() else math.nan for c in d.T])
        bad = np.flatnonzero(~np.isfinite(L))
        if bad.size:
            raise ValueError(f"field 'rod_{names[bad[0]]}_end_pt1': rod {names[bad[0]]!r} is never seen with both "
                             "end points; give rod_lengths")
        length_source = "median end-point distance of the data"
    else:
        L = np.broadcast_to(np.asarray(rod_lengths, dtype=float), (len(names),)).copy()
        length_source = "given"
    width = None
    for key in ("controls", "target_gaits"):
        if isinstance(data[0].get(key), list):
            width = len(data[0][key])
            break
    if width is None:
        raise ValueError("frame 0, field 'controls': missing (one value per actuated cable)")
    gait = [_rutgers_row(fr, i, "target_gaits", width) for i, fr in enumerate(data)]
    ctrl = [_rutgers_row(fr, i, "controls", width) for i, fr in enumerate(data)]
    cmds = {"target_gait": gait, "motor": ctrl}
    md = {"source": "Rutgers/Yale processed JSON", "file": p.replace("\\", "/").rsplit("/", 1)[-1],
          "robot": f"{len(names)}-bar tensegrity", "rod_names": names, "time_origin_unix_s": float(t0),
          "length_scale": {"divided_by": scale, "note": "the file's lengths are the robot's x this factor"},
          "tracked_points": "end-cap sphere centres (fractions 0 and 1 of each rod)",
          "rod_lengths_from": length_source,
          "world_frame": "z up; as processed by the authors, x, y centred on the first frame's end caps and the "
                         "lowest end cap of the first frame resting on z = 0",
          "commands_timing": "target_gaits and controls logged with each frame (command_t = t)"}
    pid = data[0].get("pid")
    if isinstance(pid, dict):
        try:
            mn, rg = float(pid["min_length"]), float(pid["RANGE"])
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"frame 0, field 'pid': {pid!r}; expected min_length and RANGE numbers") from None
        md["pid"] = {"min_length_m": mn / scale, "range_m": rg / scale,
                     **{k: v for k, v in pid.items() if k not in ("min_length", "RANGE")},
                     "units": "min_length_m, range_m in m; tol a fraction of the range; motor_speed a fraction "
                              "of the motor's top speed"}
        cmds["target_length"] = [[(mn + rg * g) / scale for g in row] for row in gait]
    init = data[0].get("init_act_lengths")
    if init is not None:
        md["initial_actuation_length_m"] = [x / scale for x in _rutgers_row(data[0], 0, "init_act_lengths", width)]
    try:
        return Recording(t=t, points=pts, point_rod=rod, point_along=along, rod_lengths=L, along="fraction",
                         actuators=tuple(f"spring_{j}" for j in range(width)), command_t=t, commands=cmds,
                         metadata=md, length_tolerance=tol)
    except ValueError as e:        # name the file's fields beside the recording's point numbers
        m = re.match(r"frame \d+, field 'points': points (\d+) and (\d+) ", str(e))
        if m is None:
            raise
        raise ValueError(f"{e} (fields {keys[int(m.group(1))]!r} and {keys[int(m.group(2))]!r})") from None
