"""System identification results: recover perturbed per-string stiffness and
damping and per-rod masses of a prism from one recorded 5 s trajectory, and tabulate how the error
grows with position noise and shrinks with record length.

Setup (SI units): the 3-bar prism standing on the plane (``constrained_prism``: node 0 pinned,
node 1 on a line, node 2 on the plane, gravity, 9 strings of 1000 N/m with 2 N s/m damping,
1 kg rods), every string's stiffness and damping and every rod's mass multiplied by an
independent factor uniform in [0.8, 1.2] (seeded), released from a 3 cm random displacement.

Two experiment designs on the same robot and release:

* ``free``: the free release (the cables hold their rest lengths): the motion decays (damping
  ratio ~3 %), fit with 0.2 s shooting windows (``free``) or 1 s windows (``free_1s``);
* ``actuated`` (the headline): the cables' motors keep the robot moving for the whole 5 s: every
  string's rest length is its nominal one plus ``EXCITE_AMPLITUDE`` x a sum of ``N_SINES`` sines of
  random frequencies in ``EXCITE_BAND`` Hz and random phases (seeded, independent of the robot's
  draw), sent as motor commands at 100 Hz (zero-order hold, ``HOLD`` s; at most +-2 cm on a
  0.82-0.93 m rest length). The commanded rest lengths are recorded with the motion
  (``rest_length`` (S, m), the ``.npz`` layout's actuated-cable channel) and given to the fit;
  fit with 1 s shooting windows (500 samples, see WINDOWS; a forced, damped response does not diverge over a window, and
  how far the damping lets it drift over 1 s is what identifies the damping).

The "recording" is integrated with DOP853 (rtol 1e-10, atol 1e-12; restarted at each motor
command) and sampled at 1 kHz; the fit uses RK4 at 2 ms on every second sample (500 Hz),
starting from the nominal values (up to 20 % off), and never sees the true values. The weighed
total rod mass is given (motion alone only fixes mass / stiffness / damping ratios: see
docs/sysid.md). Gaussian noise of the stated standard deviation is added to every recorded node
coordinate (seeded; at 1 mm, five noise draws).

    PYTHONPATH=. python -m scripts.figures.sysid_results [--out results/sysid] [--quick] [--record-stats]

writes ``results.json`` (every fit: errors per group, standard errors, RMS, time),
``fit_1mm.png`` (recorded vs fitted motion, actuated 5 s record, 1 mm noise) and ``README.md``
(the tables).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
import warnings
from pathlib import Path

import numpy as np

import tensegrity_gym as tg
from tensegrity_gym.core.model import State
from tensegrity_gym.physics.geometry import node_positions
from tensegrity_gym.physics.evaluate import project
from tensegrity_gym.core.params import default_params
from tensegrity_gym.tools.sysid import SysIdWarning, identify
from tensegrity_gym.io.atomic import write_atomic  # noqa: E402

FIELDS = ("stiffness", "damping", "mass")
EXCITE_AMPLITUDE = 0.005    # m, amplitude of each sine of a string's rest-length command
N_SINES = 4                 # sines per string
EXCITE_BAND = (0.5, 12.0)   # Hz (the prism's fastest mode: 13 Hz)
HOLD = 0.01                 # s, motor command period (zero-order hold)
# shooting window of each design, s: "1 s" windows hold 500 samples at the fit's 500 Hz (0.998 s;
# windows share no samples), so that five fill the 5 s record (a 1.000 s window, 501 samples,
# would leave the last second unused); 0.2 s: the earlier experiment's (24 windows, last 0.15 s unused)
WINDOWS = {"free": 0.2, "free_1s": 0.998, "actuated": 0.998}
SAMPLE_DT = 1e-3            # s, recording rate 1 kHz


def excitation(model, t, seed=0):
    """(S, m) rest lengths, m: the commanded rest lengths of the actuated design at sample times
    ``t`` (held over each HOLD s motor period; see the module doc)."""
    rng = np.random.default_rng(100 + seed)
    m = model.n_strings
    f = rng.uniform(*EXCITE_BAND, (m, N_SINES))
    ph = rng.uniform(0.0, 2 * np.pi, (m, N_SINES))
    nh = int(round(HOLD / SAMPLE_DT))
    th = (np.arange(t.size) // nh) * nh * SAMPLE_DT            # time of the command in force
    wave = np.sin(2 * np.pi * f[None] * th[:, None, None] + ph[None]).sum(-1)
    return model.rest_length[None] + EXCITE_AMPLITUDE * wave


def record(T, seed=0, actuated=True):
    """The true robot, sample times, recorded node positions (S, n, 3) m and rest lengths (S, m)
    m (None for the free release) of a T s record: DOP853 at tol 1e-10, sampled at 1 kHz,
    restarted at each motor command (the rest lengths switch there)."""
    s = tg.constrained_prism(damping=2.0)
    model = tg.compile_model(s)
    rng = np.random.default_rng(seed)
    true = {f: getattr(model, f) * rng.uniform(0.8, 1.2, getattr(model, f).shape) for f in FIELDS}
    st = tg.initial_state(model, nodes=s.nodes + 0.03 * rng.standard_normal(s.nodes.shape))
    st = State(*project(model, st.q, st.qd))
    P = default_params(model).replace(**true)
    S = int(round(T / SAMPLE_DT)) + 1
    t = np.arange(S) * SAMPLE_DT
    if not actuated:
        t, q, _ = tg.simulate(model, st, SAMPLE_DT, S - 1, "dop853", params=P, rtol=1e-10, atol=1e-12)
        return model, true, t, node_positions(model, q[:, 0]), None
    rl = excitation(model, t, seed)
    nodes = np.empty((S, model.n_nodes, 3))
    nodes[0] = node_positions(model, st.q)[0]
    nh, i = int(round(HOLD / SAMPLE_DT)), 0
    while i < S - 1:
        j = min(i + nh, S - 1)
        _, q, qd = tg.simulate(model, st, SAMPLE_DT, j - i, "dop853", params=P, rest_length=rl[i],
                               rtol=1e-10, atol=1e-12)
        nodes[i + 1:j + 1] = node_positions(model, q[1:, 0])
        st = State(q[-1], qd[-1], 0.0)
        i = j
    return model, true, t, nodes, rl


def fit(model, true, t, nodes, noise_m, rest_length=None, design="actuated", seed=1, plot=None):
    rng = np.random.default_rng(seed)
    noisy = nodes + noise_m * rng.standard_normal(nodes.shape)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always", SysIdWarning)
        r = identify(model, t, noisy, fit=FIELDS, stride=2, window=WINDOWS[design], rest_length=rest_length,
                     total_mass=float(true["mass"].sum()))
    if plot:
        r.plot(plot)
    err = {f: np.abs(r.values[f] / true[f] - 1) for f in FIELDS}
    z = np.concatenate([np.abs(r.values[f] - true[f]) / r.std_errors[f] for f in FIELDS])
    return {
        "design": design, "window_s": WINDOWS[design], "noise_seed": seed,
        "noise_mm": noise_m * 1e3, "duration_s": float(t[-1] - t[0]), "converged": r.converged, "ok": r.ok,
        "max_rel_error": float(max(e.max() for e in err.values())),
        "max_rel_error_by_field": {f: float(e.max()) for f, e in err.items()},
        "rms_rel_error_by_field": {f: float(np.sqrt(np.mean(e ** 2))) for f, e in err.items()},
        "max_rel_std_error": float(max(r.rel_std_errors[f].max() for f in FIELDS)),
        "max_rel_std_error_by_field": {f: float(r.rel_std_errors[f].max()) for f in FIELDS},
        "max_error_over_std_error": float(np.max(z)),
        "rms_m": r.rms_m, "rms_initial_m": r.rms_initial_m, "windows": r.n_windows, "nfev": r.nfev,
        "njev": r.njev, "wall_s": r.wall_s, "warnings": [str(x.message) for x in w],
        "fitted": {f: r.values[f].tolist() for f in FIELDS}, "true": {f: true[f].tolist() for f in FIELDS},
    }


def atomic_write(path: Path, text: str):
    write_atomic(path, lambda f: f.write(text.encode()))


def record_stats():
    """Print how much each 5 s record keeps the strings moving (RMS string length rate per second
    of record, m/s) and how often a string is slack (``--record-stats``, ~25 s)."""
    for actuated in (False, True):
        model, _, t, nodes, rl = record(5.0, actuated=actuated)
        st = model.structure
        L = np.linalg.norm(nodes[:, st.strings[:, 1]] - nodes[:, st.strings[:, 0]], axis=-1)
        l0 = model.rest_length[None] if rl is None else rl
        rate = np.diff(L, axis=0) / SAMPLE_DT
        per_s = [float(np.sqrt(np.mean(rate[i * 1000:(i + 1) * 1000] ** 2))) for i in range(5)]
        print(f"{'actuated' if actuated else 'free release'}: RMS string length rate in seconds 1..5: "
              + ", ".join(f"{v:.3g}" for v in per_s) + f" m/s; samples with a slack string: "
              f"{100 * float((L < l0).any(axis=1).mean()):.2g} %; largest node excursion "
              f"{1e3 * float(np.abs(nodes - nodes[0]).max()):.0f} mm")


def _show(row):
    print(json.dumps({k: v for k, v in row.items() if k not in ("fitted", "true", "warnings")}), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="results/sysid")
    ap.add_argument("--quick", action="store_true", help="actuated 5 s, noise 0 and 1 mm (one draw) only")
    ap.add_argument("--readme-only", action="store_true", help="re-render README.md from results.json")
    ap.add_argument("--record-stats", action="store_true",
                    help="only print how the two 5 s records keep the strings moving (string length rates, slack)")
    a = ap.parse_args()
    if a.record_stats:
        record_stats()
        return
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.readme_only:
        write_readme(out, json.loads((out / "results.json").read_text()))
        return
    t0 = time.perf_counter()
    model, true, t, nodes, rl = record(5.0, actuated=True)
    gen_s = time.perf_counter() - t0
    print(f"recorded 5 s (actuated) with dop853 in {gen_s:.1f} s", flush=True)
    rows = []
    noises = (0.0, 1e-3) if a.quick else (0.0, 1e-4, 3e-4, 1e-3, 3e-3)
    for nz in noises:
        rows.append(fit(model, true, t, nodes, nz, rl, plot=out / "fit_1mm.png" if nz == 1e-3 else None))
        _show(rows[-1])
    if not a.quick:
        for seed in (2, 3, 4, 5):        # more noise draws at the target's 1 mm
            rows.append(fit(model, true, t, nodes, 1e-3, rl, seed=seed))
            _show(rows[-1])
        for T in (1.0, 2.0):
            sel = t <= T + 1e-9
            for nz in (0.0, 1e-3):
                rows.append(fit(model, true, t[sel], nodes[sel], nz, rl[sel]))
                _show(rows[-1])
        g0 = time.perf_counter()
        _, true_f, t_f, nodes_f, _ = record(5.0, actuated=False)
        gen_s += time.perf_counter() - g0
        for k in FIELDS:
            assert np.array_equal(true_f[k], true[k])    # the same robot and release
        for design in ("free", "free_1s"):
            for nz in (0.0, 1e-3):
                rows.append(fit(model, true, t_f, nodes_f, nz, None, design=design))
                _show(rows[-1])
    total = time.perf_counter() - t0
    act5 = [r for r in rows if r["design"] == "actuated" and r["duration_s"] > 4]
    r0 = next(r for r in act5 if r["noise_mm"] == 0)
    r1 = [r for r in act5 if r["noise_mm"] == 1]
    worst1 = max(r["max_rel_error"] for r in r1)
    summary = {
        "command": "PYTHONPATH=. python -m scripts.figures.sysid_results" + (" --quick" if a.quick else ""),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores (shared with other jobs)",
        "generate_s": gen_s, "total_s": total,
        "excitation": {"amplitude_m_per_sine": EXCITE_AMPLITUDE, "sines_per_string": N_SINES,
                       "band_hz": list(EXCITE_BAND), "command_period_s": HOLD},
        "windows_s": WINDOWS,
        "target_noise_free_1pct": {"max_rel_error": r0["max_rel_error"], "met": r0["max_rel_error"] < 0.01},
        "target_1mm_3pct": {"max_rel_error_worst_of_draws": worst1, "noise_draws": len(r1), "met": worst1 < 0.03},
        "fits": rows,
    }
    atomic_write(out / "results.json", json.dumps(summary, indent=1))
    write_readme(out, summary)
    print(f"wrote {out}/results.json, README.md, fit_1mm.png in {total:.0f} s")


def _pct(x):
    return f"{100 * x:.3g} %"


def write_readme(out: Path, summary: dict):
    rows, total, gen_s = summary["fits"], summary["total_s"], summary["generate_s"]
    act = [r for r in rows if r["design"] == "actuated"]
    act5 = [r for r in act if r["duration_s"] > 4]
    r0 = next(r for r in act5 if r["noise_mm"] == 0)
    r1s = [r for r in act5 if r["noise_mm"] == 1]
    r1 = next(r for r in r1s if r["noise_seed"] == 1)
    head = ("| record | noise (mm) | max error, stiffness | damping | mass | all 20 fitted | max rel. SE | "
            "max abs err / SE | RMS (mm) | fit wall (s) |\n|---|---|---|---|---|---|---|---|---|---|")

    def line(r, first):
        e = r["max_rel_error_by_field"]
        return (f"| {first} | {r['noise_mm']:g} | {_pct(e['stiffness'])} | {_pct(e['damping'])} | {_pct(e['mass'])} | "
                f"**{_pct(r['max_rel_error'])}** | {_pct(r['max_rel_std_error'])} | "
                f"{r['max_error_over_std_error']:.2g} | {r['rms_m'] * 1e3:.3g} | {r['wall_s']:.0f} |")
    main_rows = sorted([r for r in act if r["noise_seed"] == 1], key=lambda r: (-r["duration_s"], r["noise_mm"]))
    table = "\n".join([head] + [line(r, f"{r['duration_s']:.0f} s") for r in main_rows])
    seeds = "\n".join([head.replace("| record |", "| noise draw |")] +
                      [line(r, f"seed {r['noise_seed']}") for r in sorted(r1s, key=lambda r: r["noise_seed"])])
    names = {"free": "free release, 0.2 s windows (the earlier experiment)", "free_1s": "free release, 1 s windows",
             "actuated": "actuated cables, 1 s windows"}
    design_rows = [r for r in rows if r["duration_s"] > 4 and r["noise_seed"] == 1 and r["noise_mm"] in (0, 1)]
    design_rows.sort(key=lambda r: (["free", "free_1s", "actuated"].index(r["design"]), r["noise_mm"]))
    designs = "\n".join(["| design | noise (mm) | stiffness | damping | mass | max rel. SE: stiffness | damping | mass |",
                         "|---|---|---|---|---|---|---|---|"] +
                        [f"| {names[r['design']]} | {r['noise_mm']:g} | {_pct(r['max_rel_error_by_field']['stiffness'])} | "
                         f"{_pct(r['max_rel_error_by_field']['damping'])} | {_pct(r['max_rel_error_by_field']['mass'])} | "
                         + " | ".join(_pct(r["max_rel_std_error_by_field"][f]) for f in FIELDS) + " |"
                         for r in design_rows])
    worst1 = max(r["max_rel_error"] for r in r1s)
    worst_d = max(r["max_rel_error_by_field"]["damping"] for r in r1s)
    by = {r["design"]: r for r in design_rows if r["noise_mm"] == 1}
    ex = summary["excitation"]
    readme = f"""# System identification of a perturbed prism

Command (total {total:.0f} s on this shared 2-core machine, of which {gen_s:.0f} s generating the
DOP853 records):

    {summary['command']}

Setup: see the docstring of `scripts/figures/sysid_results.py`. In short: prism standing on the plane
(node 0 pinned, node 1 on a line, node 2 on the plane, gravity), 9 string stiffnesses, 9 string
dampings and 3 rod masses each off by a factor in [0.8, 1.2], released from a 3 cm displacement;
recorded with DOP853 (tol 1e-10) at 1 kHz; fitted with RK4 at 2 ms on 500 Hz samples from the
nominal values, given the weighed total rod mass (the 3 masses have 2 free ratios: 20 fitted
numbers). **The experiment**: during the 5 s the cable motors drive every string's rest length
with a random multisine ({ex['sines_per_string']} sines of {1e3 * ex['amplitude_m_per_sine']:g} mm, {ex['band_hz'][0]:g}-{ex['band_hz'][1]:g} Hz, random phases,
commands at {1 / ex['command_period_s']:.0f} Hz held between commands; at most +-2 cm on 0.82-0.93 m), recorded with the motion as the
`.npz` layout's `rest_length` (S, m) and given to the fit; shooting windows of 1 s (500 samples,
0.998 s: five fill the record).
Errors are |fitted / true - 1|, maximum over the members of a group. "max rel. SE" is the
largest standard error the fit reports (relative); "max abs err / SE" compares the actual
errors with them (about 1-3 when the standard errors are honest; noise-free, the error is the
integrator's, which the standard errors do not cover).

{table}

The same 5 s record, 1 mm, five independent noise draws:

{seeds}

Targets: noise-free 5 s, every parameter within 1 %: **{_pct(r0['max_rel_error'])}**
({'met' if r0['max_rel_error'] < 0.01 else 'MISSED'}); 1 mm noise, within 3 %: **{_pct(r1['max_rel_error'])}** (draw 1), worst of
{len(r1s)} draws **{_pct(worst1)}** ({'met' if worst1 < 0.03 else 'MISSED'}).

## Why the experiment, and what each change buys

The same robot, release, noise (seed 1) and 5 s, fitted three ways:

{designs}

With the free release the per-string damping is what misses ({_pct(by['free']['max_rel_error_by_field']['damping'])} at 1 mm with 0.2 s windows):
the damping ratio is ~3 %, the fast modes die out within ~1 s and the slow sway that remains says
little about each string's damping; the fit's own standard errors predicted this (it is the
information in the record, not the optimiser). Two changes add that information:

* **Longer shooting windows** (1 s instead of 0.2 s): every window's initial state is an unknown,
  and over 0.2 s a damping error is barely distinguishable from a slightly different initial
  velocity; over 1 s the decay it causes accumulates. The motion is damped and stable, so the
  longer windows still converge from the recorded start ({_pct(by['free']['max_rel_error_by_field']['damping'])} -> {_pct(by['free_1s']['max_rel_error_by_field']['damping'])}).
* **Keeping the robot moving**: the motor excitation keeps every string's length rate, and so
  its damping force, large for the whole 5 s instead of the first second, and a forced response
  depends on the damping directly (resonant amplitudes scale with 1 / damping)
  ({_pct(by['free_1s']['max_rel_error_by_field']['damping'])} -> {_pct(by['actuated']['max_rel_error_by_field']['damping'])}; worst of {len(r1s)} noise draws {_pct(worst_d)}).

The noise-free error grows from the free release's to {_pct(r0['max_rel_error'])} with the excitation and the
longer windows: RK4 at 2 ms against DOP853 over faster, larger motion and 1 s horizons (model
error, not covered by the standard errors, hence err/SE >> 1 in the noise-free rows); it stays
{0.01 / r0['max_rel_error']:.0f}x below the 1 % target. Record length: at 1 mm the damping error falls with the
record ({', '.join(f"{r['duration_s']:.0f} s: {_pct(r['max_rel_error_by_field']['damping'])}" for r in sorted([r for r in act if r['noise_mm'] == 1 and r['noise_seed'] == 1], key=lambda r: r['duration_s']))}).

`fit_1mm.png`: recorded (dots) vs fitted (lines, one per 1 s window) displacements of the three
nodes that move most, actuated 5 s record with 1 mm noise, and the RMS error per sample.
"""
    atomic_write(out / "README.md", readme)
    print(table)
    print(seeds)
    print(designs)


if __name__ == "__main__":
    main()
