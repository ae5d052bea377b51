"""PPO on batched line following with a photodiode array, with TorchRL.

    python recipes/ppo_line.py                         # course track, 256 envs, CPU, a few minutes
    python recipes/ppo_line.py task.track=oval train.total_frames=1000000
    python recipes/ppo_line.py --resume                # continue the newest run

The same PPO as ``ppo_lidar.py`` (tanh Gaussian, observation normalisation, GAE,
``ClipPPOLoss``) on ``torchnav.envs.LineEnv``; evaluation counts full laps from
random starts. Every config key, its default and its documentation: torchnav/train_config.py;
recipes/configs/ppo_line.yaml holds what this recipe changes.
The saved ``actor.pt`` exports to ONNX and C: ``python -m torchnav.export``.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ppo_lidar  # noqa: E402


def main(argv: list[str]) -> dict:
    return ppo_lidar.main(argv, name="ppo_line")


if __name__ == "__main__":
    ppo_lidar.B.main_guard(main)
