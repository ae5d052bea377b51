"""Navigation task configuration: frozen dataclasses, every field a YAML key.

Units are in the field comments. ``NavConfig.from_dict`` rejects unknown keys
and wrong types with an error naming the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

from ..config import ConfigError, TaskConfig, fields_as
from ..sim import RANDOMIZED, CameraParams, ImuParams, LidarParams, SimParams
from ..sim.randomize import check_ranges

DEFAULT_MAP = "arena"  # NavConfig.map's default; with worlds.families the map must stay at it (it is not used)

CURRICULUM_MODES = ("growth", "success", "off")
ACTION_MODES = ("continuous", "discrete")


@dataclass(frozen=True)
class RobotConfig:
    dt: float = 0.1  # s per step
    radius: float = 0.2  # m, robot disc
    track_width: float = 0.3  # m, wheel separation
    v_max: float = 1.0  # m/s
    omega_max: float = 1.0  # rad/s
    lin_acc_max: float = math.inf  # m/s^2 (inf: no limit)
    ang_acc_max: float = math.inf  # rad/s^2 (inf: no limit)
    integrator: str = "exact"  # "exact" | "euler"
    odom_v_noise: float = 0.0  # m/s, per-step std of the odometry's speed error
    odom_omega_noise: float = 0.0  # rad/s, per-step std of the odometry's turn-rate error


@dataclass(frozen=True)
class LidarConfig:
    n_rays: int = 20  # raw rays; 180 reproduces the classic 1-degree scan
    fov_deg: float = 180.0  # degrees
    min_range: float = 0.0  # m
    max_range: float = 10.0  # m (the classic 10 m cap)
    n_sectors: int = 20  # observation bins (min over consecutive rays); must divide n_rays
    noise_std: float = 0.0  # m, Gaussian range noise
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor pose on the robot: m, m, rad
    scan: str = "rays"  # "rays", or "sectors": n_rays exact wedges (nearest obstacle point in each)
    window: int = 2  # broad phase for many obstacles: rays tested each side of an obstacle's direction
    dense_slots: int = 64  # broad phase: obstacles per kind tested on every ray (see docs/sim.md)


@dataclass(frozen=True)
class ImuConfig:
    """The robot's IMU (docs/sim.md#imu): body-frame acceleration and yaw rate."""

    enabled: bool = False  # simulate the IMU (state.imu); needed by observation.imu
    accel_noise: float = 0.0  # m/s^2, white-noise std per reading
    gyro_noise: float = 0.0  # rad/s, white-noise std per reading
    accel_bias_walk: float = 0.0  # m/s^2 per sqrt(s), bias random walk
    gyro_bias_walk: float = 0.0  # rad/s per sqrt(s), bias random walk
    rate: float = math.inf  # Hz, sample-and-hold rate (inf: every step)


@dataclass(frozen=True)
class CameraConfig:
    """A forward ray-cast camera (docs/sim.md#camera): a depth row in the step, RGB on demand."""

    enabled: bool = False  # compute the depth row every step (state.cam_depth); needed by observation.camera
    n_cols: int = 64  # image width in pixels = depth readings
    n_rows: int = 48  # image height in pixels (RGB only)
    fov_deg: float = 90.0  # horizontal field of view, degrees (0, 180)
    max_range: float = 10.0  # m, depth of misses and the depth row's cap
    height: float = 0.3  # m above the floor
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor pose on the robot: m, m, rad


Range = tuple[float, float] | None


@dataclass(frozen=True)
class RandomizeConfig:
    """Domain randomisation (docs/tasks.md#randomize): each key a ``[min, max]`` range drawn
    uniformly per env at every reset, or null for the fixed value of ``robot``/``lidar``."""

    v_max: Range = None  # m/s, speed limit (the reverse limit scales with it)
    omega_max: Range = None  # rad/s, turn-rate limit
    lin_acc_max: Range = None  # m/s^2, linear acceleration limit
    ang_acc_max: Range = None  # rad/s^2, angular acceleration limit
    delay: Range = None  # steps (whole numbers), actuator delay
    wheel_noise: Range = None  # m/s, std of Gaussian noise on each wheel's speed
    range_noise: Range = None  # m, std of the lidar's Gaussian range noise
    dropout: Range = None  # probability that a lidar ray reads max_range
    angle_offset: Range = None  # rad, lidar yaw misalignment
    max_range: Range = None  # m, lidar range (at most lidar.max_range)
    robot_radius: Range = None  # m, robot disc for collision

    def ranges(self) -> dict[str, tuple[float, float]]:
        """The randomised parameters and their ranges."""
        return {k: v for k, v in ((f, getattr(self, f)) for f in RANDOMIZED) if v is not None}


@dataclass(frozen=True)
class CurriculumConfig:
    """The bootstrapped goal radius: goals at a distance in [min_radius, radius] from the start."""

    mode: str = "growth"  # "growth" per placement, "success"-gated, or "off" (radius = max_radius)
    min_radius: float = 0.5  # m, lower bound of the goal distance
    init_radius: float = 1.0  # m, radius at the start of training
    max_radius: float = 15.0  # m, cap (15 m covers the whole 10 x 10 arena)
    growth: float = 0.004  # m added per goal placement (mode "growth"; the classic value)
    success_threshold: float = 0.8  # mode "success": grow when the success-rate average exceeds this
    success_step: float = 0.25  # m added per finished episode batch while above the threshold
    success_smoothing: float = 0.01  # weight of each finished episode in the success-rate average


PROGRESS_DISTANCES = ("euclidean", "geodesic")


@dataclass(frozen=True)
class RewardConfig:
    preset: str = "classic"  # "classic" | "progress" | "shaped"; see docs/tasks.md
    weights: dict[str, float] = field(default_factory=dict)  # per-term weight overrides
    proximity_distance: float = 1.0  # m, obstacles nearer than this are penalised
    spin_threshold: float = 0.5  # rad/s, turn rates above this are penalised ("progress")
    progress_distance: str = "euclidean"  # "euclidean" | "geodesic" (shortest safe path; needs worlds.families): what `progress` rewards the decrease of
    geodesic_margin: float = 0.0  # m, geodesic paths keep this much more than the robot's radius from obstacles


@dataclass(frozen=True)
class ObservationConfig:
    normalize: bool = True  # scale lidar and distances by max_range, angles by pi, speeds by limits
    history: int = 1  # stack the last k observations
    goal_from_odom: bool = False  # goal vector from the drifting odometry instead of the true pose
    imu: bool = False  # append the IMU reading [a_x, a_y, yaw rate] (needs imu.enabled)
    camera: bool = False  # append the camera's depth row, n_cols values (needs camera.enabled)
    goal_distance_cap: float | None = None  # m: the goal distance observed is at most this (None: uncapped)
    # Memory of where the robot has been (docs/tasks.md#visit-memory): every `visit_spacing` m driven
    # (by odometry) the robot drops a breadcrumb; the observation gets, per egocentric sector, how many
    # lie within `visit_radius` (nearer ones weigh more). 0 sectors: off.
    visit_sectors: int = 0
    visit_radius: float = 3.0  # m
    visit_spacing: float = 0.5  # m between breadcrumbs
    visit_memory: int = 64  # breadcrumbs kept; the oldest is overwritten


@dataclass(frozen=True)
class ActionConfig:
    mode: str = "continuous"  # "continuous" in [-1, 1]^2 or "discrete" (one-hot over `discrete_set`)
    forward_only: bool = True  # map a[0] to v in [0, v_max] (else [-v_max, v_max])
    # m or None: a guard caps the forward speed so that the robot's disc stops this far short of every
    # lidar return in its path within the step (docs/tasks.md#speed-guard); None: off
    stop_clearance: float | None = None
    # (v, omega) as fractions of (v_max, omega_max), for mode "discrete"
    discrete_set: tuple[tuple[float, float], ...] = (
        (1.0, 0.0), (1.0, 0.5), (1.0, -0.5), (0.5, 1.0), (0.5, -1.0), (0.0, 1.0), (0.0, -1.0),
    )


@dataclass(frozen=True)
class ResetConfig:
    start_clearance: float = 0.3  # m, free gap around the robot disc at the start pose
    goal_clearance: float = 0.4  # m, distance of the goal point from any obstacle
    candidates: int = 32  # rejection-sampling candidates per env and object
    pool: int = 0  # 0: sample exactly the envs being reset; N > 0: sample N episodes at a time and hand them out
    reuse: int = 1  # times each pooled episode is handed out (in a fresh order each pass) before the pool is refilled


@dataclass(frozen=True)
class WorldsConfig:
    """Procedural worlds (docs/worlds.md) instead of one map: every episode draws a family,
    a world of that family at the family's difficulty, a start and a reachable goal."""

    families: dict[str, float] = field(default_factory=dict)  # family -> weight ("rooms", ..., "map:arena"); empty: `map`
    difficulty: float = 0.5  # in [0, 1]: the fixed difficulty, or the starting one with `curriculum`
    curriculum: bool = False  # success-gated difficulty, one level per family
    success_threshold: float = 0.8  # raise a family's difficulty when its success average exceeds this
    difficulty_step: float = 0.05  # added per finished episode batch while above the threshold
    success_smoothing: float = 0.02  # weight of each finished episode in its family's success average
    max_difficulty: float = 1.0  # cap of the curriculum
    anywhere_goals: float = 0.0  # fraction of episodes whose goal is anywhere reachable (>= 0.5 m), not in the difficulty's band
    below_level: float = 0.0  # fraction of episodes whose difficulty is drawn uniformly below their family's level, in [0, level)
    # Moving discs placed in every generated world at reset, as a map's `moving_circles` (docs/worlds.md)
    # without `region`: they move inside each world's bounds; with `size_x` and `size_y` instead of
    # `radius`, moving boxes (a map's `moving_boxes`). Empty: none.
    movers: dict[str, Any] = field(default_factory=dict)

    def mover_spec(self):
        """``movers`` validated as a :class:`~torchnav.maps.spec.RandomMovers` (``ConfigError`` naming
        ``worlds.movers.<key>``), or None when empty."""
        if not self.movers:
            return None
        from ..maps.loader import random_movers
        from ..yamlcheck import Ctx

        class KeyCtx(Ctx):  # errors read "worlds.movers.<key>: ...", like the other config errors
            def fail(self, key: str, msg: str) -> Exception:
                return self.error(f"{key}: {msg}")

        if not isinstance(self.movers, Mapping):
            raise ConfigError(f"worlds.movers: expected a mapping like a map's moving_circles, got {self.movers!r}")
        if "region" in self.movers:
            raise ConfigError("worlds.movers.region: not allowed: movers move inside each generated world's bounds")
        return random_movers(KeyCtx("", ConfigError), dict(self.movers), (math.inf, math.inf), "worlds.movers",
                               boxes="size_x" in self.movers or "size_y" in self.movers)


@dataclass(frozen=True)
class NavConfig(TaskConfig):
    map: str = DEFAULT_MAP  # shipped map name or path to a map YAML (unused with worlds.families, which must then leave it at the default)
    max_steps: int = 500  # steps before truncation
    goal_tolerance: float = 0.3  # m, success when the robot centre is this close to the goal
    check_actions: bool = True  # raise on NaN/inf actions (one host sync per step)
    robot: RobotConfig
    lidar: LidarConfig
    imu: ImuConfig
    camera: CameraConfig
    randomize: RandomizeConfig
    curriculum: CurriculumConfig
    reward: RewardConfig
    observation: ObservationConfig
    action: ActionConfig
    reset: ResetConfig
    worlds: WorldsConfig

    def __post_init__(self) -> None:
        c = self.curriculum
        w = self.worlds
        checks = [
            (self.max_steps >= 1, "max_steps must be >= 1"),
            (self.goal_tolerance > 0, "goal_tolerance must be > 0 m"),
            (c.mode in CURRICULUM_MODES, f"curriculum.mode must be one of {CURRICULUM_MODES}, got {c.mode!r}"),
            (0 <= c.min_radius <= c.init_radius <= c.max_radius, "curriculum needs 0 <= min_radius <= init_radius <= max_radius"),
            (c.growth >= 0 and c.success_step >= 0, "curriculum growth and success_step must be >= 0"),
            (0 < c.success_smoothing <= 1, "curriculum.success_smoothing must be in (0, 1]"),
            (self.action.mode in ACTION_MODES, f"action.mode must be one of {ACTION_MODES}, got {self.action.mode!r}"),
            (len(self.action.discrete_set) >= 2, "action.discrete_set needs at least 2 actions"),
            (self.action.stop_clearance is None or (math.isfinite(self.action.stop_clearance) and self.action.stop_clearance >= 0),
             f"action.stop_clearance must be null or a finite number of metres >= 0, got {self.action.stop_clearance}"),
            (self.observation.history >= 1, "observation.history must be >= 1"),
            (self.observation.goal_distance_cap is None or (math.isfinite(self.observation.goal_distance_cap) and self.observation.goal_distance_cap > 0),
             f"observation.goal_distance_cap must be null or a finite number of metres > 0, got {self.observation.goal_distance_cap}"),
            (self.observation.visit_sectors >= 0, f"observation.visit_sectors must be >= 0, got {self.observation.visit_sectors}"),
            (self.observation.visit_radius > 0 and self.observation.visit_spacing > 0 and self.observation.visit_memory >= 1,
             "observation needs visit_radius > 0 m, visit_spacing > 0 m and visit_memory >= 1"),
            (not self.observation.imu or self.imu.enabled, "observation.imu needs imu.enabled: true"),
            (not self.observation.camera or self.camera.enabled, "observation.camera needs camera.enabled: true"),
            (self.reset.candidates >= 1, "reset.candidates must be >= 1"),
            (self.reset.pool >= 0, "reset.pool must be >= 0"),
            (isinstance(self.reset.reuse, int) and self.reset.reuse >= 1, f"reset.reuse must be an int >= 1, got {self.reset.reuse!r}"),
            (self.reset.reuse == 1 or self.reset.pool > 0 or bool(w.families), "reset.reuse > 1 needs a pool: reset.pool > 0 or procedural worlds"),
            (self.reset.start_clearance >= 0 and self.reset.goal_clearance >= 0, "reset clearances must be >= 0 m"),
            (0 <= w.difficulty <= w.max_difficulty <= 1, "worlds needs 0 <= difficulty <= max_difficulty <= 1"),
            (0 < w.success_threshold < 1 and w.difficulty_step >= 0, "worlds needs 0 < success_threshold < 1 and difficulty_step >= 0"),
            (0 < w.success_smoothing <= 1, "worlds.success_smoothing must be in (0, 1]"),
            (0 <= w.anywhere_goals <= 1, f"worlds.anywhere_goals must be in [0, 1], got {w.anywhere_goals}"),
            (0 <= w.below_level <= 1, f"worlds.below_level must be in [0, 1], got {w.below_level}"),
            (self.reward.progress_distance in PROGRESS_DISTANCES,
             f"reward.progress_distance must be one of {', '.join(PROGRESS_DISTANCES)}, got {self.reward.progress_distance!r}"),
            (self.reward.geodesic_margin >= 0, f"reward.geodesic_margin must be >= 0 m, got {self.reward.geodesic_margin}"),
            (self.reward.progress_distance != "geodesic" or bool(w.families),
             "reward.progress_distance: geodesic needs worlds.families (the distances come from each generated world's wavefront)"),
            (all(v >= 0 for v in w.families.values()) and (not w.families or sum(w.families.values()) > 0),
             f"worlds.families weights must be >= 0 with a positive sum, got {w.families}"),
            (not w.families or self.map == DEFAULT_MAP,
             f"map: {self.map!r} is not used when worlds.families is set (procedural worlds bring their own); mix it in as "
             f"the family \"map:{self.map}\", or clear worlds.families to train on the map"),
        ]
        self.require(checks)
        for name in w.families:
            _check_family(name)
        if w.mover_spec() is not None and not w.families:
            raise ConfigError("worlds.movers needs worlds.families (a map declares its movers as moving_circles)")
        params = self.sim_params()  # validates robot and lidar fields
        try:
            check_ranges(self.randomize.ranges(), params)
        except ValueError as e:
            raise ConfigError(str(e)) from None

    def sim_params(self) -> SimParams:
        r, ca = self.robot, self.camera
        try:
            return fields_as(
                SimParams, r, robot_radius=r.radius, v_min=0.0 if self.action.forward_only else -r.v_max,
                lidar=fields_as(LidarParams, self.lidar, fov=math.radians(self.lidar.fov_deg)),
                imu=fields_as(ImuParams, self.imu) if self.imu.enabled else None,
                camera=fields_as(CameraParams, ca, fov=math.radians(ca.fov_deg)) if ca.enabled else None,
            )
        except ValueError as e:
            raise ConfigError(f"robot/lidar: {e}") from e


def _check_family(name: str) -> None:
    from ..maps import MapError, available_maps, load_map
    from ..worlds import FAMILIES, MAP_PREFIX

    if name.startswith(MAP_PREFIX):
        try:
            load_map(name[len(MAP_PREFIX):])
        except MapError as e:
            raise ConfigError(f"worlds.families: {name!r}: {e}") from None
    elif name not in FAMILIES:
        raise ConfigError(f"worlds.families: unknown family {name!r}; known: {', '.join(FAMILIES)}, or {MAP_PREFIX}<map> with a map of {available_maps()}")
