"""Simulator parameters: frozen dataclasses, SI units, validated on construction.

The simulator declares no default for a parameter that a task config declares: the task config
(``torchnav.tasks.NavConfig``, ``LineConfig``) is the one place of each default, and its
``sim_params()`` builds these classes from it. So ``SimParams``, ``LidarParams`` and most of
``CameraParams`` take every value from the caller, while ``ImuParams`` (the IMU section of
``NavConfig``) and ``FloorSensorParams`` (the line task's ``sensors`` section) are themselves the
task's sections and keep their defaults. Each field declares what it allows (``checks.py``); a
bad value raises one ``ConfigError`` (a ``ValueError``) naming every refused field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .checks import Checked, checked, count, is_number, limit, non_negative, one_of, positive, real

INTEGRATORS = ("euler", "exact")
SCANS = ("rays", "sectors")


def is_pose(v: object) -> bool:
    """Whether ``v`` is a sensor pose on the robot: three finite numbers ``(x m, y m, yaw rad)``."""
    return isinstance(v, (list, tuple)) and len(v) == 3 and all(is_number(x) for x in v)


@dataclass(frozen=True)
class LidarParams(Checked):
    """A planar lidar mounted on the robot. The ray order (counter-clockwise, ray 0 on the right or,
    for 360 degrees, behind): docs/sim.md, "Frames"; the exact sector scan (``scan="sectors"``) and
    the broad phase (``window``, ``dense_slots``): docs/sim.md, "Lidar". No field has a default: a
    task config declares them (``NavConfig.lidar``, built by ``NavConfig.sim_params()``)."""

    n_rays: int = count(1)  # number of raw rays
    fov: float = checked(lambda v: is_number(v) and 0.0 < v <= 2 * math.pi + 1e-9, "a number of radians in (0, 2*pi]")  # field of view, rad
    min_range: float = non_negative()  # m; closer returns read min_range
    max_range: float = positive()  # m; misses read max_range
    offset: tuple[float, float, float] = checked(is_pose, "(x m, y m, yaw rad)")  # sensor pose in the robot frame: x m, y m, yaw rad
    noise_std: float = non_negative()  # m, std of additive Gaussian range noise (needs a generator)
    scan: str = one_of(*SCANS)  # "rays": one reading per ray; "sectors": exact nearest distance per wedge
    window: int = count(0)  # broad phase: each obstacle is tested on the 2 * window + 1 rays nearest its direction
    dense_slots: int = count(1)  # broad phase: per kind, up to this many wide obstacles are tested on every ray

    def checks(self) -> list[tuple[bool, str]]:
        return [(self.min_range < self.max_range, f"max_range={self.max_range!r} must be greater than min_range={self.min_range!r}")]

    @property
    def full_circle(self) -> bool:
        return self.fov >= 2 * math.pi - 1e-9

    def sector_bearing(self, k: float) -> float:
        """The exact sector scan's layout: the bearing (rad, sensor frame) ``k`` sector widths past the
        first sector's edge; sector ``k`` spans ``[sector_bearing(k), sector_bearing(k + 1)]``."""
        first = -math.pi if self.full_circle else -self.fov / 2
        return first + k * (self.fov / self.n_rays)

    def angles(self) -> list[float]:
        """Ray angles (rad) in the sensor frame, in ray order."""
        n = self.n_rays
        if self.full_circle:
            return [-math.pi + i * 2 * math.pi / n for i in range(n)]
        if n == 1:
            return [0.0]
        return [-self.fov / 2 + i * self.fov / (n - 1) for i in range(n)]


@dataclass(frozen=True)
class ImuParams(Checked):
    """A planar IMU (``imu.py``): body-frame acceleration ``[a_x, a_y]`` and yaw rate.

    Noise and bias walks are drawn from the step's generator; ``rate`` in Hz makes
    the reading sample-and-hold (``inf``: a new reading every step). The defaults are
    ``NavConfig.imu``'s (``ImuConfig`` adds ``enabled``): a noise-free IMU read every step.
    """

    accel_noise: float = non_negative(0.0)  # m/s^2, std of white noise on each acceleration reading
    gyro_noise: float = non_negative(0.0)  # rad/s, std of white noise on each yaw-rate reading
    accel_bias_walk: float = non_negative(0.0)  # m/s^2 per sqrt(s), random walk of the acceleration bias
    gyro_bias_walk: float = non_negative(0.0)  # rad/s per sqrt(s), random walk of the gyro bias
    rate: float = limit(math.inf)  # Hz; readings update only when a sample tick falls in the step (inf: every step)


RGB = tuple[int, int, int]


def is_rgb(c: object) -> bool:
    """Whether ``c`` is three integers (not bools) in [0, 255], a colour of the camera and of maps."""
    return isinstance(c, (list, tuple)) and len(c) == 3 and all(isinstance(x, int) and not isinstance(x, bool) and 0 <= x <= 255 for x in c)


def _colour(default: RGB) -> RGB:
    return checked(is_rgb, "3 integers in [0, 255]", default)


@dataclass(frozen=True)
class CameraParams(Checked):
    """A forward pinhole camera rendered by ray casting the 2D world (``camera.py``); its column
    angles, square pixels and obstacle prisms: docs/sim.md, "Camera". The image and mount have no
    defaults (``NavConfig.camera`` declares them); the world's heights and colours, which no task
    config sets, have theirs here."""

    n_cols: int = count(1)  # image width, pixels (= depth readings)
    n_rows: int = count(1)  # image height, pixels (RGB only)
    fov: float = checked(lambda v: is_number(v) and 0.0 < v < math.pi, "a number of radians in (0, pi)")  # horizontal field of view, rad
    max_range: float = positive()  # m; misses and farther hits read max_range in the depth row
    offset: tuple[float, float, float] = checked(is_pose, "(x m, y m, yaw rad)")  # sensor pose in the robot frame: x m, y m, yaw rad
    height: float = non_negative()  # m, the camera's height above the floor
    wall_height: float = positive(1.0)  # m
    circle_height: float = positive(0.8)  # m
    box_height: float = positive(0.5)  # m
    mover_height: float = positive(1.7)  # m, moving obstacles (pedestrian-sized)
    wall_color: RGB = _colour((170, 170, 170))
    circle_color: RGB = _colour((60, 150, 80))
    box_color: RGB = _colour((200, 120, 60))
    mover_color: RGB = _colour((210, 60, 60))
    floor_color: RGB = _colour((90, 85, 80))
    sky_color: RGB = _colour((150, 190, 235))

    @property
    def focal(self) -> float:
        """Focal length in pixels."""
        return 0.5 * self.n_cols / math.tan(0.5 * self.fov)

    def angles(self) -> list[float]:
        """Column angles (rad) in the sensor frame, left column first (CCW positive)."""
        f = self.focal
        return [math.atan((0.5 * self.n_cols - j - 0.5) / f) for j in range(self.n_cols)]


@dataclass(frozen=True)
class SimParams(Checked):
    """Differential-drive robot and world-step parameters. No robot field has a default: the task
    configs declare them (``NavConfig().sim_params()`` is the navigation task's robot)."""

    dt: float = positive()  # s per step
    robot_radius: float = positive()  # m, the robot is a disc
    track_width: float = positive()  # m, distance between the wheels
    v_min: float = real()  # m/s, slowest (most negative) forward speed
    v_max: float = real()  # m/s
    omega_max: float = non_negative()  # rad/s, symmetric limit
    lin_acc_max: float = limit()  # m/s^2, inf disables the limit
    ang_acc_max: float = limit()  # rad/s^2, inf disables the limit
    integrator: str = one_of(*INTEGRATORS)  # "exact" (constant-twist arc) or "euler"
    odom_v_noise: float = non_negative()  # m/s, std of per-step noise on the odometry's speed
    odom_omega_noise: float = non_negative()  # rad/s, std of per-step noise on the odometry's turn rate
    lidar: LidarParams  # the lidar (a task without one uses a single ray; see LineConfig.sim_params)
    imu: ImuParams | None = None  # None: no IMU (state.imu is (B, 0))
    camera: CameraParams | None = None  # None: no camera (state.cam_depth is (B, 0))

    def checks(self) -> list[tuple[bool, str]]:
        return [
            (self.v_min <= self.v_max, f"v_min={self.v_min!r} must be at most v_max={self.v_max!r}"),
            (isinstance(self.lidar, LidarParams), f"lidar must be a LidarParams, got {type(self.lidar).__name__}"),
            (self.imu is None or isinstance(self.imu, ImuParams), f"imu must be an ImuParams or None, got {type(self.imu).__name__}"),
            (self.camera is None or isinstance(self.camera, CameraParams), f"camera must be a CameraParams or None, got {type(self.camera).__name__}"),
        ]
