"""Pure-tensor simulator core: state, kinematics, geometry, lidar, collision, step.

Nothing here knows about tasks, rewards or TorchRL.
"""

from .floor import FloorSensorParams, band_coverage, build_segment_grid, floor_readings, nearest_distance, sensor_points
from .geometry import box_corners, disc_clearance, points_clearance, point_box_distance, point_circle_distance, point_segment_distance
from .kinematics import apply_limits, integrate, integrate_euler, integrate_exact, unicycle_to_wheels, wheels_to_unicycle
from .lidar import cast_rays, hit_box, hit_circle, hit_segment, lidar_fan, lidar_scan, ray_origins_and_angles, scan_is_exact, sectorize
from .camera import ObstacleStyles, camera_depth, camera_image, camera_rays
from .imu import IMU_FIELDS, imu_truth, step_imu
from .movers import BOX_FIELDS, MOVER_FIELDS, Movers, make_movers, mover_world, no_movers, step_movers
from .randomize import RANDOMIZED, EnvParams, nominal_env_params, sample_env_params
from .math import safe_hypot, safe_norm, safe_sinc, wrap_angle
from .params import CameraParams, ImuParams, LidarParams, SimParams
from .robots import Robots, RobotsState, init_robots, make_robots, robot_clearance, robot_world, seen_world, step_robots
from .state import SimState, World, cat_worlds, check_world, make_world, pad_world, planar_world
from .step import check_action, init_state, step

__all__ = [
    "LidarParams", "SimParams", "ImuParams", "CameraParams", "IMU_FIELDS", "imu_truth", "step_imu",
    "ObstacleStyles", "camera_depth", "camera_image", "camera_rays", "BOX_FIELDS", "MOVER_FIELDS", "Movers", "RANDOMIZED", "EnvParams", "nominal_env_params", "sample_env_params", "make_movers", "mover_world", "no_movers", "step_movers", "SimState", "World", "make_world", "pad_world", "cat_worlds", "planar_world", "init_state", "check_world",
    "step", "check_action", "Robots", "RobotsState", "make_robots", "init_robots", "step_robots", "robot_world", "seen_world", "robot_clearance", "lidar_scan", "lidar_fan", "scan_is_exact", "cast_rays", "hit_segment", "hit_circle", "hit_box", "sectorize", "ray_origins_and_angles", "disc_clearance",
    "point_segment_distance", "points_clearance", "point_circle_distance", "point_box_distance", "box_corners",
    "integrate", "integrate_euler", "integrate_exact", "apply_limits", "wheels_to_unicycle",
    "unicycle_to_wheels", "wrap_angle", "safe_norm", "safe_hypot", "safe_sinc",
    "FloorSensorParams", "sensor_points", "build_segment_grid", "nearest_distance", "band_coverage", "floor_readings",
]
