"""Grouped task configurations: frozen dataclasses, one per concern, as MuJoCo Playground's
``default_config()`` (SI units).

A task takes ``config=`` (a :class:`RollConfig` / :class:`ShapeConfig`, default
:func:`roll_config` / :func:`shape_config`) and any of the flat keyword arguments the env ids
document (``gymnasium.make("TensegrityRoll-v0", dt=5e-4, friction=0.8)``): each flat name is the
field of exactly one group, and a flat argument replaces that field of ``config``::

    cfg = roll_config()
    cfg = replace(cfg, contact=replace(cfg.contact, friction=0.8))
    env = gymnasium.make("TensegrityRoll-v0", config=cfg, dt=5e-4)

The values are checked where the task uses them (errors name the flat argument). The meaning and
unit of every field: the env's manual (``help(tensegrity_gym.envs.roll.TensegrityRollEnv)``).
"""
from __future__ import annotations

import dataclasses
import inspect
from dataclasses import dataclass

from ..physics.contact import GroundContact
from ..tasks.navigate import CourseSpec
from .roll_scene import MAX_CABLE_ACCELERATION, STRING_DAMPING

__all__ = ["TaskConfig", "CableConfig", "SimulationConfig", "ObservationConfig", "RandomizationConfig", "RollRobotConfig", "RollActuationConfig",
           "ContactConfig", "TerrainConfig", "RollRewardConfig", "GoalConfig", "RollConfig", "SlopeConfig", "ClimbConfig", "climb_config", "CourseConfig",
           "NavigateConfig", "navigate_config", "ShapeRobotConfig",
           "ShapeActuationConfig", "ShapeRewardConfig", "TargetConfig", "ShapeConfig", "roll_config", "shape_config",
           "flat_fields", "flatten", "with_flat", "flat_signature"]

DEFAULT_SHAPE_STRING_DAMPING = 5.0   # N s/m per string
DEFAULT_SHAPE_NODE_DAMPING = 2.0     # N s/m per rod node (viscous drag / joint friction)


@dataclass(frozen=True)
class SimulationConfig:
    """How the physics is stepped: integrator, ``dt`` (s), ``frame_skip`` physics steps per
    action, compute ``backend``, ``divergence_limit`` (m), ``allow_unstable_dt``."""

    integrator: str = "semi_implicit_euler"
    dt: float = 1e-3
    frame_skip: int = 20
    backend: str = "auto"
    divergence_limit: float | None = None
    allow_unstable_dt: bool = False


@dataclass(frozen=True)
class ObservationConfig:
    """What the policy observes: ``observation_mode`` (``"state"`` or ``"robot"``), the robot
    observation's ``sensor_noise`` and ``history`` frames."""

    observation_mode: str = "state"
    sensor_noise: dict | None = None
    history: int = 1


@dataclass(frozen=True)
class RandomizationConfig:
    """What is drawn or fixed per copy: the initial-state noise ``reset_noise_scale``, the robot
    parameters ``params`` (fixed) and ``randomize`` (spreads, :mod:`tensegrity_gym.envs.domain`)."""

    reset_noise_scale: float = 1e-3
    params: dict | None = None
    randomize: dict | None = None


@dataclass(frozen=True)
class RollRobotConfig:
    """The rolling robot: ``structure`` (a built-in name, a JSON path or a Structure) and its
    ``string_damping`` (N s/m; None: the structure's own)."""

    structure: object = "prism"
    string_damping: float | None = STRING_DAMPING


@dataclass(frozen=True)
class CableConfig:
    """What both tasks' cables share: ``action_mode``, which strings are ``actuated``, the
    force-density limits (N/m, N/(m s)), ``clip_actions``, ``action_delay`` (control steps) and
    the slack start ``start_rest_length_offset`` (m)."""

    action_mode: str = "rest_length"
    actuated: object = None
    force_density_max: float | None = None
    force_density_rate: float | None = None
    clip_actions: bool = True
    action_delay: int = 0
    start_rest_length_offset: object = None


@dataclass(frozen=True)
class RollActuationConfig(CableConfig):
    """The cables (:class:`CableConfig`) with the motor's rate and acceleration limits
    (``max_cable_speed`` m/s, ``max_cable_acceleration`` m/s^2) and ``rest_length_bounds``."""

    max_cable_speed: float = 0.2
    max_cable_acceleration: float | None = MAX_CABLE_ACCELERATION
    rest_length_bounds: tuple = (0.5, 1.1)


@dataclass(frozen=True)
class ContactConfig:
    """Ground contact (:class:`tensegrity_gym.physics.contact.GroundContact`; the names its rows carry in
    :mod:`tensegrity_gym.core.param_table`) and the optional rod-rod contact ``rod_contact``
    (:class:`tensegrity_gym.physics.rod_contact.RodContact`)."""

    friction: float = GroundContact.friction
    ground_stiffness: float = GroundContact.stiffness
    ground_damping: float = GroundContact.damping
    tangential_stiffness: float | None = GroundContact.tangential_stiffness
    tangential_damping: float = GroundContact.tangential_damping
    cap_radius: float = GroundContact.radius
    ground_max_damping: float | None = None     # None: the task's cap (m_eff / dt)
    rod_contact: object = None     # None: rods pass through each other; True or a dict of RodContact fields


@dataclass(frozen=True)
class TerrainConfig:
    """The ground the robot moves on (:mod:`tensegrity_gym.tasks.terrain`): ``terrain`` (None:
    level ground at z = 0; a ``Terrain``, a terrain file's dict or path; or a generator,
    ``TerrainGenerator`` or ``{"generator": kind, ...}``, drawn per episode) and
    ``terrain_difficulty`` in [0, 1], the scale of a generated terrain (the curriculum's knob)."""

    terrain: object = None
    terrain_difficulty: float = 1.0


@dataclass(frozen=True)
class RollRewardConfig:
    """Reward weights: ``forward_reward_weight`` (s/m), ``ctrl_cost_weight``."""

    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 0.01


@dataclass(frozen=True)
class GoalConfig:
    """The goal: ``goal_direction`` (x, y) and ``randomize_goal`` (a uniform direction per reset)."""

    goal_direction: tuple = (1.0, 0.0)
    randomize_goal: bool = False


@dataclass(frozen=True)
class TaskConfig:
    """The groups every task has: ``simulation``, ``observation``, ``randomization``."""

    simulation: SimulationConfig = SimulationConfig()
    observation: ObservationConfig = ObservationConfig()
    randomization: RandomizationConfig = RandomizationConfig()


@dataclass(frozen=True)
class RollConfig(TaskConfig):
    """Every argument of ``TensegrityRoll-v0``'s task, grouped."""

    randomization: RandomizationConfig = RandomizationConfig(reset_noise_scale=1e-3)
    robot: RollRobotConfig = RollRobotConfig()
    actuation: RollActuationConfig = RollActuationConfig()
    contact: ContactConfig = ContactConfig()
    reward: RollRewardConfig = RollRewardConfig()
    goal: GoalConfig = GoalConfig()
    terrain: TerrainConfig = TerrainConfig()


@dataclass(frozen=True)
class SlopeConfig:
    """The slope of ``TensegrityClimb-v0``: ``slope_deg`` (degrees, uphill along +x of the plane
    frame) or, for curricula, ``slope_range`` (low, high) degrees drawn uniformly per reset."""

    slope_deg: float = 20.0
    slope_range: tuple | None = None


@dataclass(frozen=True)
class ClimbConfig(RollConfig):
    """Every argument of ``TensegrityClimb-v0``'s task, grouped: the rolling task's plus the slope."""

    slope: SlopeConfig = SlopeConfig()


@dataclass(frozen=True)
class CourseConfig(CourseSpec):
    """The courses of ``TensegrityNavigate-v0``: the fields of
    :class:`tensegrity_gym.tasks.navigate.CourseSpec` (goals, walls, rough patches, the success
    radius and the planner's grid, m), the reward ``goal_bonus`` per goal reached and the optional
    ``height_scan`` ((n, spacing m): an n x n grid of terrain heights around the robot)."""

    goal_bonus: float = 10.0
    height_scan: tuple | None = None


@dataclass(frozen=True)
class NavigateConfig(RollConfig):
    """Every argument of ``TensegrityNavigate-v0``'s task, grouped: the rolling task's plus the course."""

    course: CourseConfig = CourseConfig()


def navigate_config() -> NavigateConfig:
    """The default configuration of ``TensegrityNavigate-v0``'s task."""
    return NavigateConfig()


def climb_config() -> ClimbConfig:
    """The default configuration of ``TensegrityClimb-v0``'s task."""
    return ClimbConfig()


@dataclass(frozen=True)
class ShapeRobotConfig:
    """The anchored structure (``structure``), its ``string_damping`` (N s/m; None: its own) and
    ``node_damping`` (N s/m per node)."""

    structure: object = "constrained_prism"
    string_damping: float | None = DEFAULT_SHAPE_STRING_DAMPING
    node_damping: float = DEFAULT_SHAPE_NODE_DAMPING


@dataclass(frozen=True)
class ShapeActuationConfig(CableConfig):
    """The cables (:class:`CableConfig`) with ``rest_length_bounds`` and the rate limit
    ``max_speed`` (m/s)."""

    rest_length_bounds: tuple = (0.8, 1.1)
    max_speed: float = 0.1


@dataclass(frozen=True)
class ShapeRewardConfig:
    """Reward weights and the success tolerance (m; None: the task's default)."""

    tracking_weight: float = 10.0
    proximity_weight: float = 1.0
    ctrl_cost_weight: float = 0.01
    success_tolerance: float | None = None


@dataclass(frozen=True)
class TargetConfig:
    """The targets: ``target_range`` (the spread of the rest lengths the targets are drawn from)."""

    target_range: float = 0.1


@dataclass(frozen=True)
class ShapeConfig(TaskConfig):
    """Every argument of ``TensegrityShape-v0``'s task, grouped."""

    randomization: RandomizationConfig = RandomizationConfig(reset_noise_scale=5e-3)
    robot: ShapeRobotConfig = ShapeRobotConfig()
    actuation: ShapeActuationConfig = ShapeActuationConfig()
    reward: ShapeRewardConfig = ShapeRewardConfig()
    target: TargetConfig = TargetConfig()


def roll_config() -> RollConfig:
    """The default configuration of ``TensegrityRoll-v0``'s task."""
    return RollConfig()


def shape_config() -> ShapeConfig:
    """The default configuration of ``TensegrityShape-v0``'s task."""
    return ShapeConfig()


def flat_fields(config) -> dict[str, str]:
    """Flat argument name -> its group in ``config`` (an instance of a grouped config)."""
    out = {}
    for g in dataclasses.fields(config):
        for f in dataclasses.fields(getattr(config, g.name)):
            out[f.name] = g.name
    return out


def flatten(config) -> dict:
    """Flat argument name -> value of ``config``."""
    return {name: getattr(getattr(config, group), name) for name, group in flat_fields(config).items()}


def with_flat(config, kwargs: dict, owner: str, config_type=None):
    """``config`` (None: ``config_type()``, the defaults) with the flat arguments ``kwargs``
    replacing their fields. ValueError naming ``config`` when it is not a ``config_type``; a name
    no group has is the TypeError Python raises for an unknown keyword argument of ``owner``."""
    if config_type is not None:
        if config is None:
            config = config_type()
        elif not isinstance(config, config_type):
            raise ValueError(f"config: expected a {config_type.__name__} (grouped arguments, "
                             f"tensegrity_gym.envs.config), got {config!r:.80}")
    where = flat_fields(config)
    changes: dict[str, dict] = {}
    for name, value in kwargs.items():
        if name not in where:
            raise TypeError(f"{owner}() got an unexpected keyword argument {name!r}")
        changes.setdefault(where[name], {})[name] = value
    return dataclasses.replace(config, **{g: dataclasses.replace(getattr(config, g), **c) for g, c in changes.items()})


def flat_signature(config, config_type) -> inspect.Signature:
    """The signature ``(num_envs=1, config=None, *, <every flat argument with its default>)`` of a
    task built from ``config`` (what introspection, e.g. ``agents.envs.env_argument_names``,
    lists as the task's arguments)."""
    P = inspect.Parameter
    params = [P("num_envs", P.POSITIONAL_OR_KEYWORD, default=1, annotation=int),
              P("config", P.POSITIONAL_OR_KEYWORD, default=None, annotation=config_type | None)]
    params += [P(name, P.KEYWORD_ONLY, default=value) for name, value in flatten(config).items()]
    return inspect.Signature(params)
