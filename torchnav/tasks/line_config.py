"""Line-following task configuration: frozen dataclasses, every field a YAML key.

Units are in the field comments. ``LineConfig.from_dict`` rejects unknown keys and
wrong types with an error naming the key. The defaults model a small two-wheeled
teaching robot (12 cm wheel base, 0.5 m/s wheels, a 20 Hz control loop) with five
photodiodes 15 mm apart, 8 cm ahead of the axle, over 25 mm tape.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..config import ConfigError, TaskConfig, fields_as
from ..sim import LidarParams, SimParams
from ..sim.floor import FloorSensorParams

LINE_ACTION_MODES = ("continuous", "discrete")
LINE_TERMS = ("progress", "off_line", "failure", "lap", "turning", "step")
DEFAULT_LINE_WEIGHTS: dict[str, float] = {"progress": 20.0, "off_line": -0.2, "failure": -5.0}
# (left, right) wheel commands as fractions of wheel_speed_max, for mode "discrete"
DEFAULT_DISCRETE_WHEELS: tuple[tuple[float, float], ...] = (
    (1.0, 1.0), (1.0, 0.5), (0.5, 1.0), (1.0, 0.0), (0.0, 1.0), (0.5, -0.5), (-0.5, 0.5),
)


@dataclass(frozen=True)
class LineRobotConfig:
    dt: float = 0.05  # s per step (control period)
    radius: float = 0.07  # m, robot disc (drawing and walls)
    track_width: float = 0.12  # m, distance between the wheels
    wheel_speed_max: float = 0.5  # m/s, wheel rim speed at motor command +-1
    lin_acc_max: float = math.inf  # m/s^2 on the forward speed (inf: no limit)
    ang_acc_max: float = math.inf  # rad/s^2 on the turn rate (inf: no limit)
    integrator: str = "exact"  # "exact" (constant-twist arc) | "euler"


@dataclass(frozen=True)
class LineSensorConfig:
    """The downward reflectance array; see ``torchnav.sim.floor.FloorSensorParams``."""

    count: int = 5  # sensors, evenly spaced across the front, rightmost first
    spacing: float = 0.015  # m between neighbouring sensors
    forward: float = 0.08  # m ahead of the wheel axle
    radius: float = 0.005  # m, radius of each sensor's footprint on the floor
    mode: str = "analog"  # "analog" (coverage fraction) | "binary" | "smooth" (differentiable sigmoid)
    threshold: float = 0.5  # coverage fraction that counts as "on the line" (binary mode, off-line test)
    noise_std: float = 0.0  # std of Gaussian noise on each reading (analog, binary)
    softness: float = 0.004  # m, sigmoid scale of the smooth mode


@dataclass(frozen=True)
class DistanceSensorConfig:
    enabled: bool = False  # a forward 1-ray lidar; its reading is appended to the observation
    max_range: float = 1.0  # m; misses read max_range
    forward: float = 0.07  # m, mounting point ahead of the axle
    noise_std: float = 0.0  # m, Gaussian range noise


@dataclass(frozen=True)
class LineRewardConfig:
    # per-term weights, merged over DEFAULT_LINE_WEIGHTS (terms: progress, off_line, failure, lap, turning, step)
    weights: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class LineObservationConfig:
    history: int = 6  # sensor frames in the observation: current + (history - 1) previous


@dataclass(frozen=True)
class LineActionConfig:
    mode: str = "continuous"  # "continuous" [left, right] in [-1, 1]^2 | "discrete" (one-hot over discrete_set)
    forward_only: bool = False  # continuous: map [-1, 1] to [0, wheel_speed_max] instead of [-max, max]
    discrete_set: tuple[tuple[float, float], ...] = DEFAULT_DISCRETE_WHEELS  # (left, right) fractions


@dataclass(frozen=True)
class LineTerminationConfig:
    off_line_time: float = 0.5  # s with no sensor over the line before the episode ends (rounded to steps, >= 1 step)
    stop_speed: float = 0.02  # m/s; |forward speed| below this counts as stopped
    stop_time: float = 1.0  # s stopped before the episode ends (rounded to steps, >= 1 step)
    max_path_distance: float = 0.15  # m; robot centre farther than this from the lap path ends the episode


@dataclass(frozen=True)
class LineResetConfig:
    start: float | None = None  # m of arc length for every start; None: uniform over the lap
    lateral_noise: float = 0.005  # m, start offset across the line, uniform in +-lateral_noise
    heading_noise: float = 0.15  # rad, start heading error, uniform in +-heading_noise


@dataclass(frozen=True)
class LineConfig(TaskConfig):
    track: str = "course"  # shipped track (course, loop, oval) or path to a track YAML
    max_steps: int = 1000  # steps before truncation (50 s at dt = 0.05)
    check_actions: bool = True  # raise on NaN/inf actions (one host sync per step)
    robot: LineRobotConfig
    sensors: LineSensorConfig
    distance_sensor: DistanceSensorConfig
    reward: LineRewardConfig
    observation: LineObservationConfig
    action: LineActionConfig
    termination: LineTerminationConfig
    reset: LineResetConfig

    def __post_init__(self) -> None:
        t, a = self.termination, self.action
        checks = [
            (self.max_steps >= 1, "max_steps must be >= 1"),
            (self.robot.wheel_speed_max > 0, "robot.wheel_speed_max must be > 0 m/s"),
            (a.mode in LINE_ACTION_MODES, f"action.mode must be one of {LINE_ACTION_MODES}, got {a.mode!r}"),
            (len(a.discrete_set) >= 2, "action.discrete_set needs at least 2 actions"),
            (all(abs(x) <= 1 for pair in a.discrete_set for x in pair), "action.discrete_set entries must be in [-1, 1]"),
            (self.observation.history >= 1, "observation.history must be >= 1"),
            (t.off_line_time >= 0 and t.stop_time >= 0 and t.stop_speed >= 0, "termination times and stop_speed must be >= 0"),
            (t.max_path_distance > 0, "termination.max_path_distance must be > 0 m"),
            (self.reset.lateral_noise >= 0 and self.reset.heading_noise >= 0, "reset noise must be >= 0"),
            (self.distance_sensor.max_range > 0, "distance_sensor.max_range must be > 0 m"),
        ]
        self.require(checks)
        for k in self.reward.weights:
            if k not in LINE_TERMS:
                raise ConfigError(f"reward.weights: unknown term {k!r}; terms: {', '.join(LINE_TERMS)}")
        self.sim_params()
        self.sensor_params()

    def weights(self) -> dict[str, float]:
        """Reward weights: the defaults with ``reward.weights`` applied (zero weights dropped)."""
        w = {**DEFAULT_LINE_WEIGHTS, **self.reward.weights}
        return {k: float(w[k]) for k in LINE_TERMS if w.get(k, 0.0) != 0.0}

    def sim_params(self) -> SimParams:
        r, ds = self.robot, self.distance_sensor
        vmax = r.wheel_speed_max
        try:
            return SimParams(
                dt=r.dt, robot_radius=r.radius, track_width=r.track_width,
                v_min=0.0 if self.action.forward_only else -vmax, v_max=vmax, omega_max=2 * vmax / r.track_width,
                lin_acc_max=r.lin_acc_max, ang_acc_max=r.ang_acc_max, integrator=r.integrator,
                lidar=LidarParams(n_rays=1, max_range=ds.max_range, offset=(ds.forward, 0.0, 0.0), noise_std=ds.noise_std),
            )
        except ValueError as e:
            raise ConfigError(f"robot/distance_sensor: {e}") from e

    def sensor_params(self) -> FloorSensorParams:
        try:
            return fields_as(FloorSensorParams, self.sensors)
        except ValueError as e:
            raise ConfigError(str(e)) from e
