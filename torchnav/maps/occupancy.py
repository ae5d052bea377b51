"""The PNG mask reader shared by map occupancy images and line tracks."""

from __future__ import annotations

import os

import numpy as np


class ImageError(ValueError):
    """An image file could not be read; the message names the file."""


def read_mask(path: str | os.PathLike, threshold: float = 0.5, invert: bool = False) -> np.ndarray:
    """``(H, W)`` bool mask of a PNG: grey level (in [0, 1]) above ``threshold``, or below it with ``invert``.

    Colour images are converted to grey first (ITU-R 601 luma); an alpha channel is ignored.
    Raises :class:`ImageError` when the file is missing or not an image.
    """
    # Pillow comes with matplotlib, a torchnav dependency; imported here so that importing
    # torchnav.maps does not pay for it.
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            grey = np.asarray(im.convert("L"), dtype=np.float64) / 255.0
    except FileNotFoundError:
        raise ImageError(f"{path}: image file not found") from None
    except (OSError, UnidentifiedImageError) as e:
        raise ImageError(f"{path}: cannot read image: {e}") from None
    return (grey < threshold) if invert else (grey > threshold)
