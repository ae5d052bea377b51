"""ROS ``map_server`` maps -> torchnav geometry, and the transform between torchnav's world and the ROS ``map`` frame.

A map_server map (what slam_toolbox, Cartographer, gmapping and Nav2's map_saver write) is a YAML
file with ``image``, ``resolution``, ``origin``, ``negate``, ``occupied_thresh``, ``free_thresh``
and optionally ``mode``, next to a PGM or PNG. Its pixels are classified exactly as Nav2's
map_server does (``nav2_map_server`` ``map_io.cpp``, ``loadMapFromFile``) into occupied, free and
unknown cells; torchnav's world is binary, so unknown cells become occupied or free (``unknown``),
the image may be cropped to its known area (``crop``), and the occupied cells become boxes
(:func:`~.occupancy.mask_boxes`). docs/maps.md, "ROS map_server maps", states every rule.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..yamlcheck import Ctx, check_mapping, check_number, check_vector, is_number, show
from .occupancy import ImageError, mask_boxes, read_image

MODES = ("trinary", "scale", "raw")
UNKNOWN_AS = ("occupied", "free")  # what torchnav makes of an unknown cell
KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")  # required, as map_server requires them
OPTIONAL_KEYS = ("mode",)
FREE, OCCUPIED, UNKNOWN = 0, 1, -1  # cell codes of :attr:`Grid.cells`
IDENTITY = (0.0, 0.0, 0.0)  # the frame of a map that is not a map_server map


@dataclass(frozen=True)
class Grid:
    """A map_server map as map_server reads it: ``cells`` ``(H, W)`` int8 (``FREE``, ``OCCUPIED`` or
    ``UNKNOWN``; row 0 is the top of the image), ``resolution`` m per cell and ``origin`` ``(x m, y m,
    yaw rad)``: the pose in the ROS ``map`` frame of the lower-left corner of the image's bottom-left
    pixel, the image's x axis along yaw."""

    cells: np.ndarray
    resolution: float
    origin: tuple[float, float, float]
    image: Path


def is_map_server(data: Any) -> bool:
    """Whether a parsed YAML document is a map_server map: it has ``image`` (or another key of the
    map_server format, none of which a torchnav map has: then a missing ``image`` is named) and neither
    of the torchnav keys ``size`` and ``map_server``."""
    return isinstance(data, dict) and not {"size", "map_server"} & set(data) and any(k in data for k in KEYS + OPTIONAL_KEYS)


def _negate(ctx: Ctx, v: Any) -> bool:
    # map_server reads negate as an int, else as a bool; only 0 and 1 are meaningful.
    if isinstance(v, bool) or (isinstance(v, int) and v in (0, 1)):
        return bool(v)
    raise ctx.fail("negate", f"expected 0 or 1 (or true / false), got {show(v)}")


def _threshold(ctx: Ctx, v: Any, key: str) -> float:
    if not is_number(v) or not 0.0 <= v <= 1.0:
        raise ctx.fail(key, f"expected a number in [0, 1] (an occupancy probability), got {show(v)}")
    return float(v)


def read_grid(ctx: Ctx, data: Any, base_dir: str | os.PathLike | None) -> Grid:
    """Validate a map_server YAML document ``data`` (errors name ``ctx``'s file and the key) and
    classify its image's pixels; every key is checked before the image is opened, and the image's
    size before it is decoded. ``base_dir``: the YAML file's folder (a relative ``image`` is read
    from there, as map_server does; None: the current folder)."""
    d = check_mapping(ctx, data, "", KEYS, OPTIONAL_KEYS)
    image = d["image"]
    if not isinstance(image, str) or not image:
        raise ctx.fail("image", f"expected the path of a PGM or PNG file, got {show(image)}")
    path = Path(image) if base_dir is None or os.path.isabs(image) else Path(base_dir) / image
    res = check_number(ctx, d["resolution"], "resolution", "pos")
    origin = check_vector(ctx, d["origin"], "origin", 3)
    negate = _negate(ctx, d["negate"])
    occ_th = _threshold(ctx, d["occupied_thresh"], "occupied_thresh")
    free_th = _threshold(ctx, d["free_thresh"], "free_thresh")
    if free_th >= occ_th:
        raise ctx.fail("free_thresh", f"must be below occupied_thresh ({occ_th:g}), got {free_th:g}")
    mode = d.get("mode", "trinary")
    if mode not in MODES:
        raise ctx.fail("mode", f"expected one of {', '.join(MODES)}, got {show(mode)}")
    try:
        shade, alpha = read_image(path, _shade)
    except ImageError as e:
        raise ctx.fail("image", str(e)) from None
    return Grid(classify(shade, alpha, mode, negate, occ_th, free_th), res, origin, path)


def _shade(im: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """``(H, W)`` brightness in [0, 1] (the mean of the colour channels, as map_server takes it) and
    ``(H, W)`` opacity in [0, 1], or None for an image without an alpha channel."""
    mode = im.mode
    if mode.startswith("I"):  # 16-bit grey (PGM with maxval 65535, 16-bit PNG)
        return np.asarray(im, dtype=np.float64) / 65535.0, None
    if mode == "F":
        raise ImageError(f"{im.filename}: floating-point images are not map_server images; save it as 8-bit grey")
    if mode in ("1", "L"):
        return np.asarray(im.convert("L"), dtype=np.float64) / 255.0, None
    if mode in ("LA", "La"):
        la = np.asarray(im.convert("LA"), dtype=np.float64)
        # A grey pixel's three colour channels are equal; the mean of them is its grey level.
        return la[..., 0] / 255.0, la[..., 1] / 255.0
    alpha = "A" in mode or "transparency" in im.info
    rgb = np.asarray(im.convert("RGBA" if alpha else "RGB"), dtype=np.float64)
    return rgb[..., :3].sum(axis=-1) / 3.0 / 255.0, (rgb[..., 3] / 255.0 if alpha else None)


def classify(shade: np.ndarray, alpha: np.ndarray | None, mode: str, negate: bool, occupied_thresh: float, free_thresh: float) -> np.ndarray:
    """``(H, W)`` int8 cells (``FREE``, ``OCCUPIED``, ``UNKNOWN``) of pixels of brightness ``shade``
    ``(H, W)`` in [0, 1] and opacity ``alpha`` ``(H, W)`` in [0, 1] (None: opaque), as Nav2's
    map_server classifies them. What torchnav cannot represent (scale mode's and raw mode's
    values between the thresholds) is ``UNKNOWN``."""
    if mode == "trinary" and alpha is not None:
        # map_server averages the opacity in with the colour channels in trinary mode (3 of them; a grey pixel's are equal).
        shade = (3.0 * shade + alpha) / 4.0
    if mode == "raw":
        # The grid value is the brightness on 0..255 (negate does not apply); 0..100 is an
        # occupancy in percent, anything above it unknown. The file's thresholds read that occupancy.
        value = np.floor(shade * 255.0 + 0.5)
        occ = value / 100.0
        known = value <= 100
    else:
        occ = shade if negate else 1.0 - shade
        known = np.ones(shade.shape, dtype=bool) if mode == "trinary" or alpha is None else alpha >= 1.0
    cells = np.full(shade.shape, UNKNOWN, dtype=np.int8)
    cells[known & (occ > occupied_thresh)] = OCCUPIED
    cells[known & (occ < free_thresh)] = FREE
    return cells


@dataclass(frozen=True)
class Layout:
    """A :class:`Grid` as a torchnav world: ``size`` ``(w, h)`` m, the occupied cells as boxes ``(N, 5)``
    ``[cx, cy, half_x, half_y, 0]`` m, and ``frame``, the pose ``(x m, y m, yaw rad)`` of torchnav's
    world origin in the ROS ``map`` frame (torchnav's x axis along the image's)."""

    size: tuple[float, float]
    boxes: np.ndarray
    frame: tuple[float, float, float]


def layout(ctx: Ctx, key: str, grid: Grid, unknown: str = "occupied", crop: bool = True) -> Layout:
    """The world of ``grid`` centred on torchnav's origin: unknown cells occupied (or free with
    ``unknown="free"``), cropped to the bounding box of the known (free or occupied) cells with
    ``crop``. Raises ``ctx``'s error naming ``key`` when no cell is free."""
    cells = grid.cells
    h_img = cells.shape[0]
    rows, cols = np.nonzero(cells != UNKNOWN)
    if crop and len(rows):
        r0, r1, c0, c1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
    else:
        r0, r1, c0, c1 = 0, cells.shape[0], 0, cells.shape[1]
    cells = cells[r0:r1, c0:c1]
    free = (cells == FREE) | ((cells == UNKNOWN) & (unknown == "free"))
    if not free.any():
        raise ctx.fail(key, f"{grid.image}: no pixel is free (occupancy below free_thresh{', or unknown' if unknown == 'free' else ''}); "
                       "check negate, the thresholds and mode")
    res = grid.resolution
    w, h = (c1 - c0) * res, (r1 - r0) * res
    boxes = mask_boxes(~free, res, (-w / 2, -h / 2))
    # The world's centre in the image's own frame (x right, y up from the bottom-left corner), then in the map frame.
    gx, gy = (c0 + c1) / 2 * res, (2 * h_img - r0 - r1) / 2 * res
    ox, oy, yaw = grid.origin
    c, s = math.cos(yaw), math.sin(yaw)
    return Layout((w, h), boxes, (ox + c * gx - s * gy, oy + s * gx + c * gy, yaw))


def _wrap(a: Any) -> Any:
    return torch.atan2(torch.sin(a), torch.cos(a)) if torch.is_tensor(a) else np.arctan2(np.sin(a), np.cos(a))


def _transform(frame: tuple[float, float, float], points: Any, inverse: bool) -> Any:
    fx, fy, fyaw = frame
    tensor = torch.is_tensor(points)
    p = points if tensor else np.asarray(points, dtype=np.float64)
    if p.ndim == 0 or p.shape[-1] not in (2, 3):
        raise ValueError(f"expected points (..., 2) [x, y] or poses (..., 3) [x, y, yaw], got shape {tuple(p.shape)}")
    c, s = math.cos(fyaw), math.sin(fyaw)
    x, y = p[..., 0], p[..., 1]
    if inverse:  # map frame -> torchnav: undo the translation, then the rotation
        x, y = x - fx, y - fy
        out = [c * x + s * y, -s * x + c * y]
    else:
        out = [fx + c * x - s * y, fy + s * x + c * y]
    if p.shape[-1] == 3:
        out.append(_wrap(p[..., 2] - fyaw if inverse else p[..., 2] + fyaw))
    return torch.stack(out, dim=-1) if tensor else np.stack(out, axis=-1)


def to_map_frame(frame: tuple[float, float, float], points: Any) -> Any:
    """Points ``(..., 2)`` ``[x, y]`` m or poses ``(..., 3)`` ``[x, y, yaw rad]`` from torchnav's
    world into the ROS ``map`` frame of a map whose world origin lies at pose ``frame`` there
    (:attr:`MapSpec.frame`). A tensor gives a tensor (same dtype and device), anything else a
    float64 numpy array; yaw is wrapped to [-pi, pi]."""
    return _transform(frame, points, inverse=False)


def from_map_frame(frame: tuple[float, float, float], points: Any) -> Any:
    """The inverse of :func:`to_map_frame`: points or poses in the ROS ``map`` frame (an RViz goal)
    into torchnav's world."""
    return _transform(frame, points, inverse=True)
