"""Command line: ``python -m tensegrity_gym {simulate,info,demo,export,view} ...`` (SI units throughout).

* ``simulate STRUCTURE --duration T --dt DT --integrator rk4 --out traj.npz`` writes
  ``t`` (S,) in s, ``nodes`` (S, n, 3) in m and ``energy`` (S,) in J (kinetic + string
  potential + gravity) at every step (``--record-every K`` thins the output).
* ``info STRUCTURE`` prints counts, masses, prestress, slack strings and the estimated
  largest stable step of the explicit integrators.
* ``identify STRUCTURE TRAJ.npz|TRAJ.csv --fit stiffness damping mass --per-member|--scale
  --out fit.json [--plot fit.png]`` fits physical parameters to a recorded motion
  (:mod:`tensegrity_gym.sysid`, docs/sysid.md); exit status 0 when the fit converged and every
  parameter is identifiable, 3 when the result is flagged.
* ``demo --out DIR`` simulates the default prism released off equilibrium and writes a
  plot and a JSON summary.
* ``export STRUCTURE --format mjcf --out model.xml [--ground]`` writes a MuJoCo model of the
  structure (:mod:`tensegrity_gym.mjcf`); ``--format json`` writes this package's JSON;
  ``--from tnsgrt`` reads STRUCTURE as a tnsgrt structure dict (:mod:`tensegrity_gym.tnsgrt`).
* ``simulate ... --video out.mp4`` / ``demo --video out.mp4`` also render the run to a video.
* ``view traj.npz [--structure S]`` opens an interactive view of a ``simulate`` output (time
  slider, play/pause): a window where there is a display, else a browser view (viser).

``STRUCTURE`` is a JSON file or a built-in name (``prism3``, ``icosahedron``, ...).
Output files are written atomically (temporary file in the same folder, fsync, rename) with
the user's umask: an interrupted run (Ctrl-C or SIGTERM) never leaves a truncated file, a
temporary file or a destroyed existing one. An existing output is replaced only with
``--force``; the output path is checked before anything is simulated.

Requests are estimated before they run and refused above the limits: ``--max-steps``
(default 1e9 integration steps) and ``--max-memory`` (GiB; default half the machine's
memory) for the recorded trajectory, for building a built-in structure (``prism<p>``,
``tower<q>``: the SVD of their equilibrium matrix) and for ``info``'s stable-step estimate
(eigenvalues of a 12k x 12k matrix for k rods; ``--no-stable-step`` skips it).

Exit codes (every error is one line on stderr, never a traceback):

=====  =====================================================================================
0      success
2      bad arguments (unknown option, a value that is not a positive number, ...)
3      bad input: structure file not found or unreadable, not JSON, or invalid
       (``StructureError``); ``view``: not a ``simulate`` output or a structure that does not match
4      output problem: the output is a directory, its folder is not writable, it exists and
       ``--force`` was not given, writing failed (disk full), or no renderer / viewer is available
5      request too large: more steps or memory than the limits above (the estimate is printed)
6      the simulation diverged (non-finite state, an adaptive integrator failed, or the energy
       grew a million-fold: an unstable step); ``simulate`` keeps the records up to the
       divergence in the output, flagged by ``diverged`` = True and a ``message``
130    interrupted (Ctrl-C); 143: terminated (SIGTERM); 141: output pipe closed (``| head``)
=====  =====================================================================================
"""
from __future__ import annotations

import argparse
import json
import os
import re
import signal
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from . import __version__
from . import dynamics as dyn
from .builders import BUILDERS
from .checks import check_trajectory_arrays, load_npz
from .integrators import INTEGRATORS, EvaluationBudgetExceeded, Schedule, SimulationDiverged, resolve, simulate
from .sizing import StructureTooLarge
from .structure import StructureError

PROGRESS_MIN_STEPS = 20000
DEFAULT_MAX_STEPS = 1e9
#: adaptive methods (dop853, radau) may evaluate the accelerations this many times per --max-steps step
#: (dop853 takes 12 per accepted step, radau a few Newton iterations of 3 stages) before exit code 5
ADAPTIVE_EVALUATIONS_PER_STEP = 20
EXIT_OK, EXIT_USAGE, EXIT_STRUCTURE, EXIT_OUTPUT, EXIT_TOO_LARGE, EXIT_DIVERGED = 0, 2, 3, 4, 5, 6
EXIT_INTERRUPTED, EXIT_PIPE, EXIT_TERMINATED = 130, 141, 143
CHUNK_STEPS = 200_000          # a fixed-step run is integrated in chunks of about this many steps
ENERGY_BLOWUP = 1e6            # energy growth (x its scale) that flags an unstable run


class CLIError(Exception):
    """A known error: ``message`` goes to stderr as one line, ``code`` is the exit status."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code


class _Terminated(BaseException):
    """Raised by the SIGTERM handler so that ``finally`` blocks remove temporary files."""


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _default_max_memory_gib() -> float:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 / 2**30
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return 4.0


def _gib(nbytes: float) -> str:
    return f"{nbytes / 2**30:.3g} GiB"


def _require_memory(nbytes: float, args, what: str) -> None:
    limit = args.max_memory * 2**30
    if not nbytes <= limit:
        raise CLIError(EXIT_TOO_LARGE, f"{what} needs about {_gib(nbytes)} of memory, above the limit of "
                                       f"{_gib(limit)} (--max-memory)")


# --------------------------------------------------------------------------- structure
_SIZED = {"prism": lambda p: (2 * p, p, 3 * p),
          "tower": lambda q: (6 * q, 3 * q, 15 * q - 6)}


def _builder_bytes(n: int, k: int, m: int) -> float:
    """Memory of a built-in builder's self-stress: the (6k x m) equilibrium matrix, its
    (n, 3, m) columns and the full SVD (6k x 6k and m x m), 8 bytes each."""
    return 8.0 * (3 * n * m + 6 * k * m + (6 * k) ** 2 + m * m)


def _load(spec: str, args):
    from . import load_structure
    mt = re.fullmatch(r"(prism|tower)(\d+)", spec)
    if mt and not os.path.exists(spec) and spec not in BUILDERS:
        size = int(mt.group(2)) if len(mt.group(2)) < 12 else 10 ** 12
        n, k, m = _SIZED[mt.group(1)](size)
        if mt.group(1) == "prism":
            _require_memory(_builder_bytes(n, k, m), args,
                            f"building {spec!r} ({n} nodes, {k} rods, {m} strings; SVD of its {6 * k} x {m} "
                            "equilibrium matrix)")
        else:   # tower: no SVD (uniform strain); compile + a step + the stable-step estimate, linear
            from .sizing import memory_estimate
            _require_memory(memory_estimate(k, n, m), args, f"{spec!r} ({n} nodes, {k} rods, {m} strings: "
                            "compile, one step and the stable-step estimate)")
    try:
        return load_structure(spec)
    except FileNotFoundError:
        raise CLIError(EXIT_STRUCTURE, f"structure file {spec!r} not found") from None
    except IsADirectoryError:
        raise CLIError(EXIT_STRUCTURE, f"structure {spec!r} is a directory, not a structure file") from None
    except PermissionError as e:
        raise CLIError(EXIT_STRUCTURE, f"structure file {spec!r} cannot be read ({e.strerror})") from None
    except StructureError as e:
        raise CLIError(EXIT_STRUCTURE, f"structure {spec!r}: {e}") from None


# --------------------------------------------------------------------------- output files
def _check_out(path: Path, force: bool, flag: str = "--out", create_folders: bool = True) -> None:
    """Fail before any work if ``path`` cannot be written (or would be overwritten); missing
    folders are created when writing unless ``create_folders`` is False (then an error)."""
    if not create_folders and not path.parent.is_dir():
        raise CLIError(EXIT_OUTPUT, f"{flag} {str(path)!r}: folder {str(path.parent)!r} does not exist")
    if path.is_dir():
        raise CLIError(EXIT_OUTPUT, f"{flag} {str(path)!r} is a directory; give a file name")
    if path.exists() and not force:
        raise CLIError(EXIT_OUTPUT, f"{flag} {str(path)!r} exists; pass --force to overwrite it")
    folder = path.parent
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir():
        raise CLIError(EXIT_OUTPUT, f"{flag} {str(path)!r}: {str(folder)!r} is a file, not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise CLIError(EXIT_OUTPUT, f"{flag} {str(path)!r}: folder {str(folder)!r} is not writable")


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _atomic_write(path: Path, writer) -> None:
    """``writer(file object)`` into a temporary file beside ``path``, fsync, chmod to the
    user's umask, rename over ``path``; the temporary file is removed on any failure."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as e:
        raise CLIError(EXIT_OUTPUT, f"cannot write {str(path)!r}: {e.strerror or e}") from None
    try:
        with os.fdopen(fd, "wb") as f:
            writer(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except OSError as e:
        raise CLIError(EXIT_OUTPUT, f"cannot write {str(path)!r}: {e.strerror or e}") from None
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _number(kind, what: str, ok, rule: str):
    """An argparse type: ``kind(text)`` if it parses as ``what`` and ``ok(value)``, else an error
    naming the rule and the text."""
    def parse(text):
        try:
            v = kind(text)
        except (ValueError, OverflowError):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not ok(v):
            raise argparse.ArgumentTypeError(f"{rule}, got {text!r}")
        return v
    return parse


def _positive(kind):
    return _number(kind, "a number", lambda v: np.isfinite(v) and v > 0, "must be positive and finite")


_non_negative = _number(float, "a number", lambda v: np.isfinite(v) and v >= 0, "must be >= 0 and finite")
_seed = _number(int, "an integer", lambda v: v >= 0, "must be >= 0")
_port = _number(int, "an integer", lambda v: 0 <= v <= 65535, "must be a TCP port in 0..65535 (0: any free port)")


def _n_steps(duration: float, dt: float, args) -> int:
    ratio = duration / dt
    if not ratio <= args.max_steps:
        raise CLIError(EXIT_TOO_LARGE, f"--duration {duration:g} s at --dt {dt:g} s is {ratio:.3g} steps, above "
                                       f"the limit of {args.max_steps:.3g} (--max-steps)")
    n_steps = int(round(ratio))
    if n_steps < 1:
        raise CLIError(EXIT_USAGE, f"--duration {duration} s is shorter than one step of --dt {dt} s")
    return n_steps


def _trajectory_bytes(model, n_records: int) -> float:
    """Recorded q, qd (6 k each), nodes (3 n), energy and time per record, twice (temporaries)."""
    return 2.0 * 8.0 * n_records * (12 * model.n_bars + 3 * model.n_nodes + 2)


# --------------------------------------------------------------------------- commands
def _run(model, state, args, n_steps: int, progress: bool):
    """``simulate`` in chunks (fixed-step methods) so that a divergence keeps the records before
    it. Returns ``(t, q, qd, message)``, ``message`` None unless the run diverged."""
    info = resolve(args.integrator)
    kw = dict(project=not args.no_project, backend=args.backend, rtol=args.rtol, atol=args.atol,
              rest_length=args.rest_length, force_density=args.force_density)
    if info.adaptive:
        try:
            t, q, qd = simulate(model, state, args.dt, n_steps, args.integrator, record_every=args.record_every,
                                progress=progress, max_evaluations=int(ADAPTIVE_EVALUATIONS_PER_STEP * args.max_steps),
                                **kw)
        except EvaluationBudgetExceeded as e:
            raise CLIError(EXIT_TOO_LARGE, f"{info.name}: {e}; loosen --rtol/--atol, shorten --duration or raise "
                           f"--max-steps (it allows {ADAPTIVE_EVALUATIONS_PER_STEP} evaluations per step)") from None
        except SimulationDiverged as e:
            empty = np.empty((0,) + state.q.shape)
            return np.zeros(0), empty, empty, str(e)
        return t, q, qd, None
    every = args.record_every
    n_rec = n_steps // every
    per_chunk = max(1, CHUNK_STEPS // every)
    ts = state.t + args.dt * every * np.arange(n_rec + 1)
    qs = np.empty((n_rec + 1,) + state.q.shape)
    qds = np.empty_like(qs)
    qs[0], qds[0] = state.q, state.qd
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n_steps, unit="step", desc=info.name)
    done, st, message = 0, state, None
    try:
        while done < n_rec:
            r = min(per_chunk, n_rec - done)
            try:
                _, q, qd = simulate(model, st, args.dt, r * every, args.integrator, record_every=every, **kw)
            except SimulationDiverged as e:
                # failure path only: redo this chunk one record at a time to keep the records before it
                message = str(e)
                for _ in range(r):
                    try:
                        _, q, qd = simulate(model, st, args.dt, every, args.integrator, record_every=every, **kw)
                    except SimulationDiverged as e2:
                        message = str(e2)
                        break
                    done += 1
                    qs[done], qds[done] = q[1], qd[1]
                    st = dyn.State(q[-1], qd[-1], ts[done])
                break
            qs[done + 1:done + r + 1], qds[done + 1:done + r + 1] = q[1:], qd[1:]
            done += r
            st = dyn.State(q[-1], qd[-1], ts[done])
            if bar is not None:
                bar.update(r * every)
    finally:
        if bar is not None:
            bar.close()
    S = done + 1
    return ts[:S], qs[:S], qds[:S], message


def _outputs_and_model(args, second, flag: str):
    """``(out path, structure, model)`` of a command writing ``--out`` and optionally ``second``
    (the path given to ``flag``): both checked before any work, then the structure loaded."""
    out = Path(args.out)
    _check_out(out, args.force)
    if second:
        _check_out(Path(second), args.force, flag)
    s = _load(args.structure, args)
    return out, s, dyn.compile_model(s)


def load_schedule(path, name: str, n_strings: int) -> Schedule:
    """A command schedule (:class:`tensegrity_gym.integrators.Schedule`) from ``.npz`` (arrays
    ``t`` (C,) s and ``name`` (C, m)) or ``.csv`` (a header row, then one row per command: the
    time in s, then the m strings' values). ValueError naming the file, the row and the value."""
    p = str(path)
    unit = "m" if name == "rest_length" else "N/m"
    if p.lower().endswith(".csv"):
        try:
            a = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
        except ValueError as e:
            raise ValueError(f"{p}: not a CSV of numbers after its header row ({_one_line(e)})") from None
        if a.shape[1] != n_strings + 1:
            raise ValueError(f"{p}: expected {n_strings + 1} columns (t in s, then {n_strings} strings' {name} in "
                             f"{unit}), got {a.shape[1]}")
        t, v = a[:, 0], a[:, 1:]
    else:
        z = load_npz(p, f"arrays t (C,) s and {name} (C, {n_strings}) {unit}, or a .csv")
        for k in ("t", name):
            if k not in z:
                raise ValueError(f"{p}: no array {k!r} (found {sorted(z)}); expected t (C,) s and {name} "
                                 f"(C, {n_strings}) {unit}")
        t, v = z["t"], z[name]
    v = np.asarray(v, dtype=float)
    if v.ndim != 2 or v.shape[1] != n_strings:
        raise ValueError(f"{p}: {name} must have shape (C, {n_strings}) (one row per command time, one column per "
                         f"string), got {v.shape}")
    return Schedule(t, v, name)


def cmd_simulate(args) -> int:
    out, s, model = _outputs_and_model(args, args.video, "--video")
    for name in ("rest_length", "force_density"):
        path = getattr(args, name)
        if path is None:
            continue
        flag = "--" + name.replace("_", "-")
        if args.backend == "torch":
            raise CLIError(EXIT_USAGE, f"{flag}: command schedules run with --backend auto or numba")
        try:
            sched = load_schedule(path, name, model.n_strings)
            sched.rows(np.zeros(1), args.dt)       # the first command must be at the start (t = 0 s)
            setattr(args, name, sched)
        except FileNotFoundError:
            raise CLIError(EXIT_STRUCTURE, f"{flag}: file {path!r} not found") from None
        except (ValueError, OSError, KeyError) as e:
            raise CLIError(EXIT_STRUCTURE, f"{flag} {path!r}: {_one_line(e)}") from None
    state = dyn.initial_state(model)
    n_steps = _n_steps(args.duration, args.dt, args)
    _require_memory(_trajectory_bytes(model, n_steps // args.record_every + 1), args,
                    f"recording {n_steps // args.record_every + 1} states of {s.n_nodes} nodes")
    progress = (not args.no_progress) and n_steps >= PROGRESS_MIN_STEPS
    t0 = time.perf_counter()
    if args.backend == "torch":   # optional torch backend (tensegrity_gym.torch_backend) on --device
        try:
            from . import torch_backend
            t, q, qd = torch_backend.simulate(model, state, args.dt, n_steps, args.integrator, device=args.device,
                                              record_every=args.record_every, project=not args.no_project)
        except (ImportError, ValueError) as exc:
            raise CLIError(EXIT_USAGE, f"--backend torch: {exc}") from None
        diverged = None if (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))) else \
            "the torch backend's state became non-finite"
    else:
        t, q, qd, diverged = _run(model, state, args, n_steps, progress)
    wall = time.perf_counter() - t0
    S = len(t)
    qf, qdf = q.reshape((S,) + q.shape[2:]), qd.reshape((S,) + qd.shape[2:])
    nodes = dyn.node_positions(model, qf) if S else np.zeros((0, s.n_nodes, 3))
    E = dyn.energy(model, qf, qdf) if S else np.zeros(0)
    if diverged is None and S > 1:
        scale = max(abs(float(E[0])), s.total_mass * 9.81 * max(float(np.ptp(s.nodes, axis=0).max()), 1e-3))
        grown = np.flatnonzero(~(E - E[0] <= ENERGY_BLOWUP * scale))
        if grown.size:
            i = int(grown[0])
            diverged = (f"{args.integrator}: the energy grew from {E[0]:.4g} J to {E[i]:.4g} J by t = {t[i]:.6g} s "
                        f"(dt = {args.dt:g} s): the step is unstable; reduce --dt")
    arrays = dict(t=t, nodes=nodes, energy=E, bars=s.bars, strings=s.strings)
    for name in ("rest_length", "force_density"):
        sched = getattr(args, name)
        if sched is not None and S:   # the row in force over the step from each record on
            arrays[name] = sched.values[sched.rows(t, args.dt)]
    if diverged is not None:
        arrays.update(diverged=np.array(True), message=np.array(_one_line(diverged)))
    _atomic_write(out, lambda f: np.savez(f, **arrays))
    if diverged is not None:
        raise CLIError(EXIT_DIVERGED, f"simulation diverged: {_one_line(diverged)}; wrote {S} records "
                                      f"(up to the divergence) to {out}, flagged diverged=True")
    drift = float(np.max(np.abs(E - E[0])) / max(abs(E[0]), 1e-300))
    print(f"{s.name}: {n_steps} steps of {args.dt:g} s with {args.integrator} in {wall:.3g} s wall "
          f"({n_steps / wall:,.0f} steps/s); {S} records -> {out}")
    print(f"max relative energy change {drift:.3e}; final rod-length drift "
          f"{float(dyn.rod_length_drift(model, qf[-1:])[0]):.3e}")
    return _video(args, s, model, t, qf, qdf)


def _stable_step_bytes(k: int, m: int = 0) -> float:
    """Memory of dynamics.stable_step_estimate: up to DENSE_STABILITY_MAX_RODS rods finite-difference
    Jacobians on 24 k states and the eigenvalues of the (12 k x 12 k) first-order matrix (about six
    such matrices); above, the sparse path (linear in k and the m strings: sizing.stability_bytes)."""
    if k > dyn.DENSE_STABILITY_MAX_RODS:
        from .sizing import stability_bytes
        return float(stability_bytes(k, m))
    return 8.0 * (6 * (12 * k) ** 2 + 24 * k * (6 * k) * 12)


def structure_summary(s, stable_step: bool = True) -> dict:
    """Summary numbers of a structure (SI units) as printed by ``info``; ``stable_step=False``
    skips the eigenvalue estimate (``None`` entries)."""
    model = dyn.compile_model(s)
    L = s.string_lengths
    tension = s.initial_tensions()
    slack = np.flatnonzero(L <= s.rest_length)
    st0 = dyn.initial_state(model)
    acc = dyn.accelerations(model, st0.q, st0.qd)
    est = dyn.stable_step_estimate(model) if stable_step else \
        {"omega_max": None, "semi_implicit_euler": None, "rk4": None}
    span = lambda x: [float(np.min(x)), float(np.max(x))] if len(x) else None
    return {
        "name": s.name, "nodes": s.n_nodes, "bars": s.n_bars, "strings": s.n_strings,
        "anchors": int(len(s.anchors)), "constrained_nodes": {int(k): int(v.shape[0]) for k, v in
                                                             s.node_constraints.items()},
        "total_mass_kg": s.total_mass, "bar_mass_kg": [float(x) for x in s.bar_mass],
        "bar_length_m": [float(x) for x in s.bar_lengths],
        "stiffness_N_per_m": span(s.stiffness),
        "damping_Ns_per_m": span(s.damping),
        "gravity_m_per_s2": None if s.gravity is None else s.gravity.tolist(),
        "tension_N": [float(x) for x in tension], "slack_strings": [int(i) for i in slack],
        "max_initial_acceleration": float(np.abs(acc).max()),
        "omega_max_rad_per_s": est["omega_max"],
        "stable_dt_s": {"semi_implicit_euler": est["semi_implicit_euler"], "rk4": est["rk4"]},
    }


def cmd_info(args) -> int:
    s = _load(args.structure, args)
    if not args.no_stable_step:
        how = ("sparse Jacobians and Arnoldi" if s.n_bars > dyn.DENSE_STABILITY_MAX_RODS else
               f"eigenvalues of a {12 * s.n_bars} x {12 * s.n_bars} matrix")
        _require_memory(_stable_step_bytes(s.n_bars, s.n_strings), args,
                        f"the stable-step estimate of {s.n_bars} rods ({how}; --no-stable-step skips it)")
    d = structure_summary(s, stable_step=not args.no_stable_step)
    if args.json:
        print(json.dumps(d, indent=1))
        return 0
    print(f"structure        {d['name']}")
    print(f"nodes/bars/strings {d['nodes']} / {d['bars']} / {d['strings']}   anchors {d['anchors']}")
    if d["constrained_nodes"]:
        kinds = {1: "plane", 2: "line", 3: "pinned"}
        print("constraints      " + ", ".join(f"node {k}: {kinds[v]}" for k, v in d["constrained_nodes"].items()))
    print(f"total mass       {d['total_mass_kg']:.4g} kg   rod lengths {min(d['bar_length_m']):.4g}.."
          f"{max(d['bar_length_m']):.4g} m")
    if d["strings"]:
        print(f"stiffness        {d['stiffness_N_per_m'][0]:.4g}..{d['stiffness_N_per_m'][1]:.4g} N/m   "
              f"damping {d['damping_Ns_per_m'][0]:.4g}..{d['damping_Ns_per_m'][1]:.4g} N s/m")
    else:
        print("stiffness        no strings")
    print(f"gravity          {d['gravity_m_per_s2']}")
    t = np.array(d["tension_N"])
    if t.size:
        print(f"prestress        tension {t.min():.4g}..{t.max():.4g} N; slack strings: "
              f"{d['slack_strings'] if d['slack_strings'] else 'none'}")
    else:
        print("prestress        no strings")
    print(f"initial |accel|  {d['max_initial_acceleration']:.3g} (max over rods, SI)")
    if d["omega_max_rad_per_s"] is None:
        print("stable step      not estimated (--no-stable-step)")
    else:
        print(f"stable step      omega_max {d['omega_max_rad_per_s']:.4g} rad/s -> dt < "
              f"{d['stable_dt_s']['semi_implicit_euler']:.3g} s (semi-implicit Euler), "
              f"< {d['stable_dt_s']['rk4']:.3g} s (RK4)")
    return 0


def cmd_demo(args) -> int:
    """Simulate the default prism released off equilibrium; write a plot and a summary."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from .builders import prism

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise CLIError(EXIT_OUTPUT, f"--out {str(out)!r} is a file; give a folder")
    png, summary_path = out / "demo_prism.png", out / "demo_summary.json"
    _check_out(png, args.force)
    _check_out(summary_path, args.force)
    if args.video:
        _check_out(Path(args.video), args.force, "--video")
    try:
        s = prism(3, damping=args.damping)
    except StructureError as e:
        raise CLIError(EXIT_USAGE, f"--damping {args.damping}: {e}") from None
    model = dyn.compile_model(s)
    rng = np.random.default_rng(args.seed)
    st = dyn.initial_state(model, nodes=s.nodes + args.perturbation * rng.standard_normal(s.nodes.shape))
    dt, T = 1e-3, args.duration
    n = _n_steps(T, dt, args)
    _require_memory(_trajectory_bytes(model, n // 10 + 1), args, f"recording {n // 10 + 1} states")
    t0 = time.perf_counter()
    t, q, qd = simulate(model, st, dt, n, args.integrator, record_every=10)
    wall = time.perf_counter() - t0
    q1, qd1 = q[:, 0], qd[:, 0]
    E = dyn.energy(model, q1, qd1)
    nodes = dyn.node_positions(model, q1)
    top = nodes[:, 3:6]
    bot = nodes[:, 0:3]
    ang = lambda P: np.arctan2(P[..., 1] - P[..., 1].mean(-1, keepdims=True),
                               P[..., 0] - P[..., 0].mean(-1, keepdims=True))
    twist = np.degrees(np.angle(np.mean(np.exp(1j * (ang(top) - ang(bot))), axis=-1)))
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.8))
    ax[0].plot(t, E)
    ax[0].set(xlabel="t [s]", ylabel="energy [J]", title="energy (damped strings)")
    ax[1].plot(t, twist)
    ax[1].axhline(90 - 180 / 3, ls="--", c="k", lw=0.8, label="pi/2 - pi/p")
    ax[1].set(xlabel="t [s]", ylabel="twist [deg]", title="twist between top and bottom")
    ax[1].legend()
    a = ax[2]
    for (i, j) in s.strings:
        a.plot(nodes[-1, [i, j], 0], nodes[-1, [i, j], 1], c="tab:red", lw=0.8)
    for (i, j) in s.bars:
        a.plot(nodes[-1, [i, j], 0], nodes[-1, [i, j], 1], c="k", lw=3)
    a.set(aspect="equal", title="final shape (top view)", xlabel="x [m]", ylabel="y [m]")
    fig.tight_layout()
    _atomic_write(png, lambda f: fig.savefig(f, dpi=100, format="png"))
    plt.close(fig)
    summary = {"structure": s.name, "integrator": args.integrator, "dt_s": dt, "duration_s": T,
               "wall_s": wall, "steps_per_s": n / wall, "initial_energy_J": float(E[0]),
               "final_energy_J": float(E[-1]), "final_twist_deg": float(twist[-1]),
               "expected_twist_deg": 90 - 180 / 3,
               "final_rod_length_drift": float(dyn.rod_length_drift(model, q1[-1:])[0])}
    _atomic_write(summary_path, lambda f: f.write(json.dumps(summary, indent=1).encode()))
    print(json.dumps(summary, indent=1))
    print(f"wrote {png} and {summary_path}")
    return _video(args, s, model, t, q1, qd1)


def _video(args, s, model, t, q, qd) -> int:
    """``--video PATH``: render the recorded trajectory (q, qd: (S, 1, k, 6)) in real time at 30 frames/s."""
    if not getattr(args, "video", None):
        return 0
    from .rendering import RendererUnavailable, write_video
    q, qd = q.reshape((len(t),) + q.shape[-2:]), qd.reshape((len(t),) + qd.shape[-2:])
    gamma, _, L = dyn.force_densities(model, q, qd)
    try:
        n = write_video(args.video, s, dyn.node_positions(model, q), gamma * L, t)
    except (RendererUnavailable, ValueError, OSError) as e:
        raise CLIError(EXIT_OUTPUT, f"--video {args.video}: {e}") from None
    print(f"wrote {n} frames -> {args.video}")
    return 0


def cmd_export(args) -> int:
    """``export STRUCTURE --format mjcf|json --out PATH``: exit 0, 3 (bad structure) or 4 (output)."""
    from .mjcf import export
    out = Path(args.out)
    _check_out(out, args.force, "export: --out", create_folders=False)
    if args.source == "tnsgrt":
        from .tnsgrt import from_tnsgrt
        try:
            s = from_tnsgrt(args.structure)
        except (StructureError, OSError, ValueError, KeyError, TypeError) as e:
            raise CLIError(EXIT_STRUCTURE, f"export: {e}") from None
    else:
        s = _load(args.structure, args)
    try:
        if args.format == "mjcf":
            export(s, out, ground=args.ground, timestep=args.timestep)
        else:   # the bytes of save_json, written atomically
            _atomic_write(out, lambda f: f.write(json.dumps(s.to_dict(), indent=1).encode()))
    except (StructureError, ValueError) as e:
        raise CLIError(EXIT_STRUCTURE, f"export: {e}") from None
    except OSError as e:
        raise CLIError(EXIT_OUTPUT, f"export: {e}") from None
    print(f"{s.name}: {s.n_bars} rods, {s.n_strings} strings -> {out} ({args.format})")
    return 0


def cmd_view(args) -> int:
    """``view TRAJ.npz``: interactive view of a simulate output; exit 3 on a bad trajectory or
    structure, 4 when no viewer can be opened."""
    from types import SimpleNamespace
    from .rendering import RendererUnavailable, view_trajectory
    try:
        z = load_npz(args.trajectory, "a simulate output with t, nodes, bars, strings")
        t, nodes, bars, strings = z["t"], z["nodes"], z["bars"], z["strings"]
        check_trajectory_arrays(t, nodes, args.trajectory)
    except ValueError as e:
        raise CLIError(EXIT_STRUCTURE, f"view: {e}") from None
    except (OSError, KeyError) as e:
        raise CLIError(EXIT_STRUCTURE, f"view: {args.trajectory}: not a simulate output (.npz with t, nodes, bars, "
                                       f"strings): {e}") from None
    tensions = None
    s = SimpleNamespace(bars=bars, strings=strings, n_strings=len(strings), gravity=None,
                        name=Path(args.trajectory).stem)
    if args.structure:
        st = _load(args.structure, args)
        if st.n_nodes != nodes.shape[1] or not np.array_equal(st.strings, strings):
            raise CLIError(EXIT_STRUCTURE, f"view: structure {args.structure!r} does not match the trajectory's "
                                           "nodes/strings")
        L = np.linalg.norm(nodes[:, strings[:, 1]] - nodes[:, strings[:, 0]], axis=-1)
        tensions = st.stiffness * np.maximum(0.0, L - st.rest_length)   # elastic part, N
        s = st
    try:
        view_trajectory(s, nodes, tensions, t, mode=args.mode, **({"port": args.port} if args.mode != "window" else {}))
    except (RendererUnavailable, ValueError, OSError) as e:
        raise CLIError(EXIT_OUTPUT, f"view: {e}") from None
    return 0


def cmd_identify(args) -> int:
    """Fit parameters to a recorded trajectory; write the fit as JSON (atomically) and a plot."""
    from . import sysid
    for f in args.fit:
        if sysid._ALIASES.get(f, f) not in sysid.FITTABLE:
            raise CLIError(EXIT_USAGE, f"--fit: unknown parameter {f!r}; choose from {sorted(sysid.FITTABLE)} "
                           f"(aliases {sorted(sysid._ALIASES)})")
    out, s, model = _outputs_and_model(args, args.plot, "--plot")
    try:
        t, nodes, rl, mask = sysid.load_trajectory(args.trajectory, model.n_nodes)
    except FileNotFoundError:
        raise CLIError(EXIT_STRUCTURE, f"trajectory file {args.trajectory!r} not found") from None
    except (ValueError, OSError, KeyError) as e:
        raise CLIError(EXIT_STRUCTURE, f"trajectory {args.trajectory!r}: {e}") from None
    if args.nodes is not None:
        sel = np.zeros(model.n_nodes, bool)
        for i in args.nodes:
            if not 0 <= i < model.n_nodes:
                raise CLIError(EXIT_USAGE, f"--nodes: node {i} does not exist (structure has {model.n_nodes} nodes)")
            sel[i] = True
        mask = sel if mask is None else (np.asarray(mask, bool) & sel)
    import warnings
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", sysid.SysIdWarning)   # reported below from the result
            res = sysid.identify(model, t, nodes, fit=args.fit, mode="scale" if args.scale else "per_member",
                                 rest_length=rl, node_mask=mask, window=args.window, integrator=args.integrator,
                                 dt=args.dt, stride=args.stride, total_mass=args.total_mass)
    except ValueError as e:     # the trajectory does not fit the structure, too short, ...: bad input
        raise CLIError(EXIT_STRUCTURE, str(e)) from None
    except FloatingPointError as e:   # SimulationDiverged: the starting values blow the model up
        raise CLIError(EXIT_DIVERGED, f"the simulation diverged during the fit ({e}); try a smaller --dt or "
                       "starting values closer to the robot's") from None
    d = res.to_dict()
    d.update(structure=s.name, trajectory=str(args.trajectory))
    _atomic_write(out, lambda f: f.write(json.dumps(d, indent=1).encode()))
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        pl = Path(args.plot)
        _atomic_write(pl, lambda f: res.plot().savefig(f, dpi=100, format="png"))
    for g in res.fields:
        for i, v, e, ok in zip(res.items[g], res.values[g], res.std_errors[g], res.identifiable[g]):
            err = f"+- {e:.3g}" if np.isfinite(e) else "(not identifiable)"
            print(f"{g:12s} {sysid.FITTABLE[g]} {i:3d}  {v:.6g} {err} {sysid._UNITS[g]}")
    print(f"RMS node error {res.rms_m * 1e3:.4g} mm (initial values {res.rms_initial_m * 1e3:.4g} mm); "
          f"{res.n_windows} windows of {res.window_s:g} s; converged: {res.converged}; wrote {out}"
          + (f" and {args.plot}" if args.plot else ""))
    for w in res.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0 if res.ok else 3


# --------------------------------------------------------------------------- parser and main
class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2) instead of usage + error."""

    def error(self, message):
        raise CLIError(EXIT_USAGE, f"{self.prog}: {message} (see --help)")


def _prog() -> str:
    """The program name as invoked: ``python -m tensegrity_gym`` or the script's name."""
    arg0 = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    if arg0 in ("", "-c", "__main__.py", "-m") or arg0.endswith((".py", "pytest")):
        return "python -m tensegrity_gym"
    return arg0


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    fmt = argparse.ArgumentDefaultsHelpFormatter
    p = _Parser(prog=prog or _prog(), description="Class-1 tensegrity dynamics (SI units).",
                formatter_class=fmt,
                epilog="exit codes: 0 ok, 2 bad arguments, 3 bad structure, 4 output problem, "
                       "5 request too large, 6 simulation diverged, 130 interrupted, 143 terminated")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    names = ", ".join(sorted(BUILDERS))
    max_mem = _default_max_memory_gib()

    def limits(sp):
        sp.add_argument("--max-steps", type=_positive(float), default=DEFAULT_MAX_STEPS,
                        help="refuse runs of more integration steps")
        sp.add_argument("--max-memory", type=_positive(float), default=round(max_mem, 1),
                        help="refuse requests estimated to need more memory, GiB (the default is half of this machine's memory)")

    sp = sub.add_parser("simulate", help="integrate a structure and write a trajectory (.npz)", formatter_class=fmt)
    sp.add_argument("structure", help=f"JSON file or built-in name ({names})")
    sp.add_argument("--duration", type=_positive(float), default=1.0, help="simulated time, s")
    sp.add_argument("--dt", type=_positive(float), default=1e-3, help="time step, s")
    sp.add_argument("--integrator", default="rk4", choices=sorted(INTEGRATORS), help="integration method")
    sp.add_argument("--out", default="traj.npz", help="output .npz (t, nodes, energy)")
    sp.add_argument("--force", action="store_true", help="overwrite an existing output")
    sp.add_argument("--record-every", type=_positive(int), default=1, help="keep every K-th step")
    sp.add_argument("--no-project", action="store_true", help="do not project onto the rod constraints")
    sp.add_argument("--backend", default="auto", choices=["auto", "numba", "torch"],
                    help="the compiled numba kernels (auto = numba), or torch (optional extra) on --device")
    sp.add_argument("--device", default="cpu", help="torch device for --backend torch (cpu, cuda)")
    sp.add_argument("--rtol", type=_positive(float), default=1e-10, help="adaptive methods only")
    sp.add_argument("--atol", type=_positive(float), default=1e-12, help="adaptive methods only")
    sp.add_argument("--no-progress", action="store_true", help="no progress bar")
    sp.add_argument("--rest-length", default=None, metavar="FILE",
                    help="cable commands to replay: rest lengths over time, held from each command time to the "
                         "next (.npz with t (C,) s and rest_length (C, m) m, or .csv: header, then rows "
                         "t,l_0,...,l_m-1); the output then holds rest_length (S, m) per record for identify")
    sp.add_argument("--force-density", default=None, metavar="FILE",
                    help="force densities added over time (N/m), as --rest-length (.npz array force_density)")
    limits(sp)
    sp.set_defaults(func=cmd_simulate)
    ip = sub.add_parser("info", help="print a summary of a structure", formatter_class=fmt)
    ip.add_argument("structure", help=f"JSON file or built-in name ({names})")
    ip.add_argument("--json", action="store_true", help="print JSON")
    ip.add_argument("--no-stable-step", action="store_true", help="skip the eigenvalue estimate of the stable step")
    limits(ip)
    ip.set_defaults(func=cmd_info)
    yp = sub.add_parser("identify", help="fit stiffness/damping/mass to a recorded trajectory (.npz or .csv)",
                        formatter_class=fmt)
    yp.add_argument("structure", help=f"JSON file or built-in name ({names}): the starting values")
    yp.add_argument("trajectory", help="TRAJ.npz (t (S,) s, nodes (S, n, 3) m, optional rest_length (S, m)) "
                    "or TRAJ.csv (long format: header t,node,x,y,z; one row per tracked node per sample)")
    yp.add_argument("--fit", nargs="+", default=["stiffness", "damping"],
                    help="parameters to fit: stiffness damping mass (alias rod_mass) node_damping")
    grp = yp.add_mutually_exclusive_group()
    grp.add_argument("--per-member", action="store_true", help="one value per string / rod (default)")
    grp.add_argument("--scale", action="store_true", help="one factor per parameter group")
    yp.add_argument("--total-mass", type=_positive(float), default=None,
                    help="weighed total rod mass, kg (needed to fit mass together with stiffness/damping)")
    yp.add_argument("--nodes", type=int, nargs="+", default=None, help="use only these tracked nodes")
    yp.add_argument("--window", type=_positive(float), default=0.2, help="shooting window, s")
    yp.add_argument("--integrator", default="rk4", choices=["rk4", "semi_implicit_euler", "implicit_euler"])
    yp.add_argument("--dt", type=_positive(float), default=None, help="fit step, s (divides the sample spacing)")
    yp.add_argument("--stride", type=_positive(int), default=1, help="fit every K-th sample")
    yp.add_argument("--out", default="fit.json", help="output JSON")
    yp.add_argument("--plot", default=None, help="PNG of recorded vs fitted motion")
    yp.add_argument("--force", action="store_true", help="overwrite existing outputs")
    limits(yp)
    yp.set_defaults(func=cmd_identify)
    dp = sub.add_parser("demo", help="simulate the default prism, write a plot and summary", formatter_class=fmt)
    dp.add_argument("--out", default="results/demo", help="output folder")
    dp.add_argument("--force", action="store_true", help="overwrite existing demo files")
    dp.add_argument("--duration", type=_positive(float), default=5.0, help="simulated time, s")
    dp.add_argument("--damping", type=_non_negative, default=5.0, help="string damping, N s/m")
    dp.add_argument("--perturbation", type=_non_negative, default=0.02, help="node perturbation std, m")
    dp.add_argument("--integrator", default="rk4", choices=sorted(INTEGRATORS), help="integration method")
    dp.add_argument("--seed", type=_seed, default=0, help="seed of the perturbation")
    limits(dp)
    dp.set_defaults(func=cmd_demo)
    for sp_ in (sp, dp):
        sp_.add_argument("--video", default=None, help="also write a video of the run (.mp4 or .gif)")
    ep = sub.add_parser("export", help="write a structure as a MuJoCo model (MJCF) or JSON", formatter_class=fmt)
    ep.add_argument("structure", help=f"JSON file or built-in name ({names}); tnsgrt dict JSON with --from tnsgrt")
    ep.add_argument("--format", default="mjcf", choices=["mjcf", "json"], help="output format")
    ep.add_argument("--out", required=True, help="output file (model.xml)")
    ep.add_argument("--from", dest="source", default="tensegrity_gym", choices=["tensegrity_gym", "tnsgrt"],
                    help="input format of STRUCTURE")
    ep.add_argument("--ground", action="store_true", help="MJCF: add a ground plane at z = 0")
    ep.add_argument("--timestep", type=_positive(float), default=1e-3, help="MJCF: MuJoCo time step, s")
    ep.add_argument("--force", action="store_true", help="overwrite an existing output file")
    limits(ep)
    ep.set_defaults(func=cmd_export)
    vp = sub.add_parser("view", help="interactive view of a simulate output (time slider, play/pause)",
                        formatter_class=fmt)
    vp.add_argument("trajectory", help="a .npz written by simulate")
    vp.add_argument("--structure", default=None, help="the simulated structure: strings coloured by tension")
    vp.add_argument("--mode", default="auto", choices=["auto", "window", "browser"],
                    help="window (needs a display), browser (viser web view) or auto")
    vp.add_argument("--port", type=_port, default=8080, help="browser mode: TCP port of the web viewer (0..65535; 0: any free port)")
    limits(vp)
    vp.set_defaults(func=cmd_view)
    return p


def _error(message: str) -> None:
    try:
        print(f"error: {_one_line(message)}", file=sys.stderr)
    except (BrokenPipeError, OSError):  # pragma: no cover
        pass


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Warnings as one line on stderr (``warning: ...``)."""
    try:
        print(f"warning: {_one_line(message)}", file=sys.stderr)
    except (BrokenPipeError, OSError):  # pragma: no cover
        pass


def _quiet_stdout() -> None:
    """After a broken pipe: point stdout at /dev/null so the interpreter's final flush is silent."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


def main(argv=None) -> int:
    """Run the command line; returns the exit code (see the module docstring)."""
    def on_term(signum, frame):
        raise _Terminated()

    old = None
    try:
        old = signal.signal(signal.SIGTERM, on_term)
    except ValueError:   # not the main thread
        pass
    try:
        parser = build_parser()
        try:
            args = parser.parse_args(argv)
        except SystemExit as e:            # --help, --version
            return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USAGE
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            code = args.func(args)
        sys.stdout.flush()
        return code
    except CLIError as e:
        _error(e)
        return e.code
    except StructureError as e:
        _error(f"structure: {e}")
        return EXIT_STRUCTURE
    except SimulationDiverged as e:
        _error(f"simulation diverged: {e}")
        return EXIT_DIVERGED
    except MemoryError as e:   # sizing.StructureTooLarge (refused up front) names the size
        _error(e if isinstance(e, StructureTooLarge) else
               "out of memory; reduce --duration, raise --record-every or use a smaller structure")
        return EXIT_TOO_LARGE
    except BrokenPipeError:
        _quiet_stdout()
        return EXIT_PIPE
    except KeyboardInterrupt:
        _error("interrupted; no output file was changed")
        return EXIT_INTERRUPTED
    except _Terminated:
        _error("terminated (SIGTERM); no output file was changed")
        return EXIT_TERMINATED
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
