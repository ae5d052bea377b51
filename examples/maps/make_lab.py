"""Draws examples/maps/lab.pgm, the example ROS map_server map of docs/maps.md ("ROS map_server maps").

    python examples/maps/make_lab.py          # rewrites lab.pgm next to this script

An 8 x 6 m lab at 0.05 m per pixel, grey levels as Nav2's map_saver writes them in trinary mode:
254 free, 0 occupied, 205 unknown. Two offices on top and a workshop below, each with a
0.9 m door onto a 1 m corridor; walls 0.15 m thick; unknown space outside the walls (what a
lidar never saw), and a cabinet in the workshop seen only from outside (unknown inside).
lab.yaml is its map_server YAML.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

FREE, OCCUPIED, UNKNOWN = 254, 0, 205
WALL, MARGIN = 3, 10  # px: 0.15 m walls, 0.5 m of unknown around the outer walls
W, H = 160, 120  # px inside the outer walls: 8 x 6 m


def draw() -> np.ndarray:
    """``(H + 2 * (WALL + MARGIN), W + 2 * (WALL + MARGIN))`` uint8 grey levels; row 0 is the top (north)."""
    img = np.full((H + 2 * (WALL + MARGIN), W + 2 * (WALL + MARGIN)), UNKNOWN, dtype=np.uint8)
    o = MARGIN + WALL  # image index of the inside's first pixel

    def fill(x0: int, y0: int, x1: int, y1: int, v: int) -> None:  # inside px, half-open, y down
        img[o + y0:o + y1, o + x0:o + x1] = v

    fill(-WALL, -WALL, W + WALL, H + WALL, OCCUPIED)  # the outer walls ...
    fill(0, 0, W, H, FREE)  # ... around the free inside
    fill(79, 0, 79 + WALL, 47, OCCUPIED)  # between the two offices
    fill(0, 47, W, 47 + WALL, OCCUPIED)  # offices | corridor (rows 50 to 69), with a door into each office
    fill(30, 47, 48, 47 + WALL, FREE)
    fill(110, 47, 128, 47 + WALL, FREE)
    fill(0, 70, W, 70 + WALL, OCCUPIED)  # corridor | workshop, with one door
    fill(60, 70, 78, 70 + WALL, FREE)
    fill(100, 92, 120, 104, OCCUPIED)  # a 1.0 x 0.6 m workbench in the workshop
    fill(4, 95, 28, 115, OCCUPIED)  # a cabinet: its faces seen, its inside unknown
    fill(6, 97, 26, 113, UNKNOWN)
    return img


if __name__ == "__main__":
    out = Path(__file__).resolve().with_name("lab.pgm")
    Image.fromarray(draw()).save(out)  # binary PGM (P5), as map_saver writes
    print(f"wrote {out}")
