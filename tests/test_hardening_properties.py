"""Property-based tests (hypothesis) of the env constructor arguments, ``params`` / ``randomize``,
seeds and the CLI's file inputs: every example ends either in a clear error at construction (a
ValueError with a one-line message naming the argument) or in a finite run of 100 steps, nothing
else (no exception inside ``step``, no NaN/inf observation or reward, no hang)."""
from __future__ import annotations

import json
import math
import warnings

import gymnasium as gym
import numpy as np
from hypothesis import HealthCheck, event, given, settings, strategies as st

import tensegrity_gym as tg
from tensegrity_gym.tools.cli import main
from tensegrity_gym.envs.domain import SPECS

SHAPE, ROLL = "TensegrityShape-v0", "TensegrityRoll-v0"
FAST = settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)

plausible = st.sampled_from([0.05, 0.2, 0.5, 1.0, 5.0, 10.0, 100.0, 1000.0, 2000.0])
numbers = st.one_of(
    plausible, plausible,
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from([0.0, -0.0, 1e-12, 1e-6, 1e-3, 0.5, 0.99, 1.0, 2.0, 1e6, 1e9, 1e15, 1e39, -1.0]),
    st.integers(-3, 10), st.sampled_from(["0.1", "abc", None, True, [0.1, 0.2], {}]))
spreads = st.one_of(st.floats(min_value=0.0, max_value=0.99), st.sampled_from([1.0, 0.5, 2.0, -0.1, math.nan, "0.1"]))
ROLL_PARAMS = sorted(SPECS)
SHAPE_PARAMS = [n for n in SPECS if n not in ("friction", "ground_stiffness", "ground_damping", "max_cable_acceleration")]


def _run(env_id, kwargs, seed=0, steps=100):
    """A clear ValueError at construction, or 100 finite steps."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            env = gym.make(env_id, **kwargs)
        except ValueError as e:
            msg = str(e)
            assert msg and "\n" not in msg, msg
            event("refused at construction")
            return "refused"
        try:
            obs, _ = env.reset(seed=seed)
            assert np.all(np.isfinite(obs))
            rng = np.random.default_rng(seed)
            for _ in range(steps):
                obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
                assert np.all(np.isfinite(obs)) and math.isfinite(r), (kwargs, obs, r)
                if term or trunc:
                    obs, _ = env.reset()
                    assert np.all(np.isfinite(obs))
        finally:
            env.close()
    event("ran 100 finite steps")
    return "ran"


@FAST
@given(name=st.sampled_from(ROLL_PARAMS), value=numbers, rname=st.sampled_from(ROLL_PARAMS), spread=spreads,
       seed=st.integers(0, 2**32 - 1))
def test_roll_params_and_randomize(name, value, rname, spread, seed):
    _run(ROLL, dict(params={name: value}, randomize={rname: spread}, frame_skip=5), seed)


@FAST
@given(name=st.sampled_from(SHAPE_PARAMS), value=numbers, rname=st.sampled_from(SHAPE_PARAMS), spread=spreads,
       seed=st.integers(0, 2**32 - 1))
def test_shape_params_and_randomize(name, value, rname, spread, seed):
    _run(SHAPE, dict(params={name: value}, randomize={rname: spread}, frame_skip=5), seed)


@FAST
@given(dt=st.one_of(st.sampled_from([5e-4, 1e-3, 2e-3]), numbers), frame_skip=st.one_of(st.integers(1, 30), numbers),
       noise=numbers, history=st.one_of(st.integers(1, 4), numbers),
       mode=st.sampled_from(["state", "robot", "xyz"]))
def test_roll_constructor_arguments(dt, frame_skip, noise, history, mode):
    kw = dict(dt=dt, frame_skip=frame_skip, observation_mode=mode)
    if mode == "robot":
        kw.update(sensor_noise={"cable_length": noise}, history=history)
    _run(ROLL, kw)


@FAST
@given(seed=st.one_of(st.integers(-5, 2**64), st.floats(), st.booleans(), st.text(max_size=3),
                      st.lists(st.integers(-1, 5), max_size=4)))
def test_seeds_single_and_vector(seed):
    env = gym.make(SHAPE)
    try:
        env.reset(seed=seed)
    except (ValueError, TypeError, gym.error.Error) as e:
        assert str(e) and "\n" not in str(e).strip()
    else:
        for _ in range(5):
            assert np.all(np.isfinite(env.step(env.action_space.sample())[0]))
    env.close()
    v = gym.make_vec(SHAPE, num_envs=2, vectorization_mode="vector_entry_point")
    try:
        v.reset(seed=seed)
    except ValueError as e:
        assert "seed" in str(e)
    else:
        assert isinstance(seed, int) or isinstance(seed, list) and all(type(s) is int and s >= 0 for s in seed)
        assert np.all(np.isfinite(v.step(np.zeros((2,) + v.single_action_space.shape))[0]))
    v.close()


BASE = json.loads(json.dumps(tg.load_structure("prism3").to_dict()))
json_values = st.recursive(st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                                     st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=5)),
                           lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=4), c, max_size=3),
                           max_leaves=12)


@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(field=st.sampled_from(sorted(BASE)), value=st.one_of(json_values, st.sampled_from(sorted(BASE)).map(BASE.get)),
       raw=st.binary(max_size=64), use_raw=st.booleans())
def test_cli_structure_files(tmp_path_factory, capsys, field, value, raw, use_raw):
    p = tmp_path_factory.mktemp("s") / "s.json"
    if use_raw:
        p.write_bytes(raw)
    else:
        p.write_text(json.dumps(dict(BASE, **{field: value})))
    code = main(["info", str(p), "--no-stable-step"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert code in (0, 3, 5), (code, err)
    event(f"exit {code}")
    if code:
        lines = err.splitlines()
        assert lines[-1].startswith("error: ") and sum(x.startswith("error: ") for x in lines) == 1, err


@settings(max_examples=20, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(rows=st.lists(st.tuples(st.sampled_from(["0", "0.1", "inf", "nan", "-1", "1e400", "abc", "", "2.5", "5"]),
                               st.sampled_from(["0", "1", "inf", "nan", "-1", "6", "1.5", "abc", ""]),
                               st.sampled_from(["0", "1.5", "nan", "", "inf", "x"])), max_size=6),
       bom=st.booleans())
def test_cli_csv_trajectory_files(tmp_path_factory, capsys, rows, bom):
    d = tmp_path_factory.mktemp("c")
    text = "t,node,x,y,z\n" + "".join(f"{t},{n},{x},{x},{x}\n" for t, n, x in rows)
    (d / "a.csv").write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode())
    code = main(["identify", "prism3", str(d / "a.csv"), "--out", str(d / "fit.json"), "--stride", "1"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert code in (0, 3, 6), (code, err)
    event(f"exit {code}")
    if code:
        assert err.splitlines()[-1].startswith("error: "), err


arrays = st.sampled_from(["ok", "complex", "nan", "inf", "wrong_shape", "text", "empty", "int", "huge"])


def _array(kind, good):
    with np.errstate(all="ignore"):
        return _arrays_of(kind, good)


def _arrays_of(kind, good):
    return {"ok": good, "complex": good + 1j, "nan": np.where(np.arange(good.size).reshape(good.shape) == 1, np.nan, good),
            "inf": good * np.inf, "wrong_shape": good.reshape(-1)[:-1], "text": np.array(["a", "b"]),
            "empty": good[:0], "int": good.astype(np.int64), "huge": good * 1e300}[kind]


@settings(max_examples=80, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(t_kind=arrays, n_kind=arrays, command=st.sampled_from(["identify", "view"]))
def test_cli_npz_trajectory_files(tmp_path_factory, capsys, monkeypatch, t_kind, n_kind, command):
    from tensegrity_gym.tools import cli_commands
    monkeypatch.setattr(cli_commands, "view_trajectory", lambda *a, **k: None)   # no viewer is opened
    d = tmp_path_factory.mktemp("n")
    s = tg.load_structure("prism3")
    t = np.arange(6) * 0.01
    nodes = np.repeat(s.nodes[None], 6, axis=0)
    np.savez(d / "t.npz", t=_array(t_kind, t), nodes=_array(n_kind, nodes), bars=s.bars, strings=s.strings)
    argv = (["identify", "prism3", str(d / "t.npz"), "--out", str(d / "fit.json")] if command == "identify"
            else ["view", str(d / "t.npz"), "--structure", "prism3", "--mode", "browser"])
    code = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert code in (0, 3, 4, 5, 6), (code, err)
    event(f"{command} exit {code}")
    if code:
        lines = err.splitlines()
        assert lines[-1].startswith("error: ") and sum(x.startswith("error: ") for x in lines) == 1, err
