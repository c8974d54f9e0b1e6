"""A trained SB3 policy as a program of arrays (:func:`actor_program`): the VecNormalize
observation normalisation, the actor's layers and activations and SB3's deterministic action
scaling, and that program as a torch module or a serialized file (npz, TorchScript, ONNX) for
:mod:`agents.export`."""
from __future__ import annotations

import importlib.util
import io
import json
import warnings
from pathlib import Path

import numpy as np

from tensegrity_gym.integrations import policy_runner

__all__ = ["actor_program", "torch_module", "check_writer", "serialize"]

_ACTIVATION_MODULES = {"Tanh": "tanh", "ReLU": "relu", "ELU": "elu", "LeakyReLU": "leaky_relu", "SiLU": "silu",
                       "Sigmoid": "sigmoid", "Hardtanh": "hardtanh", "Identity": "identity", "Flatten": "identity"}


# ---------------------------------------------------------------------- SB3 model -> program
def _layers(module, out: list, arrays: dict) -> None:
    """Append the ops of ``module`` (an ``nn.Sequential`` of ``Linear`` and activations) to the
    npz program's ``out``; its weights to ``arrays``."""
    from torch import nn
    if isinstance(module, nn.Sequential):
        for m in module:
            _layers(m, out, arrays)
        return
    kind = type(module).__name__
    if isinstance(module, nn.Linear):
        name = f"layer{len(out)}"
        w = module.weight.detach().cpu().numpy().astype(np.float32)
        b = (module.bias.detach().cpu().numpy() if module.bias is not None else np.zeros(w.shape[0])).astype(np.float32)
        arrays[f"{name}_weight"], arrays[f"{name}_bias"] = w, b
        out.append({"op": "linear", "weight": f"{name}_weight", "bias": f"{name}_bias"})
    elif kind in _ACTIVATION_MODULES and type(module).__module__.startswith("torch.nn"):
        op = {"op": _ACTIVATION_MODULES[kind]}
        if kind == "ELU":
            op["alpha"] = float(module.alpha)
        elif kind == "LeakyReLU":
            op["negative_slope"] = float(module.negative_slope)
        elif kind == "Hardtanh":
            op["min_val"], op["max_val"] = float(module.min_val), float(module.max_val)
        elif kind == "Flatten" and (module.start_dim, module.end_dim) != (1, -1):
            raise ValueError(f"the policy holds Flatten(start_dim={module.start_dim}, end_dim={module.end_dim}); "
                             "export supports only Flatten() of a flat observation")
        if op["op"] != "identity":
            out.append(op)
    else:
        raise ValueError(f"the policy holds a {kind} layer, which export does not support (supported: Linear, "
                         f"{', '.join(k for k in _ACTIVATION_MODULES if k != 'Identity')}, Identity)")


def _check_extractor(extractor) -> None:
    from stable_baselines3.common.torch_layers import FlattenExtractor
    if not isinstance(extractor, FlattenExtractor):
        raise ValueError(f"the policy's features extractor is a {type(extractor).__name__}; export supports "
                         "FlattenExtractor (MlpPolicy) only")


def actor_program(model, vecnormalize=None) -> tuple[dict, dict]:
    """(program, arrays) of the npz format: the deterministic action of ``model`` (an SB3 PPO,
    A2C, SAC, TD3, DDPG or TQC with an ``MlpPolicy``) for a raw observation, with the
    observation normalisation of ``vecnormalize`` (None or ``norm_obs=False``: none).
    ValueError for what cannot be exported (a non-Box space, another features extractor or layer)."""
    from gymnasium import spaces
    from stable_baselines3.common.distributions import (DiagGaussianDistribution, SquashedDiagGaussianDistribution,
                                                        StateDependentNoiseDistribution)
    from stable_baselines3.common.policies import ActorCriticPolicy

    policy = model.policy
    obs_space, act_space = policy.observation_space, policy.action_space
    if not isinstance(obs_space, spaces.Box) or len(obs_space.shape) != 1:
        raise ValueError(f"the policy observes a {obs_space}; export supports a flat Box observation only")
    if not isinstance(act_space, spaces.Box) or len(act_space.shape) != 1:
        raise ValueError(f"the policy acts in a {act_space}; export supports a flat Box action space only")
    layers: list = []
    arrays: dict = {}
    if isinstance(policy, ActorCriticPolicy):             # PPO, A2C: the Gaussian's mean
        _check_extractor(policy.pi_features_extractor)
        _layers(policy.mlp_extractor.policy_net, layers, arrays)
        _layers(policy.action_net, layers, arrays)
        dist = policy.action_dist
        if isinstance(dist, StateDependentNoiseDistribution):
            squash = dist.bijector is not None           # gSDE with squash_output: tanh of the mean
        elif isinstance(dist, DiagGaussianDistribution):
            squash = False
        else:
            raise ValueError(f"the policy's action distribution is a {type(dist).__name__}; export supports "
                             "Gaussian (continuous) policies only")
    elif hasattr(policy, "actor") and hasattr(policy.actor, "mu"):
        actor = policy.actor
        _check_extractor(actor.features_extractor)
        if hasattr(actor, "latent_pi"):                   # SAC, TQC: tanh of the Gaussian's mean
            _layers(actor.latent_pi, layers, arrays)
            _layers(actor.mu, layers, arrays)
            if not isinstance(actor.action_dist, (SquashedDiagGaussianDistribution, StateDependentNoiseDistribution)):
                raise ValueError(f"the actor's action distribution is a {type(actor.action_dist).__name__}; "
                                 "export supports the squashed Gaussian of SAC")
            squash = True
        else:                                             # TD3, DDPG: mu ends in Tanh
            _layers(actor.mu, layers, arrays)
            squash = False
    else:
        raise ValueError(f"{type(model).__name__} with a {type(policy).__name__}: export supports PPO, A2C, SAC, "
                         "TD3, DDPG and TQC with an MlpPolicy")
    n = int(obs_space.shape[0])
    normalize = None
    if vecnormalize is not None and vecnormalize.norm_obs:
        rms = vecnormalize.obs_rms
        if isinstance(rms, dict):
            raise ValueError("the VecNormalize statistics are per key of a dict observation; export supports "
                             "a flat observation only")
        arrays["obs_mean"] = np.asarray(rms.mean, np.float64).reshape(n)
        arrays["obs_var"] = np.asarray(rms.var, np.float64).reshape(n)
        normalize = {"mean": "obs_mean", "var": "obs_var", "epsilon": float(vecnormalize.epsilon),
                     "clip": float(vecnormalize.clip_obs)}
    arrays["action_low"] = np.asarray(act_space.low, np.float32)
    arrays["action_high"] = np.asarray(act_space.high, np.float32)
    program = {"format_version": policy_runner.FORMAT_VERSION, "obs_size": n, "action_size": int(act_space.shape[0]),
               "normalize": normalize, "layers": layers,
               "output": {"squash": bool(squash), "rescale": "unscale" if policy.squash_output else "clip",
                          "low": "action_low", "high": "action_high"}}
    return program, arrays


# ---------------------------------------------------------------------- program -> torch module
def torch_module(program: dict, arrays: dict):
    """The program as a ``torch.nn.Module`` (float32 observation (B, n) -> float32 action (B, na)):
    the normalisation in float64 then float32 as VecNormalize computes it, the network in float32
    as SB3 runs it, the output clip or tanh + affine map as SB3's ``predict``."""
    import torch
    from torch import nn

    class Normalize(nn.Module):
        def __init__(self, mean, var, epsilon, clip):
            super().__init__()
            self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float64))
            self.register_buffer("std", torch.as_tensor(np.sqrt(var + epsilon), dtype=torch.float64))
            self.clip = float(clip)

        def forward(self, x):
            return torch.clamp((x.to(torch.float64) - self.mean) / self.std, -self.clip, self.clip).to(torch.float32)

    class Output(nn.Module):
        def __init__(self, squash, rescale, low, high):
            super().__init__()
            self.squash, self.unscale = bool(squash), rescale == "unscale"
            self.register_buffer("low", torch.as_tensor(low, dtype=torch.float32))
            self.register_buffer("high", torch.as_tensor(high, dtype=torch.float32))
            self.register_buffer("span", torch.as_tensor(high - low, dtype=torch.float32))

        def forward(self, a):
            if self.squash:
                a = torch.tanh(a)
            if self.unscale:
                return self.low + (0.5 * (a + 1.0) * self.span)
            return torch.minimum(torch.maximum(a, self.low), self.high)

    acts = {"tanh": lambda p: nn.Tanh(), "relu": lambda p: nn.ReLU(), "elu": lambda p: nn.ELU(p["alpha"]),
            "leaky_relu": lambda p: nn.LeakyReLU(p["negative_slope"]), "silu": lambda p: nn.SiLU(),
            "sigmoid": lambda p: nn.Sigmoid(), "hardtanh": lambda p: nn.Hardtanh(p["min_val"], p["max_val"]),
            "identity": lambda p: nn.Identity()}
    mods = []
    norm = program["normalize"]
    if norm is not None:
        mods.append(Normalize(arrays[norm["mean"]], arrays[norm["var"]], norm["epsilon"], norm["clip"]))
    for layer in program["layers"]:
        if layer["op"] == "linear":
            w, b = arrays[layer["weight"]], arrays[layer["bias"]]
            lin = nn.Linear(w.shape[1], w.shape[0])
            with torch.no_grad():
                lin.weight.copy_(torch.as_tensor(w))
                lin.bias.copy_(torch.as_tensor(b))
            mods.append(lin)
        else:
            mods.append(acts[layer["op"]](layer))
    out = program["output"]
    mods.append(Output(out["squash"], out["rescale"], arrays[out["low"]], arrays[out["high"]]))
    return nn.Sequential(*mods).eval()


def check_writer(fmt: str) -> None:
    """ImportError saying what to install if format ``fmt`` cannot be written here."""
    if fmt == "onnx" and importlib.util.find_spec("onnx") is None:
        raise ImportError("--format onnx: writing ONNX needs the onnx package (pip install onnx onnxscript; "
                          "onnxruntime to run the file); or use --format torchscript or --format npz")


def serialize(fmt: str, program: dict, arrays: dict) -> bytes:
    """The exported file's bytes in format ``fmt`` (``onnx``, ``torchscript`` or ``npz``)."""
    buf = io.BytesIO()
    if fmt == "npz":
        np.savez(buf, program=np.array(json.dumps(program)), **arrays)
        return buf.getvalue()
    import torch
    module = torch_module(program, arrays)
    example = torch.zeros((2, program["obs_size"]), dtype=torch.float32)
    if fmt == "torchscript":
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)   # torch's note that TorchScript is deprecated
            torch.jit.save(torch.jit.trace(module, example), buf)
        return buf.getvalue()
    check_writer(fmt)
    import tempfile
    # torch's current exporter when onnxscript is installed, else the TorchScript-based one (onnx alone)
    dynamo = importlib.util.find_spec("onnxscript") is not None
    with tempfile.TemporaryDirectory() as tmp, torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")       # the exporters' notes on their own versions
        path = Path(tmp) / "policy.onnx"
        torch.onnx.export(module, (example,), str(path), dynamo=dynamo, external_data=False, input_names=["obs"],
                          output_names=["action"], dynamic_axes={"obs": {0: "batch"}, "action": {0: "batch"}})
        return path.read_bytes()


# ---------------------------------------------------------------------- the spec
