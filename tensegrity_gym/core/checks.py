"""Checks of user input shared by the physics and the environments: every error is a
``ValueError`` naming the argument and the value."""
from __future__ import annotations

import errno
import math
import re
import os
import stat

import numpy as np
from numba import njit

__all__ = ["ACTION_TOL", "check_positive", "check_array", "check_finite", "is_integer", "check_count",
           "check_flag", "check_options", "check_action",
           "check_action_tensor", "load_npz", "check_frame_size", "MAX_FRAME_SIZE", "check_unit_axes",
           "read_bounded", "open_regular", "load_npy", "check_real", "xml_text", "check_trajectory_arrays"]

#: an action may lie this far outside [-1, 1] (round-off of a float32 policy) before it is an error
ACTION_TOL = 1e-6
#: largest rendered frame side, pixels (an 8192 x 8192 RGB frame is 192 MiB)
MAX_FRAME_SIZE = 8192


def check_positive(value, name: str, unit: str = "", allow_zero: bool = False) -> float:
    """``float(value)`` if finite and > 0 (>= 0 with ``allow_zero``), else ValueError naming ``name``.
    A string or a bool is not a number here (``"1e-3"`` and ``True`` are refused, not converted)."""
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise ValueError(f"{name}: expected a number{' in ' + unit if unit else ''}, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number{' in ' + unit if unit else ''}, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name}: must be {'>= 0' if allow_zero else 'positive'} and finite"
                         f"{' (' + unit + ')' if unit else ''}, got {value!r}")
    return v


def is_integer(value) -> bool:
    """True for a Python or NumPy integer that is not a bool (``2.0``, ``"2"`` and ``True`` are not)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def check_count(value, name: str, minimum: int = 0, what: str = "") -> int:
    """``value`` as an int if it is an integer (or an integral float such as ``20.0``) >= ``minimum``;
    ValueError naming ``name``, what it counts and the value otherwise (a bool, a string, NaN,
    ``2.5`` or a number below ``minimum``)."""
    ok = is_integer(value) or (isinstance(value, (float, np.floating)) and math.isfinite(value)
                               and float(value).is_integer())
    if not ok or value < minimum:
        raise ValueError(f"{name}: must be an integer >= {minimum}{f' ({what})' if what else ''}, got {value!r}")
    return int(value)


def check_flag(value, name: str) -> bool:
    """``value`` as a bool if it is ``True`` or ``False`` (Python or NumPy); ValueError naming
    ``name`` otherwise (a string such as ``"false"`` would otherwise count as true)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name}: must be True or False, got {value!r}")
    return bool(value)


def check_options(options) -> dict:
    """``reset(options=...)`` as a (new) dict; ValueError unless a dict or None."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise ValueError(f"options: expected a dict or None, got {options!r}")
    return dict(options)


def check_frame_size(width, height) -> tuple[int, int]:
    """``(width, height)`` of rendered frames as ints in 1 .. :data:`MAX_FRAME_SIZE` pixels;
    ValueError naming the argument and the value otherwise (checked at construction, not at the
    first ``render()``)."""
    out = []
    for v, name in ((width, "width"), (height, "height")):
        if not is_integer(v) or not 1 <= v <= MAX_FRAME_SIZE:
            raise ValueError(f"{name}: must be an integer number of pixels in 1..{MAX_FRAME_SIZE}, got {v!r}")
        out.append(int(v))
    return out[0], out[1]


def load_npz(path, expected: str) -> dict:
    """The arrays of the NumPy ``.npz`` archive at ``path`` as a dict (pickled objects refused).
    ValueError naming the file for anything else (a single ``.npy`` array, a pickle, text, a
    damaged archive), with ``expected`` saying what the file should hold; FileNotFoundError and
    IsADirectoryError pass unchanged (the callers word them)."""
    import zipfile
    p = str(path)
    with open_regular(p, ".npz archive") as fh:   # a FIFO or a device is refused, not read
        try:
            z = np.load(fh, allow_pickle=False)
        except (FileNotFoundError, IsADirectoryError):
            raise
        except (ValueError, OSError, EOFError, zipfile.BadZipFile):
            raise ValueError(f"{p}: not a NumPy .npz archive (expected {expected})") from None
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise ValueError(f"{p}: a single NumPy array (.npy), not an .npz archive of named arrays "
                             f"(expected {expected})")
        with z:
            try:
                return {k: z[k] for k in z.files}
            except (ValueError, OSError, EOFError, zipfile.BadZipFile) as e:
                raise ValueError(f"{p}: a damaged .npz archive or one holding pickled objects (expected {expected}): "
                                 f"{' '.join(str(e).split())[:200]}") from None


def check_array(value, shape: tuple, name: str) -> np.ndarray:
    """``value`` as a float64 array of ``shape``; ValueError naming ``name`` for another shape, and
    naming the first offending index and its value for a NaN/inf entry."""
    a = _real_array(value, shape, name)
    if a.shape != tuple(shape):
        raise ValueError(f"{name}: expected shape {tuple(shape)}, got {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        idx = _first(bad)
        raise ValueError(f"{name}: entry {_index(idx)} is not finite: {float(a[idx])!r}")
    return a


def _real_array(value, shape: tuple, name: str) -> np.ndarray:
    """``value`` as a float64 array; ValueError naming ``name`` for text, ragged lists or complex
    numbers (NumPy would drop an imaginary part with only a warning)."""
    try:
        if np.iscomplexobj(value):
            raise TypeError
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected an array of real numbers with shape {tuple(shape)}, "
                         f"got {_brief(value)}") from None


def _brief(value, width: int = 120) -> str:
    """``repr(value)`` on one line, at most ``width`` characters (error messages are one line)."""
    text = " ".join(repr(value).split())
    return text if len(text) <= width else text[:width - 3] + "..."


def check_finite(x: np.ndarray, name: str, nonnegative: bool = False) -> None:
    """ValueError ``"{name}: entry {index} is {value}; must be finite"`` (``"finite and >= 0"``
    with ``nonnegative``) for the first offending entry of the float array ``x``."""
    ok = np.isfinite(x)
    if nonnegative:
        ok &= x >= 0
    if not ok.all():
        idx = _first(~ok)
        need = "finite and >= 0" if nonnegative else "finite"
        raise ValueError(f"{name}: entry {_index(idx)} is {float(x[idx])!r}; must be {need}")


def _first(mask) -> tuple:
    return tuple(int(i) for i in np.argwhere(mask)[0])


def _index(idx: tuple):
    return idx[0] if len(idx) == 1 else idx


def _nonfinite_action(name, idx, value):
    return ValueError(f"{name}: entry {_index(idx)} is {value!r}; actions must be finite numbers in [-1, 1]")


def _outside_action(name, idx, value):
    return ValueError(f"{name}: entry {_index(idx)} is {value:.6g}, outside the action space [-1, 1] "
                      "(clip it first, or construct the env with clip_actions=True to saturate instead)")


@njit(cache=True, nogil=True)
def _clip_in_place(a, clip, tol):
    """The common case of :func:`check_action` in one compiled pass over ``a`` (1-d float64,
    modified in place): False (``a`` partly clipped) if an entry is non-finite, or with ``clip``
    False beyond ``1 + tol`` of the box (the caller then runs the reference check, which raises
    the right error); else ``a`` clipped to [-1, 1] (``np.clip`` semantics) and True."""
    for i in range(a.size):
        v = a[i]
        if not np.isfinite(v):
            return False
        if not clip and abs(v) > 1.0 + tol:
            return False
        if v < -1.0:
            a[i] = -1.0
        elif v > 1.0:
            a[i] = 1.0
    return True


def check_action(action, shape: tuple, clip: bool = True, name: str = "action") -> np.ndarray:
    """An action as a float64 array of ``shape`` in [-1, 1]:

    * wrong shape -> ValueError (a flat sequence of the right size is reshaped for a 1-D ``shape``);
    * NaN or inf -> ValueError naming the (first) offending index and the value;
    * entries outside [-1, 1]: clipped to the box if ``clip`` (the documented Box contract, like
      Gymnasium's MuJoCo envs whose actuators saturate), else ValueError naming the index when
      beyond ``ACTION_TOL`` of the bounds (round-off within it is clipped).

    A float ndarray of the right shape is checked and clipped in one compiled pass; anything
    that pass does not accept goes through the NumPy check, which raises the error (the same
    result either way).
    """
    if (type(action) is np.ndarray and action.shape == tuple(shape)
            and (action.dtype == np.float32 or action.dtype == np.float64)):
        a = np.array(action, dtype=np.float64, order="C")
        if _clip_in_place(a.reshape(-1), clip, ACTION_TOL):
            return a
    a = _real_array(action, shape, name)
    if a.shape != tuple(shape):
        if a.size == int(np.prod(shape)) and a.ndim <= 1 and len(shape) == 1:
            a = a.reshape(shape)
        else:
            raise ValueError(f"{name}: expected shape {tuple(shape)}, got {a.shape}")
    finite = np.isfinite(a)
    if not finite.all():
        idx = _first(~finite)
        raise _nonfinite_action(name, idx, a[idx])
    if not clip:
        bad = np.abs(a) > 1.0 + ACTION_TOL
        if bad.any():
            idx = _first(bad)
            raise _outside_action(name, idx, a[idx])
    return np.clip(a, -1.0, 1.0)


def check_action_tensor(actions, shape: tuple, device, dtype, clip: bool, extra=None):
    """:func:`check_action` for a batch on a torch ``device`` (the device-resident vector envs):
    ``actions`` a tensor on ``device`` or anything ``torch.as_tensor`` takes, of ``shape`` (N, na);
    returns ``(the actions in dtype clipped to [-1, 1], bool(extra))`` after ONE small device ->
    host read (``extra``: a bool scalar tensor the caller needs on the host too, e.g. "an env
    must autoreset"). Errors as :func:`check_action`, plus a tensor on another device."""
    import torch
    name = "actions"
    if isinstance(actions, torch.Tensor):
        if actions.device != device:
            raise ValueError(f"{name}: tensor on device {str(actions.device)!r}, but the env runs on "
                             f"{str(device)!r}; move it with .to({str(device)!r})")
        if not (actions.is_floating_point() or actions.dtype in (torch.int32, torch.int64)):
            raise ValueError(f"{name}: expected a float tensor, got {actions.dtype}")
        a = actions.to(dtype)
    else:
        try:
            a = torch.as_tensor(np.array(actions, dtype=float), dtype=dtype, device=device)
        except (TypeError, ValueError):
            raise ValueError(f"{name}: expected a tensor or array of numbers with shape {tuple(shape)}, "
                             f"got {type(actions).__name__}") from None
    if tuple(a.shape) != tuple(shape):
        raise ValueError(f"{name}: expected shape {tuple(shape)}, got {tuple(a.shape)}")
    nonfinite = ~torch.isfinite(a)
    outside = a.abs() > 1.0 + ACTION_TOL
    no = torch.zeros((), dtype=torch.bool, device=device)
    flags = torch.stack([nonfinite.any(), no if clip else outside.any(),
                         no if extra is None else extra]).cpu().tolist()
    for bad, err, fmt in ((flags[0], nonfinite, _nonfinite_action), (flags[1], outside, _outside_action)):
        if bad:
            idx = tuple(int(x) for x in torch.nonzero(err)[0].cpu())
            raise fmt(name, idx, float(a[idx]))
    return torch.clamp(a, -1.0, 1.0), bool(flags[2])


def check_unit_axes(q, name: str = "state.q", tol: float = 1e-6) -> None:
    """ValueError naming the first rod whose axis ``b`` (entries 3:6 of ``q`` (..., k, 6)) is not a
    unit vector (``| |b| - 1 | > tol``; a zero axis would give NaN in the dynamics)."""
    b = np.asarray(q, float)[..., 3:6]
    norm = np.linalg.norm(b, axis=-1)
    bad = ~(np.abs(norm - 1.0) <= tol)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name}: rod axis b of rod {idx[-1]}{' (copy ' + str(idx[0]) + ')' if len(idx) > 1 else ''} "
                         f"has length {float(norm[idx]):.6g}; the axis must be a unit vector (|b| = 1 within {tol:g})")

def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _refuse_irregular(p: str, mode: int, what: str) -> None:
    if stat.S_ISDIR(mode):
        raise IsADirectoryError(errno.EISDIR, f"is a directory, not a {what}", p)
    if not stat.S_ISREG(mode):
        raise ValueError(f"{p} is {_kind(mode)}, not a regular file (expected a {what}; devices, FIFOs and sockets "
                         "are not read)")


def open_regular(path, what: str = "file", cap: int | None = None):
    """The regular file at ``path`` opened for binary reading: the one way user input files are
    opened. A FIFO (its open would block until a writer comes), a device (``/dev/zero`` never
    ends), a socket, or a link to one of these is refused with ValueError naming the file before
    it is opened; the type is checked again on the open file. ``cap`` (bytes): a larger file is
    refused from its size. FileNotFoundError, PermissionError and IsADirectoryError pass (the
    callers word them)."""
    p = os.fspath(path)
    _refuse_irregular(p, os.stat(p).st_mode, what)
    fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        st = os.fstat(fd)
        _refuse_irregular(p, st.st_mode, what)      # replaced between the check and the open
        if cap is not None and st.st_size > cap:
            raise ValueError(f"{p}: {st.st_size / 2**20:.4g} MiB, larger than the {cap / 2**20:.4g} MiB a {what} "
                             "may have")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_bounded(path, cap: int, what: str = "file", binary: bool = False):
    """The contents of the regular file ``path`` (:func:`open_regular`: FIFOs and devices refused
    before reading), read in chunks, ValueError naming the file as soon as more than ``cap``
    bytes were read (a file of ``/proc`` reports size 0, so the bytes read, not ``st_size``,
    bound the read). Text is decoded as UTF-8 (a BOM is dropped)."""
    p = os.fspath(path)
    chunks, total = [], 0
    with open_regular(p, what) as fh:
        while True:
            chunk = fh.read(min(1 << 20, cap + 1 - total))
            if not chunk:
                break
            total += len(chunk)
            if total > cap:
                raise ValueError(f"{p}: larger than the {cap / 2**20:.4g} MiB a {what} may have (stopped reading there)")
            chunks.append(chunk)
    data = b"".join(chunks)
    if binary:
        return data
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise ValueError(f"{p}: not UTF-8 text (byte {e.start}); the {what} must be UTF-8") from None


def load_npy(path, expected: str, what: str = "file", cap: int | None = None) -> np.ndarray:
    """The array of the NumPy ``.npy`` file at ``path`` (:func:`open_regular`; pickled objects
    refused). ValueError naming the file for anything else (an empty or truncated file, an
    ``.npz`` archive, text), with ``expected`` saying what the file should hold."""
    import zipfile
    p = os.fspath(path)
    with open_regular(p, what, cap) as fh:
        try:
            arr = np.load(fh, allow_pickle=False)
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as e:
            why = "empty" if isinstance(e, EOFError) and fh.tell() == 0 else " ".join(str(e).split())[:200]
            raise ValueError(f"{p}: not a NumPy .npy array (expected {expected}): {why or type(e).__name__}") \
                from None
        if not isinstance(arr, np.ndarray):
            arr.close()
            raise ValueError(f"{p}: an .npz archive, not a single .npy array (expected {expected})")
    return arr


def check_real(value, name: str, what: str = "") -> None:
    """ValueError naming ``name`` for complex numbers (NumPy would drop the imaginary part with
    only a warning when converting to float); anything else passes (the caller checks it)."""
    try:
        cplx = np.iscomplexobj(value)
    except (TypeError, ValueError):     # ragged: the caller's conversion words it
        return
    if cplx:
        raise ValueError(f"{name}: complex numbers are not accepted{' (' + what + ')' if what else ''}; "
                         f"expected real numbers, got {_brief(value)}")


#: characters XML 1.0 cannot hold, not even as character references (C0 controls but tab, newline
#: and carriage return; surrogates; U+FFFE, U+FFFF)
_XML_INVALID = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")


def xml_text(text: str) -> str:
    """``text`` with every character XML 1.0 cannot hold replaced by its Python escape
    (``"\\x01"`` for U+0001), so that a name from a user's file gives a parsable document."""
    return _XML_INVALID.sub(lambda m: m.group(0).encode("unicode_escape").decode("ascii"), text)


def check_trajectory_arrays(t, nodes, source: str) -> None:
    """ValueError naming ``source`` unless ``nodes`` is a real (S, n, 3) array (m) with S >= 1 and
    ``t`` real of shape (S,) (s): what a simulate output holds."""
    for name, a, what in (("t", t, "(S,) sample times, s"), ("nodes", nodes, "(S, n, 3) node positions, m")):
        if np.asarray(a).dtype.kind not in "fiu":
            raise ValueError(f"{source}: {name} holds {np.asarray(a).dtype} values; expected real numbers, {what}")
    nodes, t = np.asarray(nodes), np.asarray(t)
    if nodes.ndim != 3 or nodes.shape[2] != 3 or nodes.shape[0] < 1:
        raise ValueError(f"{source}: nodes has shape {nodes.shape}; expected (S, n, 3) node positions, m, S >= 1")
    if t.shape != nodes.shape[:1]:
        raise ValueError(f"{source}: t has shape {t.shape}; expected ({nodes.shape[0]},), one time per sample of nodes")
