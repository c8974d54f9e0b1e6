"""Device, dtype and the model's constants as tensors (:class:`TorchModel`, cached per model,
device and dtype), per-copy parameters as tensors (:func:`torch_params`). torch is imported
lazily (:func:`torch_module`): the core install never needs it.
"""
from __future__ import annotations

import weakref

import numpy as np

from ...core.param_table import physics_fields, skipped_fields

__all__ = ["torch_module", "resolve_device", "resolve_dtype", "TorchModel", "torch_model", "torch_params",
           "mass_moments", "PARAM_FIELDS"]

#: the Params fields, in order (a view of tensegrity_gym.core.param_table)
PARAM_FIELDS = physics_fields()
#: the fields whose term the equations skip where it is 0: ``torch_params`` sets ``has_<field>``
SKIPPED = skipped_fields()


def torch_module():
    """The ``torch`` module; ImportError naming the install extra when PyTorch is missing."""
    try:
        import torch
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ImportError("backend='torch' needs PyTorch: pip install 'tensegrity_gym[torch]' "
                          "(or pip install torch)") from exc
    return torch




_torch = torch_module


def resolve_device(device=None):
    """A ``torch.device`` from None (CPU), a string or a device; ValueError if CUDA (or another
    accelerator) is requested where none exists. The device is spelled as its tensors report it:
    a bare ``"cuda"`` resolves to the current CUDA device with its index (``cuda:0``), ``"cpu:0"``
    to ``cpu``."""
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
    else:
        dev = torch.device("cpu")   # 'cpu:0' -> 'cpu': CPU tensors report no index
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
    """The topology constants of a :class:`~tensegrity_gym.core.model.Model` as tensors on one
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
        self.flags = {f: model.nominal.may_be_nonzero(f) for f in SKIPPED}   # the model's "may be non-zero"
        self.defaults = {name: T(getattr(model.nominal, name)) for name in PARAM_FIELDS}   # (1, ...) nominal

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
        want = tuple(tm.defaults[name].shape[1:])
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
    for f in SKIPPED:   # ("given" maps a provided field to "may be non-zero")
        out["has_" + f] = tm.flags[f] or given.get(f, False)
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


