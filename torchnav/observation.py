"""The navigation policy's input and output, from robot data: one module for the simulator and the robot.

Everything that turns sensor readings into a navigation policy's observation (lidar sectors, the
goal vector and its cap, the visit memory's breadcrumbs, normalisation, the history of frames)
and its action back into a twist (the action mapping, the speed guard, the speed limits) is here.
``NavTask`` builds its observations with these functions, and :class:`ObservationBuilder` builds
them from a real robot's laser scan, odometry and goal with the same ones, so the observation on a
robot is the one the policy was trained on by construction (tests/test_observation_builder.py
checks it against the simulator for every shipped navigation policy).

No ROS here: ``torchnav.ros`` turns ROS messages into :class:`Scan` and plain numbers.

    drive = PolicyDriver(load_policy("checkpoints/ppo_arena_actor.pt"))     # torchnav.policy.load_policy
    v, omega = drive.act(Scan(ranges, angle_min, angle_increment, range_min, range_max), (x, y, yaw), (v, omega), (gx, gy))

Scans of another field of view, resolution or orientation are resampled to the simulator's ray
layout by :func:`resample_scan`; the rule is in its docstring and in docs/ros.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Sequence

import torch
from torch import Tensor

from .sim import LidarParams, SimParams, apply_limits, safe_hypot, sectorize, wrap_angle
from .sim.kinematics import arc_speed_guard, forward_speed_guard, guard_bearings

if TYPE_CHECKING:
    from .tasks.config import NavConfig

FAR = 1.0e6  # m, where an unused breadcrumb slot lies: beyond any visit radius


# -- the observation's parts, batched (B, ...): NavTask and ObservationBuilder both call these --------------


def goal_vector(pose: Tensor, goal: Tensor) -> tuple[Tensor, Tensor]:
    """Distance (m) and bearing (rad, robot frame, CCW) from ``pose`` ``(B, 3)`` to ``goal`` ``(B, 2)``."""
    dx, dy = goal[:, 0] - pose[:, 0], goal[:, 1] - pose[:, 1]
    dist = safe_hypot(dx, dy)
    far = dist > 1e-6  # atan2 has no gradient at the origin
    bearing = wrap_angle(torch.atan2(torch.where(far, dy, 0.0), torch.where(far, dx, 1.0)) - pose[:, 2])
    return dist, bearing


def drop_crumb(crumbs: Tensor, count: Tensor, odom: Tensor, spacing: float) -> tuple[Tensor, Tensor]:
    """``crumbs`` ``(B, K, 2)`` and ``count`` ``(B,)`` after a step that ended at ``odom`` ``(B, 3)``: a
    new breadcrumb at the odometry's position in the envs that drove at least ``spacing`` m from the
    newest one, written over the oldest once all ``K`` slots are used. No host synchronisation."""
    k = crumbs.shape[1]
    newest = crumbs.gather(1, ((count - 1) % k)[:, None, None].expand(-1, 1, 2)).squeeze(1)
    drop = safe_hypot(odom[:, 0] - newest[:, 0], odom[:, 1] - newest[:, 1]) >= spacing
    slot = torch.arange(k, device=crumbs.device) == (count % k)[:, None]
    crumbs = torch.where((drop[:, None] & slot)[..., None], odom[:, None, :2].detach(), crumbs)
    return crumbs, count + drop.long()


def first_crumbs(odom: Tensor, memory: int) -> tuple[Tensor, Tensor]:
    """The breadcrumbs ``(B, memory, 2)`` and their count ``(B,)`` of episodes starting at ``odom`` ``(B, 3)``:
    the first one marks the start, the other slots lie at :data:`FAR` (``memory`` 0: no memory)."""
    crumbs = torch.full((odom.shape[0], memory, 2), FAR, dtype=odom.dtype, device=odom.device)
    crumbs[:, :1] = odom[:, None, :2].detach()
    return crumbs, torch.ones(odom.shape[0], dtype=torch.int64, device=odom.device)


def visit_features(odom: Tensor, crumbs: Tensor, n_sectors: int, radius: float) -> Tensor:
    """How visited each direction around the robot is, ``(B, S)`` in [0, 1): sector ``k`` covers
    bearings within ``pi / S`` of ``2 pi k / S`` (robot frame, counter-clockwise; sector 0 ahead).
    A breadcrumb at distance ``d`` weighs ``max(0, 1 - d / radius)``; a sector reads
    ``1 - exp(-w / 4)`` of its summed weight ``w``: one straight pass of breadcrumbs 0.5 m apart
    through a 3 m radius reads about 0.46, two 0.71. Not differentiable (a count)."""
    odom, crumbs = odom.detach(), crumbs.detach()
    dx, dy = crumbs[..., 0] - odom[:, None, 0], crumbs[..., 1] - odom[:, None, 1]
    c, s = torch.cos(odom[:, 2:3]), torch.sin(odom[:, 2:3])
    x, y = c * dx + s * dy, c * dy - s * dx  # robot frame
    weight = (1.0 - torch.sqrt(x * x + y * y) / radius).clamp(min=0.0)
    sector = torch.round(torch.atan2(y, x) * (n_sectors / (2 * math.pi))).long() % n_sectors
    summed = torch.zeros(odom.shape[0], n_sectors, dtype=odom.dtype, device=odom.device).scatter_add_(1, sector, weight)
    return 1.0 - torch.exp(-summed / 4.0)


def frame_sizes(cfg: "NavConfig") -> tuple[int, int, int, int]:
    """The parts of one observation frame of ``cfg``: ``(lidar sectors, IMU, depth columns, visit sectors)``;
    the goal distance and bearing and ``(v, omega)`` (4 values) come after the sectors."""
    o = cfg.observation
    return cfg.lidar.n_sectors, 3 if o.imu else 0, cfg.camera.n_cols if o.camera else 0, o.visit_sectors


def obs_scale(cfg: "NavConfig", dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> Tensor:
    """The factors ``(D,)`` one observation frame is multiplied by (``observation.normalize``; ones without)."""
    li, r = cfg.lidar, cfg.robot
    n_sectors, n_imu, n_depth, n_visits = frame_sizes(cfg)
    if not cfg.observation.normalize:
        return torch.ones(n_sectors + 4 + n_imu + n_depth + n_visits, dtype=dtype, device=device)
    s = [1.0 / li.max_range] * n_sectors + [1.0 / li.max_range, 1.0 / math.pi, 1.0 / r.v_max, 1.0 / max(r.omega_max, 1e-9)]
    # IMU: accelerations by the largest centripetal one (v_max * omega_max), yaw rate by omega_max.
    s += [1.0 / max(r.v_max * r.omega_max, 1e-9)] * 2 + [1.0 / max(r.omega_max, 1e-9)] if n_imu else []
    s += [1.0 / cfg.camera.max_range] * n_depth
    s += [1.0] * n_visits  # already in [0, 1)
    return torch.tensor(s, dtype=dtype, device=device)


def observation_frame(cfg: "NavConfig", scale: Tensor, ranges: Tensor, pose: Tensor, odom: Tensor, vel: Tensor, goal: Tensor,
                      crumbs: Tensor | None = None, imu: Tensor | None = None, depth: Tensor | None = None) -> Tensor:
    """One observation frame ``(B, D)`` of a task of ``cfg``: lidar sectors of the scan ``ranges`` ``(B, R)``
    (the simulator's layout, :func:`resample_scan`), goal distance (capped at ``observation.goal_distance_cap``)
    and bearing from ``pose`` ``(B, 3)`` (``odom`` ``(B, 3)`` with ``observation.goal_from_odom``) to ``goal``
    ``(B, 2)``, the twist ``vel`` ``(B, 2)`` m/s, rad/s, then the IMU reading ``imu`` ``(B, 3)``, the depth row
    ``depth`` ``(B, C)`` and the visit memory of the breadcrumbs ``crumbs`` ``(B, K, 2)`` around ``odom``,
    each when the config observes it; multiplied by ``scale`` (:func:`obs_scale`)."""
    o = cfg.observation
    n_sectors, n_imu, n_depth, n_visits = frame_sizes(cfg)
    dist, bearing = goal_vector(odom if o.goal_from_odom else pose, goal)
    if o.goal_distance_cap is not None:
        dist = dist.clamp(max=o.goal_distance_cap)
    parts = [sectorize(ranges, n_sectors), dist[:, None], bearing[:, None], vel]
    for name, n, x in (("imu", n_imu, imu), ("camera", n_depth, depth)):
        if n:
            if x is None:
                raise ValueError(f"observation.{name} is on: the frame needs the {'IMU reading' if name == 'imu' else 'depth row'}")
            parts.append(x)
    if n_visits:
        if crumbs is None:
            raise ValueError("observation.visit_sectors is on: observe needs the episode's breadcrumbs (NavState.crumbs)")
        parts.append(visit_features(odom, crumbs, n_visits, o.visit_radius))
    return torch.cat(parts, dim=-1) * scale


def discrete_twists(cfg: "NavConfig", dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> Tensor:
    """The twists ``(A, 2)`` m/s, rad/s of ``action.discrete_set``."""
    scale = torch.tensor((cfg.robot.v_max, cfg.robot.omega_max), dtype=dtype, device=device)
    return torch.tensor(cfg.action.discrete_set, dtype=dtype, device=device) * scale


def command(cfg: "NavConfig", action: Tensor, twists: Tensor, dtype: torch.dtype = torch.float32) -> Tensor:
    """Policy action -> twist ``(B, 2)`` in m/s and rad/s.

    Continuous: ``(B, 2)`` in [-1, 1] (clamped); a[0] -> v in [0, v_max] (forward only)
    or [-v_max, v_max], a[1] -> omega in [-omega_max, omega_max]. Discrete: one-hot ``(B, n)``
    times ``twists`` (:func:`discrete_twists`).
    """
    r = cfg.robot
    if cfg.action.mode == "discrete":
        return action.to(dtype) @ twists
    a = action.clamp(-1.0, 1.0)
    v = (a[:, 0] + 1.0) * (0.5 * r.v_max) if cfg.action.forward_only else a[:, 0] * r.v_max
    return torch.stack((v, a[:, 1] * r.omega_max), dim=-1)


def guarded(cfg: "NavConfig", twist: Tensor, ranges: Tensor, lidar: LidarParams, radius: Tensor | float, dt: float,
            bearings: Tensor | None, pending: Tensor | None = None) -> Tensor:
    """``twist`` ``(B, 2)`` with its forward speed capped by the speed guard (``action.stop_clearance``;
    ``forward_speed_guard``, or ``arc_speed_guard`` with ``action.stop_path: arc``, on the scan ``ranges``
    ``(B, R)`` the policy saw, braking and delay from :func:`guard_dynamics`; ``pending`` ``(B, K, 2)``: the commands
    sent before, newest first, which the arc guard drives first under a delay); unchanged when the guard is off."""
    if cfg.action.stop_clearance is None:
        return twist
    decel, delay = guard_dynamics(cfg)
    if cfg.action.stop_path == "arc":
        v = arc_speed_guard(ranges, lidar, radius, cfg.action.stop_clearance, dt, twist, bearings, decel=decel, delay=delay,
                            pending=pending)
    else:
        v = torch.minimum(twist[:, 0], forward_speed_guard(ranges, lidar, radius, cfg.action.stop_clearance, dt, bearings,
                                                           decel=decel, delay=delay))
    return torch.stack((v, twist[:, 1]), dim=-1)


def guard_dynamics(cfg: "NavConfig") -> tuple[float, int]:
    """The deceleration (m/s^2) and actuator delay (steps) the speed guard plans its stop with: the
    robot's, or the worst its domain randomisation draws (the lowest ``lin_acc_max``, the longest delay)."""
    r = cfg.randomize
    decel = min(cfg.robot.lin_acc_max, r.lin_acc_max[0]) if r.lin_acc_max is not None else cfg.robot.lin_acc_max
    return decel, int(r.delay[1]) if r.delay is not None else 0


# -- a real scan in the simulator's layout ------------------------------------------------------------------


@dataclass(frozen=True)
class Scan:
    """One planar laser scan as ``sensor_msgs/LaserScan`` carries it: ``ranges`` (m, counter-clockwise from
    ``angle_min``), ``angle_min`` and ``angle_increment`` (rad, the scan's frame: x ahead, y left),
    ``range_min`` and ``range_max`` (m, the sensor's valid readings)."""

    ranges: Any  # (N,) sequence or array of floats; inf, -inf and NaN allowed (REP 117)
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float

    @classmethod
    def of_sim(cls, ranges: Any, lidar: LidarParams) -> "Scan":
        """The simulator's reading ``ranges`` ``(R,)`` of ``lidar`` as a scan: one beam per ray at the ray's
        angle, or for the exact sector scan at the middle of its sector (:func:`resample_scan` maps it
        back to the same ``R`` readings)."""
        n = lidar.n_rays
        if lidar.scan == "sectors":
            width = lidar.fov / n
            first, inc = lidar.sector_bearing(0.5), width
        else:
            a = lidar.angles()
            first, inc = a[0], (a[1] - a[0]) if n > 1 else lidar.fov
        return cls(ranges=ranges, angle_min=first, angle_increment=inc, range_min=lidar.min_range, range_max=lidar.max_range)


def sim_bins(lidar: LidarParams) -> tuple[float, float, bool]:
    """The angular bins of ``lidar``'s readings: ``(start, width, full_circle)``: reading ``j`` covers the
    sensor-frame bearings ``[start + j width, start + (j + 1) width)`` (a ray's bin is centred on it,
    a sector's bin is the sector)."""
    n = lidar.n_rays
    if lidar.scan == "sectors":
        return lidar.sector_bearing(0), lidar.fov / n, lidar.full_circle
    if lidar.full_circle:
        width = 2 * math.pi / n
    else:
        width = lidar.fov / (n - 1) if n > 1 else lidar.fov
    return lidar.angles()[0] - 0.5 * width, width, lidar.full_circle


def resample_scan(scan: Scan, lidar: LidarParams, yaw: float = 0.0, dtype: torch.dtype = torch.float32) -> tuple[Tensor, Tensor]:
    """A real scan in the simulator's layout of ``lidar``: ``(ranges (R,), unseen (R,) bool)``.

    The rule (docs/ros.md, "Observation contract"):

    * Beam ``i`` lies at bearing ``angle_min + i angle_increment + yaw`` in the simulated sensor's frame
      (``yaw``: how the real scan's frame is turned from it, rad, CCW), wrapped to [-pi, pi).
    * Its reading, per REP 117: ``+inf`` is no return (reads ``lidar.max_range``), ``-inf`` too close
      (reads ``lidar.min_range``); NaN, and any finite reading outside the message's
      ``[range_min, range_max]`` (drivers report 0 for no return), is invalid and ignored. Valid
      readings are clamped to ``[lidar.min_range, lidar.max_range]``, as the simulator clamps its own.
    * Each simulated reading takes the minimum of the beams in its bin (:func:`sim_bins`: a ray's
      bin is centred on it and one ray spacing wide, a sector's is the sector), the nearest obstacle
      any of them saw; a bin whose beams are all invalid reads ``max_range`` (nothing seen).
    * A bin without any beam (a coarser real scan) takes the beam nearest its centre if that centre
      lies within the real scan's field of view (half an increment beyond its ends included);
      outside it, the bin reads ``max_range`` and is flagged in ``unseen``.

    A scan of the simulator's own layout (:meth:`Scan.of_sim`) comes back unchanged, bit for bit.
    Raises ``ValueError`` for an empty scan or a non-finite or non-positive ``angle_increment``.
    """
    r = torch.as_tensor(scan.ranges, dtype=torch.float64).reshape(-1)
    n, inc = r.numel(), float(scan.angle_increment)
    if n == 0:
        raise ValueError("resample_scan: the scan has no ranges")
    if not math.isfinite(inc) or (inc <= 0 and n > 1):
        raise ValueError(f"resample_scan: angle_increment must be a finite number > 0, got {scan.angle_increment!r}")
    if not (math.isfinite(scan.angle_min) and math.isfinite(yaw)):
        raise ValueError(f"resample_scan: angle_min {scan.angle_min!r} and yaw {yaw!r} must be finite")
    lo, hi = float(scan.range_min), float(scan.range_max)
    valid = torch.isfinite(r) & (r >= lo) & (r <= hi) | torch.isinf(r)
    value = torch.where(r == math.inf, lidar.max_range, torch.where(r == -math.inf, lidar.min_range, r))
    value = torch.where(valid, value.clamp(lidar.min_range, lidar.max_range), math.inf)  # inf: an invalid beam, not a reading
    bearing = _wrap(scan.angle_min + yaw + inc * torch.arange(n, dtype=torch.float64))
    start, width, closed = sim_bins(lidar)
    m = lidar.n_rays
    u = torch.floor((bearing - start) / width).long()
    if closed:
        u = u % m
    inside = (u >= 0) & (u < m)
    best = torch.full((m,), math.inf, dtype=torch.float64).scatter_reduce(0, u[inside], value[inside], "amin")
    covered = torch.zeros(m, dtype=torch.bool).index_fill_(0, u[inside], True)
    unseen = torch.zeros(m, dtype=torch.bool)
    if not bool(covered.all()):  # bins between or beyond the real beams
        centre = start + width * (torch.arange(m, dtype=torch.float64) + 0.5)
        real_closed = n * inc >= 2 * math.pi - 1e-6
        off = _wrap(centre - (scan.angle_min + yaw)) if real_closed else _wrap_from(centre - (scan.angle_min + yaw), -0.5 * inc)
        i = torch.round(off / inc).long() if inc > 0 else torch.zeros(m, dtype=torch.long)
        if real_closed:
            i = i % n
        ok = (i >= 0) & (i < n)
        near = value[i.clamp(0, n - 1)]
        best = torch.where(covered, best, torch.where(ok, near, math.inf))
        unseen = ~covered & ~ok
    best = torch.where(torch.isinf(best), lidar.max_range, best)  # nothing valid seen: a miss, as the simulator reads it
    return best.to(dtype), unseen


def _wrap(a: Tensor) -> Tensor:
    """Angles wrapped to [-pi, pi)."""
    return a - 2 * math.pi * torch.floor((a + math.pi) / (2 * math.pi))


def _wrap_from(a: Tensor, lo: float) -> Tensor:
    """Angles wrapped to [lo, lo + 2 pi)."""
    return a - 2 * math.pi * torch.floor((a - lo) / (2 * math.pi))


# -- the stateful builder: one robot, step by step ---------------------------------------------------------


class ObservationBuilder:
    """The observation of a navigation task (``NavConfig``) from one robot's data, step by step.

    :meth:`observe` takes a :class:`Scan`, the pose ``(x, y, yaw)`` (m, rad; odometry, in the goal's
    frame) and twist ``(v, omega)`` (m/s, rad/s, measured) and the goal ``(x, y)`` and returns the
    observation ``(obs_size,)`` the policy was trained on: the frame of :func:`observation_frame`,
    stacked over ``observation.history`` frames (copies of the first at an episode's start), with the
    visit memory's breadcrumbs dropped along the pose's path. :meth:`twist` turns the policy's action
    into the twist the simulator would drive: the action mapping, the speed guard on the last scan,
    and the speed and acceleration limits relative to the last measured twist. With the arc guard
    and an actuator delay (``action.stop_path: arc``, ``randomize.delay``) it keeps the twists it
    returned, newest first (:attr:`sent`), and the guard drives those first, as the simulator's guard
    drives its command queue. :meth:`reset` starts an episode (the next :meth:`observe` is its first;
    the robot is taken to have been told to stand). Observations with an IMU or camera are refused:
    a robot provides neither reading in the simulator's form.
    """

    def __init__(self, cfg: "NavConfig", scan_yaw: float = 0.0, dtype: torch.dtype = torch.float32) -> None:
        if cfg.observation.imu or cfg.observation.camera:
            raise ValueError("ObservationBuilder: this policy observes the simulated "
                             f"{'IMU' if cfg.observation.imu else 'camera depth row'}, which a robot's data does not provide here; "
                             "only lidar, goal, odometry and visit-memory observations can be built")
        self.cfg, self.dtype, self.scan_yaw = cfg, dtype, float(scan_yaw)
        self.params: SimParams = cfg.sim_params()
        self.lidar = self.params.lidar
        self.scale = obs_scale(cfg, dtype)
        self.twists = discrete_twists(cfg, dtype)
        self.bearings = guard_bearings(self.lidar, dtype) if cfg.action.stop_clearance is not None else None
        self.frame_size = int(self.scale.numel())
        self.obs_size = self.frame_size * cfg.observation.history
        self.memory = cfg.observation.visit_memory if cfg.observation.visit_sectors else 0
        delay = guard_dynamics(cfg)[1]
        self.queued = delay if cfg.action.stop_clearance is not None and cfg.action.stop_path == "arc" else 0  # twists the guard drives first
        self.reset()

    def reset(self) -> None:
        """Start a new episode: the next :meth:`observe` is its first (history and breadcrumbs start anew)."""
        self.history: Tensor | None = None  # (H, D)
        self.crumbs = torch.zeros(1, self.memory, 2, dtype=self.dtype)
        self.count = torch.zeros(1, dtype=torch.int64)
        self.ranges: Tensor | None = None  # (R,) the last scan in the simulator's layout
        self.vel = torch.zeros(1, 2, dtype=self.dtype)
        self.sent = torch.zeros(1, self.queued, 2, dtype=self.dtype)  # (1, K, 2) the last twists returned, newest first
        self.unseen = torch.zeros(self.lidar.n_rays, dtype=torch.bool)
        self.goal_distance = math.inf  # m, from the last observe (uncapped)

    @property
    def started(self) -> bool:
        """Whether this episode has had its first observation."""
        return self.history is not None

    def observe(self, scan: Scan | Tensor, pose: Sequence[float], vel: Sequence[float], goal: Sequence[float]) -> Tensor:
        """The observation ``(obs_size,)`` after this step's readings (see the class docstring); ``scan`` may
        also be the simulator's ranges ``(R,)`` themselves. Raises ``ValueError`` for a non-finite pose,
        twist or goal (the caller stops the robot)."""
        ranges = self.ranges_of(scan)
        p, v, g = (self._vector(x, k, name) for x, k, name in ((pose, 3, "pose"), (vel, 2, "vel"), (goal, 2, "goal")))
        if self.memory:
            if self.started:
                self.crumbs, self.count = drop_crumb(self.crumbs, self.count, p, self.cfg.observation.visit_spacing)
            else:
                self.crumbs, self.count = first_crumbs(p, self.memory)
        frame = observation_frame(self.cfg, self.scale, ranges[None], p, p, v, g, self.crumbs if self.memory else None)[0]
        if self.started:
            self.history = torch.cat((self.history[1:], frame[None]), 0)
        else:
            self.history = frame[None].expand(self.cfg.observation.history, -1).clone()
        self.ranges, self.vel = ranges, v
        self.goal_distance = float(goal_vector(p, g)[0][0])
        return self.history.reshape(-1)

    def ranges_of(self, scan: Scan | Tensor) -> Tensor:
        """``scan`` in the simulator's layout ``(R,)`` (:func:`resample_scan`; its ``unseen`` bins in :attr:`unseen`)."""
        if isinstance(scan, Scan):
            ranges, self.unseen = resample_scan(scan, self.lidar, self.scan_yaw, self.dtype)
            return ranges
        ranges = torch.as_tensor(scan, dtype=self.dtype).reshape(-1)
        if ranges.numel() != self.lidar.n_rays or not bool(torch.isfinite(ranges).all()):
            raise ValueError(f"observe: simulator ranges must be {self.lidar.n_rays} finite readings, got {ranges.numel()} "
                             "(pass a Scan to resample a real one)")
        return ranges

    def twist(self, action: Tensor) -> tuple[float, float]:
        """The twist ``(v m/s, omega rad/s)`` the simulator drives for the policy's ``action`` (``(2,)`` in [-1, 1],
        or a one-hot ``(A,)`` for a discrete policy) after the last :meth:`observe`: :func:`command`, the speed
        guard on the last scan (:func:`guarded`, driving the twists :attr:`sent` first) and the limits
        (``apply_limits``; a non-finite action stops). The result is taken to be sent to the robot."""
        if self.ranges is None:
            raise RuntimeError("twist: no observation yet this episode (call observe first)")
        cmd = command(self.cfg, torch.as_tensor(action).reshape(1, -1).to(self.dtype), self.twists, self.dtype)
        cmd = guarded(self.cfg, cmd, self.ranges[None], self.lidar, self.params.robot_radius, self.params.dt, self.bearings,
                      self.sent if self.queued else None)
        out = apply_limits(cmd, self.vel, self.params)
        if self.queued:
            self.sent = torch.cat((out[:, None], self.sent[:, :-1]), 1)
        return float(out[0, 0]), float(out[0, 1])

    def _vector(self, x: Sequence[float], k: int, name: str) -> Tensor:
        t = torch.as_tensor(x, dtype=self.dtype).reshape(-1)
        if t.numel() != k or not bool(torch.isfinite(t).all()):
            raise ValueError(f"observe: {name} must be {k} finite numbers, got {x!r}")
        return t[None]


class PolicyDriver:
    """A saved navigation policy driving one robot: :class:`ObservationBuilder` and the network.
    ``saved``: ``torchnav.policy.load_policy("actor.pt")`` (a ``SavedPolicy`` of task ``"nav"``).

    :meth:`act` maps one step's readings to the twist to command; a recurrent policy's state and a
    discrete policy's argmax are handled here. :attr:`dt` is the control period the policy was trained
    at, :attr:`goal_tolerance` the distance at which its episodes succeed.
    """

    def __init__(self, saved: Any, scan_yaw: float = 0.0) -> None:
        if saved.task != "nav":
            raise ValueError(f"{saved.path}: a {saved.task!r} policy, not a navigation policy (task 'nav')")
        self.saved, self.actor = saved, saved.actor
        self.cfg = saved.config()
        self.builder = ObservationBuilder(self.cfg, scan_yaw)
        if self.actor.obs_size != self.builder.obs_size:
            raise ValueError(f"{saved.path}: the network reads {self.actor.obs_size} features, its task config makes {self.builder.obs_size}")
        self.dt = self.cfg.robot.dt
        self.goal_tolerance = self.cfg.goal_tolerance
        self.reset()

    def reset(self) -> None:
        """A new episode (a new goal): history, breadcrumbs and a recurrent policy's state start anew."""
        self.builder.reset()
        self.state = self.actor.initial_state(1) if self.actor.recurrent else None
        self.action: Tensor | None = None

    @torch.no_grad()
    def action_of(self, obs: Tensor) -> Tensor:
        """The policy's deterministic action for ``obs`` ``(obs_size,)``: ``(2,)`` in [-1, 1], or one-hot ``(A,)``."""
        x = obs[None]
        if self.actor.recurrent:
            out, self.state = self.actor.step(x, self.state, torch.tensor([self.action is None]))  # the episode's first step
        else:
            out = self.actor(x)
        if self.actor.output == "argmax":
            out = torch.nn.functional.one_hot(out.argmax(-1), out.shape[-1]).to(torch.long)
        self.action = out[0]
        return self.action

    def act(self, scan: Scan | Tensor, pose: Sequence[float], vel: Sequence[float], goal: Sequence[float]) -> tuple[float, float]:
        """One control step: the twist ``(v m/s, omega rad/s)`` to command after these readings."""
        return self.builder.twist(self.action_of(self.builder.observe(scan, pose, vel, goal)))


__all__ = [
    "FAR", "ObservationBuilder", "PolicyDriver", "Scan", "command", "discrete_twists", "drop_crumb", "first_crumbs", "frame_sizes",
    "goal_vector", "guarded", "obs_scale", "observation_frame", "resample_scan", "sim_bins", "visit_features",
]
