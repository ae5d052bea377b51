"""Simulator parameters for the tests, from the navigation task's defaults.

The simulator declares no defaults for what a task config declares (``torchnav.sim.params``), so
the tests take the navigation task's robot, lidar and camera (``NavConfig().sim_params()``) and
name only what they change. One difference: ``sim_params`` drives both ways at up to 0.5 m/s,
the limits the simulator tests were written for (the task's robot drives forward at up to 1 m/s).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from torchnav.sim import CameraParams, LidarParams, SimParams
from torchnav.tasks import NavConfig

_TASK = NavConfig.from_dict({"camera": {"enabled": True}}).sim_params()


def lidar_params(**changes: Any) -> LidarParams:
    """The navigation task's lidar (20 rays over 180 degrees, 10 m) with ``changes``."""
    return replace(_TASK.lidar, **changes)


def camera_params(**changes: Any) -> CameraParams:
    """The navigation task's camera (64 x 48 pixels, 90 degrees, 10 m) with ``changes``."""
    return replace(_TASK.camera, **changes)


def sim_params(**changes: Any) -> SimParams:
    """The navigation task's robot and lidar, driving both ways at up to 0.5 m/s, no IMU or camera, with ``changes``."""
    return replace(_TASK, **{"v_min": -0.5, "v_max": 0.5, "camera": None, **changes})
