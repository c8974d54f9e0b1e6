"""The one table of the physical parameters a robot can differ in (SI units).

Each :class:`ParamSpec` row names one number (or one number per item) of a robot's physics, the
container it lives in per copy, and how the envs fix or randomise it. Every other name table of
the package is a view of :data:`PARAMS`, computed by the functions below:

=====================================  ===========================================================
view (where it is used)                function
=====================================  ===========================================================
``params.PARAM_FIELDS``                :func:`params_fields`: ``Params`` field -> (axis word,
                                       unit, valid range)
``backends.torch.model.PARAM_FIELDS``  :func:`physics_fields`: the ``Params`` fields in order
``contact.PRM_FIELDS``                 :func:`contact_columns`: the columns of the (P, 9)
                                       contact parameter array
``terrain.PRM_FIELDS``                 :func:`part_columns`: the same without ``height``,
                                       the columns of a terrain part's (P, F, 8) array
``envs.domain.SPECS``                  :func:`domain_specs`: the names ``params=`` /
                                       ``randomize=`` take
``envs.base._PHYSICS_FIELDS``          :func:`env_fields` (``"physics"``)
``envs.roll.CONTACT_DOMAIN``           :func:`env_fields` (``"contact"``)
``envs.roll._CONTACT_ARGS``            :func:`contact_arguments`
``envs.twin_params.TWIN_PARAMS`` /     :func:`twin_params` / :func:`twin_refusals`
``NOT_REPRESENTABLE``
``Params.has_<field>``, the kernels'   :func:`skipped_fields`: the fields whose term the
flag bits                              kernels skip where every value is 0
``compile_model`` nominal values       :func:`nominal_default`: the nominal value of a
                                       physics row the structure does not give
the numba packed layout                :func:`tensegrity_gym.backends.numba.layout.packed_layout`
=====================================  ===========================================================

Columns of a row:

* ``name``: the env-facing name (``params={name: ...}``, ``randomize={name: ...}``,
  ``info["params"]``); for a value the envs do not set, the container field's name.
* ``group``: the per-copy container: ``"physics"`` (:class:`tensegrity_gym.core.params.Params`),
  ``"contact"`` (the rows of :meth:`tensegrity_gym.physics.contact.GroundContact.per_copy`) or
  ``"actuation"`` (the limits of :class:`tensegrity_gym.physics.actuation.Actuation`).
* ``field``: the field in that container (a ``Params`` field, a contact column, an
  ``Actuation`` limit).
* ``axis``: what one value is per copy: ``"rod"``, ``"string"``, ``"node"``, ``"anchor"``
  (3 coordinates per fixed anchor node), ``"vector"`` (3 components), ``"motor"`` (one per
  actuated cable), ``"scalar"`` (one per copy).
* ``unit``: SI unit of the value.
* ``valid``: the range a value must lie in: ``"positive"`` (finite, > 0), ``"nonnegative"``
  (finite, >= 0) or ``"finite"``; ``field_valid``: the container field's range when it differs
  (a string's stiffness is 0 on force-density-actuated strings).
* ``spread``: how ``randomize={name: s}`` draws, per copy at reset: ``"relative"``
  (nominal x U(1 - s, 1 + s), s in [0, 1)), ``"absolute"`` (nominal + U(-s, s), s >= 0) or
  None (not an env parameter: ``params=`` / ``randomize=`` refuse it).
* ``one_factor``: one draw scales every item (the gravity vector keeps its direction) instead of
  one draw per item.
* ``write``: how a value reaches the container field: ``"set"``, ``"elastic"`` (set, but 0 on the
  force-density-actuated strings, which have no elastic part), ``"offset"`` (field = the model's
  nominal field + the value) or ``"derived"`` (computed from other fields, never written by the
  envs).
* ``argument``: the task constructor argument that sets the nominal value, where one does.
* ``mujoco``: the MuJoCo field the twin (``TensegrityRollMuJoCo-v0``) writes it to, or
  ``no_mujoco``: why the twin refuses it.
* ``skip_zero``: the equations skip the row's term where every value of a copy set is 0
  (``Params.has_<field>``; one flag bit of the numba kernels, one flag of the torch backend).
* ``nominal``: the nominal value of every item of a physics row that ``compile_model`` does
  not compute from the structure (the model's value until a ``Params`` replaces it).
* ``doc``: what the number is.

This module imports nothing from ``tensegrity_gym``: every layer may read it.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ParamSpec", "DomainSpec", "PARAMS", "GROUPS", "AXES", "spec", "env_params", "params_fields",
           "physics_fields", "contact_columns", "contact_arguments", "env_fields", "domain_specs",
           "twin_params", "twin_refusals", "part_columns", "physics_rows", "skipped_fields", "nominal_default", "ITEM_AXES"]

GROUPS = ("physics", "contact", "actuation")
AXES = ("rod", "string", "node", "anchor", "vector", "motor", "scalar")
SPREADS = (None, "relative", "absolute")
WRITES = ("set", "elastic", "offset", "derived")
VALID = ("positive", "nonnegative", "finite")


@dataclass(frozen=True)
class ParamSpec:
    """One physical parameter (see the module doc for the columns)."""

    name: str
    group: str
    field: str
    axis: str
    unit: str
    valid: str
    doc: str
    spread: str | None = None
    one_factor: bool = False
    write: str = "set"
    field_valid: str | None = None
    argument: str | None = None
    mujoco: str | None = None
    no_mujoco: str | None = None
    skip_zero: bool = False
    nominal: float | None = None

    def __post_init__(self):
        for col, value, allowed in (("group", self.group, GROUPS), ("axis", self.axis, AXES),
                                    ("spread", self.spread, SPREADS), ("write", self.write, WRITES),
                                    ("valid", self.valid, VALID)):
            if value not in allowed:
                raise ValueError(f"ParamSpec {self.name!r}: {col} must be one of {allowed}, got {value!r}")
        if self.randomizable and (self.mujoco is None) == (self.no_mujoco is None):
            raise ValueError(f"ParamSpec {self.name!r}: an env parameter needs exactly one of mujoco (the MuJoCo "
                             "field the twin writes) and no_mujoco (why the twin refuses it)")
        if (self.skip_zero or self.nominal is not None) and self.group != "physics":
            raise ValueError(f"ParamSpec {self.name!r}: skip_zero and nominal are columns of physics rows "
                             f"(Params fields), not of group {self.group!r}")

    @property
    def randomizable(self) -> bool:
        """Whether the envs take it in ``params=`` / ``randomize=``."""
        return self.spread is not None

    @property
    def absolute(self) -> bool:
        return self.spread == "absolute"


#: the parameters: the physics rows in the order of the Params fields, the contact rows in the
#: order of the contact parameter columns (a terrain part's columns are the same without the
#: last, the ground height), then the actuation limits
PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("rod_mass", "physics", "mass", "rod", "kg", "positive",
              "rod mass (the rod's mass distribution keeps its shape)", spread="relative",
              mujoco="body_mass of the rod; body_inertia scaled by the same factor"),
    ParamSpec("f", "physics", "f", "rod", "kg m", "finite",
              "first mass moment about the rod's reference point (from rod_mass)", write="derived"),
    ParamSpec("J", "physics", "J", "rod", "kg m^2", "positive",
              "second mass moment about the rod's reference point (from rod_mass)", write="derived"),
    ParamSpec("stiffness", "physics", "stiffness", "string", "N/m", "positive",
              "string stiffness", spread="relative", write="elastic", field_valid="nonnegative",
              mujoco="tendon_stiffness"),
    ParamSpec("damping", "physics", "damping", "string", "N s/m", "nonnegative",
              "string damping (acts only while the string is taut)", spread="relative", write="elastic",
              argument="string_damping", mujoco="tendon_damping", skip_zero=True),
    ParamSpec("rest_length_offset", "physics", "rest_length", "string", "m", "finite",
              "a cable's true rest length minus the commanded (or nominal) one", spread="absolute",
              write="offset", field_valid="nonnegative", mujoco="added to tendon_lengthspring[:, 1]"),
    ParamSpec("node_damping", "physics", "node_damping", "node", "N s/m", "nonnegative",
              "viscous drag -c v on each node", spread="relative", argument="node_damping",
              no_mujoco="MuJoCo damps a rod's free-joint DOFs (centre-of-mass translation, "
                        "body-frame rotation), not its end nodes", skip_zero=True),
    ParamSpec("gravity", "physics", "gravity", "vector", "m/s^2", "finite",
              "gravitational acceleration (one draw scales its magnitude)", spread="relative",
              one_factor=True, mujoco="opt.gravity", skip_zero=True),
    ParamSpec("anchor_pos", "physics", "anchor_pos", "anchor", "m", "finite",
              "positions of the fixed anchor nodes"),
    ParamSpec("cap_radius", "contact", "radius", "scalar", "m", "nonnegative",
              "radius of the rod end caps touching the ground", argument="cap_radius"),
    ParamSpec("ground_stiffness", "contact", "stiffness", "scalar", "N/m", "positive",
              "normal contact stiffness", spread="relative", argument="ground_stiffness",
              mujoco="geom_solref[:, 0] (time constant sqrt(m_eff / k))"),
    ParamSpec("ground_damping", "contact", "damping", "scalar", "s/m", "nonnegative",
              "Hunt-Crossley normal contact damping", spread="relative", argument="ground_damping",
              mujoco="geom_solref[:, 1] (damping ratio, relative change)"),
    ParamSpec("exponent", "contact", "exponent", "scalar", "1", "positive",
              "exponent of the normal force law (one per contact model)"),
    ParamSpec("friction", "contact", "friction", "scalar", "1", "nonnegative",
              "Coulomb friction coefficient", spread="relative", argument="friction",
              mujoco="geom_friction[:, 0]"),
    ParamSpec("tangential_stiffness", "contact", "tangential_stiffness", "scalar", "N/m", "positive",
              "stiffness of the stick spring", argument="tangential_stiffness"),
    ParamSpec("tangential_damping", "contact", "tangential_damping", "scalar", "N s/m", "nonnegative",
              "damping of the stick spring", argument="tangential_damping"),
    ParamSpec("ground_max_damping", "contact", "max_damping", "scalar", "N s/m", "positive",
              "cap on the normal contact damping coefficient", argument="ground_max_damping"),
    ParamSpec("height", "contact", "height", "scalar", "m", "finite", "ground height"),
    ParamSpec("max_cable_speed", "actuation", "max_rate", "motor", "m/s", "positive",
              "rate limit of each actuated cable (N/(m s) in force-density mode)", spread="relative",
              argument="max_cable_speed", mujoco="the cable motor model (Actuation), not MuJoCo"),
    ParamSpec("max_cable_acceleration", "actuation", "max_accel", "scalar", "m/s^2", "positive",
              "acceleration limit of the cable motor model", spread="relative",
              argument="max_cable_acceleration", mujoco="the cable motor model (Actuation), not MuJoCo"),
)


def _table(table):
    return PARAMS if table is None else tuple(table)


def spec(name: str, table=None) -> ParamSpec:
    """The row called ``name``; KeyError naming the known names otherwise."""
    for row in _table(table):
        if row.name == name:
            return row
    raise KeyError(f"no parameter {name!r}; known: {sorted(r.name for r in _table(table))}")


def env_params(table=None) -> dict[str, ParamSpec]:
    """name -> row of the parameters the envs fix / randomise, in table order."""
    return {r.name: r for r in _table(table) if r.randomizable}


#: the axis word of the Params messages ("gravity component 2")
_PARAMS_AXIS = {"vector": "component"}
#: the axis word of the env messages ("params['friction']: copy 0")
_DOMAIN_AXIS = {"scalar": "copy", "motor": "actuated"}


def params_fields(table=None) -> dict[str, tuple[str, str, str]]:
    """``Params`` field -> (what its second axis counts, unit, valid range), in field order."""
    return {r.field: (_PARAMS_AXIS.get(r.axis, r.axis), r.unit, r.field_valid or r.valid)
            for r in _table(table) if r.group == "physics"}


def physics_fields(table=None) -> tuple[str, ...]:
    """The ``Params`` fields, in order."""
    return tuple(r.field for r in _table(table) if r.group == "physics")


def contact_columns(table=None) -> tuple[str, ...]:
    """The columns of the (P, 9) ground contact parameter array, in order; a terrain part's
    (P, F, 8) columns are the same without the last, ``height`` (:func:`part_columns`)."""
    return tuple(r.field for r in _table(table) if r.group == "contact")


def part_columns(table=None) -> tuple[str, ...]:
    """The columns of the (P, F, 8) per-part terrain contact parameters: the contact columns
    without the ground height (a part's geometry places it)."""
    cols = contact_columns(table)
    if cols[-1] != "height":
        raise ValueError(f"parameter table: the contact rows must end with the ground height, got {cols}")
    return cols[:-1]


def contact_arguments(table=None) -> dict[str, str]:
    """``GroundContact`` field -> the task argument that sets it, where the names differ."""
    return {r.field: r.argument for r in _table(table)
            if r.group == "contact" and r.argument is not None and r.argument != r.field}


def env_fields(group: str, table=None) -> dict[str, str]:
    """Env parameter name -> its field in the container ``group`` (one of :data:`GROUPS`)."""
    if group not in GROUPS:
        raise ValueError(f"group: expected one of {GROUPS}, got {group!r}")
    return {r.name: r.field for r in _table(table) if r.randomizable and r.group == group}


@dataclass(frozen=True)
class DomainSpec:
    """What the env parameter code reads of a row: ``per`` (the item word of its messages),
    ``unit``, ``absolute`` (absolute spread), ``one_factor``, ``valid``."""

    per: str
    unit: str
    absolute: bool
    one_factor: bool = False
    valid: str = "positive"


def domain_specs(table=None) -> dict[str, DomainSpec]:
    """Env parameter name -> :class:`DomainSpec`, in table order."""
    return {r.name: DomainSpec(_DOMAIN_AXIS.get(r.axis, r.axis), "" if r.unit == "1" else r.unit, r.absolute,
                               r.one_factor, r.valid)
            for r in _table(table) if r.randomizable}


def twin_params(table=None) -> tuple[str, ...]:
    """The env parameters the MuJoCo twin represents, sorted by name."""
    return tuple(sorted(r.name for r in _table(table) if r.randomizable and r.mujoco is not None))


def twin_refusals(table=None) -> dict[str, str]:
    """Env parameter name -> why the MuJoCo twin cannot represent it."""
    return {r.name: r.no_mujoco for r in _table(table) if r.randomizable and r.no_mujoco is not None}


#: physics axis -> the model's item count it repeats over (the per-item axes of a Params field)
ITEM_AXES = ("rod", "string", "node")


def physics_rows(table=None) -> tuple[ParamSpec, ...]:
    """The rows of the ``Params`` fields, in field order."""
    return tuple(r for r in _table(table) if r.group == "physics")


def skipped_fields(table=None) -> tuple[str, ...]:
    """The ``Params`` fields whose term the equations skip where every value is 0 (``skip_zero``),
    in field order: ``Params.has_<field>``, the numba flag bits and the torch flags are these."""
    return tuple(r.field for r in physics_rows(table) if r.skip_zero)


def nominal_default(field: str, table=None) -> float:
    """The nominal value of the physics field ``field`` where the structure gives none (the row's
    ``nominal``); ValueError naming the row when it has none."""
    for r in physics_rows(table):
        if r.field == field:
            if r.nominal is None:
                raise ValueError(f"ParamSpec {r.name!r}: compile_model does not compute field {field!r} from the "
                                 "structure, so the row needs a nominal value (nominal=...)")
            return float(r.nominal)
    raise KeyError(f"no physics field {field!r}; known: {list(physics_fields(table))}")
