"""Line-following task configuration: frozen dataclasses, every field a YAML key.

The one place of the line task's defaults, the simulator's included (:meth:`LineConfig.sim_params`
builds ``torchnav.sim``'s parameters from it; the ``sensors`` section is the simulator's
``FloorSensorParams``). Units are in the field comments; each field declares what it allows, and
``LineConfig.from_dict`` reports every unknown key, wrong type and refused value at once. The
defaults model a small two-wheeled teaching robot (12 cm wheel base, 0.5 m/s wheels, a 20 Hz
control loop) with five photodiodes 15 mm apart, 8 cm ahead of the axle, over 25 mm tape.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..config import Config, count, is_number, limit, non_negative, one_of, optional, positive, real
from ..sim import LidarParams, SimParams
from ..sim.floor import FloorSensorParams
from ..sim.params import INTEGRATORS

LINE_ACTION_MODES = ("continuous", "discrete")
LINE_TERMS = ("progress", "off_line", "failure", "lap", "turning", "step")
DEFAULT_LINE_WEIGHTS: dict[str, float] = {"progress": 20.0, "off_line": -0.2, "failure": -5.0}
# (left, right) wheel commands as fractions of wheel_speed_max, for mode "discrete"
DEFAULT_DISCRETE_WHEELS: tuple[tuple[float, float], ...] = (
    (1.0, 1.0), (1.0, 0.5), (0.5, 1.0), (1.0, 0.0), (0.0, 1.0), (0.5, -0.5), (-0.5, 0.5),
)


@dataclass(frozen=True)
class LineRobotConfig(Config):
    dt: float = positive(0.05)  # s per step (control period)
    radius: float = positive(0.07)  # m, robot disc (drawing and walls)
    track_width: float = positive(0.12)  # m, distance between the wheels
    wheel_speed_max: float = positive(0.5)  # m/s, wheel rim speed at motor command +-1
    lin_acc_max: float = limit(math.inf)  # m/s^2 on the forward speed (inf: no limit)
    ang_acc_max: float = limit(math.inf)  # rad/s^2 on the turn rate (inf: no limit)
    integrator: str = one_of(*INTEGRATORS, default="exact")  # "exact" (constant-twist arc) | "euler"


@dataclass(frozen=True)
class DistanceSensorConfig(Config):
    enabled: bool = False  # a forward 1-ray lidar; its reading is appended to the observation
    max_range: float = positive(1.0)  # m; misses read max_range
    forward: float = real(0.07)  # m, mounting point ahead of the axle
    noise_std: float = non_negative(0.0)  # m, Gaussian range noise


@dataclass(frozen=True)
class LineRewardConfig(Config):
    # per-term weights, merged over DEFAULT_LINE_WEIGHTS (terms: progress, off_line, failure, lap, turning, step)
    weights: dict[str, float] = field(default_factory=dict)

    def checks(self) -> list[tuple[bool, str]]:
        return [(k in LINE_TERMS, f"weights: unknown term {k!r}; terms: {', '.join(LINE_TERMS)}") for k in self.weights]


@dataclass(frozen=True)
class LineObservationConfig(Config):
    history: int = count(1, 6, hi=64)  # sensor frames in the observation: current + (history - 1) previous


@dataclass(frozen=True)
class LineActionConfig(Config):
    mode: str = one_of(*LINE_ACTION_MODES, default="continuous")  # "continuous" [left, right] in [-1, 1]^2 | "discrete" (one-hot over discrete_set)
    forward_only: bool = False  # continuous: map [-1, 1] to [0, wheel_speed_max] instead of [-max, max]
    discrete_set: tuple[tuple[float, float], ...] = DEFAULT_DISCRETE_WHEELS  # (left, right) fractions

    def checks(self) -> list[tuple[bool, str]]:
        return [(len(self.discrete_set) >= 2, f"discrete_set needs at least 2 actions, got {len(self.discrete_set)}"),
                (all(abs(x) <= 1 for pair in self.discrete_set for x in pair), "discrete_set entries must be in [-1, 1]")]


@dataclass(frozen=True)
class LineTerminationConfig(Config):
    off_line_time: float = non_negative(0.5)  # s with no sensor over the line before the episode ends (rounded to steps, >= 1 step)
    stop_speed: float = non_negative(0.02)  # m/s; |forward speed| below this counts as stopped
    stop_time: float = non_negative(1.0)  # s stopped before the episode ends (rounded to steps, >= 1 step)
    max_path_distance: float = positive(0.15)  # m; robot centre farther than this from the lap path ends the episode


@dataclass(frozen=True)
class LineResetConfig(Config):
    start: float | None = optional(is_number, "a finite number of metres")  # m of arc length for every start; None: uniform over the lap
    lateral_noise: float = non_negative(0.005)  # m, start offset across the line, uniform in +-lateral_noise
    heading_noise: float = non_negative(0.15)  # rad, start heading error, uniform in +-heading_noise


@dataclass(frozen=True)
class LineConfig(Config):
    track: str = "course"  # shipped track (course, loop, oval) or path to a track YAML
    max_steps: int = count(1, 1000)  # steps before truncation (50 s at dt = 0.05)
    check_actions: bool = True  # raise on NaN/inf actions (one host sync per step)
    robot: LineRobotConfig
    sensors: FloorSensorParams  # the downward reflectance array (torchnav.sim.floor)
    distance_sensor: DistanceSensorConfig
    reward: LineRewardConfig
    observation: LineObservationConfig
    action: LineActionConfig
    termination: LineTerminationConfig
    reset: LineResetConfig

    def weights(self) -> dict[str, float]:
        """Reward weights: the defaults with ``reward.weights`` applied (zero weights dropped)."""
        w = {**DEFAULT_LINE_WEIGHTS, **self.reward.weights}
        return {k: float(w[k]) for k in LINE_TERMS if w.get(k, 0.0) != 0.0}

    def sim_params(self) -> SimParams:
        """The simulator's parameters: the robot (its turn-rate limit from the wheels) and the distance
        sensor as a single forward lidar ray (read only with ``distance_sensor.enabled``)."""
        r, ds = self.robot, self.distance_sensor
        vmax = r.wheel_speed_max
        return SimParams(
            dt=r.dt, robot_radius=r.radius, track_width=r.track_width,
            v_min=0.0 if self.action.forward_only else -vmax, v_max=vmax, omega_max=2 * vmax / r.track_width,
            lin_acc_max=r.lin_acc_max, ang_acc_max=r.ang_acc_max, integrator=r.integrator,
            odom_v_noise=0.0, odom_omega_noise=0.0,  # no odometry noise: nothing in the line task reads the odometry
            # One ray straight ahead: the field of view, scan mode and broad phase of a one-ray lidar do not change its reading.
            lidar=LidarParams(n_rays=1, fov=math.pi, min_range=0.0, max_range=ds.max_range, offset=(ds.forward, 0.0, 0.0),
                              noise_std=ds.noise_std, scan="rays", window=2, dense_slots=64),
        )

    def sensor_params(self) -> FloorSensorParams:
        """The reflectance array's parameters (the ``sensors`` section itself)."""
        return self.sensors
