"""Summarise a recording, render an episode to GIF or MP4, or draw every episode's path to PNG, without Foxglove.

``python -m torchnav.record.replay FILE.mcap [--env 0 --episode 2 --out ep.gif|ep.mp4] [--out paths.png]``
(MP4 needs ffmpeg; docs/foxglove.md). Navigation episodes show the obstacles, robot, rays, goal
and trail beside the rewards (several robots per env: every robot, its goal, rays and trail in its
colour, and the table lists each robot's outcome); line-following ones the track on a dark floor
and the robot's path, and their summary counts the termination reasons."""

from __future__ import annotations

import argparse
import base64
import json
import math
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from .reader import Episode, Recording, read_recording


_STANDARD_META = ("version", "map", "seed", "checkpoint", "config", "envs", "num_envs", "dt", "lidar", "robot_radius",
                  "goal_tolerance", "reward_terms", "created", "n_robots")
NAV_OUTCOMES = ("success", "collision", "timeout")
LINE_OUTCOMES = ("left_line", "stalled", "collision", "timeout")  # the end reasons of LineEnv, and its time limit


def task_kind(episodes: Sequence[Episode]) -> str:
    """``"multi_nav"`` if the episodes (``Recording.episodes()``) have several robots per env, ``"line"`` if they have
    no goal (a line-following recording), else ``"nav"``."""
    if episodes and all(e.robots is not None for e in episodes):
        return "multi_nav"
    return "line" if episodes and all("goal" not in e.start for e in episodes) else "nav"


def summary(rec: Recording) -> str:
    """A text table of the recording's metadata and episodes."""
    info = rec.info
    eps = rec.episodes()
    kind = task_kind(eps)
    lines = [f"{rec.path}  ({'complete' if rec.complete else 'no summary: the writer was stopped; recovered what was flushed'})"]
    head = [f"task={kind}"] + [f"{'track' if k == 'map' and kind == 'line' else k}={info[k]}"
                               for k in ("map", "seed", "checkpoint", "version", "dt", "created") if info.get(k)]
    lines.append("  " + "  ".join(head))
    extra = [f"{k}={_short(v)}" for k, v in info.items() if k not in _STANDARD_META]  # metadata= entries of the writer
    if extra:
        lines.append("  " + "  ".join(extra))
    lines.append(f"  {len(eps)} episodes, {len(rec.messages)} messages")
    lines.append(f"  {'env':>4} {'ep':>4} {'outcome':>10} {'steps':>6} {'return':>9} {'start [s]':>10}")
    for e in eps:
        lines.append(f"  {e.env:>4} {e.episode:>4} {e.outcome:>10} {e.steps:>6} {e.ret:>9.2f} {e.start_time / 1e9:>10.1f}")
        for r in e.robots or ():  # several robots: the env's row (its team outcome, summed return), then each robot's
            lines.append(f"  {'':>4} {'r' + str(r['robot']):>4} {r['outcome']:>10} {r.get('steps', ''):>6} {r.get('return', float('nan')):>9.2f}")
    outcomes = [e.outcome for e in eps if e.outcome != "incomplete"]
    if outcomes:
        known = LINE_OUTCOMES if kind == "line" else NAV_OUTCOMES
        lines.append(f"  finished episodes: {len(outcomes)} ({_rates(outcomes, known)})")
    robots = [r["outcome"] for e in eps if e.outcome != "incomplete" for r in e.robots or ()]
    if robots:
        team = sum(bool(e.team_success) for e in eps if e.outcome != "incomplete")
        lines.append(f"  team success {team / len(outcomes):.0%}; robots of finished episodes: {len(robots)} ({_rates(robots, NAV_OUTCOMES)})")
    return "\n".join(lines)


def _rates(outcomes: list[str], known: tuple[str, ...]) -> str:
    keys = known + tuple(sorted(set(outcomes) - set(known)))
    return ", ".join(f"{k} {outcomes.count(k) / len(outcomes):.0%}" for k in keys)


def _short(v, n: int = 60) -> str:
    s = v if isinstance(v, str) else json.dumps(v, default=str)
    return s if len(s) <= n else s[: n - 3] + "..."


def episode_frames(rec: Recording, ep: Episode, robot: int | None = None) -> dict[str, np.ndarray]:
    """Arrays of one episode: ``time (N,)`` s, ``pose (N, 3)``, ``ranges (N, R)``, ``reward (N,)`` (0 at the start frame),
    and where recorded ``movers (N, M, 5)`` ``[x, y, vx, vy, radius]`` (the moving discs), ``mover_boxes (N, K, 7)``
    ``[x, y, vx, vy, half_x, half_y, yaw]`` and ``camera (N, H, W, 3)`` uint8 (the start frame, which has none of
    them, repeats the first step's). ``robot``: that robot's arrays, in a recording of several robots per env."""
    t0, t1 = ep.start_time, ep.end_time
    pre = f"/env{ep.env}" + ("" if robot is None else f"/robot{robot}")
    odom = rec.topic(f"{pre}/odom", t0, t1)
    scans = {m.log_time: m.data["ranges"] for m in rec.topic(f"{pre}/scan", t0, t1)}
    rewards = {m.log_time: m.data["reward"] for m in rec.topic(f"{pre}/reward", t0, t1)}
    pose, ranges, reward, times = [], [], [], []
    for m in odom:
        p = m.data["pose"]
        q = p["orientation"]
        pose.append((p["position"]["x"], p["position"]["y"], 2 * math.atan2(q["z"], q["w"])))
        ranges.append(scans.get(m.log_time, []))
        reward.append(rewards.get(m.log_time, 0.0))
        times.append((m.log_time - t0) / 1e9)
    out = {"time": np.asarray(times), "pose": np.asarray(pose).reshape(-1, 3), "ranges": np.asarray(ranges, dtype=float),
           "reward": np.asarray(reward)}
    moving = rec.topic(f"{pre}/movers", t0, t1)
    movers = {m.log_time: np.asarray(m.data["discs"], dtype=float).reshape(-1, 5) for m in moving}
    boxes = {m.log_time: np.asarray(m.data["boxes"], dtype=float).reshape(-1, 7) for m in moving if "boxes" in m.data}
    images = {m.log_time: m.data for m in rec.topic(f"{pre}/camera", t0, t1)}
    for key, per_time, decode in (("movers", movers, lambda a: a), ("mover_boxes", boxes, lambda a: a), ("camera", images, _decode_rgb)):
        if per_time:
            first = per_time[min(per_time)]
            out[key] = np.stack([decode(per_time.get(m.log_time, first)) for m in odom])
    return out


def _decode_rgb(msg: dict) -> np.ndarray:
    """A ``foxglove.RawImage`` (``rgb8``) message as an ``(H, W, 3)`` uint8 array."""
    data = np.frombuffer(base64.b64decode(msg["data"]), dtype=np.uint8)
    return data.reshape(msg["height"], msg["step"])[:, : 3 * msg["width"]].reshape(msg["height"], msg["width"], 3)


def scene_lines(rec: Recording, ep: Episode) -> dict[str, dict]:
    """Static line entities of the episode's first ``/env{i}/scene`` other than walls and trail (e.g. the
    line-following ``track``, a LINE_LIST of ``scene.line_list``): name -> ``{"segments": (S, 4) m,
    "thickness": m, "color": (r, g, b, a)}``."""
    scenes = rec.topic(f"/env{ep.env}/scene", ep.start_time, ep.end_time)
    out: dict[str, dict] = {}
    for ent in scenes[0].data.get("entities", []) if scenes else []:
        if ent.get("id") in ("walls", "trail") or not ent.get("lines"):
            continue
        for k, ln in enumerate(ent["lines"]):
            seg = np.asarray([(p["x"], p["y"]) for p in ln.get("points", [])], dtype=float).reshape(-1, 4)  # point pairs
            c = ln.get("color", {})
            out[ent["id"] if k == 0 else f"{ent['id']}.{k}"] = {
                "segments": seg, "thickness": float(ln.get("thickness", 0.02)),
                "color": tuple(float(c.get(x, 1.0)) for x in ("r", "g", "b", "a"))}
    return out


def _distance_sensor_on(info: dict) -> bool:
    """The line task's forward distance sensor is on (LineConfig in ``config``, or a recipe config's ``task``)."""
    cfg = info.get("config") or {}
    for d in (cfg, cfg.get("task") or {}) if isinstance(cfg, dict) else ():
        ds = d.get("distance_sensor") if isinstance(d, dict) else None
        if isinstance(ds, dict) and ds.get("enabled"):
            return True
    return False


def _lidar(info: dict):
    from ..sim.params import LidarParams

    li = info.get("lidar") or {}
    return LidarParams(n_rays=int(li.get("n_rays", 20)), fov=float(li.get("fov", math.pi)), min_range=float(li.get("min_range", 0.0)),
                       max_range=float(li.get("max_range", 10.0)), offset=tuple(li.get("offset", (0.0, 0.0, 0.0))),
                       noise_std=0.0, scan="rays", window=0, dense_slots=1)  # the drawing reads only the ray layout


def render_episode(rec: Recording, ep: Episode, out: str | Path, fps: float = 10.0, stride: int = 1, dpi: int = 80) -> Path:
    """Animate episode ``ep`` of ``rec`` to ``out`` (.gif with Pillow, .mp4 with ffmpeg); with several robots per
    env, every robot with its goal, rays and trail in its colour, and the team's reward."""
    from matplotlib import animation
    from matplotlib.figure import Figure

    from matplotlib.collections import LineCollection

    from ..render import draw_goal, draw_obstacles, draw_rays, draw_robots
    from .scene import ROBOT_PALETTE

    out = Path(out)
    info = rec.info
    lidar = _lidar(info)
    radius = float(info.get("robot_radius", 0.2))
    tol = float(info.get("goal_tolerance", 0.3))
    robots = [r["robot"] for r in ep.robots] if ep.robots is not None else [None]  # None: the env's only robot
    frs = [episode_frames(rec, ep, j) for j in robots]
    fr = frs[0]  # the time axis, movers and camera (one robot per env)
    if len(fr["pose"]) == 0:
        raise ValueError(f"episode {ep.episode} of env {ep.env} has no frames in {rec.path}")
    world = ep.start["world"]
    goal = np.asarray(ep.start.get("goal", ep.start.get("goals", [])), dtype=float).reshape(-1, 2)  # one per robot
    line_task = len(goal) == 0  # line following: track, path and robot on a dark floor; rays only for the distance sensor
    show_rays = not line_task or _distance_sensor_on(info)
    tapes = scene_lines(rec, ep)
    idx = list(range(0, len(fr["pose"]), max(1, stride)))
    if idx[-1] != len(fr["pose"]) - 1:
        idx.append(len(fr["pose"]) - 1)

    cam = fr.get("camera")
    fig = Figure(figsize=(9 if cam is None else 13, 4.5), dpi=dpi)
    n_panels = 2 if cam is None else 3
    ax, axr = fig.add_subplot(1, n_panels, 1), fig.add_subplot(1, n_panels, 2)
    axc = fig.add_subplot(1, n_panels, 3) if cam is not None else None
    axr2 = axr.twinx()
    pts = np.concatenate([np.asarray(world["segments"], dtype=float).reshape(-1, 2), *(f["pose"][:, :2] for f in frs), goal,
                          *(t["segments"].reshape(-1, 2) for t in tapes.values())])
    pad = 0.15 if line_task else 0.5
    lo, hi = pts.min(0) - pad, pts.max(0) + pad
    reward = np.sum([f["reward"] for f in frs], 0)  # several robots: the team's
    cum = np.cumsum(reward)
    colors = ["tab:orange" if line_task else "tab:blue"] if robots == [None] else [ROBOT_PALETTE[j % len(ROBOT_PALETTE)] for j in robots]

    def draw(k: int):
        i = idx[k]
        ax.clear()
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        if tapes:  # drawn at their true width in m: points per m of the laid-out axes
            ax.apply_aspect()
            pts_per_m = ax.get_window_extent().width / (hi[0] - lo[0]) * 72 / fig.dpi
            for t in tapes.values():
                ax.add_collection(LineCollection(t["segments"].reshape(-1, 2, 2), colors=[t["color"]],
                                                 linewidths=max(t["thickness"] * pts_per_m, 0.5), capstyle="round", zorder=1))
        if line_task:
            ax.set_facecolor("0.25")
        draw_obstacles(ax, world["segments"], world["circles"], world["boxes"])
        if len(goal) == 1:
            draw_goal(ax, goal, env=0, radius=tol)
        elif len(goal):
            for g, c in zip(goal, colors):
                draw_goal(ax, g[None], env=0, radius=tol, color=c)
        for f, c in zip(frs, colors):
            ax.plot(f["pose"][: i + 1, 0], f["pose"][: i + 1, 1], "-", color=c, lw=1.2, alpha=0.8, zorder=3)
            if show_rays and f["ranges"].ndim == 2 and f["ranges"].shape[1] == lidar.n_rays:
                draw_rays(ax, f["pose"][i : i + 1], f["ranges"][i : i + 1], lidar, env=0)
        if "movers" in fr:
            boxes = fr["mover_boxes"][i][:, [0, 1, 4, 5, 6]] if "mover_boxes" in fr else np.zeros((0, 5))
            draw_obstacles(ax, np.zeros((0, 4)), fr["movers"][i][:, [0, 1, 4]], boxes, color="#d23c3c")
        if robots == [None]:
            draw_robots(ax, fr["pose"][i : i + 1], radius, env=0)
        else:
            for f, c in zip(frs, colors):
                draw_robots(ax, f["pose"][i : i + 1], radius, env=0, color=c)
        if axc is not None:
            axc.clear()
            axc.imshow(cam[i], interpolation="nearest")
            axc.set(xticks=[], yticks=[], title="camera")
        ax.set_title(f"env {ep.env} episode {ep.episode}: {ep.outcome}  t={fr['time'][i]:.1f} s", fontsize=9)
        axr.clear()
        axr.plot(fr["time"], reward, color="0.6", lw=1, label="reward")
        axr.plot(fr["time"][: i + 1], reward[: i + 1], color="tab:red", lw=1.2)
        axr2.clear()
        axr2.plot(fr["time"][: i + 1], cum[: i + 1], color="tab:purple", lw=1.2)
        axr2.set_ylim(min(cum.min(), 0) - 1e-3, max(cum.max(), 0) + 1e-3)
        axr2.set_ylabel("return", color="tab:purple", fontsize=8)
        axr.axvline(fr["time"][i], color="k", lw=0.8)
        axr.set_xlabel("time in episode [s]")
        axr.set_ylabel("reward per step" if robots == [None] else "team reward per step (sum)", color="tab:red", fontsize=8)
        axr.set_xlim(0, max(fr["time"][-1], 1e-3))
        return []

    draw(len(idx) - 1)
    fig.tight_layout()
    anim = animation.FuncAnimation(fig, draw, frames=len(idx), blit=False)
    if out.suffix.lower() == ".gif":
        writer = animation.PillowWriter(fps=fps)
    elif out.suffix.lower() in (".mp4", ".m4v", ".mov"):
        if not animation.FFMpegWriter.isAvailable():
            raise RuntimeError("MP4 output needs ffmpeg on the PATH; install it, or write a .gif instead")
        writer = animation.FFMpegWriter(fps=fps)
    else:
        raise ValueError(f"unknown animation format {out.suffix!r}: use .gif or .mp4")
    out.parent.mkdir(parents=True, exist_ok=True)
    anim.save(str(out), writer=writer, dpi=dpi)
    return out


def plot_episodes(rec: Recording, out: str | Path, episodes: Sequence[Episode] | None = None, ncols: int = 4, dpi: int = 100) -> Path:
    """A PNG of whole episodes side by side (default: every episode of ``rec``): each panel shows the episode's
    obstacles (and track), goal and the path driven, start marked with a circle and end with a cross, titled with
    its outcome and length; several robots per env: every robot's path and goal in its colour."""
    from matplotlib.figure import Figure

    from ..render import draw_goal, draw_obstacles
    from .scene import ROBOT_PALETTE

    eps = [e for e in (rec.episodes() if episodes is None else episodes)]
    if not eps:
        raise ValueError(f"{rec.path} has no episodes to draw")
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ValueError(f"a picture of episodes is a .png, got {out.name!r}")
    tol = float(rec.info.get("goal_tolerance", 0.3))
    ncols = min(ncols, len(eps))
    nrows = -(-len(eps) // ncols)
    fig = Figure(figsize=(3.2 * ncols, 3.3 * nrows), dpi=dpi)
    for k, ep in enumerate(eps):
        ax = fig.add_subplot(nrows, ncols, k + 1)
        robots = [r["robot"] for r in ep.robots] if ep.robots is not None else [None]
        colors = ["tab:blue"] if robots == [None] else [ROBOT_PALETTE[j % len(ROBOT_PALETTE)] for j in robots]
        world = ep.start["world"]
        for t in scene_lines(rec, ep).values():
            for x0, y0, x1, y1 in t["segments"]:
                ax.plot([x0, x1], [y0, y1], "-", color=t["color"][:3], lw=2, alpha=0.6, zorder=1)
        draw_obstacles(ax, world["segments"], world["circles"], world["boxes"])
        goals = np.asarray(ep.start.get("goal", ep.start.get("goals", [])), dtype=float).reshape(-1, 2)
        for j, c in zip(robots, colors):
            xy = episode_frames(rec, ep, j)["pose"][:, :2]
            if len(xy):
                ax.plot(xy[:, 0], xy[:, 1], "-", color=c, lw=1.4, zorder=3)
                ax.plot(xy[0, 0], xy[0, 1], "o", color=c, ms=4, zorder=4)
                ax.plot(xy[-1, 0], xy[-1, 1], "x", color=c, ms=6, zorder=4)
        for g, c in zip(goals, colors):
            draw_goal(ax, g[None], env=0, radius=tol, color=c if len(goals) > 1 else "tab:green")
        ax.set_aspect("equal")
        ax.autoscale_view()
        ax.set(xticks=[], yticks=[])
        ax.set_title(f"env {ep.env} episode {ep.episode}: {ep.outcome}, {ep.steps} steps", fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, bbox_inches="tight")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m torchnav.record.replay", description=__doc__.split("\n\n")[0])
    ap.add_argument("file", help="recording (.mcap)")
    ap.add_argument("--out", help="write an animation of one episode (.gif or .mp4), or a picture of every episode's path (.png)")
    ap.add_argument("--env", type=int, default=None, help="env index (default: the first recorded)")
    ap.add_argument("--episode", type=int, default=0, help="episode number of that env (default 0)")
    ap.add_argument("--fps", type=float, default=10.0)
    ap.add_argument("--stride", type=int, default=1, help="draw every n-th step")
    ap.add_argument("--dpi", type=int, default=80)
    ap.add_argument("--json", action="store_true", help="print the episodes as JSON lines instead of a table")
    args = ap.parse_args(argv)
    if args.out and Path(args.out).suffix.lower() not in (".png", ".gif", ".mp4", ".m4v", ".mov"):
        print(f"error: --out {args.out}: unknown format {Path(args.out).suffix!r}; use .gif or .mp4 (one episode's animation) "
              "or .png (every episode's path)", file=sys.stderr)
        return 2
    try:
        rec = read_recording(args.file)
    except FileNotFoundError:
        print(f"error: no such file: {args.file}", file=sys.stderr)
        return 2
    eps = rec.episodes()
    if args.json:
        for e in eps:
            print(json.dumps({"env": e.env, "episode": e.episode, "outcome": e.outcome, "steps": e.steps, "return": e.ret,
                              "start_time": e.start_time / 1e9}))
    else:
        print(summary(rec))
    if args.out and Path(args.out).suffix.lower() == ".png":
        try:
            print(f"wrote {plot_episodes(rec, args.out, dpi=args.dpi)}")
        except ValueError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
    elif args.out:
        env = args.env if args.env is not None else (eps[0].env if eps else 0)
        match = [e for e in eps if e.env == env and e.episode == args.episode]
        if not match:
            have = sorted({(e.env, e.episode) for e in eps})
            print(f"error: no episode {args.episode} of env {env} in {args.file}; have (env, episode) {have}", file=sys.stderr)
            return 2
        path = render_episode(rec, match[0], args.out, fps=args.fps, stride=args.stride, dpi=args.dpi)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
