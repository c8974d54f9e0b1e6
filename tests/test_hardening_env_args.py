"""Env constructor arguments and actions: a clear ValueError naming the
argument and the value, or a finite result, nothing else.

CASES lists constructor arguments with the message each must give; a ``dt`` above the estimated
stability limit is refused unless ``allow_unstable_dt=True``. The hypothesis tests throw NaN,
inf, huge, wrong-shape and non-numeric actions at both envs."""
from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra import numpy as hnp

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.core.errors import StabilityWarning

SHAPE, ROLL = "TensegrityShape-v0", "TensegrityRoll-v0"

# (id, env id, constructor kwargs, regex of the ValueError)
CASES = [
    ("roll-dt-0.2", ROLL, dict(dt=0.2), r"dt: 0.2 s is above the estimated stability limit 0.00\d+ s of "
                                        r"semi_implicit_euler .* or allow_unstable_dt=True"),
    # strings and bools are not numbers (they were converted: "1e-3" -> 0.001, True -> 1.0)
    ("shape-dt-string", SHAPE, dict(dt="1e-3"), r"dt: expected a number in s, got '1e-3'"),
    ("roll-speed-bool", ROLL, dict(max_cable_speed=True), r"max_cable_speed: expected a number in m/s, got True"),
    ("shape-weight-string", SHAPE, dict(tracking_weight="10"), r"tracking_weight: expected a number in 1/m, got '10'"),
    # huge string damping: named as the cause (was "settling diverged" / "all strings are slack")
    ("roll-string-damping-1e4", ROLL, dict(string_damping=1e4),
     r"dt: 0.001 s is above the estimated stability limit .* \(strings up to 1000 N/m and 1e\+04 N s/m"),
    ("shape-string-damping-1e4", SHAPE, dict(string_damping=1e4),
     r"dt: 0.001 s is above the estimated stability limit .* \(strings up to 1000 N/m and 1e\+04 N s/m"),
    ("shape-dt-0.08", SHAPE, dict(dt=0.08), r"dt: 0.08 s is above the estimated stability limit 0.0\d+ s of "
                                            r"semi_implicit_euler .*allow_unstable_dt=True"),
    ("shape-rk4-dt-0.05", SHAPE, dict(dt=0.05, integrator="rk4"), r"dt: 0.05 s is above the estimated stability limit .* of rk4"),
    ("shape-dt-zero", SHAPE, dict(dt=0.0), r"dt: must be positive and finite \(s\), got 0.0"),
    ("shape-width-zero", SHAPE, dict(render_mode="rgb_array", width=0), r"width: must be an integer number of pixels in 1..8192, got 0"),
    ("roll-height-huge", ROLL, dict(render_mode="rgb_array", height=10**9), r"height: must be an integer number of pixels in 1..8192, got 1000000000"),
    ("roll-width-float", ROLL, dict(width=480.5), r"width: must be an integer number of pixels"),
    ("shape-bounds-text", SHAPE, dict(rest_length_bounds="ab"), r"rest_length_bounds: expected two numbers \(low, high\), got 'ab'"),
    ("roll-bounds-order", ROLL, dict(rest_length_bounds=(1.2, 0.8)), r"rest_length_bounds: need 0 < low <= 1 <= high"),
    ("shape-dt-negative", SHAPE, dict(dt=-1e-3), r"dt: must be positive and finite \(s\), got -0.001"),
    ("shape-dt-nan", SHAPE, dict(dt=math.nan), r"dt: must be positive and finite \(s\), got nan"),
    ("shape-dt-inf", SHAPE, dict(dt=math.inf), r"dt: must be positive and finite \(s\), got inf"),
    ("shape-dt-text", SHAPE, dict(dt="fast"), r"dt: expected a number in s, got 'fast'"),
    ("roll-dt-nan", ROLL, dict(dt=math.nan), r"dt: must be positive and finite \(s\), got nan"),
    ("shape-frame-skip-0", SHAPE, dict(frame_skip=0), r"frame_skip: must be an integer >= 1 \(physics steps per action\), got 0"),
    ("shape-frame-skip-float", SHAPE, dict(frame_skip=1.5), r"frame_skip: must be an integer >= 1 .*, got 1.5"),
    # named, not NumPy's/Python's anonymous conversion errors
    ("roll-frame-skip-text", ROLL, dict(frame_skip="abc"), r"frame_skip: must be an integer >= 1 .*, got 'abc'"),
    ("shape-frame-skip-nan", SHAPE, dict(frame_skip=math.nan), r"frame_skip: must be an integer >= 1 .*, got nan"),
    ("roll-delay-text", ROLL, dict(action_delay="abc"), r"action_delay: must be an integer >= 0 \(control steps\), got 'abc'"),
    ("shape-delay-nan", SHAPE, dict(action_delay=math.nan), r"action_delay: must be an integer >= 0 .*, got nan"),
    ("roll-offset-text", ROLL, dict(start_rest_length_offset="abc"), r"start_rest_length_offset: expected an array of real numbers with shape \(\), got 'abc'"),
    ("shape-offset-shape", SHAPE, dict(start_rest_length_offset=[0.01, 0.02]), r"start_rest_length_offset: expected shape \(9,\), got \(2,\)"),
    ("roll-goal-text", ROLL, dict(goal_direction="abc"), r"goal_direction: expected an array of real numbers with shape \(2,\), got 'abc'"),
    ("roll-actuated-text", ROLL, dict(actuated="abc"), r"actuated: string indices must be integers, got 'abc'"),
    ("roll-ground-stiffness", ROLL, dict(ground_stiffness=-1.0), r"ground_stiffness: must be positive and finite \(N/m\^exponent\), got -1.0"),
    ("roll-ground-damping-text", ROLL, dict(ground_damping="abc"), r"ground_damping: expected a number in s/m, got 'abc'"),
    ("roll-cap-radius-nan", ROLL, dict(cap_radius=math.nan), r"cap_radius: must be >= 0 and finite \(m\), got nan"),
    ("roll-max-damping-text", ROLL, dict(ground_max_damping="abc"), r"ground_max_damping: expected a number \(N s/m\), got 'abc'"),
    # flags: a string such as "false" would count as true
    ("shape-clip-text", SHAPE, dict(clip_actions="false"), r"clip_actions: must be True or False, got 'false'"),
    ("roll-unstable-dt-number", ROLL, dict(allow_unstable_dt=-1.0), r"allow_unstable_dt: must be True or False, got -1.0"),
    ("shape-unstable-dt-text", SHAPE, dict(allow_unstable_dt="yes"), r"allow_unstable_dt: must be True or False, got 'yes'"),
    ("roll-randomize-goal-text", ROLL, dict(randomize_goal="no"), r"randomize_goal: must be True or False, got 'no'"),
    # force-density limits in rest-length mode were accepted and never used
    ("shape-fd-max-rest-length", SHAPE, dict(force_density_max=5.0), r"force_density_max: only with action_mode='force_density'"),
    ("roll-fd-rate-rest-length", ROLL, dict(force_density_rate="abc"), r"force_density_rate: only with action_mode='force_density'"),
    ("shape-fd-max-nan", SHAPE, dict(action_mode="force_density", force_density_max=math.nan), r"force_density_max: must be positive and finite"),
    ("shape-adaptive", SHAPE, dict(integrator="dop853"), r"integrator: 'dop853' is adaptive; envs need a fixed-step method"),
    ("shape-integrator-unknown", SHAPE, dict(integrator="leapfrog"), r"integrator: unknown name 'leapfrog'"),
    ("shape-backend", SHAPE, dict(backend="gpu"), r"backend: unknown 'gpu'"),
    ("shape-backend-numpy", SHAPE, dict(backend="numpy"), r"backend: 'numpy' is no longer a backend.*tests/oracle_numpy.py"),
    ("shape-action-mode", SHAPE, dict(action_mode="torque"), r"action_mode: unknown 'torque'"),
    ("roll-damping-negative", ROLL, dict(string_damping=-1.0), r"string_damping: must be >= 0 and finite \(N s/m\), got -1.0"),
]


@pytest.mark.parametrize("case_id, env_id, kwargs, pattern", CASES, ids=[c[0] for c in CASES])
def test_bad_constructor_argument(case_id, env_id, kwargs, pattern):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")        # the settling of a roll env at a huge dt warns first
        with pytest.raises(ValueError, match=pattern):
            gym.make(env_id, **kwargs)


def test_default_dt_accepted_without_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error", StabilityWarning)
        gym.make(SHAPE).close()
        gym.make(ROLL).close()


def test_unstable_dt_allowed_on_request():
    with pytest.warns(StabilityWarning, match="stability limit"):
        env = gym.make(ROLL, dt=2.8e-3, frame_skip=7, allow_unstable_dt=True)
    env.close()
    env = gym.make(SHAPE, dt=0.08, frame_skip=1, allow_unstable_dt=True)
    env.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(30):
            obs, r, term, trunc, info = env.step(np.ones(env.action_space.shape))
            assert np.all(np.isfinite(obs)) and np.isfinite(r)      # diverged copies are truncated, finite
            if trunc:
                break


# ---------------------------------------------------------------------- actions
_ENVS: dict = {}


def _env(env_id):
    if env_id not in _ENVS:
        env = gym.make(env_id)
        env.reset(seed=0)
        _ENVS[env_id] = env
    return _ENVS[env_id]


_special = st.sampled_from([np.nan, np.inf, -np.inf, 1e308, -1e308, 1e30, 2.0, -1.0, 0.0, 1.0])
_action = st.one_of(
    hnp.arrays(np.float64, st.sampled_from([(9,), (12,), (3,), (9, 1), (1, 9), (0,), ()]),
               elements=st.one_of(_special, st.floats(-2, 2))),
    hnp.arrays(np.float32, st.just((9,)), elements=st.floats(width=32)),
    st.lists(st.one_of(_special, st.floats(-1, 1)), min_size=0, max_size=13),
    st.sampled_from(["up", None, [["a"] * 9], {"a": 1}, [True] * 9, np.zeros(9, dtype=complex)]))


def _step_clear_or_finite(env, action):
    try:
        obs, r, term, trunc, info = env.step(action)
    except ValueError as e:
        assert str(e) and "\n" not in str(e)
        return
    assert np.all(np.isfinite(obs)) and np.isfinite(r)
    if term or trunc:
        env.reset(seed=1)


@settings(max_examples=80, deadline=None)
@given(action=_action)
def test_shape_env_actions(action):
    _step_clear_or_finite(_env(SHAPE), action)


@settings(max_examples=50, deadline=None)
@given(action=_action)
def test_roll_env_actions(action):
    env = _env(ROLL)
    if isinstance(action, np.ndarray) and action.shape == (9,):
        action = np.resize(action, env.action_space.shape)
    _step_clear_or_finite(env, action)


def test_named_action_errors():
    env = _env(SHAPE)
    with pytest.raises(ValueError, match=r"action: entry 2 is (np.float64\()?nan\)?; actions must be finite numbers in \[-1, 1\]"):
        env.step(np.array([0, 0, np.nan, 0, 0, 0, 0, 0, 0.0]))
    with pytest.raises(ValueError, match=r"action: expected shape \(9,\), got \(3,\)"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match=r"action: expected an array of real numbers with shape \(9,\), got 'up'"):
        env.step("up")
    # complex actions: NumPy would drop the imaginary part with only a ComplexWarning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"action: expected an array of real numbers with shape \(9,\)"):
            env.step(np.full(9, 0.5 + 0.5j))


def test_vector_env_arguments_and_options_are_named():
    """max_episode_steps, num_envs and a non-dict ``options`` get a ValueError naming them
    (were int()'s anonymous message and "'int' object is not iterable")."""
    V = dict(vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError, match=r"max_episode_steps: must be an integer >= 1 \(control steps; or None\), got 'abc'"):
        gym.make_vec(SHAPE, num_envs=2, max_episode_steps="abc", **V)
    with pytest.raises(ValueError, match=r"num_envs: must be an integer >= 1 \(copies\), got 0"):
        gym.make_vec(ROLL, num_envs=0, **V)
    venv = gym.make_vec(SHAPE, num_envs=2, max_episode_steps=5.0, **V)   # an integral float is a count
    assert venv.max_episode_steps == 5
    with pytest.raises(ValueError, match=r"options: expected a dict or None, got 5"):
        venv.reset(seed=0, options=5)
    with pytest.raises(ValueError, match=r"options: expected a dict or None, got \['x'\]"):
        _env(SHAPE).reset(seed=0, options=["x"])
    venv.close()


@pytest.mark.parametrize("env_id", [SHAPE, ROLL])
def test_unknown_reset_options_are_refused(env_id):
    """An option the env would silently ignore is an error naming it; reset_mask still works."""
    env = gym.make(env_id)
    with pytest.raises(ValueError, match=r"options: unknown key\(s\) \['goal_direction'\]; this env's reset takes "
                                         r"no options"):
        env.reset(seed=0, options={"goal_direction": [0.0, 1.0]})
    env.reset(seed=0, options={})
    venv = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
    venv.reset(seed=0, options={"reset_mask": np.array([True, False])})
    with pytest.raises(ValueError, match=r"options: unknown key\(s\) \['seed'\]"):
        venv.reset(options={"reset_mask": np.array([True, False]), "seed": 3})


VECTOR_KINDS = [(SHAPE, {}), (ROLL, {}), ("TensegrityClimb-v0", {"slope_range": (0.0, 20.0)}),
                ("TensegrityClimb-v0", {"slope_range": (0.0, 20.0), "backend": "torch", "device": "cpu"}),
                (SHAPE, {"backend": "torch", "device": "cpu"}),
                (ROLL, {"backend": "torch", "device": "cpu"}),
                (ROLL, {"backend": "torch", "device": "cpu", "reset_sampling": "device"})]


@pytest.mark.parametrize("env_id,kw", VECTOR_KINDS, ids=lambda x: x if isinstance(x, str) else
                         "-".join(str(v) for v in x.values()) or "numpy")
@pytest.mark.parametrize("observation_mode", ["state", "robot"])
def test_reset_mask_selecting_no_env_changes_nothing(env_id, kw, observation_mode):
    """A reset_mask that selects no env is a no-op (it crashed in the shape env's noise draw and in
    the robot observation's reset reading: reshapes of zero rows)."""
    if kw.get("backend") == "torch":
        pytest.importorskip("torch")
    venv = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point", observation_mode=observation_mode,
                        randomize={"rod_mass": 0.1}, **kw)
    o0, _ = venv.reset(seed=1)
    o1, info = venv.reset(options={"reset_mask": np.zeros(3, bool)})
    assert np.array_equal(np.asarray(o0), np.asarray(o1))
    assert not any(np.asarray(v).any() for k, v in info.items() if k.startswith("_"))


def test_step_inputs_name_field_index_and_value():
    """tensegrity_gym.step: a NaN/inf state, rest length, force density or external force, a
    negative rest length, or n_steps not a positive integer is a ValueError naming it (before: NaN
    rest lengths silently made strings slack, n_steps=0 still advanced t by dt, and 1.5 gave a bare
    TypeError)."""
    import tensegrity_gym as tg
    model = tg.compile_model(tg.prism(3))
    st0 = tg.initial_state(model, 2)
    rl = np.tile(model.rest_length, (2, 1))
    rl[1, 4] = np.nan
    for backend in ("auto", "numba"):
        with pytest.raises(ValueError, match=r"rest_length: entry \(1, 4\) is nan; must be finite and >= 0"):
            tg.step(model, st0, 1e-3, rest_length=rl, backend=backend)
    with pytest.raises(ValueError, match=r"backend: 'numpy' is no longer a backend"):
        tg.step(model, st0, 1e-3, backend="numpy")
    with pytest.raises(ValueError, match=r"rest_length: entry 2 is -0.5; must be finite and >= 0"):
        tg.step(model, st0, 1e-3, rest_length=np.r_[model.rest_length[:2], -0.5, model.rest_length[3:]])
    with pytest.raises(ValueError, match=r"force_density: entry 0 is inf; must be finite"):
        tg.step(model, st0, 1e-3, force_density=np.r_[np.inf, np.zeros(8)])
    ext = np.zeros((2, model.n_nodes, 3))
    ext[0, 5, 2] = np.nan
    with pytest.raises(ValueError, match=r"external: entry \(0, 5, 2\) is nan; must be finite"):
        tg.step(model, st0, 1e-3, external=ext)
    q = st0.q.copy()
    q[1, 2, 3] = np.inf
    with pytest.raises(ValueError, match=r"state.q: entry \(1, 2, 3\) is inf; must be finite"):
        tg.step(model, tg.State(q=q, qd=st0.qd), 1e-3, integrator="rk4")
    for n in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match=r"n_steps: must be a positive integer \(steps per call\), got"):
            tg.step(model, st0, 1e-3, n_steps=n)
    assert tg.step(model, st0, 1e-3, n_steps=np.int64(2)).t == pytest.approx(2e-3)
    # force densities may be negative (added to the strings' own, the sum clipped at 0)
    assert np.isfinite(tg.step(model, st0, 1e-3, force_density=-np.ones(9)).q).all()


def test_initial_state_checks_its_inputs():
    """initial_state: batch_size 0 gave an empty state and -1 NumPy's broadcast message; wrong
    node shapes, NaN nodes and coinciding rod ends are named."""
    import tensegrity_gym as tg
    model = tg.compile_model(tg.prism(3))
    for bad in (0, -1, 2.0, True):
        with pytest.raises(ValueError, match=r"batch_size: must be a positive integer \(copies\), got"):
            tg.initial_state(model, bad)
    with pytest.raises(ValueError, match=r"nodes: expected shape \(6, 3\) or \(B, 6, 3\), got \(5, 3\)"):
        tg.initial_state(model, nodes=np.zeros((5, 3)))
    nodes = model.structure.nodes.copy()
    nodes[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"nodes: entry \(2, 1\) is nan; must be finite"):
        tg.initial_state(model, nodes=nodes)
    with pytest.raises(ValueError, match=r"nodes: rod 0 \(nodes 0 and \d\) has zero length in copy 0"):
        tg.initial_state(model, nodes=np.zeros((6, 3)))
    with pytest.raises(ValueError, match=r"velocities: 2 copies for 3 copies of nodes"):
        tg.initial_state(model, nodes=np.tile(model.structure.nodes, (3, 1, 1)), velocities=np.zeros((2, 6, 3)))
    assert tg.initial_state(model, np.int64(3)).q.shape == (3, 3, 6)


# every constructor argument, five wrong values: a ValueError naming the argument, or (the pairs
# below) a valid value; nothing silently converted (e.g. "abc" taken as True), no anonymous error
_WRONG = ["abc", -1.0, math.nan, [1, 2], {"x": 1}]
_VALID = {("actuated", "[1, 2]"), ("rest_length_bounds", "[1, 2]"), ("goal_direction", "[1, 2]"),
          ("slope_range", "[1, 2]")}


def _arguments(fn):
    import inspect
    return [p.name for p in inspect.signature(fn).parameters.values()
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name not in ("self", "num_envs")]


@pytest.mark.parametrize("env_id", [SHAPE, ROLL, "TensegrityClimb-v0", "TensegrityRollMuJoCo-v0"])
def test_every_argument_refuses_wrong_values_by_name(env_id):
    env_cls = gym.envs.registration.load_env_creator(gym.spec(env_id).entry_point) \
        if env_id != "TensegrityRollMuJoCo-v0" else pytest.importorskip("tensegrity_gym.envs.roll_mujoco").TensegrityRollMuJoCoEnv
    if env_id == "TensegrityRollMuJoCo-v0":   # the twin's own arguments (the task's are covered above)
        names = [n for n in _arguments(env_cls) if n not in ("render_mode", "width", "height")]
    else:
        names = _arguments(env_cls.task_class)
        assert len(names) > 25
    problems = []
    for name in names:
        for value in _WRONG:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    env = gym.make(env_id, **{name: value})
                    env.reset(seed=0)
                    env.step(env.action_space.sample())
                    env.close()
                if (name, repr(value)) not in _VALID:
                    problems.append(f"{name}={value!r}: accepted")
            except ValueError as e:
                if not str(e).startswith(name) and f"{name}:" not in str(e) and f"{name}[" not in str(e):
                    problems.append(f"{name}={value!r}: message does not name it: {e}")
            except Exception as e:  # noqa: BLE001 -- anything else is a finding
                problems.append(f"{name}={value!r}: {type(e).__name__}: {e}")
    assert not problems, "\n".join(problems)
