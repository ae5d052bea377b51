"""ORCA for several differential-drive robots: a decentralised classical baseline of the multi-robot
task (docs/multi_robot.md, "The classical baseline"; docs/controllers.md, "orca").

Every robot, on its own, picks the velocity nearest to its preferred one that keeps it clear of what it
knows about, in the sense of optimal reciprocal collision avoidance (van den Berg et al. 2011, RVO2's
``computeNewVelocity``). The preferred velocity points at the goal, or, where the lidar shows that way
blocked, along the open heading nearest to it (``Reactive.steer``, on the scan without the other
robots), and turns ``keep_right`` clockwise while it would hit another robot within ``time_horizon``:
a shared rule that breaks the symmetric head-on deadlock of ORCA without randomness. What it avoids:

- **Other robots** (its ``neighbours`` nearest within ``sensing_range``, from their positions and
  velocities) are reciprocal agents: each pair shares the avoidance half and half, over ``time_horizon``.
  A parked robot (at its goal or crashed) no longer moves, so the robot takes all of it.
- **Static obstacles** are its own lidar's returns, the ``obstacle_points`` nearest, each a point the
  robot takes all of over ``obstacle_horizon``. Returns on another robot's disc are left out (that
  robot is already an agent), as are rays that hit nothing.

Each neighbour or point gives one half-plane of allowed velocities; with the disc ``|v| <= v_max`` they
form a small 2-D program, solved exactly and batched: the nearest feasible velocity to the preferred
one is the preferred velocity itself, its projection onto one constraint line, or a vertex (two lines,
or a line and the disc), so every such candidate is built and checked at once and the nearest feasible
one taken. When none is feasible (crowded), the candidate, among those and a polar grid, with the
smallest worst violation is taken: RVO2's fallback (its ``linearProgram3``) on a finite set.

The holonomic velocity is then tracked by the differential drive: turn towards it (on the spot while
the heading error exceeds ``turn_in_place``) and drive at its speed times ``cos(error)``. The robot
radius is enlarged by ``margin`` for the tracking error this leaves (the idea of NH-ORCA,
Alonso-Mora et al. 2010, without its exact error bound).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from torch import Tensor

from ..config import ConfigError
from ..sim import wrap_angle
from ..tasks import MultiNavConfig, NavConfig
from .base import Controller, check_positive, parse_gains
from .reactive import Reactive


@dataclass(frozen=True)
class ORCAGains:
    time_horizon: float = 2.0  # s: robots avoid collisions with each other this far ahead
    obstacle_horizon: float = 1.0  # s: ... and with lidar returns this far ahead
    margin: float = 0.1  # m: added to the robot radius, for the differential drive's tracking error
    neighbours: int = 6  # other robots each robot avoids, nearest first
    sensing_range: float = 4.0  # m: robots farther than this (centre to centre) are ignored
    obstacle_points: int = 6  # nearest lidar returns taken as static obstacles
    k_v: float = 1.0  # 1/s: preferred speed = k_v * goal distance, capped at v_max
    lookahead: float = 1.2  # m: the preferred heading must be free of lidar returns this far (the reactive controller's test)
    k_omega: float = 2.0  # 1/s: turn rate per rad of heading error to the chosen velocity
    turn_in_place: float = 0.8  # rad: above this heading error the robot turns on the spot
    grid: int = 16  # directions of the polar grid of fallback candidates (3 speeds each)
    keep_right: float = 0.3  # rad: the preferred velocity turns this far clockwise while it would hit a robot within time_horizon

    def __post_init__(self) -> None:
        check_positive(time_horizon=self.time_horizon, obstacle_horizon=self.obstacle_horizon, sensing_range=self.sensing_range,
                       k_v=self.k_v, lookahead=self.lookahead, k_omega=self.k_omega, turn_in_place=self.turn_in_place)
        for k in ("neighbours", "obstacle_points", "grid"):
            v = getattr(self, k)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ConfigError(f"{k} must be a whole number >= 0, got {v!r}")
        if not self.margin >= 0:
            raise ConfigError(f"margin must be >= 0, got {self.margin!r}")
        if not 0 <= self.keep_right < math.pi / 2:
            raise ConfigError(f"keep_right must be in [0, pi/2) rad, got {self.keep_right!r}")


def orca_half_planes(rel_pos: Tensor, rel_vel: Tensor, vel: Tensor, radius: Tensor, share: Tensor, horizon: Tensor,
                     dt: float) -> tuple[Tensor, Tensor]:
    """ORCA's half-plane of each (robot, other) pair, RVO2's construction.

    ``rel_pos`` ``(..., K, 2)`` m: the other's position minus the robot's; ``rel_vel`` ``(..., K, 2)`` m/s:
    the robot's velocity minus the other's; ``vel`` ``(..., 1, 2)`` the robot's velocity; ``radius``
    ``(..., K)`` m: the sum of both radii; ``share`` ``(..., K)``: the robot's part of the avoidance
    (0.5 reciprocal, 1 static); ``horizon`` ``(..., K)`` s. Returns ``point`` and unit ``normal``
    ``(..., K, 2)``: allowed are the velocities ``v`` with ``normal . (v - point) >= 0``. Pairs already
    in contact are pushed apart within one step ``dt`` s."""
    dist_sq = (rel_pos**2).sum(-1)
    r_sq = radius**2
    inv_t = 1.0 / horizon
    # Not in contact: the velocity obstacle is the cone of the other's disc truncated at t = horizon.
    w = rel_vel - inv_t[..., None] * rel_pos  # from the truncation circle's centre to the relative velocity
    w_len = torch.linalg.vector_norm(w, dim=-1).clamp(min=1e-9)
    dot = (w * rel_pos).sum(-1)
    on_circle = (dot < 0) & (dot**2 > r_sq * w_len**2)
    unit_w = w / w_len[..., None]
    u_circle = ((radius * inv_t - w_len)[..., None]) * unit_w
    leg = (dist_sq - r_sq).clamp(min=0.0).sqrt()
    px, py = rel_pos[..., 0], rel_pos[..., 1]
    left = (px * w[..., 1] - py * w[..., 0]) > 0
    d_left = torch.stack((px * leg - py * radius, px * radius + py * leg), -1)
    d_right = -torch.stack((px * leg + py * radius, -px * radius + py * leg), -1)
    direction = torch.where(left[..., None], d_left, d_right) / dist_sq.clamp(min=1e-12)[..., None]
    u_leg = (rel_vel * direction).sum(-1, keepdim=True) * direction - rel_vel
    n_leg = torch.stack((-direction[..., 1], direction[..., 0]), -1)  # the leg's outward side
    # In contact: leave the other's disc within one step.
    wc = rel_vel - rel_pos / dt
    wc_len = torch.linalg.vector_norm(wc, dim=-1).clamp(min=1e-9)
    unit_wc = wc / wc_len[..., None]
    u_contact = ((radius / dt - wc_len)[..., None]) * unit_wc
    contact = dist_sq <= r_sq
    u = torch.where(contact[..., None], u_contact, torch.where(on_circle[..., None], u_circle, u_leg))
    normal = torch.where(contact[..., None], unit_wc, torch.where(on_circle[..., None], unit_w, n_leg))
    return vel + share[..., None] * u, normal


def solve_velocities(pref: Tensor, point: Tensor, normal: Tensor, valid: Tensor, v_max: float, grid: int) -> Tensor:
    """The velocity ``(M, 2)`` nearest to ``pref`` ``(M, 2)`` within ``|v| <= v_max`` and the half-planes
    ``normal . (v - point) >= 0`` (``(M, K, 2)``; only where ``valid`` ``(M, K)``), by checking every
    candidate where the optimum can lie (see the module docstring); the least-violating candidate of
    those and a ``grid``-direction polar grid where no velocity is feasible."""
    m, k = valid.shape
    pref = pref * (v_max / torch.linalg.vector_norm(pref, dim=-1, keepdim=True).clamp(min=v_max))  # into the disc
    offset = (normal * point).sum(-1)  # the line is normal . v = offset
    # projections of pref onto each line
    proj = pref[:, None] + (offset - (normal * pref[:, None]).sum(-1))[..., None] * normal
    # intersections of two lines
    i, j = torch.triu_indices(k, k, 1, device=pref.device)
    n1, n2, c1, c2 = normal[:, i], normal[:, j], offset[:, i], offset[:, j]
    det = n1[..., 0] * n2[..., 1] - n1[..., 1] * n2[..., 0]
    ok = det.abs() > 1e-9
    det = torch.where(ok, det, 1.0)
    cross = torch.stack((c1 * n2[..., 1] - c2 * n1[..., 1], n1[..., 0] * c2 - n2[..., 0] * c1), -1) / det[..., None]
    # a line and the circle |v| = v_max
    foot = offset[..., None] * normal
    half = (v_max**2 - offset**2).clamp(min=0.0).sqrt()[..., None] * torch.stack((-normal[..., 1], normal[..., 0]), -1)
    angles = torch.arange(grid, device=pref.device, dtype=pref.dtype) * (2 * math.pi / max(grid, 1))
    ring = torch.stack((torch.cos(angles), torch.sin(angles)), -1)
    polar = torch.cat([ring * (v_max * f) for f in (1 / 3, 2 / 3, 1.0)] + [ring.new_zeros(1, 2)])
    cand = torch.cat((pref[:, None], proj, cross, foot + half, foot - half, polar.expand(m, -1, -1)), 1)  # (M, C, 2)
    usable = torch.cat((torch.ones_like(valid[:, :1]), valid, valid[:, i] & valid[:, j] & ok, valid, valid,
                        torch.ones_like(valid[:, :1]).expand(m, polar.shape[0])), 1)
    # worst violation of each candidate: how far it lies outside a half-plane or the disc
    inside = (cand[:, :, None] * normal[:, None]).sum(-1) - offset[:, None]  # (M, C, K)
    worst = torch.where(valid[:, None], -inside, -math.inf).amax(-1).clamp(min=0.0)
    worst = torch.maximum(worst, torch.linalg.vector_norm(cand, dim=-1) - v_max)
    worst = torch.where(usable, worst, math.inf)
    feasible = worst <= 1e-5
    miss = (cand - pref[:, None]).square().sum(-1)
    # feasible candidates by distance to pref; otherwise by worst violation (then distance)
    score = torch.where(feasible.any(-1, keepdim=True), torch.where(feasible, miss, math.inf), worst + 1e-6 * miss)
    best = score.argmin(-1)
    return cand[torch.arange(m, device=pref.device), best]


class ORCA(Controller):
    """Decentralised ORCA for ``MultiNavEnv`` (module docstring): a TensorDict policy reading, per robot,
    ``("agents", "pose")`` ``(B, N, 3)``, ``("agents", "goal")`` ``(B, N, 2)``, ``("agents", "ranges")``
    ``(B, N, R)``, ``("agents", "velocity")`` ``(B, N, 2)`` and, when there, ``("agents", "mask")`` (which
    robots exist) and ``("agents", "done")`` (which are parked), and writing ``("agents", "action")``
    ``(B, N, 2)``. Given the agent group itself (``td["agents"]``, as ``MultiNavProtocol`` passes it) it
    reads and writes the same keys without the prefix."""

    in_keys = [("agents", k) for k in ("pose", "goal", "ranges", "velocity")]
    out_keys = [("agents", "action")]

    def __init__(self, gains: ORCAGains | dict | None = None, nav: NavConfig | None = None):
        super().__init__(nav or MultiNavConfig())
        self.gains = parse_gains(ORCAGains, gains, "orca")
        self.reactive = Reactive({"lookahead": self.gains.lookahead, "margin": self.gains.margin}, self.nav)

    def configure(self, nav: NavConfig) -> None:
        super().configure(nav)
        if hasattr(self, "reactive"):
            self.reactive.configure(nav)

    def velocities(self, pose: Tensor, goal: Tensor, ranges: Tensor, vel: Tensor, present: Tensor, parked: Tensor) -> Tensor:
        """Each robot's ORCA velocity ``(B, N, 2)`` m/s in the world frame (inputs as the class docstring, flags ``(B, N)``)."""
        g = self.gains
        b, n = present.shape
        xy = pose[..., :2]
        radius = self.radius + g.margin
        # -- the other robots this robot senses: its `neighbours` nearest present ones within range
        rel = xy[:, None, :, :] - xy[:, :, None, :]  # (B, N, N, 2): robot j relative to robot i
        d = torch.linalg.vector_norm(rel, dim=-1)
        eye = torch.eye(n, dtype=torch.bool, device=pose.device)
        sensed = present[:, None, :] & present[:, :, None] & ~eye & (d <= g.sensing_range)
        k = min(g.neighbours, n - 1)
        order = torch.where(sensed, d, math.inf).argsort(dim=-1, stable=True)[..., :k]  # (B, N, k)
        take = lambda t: t.gather(2, order.reshape(b, n, k, *([1] * (t.dim() - 3))).expand(b, n, k, *t.shape[3:]))  # noqa: E731
        nb_pos, nb_ok = take(rel), take(sensed)
        nb_vel = vel[:, None].expand(b, n, n, 2).gather(2, order[..., None].expand(b, n, k, 2))
        nb_parked = parked[:, None].expand(b, n, n).gather(2, order)
        # -- static obstacles: the lidar's returns that are not on another robot's disc
        c, s = torch.cos(pose[..., 2:3]), torch.sin(pose[..., 2:3])
        hit = self.hit_points(ranges)  # (B, N, R, 2) robot frame
        pts = torch.stack((c * hit[..., 0] - s * hit[..., 1], s * hit[..., 0] + c * hit[..., 1]), -1)  # relative, world frame
        on_robot = ((torch.linalg.vector_norm(pts[:, :, :, None] - rel[:, :, None], dim=-1) < self.radius + 0.05) & sensed[:, :, None]).any(-1)
        real = (ranges < self.max_range - 1e-4) & ~on_robot
        # -- preferred velocity: towards the goal, or along the open heading nearest to it where the scan
        # (without the robots, which ORCA handles) shows the straight way blocked
        to_goal = goal - xy
        dist = torch.linalg.vector_norm(to_goal, dim=-1)
        bearing = wrap_angle(torch.atan2(to_goal[..., 1], to_goal[..., 0]) - pose[..., 2])
        walls = torch.where(on_robot, torch.full_like(ranges, self.max_range), ranges)
        heading, any_open, _ = self.reactive.steer(walls.reshape(b * n, -1), dist.reshape(-1), bearing.reshape(-1))
        heading = heading.reshape(b, n) + pose[..., 2]
        speed = torch.where(any_open.reshape(b, n), torch.clamp(g.k_v * dist, max=self.v_max), 0.0)
        pref = speed[..., None] * torch.stack((torch.cos(heading), torch.sin(heading)), -1)
        # Symmetry breaking: robots meeting head on slow down together and deadlock in ORCA (RVO2's examples
        # perturb the preferred velocities at random); a shared rule, keep right while the preferred velocity
        # would hit a robot within the horizon, breaks it deterministically, as traffic does.
        rv = pref[:, :, None] - nb_vel
        a, bb, cc = (rv * rv).sum(-1), (nb_pos * rv).sum(-1), (nb_pos * nb_pos).sum(-1) - (2 * radius) ** 2
        disc = bb**2 - a * cc
        ttc = (bb - disc.clamp(min=0).sqrt()) / a.clamp(min=1e-9)
        conflict = (nb_ok & (bb > 0) & (disc > 0) & (ttc < g.time_horizon)).any(-1, keepdim=True)
        cr, sr = math.cos(g.keep_right), math.sin(g.keep_right)
        turned = torch.stack((cr * pref[..., 0] + sr * pref[..., 1], cr * pref[..., 1] - sr * pref[..., 0]), -1)
        pref = torch.where(conflict, turned, pref)
        m = min(g.obstacle_points, ranges.shape[-1])
        near = torch.where(real, torch.linalg.vector_norm(pts, dim=-1), math.inf).topk(m, -1, largest=False)
        ob_pos = pts.gather(2, near.indices[..., None].expand(b, n, m, 2))
        ob_ok = torch.isfinite(near.values)
        # -- one half-plane per neighbour and per point
        own = vel[:, :, None]
        rel_pos = torch.cat((nb_pos, ob_pos), 2)
        rel_vel = torch.cat((own - nb_vel, own.expand(b, n, m, 2)), 2)
        full = lambda t, v: torch.full(t.shape[:3], v, dtype=pose.dtype, device=pose.device)  # noqa: E731
        share = torch.cat((torch.where(nb_parked, 1.0, 0.5).to(pose.dtype), full(ob_pos, 1.0)), 2)
        rad = torch.cat((full(nb_pos, 2 * radius), full(ob_pos, radius)), 2)  # the other robot's tracking error too: its margin
        horizon = torch.cat((full(nb_pos, g.time_horizon), full(ob_pos, g.obstacle_horizon)), 2)
        point, normal = orca_half_planes(rel_pos, rel_vel, own, rad, share, horizon, self.dt)
        valid = torch.cat((nb_ok, ob_ok), 2)
        v = solve_velocities(pref.reshape(b * n, 2), point.reshape(b * n, -1, 2), normal.reshape(b * n, -1, 2),
                             valid.reshape(b * n, -1), self.v_max, g.grid)
        return v.reshape(b, n, 2)

    def twist(self, group: TensorDictBase) -> tuple[Tensor, Tensor]:
        """``(v m/s, omega rad/s)``, each ``(B, N)``, from the agent group ``group`` (batch ``(B, N)``)."""
        g = self.gains
        pose = group.get("pose")
        b, n = pose.shape[:2]
        flag = lambda key, default: group.get(key).reshape(b, n) if key in group.keys() else torch.full((b, n), default, device=pose.device)  # noqa: E731
        present, done = flag("mask", True), flag("done", False)
        goal = group.get("goal")
        v = self.velocities(pose, goal, group.get("ranges"), group.get("velocity"), present, done & present)
        speed = torch.linalg.vector_norm(v, dim=-1)
        # Heading to the chosen velocity; when it is (almost) zero, face the goal while waiting.
        to_goal = goal - pose[..., :2]
        slow = speed < 1e-3
        heading = torch.atan2(torch.where(slow, to_goal[..., 1], v[..., 1]), torch.where(slow, to_goal[..., 0], v[..., 0]))
        err = wrap_angle(heading - pose[..., 2])
        return self.heading_speed(speed, err, 1.0, g.k_omega, g.turn_in_place)

    @torch.no_grad()
    def forward(self, td: TensorDictBase) -> TensorDictBase:
        group = td.get("agents") if "agents" in td.keys() else td
        v, omega = self.twist(group)
        group.set("action", self.to_action(v, omega).to(group.get("pose").dtype))
        return td
