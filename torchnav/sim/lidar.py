"""Exact 2D lidar ray casting against segments, circles and oriented boxes.

Each obstacle kind has one hit function written on broadcastable tensors, so
the same maths serves two reduction strategies:

* ``batched``: all rays of all envs against all slots of a kind at once, as
  ``(B, R, N)`` tensors reduced by a minimum (fewest kernel launches in eager mode
  for many obstacles);
* ``unrolled``: a running minimum over the obstacle slots, each a ``(B, R)`` pass.
  Under ``torch.compile`` this fuses into one loop over contiguous ``(B, R)``
  memory, several times faster than the batched form on CPU (see
  docs/performance.md), and it never materialises ``(B, R, N)`` temporaries.

Every division and square root is guarded (see ``math.py``) and masking uses
``torch.where`` out of place, so backward never meets inf or NaN.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .math import rotate
from .params import LidarParams
from .state import World

_EPS = 1e-9
_TINY = 1e-12
_INF = float("inf")


def ray_origins_and_angles(pose: Tensor, lidar: LidarParams) -> tuple[Tensor, Tensor]:
    """Sensor origins ``(B, 2)`` and world-frame ray angles ``(B, R)`` for robot poses ``(B, 3)``."""
    ox, oy, oyaw = lidar.offset
    x, y, th = pose.unbind(-1)
    if ox != 0.0 or oy != 0.0:
        dx, dy = rotate(torch.full_like(th, ox), torch.full_like(th, oy), th)
        x, y = x + dx, y + dy
    angles = torch.tensor(lidar.angles(), dtype=pose.dtype, device=pose.device)
    return torch.stack((x, y), dim=-1), th.unsqueeze(-1) + (angles + oyaw)


def hit_segment(ox: Tensor, oy: Tensor, dx: Tensor, dy: Tensor, seg: Tensor, mask: Tensor) -> Tensor:
    """Distance along unit rays to segments ``[x1, y1, x2, y2]``, ``inf`` where missed.

    All arguments broadcast: ray origin ``ox, oy``, unit direction ``dx, dy``, and the
    segment's components in ``seg[..., k]`` with a bool ``mask``.
    """
    ax, ay, bx, by = seg.unbind(-1)
    ex, ey = bx - ax, by - ay
    wx, wy = ax - ox, ay - oy
    # Solve o + t d = a + s e with 2D cross products; parallel rays (denom ~ 0) miss.
    denom = dx * ey - dy * ex
    ok = denom.abs() > _EPS
    inv = 1.0 / torch.where(ok, denom, torch.ones_like(denom))
    t = (wx * ey - wy * ex) * inv
    s = (wx * dy - wy * dx) * inv
    return torch.where(ok & (t >= 0) & (s >= 0) & (s <= 1) & mask, t, _INF)


def hit_circle(ox: Tensor, oy: Tensor, dx: Tensor, dy: Tensor, circ: Tensor, mask: Tensor) -> Tensor:
    """Distance along unit rays to circles ``[cx, cy, r]``, ``inf`` where missed (broadcasting).

    A ray starting inside a circle reports the exit point. Tangent rays count as misses.
    """
    cx, cy, r = circ.unbind(-1)
    fx, fy = ox - cx, oy - cy
    b = fx * dx + fy * dy
    disc = b * b - (fx * fx + fy * fy - r * r)
    ok = disc > _EPS
    sq = torch.sqrt(torch.where(ok, disc, torch.ones_like(disc)))
    t_in, t_out = -b - sq, -b + sq
    t = torch.where(t_in >= 0, t_in, t_out)
    return torch.where(ok & (t >= 0) & mask, t, _INF)


def hit_box(ox: Tensor, oy: Tensor, dx: Tensor, dy: Tensor, box: Tensor, mask: Tensor) -> Tensor:
    """Distance along unit rays to oriented boxes ``[cx, cy, hx, hy, yaw]``, ``inf`` where missed.

    The slab method in the box frame. A ray parallel to a slab gets a tiny
    stand-in direction, which turns that slab's entry and exit into huge numbers
    of the right signs, exactly what +-inf would do, but finite for backward.
    A ray starting inside a box reports the exit point.
    """
    cx, cy, hx, hy, yaw = box.unbind(-1)
    c, s = torch.cos(yaw), torch.sin(yaw)
    px, py = ox - cx, oy - cy
    lox, loy = c * px + s * py, c * py - s * px
    ldx, ldy = c * dx + s * dy, c * dy - s * dx
    ix = 1.0 / torch.where(ldx.abs() > _TINY, ldx, torch.full_like(ldx, _TINY))
    iy = 1.0 / torch.where(ldy.abs() > _TINY, ldy, torch.full_like(ldy, _TINY))
    tx1, tx2 = (-hx - lox) * ix, (hx - lox) * ix
    ty1, ty2 = (-hy - loy) * iy, (hy - loy) * iy
    t_near = torch.maximum(torch.minimum(tx1, tx2), torch.minimum(ty1, ty2))
    t_far = torch.minimum(torch.maximum(tx1, tx2), torch.maximum(ty1, ty2))
    t = torch.where(t_near >= 0, t_near, t_far)
    return torch.where((t_near <= t_far) & (t_far >= 0) & mask, t, _INF)


_KINDS = (("segments", "segment_mask", hit_segment), ("circles", "circle_mask", hit_circle), ("boxes", "box_mask", hit_box))


def cast_rays(origin: Tensor, angles: Tensor, world: World, unroll: bool | None = None) -> Tensor:
    """Nearest hit distance ``(B, R)`` of rays from ``origin`` ``(B, 2)`` at world ``angles`` ``(B, R)``;
    ``inf`` where a ray hits nothing.

    ``unroll`` picks the reduction (see the module docstring); ``None`` unrolls when
    the world has at most 32 obstacle slots.
    """
    if unroll is None:
        unroll = sum(getattr(world, k).shape[1] for k, _, _ in _KINDS) <= 32
    dx, dy = torch.cos(angles), torch.sin(angles)
    ox, oy = origin[:, 0:1], origin[:, 1:2]  # (B, 1)
    best = torch.full_like(dx, _INF)
    for key, mkey, fn in _KINDS:
        obs, mask = getattr(world, key), getattr(world, mkey)
        if obs.shape[1] == 0:
            continue
        if unroll:
            for i in range(obs.shape[1]):
                best = torch.minimum(best, fn(ox, oy, dx, dy, obs[:, i].unsqueeze(1), mask[:, i : i + 1]))
        else:
            hits = fn(ox.unsqueeze(-1), oy.unsqueeze(-1), dx.unsqueeze(-1), dy.unsqueeze(-1), obs.unsqueeze(1), mask.unsqueeze(1))
            best = torch.minimum(best, hits.amin(-1))
    return best


def lidar_scan(
    pose: Tensor,
    world: World,
    lidar: LidarParams,
    generator: torch.Generator | None = None,
    unroll: bool | None = None,
) -> Tensor:
    """Lidar ranges in m, ``(B, n_rays)``, for robots at ``pose`` ``(B, 3)`` in ``world``.

    Misses read ``max_range``; returns closer than ``min_range`` read ``min_range``.
    With ``lidar.noise_std > 0`` and a ``generator``, Gaussian noise is added before
    clamping (no generator: no noise, so results stay reproducible by default).
    """
    origin, phi = ray_origins_and_angles(pose, lidar)
    ranges = cast_rays(origin, phi, world, unroll)
    if lidar.noise_std > 0 and generator is not None:
        ranges = ranges + lidar.noise_std * torch.randn(ranges.shape, generator=generator, dtype=ranges.dtype, device=ranges.device)
    return ranges.clamp(lidar.min_range, lidar.max_range)


def sectorize(ranges: Tensor, n_sectors: int) -> Tensor:
    """Reduce ``(B, R)`` ranges to ``(B, n_sectors)`` by the minimum over consecutive rays."""
    b, r = ranges.shape
    if r % n_sectors:
        raise ValueError(f"n_sectors={n_sectors} must divide the number of rays {r}")
    return ranges.reshape(b, n_sectors, r // n_sectors).amin(-1)
