"""Domain randomisation: per-env robot and sensor parameters that vary between episodes.

An :class:`EnvParams` holds, for every env, the quantities ``SimParams`` gives as one float
(limits, actuator delay, wheel noise, the lidar's noise, dropout, offset and range, the robot's
radius); passed to ``step(..., env_params=...)`` and ``init_state`` they replace ``SimParams``'
values env by env. :func:`sample_env_params` draws them from ranges (``RANDOMIZED``) with a
generator. What each one does in the step: docs/sim.md, "Domain randomisation"."""

from __future__ import annotations

import math
from typing import Mapping

import torch
from tensordict import tensorclass
from torch import Tensor

from .params import SimParams

RANDOMIZED = (
    "v_max", "omega_max", "lin_acc_max", "ang_acc_max", "delay", "wheel_noise",
    "range_noise", "dropout", "angle_offset", "max_range", "robot_radius",
)


@tensorclass
class EnvParams:
    """Per-env parameters, each ``(B,)`` (``delay`` int64 steps, the others floats in SI units)."""

    v_max: Tensor
    omega_max: Tensor
    lin_acc_max: Tensor
    ang_acc_max: Tensor
    delay: Tensor
    wheel_noise: Tensor
    range_noise: Tensor
    dropout: Tensor
    angle_offset: Tensor
    max_range: Tensor
    robot_radius: Tensor


def nominal_env_params(params: SimParams, batch_size: int, like: Tensor) -> EnvParams:
    """``params``' own values for every env (no delay, no wheel noise, no offset or dropout)."""
    full = lambda v: torch.full((batch_size,), float(v), dtype=like.dtype, device=like.device)  # noqa: E731
    return EnvParams(
        v_max=full(params.v_max), omega_max=full(params.omega_max), lin_acc_max=full(params.lin_acc_max),
        ang_acc_max=full(params.ang_acc_max), delay=torch.zeros(batch_size, dtype=torch.int64, device=like.device),
        wheel_noise=full(0.0), range_noise=full(params.lidar.noise_std), dropout=full(0.0), angle_offset=full(0.0),
        max_range=full(params.lidar.max_range), robot_radius=full(params.robot_radius),
        batch_size=[batch_size], device=like.device,
    )


def check_ranges(ranges: Mapping[str, tuple[float, float] | None], params: SimParams) -> None:
    """Raise a ValueError naming the first range that is unknown, reversed or out of its domain."""
    for name, r in ranges.items():
        if name not in RANDOMIZED:
            raise ValueError(f"randomize: unknown parameter {name!r}; known: {', '.join(RANDOMIZED)}")
        if r is None:
            continue
        lo, hi = r
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"randomize.{name}: expected finite [min, max] with min <= max, got {list(r)}")
        if name in ("v_max", "lin_acc_max", "ang_acc_max", "max_range", "robot_radius") and lo <= 0:
            raise ValueError(f"randomize.{name}: must be > 0, got {list(r)}")
        if name in ("omega_max", "wheel_noise", "range_noise", "delay") and lo < 0:
            raise ValueError(f"randomize.{name}: must be >= 0, got {list(r)}")
        if name == "dropout" and not (0 <= lo and hi <= 1):
            raise ValueError(f"randomize.dropout: must lie in [0, 1], got {list(r)}")
        if name == "delay" and not (float(lo).is_integer() and float(hi).is_integer()):
            raise ValueError(f"randomize.delay: whole steps expected, got {list(r)}")
        if name == "max_range" and not (params.lidar.min_range < lo and hi <= params.lidar.max_range):
            raise ValueError(f"randomize.max_range: must lie in (lidar.min_range, lidar.max_range] = ({params.lidar.min_range}, {params.lidar.max_range}], got {list(r)}")


def max_delay(ranges: Mapping[str, tuple[float, float] | None]) -> int:
    """Longest actuator delay the ranges allow (the length of ``SimState.cmd_queue``)."""
    r = ranges.get("delay")
    return int(r[1]) if r is not None else 0


def sample_env_params(ranges: Mapping[str, tuple[float, float] | None], params: SimParams, batch_size: int,
                      generator: torch.Generator, like: Tensor) -> EnvParams:
    """Per-env parameters drawn uniformly from ``ranges`` (name -> ``(min, max)``; missing or
    None: ``params``' value); ``delay`` uniformly among the whole steps of its range.
    Every parameter draws from ``generator`` whether randomised or not, so switching one off
    leaves the others' draws unchanged."""
    check_ranges(ranges, params)
    out = nominal_env_params(params, batch_size, like).to_dict()
    for name in RANDOMIZED:
        u = torch.rand(batch_size, generator=generator, dtype=like.dtype, device=generator.device).to(like.device)
        r = ranges.get(name)
        if r is None:
            continue
        lo, hi = float(r[0]), float(r[1])
        if name == "delay":
            out[name] = (lo + torch.floor(u * (hi - lo + 1)).clamp(max=hi - lo)).to(torch.int64)
        else:
            out[name] = lo + (hi - lo) * u
    return EnvParams(**out, batch_size=[batch_size], device=like.device)
