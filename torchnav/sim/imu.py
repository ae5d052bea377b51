"""A planar IMU: body-frame linear acceleration and yaw rate from the kinematics.

Forward ``(v_new - v_old) / dt``, left ``v * omega`` (centripetal), gyro ``omega``; no gravity. A
reading is ``true + bias + noise`` (bias random walk and white noise from the step's generator; none
without one), sample-and-hold at a finite ``rate``. The model in full: docs/sim.md, "IMU"."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .params import ImuParams

IMU_FIELDS = ("accel_x", "accel_y", "yaw_rate")  # the reading's columns: m/s^2, m/s^2, rad/s


def imu_truth(vel: Tensor, prev_vel: Tensor, dt: float) -> Tensor:
    """Noise-free body-frame reading ``(B, 3)`` ``[a_x, a_y, omega]`` for the twist ``vel`` ``(B, 2)``
    applied after ``prev_vel`` ``(B, 2)`` over ``dt`` s."""
    v, w = vel.unbind(-1)
    return torch.stack(((v - prev_vel[:, 0]) / dt, v * w, w), dim=-1)


def step_imu(
    reading: Tensor, bias: Tensor, vel: Tensor, prev_vel: Tensor, time: Tensor, imu: ImuParams, dt: float,
    generator: torch.Generator | None,
) -> tuple[Tensor, Tensor]:
    """The IMU's new reading and bias ``(B, 3)`` each after a step that applied ``vel`` after ``prev_vel``
    and started at ``time`` ``(B,)`` s. Pure; no host synchronisation."""
    truth = imu_truth(vel, prev_vel, dt)
    std = (imu.accel_noise, imu.accel_noise, imu.gyro_noise)
    walk = (imu.accel_bias_walk, imu.accel_bias_walk, imu.gyro_bias_walk)
    if generator is not None and any(walk):
        scale = torch.tensor(walk, dtype=vel.dtype, device=vel.device) * math.sqrt(dt)
        bias = bias + scale * torch.randn(bias.shape, generator=generator, dtype=bias.dtype, device=bias.device)
    new = truth + bias
    if generator is not None and any(std):
        scale = torch.tensor(std, dtype=vel.dtype, device=vel.device)
        new = new + scale * torch.randn(new.shape, generator=generator, dtype=new.dtype, device=new.device)
    if math.isfinite(imu.rate):
        # A sample tick k / rate falls in (t, t + dt]: the reading updates, else it holds.
        ticked = torch.floor((time + dt) * imu.rate + 1e-6) > torch.floor(time * imu.rate + 1e-6)
        new = torch.where(ticked.unsqueeze(-1), new, reading)
    return new, bias
