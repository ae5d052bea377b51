"""Pictures of the shipped line-following tracks, with the robot and its sensor array at the
lap start (docs/img/tracks/*.png). Run: python docs/scripts/track_pictures.py"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.patches import Circle, FancyArrowPatch  # noqa: E402

from torchnav.sim.floor import sensor_points  # noqa: E402
from torchnav.tasks import LineConfig, LineTask  # noqa: E402
from torchnav.tracks import available_tracks  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "img" / "tracks"


def draw(name: str, ax) -> None:
    cfg = LineConfig.from_dict({"track": name, "reset": {"start": 0.15, "lateral_noise": 0.0, "heading_noise": 0.0}})
    task = LineTask(cfg, 1)
    track = task.track
    x0, y0, x1, y1 = track.bounds
    pad = 0.15
    ax.set_xlim(x0 - pad, x1 + pad)
    ax.set_ylim(y0 - pad, y1 + pad)
    ax.set_aspect("equal")
    ax.set_facecolor("black")
    fig = ax.figure
    fig.canvas.draw()
    # line width in points for the tape's true width in metres
    bbox = ax.get_window_extent()
    pts_per_m = bbox.width / (x1 - x0 + 2 * pad) * 72 / fig.dpi
    segs = track.segments.reshape(-1, 2, 2)
    ax.add_collection(LineCollection(segs, colors="white", linewidths=track.width * pts_per_m, capstyle="round"))
    lap = track.lap
    q = len(lap) // 3
    ax.add_patch(FancyArrowPatch(lap[q], lap[q + 8], arrowstyle="-|>", mutation_scale=12, color="tab:orange", lw=1.5, zorder=5))
    state = task.initial_state(torch.Generator().manual_seed(0))
    pose = state.sim.pose
    x, y, th = pose[0].tolist()
    ax.add_patch(Circle((x, y), cfg.robot.radius, fill=False, ec="tab:blue", lw=1.5, zorder=6))
    ax.plot([x, x + 0.9 * cfg.robot.radius * np.cos(th)], [y, y + 0.9 * cfg.robot.radius * np.sin(th)], color="tab:blue", lw=1.5, zorder=6)
    sp = sensor_points(pose, task.sensor)[0].numpy()
    vals = state.readings[0].numpy()
    ax.scatter(sp[:, 0], sp[:, 1], c=vals, cmap="autumn_r", vmin=0, vmax=1, s=10, zorder=7, edgecolors="tab:red", linewidths=0.5)
    ax.set_title(f"{name}: lap {track.length:.2f} m, tape {1000 * track.width:.0f} mm", fontsize=10)
    ax.tick_params(labelsize=8)
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name in available_tracks():
        x0, y0, x1, y1 = LineTask(LineConfig.from_dict({"track": name}), 1).track.bounds
        w = 7.0
        fig, ax = plt.subplots(figsize=(w, w * (y1 - y0 + 0.3) / (x1 - x0 + 0.3) + 0.6), dpi=110)
        draw(name, ax)
        fig.tight_layout()
        fig.savefig(OUT / f"{name}.png")
        plt.close(fig)
        print("wrote", OUT / f"{name}.png")


if __name__ == "__main__":
    main()
