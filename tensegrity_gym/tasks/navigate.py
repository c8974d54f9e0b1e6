"""The navigation task (``TensegrityNavigate-v0``): courses and their planner, as pure NumPy
functions of a seeded generator, and the task's per-step part (guidance, goal tracking,
observation), written once for NumPy arrays and torch tensors (:mod:`tensegrity_gym.tasks.xp`).
SI units: m.

A course is a sequence of goal points among obstacles on level ground: ``n_goals`` goals, each
``U(goal_distance)`` m from the one before (the first from the start at the origin) in a random
direction, inside the square arena ``[-arena, arena]^2``; ``n_obstacles`` boxes (walls of
``obstacle_height`` m, sides ``U(obstacle_size)`` m, random yaw) kept ``clearance`` m clear of
the start and of every goal; and ``n_rough`` rough patches (discs of radius ``U(rough_radius)``
m of smooth bumps up to ``rough_amplitude`` m, a heightfield) that the robot may cross.

The planner is a navigation function: on a grid of ``cell`` m over the arena (and a margin),
the obstacles grown by ``inflate`` m (the robot's radius) are blocked, and the shortest path
length from every free cell to each goal (8-connected Dijkstra, :func:`scipy.sparse.csgraph.dijkstra`)
is computed once per course. The guidance at a position is the direction to the neighbouring
cell (within ``lookahead`` cells) with the shortest remaining path: it follows the shortest path
around the obstacles, and its value is the path distance to the goal. A course is drawn again
until every goal is reachable along that grid from the start and from the goal before it.
"""
from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from ..core.terrain import Box, Heightfield, Terrain
from .xp import NUMPY, namespace

__all__ = ["CourseSpec", "Course", "draw_course", "guidance", "guidance_batch", "guidance_frame", "current_goal",
           "track_goals", "navigate_observation", "height_scan", "MAX_TRIES", "MAX_GRID", "check_course_size"]

#: courses drawn before a spec is declared unsolvable
MAX_TRIES = 200
#: the most cells along a side of the planner's grid or of a height scan (as a rough terrain's grid)
MAX_GRID = 2000


@dataclass(frozen=True)
class CourseSpec:
    """What a course is drawn from (see the module doc; m unless said)."""

    n_goals: int = 3
    goal_distance: tuple = (1.0, 2.0)
    goal_radius: float = 0.3
    arena: float = 3.0
    n_obstacles: int = 5
    obstacle_size: tuple = (0.2, 0.5)
    obstacle_height: float = 0.4
    clearance: float = 0.6
    n_rough: int = 2
    rough_radius: tuple = (0.3, 0.6)
    rough_amplitude: float = 0.02
    rough_wavelength: float = 0.3
    cell: float = 0.1
    inflate: float = 0.3
    lookahead: int = 3


@dataclass(frozen=True, eq=False)
class Course:
    """One drawn course: ``goals`` (n_goals, 2) m, ``terrain`` (the obstacles and rough patches),
    ``field`` (n_goals, ny, nx) path distance (m; inf where blocked) to each goal on the planner's
    grid of ``cell`` m from ``origin`` (x0, y0) m."""

    goals: np.ndarray
    terrain: Terrain
    field: np.ndarray
    origin: np.ndarray
    cell: float


def _memory_limit() -> float:
    """Half the machine's physical memory, bytes (4 GiB where it cannot be read): what a task's
    courses may take (the CLI's default ``--max-memory``)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return 4.0 * 2**30


def grid_side(spec: CourseSpec) -> float:
    """Cells along a side of the planner's grid (:func:`_grid`), as a float (inf where it overflows)."""
    side = 2.0 * (spec.arena + spec.inflate + 0.5) / spec.cell
    return float(math.ceil(side) + 1) if math.isfinite(side) else math.inf


def course_bytes(spec: CourseSpec, num_envs: int, scan_n: int = 0) -> float:
    """About the memory (bytes) of the planner and of ``num_envs`` copies' courses: the grid's
    coordinates, obstacles, rough heights and 8-connected graph (about 50 doubles a cell while it is
    built), each course's path distances (``n_goals`` doubles a cell, kept per copy), and per copy
    and step the guidance window of ``(2 lookahead + 1)^2`` cells and the ``scan_n^2`` points of a
    height scan (a dozen doubles each)."""
    cells = grid_side(spec) ** 2
    per_copy = cells * spec.n_goals + 4.0 * (2.0 * spec.lookahead + 1) ** 2 + 12.0 * scan_n ** 2
    return 8.0 * (cells * (50 + spec.n_goals) + num_envs * per_copy)


def check_course_size(spec: CourseSpec, num_envs: int = 1, scan_n: int = 0) -> None:
    """ValueError naming the argument unless the planner's grid has at most :data:`MAX_GRID`
    cells a side (``arena``, ``inflate``, ``cell``), ``lookahead`` reaches no farther than that
    grid, a height scan has at most :data:`MAX_GRID` points a side (``height_scan``) and all of it
    for ``num_envs`` copies (:func:`course_bytes`) fits in half the machine's memory; checked
    before anything is allocated (as a rough terrain's grid is)."""
    side = grid_side(spec)
    if not side <= MAX_GRID:
        raise ValueError(f"cell, arena: a cell of {spec.cell:g} m over the arena +-{spec.arena:g} m (and a margin of "
                         f"inflate + 0.5 m) makes a planner grid of about {side:.3g} x {side:.3g} cells; at most "
                         f"{MAX_GRID} x {MAX_GRID}: use a larger cell or a smaller arena")
    n = int(math.ceil(side))
    if spec.lookahead > n:
        raise ValueError(f"lookahead: {spec.lookahead} cells reaches beyond the planner grid of {n} x {n} cells; "
                         f"at most {n}")
    if scan_n > MAX_GRID:
        raise ValueError(f"height_scan: n = {scan_n} makes a scan of {scan_n} x {scan_n} points; at most "
                         f"{MAX_GRID} x {MAX_GRID}")
    need, limit = course_bytes(spec, num_envs, scan_n), _memory_limit()
    if not need <= limit:
        raise ValueError(f"num_envs, cell, arena, n_goals, height_scan: {num_envs} copies' courses need about "
                         f"{need / 2**30:.3g} GiB of memory (planner grid {n} x {n} cells, {spec.n_goals} goals, "
                         f"scan {scan_n} x {scan_n}), above half this machine's memory ({limit / 2**30:.3g} GiB)")


def _grid(spec: CourseSpec):
    """Cell centres (x, y) 1-D of the planner's grid: the arena and a margin of ``inflate + 0.5`` m."""
    half = spec.arena + spec.inflate + 0.5
    n = int(math.ceil(2 * half / spec.cell)) + 1
    x = -half + spec.cell * np.arange(n)
    return x, x


def _square(X, Y, cx: float, cy: float, reach: float):
    """The slices (rows, columns) of the grid points (X, Y) (meshgrid, m) within ``reach`` m of
    (cx, cy) along each axis, None when there are none."""
    jj = np.nonzero(np.abs(Y[:, 0] - cy) <= reach)[0]
    ii = np.nonzero(np.abs(X[0] - cx) <= reach)[0]
    if not (jj.size and ii.size):
        return None
    return slice(jj[0], jj[-1] + 1), slice(ii[0], ii[-1] + 1)


def _blocked(spec: CourseSpec, boxes, X, Y) -> np.ndarray:
    """(ny, nx) bool: cells within ``inflate`` m of an obstacle (distance to its footprint)."""
    blocked = np.zeros(X.shape, bool)
    for b in boxes:
        c, s = math.cos(math.radians(b.yaw_deg)), math.sin(math.radians(b.yaw_deg))
        # the cells within reach: no farther than the footprint's half diagonal and the inflation
        # (a cell outside this square is farther, and stays as it is)
        sub = _square(X, Y, b.center[0], b.center[1], 0.5 * math.hypot(b.size[0], b.size[1]) + spec.inflate + spec.cell)
        if sub is None:
            continue
        dx, dy = X[sub] - b.center[0], Y[sub] - b.center[1]
        u, v = np.abs(c * dx + s * dy) - b.size[0] / 2, np.abs(-s * dx + c * dy) - b.size[1] / 2
        dist = np.hypot(np.maximum(u, 0.0), np.maximum(v, 0.0))
        blocked[sub] |= dist <= spec.inflate
    return blocked


@functools.lru_cache(maxsize=8)
def _full_graph(ny: int, nx: int, cell: float):
    """The 8-connected graph of a (ny, nx) grid of ``cell`` m with every cell free, as canonical
    CSR arrays (row of each edge, column indices sorted within each row, edge lengths m; read-only)."""
    idx = np.arange(ny * nx).reshape(ny, nx)
    rows, cols, w = [], [], []
    for dj, di in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = idx[max(0, -dj):ny - max(0, dj), max(0, -di):nx - max(0, di)].reshape(-1)
        b = idx[max(0, dj):max(0, dj) + ny - abs(dj), max(0, di):max(0, di) + nx - abs(di)].reshape(-1)
        rows += [a, b]
        cols += [b, a]
        w += [np.full(a.size, cell * math.hypot(dj, di))] * 2
    r, c, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
    order = np.lexsort((c, r))
    out = r[order], c[order].astype(np.int32), ww[order]
    for a in out:
        a.setflags(write=False)
    return out


def _graph(blocked: np.ndarray, cell: float):
    """The 8-connected grid graph of the free cells (edge lengths m): the full grid's edges
    (:func:`_full_graph`) between two free cells, in canonical CSR form (column indices sorted
    within each row)."""
    ny, nx = blocked.shape
    r, c, w = _full_graph(ny, nx, float(cell))
    free = ~blocked.reshape(-1)
    ok = free[r] & free[c]
    indptr = np.zeros(ny * nx + 1, np.int32)
    np.cumsum(np.bincount(r[ok], minlength=ny * nx), out=indptr[1:])
    return csr_matrix((w[ok], c[ok], indptr), shape=(ny * nx, ny * nx))


def _cell_of(p, x0: float, cell: float, n: int) -> tuple[int, int]:
    i = int(np.clip(round((p[0] - x0) / cell), 0, n - 1))
    j = int(np.clip(round((p[1] - x0) / cell), 0, n - 1))
    return j, i


def _rough(spec: CourseSpec, rng, X, Y):
    """Heights (ny, nx) m of the rough patches (0 outside them) and their centres."""
    h = np.zeros(X.shape)
    centres = []
    k = 2 * np.pi / spec.rough_wavelength
    for _ in range(spec.n_rough):
        cx, cy = rng.uniform(-spec.arena, spec.arena, 2)
        rad = rng.uniform(*spec.rough_radius)
        ang = rng.uniform(0.0, 2 * np.pi, 4)
        ph = rng.uniform(0.0, 2 * np.pi, 4)
        # the patch's square: outside it the fade is 0 and the heights stay as they are
        sub = _square(X, Y, cx, cy, rad)
        if sub is not None:
            Xs, Ys = X[sub], Y[sub]
            z = sum(np.cos(k * (np.cos(a) * Xs + np.sin(a) * Ys) + p) for a, p in zip(ang, ph))
            z = (z + 4.0) / 8.0                                     # in [0, 1]
            r = np.hypot(Xs - cx, Ys - cy)
            fade = np.clip((rad - r) / (0.25 * rad), 0.0, 1.0)     # a soft rim
            h[sub] = np.maximum(h[sub], spec.rough_amplitude * z * fade)
        centres.append((cx, cy, rad))
    return h, centres


def _place_goals(spec: CourseSpec, rng):
    """(n_goals, 2) goals, each ``U(goal_distance)`` from the one before inside the arena; None
    when one finds no place in 100 draws."""
    goals = np.zeros((spec.n_goals, 2))
    p = np.zeros(2)
    for g in range(spec.n_goals):
        for _ in range(100):
            th = rng.uniform(0.0, 2 * np.pi)
            q = p + rng.uniform(*spec.goal_distance) * np.array([math.cos(th), math.sin(th)])
            if np.all(np.abs(q) <= spec.arena - spec.goal_radius):
                break
        else:
            return None
        goals[g] = p = q
    return goals


def _place_walls(spec: CourseSpec, rng, keep):
    """The walls (boxes), each ``clearance`` m clear of the points ``keep`` (start and goals);
    None when one finds no place in 100 draws."""
    boxes = []
    for _ in range(spec.n_obstacles):
        for _ in range(100):
            c = rng.uniform(-spec.arena, spec.arena, 2)
            size = rng.uniform(*spec.obstacle_size, 2)
            yaw = rng.uniform(0.0, 180.0)
            if np.min(np.linalg.norm(keep - c, axis=1)) - 0.5 * float(np.hypot(*size)) >= spec.clearance:
                break
        else:
            return None
        boxes.append(Box(center=[c[0], c[1], spec.obstacle_height / 2],
                         size=[size[0], size[1], spec.obstacle_height], yaw_deg=yaw))
    return boxes


def draw_course(spec: CourseSpec, rng: np.random.Generator, surface: dict | None = None) -> Course:
    """A solvable course drawn from ``rng`` (see the module doc); ``surface``: the terrain's
    contact values (``friction``, ``stiffness``, ``damping``). ValueError naming the spec when
    :data:`MAX_TRIES` draws give no course whose goals are all reachable."""
    surface = surface or {}
    xs, ys = _grid(spec)
    X, Y = np.meshgrid(xs, ys)
    x0, n = float(xs[0]), xs.size
    for _ in range(MAX_TRIES):
        goals = _place_goals(spec, rng)
        if goals is None:
            continue
        keep = np.vstack([np.zeros((1, 2)), goals])
        boxes = _place_walls(spec, rng, keep)
        if boxes is None:
            continue
        rough, _ = _rough(spec, rng, X, Y)
        blocked = _blocked(spec, boxes, X, Y)
        if any(blocked[_cell_of(p, x0, spec.cell, n)] for p in keep):
            continue
        G = _graph(blocked, spec.cell)
        sources = [np.ravel_multi_index(_cell_of(goals[g], x0, spec.cell, n), (n, n)) for g in range(spec.n_goals)]
        field = dijkstra(G, indices=sources).reshape(spec.n_goals, n, n)
        if not all(np.isfinite(field[g][_cell_of(keep[g], x0, spec.cell, n)]) for g in range(spec.n_goals)):
            continue
        hf = Heightfield(heights=rough, cell=spec.cell, origin=[x0, x0]) if spec.n_rough else None
        terrain = Terrain(plane=None if hf is not None else Terrain().plane, boxes=tuple(boxes), heightfield=hf,
                          **surface)
        return Course(goals=goals, terrain=terrain, field=field, origin=np.array([x0, x0]), cell=spec.cell)
    raise ValueError(f"course: no solvable course in {MAX_TRIES} draws (goals {spec.n_goals} at "
                     f"{spec.goal_distance} m, {spec.n_obstacles} obstacles of {spec.obstacle_size} m grown by "
                     f"{spec.inflate} m, clearance {spec.clearance} m, arena +-{spec.arena} m): make the arena "
                     "larger or the obstacles fewer or smaller")


def guidance(course: Course, goal: int, p, lookahead: int = 3) -> tuple[np.ndarray, float]:
    """(unit direction (2,), path distance m) from the position ``p`` (x, y) m toward goal
    ``goal`` of ``course``: :func:`guidance_batch` for one position."""
    d, path = guidance_batch(course.field[goal][None], course.origin, course.cell, course.goals[goal][None],
                             np.asarray(p, float)[None], lookahead)
    return d[0], float(path[0])


def guidance_batch(field, origin, cell: float, goal, p, lookahead: int = 3, layer=None, copies=None) -> tuple:
    """Guidance of B positions ``p`` (B, 2) m toward their goals ``goal`` (B, 2) m along the path
    distances ``field`` (B, n, n) m of their courses (square grid ``origin`` (2,) m, ``cell`` m;
    or (C, L, n, n) with ``layer`` (B,) int the layer of each position and ``copies`` (B,) int its
    course, all C by default: indexed in place, no copy of the fields): the unit direction (B, 2)
    to the cell within ``lookahead`` cells with the shortest remaining path (straight at the goal
    within that reach, or where no cell in reach is nearer), and the path distance (B,) m from
    the cell under ``p`` (the straight distance where the grid has none). NumPy arrays, or torch
    tensors (``origin`` one too) on one device."""
    xp = namespace(p)
    if xp is NUMPY:
        field, p, goal = np.asarray(field, float), np.asarray(p, float), np.asarray(goal, float)
    B, n = p.shape[0], field.shape[-1]
    rows = xp.arange(B, p)
    ij = xp.to_index(xp.clip(xp.rint((p - origin) / cell), 0, n - 1))          # (B, 2) the cell under p
    i, j = ij[:, 0], ij[:, 1]
    size = 2 * lookahead + 1
    reach = xp.clip(ij[:, :, None] + (xp.arange(size, p) - lookahead), 0, n - 1)   # (B, 2, size)
    ii, jj = reach[:, 0], reach[:, 1]
    if layer is None:
        win = field[rows[:, None, None], jj[:, :, None], ii[:, None, :]].reshape(B, -1)
        here = field[rows, j, i]
    else:
        c = rows if copies is None else copies
        win = field[c[:, None, None], layer[:, None, None], jj[:, :, None], ii[:, None, :]].reshape(B, -1)
        here = field[c, layer, j, i]
    k = xp.argmin(win, 1)
    best = win[rows, k]
    dist = xp.hypot(goal[:, 0] - p[:, 0], goal[:, 1] - p[:, 1])
    cell_xy = origin + cell * xp.to_float(xp.stack([ii[rows, k % size], jj[rows, k // size]], -1), p)
    step = (best < here) & (dist > lookahead * cell)
    v = xp.where(step[:, None], cell_xy, goal) - p
    nv = xp.hypot(v[:, 0], v[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        d = xp.where(nv[:, None] > 0, v / nv[:, None], xp.const([1.0, 0.0], p))
    path = xp.where(xp.isfinite(here), here, xp.where(xp.isfinite(best), best + cell * lookahead, dist))
    return d, path


def guidance_frame(v, direction, out=None):
    """``v`` (B, m, 3) world vectors in the guidance frame of each copy: x along its unit
    ``direction`` (B, 2), y to its left, z up (a rotation about the vertical; the rolling robot is
    symmetric under it, so one policy serves every direction). ``out``: an array (B, m, 3) that
    takes the result (``v`` itself: rotated in place), else a new one."""
    c, s = direction[:, 0, None], direction[:, 1, None]
    x, y = c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1]
    if out is None:
        return namespace(v).stack([x, y, v[..., 2]], -1)
    if out is not v:
        out[..., 2] = v[..., 2]
    out[..., 0], out[..., 1] = x, y
    return out


def current_goal(goals, goal_index, rows):
    """The current goal of copies ``rows`` (r,) int: ``(layer (r,) int, position (r, 2) m)``, the
    layer ``goal_index`` (r,) clipped to the last goal of ``goals`` (B, n_goals, 2) m (after
    the last goal: the last one's)."""
    g = namespace(goals).minimum(goal_index, goals.shape[1] - 1)
    return g, goals[rows, g]


def track_goals(goals, goal_index, xy, goal_radius: float):
    """Goal bookkeeping after a step: ``goals`` (B, n_goals, 2) m, ``goal_index`` (B,) int the
    current goal of each copy (n_goals: all reached), ``xy`` (B, 2) m the centres of mass. A copy
    whose centre is within ``goal_radius`` m of its current goal has reached it. Returns
    ``(goal_index after, reached (B,) bool, success (B,) bool (all reached), distance (B,) m to
    the goal now current (0 after the last))``."""
    xp = namespace(xy)
    n_goals = goals.shape[1]
    rows = xp.arange(goals.shape[0], xy)

    def current(gi):
        g = current_goal(goals, gi, rows)[1]
        return xp.hypot(g[:, 0] - xy[:, 0], g[:, 1] - xy[:, 1])
    reached = (goal_index < n_goals) & (current(goal_index) <= goal_radius)
    goal_index = goal_index + reached
    open_ = goal_index < n_goals
    return goal_index, reached, ~open_, xp.where(open_, current(goal_index), 0.0)


def navigate_observation(obs, blocks: dict, direction, path, goal_index, n_goals: int, scan=None):
    """The navigation observation from the rolling task's state observation ``obs`` (B, size)
    (its ``blocks``: name -> slice): node positions and velocities in the guidance frame of the
    unit ``direction`` (B, 2) (:func:`guidance_frame`), the goal direction there (1, 0), then the
    path distance to the current goal (B,) m (0 after the last), the goals left and the height
    scan (B, n^2) m when given, in ``obs``'s dtype."""
    xp = namespace(obs)
    B = obs.shape[0]
    for block in ("node_position_rel_com", "node_velocity"):
        v = obs[:, blocks[block]].reshape(B, -1, 3)     # a view of obs
        guidance_frame(v, direction, out=v)
    obs[:, blocks["goal_direction"]] = xp.const([1.0, 0.0], obs)
    extra = [xp.where(goal_index >= n_goals, 0.0, path)[:, None], (n_goals - goal_index)[:, None]]
    if scan is not None:
        extra.append(scan)
    return xp.concat([obs] + [xp.to_float(e, obs) for e in extra], axis=1)


def height_scan(height_at, com, offsets):
    """(B, n^2) terrain heights (m) at the scan's points ``com[:, :2] + offsets`` ((n^2, 2) m)
    around each copy's centre of mass ``com`` (B, 3) m, relative to the height under the centre,
    clipped to +-1 m; ``height_at(x, y)`` ((B, m) m each) gives each copy's terrain heights."""
    xp = namespace(com)
    x, y = com[:, 0, None] + offsets[:, 0], com[:, 1, None] + offsets[:, 1]
    return xp.clip(height_at(x, y) - height_at(com[:, 0, None], com[:, 1, None]), -1.0, 1.0)
