"""The planar lidar: ray scans and exact sector scans of a world, with noise and range limits.

The ray casting itself (hit functions, narrow phase, the angular broad phase for
many obstacles) lives in ``raycast.py``; the exact sector scan in ``sector_scan.py``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .math import rotate
from .params import LidarParams
from .raycast import RayFan, cast_fan, cast_rays, fan_is_exact, hit_box, hit_circle, hit_segment  # noqa: F401  (re-exported)
from .sector_scan import sector_ranges
from .state import World
from .static_map import StaticMap, static_ray_hits


def ray_origins_and_angles(pose: Tensor, lidar: LidarParams) -> tuple[Tensor, Tensor]:
    """Sensor origins ``(B, 2)`` and world-frame ray angles ``(B, R)`` for robot poses ``(B, 3)``."""
    origin, heading = _mount(pose, lidar)
    angles = torch.tensor(lidar.angles(), dtype=pose.dtype, device=pose.device)
    return origin, heading.unsqueeze(-1) + angles


def _mount(pose: Tensor, lidar: LidarParams) -> tuple[Tensor, Tensor]:
    """Sensor origins ``(B, 2)`` and headings ``(B,)`` (rad) for robot poses ``(B, 3)``."""
    ox, oy, oyaw = lidar.offset
    x, y, th = pose.unbind(-1)
    if ox != 0.0 or oy != 0.0:
        dx, dy = rotate(torch.full_like(th, ox), torch.full_like(th, oy), th)
        x, y = x + dx, y + dy
    return torch.stack((x, y), dim=-1), th + oyaw


def lidar_fan(pose: Tensor, lidar: LidarParams) -> RayFan:
    """The fan of rays of ``lidar`` (``scan="rays"``) or of its sector boundaries (``"sectors"``)."""
    origin, heading = _mount(pose, lidar)
    n = lidar.n_rays
    if lidar.scan == "sectors":
        offsets = [lidar.sector_bearing(i) for i in range(n if lidar.full_circle else n + 1)]
        spacing = lidar.fov / n
    else:
        offsets = lidar.angles()
        spacing = offsets[1] - offsets[0] if n > 1 else 2 * math.pi
    first = heading + offsets[0]
    angles = heading.unsqueeze(-1) + torch.tensor(offsets, dtype=pose.dtype, device=pose.device)
    return RayFan(origin=origin, angles=angles, first=first, spacing=spacing, closed=lidar.full_circle or n == 1)


def lidar_scan(
    pose: Tensor,
    world: World,
    lidar: LidarParams,
    generator: torch.Generator | None = None,
    unroll: bool | None = None,
    movers: World | None = None,
    static: StaticMap | None = None,
) -> Tensor:
    """Lidar ranges in m, ``(B, n_rays)``, for robots at ``pose`` ``(B, 3)`` in ``world``.

    ``lidar.scan`` picks a ray scan (one reading per ray) or the exact sector scan
    (one reading per sector: the nearest obstacle point inside it; ``sector_scan.py``).

    Misses read ``max_range``; returns closer than ``min_range`` read ``min_range``.
    With ``lidar.noise_std > 0`` and a ``generator``, Gaussian noise is added before
    clamping (no generator: no noise, so results stay reproducible by default).

    ``movers`` is a second world (the moving obstacles, ``movers.mover_world``) scanned
    as well: the scan of the union of two worlds is the minimum of their scans.
    ``static``: the map whose reach lists ``world`` holds (``static_map.with_static``). A ray scan
    reads them as far as they reach and marches the rays that hit nothing there through the map's
    ray lists (:func:`~torchnav.sim.static_map.static_ray_hits`); its hits beyond ``max_range`` read
    as misses, so with range noise a return just past the range is never pulled back into it. The
    sector scan needs reach lists that reach ``max_range`` (``static_map.static_reach``).
    """
    fan = lidar_fan(pose, lidar)
    scan = sector_ranges if lidar.scan == "sectors" else cast_fan
    ranges = scan(fan, world, lidar.window, lidar.dense_slots, unroll)
    if movers is not None:
        ranges = torch.minimum(ranges, scan(fan, movers, lidar.window, lidar.dense_slots, unroll))
    if static is not None and lidar.scan == "rays":  # the map past its reach lists (in `world`): marched
        start = max(0.0, static.reach - math.hypot(*lidar.offset[:2]))  # m from the sensor
        if start < lidar.max_range:
            ranges = torch.minimum(ranges, static_ray_hits(static, fan.origin, fan.angles, lidar.max_range, start, ranges <= start))
    if lidar.noise_std > 0 and generator is not None:
        ranges = ranges + lidar.noise_std * torch.randn(ranges.shape, generator=generator, dtype=ranges.dtype, device=ranges.device)
    return ranges.clamp(lidar.min_range, lidar.max_range)


def sectorize(ranges: Tensor, n_sectors: int) -> Tensor:
    """Reduce ``(B, R)`` ranges to ``(B, n_sectors)`` by the minimum over consecutive rays."""
    b, r = ranges.shape
    if r % n_sectors:
        raise ValueError(f"n_sectors={n_sectors} must divide the number of rays {r}")
    return ranges.reshape(b, n_sectors, r // n_sectors).amin(-1)


def scan_is_exact(pose: Tensor, world: World, lidar: LidarParams) -> Tensor:
    """``(B,)`` bool: True where :func:`lidar_scan`'s broad phase gives exactly the
    every-ray-every-obstacle result (see ``raycast.py``). Not needed on the hot path."""
    return fan_is_exact(lidar_fan(pose, lidar), world, lidar.window, lidar.dense_slots)
