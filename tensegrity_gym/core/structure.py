"""Structure model of a class-1 tensegrity: nodes, rods, strings, masses, constraints.

Everything is in SI units: positions in m, masses in kg, stiffness in N/m,
rest lengths in m, damping in N s/m, gravity in m/s^2, velocities in m/s.

A :class:`Structure` is immutable and validated on construction; every error
names the offending item (which node, rod, string or field and which value).
It is pure data: the dynamics compile it into a :class:`tensegrity_gym.core.model.Model`.

Conventions
-----------
* ``nodes`` (n, 3): node coordinates.
* ``bars`` (k, 2): rod end nodes ``(a, c)``; the rod's unit vector points a -> c.
* ``strings`` (m, 2): string end nodes.
* Nodes on no rod are fixed anchors.
* ``node_constraints``: ``{node: D}`` with ``D`` of shape (p, 3), rank p in 1..3:
  the node obeys ``D n = D n0`` for all time (p = 1: slides on a plane,
  p = 2: on a line, p = 3: pinned). At most one constrained node per rod.
* ``mass_points``: per rod ``None`` (uniform rod of mass ``bar_mass[j]``) or a
  tuple of ``(mu, m)`` lumped masses at fraction ``mu`` in [0, 1] from node a
  (the seed's Example 5.2); ``bar_mass[j]`` is then their sum.

The checks and the accepted values of every field are in
:mod:`tensegrity_gym.core.structure_checks`, the rods' mass moments in
:mod:`tensegrity_gym.core.rod_mass`; this module holds the dataclass and its JSON file format.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .checks import read_bounded
from .errors import StructureError
from .rod_mass import centre_of_mass_fraction, mass_moments
from .schema import SCHEMA_PATH, _describe, loads, schema, validate_dict
from .structure_checks import MIN_STABLE_STEP, checked_fields

__all__ = ["Structure", "StructureError", "mass_moments", "load_json", "save_json", "from_dict",
           "SCHEMA_PATH", "schema", "validate_dict", "MIN_STABLE_STEP", "MAX_FILE_BYTES"]

#: largest structure file :func:`load_json` reads, bytes: about 70,000 rods as written by
#: :func:`save_json` (about 480 bytes per rod), parsed and validated in seconds; a larger file would
#: take minutes and gigabytes of memory before any check could refuse it
MAX_FILE_BYTES = 32 * 2**20


@dataclass(frozen=True, eq=False, init=False)
class Structure:
    """A validated class-1 tensegrity structure (SI units).

    Parameters
    ----------
    nodes : (n, 3) array, m.
    bars : (k, 2) int array of node indices (rods).
    strings : (m, 2) int array of node indices.
    bar_mass : number or (k,) array, kg (ignored for rods with ``mass_points``).
    stiffness : number or (m,) array, N/m, > 0.
    rest_length : (m,) array, m, >= 0. ``None``: the strings' initial lengths (no prestress).
    damping : number or (m,) array, N s/m, >= 0. Default 0.
    gravity : (3,) array, m/s^2, or ``None`` (no gravity: no gravity code runs).
    node_constraints : mapping node -> (p, 3) matrix ``D``.
    velocities : (n, 3) array of initial node velocities, m/s. Default zeros.
    mass_points : per-rod ``None`` or sequence of ``(mu, mass)`` pairs.
    name : free text.
    """

    nodes: np.ndarray
    bars: np.ndarray
    strings: np.ndarray
    bar_mass: np.ndarray
    stiffness: np.ndarray
    rest_length: np.ndarray
    damping: np.ndarray
    gravity: np.ndarray | None = None
    node_constraints: Mapping[int, np.ndarray] = field(default_factory=dict)
    velocities: np.ndarray | None = None
    mass_points: tuple | None = None
    name: str = "structure"

    # ------------------------------------------------------------------ construction
    def __init__(self, nodes, bars, strings, bar_mass=1.0, stiffness=1000.0, rest_length=None,
                 damping=0.0, gravity=None, node_constraints=None, velocities=None,
                 mass_points=None, name="structure"):
        set_ = object.__setattr__
        for key, value in checked_fields(nodes, bars, strings, bar_mass, stiffness, rest_length, damping, gravity,
                                         node_constraints, velocities, mass_points).items():
            set_(self, key, value)
        set_(self, "name", str(name))

    # ------------------------------------------------------------------ derived data
    @property
    def n_nodes(self) -> int:
        return self.nodes.shape[0]

    @property
    def n_bars(self) -> int:
        return self.bars.shape[0]

    @property
    def n_strings(self) -> int:
        return self.strings.shape[0]

    @property
    def bar_lengths(self) -> np.ndarray:
        """(k,) rod lengths, m."""
        return np.linalg.norm(self.nodes[self.bars[:, 1]] - self.nodes[self.bars[:, 0]], axis=1)

    @property
    def string_lengths(self) -> np.ndarray:
        """(m,) initial string lengths, m."""
        return np.linalg.norm(self.nodes[self.strings[:, 1]] - self.nodes[self.strings[:, 0]], axis=1)

    @property
    def anchors(self) -> np.ndarray:
        """Indices of the fixed nodes (on no rod)."""
        on_rod = np.zeros(self.n_nodes, bool)
        on_rod[self.bars.ravel()] = True
        return np.flatnonzero(~on_rod)

    @property
    def com_fraction(self) -> np.ndarray:
        """(k,) position of each rod's centre of mass as a fraction from node a."""
        mp = self.mass_points or (None,) * self.n_bars
        return np.array([centre_of_mass_fraction(p) for p in mp])

    @property
    def total_mass(self) -> float:
        return float(np.sum(self.bar_mass))

    @property
    def height(self) -> float:
        """Extent of the nodes along z, m (used for default tolerances)."""
        return float(np.ptp(self.nodes[:, 2]))

    def initial_tensions(self) -> np.ndarray:
        """(m,) string tensions at the initial nodes, N (0 for slack strings)."""
        return self.stiffness * np.maximum(0.0, self.string_lengths - self.rest_length)

    def replace(self, **changes) -> "Structure":
        """A new validated structure with some fields changed."""
        d = dict(nodes=self.nodes, bars=self.bars, strings=self.strings, bar_mass=self.bar_mass,
                 stiffness=self.stiffness, rest_length=self.rest_length, damping=self.damping,
                 gravity=self.gravity, node_constraints=self.node_constraints,
                 velocities=self.velocities, mass_points=self.mass_points, name=self.name)
        d.update(changes)
        return Structure(**d)

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict:
        d: dict[str, Any] = {
            "name": self.name,
            "nodes": self.nodes.tolist(),
            "bars": self.bars.tolist(),
            "strings": self.strings.tolist(),
            "bar_mass": self.bar_mass.tolist(),
            "stiffness": self.stiffness.tolist(),
            "rest_length": self.rest_length.tolist(),
            "damping": self.damping.tolist(),
        }
        if self.gravity is not None:
            d["gravity"] = self.gravity.tolist()
        if self.node_constraints:
            d["node_constraints"] = {str(k): v.tolist() for k, v in self.node_constraints.items()}
        if np.any(self.velocities != 0):
            d["velocities"] = self.velocities.tolist()
        if self.mass_points is not None:
            d["mass_points"] = [None if p is None else [list(x) for x in p] for p in self.mass_points]
        return d

    def __repr__(self) -> str:
        return (f"Structure(name={self.name!r}, nodes={self.n_nodes}, bars={self.n_bars}, "
                f"strings={self.n_strings}, constrained={sorted(self.node_constraints)}, "
                f"gravity={None if self.gravity is None else self.gravity.tolist()})")


_JSON_KEYS = {"name", "nodes", "bars", "strings", "bar_mass", "stiffness", "rest_length", "damping",
              "gravity", "node_constraints", "velocities", "mass_points"}


def from_dict(d: Mapping[str, Any]) -> Structure:
    """Build a :class:`Structure` from a JSON-like mapping (see the README for the keys)."""
    unknown = set(d) - _JSON_KEYS
    if unknown:
        raise StructureError(f"unknown key(s) {sorted(unknown)}; known keys: {sorted(_JSON_KEYS)}")
    for req in ("nodes", "bars", "strings"):
        if req not in d:
            raise StructureError(f"missing required key {req!r}")
    validate_dict(d)
    try:
        return Structure(**{k: d[k] for k in d})
    except StructureError as e:   # a check across keys: cite the schema's description of the key
        key = re.match(r"[a-z_]+", str(e))
        key = key and {"bar": "bars", "string": "strings"}.get(key.group(0), key.group(0))
        desc = _describe(key) if key else ""
        if desc and "(schema," not in str(e):
            raise StructureError(f"{e} (schema, {key}: {desc})") from None
        raise


def load_json(path: str | Path) -> Structure:
    """Load a structure from a JSON file."""
    path = Path(path)
    if path.is_dir():
        raise StructureError(f"{path}: is a directory, not a structure file")
    try:
        raw = read_bounded(path, MAX_FILE_BYTES, "structure file", binary=True)
    except ValueError as e:
        raise StructureError(str(e)) from None
    except PermissionError as e:
        raise StructureError(f"{path}: cannot be read ({e.strerror})") from None
    except IsADirectoryError:
        raise StructureError(f"{path}: is a directory, not a structure file") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise StructureError(f"{path}: not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start})") from None
    d = loads(text, str(path))
    if not isinstance(d, dict):
        raise StructureError(f"{path}: top level must be a JSON object")
    return from_dict(d)


def save_json(structure: Structure, path: str | Path) -> None:
    """Save a structure to a JSON file (round-trips through :func:`load_json`)."""
    Path(path).write_text(json.dumps(structure.to_dict(), indent=1))
