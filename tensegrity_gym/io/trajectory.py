"""Trajectories on disk: the output of ``simulate`` (:func:`save_simulate_output`,
:func:`load_simulate_output`) and recorded motions for system identification: motion-capture CSV
files, ``.npz`` records (times s, node positions m, optional rest lengths m and tracked-node
mask) and lab recordings (:mod:`.recording`) sampled at a fixed rate (:func:`load_trajectory`)."""
from __future__ import annotations

import numpy as np

from ..core.checks import check_trajectory_arrays, load_npz, read_bounded
from .recording import FORMAT as RECORDING_FORMAT, load_recording

__all__ = ["load_csv", "load_trajectory", "recording_trajectory", "save_simulate_output", "load_simulate_output", "MAX_CSV_BYTES"]

#: largest trajectory CSV read, bytes (counted while reading: a device or FIFO reports no size)
MAX_CSV_BYTES = 1 << 30


def save_simulate_output(f, *, t, nodes, energy, bars, strings, **extra) -> None:
    """Write a ``simulate`` output as ``.npz`` to the binary file object ``f``: ``t`` (S,) s,
    ``nodes`` (S, n, 3) m, ``energy`` (S,) J, ``bars`` (k, 2) and ``strings`` (m, 2) node
    indices, and ``extra`` arrays (``rest_length`` / ``force_density`` (S, m) in force from each
    record on; ``diverged`` and ``message`` when the run diverged)."""
    np.savez(f, t=t, nodes=nodes, energy=energy, bars=bars, strings=strings, **extra)


def load_simulate_output(path) -> tuple:
    """``(t, nodes, bars, strings)`` of a ``simulate`` output (:func:`save_simulate_output`).
    ValueError naming the file when it is not an ``.npz``; KeyError when an array is missing."""
    z = load_npz(path, "a simulate output with t, nodes, bars, strings")
    t, nodes = z["t"], z["nodes"]
    check_trajectory_arrays(t, nodes, path)
    return t, nodes, z["bars"], z["strings"]


def load_csv(path, n_nodes: int):
    """Read a long-format motion-capture CSV: a header line with the columns ``t,node,x,y,z``
    (any order, extra columns ignored), one row per tracked node per sample; ``t`` in s,
    ``node`` the 0-based node index of the structure, ``x,y,z`` in m. A node missing from a
    sample (no row, or NaN coordinates) is untracked at that sample.

    Returns ``t`` (S,), ``nodes`` (S, n_nodes, 3) with NaN where untracked, and the mask
    (S, n_nodes). Raises ValueError naming the line for bad rows."""
    import csv
    import io
    text = read_bounded(path, MAX_CSV_BYTES, "trajectory CSV")     # a BOM is dropped; /dev/zero, FIFOs refused
    with io.StringIO(text, newline="") as fh:
        rd = csv.reader(fh)
        try:
            header = [h.strip().lower() for h in next(rd)]
        except StopIteration:
            raise ValueError(f"{path}: empty CSV file") from None
        need = ("t", "node", "x", "y", "z")
        miss = [c for c in need if c not in header]
        if miss:
            raise ValueError(f"{path}: missing column(s) {miss}; expected a header with t,node,x,y,z")
        col = [header.index(c) for c in need]
        rows = []
        for ln, row in enumerate(rd, start=2):
            if not row or all(not x.strip() for x in row):
                continue
            try:
                tt = float(row[col[0]])
                nd = float(row[col[1]])
                xyz = [float(row[c]) if row[c].strip() else float("nan") for c in col[2:]]
            except (ValueError, IndexError):
                raise ValueError(f"{path}: line {ln}: cannot read {row!r} as t,node,x,y,z numbers") from None
            if not np.isfinite(tt):
                raise ValueError(f"{path}: line {ln}: t is {row[col[0]]!r}; sample times must be finite")
            if not np.isfinite(nd) or nd != int(nd) or not 0 <= nd < n_nodes:
                raise ValueError(f"{path}: line {ln}: node {row[col[1]]!r} is not a node index 0..{n_nodes - 1}")
            rows.append((tt, int(nd), *xyz))
    if not rows:
        raise ValueError(f"{path}: no data rows")
    a = np.array(rows, dtype=float)
    t, inv = np.unique(a[:, 0], return_inverse=True)
    nodes = np.full((t.size, n_nodes, 3), np.nan)
    seen = np.zeros((t.size, n_nodes), bool)
    for r, (s_, nd) in enumerate(zip(inv, a[:, 1].astype(int))):
        if seen[s_, nd]:
            raise ValueError(f"{path}: node {nd} appears twice at t = {t[s_]!r} s")
        seen[s_, nd] = True
        nodes[s_, nd] = a[r, 2:]
    mask = np.isfinite(nodes).all(axis=2)
    return t, nodes, mask


def load_trajectory(path, n_nodes: int, bars=None):
    """``(t, nodes, rest_length, mask)`` from a ``.npz`` as written by ``simulate`` (``t``,
    ``nodes``, optional ``rest_length``, optional bool ``node_mask`` (n,) or (S, n)), a
    long-format CSV (:func:`load_csv`; NaN / missing rows = untracked) or a lab recording
    (:func:`recording_trajectory`, which needs the structure's ``bars``)."""
    p = str(path)
    if p.lower().endswith(".csv"):
        t, nodes, mask = load_csv(p, n_nodes)
        return t, nodes, None, mask
    z = load_npz(p, "t (S,) s and nodes (S, n, 3) m as written by `python -m tensegrity_gym simulate`, "
                    "or a long-format .csv")
    if "metadata" in z and RECORDING_FORMAT in str(z["metadata"]):
        if bars is None:
            raise ValueError(f"{p}: a recording (tracked points on rods); its node trajectory needs the structure's "
                             "bars")
        t, nodes, mask = recording_trajectory(load_recording(p), bars, n_nodes)
        return t, nodes, None, mask
    for k in ("t", "nodes"):
        if k not in z:
            raise ValueError(f"{p}: no array {k!r} (found {sorted(z)}); expected t (S,) s and nodes "
                             f"(S, n, 3) m as written by `python -m tensegrity_gym simulate`")
    t, nodes = z["t"], z["nodes"]
    rl, mask = z.get("rest_length"), z.get("node_mask")
    if mask is None and np.asarray(nodes).ndim == 3:
        fin = np.isfinite(np.asarray(nodes, float)).all(axis=2)
        if not fin.all() and (fin | ~fin.any(axis=0)).all():
            mask = fin        # whole nodes NaN: untracked nodes (other NaN samples are reported as errors)
    return t, nodes, rl, mask


def recording_trajectory(rec, bars, n_nodes: int, rtol: float = 1e-6):
    """``(t, nodes, mask)`` of a :class:`~tensegrity_gym.io.recording.Recording` for a structure whose
    rod ``r`` joins nodes ``bars[r]``, on the fixed sample spacing system identification fits:
    the rods' end points (:meth:`~tensegrity_gym.io.recording.Recording.node_trajectory`; frames
    sharing a time stamp averaged) placed at their own sample times, and the sample times the
    recording skipped (dropped frames, gaps) added as untracked samples. Every frame must lie on
    the grid ``t0 + i h`` (``h`` the smallest interval, within ``rtol h``); ValueError naming the
    first frame off it otherwise (nothing is resampled or interpolated)."""
    t, nodes, mask = rec.node_trajectory(bars, n_nodes)
    if t.size < 2:
        return t, nodes, mask
    h = float(np.min(np.diff(t)))
    k = np.round((t - t[0]) / h)
    off = np.abs(t - t[0] - k * h)
    bad = np.flatnonzero(off > rtol * h)
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"t: frame times are not on a fixed grid (the shortest interval is {h:.6g} s, but the "
                         f"frame at t = {t[i]:.6g} s lies {off[i]:.3g} s off it); system identification fits "
                         f"evenly spaced samples, and this recording is not resampled (that would invent data)")
    S = int(k[-1]) + 1
    grid_t = t[0] + h * np.arange(S)
    grid_nodes = np.full((S, nodes.shape[1], 3), np.nan)
    grid_mask = np.zeros((S, nodes.shape[1]), bool)
    idx = k.astype(int)
    grid_nodes[idx], grid_mask[idx] = nodes, mask
    return grid_t, grid_nodes, grid_mask
