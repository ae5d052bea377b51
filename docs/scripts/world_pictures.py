"""Write docs/img/worlds/<family>.png: one world of each family at difficulty 0, 0.5 and 1.

Run from the repo root:  python docs/scripts/world_pictures.py
Each panel shows the obstacles (grey), the robot at its start (blue disc with a
heading tick), the goal (green star) and, in the title, the path length that
placement guarantees. Seeded: the pictures change only when the generators do.
"""

from __future__ import annotations

from pathlib import Path

import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from torchnav.render import draw_goal, draw_robots, draw_world
from torchnav.worlds import FAMILIES, make_worlds

OUT = Path(__file__).resolve().parents[1] / "img" / "worlds"
LEVELS = (("easy", 0.0), ("medium", 0.5), ("hard", 1.0))


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for family in FAMILIES:
        fig = Figure(figsize=(10.5, 3.8), dpi=80)
        FigureCanvasAgg(fig)
        for k, (label, difficulty) in enumerate(LEVELS):
            batch = make_worlds(family, 1, difficulty, torch.Generator().manual_seed(3))
            ax = fig.add_subplot(1, 3, k + 1)
            draw_world(ax, batch.world, env=0)
            draw_robots(ax, batch.start, batch.robot_radius, env=0)
            draw_goal(ax, batch.goal, env=0)
            xmin, ymin, xmax, ymax = batch.bounds[0].tolist()
            pad = 0.03 * (xmax - xmin)
            ax.set_xlim(xmin - pad, xmax + pad)
            ax.set_ylim(ymin - pad, ymax + pad)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
            ax.set_title(f"{family}, {label} (d={difficulty:g}): path {batch.path_length[0]:.1f} m", fontsize=9)
        fig.tight_layout()
        path = OUT / f"{family}.png"
        fig.savefig(path)
        print(f"{path} ({path.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
