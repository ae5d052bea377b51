"""``corridors``: a random maze of corridors of one width (docs/worlds.md, "corridors").

Slots (fixed for every difficulty): 4 boundary walls, then ``MAX_SEGMENTS`` merged walls. An
``n x n`` maze has ``2 n (n - 1)`` wall units between cells, and its spanning tree opens
``n * n - 1`` of them, so at most ``(n - 1) ** 2`` stay closed (loops close none): at most that
many merged walls."""

from __future__ import annotations

import torch
from torch import Tensor

from ..sim import World
from .layout import grid_edges, lerp, random_spanning_tree, runs, take_slots, uniform, walled_world

MAX_CELLS = 9  # cells per side at difficulty 1
MAX_SEGMENTS = (MAX_CELLS - 1) ** 2  # merged interior walls, worst case (module docstring)
RESOLUTION = 0.1  # m, placement grid


def params(d: Tensor) -> dict[str, Tensor]:
    """Difficulty ``(B,)`` -> parameters ``(B,)``.

    ``cells_per_side``: 4 -> 9 (steps of 1 every 1/6 of difficulty); more cells, more turns.
    ``corridor_width``: 2.0 -> 0.8 m. ``loop_prob``: chance that a wall off the spanning
    tree is opened too, 0.2 -> 0.0. The maze is ``cells_per_side * corridor_width`` m
    square (8 m at 0, 7.2 m at 1, 9.8 m at 0.5).
    """
    return {
        "cells_per_side": (4 + torch.floor(6 * d)).clamp(max=MAX_CELLS).long(),
        "corridor_width": lerp(2.0, 0.8, d),
        "loop_prob": lerp(0.2, 0.0, d),
    }


def layout(d: Tensor, generator: torch.Generator) -> tuple[World, Tensor]:
    """Mazes at difficulties ``d`` ``(B,)``: the world and its bounds ``(B, 4)`` m."""
    p = params(d)
    b, like, dev = d.shape[0], d, d.device
    n, width = p["cells_per_side"], p["corridor_width"]
    m = MAX_CELLS
    cells = torch.arange(m * m, device=dev)
    cell_on = ((cells // m)[None] < n[:, None]) & ((cells % m)[None] < n[:, None])
    a, c, _ = grid_edges(m, m, dev)
    wall_on = cell_on[:, a] & cell_on[:, c]
    tree = random_spanning_tree(a, c, wall_on, m * m, generator)
    loops = uniform(0.0, 1.0, wall_on.shape, generator, like) < p["loop_prob"][:, None]
    closed = wall_on & ~tree & ~loops  # (B, E): vertical walls (row-major), then horizontal ones
    nv = m * (m - 1)
    # Grid lines of wall units: vertical line c (between columns c and c+1) has one unit per row.
    lines = torch.cat((closed[:, :nv].reshape(b, m, m - 1).transpose(1, 2), closed[:, nv:].reshape(b, m - 1, m)), 1)  # (B, 2(m-1), m)
    _, length = runs(lines)
    half = n * width / 2
    line_pos = (torch.arange(2 * (m - 1), device=dev) % (m - 1) + 1).to(like.dtype)  # (2(m-1),) in cells
    unit = torch.arange(m, device=dev, dtype=like.dtype)
    w_, h_ = width[:, None, None], half[:, None, None]
    across = (line_pos[None, :, None] * w_ - h_).expand(b, -1, m)  # x of a vertical line, y of a horizontal one
    lo = (unit * w_ - h_).expand(b, 2 * (m - 1), m)  # where each run starts along its line
    hi = lo + length.to(like.dtype) * w_
    vertical = (torch.arange(2 * (m - 1), device=dev) < m - 1)[None, :, None]
    seg = torch.where(
        vertical[..., None],
        torch.stack((across, lo, across, hi), -1),
        torch.stack((lo, across, hi, across), -1),
    ).reshape(b, -1, 4)
    idx, valid = take_slots(length.reshape(b, -1).to(like.dtype), MAX_SEGMENTS)
    walls = seg.gather(1, idx[..., None].expand(-1, -1, 4)) * valid[..., None]
    return walled_world(half, half, segments=(walls, valid))
