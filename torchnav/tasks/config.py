"""Navigation task configuration: frozen dataclasses, every field a YAML key.

This is the one place of the navigation task's defaults, the simulator's included: the robot,
lidar and camera sections are built into ``torchnav.sim``'s parameter classes by
:meth:`NavConfig.sim_params` (which declare no defaults of their own), and the IMU section is the
simulator's ``ImuParams`` plus ``enabled``. Units are in the field comments; each field declares
what it allows (``torchnav.config``), and ``NavConfig.from_dict`` reports every unknown key, wrong
type and refused value at once, each under its dotted key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

from ..config import (Config, ConfigError, checked, count, is_number, limit, non_negative, one_of, optional, positive,
                      probability, raises, real, within)
from ..sim import RANDOMIZED, CameraParams, ImuParams, LidarParams, SimParams
from ..sim.params import INTEGRATORS, SCANS, is_pose
from ..sim.randomize import check_ranges
from .robots import ROBOT_PRESETS, with_robot_preset

DEFAULT_MAP = "arena"  # NavConfig.map's default; with worlds.families the map must stay at it (it is not used)

CURRICULUM_MODES = ("growth", "success", "off")
ACTION_MODES = ("continuous", "discrete")


def pose(default: tuple[float, float, float]) -> Any:
    """A sensor pose on the robot, ``(x m, y m, yaw rad)``."""
    return checked(is_pose, "(x m, y m, yaw rad)", default)


# Sizes past which the tensors of a batch would not fit in memory: refused with a named error up front.
MAX_RAYS = 4096  # lidar rays and sectors, camera columns and rows
MAX_RANGE = 10_000.0  # m, a sensor's range (the largest map's side)
MAX_HISTORY = 64  # observation frames stacked

@dataclass(frozen=True)
class RobotConfig(Config):
    preset: str = one_of(*ROBOT_PRESETS, default="default")  # the values this robot started from (torchnav/tasks/robots.py); keys given beside it win
    dt: float = positive(0.1)  # s per step
    radius: float = positive(0.2)  # m, robot disc
    track_width: float = positive(0.3)  # m, wheel separation
    v_max: float = non_negative(1.0)  # m/s
    omega_max: float = non_negative(1.0)  # rad/s
    lin_acc_max: float = limit(math.inf)  # m/s^2 (inf: no limit)
    ang_acc_max: float = limit(math.inf)  # rad/s^2 (inf: no limit)
    integrator: str = one_of(*INTEGRATORS, default="exact")  # "exact" | "euler"
    odom_v_noise: float = non_negative(0.0)  # m/s, per-step std of the odometry's speed error
    odom_omega_noise: float = non_negative(0.0)  # rad/s, per-step std of the odometry's turn-rate error


@dataclass(frozen=True)
class LidarConfig(Config):
    n_rays: int = count(1, 20, hi=MAX_RAYS)  # raw rays; 180 reproduces the classic 1-degree scan
    fov_deg: float = checked(lambda v: is_number(v) and 0 < v <= 360, "a number of degrees in (0, 360]", 180.0)  # degrees
    min_range: float = non_negative(0.0)  # m
    max_range: float = checked(lambda v: is_number(v) and 0 < v <= MAX_RANGE, f"a number of m in (0, {MAX_RANGE:g}]", 10.0)  # m (the classic 10 m cap)
    n_sectors: int = count(1, 20, hi=MAX_RAYS)  # observation bins (min over consecutive rays); must divide n_rays
    noise_std: float = non_negative(0.0)  # m, Gaussian range noise
    offset: tuple[float, float, float] = pose((0.0, 0.0, 0.0))  # sensor pose on the robot: m, m, rad
    scan: str = one_of(*SCANS, default="rays")  # "rays", or "sectors": n_rays exact wedges (nearest obstacle point in each)
    window: int = count(0, 2)  # broad phase for many obstacles: rays tested each side of an obstacle's direction
    dense_slots: int = count(1, 64)  # broad phase: obstacles per kind tested on every ray (see docs/sim.md)

    def checks(self) -> list[tuple[bool, str]]:
        return [
            (self.n_rays % self.n_sectors == 0, f"n_sectors={self.n_sectors} must divide n_rays={self.n_rays}"),
            (self.min_range < self.max_range, f"max_range={self.max_range!r} must be greater than min_range={self.min_range!r}"),
        ]


@dataclass(frozen=True)
class ImuConfig(ImuParams):
    """The robot's IMU (docs/sim.md#imu): body-frame acceleration and yaw rate; the simulator's
    ``ImuParams`` (its noise, bias walks and rate, with their defaults) and whether to simulate it."""

    enabled: bool = False  # simulate the IMU (state.imu); needed by observation.imu


@dataclass(frozen=True)
class CameraConfig(Config):
    """A forward ray-cast camera (docs/sim.md#camera): a depth row in the step, RGB on demand."""

    enabled: bool = False  # compute the depth row every step (state.cam_depth); needed by observation.camera
    n_cols: int = count(1, 64, hi=MAX_RAYS)  # image width in pixels = depth readings
    n_rows: int = count(1, 48, hi=MAX_RAYS)  # image height in pixels (RGB only)
    fov_deg: float = checked(lambda v: is_number(v) and 0 < v < 180, "a number of degrees in (0, 180)", 90.0)  # horizontal field of view, degrees
    max_range: float = checked(lambda v: is_number(v) and 0 < v <= MAX_RANGE, f"a number of m in (0, {MAX_RANGE:g}]", 10.0)  # m, depth of misses and the depth row's cap
    height: float = non_negative(0.3)  # m above the floor
    offset: tuple[float, float, float] = pose((0.0, 0.0, 0.0))  # sensor pose on the robot: m, m, rad


Range = tuple[float, float] | None


@dataclass(frozen=True)
class RandomizeConfig(Config):
    """Domain randomisation (docs/tasks.md#randomize): each key a ``[min, max]`` range drawn
    uniformly per env at every reset, or null for the fixed value of ``robot``/``lidar``; the ranges
    are checked against those values by ``NavConfig``."""

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
class CurriculumConfig(Config):
    """The bootstrapped goal radius: goals at a distance in [min_radius, radius] from the start."""

    mode: str = one_of(*CURRICULUM_MODES, default="growth")  # "growth" per placement, "success"-gated, or "off" (radius = max_radius)
    min_radius: float = non_negative(0.5)  # m, lower bound of the goal distance
    init_radius: float = non_negative(1.0)  # m, radius at the start of training
    max_radius: float = non_negative(15.0)  # m, cap (15 m covers the whole 10 x 10 arena)
    growth: float = non_negative(0.004)  # m added per goal placement (mode "growth"; the classic value)
    success_threshold: float = real(0.8)  # mode "success": grow when the success-rate average exceeds this
    success_step: float = non_negative(0.25)  # m added per finished episode batch while above the threshold
    success_smoothing: float = within(0.0, 1.0, 0.01, closed="(]")  # weight of each finished episode in the success-rate average

    def checks(self) -> list[tuple[bool, str]]:
        return [(self.min_radius <= self.init_radius <= self.max_radius,
                 f"init_radius={self.init_radius!r} must lie in [min_radius, max_radius] = [{self.min_radius!r}, {self.max_radius!r}] "
                 "(the curriculum needs 0 <= min_radius <= init_radius <= max_radius)")]


PROGRESS_DISTANCES = ("euclidean", "geodesic")


@dataclass(frozen=True)
class RewardConfig(Config):
    preset: str = "classic"  # "classic" | "progress" | "shaped"; see docs/tasks.md (an unknown one is named when the task is built)
    weights: dict[str, float] = field(default_factory=dict)  # per-term weight overrides
    proximity_distance: float = real(1.0)  # m, obstacles nearer than this are penalised
    spin_threshold: float = real(0.5)  # rad/s, turn rates above this are penalised ("progress")
    progress_distance: str = one_of(*PROGRESS_DISTANCES, default="euclidean")  # "euclidean" | "geodesic" (shortest safe path; needs worlds.families): what `progress` rewards the decrease of
    geodesic_margin: float = non_negative(0.0)  # m, geodesic paths keep this much more than the robot's radius from obstacles


@dataclass(frozen=True)
class ObservationConfig(Config):
    normalize: bool = True  # scale lidar and distances by max_range, angles by pi, speeds by limits
    history: int = count(1, 1, hi=MAX_HISTORY)  # stack the last k observations
    goal_from_odom: bool = False  # goal vector from the drifting odometry instead of the true pose
    imu: bool = False  # append the IMU reading [a_x, a_y, yaw rate] (needs imu.enabled)
    camera: bool = False  # append the camera's depth row, n_cols values (needs camera.enabled)
    goal_distance_cap: float | None = optional(lambda v: is_number(v) and v > 0, "a finite number of metres > 0")  # m: the goal distance observed is at most this (None: uncapped)
    # Memory of where the robot has been (docs/tasks.md#visit-memory): every `visit_spacing` m driven
    # (by odometry) the robot drops a breadcrumb; the observation gets, per egocentric sector, how many
    # lie within `visit_radius` (nearer ones weigh more). 0 sectors: off.
    visit_sectors: int = count(0, 0)
    visit_radius: float = positive(3.0)  # m
    visit_spacing: float = positive(0.5)  # m between breadcrumbs
    visit_memory: int = count(1, 64, hi=4096)  # breadcrumbs kept; the oldest is overwritten


@dataclass(frozen=True)
class ActionConfig(Config):
    mode: str = one_of(*ACTION_MODES, default="continuous")  # "continuous" in [-1, 1]^2 or "discrete" (one-hot over `discrete_set`)
    forward_only: bool = True  # map a[0] to v in [0, v_max] (else [-v_max, v_max])
    # m or None: a guard caps the forward speed so that the robot's disc stops this far short of every
    # lidar return in its path within the step (docs/tasks.md#speed-guard); None: off
    stop_clearance: float | None = optional(lambda v: is_number(v) and v >= 0, "a finite number of metres >= 0")
    # the path the guard checks: "straight" (the step's arc as a straight line) or "arc" (the command's
    # arc, braking along it: for fast robots that turn hard, docs/tasks.md#speed-guard)
    stop_path: str = one_of("straight", "arc", default="straight")
    # (v, omega) as fractions of (v_max, omega_max), for mode "discrete"
    discrete_set: tuple[tuple[float, float], ...] = (
        (1.0, 0.0), (1.0, 0.5), (1.0, -0.5), (0.5, 1.0), (0.5, -1.0), (0.0, 1.0), (0.0, -1.0),
    )

    def checks(self) -> list[tuple[bool, str]]:
        return [(len(self.discrete_set) >= 2, f"discrete_set needs at least 2 actions, got {len(self.discrete_set)}"),
                (self.stop_path == "straight" or self.stop_clearance is not None,
                 f"stop_path={self.stop_path!r} is the speed guard's, which is off: set stop_clearance too")]


@dataclass(frozen=True)
class ResetConfig(Config):
    start_clearance: float = non_negative(0.3)  # m, free gap around the robot disc at the start pose
    goal_clearance: float = non_negative(0.4)  # m, distance of the goal point from any obstacle
    candidates: int = count(1, 32)  # rejection-sampling candidates per env and object
    pool: int = count(0, 0)  # 0: sample exactly the envs being reset; N > 0: sample N episodes at a time and hand them out
    reuse: int = count(1, 1)  # times each pooled episode is handed out (in a fresh order each pass) before the pool is refilled


@dataclass(frozen=True)
class WorldsConfig(Config):
    """Procedural worlds (docs/worlds.md) instead of one map: every episode draws a family,
    a world of that family at the family's difficulty, a start and a reachable goal."""

    families: dict[str, float] = field(default_factory=dict)  # family -> weight ("rooms", ..., "map:arena"); empty: `map`
    difficulty: float = probability(0.5)  # in [0, 1]: the fixed difficulty, or the starting one with `curriculum`
    curriculum: bool = False  # success-gated difficulty, one level per family
    success_threshold: float = within(0.0, 1.0, 0.8, closed="()")  # raise a family's difficulty when its success average exceeds this
    difficulty_step: float = non_negative(0.05)  # added per finished episode batch while above the threshold
    success_smoothing: float = within(0.0, 1.0, 0.02, closed="(]")  # weight of each finished episode in its family's success average
    max_difficulty: float = probability(1.0)  # cap of the curriculum
    anywhere_goals: float = probability(0.0)  # fraction of episodes whose goal is anywhere reachable (>= 0.5 m), not in the difficulty's band
    below_level: float = probability(0.0)  # fraction of episodes whose difficulty is drawn uniformly below their family's level, in [0, level)
    # Moving discs placed in every generated world at reset, as a map's `moving_circles` (docs/worlds.md)
    # without `region`: they move inside each world's bounds; with `size_x` and `size_y` instead of
    # `radius`, moving boxes (a map's `moving_boxes`). Empty: none.
    movers: dict[str, Any] = field(default_factory=dict)

    def checks(self) -> list[tuple[bool, str]]:
        return [
            (self.difficulty <= self.max_difficulty, f"difficulty={self.difficulty!r} must be at most max_difficulty={self.max_difficulty!r}"),
        ]

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
class NavConfig(Config):
    map: str = DEFAULT_MAP  # shipped map name or path to a map YAML (unused with worlds.families, which must then leave it at the default)
    max_steps: int = count(1, 500)  # steps before truncation
    goal_tolerance: float = positive(0.3)  # m, success when the robot centre is this close to the goal
    check_actions: bool = True  # raise on NaN/inf actions (one host sync per step)
    # Hold the map's fixed obstacles once for the whole batch, with a grid index of what each place can
    # see (torchnav/sim/static_map.py; the same readings, less memory and time on big maps): "auto" on
    # maps with at least 256 fixed obstacles, "on", or "off" (a copy in every env).
    shared_map: str = one_of("auto", "on", "off", default="auto")
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

    def checks(self) -> list[tuple[bool, str]]:
        w, reset = self.worlds, self.reset
        return [
            (not self.observation.imu or self.imu.enabled, "observation.imu needs imu.enabled: true"),
            (not self.observation.camera or self.camera.enabled, "observation.camera needs camera.enabled: true"),
            (reset.reuse == 1 or reset.pool > 0 or bool(w.families), "reset.reuse > 1 needs a pool: reset.pool > 0 or procedural worlds"),
            (self.reward.progress_distance != "geodesic" or bool(w.families),
             "reward.progress_distance: geodesic needs worlds.families (the distances come from each generated world's wavefront)"),
            (not w.families or self.map == DEFAULT_MAP,
             f"map: {self.map!r} is not used when worlds.families is set (procedural worlds bring their own); mix it in as "
             f"the family \"map:{self.map}\", or clear worlds.families to train on the map"),
            (all(v >= 0 for v in w.families.values()) and (not w.families or sum(w.families.values()) > 0),
             f"worlds.families weights must be >= 0 with a positive sum, got {w.families}"),
            *(raises(lambda name=name: _check_family(name)) for name in w.families),
            raises(w.mover_spec),
            (not w.movers or bool(w.families), "worlds.movers needs worlds.families (a map declares its movers as moving_circles)"),
            raises(lambda: check_ranges(self.randomize.ranges(), self.sim_params())),
        ]

    # from_dict fills in robot.preset's values under the keys the data gives (torchnav/tasks/robots.py)
    prepare_dict = staticmethod(with_robot_preset)

    def sim_params(self) -> SimParams:
        """The simulator's parameters of this task: the robot, its lidar, and the IMU and camera when enabled."""
        r, li, imu, ca = self.robot, self.lidar, self.imu, self.camera
        return SimParams(
            dt=r.dt, robot_radius=r.radius, track_width=r.track_width, v_min=0.0 if self.action.forward_only else -r.v_max,
            v_max=r.v_max, omega_max=r.omega_max, lin_acc_max=r.lin_acc_max, ang_acc_max=r.ang_acc_max, integrator=r.integrator,
            odom_v_noise=r.odom_v_noise, odom_omega_noise=r.odom_omega_noise,
            lidar=LidarParams(n_rays=li.n_rays, fov=math.radians(li.fov_deg), min_range=li.min_range, max_range=li.max_range,
                              offset=li.offset, noise_std=li.noise_std, scan=li.scan, window=li.window, dense_slots=li.dense_slots),
            imu=ImuParams(accel_noise=imu.accel_noise, gyro_noise=imu.gyro_noise, accel_bias_walk=imu.accel_bias_walk,
                          gyro_bias_walk=imu.gyro_bias_walk, rate=imu.rate) if imu.enabled else None,
            camera=CameraParams(n_cols=ca.n_cols, n_rows=ca.n_rows, fov=math.radians(ca.fov_deg), max_range=ca.max_range,
                                offset=ca.offset, height=ca.height) if ca.enabled else None,
        )


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


SCENARIOS = ("random", "circle_swap", "crossing")
ON_COLLISION = ("robot", "team")


@dataclass(frozen=True)
class RobotsConfig(Config):
    """Several robots per env (docs/multi_robot.md): how many, where they start, what a collision ends."""

    n: int = checked(lambda v: isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 16, "a whole number in [1, 16]", 4)  # robot slots per env
    min_n: int = count(0, 0)  # > 0: each reset draws an env's robot count uniformly in [min_n, n] (the others are absent); 0: always n
    scenario: str = one_of(*SCENARIOS, default="random")  # "random" starts and goals, "circle_swap" (goals at the antipodes), "crossing" (two groups swap sides)
    on_collision: str = one_of(*ON_COLLISION, default="robot")  # a collision parks that "robot" (an obstacle from then on), or ends the "team"'s episode
    neighbours: int = count(0, 3)  # k nearest other robots in range in each robot's observation (5 values each, padded with a 0 flag); 3: a 4-robot team fills every slot
    neighbour_range: float = positive(3.0)  # m, other robots farther than this are not observed (their slots padded)
    separation: float = non_negative(0.2)  # m, free gap between two robots' discs at the start, and between goals beyond 2 * goal_tolerance
    circle_radius: float = non_negative(0.0)  # m, circle_swap's circle; 0: 0.4 of the map's smaller side

    def checks(self) -> list[tuple[bool, str]]:
        return [(self.min_n <= self.n, f"min_n={self.min_n} must be at most n={self.n}")]


@dataclass(frozen=True)
class MultiNavConfig(NavConfig):
    """The navigation task with ``robots.n`` robots per env: every NavConfig section, plus ``robots``."""

    robots: RobotsConfig
