"""Simulator parameters: frozen dataclasses, SI units, validated on construction."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

INTEGRATORS = ("euler", "exact")
SCANS = ("rays", "sectors")


def _require(cond: bool, msg: str) -> None:
    if not cond:
        raise ValueError(msg)


@dataclass(frozen=True)
class LidarParams:
    """A planar lidar mounted on the robot. The ray order (counter-clockwise, ray 0 on the right or,
    for 360 degrees, behind): docs/sim.md, "Frames"; the exact sector scan (``scan="sectors"``) and
    the broad phase (``window``, ``dense_slots``): docs/sim.md, "Lidar"."""

    n_rays: int = 20  # number of raw rays
    fov: float = math.pi  # field of view, rad (0, 2*pi]
    min_range: float = 0.0  # m; closer returns read min_range
    max_range: float = 10.0  # m; misses read max_range
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor pose in the robot frame: x m, y m, yaw rad
    n_sectors: int | None = None  # if set, ``sectorize`` bins the rays into this many sectors by their minimum
    noise_std: float = 0.0  # m, std of additive Gaussian range noise (needs a generator)
    scan: str = "rays"  # "rays": one reading per ray; "sectors": exact nearest distance per wedge
    window: int = 2  # broad phase: each obstacle is tested on the 2 * window + 1 rays nearest its direction
    dense_slots: int = 64  # broad phase: per kind, up to this many wide obstacles are tested on every ray

    def __post_init__(self) -> None:
        _require(isinstance(self.n_rays, int) and self.n_rays >= 1, f"lidar.n_rays must be a positive int, got {self.n_rays!r}")
        _require(0.0 < self.fov <= 2 * math.pi + 1e-9, f"lidar.fov must be in (0, 2*pi] rad, got {self.fov!r}")
        _require(0.0 <= self.min_range < self.max_range, f"lidar needs 0 <= min_range < max_range, got {self.min_range!r}, {self.max_range!r}")
        _require(len(self.offset) == 3, f"lidar.offset must be (x, y, yaw), got {self.offset!r}")
        _require(self.noise_std >= 0.0, f"lidar.noise_std must be >= 0, got {self.noise_std!r}")
        _require(self.scan in SCANS, f"lidar.scan must be one of {SCANS}, got {self.scan!r}")
        _require(isinstance(self.window, int) and self.window >= 0, f"lidar.window must be an int >= 0, got {self.window!r}")
        _require(isinstance(self.dense_slots, int) and self.dense_slots >= 1, f"lidar.dense_slots must be an int >= 1, got {self.dense_slots!r}")
        if self.n_sectors is not None:
            _require(
                isinstance(self.n_sectors, int) and self.n_sectors >= 1 and self.n_rays % self.n_sectors == 0,
                f"lidar.n_sectors must divide n_rays={self.n_rays}, got {self.n_sectors!r}",
            )

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
class ImuParams:
    """A planar IMU (``imu.py``): body-frame acceleration ``[a_x, a_y]`` and yaw rate.

    Noise and bias walks are drawn from the step's generator; ``rate`` in Hz makes
    the reading sample-and-hold (``inf``: a new reading every step).
    """

    accel_noise: float = 0.0  # m/s^2, std of white noise on each acceleration reading
    gyro_noise: float = 0.0  # rad/s, std of white noise on each yaw-rate reading
    accel_bias_walk: float = 0.0  # m/s^2 per sqrt(s), random walk of the acceleration bias
    gyro_bias_walk: float = 0.0  # rad/s per sqrt(s), random walk of the gyro bias
    rate: float = math.inf  # Hz; readings update only when a sample tick falls in the step

    def __post_init__(self) -> None:
        for name in ("accel_noise", "gyro_noise", "accel_bias_walk", "gyro_bias_walk"):
            v = getattr(self, name)
            _require(math.isfinite(v) and v >= 0.0, f"imu.{name} must be a finite number >= 0, got {v!r}")
        _require(self.rate > 0, f"imu.rate must be > 0 Hz (inf: every step), got {self.rate!r}")


RGB = tuple[int, int, int]


def is_rgb(c: object) -> bool:
    """Whether ``c`` is three integers (not bools) in [0, 255], a colour of the camera and of maps."""
    return isinstance(c, (list, tuple)) and len(c) == 3 and all(isinstance(x, int) and not isinstance(x, bool) and 0 <= x <= 255 for x in c)


@dataclass(frozen=True)
class CameraParams:
    """A forward pinhole camera rendered by ray casting the 2D world (``camera.py``); its column
    angles, square pixels and obstacle prisms: docs/sim.md, "Camera"."""

    n_cols: int = 64  # image width, pixels (= depth readings)
    n_rows: int = 48  # image height, pixels (RGB only)
    fov: float = math.pi / 2  # horizontal field of view, rad (0, pi)
    max_range: float = 10.0  # m; misses and farther hits read max_range in the depth row
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor pose in the robot frame: x m, y m, yaw rad
    height: float = 0.3  # m, the camera's height above the floor
    wall_height: float = 1.0  # m
    circle_height: float = 0.8  # m
    box_height: float = 0.5  # m
    mover_height: float = 1.7  # m, moving obstacles (pedestrian-sized)
    wall_color: RGB = (170, 170, 170)
    circle_color: RGB = (60, 150, 80)
    box_color: RGB = (200, 120, 60)
    mover_color: RGB = (210, 60, 60)
    floor_color: RGB = (90, 85, 80)
    sky_color: RGB = (150, 190, 235)

    def __post_init__(self) -> None:
        _require(isinstance(self.n_cols, int) and self.n_cols >= 1, f"camera.n_cols must be a positive int, got {self.n_cols!r}")
        _require(isinstance(self.n_rows, int) and self.n_rows >= 1, f"camera.n_rows must be a positive int, got {self.n_rows!r}")
        _require(0.0 < self.fov < math.pi, f"camera.fov must be in (0, pi) rad, got {self.fov!r}")
        _require(0.0 < self.max_range < math.inf, f"camera.max_range must be a finite number > 0 m, got {self.max_range!r}")
        _require(len(self.offset) == 3, f"camera.offset must be (x, y, yaw), got {self.offset!r}")
        _require(self.height >= 0.0, f"camera.height must be >= 0 m, got {self.height!r}")
        for name in ("wall_height", "circle_height", "box_height", "mover_height"):
            _require(getattr(self, name) > 0.0, f"camera.{name} must be > 0 m, got {getattr(self, name)!r}")
        for name in ("wall_color", "circle_color", "box_color", "mover_color", "floor_color", "sky_color"):
            c = getattr(self, name)
            _require(is_rgb(c), f"camera.{name} must be 3 ints in [0, 255], got {c!r}")

    @property
    def focal(self) -> float:
        """Focal length in pixels."""
        return 0.5 * self.n_cols / math.tan(0.5 * self.fov)

    def angles(self) -> list[float]:
        """Column angles (rad) in the sensor frame, left column first (CCW positive)."""
        f = self.focal
        return [math.atan((0.5 * self.n_cols - j - 0.5) / f) for j in range(self.n_cols)]


@dataclass(frozen=True)
class SimParams:
    """Differential-drive robot and world-step parameters."""

    dt: float = 0.1  # s per step
    robot_radius: float = 0.2  # m, the robot is a disc
    track_width: float = 0.3  # m, distance between the wheels
    v_min: float = -0.5  # m/s
    v_max: float = 0.5  # m/s
    omega_max: float = 1.0  # rad/s, symmetric limit
    lin_acc_max: float = math.inf  # m/s^2, inf disables the limit
    ang_acc_max: float = math.inf  # rad/s^2, inf disables the limit
    integrator: str = "exact"  # "exact" (constant-twist arc) or "euler"
    odom_v_noise: float = 0.0  # m/s, std of per-step noise on the odometry's speed
    odom_omega_noise: float = 0.0  # rad/s, std of per-step noise on the odometry's turn rate
    lidar: LidarParams = field(default_factory=LidarParams)
    imu: ImuParams | None = None  # None: no IMU (state.imu is (B, 0))
    camera: CameraParams | None = None  # None: no camera (state.cam_depth is (B, 0))

    def __post_init__(self) -> None:
        _require(self.dt > 0, f"dt must be > 0 s, got {self.dt!r}")
        _require(self.robot_radius > 0, f"robot_radius must be > 0 m, got {self.robot_radius!r}")
        _require(self.track_width > 0, f"track_width must be > 0 m, got {self.track_width!r}")
        _require(self.v_min <= self.v_max, f"need v_min <= v_max, got {self.v_min!r}, {self.v_max!r}")
        _require(self.omega_max >= 0, f"omega_max must be >= 0 rad/s, got {self.omega_max!r}")
        _require(self.lin_acc_max > 0 and self.ang_acc_max > 0, "acceleration limits must be > 0 (use inf to disable)")
        _require(self.integrator in INTEGRATORS, f"integrator must be one of {INTEGRATORS}, got {self.integrator!r}")
        _require(self.odom_v_noise >= 0 and self.odom_omega_noise >= 0, "odometry noise std must be >= 0")
        _require(isinstance(self.lidar, LidarParams), f"lidar must be a LidarParams, got {type(self.lidar).__name__}")
        _require(self.imu is None or isinstance(self.imu, ImuParams), f"imu must be an ImuParams or None, got {type(self.imu).__name__}")
        _require(self.camera is None or isinstance(self.camera, CameraParams), f"camera must be a CameraParams or None, got {type(self.camera).__name__}")
