"""System identification (tensegrity_gym.tools.sysid): known parameters are recovered from a trajectory
made by a different integrator at a finer step, with all or half of the nodes tracked; bad
input is refused with a message naming it; unidentifiable parameters are flagged."""
import json
import warnings

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.model import State
from tensegrity_gym.physics.geometry import node_positions
from tensegrity_gym.physics.evaluate import project
from tensegrity_gym.core.params import default_params
from tensegrity_gym.tools.sysid import SysIdWarning, identify, load_csv

GEN_DT = 5e-4     # record spacing of the reference runs (dop853, tolerance 1e-10): 2 kHz


def _record(structure, true, T=0.62, seed=0, amp=0.03, integrator="dop853"):
    """(model, t, nodes) of ``structure`` with parameters ``true`` released off equilibrium."""
    model = tg.compile_model(structure)
    rng = np.random.default_rng(seed)
    st = tg.initial_state(model, nodes=structure.nodes + amp * rng.standard_normal(structure.nodes.shape))
    st = State(*project(model, st.q, st.qd))
    P = default_params(model).replace(**true) if true else None
    t, q, _ = tg.simulate(model, st, GEN_DT, int(round(T / GEN_DT)), integrator, params=P)
    return model, t, node_positions(model, q[:, 0])


def _perturbed(model, rng, fields=("stiffness", "damping", "mass")):
    out = {}
    for f in fields:
        v = getattr(model, f)
        out[f] = v * rng.uniform(0.8, 1.2, v.shape)
    return out


@pytest.fixture(scope="module")
def constrained_case():
    s = tg.constrained_prism(damping=2.0)
    model = tg.compile_model(s)
    true = _perturbed(model, np.random.default_rng(1))
    _, t, nodes = _record(s, true)
    return model, true, t, nodes


def test_recovers_stiffness_damping_and_mass(constrained_case):
    """Prism (3 rods, 9 strings, gravity, bottom nodes on a pin / line / plane) with every
    stiffness, damping and rod mass off by up to 20 %: the rk4 fit at 2 ms recovers each from a
    dop853 record (2 kHz) to well under 1 %; mass needs the weighed total."""
    model, true, t, nodes = constrained_case
    with warnings.catch_warnings():
        warnings.simplefilter("error", SysIdWarning)
        r = identify(model, t, nodes, fit=("stiffness", "damping", "mass"), stride=4, window=0.15,
                     total_mass=float(true["mass"].sum()))
    assert r.converged and r.ok, r.message
    assert r.integrator == "rk4" and r.dt_s == pytest.approx(2e-3)
    for f in ("stiffness", "damping", "mass"):
        err = np.abs(r.values[f] / true[f] - 1)
        assert err.max() < 1e-3, (f, err)
        start = np.abs(r.initial[f] / true[f] - 1)
        assert start.max() > 0.05          # the fit really moved them
        assert np.all(np.isfinite(r.std_errors[f]))
    assert r.rms_m < 1e-5 < r.rms_initial_m
    d = r.to_dict()
    json.dumps(d)
    assert d["ok"] and len(d["values"]["stiffness"]) == 9


def test_mass_without_total_is_flagged(constrained_case):
    """Motion cannot tell the robot from one with mass, stiffness and damping all scaled by the
    same factor (weight scales with mass): without the weighed total that direction is flagged."""
    model, true, t, nodes = constrained_case
    with pytest.warns(SysIdWarning, match="not identifiable"):
        r = identify(model, t, nodes, fit=("stiffness", "damping", "mass"), stride=4, window=0.15)
    assert not r.ok
    assert not any(r.identifiable["mass"]) and not any(r.identifiable["stiffness"])
    assert np.all(np.isinf(r.std_errors["mass"]))
    # what the record does fix: every ratio (all 21 values are off from the truth by one factor)
    f = np.concatenate([r.values[g] / true[g] for g in ("stiffness", "damping", "mass")])
    assert np.ptp(f) < 2e-3 * f.mean()


def test_partial_observation_half_the_nodes():
    """A free prism (no gravity), only its three top nodes tracked (one end of each rod): the
    window states of the untracked ends are fitted too; stiffness and damping per string come
    back within 1 %."""
    s = tg.prism(3, damping=2.0)
    model = tg.compile_model(s)
    true = _perturbed(model, np.random.default_rng(2), ("stiffness", "damping"))
    _, t, nodes = _record(s, true, T=0.47, seed=3)
    nodes = nodes.copy()
    nodes[:, :3] = np.nan                      # bottom nodes not tracked
    r = identify(model, t, nodes, fit=("stiffness", "damping"), node_mask=[3, 4, 5], stride=4, window=0.15)
    assert r.converged and r.ok, r.message
    for f in ("stiffness", "damping"):
        err = np.abs(r.values[f] / true[f] - 1)
        assert err.max() < 0.01, (f, err)
    assert r.rms_m < 1e-4


def test_scale_mode_one_factor_per_group():
    s = tg.prism(3, damping=2.0)
    model = tg.compile_model(s)
    true = {"stiffness": model.stiffness * 1.15, "damping": model.damping * 0.85}
    _, t, nodes = _record(s, true, T=0.42, seed=4)
    r = identify(model, t, nodes, fit=("stiffness", "damping"), mode="scale", stride=4, window=0.2)
    assert r.ok
    assert r.scale["stiffness"] == pytest.approx(1.15, rel=1e-3)
    assert r.scale["damping"] == pytest.approx(0.85, rel=1e-3)
    assert np.allclose(r.values["stiffness"], 1.15 * model.stiffness, rtol=1e-3)


def test_slack_string_and_no_motion_are_flagged():
    """An extra string that never goes taut: its stiffness and damping have no effect and are
    flagged, the others still fit. A structure at rest: nothing is identifiable."""
    base = tg.prism(3, damping=2.0)
    extra = np.array([[0, 4]])
    L = np.linalg.norm(base.nodes[4] - base.nodes[0])
    s = tg.Structure(base.nodes, base.bars, np.concatenate([base.strings, extra]), bar_mass=1.0,
                     stiffness=1000.0, rest_length=np.concatenate([base.rest_length, [1.5 * L]]), damping=2.0)
    model, t, nodes = _record(s, None, T=0.42, seed=5)
    with pytest.warns(SysIdWarning, match="stiffness string 9.*damping string 9"):
        r = identify(model, t, nodes, fit=("stiffness", "damping"), stride=4, window=0.2)
    assert not r.ok
    assert list(np.flatnonzero(~r.identifiable["stiffness"])) == [9]
    assert list(np.flatnonzero(~r.identifiable["damping"])) == [9]
    assert np.isinf(r.std_errors["damping"][9]) and np.isfinite(r.std_errors["damping"][:9]).all()
    assert np.allclose(r.values["stiffness"][:9], 1000.0, rtol=1e-3)
    # at rest (the prestressed equilibrium, no gravity): no motion, nothing to identify
    model = tg.compile_model(tg.prism(3, damping=2.0))
    t = np.arange(200) * 2e-3
    nodes = np.repeat(model.structure.nodes[None], t.size, 0)
    with pytest.warns(SysIdWarning, match="mass rod 0"):
        r = identify(model, t, nodes, fit=("mass",), window=0.1)
    assert not any(r.identifiable["mass"]) and not r.ok


def test_not_converged_is_flagged(constrained_case):
    model, true, t, nodes = constrained_case
    with pytest.warns(SysIdWarning, match="did not converge"):
        r = identify(model, t, nodes, fit=("stiffness",), stride=4, window=0.15, max_nfev=1)
    assert not r.converged and not r.ok


@pytest.mark.parametrize("change,match", [
    (lambda t, n: (t, n[:, :5]), "5 nodes per sample but structure 'prism3' has 6"),
    (lambda t, n: (t, np.where(np.arange(len(t))[:, None, None] == 7, np.nan, n)), "sample 7 .* node 0"),
    (lambda t, n: (np.where(np.arange(len(t)) == 9, t[7], t), n), "strictly increasing; sample 9"),
    (lambda t, n: (t * np.linspace(1, 1.2, len(t)), n), "evenly spaced"),
    (lambda t, n: (t[:, None], n), "1-D array"),
])
def test_bad_trajectories_are_refused(change, match):
    model = tg.compile_model(tg.prism(3, damping=2.0))
    t = np.arange(100) * 1e-3
    nodes = np.repeat(model.structure.nodes[None], 100, 0)
    t2, n2 = change(t, nodes)
    with pytest.raises(ValueError, match=match):
        identify(model, t2, n2, fit=("stiffness",), window=0.05)


@pytest.mark.parametrize("kw,match", [
    (dict(fit=("stifness",)), "unknown parameter 'stifness'"),
    (dict(fit=("stiffness",), mode="global"), "per_member"),
    (dict(fit=("stiffness",), node_mask=[0, 9]), "node 9 does not exist"),
    (dict(fit=("damping",), initial={"damping": 0.0}), "positive starting value"),
    (dict(fit=("stiffness",), window=5.0), "longer than the record"),
    (dict(fit=("stiffness",), total_mass=3.0), "only used when 'mass'"),
    (dict(fit=("stiffness",), rest_length=np.ones((3, 9))), r"rest_length: expected shape \(100, 9\)"),
    (dict(fit=("stiffness",), integrator="dop853"), "adaptive"),
])
def test_bad_arguments_are_refused(kw, match):
    model = tg.compile_model(tg.prism(3, damping=2.0))
    t = np.arange(100) * 1e-3
    nodes = np.repeat(model.structure.nodes[None], 100, 0)
    kw.setdefault("window", 0.05)
    with pytest.raises(ValueError, match=match):
        identify(model, t, nodes, **kw)


def test_cli_identify_npz_csv_and_errors(tmp_path, capsys):
    from tensegrity_gym.tools.cli import main
    s = tg.prism(3, damping=2.0)
    model = tg.compile_model(s)
    true = {"stiffness": model.stiffness * 1.1}
    _, t, nodes = _record(s, true, T=0.42, seed=6)
    np.savez(tmp_path / "traj.npz", t=t, nodes=nodes)
    out, png = tmp_path / "fit.json", tmp_path / "fit.png"
    st = tmp_path / "prism.json"
    tg.save_json(s, st)
    rc = main(["identify", str(st), str(tmp_path / "traj.npz"), "--fit", "stiffness", "--scale", "--stride", "4",
               "--out", str(out), "--plot", str(png)])
    assert rc == 0
    d = json.loads(out.read_text())
    assert d["ok"] and d["scale"]["stiffness"] == pytest.approx(1.1, rel=1e-3)
    assert png.stat().st_size > 1000
    # the same record as long-format CSV with node 2 dropped at some samples
    rows = ["t,node,x,y,z"]
    for i, ti in enumerate(t):
        for j in range(6):
            if j == 2 and i % 7 == 0:
                continue
            rows.append(f"{float(ti)!r},{j},{float(nodes[i, j, 0])!r},{float(nodes[i, j, 1])!r},{float(nodes[i, j, 2])!r}")
    (tmp_path / "traj.csv").write_text("\n".join(rows) + "\n")
    tc, nc, mc = load_csv(tmp_path / "traj.csv", 6)
    assert np.array_equal(tc, t) and not mc[0, 2] and mc[1, 2] and np.isnan(nc[0, 2]).all()
    rc = main(["identify", str(st), str(tmp_path / "traj.csv"), "--fit", "stiffness", "--scale", "--stride", "4",
               "--out", str(out), "--force"])
    assert rc == 0 and json.loads(out.read_text())["scale"]["stiffness"] == pytest.approx(1.1, rel=1e-3)
    # errors: a CSV line that is not numbers, a trajectory for another structure, a bad name
    # (each a non-zero exit code and one "error:" line on stderr, no output file)
    (tmp_path / "bad.csv").write_text("t,node,x,y,z\n0,0,1,2,3\n0.001,zero,1,2,3\n")
    cases = [(["identify", "prism3", str(tmp_path / "bad.csv"), "--out", str(tmp_path / "x.json")], 3, "line 3"),
             (["identify", "icosahedron", str(tmp_path / "traj.npz"), "--fit", "stiffness", "--out",
               str(tmp_path / "x.json")], 3, "nodes per sample"),
             (["identify", "prism3", str(tmp_path / "traj.npz"), "--fit", "spring", "--out", str(tmp_path / "x.json")],
              2, "unknown parameter 'spring'")]
    for argv, code, msg in cases:
        capsys.readouterr()
        assert main(argv) == code
        err = capsys.readouterr().err.strip().splitlines()
        assert len([x for x in err if x.startswith("error:")]) == 1 and msg in err[-1], err
    assert not (tmp_path / "x.json").exists()


def test_actuated_rest_lengths_are_followed():
    """Cables actuated during the record (rest lengths changing every sample, zero-order hold at
    the 500 Hz record rate): given the recorded rest lengths the fit recovers the stiffness; the
    same record without them cannot be matched (large residual)."""
    s = tg.prism(3, damping=2.0)
    model = tg.compile_model(s)
    true = _perturbed(model, np.random.default_rng(7), ("stiffness",))
    P = default_params(model).replace(**true)
    h, S = 2e-3, 211
    t = np.arange(S) * h
    phase = np.arange(model.n_strings)
    rl = model.rest_length * (1 - 0.02 * np.sin(2 * np.pi * 3 * t[:, None] + phase))
    st = tg.initial_state(model)
    nodes = np.empty((S, model.n_nodes, 3))
    nodes[0] = node_positions(model, st.q)[0]
    for k in range(1, S):      # finer RK4 steps, each sample interval at the interval's first rest lengths
        st = tg.step(model, st, h / 10, "rk4", n_steps=10, rest_length=rl[k - 1], params=P)
        nodes[k] = node_positions(model, st.q)[0]
    assert np.ptp(nodes, axis=0).max() > 0.005
    r = identify(model, t, nodes, fit=("stiffness",), rest_length=rl, window=0.2)
    assert r.ok and np.abs(r.values["stiffness"] / true["stiffness"] - 1).max() < 1e-3
    with pytest.warns(SysIdWarning):
        r2 = identify(model, t, nodes, fit=("stiffness",), window=0.2, max_nfev=3)
    assert r2.rms_m > 100 * r.rms_m


def test_sysid_results_actuated_experiment_is_consistent():
    """scripts/figures/sysid_results.py's actuated record: the commanded rest lengths are held between
    100 Hz motor commands, stay within +-2 cm, the record is the same robot as the free release,
    and a noise-free 1 s record fitted as the script fits it (1 s window, the recorded rest
    lengths) recovers every parameter within 1 %."""
    import runpy
    from pathlib import Path
    mod = runpy.run_path(str(Path(__file__).resolve().parents[1] / "scripts" / "figures" / "sysid_results.py"), run_name="sysid")
    model, true, t, nodes, rl = mod["record"](1.0)
    nh = int(round(mod["HOLD"] / mod["SAMPLE_DT"]))
    assert rl.shape == (t.size, model.n_strings)
    assert np.all(rl.reshape(-1)[:] > 0)
    blocks = rl[: (t.size // nh) * nh].reshape(-1, nh, model.n_strings)
    assert np.all(blocks == blocks[:, :1])                       # zero-order hold between commands
    assert np.abs(rl - model.rest_length).max() <= 4 * mod["EXCITE_AMPLITUDE"] + 1e-12
    assert np.std(np.diff(blocks[:, 0], axis=0)) > 1e-4           # and it does move
    _, true_f, _, nodes_f, rl_f = mod["record"](1.0, actuated=False)
    assert rl_f is None and all(np.array_equal(true_f[k], true[k]) for k in true)
    assert np.abs(nodes - nodes_f).max() > 0.01
    r = mod["fit"](model, true, t, nodes, 0.0, rl)
    assert r["converged"] and r["ok"] and r["windows"] == 1
    assert r["max_rel_error"] < 0.01, r["max_rel_error_by_field"]
