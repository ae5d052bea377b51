"""Downward-facing reflectance sensors over a floor line (tape on a floor), as pure tensor functions.

Sensor positions, the exact coverage of a sensor's disc by a straight strip, the ``analog``,
``binary`` and ``smooth`` modes, and a :class:`SegmentGrid` whose cells list the segments within
``reach`` (a query costs ``M`` distances instead of ``S``; beyond ``reach`` reads ``reach``).
Every env sees the same line. The model and its formula: docs/line.md, "Sensor model"."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .checks import Checked, count, non_negative, one_of, positive, real, within
from .geometry import segment_distance
from .math import rotate

FLOOR_MODES = ("analog", "binary", "smooth")


def _require(cond: bool, msg: str) -> None:
    if not cond:
        raise ValueError(msg)


@dataclass(frozen=True)
class FloorSensorParams(Checked):
    """A straight array of ``count`` downward sensors across the robot's front, sensor 0 the
    rightmost (docs/line.md, "Sensor model"). It is the line task's ``sensors`` section
    (``LineConfig.sensors``): its defaults are the task's, five photodiodes 15 mm apart, 8 cm
    ahead of the axle."""

    count: int = count(1, 5)  # number of sensors
    spacing: float = non_negative(0.015)  # m between neighbouring sensor centres
    forward: float = real(0.08)  # m, offset of the array ahead of the wheel axle
    radius: float = positive(0.005)  # m, radius of each sensor's circular footprint on the floor
    mode: str = one_of(*FLOOR_MODES, default="analog")  # "analog" (coverage fraction) | "binary" | "smooth" (differentiable sigmoid)
    threshold: float = within(0.0, 1.0, 0.5, closed="()")  # coverage fraction above which a sensor reports the line ("binary", off-line test)
    noise_std: float = non_negative(0.0)  # std of additive Gaussian noise on the coverage fraction (analog, binary; needs a generator)
    softness: float = positive(0.004)  # m, sigmoid scale of the "smooth" mode

    def offsets(self) -> list[tuple[float, float]]:
        """Sensor centres ``(x, y)`` in the robot frame, m, in sensor order."""
        y0 = -(self.count - 1) * self.spacing / 2
        return [(self.forward, y0 + i * self.spacing) for i in range(self.count)]


def sensor_points(pose: Tensor, params: FloorSensorParams) -> Tensor:
    """World positions ``(B, K, 2)`` of the sensor centres for robot poses ``(B, 3)``."""
    off = torch.tensor(params.offsets(), dtype=pose.dtype, device=pose.device)  # (K, 2)
    th = pose[:, 2:3]
    dx, dy = rotate(off[:, 0], off[:, 1], th)  # (B, K)
    return torch.stack((pose[:, 0:1] + dx, pose[:, 1:2] + dy), dim=-1)


# --------------------------------------------------------------------------- distances


@dataclass(frozen=True)
class SegmentGrid:
    """Candidate lists of segments per grid cell (see the module docstring).

    Attributes:
        segments: ``(S, 4)`` centreline segments, m.
        origin: ``(2,)`` lower-left corner of the grid, m. cell: cell size, m.
        nx, ny: cells along x and y. reach: m, distances beyond it read ``reach``.
        cand: ``(ny * nx, M)`` int64 segment indices per cell (row-major, y outer).
        cand_mask: ``(ny * nx, M)`` bool, valid entries of ``cand``.
    """

    segments: Tensor
    origin: Tensor
    cell: float
    nx: int
    ny: int
    reach: float
    cand: Tensor
    cand_mask: Tensor

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> "SegmentGrid":
        return SegmentGrid(
            segments=self.segments.to(device=device, dtype=dtype), origin=self.origin.to(device=device, dtype=dtype),
            cell=self.cell, nx=self.nx, ny=self.ny, reach=self.reach,
            cand=self.cand.to(device=device), cand_mask=self.cand_mask.to(device=device),
        )


def nearest_distance_brute(points: Tensor, segments: Tensor) -> Tensor:
    """Distance ``(...)`` from points ``(..., 2)`` to the nearest of all segments ``(S, 4)`` (reference)."""
    d = segment_distance(points[..., 0:1], points[..., 1:2], segments)
    return d.amin(-1)


def build_segment_grid(segments: Tensor, reach: float, cell: float | None = None, chunk: int = 4096) -> SegmentGrid:
    """A :class:`SegmentGrid` over the segments' bounding box grown by ``reach`` (m).

    A segment is listed in a cell when its distance to the cell centre is at most
    ``reach`` plus half the cell diagonal, so every segment within ``reach`` of any
    point of the cell is listed (triangle inequality). ``cell`` defaults to ``reach``.
    Built once per track, on the segments' device.
    """
    _require(segments.dim() == 2 and segments.shape[-1] == 4 and segments.shape[0] >= 1, f"segments must be (S, 4) with S >= 1, got {tuple(segments.shape)}")
    _require(reach > 0, f"reach must be > 0 m, got {reach!r}")
    cell = float(reach if cell is None else cell)
    seg = segments.detach().to(torch.float64)
    lo = torch.minimum(seg[:, 0:2], seg[:, 2:4]).amin(0) - reach
    hi = torch.maximum(seg[:, 0:2], seg[:, 2:4]).amax(0) + reach
    nx, ny = (int(math.ceil(v)) for v in ((hi - lo) / cell).clamp(min=1).tolist())
    iy, ix = torch.meshgrid(torch.arange(ny), torch.arange(nx), indexing="ij")
    cx = (lo[0] + (ix.reshape(-1).to(seg) + 0.5) * cell).to(seg.device)
    cy = (lo[1] + (iy.reshape(-1).to(seg) + 0.5) * cell).to(seg.device)
    limit = reach + cell * math.sqrt(0.5)
    near = torch.cat([segment_distance(cx[i:i + chunk, None], cy[i:i + chunk, None], seg) <= limit
                      for i in range(0, cx.numel(), chunk)])  # (cells, S)
    m = max(1, int(near.sum(-1).max()))
    # Stable sort puts each cell's listed segments first, in index order.
    order = torch.sort((~near).to(torch.int8), dim=-1, stable=True).indices[:, :m]
    mask = torch.gather(near, 1, order)
    return SegmentGrid(
        segments=segments, origin=lo.to(segments), cell=cell, nx=nx, ny=ny, reach=float(reach),
        cand=torch.where(mask, order, torch.zeros_like(order)), cand_mask=mask,
    )


def nearest_distance(points: Tensor, grid: SegmentGrid) -> Tensor:
    """Distance ``(...)`` from points ``(..., 2)`` to the nearest centreline segment, capped at ``grid.reach``.

    Exact (equal to :func:`nearest_distance_brute`) wherever that is below ``reach``.
    Points outside the grid read ``reach``.
    """
    rel = (points - grid.origin) / grid.cell
    ix = torch.floor(rel[..., 0]).long()
    iy = torch.floor(rel[..., 1]).long()
    inside = (ix >= 0) & (ix < grid.nx) & (iy >= 0) & (iy < grid.ny)
    flat = torch.where(inside, iy.clamp(0, grid.ny - 1) * grid.nx + ix.clamp(0, grid.nx - 1), torch.zeros_like(ix))
    cand = grid.cand[flat]  # (..., M)
    seg = grid.segments[cand]  # (..., M, 4)
    d = segment_distance(points[..., 0:1], points[..., 1:2], seg)
    d = torch.where(grid.cand_mask[flat] & inside[..., None], d, torch.full_like(d, grid.reach))
    return d.amin(-1).clamp(max=grid.reach)


# --------------------------------------------------------------------------- readings


def _disc_left_of(t: Tensor, radius: float) -> Tensor:
    """Fraction of a disc of ``radius`` lying at offset ``< t`` from its centre along one axis."""
    u = t / radius
    inside = u.abs() < 1.0
    us = torch.where(inside, u, torch.zeros_like(u))  # keep acos/sqrt away from |u| = 1 in backward
    f = (torch.acos(-us) + us * torch.sqrt(1.0 - us * us)) / math.pi
    return torch.where(inside, f, (u > 0).to(u.dtype))


def band_coverage(d: Tensor, half_width: float, radius: float) -> Tensor:
    """Fraction in [0, 1] of a disc of ``radius`` centred at distance ``d`` (m) from the centre
    line of a straight band of half-width ``half_width`` (m) that the band covers."""
    return (_disc_left_of(half_width - d, radius) - _disc_left_of(-half_width - d, radius)).clamp(0.0, 1.0)


def floor_readings(d: Tensor, half_width: float, params: FloorSensorParams, generator: torch.Generator | None = None) -> Tensor:
    """Sensor values ``(B, K)`` in [0, 1] from distances ``d`` ``(B, K)`` (m) to the line centre.

    Noise is added only with ``params.noise_std > 0`` and a ``generator`` (``analog`` and
    ``binary`` modes; the ``smooth`` mode is noise-free).
    """
    if params.mode == "smooth":
        return torch.sigmoid((half_width + params.radius - d) / params.softness)
    c = band_coverage(d, half_width, params.radius)
    if params.noise_std > 0 and generator is not None:
        c = (c + params.noise_std * torch.randn(c.shape, generator=generator, dtype=c.dtype, device=c.device)).clamp(0.0, 1.0)
    if params.mode == "binary":
        return (c > params.threshold).to(c.dtype)
    return c
