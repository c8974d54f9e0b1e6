"""Command schedules: physics.rollout.Schedule (inputs held piecewise constant over time) in
physics.simulate and `simulate --rest-length / --force-density` on the command line, and the
round trip simulate (replayed cable commands) -> identify."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.physics.rollout import simulate
from tensegrity_gym.physics.integrate import step
from tensegrity_gym.core.errors import SimulationDiverged
from tensegrity_gym.tools.cli import main
from tensegrity_gym.physics.rollout import Schedule

DT = 1e-3


def _prism(B=2):
    model = compile_model(tg.prism(3))
    st = initial_state(model, B)
    qd = st.qd + 0.01 * np.random.default_rng(0).standard_normal(st.qd.shape)
    return model, State(st.q, qd, 0.0)


def _commands(model, per_copy=False, B=2):
    L = model.rest_length
    tc = np.array([0.0, 0.0105, 0.02, 0.0333])
    v = np.array([L, 0.95 * L, 0.9 * L, 1.02 * L])
    if per_copy:
        v = np.stack([v, v * np.linspace(0.97, 1.0, 9)], axis=1)   # (C, B, m)
        assert v.shape == (4, B, 9)
    return tc, v


def _manual(model, st, tc, v, n, integrator, every, name="rest_length"):
    """The reference: one step() per time step with the row in force at the step's start."""
    qs, qds = [st.q], [st.qd]
    for s in range(n - n % every):
        i = np.searchsorted(tc, s * DT + 1e-12, side="right") - 1
        st = step(model, st, DT, integrator, **{name: v[i]})
        if (s + 1) % every == 0:
            qs.append(st.q)
            qds.append(st.qd)
    return np.array(qs), np.array(qds)


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("every", [1, 5, 7])
@pytest.mark.parametrize("per_copy", [False, True])
def test_fixed_step_equals_step_by_step(integrator, every, per_copy):
    """Bit for bit the step-by-step loop, whatever the record grid (commands inside a record
    interval and inside a time step: 0.0105 s takes effect at the step from 0.011 s)."""
    model, st = _prism()
    tc, v = _commands(model, per_copy)
    t, q, qd = simulate(model, st, DT, 50, integrator, record_every=every, rest_length=Schedule(tc, v))
    Q, QD = _manual(model, st, tc, v, 50, integrator, every)
    assert q.shape == Q.shape and np.array_equal(q, Q) and np.array_equal(qd, QD)
    np.testing.assert_allclose(t, DT * every * np.arange(len(Q)), rtol=0, atol=1e-15)


def test_force_density_schedule_and_constant_rest_length():
    model, st = _prism()
    tc = np.array([0.0, 0.01, 0.03])
    fd = np.array([np.zeros(9), np.full(9, 5.0), np.full(9, 2.0)])
    rl = 0.99 * model.rest_length
    _, q, _ = simulate(model, st, DT, 40, "rk4", record_every=4, rest_length=rl,
                       force_density=Schedule(tc, fd, "force_density"))
    ref = st
    for s in range(40):
        i = np.searchsorted(tc, s * DT + 1e-12, side="right") - 1
        ref = step(model, ref, DT, "rk4", rest_length=rl, force_density=fd[i])
    assert np.array_equal(q[-1], ref.q)


def test_adaptive_restarts_where_commands_change():
    """dop853: the same as integrating each run of constant commands on its own."""
    model, st = _prism(B=1)
    tc, v = _commands(model)
    t, q, _ = simulate(model, st, DT, 40, "dop853", record_every=10, rest_length=Schedule(tc, v))
    ref = st
    for a, b, i in ((0, 11, 0), (11, 20, 1), (20, 34, 2), (34, 40, 3)):   # steps from 11, 20, 34 ms on
        ref = step(model, ref, (b - a) * DT, "dop853", rest_length=v[i])
    np.testing.assert_allclose(q[-1], ref.q, rtol=0, atol=1e-9)
    assert t.shape == (5,)


def test_constant_schedule_equals_constant_input():
    model, st = _prism()
    L = 0.97 * model.rest_length
    _, q1, qd1 = simulate(model, st, DT, 30, "rk4", record_every=3, rest_length=Schedule([0.0], [L]))
    _, q2, qd2 = simulate(model, st, DT, 30, "rk4", record_every=3, rest_length=L)
    assert np.array_equal(q1, q2) and np.array_equal(qd1, qd2)


@pytest.mark.parametrize("t, v, name, pattern", [
    ([0.0, 0.1, 0.1], np.ones((3, 9)), "rest_length", r"t\[2\] = 0.1 s is not after t\[1\] = 0.1 s"),
    ([0.0, np.nan], np.ones((2, 9)), "rest_length", r"t\[1\] is nan"),
    ([0.0, 0.1], np.ones((3, 9)), "rest_length", r"values must have shape \(2, m\)"),
    ([0.0, 0.1], [[1.0] * 9, [1.0] * 8 + [-0.5]], "rest_length", r"row 1 \(t = 0.1 s\), string 8 is -0.5"),
    ([0.0], [[np.inf] * 9], "force_density", r"row 0 \(t = 0 s\), string 0 is inf; must be finite"),
    ([], np.ones((0, 9)), "rest_length", "non-empty"),
    ([0.0], np.ones((1, 9)), "stiffness", "name must be"),
])
def test_schedule_bad_input(t, v, name, pattern):
    with pytest.raises(ValueError, match=pattern):
        Schedule(t, v, name)


def test_schedule_errors_at_run_time():
    model, st = _prism()
    with pytest.raises(ValueError, match=r"first command is at t = 0.01 s, after the run's start at t = 0 s"):
        simulate(model, st, DT, 20, rest_length=Schedule([0.01], [model.rest_length]))
    with pytest.raises(ValueError, match=r"shape \(C, 9\) or \(C, 2, 9\)"):
        simulate(model, st, DT, 20, rest_length=Schedule([0.0], np.ones((1, 3, 9))))
    with pytest.raises(ValueError, match="force_density: got a Schedule of rest_length"):
        simulate(model, st, DT, 20, force_density=Schedule([0.0], [model.rest_length]))


# ------------------------------------------------------------------ command line
def _write_commands(tmp_path, L):
    t = np.arange(0.0, 0.6, 0.02)
    rl = L[None] * (1 + 0.05 * np.sin(2 * np.pi * 1.5 * t)[:, None] * (np.arange(9) % 3 == 0))
    np.savez(tmp_path / "cmds.npz", t=t, rest_length=rl)
    with open(tmp_path / "cmds.csv", "w") as f:
        f.write("t," + ",".join(f"l{i}" for i in range(9)) + "\n")
        for ti, r in zip(t, rl):
            f.write(",".join(repr(float(x)) for x in (ti, *r)) + "\n")
    return t, rl


def test_cli_simulate_replays_commands_and_identify_recovers_stiffness(tmp_path):
    """simulate a robot 20 % stiffer than the nominal prism under replayed cable commands, then
    identify the stiffness from the recording (which carries the commands per record)."""
    s = tg.prism(3)
    L = s.rest_length
    _write_commands(tmp_path, L)
    tg.save_json(s.replace(stiffness=1.2 * s.stiffness), tmp_path / "robot.json")
    rec = tmp_path / "rec.npz"
    argv = ["simulate", str(tmp_path / "robot.json"), "--duration", "0.6", "--dt", "1e-3", "--record-every", "10",
            "--no-progress", "--out"]
    assert main(argv + [str(rec), "--rest-length", str(tmp_path / "cmds.npz")]) == 0
    assert main(argv + [str(tmp_path / "rec_csv.npz"), "--rest-length", str(tmp_path / "cmds.csv")]) == 0
    d, d2 = np.load(rec), np.load(tmp_path / "rec_csv.npz")
    assert np.array_equal(d["nodes"], d2["nodes"])
    assert d["rest_length"].shape == (61, 9)
    assert np.array_equal(d["rest_length"][2], d["rest_length"][3])      # the command of 0.02 s holds to 0.04 s
    assert not np.allclose(d["nodes"][-1], d["nodes"][0])                 # the commands moved it
    fit = tmp_path / "fit.json"
    assert main(["identify", "prism3", str(rec), "--fit", "stiffness", "--scale", "--out", str(fit)]) == 0
    k = np.array(json.loads(fit.read_text())["values"]["stiffness"])
    np.testing.assert_allclose(k, 1.2 * s.stiffness, rtol=1e-4)


def test_cli_simulate_command_file_errors(tmp_path, capsys):
    L = tg.prism(3).rest_length
    _write_commands(tmp_path, L)
    np.savez(tmp_path / "short.npz", t=[0.0, 0.1], rest_length=np.ones((2, 8)))
    np.savez(tmp_path / "late.npz", t=[0.05], rest_length=[L])
    base = ["simulate", "prism3", "--duration", "0.05", "--no-progress", "--out", str(tmp_path / "o.npz"),
            "--force"]
    cases = [
        (["--rest-length", str(tmp_path / "missing.npz")], 3, "not found"),
        (["--rest-length", str(tmp_path / "short.npz")], 3, r"rest_length must have shape \(C, 9\)"),
        (["--force-density", str(tmp_path / "cmds.npz")], 3, r"no array 'force_density'"),
        (["--rest-length", str(tmp_path / "cmds.npz"), "--backend", "torch"], 2, "--backend auto or numba"),
        (["--rest-length", str(tmp_path / "late.npz")], 3, r"first command is at t = 0.05 s"),
    ]
    for extra, code, pattern in cases:
        got = main(base + extra)
        err = capsys.readouterr().err
        assert got == code, (extra, got, err)
        assert "Traceback" not in err and re.search(pattern, err), (extra, err)


# ------------------------------------------------------------------ fuzzing (hypothesis)
from hypothesis import given, settings, strategies as hst  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

_MODEL = compile_model(tg.prism(3))
_floats = hst.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=60, deadline=None)
@given(t=hnp.arrays(np.float64, hst.integers(0, 4), elements=_floats),
       v=hnp.arrays(np.float64, hst.tuples(hst.integers(0, 4), hst.integers(7, 10)), elements=_floats),
       name=hst.sampled_from(["rest_length", "force_density"]))
def test_schedule_fuzz_valid_or_value_error(t, v, name):
    """Any times and values: a Schedule that simulates to finite states, or a ValueError; never
    another exception, never a NaN in the output."""
    try:
        sched = Schedule(t, v, name)
    except ValueError:
        return
    state = initial_state(_MODEL, 1)
    try:
        _, q, qd = simulate(_MODEL, state, DT, 5, "semi_implicit_euler", **{name: sched})
    except (ValueError, SimulationDiverged):
        return
    assert np.isfinite(q).all() and np.isfinite(qd).all()


@settings(max_examples=60, deadline=None)
@given(times=hnp.arrays(np.float64, hst.integers(1, 5), elements=hst.floats(0.0, 0.02), unique=True),
       scale=hnp.arrays(np.float64, 5, elements=hst.floats(0.9, 1.05)),
       every=hst.integers(1, 6), n=hst.integers(0, 25))
def test_schedule_fuzz_equals_step_by_step(times, scale, every, n):
    """Random command times (anywhere, also inside steps) and record grids: simulate equals
    stepping one step at a time, bit for bit."""
    tc = np.sort(times)
    tc[0] = 0.0
    tc = np.unique(tc)
    v = _MODEL.rest_length[None] * scale[:tc.size, None]
    model, st = _prism(B=1)
    _, q, qd = simulate(model, st, DT, n, "rk4", record_every=every, rest_length=Schedule(tc, v))
    Q, QD = _manual(model, st, tc, v, n, "rk4", every)
    assert np.array_equal(q, Q) and np.array_equal(qd, QD)
