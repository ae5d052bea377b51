"""``forest``: a square field of posts (circles), thin and dense at high difficulty.

Posts are scattered uniformly inside the walls and may overlap (two overlapping posts are one
thicker obstacle). Thin posts test whether a policy sees objects that only a
few lidar rays hit.

Slots (fixed for every difficulty): 4 boundary walls and ``MAX_POSTS`` circles;
an env with fewer posts masks the rest off.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..sim import World
from .layout import lerp, uniform, walled_world

SIDE = 10.0  # m, the forest is SIDE x SIDE
MAX_DENSITY = 0.7  # posts per m^2 at difficulty 1
MAX_POSTS = round(MAX_DENSITY * SIDE * SIDE)
RESOLUTION = 0.1  # m, placement grid


def params(d: Tensor) -> dict[str, Tensor]:
    """Difficulty ``(B,)`` -> parameters ``(B,)``.

    ``density``: posts per m^2, 0.15 -> 0.7 (15 -> 70 posts). Post radii are uniform
    in [``radius_min``, ``radius_max``]: ``radius_min`` 0.15 -> 0.05 m, ``radius_max``
    0.35 -> 0.15 m.
    """
    density = lerp(0.15, MAX_DENSITY, d)
    return {
        "density": density,
        "posts": torch.round(density * SIDE * SIDE).long(),
        "radius_min": lerp(0.15, 0.05, d),
        "radius_max": lerp(0.35, 0.15, d),
    }


def layout(d: Tensor, generator: torch.Generator) -> tuple[World, Tensor]:
    """Forests at difficulties ``d`` ``(B,)``: the world and its bounds ``(B, 4)`` m."""
    p = params(d)
    b, like, dev = d.shape[0], d, d.device
    shape = (b, MAX_POSTS)
    radius = uniform(p["radius_min"][:, None], p["radius_max"][:, None], shape, generator, like)
    reach = (SIDE / 2 - radius)[..., None]  # posts stay inside the walls
    xy = uniform(-reach, reach, (b, MAX_POSTS, 2), generator, like)
    on = torch.arange(MAX_POSTS, device=dev) < p["posts"][:, None]
    half = torch.full((b,), SIDE / 2, dtype=like.dtype, device=dev)
    return walled_world(half, half, circles=(torch.cat((xy, radius[..., None]), -1) * on[..., None], on))
