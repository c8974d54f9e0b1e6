"""CUDA graphs of the physics (``cuda_graph=True``, backends/torch/graphs.py): the wrapper's
layouts, copies and clones on any device (a stand-in capture that re-runs the function on the
buffers), the physics loops free of host reads (what a capture refuses), the argument's errors,
and on CUDA the graphed env equal to the compiled env, step for step."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tensegrity_gym.backends.torch.contact import contact_step, contact_substep  # noqa: E402
from tensegrity_gym.backends.torch.driver import step, step_once  # noqa: E402
from tensegrity_gym.backends.torch.graphs import SYNC_OPS, CapturedCall  # noqa: E402
from tensegrity_gym.backends.torch.terrain import terrain_step  # noqa: E402

CUDA = torch.cuda.is_available()


def rerun_capture(fn, args, kwargs, warmup):
    """A capture stand-in with a graph's semantics: fixed output buffers, rewritten from the
    input buffers at each replay."""
    out = fn(*args, **kwargs)
    outs = list(out) if isinstance(out, tuple) else [out]

    def replay():
        new = fn(*args, **kwargs)
        for o, n in zip(outs, list(new) if isinstance(new, tuple) else [new]):
            o.copy_(n)
    return replay, out


def roll_env(n=4, **kw):
    return gym.make_vec("TensegrityRoll-v0", num_envs=n, vectorization_mode="vector_entry_point", backend="torch",
                        **kw)


def physics_args(env):
    """The arguments of the flat roll env's physics call after one reset and a random control."""
    u = env.unwrapped
    task = u.task
    inputs = u._physics_inputs()
    kw = dict(rest_length=inputs.get("rest_length"), force_density=inputs.get("force_density"),
              params=u._params, contact_prm=u._contact_prm)
    return (u.tm, task.contact, u.q, u.qd, u.anchor, u.active, task.dt, task.integrator), kw


def test_captured_call_equals_the_function_and_copies_each_calls_inputs():
    env = roll_env()
    env.reset(seed=3)
    args, kw = physics_args(env)
    call = CapturedCall(contact_step, capture=rerun_capture)
    ref = contact_step(*args, 20, **kw)
    got = call(*args, 20, **kw)
    assert call.captures == 1
    for a, b in zip(ref, got):
        assert torch.equal(a, b)
    # new values, same layout: the same capture, the new inputs copied in
    q2 = args[2] + 1e-3
    args2 = args[:2] + (q2,) + args[3:]
    ref2 = contact_step(*args2, 20, **kw)
    got2 = call(*args2, 20, **kw)
    assert call.captures == 1
    for a, b in zip(ref2, got2):
        assert torch.equal(a, b)
    # the first results are clones: not rewritten by the later replay
    for a, b in zip(ref, got):
        assert torch.equal(a, b)
    # another layout (n_steps, a missing control): its own capture
    call(*args, 5, **kw)
    call(*args, 5, **dict(kw, force_density=None, rest_length=kw["rest_length"][:1]))
    assert call.captures == 3
    env.close()


def test_captured_call_accepts_inference_tensors_then_plain_ones():
    """rsl_rl steps the env under inference_mode, its evaluations under no_grad: the buffers
    made in the first call stay writable in the second."""
    env = roll_env()
    env.reset(seed=0)
    args, kw = physics_args(env)
    call = CapturedCall(contact_step, capture=rerun_capture)
    with torch.inference_mode():
        inf_args = tuple(a.clone() if isinstance(a, torch.Tensor) else a for a in args)
        call(*inf_args, 3, **kw)
    with torch.no_grad():
        got = call(*args, 3, **kw)
        ref = contact_step(*args, 3, **kw)
    for a, b in zip(ref, got):
        assert torch.equal(a, b)
    env.close()


def test_a_failed_capture_names_the_function_and_the_way_out():
    def refusing_capture(fn, args, kwargs, warmup):
        raise RuntimeError("operation not permitted when stream is capturing")
    call = CapturedCall(step_once, capture=refusing_capture)
    with pytest.raises(RuntimeError, match=r"cuda_graph: capturing step_once failed \(RuntimeError: operation not "
                                           r"permitted.*cuda_graph=False"):
        call(torch.zeros(2, 3))
    assert call.captures == 0


def host_reads(fn) -> set:
    """The aten operations of :data:`SYNC_OPS` that ``fn()`` dispatches."""
    from torch.profiler import ProfilerActivity, profile
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        fn()
    return {e.name for e in prof.events()} & SYNC_OPS


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "rk4"])
def test_flat_and_shape_physics_loops_read_nothing_back_from_the_device(integrator):
    env = roll_env(integrator=integrator)
    env.reset(seed=1)
    args, kw = physics_args(env)
    args = args[:-1] + (integrator,)
    assert host_reads(lambda: contact_step(*args, 4, **kw)) == set()
    shape = gym.make_vec("TensegrityShape-v0", num_envs=3, vectorization_mode="vector_entry_point", backend="torch")
    shape.reset(seed=0)
    u = shape.unwrapped
    inputs = u._physics_inputs()
    assert host_reads(lambda: step(u.tm, u.q, u.qd, u.task.dt, u.task.integrator, 4,
                                   rest_length=inputs.get("rest_length"),
                                   force_density=inputs.get("force_density"), params=u._params)) == set()
    env.close()
    shape.close()


@pytest.mark.parametrize("terrain", [
    {"generator": "rough", "size": 2.0, "cell": 0.05, "pad": 0.0},
    {"generator": "steps"},
    {"plane": {"slope_deg": 10.0}, "boxes": [{"center": [1.0, 0.0, 0.05], "size": [0.4, 0.4, 0.1]}]},
])
def test_terrain_physics_loop_compiled_reads_nothing_back(monkeypatch, terrain):
    """Under torch.compile the terrain loop takes no host read (the eager loop's heightfield
    bound and far-part skip do, which the check sees; cuda_graph therefore needs compile=True):
    checked on the code path taken while compiling."""
    env = roll_env(terrain=terrain)
    env.reset(seed=0)
    u = env.unwrapped
    inputs = u._physics_inputs()
    t = u._terrain
    if terrain.get("generator") == "rough":      # the eager heightfield loop reads its bound back: the check sees it
        assert "aten::_local_scalar_dense" in host_reads(
            lambda: terrain_step(u.tm, t.geom, u._terrain_prm, u.q, u.qd, t.anchor, t.eta0, t.active, u.task.dt,
                                 u.task.integrator, 1, rest_length=inputs.get("rest_length"), params=u._params,
                                 hf=t.hf, layout=t.layout))
    monkeypatch.setattr(torch.compiler, "is_compiling", lambda: True)
    run = lambda: terrain_step(u.tm, t.geom, u._terrain_prm, u.q, u.qd, t.anchor, t.eta0, t.active,  # noqa: E731
                               u.task.dt, u.task.integrator, 3, rest_length=inputs.get("rest_length"),
                               force_density=inputs.get("force_density"), params=u._params, hf=t.hf,
                               layout=t.layout)
    assert host_reads(run) == set()
    env.close()


def test_cuda_graph_argument_errors():
    with pytest.raises(ValueError, match="cuda_graph: expected True or False, got 'yes'"):
        roll_env(cuda_graph="yes")
    with pytest.raises(ValueError, match="cuda_graph: needs a CUDA device, got device='cpu'"):
        roll_env(device="cpu", compile=True, cuda_graph=True)
    with pytest.raises(ValueError, match="cuda_graph: only with backend='torch'"):
        gym.make_vec("TensegrityRoll-v0", num_envs=2, vectorization_mode="vector_entry_point", cuda_graph=True)
    if CUDA:
        with pytest.raises(ValueError, match="cuda_graph: needs compile=True"):
            roll_env(device="cuda", cuda_graph=True)


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
def test_captured_call_replays_the_compiled_physics_cuda():
    """A replay computes what the same compiled function computes on the same buffers: bit for
    bit where two direct calls agree bit for bit (deterministic kernels), else to round-off."""
    env = roll_env(n=64, device="cuda", dtype="float32")
    env.reset(seed=3)
    args, kw = physics_args(env)

    def own(v):       # the buffers' layout: clones, as the capture makes them (the same strides)
        if isinstance(v, dict):
            return {k: own(x) for k, x in v.items()}
        if type(v) is tuple:
            return tuple(own(x) for x in v)
        return v.detach().clone() if isinstance(v, torch.Tensor) else v
    args, kw = own(args), own(kw)
    sub = torch.compile(contact_substep, dynamic=False)
    with torch.no_grad():
        ref = contact_step(*args, 20, substep=sub, **kw)
        again = contact_step(*args, 20, substep=sub, **kw)
        call = CapturedCall(contact_step)
        got = call(*args, 20, substep=sub, **kw)
        args2 = args[:2] + (args[2] + 1e-3,) + args[3:]
        ref2 = contact_step(*args2, 20, substep=sub, **kw)
        got2 = call(*args2, 20, substep=sub, **kw)
    exact = all(torch.equal(a, b) for a, b in zip(ref, again))
    for a, b in zip(ref + ref2, got + got2):
        if exact:
            assert torch.equal(a, b)
        else:
            torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    assert call.captures == 1
    env.close()


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
@pytest.mark.parametrize("env_id,kw", [
    ("TensegrityRoll-v0", {"reset_sampling": "device"}),
    ("TensegrityRoll-v0", {"terrain": {"plane": {"slope_deg": 10.0}}}),
    ("TensegrityShape-v0", {}),
])
def test_cuda_graph_env_follows_the_compiled_env_cuda(env_id, kw):
    """The graphed env against the compiled env (each compiles the physics on its own, so their
    float32 round-off may differ, and a contact switch that it flips grows over the steps): the
    first step agrees to 1e-3, the ends over the first 3; then 60 steps with resets between
    replays stay finite on one capture."""
    envs = [gym.make_vec(env_id, num_envs=16, vectorization_mode="vector_entry_point", backend="torch",
                         device="cuda", dtype="float32", compile=True, cuda_graph=g, max_episode_steps=25, **kw)
            for g in (False, True)]
    rng = np.random.default_rng(0)
    with torch.no_grad():
        outs = [e.reset(seed=7)[0] for e in envs]
        assert torch.equal(outs[0], outs[1])
        for k in range(60):
            a = torch.as_tensor(rng.uniform(-1, 1, (16, envs[0].single_action_space.shape[0])), device="cuda",
                                dtype=torch.float32)
            r = [e.step(a) for e in envs]
            assert torch.isfinite(r[1][0]).all() and torch.isfinite(r[1][1]).all()
            if k == 0:
                for x, y in zip(r[0][:2], r[1][:2]):
                    torch.testing.assert_close(x, y, rtol=1e-3, atol=1e-3)
            if k < 3:
                for x, y in zip(r[0][2:4], r[1][2:4]):
                    assert torch.equal(x, y)
    graphs = envs[1].unwrapped._graphs
    assert graphs and all(c.captures == 1 for c in graphs.values())
    for e in envs:
        e.close()
