"""ROS messages (ROS 1 or ROS 2, from rospy or rosbags: only their fields are read) to plain numbers and back."""

from __future__ import annotations

import math
import sys
from typing import Any

from ..observation import Scan

ROSPY_INSTALL = ("rospy and roscore (ROS 1): on Debian `apt-get install ros-core python3-rospy python3-tf2-ros python3-sensor-msgs "
                 "python3-nav-msgs python3-geometry-msgs` and PYTHONPATH=/usr/lib/python3/dist-packages after the project's own "
                 "paths; elsewhere `source /opt/ros/noetic/setup.bash`")


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """``(x, y, z, w)`` of a rotation by ``yaw`` rad about z."""
    return 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)


def quaternion_yaw(x: float, y: float, z: float, w: float) -> float:
    """The rotation about z (rad) of a quaternion (the planar part of any orientation)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def scan_of(msg: Any) -> Scan:
    """A ``sensor_msgs/LaserScan`` as a :class:`~torchnav.observation.Scan`; ``ValueError`` naming a missing field."""
    try:
        return Scan(ranges=[float(r) for r in msg.ranges], angle_min=float(msg.angle_min), angle_increment=float(msg.angle_increment),
                    range_min=float(msg.range_min), range_max=float(msg.range_max))
    except AttributeError as e:
        raise ValueError(f"not a sensor_msgs/LaserScan: {e}") from None


def odom_of(msg: Any) -> tuple[tuple[float, float, float], tuple[float, float]]:
    """A ``nav_msgs/Odometry`` -> ``((x, y, yaw), (v, omega))`` (m, rad, m/s, rad/s)."""
    p, q, tw = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist
    return (float(p.x), float(p.y), quaternion_yaw(q.x, q.y, q.z, q.w)), (float(tw.linear.x), float(tw.angular.z))


def pose_of(msg: Any) -> tuple[float, float, float]:
    """A ``geometry_msgs/Pose`` -> ``(x, y, yaw)``."""
    p, q = msg.position, msg.orientation
    return float(p.x), float(p.y), quaternion_yaw(q.x, q.y, q.z, q.w)


def compose(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """The planar pose ``b`` (in frame ``a``) in ``a``'s parent frame: ``a * b``."""
    c, s = math.cos(a[2]), math.sin(a[2])
    yaw = a[2] + b[2]
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.atan2(math.sin(yaw), math.cos(yaw))


def relative(pose: tuple[float, float, float], odom: tuple[float, float, float]) -> tuple[float, float, float]:
    """The transform ``T`` with ``T * odom = pose`` (``map`` -> ``odom`` from the true pose and the odometry's)."""
    yaw = pose[2] - odom[2]
    c, s = math.cos(yaw), math.sin(yaw)
    return pose[0] - (c * odom[0] - s * odom[1]), pose[1] - (s * odom[0] + c * odom[1]), math.atan2(math.sin(yaw), math.cos(yaw))


def run_node(module: str, name: str, node: Any, argv: list[str] | None = None) -> int:
    """The ``main`` of a ROS 1 node: import rospy (a missing one is named, exit 2), ``init_node(name)``,
    build ``node(rospy)`` (a bad parameter is logged, exit 2), then spin until shutdown (exit 0)."""
    try:
        import rospy
    except ImportError as e:
        print(f"torchnav.ros.{module} needs {ROSPY_INSTALL} ({e})", file=sys.stderr)
        return 2
    rospy.init_node(name, argv=argv)
    try:
        node(rospy)
    except (ValueError, FileNotFoundError) as e:
        rospy.logerr(f"{module}: {e}")
        return 2
    rospy.spin()
    return 0

