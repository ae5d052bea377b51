"""Moving obstacles: discs with velocities, stepped inside the batched simulator step.

Each env holds ``M`` mover slots as one ``(B, M, 9)`` tensor (``SimState.movers``)
with a ``(B, M)`` bool mask; the columns are ``MOVER_FIELDS``:

    x, y (m), vx, vy (m/s), radius (m), xmin, ymin, xmax, ymax (m: the region)

A mover drives at constant velocity; inside a finite region it bounces off the
region's edges (its disc stays inside: the position is mirrored at ``edge +- radius``
and that velocity component flips). An unbounded region (``+-inf``, the default)
gives plain constant-velocity motion. Masked slots move too but are seen by
nothing. The lidar, the camera and collision treat a mover like a static circle
at its position after the step.
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from .state import World

MOVER_FIELDS = ("x", "y", "vx", "vy", "radius", "xmin", "ymin", "xmax", "ymax")
N_MOVER_FIELDS = len(MOVER_FIELDS)


def make_movers(
    batch_size: int,
    discs: Sequence[Sequence[float]] | Tensor | None = None,
    region: Sequence[float] | None = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> tuple[Tensor, Tensor]:
    """The same movers in every env: ``discs`` ``(M, 5)`` rows ``[x, y, vx, vy, radius]``,
    bouncing inside ``region`` ``(xmin, ymin, xmax, ymax)`` (``None``: unbounded, constant velocity).

    Returns ``movers`` ``(B, M, 9)`` and ``mover_mask`` ``(B, M)`` (all True)."""
    d = torch.as_tensor(discs if discs is not None and len(discs) else [], dtype=dtype, device=device)
    d = d.reshape(0, 5) if d.numel() == 0 else d
    if d.dim() != 2 or d.shape[1] != 5:
        raise ValueError(f"movers must have shape (M, 5) [x, y, vx, vy, radius], got {tuple(d.shape)}")
    if (d[:, 4] <= 0).any() or not torch.isfinite(d).all():
        raise ValueError("movers: radius must be > 0 and every value finite")
    reg = (-math.inf, -math.inf, math.inf, math.inf) if region is None else tuple(float(v) for v in region)
    if len(reg) != 4 or not (reg[0] < reg[2] and reg[1] < reg[3]):
        raise ValueError(f"movers: region must be (xmin, ymin, xmax, ymax) with xmin < xmax and ymin < ymax, got {region!r}")
    if d.shape[0] and region is not None:
        r = d[:, 4]
        inside = (d[:, 0] - r >= reg[0]) & (d[:, 0] + r <= reg[2]) & (d[:, 1] - r >= reg[1]) & (d[:, 1] + r <= reg[3])
        if not inside.all():
            raise ValueError(f"movers: every disc must start inside its region {reg}")
    rows = torch.cat((d, torch.tensor(reg, dtype=dtype, device=device).expand(d.shape[0], 4)), 1)
    return rows.unsqueeze(0).expand(batch_size, -1, -1).clone(), torch.ones(batch_size, d.shape[0], dtype=torch.bool, device=device)


def no_movers(batch_size: int, like: Tensor) -> tuple[Tensor, Tensor]:
    """Zero mover slots: ``(B, 0, 9)`` and ``(B, 0)``."""
    return like.new_zeros(batch_size, 0, N_MOVER_FIELDS), torch.zeros(batch_size, 0, dtype=torch.bool, device=like.device)


def step_movers(movers: Tensor, dt: float) -> Tensor:
    """Every mover ``(B, M, 9)`` advanced by ``dt`` s: constant velocity, bouncing off its region. Pure."""
    if movers.shape[1] == 0:
        return movers
    x, y, vx, vy, r, xmin, ymin, xmax, ymax = movers.unbind(-1)
    x, vx = _bounce(x + vx * dt, vx, xmin + r, xmax - r)
    y, vy = _bounce(y + vy * dt, vy, ymin + r, ymax - r)
    return torch.stack((x, y, vx, vy, r, xmin, ymin, xmax, ymax), -1)


def _bounce(p: Tensor, v: Tensor, lo: Tensor, hi: Tensor) -> tuple[Tensor, Tensor]:
    """Mirror positions that left ``[lo, hi]`` back inside and flip their velocity (one reflection per
    step: a mover crosses its region in more than one step)."""
    below, above = p < lo, p > hi
    p = torch.where(below, 2 * lo - p, torch.where(above, 2 * hi - p, p))
    v = torch.where(below | above, -v, v)
    return p, v


def mover_world(movers: Tensor, mask: Tensor) -> World:
    """The movers as a :class:`World` of circles ``[x, y, radius]`` (no walls, no boxes)."""
    b = movers.shape[0]
    return World(
        segments=movers.new_zeros(b, 0, 4), segment_mask=mask[:, :0],
        circles=torch.stack((movers[..., 0], movers[..., 1], movers[..., 4]), -1), circle_mask=mask,
        boxes=movers.new_zeros(b, 0, 5), box_mask=mask[:, :0],
        batch_size=[b], device=movers.device,
    )
