"""The torch backend (tensegrity_gym.backends.torch) against the NumPy/numba reference.

Agreement: float64 torch on CPU equals the numba path to round-off (1e-10 m) on the prism,
the icosahedron and constrained structures, RK4 and semi-implicit Euler at dt = 1e-4. The
tests run 0.1 s (1000 steps) to stay within seconds on a 2-core CI machine; the full 1 s
comparison is printed by ``python -m scripts.bench.bench_gpu --agreement`` (docs/bench_gpu.md).
Contact: the rolling robot against ``physics.pipeline.contact_step``. Gradients: autograd directional
derivatives against central finite differences of the NumPy path (not of torch), so a
wrong torch gradient fails.
"""

import re

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tensegrity_gym.core import builders  # noqa: E402
from tensegrity_gym.core.model import State, compile_model, initial_state  # noqa: E402
from tensegrity_gym.physics import contact as physics_contact, evaluate, geometry, integrate, pipeline  # noqa: E402
from tensegrity_gym.backends.torch import contact as torch_contact, divergence, driver, equations  # noqa: E402
from tensegrity_gym.backends.torch.model import resolve_dtype, torch_model, torch_params  # noqa: E402
from tensegrity_gym.backends.torch.actuation import physics_inputs, update_motor  # noqa: E402
from tensegrity_gym.envs import roll  # noqa: E402
from tensegrity_gym.envs.common import Actuation  # noqa: E402
from tensegrity_gym.core.params import default_params  # noqa: E402

T64 = torch.float64


def _released(model, B=3, seed=0, scale=0.2):
    """B copies of the structure's initial state with random node-velocity perturbations."""
    rng = np.random.default_rng(seed)
    st = initial_state(model, B)
    qd = st.qd + rng.normal(0.0, scale, st.qd.shape)
    q, qd = evaluate.project(model, st.q, qd)
    return State(q, qd)


SCENES = {
    "prism": lambda: builders.prism(3, prestress=100),
    "icosahedron": lambda: builders.icosahedron(),
    "constrained_prism": lambda: builders.constrained_prism(),
    "pinned_rod": lambda: builders.pinned_rod(damping=1.0),
}


@pytest.mark.parametrize("integrator", ["rk4", "semi_implicit_euler"])
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_float64_agrees_with_numba(scene, integrator):
    model = compile_model(SCENES[scene]())
    st = _released(model)
    ref = integrate.step(model, st, 1e-4, integrator, n_steps=1000, backend="numba")
    out = integrate.step(model, st, 1e-4, integrator, n_steps=1000, backend="torch", device="cpu")
    err = np.abs(geometry.node_positions(model, out.q) - geometry.node_positions(model, ref.q)).max()
    assert err < 1e-10, err
    assert np.abs(out.qd - ref.qd).max() < 1e-8
    assert out.t == pytest.approx(ref.t)
    moved = np.abs(geometry.node_positions(model, ref.q) - geometry.node_positions(model, st.q)).max()
    assert moved > 1e-3   # the comparison is not of a structure at rest


def test_float32_close_and_controls_node_drag():
    """float32 within 1e-4 m over 0.1 s; per-copy rest lengths, force densities and node drag agree in float64."""
    model = compile_model(builders.prism(3, prestress=100, damping=2.0, gravity=(0, 0, -9.81)),
                          node_damping=0.5)
    st = _released(model)
    rng = np.random.default_rng(1)
    rl = model.rest_length * (1 + 0.02 * rng.standard_normal((3, model.n_strings)))
    fd = np.abs(rng.normal(0, 5.0, (3, model.n_strings)))
    ref = integrate.step(model, st, 1e-4, "rk4", n_steps=300, backend="numba", rest_length=rl, force_density=fd)
    out = integrate.step(model, st, 1e-4, "rk4", n_steps=300, backend="torch", rest_length=rl, force_density=fd)
    assert np.abs(out.q - ref.q).max() < 1e-10
    f32 = integrate.step(model, st, 1e-4, "rk4", n_steps=300, backend="torch", dtype="float32",
                         rest_length=rl, force_density=fd)
    err = np.abs(geometry.node_positions(model, f32.q) - geometry.node_positions(model, ref.q)).max()
    assert 0 < err < 1e-4, err


def test_accelerations_match_numpy_with_slack_and_params():
    model = compile_model(builders.prism(3, prestress=100, damping=1.5, gravity=(0, 0, -9.81)))
    st = _released(model, B=4)
    rl = np.tile(model.rest_length, (4, 1))
    rl[1, :3] *= 1.5                      # copy 1: its bottom strings slack
    a_np = evaluate.accelerations(model, st.q, st.qd, rl)
    q, qd = torch.tensor(st.q), torch.tensor(st.qd)
    a_t = driver.accelerations(model, q, qd, rest_length=torch.tensor(rl))
    assert np.abs(a_t.numpy() - a_np).max() < 1e-10 * np.abs(a_np).max()
    # per-copy params: a copy with stiffness x2 equals the model compiled with stiffness x2
    stiff = np.tile(model.stiffness, (4, 1))
    stiff[2] *= 2.0
    a_p = driver.accelerations(model, q, qd, params={"stiffness": stiff})
    m2 = model.replace(stiffness=model.stiffness * 2.0)
    assert np.allclose(a_p[2].numpy(), evaluate.accelerations(m2, st.q[2:3], st.qd[2:3])[0], rtol=0, atol=1e-10)
    assert np.allclose(a_p[0].numpy(), evaluate.accelerations(model, st.q[:1], st.qd[:1])[0], rtol=0, atol=1e-10)


def test_per_copy_params_agree_with_numba():
    """A Params with one row per copy (masses, stiffness, damping, gravity, node drag, anchors)
    gives the numba backend's numbers; gravity and damping on a model compiled without them too."""
    for s in (builders.prism(3, prestress=100), builders.pinned_rod()):
        model = compile_model(s)
        st = _released(model, B=3, seed=4)
        rng = np.random.default_rng(0)
        p = default_params(model, 3).replace(
            mass=model.mass * (1 + 0.2 * rng.random((3, model.n_bars))),
            stiffness=model.stiffness * (1 + 0.3 * rng.random((3, model.n_strings))),
            damping=rng.random((3, model.n_strings)), node_damping=0.1 * rng.random((3, model.n_nodes)),
            gravity=np.array([[0, 0, -9.81], [0, 0, 0], [1.0, 0, -3.0]]),
            anchor_pos=model.anchor_pos + 0.01 * rng.standard_normal((3,) + model.anchor_pos.shape))
        ref = integrate.step(model, st, 1e-4, "rk4", n_steps=300, backend="numba", params=p)
        out = integrate.step(model, st, 1e-4, "rk4", n_steps=300, backend="torch", params=p)
        assert np.abs(out.q - ref.q).max() < 1e-10
        q, qd = driver.step(model, torch.tensor(st.q), torch.tensor(st.qd), 1e-4, "rk4", 300, params=p.take([1]))
        ref1 = integrate.step(model, State(st.q, st.qd), 1e-4, "rk4", n_steps=300, backend="numba",
                              params=p.take([1]))
        assert np.abs(q.numpy() - ref1.q).max() < 1e-10


def _roll_scene():
    s = roll.robot_prism()
    rod_com = (s.nodes[s.bars[:, 0]] * (1 - s.com_fraction)[:, None] + s.nodes[s.bars[:, 1]] * s.com_fraction[:, None])
    com = s.bar_mass @ rod_com / s.bar_mass.sum()
    axis = s.nodes[3:].mean(0) - s.nodes[:3].mean(0)
    nodes, _ = roll.place_on_ground(s.nodes, com, 0.02, exclude_axis=axis)
    s = s.replace(nodes=nodes + np.array([0.0, 0.0, 0.01]))   # dropped from 1 cm: touch-down, stick and slip
    model = compile_model(s)
    contact = physics_contact.GroundContact(radius=0.02, max_damping=0.2 / 4 / 1e-3)
    return model, contact


def test_contact_agrees_with_contact_step():
    model, contact = _roll_scene()
    rng = np.random.default_rng(3)
    st = initial_state(model, 2)
    qd = st.qd.copy()
    qd[1, :, :3] += np.array([0.3, 0.1, 0.0])     # copy 1 slides sideways on landing
    st = State(*evaluate.project(model, st.q, qd))
    rl = model.rest_length * (1 + 0.05 * rng.standard_normal((2, model.n_strings)))
    cs = physics_contact.init_contact_state(model, 2)
    ref, cs_ref = pipeline.contact_step(model, contact, st, cs, 1e-3, "semi_implicit_euler", n_steps=400, rest_length=rl)
    q, qd = torch.tensor(st.q), torch.tensor(st.qd)
    anchor, active = torch_contact.init_contact_state(model, 2)
    slipped = torch.zeros((), dtype=torch.bool)
    for _ in range(400):     # step by step to record that both stick and slip occurred
        W, _, _, slip = torch_contact.contact_forces(contact, model, q, qd, anchor, active)
        slipped = slipped | slip.any()
        q, qd, anchor, active = torch_contact.contact_step(model, contact, q, qd, anchor, active, 1e-3, rest_length=rl)
    assert bool(slipped) and bool(active.any())
    assert np.abs(q.numpy() - ref.q).max() < 1e-10
    assert np.array_equal(active.numpy(), cs_ref.active)
    assert np.abs(anchor.numpy() - cs_ref.anchor).max() < 1e-10


def test_motor_matches_actuation():
    act = Actuation("rest_length", [0, 4, 7], 0.1, 0.4, 0.2, 0.02, np.full(9, 0.3), np.full(3, 0.3), max_accel=2.0)
    rng = np.random.default_rng(0)
    ctrl = rng.uniform(0.1, 0.4, (64, 3))
    ctrl[:4] = 0.4
    speed = rng.uniform(-0.2, 0.2, (64, 3))
    a = rng.uniform(-1, 1, (64, 3))
    for _ in range(20):
        new, v = act.update_motor(ctrl, speed, a)[:2]
        nt, vt = update_motor(act, torch.tensor(ctrl), torch.tensor(speed), torch.tensor(a))
        assert np.array_equal(nt.numpy(), new) and np.array_equal(vt.numpy(), v)
        rl = physics_inputs(act, nt)["rest_length"].numpy()
        assert np.array_equal(rl, act.physics_inputs(new)["rest_length"])
        ctrl, speed = new, v


# ---------------------------------------------------------------------- gradients
def _grad_scene():
    """A damped, gravity-loaded prism released with small velocities: every string stays taut over the
    rollout (checked), so the loss is smooth in all inputs."""
    model = compile_model(builders.prism(3, prestress=100, damping=2.0, gravity=(0, 0, -9.81)),
                          node_damping=0.3)
    st = _released(model, B=2, seed=5, scale=0.05)
    return model, st


N_GRAD, DT_GRAD = 150, 1e-3
W_LOSS = np.random.default_rng(11).standard_normal((2, 6, 3))


def _loss_numpy(model, st, rest_length=None, force_density=None, params=None):
    out = integrate.step(model, st, DT_GRAD, "rk4", n_steps=N_GRAD, rest_length=rest_length,
                         force_density=force_density, params=params)
    return float(np.sum(W_LOSS * geometry.node_positions(model, out.q)))


def _loss_torch(model, q, qd, rest_length=None, force_density=None, params=None):
    tm = torch_model(model)
    q, qd = driver.step(model, q, qd, DT_GRAD, "rk4", N_GRAD, rest_length, force_density, params)
    prm = torch_params(tm, params, q.shape[0])
    return (torch.tensor(W_LOSS) * equations.node_positions(tm, q, prm)).sum()


def _agree(ad, fd, rel=1e-6):
    return abs(ad - fd) <= rel * max(abs(fd), 1e-12)


def test_smooth_stretch_has_no_switch():
    model, st = _grad_scene()
    q, qd = st.q, st.qd
    for _ in range(N_GRAD // 10):
        s = integrate.step(model, State(q, qd), DT_GRAD, "rk4", n_steps=10)
        q, qd = s.q, s.qd
        _, L, _ = geometry.string_state(model, q)
        assert np.min(L - model.rest_length) > 1e-3   # all strings taut by a margin


FIELDS = ["stiffness", "damping", "mass", "rest_length", "J", "node_damping"]


@pytest.mark.parametrize("field", FIELDS)
def test_param_gradient_matches_numpy_fd(field):
    model, st = _grad_scene()
    base = np.asarray(getattr(model, field), float)
    d = np.random.default_rng(FIELDS.index(field)).standard_normal(base.shape)   # a fixed random direction
    p = torch.tensor(base[None], requires_grad=True)
    loss = _loss_torch(model, torch.tensor(st.q), torch.tensor(st.qd), params={field: p})
    (g,) = torch.autograd.grad(loss, p)
    ad = float((g[0].numpy() * d).sum())
    h = 1e-5 * float(np.abs(base).max())   # relative step: 1e-6 .. 1e-4 all agree to < 6e-6 here; 1e-5 best

    def at(x):   # the NumPy reference with Params (mass alone rescales f and J there, as in torch)
        return _loss_numpy(model, st, params=default_params(model).replace(**{field: x}))
    fd = (at(base + h * d) - at(base - h * d)) / (2 * h)
    assert _agree(ad, fd), (field, ad, fd)
    assert abs(fd) > 1e-6                        # the parameter matters to the loss


def test_state_and_control_gradients_match_numpy_fd():
    model, st = _grad_scene()
    rng = np.random.default_rng(7)
    fd0 = np.full((2, model.n_strings), 3.0)
    q = torch.tensor(st.q, requires_grad=True)
    qd = torch.tensor(st.qd, requires_grad=True)
    u = torch.tensor(fd0, requires_grad=True)
    loss = _loss_torch(model, q, qd, force_density=u)
    gq, gqd, gu = torch.autograd.grad(loss, (q, qd, u))
    for name, g, base in (("qd", gqd, st.qd), ("force_density", gu, fd0)):
        d = rng.standard_normal(base.shape)
        ad = float((g.numpy() * d).sum())
        h = 1e-5

        def at(x):
            if name == "qd":
                return _loss_numpy(model, State(st.q, x), force_density=fd0)
            return _loss_numpy(model, st, force_density=x)
        fd = (at(base + h * d) - at(base - h * d)) / (2 * h)
        assert _agree(ad, fd), (name, ad, fd)
    # initial positions: perturb r only (b stays a unit vector)
    d = np.zeros(st.q.shape)
    d[..., :3] = rng.standard_normal(st.q[..., :3].shape)
    ad = float((gq.numpy() * d).sum())
    h = 1e-5
    fdq = (_loss_numpy(model, State(st.q + h * d, st.qd), force_density=fd0)
           - _loss_numpy(model, State(st.q - h * d, st.qd), force_density=fd0)) / (2 * h)
    assert _agree(ad, fdq), (ad, fdq)


def test_wrong_gradient_is_caught():
    """The check used above fails for a gradient that is slightly wrong: the autograd gradient of a model
    whose stiffness is off by 0.1 % does not pass against the NumPy finite difference of the right model."""
    model, st = _grad_scene()
    wrong = model.replace(stiffness=model.stiffness * 1.001)
    d = np.random.default_rng(2).standard_normal(model.n_strings)
    p = torch.tensor(wrong.stiffness[None], requires_grad=True)
    loss = _loss_torch(wrong, torch.tensor(st.q), torch.tensor(st.qd), params={"stiffness": p})
    (g,) = torch.autograd.grad(loss, p)
    ad = float((g[0].numpy() * d).sum())
    h = 1e-3
    fd = (_loss_numpy(model.replace(stiffness=model.stiffness + h * d), st)
          - _loss_numpy(model.replace(stiffness=model.stiffness - h * d), st)) / (2 * h)
    assert not _agree(ad, fd)


def test_gradient_through_contact_and_motor_is_finite():
    """Through contact (stick, slip, touch-down) and the motor the gradient exists and is finite."""
    model, contact = _roll_scene()
    act = Actuation("rest_length", [0, 1, 2], 0.5 * model.rest_length[:3], 1.1 * model.rest_length[:3], 0.2, 0.02,
                    model.rest_length, model.rest_length[:3], max_accel=2.0)
    st = initial_state(model, 2)
    q, qd = torch.tensor(st.q), torch.tensor(st.qd)
    anchor, active = torch_contact.init_contact_state(model, 2)
    a = torch.full((2, 3), -0.5, dtype=T64, requires_grad=True)
    ctrl = torch.tensor(np.tile(act.nominal, (2, 1)))
    speed = torch.zeros((2, 3), dtype=T64)
    for _ in range(5):
        ctrl, speed = update_motor(act, ctrl, speed, a)
        rl = physics_inputs(act, ctrl)["rest_length"]
        q, qd, anchor, active = torch_contact.contact_step(model, contact, q, qd, anchor, active, 1e-3, n_steps=20,
                                                           rest_length=rl)
    loss = q[..., 0].sum()
    (g,) = torch.autograd.grad(loss, a)
    assert torch.isfinite(g).all() and float(g.abs().max()) > 0


# ---------------------------------------------------------------------- bad input
def test_bad_device_dtype_and_params_device():
    model = compile_model(builders.prism(3))
    st = initial_state(model, 1)
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="cuda.*not available"):
            integrate.step(model, st, 1e-3, backend="torch", device="cuda")
    with pytest.raises(ValueError, match="dtype.*float16"):
        integrate.step(model, st, 1e-3, backend="torch", dtype="float16")
    with pytest.raises(ValueError, match="dtype"):
        resolve_dtype(torch.int32)
    with pytest.raises(ValueError, match="params.stiffness: tensor on device 'meta'"):
        driver.step(model, torch.tensor(st.q), torch.tensor(st.qd), 1e-3,
                    params={"stiffness": torch.zeros((1, model.n_strings), dtype=T64, device="meta")})
    with pytest.raises(ValueError, match="params.mass.*leading axis 2"):
        driver.step(model, torch.tensor(np.repeat(st.q, 3, 0)), torch.tensor(np.repeat(st.qd, 3, 0)), 1e-3,
                    params={"mass": np.ones((2, 3))})
    with pytest.raises(ValueError, match="integrator"):
        integrate.step(model, st, 1e-3, "dop853", backend="torch")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_agrees_with_cpu():
    model = compile_model(builders.icosahedron())
    st = _released(model)
    a = integrate.step(model, st, 1e-4, "rk4", n_steps=200, backend="torch", device="cpu")
    b = integrate.step(model, st, 1e-4, "rk4", n_steps=200, backend="torch", device="cuda")
    assert np.abs(a.q - b.q).max() < 1e-10
    with pytest.raises(ValueError, match="params.stiffness: tensor on device 'cpu'"):
        driver.step(model, torch.tensor(st.q, device="cuda"), torch.tensor(st.qd, device="cuda"), 1e-3,
                    params={"stiffness": torch.tensor(model.stiffness[None])})


def test_cli_simulate_torch(tmp_path, capsys):
    from tensegrity_gym.tools import cli
    out = tmp_path / "traj.npz"
    assert cli.main(["simulate", "prism3", "--duration", "0.01", "--dt", "1e-3", "--backend", "torch",
                     "--device", "cpu", "--out", str(out)]) == 0
    ref = tmp_path / "ref.npz"
    assert cli.main(["simulate", "prism3", "--duration", "0.01", "--dt", "1e-3", "--backend", "numba",
                     "--out", str(ref)]) == 0
    assert np.abs(np.load(out)["nodes"] - np.load(ref)["nodes"]).max() < 1e-12
    if not torch.cuda.is_available():
        capsys.readouterr()
        assert cli.main(["simulate", "prism3", "--duration", "0.01", "--backend", "torch", "--device", "cuda",
                         "--out", str(tmp_path / "x.npz")]) == 2
        err = capsys.readouterr().err
        assert re.search("cuda.*not available", err) and err.count("error:") == 1
        assert not (tmp_path / "x.npz").exists()


@pytest.mark.parametrize("local", [False, True])
def test_diverged_equals_the_pipeline(local):
    """tb.diverged flags the same copies as pipeline.diverged: a NaN in q or qd, a reference point
    past the limit (from the start's centre, or with ``local`` from the copy's own centre, whose
    height is checked), and leaves travelled-but-fine copies alone."""
    from tensegrity_gym.physics import pipeline
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.2, 0.2, (6, 3, 6))
    qd = rng.standard_normal((6, 3, 6))
    q[1, 0, 4] = np.nan                      # non-finite direction
    qd[2, 2, 0] = np.inf                     # non-finite velocity
    q[3, 1, 0] += 5.0                        # one rod far from the others and from the centre
    q[4, :, 0] += 5.0                        # the whole robot travelled 5 m along x
    q[5, :, 2] += 5.0                        # the whole robot rose 5 m
    center, limit = np.array([0.0, 0.0, 0.1]), 1.0
    want = pipeline.diverged(q, qd, center, limit, local=local)
    got = divergence.diverged(torch.as_tensor(q), torch.as_tensor(qd), torch.as_tensor(center), limit, local=local)
    assert got.tolist() == want.tolist()
    assert want.tolist() == [False, True, True, True, not local, True]
