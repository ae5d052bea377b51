"""``cave``: cellular-automaton clutter, merged into boxes (docs/worlds.md, "cave").

Slots (fixed for every difficulty): 4 boundary walls and ``MAX_BOXES`` boxes; a cave with more
boxes loses its smallest ones (1 of 20,000 caves at difficulty 1 had more, none at 0.5)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ..sim import World
from .layout import lerp, runs, take_slots, walled_world

GRID = 20  # cells per side
CELL = 0.5  # m, side of a cell: the cave is GRID * CELL = 10 m square
CA_STEPS = 2  # smoothing steps
MAX_BOXES = 48  # box slots
RESOLUTION = 0.1  # m, placement grid


def params(d: Tensor) -> dict[str, Tensor]:
    """Difficulty ``(B,)`` -> parameters ``(B,)``.

    ``fill``: share of rock cells before smoothing, 0.40 -> 0.52 (after smoothing
    rock covers about 15% of the cave at 0, 28% at 0.5 and 44% at 1, with narrower passages).
    """
    return {"fill": lerp(0.40, 0.52, d)}


def smooth(rock: Tensor) -> Tensor:
    """One cave-rule step on ``rock`` ``(B, G, G)`` bool: rock where >= 5 of the 3 x 3 cells are."""
    count = F.conv2d(F.pad(rock[:, None].float(), (1, 1, 1, 1), value=0.0), rock.new_ones(1, 1, 3, 3, dtype=torch.float32))
    return count[:, 0] >= 5


def rock_boxes(rock: Tensor, origin: float, slots: int) -> tuple[Tensor, Tensor]:
    """Axis-aligned boxes ``(B, slots, 5)`` m and mask covering the rock cells ``(B, G, G)``
    (row ``j`` is y, column ``i`` is x; cell ``(j, i)`` spans ``origin + [i, i + 1] * CELL`` in x)."""
    b, g, _ = rock.shape
    row_start, width = runs(rock)  # (B, G, G): runs along x
    col_start, height = runs(torch.where(row_start, width, 0).transpose(1, 2))  # (B, x, y): equal runs up y
    x, y = torch.meshgrid(torch.arange(g, device=rock.device), torch.arange(g, device=rock.device), indexing="ij")
    wide = width.transpose(1, 2)  # (B, x, y)
    dtype = torch.float32
    cx = origin + (x + wide / 2) * CELL
    cy = origin + (y + height / 2) * CELL
    boxes = torch.stack((cx.to(dtype), cy.to(dtype), wide * CELL / 2, height * CELL / 2, torch.zeros_like(cx, dtype=dtype)), -1)
    idx, valid = take_slots((wide * height * col_start).reshape(b, -1).to(dtype), slots)
    return boxes.reshape(b, -1, 5).gather(1, idx[..., None].expand(-1, -1, 5)) * valid[..., None], valid


def layout(d: Tensor, generator: torch.Generator) -> tuple[World, Tensor]:
    """Caves at difficulties ``d`` ``(B,)``: the world and its bounds ``(B, 4)`` m."""
    b, like, dev = d.shape[0], d, d.device
    rock = torch.rand((b, GRID, GRID), generator=generator, device=dev) < params(d)["fill"][:, None, None].float()
    for _ in range(CA_STEPS):
        rock = smooth(rock)
    half = torch.full((b,), GRID * CELL / 2, dtype=like.dtype, device=dev)
    boxes, box_mask = rock_boxes(rock, -GRID * CELL / 2, MAX_BOXES)
    return walled_world(half, half, boxes=(boxes.to(like.dtype), box_mask))
