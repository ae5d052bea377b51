"""Geodesic distance to the goal, kept per env on a coarse grid: the potential of the
``geodesic`` progress reward (docs/tasks.md, "Rewards").

When a world's start and goal are placed, a second wavefront runs from the goal over the
placement grid, through every cell whose centre a robot may stand on (clearance above its
radius; start and goal placement keep a wider margin). Its distances are sampled at the
centres of a ``cells x cells`` grid laid over the env's bounds (square cells of
``max(width, height) / cells`` m) and stored as int16 centimetres, 8 KB per env at 64 cells.

A position's distance is the least, over the 4 coarse centres around it that a path reaches,
of that centre's distance plus the straight line to it; ``inf`` where none is reached (the robot
hugs a wall closer than the grid resolves). Why that straight line crosses no thin wall: a
centre behind the wall and a robot in front of it are each more than ``robot_radius`` from it,
so more than ``2 * robot_radius`` apart, farther than the farthest of the 4 centres
(``sqrt(2)`` coarse cells: 0.34 m in the largest offices, 0.22 m in 10 m worlds; only
``open`` at 20 m has 0.44 m cells, and its obstacles are solid boxes and discs, not thin walls).
"""

from __future__ import annotations

import functools
import math

import torch
from torch import Tensor

from .wavefront import ORTHO, UNREACHED

GUIDE_CELLS = 64  # coarse cells per side of an env's goal-distance grid
UNKNOWN = torch.iinfo(torch.int16).max  # stored where no path reaches a coarse centre
_CM = 100.0  # stored units per metre
_AROUND = ((0, 0), (1, 0), (0, 1), (1, 1))  # the 4 coarse centres around a position, (col, row) offsets


@functools.cache
def _around(device: torch.device) -> Tensor:
    """:data:`_AROUND` as a ``(4, 2)`` tensor on ``device``, made once (the task's step reads it)."""
    return torch.tensor(_AROUND, device=device)


def coarse_goal_field(
    dist: Tensor, origin: tuple[float, float], resolution: float, bounds: Tensor, cells: int = GUIDE_CELLS,
) -> tuple[Tensor, Tensor]:
    """The goal-distance grids ``(B, cells, cells)`` int16 cm (row = y, col = x; :data:`UNKNOWN`
    where unreached) and their frames ``(B, 3)`` ``[x0, y0, cell m]``, from the wavefront
    ``dist`` ``(B, H, W)`` (units of ``1 / ORTHO`` cell, :data:`~.wavefront.UNREACHED` where
    unreached) on the placement grid whose cell ``(0, 0)`` has its lower-left corner at
    ``origin`` m, cells of ``resolution`` m; ``bounds`` ``(B, 4)`` m per env."""
    b, h, w = dist.shape
    size = (bounds[:, 2:] - bounds[:, :2]).amax(1) / cells  # (B,) m per coarse cell
    frame = torch.cat((bounds[:, :2], size[:, None]), 1)
    k = torch.arange(cells, dtype=bounds.dtype, device=bounds.device) + 0.5
    cx = frame[:, 0, None] + k * size[:, None]  # (B, cells) x of each column's centre
    cy = frame[:, 1, None] + k * size[:, None]
    col = ((cx - origin[0]) / resolution).floor().long()
    row = ((cy - origin[1]) / resolution).floor().long()
    inside = ((col >= 0) & (col < w) & (cx <= bounds[:, 2, None]))[:, None, :] & ((row >= 0) & (row < h) & (cy <= bounds[:, 3, None]))[:, :, None]
    flat = row.clamp(0, h - 1)[:, :, None] * w + col.clamp(0, w - 1)[:, None, :]
    value = dist.reshape(b, -1).gather(1, flat.reshape(b, -1)).reshape(b, cells, cells)
    metres = value.to(torch.float64) * (resolution / ORTHO)
    known = inside & (value < UNREACHED) & (metres * _CM < UNKNOWN)
    field = torch.where(known, (metres * _CM).round(), float(UNKNOWN)).to(torch.int16)
    return field, frame


def goal_distance(field: Tensor, frame: Tensor, goal: Tensor, xy: Tensor) -> Tensor:
    """The geodesic distance ``(B,)`` m from positions ``xy`` ``(B, 2)`` to each env's ``goal``
    ``(B, 2)``, read from its grid (``field`` and ``frame`` of :func:`coarse_goal_field`); ``inf``
    where none of the 4 coarse centres around the position is reached (see the module notes).
    The goal itself counts as a fifth centre, at distance 0, when it is nearer than the farthest
    of the 4 could be (so the distance goes to 0 at the goal, not to a coarse cell's round-off).
    Differentiable in ``xy`` through the straight-line part."""
    g = field.shape[-1]
    size = frame[:, 2:3]
    u = (xy - frame[:, :2]) / size - 0.5  # coarse centres sit at whole numbers
    idx = u.floor().long()[:, None, :] + _around(xy.device)  # (B, 4, 2) [col, row]
    inside = ((idx >= 0) & (idx < g)).all(-1)
    idx = idx.clamp(0, g - 1)
    value = field.reshape(field.shape[0], -1).gather(1, idx[..., 1] * g + idx[..., 0])
    centre = frame[:, None, :2] + (idx.to(xy.dtype) + 0.5) * size[:, None, :]
    delta = xy[:, None, :] - centre
    line = (delta.square().sum(-1) + 1e-12).sqrt()  # no NaN gradient at a centre
    d = torch.where(inside & (value != UNKNOWN), value.to(xy.dtype) / _CM + line, math.inf).amin(1)
    to_goal = ((xy - goal).square().sum(-1) + 1e-12).sqrt()
    return torch.where(to_goal < size[:, 0] * math.sqrt(2.0), torch.minimum(d, to_goal), d)
