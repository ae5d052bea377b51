"""Start and goal placement with a guaranteed collision-free path for the robot's disc.

Per env: the world's clearance on a grid of ``resolution`` m, free cells more than
``robot_radius + resolution / sqrt(2)`` m from every obstacle and the edge, a start in a large
free component, a geodesic wavefront from it, and a goal whose path length lies in a
difficulty-dependent band. Why the path is safe, and how tight its length is: docs/worlds.md,
"Starts, goals and the path guarantee"."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor

from ..sim import World
from .layout import lerp, uniform
from .raster import clearance_grid
from .guide import GUIDE_CELLS, coarse_goal_field
from .wavefront import ORTHO, UNREACHED, geodesic_distance

GOAL_BAND_EASY = (0.1, 0.4)  # goal path length as a fraction of the farthest reachable one, at difficulty 0
GOAL_BAND_HARD = (0.6, 1.0)  # ... and at difficulty 1 (linear in between)
ANYWHERE_MIN_GOAL = 0.5  # m of path, the least goal distance of an "anywhere" goal (the maps' curriculum.min_radius)
START_REDRAWS = 2  # redraws of a start that lies in a small free component
_CELLS_PER_CHUNK = 1 << 18  # envs are placed in chunks of at most this many grid cells (small chunks stay in cache)


def goal_band(difficulty: Tensor) -> tuple[Tensor, Tensor]:
    """The ``(low, high)`` fractions ``(B,)`` of the farthest reachable path length between which
    a goal's path length is drawn, at ``difficulty`` ``(B,)``."""
    return lerp(GOAL_BAND_EASY[0], GOAL_BAND_HARD[0], difficulty), lerp(GOAL_BAND_EASY[1], GOAL_BAND_HARD[1], difficulty)


def _clearance(world: World, bounds: Tensor, robot_radius: float, resolution: float) -> tuple[Tensor, Tensor, tuple[float, float]]:
    """Each cell's clearance ``(B, H, W)`` m to the obstacles and the bounds' edge, exact up to the
    safe clearance of :func:`free_cells` and at least it beyond, the centres ``(H, W, 2)`` m of
    the batch's shared grid, which covers every env's bounds ``(B, 4)``, and the lower-left corner
    ``(x, y)`` m of its cell ``(0, 0)``."""
    lo = bounds[:, :2].amin(0).tolist()
    hi = bounds[:, 2:].amax(0).tolist()
    shape = (math.ceil((hi[1] - lo[1]) / resolution), math.ceil((hi[0] - lo[0]) / resolution))
    clear = clearance_grid(world, (lo[0], lo[1]), shape, resolution, reach=_safe(robot_radius, resolution))
    like = bounds
    xs = lo[0] + (torch.arange(shape[1], dtype=like.dtype, device=like.device) + 0.5) * resolution
    ys = lo[1] + (torch.arange(shape[0], dtype=like.dtype, device=like.device) + 0.5) * resolution
    centres = torch.stack(torch.meshgrid(ys, xs, indexing="ij")[::-1], -1)  # (H, W, 2) [x, y]
    b = bounds[:, None, None, :]
    edge = torch.minimum(
        torch.minimum(centres[..., 0] - b[..., 0], b[..., 2] - centres[..., 0]),
        torch.minimum(centres[..., 1] - b[..., 1], b[..., 3] - centres[..., 1]),
    )
    return torch.minimum(clear, edge), centres, (lo[0], lo[1])


def _safe(robot_radius: float, resolution: float) -> float:
    """The clearance (m) of a cell centre from which every point of the cell is clear of the disc."""
    return robot_radius + resolution / math.sqrt(2.0) + 1e-4  # 1e-4 m: float32 round-off


def free_cells(world: World, bounds: Tensor, robot_radius: float, resolution: float) -> tuple[Tensor, Tensor]:
    """Cells ``(B, H, W)`` whose centre is safe for the robot (see the module notes), and the
    centres ``(H, W, 2)`` m of the batch's shared grid, which covers every env's bounds ``(B, 4)``."""
    clear, centres, _ = _clearance(world, bounds, robot_radius, resolution)
    return clear > _safe(robot_radius, resolution), centres


def _random_cell(candidates: Tensor, generator: torch.Generator) -> Tensor:
    """A uniformly drawn True cell (flat index) of each row of ``candidates`` ``(B, N)``; 0 if none."""
    key = torch.rand(candidates.shape, generator=generator, device=candidates.device)
    return torch.where(candidates, key, -1.0).argmax(1)


def _start_and_distances(free: Tensor, generator: torch.Generator, allowed: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """A start cell ``(B,)`` in a large free component and the distances from it ``(B, H * W)``; how the
    start is redrawn out of a pocket (``START_REDRAWS`` times): docs/worlds.md, "Starts, goals and the path guarantee".
    ``allowed`` ``(B, H * W)``: the free cells the start may take (default every free one; at least one per env)."""
    b = free.shape[0]
    flat_free = free.reshape(b, -1)
    allowed = flat_free if allowed is None else allowed
    start = _random_cell(allowed, generator)
    dist = geodesic_distance(free, start).reshape(b, -1)
    for _ in range(START_REDRAWS):
        reached = (dist < UNREACHED).sum(1)
        idx = (2 * reached < flat_free.sum(1)).nonzero()[:, 0]
        if idx.numel() == 0:
            break
        # Redrawn only where an allowed cell lies outside the start's component (else _random_cell's 0 would be taken).
        elsewhere = allowed[idx] & (dist[idx] == UNREACHED)
        other = _random_cell(elsewhere, generator)
        d_other = geodesic_distance(free[idx], other).reshape(idx.numel(), -1)
        better = ((d_other < UNREACHED).sum(1) > reached[idx]) & elsewhere.any(1)
        start[idx[better]], dist[idx[better]] = other[better], d_other[better]
    return start, dist


def _goal_cell(dist: Tensor, difficulty: Tensor, min_goal_cells: Tensor, anywhere: Tensor, generator: torch.Generator,
               allowed: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """A goal cell (flat index, ``(B,)``) and its path length in cells, drawn from the distances
    ``dist`` ``(B, H * W)`` of a start; where ``anywhere`` ``(B,)`` is True the band is every reachable
    cell. ``allowed`` ``(B, H * W)``: the cells the goal may take (default all); where none of them
    is reachable, the fallback ignores it."""
    reached = dist < UNREACHED
    cells = dist.to(torch.float64) / ORTHO
    far = torch.where(reached, cells, 0.0).amax(1, keepdim=True)
    lo, hi = goal_band(difficulty.to(torch.float64))
    lo, hi = torch.where(anywhere, 0.0, lo), torch.where(anywhere, 1.0, hi)
    in_band = reached & (cells >= lo[:, None] * far) & (cells <= hi[:, None] * far) & (cells >= min_goal_cells[:, None])
    # Fallback when the band is empty (a component too small for min_goal): the farthest reachable cell
    # (the farthest allowed one where one is reachable).
    score = torch.where(reached, cells, -1.0)
    if allowed is not None:
        in_band = in_band & allowed
        score = score + torch.where(reached & allowed, 2.0 * UNREACHED, 0.0)
    goal = torch.where(in_band.any(1), _random_cell(in_band, generator), score.argmax(1))
    return goal, cells.gather(1, goal[:, None])[:, 0]


def _free_grid(world: World, bounds: Tensor, robot_radius: float, resolution: float) -> tuple[Tensor, Tensor, tuple[float, float], Tensor]:
    """:func:`_clearance` and the free cells ``(B, H, W)`` (see the module notes); ValueError where an env has none."""
    clear, centres, origin = _clearance(world, bounds, robot_radius, resolution)
    free = clear > _safe(robot_radius, resolution)
    empty = ~free.flatten(1).any(1)
    if empty.any():
        raise ValueError(f"no free space for a robot of radius {robot_radius} m at resolution {resolution} m in {int(empty.sum())} env(s)")
    return clear, centres, origin, free


def _min_goal_cells(anywhere: Tensor, min_goal_distance: float, resolution: float) -> Tensor:
    """The least goal path length ``(B,)`` in cells: ``min_goal_distance`` m, at most ``ANYWHERE_MIN_GOAL`` where ``anywhere``."""
    return torch.where(anywhere, min(ANYWHERE_MIN_GOAL, min_goal_distance), min_goal_distance).to(torch.float64) / resolution


def _place(
    world: World, bounds: Tensor, difficulty: Tensor, anywhere: Tensor, generator: torch.Generator, robot_radius: float, resolution: float,
    min_goal_distance: float, guide_cells: int, guide_margin: float,
) -> tuple[Tensor, ...]:
    """:func:`place_episodes` for one chunk of envs."""
    clear, centres, origin, free = _free_grid(world, bounds, robot_radius, resolution)
    min_goal = _min_goal_cells(anywhere, min_goal_distance, resolution)
    start_cell, dist = _start_and_distances(free, generator)
    goal_cell, cells = _goal_cell(dist, difficulty, min_goal, anywhere, generator)
    n, like, flat = bounds.shape[0], bounds, centres.reshape(-1, 2)
    jitter = uniform(-0.5 * resolution, 0.5 * resolution, (2, n, 2), generator, like)
    heading = uniform(-math.pi, math.pi, (n, 1), generator, like)
    length = cells.to(like.dtype) * resolution + jitter.norm(dim=-1).sum(0)
    out = (torch.cat((flat[start_cell] + jitter[0], heading), -1), flat[goal_cell] + jitter[1], length)
    if not guide_cells:
        return out
    return out + coarse_goal_field(_goal_wavefront(clear, goal_cell, robot_radius + guide_margin), origin, resolution, bounds, guide_cells)


def _goal_wavefront(clear: Tensor, goal_cell: Tensor, need: float) -> Tensor:
    """The wavefront from ``goal_cell`` ``(B,)`` over the cells whose clearance ``clear`` ``(B, H, W)``
    is above ``need`` m, and the goal's own cell whatever its clearance."""
    passable = (clear > need).reshape(clear.shape[0], -1).scatter(1, goal_cell[:, None], True).reshape(clear.shape)
    return geodesic_distance(passable, goal_cell)


def goal_distance_grid(
    world: World, bounds: Tensor, goal: Tensor, robot_radius: float = 0.2, resolution: float = 0.1, cells: int = GUIDE_CELLS,
    margin: float = 0.0,
) -> tuple[Tensor, Tensor]:
    """Each env's grid of geodesic distances to its ``goal`` ``(B, 2)`` m and the grid's frame
    (:func:`~.guide.coarse_goal_field`; read a position's distance with :func:`~.guide.goal_distance`),
    from a wavefront run from the goal's cell over the cells whose centre a disc of ``robot_radius``
    m may stand on (clearance above the radius), or with ``margin`` m more to spare (paths keep
    that far from obstacles, and gaps narrower than ``2 * (robot_radius + margin)`` close).
    Raises ValueError where a goal's cell is not one where the disc fits."""
    clear, _, origin = _clearance(world, bounds, robot_radius, resolution)
    free = clear > robot_radius
    h, w = free.shape[1:]
    col = ((goal[:, 0] - origin[0]) / resolution).floor().long()
    row = ((goal[:, 1] - origin[1]) / resolution).floor().long()
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    cell = row.clamp(0, h - 1) * w + col.clamp(0, w - 1)
    safe = inside & free.reshape(free.shape[0], -1).gather(1, cell[:, None])[:, 0]
    if not safe.all():
        raise ValueError(f"goal_distance_grid: the goal of env(s) {(~safe).nonzero()[:, 0].tolist()} is not on a cell where a "
                         f"{robot_radius} m disc fits, at {resolution} m resolution")
    return coarse_goal_field(_goal_wavefront(clear, cell, robot_radius + margin), origin, resolution, bounds, cells)


def place_episodes(
    world: World,
    bounds: Tensor,
    difficulty: Tensor,
    generator: torch.Generator,
    robot_radius: float = 0.2,
    resolution: float = 0.1,
    min_goal_distance: float = 1.0,
    anywhere: Tensor | None = None,
    guide_cells: int = 0,
    guide_margin: float = 0.0,
) -> tuple[Tensor, ...]:
    """Start poses ``(B, 3)``, goals ``(B, 2)`` and path lengths ``(B,)`` (m) in ``world``; with
    ``guide_cells > 0`` also each env's grid of geodesic distances to its goal and the grid's frame
    (:func:`~.guide.coarse_goal_field`, from a second wavefront, run from the goal; ``guide_margin``
    as ``margin`` of :func:`goal_distance_grid`).

    ``bounds`` ``(B, 4)`` ``[xmin, ymin, xmax, ymax]`` m per env; ``difficulty`` ``(B,)`` in
    [0, 1] sets the goal band (:func:`goal_band`); goals are at least
    ``min_goal_distance`` m of path from the start when the start's component allows
    (else the goal is the farthest reachable cell). Where ``anywhere`` ``(B,)`` (bool) is
    True the goal is drawn among every reachable cell at least ``min(0.5, min_goal_distance)``
    m of path away, whatever the difficulty (as goals are on maps in evaluation). The start lies in a free
    component holding at least half of the free space where one does (see
    :func:`_start_and_distances`), with a uniform heading. Raises ValueError if
    some env has no free cell for a disc of ``robot_radius`` m.
    Envs are processed in chunks of similar world size, of at most ``2**18`` grid cells
    (faster in cache than all at once).
    """
    if anywhere is None:
        anywhere = torch.zeros(bounds.shape[0], dtype=torch.bool, device=bounds.device)
    return _in_chunks(bounds, resolution, lambda idx: _place(world[idx], bounds[idx], difficulty[idx], anywhere[idx], generator, robot_radius,
                                                             resolution, min_goal_distance, guide_cells, guide_margin))


def _in_chunks(bounds: Tensor, resolution: float, place: Callable[[Tensor], tuple[Tensor, ...]]) -> tuple[Tensor, ...]:
    """``place(idx)``'s outputs for chunks ``idx`` of envs of similar world size (``bounds`` ``(B, 4)``), so
    a chunk's grid fits its envs closely, of at most ``_CELLS_PER_CHUNK`` cells; joined in env order."""
    cells = ((bounds[:, 2:] - bounds[:, :2]) / resolution + 1).prod(1)
    order = torch.argsort(cells, stable=True)
    sizes = cells[order].tolist()
    parts, i = [], 0
    while i < len(sizes):
        j = i + 1
        while j < len(sizes) and (j + 1 - i) * sizes[j] <= _CELLS_PER_CHUNK:
            j += 1
        parts.append(place(order[i:j]))
        i = j
    inverse = torch.argsort(order)
    return tuple(torch.cat(t)[inverse] for t in zip(*parts))


@dataclass(frozen=True)
class RobotPlacement:
    """Several robots per world (:func:`place_robots`, ``make_worlds(robots=...)``)."""

    n: int  # robots per world
    start_apart: float = 0.0  # m, least distance between two robots' starts (centre to centre)
    goal_apart: float = 0.0  # m, least distance between two goals
    sides: bool = False  # True: even robots start in the left third of the world and go to the right third, odd ones the other way

    def __post_init__(self) -> None:
        if not (isinstance(self.n, int) and self.n >= 1) or self.start_apart < 0 or self.goal_apart < 0:
            raise ValueError(f"RobotPlacement needs n >= 1 and distances >= 0, got {self}")


def _gap(points: Tensor, placed: list[Tensor]) -> Tensor:
    """Distance ``(B, C)`` m of each of ``points`` ``(B, C, 2)`` to the nearest of ``placed`` (``(B, 2)`` each; inf if none)."""
    if not placed:
        return points.new_full(points.shape[:2], math.inf)
    return (points[:, :, None] - torch.stack(placed, 1)[:, None]).norm(dim=-1).amin(-1)


def _place_robots(
    world: World, bounds: Tensor, difficulty: Tensor, anywhere: Tensor, generator: torch.Generator, robot_radius: float, resolution: float,
    min_goal_distance: float, robots: RobotPlacement,
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`place_robots` for one chunk of envs: robot after robot, each placed as :func:`_place` places
    its one, among the cells that keep the distances from the robots placed before it."""
    _, centres, _, free = _free_grid(world, bounds, robot_radius, resolution)
    b, like, flat = bounds.shape[0], bounds, centres.reshape(-1, 2)
    flat_free = free.reshape(b, -1)
    everywhere = torch.ones_like(flat_free)
    regions = (everywhere, everywhere)
    if robots.sides:  # the goal lies anywhere reachable in the far third: no difficulty band
        third, x = (bounds[:, 2:3] - bounds[:, 0:1]) / 3, flat[None, :, 0]
        regions = (x <= bounds[:, 0:1] + third, x >= bounds[:, 2:3] - third)
        anywhere = torch.ones_like(anywhere)
    min_goal = _min_goal_cells(anywhere, min_goal_distance, resolution)
    rows = torch.arange(b, device=bounds.device)
    starts, goals, headings, lengths = [], [], [], []
    for i in range(robots.n):
        home, away = regions[i % 2], regions[(i + 1) % 2]
        # The jitter first, so that the distances are tested on the very points each cell would give.
        jitter = uniform(-0.5 * resolution, 0.5 * resolution, (2, b, 2), generator, like)
        at_start, at_goal = flat + jitter[0][:, None], flat + jitter[1][:, None]  # (b, C, 2)
        # Start cells: free, in the home region where it has free cells, apart from the starts before;
        # where none is, the one of them farthest from those (the robots then start closer).
        pool = flat_free & home
        pool = torch.where(pool.any(1, keepdim=True), pool, flat_free)
        gap = _gap(at_start, starts)
        allowed = pool & (gap >= robots.start_apart)
        farthest = torch.zeros_like(pool).scatter(1, torch.where(pool, gap, -1.0).argmax(1, keepdim=True), True)
        start_cell, dist = _start_and_distances(free, generator, torch.where(allowed.any(1, keepdim=True), allowed, farthest))
        goal_cell, cells = _goal_cell(dist, difficulty, min_goal, anywhere, generator, away & (_gap(at_goal, goals) >= robots.goal_apart))
        headings.append(uniform(-math.pi, math.pi, (b,), generator, like))
        starts.append(at_start[rows, start_cell])
        goals.append(at_goal[rows, goal_cell])
        lengths.append(cells.to(like.dtype) * resolution + jitter.norm(dim=-1).sum(0))
    start = torch.cat((torch.stack(starts, 1), torch.stack(headings, 1)[..., None]), -1)
    return start, torch.stack(goals, 1), torch.stack(lengths, 1)


def place_robots(
    world: World,
    bounds: Tensor,
    difficulty: Tensor,
    generator: torch.Generator,
    robots: RobotPlacement,
    robot_radius: float = 0.2,
    resolution: float = 0.1,
    min_goal_distance: float = 1.0,
    anywhere: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Start poses ``(B, N, 3)``, goals ``(B, N, 2)`` and path lengths ``(B, N)`` (m) of ``robots.n`` robots
    per world, each placed as :func:`place_episodes` places its one robot (free cells, a start in a large
    free component, a goal in the difficulty's band reachable from that start: the same path guarantee
    for each robot's disc), robot after robot. Each start also keeps ``robots.start_apart`` m from the
    starts before it and each goal ``robots.goal_apart`` m from the goals before it, measured on the
    jittered points. Fallbacks: where no free cell is far enough from the other starts, the farthest
    one; where no reachable goal cell is far enough from the other goals, the band (then the farthest
    reachable cell) ignores them. With ``robots.sides`` even robots start in the left third of the
    world (where it has a free cell) and their goal is any reachable cell at least ``min(0.5,
    min_goal_distance)`` m of path away in the right third, odd robots the other way. ValueError as
    :func:`place_episodes`."""
    if anywhere is None:
        anywhere = torch.zeros(bounds.shape[0], dtype=torch.bool, device=bounds.device)
    return _in_chunks(bounds, resolution, lambda idx: _place_robots(world[idx], bounds[idx], difficulty[idx], anywhere[idx], generator,
                                                                    robot_radius, resolution, min_goal_distance, robots))
