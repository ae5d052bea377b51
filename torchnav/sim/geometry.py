"""Distances from points and robot discs to obstacles, and box corners."""

from __future__ import annotations

import torch
from torch import Tensor

from .math import rotate, safe_hypot
from .state import World


def box_corners(boxes: Tensor) -> Tensor:
    """Corners of oriented boxes ``(..., 5)`` ``[cx, cy, hx, hy, yaw]`` -> ``(..., 4, 2)``, CCW."""
    cx, cy, hx, hy, yaw = boxes.unbind(-1)
    sx = torch.stack((hx, -hx, -hx, hx), dim=-1)
    sy = torch.stack((hy, hy, -hy, -hy), dim=-1)
    rx, ry = rotate(sx, sy, yaw.unsqueeze(-1))
    return torch.stack((rx + cx.unsqueeze(-1), ry + cy.unsqueeze(-1)), dim=-1)


def segment_distance(px: Tensor, py: Tensor, seg: Tensor) -> Tensor:
    """Distance from points ``(px, py)`` to segments ``seg[..., 4]`` (all broadcast); gradient-safe."""
    ax, ay, bx, by = seg.unbind(-1)
    ex, ey = bx - ax, by - ay
    wx, wy = px - ax, py - ay
    ee = ex * ex + ey * ey
    degenerate = ee <= 1e-12
    t = ((wx * ex + wy * ey) / torch.where(degenerate, torch.ones_like(ee), ee)).clamp(0.0, 1.0)
    t = torch.where(degenerate, torch.zeros_like(t), t)
    return safe_hypot(wx - t * ex, wy - t * ey)


def _circle_dist(px: Tensor, py: Tensor, circ: Tensor) -> Tensor:
    return safe_hypot(px - circ[..., 0], py - circ[..., 1]) - circ[..., 2]


def _box_dist(px: Tensor, py: Tensor, box: Tensor) -> Tensor:
    cx, cy, hx, hy, yaw = box.unbind(-1)
    qx, qy = rotate(px - cx, py - cy, -yaw)
    dx, dy = qx.abs() - hx, qy.abs() - hy
    outside = safe_hypot(dx.clamp(min=0.0), dy.clamp(min=0.0))
    inside = torch.maximum(dx, dy).clamp(max=0.0)
    return outside + inside


def point_segment_distance(p: Tensor, seg: Tensor) -> Tensor:
    """Distance from points ``(B, 2)`` to segments ``(B, S, 4)`` -> ``(B, S)``; safe for zero-length segments."""
    return segment_distance(p[:, 0:1], p[:, 1:2], seg)


def point_circle_distance(p: Tensor, circles: Tensor) -> Tensor:
    """Signed distance from points ``(B, 2)`` to circles ``(B, C, 3)`` -> ``(B, C)`` (negative inside)."""
    return _circle_dist(p[:, 0:1], p[:, 1:2], circles)


def point_box_distance(p: Tensor, boxes: Tensor) -> Tensor:
    """Signed distance from points ``(B, 2)`` to oriented boxes ``(B, K, 5)`` -> ``(B, K)`` (negative inside)."""
    return _box_dist(p[:, 0:1], p[:, 1:2], boxes)


def points_clearance(points: Tensor, world: World) -> Tensor:
    """Signed distance from points ``(B, P, 2)`` to the nearest valid obstacle of their env -> ``(B, P)``.

    ``+inf`` where an env has no valid obstacle. Used by reset samplers to test
    many candidate positions per env at once.
    """
    px, py = points[..., 0:1], points[..., 1:2]  # (B, P, 1)
    best = torch.full_like(points[..., 0], float("inf"))
    for obs, mask, fn in (
        (world.segments, world.segment_mask, segment_distance),
        (world.circles, world.circle_mask, _circle_dist),
        (world.boxes, world.box_mask, _box_dist),
    ):
        if obs.shape[1]:
            d = fn(px, py, obs.unsqueeze(1))  # (B, P, N)
            best = torch.minimum(best, torch.where(mask.unsqueeze(1), d, float("inf")).amin(-1))
    return best


def disc_clearance(pose: Tensor, world: World, radius: float) -> Tensor:
    """Signed gap in m between robot discs at ``pose`` ``(B, 3)`` and the nearest obstacle -> ``(B,)``.

    Walls are treated as zero-thickness segments, so the gap is never below
    ``-radius`` for them. An env with no obstacle reads +inf.
    """
    return points_clearance(pose[:, None, :2], world)[:, 0] - radius
