"""A line-following track: line geometry for the sensors and a lap path for progress.

Built once (numpy, float64) by :mod:`torchnav.tracks.loader`; moved to the
simulation device and dtype with :meth:`Track.tensors`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..sim.floor import SegmentGrid, build_segment_grid
from .geometry import arc_lengths


class TrackError(ValueError):
    """A track could not be found, read or validated. The message names the file and key."""


@dataclass(frozen=True, eq=False)
class Track:
    """One track (the same for every env of a batch); arrays in m."""

    name: str  # track name (file stem for files)
    width: float  # m, width of the line (tape)
    segments: np.ndarray  # (S, 4) centreline segments [x1, y1, x2, y2] of every line
    lines: tuple[np.ndarray, ...]  # resampled polylines (N_i, 2) for drawing (a closed one repeats its first point)
    lap: np.ndarray  # (P, 2) closed lap path, first vertex repeated, in driving direction; lap[0] is the start line
    walls: np.ndarray  # (W, 4) wall segments seen by the forward distance sensor; often empty
    spacing: float  # m, resampling step of lines and lap path
    source: str = "<dict>"  # the file the track came from
    description: str = ""  # free text from the file

    @property
    def lap_s(self) -> np.ndarray:
        """``(P,)`` cumulative arc length (m) at the lap path's vertices."""
        return arc_lengths(self.lap)

    @property
    def length(self) -> float:
        """Lap length in m."""
        return float(self.lap_s[-1])

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of the line centres and walls, m."""
        pts = np.concatenate([self.segments[:, :2], self.segments[:, 2:], self.walls[:, :2], self.walls[:, 2:]])
        lo, hi = pts.min(0), pts.max(0)
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))

    def tensors(self, reach: float, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32) -> "TrackTensors":
        """The track on ``device`` with a :class:`SegmentGrid` of ``reach`` (m) for the sensors."""
        seg = torch.as_tensor(self.segments, dtype=torch.float64)
        grid = build_segment_grid(seg, reach=reach, cell=reach / 2).to(device=device, dtype=dtype)
        return TrackTensors(
            grid=grid,
            lap=torch.as_tensor(self.lap, dtype=dtype, device=device),
            lap_s=torch.as_tensor(self.lap_s, dtype=dtype, device=device),
            walls=torch.as_tensor(self.walls.reshape(-1, 4), dtype=dtype, device=device),
            length=self.length,
            width=self.width,
        )


@dataclass(frozen=True)
class TrackTensors:
    """A :class:`Track` as tensors on the simulation device (m)."""

    grid: SegmentGrid  # segments and cell lists for torchnav.sim.floor.nearest_distance
    lap: Tensor  # (P, 2) lap path vertices
    lap_s: Tensor  # (P,) their arc lengths
    walls: Tensor  # (W, 4) wall segments
    length: float  # lap length
    width: float  # line width
