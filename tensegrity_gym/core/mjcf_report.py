"""The report of an MJCF import (:func:`tensegrity_gym.core.mjcf_import.from_mjcf`): what was read,
how it was mapped, what was dropped, and the strings an actuator sets. SI units (m, kg, s, N)."""
from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["ImportReport", "ActuatedString"]


@dataclass
class ActuatedString:
    """A string whose rest length an actuator sets: ``rest_length_range`` (low, high) m over the
    control range (None: unlimited), ``per_ctrl`` m of rest length per unit of control,
    ``time_constant`` s of a filter (None: none), ``rate_range`` m/s for an integrator (its
    control sets the rate), ``max_tension`` N (None: unlimited), ``ctrl_range`` as written."""
    actuator: str
    tendon: str
    string: int
    per_ctrl: float
    rest_length_range: tuple | None
    time_constant: float | None = None
    rate_range: tuple | None = None
    max_tension: float | None = None
    ctrl_range: tuple | None = None



@dataclass
class ImportReport:
    """What :func:`from_mjcf` read, mapped and dropped (SI units)."""
    source: str
    rods: list = field(default_factory=list)            # body name of rod j
    strings: list = field(default_factory=list)         # tendon name of string i
    node_sites: list = field(default_factory=list)      # site names mapped to node i
    node_frames: list = field(default_factory=list)     # (body name or None, (3,) point in its frame, m)
    site_offsets: dict = field(default_factory=dict)    # site -> (distance from the axis, shift along it), m
    max_axis_offset: float = 0.0                        # largest site distance from its rod's axis, m
    max_axial_shift: float = 0.0                        # largest site shift along the axis to a node, m
    cap_radius: float | None = None                     # end-cap sphere radius (else rod radius), m
    actuated: list = field(default_factory=list)        # ActuatedString rows
    dropped: list = field(default_factory=list)         # what was not imported, and why
    notes: list = field(default_factory=list)           # approximations of the mapping
    gravity: tuple | None = None                        # m/s^2
    timestep: float = 0.002                             # s
    integrator: str = "Euler"
    floor: dict | None = None                           # name, point (m), normal, friction
    contact: bool = True
    groups: dict = field(default_factory=dict, repr=False)   # (kind, template) -> names, see add()

    def add(self, kind: str, template: str, name: str) -> None:
        """Collect ``name`` for one line of ``kind`` ("notes" or "dropped") that lists every name
        given the same ``template`` (its ``{names}`` field); :meth:`close` writes the lines."""
        self.groups.setdefault((kind, template), []).append(name)

    def close(self) -> None:
        for (kind, template), names in self.groups.items():
            shown = names if len(names) <= 4 else names[:3] + ["...", names[-1]]
            getattr(self, kind).append(template.format(names=", ".join(map(repr, shown)).replace("'...'", "...")
                                                       + (f" ({len(names)})" if len(names) > 4 else "")))
        self.groups.clear()

    @property
    def actuated_strings(self) -> list:
        """String indices of the actuated strings (an env's ``actuated=``)."""
        return [a.string for a in self.actuated]

    def to_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k not in ("actuated", "node_frames", "groups")}
        d["node_frames"] = [[b, [float(x) for x in p]] for b, p in self.node_frames]
        d["actuated"] = [dict(a.__dict__) for a in self.actuated]
        return d

    def summary(self) -> str:
        lines = [f"rods {len(self.rods)}, strings {len(self.strings)}, nodes {len(self.node_sites)}",
                 f"largest site offset from a rod axis {self.max_axis_offset:.4g} m, largest shift along "
                 f"an axis {self.max_axial_shift:.4g} m",
                 f"gravity {list(self.gravity) if self.gravity else None} m/s^2, timestep {self.timestep:g} s "
                 f"({self.integrator}), end-cap radius {self.cap_radius if self.cap_radius is None else f'{self.cap_radius:.4g}'} m",
                 "floor " + ("none" if self.floor is None else
                             f"{self.floor['name']!r} friction {self.floor['friction']:g}"
                             + ("" if self.contact else " (contact disabled)"))]
        for a in self.actuated:
            rng = "unlimited" if a.rest_length_range is None else \
                f"{a.rest_length_range[0]:.4g}..{a.rest_length_range[1]:.4g} m"
            extra = "".join([f", filter {a.time_constant:g} s" if a.time_constant else "",
                             f", rate {a.rate_range[0]:.4g}..{a.rate_range[1]:.4g} m/s" if a.rate_range else "",
                             f", max tension {a.max_tension:.4g} N" if a.max_tension is not None else ""])
            lines.append(f"actuated string {a.string} ({a.tendon}) by {a.actuator}: rest length {rng}{extra}")
        lines += [f"dropped: {d}" for d in self.dropped] + [f"note: {n}" for n in self.notes]
        return "\n".join(lines)
