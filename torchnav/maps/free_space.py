"""Offline checks of a map's free space, in numpy: distance field and connectivity.

Built on the simulator's geometry (``torchnav.sim.points_clearance``, in float64);
this is for map authors, planners and tests: "can a robot of radius r
get from anywhere to anywhere in this map?". Only the fixed obstacles of a
:class:`MapSpec` are used.
"""

from __future__ import annotations

import functools
from collections import deque

import numpy as np
import torch

from ..sim import make_world, points_clearance
from ..sim.static_map import build_static_map, static_clearance
from .spec import MapError, MapSpec


INDEX_FROM = 256  # obstacles from which distances go through a grid index


def obstacle_distance(spec: MapSpec, xy: np.ndarray) -> np.ndarray:
    """Distance in m from points ``xy`` ``(N, 2)`` to the nearest fixed obstacle, ``(N,)``.

    Negative inside a circle or box (signed distance); walls are lines of zero
    thickness so the distance to them is never negative. ``+inf`` for an empty map.
    """
    return obstacle_distance_arrays(xy, spec.segments, spec.circles, spec.boxes)


def obstacle_distance_arrays(xy: np.ndarray, segments=(), circles=(), boxes=()) -> np.ndarray:
    """:func:`obstacle_distance` for obstacles given as arrays in the layouts of ``World``:
    walls ``(S, 4)``, circles ``(C, 3)``, boxes ``(K, 5)`` (half extents, yaw in rad). ``(N,)`` m.

    The simulator's own geometry (``torchnav.sim.points_clearance``) in float64, so planners,
    map checks and the simulator agree on every distance."""
    segments, circles, boxes = (torch.as_tensor(np.asarray(a, dtype=np.float64).reshape(-1, w)) for a, w in ((segments, 4), (circles, 3), (boxes, 5)))
    pts = torch.as_tensor(np.asarray(xy, dtype=np.float64).reshape(1, -1, 2))
    if len(segments) + len(circles) + len(boxes) > INDEX_FROM and pts.shape[1]:
        # Many obstacles: each point is measured against its cell's candidates only (sim/static_map.py),
        # the same distances as against every obstacle.
        lo, hi = pts[0].amin(0) - 1.0, pts[0].amax(0) + 1.0
        static = build_static_map((lo[0], lo[1], hi[0], hi[1]), segments, circles, boxes, reach=0.0, dtype=torch.float64, rays=False, clearance_grid=False)
        return static_clearance(static, pts)[0].numpy()
    world = make_world(1, segments=segments, circles=circles, boxes=boxes, dtype=torch.float64)
    # points_clearance holds a (points, obstacles) table per kind: chunk the points to keep it small.
    step = max(1, (1 << 22) // max(1, world.segments.shape[1], world.circles.shape[1], world.boxes.shape[1]))
    chunks = [points_clearance(pts[:, i:i + step], world)[0] for i in range(0, pts.shape[1], step)]
    return torch.cat(chunks).numpy() if chunks else np.zeros(0)  # no points: a grid with no cell (a world thinner than its sampling)


def free_grid(spec: MapSpec, robot_radius: float, resolution: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells where a disc of ``robot_radius`` m fits, sampled at cell centres every ``resolution`` m.

    Returns ``(free, xs, ys)``: ``free`` is ``(ny, nx)`` bool (row ``j`` is y = ``ys[j]``),
    ``xs`` ``(nx,)`` and ``ys`` ``(ny,)`` the cell centres in m.
    """
    d, edge, xs, ys = _distance_grid(spec, resolution)
    return (d > robot_radius) & (edge > robot_radius), xs, ys


@functools.lru_cache(maxsize=16)
def _distance_grid(spec: MapSpec, resolution: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`free_grid`'s distances ``(ny, nx)`` to the nearest obstacle and to the world's edge, and
    its cell centres ``xs``, ``ys``: measured once per map and resolution (read-only arrays)."""
    xmin, ymin, xmax, ymax = spec.bounds
    xs = np.arange(xmin + resolution / 2, xmax, resolution)
    ys = np.arange(ymin + resolution / 2, ymax, resolution)
    gx, gy = np.meshgrid(xs, ys)
    d = obstacle_distance(spec, np.stack([gx.ravel(), gy.ravel()], -1)).reshape(gx.shape)
    # The world rectangle bounds the grid even when the map has no boundary walls.
    edge = np.minimum(np.minimum(gx - xmin, xmax - gx), np.minimum(gy - ymin, ymax - gy))
    for a in (d, edge, xs, ys):
        a.flags.writeable = False
    return d, edge, xs, ys


def _room_resolution(spec: MapSpec) -> float:
    return max(0.05, max(spec.size) / 200)  # a grid of at most about 200 x 200 cells


@functools.lru_cache(maxsize=64)
def free_points(spec: MapSpec, need: float) -> np.ndarray:
    """Centres ``(F, 2)`` (m) of the cells of :func:`check_room`'s grid that lie more than ``need`` m
    from every fixed obstacle and the world's edge: collision-free places for a disc of radius ``need``."""
    free, xs, ys = free_grid(spec, need, _room_resolution(spec))
    j, i = np.nonzero(free)
    return np.stack((xs[i], ys[j]), -1)


@functools.lru_cache(maxsize=64)
def check_room(spec: MapSpec, robot_need: float, goal_need: float) -> None:
    """Raise a MapError unless some place lies ``robot_need`` m from every fixed obstacle and the
    world's edge (a start for the robot's disc) and some place ``goal_need`` m from every fixed
    obstacle (a goal). Sampled on a grid of at most about 200 x 200 cells."""
    res = _room_resolution(spec)
    for need, what in ((robot_need, "a start (robot radius + reset.start_clearance)"), (goal_need, "a goal (reset.goal_clearance)")):
        if not free_grid(spec, need, res)[0].any():
            raise MapError(f"{spec.source}: no room for {what}: no place is {need:g} m from every fixed obstacle and the "
                           f"world's edge (sampled every {res:g} m); the map is full or smaller than the robot")


def label_components(free: np.ndarray) -> tuple[np.ndarray, int]:
    """4-connected components of a bool grid: ``(labels, n)``, labels ``-1`` on blocked cells."""
    labels = np.full(free.shape, -1, dtype=np.int64)
    n = 0
    ny, nx = free.shape
    for j0, i0 in zip(*np.nonzero(free)):
        if labels[j0, i0] >= 0:
            continue
        labels[j0, i0] = n
        queue = deque([(j0, i0)])
        while queue:
            j, i = queue.popleft()
            for jj, ii in ((j + 1, i), (j - 1, i), (j, i + 1), (j, i - 1)):
                if 0 <= jj < ny and 0 <= ii < nx and free[jj, ii] and labels[jj, ii] < 0:
                    labels[jj, ii] = n
                    queue.append((jj, ii))
        n += 1
    return labels, n


def reachable_fraction(spec: MapSpec, robot_radius: float, resolution: float = 0.05) -> float:
    """Share of the free cells that lie in the largest connected free region (1.0: all connected)."""
    free, _, _ = free_grid(spec, robot_radius, resolution)
    labels, n = label_components(free)
    if n == 0:
        return 0.0
    return float(np.bincount(labels[labels >= 0]).max() / free.sum())
