"""Recordings of a real robot: what a lab measures (tracked points on rods, the commands sent,
IMU and cable-encoder readings) as a :class:`Recording`, written and read as ``.npz``
(:func:`save_recording`, :func:`load_recording`) and imported from the Rutgers/Yale processed
JSON (:func:`tensegrity_gym.io.recording_rutgers.import_rutgers`).

Every :class:`Recording` is checked when it is made: a malformed one (a point on a rod that does
not exist, an infinite coordinate, time going backwards, two points of one rod farther apart or
closer than the rod allows, a command with the wrong number of values) raises ValueError naming
the frame and the field. What a real recording legitimately holds (missing points, gaps in
time, repeated time stamps) is kept as recorded and described in :attr:`Recording.report`;
nothing is interpolated. The format is documented in docs/recordings.md.

SI units: times s, positions and lengths m, accelerations m/s^2, angular rates rad/s.
"""
from __future__ import annotations

import json
import math
import re
import warnings
from dataclasses import dataclass, field
from types import MappingProxyType
from collections.abc import Mapping

import numpy as np

from ..core.checks import load_npz
from .atomic import write_atomic
from .recording_checks import check_readings, check_rows, check_times, float_array, frozen
from .recording_geometry import RecordingGeometry

__all__ = ["Recording", "RecordingWarning", "save_recording", "load_recording",
           "FORMAT", "FORMAT_VERSION", "LENGTH_TOLERANCE", "GAP_FACTOR", "COMMAND_UNITS"]

#: the ``format`` entry of a recording's metadata
FORMAT = "tensegrity_gym.recording"
FORMAT_VERSION = 1
#: two tracked points of one rod may be this fraction of the rod's length farther apart or closer
#: than their positions along the rod say (tracking noise, rod flex) before the frame is refused
LENGTH_TOLERANCE = 0.10
#: an interval between frames longer than this many times the median interval is reported as a gap
GAP_FACTOR = 3.0
#: units of the command channels known by name; any other channel names its unit in
#: ``metadata["command_units"]``
COMMAND_UNITS = {
    "rest_length": "m",
    "target_length": "m",
    "motor": "1 (motor speed as a fraction of its top speed, -1..1)",
    "target_gait": "1 (target position as a fraction of the PID range: length = min_length + range * gait)",
}

_UNITS = {"t": "s", "points": "m", "point_along": "fraction of the rod length from node a, or m from node a",
          "rod_lengths": "m", "command_t": "s", "imu_t": "s", "imu_accel": "m/s^2", "imu_gyro": "rad/s",
          "encoder_t": "s", "encoder": "m"}
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


class RecordingWarning(UserWarning):
    """Something :func:`load_recording` reports about a recording it accepted (gaps, repeated time
    stamps, missing points); the details are in :attr:`Recording.report`."""


@dataclass(frozen=True, eq=False)
class Recording(RecordingGeometry):
    """A robot's motion as a lab records it. Arrays are read-only copies; the constructor checks
    everything (ValueError naming the frame and the field) and fills :attr:`report`.

    t : (F,) frame time stamps, s; non-decreasing (repeated stamps are kept and reported),
        intervals need not be regular.
    points : (F, P, 3) tracked point positions, m; NaN in all three coordinates marks a point
        missing in that frame (inf, or NaN in only some coordinates, is refused).
    point_rod : (P,) the rod each point is on (0-based, as the structure's rods are numbered;
        every rod carries at least one point).
    point_along : (P,) where on its rod each point is: with ``along="fraction"`` 0 at node a,
        1 at node b (values outside [0, 1] lie on the rod's extension); with ``along="m"`` the
        signed distance from node a towards node b, m.
    rod_lengths : (k,) the rods' lengths (node a to node b), m; checks the tracked points.
    actuators : names of the actuated cables, one per column of the commands and encoders.
    command_t : (C,) command time stamps, s, non-decreasing; a command holds until the next.
    commands : {channel: (C, A) values}, one column per actuator (units :data:`COMMAND_UNITS`
        or ``metadata["command_units"]``), e.g. ``rest_length`` (m), ``motor`` (-1..1).
    imu_t, imu_accel, imu_gyro : (I,) s, (I, k, 3) m/s^2 and rad/s per rod (rod frame as the
        lab states it in the metadata), optional; NaN = missing.
    encoder_t, encoder : (E,) s and (E, A) cable lengths read by the winch encoders, m; optional.
    metadata : JSON-serialisable dict (``robot``, ``source``, ``units``, ``command_units``, ...);
        ``format``, ``format_version`` and ``units`` are filled in.
    length_tolerance : the fraction of a rod's length by which two of its points may disagree
        with their positions along it (default :data:`LENGTH_TOLERANCE`).
    """
    t: np.ndarray
    points: np.ndarray
    point_rod: np.ndarray
    point_along: np.ndarray
    rod_lengths: np.ndarray
    along: str = "fraction"
    actuators: tuple = ()
    command_t: np.ndarray | None = None
    commands: Mapping = field(default_factory=dict)
    imu_t: np.ndarray | None = None
    imu_accel: np.ndarray | None = None
    imu_gyro: np.ndarray | None = None
    encoder_t: np.ndarray | None = None
    encoder: np.ndarray | None = None
    metadata: Mapping = field(default_factory=dict)
    length_tolerance: float = LENGTH_TOLERANCE
    report: Mapping = field(init=False, repr=False, compare=False)

    # ------------------------------------------------------------------ checks
    def __post_init__(self):
        put = lambda k, v: object.__setattr__(self, k, v)   # noqa: E731 (frozen dataclass)
        if self.along not in ("fraction", "m"):
            raise ValueError(f"field 'along': {self.along!r}; expected 'fraction' or 'm'")
        tol = self.length_tolerance
        if not (isinstance(tol, (int, float)) and math.isfinite(tol) and 0 < tol < 1):
            raise ValueError(f"field 'length_tolerance': {tol!r}; expected a fraction of the rod length in (0, 1)")
        t = check_times(self.t, "t")
        if t.size < 1:
            raise ValueError("field 't': no frames")
        L = float_array(self.rod_lengths, "rod_lengths", 1, "(k,) rod lengths, m")
        bad = np.flatnonzero(~(np.isfinite(L) & (L > 0)))
        if L.size == 0 or bad.size:
            raise ValueError(f"field 'rod_lengths': {'no rods' if L.size == 0 else f'rod {bad[0]} has length {float(L[bad[0]])!r}'}"
                             "; rod lengths must be finite and > 0 (m)")
        k = L.size
        pr = np.asarray(self.point_rod)
        if pr.ndim != 1 or (pr.size and pr.dtype.kind not in "iu" and not
                            (pr.dtype.kind == "f" and np.all(np.isfinite(pr)) and np.all(pr == np.round(pr)))):
            raise ValueError(f"field 'point_rod': expected a 1-D array of rod indices, got {pr!r}"[:200])
        pr = pr.astype(np.int64)
        P = pr.size
        out = np.flatnonzero((pr < 0) | (pr >= k))
        if out.size:
            raise ValueError(f"field 'point_rod': point {out[0]} is on rod {pr[out[0]]}, but the recording has {k} "
                             f"rods (0..{k - 1})")
        untracked = np.setdiff1d(np.arange(k), pr)
        if untracked.size:
            raise ValueError(f"field 'point_rod': rod {untracked[0]} has no tracked point (every rod of the robot "
                             "needs at least one)")
        s = float_array(self.point_along, "point_along", 1, "(P,) positions along the rods")
        if s.size != P:
            raise ValueError(f"field 'point_along': {s.size} entries, but point_rod has {P}")
        bad = np.flatnonzero(~np.isfinite(s))
        if bad.size:
            raise ValueError(f"field 'point_along': point {bad[0]} is at {float(s[bad[0]])!r}; positions must be finite")
        frac = s if self.along == "fraction" else s / L[pr]
        for r in range(k):
            idx = np.flatnonzero(pr == r)
            _, first, count = np.unique(frac[idx], return_index=True, return_counts=True)
            if (count > 1).any():
                same = idx[frac[idx] == frac[idx][first[count > 1][0]]]
                raise ValueError(f"field 'point_along': points {same[0]} and {same[1]} are the same point of rod {r}")
        pts = float_array(self.points, "points", 3, "an (F, P, 3) array of point positions, m")
        if pts.shape != (t.size, P, 3):
            raise ValueError(f"field 'points': shape {pts.shape}, expected {(t.size, P, 3)} (frames, points, xyz)")
        bad = np.argwhere(np.isinf(pts))
        if bad.size:
            i, p, c = (int(x) for x in bad[0])
            raise ValueError(f"frame {i}, field 'points': point {p} (rod {pr[p]}) coordinate {'xyz'[c]} is "
                             f"{float(pts[i, p, c])!r}; NaN marks a missing point, inf is an error")
        nan = np.isnan(pts)
        part = np.argwhere(nan.any(axis=2) & ~nan.all(axis=2))
        if part.size:
            i, p = (int(x) for x in part[0])
            raise ValueError(f"frame {i}, field 'points': point {p} (rod {pr[p]}) has NaN in some coordinates only "
                             f"({pts[i, p].tolist()}); a missing point is NaN in all three")
        self._check_lengths(pts, pr, frac, L, tol)
        put("t", frozen(t))
        put("points", frozen(pts))
        put("point_rod", frozen(pr))
        put("point_along", frozen(s))
        put("rod_lengths", frozen(L))
        put("length_tolerance", float(tol))
        self._check_commands()
        self._check_sensors(k)
        self._check_metadata()
        put("report", MappingProxyType(self._make_report()))

    @staticmethod
    def _check_lengths(pts, pr, frac, L, tol):
        """Every pair of points on one rod, seen in one frame, must be ``|s_p - s_q| L`` apart
        within ``tol L`` (a rod is rigid)."""
        for r in range(L.size):
            idx = np.flatnonzero(pr == r)
            for a in range(idx.size):
                for b in range(a + 1, idx.size):
                    p, q = idx[a], idx[b]
                    want = abs(frac[q] - frac[p]) * L[r]
                    d = np.linalg.norm(pts[:, q] - pts[:, p], axis=1)
                    bad = np.flatnonzero(np.abs(d - want) > tol * L[r])     # NaN (missing) compares False
                    if bad.size:
                        i = int(bad[0])
                        how = "farther apart" if d[i] > want else "closer"
                        raise ValueError(
                            f"frame {i}, field 'points': points {p} and {q} of rod {r} are {d[i]:.6g} m apart, "
                            f"{how} than the rod allows ({want:.6g} m from their positions along its "
                            f"{L[r]:.6g} m, tolerance {tol:.0%} of its length)")

    def _check_commands(self):
        put = lambda k, v: object.__setattr__(self, k, v)   # noqa: E731
        if not isinstance(self.metadata, Mapping):
            raise ValueError(f"field 'metadata': {type(self.metadata).__name__}; expected a dict")
        acts = tuple(self.actuators)
        for i, a in enumerate(acts):
            if not isinstance(a, str) or not a:
                raise ValueError(f"field 'actuators': entry {i} is {a!r}; actuator names are non-empty strings")
        if len(set(acts)) != len(acts):
            raise ValueError(f"field 'actuators': repeated name in {list(acts)}")
        put("actuators", acts)
        cmds = dict(self.commands or {})
        if self.command_t is None and not cmds:
            put("command_t", frozen(np.zeros(0)))
            put("commands", MappingProxyType({}))
            return
        if self.command_t is None:
            raise ValueError("field 'command_t': commands given without their time stamps")
        ct = check_times(self.command_t, "command_t")
        if cmds and not acts:
            raise ValueError("field 'actuators': commands given but no actuators named (one name per column)")
        given = self.metadata.get("command_units", {})
        if not isinstance(given, Mapping):
            raise ValueError(f"field 'metadata.command_units': {given!r}; expected {{channel: unit}}")
        units = dict(COMMAND_UNITS, **given)
        out = {}
        for name, rows in cmds.items():
            if not isinstance(name, str) or not _NAME.match(name):
                raise ValueError(f"field 'commands': channel name {name!r}; use letters, digits and _")
            if name not in units:
                raise ValueError(f"field 'commands.{name}': no unit; give it in metadata['command_units'][{name!r}]")
            out[name] = frozen(check_rows(rows, ct.size, len(acts), f"commands.{name}",
                                            f"one per actuator: {', '.join(acts)}"))
        put("command_t", frozen(ct))
        put("commands", MappingProxyType(out))

    def _check_sensors(self, k):
        put = lambda k_, v: object.__setattr__(self, k_, v)   # noqa: E731
        if self.imu_t is None:
            if self.imu_accel is not None or self.imu_gyro is not None:
                raise ValueError("field 'imu_t': IMU readings given without their time stamps")
        else:
            it = check_times(self.imu_t, "imu_t")
            put("imu_t", frozen(it))
            if self.imu_accel is None and self.imu_gyro is None:
                raise ValueError("field 'imu_t': time stamps given without imu_accel or imu_gyro")
            for name, what in (("imu_accel", "accelerations per rod, m/s^2"), ("imu_gyro", "angular rates per rod, rad/s")):
                v = getattr(self, name)
                if v is not None:
                    put(name, frozen(check_readings(v, it, name, (k, 3), what)))
        if self.encoder_t is None:
            if self.encoder is not None:
                raise ValueError("field 'encoder_t': encoder readings given without their time stamps")
        else:
            et = check_times(self.encoder_t, "encoder_t")
            if self.encoder is None:
                raise ValueError("field 'encoder_t': time stamps given without encoder readings")
            if not self.actuators:
                raise ValueError("field 'actuators': encoder readings given but no actuators named")
            put("encoder_t", frozen(et))
            put("encoder", frozen(check_readings(self.encoder, et, "encoder", (len(self.actuators),),
                                                   "cable lengths per actuator, m")))

    def _check_metadata(self):
        md = dict(self.metadata or {})
        md.update(format=FORMAT, format_version=FORMAT_VERSION, units=dict(_UNITS))
        if self.commands:
            cu = dict(md.get("command_units", {}))
            md["command_units"] = {n: cu.get(n, COMMAND_UNITS.get(n)) for n in self.commands}
        try:
            md = json.loads(json.dumps(md, allow_nan=False))
        except (TypeError, ValueError) as e:
            raise ValueError(f"field 'metadata': not JSON-serialisable ({e})") from None
        object.__setattr__(self, "metadata", MappingProxyType(md))

    # ------------------------------------------------------------------ report
    def _make_report(self) -> dict:
        t = self.t
        F, P = self.points.shape[:2]
        dt = np.diff(t)
        pos = dt[dt > 0]
        h = float(np.median(pos)) if pos.size else float("nan")
        gaps = [{"after_frame": int(i), "t_s": float(t[i]), "length_s": float(dt[i])}
                for i in np.flatnonzero(dt > GAP_FACTOR * h)] if pos.size else []
        dups, i = [], 0
        while i < F - 1:
            j = i
            while j + 1 < F and t[j + 1] == t[i]:
                j += 1
            if j > i:
                dups.append({"frames": list(range(i, j + 1)), "t_s": float(t[i])})
            i = j + 1
        missing = np.isnan(self.points[..., 0])
        dropped = [int(i) for i in np.flatnonzero(missing.all(axis=1))]
        unposed = self.rod_unposed()
        rep = {"frames": F, "duration_s": float(t[-1] - t[0]), "median_interval_s": h,
               "rods": int(self.rod_lengths.size), "points": P, "gaps": gaps, "duplicate_times": dups,
               "missing_points": int(missing.sum()), "frames_with_missing_points": int(missing.any(axis=1).sum()),
               "dropped_frames": dropped, "missing_per_point": [int(x) for x in missing.sum(axis=0)],
               "frames_without_rod_pose": [int(x) for x in unposed.sum(axis=0)], "warnings": []}
        w = rep["warnings"]
        if gaps:
            g = max(gaps, key=lambda g: g["length_s"])
            w.append(f"{len(gaps)} gap(s) longer than {GAP_FACTOR:g} x the median frame interval ({h:.4g} s); the "
                     f"longest {g['length_s']:.4g} s after frame {g['after_frame']} (t = {g['t_s']:.4g} s)")
        if dups:
            w.append(f"{len(dups)} repeated time stamp(s), {sum(len(d['frames']) for d in dups)} frames; the first "
                     f"at frames {dups[0]['frames']} (t = {dups[0]['t_s']:.6g} s)")
        if missing.any():
            w.append(f"{rep['missing_points']} missing point(s) in {rep['frames_with_missing_points']} frame(s)"
                     + (f", {len(dropped)} frame(s) with no point at all" if dropped else ""))
        return rep

    # ------------------------------------------------------------------ disk
    def arrays(self) -> dict:
        """The named arrays of the ``.npz`` file (docs/recordings.md)."""
        d = {"t": self.t, "points": self.points, "point_rod": self.point_rod, "point_along": self.point_along,
             "rod_lengths": self.rod_lengths, "along": np.array(self.along),
             "actuators": np.array(self.actuators, dtype=str) if self.actuators else np.zeros(0, dtype="<U1"),
             "length_tolerance": np.array(self.length_tolerance),
             "metadata": np.array(json.dumps(dict(self.metadata), sort_keys=True))}
        if self.command_t.size or self.commands:
            d["command_t"] = self.command_t
            d.update({f"command_{k}": v for k, v in self.commands.items()})
        for k in ("imu_t", "imu_accel", "imu_gyro", "encoder_t", "encoder"):
            if getattr(self, k) is not None:
                d[k] = getattr(self, k)
        return d


def save_recording(path, rec: Recording) -> None:
    """Write ``rec`` as an ``.npz`` archive at ``path`` (atomically: the old file or the new one,
    never a partial one). A binary file object is written to directly."""
    if not isinstance(rec, Recording):
        raise ValueError(f"rec: expected a Recording, got {type(rec).__name__}")
    arrays = rec.arrays()
    if hasattr(path, "write"):
        np.savez(path, **arrays)
        return
    write_atomic(path, lambda f: np.savez(f, **arrays))


def load_recording(path, *, warn: bool = True) -> Recording:
    """Read a recording written by :func:`save_recording`, checked as the constructor checks it
    (ValueError naming the file, the frame and the field). With ``warn`` a
    :class:`RecordingWarning` says what :attr:`Recording.report` found (gaps, repeated time stamps,
    missing points)."""
    p = str(path)
    z = load_npz(p, "a recording written by tensegrity_gym.io.recording.save_recording")
    miss = [k for k in ("t", "points", "point_rod", "point_along", "rod_lengths", "metadata") if k not in z]
    if miss:
        raise ValueError(f"{p}: not a recording: no array {miss[0]!r} (found {sorted(z)}; docs/recordings.md)")
    try:
        md = json.loads(str(z["metadata"]))
    except (ValueError, TypeError):
        raise ValueError(f"{p}: field 'metadata': not a JSON string") from None
    if not isinstance(md, dict) or md.get("format") != FORMAT:
        raise ValueError(f"{p}: field 'metadata': format is {md.get('format') if isinstance(md, dict) else md!r}, "
                         f"expected {FORMAT!r}")
    if md.get("format_version", 0) > FORMAT_VERSION:
        raise ValueError(f"{p}: format_version {md['format_version']} is newer than this reader's {FORMAT_VERSION}")
    cmds = {k[len("command_"):]: v for k, v in z.items() if k.startswith("command_") and k != "command_t"}
    opt = {k: z[k] for k in ("command_t", "imu_t", "imu_accel", "imu_gyro", "encoder_t", "encoder") if k in z}
    try:
        rec = Recording(t=z["t"], points=z["points"], point_rod=z["point_rod"], point_along=z["point_along"],
                        rod_lengths=z["rod_lengths"], along=str(z.get("along", "fraction")),
                        actuators=tuple(str(a) for a in z.get("actuators", ())), commands=cmds, metadata=md,
                        length_tolerance=float(z.get("length_tolerance", LENGTH_TOLERANCE)), **opt)
    except ValueError as e:
        raise ValueError(f"{p}: {e}") from None
    if warn:
        for w in rec.report["warnings"]:
            warnings.warn(f"{p}: {w}", RecordingWarning, stacklevel=2)
    return rec
