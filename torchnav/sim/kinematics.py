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
    f = free.amin(-1).clamp(min=0.0)
    t = (1 + delay) * dt  # s driven at the commanded speed before braking can start
    if not math.isfinite(decel):
        return f / t
    # the positive root of v^2 / (2 decel) + v t - f = 0, written to stay exact for small f (and inf for f = inf)
    return torch.where(f.isinf(), f, 2 * f / (t + torch.sqrt(t * t + 2 * f / decel)))
