"""``open``: a large open room with a few obstacles, for long ranges and long goals.

A square room whose side grows with difficulty (10 -> 20 m), holding a few
oriented boxes and circles scattered uniformly. With the default 10 m lidar,
much of a 20 m room is out of range, so a policy has to head for goals it
cannot see walls around.

Slots (fixed for every difficulty): 4 boundary walls, ``MAX_BOXES`` boxes and
``MAX_CIRCLES`` circles; unused ones are masked off.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..sim import World
from .layout import lerp, uniform, walled_world

MAX_BOXES = 8
MAX_CIRCLES = 4
BOX_HALF = (0.2, 1.0)  # m, range of box half extents
CIRCLE_RADIUS = (0.2, 0.6)  # m
EDGE_GAP = 1.5  # m, obstacle centres keep this far from the walls (boxes stay inside the room)
RESOLUTION = 0.2  # m, placement grid (the room is large and its gaps are wide)


def params(d: Tensor) -> dict[str, Tensor]:
    """Difficulty ``(B,)`` -> parameters ``(B,)``.

    ``side``: room side 10 -> 20 m. ``boxes``: 2 -> 8 oriented boxes (half extents
    uniform in 0.2 - 1.0 m). ``circles``: 1 -> 4 circles (radius 0.2 - 0.6 m).
    """
    return {
        "side": lerp(10.0, 20.0, d),
        "boxes": torch.round(lerp(2.0, MAX_BOXES, d)).long(),
        "circles": torch.round(lerp(1.0, MAX_CIRCLES, d)).long(),
    }


def layout(d: Tensor, generator: torch.Generator) -> tuple[World, Tensor]:
    """Open rooms at difficulties ``d`` ``(B,)``: the world and its bounds ``(B, 4)`` m."""
    p = params(d)
    b, like, dev = d.shape[0], d, d.device
    half = p["side"] / 2
    span = (half - EDGE_GAP)[:, None, None]
    box_xy = uniform(-span, span, (b, MAX_BOXES, 2), generator, like)
    box_half = uniform(*BOX_HALF, (b, MAX_BOXES, 2), generator, like)
    yaw = uniform(-math.pi, math.pi, (b, MAX_BOXES, 1), generator, like)
    circle_xy = uniform(-span, span, (b, MAX_CIRCLES, 2), generator, like)
    radius = uniform(*CIRCLE_RADIUS, (b, MAX_CIRCLES, 1), generator, like)
    box_on = torch.arange(MAX_BOXES, device=dev) < p["boxes"][:, None]
    circle_on = torch.arange(MAX_CIRCLES, device=dev) < p["circles"][:, None]
    return walled_world(half, half, circles=(torch.cat((circle_xy, radius), -1) * circle_on[..., None], circle_on),
                        boxes=(torch.cat((box_xy, box_half, yaw), -1) * box_on[..., None], box_on))
