"""The potential field's local minimum: a cup-shaped wall between the robot and the goal.

    python docs/scripts/controller_pictures.py --out docs/img/potential_field_trap.png

Drives potential_field, reactive and astar (torchnav.controllers.drive) from the same
start to the same goal behind the cup, 300 steps (30 s), and draws the three paths.
The map is the one tests/test_controllers.py uses for the same claim.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
from matplotlib.figure import Figure  # noqa: E402

from _figures import save  # noqa: E402

from torchnav.controllers import drive, make_controller  # noqa: E402
from torchnav.maps import load_map  # noqa: E402
from torchnav.render import draw_goal, draw_obstacles, draw_robots  # noqa: E402
from torchnav.tasks import NavConfig  # noqa: E402

CUP = """
name: cup
size: [10.0, 10.0]
walls:
  - boundary
  - [1.0, -1.5, 1.0, 1.5]
  - [1.0, -1.5, -0.5, -1.5]
  - [1.0, 1.5, -0.5, 1.5]
"""
START, GOAL = [[-3.0, 0.0, 0.0]], [[3.5, 0.0]]


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--out", default="docs/img/potential_field_trap.png")
    a = p.parse_args()
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "cup.yaml"
        path.write_text(CUP)
        spec = load_map(str(path))
        nav = NavConfig.from_dict({"map": str(path)})
        names = ("potential_field", "reactive", "astar")
        runs = {n: drive(make_controller(n), nav, START, GOAL, steps=300) for n in names}
    fig = Figure(figsize=(10.5, 3.8))
    for k, n in enumerate(names):
        ax = fig.add_subplot(1, 3, k + 1)
        r = runs[n]
        draw_obstacles(ax, spec.segments)
        xy = r["pose"][0, :, :2].numpy()
        ax.plot(xy[:, 0], xy[:, 1], "-", color="tab:blue", lw=1.2)
        draw_robots(ax, r["pose"][:, -1], nav.robot.radius)
        draw_goal(ax, GOAL, radius=nav.goal_tolerance)
        outcome = "reached the goal" if r["success"][0] else "collided" if r["collision"][0] else "still trapped after 30 s"
        ax.set_title(f"{n}: {outcome}", fontsize=9)
        ax.set_xlim(-4.5, 4.5)
        ax.set_ylim(-3.5, 3.5)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    save(fig, a.out, dpi=100)


if __name__ == "__main__":
    main()
