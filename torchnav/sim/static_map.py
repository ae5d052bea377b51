"""A map's fixed obstacles held once for a whole batch, with a grid index of what each place can see.

A big static map (a building from SLAM: thousands of boxes after the occupancy conversion) is the
same in every env of a batch. Copying it into every env's :class:`~torchnav.sim.state.World` costs
memory in proportion to the number of envs, and testing every lidar ray against every obstacle costs
time in proportion to the map. A :class:`StaticMap` holds the obstacles once, and a uniform grid of
cells over the map in which each cell lists the obstacles that can matter to a robot standing in it:

* every obstacle within ``reach`` of some point of the cell (``reach`` is at least the longest
  sensor ray from the robot's centre, :func:`static_reach`), so the lidar, the exact sector scan and
  the camera see exactly what they would see of the whole map;
* every obstacle that can be the nearest one to some point of the cell, so the clearance (and the
  collision test) is exactly the whole map's, however far the nearest obstacle is.

Both follow from the obstacles' signed distances being 1-Lipschitz: for a point ``p`` of a cell of
centre ``c`` and half diagonal ``h``, ``|sd(p, o) - sd(c, o)| <= h``. Every step gathers each
robot's cell list into a small per-env world (:func:`local_world`), so the rest of the step is the
brute-force code, unchanged, on fewer slots: the readings are the whole map's, up to nothing (the
nearest hit is a minimum over the same per-obstacle values), gradients flow to the pose as before,
and the per-env memory is that of one cell list. The guarantee holds for robots inside the grid
(the map's bounds); a robot outside it uses its nearest cell's list.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .geometry import _box_dist, _circle_dist, segment_distance
from .params import SimParams
from .state import World

# Most (cells, obstacles) distance elements computed at once while building the index.
_BUILD_CHUNK = 1 << 22
_KINDS = (("segments", "segment_mask", 4), ("circles", "circle_mask", 3), ("boxes", "box_mask", 5))
_IDS = {"segments": "segment_ids", "circles": "circle_ids", "boxes": "box_ids"}


@dataclass(frozen=True, eq=False)
class StaticMap:
    """Fixed obstacles shared by every env of a batch, and the grid index of :func:`build_static_map`.

    Obstacle tables are stored component-major with one extra zero column that empty list entries
    point at: ``segments`` ``(4, S + 1)``, ``circles`` ``(3, C + 1)``, ``boxes`` ``(5, K + 1)`` (the
    layouts of :class:`~torchnav.sim.state.World`, m and rad). ``*_ids`` ``(ny * nx, M)`` int64 list
    each cell's obstacles of a kind (row ``j * nx + i`` is the cell ``i`` along x, ``j`` along y),
    padded with the index of the zero column."""

    segments: Tensor
    circles: Tensor
    boxes: Tensor
    segment_ids: Tensor
    circle_ids: Tensor
    box_ids: Tensor
    origin: tuple[float, float]  # m, the lower-left corner of cell (0, 0)
    cell: float  # m, the side of a cell
    nx: int
    ny: int
    reach: float  # m, every obstacle this close to a cell is in its lists

    @property
    def n_obstacles(self) -> dict[str, int]:
        """Obstacles of each kind held (without the padding column)."""
        return {k: getattr(self, k).shape[1] - 1 for k, _, _ in _KINDS}

    @property
    def slots(self) -> dict[str, int]:
        """Per-env slots of each kind that :func:`local_world` gathers: the longest cell list."""
        return {k: getattr(self, _IDS[k]).shape[1] for k, _, _ in _KINDS}

    def nbytes(self) -> int:
        """Bytes held by the obstacle tables and the index (the same for any number of envs)."""
        return sum(t.numel() * t.element_size() for t in (self.segments, self.circles, self.boxes, self.segment_ids, self.circle_ids, self.box_ids))


def static_reach(params: SimParams) -> float:
    """The distance (m) from a robot's centre that its sensors can see: the lidar's range plus its
    mount offset, or the camera's if it sees farther (its range is a depth along the optical axis, so
    its edge columns see ``1 / cos(fov / 2)`` times as far). A :class:`StaticMap` built with at least
    this ``reach`` gives these params' lidar, camera and clearance exactly."""
    reach = params.lidar.max_range + math.hypot(*params.lidar.offset[:2])
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


BLOCK = 8  # cells per side of the coarse blocks whose lists the cells choose from


def build_static_map(
    bounds: tuple[float, float, float, float],
    segments: Tensor | None = None,
    circles: Tensor | None = None,
    boxes: Tensor | None = None,
    reach: float = 10.0,
    cell: float | None = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> StaticMap:
    """Index fixed obstacles (``segments`` ``(S, 4)``, ``circles`` ``(C, 3)``, ``boxes`` ``(K, 5)``, the
    layouts of :class:`~torchnav.sim.state.World`) over a grid of square cells covering ``bounds``
    ``(xmin, ymin, xmax, ymax)`` m. ``reach`` m: at least the sensors' (:func:`static_reach`; 0 for
    clearance queries only). ``cell`` m: the cell side; None picks ``reach / 20`` within [0.25, 0.5] m
    and at most 2**16 cells.

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
    nx, ny = max(1, math.ceil((xmax - xmin) / cell)), max(1, math.ceil((ymax - ymin) / cell))
    # Rounding of the float32 distances and obstacles: a little more than the Lipschitz bound, never less.
    tol = 1e-4 + 1e-6 * max(abs(xmin), abs(ymin), abs(xmax), abs(ymax))
    given = {"segments": segments, "circles": circles, "boxes": boxes}
    exact = {kind: torch.as_tensor(given[kind] if given[kind] is not None else torch.zeros(0, width)).to(dtype).reshape(-1, width)
             for kind, _, width in _KINDS}  # the values the simulator will see
    tables = {kind: t.float() for kind, t in exact.items()}  # chosen from in float32, within `tol`

    def centres(n_x: int, n_y: int, side: float) -> Tensor:  # row j * n_x + i
        xs = xmin + side * (torch.arange(n_x, dtype=torch.float64) + 0.5)
        ys = ymin + side * (torch.arange(n_y, dtype=torch.float64) + 0.5)
        return torch.stack(torch.meshgrid(xs, ys, indexing="xy"), -1).reshape(-1, 2).float()

    bx, by = math.ceil(nx / BLOCK), math.ceil(ny / BLOCK)
    blocks = _select(centres(bx, by, BLOCK * cell), BLOCK * cell * math.sqrt(0.5) * (1 + 1e-4) + tol, reach, tables)
    i, j = torch.arange(nx).repeat(ny), torch.arange(ny).repeat_interleave(nx)
    block_of = (j // BLOCK) * bx + i // BLOCK  # (cells,)
    ids = _select(centres(nx, ny, cell), cell * math.sqrt(0.5) * (1 + 1e-4) + tol, reach, tables, {k: v[block_of] for k, v in blocks.items()})
    ids = {k: v.to(device) for k, v in ids.items()}
    planar = {k: torch.cat((t, t.new_zeros(1, t.shape[1])), 0).t().contiguous().to(device=device) for k, t in exact.items()}
    return StaticMap(
        segments=planar["segments"], circles=planar["circles"], boxes=planar["boxes"],
        segment_ids=ids["segments"], circle_ids=ids["circles"], box_ids=ids["boxes"],
        origin=(xmin, ymin), cell=float(cell), nx=nx, ny=ny, reach=float(reach),
    )


def cell_of(static: StaticMap, xy: Tensor) -> Tensor:
    """Index ``(...)`` int64 of the cell holding each point ``xy`` ``(..., 2)`` m (the nearest cell
    for points outside the grid)."""
    i = ((xy[..., 0] - static.origin[0]) / static.cell).floor().clamp(0, static.nx - 1).long()
    j = ((xy[..., 1] - static.origin[1]) / static.cell).floor().clamp(0, static.ny - 1).long()
    return j * static.nx + i


def local_world(static: StaticMap, xy: Tensor) -> World:
    """The obstacles that matter to robots at ``xy`` ``(B, 2)`` m: a world of batch ``B`` with each
    kind's slots from the robot's cell list (masked off past the list's end), stored component-major
    (:func:`~torchnav.sim.state.planar_world`). Not differentiated through the obstacles, which are fixed."""
    cells = cell_of(static, xy.detach())
    out = {}
    for kind, mkey, _ in _KINDS:
        ids = getattr(static, _IDS[kind])[cells]  # (B, M)
        table = getattr(static, kind)  # (k, N + 1)
        out[kind] = table[:, ids].permute(1, 2, 0)  # (B, M, k), each component a contiguous (B, M) block
        out[mkey] = ids < table.shape[1] - 1
    return World(**out, batch_size=[xy.shape[0]], device=xy.device)


def with_static(world: World, static: StaticMap, xy: Tensor) -> World:
    """``world`` (per-env objects, batch ``B``) with the static obstacles near ``xy`` ``(B, 2)`` as
    its first slots of each kind (:func:`local_world`), stored component-major."""
    near = local_world(static, xy)
    out = {}
    for kind, mkey, _ in _KINDS:
        a, b = getattr(near, kind), getattr(world, kind)
        # Concatenated component-major: (k, B, Ma + Mb) blocks, viewed as (B, M, k).
        out[kind] = torch.cat((a.permute(2, 0, 1), b.permute(2, 0, 1)), 2).permute(1, 2, 0)
        out[mkey] = torch.cat((getattr(near, mkey), getattr(world, mkey)), 1)
    return World(**out, batch_size=world.batch_size, device=world.device)


def static_clearance(static: StaticMap, points: Tensor, chunk: int = 1 << 20) -> Tensor:
    """Signed distance ``(n, P)`` m from points ``(n, P, 2)`` to the nearest static obstacle, exactly
    the whole map's (the cell lists hold every obstacle that can be nearest), in chunks of at most
    ``chunk`` (point, slot) pairs; ``+inf`` on an empty map."""
    flat = points.reshape(-1, 2)
    best = torch.full((flat.shape[0],), math.inf, dtype=points.dtype, device=points.device)
    slots = max(1, max(static.slots.values()))
    step = max(1, chunk // slots)
    for s in range(0, flat.shape[0], step):
        xy = flat[s : s + step]
        near = local_world(static, xy)
        for kind, mkey, _ in _KINDS:
            obs = getattr(near, kind)
            if obs.shape[1]:
                fn = {"segments": segment_distance, "circles": _circle_dist, "boxes": _box_dist}[kind]
                d = torch.where(getattr(near, mkey), fn(xy[:, 0:1], xy[:, 1:2], obs), math.inf)
                best[s : s + step] = torch.minimum(best[s : s + step], d.amin(1))
    return best.reshape(points.shape[:-1])
