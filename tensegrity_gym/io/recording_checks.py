"""Input checks of a :class:`~tensegrity_gym.io.recording.Recording`: arrays of numbers, time
stamps, readings and command rows, each refusal naming the frame and the field."""
from __future__ import annotations

import numpy as np

__all__ = ["frozen", "float_array", "check_times", "check_readings", "check_rows"]


def frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a)          # a copy the caller cannot change under the recording
    a.setflags(write=False)
    return a


def float_array(value, name: str, ndim: int, what: str) -> np.ndarray:
    try:
        if np.iscomplexobj(value):
            raise TypeError
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"field {name!r}: expected {what} (real numbers)") from None
    if a.ndim != ndim:
        raise ValueError(f"field {name!r}: expected {what}, got an array of shape {a.shape}")
    return a


def check_times(t, name: str) -> np.ndarray:
    t = float_array(t, name, 1, "a 1-D array of time stamps, s")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ValueError(f"frame {bad[0]}, field {name!r}: time stamp {float(t[bad[0]])!r}; time stamps must be finite (s)")
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise ValueError(f"frame {i}, field {name!r}: time goes backwards ({float(t[i])!r} s after {float(t[i - 1])!r} s at frame "
                         f"{i - 1}); frames must be in time order")
    return t


def check_readings(a, t, name: str, width: tuple, what: str) -> np.ndarray:
    """A (T, *width) array of readings at times ``t``: NaN marks a missing reading, inf is refused."""
    a = float_array(a, name, 1 + len(width), f"an array of shape (frames, {', '.join(map(str, width))}), {what}")
    if a.shape != (t.size,) + tuple(width):
        raise ValueError(f"field {name!r}: shape {a.shape}, expected {(t.size,) + tuple(width)} ({what})")
    bad = np.argwhere(np.isinf(a))
    if bad.size:
        i = tuple(int(x) for x in bad[0])
        raise ValueError(f"frame {i[0]}, field {name!r}: entry {i[1:]} is {float(a[i])!r}; NaN marks a missing reading, "
                         "inf is an error")
    return a


def check_rows(rows, n_rows: int, width: int, name: str, what: str) -> np.ndarray:
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
    a = float_array(seq, name, 2, f"(frames, {width}) numbers") if len(seq) else np.zeros((0, width))
    if a.shape[0] != n_rows:
        raise ValueError(f"field {name!r}: {a.shape[0]} frames, but command_t has {n_rows} time stamps")
    bad = np.argwhere(~np.isfinite(a))
    if bad.size:
        i, j = (int(x) for x in bad[0])
        raise ValueError(f"frame {i}, field {name!r}: value {j} is {float(a[i, j])!r}; commands must be finite")
    return a
