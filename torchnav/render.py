"""Matplotlib drawing of worlds, robots, lidar rays and goals, one env at a time.

Every function draws onto an ``ax`` you pass in and returns it; nothing here
touches pyplot's global state, so it is safe under the Agg backend, in threads
and in notebooks. Inputs may be torch tensors (any device, with or without
grad) or numpy arrays. World frame: x right, y up, metres; yaw in radians CCW.

Typical episode plot::

    from matplotlib.figure import Figure
    fig = Figure(figsize=(5, 5)); ax = fig.add_subplot()
    draw_world(ax, world, env=0)
    draw_rays(ax, state.pose, state.ranges, params.lidar, env=0)
    draw_robots(ax, state.pose, params.robot_radius, env=0)
    draw_goal(ax, goal_xy, env=0)
    fig.savefig("episode.png")
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
from matplotlib.collections import LineCollection, PatchCollection
from matplotlib.patches import Circle, Polygon

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from torchnav.maps.spec import MapSpec
    from torchnav.sim.params import LidarParams
    from torchnav.sim.state import World

OBSTACLE_FACE = "0.55"
OBSTACLE_EDGE = "0.15"
ROBOT_COLOR = "tab:blue"
RAY_COLOR = "tab:red"
GOAL_COLOR = "tab:green"
RANDOM_COLOR = "tab:orange"


def _np(x: Any) -> np.ndarray:
    """A float64 numpy copy of a tensor (any device, grad or not) or array-like."""
    if hasattr(x, "detach"):
        x = x.detach().cpu()
        if x.is_floating_point():
            x = x.double()
        return x.numpy()
    return np.asarray(x)


def _envs(env: int | Sequence[int] | None, batch: int) -> list[int]:
    if env is None:
        return list(range(batch))
    if isinstance(env, (int, np.integer)):
        return [int(env)]
    return [int(e) for e in env]


def box_corners(boxes: np.ndarray) -> np.ndarray:
    """Corners ``(K, 4, 2)`` in m of oriented boxes ``(K, 5)`` ``[cx, cy, half_x, half_y, yaw]``, CCW."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 5)
    signs = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64)
    local = signs[None] * boxes[:, None, 2:4]  # (K, 4, 2)
    c, s = np.cos(boxes[:, 4])[:, None], np.sin(boxes[:, 4])[:, None]
    x = boxes[:, None, 0] + c * local[..., 0] - s * local[..., 1]
    y = boxes[:, None, 1] + s * local[..., 0] + c * local[..., 1]
    return np.stack([x, y], -1)


def draw_obstacles(
    ax: Axes,
    segments: np.ndarray = (),
    circles: np.ndarray = (),
    boxes: np.ndarray = (),
    color: str = OBSTACLE_FACE,
    edgecolor: str = OBSTACLE_EDGE,
    linestyle: str = "-",
    alpha: float = 1.0,
) -> Axes:
    """Draw walls ``(S, 4)``, circles ``(C, 3)`` and boxes ``(K, 5)`` given as plain arrays in m."""
    segments = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    circles = np.asarray(circles, dtype=np.float64).reshape(-1, 3)
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 5)
    if len(segments):
        ax.add_collection(
            LineCollection(segments.reshape(-1, 2, 2), colors=edgecolor, linewidths=2.0, linestyles=linestyle, alpha=alpha, zorder=2)
        )
    patches = [Circle((cx, cy), r) for cx, cy, r in circles]
    patches += [Polygon(c, closed=True) for c in box_corners(boxes)]
    if patches:
        ax.add_collection(
            PatchCollection(
                patches, facecolor=color, edgecolor=edgecolor, linewidths=1.0, linestyle=linestyle, alpha=alpha, zorder=2
            )
        )
    return ax


def draw_world(ax: Axes, world: World, env: int = 0, color: str = OBSTACLE_FACE, edgecolor: str = OBSTACLE_EDGE) -> Axes:
    """Draw the masked-in walls, circles and boxes of env ``env`` of a batched :class:`World`."""
    return draw_obstacles(
        ax,
        _np(world.segments[env])[_np(world.segment_mask[env])],
        _np(world.circles[env])[_np(world.circle_mask[env])],
        _np(world.boxes[env])[_np(world.box_mask[env])],
        color=color,
        edgecolor=edgecolor,
    )


def draw_robots(
    ax: Axes, pose: Any, radius: float, env: int | Sequence[int] | None = 0, color: str = ROBOT_COLOR, alpha: float = 0.9
) -> Axes:
    """Draw robots as discs of ``radius`` m with a heading tick, from poses ``(B, 3)`` ``[x, y, theta]``.

    ``env`` is one env index, a list of them, or None for all ``B``.
    """
    pose = _np(pose).reshape(-1, 3)
    idx = _envs(env, len(pose))
    p = pose[idx]
    ax.add_collection(
        PatchCollection([Circle((x, y), radius) for x, y, _ in p], facecolor=color, edgecolor="k", linewidths=1.0, alpha=alpha, zorder=4)
    )
    tips = p[:, :2] + radius * np.stack([np.cos(p[:, 2]), np.sin(p[:, 2])], -1)
    ax.add_collection(LineCollection(np.stack([p[:, :2], tips], 1), colors="k", linewidths=1.5, zorder=5))
    return ax


def draw_rays(
    ax: Axes, pose: Any, ranges: Any, lidar: LidarParams, env: int = 0, color: str = RAY_COLOR, alpha: float = 0.5
) -> Axes:
    """Draw the lidar rays of env ``env``: ``pose`` ``(B, 3)``, ``ranges`` ``(B, n_rays)`` in m.

    Rays start at the sensor (``lidar.offset`` in the robot frame) and point at
    ``theta + offset_yaw + lidar.angles()[i]``; returns shorter than
    ``max_range`` get a dot at the hit point.
    """
    x, y, th = _np(pose).reshape(-1, 3)[env]
    r = _np(ranges).reshape(-1, lidar.n_rays)[env]
    ox, oy, oyaw = lidar.offset
    sx, sy = x + math.cos(th) * ox - math.sin(th) * oy, y + math.sin(th) * ox + math.cos(th) * oy
    ang = th + oyaw + np.asarray(lidar.angles())
    ends = np.stack([sx + r * np.cos(ang), sy + r * np.sin(ang)], -1)
    starts = np.broadcast_to(np.array([sx, sy]), ends.shape)
    ax.add_collection(LineCollection(np.stack([starts, ends], 1), colors=color, linewidths=0.7, alpha=alpha, zorder=3))
    hit = r < lidar.max_range - 1e-6
    if hit.any():
        ax.plot(ends[hit, 0], ends[hit, 1], ".", color=color, markersize=3, zorder=3)
    return ax


def draw_goal(
    ax: Axes, goal_xy: Any, env: int | Sequence[int] | None = 0, radius: float | None = None, color: str = GOAL_COLOR
) -> Axes:
    """Draw goals ``(B, 2)`` in m as stars; with ``radius`` (m, the goal tolerance) also a dashed circle."""
    g = _np(goal_xy).reshape(-1, 2)
    g = g[_envs(env, len(g))]
    ax.plot(g[:, 0], g[:, 1], "*", color=color, markersize=12, markeredgecolor="k", zorder=6)
    if radius is not None:
        ax.add_collection(
            PatchCollection([Circle(p, radius) for p in g], facecolor="none", edgecolor=color, linestyle="--", zorder=6)
        )
    return ax


def _example_random_objects(spec: MapSpec, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One illustrative layout of a map's random objects: ``(circles (C, 3), boxes (K, 5))``.

    A plain rejection sampler on bounding circles that honours ``margin`` but not
    ``clearance`` (a picture has no start or goal). The task's reset sampler
    is the one that matters for training; this only shows sizes and counts.
    """
    from torchnav.maps.free_space import obstacle_distance

    xmin, ymin, xmax, ymax = spec.bounds
    placed: list[tuple[float, float, float]] = []  # bounding circles of accepted objects
    circles, boxes = [], []
    wanted = []
    if spec.random_boxes:
        wanted += [("box", spec.random_boxes)] * spec.random_boxes.count
    if spec.random_circles:
        wanted += [("circle", spec.random_circles)] * spec.random_circles.count
    for kind, cfg in wanted:
        if kind == "box":
            hx, hy = rng.uniform(*cfg.size_x) / 2, rng.uniform(*cfg.size_y) / 2
            yaw, r_bound = rng.uniform(*cfg.yaw), math.hypot(hx, hy)
        else:
            r_bound = rng.uniform(*cfg.radius)
        for _ in range(2000):
            p = rng.uniform([xmin + r_bound, ymin + r_bound], [xmax - r_bound, ymax - r_bound])
            if obstacle_distance(spec, p[None])[0] < r_bound + cfg.margin:
                continue
            if any(math.hypot(p[0] - q[0], p[1] - q[1]) < r_bound + q[2] + cfg.margin for q in placed):
                continue
            placed.append((p[0], p[1], r_bound))
            if kind == "box":
                boxes.append((p[0], p[1], hx, hy, yaw))
            else:
                circles.append((p[0], p[1], r_bound))
            break
    return np.asarray(circles).reshape(-1, 3), np.asarray(boxes).reshape(-1, 5)


def plot_map(spec: MapSpec, ax: Axes | None = None, n_samples: int = 0, seed: int = 0) -> Axes:
    """Draw a map's fixed obstacles, with the random-object counts in the title.

    With ``n_samples > 0`` also draws that many example layouts of the random
    objects (dashed, orange; see :func:`_example_random_objects`). Without an
    ``ax`` a new pyplot-free Figure is made; reach it as ``ax.figure``.
    """
    if ax is None:
        from matplotlib.figure import Figure

        w, h = spec.size
        ax = Figure(figsize=(5.0, 5.0 * h / w + 0.4)).add_subplot()
    draw_obstacles(ax, spec.segments, spec.circles, spec.boxes)
    rng = np.random.default_rng(seed)
    for _ in range(n_samples):
        c, b = _example_random_objects(spec, rng)
        draw_obstacles(ax, (), c, b, color=RANDOM_COLOR, edgecolor=RANDOM_COLOR, linestyle="--", alpha=0.6)
    xmin, ymin, xmax, ymax = spec.bounds
    pad = 0.02 * max(xmax - xmin, ymax - ymin)
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    extras = []
    if spec.random_boxes and spec.random_boxes.count:
        extras.append(f"{spec.random_boxes.count} boxes")
    if spec.random_circles and spec.random_circles.count:
        extras.append(f"{spec.random_circles.count} circles")
    title = f"{spec.name} ({spec.size[0]:g} x {spec.size[1]:g} m)"
    if extras:
        title += "\nrandom per reset: " + ", ".join(extras) + (" (dashed)" if n_samples else "")
    ax.set_title(title, fontsize=10)
    return ax
