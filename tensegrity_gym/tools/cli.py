"""Command line: ``python -m tensegrity_gym {simulate,info,demo,export,import,view,identify,import-recording} ...``
(SI units throughout).

* ``simulate STRUCTURE --duration T --dt DT --integrator rk4 --out traj.npz`` writes
  ``t`` (S,) in s, ``nodes`` (S, n, 3) in m and ``energy`` (S,) in J (kinetic + string
  potential + gravity) at every step (``--record-every K`` thins the output).
* ``info STRUCTURE`` prints counts, masses, prestress, slack strings and the estimated
  largest stable step of the explicit integrators.
* ``identify STRUCTURE TRAJ.npz|TRAJ.csv --fit stiffness damping mass --per-member|--scale
  --out fit.json [--plot fit.png]`` fits physical parameters to a recorded motion
  (:mod:`tensegrity_gym.tools.sysid`, docs/sysid.md); with ``--ground`` (and ``simulate``'s contact
  options) the motion runs on a level ground and ``--fit friction ground_stiffness ground_damping``
  fits its contact; exit status 0 when the fit converged and every
  parameter is identifiable, 3 when the result is flagged.
* ``demo --out DIR`` simulates the default prism released off equilibrium and writes a
  plot and a JSON summary.
* ``simulate ... --terrain FILE.json`` (or ``--ground``: a level plane at z = 0) lifts the
  structure onto the terrain (docs/terrain.md) and simulates it with terrain contact;
  ``--friction``, ``--ground-stiffness``, ``--ground-damping`` override the file's contact
  values, ``--cap-radius`` sets the rods' capsule radius (m).
* ``export STRUCTURE --format mjcf --out model.xml [--ground | --terrain FILE.json]`` writes a
  MuJoCo model of the structure (:mod:`tensegrity_gym.io.mjcf`), with the terrain's plane, boxes
  and heightfield as MuJoCo geoms; ``--format json`` writes this package's JSON;
  ``--from tnsgrt`` reads STRUCTURE as a tnsgrt structure dict (:mod:`tensegrity_gym.io.tnsgrt`).
* ``import robot.xml --out robot.json [--report report.json]`` reads a MuJoCo model of a class-1
  tensegrity (:mod:`tensegrity_gym.core.mjcf_import`, docs/mjcf.md), writes the structure and prints
  what was mapped, approximated and dropped; a joint, an equality constraint, a tendon through
  more than two sites or a pulley is refused (exit 3) naming the element, its name and its line.
* ``simulate ... --video out.mp4`` / ``demo --video out.mp4`` also render the run to a video.
* ``import-recording FILE --format rutgers --out rec.npz`` converts a lab's recording (the
  Rutgers/Yale processed JSON: rod end points, times, gait commands) to this package's recording
  format (:mod:`tensegrity_gym.io.recording`, docs/recordings.md) in SI units, refusing a malformed
  one with the frame and field named and reporting gaps and repeated time stamps.
* ``view traj.npz [--structure S] [--terrain FILE.json]`` opens an interactive view of a ``simulate`` output (time
  slider, play/pause): a window where there is a display, else a browser view (viser).

``STRUCTURE`` is a JSON file, a MuJoCo model (``.xml``, read as ``import`` reads it) or a built-in
name (``prism3``, ``icosahedron``, ...).
Outputs are written by :mod:`tensegrity_gym.io.claim` and :mod:`tensegrity_gym.io.atomic`: every
output of a command is claimed before anything is simulated (a lock file ``.<name>.lock`` beside
it names the run; a second run to the same output is refused at once naming the first one's pid,
host and start time; a lock left by a run that no longer runs is taken over only with
``--steal-lock``), written to a temporary file in the same folder with the user's umask, and
published together at the end (``simulate`` + ``--video``, ``identify`` + ``--plot``, ``demo``'s
files: all or none). An existing output is replaced only with ``--force``, also one created by
someone else during the run. An interrupted run (Ctrl-C or SIGTERM) never leaves a truncated or
temporary file and says which outputs it wrote.

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
       (``StructureError``); a terrain file that cannot be read or is invalid (``--terrain``);
       ``view``: not a ``simulate`` output or a structure that does not match; ``import-recording``:
       a recording that cannot be read or is malformed (the frame and field are named)
4      output problem: the output is a directory, its folder is not writable, it exists and
       ``--force`` was not given, writing failed (disk full), or no renderer / viewer is available
5      request too large: more steps or memory than the limits above (the estimate is printed)
6      the simulation diverged (non-finite state, an adaptive integrator failed, or the energy
       grew a million-fold: an unstable step); ``simulate`` keeps the records up to the
       divergence in the output, flagged by ``diverged`` = True and a ``message``
130    interrupted (Ctrl-C); 143: terminated (SIGTERM); 141: output pipe closed (``| head``)
=====  =====================================================================================

The verbs live in :mod:`.cli_simulate` (simulate, demo) and :mod:`.cli_commands` (info, export,
view, identify, import-recording); exit codes, limits and the outputs' claim in :mod:`.cli_common`.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import warnings

from .. import __version__
from ..core.builders import BUILDERS
from ..core.integrators import INTEGRATORS
from ..core.errors import SimulationDiverged
from ..core.sizing import StructureTooLarge
from ..core.structure import StructureError
from .cli_commands import (cmd_export, cmd_identify, cmd_import, cmd_import_recording, cmd_info, cmd_view,
                           structure_summary)
from .cli_common import (DEFAULT_MAX_STEPS, EXIT_DIVERGED, EXIT_INTERRUPTED, EXIT_PIPE, EXIT_STRUCTURE,
                         EXIT_TERMINATED, EXIT_TOO_LARGE, EXIT_USAGE, CLIError, _default_max_memory_gib,
                         _non_negative, _one_line, _port, _positive, _seed, TERMINATED, _Terminated)
from .cli_simulate import cmd_demo, cmd_simulate, load_schedule
from .cli_terrain import add_terrain_args

__all__ = ["main", "entry", "build_parser", "CLIError", "structure_summary", "load_schedule", "cmd_simulate",
           "cmd_info", "cmd_demo", "cmd_export", "cmd_import", "cmd_view", "cmd_identify", "cmd_import_recording"]


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
    sp.add_argument("--steal-lock", action="store_true",
                    help="take over an output's lock left by a run that no longer runs (or runs on another host)")
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
    add_terrain_args(sp)
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
    yp.add_argument("trajectory", help="TRAJ.npz (t (S,) s, nodes (S, n, 3) m, optional rest_length (S, m)), "
                    "TRAJ.csv (long format: header t,node,x,y,z; one row per tracked node per sample) or a "
                    "recording .npz (docs/recordings.md) sampled at a fixed rate: its rods' end points are the nodes")
    yp.add_argument("--fit", nargs="+", default=["stiffness", "damping"],
                    help="parameters to fit: stiffness damping mass (alias rod_mass) node_damping; with --ground "
                         "also friction ground_stiffness ground_damping")
    grp = yp.add_mutually_exclusive_group()
    grp.add_argument("--per-member", action="store_true", help="one value per string / rod (default)")
    grp.add_argument("--scale", action="store_true", help="one factor per parameter group")
    yp.add_argument("--initial", nargs="+", default=None, metavar="NAME=VALUE",
                    help="starting values instead of the structure's: a number for every member, or one per "
                         "member separated by commas (e.g. --initial damping=0.5 stiffness=800,800,...; SI units)")
    yp.add_argument("--total-mass", type=_positive(float), default=None,
                    help="weighed total rod mass, kg (needed to fit mass together with stiffness/damping)")
    yp.add_argument("--nodes", type=int, nargs="+", default=None, help="use only these tracked nodes")
    yp.add_argument("--window", type=_positive(float), default=None,
                    help="shooting window, s (default 0.2; 0.05 with --ground)")
    yp.add_argument("--integrator", default=None, choices=["rk4", "semi_implicit_euler", "implicit_euler"],
                    help="default rk4; semi_implicit_euler with --ground")
    yp.add_argument("--dt", type=_positive(float), default=None, help="fit step, s (divides the sample spacing)")
    yp.add_argument("--stride", type=_positive(int), default=1, help="fit every K-th sample")
    yp.add_argument("--out", default="fit.json", help="output JSON")
    yp.add_argument("--plot", default=None, help="PNG of recorded vs fitted motion")
    yp.add_argument("--force", action="store_true", help="overwrite existing outputs")
    yp.add_argument("--steal-lock", action="store_true",
                    help="take over an output's lock left by a run that no longer runs (or runs on another host)")
    add_terrain_args(yp, terrain_file=False,
                     ground_help="the recording was made on a level ground at z = 0 (as simulate --ground): the "
                                 "fit simulates it there; the contact options give its values (the start values "
                                 "of fitted ones)")
    limits(yp)
    yp.set_defaults(func=cmd_identify)
    dp = sub.add_parser("demo", help="simulate the default prism, write a plot and summary", formatter_class=fmt)
    dp.add_argument("--out", default="results/demo", help="output folder")
    dp.add_argument("--force", action="store_true", help="overwrite existing demo files")
    dp.add_argument("--steal-lock", action="store_true",
                    help="take over an output's lock left by a run that no longer runs (or runs on another host)")
    dp.add_argument("--duration", type=_positive(float), default=5.0, help="simulated time, s")
    dp.add_argument("--damping", type=_non_negative, default=5.0, help="string damping, N s/m")
    dp.add_argument("--perturbation", type=_non_negative, default=0.02, help="node perturbation std, m")
    dp.add_argument("--integrator", default="rk4", choices=sorted(INTEGRATORS), help="integration method")
    dp.add_argument("--seed", type=_seed, default=0, help="seed of the perturbation")
    limits(dp)
    dp.set_defaults(func=cmd_demo)
    for sp_ in (sp, dp):
        sp_.add_argument("--video", default=None, help="also write a video of the run (.mp4 or .gif)")
    sp.add_argument("--loads", action="store_true",
                    help="also record each string's tension and each rod's compression at its centre per record "
                         "(string_tension, rod_compression, N; with the terrain's contact forces) and print the peaks")
    ep = sub.add_parser("export", help="write a structure as a MuJoCo model (MJCF) or JSON", formatter_class=fmt)
    ep.add_argument("structure", help=f"JSON file or built-in name ({names}); tnsgrt dict JSON with --from tnsgrt")
    ep.add_argument("--format", default="mjcf", choices=["mjcf", "json"], help="output format")
    ep.add_argument("--out", required=True, help="output file (model.xml)")
    ep.add_argument("--from", dest="source", default="tensegrity_gym", choices=["tensegrity_gym", "tnsgrt"],
                    help="input format of STRUCTURE")
    add_terrain_args(ep, contact=False,
                     ground_help="MJCF: add a ground plane at z = 0 (the structure is written where it is)")
    ep.add_argument("--timestep", type=_positive(float), default=1e-3, help="MJCF: MuJoCo time step, s")
    ep.add_argument("--force", action="store_true", help="overwrite an existing output file")
    ep.add_argument("--steal-lock", action="store_true",
                    help="take over an output's lock left by a run that no longer runs (or runs on another host)")
    limits(ep)
    ep.set_defaults(func=cmd_export)
    rp = sub.add_parser("import-recording", help="convert a lab's recording (Rutgers/Yale JSON) to a recording .npz",
                        formatter_class=fmt)
    rp.add_argument("file", help="the recording to import (--format rutgers: the processed JSON, a list of frames)")
    rp.add_argument("--format", default="rutgers", choices=["rutgers"], help="input format (docs/recordings.md)")
    rp.add_argument("--out", default="rec.npz", help="output recording (.npz, docs/recordings.md)")
    rp.add_argument("--scale", type=_positive(float), default=None,
                    help="the input's lengths divided by this are m (rutgers default 10: its data are upscaled x10)")
    rp.add_argument("--rod-length", type=_positive(float), default=None,
                    help="the rods' end-cap-centre length, m (default: each rod's median measured length)")
    rp.add_argument("--json", action="store_true", help="print the recording's report as JSON")
    rp.add_argument("--force", action="store_true", help="overwrite an existing output")
    rp.add_argument("--steal-lock", action="store_true",
                    help="take over an output's lock left by a run that no longer runs (or runs on another host)")
    rp.set_defaults(func=cmd_import_recording)
    mp = sub.add_parser("import", help="read a MuJoCo model (MJCF) of a class-1 tensegrity as a structure (JSON)",
                        formatter_class=fmt)
    mp.add_argument("model", help="MJCF file (robot.xml)")
    mp.add_argument("--out", required=True, help="output structure file (robot.json)")
    mp.add_argument("--report", default=None, help="also write the import report (JSON)")
    mp.add_argument("--force", action="store_true", help="overwrite existing output files")
    mp.add_argument("--steal-lock", action="store_true",
                    help="take over an output's lock left by a run that no longer runs (or runs on another host)")
    mp.set_defaults(func=cmd_import)
    vp = sub.add_parser("view", help="interactive view of a simulate output (time slider, play/pause)",
                        formatter_class=fmt)
    vp.add_argument("trajectory", help="a .npz written by simulate")
    vp.add_argument("--structure", default=None, help="the simulated structure: strings coloured by tension")
    vp.add_argument("--mode", default="auto", choices=["auto", "window", "browser"],
                    help="window (needs a display), browser (viser web view) or auto")
    vp.add_argument("--terrain", default=None, metavar="FILE.json", help="draw this terrain (docs/terrain.md)")
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


def _written(args) -> str:
    """What an interrupted command left written: "no output file was changed" or "wrote ..."."""
    tx = getattr(args, "outputs", None)
    return tx.report() if tx is not None else "no output file was changed"


def _ignore_unraisable(unraisable) -> None:
    """``sys.unraisablehook`` after a SIGTERM: finalisers' errors while the process exits are dropped."""


def main(argv=None) -> int:
    """Run the command line; returns the exit code (see the module docstring)."""
    def on_term(signum, frame):
        TERMINATED.set()
        # from here the process only cleans up and exits: an exception a finaliser raises while the
        # interrupted work unwinds (numba / llvmlite objects of a compile cut short) is not an
        # error of this command, and Python would print its traceback after the one-line message
        sys.unraisablehook = _ignore_unraisable
        raise _Terminated()

    TERMINATED.clear()

    old = args = None
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
        if TERMINATED.is_set():        # the handler's exception was swallowed (see cli_common.TERMINATED)
            raise _Terminated()
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
        _error(f"interrupted; {_written(args)}")
        return EXIT_INTERRUPTED
    except _Terminated:
        _error(f"terminated (SIGTERM); {_written(args)}")
        return EXIT_TERMINATED
    finally:
        if getattr(args, "outputs", None) is not None:
            args.outputs.release()    # unpublished temporary files and the locks
        if old is not None:
            signal.signal(signal.SIGTERM, old)


def entry() -> None:
    """The process entry (``python -m tensegrity_gym``, the ``tensegrity-gym`` script): exits with
    :func:`main`'s code. After a SIGTERM it exits without the interpreter's finalisation: the
    command has cleaned up and reported already, and a compile the signal cut short can leave
    llvmlite objects whose teardown aborts the process (a double free, exit status -6, not 143)."""
    code = main()
    if TERMINATED.is_set():
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":  # pragma: no cover
    entry()
