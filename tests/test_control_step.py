"""pipeline.control_step: one control step from actions (actuation, contact, physics) as one pure
call, bit-identical to what the envs do per control step (they run the same two pipeline
pieces: Actuation.update, then the physics)."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.core import builders
from tensegrity_gym.physics.pipeline import control_step, step
from tensegrity_gym.physics.actuation import Actuation

RANDOM_ROLL = {"stiffness": 0.2, "rod_mass": 0.2, "rest_length_offset": 0.01, "friction": 0.3,
               "max_cable_speed": 0.2}


def _venv(env_id, n, seed, **kw):
    """A vector env of ``n`` copies reset with ``seed``, and its task."""
    env = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kw)
    env.reset(seed=seed)
    return env, env.unwrapped.task


def _env_and_control_step(env, task, action, **kw):
    """``(state before, ControlStep)``: control_step from the task's state with its actuation,
    robots and ``kw`` (contact), then ``env.step(action)``; the two agree bit for bit in the
    rod state and the controls."""
    state = State(task.q.copy(), task.qd.copy(), 0.0)
    speed = None if task.speed is None or task.speed.shape[1] == 0 else task.speed.copy()
    out = control_step(task.model, state, task.actuation, task.ctrl.copy(), action, task.dt,
                       task.integrator, n_steps=task.frame_skip, speed=speed, rest_offset=task.rest_offset,
                       params=task.params, **kw)
    env.step(action)
    assert np.array_equal(out.state.q, task.q) and np.array_equal(out.state.qd, task.qd)
    assert np.array_equal(out.controls, task.ctrl)
    return state, out


@pytest.mark.parametrize("randomize", [None, RANDOM_ROLL])
@pytest.mark.parametrize("motor", [True, False])
def test_roll_env_step_is_control_step(randomize, motor):
    """A roll vector env step (contact sub-steps, cable motor, per-copy robots and rest-length
    offsets) equals control_step from the same state, bit for bit."""
    kw = {} if motor else {"max_cable_acceleration": None}
    env, task = _venv("TensegrityRoll-v0", 5, 4, randomize=randomize, **kw)
    rng = np.random.default_rng(0)
    for _ in range(3):
        cs = task.cstate.copy()
        cs0 = cs.copy()
        action = rng.uniform(-1, 1, (5, task.action_size))
        state, out = _env_and_control_step(env, task, action, contact=task.contact, cstate=cs,
                                           contact_params=task._contact_prm)
        if motor:
            assert np.array_equal(out.speed, task.speed)
        else:
            assert out.speed is None
        assert np.array_equal(out.cstate.anchor, task.cstate.anchor)
        assert np.array_equal(out.cstate.active, task.cstate.active)
        # the inputs are untouched
        assert np.array_equal(cs.anchor, cs0.anchor) and np.array_equal(cs.active, cs0.active)
        assert not np.array_equal(state.q, out.state.q)
    env.close()


@pytest.mark.parametrize("mode", ["rest_length", "force_density"])
def test_shape_env_step_is_control_step(mode):
    """A shape vector env step (the fused compiled step in rest-length mode) equals control_step."""
    kw = {"node_damping": 10.0} if mode == "force_density" else {"randomize": {"rest_length_offset": 0.01}}
    env, task = _venv("TensegrityShape-v0", 4, 1, action_mode=mode, **kw)
    rng = np.random.default_rng(1)
    for _ in range(3):
        q0 = task.q.copy()
        state, out = _env_and_control_step(env, task, rng.uniform(-1, 1, (4, task.action_size)))
        assert out.cstate is None and np.array_equal(state.q, q0)
    env.close()


def _prism_actuation(max_accel=None):
    model = compile_model(builders.prism(3))
    act = Actuation("rest_length", [0, 1, 2], 0.5 * model.rest_length[:3], 1.1 * model.rest_length[:3], 0.2, 0.02,
                    model.rest_length, model.rest_length[:3], max_accel=max_accel)
    return model, act


def test_control_step_motor_matches_actuation_then_step():
    """With a motor: Actuation.update_motor, then pipeline.step with its physics inputs."""
    model, act = _prism_actuation(max_accel=2.0)
    B = 3
    state = initial_state(model, B)
    ctrl = np.tile(act.nominal, (B, 1))
    speed = np.zeros((B, 3))
    action = np.array([[1.0, -0.5, 0.2], [0.0, 1.0, -1.0], [-1.0, -1.0, 0.5]])
    out = control_step(model, state, act, ctrl, action, 1e-3, "rk4", n_steps=10, speed=speed)
    new, v, inputs = act.update_motor(ctrl, speed, action)
    ref = step(model, state, 1e-3, "rk4", n_steps=10, **inputs)
    assert np.array_equal(out.controls, new) and np.array_equal(out.speed, v)
    assert np.array_equal(out.state.q, ref.q) and np.array_equal(out.state.qd, ref.qd)
    assert out.state.t == pytest.approx(0.01)


def test_control_step_bad_input():
    model, act = _prism_actuation(max_accel=2.0)
    state = initial_state(model, 2)
    ctrl = np.tile(act.nominal, (2, 1))
    speed = np.zeros((2, 3))
    ok = np.zeros((2, 3))
    bad = ok.copy()
    bad[1, 2] = 1.5
    with pytest.raises(ValueError, match=r"action: entry \(1, 2\) is 1\.5, outside the action space \[-1, 1\]"):
        control_step(model, state, act, ctrl, bad, 1e-3, speed=speed)
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match=r"action: entry \(1, 2\) is (np.float64\()?nan\)?; actions must be finite"):
        control_step(model, state, act, ctrl, bad, 1e-3, speed=speed)
    with pytest.raises(ValueError, match=r"controls: expected shape \(2, 3\), got \(3,\)"):
        control_step(model, state, act, ctrl[0], ok, 1e-3, speed=speed)
    with pytest.raises(ValueError, match="speed: the motor model needs the cable speeds"):
        control_step(model, state, act, ctrl, ok, 1e-3)
    with pytest.raises(ValueError, match=r"rest_offset: expected shape \(1, 9\), got \(3, 9\)"):
        control_step(model, state, act, ctrl, ok, 1e-3, speed=speed, rest_offset=np.zeros((3, 9)))
    with pytest.raises(ValueError, match="dt"):
        control_step(model, state, act, ctrl, ok, -1.0, speed=speed)


from hypothesis import given, settings, strategies as hst  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402


@settings(max_examples=80, deadline=None)
@given(action=hnp.arrays(np.float64, hst.sampled_from([(2, 3), (3,), (2, 4), (1, 3)]),
                         elements=hst.floats(allow_nan=True, allow_infinity=True, width=64)))
def test_control_step_fuzz_action(action):
    """Any action array: a finite step within the bounds, or a ValueError naming ``action``."""
    model, act = _prism_actuation(max_accel=2.0)
    state = initial_state(model, 2)
    ctrl = np.tile(act.nominal, (2, 1))
    try:
        out = control_step(model, state, act, ctrl, action, 1e-3, speed=np.zeros((2, 3)))
    except ValueError as e:
        assert str(e).startswith("action: ")
        return
    assert np.isfinite(out.state.q).all() and np.isfinite(out.speed).all()
    assert (out.controls >= act.low).all() and (out.controls <= act.high).all()
