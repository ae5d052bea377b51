"""Robot presets: the bodies, speed and acceleration limits and actuator delays of robots users
deploy to, as ``robot`` (and ``randomize.delay``) values of a navigation config (docs/tasks.md,
"Robot presets", says where each number comes from).

``robot: {preset: jackal}`` starts the robot from the preset; keys given beside it win over the
preset's (``robot: {preset: jackal, v_max: 1.0}``). A preset's delay (whole steps of ``robot.dt``)
becomes ``randomize.delay: [d, d]`` unless ``randomize.delay`` is given. A rectangular robot is a
conservative disc: the smallest disc about its rotation centre that holds its footprint.
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping

# name -> (robot values, actuator delay in steps of robot.dt)
ROBOT_PRESETS: dict[str, tuple[dict[str, float], int]] = {
    # torchnav's idealised robot (the RobotConfig defaults): a 0.2 m disc, no acceleration limit, no delay
    "default": ({}, 0),
    # ROBOTIS TurtleBot3 Burger: 0.22 m/s and 2.84 rad/s (the e-Manual's specifications), wheel separation
    # 0.160 m and robot radius 0.105 m (OpenCR firmware), 2.5 m/s^2 and 3.2 rad/s^2 (turtlebot3_navigation's
    # DWA parameters for the Burger)
    "turtlebot3_burger": ({"radius": 0.105, "track_width": 0.160, "v_max": 0.22, "omega_max": 2.84, "lin_acc_max": 2.5,
                           "ang_acc_max": 3.2}, 1),
    # TurtleBot3 Waffle / Waffle Pi: 0.26 m/s and 1.82 rad/s (e-Manual), wheel separation 0.287 m (firmware), the
    # disc about base_link round the navigation footprint x in [-0.205, 0.077], y in [-0.145, 0.145] m (0.251 m),
    # 2.5 m/s^2 and 3.2 rad/s^2 (turtlebot3_navigation's DWA parameters for the Waffle)
    "turtlebot3_waffle": ({"radius": round(math.hypot(0.205, 0.145), 3), "track_width": 0.287, "v_max": 0.26, "omega_max": 1.82,
                           "lin_acc_max": 2.5, "ang_acc_max": 3.2}, 1),
    # Clearpath Jackal: 2.0 m/s, 4.0 rad/s, 20 m/s^2 and 25 rad/s^2 (the velocity controller's limits,
    # jackal_control/config/control.yaml), track 0.376 m (jackal_description), the disc round the navigation
    # footprint 0.42 x 0.33 m (jackal_navigation: 0.267 m)
    "jackal": ({"radius": round(math.hypot(0.21, 0.165), 3), "track_width": 0.376, "v_max": 2.0, "omega_max": 4.0, "lin_acc_max": 20.0,
                "ang_acc_max": 25.0}, 1),
}
# The delay: none of the sources gives a command-to-motion latency; one control step (0.1 s) is an assumption.


BODY_KEYS = ("radius", "track_width", "v_max", "omega_max", "lin_acc_max", "ang_acc_max")  # what a preset sets


def override_config(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """A navigation config ``base`` (a dict: a checkpoint's saved task config) with the overrides
    ``over`` laid over it (``torchnav.config.merge``). A ``robot.preset`` in ``over`` replaces the
    base's body (:data:`BODY_KEYS`): the saved config holds every robot key, and as keys given beside
    a preset they would win over it, so the preset would change nothing. The robot keys ``over`` gives
    still win over its preset; ``dt``, the integrator, odometry noise and ``randomize`` stay the base's."""
    from ..config import merge

    robot = over.get("robot")
    if isinstance(robot, Mapping) and "preset" in robot and isinstance(base.get("robot"), Mapping):
        base = {**base, "robot": without_body(base["robot"])}
    return merge(base, over)


def without_body(robot: Mapping[str, Any], keep: Iterable[str] = ()) -> dict[str, Any]:
    """A ``robot`` section without its body (:data:`BODY_KEYS`) but for ``keep``: what a preset laid
    over it leaves of it."""
    keep = set(keep)
    return {k: v for k, v in robot.items() if k not in BODY_KEYS or k in keep}


def with_robot_preset(data: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """``data`` (a navigation config as a dict) with its ``robot.preset``'s values under the keys it gives;
    unchanged without a preset, or with an unknown one (which ``RobotConfig`` then names)."""
    if not isinstance(data, Mapping) or not isinstance(data.get("robot"), Mapping):
        return data  # type: ignore[return-value]
    robot = data["robot"]
    name = robot.get("preset")
    if not isinstance(name, str) or name not in ROBOT_PRESETS:
        return dict(data)
    values, delay = ROBOT_PRESETS[name]
    out = {**data, "robot": {**values, **robot}}
    randomize = data.get("randomize")
    if delay and (randomize is None or isinstance(randomize, Mapping)) and (randomize or {}).get("delay") is None:
        out["randomize"] = {**(randomize or {}), "delay": [delay, delay]}
    return out


__all__ = ["BODY_KEYS", "ROBOT_PRESETS", "override_config", "with_robot_preset", "without_body"]
