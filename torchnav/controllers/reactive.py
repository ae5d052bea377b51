"""Reactive controllers: go-to-goal, go-to-goal with lidar avoidance, potential field.

Each maps the current ``pose``, ``goal`` and raw lidar ``ranges`` to a twist with a
few tensor operations over the whole batch; no memory between steps. Gains are
frozen dataclasses (units in the comments); see docs/controllers.md for how each
one behaves and where it fails.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
import torch
from tensordict import TensorDictBase
from torch import Tensor

from ..config import ConfigError
from ..tasks import NavConfig, NavTask
from .base import Controller, check_positive, parse_gains


@dataclass(frozen=True)
class GoToGoalGains:
    k_v: float = 1.0  # 1/s: forward speed = k_v * goal distance (then capped at v_max)
    k_omega: float = 2.0  # 1/s: turn rate = k_omega * bearing error (rad/s per rad)
    turn_in_place: float = 0.8  # rad: above this bearing error the robot turns on the spot (v = 0)

    def __post_init__(self) -> None:
        check_positive(k_v=self.k_v, k_omega=self.k_omega, turn_in_place=self.turn_in_place)


class GoToGoal(Controller):
    """Drive straight at the goal: turn rate proportional to the bearing, speed to the distance
    (times ``cos(bearing)``; zero above ``turn_in_place``). Blind to obstacles."""

    def __init__(self, gains: GoToGoalGains | dict | None = None, nav: NavConfig | None = None):
        super().__init__(nav)
        self.gains = parse_gains(GoToGoalGains, gains, "go_to_goal")

    def twist(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        g = self.gains
        dist, bearing = NavTask.goal_vector(td.get("pose"), td.get("goal"))
        return self.heading_speed(dist, bearing, g.k_v, g.k_omega, g.turn_in_place)


@dataclass(frozen=True)
class ReactiveGains:
    k_v: float = 1.0  # 1/s: speed = k_v * goal distance, as go_to_goal
    k_omega: float = 2.0  # 1/s: turn rate per rad of heading error
    turn_in_place: float = 0.8  # rad: turn on the spot above this heading error
    lookahead: float = 1.2  # m: a heading is open when no return lies in the corridor this far ahead
    margin: float = 0.1  # m: corridor half-width = robot radius + margin
    slow_distance: float = 0.8  # m: speed is cut linearly once the nearest return is closer than this gap
    stop_distance: float = 0.05  # m: ... down to zero at this gap (robot edge to return)

    def __post_init__(self) -> None:
        check_positive(k_v=self.k_v, k_omega=self.k_omega, turn_in_place=self.turn_in_place,
                       lookahead=self.lookahead, slow_distance=self.slow_distance)
        if not 0 <= self.stop_distance < self.slow_distance or self.margin < 0:
            raise ConfigError("margin, stop_distance: need margin >= 0 and 0 <= stop_distance < slow_distance")


class Reactive(Controller):
    """Go-to-goal that steers around what the lidar sees, a minimal vector-field-histogram
    (docs/controllers.md, "reactive"): at the goal if that heading is open, else at the open
    ray direction nearest to it, on the spot towards the goal when nothing is open."""

    def __init__(self, gains: ReactiveGains | dict | None = None, nav: NavConfig | None = None):
        super().__init__(nav)
        self.gains = parse_gains(ReactiveGains, gains, "reactive")

    def open_headings(self, pts: Tensor, cand: Tensor, reach: Tensor) -> Tensor:
        """Whether headings ``cand`` ``(B, K)`` rad are open up to ``reach`` ``(B, K)`` m,
        given returns ``pts`` ``(B, R, 2)`` in the robot frame -> ``(B, K)`` bool."""
        ux, uy = torch.cos(cand)[..., None], torch.sin(cand)[..., None]  # (B, K, 1)
        px, py = pts[:, None, :, 0], pts[:, None, :, 1]  # (B, 1, R)
        along = px * ux + py * uy
        across = (px * uy - py * ux).abs()
        hit = (along > 0) & (along < reach[..., None]) & (across < self.radius + self.gains.margin)
        return ~hit.any(-1)

    def steer(self, ranges: Tensor, dist: Tensor, bearing: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The heading ``(B,)`` rad (robot frame) to steer at, given the scan ``ranges`` ``(B, R)`` m and the
        goal's distance and bearing ``(B,)``: the goal's if open, else the open ray nearest to it (the
        goal's where nothing is open); whether any heading is open ``(B,)``; the returns ``(B, R, 2)``."""
        g = self.gains
        pts = self.hit_points(ranges)
        rays = self.ray_angles(ranges).expand(ranges.shape[0], -1)  # (B, R)
        cand = torch.cat((bearing[:, None], rays), dim=1)  # (B, 1 + R)
        reach = torch.full_like(cand, g.lookahead)
        reach[:, 0] = torch.minimum(dist, reach[:, 0])
        is_open = self.open_headings(pts, cand, reach)
        half_fov = rays.abs().amax(-1, keepdim=True) + 1e-6
        is_open[:, :1] &= bearing[:, None].abs() <= half_fov  # the lidar cannot vouch for what it does not see
        # Goal first (cost -1), then the open ray nearest to the goal bearing.
        cost = torch.cat((torch.full_like(bearing[:, None], -1.0), (rays - bearing[:, None]).abs()), dim=1)
        cost = torch.where(is_open, cost, torch.full_like(cost, math.inf))
        best = cost.argmin(-1)
        any_open = is_open.any(-1)
        return torch.where(any_open, cand.gather(1, best[:, None])[:, 0], bearing), any_open, pts

    def twist(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        g = self.gains
        pose = td.get("pose")
        dist, bearing = NavTask.goal_vector(pose, td.get("goal"))
        target, any_open, pts = self.steer(td.get("ranges"), dist, bearing)
        v, omega = self.heading_speed(dist, target, g.k_v, g.k_omega, g.turn_in_place)
        # Blocked all round: spin towards the goal side (a disc robot can always turn safely).
        spin = torch.where(bearing >= 0, torch.ones_like(v), -torch.ones_like(v)) * self.omega_max
        v, omega = torch.where(any_open, v, torch.zeros_like(v)), torch.where(any_open, omega, spin)
        gap = pts.norm(dim=-1).amin(-1) - self.radius
        scale = ((gap - g.stop_distance) / (g.slow_distance - g.stop_distance)).clamp(0.0, 1.0)
        return v * (0.3 + 0.7 * scale), omega


@dataclass(frozen=True)
class PotentialFieldGains:
    k_att: float = 1.0  # 1/s: attraction = k_att * (goal - pose), capped at ...
    att_distance: float = 1.0  # m: ... this distance (beyond it the pull has constant size k_att * att_distance)
    k_rep: float = 0.3  # m^3/s per rad of scan: Khatib repulsion k_rep (1/d - 1/d0) / d^2 per return, summed over rays x ray spacing
    influence: float = 0.6  # m: d0, returns farther than this gap (robot edge to return) do not repel
    min_gap: float = 0.05  # m: gaps are floored here so the repulsion stays finite
    k_v: float = 1.0  # 1/s: speed = k_v * goal distance (then capped at v_max), times cos(heading error)
    k_omega: float = 2.0  # 1/s: turn rate per rad between heading and the force direction
    turn_in_place: float = 1.2  # rad: turn on the spot above this heading error

    def __post_init__(self) -> None:
        check_positive(k_att=self.k_att, att_distance=self.att_distance, influence=self.influence,
                       min_gap=self.min_gap, k_v=self.k_v, k_omega=self.k_omega, turn_in_place=self.turn_in_place)
        if self.k_rep < 0:
            raise ConfigError(f"k_rep must be >= 0, got {self.k_rep!r}")


class PotentialField(Controller):
    """Classic artificial potential field (Khatib 1986) on lidar returns: the robot heads along
    the pull to the goal plus each near return's push (docs/controllers.md, "potential_field"),
    and stops in the local minima the theory predicts (a cup facing the goal)."""

    def __init__(self, gains: PotentialFieldGains | dict | None = None, nav: NavConfig | None = None):
        super().__init__(nav)
        self.gains = parse_gains(PotentialFieldGains, gains, "potential_field")

    def force(self, td: TensorDictBase) -> tuple[Tensor, Tensor, Tensor]:
        """Attraction and repulsion ``(B, 2)`` in the robot frame, and the goal distance ``(B,)`` m."""
        g = self.gains
        pose, ranges = td.get("pose"), td.get("ranges")
        dist, bearing = NavTask.goal_vector(pose, td.get("goal"))
        pull = g.k_att * torch.clamp(dist, max=g.att_distance)
        att = torch.stack((pull * torch.cos(bearing), pull * torch.sin(bearing)), dim=-1)
        pts = self.hit_points(ranges)  # (B, R, 2)
        norm = pts.norm(dim=-1).clamp(min=1e-6)
        gap = (norm - self.radius).clamp(min=g.min_gap)
        mag = g.k_rep * (1.0 / gap - 1.0 / g.influence) / gap**2
        mag = torch.where(gap < g.influence, mag, torch.zeros_like(mag))
        spacing = self.ray_spacing()
        rep = -(mag[..., None] * pts / norm[..., None]).sum(1) * spacing
        return att, rep, dist

    def ray_spacing(self) -> float:
        a = self._ray_angles
        return float((a[-1] - a[0]) / (len(a) - 1)) if len(a) > 1 else 1.0

    def twist(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        g = self.gains
        att, rep, dist = self.force(td)
        f = att + rep
        heading = torch.atan2(f[:, 1], f[:, 0])
        return self.heading_speed(dist, heading, g.k_v, g.k_omega, g.turn_in_place)

