"""A ROS 1 node (rospy) that drives a robot with a torchnav navigation policy.

    python -m torchnav.ros.policy_node _policy:=checkpoints/ppo_arena_actor.pt

Subscribes to a ``sensor_msgs/LaserScan`` (``~scan_topic``, default ``/scan``), ``nav_msgs/Odometry``
(``~odom_topic``, ``/odom``) and goals as ``geometry_msgs/PoseStamped`` (``~goal_topic``,
``/move_base_simple/goal``: RViz's "2D Nav Goal"), and publishes ``geometry_msgs/Twist`` on
``~cmd_topic`` (``/cmd_vel``) at the policy's control rate (its task's ``dt``), built by
``torchnav.observation.PolicyDriver``: the observation the policy was trained on, its speed guard
and its speed limits. A goal in another frame than the odometry's is transformed by tf2 (refused,
with a warning, when no transform is known). ``~status`` (``std_msgs/String``, latched) says what
it does: ``idle``, ``goal (x, y)`` (a new goal taken, in the odometry's frame), ``driving``,
``reached``, ``stopped: <why>``.

It stops the robot (publishes a zero twist) when it has no goal, when the goal is reached (the
policy's goal tolerance), when the scan or the odometry is older than ``~stale_timeout`` s, when a
reading is refused (non-finite pose, an empty scan, a message of the wrong layout), and on shutdown.
Each problem is a named ``rospy.logwarn_throttle``, never a traceback.

Private parameters: ``~policy`` (required), ``~scan_topic``, ``~odom_topic``, ``~goal_topic``,
``~cmd_topic``, ``~odom_frame`` (the goal's frame after tf2, default the odometry's ``header.frame_id``),
``~rate`` (Hz, default ``1 / dt``), ``~stale_timeout`` (s, default 0.5), ``~scan_yaw`` (rad, the scan
frame's turn from the robot's heading), ``~max_speed`` / ``~max_turn`` (extra limits, m/s and rad/s,
default the policy's), ``~goal_tolerance`` (m, default the policy's), ``~trigger`` (``timer``: act at
``~rate``; ``scan``: act once per new scan, when the odometry of the same time has arrived, the lock
step ``sim_node`` runs with). docs/ros.md has the deployment steps.
"""

from __future__ import annotations

import math
import sys
import threading
from typing import Any

from .convert import compose, odom_of, pose_of, quaternion_yaw, run_node, scan_of

WARN_PERIOD = 2.0  # s between repeats of one warning


class PolicyNode:
    """The node's state and callbacks (see the module docstring); built after ``rospy.init_node``."""

    def __init__(self, rospy: Any) -> None:
        import tf2_ros
        from geometry_msgs.msg import PoseStamped, Twist
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import LaserScan
        from std_msgs.msg import String

        from ..observation import PolicyDriver
        from ..policy import load_policy

        self.rospy, self.Twist, self.String = rospy, Twist, String
        path = rospy.get_param("~policy", None)
        if not path:
            raise ValueError("~policy is not set: give the policy file, e.g. _policy:=checkpoints/ppo_arena_actor.pt")
        self.driver = PolicyDriver(load_policy(path), scan_yaw=float(rospy.get_param("~scan_yaw", 0.0)))
        r = self.driver.cfg.robot
        self.rate = float(rospy.get_param("~rate", 1.0 / self.driver.dt))
        if abs(self.rate * self.driver.dt - 1.0) > 0.05:
            rospy.logwarn(f"policy_node: ~rate {self.rate:g} Hz differs from the policy's control rate {1.0 / self.driver.dt:g} Hz "
                          "(its task's dt): the policy sees other speeds and distances per step than it was trained with")
        self.stale = float(rospy.get_param("~stale_timeout", 0.5))
        self.max_speed = min(float(rospy.get_param("~max_speed", r.v_max)), r.v_max)
        self.max_turn = min(float(rospy.get_param("~max_turn", r.omega_max)), r.omega_max)
        self.tolerance = float(rospy.get_param("~goal_tolerance", self.driver.goal_tolerance))
        self.odom_frame = rospy.get_param("~odom_frame", "")
        self.trigger = rospy.get_param("~trigger", "timer")
        if self.trigger not in ("timer", "scan"):
            raise ValueError(f"~trigger must be 'timer' or 'scan', got {self.trigger!r}")
        self.lock = threading.Lock()
        self.scan = self.odom = self.goal = None  # latest messages; goal: (x, y) in the odometry's frame
        self.goal_stamp = 0.0
        self.acted_stamp = -1.0  # stamp of the last scan acted upon
        self.status = ""
        self.shutting_down = False
        self.tf = tf2_ros.Buffer()
        self.tf_listener = tf2_ros.TransformListener(self.tf)
        self.cmd = rospy.Publisher(rospy.get_param("~cmd_topic", "/cmd_vel"), Twist, queue_size=1)
        self.status_pub = rospy.Publisher("~status", String, queue_size=1, latch=True)
        rospy.Subscriber(rospy.get_param("~scan_topic", "/scan"), LaserScan, self.on_scan, queue_size=1)
        rospy.Subscriber(rospy.get_param("~odom_topic", "/odom"), Odometry, self.on_odom, queue_size=1)
        rospy.Subscriber(rospy.get_param("~goal_topic", "/move_base_simple/goal"), PoseStamped, self.on_goal, queue_size=1)
        rospy.on_shutdown(self.on_shutdown)
        self.say("idle")
        if self.trigger == "timer":
            self.timer = rospy.Timer(rospy.Duration(1.0 / self.rate), lambda _: self.tick())
        rospy.loginfo(f"policy_node: {path} ({self.driver.saved.algorithm}), {self.trigger} at {self.rate:g} Hz, "
                      f"speed <= {self.max_speed:g} m/s, turn <= {self.max_turn:g} rad/s, stale after {self.stale:g} s")

    # -- callbacks ------------------------------------------------------------------------------

    def on_scan(self, msg: Any) -> None:
        with self.lock:
            self.scan = msg
        if self.trigger == "scan":
            self.tick()

    def on_odom(self, msg: Any) -> None:
        with self.lock:
            self.odom = msg
        if self.trigger == "scan":
            self.tick()

    def on_goal(self, msg: Any) -> None:
        try:
            goal = self.goal_in_odom(msg)
        except Exception as e:  # noqa: BLE001 - a refused goal is a warning; the robot stays stopped
            self.warn("goal", f"goal refused: {e}")
            return
        if goal is None:
            return
        with self.lock:
            self.goal, self.goal_stamp = goal, msg.header.stamp.to_sec()
            self.driver.reset()
        self.rospy.loginfo(f"policy_node: new goal ({goal[0]:.2f}, {goal[1]:.2f}) in the odometry's frame")
        self.say(f"goal ({goal[0]:.2f}, {goal[1]:.2f})")
        if self.trigger == "scan":
            self.tick()

    def goal_in_odom(self, msg: Any) -> tuple[float, float] | None:
        """The goal ``(x, y)`` in the odometry's frame (through tf2 when it is in another), or None (warned)."""
        x, y, _ = pose_of(msg.pose)
        if not (math.isfinite(x) and math.isfinite(y)):
            self.warn("goal", f"goal refused: position ({x}, {y}) is not finite")
            return None
        target = self.odom_frame or (self.odom.header.frame_id if self.odom is not None else "")
        frame = msg.header.frame_id.lstrip("/")
        if not target or frame in ("", target.lstrip("/")):
            return x, y
        try:
            t = self.tf.lookup_transform(target, frame, self.rospy.Time(0), self.rospy.Duration(0.2))
        except Exception as e:  # noqa: BLE001 - tf2 raises several kinds
            self.warn("goal", f"goal refused: it is in frame {frame!r} and no transform to the odometry's frame {target!r} is known ({type(e).__name__})")
            return None
        tr, q = t.transform.translation, t.transform.rotation
        gx, gy, _ = compose((tr.x, tr.y, quaternion_yaw(q.x, q.y, q.z, q.w)), (x, y, 0.0))
        return gx, gy

    def on_shutdown(self) -> None:
        with self.lock:  # no control step after this one: the last command is a stop
            self.shutting_down = True
            self.cmd.publish(self.Twist())

    # -- control -----------------------------------------------------------------------------------

    def tick(self) -> None:
        """One control step: the policy's twist, or a stop (with the reason in ``~status``)."""
        with self.lock:
            if self.shutting_down:
                return
            try:
                twist = self.control()
            except Exception as e:  # noqa: BLE001 - never a traceback: stop and say why
                self.warn("error", f"stopped: {type(e).__name__}: {e}")
                twist = (0.0, 0.0)
            if twist is not None:
                self.publish(*twist)

    def control(self) -> tuple[float, float] | None:
        """The twist to publish now, or None (nothing new to act on: trigger ``scan``)."""
        rospy = self.rospy
        if self.goal is None:
            return (0.0, 0.0) if self.trigger == "timer" else None
        if self.scan is None or self.odom is None:
            if self.trigger == "scan":
                return None  # a lock-step simulator steps on every command: send none before the first readings
            return self.stop("waiting for the first " + ("scan" if self.scan is None else "odometry"))
        scan_t, odom_t = self.scan.header.stamp.to_sec(), self.odom.header.stamp.to_sec()
        if self.trigger == "scan":
            if scan_t <= self.acted_stamp or scan_t < self.goal_stamp or odom_t < scan_t - 1e-6:
                return None  # wait for a new scan after the goal, and for the odometry of its time
            self.acted_stamp = scan_t
        else:
            now = rospy.get_time()
            for name, t in (("scan", scan_t), ("odometry", odom_t)):
                if now - t > self.stale:
                    return self.stop(f"stale {name}: the last one is {now - t:.2f} s old (~stale_timeout {self.stale:g} s)")
        try:
            scan = scan_of(self.scan)
            pose, vel = odom_of(self.odom)
        except (AttributeError, ValueError, TypeError) as e:
            return self.stop(f"a message of the wrong layout: {e}")
        try:
            v, w = self.driver.act(scan, pose, vel, self.goal)
        except ValueError as e:
            return self.stop(f"reading refused: {e}")
        unseen = int(self.driver.builder.unseen.sum())
        if unseen:
            self.warn("unseen", f"{unseen} of the policy's {self.driver.builder.lidar.n_rays} lidar bins lie outside the scan's field of "
                                "view: they read max_range (free)")
        if self.driver.builder.goal_distance < self.tolerance:
            self.goal = None
            self.say("reached")
            rospy.loginfo("policy_node: goal reached")
            return 0.0, 0.0
        if self.status != "driving":
            self.say("driving")
        return max(-self.max_speed, min(self.max_speed, v)), max(-self.max_turn, min(self.max_turn, w))

    def stop(self, why: str) -> tuple[float, float]:
        self.warn(why.split(":")[0], f"stopped: {why}")
        return 0.0, 0.0

    def warn(self, key: str, text: str) -> None:
        self.rospy.logwarn_throttle(WARN_PERIOD, f"policy_node: {text}")
        self.say(text if text.startswith("stopped") else f"warning: {text}")

    def say(self, status: str) -> None:
        if status != self.status:
            self.status = status
            self.status_pub.publish(self.String(data=status))

    def publish(self, v: float, w: float) -> None:
        t = self.Twist()
        t.linear.x, t.angular.z = float(v), float(w)
        self.cmd.publish(t)


def main(argv: list[str] | None = None) -> int:
    return run_node("policy_node", "torchnav_policy", PolicyNode, argv)


if __name__ == "__main__":
    sys.exit(main(sys.argv))


__all__ = ["PolicyNode", "main"]
