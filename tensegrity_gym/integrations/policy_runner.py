"""Run a policy exported by ``python -m agents.export``: observation in, action out.

The exported file holds the whole map from a raw observation (SI units, the layout of the
spec's ``observation.layout``) to the action the env takes (in its action space, [-1, 1] per
actuated string): the VecNormalize observation normalisation, the actor network and the
action scaling (PPO/A2C: the Gaussian mean clipped to the action space; SAC: the tanh-squashed
mean mapped to it; TD3/DDPG: the tanh output mapped to it), as Stable-Baselines3's
``model.predict(vecnormalize.normalize_obs(obs), deterministic=True)`` computes it. Beside
it, ``<file>.json`` is its spec (observation layout and units, action meaning, control rate,
the latency it was trained with, the env and its arguments).

:class:`PolicyRunner` loads a file and its spec and runs it with

* ``onnxruntime`` for an ``.onnx`` file (``--format onnx``),
* ``torch`` for a TorchScript ``.pt`` file (``--format torchscript``),
* NumPy alone for an ``.npz`` file (``--format npz``: the weights, activations and
  normalisation as arrays and a JSON program; no other package needed).

This module imports nothing but NumPy and the standard library (onnxruntime or torch only when
such a file is loaded): the file can be copied onto a robot's computer and imported there
without Stable-Baselines3, torch or the rest of tensegrity_gym.

Example::

    runner = PolicyRunner("policy.npz")          # reads policy.npz.json beside it
    action = runner(obs)                          # (obs_size,) -> (action_size,) float32
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

__all__ = ["FORMATS", "FORMAT_VERSION", "PolicyRunner", "load_spec", "open_policy", "spec_path", "npz_forward", "sha256_of"]

#: export format -> (file suffix, package that runs it; None: NumPy alone)
FORMATS = {"onnx": (".onnx", "onnxruntime"), "torchscript": (".pt", "torch"), "npz": (".npz", None)}
#: version of the spec and of the npz program; a runner refuses a newer one
FORMAT_VERSION = 1

#: the elementwise activations of the npz program (float64 in, float64 out)
_ACTIVATIONS = {
    "tanh": lambda x, p: np.tanh(x),
    "relu": lambda x, p: np.maximum(x, 0.0),
    "elu": lambda x, p: np.where(x > 0.0, x, p["alpha"] * np.expm1(np.minimum(x, 0.0))),
    "leaky_relu": lambda x, p: np.where(x >= 0.0, x, p["negative_slope"] * x),
    "silu": lambda x, p: x / (1.0 + np.exp(-x)),
    "sigmoid": lambda x, p: 1.0 / (1.0 + np.exp(-x)),
    "hardtanh": lambda x, p: np.clip(x, p["min_val"], p["max_val"]),
    "identity": lambda x, p: x,
}


def spec_path(policy_path: str | Path) -> Path:
    """The spec written beside an exported policy: ``<file>.json`` (``policy.onnx.json``)."""
    p = Path(policy_path)
    return p.with_name(p.name + ".json")


def sha256_of(path: str | Path) -> str:
    """Hex SHA-256 of a file (the spec records the one of its policy file)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def load_spec(path: str | Path) -> dict:
    """The spec (a dict) of an exported policy: ``path`` is the spec itself (``.json``) or the
    policy file beside it. FileNotFoundError / ValueError naming the file otherwise."""
    p = Path(path)
    sp = p if p.suffix == ".json" else spec_path(p)
    if not sp.is_file():
        raise FileNotFoundError(f"{sp}: no spec (the .json agents.export writes beside {p.name})")
    try:
        spec = json.loads(sp.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ValueError(f"{sp}: not a policy spec ({type(e).__name__}: {e})") from None
    if not isinstance(spec, dict) or spec.get("format") not in FORMATS or "file" not in spec:
        raise ValueError(f"{sp}: not a policy spec of agents.export (no 'format' in {sorted(FORMATS)} and 'file')")
    if int(spec.get("format_version", 0)) > FORMAT_VERSION:
        raise ValueError(f"{sp}: format_version {spec['format_version']} is newer than this runner's "
                         f"{FORMAT_VERSION}; update tensegrity_gym")
    return spec


# ---------------------------------------------------------------------- the npz program
def npz_forward(program: dict, arrays, obs: np.ndarray) -> np.ndarray:
    """Action (B, na) float32 of raw observations ``obs`` (B, n) under the npz ``program``
    (its JSON dict) with its ``arrays`` (name -> array). The normalisation is Stable-Baselines3's
    VecNormalize ``normalize_obs`` (float64, then float32); the network runs in float64."""
    x = np.asarray(obs, np.float32)
    norm = program.get("normalize")
    if norm is not None:
        mean, var = arrays[norm["mean"]], arrays[norm["var"]]
        x = np.clip((x - mean) / np.sqrt(var + norm["epsilon"]), -norm["clip"], norm["clip"]).astype(np.float32)
    h = x.astype(np.float64)
    for layer in program["layers"]:
        op = layer["op"]
        if op == "linear":
            h = h @ arrays[layer["weight"]].astype(np.float64).T + arrays[layer["bias"]].astype(np.float64)
        elif op in _ACTIVATIONS:
            h = _ACTIVATIONS[op](h, layer)
        else:
            raise ValueError(f"npz program: unknown op {op!r}; known: linear, {', '.join(_ACTIVATIONS)}")
    out = program["output"]
    low, high = arrays[out["low"]], arrays[out["high"]]
    a = (np.tanh(h) if out["squash"] else h).astype(np.float32)
    if out["rescale"] == "unscale":       # [-1, 1] -> [low, high], as SB3's unscale_action
        return low + (np.float32(0.5) * (a + np.float32(1.0)) * (high - low))
    if out["rescale"] == "clip":          # SB3's predict for an unsquashed Gaussian
        return np.clip(a, low, high)
    raise ValueError(f"npz program: unknown output rescale {out['rescale']!r}; known: unscale, clip")


class _NpzPolicy:
    def __init__(self, path: Path):
        with np.load(path, allow_pickle=False) as z:
            self.arrays = {k: z[k] for k in z.files}
        if "program" not in self.arrays:
            raise ValueError(f"{path}: no 'program' entry (not an npz policy of agents.export)")
        self.program = json.loads(str(self.arrays.pop("program")))
        if int(self.program.get("format_version", 0)) > FORMAT_VERSION:
            raise ValueError(f"{path}: format_version {self.program['format_version']} is newer than this "
                             f"runner's {FORMAT_VERSION}; update tensegrity_gym")

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return npz_forward(self.program, self.arrays, obs)


class _OnnxPolicy:
    def __init__(self, path: Path):
        try:
            import onnxruntime as ort
        except ImportError:
            raise ImportError(f"{path}: running an ONNX policy needs onnxruntime (pip install onnxruntime); "
                              "or export with --format npz, which runs on NumPy alone") from None
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1       # one small network per control step: threads cost more than they give
        self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        self.input = self.session.get_inputs()[0].name

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.session.run(None, {self.input: np.asarray(obs, np.float32)})[0]


class _TorchScriptPolicy:
    def __init__(self, path: Path):
        try:
            import torch
        except ImportError:
            raise ImportError(f"{path}: running a TorchScript policy needs torch (pip install torch); "
                              "or export with --format npz, which runs on NumPy alone") from None
        import warnings
        self.torch = torch
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)   # torch's note that TorchScript is deprecated
            self.module = torch.jit.load(str(path), map_location="cpu").eval()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        with self.torch.no_grad():
            return self.module(self.torch.as_tensor(np.asarray(obs, np.float32))).numpy()


_BACKENDS = {"onnx": ("onnxruntime", _OnnxPolicy), "torchscript": ("torch", _TorchScriptPolicy),
             "npz": ("numpy", _NpzPolicy)}


def open_policy(path: str | Path, fmt: str):
    """(backend name, callable) of the exported file ``path`` in format ``fmt``, without its
    spec: the callable maps float32 observations (B, n) to actions (B, na). ImportError saying
    what to install when the format's backend is missing."""
    if fmt not in _BACKENDS:
        raise ValueError(f"fmt: unknown {fmt!r}; choose one of {sorted(_BACKENDS)}")
    backend, cls = _BACKENDS[fmt]
    return backend, cls(Path(path))


class PolicyRunner:
    """An exported policy and its spec.

    ``path``: the exported file (``.onnx``, ``.pt``, ``.npz``) or its spec (``<file>.json``).
    The spec must lie beside the file and name it (its SHA-256 is checked: a spec of another
    export is refused). The backend follows the format: onnxruntime, torch (TorchScript) or
    NumPy (npz); ImportError saying what to install when it is missing.

    Attributes: ``spec`` (dict), ``backend`` (``"onnxruntime"``, ``"torch"`` or ``"numpy"``),
    ``obs_size``, ``action_size``, ``control_dt`` (s, one control step; None if the env has none),
    ``path`` (the policy file).
    """

    def __init__(self, path: str | Path):
        p = Path(path)
        self.spec = load_spec(p)
        base = p.parent
        self.path = base / self.spec["file"]
        if not self.path.is_file():
            raise FileNotFoundError(f"{self.path}: the policy file its spec names is missing")
        digest = self.spec.get("sha256")
        if digest is not None and sha256_of(self.path) != digest:
            raise ValueError(f"{self.path}: does not match its spec {spec_path(self.path).name} (SHA-256 differs): "
                             "export the policy again")
        self.backend, self._policy = open_policy(self.path, self.spec["format"])
        self.obs_size = int(self.spec["observation"]["size"])
        self.action_size = int(self.spec["action"]["size"])
        self.control_dt = self.spec.get("control", {}).get("control_dt")

    def act(self, obs) -> np.ndarray:
        """The action for ``obs``: (obs_size,) -> (action_size,), or a batch (B, obs_size) ->
        (B, action_size); float32. ValueError naming ``obs`` for a wrong shape or a non-finite
        entry (a sensor fault must not reach the motors as a NaN command)."""
        x = np.asarray(obs, dtype=np.float32)
        single = x.ndim == 1
        if x.ndim not in (1, 2) or x.shape[-1] != self.obs_size:
            raise ValueError(f"obs: expected shape ({self.obs_size},) or (B, {self.obs_size}), got {x.shape}")
        bad = ~np.isfinite(x)
        if bad.any():
            idx = np.argwhere(bad)[0]
            raise ValueError(f"obs: non-finite entry {float(x[tuple(idx)])!r} at index {tuple(int(i) for i in idx)}")
        a = np.asarray(self._policy(x[None] if single else x), dtype=np.float32)
        return a[0] if single else a

    __call__ = act
