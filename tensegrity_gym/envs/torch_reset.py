"""Resets drawn on the device (``reset_sampling="device"`` of the torch vector envs; SI units).

By default (``reset_sampling="host"``) a torch vector env draws each reset env's noise, goal and
randomised robot parameters on the host, from that env's NumPy generator, exactly as the NumPy
vector env, and copies the reset rows to the device (:mod:`tensegrity_gym.envs.torch_vec`).
That costs a Python loop over the reset envs (14-35 us per env on a 2-core CPU), and when
every env of a large batch reaches the time limit in the same step, seconds.

With ``reset_sampling="device"`` the reset runs on the device, with no host loop and no copy of
reset rows; its random numbers come from :class:`CounterStreams`:

* **Per-env streams, keyed by the seed.** ``reset(seed=s)`` keys env i with ``s + i`` (a list
  keys each env; None keeps the key; an env never keyed gets a random key at its first reset,
  from the operating system's entropy), the same rule as the NumPy envs' generators.
* **Counter-based.** The k-th reset of an env after it was keyed reads the uniforms
  ``u_j = U(key, k, j)``, j = 0, 1, ..., where ``U`` is SplitMix64's output function (Steele,
  Lea & Flood 2014; the generator Java's ``SplittableRandom`` uses) applied to the key, the reset
  count and the draw index (:func:`reference_uniforms` is the definition, in plain Python
  integers). Nothing is carried from one draw to the next, so the numbers an env reads depend
  only on its key and how many times it was reset: not on ``num_envs``, not on which other envs
  reset in the same step, not on the device (the uniforms are bit-identical on CPU and CUDA:
  64-bit integer arithmetic), and not on thread counts.
* **Not the NumPy generators' numbers.** A device reset draws the same *distributions* as the
  host reset (the task's noise, goal and :mod:`~tensegrity_gym.envs.domain` draws, same order
  of names and items), from other numbers. ``tests/test_torch_reset.py`` checks that a host reset
  fed these numbers gives the device reset's state, observation and infos to round-off.

:class:`TorchDomain` is the device side of :class:`~tensegrity_gym.envs.domain.Domain`: the
randomised parameter values of the reset envs drawn from the uniforms and written into the env's
per-copy tensors (the physics ``Params`` rows, the cables' rest-length offsets, the contact
parameters, the motor limits, the rods' mass fractions) by the host's writer,
:func:`~tensegrity_gym.envs.domain.write_copies`, with the device tensors as its sink.
"""
from __future__ import annotations

import numpy as np

from ..backends.torch.model import mass_moments, torch_module
from ..core.param_table import contact_columns
from ..tasks.randomization import draw_count, draw_range, values_from_draws
from .domain import write_copies
from .shells import per_env_seeds
from .vector_rules import check_seed_value

__all__ = ["CounterStreams", "TorchDomain", "reference_uniforms", "RESET_SAMPLING", "SALTS"]

RESET_SAMPLING = ("host", "device")

_MASK64 = (1 << 64) - 1
_GOLDEN = 0x9E3779B97F4A7C15      # SplitMix64's increment (2^64 / golden ratio, odd)
_M1 = 0xBF58476D1CE4E5B9           # SplitMix64's output-function multipliers
_M2 = 0x94D049BB133111EB
_EPISODE = 0xD1B54A32D192ED03      # odd multiplier of the reset count (another Weyl sequence)
_STEP = 0xA0761D6478BD642F         # odd multiplier of the step count (sensor noise)
#: per use, keys are not the seeds themselves (nor the NumPy streams', nor each other's)
SALTS = {"reset": 0x7A3C5E0F12D4B689, "sensor_noise": 0x3C6EF372FE94F82B}


def _signed(x: int) -> int:
    """A 64-bit pattern as the int64 value with the same bits."""
    x &= _MASK64
    return x - (1 << 64) if x >> 63 else x


def _mix_int(z: int) -> int:
    """SplitMix64's output function on a Python int (mod 2^64)."""
    z &= _MASK64
    z = ((z ^ (z >> 30)) * _M1) & _MASK64
    z = ((z ^ (z >> 27)) * _M2) & _MASK64
    return z ^ (z >> 31)


def reference_uniforms(seed: int, reset: int, n: int, step: int | None = None, use: str = "reset") -> np.ndarray:
    """The definition of the device streams, in Python integers: the ``n`` uniforms in [0, 1)
    that the ``reset``-th reset (0 first) of an env keyed with ``seed`` reads (``use="reset"``),
    or that its sensor noise reads at step ``step`` of its ``reset``-th episode
    (``use="sensor_noise"``). Key ``K = mix(seed ^ SALT[use])``, stream ``S = mix(K + (reset + 1)
    C)`` (then ``S = mix(S + (step + 1) D)`` with a step), ``u_j = (mix(S + (j + 1) G) >> 11)
    2^-53`` with SplitMix64's ``mix`` and increment ``G``."""
    key = _mix_int((int(seed) & _MASK64) ^ SALTS[use])
    st = _mix_int(key + (int(reset) + 1) * _EPISODE)
    if step is not None:
        st = _mix_int(st + (int(step) + 1) * _STEP)
    return np.array([(_mix_int(st + (j + 1) * _GOLDEN) >> 11) * 2.0 ** -53 for j in range(int(n))])


def _lsr(z, k: int):
    """Logical right shift of an int64 tensor (torch's ``>>`` is arithmetic)."""
    return (z >> k) & ((1 << (64 - k)) - 1)


def _mix(z):
    """SplitMix64's output function on an int64 tensor (wrapping products: the bits of the uint64 ones)."""
    z = (z ^ _lsr(z, 30)) * _signed(_M1)
    z = (z ^ _lsr(z, 27)) * _signed(_M2)
    return z ^ _lsr(z, 31)


_check_seed = check_seed_value   # the vector envs' per-env seed check (one implementation)


class CounterStreams:
    """Per-env counter-based random streams on a torch device (see the module doc).

    ``keys`` (N,) int64: each env's key; ``resets`` (N,) int64: how many resets it drew since it
    was keyed; ``use``: ``"reset"`` or ``"sensor_noise"`` (another salt: other numbers from the
    same seeds)."""

    def __init__(self, num_envs: int, device, use: str = "reset"):
        torch = torch_module()
        self.num_envs = int(num_envs)
        self.device = device
        self.salt = SALTS[use]
        self.keys = torch.zeros(self.num_envs, dtype=torch.int64, device=device)
        self.resets = torch.zeros(self.num_envs, dtype=torch.int64, device=device)
        self._keyed = np.zeros(self.num_envs, bool)

    def seed(self, seed, mask: np.ndarray) -> None:
        """Key the envs selected by ``mask`` (N,) bool from ``seed`` (the vector envs' rule: an
        int s keys env i with s + i, a list keys each env (None: keep), None keeps every key;
        envs still unkeyed afterwards get random keys). Rekeyed envs start again at reset 0."""
        torch = torch_module()
        N = self.num_envs
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            _check_seed(seed, 0)
        seeds = per_env_seeds(seed, N)
        chosen = np.array([bool(mask[i]) and seeds[i] is not None for i in range(N)])
        fresh = np.asarray(mask, bool) & ~chosen & ~self._keyed
        if not (chosen.any() or fresh.any()):
            return
        raw = np.zeros(N, dtype=np.uint64)
        for i in np.flatnonzero(chosen):
            raw[i] = _check_seed(seeds[i], i) & _MASK64
        if fresh.any():
            raw[fresh] = np.random.SeedSequence().generate_state(int(fresh.sum()), np.uint64)
        sel = chosen | fresh
        idx = torch.as_tensor(np.flatnonzero(sel), dtype=torch.int64, device=self.device)
        vals = torch.as_tensor(raw[sel].view(np.int64), device=self.device)
        self.keys[idx] = _mix(vals ^ _signed(self.salt))
        self.resets[idx] = 0
        self._keyed |= sel

    def uniform(self, it, n: int):
        """(len(it), n) float64 uniforms in [0, 1) of the next reset of envs ``it`` (an int64
        index tensor on the device); counts that reset."""
        u = self.uniform_at(self.keys[it], self.resets[it], None, n)
        self.resets[it] = self.resets[it] + 1
        return u

    @staticmethod
    def uniform_at(keys, resets, steps, n: int):
        """(r, n) float64 uniforms of envs with ``keys`` at reset count ``resets`` and, when not
        None, step ``steps`` ((r,) int64 tensors; :func:`reference_uniforms`); stateless."""
        torch = torch_module()
        st = _mix(keys + (resets + 1) * _signed(_EPISODE))
        if steps is not None:
            st = _mix(st + (steps + 1) * _signed(_STEP))
        j = torch.arange(1, int(n) + 1, dtype=torch.int64, device=keys.device)
        z = _mix(st[:, None] + j[None, :] * _signed(_GOLDEN))
        return _lsr(z, 11).to(torch.float64) * (2.0 ** -53)


class TorchDomain:
    """The randomised robot parameters (:class:`~tensegrity_gym.envs.domain.Domain`) of a torch
    vector env, drawn on the device at reset.

    ``size``: the uniforms one reset reads (one per item of each randomised name, one per
    ``gravity``; names in alphabetical order, as the host draws them); ``values``: name ->
    (N, ...) float64 tensor, each env's current values (what ``info["params"]`` reports)."""

    def __init__(self, env):
        torch = torch_module()
        dom = env.task.domain
        self.env = env
        dev = env.device
        self.values = {name: torch.as_tensor(np.asarray(dom.values[name], float), dtype=torch.float64, device=dev)
                       for name in dom.names}
        if not dom.randomized:   # fixed values: every env reports row 0
            self.values = {name: v[:1].expand((env.num_envs,) + tuple(v.shape[1:])) for name, v in self.values.items()}
        self.base = {name: torch.as_tensor(np.asarray(dom.base[name], float), dtype=torch.float64, device=dev)
                     for name in dom.spread}
        self.layout = []
        start = 0
        self.specs = dom.specs
        for name, s in dom.spread.items():          # sorted by name (Domain)
            count = draw_count(self.specs[name], self.base[name])
            self.layout.append((name, float(s), start, count))
            start += count
        self.size = start
        model = env.task.model
        self._elastic_off = torch.as_tensor(np.array(model.active, bool), device=dev)     # force-density strings
        self._rest0 = torch.as_tensor(np.array(model.rest_length, float), dtype=torch.float64, device=dev)

    def sample(self, it, u) -> dict:
        """name -> (r, ...) float64 values of the reset envs ``it`` from their uniforms ``u``
        (r, size) (as :meth:`Domain.sample`: relative ``base x U(1 - s, 1 + s)``, absolute
        ``base + U(-s, s)``, one factor for the gravity vector); stored in :attr:`values`."""
        out = {}
        for name, s, start, count in self.layout:
            spec = self.specs[name]
            lo, hi = draw_range(spec, s)
            x = lo + (hi - lo) * u[:, start:start + count]    # U(lo, hi) as NumPy's Generator.uniform computes it
            v = values_from_draws(spec, self.base[name], x)
            self.values[name][it] = v
            out[name] = v
        return out

    def apply(self, it, vals: dict) -> None:
        """Envs ``it`` take the drawn ``vals`` in the env's per-copy tensors
        (:func:`~tensegrity_gym.envs.domain.write_copies`, the host's writer, with this object
        as the sink)."""
        write_copies(self, it, vals)

    # the per-copy tensors, as write_copies writes them (the device side)
    def nominal(self, field: str):
        """The model's nominal value of a ``Params`` field (float64 on the device)."""
        if field != "rest_length":
            raise ValueError(f"{field}: no nominal value to offset on the device")
        return self._rest0

    @property
    def no_elastic_part(self):
        return self._elastic_off

    @staticmethod
    def zero_where(mask, v):
        torch = torch_module()
        return torch.where(mask, torch.zeros_like(v), v)

    def write_physics(self, it, fields: dict, offsets: dict) -> None:
        env = self.env
        prm = env._params
        for fld, v in fields.items():
            if fld not in prm:            # a node drag the model lacks: its nominal (0) stays 0
                continue
            prm[fld][it] = v.to(env.dtype)
            if fld == "mass":
                f, J = mass_moments(env.tm, v.to(env.dtype))
                prm["f"][it], prm["J"][it] = f, J
                env._mass_frac[it] = (v / v.sum(dim=1, keepdim=True)).to(env.dtype)
        if "rest_length" in offsets:
            env._rest_offset[it] = offsets["rest_length"].to(env.dtype)

    def write_contact(self, it, columns: dict) -> None:
        """As the host's: the terrain's rows (every part) where the env has a terrain, else the ground's."""
        cols = contact_columns()
        terrain_prm = getattr(self.env, "_terrain_prm", None)
        prm = self.env._contact_prm if terrain_prm is None else terrain_prm
        for fld, v in columns.items():
            v = v.to(self.env.dtype)
            prm[it, ..., cols.index(fld)] = v if terrain_prm is None else v[:, None]

    def write_actuation(self, it, fields: dict) -> None:
        env = self.env
        for fld, v in fields.items():
            if fld == "max_rate":
                env._max_rate[it] = v.to(env.dtype)
            elif fld == "max_accel":
                env._max_accel[it, 0] = v.to(env.dtype)
            else:   # a limit this env does not hold: refuse rather than ignore
                raise ValueError(f"randomize: actuation limit {fld!r} not supported with reset_sampling='device' "
                                 f"by {type(env).__name__}")

    def report(self, it) -> dict:
        """name -> (r, ...) values of envs ``it`` in the env's dtype (``info["params"]``)."""
        return {name: v[it].to(self.env.dtype) for name, v in self.values.items()}
