"""Matplotlib drawing of worlds, robots, lidar rays and goals, one env at a time, and run logs.

Every function draws onto an ``ax`` you pass in (or a new pyplot-free ``Figure``) and returns
it; nothing touches pyplot's global state, so it is safe under the Agg backend, in threads and in
notebooks. Inputs may be torch tensors (any device, with or without grad) or numpy arrays."""

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
    if len(boxes):
        import torch

        from .sim.geometry import box_corners

        patches += [Polygon(c, closed=True) for c in box_corners(torch.from_numpy(boxes)).numpy()]
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


def _example_random_objects(spec: MapSpec, n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` layouts of a map's random objects, ``(circles (C, 3), boxes (K, 5))`` each, drawn by the
    task's reset sampler with no start or goal (a picture has none), so only ``margin`` applies."""
    import torch

    from .tasks.sampling import place_random_objects

    far = torch.full((n, 2), 1e6)
    w = place_random_objects(spec.build_world(n), spec, far, far, 32, torch.Generator().manual_seed(seed))
    c0, b0 = spec.n_fixed_circles, spec.n_fixed_boxes
    return [(_np(w.circles[i, c0:])[_np(w.circle_mask[i, c0:])], _np(w.boxes[i, b0:])[_np(w.box_mask[i, b0:])]) for i in range(n)]


def plot_map(spec: MapSpec, ax: Axes | None = None, n_samples: int = 0, seed: int = 0) -> Axes:
    """Draw a map's fixed obstacles, with the random-object counts in the title.

    With ``n_samples > 0`` also draws that many example layouts of the random
    objects (dashed, orange), as the reset sampler places them. Without an
    ``ax`` a new pyplot-free Figure is made; reach it as ``ax.figure``.
    """
    if ax is None:
        from matplotlib.figure import Figure

        w, h = spec.size
        ax = Figure(figsize=(5.0, 5.0 * h / w + 0.4)).add_subplot()
    draw_obstacles(ax, spec.segments, spec.circles, spec.boxes)
    for c, b in _example_random_objects(spec, n_samples, seed) if n_samples > 0 else ():
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


# -- several envs, trajectories, learning curves -----------------------------------------------


def _grid(n: int, ncols: int, panel: float = 3.2):
    from matplotlib.figure import Figure

    ncols = max(1, min(ncols, n))
    nrows = math.ceil(n / ncols)
    fig = Figure(figsize=(panel * ncols, panel * nrows))
    axes = [fig.add_subplot(nrows, ncols, i + 1) for i in range(n)]
    return fig, axes


def plot_envs(
    world: World,
    pose: Any,
    ranges: Any,
    goal: Any,
    lidar: LidarParams,
    robot_radius: float,
    envs: Sequence[int] | None = None,
    ncols: int = 4,
    goal_radius: float | None = None,
    titles: Sequence[str] | None = None,
):
    """Top-down views of several envs of a batch side by side: map, robot, lidar rays, goal.

    ``pose`` ``(B, 3)``, ``ranges`` ``(B, n_rays)``, ``goal`` ``(B, 2)`` in m; ``envs`` the
    indices to show (default: the first 8). Returns a pyplot-free ``Figure``.
    """
    b = _np(pose).reshape(-1, 3).shape[0]
    envs = list(range(min(b, 8))) if envs is None else [int(e) for e in envs]
    fig, axes = _grid(len(envs), ncols)
    for k, (ax, e) in enumerate(zip(axes, envs)):
        draw_world(ax, world, env=e)
        draw_rays(ax, pose, ranges, lidar, env=e)
        draw_goal(ax, goal, env=e, radius=goal_radius)
        draw_robots(ax, pose, robot_radius, env=e)
        ax.set_aspect("equal")
        ax.autoscale_view()
        ax.set_title(titles[k] if titles else f"env {e}", fontsize=9)
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    return fig


def plot_env(env: Any, envs: Sequence[int] | None = None, ncols: int = 4):
    """:func:`plot_envs` of a ``NavEnv``'s current state (call ``env.reset()`` first)."""
    s = env.state
    if s is None:
        raise ValueError("plot_env: the env has no state yet; call env.reset() first")
    return plot_envs(env.task.full_world(s.world), s.sim.pose, s.sim.ranges, s.goal, env.task.params.lidar, env.cfg.robot.radius,
                     envs=envs, ncols=ncols, goal_radius=env.cfg.goal_tolerance)


def plot_trajectories(
    pose: Any,
    world: World | None = None,
    envs: Sequence[int] | None = None,
    done: Any | None = None,
    goal: Any | None = None,
    ax: Axes | None = None,
    env_world: int | None = None,
) -> Axes:
    """Paths of robots over a rollout: ``pose`` ``(B, T, 3)`` (TorchRL layout, e.g. ``td["next", "pose"]``).

    ``done`` ``(B, T)`` or ``(B, T, 1)`` breaks a path where an episode ended (start
    marked with a circle, end with a cross); ``goal`` ``(B, T, 2)`` or ``(B, 2)`` adds
    the goals. The map of ``world`` env ``env_world`` (default: the first shown env)
    is drawn underneath; random objects differ between episodes, so it is only
    exact for one episode. Returns the axes.
    """
    p = _np(pose)
    if p.ndim == 2:
        p = p[None]
    b, t = p.shape[:2]
    envs = list(range(min(b, 8))) if envs is None else [int(e) for e in envs]
    if ax is None:
        from matplotlib.figure import Figure

        ax = Figure(figsize=(5.5, 5.5)).add_subplot()
    if world is not None:
        draw_world(ax, world, env=envs[0] if env_world is None else env_world)
    d = np.zeros((b, t), bool) if done is None else _np(done).reshape(b, t).astype(bool)
    colors = [f"C{i % 10}" for i in range(len(envs))]
    for c, e in zip(colors, envs):
        cuts = np.flatnonzero(d[e]) + 1
        for seg in np.split(np.arange(t), cuts):
            if len(seg) == 0:
                continue
            xy = p[e, seg, :2]
            ax.plot(xy[:, 0], xy[:, 1], "-", color=c, lw=1.2, alpha=0.85)
            ax.plot(xy[0, 0], xy[0, 1], "o", color=c, ms=4)
            if d[e, seg[-1]]:
                ax.plot(xy[-1, 0], xy[-1, 1], "x", color=c, ms=6)
        if goal is not None:
            g = _np(goal)
            g = g[e].reshape(-1, 2)
            ax.plot(g[:, 0], g[:, 1], "*", color=c, ms=10, markeredgecolor="k", linestyle="none")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"trajectories of env{'s' if len(envs) > 1 else ''} {', '.join(map(str, envs))}", fontsize=10)
    return ax


def read_scalars(run_dir: Any) -> dict[str, np.ndarray]:
    """Scalar logs of a run directory: ``{name: (N, 2) [step, value]}``.

    Reads TorchRL's CSV logger layout (``<run>/**/scalars/<name>.csv``, rows
    ``step,value``; names may contain ``/``) and ``*.jsonl`` files of dicts with a
    ``step`` key (every other numeric key becomes a curve).
    """
    import json
    from pathlib import Path

    run = Path(run_dir)
    out: dict[str, list] = {}
    for f in sorted(run.glob("**/scalars/**/*.csv")):
        root = next(p for p in f.parents if p.name == "scalars")
        name = str(f.relative_to(root).with_suffix(""))
        rows = []
        for line in f.read_text().splitlines():
            parts = line.split(",")
            try:
                rows.append((float(parts[0]) if parts[0] not in ("", "None") else len(rows), float(parts[1])))
            except (ValueError, IndexError):
                continue  # header or torn last line
        out[name] = rows
    for f in sorted(run.glob("**/*.jsonl")):
        for i, line in enumerate(f.read_text().splitlines()):
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            step = rec.get("step", i)
            for k, v in rec.items():
                if k != "step" and isinstance(v, (int, float)) and not isinstance(v, bool):
                    out.setdefault(k, []).append((float(step), float(v)))
    return {k: np.asarray(v, dtype=np.float64).reshape(-1, 2) for k, v in out.items() if v}


def plot_learning_curves(run_dir: Any, keys: Sequence[str] | None = None, smooth: int = 1, ncols: int = 3):
    """One panel per logged scalar of a run directory (see :func:`read_scalars`).

    ``keys`` selects and orders the curves (default: all, sorted); ``smooth`` is a
    moving-average window in log points (1: raw). Raises ``FileNotFoundError`` when
    the directory holds no scalar logs. Returns a pyplot-free ``Figure``.
    """
    scalars = read_scalars(run_dir)
    if not scalars:
        raise FileNotFoundError(f"no scalar logs (scalars/*.csv or *.jsonl) under {run_dir}")
    keys = sorted(scalars) if keys is None else [k for k in keys if k in scalars]
    fig, axes = _grid(len(keys), ncols, panel=3.4)
    for ax, k in zip(axes, keys):
        a = scalars[k][np.argsort(scalars[k][:, 0], kind="stable")]
        ax.plot(a[:, 0], a[:, 1], color="0.7" if smooth > 1 else "tab:blue", lw=0.8)
        if smooth > 1 and len(a) >= smooth:
            kern = np.ones(smooth) / smooth
            ax.plot(a[smooth - 1 :, 0], np.convolve(a[:, 1], kern, mode="valid"), color="tab:blue", lw=1.4)
        ax.set_title(k, fontsize=9)
        ax.set_xlabel("step", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig
