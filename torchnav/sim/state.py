"""Batched simulator state and world, as tensorclasses of ``(B, ...)`` tensors.

Frames and units: the world frame has x to the right and y up, in metres; a
heading ``theta`` is measured counter-clockwise from +x in radians and kept in
[-pi, pi).
"""

from __future__ import annotations

from typing import Sequence

import torch
from tensordict import tensorclass
from torch import Tensor


@tensorclass
class World:
    """Per-env obstacles as padded tensors with validity masks: ``segments`` ``(B, S, 4)``, ``circles``
    ``(B, C, 3)``, ``boxes`` ``(B, K, 5)`` and their bool masks; slots masked off are ignored. The row
    layouts and units: docs/sim.md, "Worlds and obstacles"."""

    segments: Tensor  # (B, S, 4) walls [x1, y1, x2, y2], m
    segment_mask: Tensor
    circles: Tensor  # (B, C, 3) [cx, cy, radius], m
    circle_mask: Tensor
    boxes: Tensor  # (B, K, 5) oriented boxes [cx, cy, half_x, half_y, yaw], m and rad
    box_mask: Tensor


@tensorclass
class SimState:
    """Everything the simulator knows about ``B`` robots after a step, all ``(B, ...)``; each field's
    shape, meaning and unit is tabled in docs/sim.md, "State and units"."""

    pose: Tensor  # (B, 3) true pose [x m, y m, theta rad]
    vel: Tensor  # (B, 2) applied twist [v m/s, omega rad/s], after the limits
    odom: Tensor  # (B, 3) odometry estimate, integrated from noisy velocities
    ranges: Tensor  # (B, n_rays) lidar ranges at pose, m
    clearance: Tensor  # (B,) signed gap robot disc - nearest obstacle, m (negative when penetrating)
    collided: Tensor  # (B,) bool, clearance <= 0
    time: Tensor  # (B,) s since the last reset
    imu: Tensor  # (B, 3) [a_x m/s^2, a_y m/s^2, yaw rate rad/s] in the body frame; (B, 0) without an IMU
    imu_bias: Tensor  # (B, 3) the IMU's bias (same units); (B, 0) without an IMU
    cam_depth: Tensor  # (B, n_cols) camera depth row, m; (B, 0) without a camera
    movers: Tensor  # (B, M, 9) moving obstacles (movers.py); M may be 0
    mover_mask: Tensor  # (B, M) bool, which mover slots exist
    mover_plan: Tensor  # (B, M, 4 + 2P) patrol and pedestrian waypoints; (B, M, 0) if all are ballistic
    mover_target: Tensor  # (B, M) index of the waypoint each patrol and pedestrian heads for now; (B, 0) if all are ballistic
    mover_boxes: Tensor  # (B, K, 3) [half_x, half_y, yaw] of the last K movers, which are boxes; K = 0: all discs
    cmd_queue: Tensor  # (B, K, 2) the last K commands, newest first, for actuator delay (randomize.py)


_KIND_MASKS = (("segments", "segment_mask", 4), ("circles", "circle_mask", 3), ("boxes", "box_mask", 5))


def _as_rows(x, width: int, name: str, dtype, device) -> Tensor:
    t = torch.as_tensor(x if x is not None and len(x) else [], dtype=dtype, device=device)
    if t.numel() == 0:
        return t.reshape(0, width)
    if t.dim() != 2 or t.shape[-1] != width:
        raise ValueError(f"{name} must have shape (N, {width}), got {tuple(t.shape)}")
    return t


def make_world(
    batch_size: int,
    segments: Sequence[Sequence[float]] | Tensor | None = None,
    circles: Sequence[Sequence[float]] | Tensor | None = None,
    boxes: Sequence[Sequence[float]] | Tensor | None = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> World:
    """The same obstacles in every env of a batch of ``batch_size``.

    ``segments`` is ``(S, 4)``, ``circles`` ``(C, 3)``, ``boxes`` ``(K, 5)``, in the
    layouts of :class:`World`. Padded slots can be added later by concatenation.
    """
    given = {"segments": segments, "circles": circles, "boxes": boxes}
    parts = {key: _as_rows(given[key], width, key, dtype, device) for key, _, width in _KIND_MASKS}
    if parts["circles"].numel() and (parts["circles"][:, 2] < 0).any():
        raise ValueError("circles: radius must be >= 0")
    if parts["boxes"].numel() and (parts["boxes"][:, 2:4] < 0).any():
        raise ValueError("boxes: half extents must be >= 0")
    out = {}
    for key, mkey, _ in _KIND_MASKS:
        out[key] = parts[key].unsqueeze(0).expand(batch_size, *parts[key].shape).clone()
        out[mkey] = torch.ones(batch_size, parts[key].shape[0], dtype=torch.bool, device=device)
    return World(**out, batch_size=[batch_size], device=device)


def pad_world(world: World, segments: int | None = None, circles: int | None = None, boxes: int | None = None) -> World:
    """``world`` with each obstacle kind padded to at least the given number of slots.

    New slots hold zeros and are masked off, so collision and lidar ignore them.
    ``None`` keeps a kind's slot count.
    """
    want = {"segments": segments, "circles": circles, "boxes": boxes}
    out = {}
    for key, mkey, width in _KIND_MASKS:
        t, m = getattr(world, key), getattr(world, mkey)
        extra = max(0, (want[key] or 0) - t.shape[1])
        if extra:
            t = torch.cat((t, t.new_zeros(t.shape[0], extra, width)), 1)
            m = torch.cat((m, m.new_zeros(m.shape[0], extra)), 1)
        out[key], out[mkey] = t, m
    return World(**out, batch_size=world.batch_size, device=world.device)


def cat_worlds(worlds: Sequence[World]) -> World:
    """Concatenate worlds along the batch, padding each kind to the largest slot count.

    Envs of one batch may so hold different worlds: ``cat_worlds([arena, maze])``
    is a batch of ``len(arena) + len(maze)`` envs.
    """
    if not worlds:
        raise ValueError("cat_worlds needs at least one world")
    n = {key: max(getattr(w, key).shape[1] for w in worlds) for key, _, _ in _KIND_MASKS}
    padded = [pad_world(w, **n) for w in worlds]
    out = {k: torch.cat([getattr(w, k) for w in padded], 0) for key, mkey, _ in _KIND_MASKS for k in (key, mkey)}
    return World(**out, batch_size=[sum(w.batch_size[0] for w in worlds)], device=worlds[0].device)


@torch.library.custom_op("torchnav::planar_copy", mutates_args=())
def _planar_copy(x: Tensor) -> Tensor:
    """``(B, N, k)`` -> a new ``(k, B, N)`` contiguous tensor (an opaque op, so that
    ``torch.compile`` materialises it instead of fusing the strided reads into its consumers)."""
    return x.permute(2, 0, 1).clone(memory_format=torch.contiguous_format)


@_planar_copy.register_fake
def _(x: Tensor) -> Tensor:
    return x.new_empty((x.shape[2], x.shape[0], x.shape[1]))


_planar_copy.register_autograd(lambda ctx, grad: grad.permute(1, 2, 0))


def is_planar(x: Tensor) -> bool:
    """Whether ``x`` ``(B, N, k)`` is stored component-major: ``x[..., i]`` a contiguous block, ``(B, N)`` or
    (the movers' layout) ``(N, B)``."""
    return x.shape[1] == 0 or x.permute(2, 0, 1).is_contiguous() or x.permute(2, 1, 0).is_contiguous()


def stack_rows(components: list[Tensor] | tuple[Tensor, ...], like: Tensor) -> Tensor:
    """Components ``(B, N)`` stacked into rows ``(B, N, k)`` stored component-major in ``like``'s block
    order (``(N, B)`` blocks for the movers' layout), so that building them reads and writes
    contiguous memory instead of transposing."""
    if like.dim() == 3 and like.shape[1] > 1 and like.stride(0) == 1:
        return torch.stack([c.transpose(0, 1) for c in components], 0).permute(2, 1, 0)
    return torch.stack(tuple(components), 0).permute(*range(1, like.dim()), 0)


def planar_rows(x: Tensor) -> Tensor:
    """``x`` ``(B, N, k)`` stored component-major (same shape and values): ``x`` itself when it
    already is (:func:`is_planar`), else a materialised copy whose ``x[..., i]`` is a contiguous ``(B, N)`` block."""
    return x if is_planar(x) else _planar_copy(x).permute(1, 2, 0)


def planar_world(world: World) -> World:
    """``world`` with each obstacle tensor stored component-major: the same ``(B, N, k)``
    shapes and values, but ``obs[..., i]`` is a contiguous ``(B, N)`` block.

    The simulator step calls this once per step: under ``torch.compile`` the obstacle
    loops then read contiguous memory and vectorise (atan2 over ``(B, N, 3)``
    circles read with stride 3 ran 15x slower than over planar ones). A world that
    is already planar is used as it is, so a caller that steps one static world many
    times can convert it once (``world = planar_world(world)``) and save the copy
    (about 4 ms per step for 400 obstacles x 4,096 envs on 2 CPU cores).
    """
    out = {}
    for key, mkey, _ in _KIND_MASKS:
        out[key] = planar_rows(getattr(world, key))
        out[mkey] = getattr(world, mkey)
    return World(**out, batch_size=world.batch_size, device=world.device)


def check_world(world: World, batch_size: int, dtype: torch.dtype, device: torch.device) -> None:
    """Raise a ValueError naming the field whose shape, dtype or device is off."""
    for name, mask, width in _KIND_MASKS:
        t, m = getattr(world, name), getattr(world, mask)
        if t.dim() != 3 or t.shape[0] != batch_size or t.shape[2] != width:
            raise ValueError(f"world.{name} must have shape ({batch_size}, N, {width}), got {tuple(t.shape)}")
        if m.shape != t.shape[:2] or m.dtype != torch.bool:
            raise ValueError(f"world.{mask} must be a bool tensor of shape {tuple(t.shape[:2])}, got {m.dtype} {tuple(m.shape)}")
        if t.dtype != dtype:
            raise ValueError(f"world.{name} has dtype {t.dtype}, expected {dtype} (the state's dtype)")
        if t.device != device:
            raise ValueError(f"world.{name} is on {t.device}, expected {device} (the state's device)")
