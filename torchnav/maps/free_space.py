"""Offline checks of a map's free space, in numpy: distance field and connectivity.

Not used by the simulator (which has its own differentiable geometry in
``torchnav.sim``); this is for map authors and tests: "can a robot of radius r
get from anywhere to anywhere in this map?", and for placing illustrative
objects in pictures. Only the fixed obstacles of a :class:`MapSpec` are used.
"""

from __future__ import annotations

import functools
from collections import deque

import numpy as np

from .spec import MapError, MapSpec


def obstacle_distance(spec: MapSpec, xy: np.ndarray) -> np.ndarray:
    """Distance in m from points ``xy`` ``(N, 2)`` to the nearest fixed obstacle, ``(N,)``.

    Negative inside a circle or box (signed distance); walls are lines of zero
    thickness so the distance to them is never negative. ``+inf`` for an empty map.
    """
    return obstacle_distance_arrays(xy, spec.segments, spec.circles, spec.boxes)


def obstacle_distance_arrays(xy: np.ndarray, segments=(), circles=(), boxes=()) -> np.ndarray:
    """:func:`obstacle_distance` for obstacles given as arrays in the layouts of ``World``:
    walls ``(S, 4)``, circles ``(C, 3)``, boxes ``(K, 5)`` (half extents, yaw in rad). ``(N,)`` m."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    best = np.full(len(xy), np.inf)
    if len(segments):
        s = np.asarray(segments, dtype=np.float64).reshape(-1, 4)  # (S, 4)
        a, d = s[:, :2], s[:, 2:] - s[:, :2]
        rel = xy[:, None, :] - a[None]  # (N, S, 2)
        t = np.clip((rel * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(rel - t[..., None] * d, axis=-1).min(1))
    if len(circles):
        c = np.asarray(circles, dtype=np.float64).reshape(-1, 3)
        dist = np.linalg.norm(xy[:, None, :] - c[None, :, :2], axis=-1) - c[None, :, 2]
        best = np.minimum(best, dist.min(1))
    if len(boxes):
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 5)  # (K, 5) cx, cy, hx, hy, yaw
        rel = xy[:, None, :] - b[None, :, :2]
        cos, sin = np.cos(b[:, 4]), np.sin(b[:, 4])
        # Into each box's frame; then the usual signed distance of an axis-aligned rectangle.
        lx = np.abs(rel[..., 0] * cos + rel[..., 1] * sin) - b[:, 2]
        ly = np.abs(-rel[..., 0] * sin + rel[..., 1] * cos) - b[:, 3]
        outside = np.hypot(np.maximum(lx, 0.0), np.maximum(ly, 0.0))
        inside = np.minimum(np.maximum(lx, ly), 0.0)
        best = np.minimum(best, (outside + inside).min(1))
    return best


def free_grid(spec: MapSpec, robot_radius: float, resolution: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells where a disc of ``robot_radius`` m fits, sampled at cell centres every ``resolution`` m.

    Returns ``(free, xs, ys)``: ``free`` is ``(ny, nx)`` bool (row ``j`` is y = ``ys[j]``),
    ``xs`` ``(nx,)`` and ``ys`` ``(ny,)`` the cell centres in m.
    """
    xmin, ymin, xmax, ymax = spec.bounds
    xs = np.arange(xmin + resolution / 2, xmax, resolution)
    ys = np.arange(ymin + resolution / 2, ymax, resolution)
    gx, gy = np.meshgrid(xs, ys)
    d = obstacle_distance(spec, np.stack([gx.ravel(), gy.ravel()], -1)).reshape(gx.shape)
    # The world rectangle bounds the grid even when the map has no boundary walls.
    edge = np.minimum(np.minimum(gx - xmin, xmax - gx), np.minimum(gy - ymin, ymax - gy))
    return (d > robot_radius) & (edge > robot_radius), xs, ys


@functools.lru_cache(maxsize=64)
def check_room(spec: MapSpec, robot_need: float, goal_need: float) -> None:
    """Raise a MapError unless some place lies ``robot_need`` m from every fixed obstacle and the
    world's edge (a start for the robot's disc) and some place ``goal_need`` m from every fixed
    obstacle (a goal). Sampled on a grid of at most about 200 x 200 cells."""
    res = max(0.05, max(spec.size) / 200)
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
