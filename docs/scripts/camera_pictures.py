"""Write docs/img/camera.png: a top-down view of a robot in the arena with its camera's
column rays, the camera's 2.5D RGB image and its depth row.

Run from anywhere:  python docs/scripts/camera_pictures.py
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from torchnav.sim import CameraParams, camera_image, camera_rays, make_movers, make_world, mover_world
from torchnav.render import draw_obstacles, draw_robots

OUT = Path(__file__).resolve().parents[1] / "img" / "camera.png"


def main() -> None:
    world = make_world(
        1,
        segments=[[-5, -5, 5, -5], [5, -5, 5, 5], [5, 5, -5, 5], [-5, 5, -5, -5]],
        circles=[[2.0, 1.2, 0.35], [3.2, -1.5, 0.5]],
        boxes=[[1.5, -0.6, 0.3, 0.25, 0.4], [3.5, 0.6, 0.25, 0.6, 0.0]],
    )
    movers, mask, _ = make_movers(1, [[2.6, -0.1, 0.0, 0.3, 0.25]])
    cam = CameraParams(n_cols=160, n_rows=90, fov=math.radians(90), max_range=10.0, offset=(0.0, 0.0, 0.0), height=0.3)
    pose = torch.tensor([[-1.5, 0.0, 0.0]])
    depth, rgb = camera_image(pose, world, cam, mover_world(movers, mask))
    fig = Figure(figsize=(11, 3.6), dpi=90)
    FigureCanvasAgg(fig)
    ax0, ax1, ax2 = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1, 1.6, 1.6]})
    draw_obstacles(ax0, world.segments[0].numpy(), world.circles[0].numpy(), world.boxes[0].numpy())
    draw_obstacles(ax0, np.zeros((0, 4)), movers[0, :, [0, 1, 4]].numpy(), np.zeros((0, 5)), color="#d23c3c")
    origin, angles, local = camera_rays(pose, cam)
    d = (depth[0] / torch.cos(local)).numpy()[::8]
    a = angles[0].numpy()[::8]
    o = origin[0].numpy()
    ends = o + d[:, None] * np.stack([np.cos(a), np.sin(a)], -1)
    ax0.add_collection(LineCollection(np.stack([np.broadcast_to(o, ends.shape), ends], 1), colors="tab:blue", linewidths=0.6, alpha=0.7))
    draw_robots(ax0, pose, 0.2)
    ax0.set(xlim=(-5.2, 5.2), ylim=(-5.2, 5.2), aspect="equal", title="top view (every 8th column)")
    ax1.imshow(rgb[0].numpy(), interpolation="nearest")
    ax1.set(title=f"camera_image: RGB {cam.n_rows} x {cam.n_cols}", xticks=[], yticks=[])
    ax2.plot(depth[0].numpy(), color="tab:blue")
    ax2.set(xlabel="column (0 = left)", ylabel="depth (m)", title="depth row", ylim=(0, None))
    fig.tight_layout()
    fig.savefig(OUT)
    print(f"{OUT} ({OUT.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
