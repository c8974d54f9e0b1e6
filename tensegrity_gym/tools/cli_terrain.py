"""The command line's terrain options: ``--terrain FILE.json`` / ``--ground`` and the contact
overrides (``--friction``, ``--ground-stiffness``, ``--ground-damping``, ``--cap-radius``), read
into a :class:`~tensegrity_gym.core.terrain.Terrain` with one-line errors (SI units)."""
from __future__ import annotations

import dataclasses

from ..core.terrain import SURFACE_KEYS, Terrain
from ..physics.terrain import TerrainContact
from .cli_common import EXIT_STRUCTURE, EXIT_USAGE, CLIError, _non_negative, _one_line, _positive

__all__ = ["add_terrain_args", "terrain_from_args", "terrain_label", "with_contact", "DEFAULT_CAP_RADIUS"]

#: cap radius of the rods' capsules (m) when ``--cap-radius`` is not given: the physics' own default
DEFAULT_CAP_RADIUS = TerrainContact.__dataclass_fields__["radius"].default

#: the contact overrides: (command-line flag, argparse dest, Terrain field)
_OVERRIDES = (("--friction", "friction", "friction"), ("--ground-stiffness", "ground_stiffness", "stiffness"),
              ("--ground-damping", "ground_damping", "damping"))


def add_terrain_args(p, *, contact: bool = True, ground_help: str | None = None, terrain_file: bool = True) -> None:
    """``--terrain`` / ``--ground`` (one or the other) and the contact overrides on parser ``p``;
    ``contact=False`` keeps only ``--friction`` (``export``: MuJoCo's contact takes the friction,
    its own soft contact replaces the stiffness and damping, and it sizes its capsules itself);
    ``terrain_file=False`` leaves out ``--terrain`` (``identify``: a level ground only)."""
    g = p.add_mutually_exclusive_group()
    if terrain_file:
        g.add_argument("--terrain", default=None, metavar="FILE.json",
                       help="a terrain file (docs/terrain.md: a sloped plane, boxes, a heightfield)")
    g.add_argument("--ground", action="store_true",
                   help=ground_help or "a level plane at z = 0 (the same as --terrain with a file holding {})")
    level = Terrain()      # --ground's values: a file holding {}

    def default(field: str) -> str:
        v = f"{getattr(level, field):g}"
        return f"default: the terrain file's; {v} with --ground" if terrain_file else f"default {v}"
    where = "every terrain part" if terrain_file else "the ground"
    p.add_argument("--friction", type=_non_negative, default=None,
                   help=f"Coulomb friction coefficient of {where} ({default('friction')})")
    if not contact:
        return
    p.add_argument("--ground-stiffness", type=_positive(float), default=None,
                   help=f"normal contact stiffness of {where}, N/m ({default('stiffness')})")
    p.add_argument("--ground-damping", type=_non_negative, default=None,
                   help=f"Hunt-Crossley contact damping of {where}, s/m ({default('damping')})")
    p.add_argument("--cap-radius", type=_positive(float), default=None,
                   help=f"radius of the rods' end caps and capsules touching the terrain, m "
                        f"(default {DEFAULT_CAP_RADIUS:g})")


def with_contact(terrain: Terrain, friction=None, stiffness=None, damping=None) -> Terrain:
    """``terrain`` with the given contact values (Coulomb 1, N/m, s/m; None: unchanged) for the
    whole terrain: the parts' own overrides of those values are dropped, so every part uses them."""
    changes = {k: v for k, v in (("friction", friction), ("stiffness", stiffness), ("damping", damping))
               if v is not None}
    if not changes:
        return terrain
    clear = dict.fromkeys(changes)
    contact = {k: getattr(terrain, k) for k in SURFACE_KEYS}
    return Terrain.from_parts([dataclasses.replace(p, **clear) for p in terrain.parts()], **{**contact, **changes})


def terrain_from_args(args) -> Terrain | None:
    """The terrain the options ask for (None without ``--terrain`` and ``--ground``), with the
    contact overrides applied. CLIError: exit 3 for a bad terrain file (the message names the
    field and the value), exit 2 for a contact option given without a terrain."""
    path, ground = getattr(args, "terrain", None), getattr(args, "ground", False)
    flags = [(flag, getattr(args, dest, None)) for flag, dest, _ in _OVERRIDES]
    flags.append(("--cap-radius", getattr(args, "cap_radius", None)))
    if path is None and not ground:
        given = [flag for flag, v in flags if v is not None]
        if given:
            where = "--terrain FILE.json or --ground" if hasattr(args, "terrain") else "--ground"
            raise CLIError(EXIT_USAGE, f"{given[0]}: a terrain contact option; add {where}")
        return None
    if ground:
        terrain = Terrain()
    else:
        try:
            terrain = Terrain.from_file(path)
        except (ValueError, TypeError, OSError, RecursionError) as e:
            raise CLIError(EXIT_STRUCTURE, f"--terrain {path!r}: {_one_line(e)}") from None
    return with_contact(terrain, **{field: getattr(args, dest, None) for _, dest, field in _OVERRIDES})


def terrain_label(args) -> str:
    """How the terrain was given, for messages: ``--terrain 'ramp.json'`` or ``--ground``."""
    return "--ground" if getattr(args, "ground", False) else f"--terrain {args.terrain!r}"
