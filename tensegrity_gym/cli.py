"""Command line: ``python -m tensegrity_gym {simulate,info,demo} ...`` (SI units throughout).

* ``simulate STRUCTURE --duration T --dt DT --integrator rk4 --out traj.npz`` writes
  ``t`` (S,) in s, ``nodes`` (S, n, 3) in m and ``energy`` (S,) in J (kinetic + string
  potential + gravity) at every step (``--record-every K`` thins the output).
* ``info STRUCTURE`` prints counts, masses, prestress, slack strings and the estimated
  largest stable step of the explicit integrators.
* ``demo --out DIR`` simulates the default prism released off equilibrium and writes a
  plot and a JSON summary.
* ``export STRUCTURE --format mjcf --out model.xml [--ground]`` writes a MuJoCo model of the
  structure (:mod:`tensegrity_gym.mjcf`); ``--format json`` writes this package's JSON;
  ``--from tnsgrt`` reads STRUCTURE as a tnsgrt structure dict (:mod:`tensegrity_gym.tnsgrt`).
* ``simulate ... --video out.mp4`` / ``demo --video out.mp4`` also render the run to a video.
* ``view traj.npz [--structure S]`` opens an interactive view of a ``simulate`` output (time
  slider, play/pause): a window where there is a display, else a browser view (viser).

``STRUCTURE`` is a JSON file or a built-in name (``prism3``, ``icosahedron``, ...).
Output files are written atomically (temporary file, then rename): an interrupted run
never leaves a truncated file or destroys an existing one.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from . import dynamics as dyn
from .builders import BUILDERS
from .integrators import INTEGRATORS, simulate
from .structure import StructureError

PROGRESS_MIN_STEPS = 20000


def _load(spec: str):
    from . import load_structure
    try:
        return load_structure(spec)
    except FileNotFoundError:
        raise SystemExit(f"error: structure file {spec!r} not found") from None
    except StructureError as e:
        raise SystemExit(f"error: structure {spec!r}: {e}") from None


def _atomic_write(path: Path, writer) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        writer(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _positive(kind):
    def parse(text):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not (np.isfinite(v) and v > 0):
            raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
        return v
    return parse


def cmd_simulate(args) -> int:
    s = _load(args.structure)
    n_steps = int(round(args.duration / args.dt))
    if n_steps < 1:
        raise SystemExit(f"error: --duration {args.duration} s is shorter than one step of --dt {args.dt} s")
    from .sizing import check_size
    check_size(s, records=n_steps // args.record_every + 1)   # the recorded trajectory must fit too
    model = dyn.compile_model(s)
    state = dyn.initial_state(model)
    progress = (not args.no_progress) and n_steps >= PROGRESS_MIN_STEPS
    t0 = time.perf_counter()
    t, q, qd = simulate(model, state, args.dt, n_steps, args.integrator, record_every=args.record_every,
                        project=not args.no_project, backend=args.backend, progress=progress,
                        rtol=args.rtol, atol=args.atol)
    wall = time.perf_counter() - t0
    S = len(t)
    qf, qdf = q.reshape((S,) + q.shape[2:]), qd.reshape((S,) + qd.shape[2:])
    nodes = dyn.node_positions(model, qf)
    E = dyn.energy(model, qf, qdf)
    out = Path(args.out)
    _atomic_write(out, lambda tmp: np.savez(open(tmp, "wb"), t=t, nodes=nodes, energy=E,
                                            bars=s.bars, strings=s.strings))
    drift = float(np.max(np.abs(E - E[0])) / max(abs(E[0]), 1e-300))
    print(f"{s.name}: {n_steps} steps of {args.dt:g} s with {args.integrator} in {wall:.3g} s wall "
          f"({n_steps / wall:,.0f} steps/s); {S} records -> {out}")
    print(f"max relative energy change {drift:.3e}; final rod-length drift "
          f"{float(dyn.rod_length_drift(model, qf[-1:])[0]):.3e}")
    return _video(args, s, model, t, qf, qdf)


def structure_summary(s) -> dict:
    """Summary numbers of a structure (SI units) as printed by ``info``."""
    model = dyn.compile_model(s)
    L = s.string_lengths
    tension = s.initial_tensions()
    slack = np.flatnonzero(L <= s.rest_length)
    acc = dyn.accelerations(model, dyn.initial_state(model).q, dyn.initial_state(model).qd)
    est = dyn.stable_step_estimate(model)
    return {
        "name": s.name, "nodes": s.n_nodes, "bars": s.n_bars, "strings": s.n_strings,
        "anchors": int(len(s.anchors)), "constrained_nodes": {int(k): int(v.shape[0]) for k, v in
                                                             s.node_constraints.items()},
        "total_mass_kg": s.total_mass, "bar_mass_kg": [float(x) for x in s.bar_mass],
        "bar_length_m": [float(x) for x in s.bar_lengths],
        "stiffness_N_per_m": [float(np.min(s.stiffness)), float(np.max(s.stiffness))],
        "damping_Ns_per_m": [float(np.min(s.damping)), float(np.max(s.damping))],
        "gravity_m_per_s2": None if s.gravity is None else s.gravity.tolist(),
        "tension_N": [float(x) for x in tension], "slack_strings": [int(i) for i in slack],
        "max_initial_acceleration": float(np.abs(acc).max()),
        "omega_max_rad_per_s": est["omega_max"],
        "stable_dt_s": {"semi_implicit_euler": est["semi_implicit_euler"], "rk4": est["rk4"]},
    }


def cmd_info(args) -> int:
    s = _load(args.structure)
    d = structure_summary(s)
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
    print(f"stiffness        {d['stiffness_N_per_m'][0]:.4g}..{d['stiffness_N_per_m'][1]:.4g} N/m   "
          f"damping {d['damping_Ns_per_m'][0]:.4g}..{d['damping_Ns_per_m'][1]:.4g} N s/m")
    print(f"gravity          {d['gravity_m_per_s2']}")
    t = np.array(d["tension_N"])
    print(f"prestress        tension {t.min():.4g}..{t.max():.4g} N; slack strings: "
          f"{d['slack_strings'] if d['slack_strings'] else 'none'}")
    print(f"initial |accel|  {d['max_initial_acceleration']:.3g} (max over rods, SI)")
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
    out.mkdir(parents=True, exist_ok=True)
    s = prism(3, damping=args.damping)
    model = dyn.compile_model(s)
    rng = np.random.default_rng(args.seed)
    st = dyn.initial_state(model, nodes=s.nodes + args.perturbation * rng.standard_normal(s.nodes.shape))
    dt, T = 1e-3, args.duration
    n = int(round(T / dt))
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
    fig.savefig(out / "demo_prism.png", dpi=100)
    summary = {"structure": s.name, "integrator": args.integrator, "dt_s": dt, "duration_s": T,
               "wall_s": wall, "steps_per_s": n / wall, "initial_energy_J": float(E[0]),
               "final_energy_J": float(E[-1]), "final_twist_deg": float(twist[-1]),
               "expected_twist_deg": 90 - 180 / 3,
               "final_rod_length_drift": float(dyn.rod_length_drift(model, q1[-1:])[0])}
    (out / "demo_summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))
    print(f"wrote {out / 'demo_prism.png'} and {out / 'demo_summary.json'}")
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
        print(f"error: --video {args.video}: {e}", file=sys.stderr)
        return 1
    print(f"wrote {n} frames -> {args.video}")
    return 0


def cmd_export(args) -> int:
    """``export STRUCTURE --format mjcf|json --out PATH``: exit 0, or 2 with one line on stderr."""
    from .mjcf import export
    from .structure import save_json
    try:
        if args.source == "tnsgrt":
            from .tnsgrt import from_tnsgrt
            s = from_tnsgrt(args.structure)
        else:
            s = _load(args.structure)
        out = Path(args.out)
        if out.is_dir():
            raise OSError(f"--out {args.out!r} is a directory")
        if out.exists() and not args.force:
            raise OSError(f"--out {args.out!r} exists (use --force to overwrite)")
        if not os.access(out.parent if str(out.parent) else ".", os.W_OK):
            raise OSError(f"--out {args.out!r}: folder {str(out.parent)!r} is not writable or does not exist")
        if args.format == "mjcf":
            export(s, out, ground=args.ground, timestep=args.timestep)
        else:
            _atomic_write(out, lambda tmp: save_json(s, tmp))
    except (StructureError, OSError, ValueError) as e:
        print(f"error: export: {e}", file=sys.stderr)
        return 2
    print(f"{s.name}: {s.n_bars} rods, {s.n_strings} strings -> {out} ({args.format})")
    return 0


def cmd_view(args) -> int:
    """``view TRAJ.npz``: interactive view of a simulate output; exit 2 with one line on stderr on bad input."""
    from types import SimpleNamespace
    from .rendering import RendererUnavailable, view_trajectory
    try:
        with np.load(args.trajectory) as z:
            t, nodes, bars, strings = z["t"], z["nodes"], z["bars"], z["strings"]
    except (OSError, ValueError, KeyError) as e:
        print(f"error: view: {args.trajectory}: not a simulate output (.npz with t, nodes, bars, strings): {e}",
              file=sys.stderr)
        return 2
    tensions = None
    s = SimpleNamespace(bars=bars, strings=strings, n_strings=len(strings), gravity=None,
                        name=Path(args.trajectory).stem)
    if args.structure:
        st = _load(args.structure)
        if st.n_nodes != nodes.shape[1] or not np.array_equal(st.strings, strings):
            print(f"error: view: structure {args.structure!r} does not match the trajectory's nodes/strings",
                  file=sys.stderr)
            return 2
        L = np.linalg.norm(nodes[:, strings[:, 1]] - nodes[:, strings[:, 0]], axis=-1)
        tensions = st.stiffness * np.maximum(0.0, L - st.rest_length)   # elastic part, N
        s = st
    try:
        view_trajectory(s, nodes, tensions, t, mode=args.mode, **({"port": args.port} if args.mode != "window" else {}))
    except (RendererUnavailable, ValueError, OSError) as e:
        print(f"error: view: {e}", file=sys.stderr)
        return 2
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m tensegrity_gym",
                                description="Class-1 tensegrity dynamics (SI units).")
    sub = p.add_subparsers(dest="command", required=True)
    names = ", ".join(sorted(BUILDERS))
    sp = sub.add_parser("simulate", help="integrate a structure and write a trajectory (.npz)")
    sp.add_argument("structure", help=f"JSON file or built-in name ({names})")
    sp.add_argument("--duration", type=_positive(float), default=1.0, help="simulated time, s")
    sp.add_argument("--dt", type=_positive(float), default=1e-3, help="time step, s")
    sp.add_argument("--integrator", default="rk4", choices=sorted(INTEGRATORS))
    sp.add_argument("--out", default="traj.npz", help="output .npz (t, nodes, energy)")
    sp.add_argument("--record-every", type=_positive(int), default=1, help="keep every K-th step")
    sp.add_argument("--no-project", action="store_true", help="do not project onto the rod constraints")
    sp.add_argument("--backend", default="auto", choices=["auto", "numpy", "numba"])
    sp.add_argument("--rtol", type=_positive(float), default=1e-10, help="adaptive methods only")
    sp.add_argument("--atol", type=_positive(float), default=1e-12, help="adaptive methods only")
    sp.add_argument("--no-progress", action="store_true", help="no progress bar")
    sp.set_defaults(func=cmd_simulate)
    ip = sub.add_parser("info", help="print a summary of a structure")
    ip.add_argument("structure")
    ip.add_argument("--json", action="store_true", help="print JSON")
    ip.set_defaults(func=cmd_info)
    dp = sub.add_parser("demo", help="simulate the default prism, write a plot and summary")
    dp.add_argument("--out", default="results/demo")
    dp.add_argument("--duration", type=_positive(float), default=5.0)
    dp.add_argument("--damping", type=float, default=5.0, help="string damping, N s/m")
    dp.add_argument("--perturbation", type=float, default=0.02, help="node perturbation std, m")
    dp.add_argument("--integrator", default="rk4", choices=sorted(INTEGRATORS))
    dp.add_argument("--seed", type=int, default=0)
    dp.set_defaults(func=cmd_demo)
    for sp_ in (sp, dp):
        sp_.add_argument("--video", default=None, help="also write a video of the run (.mp4 or .gif)")
    ep = sub.add_parser("export", help="write a structure as a MuJoCo model (MJCF) or JSON")
    ep.add_argument("structure", help=f"JSON file or built-in name ({names}); tnsgrt dict JSON with --from tnsgrt")
    ep.add_argument("--format", default="mjcf", choices=["mjcf", "json"], help="output format (default: mjcf)")
    ep.add_argument("--out", required=True, help="output file (model.xml)")
    ep.add_argument("--from", dest="source", default="tensegrity_gym", choices=["tensegrity_gym", "tnsgrt"],
                    help="input format of STRUCTURE (default: tensegrity_gym)")
    ep.add_argument("--ground", action="store_true", help="MJCF: add a ground plane at z = 0")
    ep.add_argument("--timestep", type=_positive(float), default=1e-3, help="MJCF: MuJoCo time step, s")
    ep.add_argument("--force", action="store_true", help="overwrite an existing output file")
    ep.set_defaults(func=cmd_export)
    vp = sub.add_parser("view", help="interactive view of a simulate output (time slider, play/pause)")
    vp.add_argument("trajectory", help="a .npz written by simulate")
    vp.add_argument("--structure", default=None, help="the simulated structure: strings coloured by tension")
    vp.add_argument("--mode", default="auto", choices=["auto", "window", "browser"],
                    help="window (needs a display), browser (viser web view) or auto")
    vp.add_argument("--port", type=int, default=8080, help="browser mode: port of the web viewer")
    vp.set_defaults(func=cmd_view)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("interrupted; no output file was changed", file=sys.stderr)
        return 130
    except MemoryError as e:   # sizing.StructureTooLarge: refused up front, naming the size
        print(f"error: {e or 'out of memory'}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
