"""Analytic policy gradients through the differentiable simulator on the line-following task.

    python recipes/apg_line.py                        # the course track, 64 envs, horizons of 32 steps, CPU
    python recipes/apg_line.py task.track=oval smooth.path=-1.0

The same algorithm as ``apg_lidar.py`` (SHAC-style: backpropagation through
``LineTask.step`` over a short horizon, a critic bootstrapping its end): the floor
sensors' readings are soft coverages of the tape, so the observation, the progress
along the lap and the distance from the line are all differentiable in the pose.
Leaving the line, stalling and collisions end an episode with a constant penalty
that has no gradient; ``smooth.path`` adds ``smooth.path * (d / max_path_distance)^2``,
``d`` the distance of the robot centre from the lap path, in their place. Every
config key is documented in recipes/configs/apg_line.yaml.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import apg_lidar  # noqa: E402


def main(argv: list[str]) -> dict:
    return apg_lidar.main(argv, name="apg_line")


if __name__ == "__main__":
    apg_lidar.B.main_guard(main)
