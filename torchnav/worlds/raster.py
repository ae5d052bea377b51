"""Clearance of a batch of worlds sampled on a grid, in torch, for threshold tests.

Blocks of ``block x block`` cells: a coarse pass from each block centre keeps the obstacles that
can lie within ``reach`` of the block, a fine pass measures its cells against those only. The
result is the true clearance wherever that is at most ``reach`` and exceeds ``reach`` elsewhere
(all a test ``clearance > t`` with ``t <= reach`` needs), from :func:`torchnav.sim.points_clearance`."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..sim import World, points_clearance

_KINDS = (("segments", "segment_mask"), ("circles", "circle_mask"), ("boxes", "box_mask"))


def _one_kind(world: World, kind: str, obstacles: Tensor, mask: Tensor) -> World:
    """A :class:`World` holding only ``obstacles`` ``(n, N, width)`` of ``kind``."""
    n = obstacles.shape[0]
    parts = {}
    for key, mkey in _KINDS:
        t = getattr(world, key)
        if key == kind:
            parts[key], parts[mkey] = obstacles, mask
        else:
            parts[key], parts[mkey] = t.new_zeros(n, 0, t.shape[-1]), mask.new_zeros(n, 0)
    return World(**parts, batch_size=[n], device=obstacles.device)


def _kind_clearance(world: World, kind: str, centres: Tensor, cells: Tensor, reach: float) -> Tensor | None:
    """Clearance ``(B * P, C)`` of the cells ``cells`` ``(B * P, C, 2)`` of ``P`` blocks per env to
    the obstacles of ``kind`` within ``reach`` of the block centres ``(B, P, 2)`` (``+inf`` where
    there are none); None when no block has any.

    Blocks are grouped by how many obstacles are near them (1, 2, 3-4, 5-8, ...), and each
    group measures only that many, so a few crowded blocks do not cost every block.
    """
    obs, mask = getattr(world, kind), getattr(world, dict(_KINDS)[kind])
    b, n = mask.shape
    p = centres.shape[1]
    if n == 0:
        return None
    # Distance of every centre to each obstacle on its own: one single-obstacle world per (env, slot).
    single = _one_kind(world, kind, obs.reshape(b * n, 1, -1), mask.reshape(b * n, 1))
    d = points_clearance(centres[:, None].expand(b, n, p, 2).reshape(b * n, p, 2), single).reshape(b, n, p)
    count = (d <= reach).sum(1).reshape(-1)  # (B * P,)
    most = int(count.max())
    if most == 0:
        return None
    nearest = d.topk(most, dim=1, largest=False).indices.transpose(1, 2).reshape(b * p, most)  # slots, nearest first
    env = torch.arange(b, device=obs.device).repeat_interleave(p)
    out = torch.full(cells.shape[:2], math.inf, dtype=cells.dtype, device=cells.device)
    fewer, k = 0, 1
    while fewer < most:
        sel = ((count > fewer) & (count <= k)).nonzero()[:, 0]
        if sel.numel():
            slots = nearest[sel, : min(k, most)]
            near_mask = mask[env[sel, None], slots] & (torch.arange(slots.shape[1], device=obs.device) < count[sel, None])
            out[sel] = points_clearance(cells[sel], _one_kind(world, kind, obs[env[sel, None], slots], near_mask))
        fewer, k = k, 2 * k
    return out


def clearance_grid(world: World, origin: tuple[float, float], shape: tuple[int, int], resolution: float, reach: float, block: int = 8) -> Tensor:
    """Clearance in m of ``world`` (batch ``B``) at the cell centres of a grid, ``(B, H, W)``.

    Cell ``(j, i)`` has its centre at ``origin + ((i + 0.5), (j + 0.5)) * resolution``.
    Exact where the clearance is ``<= reach`` m; ``> reach`` (possibly ``+inf``)
    elsewhere. ``block`` is the side of the coarse blocks in cells.
    """
    b = world.batch_size[0]
    h, w = shape
    hb, wb = -(-h // block), -(-w // block)
    like = world.segments
    x0, y0 = origin
    side = block * resolution
    cx = x0 + (torch.arange(wb, dtype=like.dtype, device=like.device) + 0.5) * side
    cy = y0 + (torch.arange(hb, dtype=like.dtype, device=like.device) + 0.5) * side
    centres = torch.stack(torch.meshgrid(cy, cx, indexing="ij")[::-1], -1).reshape(1, -1, 2).expand(b, -1, 2)
    # Offsets of a block's cells from its centre: (block * block, 2).
    o = (torch.arange(block, dtype=like.dtype, device=like.device) - (block - 1) / 2) * resolution
    offsets = torch.stack(torch.meshgrid(o, o, indexing="ij")[::-1], -1).reshape(-1, 2)
    cells = (centres[:, :, None, :] + offsets).reshape(b * hb * wb, block * block, 2)
    best = torch.full(cells.shape[:2], math.inf, dtype=like.dtype, device=like.device)
    half_diag = (block - 1) / 2 * resolution * math.sqrt(2.0)
    for kind, _ in _KINDS:
        got = _kind_clearance(world, kind, centres, cells, reach + half_diag)
        if got is not None:
            best = torch.minimum(best, got)
    # (B, hb, wb, block_y, block_x) -> (B, hb * block, wb * block), then crop.
    grid = best.reshape(b, hb, wb, block, block).permute(0, 1, 3, 2, 4).reshape(b, hb * block, wb * block)
    return grid[:, :h, :w]
