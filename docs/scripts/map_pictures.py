"""Write docs/img/maps/<name>.png for every shipped map and the dense example map of docs/maps.md.

Run from anywhere:  python docs/scripts/map_pictures.py
Each picture shows the fixed obstacles (grey), one example layout of the
random objects (dashed orange; the task re-samples them on every reset) and a
0.2 m robot in the bottom-left free corner for scale.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from torchnav.maps import available_maps, load_map
from torchnav.maps.free_space import free_grid
from torchnav.render import draw_robots, plot_map

OUT = Path(__file__).resolve().parents[1] / "img" / "maps"
EXAMPLE = Path(__file__).resolve().parents[2] / "tests" / "data" / "dense_room.yaml"  # not shipped: an example
ROBOT_RADIUS = 0.2  # m, the default SimParams.robot_radius


def scale_robot_pose(spec) -> np.ndarray:
    """A free spot near the bottom-left corner, to show the robot's size."""
    free, xs, ys = free_grid(spec, ROBOT_RADIUS + 0.1, resolution=0.1)
    j, i = np.argwhere(free)[np.argmin([ys[j] + xs[i] for j, i in np.argwhere(free)])]
    return np.array([[xs[i], ys[j], 0.0]])


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for spec in [load_map(name) for name in available_maps()] + [load_map(EXAMPLE)]:
        w, h = spec.size
        fig = Figure(figsize=(4.5, 4.5 * h / w + 0.5), dpi=90)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        plot_map(spec, ax, n_samples=1, seed=1)
        draw_robots(ax, scale_robot_pose(spec), ROBOT_RADIUS)
        path = OUT / f"{spec.name}.png"
        fig.savefig(path, bbox_inches="tight")
        print(f"{path} ({path.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
