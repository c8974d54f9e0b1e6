"""Terrain of a locomotion task: a fixed terrain or one drawn per episode (procedural), as pure
functions of a seeded generator. SI units: m, degrees.

A task's ``terrain`` argument is one of

* ``None`` (or ``{}``): today's level ground at z = 0 (the ground contact's fast path);
* a :class:`~tensegrity_gym.core.terrain.Terrain`, a terrain file's dict or the path of a terrain
  JSON file (:mod:`tensegrity_gym.core.terrain`): the same terrain in every episode;
* a :class:`TerrainGenerator`, or a dict with the key ``"generator"`` (its other keys the
  generator's fields): a new terrain per episode and copy, drawn by :func:`generate` from the
  copy's ``np_random``, scaled by the ``difficulty`` in [0, 1] (the curriculum's knob).

A draw reads :func:`terrain_draws` uniforms in [0, 1) and is written once, over the array
namespace: :func:`drawn_values` (NumPy here, from the copy's ``np_random``; torch at a device
reset, from the env's streams, :mod:`tensegrity_gym.envs.torch_terrain`).

Every generated terrain keeps a level pad of radius ``pad`` m around the start (the origin), so
the robot starts as on flat ground, and has the same parts and grid shape for a given generator
(copies of a vector env differ only in numbers). The kinds:

``"slope"``
    a plane rising along the goal direction at ``difficulty * U(slope_range)`` degrees (the pad
    is the plane itself: a slope starts at the robot);
``"steps"``
    ``n_steps`` ascending steps across the goal direction, the first at ``pad`` m, each ``tread``
    m deep and ``difficulty * U(0.5, 1) * step_height`` m high, on the level plane;
``"rough"``
    a heightfield of ``size`` m square (``cell`` m grid) of smooth random bumps: a sum of
    ``waves`` cosines of wavelength ``wavelength`` m in random directions and phases, scaled to
    ``[0, difficulty * amplitude]`` m, faded to 0 inside the pad (and held at its edge values
    outside the grid).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from ..core.terrain import MAX_EXTENT, Box, Heightfield, Plane, Terrain
from .xp import namespace

__all__ = ["TerrainGenerator", "generate", "terrain_from", "terrain_draws", "drawn_values", "step_extents",
           "rough_axis", "rough_grid", "resolve_terrain", "KINDS", "start_lift", "rod_end_contacts"]

KINDS = ("slope", "steps", "rough")
#: length of the step boxes across the goal direction and of the last step, m
STEP_SPAN = 20.0
#: the most steps or waves a generator takes (a terrain of that many parts or cosines per draw)
MAX_COUNT = 1000


def _show(v) -> str:
    """``v`` for an error message: its repr cut to 80 characters, or the size of an integer too
    long to print (Python refuses the digits of one beyond 4300)."""
    if isinstance(v, (int, np.integer)) and not isinstance(v, bool) and int(v).bit_length() > 64:
        return f"an integer of {int(v).bit_length()} bits"
    try:
        return f"{v!r:.80}"
    except ValueError:
        return f"a {type(v).__name__} too long to print"


@dataclass(frozen=True)
class TerrainGenerator:
    """A procedural terrain (see the module doc). ``kind``: one of :data:`KINDS`. Contact
    parameters ``friction``, ``stiffness`` (N/m), ``damping`` (s/m): None takes the task's."""

    kind: str
    slope_range: tuple = (0.0, 20.0)
    step_height: float = 0.05
    tread: float = 0.5
    n_steps: int = 4
    amplitude: float = 0.02
    wavelength: float = 0.4
    waves: int = 8
    size: float = 12.0
    cell: float = 0.05
    pad: float = 0.4
    friction: float | None = None
    stiffness: float | None = None
    damping: float | None = None

    def __post_init__(self):
        s = object.__setattr__
        if self.kind not in KINDS:
            raise ValueError(f"terrain.generator: unknown kind {self.kind!r}; choose one of {list(KINDS)}")
        try:
            if isinstance(self.slope_range, (str, bytes)) or any(isinstance(v, (bool, complex, np.bool_, str))
                                                                 for v in self.slope_range):
                raise TypeError
            lo, hi = (float(v) for v in self.slope_range)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"terrain.slope_range: expected (low, high) degrees, got {_show(self.slope_range)}") \
                from None
        if not (math.isfinite(lo) and math.isfinite(hi) and -60.0 <= lo <= hi <= 60.0):
            raise ValueError(f"terrain.slope_range: expected -60 <= low <= high <= 60 degrees, got {self.slope_range!r}")
        s(self, "slope_range", (lo, hi))
        for name, lo_open in (("step_height", False), ("tread", True), ("amplitude", False), ("wavelength", True),
                              ("size", True), ("cell", True), ("pad", False)):
            v = getattr(self, name)
            ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and \
                -MAX_EXTENT <= v <= MAX_EXTENT         # False for nan and inf, no float of a huge int
            if not ok or v < 0 or (lo_open and v == 0):
                raise ValueError(f"terrain.{name}: must be a {'positive' if lo_open else 'non-negative'} "
                                 f"number of at most {MAX_EXTENT:g} m, got {_show(v)}")
            s(self, name, float(v))
        for name in ("n_steps", "waves"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_COUNT:
                raise ValueError(f"terrain.{name}: must be an integer in [1, {MAX_COUNT}], got {_show(v)}")
            s(self, name, int(v))
        # the steps' top and far end within the terrain's extent (each part's bound, named here)
        if self.n_steps * self.step_height > MAX_EXTENT:
            raise ValueError(f"terrain.step_height: {self.step_height:g} m x {self.n_steps} steps rises above "
                             f"{MAX_EXTENT:g} m (a terrain's physical extent)")
        if self.pad + self.n_steps * self.tread + STEP_SPAN > MAX_EXTENT:
            raise ValueError(f"terrain.tread: {self.tread:g} m x {self.n_steps} steps reaches beyond "
                             f"{MAX_EXTENT:g} m (a terrain's physical extent)")
        if self.size / self.cell > 2000:
            raise ValueError(f"terrain.cell: {self.cell:g} m makes a grid of more than 2000 x 2000 cells over "
                             f"size {self.size:g} m; use a larger cell or a smaller size")
        if self.pad >= self.size / 2:
            raise ValueError(f"terrain.pad: {self.pad:g} m leaves no rough ground inside size {self.size:g} m")

    @classmethod
    def from_dict(cls, d: dict) -> "TerrainGenerator":
        """A generator from ``{"generator": kind, **fields}``; ValueError naming an unknown key."""
        d = dict(d)
        kind = d.pop("generator")
        names = {f.name for f in fields(cls)} - {"kind"}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"terrain: unknown key {unknown[0]!r} of a {kind!r} generator (expected some of "
                             f"{sorted(names)})")
        if "slope_range" in d and isinstance(d["slope_range"], list):
            d["slope_range"] = tuple(d["slope_range"])
        return cls(kind=kind, **d)


def resolve_terrain(value, surface: dict):
    """The task's ``terrain`` argument as ``None`` (level ground), a :class:`Terrain` or a
    :class:`TerrainGenerator`. ``surface``: the task's contact values (``friction``,
    ``stiffness``, ``damping``) taken where a file, dict or generator does not give its own."""
    if value is None or isinstance(value, TerrainGenerator):
        return None if value is None else _with_surface(value, surface)
    if isinstance(value, Terrain):
        return value
    if isinstance(value, (str, Path)):
        p = Path(value)
        if p.suffix.lower() != ".json":
            raise ValueError(f"terrain: expected a terrain JSON file, a dict, a Terrain or a generator, got {value!r}")
        return Terrain.from_file(p, defaults=surface)
    if not isinstance(value, dict):
        raise ValueError(f"terrain: expected a terrain JSON file, a dict, a Terrain or a TerrainGenerator, "
                         f"got {type(value).__name__}")
    if "generator" in value:
        return _with_surface(TerrainGenerator.from_dict(value), surface)
    if not value:
        return None                     # {} is the level plane at z = 0: the flat ground
    return Terrain.from_dict({**surface, **value})


def _with_surface(gen: TerrainGenerator, surface: dict) -> TerrainGenerator:
    return replace(gen, **{k: v for k, v in surface.items() if getattr(gen, k) is None})


def generate(gen: TerrainGenerator, rng: np.random.Generator, goal=(1.0, 0.0), difficulty: float = 1.0) -> Terrain:
    """One terrain drawn from ``gen`` with ``rng`` (its :func:`terrain_draws` uniforms in order),
    rising along the unit ``goal`` (x, y) direction, scaled by ``difficulty`` in [0, 1]."""
    return terrain_from(gen, rng.random(terrain_draws(gen)), goal, difficulty)


def terrain_draws(gen: TerrainGenerator) -> int:
    """How many uniforms in [0, 1) one terrain of ``gen`` reads: a slope its angle, steps their
    heights, rough ground its waves' directions, then their phases."""
    return {"slope": 1, "steps": gen.n_steps, "rough": 2 * gen.waves}[gen.kind]


def drawn_values(gen: TerrainGenerator, u, difficulty: float = 1.0):
    """What a drawn terrain of ``gen`` varies in, for r terrains from their uniforms ``u`` (r,
    :func:`terrain_draws`) in [0, 1) (NumPy or torch, the result alike): a slope's angle (r,)
    deg, the steps' tops (r, n_steps) m, rough ground's heights (r, n, n) m on
    :func:`rough_grid`. Each U(lo, hi) is ``lo + (hi - lo) u`` (as NumPy's ``Generator.uniform``)."""
    xp = namespace(u)
    d = float(difficulty)
    if gen.kind == "slope":
        lo, hi = gen.slope_range
        return d * (lo + (hi - lo) * u[:, 0])
    if gen.kind == "steps":
        return xp.cumsum(d * (0.5 + (1.0 - 0.5) * u) * gen.step_height, axis=1)
    x, fade = (xp.const(a, u) for a in rough_grid(gen))
    w = gen.waves
    ang, phase = 0.0 + (2 * np.pi - 0.0) * u[:, :w], 0.0 + (2 * np.pi - 0.0) * u[:, w:]
    k = 2 * np.pi / gen.wavelength
    # each wave cos(k (cos a X + sin a Y) + phase) on the square grid X[j, i] = x[i], Y[j, i] = x[j],
    # by the angle sum: cos(A_i + B_j) = cos A_i cos B_j - sin A_i sin B_j with A = k cos a x and
    # B = k sin a x + phase, so that a wave costs 4 n trigonometric calls, not n^2
    A = k * (xp.cos(ang)[:, :, None] * x)                          # (r, waves, n)
    B = k * (xp.sin(ang)[:, :, None] * x) + phase[:, :, None]
    cA, sA, cB, sB = xp.cos(A), xp.sin(A), xp.cos(B), xp.sin(B)
    # each wave's two products written into two (r, n, n) scratch arrays, the sum and its scaling
    # in place: no new grid-sized array per operation (the same numbers, in the same order)
    z = cB[:, 0, :, None] * cA[:, 0, None, :]
    s = sB[:, 0, :, None] * sA[:, 0, None, :]
    z -= s
    t = xp.zeros_like(z)
    for i in range(1, w):
        xp.multiply(cB[:, i, :, None], cA[:, i, None, :], t)
        xp.multiply(sB[:, i, :, None], sA[:, i, None, :], s)
        t -= s
        z += t
    lo = xp.amin(z, axis=(1, 2))[:, None, None]
    span = xp.amax(z, axis=(1, 2))[:, None, None] - lo
    z -= lo
    z /= xp.maximum(span, 1e-12)
    z *= d * gen.amplitude
    z *= fade
    return z


def rough_axis(gen: TerrainGenerator) -> np.ndarray:
    """The axis (n,) m of rough ground's square grid: centred on the start, ``cell`` apart."""
    n = int(round(gen.size / gen.cell)) + 1
    return (np.arange(n) - (n - 1) / 2) * gen.cell


@functools.lru_cache(maxsize=16)
def rough_grid(gen: TerrainGenerator):
    """``(x, fade)`` of rough ground: the axis (n,) m of its square grid (:func:`rough_axis`; the
    point ``[j, i]`` at ``(x[i], x[j])``) and the bumps' fade (n, n) (0 inside the pad, 1 a
    wavelength beyond it). Read-only, computed once per generator."""
    x = rough_axis(gen)
    X, Y = np.meshgrid(x, x)
    fade = np.clip((np.hypot(X, Y) - gen.pad) / max(gen.wavelength, 1e-9), 0.0, 1.0)
    x.setflags(write=False)
    fade.setflags(write=False)
    return x, fade


def step_extents(gen: TerrainGenerator):
    """``(along, depth)`` per step of a ``steps`` terrain: its box's centre along the goal
    direction and its depth, m (the last step ``STEP_SPAN`` deep)."""
    out = []
    for i in range(gen.n_steps):
        start = gen.pad + i * gen.tread       # the step's front edge, m along the goal direction
        depth = STEP_SPAN if i == gen.n_steps - 1 else gen.tread
        out.append((start + depth / 2, depth))
    return out


def terrain_from(gen: TerrainGenerator, u, goal=(1.0, 0.0), difficulty: float = 1.0) -> Terrain:
    """The terrain of ``gen`` drawn from its uniforms ``u`` (:func:`terrain_draws` of them) in [0, 1),
    rising along the unit ``goal`` (x, y) direction, scaled by ``difficulty`` in [0, 1]."""
    surf = {k: getattr(gen, k) for k in ("friction", "stiffness", "damping") if getattr(gen, k) is not None}
    vals = drawn_values(gen, np.asarray(u, dtype=float)[None], difficulty)[0]
    gx, gy = float(goal[0]), float(goal[1])
    heading = math.degrees(math.atan2(gy, gx))
    if gen.kind == "slope":
        return Terrain(plane=Plane(slope_deg=float(vals), uphill_deg=heading), **surf)
    if gen.kind == "steps":
        boxes = []
        for top, (along, depth) in zip(vals, step_extents(gen)):
            # each box rises from z = -1 m to the step's top (a solid block under the tread)
            height = top + 1.0
            boxes.append(Box(center=[along * gx, along * gy, top - height / 2], size=[depth, STEP_SPAN, height],
                             yaw_deg=heading))
        return Terrain(plane=Plane(), boxes=tuple(boxes), **surf)
    x = rough_axis(gen)
    return Terrain(plane=None, heightfield=Heightfield(heights=vals, cell=gen.cell, origin=[x[0], x[0]]), **surf)


def start_lift(terrain: Terrain, nodes: np.ndarray, radius: float) -> np.ndarray:
    """(B,) height (m) to raise each copy of ``nodes`` (B, n, 3) m by so that every node's cap of
    ``radius`` m clears the terrain's top surface under it (0 where it already does)."""
    ground = terrain.height_at(nodes[..., 0], nodes[..., 1])
    gap = (nodes[..., 2] - radius) - ground
    return np.maximum(-gap.min(axis=-1), 0.0)


@functools.lru_cache(maxsize=8)
def _end_slots(n_bars: int) -> np.ndarray:
    """The columns (2 k,) of the rod ends' slots in one terrain part's slot flags (3 k,)."""
    idx = (3 * np.arange(n_bars)[:, None] + np.arange(2)).reshape(-1)
    idx.setflags(write=False)
    return idx


def rod_end_contacts(slots, n_bars: int, out=None):
    """(B, 2 k) bool contact flags of the rod ends (rod i's ends at 2 i, 2 i + 1), what the
    observation reports, from the terrain contact's slot flags ``slots`` (B, 3 k F) bool (per
    rod, per terrain part: end a, end c, interior point; :mod:`tensegrity_gym.physics.terrain`):
    an end touches when its slot touches any part. NumPy array or torch tensor; ``out`` (NumPy,
    C-contiguous (B, 2 k) bool) receives the flags in place and is returned."""
    B = slots.shape[0]
    if out is None:
        return namespace(slots).any(slots.reshape(B, n_bars, -1, 3)[..., :2], 2).reshape(B, 2 * n_bars)
    if slots.shape[1] == 3 * n_bars:    # one terrain part: its end slots, one gather into out
        # (mode "clip": the indices are in range; the default mode copies through a buffer)
        slots.take(_end_slots(n_bars), axis=1, out=out, mode="clip")
    else:
        np.logical_or.reduce(slots.reshape(B, n_bars, -1, 3)[..., :2], axis=2, out=out.reshape(B, n_bars, 2))
    return out
