"""``rooms``: an office of rooms on a grid, separated by walls with doors, some furnished (docs/worlds.md, "rooms").

Slots (fixed for every difficulty): 4 boundary walls, then 2 segments per interior wall
(``MAX_ROOMS * (MAX_ROOMS - 1) * 2`` walls, vertical ones first): segment ``4 + 2k`` runs from the
wall's start to its door (or along the whole wall when it has none, and then ``4 + 2k + 1`` is
masked off). One box per room."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..sim import World
from .layout import grid_edges, lerp, random_spanning_tree, uniform, walled_world

MAX_ROOMS = 4  # rooms per side at difficulty 1
ROOM_SIZE = (2.5, 4.0)  # m, range of a column's width and a row's height
DOOR_END_GAP = 0.3  # m, least wall left between a door and a wall's end
FURNITURE_GAP = 1.0  # m, least gap between furniture and any wall
FURNITURE_HALF = (0.2, 0.6)  # m, range of furniture half extents (before shrinking to fit)
RESOLUTION = 0.125  # m, placement grid: a 0.8 m door leaves a 0.22 m band of safe cell centres, wider than a cell


def params(d: Tensor) -> dict[str, Tensor]:
    """Difficulty ``(B,)`` -> parameters ``(B,)``.

    ``rooms_per_side``: 2 for d < 1/3, 3 below 2/3, then 4. ``door_width``: 1.6 -> 0.8 m.
    ``extra_door_prob``: chance that a wall off the spanning tree gets a door too
    (loops), 0.5 -> 0.1. ``furniture_prob``: chance that a room is furnished, 0.2 -> 0.9.
    """
    return {
        "rooms_per_side": (2 + torch.floor(3 * d)).clamp(max=MAX_ROOMS).long(),
        "door_width": lerp(1.6, 0.8, d),
        "extra_door_prob": lerp(0.5, 0.1, d),
        "furniture_prob": lerp(0.2, 0.9, d),
    }


def _edges_along(sizes: Tensor, n: Tensor) -> Tensor:
    """Cumulative wall positions ``(B, MAX_ROOMS + 1)`` m of columns (or rows) centred on 0;
    sizes past an env's ``n`` rooms count 0."""
    sizes = torch.where(torch.arange(MAX_ROOMS, device=sizes.device) < n[:, None], sizes, 0.0)
    edges = torch.cat((sizes.new_zeros(sizes.shape[0], 1), sizes.cumsum(1)), 1)
    return edges - edges[:, -1:] / 2


def _furniture(xe: Tensor, ye: Tensor, active: Tensor, prob: Tensor, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """One optional box per room ``(B, R, 5)`` and its mask ``(B, R)``."""
    b, like = xe.shape[0], xe
    r = MAX_ROOMS * MAX_ROOMS
    row, col = torch.arange(r, device=like.device) // MAX_ROOMS, torch.arange(r, device=like.device) % MAX_ROOMS
    x0, x1, y0, y1 = xe[:, col], xe[:, col + 1], ye[:, row], ye[:, row + 1]
    hx, hy = uniform(*FURNITURE_HALF, (b, r), generator, like), uniform(*FURNITURE_HALF, (b, r), generator, like)
    yaw = uniform(-math.pi, math.pi, (b, r), generator, like)
    # Shrink to fit: the circumscribed circle stays FURNITURE_GAP m clear of the room's walls.
    room_half = torch.minimum(x1 - x0, y1 - y0) / 2
    circ = torch.hypot(hx, hy)
    scale = ((room_half - FURNITURE_GAP) / circ).clamp(max=1.0)
    hx, hy, circ = hx * scale, hy * scale, circ * scale
    cx = (x0 + x1) / 2 + uniform(-1.0, 1.0, (b, r), generator, like) * ((x1 - x0) / 2 - FURNITURE_GAP - circ).clamp(min=0)
    cy = (y0 + y1) / 2 + uniform(-1.0, 1.0, (b, r), generator, like) * ((y1 - y0) / 2 - FURNITURE_GAP - circ).clamp(min=0)
    on = active & (uniform(0.0, 1.0, (b, r), generator, like) < prob[:, None]) & (scale > 0)
    return torch.stack((cx, cy, hx, hy, yaw), -1), on


def layout(d: Tensor, generator: torch.Generator) -> tuple[World, Tensor]:
    """Offices at difficulties ``d`` ``(B,)``: the world and its bounds ``(B, 4)`` m."""
    p = params(d)
    b, like, dev = d.shape[0], d, d.device
    n = p["rooms_per_side"]
    xe = _edges_along(uniform(*ROOM_SIZE, (b, MAX_ROOMS), generator, like), n)
    ye = _edges_along(uniform(*ROOM_SIZE, (b, MAX_ROOMS), generator, like), n)
    cells = torch.arange(MAX_ROOMS * MAX_ROOMS, device=dev)
    cell_on = ((cells // MAX_ROOMS)[None] < n[:, None]) & ((cells % MAX_ROOMS)[None] < n[:, None])  # (B, R)
    a, c, vertical = grid_edges(MAX_ROOMS, MAX_ROOMS, dev)
    wall_on = cell_on[:, a] & cell_on[:, c]  # (B, E)
    tree = random_spanning_tree(a, c, wall_on, MAX_ROOMS * MAX_ROOMS, generator)
    e = a.shape[0]
    door = tree | (wall_on & (uniform(0.0, 1.0, (b, e), generator, like) < p["extra_door_prob"][:, None]))
    # Wall k separates cell a[k] from its right (vertical) or upper neighbour c[k].
    ra, ca = a // MAX_ROOMS, a % MAX_ROOMS
    x0 = torch.where(vertical, xe[:, ca + 1], xe[:, ca])
    y0 = torch.where(vertical, ye[:, ra], ye[:, ra + 1])
    p0, p1 = torch.stack((x0, y0), -1), torch.stack((xe[:, ca + 1], ye[:, ra + 1]), -1)  # (B, E, 2)
    length = (p1 - p0).norm(dim=-1).clamp(min=1e-6)
    unit = (p1 - p0) / length[..., None]
    width = p["door_width"][:, None].expand(b, e)
    offset = DOOR_END_GAP + uniform(0.0, 1.0, (b, e), generator, like) * (length - 2 * DOOR_END_GAP - width).clamp(min=0)
    first_end = torch.where(door[..., None], p0 + unit * offset[..., None], p1)
    second_start = p0 + unit * (offset + width)[..., None]
    walls = torch.stack((torch.cat((p0, first_end), -1), torch.cat((second_start, p1), -1)), 2).reshape(b, 2 * e, 4)
    wall_mask = torch.stack((wall_on, wall_on & door), 2).reshape(b, 2 * e)
    furniture = _furniture(xe, ye, cell_on, p["furniture_prob"], generator)
    return walled_world(xe[:, -1], ye[:, -1], segments=(walls, wall_mask), boxes=furniture)
