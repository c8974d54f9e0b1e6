"""TensegrityClimb-v0: roll a tensegrity robot up a slope by changing its cables.

The rolling task (:class:`~tensegrity_gym.envs.roll.RollTask`) on a plane of slope ``slope_deg``,
simulated in the plane's frame (:mod:`tensegrity_gym.tasks.climb`: the level ground contact
with gravity tilted, exact for a plane); the goal is uphill (+x). SI units, angles in degrees.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.checks import check_array
from ..core.params import default_params
from ..tasks.climb import gravity_direction, plane_gravity
from ..tasks.state import StateField
from ..tasks.xp import namespace
from .config import ClimbConfig, climb_config, flat_signature, with_flat
from .roll import RollTask
from .shells import TaskEnv, TaskVectorEnv

__all__ = ["ClimbTask", "TensegrityClimbEnv", "TensegrityClimbVectorEnv", "check_slope"]

ENV_ID = "TensegrityClimb-v0"
#: steepest slope accepted, degrees (a robot on a steeper plane mostly falls)
MAX_SLOPE_DEG = 60.0


def check_slope(slope_deg, slope_range) -> tuple[float, float]:
    """(low, high) slope in degrees from ``slope_deg`` or ``slope_range``; ValueError naming the
    argument and the value unless each is a finite number in [0, MAX_SLOPE_DEG] (low <= high)."""
    def angle(v, name):
        if isinstance(v, (bool, np.bool_, str, bytes)):
            raise ValueError(f"{name}: expected a number of degrees, got {v!r}")
        try:
            x = float(v)
        except OverflowError:      # an integer too large for a float
            raise ValueError(f"{name}: must be in [0, {MAX_SLOPE_DEG:g}] degrees, got an integer of "
                             f"{int(v).bit_length()} bits") from None
        except (TypeError, ValueError):
            raise ValueError(f"{name}: expected a number of degrees, got {v!r:.80}") from None
        if not (math.isfinite(x) and 0.0 <= x <= MAX_SLOPE_DEG):
            raise ValueError(f"{name}: must be in [0, {MAX_SLOPE_DEG:g}] degrees, got {v!r}")
        return x
    if slope_range is None:
        a = angle(slope_deg, "slope_deg")
        return a, a
    try:
        if isinstance(slope_range, (str, bytes, dict)):
            raise TypeError
        lo, hi = slope_range
    except (TypeError, ValueError):
        raise ValueError(f"slope_range: expected (low, high) degrees, got {slope_range!r:.80}") from None
    lo, hi = angle(lo, "slope_range[0]"), angle(hi, "slope_range[1]")
    if lo > hi:
        raise ValueError(f"slope_range: low {lo:g} is above high {hi:g} degrees")
    return lo, hi


class ClimbTask(RollTask):
    """The rolling task on a slope (arguments: see :class:`TensegrityClimbEnv`).

    State: the rolling task's, in the plane frame (x uphill, z along the plane's normal), and
    ``slope`` (B,) degrees, each copy's slope this episode, and ``gdir`` (B, 3) its gravity
    direction (observed; float32 values)."""

    STATE = RollTask.STATE + (StateField("slope"), StateField("gdir"))
    #: the vector env's ``set_attr`` sets the slope range (a terrain difficulty has no terrain here)
    CURRICULUM_HOOKS = {"slope_range": "set_slope_range"}

    def __init__(self, num_envs: int = 1, config: ClimbConfig | None = None, **kwargs):
        c = with_flat(config, kwargs, "ClimbTask.__init__", ClimbConfig)
        self._slope_range = check_slope(c.slope.slope_deg, c.slope.slope_range)
        if c.goal.randomize_goal:
            raise ValueError("randomize_goal: the goal of TensegrityClimb-v0 is uphill (+x of the plane frame)")
        if tuple(check_array(c.goal.goal_direction, (2,), "goal_direction")) != (1.0, 0.0):
            raise ValueError(f"goal_direction: the goal of TensegrityClimb-v0 is uphill, (1, 0); got "
                             f"{c.goal.goal_direction!r}")
        if c.terrain.terrain not in (None, {}):
            raise ValueError(f"terrain: the ground of {ENV_ID} is its slope (slope_deg, slope_range); for other "
                             f"terrain use TensegrityRoll-v0's terrain argument, got {c.terrain.terrain!r:.80}")
        for arg in ("params", "randomize"):
            d = getattr(c.randomization, arg)
            if isinstance(d, dict) and "gravity" in d:
                raise ValueError(f"{arg}: 'gravity' is set by the slope in TensegrityClimb-v0 (slope_deg, slope_range)")
        super().__init__(num_envs, config=c)
        B = self.num_envs
        lo, hi = self.slope_range
        self.slope = np.full(B, lo)
        self._draws_slope = hi > lo
        if self._draws_slope:      # one gravity row per copy, drawn at each reset
            if self.params is None:
                self.params = default_params(self.model, B)
            elif self.params.batch_size != B:
                self.params = self.params.take(np.zeros(B, int))
            self._physics_per_copy = True
        self.gdir = np.tile(gravity_direction(plane_gravity(lo, self._g)), (B, 1)).astype(np.float32)
        if self.sensors is None:     # the state observation: the rolling task's plus the slope
            self.observation_size = self._state_size + 3

    @property
    def slope_range(self) -> tuple[float, float]:
        """(low, high) degrees: the range the next resets draw each copy's slope from (low = high:
        a fixed slope). Set it between episodes (a curriculum) to a new (low, high) in
        [0, MAX_SLOPE_DEG] degrees (:meth:`set_slope_range`)."""
        return self._slope_range

    @slope_range.setter
    def slope_range(self, value) -> None:
        self.set_slope_range(value)

    def set_slope_range(self, value) -> None:
        """The curriculum hook: the slopes drawn from the next resets on are U(low, high) degrees
        for ``value`` = (low, high), finite numbers in [0, MAX_SLOPE_DEG] with low <= high
        (ValueError naming ``slope_range`` otherwise). An env built with one fixed ``slope_deg``
        has a single gravity for all copies and draws no slope: its range cannot change (build it
        with ``slope_range`` to change the slope between episodes)."""
        lo, hi = check_slope(None, value)
        if not self._draws_slope and (lo, hi) != self._slope_range:
            raise ValueError(f"slope_range: this env was built with the fixed slope_deg={self._slope_range[0]:g} "
                             f"degrees and draws no slope; build it with slope_range=(low, high) to change "
                             f"the slope between episodes, got {value!r:.80}")
        self._slope_range = (lo, hi)

    def _scene_structure(self, s):
        self._g = float(np.linalg.norm(s.gravity))
        return s.replace(gravity=plane_gravity(self.slope_range[0], self._g))

    @property
    def draws_physics(self) -> bool:
        return super().draws_physics or self._draws_slope

    @property
    def first_draws(self) -> int:
        """The slope, with a ``slope_range``: the first draw of each copy's generator at reset."""
        return int(self._draws_slope)

    def reset_first(self, rec, rows, u) -> None:
        """Copies ``rows`` of the record ``rec`` take the slope U(lo, hi) degrees of their uniforms
        ``u[:, 0]`` in [0, 1) (``lo + (hi - lo) u``: NumPy's ``uniform(lo, hi)`` of the same draw),
        its gravity in the plane frame (:func:`~tensegrity_gym.tasks.climb.plane_gravity`) and its
        gravity direction (float32 values)."""
        lo, hi = self.slope_range
        a = lo + (hi - lo) * u[:, 0]
        g = plane_gravity(a, self._g)
        rec.write_params(rows, {"gravity": g})
        rec.slope[rows] = a
        xp = namespace(g)
        rec.gdir[rows] = xp.to_float(xp.float32(gravity_direction(g)), rec.gdir)

    def reset_info(self, rec, rows) -> dict:
        return {"slope_deg": namespace(rec.slope).copy(rec.slope[rows])}

    def slope_gravity(self) -> np.ndarray:
        """(B, 3) each copy's gravity this episode in its plane frame, m/s^2 (from its slope; what
        another simulator of this task, such as the MuJoCo twin, sets as its gravity)."""
        return plane_gravity(self.slope, self._g)

    def climb_info(self, rec, forward_velocity) -> dict:
        """The info keys of this task beyond the rolling task's on the record ``rec``, from the
        velocity along the goal ``forward_velocity`` (B,) m/s: ``slope_deg`` (B,) degrees and
        ``uphill_velocity`` (B,) m/s."""
        return {"slope_deg": namespace(rec.slope).copy(rec.slope), "uphill_velocity": forward_velocity}

    def task_step(self, rec, com0, com, action):
        terms, terminated, infos = super().task_step(rec, com0, com, action)
        infos.update(self.climb_info(rec, infos["forward_velocity"]))     # the goal is uphill (+x)
        return terms, terminated, infos

    def observe_task(self, rec, obs):
        """The rolling task's observation and the gravity direction (B, 3)."""
        return namespace(obs).concat([obs, rec.gdir], axis=1)

    def observation_layout(self) -> list[tuple[str, slice, str]]:
        out = super().observation_layout()
        if self.sensors is None:
            out.append(("gravity_direction", slice(self._state_size, self._state_size + 3), "1"))
        return out

    def render_data(self, i: int) -> dict:
        d = super().render_data(i)
        d["caption"] = f"slope {self.slope[i]:.1f} deg, " + d["caption"].replace("rolled", "climbed")
        return d


ClimbTask.__signature__ = flat_signature(climb_config(), ClimbConfig)

_DOC = r"""
    ## Description
    The rolling robot of ``TensegrityRoll-v0`` (same robots, cables, actions, contact and
    arguments) on a plane of slope ``slope_deg`` degrees; the goal is uphill. The physics runs
    in the plane's frame (x uphill, y across, z along the plane's normal): the plane is the
    level ground z = 0 with gravity tilted to ``|g| (-sin a, 0, -cos a)``, exactly the physics of
    a sloped plane, rotated. Positions, velocities and rewards are in that frame.

    ## Arguments (besides those of TensegrityRoll-v0)
    | argument | default | meaning |
    |---|---|---|
    | ``slope_deg`` | 20.0 | slope, degrees in [0, 60] |
    | ``slope_range`` | None | (low, high) degrees: a slope drawn uniformly per reset from the env's ``np_random`` (curricula: change it between episodes with ``env.unwrapped.task.slope_range = (lo, hi)`` or a vector env's ``set_attr("slope_range", (lo, hi))``, validated; an env built with a fixed ``slope_deg`` refuses a new range) |

    ``goal_direction`` must be (1, 0) and ``randomize_goal`` False (the goal is uphill).

    ## Observation
    State mode: the rolling task's observation plus ``gravity_direction`` (3): the unit vector
    of gravity in the plane frame (the slope as the robot's IMU sees it at rest). Robot mode:
    the rolling task's sensors (the accelerometers read the tilted gravity).

    ## Rewards and info
    ``reward_forward``: ``forward_reward_weight`` x the uphill velocity of the centre of mass
    (m/s); ``reward_ctrl`` as TensegrityRoll-v0. ``info``: the rolling task's, plus
    ``slope_deg`` and ``uphill_velocity`` (m/s; ``distance_rolled`` is the distance climbed
    along the slope, m).
"""

TensegrityClimbEnv = TaskEnv.for_task(ClimbTask, ENV_ID, _DOC, __name__)
TensegrityClimbVectorEnv = TaskVectorEnv.for_task(ClimbTask, ENV_ID, _DOC + r"""
    ## Vector env
    ``gymnasium.make_vec("TensegrityClimb-v0", num_envs=N, vectorization_mode="vector_entry_point")``
    or ``TensegrityClimbVectorEnv(num_envs=N, **kwargs)``; as TensegrityRoll-v0's vector env.
""", __name__)
