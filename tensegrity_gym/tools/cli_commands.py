"""``info``, ``export``, ``import``, ``view``, ``identify`` and ``import-recording``: the command-line verbs
that do not integrate a run of their own."""
from __future__ import annotations

import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np

from ..physics.stability import DENSE_STABILITY_MAX_RODS, stable_step_estimate
from ..core.model import compile_model, initial_state
from ..physics.evaluate import accelerations
from ..core.placement import place_on_terrain
from ..core.terrain import Terrain
from ..io.mjcf import default_rod_radius, from_mjcf, terrain_xml_bytes, to_mjcf
from ..io.tnsgrt import from_tnsgrt
from ..io.recording import save_recording
from ..io.recording_rutgers import RUTGERS_SCALE, import_rutgers
from ..io.trajectory import load_simulate_output
from ..core.sizing import stability_bytes
from ..core.structure import StructureError
from .cli_common import (EXIT_DIVERGED, EXIT_OUTPUT, EXIT_STRUCTURE, EXIT_USAGE, CLIError, _claim, _commit, _load,
                         _one_line, _require_memory, _stage)
from .cli_simulate import _outputs_and_model
from .cli_terrain import DEFAULT_CAP_RADIUS, terrain_from_args, terrain_label
from .rendering import RendererUnavailable, view_trajectory


def _stable_step_bytes(k: int, m: int = 0) -> float:
    """Memory of physics.stability.stable_step_estimate: up to DENSE_STABILITY_MAX_RODS rods finite-difference
    Jacobians on 24 k states and the eigenvalues of the (12 k x 12 k) first-order matrix (about six
    such matrices); above, the sparse path (linear in k and the m strings: sizing.stability_bytes)."""
    if k > DENSE_STABILITY_MAX_RODS:
        return float(stability_bytes(k, m))
    return 8.0 * (6 * (12 * k) ** 2 + 24 * k * (6 * k) * 12)


def structure_summary(s, stable_step: bool = True) -> dict:
    """Summary numbers of a structure (SI units) as printed by ``info``; ``stable_step=False``
    skips the eigenvalue estimate (``None`` entries)."""
    model = compile_model(s)
    L = s.string_lengths
    tension = s.initial_tensions()
    slack = np.flatnonzero(L <= s.rest_length)
    st0 = initial_state(model)
    acc = accelerations(model, st0.q, st0.qd)
    est = stable_step_estimate(model) if stable_step else \
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
        how = ("sparse Jacobians and Arnoldi" if s.n_bars > DENSE_STABILITY_MAX_RODS else
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


def cmd_export(args) -> int:
    """``export STRUCTURE --format mjcf|json --out PATH [--ground | --terrain FILE.json]``: exit 0,
    2 (a terrain with --format json), 3 (bad structure or terrain file) or 4 (output). With
    ``--terrain`` the structure is lifted onto the terrain (its rod capsules clear it)."""
    terrain = terrain_from_args(args)
    if (terrain is not None or args.friction is not None) and args.format != "mjcf":
        raise CLIError(EXIT_USAGE, f"export: {'--friction' if terrain is None else terrain_label(args)} "
                                   "applies to --format mjcf")
    if terrain is not None:     # before the output is claimed: a refusal leaves no lock behind
        n_parts = len(terrain.parts())
        _require_memory(terrain_xml_bytes(terrain), args, f"export: {terrain_label(args)} ({n_parts} terrain "
                        f"part{'' if n_parts == 1 else 's'} written as MJCF)")
    out = Path(args.out)
    tx = _claim(args, [(out, "export: --out")], create_folders=False)
    if args.source == "tnsgrt":
        try:
            s = from_tnsgrt(args.structure)
        except (StructureError, OSError, ValueError, KeyError, TypeError) as e:
            raise CLIError(EXIT_STRUCTURE, f"export: {e}") from None
    else:
        s = _load(args.structure, args)
    lift = 0.0
    try:
        if args.format == "mjcf" and args.ground:
            text = to_mjcf(s, ground=True, timestep=args.timestep,
                           friction=1.0 if args.friction is None else args.friction)
        elif args.format == "mjcf" and terrain is not None:
            s, lift = place_on_terrain(s, terrain, default_rod_radius(s))
            text = to_mjcf(s, timestep=args.timestep, terrain=terrain)
        elif args.format == "mjcf":
            text = to_mjcf(s, timestep=args.timestep)
        else:   # the bytes of save_json
            text = json.dumps(s.to_dict(), indent=1)
    except (StructureError, ValueError) as e:
        raise CLIError(EXIT_STRUCTURE, f"export: {e}") from None
    except OSError as e:
        raise CLIError(EXIT_OUTPUT, f"export: {e}") from None
    _stage(tx, out, lambda f: f.write(text.encode("utf-8")))
    _commit(tx)
    print(f"{s.name}: {s.n_bars} rods, {s.n_strings} strings -> {out} ({args.format})"
          + (f"; on the terrain ({terrain_label(args)}, lifted {lift:.4g} m)" if terrain is not None and not args.ground
             else ""))
    return 0


def cmd_import(args) -> int:
    """``import MODEL.xml --out robot.json [--report report.json]``: reads a MuJoCo model as a
    structure (:func:`tensegrity_gym.io.mjcf.from_mjcf`), writes its JSON and prints the import
    report; exit 0, 3 (not found, not MJCF, or not a class-1 tensegrity: the element, its name
    and its line) or 4 (output)."""
    out = Path(args.out)
    outputs = [(out, "import: --out")] + ([(Path(args.report), "import: --report")] if args.report else [])
    tx = _claim(args, outputs, create_folders=False)
    try:
        s, report = from_mjcf(Path(args.model))
    except FileNotFoundError:
        raise CLIError(EXIT_STRUCTURE, f"import: MJCF file {args.model!r} not found") from None
    except PermissionError as e:
        raise CLIError(EXIT_STRUCTURE, f"import: MJCF file {args.model!r} cannot be read ({e.strerror})") from None
    except (StructureError, OSError) as e:
        raise CLIError(EXIT_STRUCTURE, f"import: {e}") from None
    _stage(tx, out, lambda f: f.write(json.dumps(s.to_dict(), indent=1).encode("utf-8")))
    if args.report:
        _stage(tx, Path(args.report), lambda f: f.write(json.dumps(report.to_dict(), indent=1).encode("utf-8")))
    _commit(tx)
    print(f"{s.name}: {s.n_bars} rods, {s.n_strings} strings -> {out}")
    print(report.summary())
    return 0


def cmd_view(args) -> int:
    """``view TRAJ.npz``: interactive view of a simulate output; exit 3 on a bad trajectory or
    structure, 4 when no viewer can be opened."""
    from types import SimpleNamespace
    try:
        t, nodes, bars, strings = load_simulate_output(args.trajectory)
    except ValueError as e:
        raise CLIError(EXIT_STRUCTURE, f"view: {e}") from None
    except (OSError, KeyError) as e:
        raise CLIError(EXIT_STRUCTURE, f"view: {args.trajectory}: not a simulate output (.npz with t, nodes, bars, "
                                       f"strings): {e}") from None
    terrain = None
    if args.terrain is not None:
        try:
            terrain = Terrain.from_file(args.terrain)
        except (ValueError, TypeError, OSError, RecursionError) as e:
            raise CLIError(EXIT_STRUCTURE, f"view: --terrain {args.terrain!r}: {_one_line(e)}") from None
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
        view_trajectory(s, nodes, tensions, t, mode=args.mode, terrain=terrain,
                        **({"port": args.port} if args.mode != "window" else {}))
    except (RendererUnavailable, ValueError, OSError) as e:
        raise CLIError(EXIT_OUTPUT, f"view: {e}") from None
    return 0


def parse_initial(items, model, fittable: dict, aliases: dict, contact_fields=()) -> dict:
    """``--initial NAME=VALUE ...`` as ``{name: value}``: VALUE one number for every member, or one
    per member separated by commas (one number for the ground's ``contact_fields``); CLIError
    naming the item otherwise."""
    from ..core.params import default_params
    out = {}
    for item in items or ():
        name, eq, text = item.partition("=")
        g = aliases.get(name, name)
        if not eq or not text:
            raise CLIError(EXIT_USAGE, f"--initial {item!r}: expected NAME=VALUE (e.g. damping=0.5)")
        if g not in fittable:
            raise CLIError(EXIT_USAGE, f"--initial {item!r}: unknown parameter {name!r}; choose from {sorted(fittable)}")
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            raise CLIError(EXIT_USAGE, f"--initial {item!r}: VALUE must be a number or numbers separated by commas")
        value = np.array(vals[0] if len(vals) == 1 else vals)
        if g in contact_fields and value.size != 1:
            raise CLIError(EXIT_USAGE, f"--initial {item!r}: {name} is one number (the ground's)")
        bad = ~(np.isfinite(value) & (value > 0))
        if bad.any():
            i = int(np.flatnonzero(bad.reshape(-1))[0])
            raise CLIError(EXIT_USAGE, f"--initial {name}: value {i} is {float(value.reshape(-1)[i])!r}; starting "
                           "values must be finite and > 0 (they are fitted in log space)")
        if g in contact_fields:
            out[g] = float(value)
            continue
        try:
            default_params(model).replace(**{g: value})
        except ValueError as e:
            raise CLIError(EXIT_USAGE, f"--initial {name}: {str(e).partition(': ')[2] or e}") from None
        out[g] = value
    return out


def cmd_identify(args) -> int:
    """Fit parameters to a recorded trajectory; write the fit as JSON (atomically) and a plot."""
    from . import sysid     # scipy: imported only when identify runs
    for f in args.fit:
        if sysid._ALIASES.get(f, f) not in sysid.FITTABLE:
            raise CLIError(EXIT_USAGE, f"--fit: unknown parameter {f!r}; choose from {sorted(sysid.FITTABLE)} "
                           f"(aliases {sorted(sysid._ALIASES)})")
    ground = [f for f in args.fit if f in sysid.CONTACT_FIELDS]
    ground += [i.partition("=")[0] for i in args.initial or () if i.partition("=")[0] in sysid.CONTACT_FIELDS]
    if ground and not args.ground:
        raise CLIError(EXIT_USAGE, f"{'--fit' if ground[0] in args.fit else '--initial'} {ground[0]}: a ground contact "
                       "parameter; add --ground (and give a recording made on the ground)")
    terrain = terrain_from_args(args)      # contact options without --ground: exit 2
    contact = None
    out, tx, s, model = _outputs_and_model(args, args.plot, "--plot")
    if terrain is not None:               # --ground: a level plane at z = 0, as simulate --ground runs it
        from ..physics.contact import GroundContact, impact_damping_cap
        # with --dt, the damping cap simulate --ground applies at that step (impact_damping_cap)
        cap = math.inf if args.dt is None else impact_damping_cap(s.bar_mass, args.dt)
        contact = GroundContact(friction=terrain.friction, stiffness=terrain.stiffness, damping=terrain.damping,
                                radius=DEFAULT_CAP_RADIUS if args.cap_radius is None else args.cap_radius,
                                max_damping=cap)
    initial = parse_initial(args.initial, model, sysid.FITTABLE, sysid._ALIASES, sysid.CONTACT_FIELDS)
    try:
        t, nodes, rl, mask = sysid.load_trajectory(args.trajectory, model.n_nodes, bars=model.structure.bars)
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
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", sysid.SysIdWarning)   # reported below from the result
            res = sysid.identify(model, t, nodes, fit=args.fit, mode="scale" if args.scale else "per_member",
                                 rest_length=rl, node_mask=mask, window=args.window, integrator=args.integrator,
                                 dt=args.dt, stride=args.stride, total_mass=args.total_mass, initial=initial,
                                 contact=contact)
    except sysid.StartValueError as e:     # a zero start value: the command-line remedy
        raise CLIError(EXIT_STRUCTURE, f"{e.problem}: start it with --initial {e.name}=VALUE "
                       f"({e.unit})") from None
    except ValueError as e:     # the trajectory does not fit the structure, too short, ...: bad input
        raise CLIError(EXIT_STRUCTURE, str(e)) from None
    except FloatingPointError as e:   # SimulationDiverged: the starting values blow the model up
        raise CLIError(EXIT_DIVERGED, f"the simulation diverged during the fit ({e}); try a smaller --dt or "
                       "starting values closer to the robot's") from None
    d = res.to_dict()
    d.update(structure=s.name, trajectory=str(args.trajectory))
    _stage(tx, out, lambda f: f.write(json.dumps(d, indent=1).encode()))
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        _stage(tx, Path(args.plot), lambda f: res.plot().savefig(f, dpi=100, format="png"))
    _commit(tx)
    for g in res.fields:
        pinned = res.at_bound.get(g, np.zeros(len(res.items[g]), bool))
        for i, v, e, b in zip(res.items[g], res.values[g], res.std_errors[g], pinned):
            err = "(at the search bound)" if b else f"+- {e:.3g}" if np.isfinite(e) else "(not identifiable)"
            print(f"{g:12s} {sysid.FITTABLE[g]} {i:3d}  {v:.6g} {err} {sysid._UNITS[g]}")
    print(f"RMS node error {res.rms_m * 1e3:.4g} mm (initial values {res.rms_initial_m * 1e3:.4g} mm; record noise "
          f"{res.noise_m * 1e3:.3g} mm, motion {res.motion_rms_m * 1e3:.3g} mm RMS); {res.n_windows} windows of "
          f"{res.window_s:g} s; converged: {res.converged}; ok: {res.ok}; wrote {out}"
          + (f" and {args.plot}" if args.plot else ""))
    for w in res.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0 if res.ok else 3


def cmd_import_recording(args) -> int:
    """``import-recording FILE --format rutgers --out rec.npz``: exit 0, 3 (the input cannot be read
    or is malformed: the frame and field are named) or 4 (output). Prints what the recording holds,
    the unit conversion and its report (gaps, repeated time stamps, missing points)."""
    out = Path(args.out)
    tx = _claim(args, [(out, "import-recording: --out")], create_folders=False)
    scale = RUTGERS_SCALE if args.scale is None else args.scale
    try:
        rec = import_rutgers(args.file, rod_lengths=args.rod_length, scale=scale)
    except FileNotFoundError:
        raise CLIError(EXIT_STRUCTURE, f"import-recording: {args.file!r} not found") from None
    except IsADirectoryError:
        raise CLIError(EXIT_STRUCTURE, f"import-recording: {args.file!r} is a directory") from None
    except PermissionError as e:
        raise CLIError(EXIT_STRUCTURE, f"import-recording: {args.file!r} cannot be read ({e.strerror})") from None
    except (ValueError, OSError) as e:
        raise CLIError(EXIT_STRUCTURE, f"import-recording: {e}") from None
    _stage(tx, out, lambda f: save_recording(f, rec))
    _commit(tx)
    rep = rec.report
    if args.json:
        print(json.dumps(dict(rep), indent=1))
    else:
        lengths = ", ".join(f"{x:.4g}" for x in rec.rod_lengths)
        print(f"{args.file}: {rep['frames']} frames over {rep['duration_s']:.4g} s (median interval "
              f"{rep['median_interval_s']:.4g} s), {rep['rods']} rods ({lengths} m), {rep['points']} tracked points, "
              f"{len(rec.actuators)} actuated cables, commands {', '.join(rec.commands) or 'none'}")
        print(f"units: lengths divided by {scale:g} to m; times from the first frame (Unix "
              f"{rec.metadata['time_origin_unix_s']:.3f} s)")
        print(f"gaps {len(rep['gaps'])}, repeated time stamps {len(rep['duplicate_times'])}, missing points "
              f"{rep['missing_points']} -> {out}")
    for w in rep["warnings"]:
        print(f"warning: {w}", file=sys.stderr)
    return 0
