"""``simulate`` and ``demo``: integrate a structure, write the trajectory, a plot, a summary and a video."""
from __future__ import annotations

import io
import json
import time
import warnings
from pathlib import Path

import numpy as np

from ..core.model import State, compile_model, initial_state
from ..physics.geometry import energy, node_positions, rod_length_drift
from ..core.builders import prism
from ..core.checks import load_npz, read_bounded
from ..core.errors import StabilityWarning
from ..core.placement import place_on_terrain
from ..core.errors import EvaluationBudgetExceeded, SimulationDiverged
from ..physics.rollout import Schedule, simulate
from ..core.integrators import resolve
from ..io.trajectory import MAX_CSV_BYTES, save_simulate_output
from ..physics import terrain as terrain_physics
from ..physics.contact import impact_damping_cap
from ..physics.loads import member_loads
from ..core.structure import StructureError
from .cli_common import (ADAPTIVE_EVALUATIONS_PER_STEP, CHUNK_STEPS, ENERGY_BLOWUP, EXIT_DIVERGED, EXIT_OUTPUT,
                         EXIT_STRUCTURE, EXIT_TOO_LARGE, EXIT_USAGE, PROGRESS_MIN_STEPS, CLIError, _claim, _commit, _load, _n_steps, _one_line,
                         _require_memory, _stage, _trajectory_bytes)
from .cli_terrain import DEFAULT_CAP_RADIUS, terrain_from_args, terrain_label
from .cli_video import print_video, stage_video


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
                    st = State(q[-1], qd[-1], ts[done])
                break
            qs[done + 1:done + r + 1], qds[done + 1:done + r + 1] = q[1:], qd[1:]
            done += r
            st = State(q[-1], qd[-1], ts[done])
            if bar is not None:
                bar.update(r * every)
    finally:
        if bar is not None:
            bar.close()
    S = done + 1
    return ts[:S], qs[:S], qds[:S], message


def _check_terrain_options(args) -> None:
    """CLIError (exit 2) for the options terrain contact cannot run with: the torch backend (its
    terrain twin has no command-line driver) and the adaptive integrators (the contact forces are
    held over fixed steps)."""
    if args.backend == "torch":
        raise CLIError(EXIT_USAGE, f"{terrain_label(args)}: terrain contact runs on the numba kernels; use "
                                   "--backend auto or numba")
    if resolve(args.integrator).adaptive:
        raise CLIError(EXIT_USAGE, f"{terrain_label(args)}: terrain contact runs fixed-step methods "
                                   f"(semi_implicit_euler, rk4, implicit_euler), not --integrator {args.integrator}")


def _terrain_setup(args, terrain, s):
    """``(structure, model, contact, lift)`` of ``simulate --terrain/--ground``: the structure lifted
    onto the terrain (:func:`tensegrity_gym.core.placement.place_on_terrain`, lift in m), its model
    and the :class:`~tensegrity_gym.physics.terrain.TerrainContact` (its normal damping capped by
    :func:`~tensegrity_gym.physics.contact.impact_damping_cap` at ``--dt``). CLIError (exit 3) when the
    contact refuses the terrain or the structure cannot be placed on it; a StabilityWarning (one
    line) when ``--dt`` is above the contact's estimated stable step."""
    radius = DEFAULT_CAP_RADIUS if args.cap_radius is None else args.cap_radius
    try:    # the envs' damping cap: impacts stay passive at --dt (physics.contact.impact_damping_cap)
        tc = terrain_physics.TerrainContact(terrain, radius=radius, max_damping=impact_damping_cap(s.bar_mass, args.dt))
        s, lift = place_on_terrain(s, terrain, radius)
    except ValueError as e:
        raise CLIError(EXIT_STRUCTURE, f"{terrain_label(args)}: {_one_line(e)}") from None
    except StructureError as e:
        raise CLIError(EXIT_STRUCTURE, f"{terrain_label(args)}: the structure lifted onto the terrain: {e}") from None
    model = compile_model(s)
    if s.gravity is None or not np.any(s.gravity):
        warnings.warn(f"structure {s.name!r} has no gravity: it does not fall onto the terrain (give \"gravity\" "
                      "in a structure file)", stacklevel=2)
    est = terrain_physics.stable_step(tc, model)
    limit = float(est["semi_implicit_euler"])
    if args.dt > limit:
        k = float(tc.prm[0, est["feature"], 1])
        warnings.warn(StabilityWarning(
            f"terrain contact: --dt {args.dt:g} s is above its estimated stable step {limit:.3g} s (contact "
            f"stiffness {k:.4g} N/m on the lightest rod); use --dt {limit:.2g} or lower, or a lower "
            "--ground-stiffness"), stacklevel=2)
    return s, model, tc, lift


def _run_terrain(model, state, args, n_steps: int, progress: bool, tc, contact=None):
    """``simulate`` with terrain contact (:func:`tensegrity_gym.physics.terrain.step`): the
    records of every ``--record-every`` steps, the command schedules' rows in force over each
    step. Returns ``(t, q, qd, message)`` as :func:`_run` (records up to a divergence).
    ``contact``: None, or an array (records, 1, n, 3) that takes the contact forces (N) at each
    record's state (``--loads``)."""
    info = resolve(args.integrator)
    every, dt = args.record_every, args.dt
    n_rec = n_steps // every
    ts = state.t + dt * every * np.arange(n_rec + 1)
    qs = np.empty((n_rec + 1,) + state.q.shape)
    qds = np.empty_like(qs)
    qs[0], qds[0] = state.q, state.qd
    starts = state.t + dt * np.arange(n_rec * every)
    rows = {name: getattr(args, name).rows(starts, dt) for name in ("rest_length", "force_density")
            if getattr(args, name) is not None}
    # step indices where a schedule's row changes: a step run never crosses one
    change = np.zeros(n_rec * every + 1, bool)
    for r in rows.values():
        change[1:-1] |= r[1:] != r[:-1]
    change[::every] = True
    change[-1] = True
    cuts = np.flatnonzero(change)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n_steps, unit="step", desc=f"{info.name}, terrain")
    tstate = terrain_physics.init_terrain_state(tc, model)
    st, done, message = state, 0, None
    if contact is not None:
        contact[0] = terrain_physics.contact_forces(tc, model, st.q, st.qd, tstate)[0]
    try:
        for a, b in zip(cuts[:-1], cuts[1:]):
            inputs = {name: np.ascontiguousarray(getattr(args, name).value(int(r[a]), 1, model.n_strings),
                                                 dtype=np.float64).reshape(1, -1) for name, r in rows.items()}
            last = st
            try:
                st, tstate = terrain_physics.step(model, st, dt, tc, tstate, info.name, n_steps=int(b - a),
                                                  project=not args.no_project, backend=args.backend, **inputs)
                finite = bool(np.all(np.isfinite(st.q)) and np.all(np.isfinite(st.qd)))
                what = "the state became non-finite"
            except (ZeroDivisionError, OverflowError, FloatingPointError) as exc:   # compiled kernels
                finite, what = False, f"{type(exc).__name__} ({exc})"
            if not finite:
                message = (f"{info.name} with terrain contact: {what} between t = {last.t:.6g} s and "
                           f"t = {last.t + dt * (b - a):.6g} s (dt = {dt:g} s); reduce --dt")
                break
            if b % every == 0:
                done = b // every
                qs[done], qds[done] = st.q, st.qd
                if contact is not None:
                    contact[done] = terrain_physics.contact_forces(tc, model, st.q, st.qd, tstate)[0]
            if bar is not None:
                bar.update(int(b - a))
    finally:
        if bar is not None:
            bar.close()
    S = done + 1
    return ts[:S], qs[:S], qds[:S], message


def _outputs_and_model(args, second, flag: str):
    """``(out path, transaction, structure, model)`` of a command writing ``--out`` and optionally
    ``second`` (the path given to ``flag``): both claimed before any work, then the structure loaded."""
    out = Path(args.out)
    tx = _claim(args, [(out, "--out")] + ([(Path(second), flag)] if second else []))
    s = _load(args.structure, args)
    return out, tx, s, compile_model(s)


def load_schedule(path, name: str, n_strings: int) -> Schedule:
    """A command schedule (:class:`tensegrity_gym.physics.rollout.Schedule`) from ``.npz`` (arrays
    ``t`` (C,) s and ``name`` (C, m)) or ``.csv`` (a header row, then one row per command: the
    time in s, then the m strings' values). ValueError naming the file, the row and the value."""
    p = str(path)
    unit = "m" if name == "rest_length" else "N/m"
    if p.lower().endswith(".csv"):
        text = read_bounded(p, MAX_CSV_BYTES, "command schedule CSV")    # FIFOs and devices refused
        try:
            a = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, ndmin=2)
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
    terrain = terrain_from_args(args)     # a bad terrain file is refused before any output is claimed
    if terrain is not None:
        _check_terrain_options(args)
    out, tx, s, model = _outputs_and_model(args, args.video, "--video")
    tc = None
    if terrain is not None:
        s, model, tc, lift = _terrain_setup(args, terrain, s)
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
    state = initial_state(model)
    n_steps = _n_steps(args.duration, args.dt, args)
    _require_memory(_trajectory_bytes(model, n_steps // args.record_every + 1), args,
                    f"recording {n_steps // args.record_every + 1} states of {s.n_nodes} nodes")
    progress = (not args.no_progress) and n_steps >= PROGRESS_MIN_STEPS
    t0 = time.perf_counter()
    if args.backend == "torch":   # optional torch backend (tensegrity_gym.backends.torch) on --device
        try:
            from ..backends.torch import driver     # optional: needs torch
            t, q, qd = driver.simulate(model, state, args.dt, n_steps, args.integrator, device=args.device,
                                       record_every=args.record_every, project=not args.no_project)
        except (ImportError, ValueError) as exc:
            raise CLIError(EXIT_USAGE, f"--backend torch: {exc}") from None
        diverged = None if (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))) else \
            "the torch backend's state became non-finite"
    elif tc is not None:
        W = np.zeros((n_steps // args.record_every + 1, 1, model.n_nodes, 3)) if args.loads else None
        t, q, qd, diverged = _run_terrain(model, state, args, n_steps, progress, tc, W)
    else:
        t, q, qd, diverged = _run(model, state, args, n_steps, progress)
    wall = time.perf_counter() - t0
    S = len(t)
    qf, qdf = q.reshape((S,) + q.shape[2:]), qd.reshape((S,) + qd.shape[2:])
    nodes = node_positions(model, qf) if S else np.zeros((0, s.n_nodes, 3))
    E = energy(model, qf, qdf) if S else np.zeros(0)
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
    if args.loads and S:    # the members' loads at each record (physics.loads)
        ext = W[:S, 0] if tc is not None else None
        arrays.update(member_loads(model, qf, qdf, arrays.get("rest_length"), arrays.get("force_density"), ext))
    if diverged is not None:
        arrays.update(diverged=np.array(True), message=np.array(_one_line(diverged)))
    _stage(tx, out, lambda f: save_simulate_output(f, **arrays))
    if diverged is not None:
        _commit(tx)
        raise CLIError(EXIT_DIVERGED, f"simulation diverged: {_one_line(diverged)}; wrote {S} records "
                                      f"(up to the divergence) to {out}, flagged diverged=True"
                       + (f"; no video written to {args.video}" if args.video else ""))
    frames = stage_video(tx, args, s, model, t, qf, qdf, terrain)
    _commit(tx)
    drift = float(np.max(np.abs(E - E[0])) / max(abs(E[0]), 1e-300))
    print(f"{s.name}: {n_steps} steps of {args.dt:g} s with {args.integrator} in {wall:.3g} s wall "
          f"({n_steps / wall:,.0f} steps/s); {S} records -> {out}")
    if tc is not None:
        parts = f"{tc.n_features} part{'' if tc.n_features == 1 else 's'}"
        print(f"terrain contact ({terrain_label(args)}, {parts}, cap radius {tc.radius:g} m): "
              f"the structure was lifted {lift:.4g} m to rest on it")
    print(f"max relative energy change {drift:.3e}; final rod-length drift "
          f"{float(rod_length_drift(model, qf[-1:])[0]):.3e}")
    if args.loads and S:
        T, C = arrays["string_tension"], arrays["rod_compression"]
        i, j = np.unravel_index(np.argmax(T), T.shape) if T.size else (0, -1)
        a, b = np.unravel_index(np.argmax(C), C.shape)
        print((f"peak string tension {T[i, j]:.4g} N (string {j}, t = {t[i]:.6g} s); " if T.size else "")
              + f"peak rod compression {C[a, b]:.4g} N (rod {b}, t = {t[a]:.6g} s)")
    print_video(args, frames)
    return 0


def cmd_demo(args) -> int:
    """Simulate the default prism released off equilibrium; write a plot and a summary."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise CLIError(EXIT_OUTPUT, f"--out {str(out)!r} is a file; give a folder")
    png, summary_path = out / "demo_prism.png", out / "demo_summary.json"
    tx = _claim(args, [(png, "--out"), (summary_path, "--out")] + ([(Path(args.video), "--video")] if args.video else []))
    try:
        s = prism(3, damping=args.damping)
    except StructureError as e:
        raise CLIError(EXIT_USAGE, f"--damping {args.damping}: {e}") from None
    model = compile_model(s)
    rng = np.random.default_rng(args.seed)
    st = initial_state(model, nodes=s.nodes + args.perturbation * rng.standard_normal(s.nodes.shape))
    dt, T = 1e-3, args.duration
    n = _n_steps(T, dt, args)
    _require_memory(_trajectory_bytes(model, n // 10 + 1), args, f"recording {n // 10 + 1} states")
    t0 = time.perf_counter()
    t, q, qd = simulate(model, st, dt, n, args.integrator, record_every=10)
    wall = time.perf_counter() - t0
    q1, qd1 = q[:, 0], qd[:, 0]
    E = energy(model, q1, qd1)
    nodes = node_positions(model, q1)
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
    _stage(tx, png, lambda f: fig.savefig(f, dpi=100, format="png"))
    plt.close(fig)
    summary = {"structure": s.name, "integrator": args.integrator, "dt_s": dt, "duration_s": T,
               "wall_s": wall, "steps_per_s": n / wall, "initial_energy_J": float(E[0]),
               "final_energy_J": float(E[-1]), "final_twist_deg": float(twist[-1]),
               "expected_twist_deg": 90 - 180 / 3,
               "final_rod_length_drift": float(rod_length_drift(model, q1[-1:])[0])}
    _stage(tx, summary_path, lambda f: f.write(json.dumps(summary, indent=1).encode()))
    frames = stage_video(tx, args, s, model, t, q1, qd1)
    _commit(tx)
    print(json.dumps(summary, indent=1))
    print(f"wrote {png} and {summary_path}")
    print_video(args, frames)
    return 0
