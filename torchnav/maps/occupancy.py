"""Occupancy images -> axis-aligned boxes, and the PNG mask reader shared with line tracks.

A map's ``occupancy:`` image is thresholded to a bool mask and its occupied pixels are merged
into disjoint rectangles whose union is exactly the occupied pixels. The pixel-to-world layout
(row 0 at the top) and the greedy cover: docs/maps.md, "Occupancy images".
"""

from __future__ import annotations

import os
from typing import Any, Callable

import numpy as np


class ImageError(ValueError):
    """An image file could not be read; the message names the file."""


MAX_PIXELS = 4096 * 4096  # an occupancy or track image larger than this is refused before decoding


def read_image(path: str | os.PathLike, convert: Callable[[Any], np.ndarray]) -> np.ndarray:
    """``convert(image)`` of the Pillow image at ``path``, once its size is known to be at most
    :data:`MAX_PIXELS`. Raises :class:`ImageError` naming the file when it is missing, too big or
    not an image (also for an error ``convert`` raises while decoding)."""
    # Pillow comes with matplotlib, a torchnav dependency; imported here so that importing
    # torchnav.maps does not pay for it.
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:  # reads the header only: the size is known before any pixel is decoded
            if im.width * im.height > MAX_PIXELS:
                raise ImageError(f"{path}: {im.width} x {im.height} pixels is more than the {MAX_PIXELS:,} allowed; downscale the image")
            return convert(im)
    except Image.DecompressionBombError as e:  # Pillow's own, larger, limit refuses it inside open()
        raise ImageError(f"{path}: more than the {MAX_PIXELS:,} pixels allowed ({e}); downscale the image") from None
    except FileNotFoundError:
        raise ImageError(f"{path}: image file not found") from None
    except (OSError, UnidentifiedImageError) as e:
        raise ImageError(f"{path}: cannot read image: {e}") from None


def read_mask(path: str | os.PathLike, threshold: float = 0.5, invert: bool = False) -> np.ndarray:
    """``(H, W)`` bool mask of a PNG: grey level (in [0, 1]) above ``threshold``, or below it with ``invert``.

    Colour images are converted to grey first (ITU-R 601 luma); an alpha channel is ignored.
    Raises :class:`ImageError` when the file is missing or not an image.
    """
    grey = read_image(path, lambda im: np.asarray(im.convert("L"), dtype=np.float64) / 255.0)
    return (grey < threshold) if invert else (grey > threshold)


def mask_rectangles(mask: np.ndarray) -> np.ndarray:
    """Disjoint pixel rectangles whose union is the True pixels of ``mask`` ``(H, W)``.

    Returns ``(N, 4)`` int64 ``[row0, col0, row1, col1]``, half-open (rows ``row0 ..
    row1 - 1``, columns ``col0 .. col1 - 1``), sorted by ``(row0, col0)``.
    """
    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise ValueError(f"mask must be 2-D (H, W), got shape {m.shape}")
    h, w = m.shape
    padded = np.zeros((h, w + 2), dtype=np.int8)
    padded[:, 1:-1] = m
    step = np.diff(padded, axis=1)  # (H, W + 1): +1 at a run's first column, -1 one past its last
    row, c0 = np.nonzero(step == 1)
    _, c1 = np.nonzero(step == -1)  # row-major order: the k-th end closes the k-th start
    if len(row) == 0:
        return np.zeros((0, 4), dtype=np.int64)
    # Runs over the same columns in consecutive rows form one rectangle: sort by (c0, c1, row)
    # and cut wherever the columns change or a row is skipped.
    order = np.lexsort((row, c1, c0))
    row, c0, c1 = row[order], c0[order], c1[order]
    cut = np.ones(len(row), dtype=bool)
    cut[1:] = (c0[1:] != c0[:-1]) | (c1[1:] != c1[:-1]) | (row[1:] != row[:-1] + 1)
    first = np.nonzero(cut)[0]
    last = np.append(first[1:], len(row)) - 1
    rects = np.stack((row[first], c0[first], row[last] + 1, c1[first]), axis=1).astype(np.int64)
    return rects[np.lexsort((rects[:, 1], rects[:, 0]))]


def mask_boxes(mask: np.ndarray, resolution: float, origin: tuple[float, float]) -> np.ndarray:
    """World boxes ``(N, 5)`` ``[cx, cy, half_x, half_y, yaw=0]`` (m, rad) covering the True pixels of
    ``mask`` ``(H, W)`` exactly, for pixels of ``resolution`` m with the image's lower-left corner at
    world ``origin`` ``(x, y)`` m."""
    h = np.asarray(mask).shape[0]
    r = mask_rectangles(mask).astype(np.float64)
    ox, oy = origin
    x0, x1 = ox + r[:, 1] * resolution, ox + r[:, 3] * resolution
    y0, y1 = oy + (h - r[:, 2]) * resolution, oy + (h - r[:, 0]) * resolution
    return np.stack(((x0 + x1) / 2, (y0 + y1) / 2, (x1 - x0) / 2, (y1 - y0) / 2, np.zeros(len(r))), axis=1)
