"""A map's fixed obstacles held once for a whole batch, with grid indexes of what each place can see.

A big static map (a building from SLAM: thousands of boxes after the occupancy conversion) is the
same in every env of a batch. Copying it into every env's :class:`~torchnav.sim.state.World` costs
memory in proportion to the number of envs, and testing every lidar ray against every obstacle costs
time in proportion to the map. A :class:`StaticMap` holds the obstacles once, with uniform grids of
cells over the map in which each cell lists obstacles that matter to a robot standing in it:

* reach lists: every obstacle within ``reach`` of some point of the cell, and every one that can be
  the nearest to some point of it. Each step gathers each robot's list into its per-env world
  (:func:`with_static`), so the clearance, the collision test and the sensors are the brute-force
  code on fewer slots, and read the whole map as far as ``reach`` (:func:`static_reach`);
* ray lists: each cell's nearest few obstacles, and a step that no obstacle left out is nearer than
  to any point of the cell. A ray scan marches the rays that hit nothing within ``reach`` from cell
  to cell (:func:`static_ray_hits`), so the lidar needs only a short ``reach`` and a ray costs a
  few cells whatever the map's size;
* near lists: every obstacle that can be the nearest to some point of the cell, for clearance queries
  of many points (:func:`static_clearance`: the reset samplers);
* a clearance grid: the exact clearance at the centres of fine cells, which bounds any point's. The
  reset samplers mostly ask whether a candidate is clear by some margin, and the grid answers that
  for the candidates not near that margin without measuring them (:func:`static_clearance`'s ``floor``).

All follow from the obstacles' signed distances being 1-Lipschitz: for a point ``p`` of a cell of
centre ``c`` and half diagonal ``h``, ``|sd(p, o) - sd(c, o)| <= h``. The readings are the whole
map's, up to nothing (the nearest hit is a minimum over the same per-obstacle values), gradients
flow to the pose as before, and the per-env memory is that of one reach list. The guarantee holds
for robots inside the grid (the map's bounds); a robot outside it uses its nearest cell's lists,
while its rays march from where they enter the grid.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass

import torch
from torch import Tensor

from .geometry import _box_dist, _circle_dist, segment_distance
from .raycast import _box_rows, _hit_box_rows, hit_circle, hit_segment
from .params import SimParams
from .state import World

# Most (cells, obstacles) distance elements computed at once while building the index.
_BUILD_CHUNK = 1 << 22
_KINDS = (("segments", "segment_mask", 4), ("circles", "circle_mask", 3), ("boxes", "box_mask", 5))


def _cell_index(x: Tensor, y: Tensor, origin: tuple[float, float], cell: float, nx: int, ny: int) -> Tensor:
    """Row-major index (int64, the shape of ``x`` and ``y``) of the grid cell holding each point ``(x, y)`` m
    (cells of side ``cell`` from ``origin``, ``nx`` by ``ny``); the nearest cell for points outside the grid."""
    i = ((x - origin[0]) / cell).floor().clamp(0, nx - 1).long()
    j = ((y - origin[1]) / cell).floor().clamp(0, ny - 1).long()
    return j * nx + i


@dataclass(frozen=True, eq=False)
class CellLists:
    """A uniform grid of square cells, each listing some of a :class:`StaticMap`'s obstacles.

    ``ids[kind]`` ``(ny * nx, M)`` int64 lists each cell's obstacles of that kind (row ``j * nx + i``
    is the cell ``i`` along x, ``j`` along y), padded with the index of the obstacle table's zero column."""

    ids: dict[str, Tensor]
    origin: tuple[float, float]  # m, the lower-left corner of cell (0, 0)
    cell: float  # m, the side of a cell
    nx: int
    ny: int

    @property
    def slots(self) -> dict[str, int]:
        """The longest list of each kind: the slots a world gathered from these lists holds."""
        return {k: v.shape[1] for k, v in self.ids.items()}

    def cells_of(self, xy: Tensor) -> Tensor:
        """Index ``(...)`` int64 of the cell holding each point ``xy`` ``(..., 2)`` m (the nearest cell
        for points outside the grid)."""
        return _cell_index(xy[..., 0], xy[..., 1], self.origin, self.cell, self.nx, self.ny)

    def nbytes(self) -> int:
        return sum(t.numel() * t.element_size() for t in self.ids.values())


@dataclass(frozen=True, eq=False)
class ClearanceGrid:
    """The exact clearance ``values`` ``(ny, nx)`` m at the centres of square cells of side ``cell`` from
    ``origin`` (the lower-left corner of cell (0, 0)). A point in a cell is within the cell's half
    diagonal of its centre, and clearance is 1-Lipschitz, so the point's clearance is within
    ``margin`` (the half diagonal, with rounding) of its cell's value."""

    values: Tensor
    origin: tuple[float, float]
    cell: float
    margin: float

    def bounds(self, xy: Tensor) -> tuple[Tensor, Tensor]:
        """Lower and upper bounds ``(N,)`` m of the clearance at the points ``xy`` ``(N, 2)``; ``-inf`` and
        ``inf`` outside the grid."""
        ny, nx = self.values.shape
        (x0, y0), side = self.origin, self.cell
        inside = (xy[:, 0] >= x0) & (xy[:, 0] < x0 + nx * side) & (xy[:, 1] >= y0) & (xy[:, 1] < y0 + ny * side)
        value = self.values.reshape(-1).index_select(0, _cell_index(xy[:, 0], xy[:, 1], self.origin, side, nx, ny))
        return torch.where(inside, value - self.margin, -math.inf), torch.where(inside, value + self.margin, math.inf)


@dataclass(frozen=True, eq=False)
class StaticMap:
    """Fixed obstacles shared by every env of a batch, and the grid indexes of :func:`build_static_map`.

    Obstacle tables are stored component-major with one extra zero column that empty list entries
    point at: ``segments`` ``(4, S + 1)``, ``circles`` ``(3, C + 1)``, ``boxes`` ``(5, K + 1)`` (the
    layouts of :class:`~torchnav.sim.state.World`, m and rad). Three sets of cell lists index them:

    * ``reach_lists``: every obstacle within ``reach`` of some point of the cell, and every one that
      can be the nearest to some point of it (for the exact sector scan and the camera);
    * ``near_lists``: every obstacle that can be the nearest to some point of the cell (clearance,
      collision and the reset samplers' free-space tests);
    * ``ray_lists`` and ``ray_step`` ``(cells,)`` m, on the same grid as ``near_lists``: a few of the
      obstacles nearest to the cell, such that every obstacle left out is farther than ``ray_step``
      from every point of the cell (:func:`static_ray_hits` marches rays with them).

    ``clearance_grid`` (None when built without) bounds the clearance of any point in the grid.
    """

    segments: Tensor
    circles: Tensor
    boxes: Tensor
    reach_lists: CellLists | None  # None when built with reach 0
    near_lists: CellLists
    ray_lists: CellLists | None  # None when built with rays=False
    ray_step: Tensor | None
    ray_rows: dict[str, Tensor] | None  # per kind (cells, w, M): each cell's listed obstacles as the hit functions take them
    bounds: tuple[float, float, float, float]  # m, the near and ray grids': the map's bounds and every obstacle
    reach: float  # m, every obstacle this close to a cell is in its reach list
    clearance_grid: ClearanceGrid | None = None

    @property
    def n_obstacles(self) -> dict[str, int]:
        """Obstacles of each kind held (without the padding column)."""
        return {k: getattr(self, k).shape[1] - 1 for k, _, _ in _KINDS}

    @property
    def slots(self) -> dict[str, int]:
        """Per-env slots of each kind that :func:`local_world` gathers: the longest reach list."""
        return self._lists("reach").slots

    @property
    def lists(self) -> dict[str, CellLists]:
        """The cell lists this map was built with, by name (``"reach"``, ``"near"``, ``"ray"``)."""
        return {k: v for k, v in (("reach", self.reach_lists), ("near", self.near_lists), ("ray", self.ray_lists)) if v is not None}

    def nbytes(self) -> int:
        """Bytes held by the obstacle tables and the indexes (the same for any number of envs)."""
        lists = sum(c.nbytes() for c in (self.reach_lists, self.near_lists, self.ray_lists) if c is not None)
        tables = (self.segments, self.circles, self.boxes) + ((self.ray_step, *self.ray_rows.values()) if self.ray_step is not None else ())
        tables += (self.clearance_grid.values,) if self.clearance_grid is not None else ()
        return lists + sum(t.numel() * t.element_size() for t in tables)

    def _lists(self, which: str) -> CellLists:
        """The ``"reach"``, ``"near"`` or ``"ray"`` lists; a ValueError names the build option that leaves them out."""
        lists = {"reach": self.reach_lists, "near": self.near_lists, "ray": self.ray_lists}[which]
        if lists is None:
            raise ValueError("this StaticMap has no reach lists (built with reach=0: for clearance and ray scans only)" if which == "reach"
                             else "this StaticMap has no ray lists (built with rays=False)")
        return lists


MARCH_FROM = 1.5  # m from the sensor: a ray scan reads a static map's reach lists this far, and marches beyond


def static_reach(params: SimParams, march: bool = False) -> float:
    """The distance (m) from a robot's centre that its sensors can see: the lidar's range plus its
    mount offset, or the camera's if it sees farther (its range is a depth along the optical axis, so
    its edge columns see ``1 / cos(fov / 2)`` times as far). A :class:`StaticMap` built with at least
    this ``reach`` gives these params' lidar, camera and clearance exactly. ``march``: the reach a ray
    scan without a camera needs when it marches past ``MARCH_FROM`` m (``lidar.lidar_scan``)."""
    mount = math.hypot(*params.lidar.offset[:2])
    if march and params.lidar.scan == "rays" and params.camera is None:
        return min(params.lidar.max_range, MARCH_FROM) + mount
    reach = params.lidar.max_range + mount
    if params.camera is not None:
        cam = params.camera
        reach = max(reach, cam.max_range / math.cos(cam.fov / 2) + math.hypot(*cam.offset[:2]))
    return reach


def _distances(kind: str, px: Tensor, py: Tensor, obs: Tensor) -> Tensor:
    """Signed distance from points ``px, py`` ``(P, 1)`` to obstacles ``obs`` ``(P or 1, N, k)`` of one
    kind, ``(P, N)``: the simulator's distances (``geometry.py``), written for a build with no gradient."""
    if kind == "segments":
        return segment_distance(px, py, obs)
    if kind == "circles":
        return torch.hypot(px - obs[..., 0], py - obs[..., 1]) - obs[..., 2]
    cx, cy, hx, hy, yaw = obs.unbind(-1)
    c, s = torch.cos(yaw), torch.sin(yaw)
    wx, wy = px - cx, py - cy
    dx, dy = (wx * c + wy * s).abs() - hx, (wy * c - wx * s).abs() - hy  # in the box's frame
    return torch.hypot(dx.clamp(min=0.0), dy.clamp(min=0.0)) + torch.maximum(dx, dy).clamp(max=0.0)


def _select(centres: Tensor, h: float, reach: float, tables: dict[str, Tensor], cand: dict[str, Tensor] | None = None) -> dict[str, Tensor]:
    """Per kind, the obstacles ``(P, M)`` (indices into ``tables[kind]``, padded with its length) that lie
    within ``max(reach + h, nearest + 2 h)`` of each of the points ``centres`` ``(P, 2)``, ``nearest``
    being the point's nearest obstacle of any kind: every obstacle that matters to the square of half
    diagonal ``h`` around the point. ``cand``: per kind ``(P, Mc)`` candidates to choose from (padded
    likewise), which must hold every obstacle that can be chosen; None: all."""
    width = max(1, *(c.shape[1] for c in cand.values())) if cand is not None else max(1, *(len(t) for t in tables.values()))
    step = max(1, _BUILD_CHUNK // width)
    parts: dict[str, list[Tensor]] = {kind: [] for kind in tables}
    for i in range(0, len(centres), step):
        px, py = centres[i : i + step, 0:1], centres[i : i + step, 1:2]
        d, idx = {}, {}
        for kind, t in tables.items():
            if cand is None:
                idx[kind] = torch.arange(len(t)).expand(len(px), len(t))
                d[kind] = _distances(kind, px, py, t[None])
            else:
                ids = cand[kind][i : i + step]
                rows = torch.cat((t, t.new_zeros(1, t.shape[1])))[ids]
                idx[kind], d[kind] = ids, torch.where(ids < len(t), _distances(kind, px, py, rows), math.inf)
        nearest = torch.stack([x.amin(1) if x.shape[1] else torch.full_like(px[:, 0], math.inf) for x in d.values()]).amin(0)
        limit = torch.clamp(nearest + 2 * h, min=reach + h)  # (P,)
        for kind, x in d.items():
            keep = x <= limit[:, None]
            n = int(keep.sum(1).max()) if x.shape[1] else 0
            # Each point's kept obstacles in index order; the rest of the row is padding.
            row, col = keep.nonzero(as_tuple=True)
            out = torch.full((len(px), n), len(tables[kind]), dtype=torch.int64)
            out[row, keep.cumsum(1)[row, col] - 1] = idx[kind][row, col]
            parts[kind].append(out)
    return {kind: torch.cat([torch.nn.functional.pad(q, (0, max(r.shape[1] for r in p) - q.shape[1]), value=len(tables[kind])) for q in p])
            for kind, p in parts.items()}


def _nearest_lists(centres: Tensor, h: float, tables: dict[str, Tensor], cand: dict[str, Tensor], slots: int,
                   step_min: float, step_max: float) -> tuple[dict[str, Tensor], Tensor]:
    """Per kind, each point's ``slots`` nearest obstacles of that kind among the candidates ``cand``
    (more where more lie within ``h + step_min``; padded as :func:`_select`'s), and the step ``(P,)``:
    every obstacle left out is farther than it from every point of the square of half diagonal ``h``
    around the point. ``cand`` must hold every obstacle within ``step_max`` of that square."""
    width = max(1, *(c.shape[1] for c in cand.values()))
    chunk = max(1, _BUILD_CHUNK // width)
    parts: dict[str, list[Tensor]] = {kind: [] for kind in tables}
    steps = []
    for i in range(0, len(centres), chunk):
        px, py = centres[i : i + chunk, 0:1], centres[i : i + chunk, 1:2]
        step = torch.full((len(px),), step_max)
        for kind, t in tables.items():
            ids = cand[kind][i : i + chunk]
            if ids.shape[1] == 0:
                parts[kind].append(ids)
                continue
            rows = torch.cat((t, t.new_zeros(1, t.shape[1])))[ids]
            d, order = torch.where(ids < len(t), _distances(kind, px, py, rows), math.inf).sort(1)
            ids = ids.gather(1, order)  # nearest first, the padding last
            m = min(ids.shape[1], max(slots, int((d <= h + step_min).sum(1).max())))
            if m < ids.shape[1]:  # the nearest obstacle left out bounds the step
                step = torch.minimum(step, d[:, m] - h)
            parts[kind].append(ids[:, :m])
        steps.append(step)
    lists = {kind: torch.cat([torch.nn.functional.pad(q, (0, max(r.shape[1] for r in p) - q.shape[1]), value=len(tables[kind])) for q in p])
             for kind, p in parts.items()}
    return lists, torch.cat(steps)


BLOCK = 8  # cells per side of the coarse blocks whose lists the cells choose from
RAY_CELL = 0.2  # m, the side of the near and ray lists' cells (larger on maps of more than MAX_CELLS of them)
RAY_SLOTS = 8  # obstacles of a kind each ray list holds at least (as many as the map has, if fewer)
RAY_STEP_MIN = 0.05  # m, the shortest march step: a ray list holds every obstacle this close to its cell
RAY_STEP_MAX = 3.0  # m, the longest march step
MAX_CELLS = 1 << 18
CLEAR_CELL = 0.05  # m, the side of the clearance grid's cells (larger on maps of more than MAX_CLEAR_CELLS of them)
MAX_CLEAR_CELLS = 1 << 20


def _extent(bounds: tuple[float, float, float, float], tables: dict[str, Tensor]) -> tuple[float, float, float, float]:
    """``bounds`` grown to hold every obstacle (segments' ends, circles, boxes' axis-aligned bounding boxes)."""
    xs, ys = [bounds[0], bounds[2]], [bounds[1], bounds[3]]
    for kind, t in tables.items():
        if len(t):
            if kind == "segments":
                xs += [float(t[:, [0, 2]].min()), float(t[:, [0, 2]].max())]
                ys += [float(t[:, [1, 3]].min()), float(t[:, [1, 3]].max())]
            else:
                if kind == "circles":
                    rx = ry = t[:, 2]
                else:  # a box's half extents along x and y, rotated by its yaw
                    c, s = t[:, 4].cos().abs(), t[:, 4].sin().abs()
                    rx, ry = t[:, 2] * c + t[:, 3] * s, t[:, 2] * s + t[:, 3] * c
                xs += [float((t[:, 0] - rx).min()), float((t[:, 0] + rx).max())]
                ys += [float((t[:, 1] - ry).min()), float((t[:, 1] + ry).max())]
    return min(xs), min(ys), max(xs), max(ys)


def build_static_map(
    bounds: tuple[float, float, float, float],
    segments: Tensor | None = None,
    circles: Tensor | None = None,
    boxes: Tensor | None = None,
    reach: float = 10.0,
    cell: float | None = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
    ray_cell: float | None = None,
    rays: bool = True,
    clearance_grid: bool = True,
) -> StaticMap:
    """Index fixed obstacles (``segments`` ``(S, 4)``, ``circles`` ``(C, 3)``, ``boxes`` ``(K, 5)``, the
    layouts of :class:`~torchnav.sim.state.World`) over grids of square cells covering ``bounds``
    ``(xmin, ymin, xmax, ymax)`` m (grown to hold every obstacle for the near and ray lists).
    ``reach`` m: at least the sensors' (:func:`static_reach`; 0 builds no reach lists: for clearance and
    ray scans only). ``rays``: build the ray lists (False: for clearance only). ``clearance_grid``:
    build the clearance grid (cells of ``CLEAR_CELL`` m, at most ``MAX_CLEAR_CELLS``). ``cell``
    m: the reach lists' cell side; None picks ``reach / 20`` within [0.25, 0.5] m and at most 2**16
    cells. ``ray_cell`` m: the near and ray lists' cell side; None picks ``RAY_CELL`` and at most
    ``MAX_CELLS`` cells.

    Each list pads to the longest, so each per-env world of :func:`local_world` holds that many slots
    of each kind. The cells choose from the lists of blocks of ``BLOCK x BLOCK`` cells, chosen by the
    same rule for the blocks' larger squares: a block's list holds every obstacle any of its cells can
    keep, so the index is that of testing every cell against every obstacle, in a fraction of the time."""
    xmin, ymin, xmax, ymax = (float(v) for v in bounds)
    if not (xmax > xmin and ymax > ymin):
        raise ValueError(f"bounds must be (xmin, ymin, xmax, ymax) with xmin < xmax and ymin < ymax, got {bounds}")
    if not (math.isfinite(reach) and reach >= 0):
        raise ValueError(f"reach must be a finite number of metres >= 0, got {reach!r}")
    if cell is None:
        cell = min(0.5, max(0.25, reach / 20))
        cell = max(cell, math.sqrt((xmax - xmin) * (ymax - ymin) / 65536))
    if not (math.isfinite(cell) and cell > 0):
        raise ValueError(f"cell must be a positive number of metres, got {cell!r}")
    given = {"segments": segments, "circles": circles, "boxes": boxes}
    exact = {kind: torch.as_tensor(given[kind] if given[kind] is not None else torch.zeros(0, width)).to(dtype).reshape(-1, width)
             for kind, _, width in _KINDS}  # the values the simulator will see
    tables = {kind: t.float() for kind, t in exact.items()}  # chosen from in float32, within `tol`
    for kind, t in exact.items():
        if not torch.isfinite(t).all():
            raise ValueError(f"{kind} must be finite, got non-finite values in rows {(~torch.isfinite(t)).any(1).nonzero()[:10, 0].tolist()}")
    grid = _extent((xmin, ymin, xmax, ymax), tables)
    if ray_cell is None:
        ray_cell = max(RAY_CELL, math.sqrt((grid[2] - grid[0]) * (grid[3] - grid[1]) / MAX_CELLS))
    if not (math.isfinite(ray_cell) and ray_cell > 0):
        raise ValueError(f"ray_cell must be a positive number of metres, got {ray_cell!r}")
    # Rounding of the float32 distances and obstacles: a little more than the Lipschitz bound, never less.
    tol = 1e-4 + 1e-6 * max(abs(v) for v in grid)

    def cells(x0: float, y0: float, x1: float, y1: float, side: float, block_reach: float) -> tuple[Tensor, Tensor, dict[str, Tensor], int, int]:
        """The cells of side ``side`` over the box: centres, half diagonal (with ``tol``), the
        candidates from their blocks (chosen for ``block_reach``) and the grid's size."""
        nx, ny = max(1, math.ceil((x1 - x0) / side)), max(1, math.ceil((y1 - y0) / side))

        def centres(n_x: int, n_y: int, s: float) -> Tensor:  # row j * n_x + i
            xs = x0 + s * (torch.arange(n_x, dtype=torch.float64) + 0.5)
            ys = y0 + s * (torch.arange(n_y, dtype=torch.float64) + 0.5)
            return torch.stack(torch.meshgrid(xs, ys, indexing="xy"), -1).reshape(-1, 2).float()

        bx, by = math.ceil(nx / BLOCK), math.ceil(ny / BLOCK)
        blocks = _select(centres(bx, by, BLOCK * side), BLOCK * side * math.sqrt(0.5) * (1 + 1e-4) + tol, block_reach, tables)
        i, j = torch.arange(nx).repeat(ny), torch.arange(ny).repeat_interleave(nx)
        block_of = (j // BLOCK) * bx + i // BLOCK  # (cells,)
        return centres(nx, ny, side), side * math.sqrt(0.5) * (1 + 1e-4) + tol, {k: v[block_of] for k, v in blocks.items()}, nx, ny

    def to_device(ids: dict[str, Tensor]) -> dict[str, Tensor]:
        return {k: v.to(device) for k, v in ids.items()}

    reach_lists = ray_lists = ray_step = ray_rows = None
    planar = {k: torch.cat((t, t.new_zeros(1, t.shape[1])), 0).t().contiguous().to(device=device) for k, t in exact.items()}
    if reach > 0:
        pts, h, cand, nx, ny = cells(xmin, ymin, xmax, ymax, cell, reach)
        reach_lists = CellLists(to_device(_select(pts, h, reach, tables, cand)), (xmin, ymin), float(cell), nx, ny)
    pts, h, cand, nx, ny = cells(*grid, ray_cell, RAY_STEP_MAX if rays else 0.0)
    near_lists = CellLists(to_device(_select(pts, h, 0.0, tables, cand)), grid[:2], float(ray_cell), nx, ny)
    if rays:
        ray_ids, ray_step = _nearest_lists(pts, h, tables, cand, RAY_SLOTS, RAY_STEP_MIN, RAY_STEP_MAX)
        ray_lists, ray_step = CellLists(to_device(ray_ids), grid[:2], float(ray_cell), nx, ny), ray_step.to(device=device, dtype=dtype)
        # The padding column is an obstacle of zero size, which every hit function misses: no mask needed.
        ray_rows = {k: _ROWS[k](planar[k])[:, ids].permute(1, 0, 2).contiguous() for k, ids in ray_lists.ids.items()}
    static = StaticMap(
        segments=planar["segments"], circles=planar["circles"], boxes=planar["boxes"],
        reach_lists=reach_lists, near_lists=near_lists, ray_lists=ray_lists, ray_step=ray_step, ray_rows=ray_rows,
        bounds=grid, reach=float(reach),
    )
    return dataclasses.replace(static, clearance_grid=_clearance_grid(static, tol)) if clearance_grid else static


def _clearance_grid(static: StaticMap, tol: float) -> ClearanceGrid:
    """The exact clearance at the centres of cells of ``CLEAR_CELL`` m (coarser on a map that would need more
    than ``MAX_CLEAR_CELLS``) over ``static``'s grid, measured through its near lists."""
    x0, y0, x1, y1 = static.bounds
    side = max(CLEAR_CELL, math.sqrt((x1 - x0) * (y1 - y0) / MAX_CLEAR_CELLS))
    nx, ny = max(1, math.ceil((x1 - x0) / side)), max(1, math.ceil((y1 - y0) / side))
    like = static.boxes
    xs = x0 + side * (torch.arange(nx, dtype=torch.float64) + 0.5)
    ys = y0 + side * (torch.arange(ny, dtype=torch.float64) + 0.5)
    centres = torch.stack(torch.meshgrid(xs, ys, indexing="xy"), -1).to(device=like.device, dtype=like.dtype)  # (ny, nx, 2)
    values = static_clearance(static, centres)
    return ClearanceGrid(values, (x0, y0), side, side * math.sqrt(0.5) * (1 + 1e-4) + tol)


def local_world(static: StaticMap, xy: Tensor, lists: str = "reach") -> World:
    """The obstacles that matter to robots at ``xy`` ``(B, 2)`` m: a world of batch ``B`` with each
    kind's slots from the robot's cell list (masked off past the list's end), stored component-major
    (:func:`~torchnav.sim.state.planar_world`). ``lists``: ``"reach"`` (what the sensors see) or
    ``"near"`` (what can be nearest). Not differentiated through the obstacles, which are fixed."""
    index = static._lists(lists)
    cells = index.cells_of(xy.detach())
    out = {}
    for kind, mkey, _ in _KINDS:
        ids = index.ids[kind][cells]  # (B, M)
        table = getattr(static, kind)  # (k, N + 1)
        out[kind] = table.index_select(1, ids.reshape(-1)).reshape(table.shape[0], *ids.shape).permute(1, 2, 0)  # (B, M, k), each component a contiguous (B, M) block
        out[mkey] = ids < table.shape[1] - 1
    return World(**out, batch_size=[xy.shape[0]], device=xy.device)


def with_static(world: World, static: StaticMap, xy: Tensor) -> World:
    """``world`` (per-env objects, batch ``B``) with the static obstacles of the reach lists near ``xy``
    ``(B, 2)`` as its first slots of each kind (:func:`local_world`), stored component-major."""
    near = local_world(static, xy)
    out = {}
    for kind, mkey, _ in _KINDS:
        a, b = getattr(near, kind), getattr(world, kind)
        # Concatenated component-major: (k, B, Ma + Mb) blocks, viewed as (B, M, k).
        out[kind] = torch.cat((a.permute(2, 0, 1), b.permute(2, 0, 1)), 2).permute(1, 2, 0)
        out[mkey] = torch.cat((getattr(near, mkey), getattr(world, mkey)), 1)
    return World(**out, batch_size=world.batch_size, device=world.device)


def static_clearance(static: StaticMap, points: Tensor, chunk: int = 1 << 20, floor: float | None = None) -> Tensor:
    """Signed distance ``(n, P)`` m from points ``(n, P, 2)`` to the nearest static obstacle, exactly
    the whole map's (the near lists hold every obstacle that can be nearest), in chunks of at most
    ``chunk`` (point, slot) pairs; ``+inf`` on an empty map.

    With ``floor`` m and the map's clearance grid, only the points whose clearance the grid leaves
    within about a cell of ``floor`` are measured. The others read a bound of their clearance on the
    same side of ``floor`` (at least ``floor`` for a point clear of it, below it for one that is not):
    ``clearance >= floor`` is decided as exactly, but only the measured values are exact."""
    flat = points.reshape(-1, 2)
    if floor is not None and static.clearance_grid is not None:
        low, high = static.clearance_grid.bounds(flat)
        clear = low >= floor
        measure = (~(clear | (high < floor))).nonzero()[:, 0]
        out = torch.where(clear, low, high).index_copy(0, measure, static_clearance(static, flat.index_select(0, measure)[None], chunk)[0])
        return out.reshape(points.shape[:-1])
    best = torch.full((flat.shape[0],), math.inf, dtype=points.dtype, device=points.device)
    slots = max(1, max(static.near_lists.slots.values()))
    step = max(1, chunk // slots)
    for s in range(0, flat.shape[0], step):
        xy = flat[s : s + step]
        near = local_world(static, xy, "near")
        for kind, mkey, _ in _KINDS:
            obs = getattr(near, kind)
            if obs.shape[1]:
                fn = {"segments": segment_distance, "circles": _circle_dist, "boxes": _box_dist}[kind]
                d = torch.where(getattr(near, mkey), fn(xy[:, 0:1], xy[:, 1:2], obs), math.inf)
                best[s : s + step] = torch.minimum(best[s : s + step], d.amin(1))
    return best.reshape(points.shape[:-1])


def _entry_distance(bounds: tuple[float, float, float, float], ox: Tensor, oy: Tensor, dx: Tensor, dy: Tensor) -> Tensor:
    """Distance along unit rays to where they enter the box ``bounds``: 0 from inside, ``inf`` for a
    ray that misses it (the slab method)."""
    def slab(o: Tensor, d: Tensor, lo: float, hi: float) -> tuple[Tensor, Tensor]:
        inv = 1.0 / torch.where(d.abs() > 1e-12, d, torch.full_like(d, 1e-12))
        a, b = (lo - o) * inv, (hi - o) * inv
        return torch.minimum(a, b), torch.maximum(a, b)

    xa, xb = slab(ox, dx, bounds[0], bounds[2])
    ya, yb = slab(oy, dy, bounds[1], bounds[3])
    t_in, t_out = torch.maximum(xa, ya).clamp(min=0.0), torch.minimum(xb, yb)
    return torch.where(t_in <= t_out, t_in, math.inf)


_HITS = {"segments": hit_segment, "circles": hit_circle, "boxes": _hit_box_rows}
_ROWS = {"segments": lambda t: t, "circles": lambda t: t, "boxes": lambda t: _box_rows(t.t()).t()}  # planar (w, N) -> hit rows


def _march_step(ray: Tensor, where: Tensor, rows: dict[str, Tensor], cell_step: Tensor, grid: tuple[float, float, float, int, int],
                bounds: tuple[float, float, float, float], max_range: float, steps: int = 1) -> tuple[Tensor, Tensor, Tensor]:
    """``steps`` march steps of the rays ``ray`` ``(n, 6)`` ``[ox, oy, dx, dy, t, best]`` (the point
    ``o + t d`` and the nearest hit so far) and ``where`` ``(n,)``, the cell that listed that hit:
    test each ray against its cell's ray lists (``rows``, :attr:`StaticMap.ray_rows`, on the cells
    ``grid`` ``(x0, y0, side, nx, ny)``) and move it on by the cell's step ``cell_step``. Returns the
    new ``(ray, where)`` and ``going`` ``(n,)`` bool: the rays still to march (short of their nearest
    hit and the range, inside ``bounds``, which hold every obstacle). A ray done before the last step
    steps on harmlessly: all it can meet are real hits no nearer than the first, and once out of the
    bounds it stays out. Takes tensors and numbers only, so that compiled calls check few guards."""
    ox, oy, dx, dy, t, best = ray.unbind(1)
    x0, y0, side, nx, ny = grid
    ok = torch.ones((), dtype=torch.bool, device=ray.device)
    for _ in range(steps):
        cells = _cell_index(ox + t * dx, oy + t * dy, (x0, y0), side, nx, ny)
        for key, table in rows.items():
            obs = table.index_select(0, cells).transpose(1, 2)  # (n, M, w)
            near = _HITS[key](ox[:, None], oy[:, None], dx[:, None], dy[:, None], obs, ok).amin(1)
            where = torch.where(near < best, cells, where)
            best = torch.minimum(near, best)
        t = t + cell_step.index_select(0, cells)
    x, y = ox + t * dx, oy + t * dy
    going = (t < best) & (t < max_range) & (x >= bounds[0]) & (x <= bounds[2]) & (y >= bounds[1]) & (y <= bounds[3])
    return torch.stack((ox, oy, dx, dy, t, best), 1), where, going


_compiled_march_step = None
COMPILED_MARCH_STEPS = 2  # march steps per call of the compiled step
_MARCH_COMPILED = contextvars.ContextVar("torchnav_march_compiled", default=False)


@contextlib.contextmanager
def compiled_march() -> Iterator[None]:
    """Within it, eager calls march their rays with the compiled march steps too, as calls inside
    ``torch.compile`` always do (compiled once per process, 20-60 s). A compiled task's fresh
    episodes take their first scan under it: their march, on a few hundred envs, costs about half."""
    token = _MARCH_COMPILED.set(True)
    try:
        yield
    finally:
        _MARCH_COMPILED.reset(token)


@torch.compiler.disable
@torch.no_grad()
def _march(static: StaticMap, ox: Tensor, oy: Tensor, dx: Tensor, dy: Tensor, start: float, done: Tensor, max_range: float,
           compiled: bool) -> tuple[Tensor, Tensor]:
    """March the rays (flat ``(N,)`` origins and unit directions) from ``start`` m on, but those
    ``done``: each ray's nearest hit ``(N,)`` m (inf: none found) and the cell ``(N,)`` that listed it
    (-1: none). Eager (a loop whose length depends on the rays), on the rays still marching only;
    ``compiled``: its steps through ``torch.compile`` (dynamic shapes, compiled once per process)."""
    global _compiled_march_step
    step, steps = _march_step, 1
    if compiled:
        if _compiled_march_step is None:
            _compiled_march_step = torch.compile(_march_step, dynamic=True)
        step, steps = _compiled_march_step, COMPILED_MARCH_STEPS
    lists = static.ray_lists
    rows = {k: v for k, v in static.ray_rows.items() if v.shape[2]}
    grid = (*lists.origin, lists.cell, lists.nx, lists.ny)
    best = torch.full_like(ox, math.inf)
    where = torch.full_like(ox, -1, dtype=torch.int64)
    # Rays from outside the grid start where they enter it; those that miss it never start.
    t = torch.maximum(_entry_distance(static.bounds, ox, oy, dx, dy), torch.full_like(ox, start))
    live = ((t < max_range) & ~done).nonzero()[:, 0]
    ray = torch.stack((ox, oy, dx, dy, t, best), 1).index_select(0, live)
    at = where.index_select(0, live)
    while live.numel():
        ray, at, going = step(ray, at, rows, static.ray_step, grid, static.bounds, max_range, steps)
        if not bool(going.all()):
            stop = (~going).nonzero()[:, 0]
            best.index_copy_(0, live.index_select(0, stop), ray[:, 5].index_select(0, stop))
            where.index_copy_(0, live.index_select(0, stop), at.index_select(0, stop))
            keep = going.nonzero()[:, 0]
            live, ray, at = live.index_select(0, keep), ray.index_select(0, keep), at.index_select(0, keep)
    return best, where


def static_ray_hits(static: StaticMap, origin: Tensor, angles: Tensor, max_range: float, start: float = 0.0,
                    done: Tensor | None = None) -> Tensor:
    """Distance ``(B, R)`` m along rays from ``origin`` ``(B, 2)`` at world ``angles`` ``(B, R)`` to the
    first static obstacle they hit from ``start`` m on; ``inf`` where none lies nearer than
    ``max_range`` or the ray is ``done`` ``(B, R)`` bool (not marched).

    Each ray marches from cell to cell of the ray lists: at each point it is tested against the
    obstacles its cell lists, then it moves on by the cell's step, which no obstacle left out of the
    list is nearer than. No obstacle the ray meets is ever stepped over, so the nearest hit found is
    the whole map's. With gradients to the origin or angles, the cell that listed it is tested once
    more, differentiably (the every-obstacle scan's minimum has the same gradients). The march costs
    a few cells per ray, whatever the map's size; it runs eagerly under ``torch.compile``, each of
    its steps compiled (and so in eager calls within :func:`compiled_march`)."""
    static._lists("ray")  # names them if missing
    dx, dy = torch.cos(angles), torch.sin(angles)
    ox, oy = origin[:, 0:1].expand_as(dx), origin[:, 1:2].expand_as(dx)
    done = torch.zeros_like(dx, dtype=torch.bool) if done is None else done
    rays = [v.detach().reshape(-1) for v in (ox, oy, dx, dy)]
    best, where = _march(static, *rays, start, done.reshape(-1), max_range, torch.compiler.is_compiling() or _MARCH_COMPILED.get())
    # The march stops at the range: a hit past it need not be the first one there, so none is kept.
    where = torch.where(best < max_range, where, -1).reshape(dx.shape)
    best = torch.where(best < max_range, best, math.inf).reshape(dx.shape)
    if not (torch.is_grad_enabled() and (origin.requires_grad or angles.requires_grad)):
        return best
    out = torch.full_like(dx, math.inf)
    ok = torch.ones((), dtype=torch.bool, device=dx.device)
    for key, rows in static.ray_rows.items():
        if rows.shape[2]:
            obs = rows.index_select(0, where.clamp(min=0).reshape(-1)).reshape(*dx.shape, *rows.shape[1:]).transpose(-1, -2)  # (B, R, M, w)
            out = torch.minimum(out, _HITS[key](ox[..., None], oy[..., None], dx[..., None], dy[..., None], obs, ok).amin(-1))
    return torch.where(where >= 0, out, math.inf)
