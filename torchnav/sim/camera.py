"""A forward camera rendered by ray casting the 2D world: a depth row and a 2.5D RGB image.

Each image column casts one ray from the camera (``CameraParams.angles``, pinhole
spacing). The depth row reads the hit's distance along the optical axis
(``range * cos(column angle)``, what a depth camera reports), clamped to ``max_range``
(misses read ``max_range``). It equals the lidar's ray caster (``raycast.cast_rays``) on
the same rays, but is computed in the camera frame: every obstacle is moved into that
frame once per env (:func:`_segment_rows` and its siblings), where column ``j`` is the
ray ``z * (1, m_j)`` with the fixed slope ``m_j = tan(column angle)``, so its depth ``z``
comes out directly and each column-obstacle test needs no trigonometry and few
per-env terms (docs/performance.md, "Simulator options").

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
from .raycast import _PARALLEL_EPS, _TINY, unrolled
from .state import World

_INF = float("inf")
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


def _camera_frame(pose: Tensor, camera: CameraParams) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Camera position ``x, y`` and heading cosine and sine, each ``(B, 1)``."""
    ox, oy, oyaw = camera.offset
    x, y, th = pose.unbind(-1)
    c, s = torch.cos(th), torch.sin(th)
    if ox != 0.0 or oy != 0.0:
        x, y = x + c * ox - s * oy, y + s * ox + c * oy
    if oyaw != 0.0:
        c, s = torch.cos(th + oyaw), torch.sin(th + oyaw)
    return x[:, None], y[:, None], c[:, None], s[:, None]


def _columns(camera: CameraParams, like: Tensor) -> tuple[Tensor, ...]:
    """Per column ``(W,)``: the slope ``m = tan(angle)``, ``k = 1 + m^2``, ``sqrt(k)`` and ``1 / k``."""
    m = [(0.5 * camera.n_cols - j - 0.5) / camera.focal for j in range(camera.n_cols)]
    return tuple(torch.tensor(v, dtype=like.dtype, device=like.device)
                 for v in (m, [1 + a * a for a in m], [(1 + a * a) ** 0.5 for a in m], [1 / (1 + a * a) for a in m]))


def _local(x: Tensor, y: Tensor, frame: tuple[Tensor, ...]) -> tuple[Tensor, Tensor]:
    """World points -> camera frame (x along the optical axis)."""
    cx, cy, c, s = frame
    px, py = x - cx, y - cy
    return c * px + s * py, c * py - s * px


# Each kind's rows hold per env and slot the terms that every column reuses, stacked (k, B, N);
# the stack makes the compiler store them once instead of recomputing them for every column.
# Masked slots get rows that no column hits.

def _segment_rows(seg: Tensor, mask: Tensor, frame: tuple[Tensor, ...]) -> Tensor:
    ax, ay, bx, by = seg.unbind(-1)
    lax, lay = _local(ax, ay, frame)
    ex, ey = bx - ax, by - ay
    _, _, c, s = frame
    lex, ley = c * ex + s * ey, c * ey - s * ex
    tol = _PARALLEL_EPS * torch.finfo(seg.dtype).eps
    parallel = torch.where(mask, (tol * tol) * (ex * ex + ey * ey), float("inf"))  # as hit_segment's test
    return torch.stack((lax, lay, lex, ley, lax * ley - lay * lex, parallel))


def _segment_depth(row: Tensor, m: Tensor, k: Tensor, sqrt_k: Tensor, inv_k: Tensor) -> Tensor:
    """Depth of the columns ``m`` on segments: ``z (1, m) = a + s e`` solved with cross products."""
    ax, ay, ex, ey, cross, parallel = row.unbind(0)
    den = ey - m * ex
    ok = den * den > parallel * k
    inv = 1.0 / torch.where(ok, den, torch.ones_like(den))
    z = cross * inv
    s = (ax * m - ay) * inv
    return torch.where(ok & (z >= 0) & (s >= 0) & (s <= 1), z, _INF)


def _circle_rows(circ: Tensor, mask: Tensor, frame: tuple[Tensor, ...]) -> Tensor:
    cx, cy, r = circ.unbind(-1)
    return torch.stack((*_local(cx, cy, frame), torch.where(mask, r, 0.0)))  # radius 0: never hit


def _circle_depth(row: Tensor, m: Tensor, k: Tensor, sqrt_k: Tensor, inv_k: Tensor) -> Tensor:
    """Depth of the columns ``m`` on circles: ``|z (1, m) - c| = r``, the exit point from inside.

    ``p`` is the centre's projection and ``h`` its distance from the column's line, both
    scaled by ``sqrt(k)``; the half chord is ``(r - h)(r + h)`` as in ``hit_circle``."""
    cx, cy, r = row.unbind(0)
    p = cx + m * cy
    h = cx * m - cy
    rk = r * sqrt_k
    disc = (rk - h) * (rk + h)
    ok = disc > 0
    sq = torch.sqrt(torch.where(ok, disc, torch.ones_like(disc)))
    z_in = p - sq
    z = torch.where(z_in >= 0, z_in, p + sq)
    return torch.where(ok & (z >= 0), z * inv_k, _INF)


def _box_rows(box: Tensor, mask: Tensor, frame: tuple[Tensor, ...]) -> Tensor:
    cx, cy, hx, hy, yaw = box.unbind(-1)
    lx, ly = _local(cx, cy, frame)
    _, _, c, s = frame
    cb, sb = torch.cos(yaw), torch.sin(yaw)
    cr, sr = cb * c + sb * s, sb * c - cb * s  # the box's yaw relative to the camera
    ox, oy = -(cr * lx + sr * ly), -(cr * ly - sr * lx)  # the camera in the box frame
    visible = (mask & ((hx > 0) | (hy > 0))).to(box.dtype)
    return torch.stack((cr, sr, -ox, hx, -oy, hy, visible))


def _box_depth(row: Tensor, m: Tensor, k: Tensor, sqrt_k: Tensor, inv_k: Tensor) -> Tensor:
    """Depth of the columns ``m`` on oriented boxes: ``hit_box``'s slab method in the box frame."""
    cr, sr, mox, hx, moy, hy, visible = row.unbind(0)
    dx, dy = cr + sr * m, cr * m - sr
    ix = 1.0 / torch.where(dx.abs() > _TINY, dx, torch.full_like(dx, _TINY))
    iy = 1.0 / torch.where(dy.abs() > _TINY, dy, torch.full_like(dy, _TINY))
    # Each slab's entry and exit as in the lidar's _hit_box_rows: -o/d -+ h|1/d|.
    ax, ay, bx, by = mox * ix, moy * iy, hx * ix.abs(), hy * iy.abs()
    near = torch.maximum(ax - bx, ay - by)
    far = torch.minimum(ax + bx, ay + by)
    z = torch.where(near >= 0, near, far)
    return torch.where((near <= far) & (far >= 0) & (visible > 0), z, _INF)


# Per obstacle kind: the world's field, its mask, its rows and its column depths.
_KINDS = (
    ("segments", "segment_mask", _segment_rows, _segment_depth),
    ("circles", "circle_mask", _circle_rows, _circle_depth),
    ("boxes", "box_mask", _box_rows, _box_depth),
)


def _kind_depths(pose: Tensor, camera: CameraParams, source: World):
    """``(key, depth)`` per non-empty kind of ``source``: every column against every slot, ``(B, W, N)``."""
    frame, cols = _camera_frame(pose, camera), _columns(camera, pose)
    for key, mkey, rows, depth in _KINDS:
        obs = getattr(source, key)
        if obs.shape[1]:
            yield key, depth(rows(obs, getattr(source, mkey), frame)[:, :, None, :], *(c[:, None] for c in cols))


def camera_depth(pose: Tensor, world: World, camera: CameraParams, movers: World | None = None) -> Tensor:
    """Depth row ``(B, n_cols)`` in m (along the optical axis), left column first; differentiable.

    ``movers``, if given, is a second world (the moving obstacles) seen as well. Kinds with
    few slots run one slot at a time where the lidar's would (``raycast.unrolled``)."""
    frame, cols = _camera_frame(pose, camera), _columns(camera, pose)
    best = pose.new_full((pose.shape[0], camera.n_cols), _INF)
    for source in (world, movers):
        for key, mkey, rows, depth in _KINDS if source is not None else ():
            obs = getattr(source, key)
            n = obs.shape[1]
            if not n:
                continue
            row = rows(obs, getattr(source, mkey), frame)  # (k, B, N)
            if unrolled(n, best.numel()):
                for i in range(n):
                    best = torch.minimum(best, depth(row[:, :, i : i + 1], *cols))
            else:
                best = torch.minimum(best, depth(row[:, :, None, :], *(c[:, None] for c in cols)).amin(-1))
    return best.clamp(max=camera.max_range)


@torch.no_grad()
def camera_image(pose: Tensor, world: World, camera: CameraParams, movers: World | None = None,
                 styles: ObstacleStyles | None = None) -> tuple[Tensor, Tensor]:
    """Render the camera: depth ``(B, n_cols)`` in m (as :func:`camera_depth`) and an RGB image
    ``(B, n_rows, n_cols, 3)`` uint8 (row 0 at the top, column 0 on the left). ``styles`` gives
    single obstacles of ``world`` their own height and colour."""
    styles = styles or ObstacleStyles()
    defaults = {"segments": (camera.wall_height, camera.wall_color), "circles": (camera.circle_height, camera.circle_color),
                "boxes": (camera.box_height, camera.box_color)}
    dists, looks = [], []  # per kind: nearest depth (B, W) and that obstacle's [height, r, g, b] (B, W, 4)
    for source, kind_styles in ((world, styles), (movers, None)):
        for key, depths in _kind_depths(pose, camera, source) if source is not None else ():
            dist, idx = depths.min(-1)
            height, color = defaults[key] if kind_styles else (camera.mover_height, camera.mover_color)
            table = (kind_styles or ObstacleStyles()).table(key, depths.shape[-1], height, color, pose)
            dists.append(dist)
            looks.append(table[idx])
    dt, like = pose.dtype, pose
    b, w, h = pose.shape[0], camera.n_cols, camera.n_rows
    if dists:
        z, kind = torch.stack(dists).min(0)  # (B, W), inf on a miss
        look = torch.stack(looks).gather(0, kind[None, ..., None].expand(1, b, w, 4))[0]
        height, color = look[..., 0], look[..., 1:]
    else:
        z = torch.full((b, w), _INF, dtype=dt, device=like.device)
        height = torch.zeros_like(z)
        color = torch.zeros(b, w, 3, dtype=dt, device=like.device)
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
