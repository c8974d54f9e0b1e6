"""The compiled per-step helpers (tensegrity_gym/physics/pipeline.py, tensegrity_gym/envs/compiled.py) and the small-array fast paths
give bit-identical results to the NumPy reference paths, and bad input still raises the same
errors."""
import numpy as np
import pytest

from tensegrity_gym import rewards
from tensegrity_gym.physics.pipeline import diverged
from tensegrity_gym.envs import compiled
from tensegrity_gym.envs.common import check_action
from tensegrity_gym.envs.shape import TensegrityShapeEnv, TensegrityShapeVectorEnv

import oracle_numpy as oracle

#: the NumPy references of the compiled bookkeeping (tests/oracle_numpy.py) inside the block
reference = oracle.reference_paths


def same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


@pytest.mark.parametrize("mode", ["rest_length", "force_density"])
def test_shape_env_fast_path_is_bit_identical(mode):
    fast = TensegrityShapeEnv(action_mode=mode)
    with reference():
        ref = TensegrityShapeEnv(action_mode=mode)
    assert fast.task._obs_rod is not None and ref.task._obs_rod is None
    rng = np.random.default_rng(3)
    o1, i1 = fast.reset(seed=7)
    with reference():
        o2, i2 = ref.reset(seed=7)
    assert same(o1, o2) and i1 == i2
    for t in range(40):
        a = rng.uniform(-1.5, 1.5, 9)                      # some entries outside the box: clipped
        a = a.astype(np.float32) if t % 2 else a
        r1 = fast.step(a)
        with reference():
            r2 = ref.step(a)
        assert same(r1[0], r2[0]), t
        assert r1[1:4] == r2[1:4], t
        assert r1[4] == r2[4] and all(type(r1[4][k]) is type(r2[4][k]) for k in r1[4]), t
    assert fast.task._fused and ref.task._fused is False     # the fused step ran (see below)


@pytest.mark.parametrize("mode", ["rest_length", "force_density"])
@pytest.mark.parametrize("num_envs", [1, 3])
@pytest.mark.parametrize("divergence_limit", [None, 0.3])
def test_shape_fused_step_is_bit_identical(mode, num_envs, divergence_limit):
    """ShapeTask's fused step (one compiled call: control update, physics kernel, divergence
    check, observation, errors; compiled.shape_step) against the unfused path (physics.step
    and the separate compiled helpers): same observations, rewards, infos and state, bit for
    bit, including steps where a copy diverges (a 0.3 m limit: some copies leave it)."""
    kw = dict(action_mode=mode, divergence_limit=divergence_limit)
    envs = [TensegrityShapeVectorEnv(num_envs=num_envs, max_episode_steps=None, **kw) for _ in range(2)]
    envs[1].task._fused = False                            # the unfused path
    rng = np.random.default_rng(5)
    outs = [e.reset(seed=2) for e in envs]
    assert same(outs[0][0], outs[1][0])
    n_div = 0
    for t in range(30):
        A = rng.uniform(-1.5, 1.5, (num_envs, 9))
        A = A.astype(np.float32) if t % 2 else A
        r1, r2 = (e.step(A) for e in envs)
        for x, y in zip(r1[:4], r2[:4]):
            assert same(x, y), t
        assert r1[4].keys() == r2[4].keys() and all(same(r1[4][k], r2[4][k]) for k in r1[4]), t
        for nm in ("q", "qd", "ctrl", "elapsed"):
            assert same(getattr(envs[0].task, nm), getattr(envs[1].task, nm)), (t, nm)
        n_div += int(r1[4]["diverged"].sum())
    assert envs[0].task._fused and envs[1].task._fused is False
    if divergence_limit is not None:
        assert n_div > 0                                   # the diverged branch ran
    # single env: the same through TaskEnv, and a foreign action type falls back unchanged
    e1, e2 = TensegrityShapeEnv(**kw), TensegrityShapeEnv(**kw)
    e2.task._fused = False
    assert same(e1.reset(seed=4)[0], e2.reset(seed=4)[0])
    for t in range(10):
        a = rng.uniform(-1, 1, 9)
        r1, r2 = e1.step(a), e2.step(a)
        assert same(r1[0], r2[0]) and r1[1:] == r2[1:], t
    assert e1.task.step(np.zeros((1, 18))[:, ::2]) is not None    # a strided action: reference path


@pytest.mark.parametrize("mode", ["rest_length", "force_density"])
@pytest.mark.parametrize("robot", [dict(params={"rest_length_offset": 0.004}),
                                   dict(randomize={"rest_length_offset": 0.005, "stiffness": 0.2})])
def test_shape_fused_step_with_rest_length_offsets(mode, robot):
    """A single env whose robot has rest-length offsets (fixed, or drawn at every reset) keeps the
    fused step (the offsets added inside it, as BatchedTask.with_offset adds them) and matches
    the unfused path bit for bit; a vector env with per-copy offsets runs the unfused path."""
    e1, e2 = TensegrityShapeEnv(action_mode=mode, **robot), TensegrityShapeEnv(action_mode=mode, **robot)
    e2.task._fused = False
    calls = []
    fz = e1.task._fused_setup()
    e1.task._fused = (lambda *x: calls.append(1) or fz[0](*x),) + fz[1:]
    for seed in (4, 5):                                    # a second reset redraws the randomised robot
        assert same(e1.reset(seed=seed)[0], e2.reset(seed=seed)[0])
        rng = np.random.default_rng(seed)
        for t in range(8):
            a = rng.uniform(-1, 1, 9)
            r1, r2 = e1.step(a), e2.step(a)
            assert same(r1[0], r2[0]) and r1[1:] == r2[1:], (seed, t)
            assert same(e1.task.q, e2.task.q), (seed, t)
    assert e1.task.rest_offset is not None and len(calls) == 16        # every step fused
    v = TensegrityShapeVectorEnv(num_envs=3, max_episode_steps=None, action_mode=mode,
                                 randomize={"rest_length_offset": 0.005})
    v.reset(seed=0)
    v.step(np.zeros((3, 9)))
    assert v.task._fused and v.task._fused_step(v.task._fused, np.zeros((3, 9))) is None   # per-copy: unfused


def _assert_same_step(r1, r2, t):
    """Two vector-env ``step`` results (obs, reward, terminated, truncated, info) are bit-identical."""
    for x, y in zip(r1[:4], r2[:4]):
        assert same(x, y), t
    assert r1[4].keys() == r2[4].keys()
    for k in r1[4]:
        assert same(r1[4][k], r2[4][k]), (t, k)


def test_shape_vector_env_fast_path_is_bit_identical():
    fast = TensegrityShapeVectorEnv(num_envs=3, max_episode_steps=5)
    with reference():
        ref = TensegrityShapeVectorEnv(num_envs=3, max_episode_steps=5)
    o1, _ = fast.reset(seed=1)
    with reference():
        o2, _ = ref.reset(seed=1)
    assert same(o1, o2)
    rng = np.random.default_rng(0)
    for t in range(12):
        A = rng.uniform(-1.2, 1.2, (3, 9))
        r1 = fast.step(A)
        with reference():
            r2 = ref.step(A)
        _assert_same_step(r1, r2, t)


def test_tolerance_one_element_fast_path_is_bit_identical():
    xs = np.concatenate([np.linspace(-0.3, 0.3, 601), [0.0, 0.01, 0.0100000001, -1e-300, 1e300, np.inf,
                                                        -np.inf, np.nan]])
    for bounds, margin, v in [((0.0, 0.01), 0.1, 0.1), ((-0.02, 0.01), 0.03, 0.3), ((0.0, 0.0), 1e-3, 0.5)]:
        full = rewards.tolerance(xs, bounds, margin=margin, value_at_margin=v)
        for x, y in zip(xs, full):
            one = rewards.tolerance(np.array([x]), bounds, margin=margin, value_at_margin=v)
            assert one.shape == (1,) and same(one[0], y), (x, bounds)
            zero_d = rewards.tolerance(x, bounds, margin=margin, value_at_margin=v)
            assert zero_d.shape == () and same(zero_d, y)
    with pytest.raises(ValueError, match="value_at_margin"):
        rewards.tolerance(np.array([0.0]), (0.0, 1.0), margin=1.0, value_at_margin=1.5)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_check_action_fast_path(dtype):
    a = np.array([0.5, -2.0, 1.0 + 1e-7, 0.25], dtype)
    out = check_action(a, (4,))
    with reference():
        ref = check_action(a, (4,))
    assert same(out, ref) and out is not a
    for bad, msg in [(np.nan, "entry 2 is .*nan"), (np.inf, "entry 2 is .*inf")]:
        b = a.copy()
        b[2] = bad
        with pytest.raises(ValueError, match=msg):
            check_action(b, (4,))
    with pytest.raises(ValueError, match="entry 1 is -2"):
        check_action(a, (4,), clip=False)
    ok = np.array([0.5, -1.0 - 1e-7, 1.0], dtype)
    if dtype == np.float64:
        assert same(check_action(ok, (3,), clip=False), np.array([0.5, -1.0, 1.0]))
    A = np.zeros((2, 3), dtype)
    A[1, 2] = np.nan
    with pytest.raises(ValueError, match=r"entry \(1, 2\)"):
        check_action(A, (2, 3), name="actions")
    with pytest.raises(ValueError, match="shape"):
        check_action(np.zeros(5, dtype), (4,))


@pytest.mark.parametrize("num_envs", [1, 3])
def test_roll_env_fast_path_is_bit_identical(num_envs):
    from tensegrity_gym.envs.roll import TensegrityRollEnv, TensegrityRollVectorEnv
    make = (lambda: TensegrityRollEnv()) if num_envs == 1 else \
        (lambda: TensegrityRollVectorEnv(num_envs=num_envs, max_episode_steps=7))
    fast = make()
    with reference():
        ref = make()
    o1, _ = fast.reset(seed=2)
    with reference():
        o2, _ = ref.reset(seed=2)
    assert same(o1, o2)
    shape = fast.action_space.shape
    rng = np.random.default_rng(1)
    for t in range(15):
        a = rng.uniform(-1.3, 1.3, shape)
        r1 = fast.step(a)
        with reference():
            r2 = ref.step(a)
        _assert_same_step(r1, r2, t)


def test_mean_max_matches_numpy_reductions():
    rng = np.random.default_rng(4)
    for nt in range(1, 12):
        for B in (1, 3, 64):
            d = np.abs(rng.normal(size=(B, nt))) * 10.0 ** rng.integers(-17, 1, size=(B, nt))
            mean, mx = np.empty(B), np.empty(B)
            done = compiled.mean_max(d, mean, mx)
            assert done == (nt < 8)
            if done:
                assert same(mean, d.mean(axis=1)) and same(mx, d.max(axis=1)), (nt, B)
    d = np.array([[0.1, np.nan, 0.3], [0.2, 0.1, 0.0]])
    mean, mx = np.empty(2), np.empty(2)
    assert compiled.mean_max(d, mean, mx)
    assert same(mean, d.mean(axis=1)) and same(mx, d.max(axis=1))


@pytest.mark.parametrize("kw", [dict(), dict(num_envs=20, integrator="rk4"),
                                dict(num_envs=5, randomize={"rod_mass": 0.1, "friction": 0.2}),
                                dict(observation_mode="robot"), dict(num_envs=12), dict(num_envs=70),
                                dict(num_envs=210, integrator="rk4"),
                                dict(num_envs=220, integrator="rk4", randomize={"rod_mass": 0.1, "friction": 0.2})])
def test_compiled_contact_loop_equals_python_loop(monkeypatch, kw):
    """pipeline.advance's contact steps in ONE compiled call (_contact_loop on this thread, or
    _contact_parallel on chunks of the batch when one sub-step has the parallel kernel's work:
    210 and 220 copies with RK4) give the same bits as its Python loop of contact.forces_inplace +
    the numba backend's step_inplace, and reuse the model's packed buffer (no repacking per control step)."""
    from tensegrity_gym.backends.numba import api as numba_api
    from tensegrity_gym.physics import pipeline as physics_pipeline
    from tensegrity_gym.envs.roll import TensegrityRollEnv, TensegrityRollVectorEnv
    n = kw.pop("num_envs", 1)
    make = (lambda: TensegrityRollEnv(**kw)) if n == 1 else \
        (lambda: TensegrityRollVectorEnv(num_envs=n, max_episode_steps=None, **kw))
    fused, loop = make(), make()
    calls = []
    for name in ("_contact_loop", "_contact_loop_simd", "_contact_parallel"):
        monkeypatch.setattr(numba_api, name, lambda *a, _f=getattr(numba_api, name), _n=name: calls.append(_n) or _f(*a))
    assert same(fused.reset(seed=1)[0], loop.reset(seed=1)[0])
    packed = []
    rng = np.random.default_rng(2)
    for t in range(6):
        a = rng.uniform(-1, 1, fused.action_space.shape)
        r1 = fused.step(a)
        with monkeypatch.context() as m:
            m.setattr(physics_pipeline, "_contact_compiled", lambda *x: False)     # the Python loop
            r2 = loop.step(a)
        assert same(r1[0], r2[0]) and same(r1[1], r2[1]), t
        ft, lt = fused.unwrapped.task, loop.unwrapped.task
        assert same(ft.cstate.anchor, lt.cstate.anchor) and same(ft.cstate.active, lt.cstate.active), t
        # the last sub-step's contact forces and slip flags, which the driver stores with the state
        assert same(ft._W, lt._W) and same(ft._slip, lt._slip), t
        packed.append(numba_api._CACHE.get(id(fused.unwrapped.task.model)))
    assert len(calls) == 6 * (2 if kw.get("observation_mode") == "robot" else 1)   # robot: IMUs split the last step
    expect = "_contact_parallel" if n >= 200 else "_contact_loop_simd" if n >= 16 else "_contact_loop"
    assert set(calls) == {expect}, (n, set(calls))
    assert packed[0] is not None and all(p is packed[0] for p in packed)


def test_contact_loop_is_compiled_once_for_copied_envs_and_per_copy_contact():
    """The compiled contact loop takes the model's and the contact's arrays read-only
    (backends.numba.api._frozen): a deep-copied env (whose model arrays deepcopy makes writable) and a
    randomised env (writable per-copy contact parameters) run the instance already compiled,
    not a second one of the loop driver (a minute of compilation on 2 cores), with the same bits."""
    import copy
    from tensegrity_gym.envs.roll import TensegrityRollEnv, TensegrityRollVectorEnv
    env = TensegrityRollEnv()
    env.reset(seed=4)
    a = np.linspace(-1, 1, env.action_space.shape[0])
    env.step(a)
    from tensegrity_gym.backends.numba.entries import _contact_loop
    n_sigs = len(_contact_loop.signatures)
    twin = copy.deepcopy(env)
    assert twin.unwrapped.task.model.eta.flags.writeable and not env.unwrapped.task.model.eta.flags.writeable
    r1, r2 = env.step(a), twin.step(a)
    assert same(r1[0], r2[0]) and r1[1] == r2[1]
    rnd = TensegrityRollVectorEnv(num_envs=2, max_episode_steps=None, randomize={"friction": 0.2, "ground_stiffness": 0.2})
    rnd.reset(seed=0)
    rnd.step(np.tile(a, (2, 1)))
    assert len(_contact_loop.signatures) == n_sigs


@pytest.mark.parametrize("mode", ["rest_length", "force_density"])
@pytest.mark.parametrize("per_copy", [False, True])
def test_actuation_update_matches_the_numpy_oracle(mode, per_copy):
    """Actuation.update_rate / update_motor (the compiled update, the package's only one) against
    the NumPy reference, bit for bit, with per-copy limits; any float array layout is accepted
    (float32, strided); a wrong shape is a ValueError naming the array."""
    from tensegrity_gym.physics.actuation import Actuation
    rng = np.random.default_rng(7)
    B, m = 12, 9
    act_idx = np.array([0, 2, 3, 7])
    acc = 2.0 if mode == "rest_length" else None
    act = Actuation(mode, act_idx, 0.1, 0.5, 0.2, 0.02, np.full(m, 0.3), 0.3, max_accel=acc)
    if per_copy:
        act.set_copy_limits(B, np.arange(B), max_rate=rng.uniform(0.1, 0.3, (B, 4)),
                            max_accel=rng.uniform(1, 3, B) if acc else None)
    ctrl = rng.uniform(0.1, 0.5, (B, 4))
    ctrl[:3] = 0.5
    speed = rng.uniform(-0.2, 0.2, (B, 4))
    for t in range(10):
        action = rng.choice([-1.0, 1.0, 0.4, -0.7], (B, 4))
        if acc:
            new, v, phys = act.update_motor(ctrl, speed, action)
            new_r, v_r = oracle.actuation_apply_motor(act, ctrl, speed, action)
            assert same(v, v_r), t
            speed = v
        else:
            new, phys = act.update_rate(ctrl, action)
            new_r = oracle.actuation_apply(act, ctrl, action)
        assert same(new, new_r), t
        ref_phys = act.physics_inputs(new_r)
        assert phys.keys() == ref_phys.keys(), t
        assert all((phys[k] is None and ref_phys[k] is None) or same(phys[k], ref_phys[k]) for k in phys), t
        ctrl = new
    wide = np.zeros((B, 8), np.float32)
    wide[:, ::2] = 0.5
    if acc:
        out = act.update_motor(ctrl, speed, wide[:, ::2])
        assert same(out[0], act.update_motor(ctrl, speed, np.full((B, 4), 0.5))[0])
        with pytest.raises(ValueError, match="speed"):
            act.update_motor(ctrl, speed[:, :3], wide[:, ::2])
    else:
        out = act.update_rate(ctrl, wide[:, ::2])
        assert same(out[0], act.update_rate(ctrl, np.full((B, 4), 0.5))[0])
    with pytest.raises(ValueError, match="action"):
        (act.update_motor(ctrl, speed, np.zeros((B, 3))) if acc else act.update_rate(ctrl, np.zeros((B, 3))))


@pytest.mark.parametrize("local", [False, True])
def test_diverged_matches_the_numpy_oracle(local):
    """pipeline.diverged (one compiled pass) flags exactly the copies the NumPy reference flags:
    NaN or inf in q or qd, a reference point beyond the limit (absolute, or from its copy's mean
    and that mean's height with ``local``); lists, float32 and strided arrays are accepted."""
    rng = np.random.default_rng(3)
    B, k, limit = 40, 3, 1.0
    center = np.array([0.1, -0.2, 0.3])
    q = rng.uniform(-0.5, 0.5, (B, k, 6))
    q[..., :3] += center
    qd = rng.normal(size=(B, k, 6))
    q[1, 0, 4] = np.nan
    qd[2, 2, 1] = np.inf
    q[3, 1, 0] += 4.0                    # one rod far off: beyond the limit either way
    q[4, :, 2] += 5.0                    # the whole copy lifted: off the centre and off the height
    q[5, :, 0] += 50.0                   # the whole copy travelled: only the absolute check flags it
    got = diverged(q, qd, center, limit, local)
    want = oracle.diverged(q, qd, center, limit, local)
    assert same(got, want) and got[[1, 2, 3, 4]].all() and got[5] == (not local) and not got[6:].any()
    assert same(diverged(q.astype(np.float32), qd.tolist(), list(center), limit, local),
                oracle.diverged(q.astype(np.float32), qd, center, limit, local))
    wide = np.zeros((B, k, 12))
    wide[..., ::2] = q
    assert same(diverged(wide[..., ::2], qd, center, limit, local), want)
    with pytest.raises(ValueError, match="shape"):
        diverged(q, qd[:, :2], center, limit, local)
