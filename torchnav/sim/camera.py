"""A forward camera rendered by ray casting the 2D world: a depth row and a 2.5D RGB image.

Each image column casts one ray from the camera (``CameraParams.angles``, pinhole
spacing) with the lidar's hit functions (``raycast.cast_rays``). The depth row reads
the hit's distance along the optical axis (``range * cos(column angle)``, what a depth
camera reports), clamped to ``max_range`` (misses read ``max_range``).

The RGB image treats every obstacle as a prism standing on the floor, of its kind's
height and colour (``CameraParams``), or its own (:class:`ObstacleStyles`, from a map's
``height`` and ``color`` keys): in column ``j`` the pixel of row ``i`` looks
up at ``tan(e_i) = (n_rows/2 - i - 1/2) / f`` and reaches the nearest obstacle's face
at height ``height + z tan(e_i)``. If that height lies within the obstacle it sees the
obstacle, else the floor (looking down) or the sky. Only the nearest obstacle of a
column is drawn: a taller one behind a low box is hidden. Colours darken with distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .math import rotate
from .params import RGB, CameraParams
from .raycast import KINDS, cast_rays
from .state import World, planar_rows

Style = tuple[float | None, RGB | None]  # height m, colour; None: the kind's default from CameraParams


@dataclass(frozen=True)
class ObstacleStyles:
    """Camera heights and colours of single obstacles, for the RGB render.

    Entry ``i`` of a kind styles slot ``i`` of that kind in every env (a map's fixed obstacles
    come first, see ``MapSpec``); slots past the tuple, and ``None`` entries, keep the kind's
    height and colour from :class:`CameraParams`."""

    segments: tuple[Style, ...] = ()
    circles: tuple[Style, ...] = ()
    boxes: tuple[Style, ...] = ()

    def table(self, key: str, n: int, height: float, color: RGB, like: Tensor) -> Tensor:
        """``(n, 4)`` rows ``[height, r, g, b]`` of the first ``n`` slots of kind ``key``."""
        rows = [(height, *color)] * n
        for i, (h, c) in enumerate(getattr(self, key)[:n]):
            rows[i] = (height if h is None else h, *(color if c is None else c))
        return torch.tensor(rows, dtype=like.dtype, device=like.device).reshape(n, 4)


def camera_rays(pose: Tensor, camera: CameraParams) -> tuple[Tensor, Tensor, Tensor]:
    """Camera origins ``(B, 2)``, world-frame column angles ``(B, W)`` and sensor-frame angles ``(W,)``."""
    ox, oy, oyaw = camera.offset
    x, y, th = pose.unbind(-1)
    if ox != 0.0 or oy != 0.0:
        dx, dy = rotate(torch.full_like(th, ox), torch.full_like(th, oy), th)
        x, y = x + dx, y + dy
    local = torch.tensor(camera.angles(), dtype=pose.dtype, device=pose.device)
    return torch.stack((x, y), dim=-1), (th + oyaw).unsqueeze(-1) + local, local


def camera_depth(pose: Tensor, world: World, camera: CameraParams, movers: World | None = None) -> Tensor:
    """Depth row ``(B, n_cols)`` in m (along the optical axis), left column first; differentiable.

    ``movers``, if given, is a second world (the moving obstacles) seen as well."""
    origin, angles, local = camera_rays(pose, camera)
    dist = cast_rays(origin, angles, world)
    if movers is not None:
        dist = torch.minimum(dist, cast_rays(origin, angles, movers))
    return (dist * torch.cos(local)).clamp(max=camera.max_range)


@torch.no_grad()
def camera_image(pose: Tensor, world: World, camera: CameraParams, movers: World | None = None,
                 styles: ObstacleStyles | None = None) -> tuple[Tensor, Tensor]:
    """Render the camera: depth ``(B, n_cols)`` in m (as :func:`camera_depth`) and an RGB image
    ``(B, n_rows, n_cols, 3)`` uint8 (row 0 at the top, column 0 on the left). ``styles`` gives
    single obstacles of ``world`` their own height and colour."""
    origin, angles, local = camera_rays(pose, camera)
    dx, dy = torch.cos(angles)[..., None], torch.sin(angles)[..., None]  # (B, W, 1)
    ox, oy = origin[:, 0, None, None], origin[:, 1, None, None]
    styles = styles or ObstacleStyles()
    defaults = {"segments": (camera.wall_height, camera.wall_color), "circles": (camera.circle_height, camera.circle_color),
                "boxes": (camera.box_height, camera.box_color)}
    dists, looks = [], []  # per kind: nearest hit (B, W) and that obstacle's [height, r, g, b] (B, W, 4)
    for source, kind_styles in ((world, styles), (movers, None)):
        if source is None:
            continue
        for key, mkey, fn, rows in KINDS:
            obs, mask = getattr(source, key), getattr(source, mkey)
            if not obs.shape[1]:
                continue
            hits = fn(ox, oy, dx, dy, planar_rows(rows(obs))[:, None], mask[:, None])  # (B, W, N)
            dist, idx = hits.min(-1)
            height, color = defaults[key] if kind_styles else (camera.mover_height, camera.mover_color)
            table = (kind_styles or ObstacleStyles()).table(key, obs.shape[1], height, color, pose)
            dists.append(dist)
            looks.append(table[idx])
    dt, like = pose.dtype, pose
    b, w, h = pose.shape[0], camera.n_cols, camera.n_rows
    if dists:
        dist, kind = torch.stack(dists).min(0)  # (B, W)
        look = torch.stack(looks).gather(0, kind[None, ..., None].expand(1, b, w, 4))[0]
        height, color = look[..., 0], look[..., 1:]
    else:
        dist = torch.full((b, w), float("inf"), dtype=dt, device=like.device)
        height = torch.zeros_like(dist)
        color = torch.zeros(b, w, 3, dtype=dt, device=like.device)
    z = dist * torch.cos(local)  # (B, W), inf on a miss
    f = camera.focal
    tan_e = (0.5 * h - 0.5 - torch.arange(h, dtype=dt, device=like.device)) / f  # (H,)
    seen = camera.height + z[:, None, :] * tan_e[None, :, None]  # (B, H, W) height where the pixel meets the face
    hit = torch.isfinite(z)[:, None, :] & (z[:, None, :] <= camera.max_range) & (seen >= 0) & (seen <= height[:, None, :])
    shade_obs = (1.0 / (1.0 + 0.08 * z.clamp(max=camera.max_range)))[:, None, :, None]  # (B, 1, W, 1)
    down = tan_e < 0
    floor_z = torch.where(down, camera.height / torch.where(down, -tan_e, 1.0), 0.0)  # floor distance along the axis
    shade_floor = (0.6 + 0.4 / (1.0 + 0.15 * floor_z))[None, :, None, None]  # (1, H, 1, 1)
    floor = torch.tensor(camera.floor_color, dtype=dt, device=like.device) * shade_floor
    sky = torch.tensor(camera.sky_color, dtype=dt, device=like.device).expand(1, h, 1, 3)
    back = torch.where(down[None, :, None, None], floor, sky).expand(b, h, w, 3)
    img = torch.where(hit[..., None], (color[:, None] * shade_obs).expand(b, h, w, 3), back)
    depth = z.clamp(max=camera.max_range)
    return depth, img.round().clamp(0, 255).to(torch.uint8)
