"""Batched, differentiable torch backend of the physics (float64 / float32, CPU / CUDA).

The same equations as the NumPy reference (:mod:`tensegrity_gym.dynamics`,
:mod:`tensegrity_gym.integrators`, :mod:`tensegrity_gym.contact`, the cable motor of
:class:`tensegrity_gym.envs.common.Actuation`), written once in torch and batched over a
leading axis B. torch is imported lazily: the core install never needs it (``pip install
tensegrity_gym[torch]``). SI units throughout (m, kg, s, N).

Entry points
------------
* :func:`accelerations` ``(model, q, qd, ...) -> (B, k, 6)`` ``[r'', b'']`` (m/s^2, 1/s^2);
* :func:`step` ``(model, q, qd, dt, integrator, n_steps, ...) -> (q, qd)`` on torch tensors
  (``"semi_implicit_euler"`` with the great-circle drift when ``project=True``, or ``"rk4"``,
  projection after each step as :func:`tensegrity_gym.integrators.step`);
* :func:`contact_forces`, :func:`contact_step`, :func:`contact_substep`: ground contact with
  Coulomb friction and a stick phase (as :mod:`tensegrity_gym.contact`, the anchors and contact
  flags as tensors; per-copy contact parameters as a (P, 9) tensor ``prm`` / ``contact_prm``);
* :func:`motor`: the cable motor (``Actuation.apply_motor``), :func:`advance`: the control
  update without a motor (``Actuation.apply``), both with optional per-copy limits, and
  :func:`physics_inputs`;
* :func:`step_state` / :func:`simulate`: numpy :class:`~tensegrity_gym.dynamics.State` in
  and out, what ``integrators.step(..., backend="torch", device=..., dtype=...)`` and
  ``python -m tensegrity_gym simulate --backend torch --device cpu`` call.

Per-copy parameters
-------------------
``params``: None (the model's own numbers), a :class:`tensegrity_gym.params.Params`, or a dict
(or any object) with the attributes/keys ``mass`` (P, k) kg,
``f`` (P, k) kg m, ``J`` (P, k) kg m^2, ``stiffness`` / ``damping`` / ``rest_length`` (P, m)
N/m, N s/m, m, ``node_damping`` (P, n) N s/m, ``gravity`` (P, 3) m/s^2, ``anchor_pos``
(P, na, 3) m (missing ones come from the model), with P = 1 (shared) or B (one row per copy).
``mass`` given without ``f`` and ``J`` keeps each rod's mass distribution: ``f`` and ``J`` scale
with it (as ``Params.replace(mass=...)``). A damping, gravity or node-drag term that the model
lacks runs when ``params`` give it (a NumPy value that is not all zero, or any tensor). Values may be NumPy
arrays or torch tensors; a tensor with ``requires_grad`` makes the rollout differentiable with
respect to it. The gravity nodal loads are derived here from ``mass`` and ``gravity`` (a rod's
weight split between its nodes by its centre-of-mass fraction), so a gradient with respect to
``mass`` includes its weight. A tensor on another device than the state is a ValueError
naming the field.

Differentiability and the gradient at a switch
----------------------------------------------
Everything is built from out-of-place torch operations (no in-place writes on tensors that
carry gradients, no ``.item()``), so ``loss.backward()`` through any number of steps gives the
gradient with respect to the initial state, the controls (``rest_length``, ``force_density``,
motor actions) and the parameters. The model is piecewise smooth; autograd returns the
derivative of the branch that the forward pass took (``torch.where`` / ``clamp``):

* slack/taut string: at ``|s| = l0`` exactly the string counts as slack (``|s| > l0`` is
  taut, as in NumPy), so the gradient there is that of a slack string (zero force). The
  elastic force ``k (|s| - l0)`` is continuous there, so the one-sided gradients differ only
  by the jump of the force *slope* (``k``), and the damping term ``c d|s|/dt`` jumps: the
  force itself is discontinuous when the string goes taut while lengthening.
* the tension clip ``max(0, tension)`` (damping pulling a string slack faster than the
  spring) and the control clip ``max(0, gamma + u)``: gradient of the active branch,
  zero on the clipped side (torch's ``clamp`` passes the gradient when the value is
  exactly at the bound).
* contact on/off (``delta > 0``): off gives zero gradient; the normal force ``k delta`` is
  continuous at touch-down, its damping part ``min(k delta d, c_max) delta'`` too (it
  vanishes with ``delta``), the friction is not (the anchor is set at touch-down), so a
  rollout's gradient is the gradient along the sequence of contact modes that the forward
  pass visited; it does not see a mode change that a finite perturbation would cause.
* friction stick/slip: stick differentiates the spring-damper ``-k_t xi - c_t v``, slip the
  scaled force ``mu F_n F*/|F*|`` (continuous at the switch, the derivative is not); the
  anchor is state and its gradient is carried through the steps.
* the motor's clips (rate change, bounds, end stop) likewise: gradient of the branch taken,
  zero through an active bound.
* the great-circle drift at a rod with ``b' = 0`` exactly: the rotation angle is computed
  without a square root of zero (``sin(x)/x`` by its series below 1e-4 rad), so the gradient
  is finite (the exact one).

Finite differences across a switch therefore disagree with autograd by design; the tests
compare the two on smooth stretches only (``tests/test_torch_backend.py``).

Numbers (``scripts/bench_gpu.py --agreement``, ``docs/bench_gpu.md``): over 1 s of RK4 at
dt = 1e-4 (10,000 steps) float64 on CPU agrees with the numba path to round-off (largest node
error 9e-15 m on the prism, 1e-15 m on the icosahedron, 4e-15 m on the constrained prism);
float32 stays within 1.4e-6 .. 3.7e-6 m of it on the same runs.
"""
from __future__ import annotations

import math
import weakref

import numpy as np

from .core.param_table import physics_fields

__all__ = ["resolve_device", "resolve_dtype", "TorchModel", "torch_model", "torch_params", "mass_moments", "node_positions",
           "node_velocities", "string_state", "force_densities", "nodal_forces", "accelerations", "project",
           "sphere_drift", "step", "contact_forces", "contact_step", "contact_substep", "init_contact_state", "motor", "advance",
           "physics_inputs", "step_state", "simulate", "diverged", "PARAM_FIELDS"]

#: the Params fields, in order (a view of tensegrity_gym.core.param_table)
PARAM_FIELDS = physics_fields()
_SINC_SMALL = 1e-4   # rad: below this rotation per step sin(x)/x = 1 - x^2/6 (as integrators._SINC_SMALL)


def _torch():
    try:
        import torch
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ImportError("backend='torch' needs PyTorch: pip install 'tensegrity_gym[torch]' "
                          "(or pip install torch)") from exc
    return torch


# ---------------------------------------------------------------------- device, dtype
def resolve_device(device=None):
    """A ``torch.device`` from None (CPU), a string or a device; ValueError if CUDA (or another
    accelerator) is requested where none exists. A bare ``"cuda"`` resolves to the current CUDA
    device with its index (``cuda:0``), the device its tensors report."""
    torch = _torch()
    if device is None:
        return torch.device("cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise ValueError(f"device: cannot parse {device!r} ({exc})") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device: {str(dev)!r} requested but CUDA is not available "
                             f"(torch {torch.__version__}, no CUDA device found); use device='cpu'")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"device: {str(dev)!r} requested but only {torch.cuda.device_count()} CUDA "
                             "device(s) exist")
        if dev.index is None:   # 'cuda' -> 'cuda:<current>': tensors report their index, so compare equal
            dev = torch.device("cuda", torch.cuda.current_device())
    elif dev.type == "mps":
        if not (hasattr(torch.backends, "mps") and torch.backends.mps.is_available()):
            raise ValueError(f"device: {str(dev)!r} requested but MPS is not available")
    elif dev.type != "cpu":
        raise ValueError(f"device: {str(dev)!r} is not supported; use 'cpu' or 'cuda'")
    return dev


def resolve_dtype(dtype=None):
    """torch.float64 (default) or torch.float32 from a torch/NumPy dtype or its name; ValueError otherwise."""
    torch = _torch()
    if dtype is None:
        return torch.float64
    table = {"float64": torch.float64, "double": torch.float64, "float32": torch.float32, "float": torch.float32,
             "torch.float64": torch.float64, "torch.float32": torch.float32}
    if isinstance(dtype, torch.dtype):
        if dtype in (torch.float64, torch.float32):
            return dtype
    elif isinstance(dtype, str):
        if dtype in table:
            return table[dtype]
    else:
        try:
            nd = np.dtype(dtype)
        except TypeError:
            nd = None
        if nd == np.float64:
            return torch.float64
        if nd == np.float32:
            return torch.float32
    raise ValueError(f"dtype: {dtype!r} is not supported; use float32 or float64")


# ---------------------------------------------------------------------- compiled constants
class TorchModel:
    """The topology constants of a :class:`~tensegrity_gym.dynamics.Model` as tensors on one
    device and dtype (index arrays as int64). Built by :func:`torch_model` (cached per model,
    device and dtype)."""

    def __init__(self, model, device, dtype):
        torch = _torch()
        self.model = model
        self.device, self.dtype = device, dtype
        k, n, m = model.n_bars, model.n_nodes, model.n_strings
        self.k, self.n, self.m = k, n, m
        self.na = int(model.anchor_idx.size)

        def T(x):
            return torch.as_tensor(np.array(x, dtype=float), dtype=dtype, device=device)

        def I(x):
            return torch.as_tensor(np.array(x, dtype=np.int64), device=device)
        self.eta_a = T(model.eta[:, 0])[None, :, None]      # (1, k, 1) m
        self.eta_c = T(model.eta[:, 1])[None, :, None]
        self.proj = T(model.proj)                            # (k, 3, 3)
        self.offset = T(model.offset)                        # (k, 3) m
        self.any_constrained = bool(model.constrained.any())
        self.str_i, self.str_j = I(model.str_i), I(model.str_j)
        self.rod_a, self.rod_c = I(model.rod_a), I(model.rod_c)
        # node gather: cat([end a of rods (k), end c of rods (k), anchors (na), zero]) -> nodes (n)
        perm = np.full(n, 2 * k + self.na, dtype=np.int64)
        perm[model.rod_a] = np.arange(k)
        perm[model.rod_c] = k + np.arange(k)
        perm[model.anchor_idx] = 2 * k + np.arange(self.na)
        self.perm = I(perm)
        self.has_free_node = bool(np.any(perm == 2 * k + self.na))
        com = np.asarray(model.structure.com_fraction, dtype=float)
        self.com_a = T(1.0 - com)[None, :, None]              # share of a rod's weight at node a
        self.com_c = T(com)[None, :, None]
        self.has_damping = bool(model.has_damping)
        self.has_node_damping = bool(model.has_node_damping)
        self.has_gravity = bool(model.has_gravity)
        self.defaults = {}
        for name in PARAM_FIELDS:
            val = _model_field(model, name)
            self.defaults[name] = None if val is None else T(val)[None]

    def gather_nodes(self, Xa, Xc, anchors=None):
        """(B, n, 3) from per-rod end values ``Xa``, ``Xc`` (B, k, 3) and anchor values (P|B, na, 3)."""
        torch = _torch()
        B = Xa.shape[0]
        parts = [Xa, Xc]
        if self.na:
            parts.append(anchors.expand(B, self.na, 3) if anchors is not None
                         else Xa.new_zeros((B, self.na, 3)))
        parts.append(Xa.new_zeros((B, 1, 3)))
        return torch.cat(parts, dim=1).index_select(1, self.perm)


def _model_field(model, name):
    if name == "gravity":
        g = model.gravity
        return np.zeros(3) if g is None else np.asarray(g, float)
    if name == "node_damping":
        nd = model.node_damping
        return np.zeros(model.n_nodes) if nd is None else nd
    return getattr(model, name)


_MODELS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def torch_model(model, device=None, dtype=None) -> TorchModel:
    """The cached :class:`TorchModel` of ``model`` on ``device`` / ``dtype``."""
    dev, dt = resolve_device(device), resolve_dtype(dtype)
    per = _MODELS.setdefault(model, {})
    key = (str(dev), str(dt))
    tm = per.get(key)
    if tm is None:
        tm = per[key] = TorchModel(model, dev, dt)
    return tm


def torch_params(tm: TorchModel, params=None, batch_size: int | None = None) -> dict:
    """Dict of parameter tensors with a leading axis P (1 or B) on ``tm``'s device and dtype, from
    ``params`` (None, an object with the :data:`PARAM_FIELDS` attributes, or a dict); plus
    ``W0`` (P, n, 3) N, the gravity nodal loads derived from ``mass`` and ``gravity``.
    ValueError names a field on another device, of a wrong shape, or a P that is neither 1 nor B."""
    torch = _torch()
    out = {}
    given = {}
    shapes = {"mass": (tm.k,), "f": (tm.k,), "J": (tm.k,), "stiffness": (tm.m,), "damping": (tm.m,),
              "rest_length": (tm.m,), "node_damping": (tm.n,), "gravity": (3,), "anchor_pos": (tm.na, 3)}
    for name in PARAM_FIELDS:
        val = None
        if params is not None:
            val = params.get(name) if isinstance(params, dict) else getattr(params, name, None)
        if val is None:
            out[name] = tm.defaults[name]
            continue
        # a term the model lacks (damping, gravity, node drag) runs when a given value may be non-zero
        given[name] = True if isinstance(val, torch.Tensor) else bool(np.any(np.asarray(val, dtype=float) != 0))
        if isinstance(val, torch.Tensor):
            if val.device != tm.device:
                raise ValueError(f"params.{name}: tensor on device {str(val.device)!r}, but the state is on "
                                 f"{str(tm.device)!r}; move it with .to({str(tm.device)!r})")
            if not val.is_floating_point():
                val = val.to(tm.dtype)
            elif val.dtype != tm.dtype:
                val = val.to(tm.dtype)
        else:
            val = torch.as_tensor(np.array(val, dtype=float), dtype=tm.dtype, device=tm.device)
        want = shapes[name]
        if tuple(val.shape) == want:
            val = val[None]
        if tuple(val.shape[1:]) != want:
            raise ValueError(f"params.{name}: expected shape (P, {', '.join(map(str, want))}) with P = 1 or "
                             f"the batch size, got {tuple(val.shape)}")
        P = val.shape[0]
        if batch_size is not None and P not in (1, batch_size):
            raise ValueError(f"params.{name}: leading axis {P} is neither 1 nor the batch size {batch_size}")
        out[name] = val
    if "mass" in given and "f" not in given and "J" not in given:
        out["f"], out["J"] = mass_moments(tm, out["mass"])
    # ("given" maps a provided field to "may be non-zero")
    out["has_damping"] = tm.has_damping or given.get("damping", False)
    out["has_gravity"] = tm.has_gravity or given.get("gravity", False)
    out["has_node_damping"] = tm.has_node_damping or given.get("node_damping", False)
    g = out["gravity"][:, None, :]                                   # (P, 1, 3)
    mass = out["mass"][..., None]                                     # (P, k, 1)
    Wa, Wc = tm.com_a * mass * g, tm.com_c * mass * g                 # (P, k, 3)
    out["W0"] = tm.gather_nodes(Wa, Wc)                               # (P, n, 3); anchors get 0
    return out


def mass_moments(tm: TorchModel, mass):
    """(P, k) first and second mass moments ``f`` (kg m), ``J`` (kg m^2) of rods of mass ``mass``
    (P, k) kg with the model's mass distribution: each rod's distribution keeps its shape, so
    ``f`` and ``J`` scale with the mass (as ``Params.replace(mass=...)``)."""
    m0 = tm.defaults["mass"]
    return mass * (tm.defaults["f"] / m0), mass * (tm.defaults["J"] / m0)


def _dot(a, b):
    """Dot product over the last axis (of length 3), written out: torch's reduction over a
    length-3 axis is ~10x slower than three products on CPU."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _proj_apply(Pi, x):
    """``Pi @ x`` per rod: Pi (k, 3, 3), x (B, k, 3) -> (B, k, 3) (elementwise, no bmm)."""
    return torch_stack3(
        _dot(Pi[:, 0], x), _dot(Pi[:, 1], x), _dot(Pi[:, 2], x))


def torch_stack3(a, b, c):
    return _torch().stack([a, b, c], dim=-1)


# ---------------------------------------------------------------------- dynamics
def node_positions(tm: TorchModel, q, prm):
    """(B, n, 3) node positions, m."""
    r, b = q[..., :3], q[..., 3:]
    return tm.gather_nodes(r + tm.eta_a * b, r + tm.eta_c * b, prm["anchor_pos"])


def diverged(q, qd, center, limit: float, local: bool = False):
    """(B,) bool, :func:`tensegrity_gym.pipeline.diverged` in torch: copy b has a non-finite entry
    in ``q``/``qd`` (B, k, 6), or a rod reference point farther than ``limit`` m (per
    coordinate) from ``center`` (3,) m (a tensor on q's device and dtype); with ``local`` (a
    robot that travels) from its copy's mean reference point instead, that mean's height checked
    against ``float(center[2])`` (horizontal travel is not limited)."""
    torch = _torch()
    finite = torch.isfinite(q).all(dim=2).all(dim=1) & torch.isfinite(qd).all(dim=2).all(dim=1)
    r = q[..., :3]
    r = torch.where(torch.isfinite(r), r, torch.zeros_like(r))
    if local:
        m = r.mean(dim=1, keepdim=True)
        far = ~(((r - m).abs().amax(dim=(1, 2)) <= limit) & ((m[:, 0, 2] - float(center[2])).abs() <= limit))
    else:
        far = ~((r - center).abs().amax(dim=(1, 2)) <= limit)
    return ~finite | far


def node_velocities(tm: TorchModel, qd):
    """(B, n, 3) node velocities, m/s (anchors 0)."""
    rd, bd = qd[..., :3], qd[..., 3:]
    return tm.gather_nodes(rd + tm.eta_a * bd, rd + tm.eta_c * bd)


def string_state(tm: TorchModel, q, qd, prm, with_rate: bool):
    """String vectors (B, m, 3), lengths (B, m) m, length rates (B, m) m/s or None."""
    torch = _torch()
    N = node_positions(tm, q, prm)
    S = N.index_select(1, tm.str_j) - N.index_select(1, tm.str_i)
    L = torch.sqrt(_dot(S, S))
    Ld = None
    if with_rate:
        V = node_velocities(tm, qd)
        Sd = V.index_select(1, tm.str_j) - V.index_select(1, tm.str_i)
        pos = L > 0
        Ld = torch.where(pos, _dot(S, Sd) / torch.where(pos, L, torch.ones_like(L)), torch.zeros_like(L))
    return S, L, Ld


def force_densities(tm: TorchModel, q, qd, prm, rest_length=None, force_density=None):
    """gamma (B, m) N/m, string vectors and lengths; tension-only, damping only while taut,
    controls clipped at 0 (see :func:`tensegrity_gym.dynamics.force_densities`)."""
    torch = _torch()
    l0 = prm["rest_length"] if rest_length is None else rest_length
    S, L, Ld = string_state(tm, q, qd, prm, prm["has_damping"])
    taut = L > l0
    safeL = torch.where(taut, L, torch.ones_like(L))
    tension = prm["stiffness"] * (L - l0)
    if prm["has_damping"]:
        tension = tension + prm["damping"] * Ld
    gamma = torch.where(taut, torch.clamp(tension, min=0.0) / safeL, torch.zeros_like(L))
    if force_density is not None:
        gamma = torch.clamp(gamma + force_density, min=0.0)
    return gamma, S, L


def nodal_forces(tm: TorchModel, q, qd, prm, rest_length=None, force_density=None, external=None):
    """Total nodal forces (B, n, 3) N (strings, gravity, node drag, ``external``) and gamma (B, m)."""
    gamma, S, _ = force_densities(tm, q, qd, prm, rest_length, force_density)
    gS = gamma[..., None] * S
    F = gS.new_zeros((S.shape[0], tm.n, 3)).index_add(1, tm.str_i, gS).index_add(1, tm.str_j, -gS)
    if prm["has_gravity"]:
        F = F + prm["W0"]
    if prm["has_node_damping"]:
        F = F - prm["node_damping"][..., None] * node_velocities(tm, qd)
    if external is not None:
        F = F + external
    return F, gamma


def _rod_accelerations(tm: TorchModel, q, qd, F, prm):
    """The branch-free Sherman-Morrison form of ``dynamics._rod_accelerations`` (free and
    constrained rods alike)."""
    torch = _torch()
    b = q[..., 3:]
    bd = qd[..., 3:]
    Fa, Fc = F.index_select(1, tm.rod_a), F.index_select(1, tm.rod_c)
    fr = Fa + Fc
    fb = tm.eta_a * Fa + tm.eta_c * Fc
    bb = _dot(b, b)[..., None]
    w = _dot(bd, bd)[..., None] / bb
    Pfb = fb - b * _dot(b, fb)[..., None] / bb
    f = prm["f"][..., None]
    J = prm["J"][..., None]
    m = prm["mass"][..., None]
    h = fr - (f / J) * Pfb + f * w * b
    alpha = m - f * f / J
    beta = f * f / J
    Pi = tm.proj
    if tm.any_constrained:
        u = _proj_apply(Pi, b) / torch.sqrt(bb)
        Pih = _proj_apply(Pi, h)
    else:   # every Pi = I (free rods): the same numbers without the products
        u = b / torch.sqrt(bb)
        Pih = h
    uu = _dot(u, u)[..., None]
    uh = _dot(u, h)[..., None]
    rdd = (Pih - beta * u * uh / (alpha + beta * uu)) / alpha
    Prdd = rdd - b * _dot(b, rdd)[..., None] / bb
    bdd = Pfb / J - (f / J) * Prdd - w * b
    return torch.cat([rdd, bdd], dim=-1)


def _accel(tm, q, qd, prm, rest_length, force_density, external):
    F, _ = nodal_forces(tm, q, qd, prm, rest_length, force_density, external)
    return _rod_accelerations(tm, q, qd, F, prm)


def project(tm: TorchModel, q, qd):
    """``|b| = 1``, ``b . b' = 0`` and the constrained reference points back on their set
    (as :func:`tensegrity_gym.dynamics.project`)."""
    torch = _torch()
    r, b = q[..., :3], q[..., 3:]
    rd, bd = qd[..., :3], qd[..., 3:]
    b = b / torch.sqrt(_dot(b, b))[..., None]
    bd = bd - b * _dot(b, bd)[..., None]
    if tm.any_constrained:
        r = tm.offset + _proj_apply(tm.proj, r)
        rd = _proj_apply(tm.proj, rd)
    return torch.cat([r, b], dim=-1), torch.cat([rd, bd], dim=-1)


def sphere_drift(q, qd, dt):
    """Drift half of semi-implicit Euler with projection: ``r += dt r'`` and each ``b`` along its
    great circle (as ``integrators._sphere_drift``; no square root of zero, so its gradient is
    finite at ``b' = 0``)."""
    torch = _torch()
    r, b = q[..., :3], q[..., 3:]
    rd, bd = qd[..., :3], qd[..., 3:]
    r = r + dt * rd
    b = b * (1.0 / torch.sqrt(_dot(b, b)))[..., None]
    bd = bd - b * _dot(b, bd)[..., None]
    ww = _dot(bd, bd)[..., None]
    pos = ww > 0
    w = torch.where(pos, torch.sqrt(torch.where(pos, ww, torch.ones_like(ww))), torch.zeros_like(ww))
    x = w * dt
    small = x < _SINC_SMALL
    xs = torch.where(small, torch.ones_like(x), x)
    sinc = torch.where(small, 1.0 - x * x / 6.0, torch.sin(xs) / xs)
    c = torch.cos(x)
    bn = b * c + bd * (dt * sinc)
    bdn = bd * c - b * (w * (x * sinc))
    return torch.cat([r, bn], dim=-1), torch.cat([rd, bdn], dim=-1)


def _setup(model, q, params, rest_length, force_density):
    """TorchModel and parameter dict for tensors ``q`` (device/dtype from ``q``)."""
    torch = _torch()
    if not isinstance(q, torch.Tensor):
        raise TypeError(f"q: expected a torch.Tensor (B, k, 6), got {type(q).__name__}; "
                        "for NumPy states use step_state or integrators.step(..., backend='torch')")
    if q.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"dtype: {q.dtype} is not supported; use float32 or float64")
    tm = model if isinstance(model, TorchModel) else torch_model(model, q.device, q.dtype)
    if q.ndim != 3 or q.shape[1:] != (tm.k, 6):
        raise ValueError(f"q: expected shape (B, {tm.k}, 6), got {tuple(q.shape)}")
    B = q.shape[0]
    prm = torch_params(tm, params, B)
    rest_length = _control(tm, rest_length, B, "rest_length")
    force_density = _control(tm, force_density, B, "force_density")
    return tm, prm, rest_length, force_density


def _control(tm, x, B, name):
    torch = _torch()
    if x is None:
        return None
    if isinstance(x, torch.Tensor):
        if x.device != tm.device:
            raise ValueError(f"{name}: tensor on device {str(x.device)!r}, but the state is on {str(tm.device)!r}")
        x = x.to(tm.dtype)
    else:
        x = torch.as_tensor(np.array(x, dtype=float), dtype=tm.dtype, device=tm.device)
    if tuple(x.shape) not in ((tm.m,), (B, tm.m), (1, tm.m)):
        raise ValueError(f"{name}: expected shape ({tm.m},) or ({B}, {tm.m}), got {tuple(x.shape)}")
    return x


def _check_external(tm, external, B):
    torch = _torch()
    if external is None:
        return None
    if not isinstance(external, torch.Tensor):
        external = torch.as_tensor(np.array(external, dtype=float), dtype=tm.dtype, device=tm.device)
    elif external.device != tm.device:
        raise ValueError(f"external: tensor on device {str(external.device)!r}, but the state is on "
                         f"{str(tm.device)!r}")
    if tuple(external.shape) not in ((tm.n, 3), (B, tm.n, 3), (1, tm.n, 3)):
        raise ValueError(f"external: expected shape ({B}, {tm.n}, 3) or ({tm.n}, 3) (N), got {tuple(external.shape)}")
    return external.to(tm.dtype)


def accelerations(model, q, qd, rest_length=None, force_density=None, external=None, params=None):
    """``[r'', b'']`` (B, k, 6) of torch tensors ``q``, ``qd`` (B, k, 6) (as
    :func:`tensegrity_gym.dynamics.accelerations`; ``params``: see the module doc)."""
    tm, prm, rl, fd = _setup(model, q, params, rest_length, force_density)
    return _accel(tm, q, qd, prm, rl, fd, _check_external(tm, external, q.shape[0]))


def _integrator_name(integrator):
    from .integrators import resolve
    name = resolve(integrator).name
    if name not in ("semi_implicit_euler", "rk4"):
        raise ValueError(f"integrator: {integrator!r} is not available in the torch backend; "
                         "use 'semi_implicit_euler' or 'rk4'")
    return name


def step_once(tm, q, qd, dt, name, prm, rl, fd, ext, project_):
    """One integrator step on prepared inputs (``tm``: :class:`TorchModel`, ``prm``:
    :func:`torch_params`' dict, ``name``: a resolved integrator name, ``rl`` / ``fd`` / ``ext``:
    controls and nodal forces or None): the unit :func:`step` repeats, and what ``torch.compile``
    wraps (``step(..., substep=torch.compile(step_once))``). Returns ``(q, qd)``."""
    if name == "semi_implicit_euler":
        qd = qd + dt * _accel(tm, q, qd, prm, rl, fd, ext)
        if project_:
            q, qd = sphere_drift(q, qd, dt)
        else:
            q = q + dt * qd
    else:
        h = 0.5 * dt
        a1 = _accel(tm, q, qd, prm, rl, fd, ext)
        q2, qd2 = q + h * qd, qd + h * a1
        a2 = _accel(tm, q2, qd2, prm, rl, fd, ext)
        q3, qd3 = q + h * qd2, qd + h * a2
        a3 = _accel(tm, q3, qd3, prm, rl, fd, ext)
        q4, qd4 = q + dt * qd3, qd + dt * a3
        a4 = _accel(tm, q4, qd4, prm, rl, fd, ext)
        q = q + dt / 6.0 * (qd + 2.0 * qd2 + 2.0 * qd3 + qd4)
        qd = qd + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    if project_:
        q, qd = project(tm, q, qd)
    return q, qd


def step(model, q, qd, dt: float, integrator: str = "semi_implicit_euler", n_steps: int = 1, rest_length=None,
         force_density=None, params=None, project: bool = True, external=None, substep=None):
    """Advance torch tensors ``q``, ``qd`` (B, k, 6) by ``n_steps`` fixed steps of ``dt`` s.

    ``integrator``: ``"semi_implicit_euler"`` (great-circle drift when ``project``) or
    ``"rk4"``; ``rest_length`` / ``force_density``: (m,) or (B, m) held over the steps (m, N/m);
    ``external``: (B, n, 3) or (n, 3) nodal forces, N, held; ``params``: per-copy parameters
    (module doc); ``substep``: a replacement for :func:`step_once` with its signature (e.g.
    ``torch.compile(step_once)``). Returns new ``(q, qd)``; differentiable with respect to every
    tensor input."""
    name = _integrator_name(integrator)
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a positive finite time step in seconds, got {dt}")
    if int(n_steps) != n_steps or n_steps < 0:
        raise ValueError(f"n_steps: must be a non-negative integer, got {n_steps}")
    tm, prm, rl, fd = _setup(model, q, params, rest_length, force_density)
    if qd.shape != q.shape or qd.device != q.device or qd.dtype != q.dtype:
        raise ValueError(f"qd: expected shape {tuple(q.shape)}, dtype {q.dtype} on {q.device}, got "
                         f"{tuple(qd.shape)}, {qd.dtype} on {qd.device}")
    ext = _check_external(tm, external, q.shape[0])
    one = step_once if substep is None else substep
    for _ in range(int(n_steps)):
        q, qd = one(tm, q, qd, dt, name, prm, rl, fd, ext, project)
    return q, qd


# ---------------------------------------------------------------------- ground contact
def init_contact_state(tm_or_model, batch_size: int, device=None, dtype=None):
    """``(anchor (B, 2k, 2) m, active (B, 2k) bool)``: no contact active."""
    torch = _torch()
    tm = tm_or_model if isinstance(tm_or_model, TorchModel) else torch_model(tm_or_model, device, dtype)
    nc = 2 * tm.k
    return (torch.zeros((batch_size, nc, 2), dtype=tm.dtype, device=tm.device),
            torch.zeros((batch_size, nc), dtype=torch.bool, device=tm.device))


def contact_forces(contact, model, q, qd, anchor, active, prm=None):
    """Ground contact forces as ``contact._forces_numpy`` (Hunt-Crossley normal force, Coulomb
    friction with a stick anchor): returns ``(W (B, n, 3) N, anchor, active, slip)``, the
    contact state as new tensors. ``contact``: a :class:`tensegrity_gym.contact.GroundContact`.
    ``prm``: None (the contact's own numbers) or a (P, 9) tensor of per-copy parameters in the
    columns of :data:`tensegrity_gym.contact.PRM_FIELDS` (as ``GroundContact.per_copy``; P = 1
    or B; the exponent stays the contact's)."""
    torch = _torch()
    tm = model if isinstance(model, TorchModel) else torch_model(model, q.device, q.dtype)
    B, k = q.shape[0], tm.k
    if prm is None:
        height, radius, kn, dn = contact.height, contact.radius, contact.stiffness, contact.damping
        mu, kt, ct, cmax = contact.friction, contact.tangential_stiffness, contact.tangential_damping, \
            contact.max_damping
    else:
        if not isinstance(prm, torch.Tensor) or prm.device != q.device:
            raise ValueError(f"prm: expected a (P, 9) tensor on {str(q.device)!r} (contact.PRM_FIELDS columns)")
        if prm.ndim != 2 or prm.shape[1] != 9 or prm.shape[0] not in (1, B):
            raise ValueError(f"prm: expected shape (1, 9) or ({B}, 9), got {tuple(prm.shape)}")
        prm = prm.to(q.dtype)
        height, radius, kn, dn, _, mu, kt, ct, cmax = (prm[:, i:i + 1] for i in range(9))
    r, b = q[..., :3], q[..., 3:]
    rd, bd = qd[..., :3], qd[..., 3:]
    # (B, k, 2, 3) -> (B, 2k, 3): rod j end a, rod j end c
    P = torch.stack([r + tm.eta_a * b, r + tm.eta_c * b], dim=2).reshape(B, 2 * k, 3)
    V = torch.stack([rd + tm.eta_a * bd, rd + tm.eta_c * bd], dim=2).reshape(B, 2 * k, 3)
    delta = height + radius - P[..., 2]
    touch = delta > 0.0
    zero = torch.zeros_like(delta)
    dpos = torch.where(touch, delta, zero)
    de = dpos if contact.exponent == 1.0 else dpos ** contact.exponent
    kd = kn * de
    cn = torch.minimum(kd * dn, torch.as_tensor(cmax, dtype=q.dtype, device=q.device))
    Fn = torch.where(touch, torch.clamp(kd - cn * V[..., 2], min=0.0), zero)
    pt = P[..., :2]
    anchor = torch.where((touch & ~active)[..., None], pt, anchor)
    xi = pt - anchor
    kt_, ct_ = (kt, ct) if prm is None else (kt[..., None], ct[..., None])
    Ft = -kt_ * xi - ct_ * V[..., :2]
    nn = Ft[..., 0] * Ft[..., 0] + Ft[..., 1] * Ft[..., 1]
    pos = nn > 0
    norm = torch.where(pos, torch.sqrt(torch.where(pos, nn, torch.ones_like(nn))), zero)
    lim = mu * Fn
    slip = touch & (norm > lim)
    scale = torch.where(slip, lim / torch.where(slip, norm, torch.ones_like(norm)), torch.ones_like(norm))
    Ft = Ft * scale[..., None]
    anchor = torch.where(slip[..., None], pt + Ft / kt_, anchor)
    Ft = torch.where(touch[..., None], Ft, torch.zeros_like(Ft))
    Fc = torch.cat([Ft, Fn[..., None]], dim=-1).reshape(B, k, 2, 3)
    W = tm.gather_nodes(Fc[:, :, 0], Fc[:, :, 1])
    return W, anchor, touch, slip


def contact_step(model, contact, q, qd, anchor, active, dt: float, integrator: str = "semi_implicit_euler",
                 n_steps: int = 1, rest_length=None, force_density=None, params=None, project: bool = True,
                 external=None, contact_prm=None, substep=None):
    """``n_steps`` physics steps with ground contact (as :func:`tensegrity_gym.contact.step`):
    per step, contact forces from the state at its start, held over one integrator step
    (:func:`contact_substep`). ``contact_prm``: per-copy contact parameters (``prm`` of
    :func:`contact_forces`). ``substep``: a replacement for :func:`contact_substep` with its
    signature (e.g. ``torch.compile(contact_substep)``). Returns ``(q, qd, anchor, active)``."""
    name = _integrator_name(integrator)
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be a positive finite time step in seconds, got {dt}")
    tm, prm, rl, fd = _setup(model, q, params, rest_length, force_density)
    ext = _check_external(tm, external, q.shape[0])
    one = contact_substep if substep is None else substep
    for _ in range(int(n_steps)):
        q, qd, anchor, active = one(tm, contact, q, qd, anchor, active, dt, name, prm, rl, fd, ext, contact_prm,
                                    project)
    return q, qd, anchor, active


def contact_substep(tm, contact, q, qd, anchor, active, dt, name, prm, rl, fd, ext, contact_prm, project_):
    """One physics step with ground contact on prepared inputs (``tm``: :class:`TorchModel`,
    ``prm``: :func:`torch_params`' dict, ``name``: a resolved integrator name): contact forces
    from the state at the step's start (plus ``ext``), then one integrator step."""
    W, anchor, active, _ = contact_forces(contact, tm, q, qd, anchor, active, contact_prm)
    if ext is not None:
        W = W + ext
    q, qd = step_once(tm, q, qd, dt, name, prm, rl, fd, W, project_)
    return q, qd, anchor, active


# ---------------------------------------------------------------------- cable motor
_ACTS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _act_tensors(actuation, like) -> dict:
    """The constants of an :class:`~tensegrity_gym.envs.common.Actuation` as tensors on ``like``'s
    device and dtype (cached per actuation, device and dtype: no host copy per call):
    ``low``, ``high``, ``max_rate`` (na,), ``base`` (m,) rest lengths, ``idx`` (na,) int64."""
    torch = _torch()
    per = _ACTS.setdefault(actuation, {})
    key = (str(like.device), str(like.dtype))
    c = per.get(key)
    if c is None:
        def T(x):
            return torch.as_tensor(np.array(x, dtype=float), dtype=like.dtype, device=like.device)
        c = per[key] = {"low": T(actuation.low), "high": T(actuation.high), "max_rate": T(actuation.max_rate),
                        "base": T(actuation.base_rest_length),
                        "idx": torch.as_tensor(np.array(actuation.actuated, dtype=np.int64), device=like.device)}
    return c


def motor(actuation, ctrl, speed, action, max_rate=None, max_accel=None):
    """The cable motor (``Actuation.apply_motor``) on tensors (B, na): rate toward the command
    ``action * max_rate`` by at most ``max_accel * control_dt``, control moved by
    ``rate * control_dt`` and clipped to [low, high], rate zeroed at an end stop. Returns
    ``(new control, new rate)``. ``max_rate`` (P, na) unit/s and ``max_accel`` (P, 1) unit/s^2:
    per-copy limits as tensors (``Actuation.set_copy_limits``); None: the actuation's nominal ones."""
    torch = _torch()
    if actuation.max_accel is None:
        raise ValueError("motor: this Actuation has no max_accel (no motor model)")
    c = _act_tensors(actuation, ctrl)
    low, high = c["low"], c["high"]
    rate = c["max_rate"] if max_rate is None else max_rate
    if max_accel is None:
        dv = actuation.max_accel * actuation.control_dt
        v = speed + torch.clamp(action * rate - speed, -dv, dv)
    else:
        dv = max_accel * actuation.control_dt
        v = speed + torch.minimum(torch.maximum(action * rate - speed, -dv), dv)
    new = torch.minimum(torch.maximum(ctrl + v * actuation.control_dt, low), high)
    stop = ((new <= low) & (v < 0.0)) | ((new >= high) & (v > 0.0))
    v = torch.where(stop, torch.zeros_like(v), v)
    return new, v


def advance(actuation, ctrl, action, max_rate=None):
    """The control update without a motor model (``Actuation.apply``): ``clip(ctrl + action *
    max_rate * control_dt, low, high)`` on tensors (B, na); ``max_rate`` (P, na) per-copy rate
    limits (unit/s) or None (the nominal ones)."""
    torch = _torch()
    c = _act_tensors(actuation, ctrl)
    rate = (c["max_rate"] if max_rate is None else max_rate) * actuation.control_dt
    return torch.minimum(torch.maximum(ctrl + action * rate, c["low"]), c["high"])


def physics_inputs(actuation, ctrl) -> dict:
    """``rest_length`` (B, m) or ``force_density`` (B, m) tensors from the actuated controls
    (B, na) (``Actuation.physics_inputs``), differentiable in ``ctrl``."""
    c = _act_tensors(actuation, ctrl)
    B = ctrl.shape[0]
    if actuation.mode == "rest_length":
        return {"rest_length": c["base"].expand(B, -1).index_copy(1, c["idx"], ctrl)}
    fd = ctrl.new_zeros((B, actuation.n_strings)).index_copy(1, c["idx"], ctrl)
    return {"rest_length": None, "force_density": fd}


# ---------------------------------------------------------------------- numpy State in / out
def step_state(model, state, dt, integrator="semi_implicit_euler", *, rest_length=None, force_density=None,
               external=None, project=True, n_steps=1, device=None, dtype=None, params=None):
    """``integrators.step`` contract on a NumPy :class:`~tensegrity_gym.dynamics.State`: the state is
    copied to ``device`` / ``dtype`` (default CPU, float64), stepped by :func:`step`, and copied
    back as float64 NumPy arrays. ``external`` must be an array (a callable is not supported)."""
    torch = _torch()
    from .dynamics import State
    if callable(external):
        raise ValueError("external: a callable is not supported by backend='torch'; pass a (B, n, 3) array")
    dev, dty = resolve_device(device), resolve_dtype(dtype)
    q = torch.as_tensor(np.array(state.q, dtype=float), device=dev).to(dty)
    qd = torch.as_tensor(np.array(state.qd, dtype=float), device=dev).to(dty)
    with torch.no_grad():
        q, qd = step(model, q, qd, dt, integrator, n_steps, rest_length, force_density, params, project, external)
    t = state.t
    for _ in range(int(n_steps)):
        t = t + dt
    return State(q=q.to(torch.float64).cpu().numpy(), qd=qd.to(torch.float64).cpu().numpy(), t=t)


def simulate(model, state, dt, n_steps, integrator="rk4", *, record_every=1, rest_length=None,
             force_density=None, project=True, device=None, dtype=None, params=None):
    """``integrators.simulate`` on the torch backend: ``(t (S,), q, qd (S, B, k, 6))`` as NumPy
    float64, the state kept on the device between records. Raises
    :class:`~tensegrity_gym.integrators.SimulationDiverged` when the state stops being finite."""
    torch = _torch()
    from .integrators import SimulationDiverged
    if int(n_steps) != n_steps or n_steps < 0:
        raise ValueError(f"n_steps: must be a non-negative integer, got {n_steps}")
    if int(record_every) != record_every or record_every < 1:
        raise ValueError(f"record_every: must be a positive integer, got {record_every}")
    dev, dty = resolve_device(device), resolve_dtype(dtype)
    n_rec = n_steps // record_every
    ts = state.t + dt * record_every * np.arange(n_rec + 1)
    q = torch.as_tensor(np.array(state.q, dtype=float), device=dev).to(dty)
    qd = torch.as_tensor(np.array(state.qd, dtype=float), device=dev).to(dty)
    qs = np.empty((n_rec + 1,) + tuple(state.q.shape))
    qds = np.empty_like(qs)
    qs[0], qds[0] = state.q, state.qd
    with torch.no_grad():
        for i in range(1, n_rec + 1):
            q, qd = step(model, q, qd, dt, integrator, record_every, rest_length, force_density, params, project)
            qs[i], qds[i] = q.to(torch.float64).cpu().numpy(), qd.to(torch.float64).cpu().numpy()
            if not (np.all(np.isfinite(qs[i])) and np.all(np.isfinite(qds[i]))):
                raise SimulationDiverged(f"{integrator}: state became non-finite between t = {ts[i - 1]:.6g} s and "
                                         f"t = {ts[i]:.6g} s (dt = {dt:g} s, torch backend)")
    return ts, qs, qds
