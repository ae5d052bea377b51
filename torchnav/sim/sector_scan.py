"""Exact sector scan: per angular sector, the distance to the nearest obstacle point inside it.

What a lidar converges to as its rays become infinitely dense and are min-pooled
per sector: it never misses an obstacle thinner than the gap between two rays.

Why it is cheap. For a convex obstacle seen from outside, the distance along a ray
is unimodal in the ray's direction, smallest towards the obstacle's nearest point.
So inside a wedge the nearest obstacle point is either that nearest point (when
its direction lies in the wedge) or lies on one of the wedge's two boundary rays.
A sector's reading is therefore the minimum of

* the nearest-point distances of the obstacles whose nearest point falls in the
  sector (one scatter-min over obstacles), and
* the ray casts along the sector's two boundary rays (``n + 1`` rays for a partial
  field of view, ``n`` for a full circle, through :func:`raycast.cast_fan` with its
  broad phase).

A sensor inside a circle or a box is itself on an obstacle point: every sector
reads 0 (``min_range`` after clamping), where a ray scan reads the distance to the
exit. Zero-size obstacles stay invisible. The cost is
``O(obstacles * (2 window + 2) + (sectors + 1) * dense_slots)`` per env.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .geometry import point_box_distance, segment_distance
from .math import rotate, safe_hypot
from .raycast import RayFan, cast_fan
from .state import World

_INF = float("inf")


def _nearest_points(origin: Tensor, world: World) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Per obstacle of every kind (walls, circles, boxes, concatenated): the distance ``(B, M)``
    from the sensor to its nearest point (0 inside a solid obstacle, ``inf`` for masked slots
    and zero-size obstacles), that point's world direction (rad, not differentiated), and
    ``(B,)`` whether the sensor lies inside any circle or box.

    Validity is folded into the distances rather than returned as a mask: compiled CPU
    kernels store bool tensors about 20x slower than floats (docs/performance.md)."""
    ox, oy = origin[:, 0:1], origin[:, 1:2]
    dist, phi = [], []
    inside = torch.zeros(origin.shape[0], dtype=torch.bool, device=origin.device)
    if world.segments.shape[1]:
        seg = world.segments
        ax, ay, bx, by = seg.unbind(-1)
        ex, ey = bx - ax, by - ay
        ee = ex * ex + ey * ey
        dist.append(torch.where(world.segment_mask & (ee > 0), segment_distance(ox, oy, seg), _INF))
        with torch.no_grad():
            t = (((ox - ax) * ex + (oy - ay) * ey) / ee.clamp(min=1e-30)).clamp(0.0, 1.0)
            phi.append(torch.atan2(ay + t * ey - oy, ax + t * ex - ox))
    if world.circles.shape[1]:
        cx, cy, r = world.circles.unbind(-1)
        gap = safe_hypot(cx - ox, cy - oy) - r
        ok = world.circle_mask & (r > 0)
        dist.append(torch.where(ok, gap.clamp(min=0.0), _INF))
        with torch.no_grad():
            phi.append(torch.atan2(cy - oy, cx - ox))
        inside |= (ok & (gap <= 0)).any(1)
    if world.boxes.shape[1]:
        cx, cy, hx, hy, yaw = world.boxes.unbind(-1)
        gap = point_box_distance(origin, world.boxes)
        ok = world.box_mask & ((hx > 0) | (hy > 0))
        dist.append(torch.where(ok, gap.clamp(min=0.0), _INF))
        with torch.no_grad():
            # The nearest point in the box frame is the sensor clamped to the box.
            qx, qy = rotate(ox - cx, oy - cy, -yaw)
            nx, ny = qx.clamp(-hx, hx) - qx, qy.clamp(-hy, hy) - qy
            wx, wy = rotate(nx, ny, yaw)
            phi.append(torch.atan2(wy, wx))
        inside |= (ok & (gap <= 0)).any(1)
    return torch.cat(dist, 1), torch.cat(phi, 1), inside


def sector_ranges(boundaries: RayFan, world: World, window: int = 2, dense_slots: int = 64, unroll: bool | None = None) -> Tensor:
    """Nearest obstacle distance (m) per sector ``(B, S)``, ``inf`` where a sector sees nothing.

    ``boundaries`` is the fan of sector boundary rays: ``S + 1`` rays for sectors
    over a partial field of view, ``S`` for a ``closed`` fan over the full circle
    (sector ``j`` lies between boundary ``j`` and ``j + 1``).
    """
    edge = cast_fan(boundaries, world, window, dense_slots, unroll)  # (B, S or S+1)
    if boundaries.closed:
        n = boundaries.n
        best = torch.minimum(edge, edge.roll(-1, dims=1))
    else:
        n = boundaries.n - 1
        best = torch.minimum(edge[:, :-1], edge[:, 1:])
    if world.segments.shape[1] + world.circles.shape[1] + world.boxes.shape[1] == 0:
        return best
    dist, phi, inside = _nearest_points(boundaries.origin, world)
    with torch.no_grad():
        u = torch.floor(boundaries.index_of(phi))
        if boundaries.closed:
            u = u - n * torch.floor(u / n)  # index_of does not wrap closed fans
        sector = u.clamp(0, n - 1).long()
    if not boundaries.closed:  # a nearest point exactly on the last boundary is that boundary ray's hit anyway
        dist = torch.where((u >= 0) & (u < n), dist, _INF)
    best = best.scatter_reduce(1, sector, dist, "amin", include_self=True)
    return torch.where(inside.unsqueeze(-1), torch.zeros_like(best), best)
