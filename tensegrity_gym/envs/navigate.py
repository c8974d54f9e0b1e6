"""TensegrityNavigate-v0: roll a tensegrity robot through a sequence of goal points among
obstacles and rough patches.

The rolling task (:class:`~tensegrity_gym.envs.roll.RollTask`, same robots, cables, actions and
contact) on a course drawn per episode (:mod:`tensegrity_gym.tasks.navigate`): its terrain is the
course's boxes and rough heightfield (terrain contact), and the goal direction the task rewards
and observes is the course planner's guidance toward the current goal point. SI units.
"""
from __future__ import annotations

import numpy as np

from ..core.checks import check_array
from ..tasks.navigate import (CourseSpec, check_course_size, current_goal, draw_course, guidance_batch, height_scan,
                              navigate_observation, track_goals)
from ..tasks.state import StateField
from ..tasks.xp import namespace
from .config import NavigateConfig, flat_signature, navigate_config, with_flat
from .roll import RollTask
from .shells import TaskEnv, TaskVectorEnv
from .validate import check_positive

__all__ = ["NavigateTask", "TensegrityNavigateEnv", "TensegrityNavigateVectorEnv"]

ENV_ID = "TensegrityNavigate-v0"


def _course_spec(c) -> CourseSpec:
    """The :class:`CourseSpec` of the ``course`` group ``c``; ValueError naming a wrong argument."""
    def count(name, lo):
        v = getattr(c, name)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{name}: must be an integer >= {lo}, got {v!r}")
        return int(v)

    def span(name):
        v = getattr(c, name)
        a = check_array(v, (2,), name)
        if not (0 < a[0] <= a[1]):
            raise ValueError(f"{name}: expected (low, high) with 0 < low <= high (m), got {v!r}")
        return float(a[0]), float(a[1])

    def length(name, allow_zero=False):
        return check_positive(getattr(c, name), name, "m", allow_zero=allow_zero)
    return CourseSpec(n_goals=count("n_goals", 1), goal_distance=span("goal_distance"), goal_radius=length("goal_radius"),
                      arena=length("arena"), n_obstacles=count("n_obstacles", 0), obstacle_size=span("obstacle_size"),
                      obstacle_height=length("obstacle_height"), clearance=length("clearance", True),
                      n_rough=count("n_rough", 0), rough_radius=span("rough_radius"),
                      rough_amplitude=length("rough_amplitude", True), rough_wavelength=length("rough_wavelength"),
                      cell=length("cell"), inflate=length("inflate", True), lookahead=count("lookahead", 1))


class NavigateTask(RollTask):
    """The rolling task on a course (arguments: see :class:`TensegrityNavigateEnv`).

    State: the rolling task's, with ``goal`` (B, 2) the planner's unit guidance toward the current
    goal; ``courses`` (one :class:`~tensegrity_gym.tasks.navigate.Course` per copy),
    ``goal_index`` (B,) the current goal (``n_goals``: all reached), ``path`` (B,) the planner's
    path distance to it, m."""

    STATE = RollTask.STATE + (StateField("goal_index", "int"), StateField("path"),
                              StateField("fields", nan=np.inf), StateField("goals", nan=0.0))
    CONSTANTS = (StateField("origin"), StateField("scan"))
    DEVICE_RESET = False
    NO_DEVICE_RESET = "its courses are drawn and planned per reset on the host"
    #: no curriculum hook: a course is not scaled by a terrain difficulty
    CURRICULUM_HOOKS = {}

    def __init__(self, num_envs: int = 1, config: NavigateConfig | None = None, **kwargs):
        c = with_flat(config, kwargs, "NavigateTask.__init__", NavigateConfig)
        if c.terrain.terrain not in (None, {}):
            raise ValueError(f"terrain: the ground of {ENV_ID} is its course (n_obstacles, n_rough, ...), got "
                             f"{c.terrain.terrain!r:.80}")
        if c.goal.randomize_goal:
            raise ValueError(f"randomize_goal: the goals of {ENV_ID} are the course's goal points")
        self.spec = _course_spec(c.course)
        self.goal_bonus = check_positive(c.course.goal_bonus, "goal_bonus", allow_zero=True)
        self.scan = None
        n = 0
        if c.course.height_scan is not None:
            try:
                n, spacing = c.course.height_scan
            except (TypeError, ValueError):
                raise ValueError(f"height_scan: expected (n, spacing m), got {c.course.height_scan!r:.80}") from None
            if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
                raise ValueError(f"height_scan: n must be a positive integer, got {n!r:.80}")
            spacing = check_positive(spacing, "height_scan spacing", "m")
        # the planner's grid, its guidance window and the scan: refused before they are allocated
        check_course_size(self.spec, max(int(num_envs), 1) if isinstance(num_envs, (int, np.integer)) else 1, int(n))
        if c.course.height_scan is not None:
            u = (np.arange(n) - (n - 1) / 2) * spacing
            self.scan = np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)      # (n^2, 2) offsets, m
        self.courses = [None] * max(int(num_envs), 1)
        super().__init__(num_envs, config=c)
        B = self.num_envs
        self.goal_index = np.zeros(B, int)
        self.path = np.zeros(B)
        self.n_extra = 2 + (0 if self.scan is None else len(self.scan))
        self._blocks = {name: sl for name, sl, _ in RollTask.observation_layout(self)}
        if self.sensors is None:
            self.observation_size = self._state_size + self.n_extra

    # ------------------------------------------------------------------ course
    def _terrain_source(self, tcfg, surface: dict):
        return self.spec

    def _draw_terrain(self, i: int, rng: np.random.Generator, goal):
        course = draw_course(self.spec, rng, self._surface)
        if i == 0 and self.courses[0] is None:    # the first draw: the per-copy arrays of every course
            B = len(self.courses)
            self.fields = np.empty((B,) + course.field.shape)
            self.goals = np.empty((B,) + course.goals.shape)
        self.courses[i] = course
        self.fields[i], self.goals[i] = course.field, course.goals
        return course.terrain

    @property
    def origin(self) -> np.ndarray:
        """(2,) the planner grid's origin, m (the same for every course)."""
        return self.courses[0].origin

    def guide(self, idx) -> None:
        """Guidance (``goal``) and path distance (``path``, m) of copies ``idx`` toward their current
        goal from their current state (the MuJoCo twin calls it on its start state)."""
        idx = np.asarray(idx, dtype=int)
        self.guide_rows(self, self._com(self.q[idx]), idx)

    def guide_rows(self, rec, com, rows=None) -> None:
        """On the record ``rec``: guidance (``goal``) and path distance (``path``, m) of copies
        ``rows`` (r,) int (None: all) toward their current goal from their centres of mass ``com``
        (r, 3) m."""
        ii = namespace(com).arange(com.shape[0], com) if rows is None else rows
        g, goal = current_goal(rec.goals, rec.goal_index[ii], ii)
        rec.goal[ii], rec.path[ii] = guidance_batch(rec.fields, rec.origin, self.courses[0].cell, goal,
                                                    com[:, :2], self.spec.lookahead, g, rows)

    # ------------------------------------------------------------------ task API
    def reset_idx(self, idx, rngs, options=None) -> dict:
        idx = np.asarray(idx, dtype=int)
        info = super().reset_idx(idx, rngs, options)
        self.goal_index[idx] = 0
        self.guide(idx)
        info["goal_direction"] = self.goal[idx].copy()
        info["goal_position"] = self.goals[idx, 0].copy()
        info["path_distance"] = self.path[idx].copy()
        return info

    def task_step(self, rec, com0, com, action):
        terms, _, infos = super().task_step(rec, com0, com, action)
        goal_terms, success, goal_infos = self.goal_step(rec, com)
        terms.update(goal_terms)
        infos.update(goal_infos)
        return terms, success, infos

    def goal_step(self, rec, com) -> tuple[dict, object, dict]:
        """After a step, on the record ``rec`` from the centres of mass ``com`` (B, 3) m: the goals
        reached (centre of mass within ``goal_radius`` m of the current goal), the guidance
        toward the next goal, and their reward term ``{"goal": (B,)}``, success flags (B,) (all
        goals reached) and info (``goals_reached``, ``goal_reached``, ``success``,
        ``distance_to_goal`` m, ``path_distance`` m)."""
        xp = namespace(com)
        rec.goal_index, reached, success, dist = track_goals(rec.goals, rec.goal_index, com[:, :2],
                                                             self.spec.goal_radius)
        self.guide_rows(rec, com)
        infos = dict(goals_reached=xp.copy(rec.goal_index), goal_reached=reached, success=success,
                     distance_to_goal=dist, path_distance=xp.where(success, 0.0, rec.path))
        return {"goal": self.goal_bonus * xp.to_float(reached, com)}, success, infos

    def track_goals(self) -> tuple[dict, np.ndarray, dict]:
        """:meth:`goal_step` of this task from its current state ``q`` (the MuJoCo twin syncs its
        own into it)."""
        return self.goal_step(self, self._com(self.q))

    def observe_task(self, rec, obs):
        """Node positions and velocities in the guidance frame (the goal direction there is
        (1, 0)), the path distance, the goals left and the optional height scan, from the rolling
        task's ``obs`` on the record ``rec``."""
        scan = None
        if rec.scan is not None:
            scan = height_scan(rec.terrain_height, rec.com(rec.q), rec.scan)
        return navigate_observation(obs, self._blocks, rec.goal, rec.path, rec.goal_index, self.spec.n_goals, scan)

    def observation_layout(self) -> list[tuple[str, slice, str]]:
        out = super().observation_layout()
        if self.sensors is None:
            s = self._state_size
            out += [("path_distance", slice(s, s + 1), "m"), ("goals_left", slice(s + 1, s + 2), "1")]
            if self.scan is not None:
                out.append(("height_scan", slice(s + 2, s + self.n_extra), "m"))
        return out

    def render_data(self, i: int) -> dict:
        d = super().render_data(i)
        g = min(self.goal_index[i], self.spec.n_goals - 1)
        d["goal"] = np.array([*self.goals[i, g], 0.0])
        d["caption"] = f"goal {min(self.goal_index[i] + 1, self.spec.n_goals)}/{self.spec.n_goals}, " + d["caption"]
        return d


NavigateTask.__signature__ = flat_signature(navigate_config(), NavigateConfig)

_DOC = r"""
    ## Description
    The rolling robot of ``TensegrityRoll-v0`` (same robots, cables, actions, contact and
    arguments) must reach ``n_goals`` goal points in turn, within ``goal_radius`` m of each,
    on a course drawn per episode from the env's ``np_random``: goals 1-2 m apart in a
    +-``arena`` m square, ``n_obstacles`` walls (boxes ``obstacle_height`` m tall) kept clear of
    the start and the goals, and ``n_rough`` rough patches (bumps up to ``rough_amplitude`` m, a
    heightfield) the robot may cross (:mod:`tensegrity_gym.tasks.navigate`). Every course is
    solvable: the planner (a navigation function on a 0.1 m grid, the walls grown by 0.3 m)
    reaches every goal. The task's goal direction is the planner's guidance: the direction of
    the shortest path around the walls toward the current goal.

    ## Arguments (besides those of TensegrityRoll-v0)
    | argument | default | meaning |
    |---|---|---|
    | ``n_goals`` | 3 | goal points per course |
    | ``goal_distance`` | (1.0, 2.0) | m, distance between consecutive goals (the first from the start) |
    | ``goal_radius`` | 0.3 | m, a goal is reached when the centre of mass is this close (horizontally) |
    | ``arena`` | 3.0 | m, half side of the square holding the course |
    | ``n_obstacles``, ``obstacle_size``, ``obstacle_height`` | 5, (0.2, 0.5), 0.4 | walls: count, side range m, height m |
    | ``n_rough``, ``rough_amplitude`` | 2, 0.02 | rough patches: count, bump height m |
    | ``clearance`` | 0.6 | m, walls kept this far from the start and the goals |
    | ``rough_radius``, ``rough_wavelength`` | (0.3, 0.6), 0.3 | m: radius range of a rough patch, wavelength of its bumps |
    | ``cell``, ``inflate``, ``lookahead`` | 0.1, 0.3, 3 | the planner: grid cell m, walls grown by m (the robot's radius), cells of reach |
    | ``goal_bonus`` | 10.0 | reward per goal reached |
    | ``height_scan`` | None | (n, spacing m): observe an n x n grid of terrain heights around the robot |

    ``terrain`` and ``randomize_goal`` are refused (the course is the ground and the goals).

    ## Observation
    State mode: the rolling task's observation in the guidance frame (x along the guidance, y to
    its left, z up: node positions about the centre of mass and node velocities rotated about
    the vertical, so ``goal_direction`` reads (1, 0); the robot is symmetric under that rotation,
    so one policy serves every direction), plus ``path_distance`` (m, the planner's path length
    to the current goal) and ``goals_left``; with ``height_scan`` also ``n^2`` heights (m,
    relative to the ground under the centre of mass, on a grid of world axes). Robot mode: the
    rolling task's sensors, with the guidance (world frame) as the goal direction.

    ## Rewards, info, episode end
    ``reward_forward``: ``forward_reward_weight`` x the velocity of the centre of mass along the
    guidance (m/s); ``reward_goal``: ``goal_bonus`` when a goal is reached; ``reward_ctrl`` as
    TensegrityRoll-v0. ``info``: the rolling task's, plus ``goals_reached``, ``goal_reached``,
    ``success`` (all goals reached), ``distance_to_goal`` and ``path_distance`` (m). The episode
    terminates on success and is truncated at the registered 3000 control steps (60 s).

    ## Baseline
    :class:`tensegrity_gym.tools.baselines.RollingGait` steered by the guidance (it reads the goal
    direction from the observation): ``python -m scripts.eval.eval_navigate --baseline``.
"""

TensegrityNavigateEnv = TaskEnv.for_task(NavigateTask, ENV_ID, _DOC, __name__)
TensegrityNavigateVectorEnv = TaskVectorEnv.for_task(NavigateTask, ENV_ID, _DOC + r"""
    ## Vector env
    ``gymnasium.make_vec("TensegrityNavigate-v0", num_envs=N, vectorization_mode="vector_entry_point")``
    or ``TensegrityNavigateVectorEnv(num_envs=N, **kwargs)`` (NumPy/numba only).
""", __name__)
