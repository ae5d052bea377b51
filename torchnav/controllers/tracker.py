"""Planner plus tracker: A* or RRT-Connect waypoints per env at reset, a batched PID tracker after
(docs/controllers.md, "astar and rrt"). ``PlannerController`` reads the worlds of the env it
drives, so it must be bound first (``controller.bind(env)``; ``torchnav.evaluation`` does it); it
plans for every env whose episode has just started (``("episode", "length") == 0``) or whose goal
changed."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torch import Tensor

from ..config import ConfigError
from ..sim import wrap_angle
from ..tasks import NavConfig
from .base import Controller, check_positive, parse_gains
from .planning import Obstacles, OccupancyGrid, RRTParams, plan_astar, plan_rrt

PLANNERS = ("astar", "rrt")
NO_PATH = ("stop", "go_to_goal")


@dataclass(frozen=True)
class TrackerGains:
    kp: float = 2.0  # 1/s: turn rate per rad of heading error to the carrot point
    ki: float = 0.0  # 1/s^2: turn rate per rad*s of accumulated heading error
    kd: float = 0.05  # 1: turn rate per rad/s of heading-error change
    integral_limit: float = 0.5  # rad*s: anti-windup bound on the accumulated error
    lookahead: float = 0.4  # m: the carrot runs this far ahead of the robot's projection on the current segment
    k_v: float = 1.0  # 1/s: speed = k_v * remaining path length (then capped at v_max), times cos(error)
    corner_speed: float = 0.2  # m/s: speed on arrival at a waypoint where the path turns by corner_angle or more
    corner_angle: float = 0.5  # rad: turns this sharp or sharper are entered at corner_speed; gentler ones faster
    turn_in_place: float = 0.6  # rad: above this heading error the robot turns on the spot
    accept_radius: float = 0.1  # m: a waypoint counts as reached this close (the last one never does)

    def __post_init__(self) -> None:
        check_positive(kp=self.kp, lookahead=self.lookahead, k_v=self.k_v, corner_speed=self.corner_speed, corner_angle=self.corner_angle,
                       turn_in_place=self.turn_in_place, accept_radius=self.accept_radius)
        if self.ki < 0 or self.kd < 0 or self.integral_limit < 0:
            raise ConfigError("ki, kd and integral_limit must be >= 0")


class WaypointTracker:
    """Batched path tracker: a carrot on the current segment, PID on the heading error to it. The
    carrot, the switch to the next segment and the speed limits: docs/controllers.md, "astar and rrt".

    State per env: the path ``(B, W, 2)`` m (row 0 where the robot was when it got the
    path, padded by repeating the last point), its length ``(B,)``, the index of the
    waypoint the robot is heading for (segment ``idx-1 -> idx``), the PID integral and
    last error. At a waypoint where the path turns by ``a`` rad the speed is at most
    ``k_v * distance + corner_speed + v_max * max(0, 1 - a / corner_angle)``.
    """

    def __init__(self, gains: TrackerGains, num_envs: int, dt: float, v_max: float = 1.0, omega_max: float = 1.0,
                 device: Any = "cpu", dtype=torch.float32):
        self.g, self.dt, self.v_max, self.omega_max = gains, dt, v_max, omega_max
        self.wp = torch.zeros(num_envs, 2, 2, device=device, dtype=dtype)
        self.rest = torch.zeros(num_envs, 2, device=device, dtype=dtype)  # path length from point k to the end
        self.bend = torch.zeros(num_envs, 2, device=device, dtype=dtype)  # turn angle (rad) at point k (pi at the last)
        self.count = torch.full((num_envs,), 2, dtype=torch.long, device=device)
        self.idx = torch.ones(num_envs, dtype=torch.long, device=device)
        self.integral = torch.zeros(num_envs, device=device, dtype=dtype)
        self.prev = torch.zeros(num_envs, device=device, dtype=dtype)
        self.fresh = torch.ones(num_envs, dtype=torch.bool, device=device)

    def set_paths(self, envs: list[int], paths: list[np.ndarray]) -> None:
        """Give env ``envs[k]`` the path ``paths[k]`` ``(N_k, 2)`` m, ``N_k >= 2``, from where the
        robot is now to the goal."""
        width = max([self.wp.shape[1]] + [len(p) for p in paths])
        if width > self.wp.shape[1]:  # widen the padding, repeating each env's last point
            pad = width - self.wp.shape[1]
            self.wp = torch.cat((self.wp, self.wp[:, -1:].expand(-1, pad, -1)), 1)
            self.rest = torch.cat((self.rest, self.rest.new_zeros(self.rest.shape[0], pad)), 1)
            self.bend = torch.cat((self.bend, self.bend.new_full((self.bend.shape[0], pad), math.pi)), 1)
        for e, p in zip(envs, paths):
            p = torch.as_tensor(np.asarray(p, np.float64).reshape(-1, 2), dtype=self.wp.dtype, device=self.wp.device)
            if len(p) < 2:
                raise ValueError(f"set_paths: env {e} needs a path of at least 2 points (robot position, goal), got {len(p)}")
            seg = (p[1:] - p[:-1]).norm(dim=-1)  # (N-1,)
            u = (p[1:] - p[:-1]) / seg.clamp(min=1e-9)[:, None]
            turn = torch.acos((u[:-1] * u[1:]).sum(-1).clamp(-1.0, 1.0))
            bend = torch.cat((seg.new_zeros(1), turn, seg.new_full((1,), math.pi)))
            rest = torch.cat((seg.flip(0).cumsum(0).flip(0), seg.new_zeros(1)))
            fill = width - len(p)
            self.wp[e] = torch.cat((p, p[-1:].expand(fill, 2)))
            self.rest[e] = torch.cat((rest, rest.new_zeros(fill)))
            self.bend[e] = torch.cat((bend, bend.new_full((fill,), math.pi)))
            self.count[e] = len(p)
        idx = torch.as_tensor(envs, dtype=torch.long, device=self.wp.device)
        self.idx[idx] = 1
        self.integral[idx] = 0.0
        self.fresh[idx] = True

    def _at(self, t: Tensor, offset: int = 0) -> Tensor:
        k = (self.idx + offset)[:, None]
        return t.gather(1, k[..., None].expand(-1, 1, 2))[:, 0] if t.dim() == 3 else t.gather(1, k)[:, 0]

    def current(self) -> Tensor:
        """The waypoint each env is heading for, ``(B, 2)`` m."""
        return self._at(self.wp)

    def carrot(self, xy: Tensor) -> tuple[Tensor, Tensor]:
        """Carrot points ``(B, 2)`` m for robot positions ``xy`` ``(B, 2)``, and the robot's
        progress ``(B,)`` along the current segment (1 at the waypoint)."""
        a, b = self._at(self.wp, -1), self.current()
        ab = b - a
        length = ab.norm(dim=-1).clamp(min=1e-9)
        t = ((xy - a) * ab).sum(-1) / length**2
        return a + ab * (t.clamp(min=0.0) + self.g.lookahead / length).clamp(max=1.0)[:, None], t

    def __call__(self, pose: Tensor) -> tuple[Tensor, Tensor]:
        """Twist ``(v m/s, omega rad/s)``, each ``(B,)``, for poses ``(B, 3)``; advances waypoints."""
        g = self.g
        _, t = self.carrot(pose[:, :2])
        d = (self.current() - pose[:, :2]).norm(dim=-1)
        advance = ((d < g.accept_radius) | (t >= 1.0)) & (self.idx < self.count - 1)
        self.idx = self.idx + advance.long()
        self.fresh |= advance
        target, _ = self.carrot(pose[:, :2])
        delta = target - pose[:, :2]
        err = wrap_angle(torch.atan2(delta[:, 1], delta[:, 0]) - pose[:, 2])
        deriv = torch.where(self.fresh, torch.zeros_like(err), wrap_angle(err - self.prev) / self.dt)
        self.integral = torch.where(self.fresh, torch.zeros_like(err), self.integral + err * self.dt)
        self.integral = self.integral.clamp(-g.integral_limit, g.integral_limit)
        self.prev, self.fresh = err, torch.zeros_like(self.fresh)
        omega = g.kp * err + g.ki * self.integral + g.kd * deriv
        d = (self.current() - pose[:, :2]).norm(dim=-1)
        remaining = d + self._at(self.rest)
        corner = g.k_v * d + g.corner_speed + self.v_max * (1.0 - self._at(self.bend) / g.corner_angle).clamp(min=0.0)
        v = torch.minimum(g.k_v * remaining, corner) * torch.cos(err).clamp(min=0.0)
        v = torch.minimum(v, self.omega_max * delta.norm(dim=-1) / (2.0 * torch.sin(err).abs()).clamp(min=1e-6))
        return torch.where(err.abs() > g.turn_in_place, torch.zeros_like(v), v), omega


@dataclass(frozen=True)
class PlannerGains:
    planner: str = "astar"  # "astar" (occupancy grid) or "rrt" (RRT-Connect in continuous space)
    resolution: float = 0.1  # m: A* grid cell size
    margins: tuple[float, ...] = (0.1, 0.03)  # m added to the robot radius to inflate obstacles; tried in order until a path is found
    snap: float = 0.5  # m: A* moves a blocked start/goal to the nearest free cell within this distance
    rrt_step: float = 0.5  # m: longest RRT edge
    rrt_max_iters: int = 3000  # RRT iterations per margin before reporting no path
    rrt_check_step: float = 0.05  # m: spacing of RRT collision checks along an edge
    seed: int = 0  # RRT sampling seed (combined with each query, so a scenario always gets the same plan)
    no_path: str = "stop"  # "stop" (stand still until the episode times out) or "go_to_goal" (drive straight at it)
    tracker: TrackerGains = field(default_factory=TrackerGains)

    def __post_init__(self) -> None:
        if self.planner not in PLANNERS:
            raise ConfigError(f"planner must be one of {PLANNERS}, got {self.planner!r}")
        if self.no_path not in NO_PATH:
            raise ConfigError(f"no_path must be one of {NO_PATH}, got {self.no_path!r}")
        if not self.margins or min(self.margins) < 0:
            raise ConfigError(f"margins must be a non-empty list of values >= 0 m, got {self.margins!r}")
        check_positive(resolution=self.resolution, rrt_step=self.rrt_step, rrt_check_step=self.rrt_check_step, rrt_max_iters=self.rrt_max_iters)


class PlannerController(Controller):
    """Plan at reset (A* or RRT-Connect on the env's actual world, inflated), track with PID.

    Without a path (``plan`` returned None for every margin) the env does what
    ``gains.no_path`` says. ``stats`` counts plans, failures and planning seconds.
    """

    in_keys = ["pose", "goal", "ranges", ("episode", "length")]

    planner = "astar"  # the planner of this class; gains may not name another

    def __init__(self, gains: PlannerGains | dict | None = None, nav: NavConfig | None = None):
        super().__init__(nav)
        if gains is None or isinstance(gains, dict):
            gains = {"planner": self.planner, **(gains or {})}
        self.gains = parse_gains(PlannerGains, gains, self.planner)
        if self.gains.planner != self.planner:
            raise ConfigError(f"{self.planner}: gains name planner {self.gains.planner!r}; use the {self.gains.planner!r} controller instead")
        self._env = None
        self.stats = {"plans": 0, "no_path": 0, "seconds": 0.0}

    def bind(self, env: Any) -> "PlannerController":
        """Drive ``env`` (a ``NavEnv``, or anything with ``cfg``, ``num_envs``, ``state.world``
        and ``task.spec``): adopt its config and cache the grid of its map's fixed obstacles."""
        spec = env.task.spec
        if spec is None:
            raise ValueError(f"the {self.planner} planner needs a map's fixed obstacles; it does not run on procedural worlds (worlds.families)")
        super().bind(env)
        self._env = env
        self._bounds = spec.bounds
        self._n_fixed = (spec.n_fixed_circles, spec.n_fixed_boxes)
        # the map's fixed obstacles and, for A*, their clearance grid (built once; each env adds its random ones)
        self.fixed = Obstacles(*(np.asarray(x, np.float64).reshape(-1, w) for x, w in
                                  ((spec.segments, 4), (spec.circles, 3), (spec.boxes, 5))), spec.bounds)
        self.fixed_grid = OccupancyGrid.build(self.fixed, self.gains.resolution) if self.gains.planner == "astar" else None
        n = env.num_envs
        self.tracker = WaypointTracker(self.gains.tracker, n, self.dt, v_max=self.v_max, omega_max=self.omega_max, device=env.device)
        self._goal = torch.full((n, 2), float("nan"), device=env.device)
        self._has_path = torch.zeros(n, dtype=torch.bool, device=env.device)
        return self

    def env_obstacles(self, world, e: int) -> tuple[Obstacles, Obstacles]:
        """All obstacles of env ``e`` of a CPU ``World``, and only its randomly placed ones."""
        nc, nb = self._n_fixed
        seg = world.segments[e][world.segment_mask[e]].double().numpy()
        circ, cm = world.circles[e].double().numpy(), world.circle_mask[e].numpy()
        box, bm = world.boxes[e].double().numpy(), world.box_mask[e].numpy()
        rand = Obstacles(np.zeros((0, 4)), circ[nc:][cm[nc:]], box[nb:][bm[nb:]], self._bounds)
        return Obstacles(seg, circ[cm], box[bm], self._bounds), rand

    def grid(self, rand: Obstacles) -> OccupancyGrid:
        """The occupancy grid of one episode: the cached grid of the map's fixed obstacles with the
        episode's random ones stamped in (exact up to the largest inflation plus two cells)."""
        g = self.gains
        window = self.radius + max(g.margins) + 2 * g.resolution
        return OccupancyGrid.build(rand, g.resolution, base=self.fixed_grid.clearance, window=window)

    def plan(self, world, e: int, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """Waypoints ``(N, 2)`` m from ``start`` to ``goal`` in env ``e`` of ``world`` (CPU), or None.

        Tries each inflation ``radius + margin`` of ``gains.margins`` in turn."""
        g = self.gains
        full, rand = self.env_obstacles(world, e)
        grid = None
        if g.planner == "astar":
            grid = self.grid(rand)
        for m in g.margins:
            if g.planner == "astar":
                path = plan_astar(grid, start, goal, self.radius + m, snap=g.snap)
            else:
                params = RRTParams(step=g.rrt_step, max_iters=g.rrt_max_iters, check_step=g.rrt_check_step)
                path = plan_rrt(full, start, goal, self.radius + m, params, seed=g.seed)
            if path is not None:
                return path
        return None

    def _replan(self, envs: list[int], pose: Tensor, goal: Tensor) -> None:
        t0 = time.perf_counter()
        state = self._env.state
        if state is None:
            raise RuntimeError(f"{type(self).__name__}: the bound env has no state; reset it first")
        idx = torch.as_tensor(envs, device=pose.device)
        world = getattr(self._env.task, "full_world", lambda w: w)(state.world[idx]).to("cpu")  # the map's shared obstacles too
        starts, goals = pose[idx, :2].double().cpu().numpy(), goal[idx].double().cpu().numpy()
        paths, ok = [], []
        for k in range(len(envs)):
            path = self.plan(world, k, starts[k], goals[k])
            ok.append(path is not None)
            paths.append(path if path is not None else np.stack([starts[k], goals[k]]))
        self.tracker.set_paths(envs, paths)
        self._has_path[idx] = torch.as_tensor(ok, device=pose.device)
        self._goal[idx] = goal[idx]
        self.stats["plans"] += len(envs)
        self.stats["no_path"] += len(envs) - sum(ok)
        self.stats["seconds"] += time.perf_counter() - t0

    def twist(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        if self._env is None:
            raise RuntimeError(f"{type(self).__name__} is not bound to an env: call controller.bind(env) first "
                               "(torchnav.evaluation.run_episodes does it for you)")
        pose, goal = td.get("pose"), td.get("goal")
        if pose.shape[0] != self._goal.shape[0]:
            raise RuntimeError(f"{type(self).__name__}: bound to {self._goal.shape[0]} envs, got a batch of {pose.shape[0]}")
        need = (goal != self._goal).any(-1)
        length = td.get(("episode", "length"), None)
        if length is not None:
            need |= length.reshape(-1) == 0
        envs = need.nonzero().squeeze(-1).tolist()
        if envs:
            self._replan(envs, pose, goal)
        v, omega = self.tracker(pose)
        if self.gains.no_path == "stop":
            v, omega = torch.where(self._has_path, v, 0.0), torch.where(self._has_path, omega, 0.0)
        return v, omega


class AStarController(PlannerController):
    """A* on an occupancy grid of the env's world, shortcut, then the PID tracker."""

    planner = "astar"


class RRTController(PlannerController):
    """RRT-Connect in continuous space against the env's world, shortcut, then the PID tracker."""

    planner = "rrt"
