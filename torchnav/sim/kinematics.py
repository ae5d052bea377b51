"""Differential-drive kinematics: command conversions, limits and integrators.

A twist is ``(v, omega)``: forward speed in m/s and turn rate in rad/s (CCW
positive). Wheel speeds are the linear rim speeds of the left and right wheels
in m/s.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from .math import safe_sinc, wrap_angle
from .params import LidarParams, SimParams

if TYPE_CHECKING:
    from .randomize import EnvParams


def wheels_to_unicycle(wheels: Tensor, track_width: float) -> Tensor:
    """``(..., 2)`` wheel speeds ``[v_left, v_right]`` (m/s) -> twist ``[v, omega]``."""
    vl, vr = wheels.unbind(-1)
    return torch.stack(((vr + vl) * 0.5, (vr - vl) / track_width), dim=-1)


def unicycle_to_wheels(twist: Tensor, track_width: float) -> Tensor:
    """``(..., 2)`` twist ``[v, omega]`` -> wheel speeds ``[v_left, v_right]`` (m/s)."""
    v, w = twist.unbind(-1)
    half = 0.5 * track_width * w
    return torch.stack((v - half, v + half), dim=-1)


def apply_limits(cmd: Tensor, prev: Tensor, params: SimParams, env: "EnvParams | None" = None) -> Tensor:
    """Clamp a commanded twist ``(B, 2)`` to the speed limits and, if finite, to the acceleration
    limits relative to the previous twist ``prev`` ``(B, 2)``; a non-finite entry becomes 0 (stop)
    first (docs/sim.md, "Kinematics"). ``env`` (``randomize.EnvParams``) gives per-env limits
    instead of ``params``' (``v_min`` scales with ``v_max``)."""
    cmd = torch.where(torch.isfinite(cmd), cmd, torch.zeros_like(cmd))
    if env is not None:
        v_max, w_max = env.v_max, env.omega_max
        v = torch.minimum(torch.maximum(cmd[:, 0], v_max * (params.v_min / params.v_max if params.v_max else 0.0)), v_max)
        w = torch.minimum(torch.maximum(cmd[:, 1], -w_max), w_max)
        dv, dw = env.lin_acc_max * params.dt, env.ang_acc_max * params.dt
        v = torch.minimum(torch.maximum(v, prev[:, 0] - dv), prev[:, 0] + dv)
        w = torch.minimum(torch.maximum(w, prev[:, 1] - dw), prev[:, 1] + dw)
        return torch.stack((v, w), dim=-1)
    v = cmd[:, 0].clamp(params.v_min, params.v_max)
    w = cmd[:, 1].clamp(-params.omega_max, params.omega_max)
    if math.isfinite(params.lin_acc_max):
        dv = params.lin_acc_max * params.dt
        v = torch.minimum(torch.maximum(v, prev[:, 0] - dv), prev[:, 0] + dv)
    if math.isfinite(params.ang_acc_max):
        dw = params.ang_acc_max * params.dt
        w = torch.minimum(torch.maximum(w, prev[:, 1] - dw), prev[:, 1] + dw)
    return torch.stack((v, w), dim=-1)


def integrate_euler(pose: Tensor, twist: Tensor, dt: float) -> Tensor:
    """Textbook forward-Euler step: ``x += v cos(theta) dt``, ``theta += omega dt``.

    Args:
        pose: ``(B, 3)`` ``[x, y, theta]``. twist: ``(B, 2)``. dt: s.
    """
    x, y, th = pose.unbind(-1)
    v, w = twist.unbind(-1)
    return torch.stack((x + v * torch.cos(th) * dt, y + v * torch.sin(th) * dt, wrap_angle(th + w * dt)), dim=-1)


def integrate_exact(pose: Tensor, twist: Tensor, dt: float) -> Tensor:
    """Exact pose after driving the constant twist for ``dt``: a circular arc.

    Written as a chord of length ``v dt sinc(omega dt / 2)`` along the mean heading
    ``theta + omega dt / 2``, which equals ``v/omega (sin(theta + omega dt) - sin theta)``
    etc. but stays finite, with a finite gradient, as ``omega -> 0``.
    """
    x, y, th = pose.unbind(-1)
    v, w = twist.unbind(-1)
    half = 0.5 * w * dt
    chord = v * dt * safe_sinc(half)
    mid = th + half
    return torch.stack((x + chord * torch.cos(mid), y + chord * torch.sin(mid), wrap_angle(th + 2.0 * half)), dim=-1)


def integrate(pose: Tensor, twist: Tensor, params: SimParams) -> Tensor:
    """Advance ``pose`` ``(B, 3)`` by ``twist`` ``(B, 2)`` over ``params.dt`` with ``params.integrator``."""
    if params.integrator == "euler":
        return integrate_euler(pose, twist, params.dt)
    return integrate_exact(pose, twist, params.dt)


def guard_bearings(lidar: LidarParams, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> Tensor:
    """For each reading of ``lidar``'s scan, ``(R,)``, the bearing (rad, robot frame) nearest straight
    ahead at which its return can lie: the ray's own angle, or for the exact sector scan the point
    of the sector nearest 0 (``forward_speed_guard``)."""
    if lidar.scan == "sectors":
        centres, half = [lidar.sector_bearing(k + 0.5) for k in range(lidar.n_rays)], 0.5 * lidar.fov / lidar.n_rays
    else:
        centres, half = lidar.angles(), 0.0
    centre = wrap_angle(torch.tensor(centres, dtype=dtype, device=device) + lidar.offset[2])
    return torch.sign(centre) * (centre.abs() - half).clamp(min=0.0)


def forward_speed_guard(ranges: Tensor, lidar: LidarParams, radius: Tensor | float, clearance: float, dt: float,
                        bearings: Tensor | None = None, decel: float = math.inf, delay: int = 0) -> Tensor:
    """The highest forward speed ``(B,)`` m/s at which a robot disc of ``radius`` m, driving straight
    for ``dt`` s, stays ``clearance`` m short of every return of its last scan ``ranges``
    ``(B, R)`` (``lidar``'s layout) ahead of its centre and nearer its path than ``radius + clearance``;
    ``inf`` where none is (misses, at ``lidar.max_range``, are none). A return already that near
    and ahead stops it: the robot turns away first (turning on the spot moves no part of the disc).

    With a finite deceleration ``decel`` m/s^2 and an actuator ``delay`` of whole steps, the robot
    must also be able to stop in the free distance ``f``: the speed ``v`` driven for the ``1 + delay``
    steps before a stop takes effect, then braking, ``v (1 + delay) dt + v^2 / (2 decel) <= f``
    (``f / dt`` with neither).

    A return of the exact sector scan lies somewhere in its sector: the bound takes the bearing
    in the sector nearest straight ahead, the worst case (the distance the disc can drive before
    touching a point at a given range only grows with the point's bearing). Exact for a sensor at
    the robot's centre; an offset sensor's returns are placed from its mount. Straight motion
    stands in for the step's arc (at 1 m/s and 2 rad/s they part by 1 cm in 0.1 s). ``bearings``
    ``(R,)``: ``guard_bearings(lidar)`` as a tensor, built once by a caller that steps many times."""
    ox, oy, _ = lidar.offset
    nearest = guard_bearings(lidar, ranges.dtype, ranges.device) if bearings is None else bearings
    x, y = ox + ranges * torch.cos(nearest), (oy + ranges * torch.sin(nearest)).abs()
    reach = torch.as_tensor(radius, dtype=ranges.dtype, device=ranges.device).reshape(-1, 1) + clearance
    blocks = (x > 0) & (y < reach) & (ranges < lidar.max_range)  # a miss reads max_range
    free = torch.where(blocks, x - torch.sqrt((reach * reach - y * y).clamp(min=0.0)), torch.full_like(ranges, math.inf))
    return stopping_speed(free.amin(-1).clamp(min=0.0), (1 + delay) * dt, decel)


def stopping_speed(free: Tensor, t: float, decel: float) -> Tensor:
    """The highest speed ``v`` that, driven for ``t`` s and then braked at ``decel`` m/s^2, stops within
    ``free`` m: ``v t + v^2 / (2 decel) = free`` (``free / t`` for an instant stop; inf stays inf)."""
    if not math.isfinite(decel):
        return free / t
    # the positive root of v^2 / (2 decel) + v t - f = 0, written to stay exact for small f (and inf for f = inf)
    return torch.where(free.isinf(), free, 2 * free / (t + torch.sqrt(t * t + 2 * free / decel)))


def arc_free_length(x: Tensor, y: Tensor, curvature: Tensor, reach: Tensor) -> Tensor:
    """How far (m) a disc of radius ``reach`` can drive along the circle of signed ``curvature`` (1/m,
    positive turning left) from the origin, heading +x, before it touches the point ``(x, y)``; all
    broadcast together. ``inf`` where it never does within one turn; 0 for a point already within
    ``reach`` that the first motion approaches (one it leaves is inf). Straight motion is the limit
    ``curvature -> 0``, computed without dividing by the radius (curvatures under 1e-6/m are 1e-6).

    The disc's centre runs on the circle of radius ``rho = 1/|k|`` round ``(0, rho)``; a point at
    distance ``d`` from that centre is touched where the centre's angle is within ``delta`` of the
    point's, ``reach^2 = (d - rho)^2 + 4 rho d sin^2(delta / 2)``; the first touch is the angle the
    centre sweeps to the point less ``delta``."""
    side = torch.where(curvature < 0, -1.0, 1.0)
    k = curvature.abs().clamp(min=1e-6)
    y = y * side  # mirrored to a left turn
    kd = torch.sqrt((k * x) ** 2 + (1 - k * y) ** 2)  # k d
    u = (k * (x * x + y * y) - 2 * y) / (kd + 1)  # d - rho, without cancellation
    swept = torch.atan2(k * x, 1 - k * y)  # the centre's angle round the circle to the point's, in (-pi, pi]
    half = k * torch.sqrt((reach * reach - u * u).clamp(min=0.0) / (4 * kd.clamp(min=1e-12)))
    turn = swept - 2 * torch.asin(half.clamp(max=1.0))
    free = torch.where(turn < 0, turn + 2 * math.pi, turn) / k
    inside = x * x + y * y < reach * reach
    free = torch.where(u.abs() < reach, free, math.inf)
    return torch.where(inside, torch.where(x > 0, 0.0, math.inf), free)


def arc_speed_guard(ranges: Tensor, lidar: LidarParams, radius: Tensor | float, clearance: float, dt: float, twist: Tensor,
                    bearings: Tensor | None = None, decel: float = math.inf, delay: int = 0, pending: Tensor | None = None,
                    passes: int = 2) -> Tensor:
    """``forward_speed_guard`` for a robot that turns: the highest forward speed ``(B,)`` m/s, at most the
    commanded ``twist[:, 0]`` ``(B, 2)``, at which the disc driving the arc of the command's curvature
    and then braking along it at ``decel`` stays ``clearance`` m off every return of ``ranges``
    (``arc_free_length``); never above the straight-line bound.

    The actuator ``delay`` (whole steps, at most): without ``pending`` the command is driven for
    ``1 + delay`` steps from where the scan was taken. ``pending`` ``(B, K, 2)``, the commands sent
    before this one, newest first (``K >= delay``), are what the robot drives first if it is ``d``
    steps behind: for every ``d`` in ``0..delay`` the guard drives the ``d`` newest of them (exact arcs),
    then this command for one step, and brakes from there; the bound holds for every ``d``.

    Lowering the speed at the commanded turn rate tightens the arc, so the bound is refined
    ``passes`` times, each at the curvature of the last speed. A ray's return lies at its angle; a
    return of the exact sector scan anywhere on its sector's arc, so it is taken at the sector's
    middle with the disc grown by the farthest the arc reaches from there, ``2 r sin(width / 4)``
    (8.7 cm at 1 m for 10-degree sectors): conservative, where the straight-line bound is exact."""
    v = torch.minimum(twist[:, 0], forward_speed_guard(ranges, lidar, radius, clearance, dt, bearings, decel, delay))
    if lidar.scan == "sectors":
        angles, grow = [lidar.sector_bearing(k + 0.5) for k in range(lidar.n_rays)], 2 * math.sin(lidar.fov / lidar.n_rays / 4)
    else:
        angles, grow = lidar.angles(), 0.0
    b = torch.tensor(angles, dtype=ranges.dtype, device=ranges.device) + lidar.offset[2]
    x, y = lidar.offset[0] + ranges * torch.cos(b), lidar.offset[1] + ranges * torch.sin(b)  # (B, R), robot frame
    reach = torch.as_tensor(radius, dtype=ranges.dtype, device=ranges.device).reshape(-1, 1) + clearance + grow * ranges
    seen = ranges < lidar.max_range  # a miss is no return
    drive = (1 + delay) * dt
    if pending is not None and delay > 0:
        if pending.shape[1] < delay:
            raise ValueError(f"arc_speed_guard: {pending.shape[1]} pending commands for a delay of up to {delay} steps")
        xs, ys = [x], [y]
        for d in range(1, delay + 1):  # d steps behind: pending[:, d - 1], ..., pending[:, 0] are driven first, oldest first
            pose = torch.zeros_like(twist[:, :1]).expand(-1, 3)
            for k in range(d - 1, -1, -1):
                pose = integrate_exact(pose, pending[:, k], dt)
            c, s = torch.cos(pose[:, 2:]), torch.sin(pose[:, 2:])
            dx, dy = x - pose[:, :1], y - pose[:, 1:2]
            xs.append(c * dx + s * dy)  # the returns in the frame the robot will be in
            ys.append(c * dy - s * dx)
        x, y = torch.cat(xs, 1), torch.cat(ys, 1)
        reach, seen, drive = reach.expand_as(ranges).repeat(1, delay + 1), seen.repeat(1, delay + 1), dt
    for _ in range(passes):
        free = torch.where(seen, arc_free_length(x, y, (twist[:, 1] / v.clamp(min=1e-6))[:, None], reach), math.inf).amin(-1)
        v = torch.where(v > 0, torch.minimum(v, stopping_speed(free, drive, decel)), v)
    return v
