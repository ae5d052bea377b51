"""``fences``: a room crossed by fences (walls or racks) that the robot passes through gaps as narrow as
0.55 m, some split in two by a post (docs/worlds.md, "fences").

Each fence runs from wall to wall and has a few openings, one in each equal section of its length;
an opening is one gap, or a post in its middle with a gap on each side. Every fence of a world runs
the same way (along x, or along y in half the worlds).

Slots (fixed for every difficulty): 4 boundary walls, ``MAX_FENCES * (MAX_GAPS + 1)`` boxes (the
solid pieces of fence ``k`` are boxes ``k * (MAX_GAPS + 1)`` onwards, in order along it) and
``MAX_FENCES * MAX_GAPS`` circles (the post of opening ``j`` of fence ``k`` is circle
``k * MAX_GAPS + j``); unused ones are masked off."""

from __future__ import annotations

import torch
from torch import Tensor

from ..sim import World
from .layout import lerp, uniform, walled_world

MAX_FENCES = 3  # fences at difficulty 2/3 and above
MAX_GAPS = 3  # openings per fence at difficulty 0
POST_RADIUS = (0.1, 0.3)  # m, range of a post's radius
MIN_THICKNESS = 0.1  # m, the thinnest fence (a wall)
FENCE_JITTER = 0.2  # m, a fence moves up to this far from its evenly spaced place
MIN_PIECE = 0.05  # m, shorter solid pieces are left out
RESOLUTION = 0.05  # m, placement grid: a 0.55 m gap leaves a 0.08 m band of safe cell centres, wider than a cell


def params(d: Tensor) -> dict[str, Tensor]:
    """Difficulty ``(B,)`` -> parameters ``(B,)``.

    ``side``: room side 6 -> 10 m. ``fences``: 1 for d < 1/3, 2 below 2/3, then 3. ``gaps``: openings
    per fence, 3 -> 1 (rounded). Each gap's width is uniform in [``gap_min``, ``gap_max``]: ``gap_min``
    0.9 -> 0.55 m, ``gap_max`` 1.4 -> 0.9 m. ``post_prob``: chance that an opening holds a post
    (radius 0.1 - 0.3 m) with a gap on each side, 0.2 -> 0.6. ``thickness_max``: fences are uniform
    in [0.1, ``thickness_max``] m thick, 0.3 -> 1.0 m (walls to racks).
    """
    return {
        "side": lerp(6.0, 10.0, d),
        "fences": (1 + torch.floor(3 * d)).clamp(max=MAX_FENCES).long(),
        "gaps": torch.round(lerp(MAX_GAPS, 1.0, d)).long(),
        "gap_min": lerp(0.9, 0.55, d),
        "gap_max": lerp(1.4, 0.9, d),
        "post_prob": lerp(0.2, 0.6, d),
        "thickness_max": lerp(0.3, 1.0, d),
    }


def layout(d: Tensor, generator: torch.Generator) -> tuple[World, Tensor]:
    """Rooms of fences at difficulties ``d`` ``(B,)``: the world and its bounds ``(B, 4)`` m."""
    p = params(d)
    b, like, dev = d.shape[0], d, d.device
    f_, g_ = MAX_FENCES, MAX_GAPS
    half = p["side"] / 2
    h = half[:, None, None]  # (B, 1, 1)
    n, m = p["fences"][:, None], p["gaps"][:, None, None]  # (B, 1), (B, 1, 1)
    # Fence k of n sits at the k-th of n evenly spaced places across the room, jittered.
    k = torch.arange(f_, device=dev, dtype=like.dtype)
    across = -half[:, None] + (k + 1) * 2 * half[:, None] / (n + 1) + uniform(-FENCE_JITTER, FENCE_JITTER, (b, f_), generator, like)
    thickness = uniform(MIN_THICKNESS, p["thickness_max"][:, None], (b, f_), generator, like)
    # Openings: a gap, or a post with a gap on each side; one opening in each of m equal sections.
    gap = uniform(p["gap_min"][:, None, None], p["gap_max"][:, None, None], (b, f_, g_), generator, like)
    radius = uniform(*POST_RADIUS, (b, f_, g_), generator, like)
    section = 2 * h / m
    post = (uniform(0.0, 1.0, (b, f_, g_), generator, like) < p["post_prob"][:, None, None]) & (2 * (gap + radius) <= section)
    width = torch.where(post, 2 * (gap + radius), gap)  # at most a section, so openings never overlap
    j = torch.arange(g_, device=dev)
    real = j < m  # (B, 1, G)
    start = -h + j.to(like.dtype) * section + uniform(0.0, 1.0, (b, f_, g_), generator, like) * (section - width).clamp(min=0)
    start = torch.where(real, start, h)  # unused openings sit at the fence's far end, empty
    end = torch.where(real, start + width, h)
    # Solid pieces between openings: [-h, start_0], [end_0, start_1], ..., [end_(G-1), h].
    lo = torch.cat((-h.expand(b, f_, 1), end), 2)
    hi = torch.cat((start, h.expand(b, f_, 1)), 2)  # (B, F, G + 1)
    fence_on = (torch.arange(f_, device=dev) < n)[..., None]  # (B, F, 1)
    piece_on = fence_on & (hi - lo > MIN_PIECE)
    # Laid out along x, each fence at y = across: a piece's centre, half extents and yaw 0.
    fence_y = across[..., None].expand(b, f_, g_ + 1)
    pieces = torch.stack(((lo + hi) / 2, fence_y, ((hi - lo) / 2).clamp(min=0), (thickness / 2)[..., None].expand_as(fence_y),
                          torch.zeros_like(fence_y)), -1)
    post_on = fence_on & real & post
    posts = torch.stack(((start + end) / 2, across[..., None].expand(b, f_, g_), radius), -1)
    # Half the worlds run their fences along y: swap x and y of every centre and half extent.
    turn = (uniform(0.0, 1.0, (b,), generator, like) < 0.5)[:, None, None, None]
    pieces = torch.where(turn, pieces[..., [1, 0, 3, 2, 4]], pieces)
    posts = torch.where(turn, posts[..., [1, 0, 2]], posts)
    boxes = (pieces.reshape(b, -1, 5) * piece_on.reshape(b, -1, 1), piece_on.reshape(b, -1))
    circles = (posts.reshape(b, -1, 3) * post_on.reshape(b, -1, 1), post_on.reshape(b, -1))
    return walled_world(half, half, circles=circles, boxes=boxes)
