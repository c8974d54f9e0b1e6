"""Recordings of a real robot: what a lab measures (tracked points on rods, the commands sent,
IMU and cable-encoder readings) as a :class:`Recording`, written and read as ``.npz``
(:func:`save_recording`, :func:`load_recording`) and imported from the Rutgers/Yale processed
JSON (:func:`import_rutgers`).

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

from ..core.checks import load_npz, read_bounded
from .atomic import write_atomic

__all__ = ["Recording", "RecordingWarning", "save_recording", "load_recording", "import_rutgers",
           "FORMAT", "FORMAT_VERSION", "LENGTH_TOLERANCE", "GAP_FACTOR", "COMMAND_UNITS", "RUTGERS_SCALE"]

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
#: the Rutgers/Yale 3-bar data are ten times the robot's size: their lengths divided by this are m
RUTGERS_SCALE = 10.0
#: largest Rutgers JSON read, bytes
MAX_JSON_BYTES = 256 << 20

_UNITS = {"t": "s", "points": "m", "point_along": "fraction of the rod length from node a, or m from node a",
          "rod_lengths": "m", "command_t": "s", "imu_t": "s", "imu_accel": "m/s^2", "imu_gyro": "rad/s",
          "encoder_t": "s", "encoder": "m"}
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


class RecordingWarning(UserWarning):
    """Something :func:`load_recording` reports about a recording it accepted (gaps, repeated time
    stamps, missing points); the details are in :attr:`Recording.report`."""


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a)          # a copy the caller cannot change under the recording
    a.setflags(write=False)
    return a


def _float_array(value, name: str, ndim: int, what: str) -> np.ndarray:
    try:
        if np.iscomplexobj(value):
            raise TypeError
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"field {name!r}: expected {what} (real numbers)") from None
    if a.ndim != ndim:
        raise ValueError(f"field {name!r}: expected {what}, got an array of shape {a.shape}")
    return a


def _check_times(t, name: str) -> np.ndarray:
    t = _float_array(t, name, 1, "a 1-D array of time stamps, s")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ValueError(f"frame {bad[0]}, field {name!r}: time stamp {float(t[bad[0]])!r}; time stamps must be finite (s)")
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise ValueError(f"frame {i}, field {name!r}: time goes backwards ({float(t[i])!r} s after {float(t[i - 1])!r} s at frame "
                         f"{i - 1}); frames must be in time order")
    return t


def _check_readings(a, t, name: str, width: tuple, what: str) -> np.ndarray:
    """A (T, *width) array of readings at times ``t``: NaN marks a missing reading, inf is refused."""
    a = _float_array(a, name, 1 + len(width), f"an array of shape (frames, {', '.join(map(str, width))}), {what}")
    if a.shape != (t.size,) + tuple(width):
        raise ValueError(f"field {name!r}: shape {a.shape}, expected {(t.size,) + tuple(width)} ({what})")
    bad = np.argwhere(np.isinf(a))
    if bad.size:
        i = tuple(int(x) for x in bad[0])
        raise ValueError(f"frame {i[0]}, field {name!r}: entry {i[1:]} is {float(a[i])!r}; NaN marks a missing reading, "
                         "inf is an error")
    return a


def _check_rows(rows, n_rows: int, width: int, name: str, what: str) -> np.ndarray:
    """``rows`` (one per command frame, each ``width`` values) as an (n_rows, width) array; a row
    of another length or a non-finite value raises ValueError naming the frame."""
    if isinstance(rows, np.ndarray) and rows.ndim == 2:
        if rows.shape[1] != width:
            raise ValueError(f"frame 0, field {name!r}: {rows.shape[1]} values, expected {width} ({what})")
        seq = rows
    else:
        seq = list(rows)
        for i, row in enumerate(seq):
            n = np.size(row) if np.ndim(row) == 1 else None
            if n != width:
                got = f"{n} values" if n is not None else f"{np.ndim(row)}-D value"
                raise ValueError(f"frame {i}, field {name!r}: {got}, expected {width} ({what})")
    a = _float_array(seq, name, 2, f"(frames, {width}) numbers") if len(seq) else np.zeros((0, width))
    if a.shape[0] != n_rows:
        raise ValueError(f"field {name!r}: {a.shape[0]} frames, but command_t has {n_rows} time stamps")
    bad = np.argwhere(~np.isfinite(a))
    if bad.size:
        i, j = (int(x) for x in bad[0])
        raise ValueError(f"frame {i}, field {name!r}: value {j} is {float(a[i, j])!r}; commands must be finite")
    return a


@dataclass(frozen=True, eq=False)
class Recording:
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
        t = _check_times(self.t, "t")
        if t.size < 1:
            raise ValueError("field 't': no frames")
        L = _float_array(self.rod_lengths, "rod_lengths", 1, "(k,) rod lengths, m")
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
        s = _float_array(self.point_along, "point_along", 1, "(P,) positions along the rods")
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
        pts = _float_array(self.points, "points", 3, "an (F, P, 3) array of point positions, m")
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
        put("t", _frozen(t))
        put("points", _frozen(pts))
        put("point_rod", _frozen(pr))
        put("point_along", _frozen(s))
        put("rod_lengths", _frozen(L))
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
            put("command_t", _frozen(np.zeros(0)))
            put("commands", MappingProxyType({}))
            return
        if self.command_t is None:
            raise ValueError("field 'command_t': commands given without their time stamps")
        ct = _check_times(self.command_t, "command_t")
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
            out[name] = _frozen(_check_rows(rows, ct.size, len(acts), f"commands.{name}",
                                            f"one per actuator: {', '.join(acts)}"))
        put("command_t", _frozen(ct))
        put("commands", MappingProxyType(out))

    def _check_sensors(self, k):
        put = lambda k_, v: object.__setattr__(self, k_, v)   # noqa: E731
        if self.imu_t is None:
            if self.imu_accel is not None or self.imu_gyro is not None:
                raise ValueError("field 'imu_t': IMU readings given without their time stamps")
        else:
            it = _check_times(self.imu_t, "imu_t")
            put("imu_t", _frozen(it))
            if self.imu_accel is None and self.imu_gyro is None:
                raise ValueError("field 'imu_t': time stamps given without imu_accel or imu_gyro")
            for name, what in (("imu_accel", "accelerations per rod, m/s^2"), ("imu_gyro", "angular rates per rod, rad/s")):
                v = getattr(self, name)
                if v is not None:
                    put(name, _frozen(_check_readings(v, it, name, (k, 3), what)))
        if self.encoder_t is None:
            if self.encoder is not None:
                raise ValueError("field 'encoder_t': encoder readings given without their time stamps")
        else:
            et = _check_times(self.encoder_t, "encoder_t")
            if self.encoder is None:
                raise ValueError("field 'encoder_t': time stamps given without encoder readings")
            if not self.actuators:
                raise ValueError("field 'actuators': encoder readings given but no actuators named")
            put("encoder_t", _frozen(et))
            put("encoder", _frozen(_check_readings(self.encoder, et, "encoder", (len(self.actuators),),
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

    # ------------------------------------------------------------------ derived
    @property
    def n_rods(self) -> int:
        return int(self.rod_lengths.size)

    def fractions(self) -> np.ndarray:
        """(P,) each point's position along its rod as a fraction (0 at node a, 1 at node b)."""
        if self.along == "fraction":
            return np.array(self.point_along)
        return self.point_along / self.rod_lengths[self.point_rod]

    def rod_unposed(self) -> np.ndarray:
        """(F, k) True where a rod has fewer than two distinct points in a frame (its end points
        cannot be told from the tracked points)."""
        seen = ~np.isnan(self.points[..., 0])
        return np.stack([seen[:, self.point_rod == r].sum(axis=1) < 2 for r in range(self.n_rods)], axis=1)

    def end_points(self) -> np.ndarray:
        """(F, k, 2, 3) each rod's node a and node b, m, fitted by least squares to its points in
        each frame (exact for two points); NaN where :meth:`rod_unposed`. The fitted end points
        keep the tracked points' spacing, so they are not forced to the rod's length."""
        F, k = self.t.size, self.n_rods
        out = np.full((F, k, 2, 3), np.nan)
        s = self.fractions()
        for r in range(k):
            idx = np.flatnonzero(self.point_rod == r)
            x = self.points[:, idx]                              # (F, p, 3)
            v = ~np.isnan(x[..., 0])
            w0, w1 = np.where(v, 1.0 - s[idx], 0.0), np.where(v, s[idx], 0.0)
            a00, a01, a11 = (w0 * w0).sum(1), (w0 * w1).sum(1), (w1 * w1).sum(1)
            xz = np.where(v[..., None], x, 0.0)
            r0, r1 = (w0[..., None] * xz).sum(1), (w1[..., None] * xz).sum(1)
            det = a00 * a11 - a01 * a01
            ok = v.sum(1) >= 2
            with np.errstate(divide="ignore", invalid="ignore"):
                a = (a11[:, None] * r0 - a01[:, None] * r1) / det[:, None]
                b = (a00[:, None] * r1 - a01[:, None] * r0) / det[:, None]
            out[ok, r, 0], out[ok, r, 1] = a[ok], b[ok]
        return out

    def node_trajectory(self, bars, n_nodes: int | None = None):
        """``(t, nodes, mask)`` for a structure whose rod ``r`` joins nodes ``bars[r]`` (a, b):
        ``t`` (S,) the distinct time stamps, s; ``nodes`` (S, n, 3) the rods' end points, m
        (:meth:`end_points`), frames sharing a time stamp averaged over the rods seen in them;
        ``mask`` (S, n) True where a node is known. NaN where unknown; nothing is interpolated."""
        bars = np.asarray(bars, dtype=np.int64)
        if bars.shape != (self.n_rods, 2):
            raise ValueError(f"bars: shape {bars.shape}; the recording has {self.n_rods} rods, expected "
                             f"({self.n_rods}, 2) node indices")
        n = int(bars.max()) + 1 if n_nodes is None else int(n_nodes)
        if bars.min() < 0 or bars.max() >= n:
            raise ValueError(f"bars: node indices must be in 0..{n - 1}")
        ep = self.end_points()
        t, inv = np.unique(self.t, return_inverse=True)
        per = np.full((self.t.size, n, 3), np.nan)
        per[:, bars[:, 0]], per[:, bars[:, 1]] = ep[:, :, 0], ep[:, :, 1]
        known = ~np.isnan(per[..., 0])
        total = np.zeros((t.size, n, 3))
        count = np.zeros((t.size, n))
        np.add.at(total, inv, np.where(known[..., None], per, 0.0))
        np.add.at(count, inv, known)
        with np.errstate(invalid="ignore", divide="ignore"):
            nodes = total / count[..., None]
        return t, nodes, count > 0

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


# ---------------------------------------------------------------------- Rutgers / Yale
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
    t = _check_times(t - t0 if np.isfinite(t0) else t, "time")
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
