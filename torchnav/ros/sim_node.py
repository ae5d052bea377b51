"""A ROS 1 node (rospy) that simulates a robot with torchnav: the loop of ``policy_node`` without Gazebo.

    python -m torchnav.ros.sim_node _policy:=checkpoints/ppo_arena_actor.pt     # the policy's robot, lidar and map

Publishes what a robot's drivers would: ``sensor_msgs/LaserScan`` (``~scan_topic``, default ``/scan``,
frame ``laser``, the simulator's ray layout), ``nav_msgs/Odometry`` (``~odom_topic``, ``/odom``, frame
``odom`` -> ``base_link``), tf (``map`` -> ``odom`` -> ``base_link``, static ``base_link`` -> ``laser``) and
the episode's obstacles as a latched ``nav_msgs/OccupancyGrid`` on ``/map``; drives the
``geometry_msgs/Twist`` it gets on ``~cmd_topic`` (``/cmd_vel``; the simulator's limits apply).

Episodes: a pose on ``/initialpose`` (``geometry_msgs/PoseWithCovarianceStamped``, RViz's "2D Pose
Estimate") is the next start; a goal on ``~goal_topic`` (``/move_base_simple/goal``, frame ``map``) starts
an episode there: a fresh ``NavEnv`` of seed ``~seed`` placed with ``reset_to(start, goal)`` (the map's
random objects placed as ``recipes/evaluate.py`` places them for one episode), so an episode here is the
in-process evaluation's episode of the same start, goal and seed. It ends in success (within the
task's goal tolerance), collision (the robot then stays where it hit) or timeout (``max_steps``); the
latched ``~episode`` (``std_msgs/String``, JSON: ``episode``, ``status``, ``steps``, ``start``, ``goal``)
says which.

Private parameters: ``~policy`` (its task config: robot, lidar, map) or ``~map`` (another map; default
the policy's, ``arena`` without a policy), ``~seed`` (20000, the evaluation's), ``~lockstep`` (false:
step every ``dt`` of wall time with the latest command, stopping after ``~cmd_timeout`` s without one;
true: one step per command received during an episode, for reproducible runs against ``policy_node``
with ``_trigger:=scan``), topic names as above and ``~initialpose_topic``, frame names ``~map_frame``,
``~odom_frame``, ``~base_frame`` (``base_link``) and ``~laser_frame``.
"""

from __future__ import annotations

import json
import math
import sys
import threading
from typing import Any

import torch

from .convert import pose_of, relative, run_node, yaw_quaternion


def sim_config(policy: str | None, map: str | None):
    """The task config the node simulates: the policy's task as evaluation plays it (on ``map`` if given), or
    the default navigation task on ``map`` (``arena``)."""
    from ..evaluation import eval_config
    from ..tasks import NavConfig

    if policy:
        from ..policy import load_policy

        sp = load_policy(policy)
        if sp.task != "nav":
            raise ValueError(f"{policy}: a {sp.task!r} policy, not a navigation policy")
        cfg = sp.config()
    else:
        cfg = NavConfig()
    return eval_config(cfg, map=map or (None if not cfg.worlds.families else "arena"), anywhere=True)


class SimNode:
    """The simulator and its ROS interface (see the module docstring); built after ``rospy.init_node``."""

    def __init__(self, rospy: Any) -> None:
        import tf2_ros
        from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, TransformStamped, Twist
        from nav_msgs.msg import OccupancyGrid, Odometry
        from sensor_msgs.msg import LaserScan
        from std_msgs.msg import String

        self.rospy, self.msgs = rospy, dict(LaserScan=LaserScan, Odometry=Odometry, TransformStamped=TransformStamped,
                                             OccupancyGrid=OccupancyGrid, String=String)
        self.cfg = sim_config(rospy.get_param("~policy", None), rospy.get_param("~map", None))
        self.seed = int(rospy.get_param("~seed", 20000))
        self.lockstep = bool(rospy.get_param("~lockstep", False))
        self.cmd_timeout = float(rospy.get_param("~cmd_timeout", 0.5))
        self.params = self.cfg.sim_params()
        self.frames = {k: rospy.get_param(f"~{k}_frame", k if k != "base" else "base_link") for k in ("map", "odom", "base", "laser")}
        self.dt = self.params.dt
        self.lock = threading.Lock()
        self.twist, self.twist_time = (0.0, 0.0), -math.inf
        self.episode, self.status, self.steps = 0, "idle", 0
        self.pending_start: tuple[float, float, float] | None = None
        self.goal: tuple[float, float] | None = None
        self.scan_pub = rospy.Publisher(rospy.get_param("~scan_topic", "/scan"), LaserScan, queue_size=5)
        self.odom_pub = rospy.Publisher(rospy.get_param("~odom_topic", "/odom"), Odometry, queue_size=5)
        self.map_pub = rospy.Publisher("/map", OccupancyGrid, queue_size=1, latch=True)
        self.episode_pub = rospy.Publisher("~episode", String, queue_size=5, latch=True)
        self.tf = tf2_ros.TransformBroadcaster()
        self.tf_static = tf2_ros.StaticTransformBroadcaster()
        ox, oy, oyaw = self.params.lidar.offset
        self.tf_static.sendTransform(self.transform(rospy.Time.now(), self.frames["base"], self.frames["laser"], (ox, oy, oyaw)))
        self.new_episode(None, None)  # a sampled start to stand at until the first goal
        rospy.Subscriber(rospy.get_param("~cmd_topic", "/cmd_vel"), Twist, self.on_cmd, queue_size=10)
        rospy.Subscriber(rospy.get_param("~goal_topic", "/move_base_simple/goal"), PoseStamped, self.on_goal, queue_size=1)
        rospy.Subscriber(rospy.get_param("~initialpose_topic", "/initialpose"), PoseWithCovarianceStamped, self.on_initialpose, queue_size=1)
        if not self.lockstep:
            self.timer = rospy.Timer(rospy.Duration(self.dt), lambda _: self.tick())
        rospy.loginfo(f"sim_node: map {self.cfg.map}, seed {self.seed}, dt {self.dt:g} s, {'lock step' if self.lockstep else 'real time'}")

    # -- episodes --------------------------------------------------------------------------------

    def new_episode(self, start: tuple[float, float, float] | None, goal: tuple[float, float] | None) -> None:
        """A fresh env of seed ``~seed``, at ``start`` with ``goal`` (both given), or sampled; then publish it."""
        from ..envs import NavEnv

        env = NavEnv(self.cfg, num_envs=1, seed=self.seed)
        if start is None:
            env.reset()
        else:
            env.reset_to(torch.tensor([start]), torch.tensor([goal]))  # ValueError for a start or goal in an obstacle
        self.env, self.state = env, env.state
        self.sim, self.world = self.state.sim, self.state.world
        self.steps = 0
        self.publish_map()
        self.publish_state()

    def on_initialpose(self, msg: Any) -> None:
        start = pose_of(msg.pose.pose)
        if not all(math.isfinite(v) for v in start):
            self.rospy.logwarn_throttle(2.0, f"sim_node: /initialpose refused: {start} is not finite")
            return
        with self.lock:
            self.pending_start = start
            self.say("ready")

    def on_goal(self, msg: Any) -> None:
        x, y, _ = pose_of(msg.pose)
        if msg.header.frame_id.lstrip("/") not in ("", self.frames["map"], self.frames["odom"]):
            self.rospy.logwarn_throttle(2.0, f"sim_node: goal refused: frame {msg.header.frame_id!r}; the simulator takes goals in "
                                             f"{self.frames['map']!r}")
            return
        with self.lock:
            start = self.pending_start or tuple(float(v) for v in self.sim.pose[0])
            try:
                self.new_episode(start, (x, y))
            except ValueError as e:
                self.rospy.logwarn(f"sim_node: episode refused: {e}")
                self.say("refused")
                return
            self.pending_start, self.goal = None, (x, y)
            self.episode += 1
            self.say("running")

    def on_cmd(self, msg: Any) -> None:
        with self.lock:
            self.twist, self.twist_time = (float(msg.linear.x), float(msg.angular.z)), self.rospy.get_time()
            if self.lockstep and self.status == "running":
                self.advance(self.twist)

    def tick(self) -> None:
        with self.lock:
            if self.status in ("collision",):
                self.publish_state()  # the robot stays where it hit; its sensors keep reading
                return
            fresh = self.rospy.get_time() - self.twist_time <= self.cmd_timeout
            self.advance(self.twist if fresh else (0.0, 0.0))

    def advance(self, twist: tuple[float, float]) -> None:
        """One simulator step driving ``twist`` (the task's limits apply), then the episode's outcome."""
        from ..sim import step

        task = self.env.task
        action = torch.tensor([twist], dtype=self.sim.pose.dtype)
        self.sim = step(self.sim, action, self.world, self.params, generator=self.env.generator,
                        env_params=self.state.env_params if task.randomized else None)
        self.steps += 1
        if self.status == "running":
            dist = float(task.goal_vector(self.sim.pose, torch.tensor([self.goal], dtype=self.sim.pose.dtype))[0][0])
            collided = bool(self.sim.collided[0])
            if collided:
                self.say("collision")
            elif dist < self.cfg.goal_tolerance:
                self.say("success")
            elif self.steps >= self.cfg.max_steps:
                self.say("timeout")
        self.publish_state()

    # -- publishing --------------------------------------------------------------------------------

    def say(self, status: str) -> None:
        self.status = status
        info = {"episode": self.episode, "status": status, "steps": self.steps, "goal": self.goal,
                "start": [float(v) for v in self.state.start[0]] if status != "ready" else list(self.pending_start or ())}
        self.episode_pub.publish(self.msgs["String"](data=json.dumps(info)))

    def transform(self, stamp: Any, parent: str, child: str, pose: tuple[float, float, float]) -> Any:
        t = self.msgs["TransformStamped"]()
        t.header.stamp, t.header.frame_id, t.child_frame_id = stamp, parent, child
        t.transform.translation.x, t.transform.translation.y = float(pose[0]), float(pose[1])
        q = t.transform.rotation
        q.x, q.y, q.z, q.w = yaw_quaternion(float(pose[2]))
        return t

    def publish_state(self) -> None:
        """Odometry first, then the scan of the same stamp (``policy_node`` with ``_trigger:=scan`` acts on the pair)."""
        from ..observation import Scan

        rospy, s = self.rospy, self.sim
        now = rospy.Time.now()
        odom = tuple(float(v) for v in s.odom[0])
        pose = tuple(float(v) for v in s.pose[0])
        f = self.frames
        self.tf.sendTransform([self.transform(now, f["map"], f["odom"], relative(pose, odom)), self.transform(now, f["odom"], f["base"], odom)])
        o = self.msgs["Odometry"]()
        o.header.stamp, o.header.frame_id, o.child_frame_id = now, f["odom"], f["base"]
        o.pose.pose.position.x, o.pose.pose.position.y = odom[0], odom[1]
        q = o.pose.pose.orientation
        q.x, q.y, q.z, q.w = yaw_quaternion(odom[2])
        o.twist.twist.linear.x, o.twist.twist.angular.z = float(s.vel[0, 0]), float(s.vel[0, 1])
        self.odom_pub.publish(o)
        scan = Scan.of_sim(s.ranges[0].tolist(), self.params.lidar)
        m = self.msgs["LaserScan"]()
        m.header.stamp, m.header.frame_id = now, f["laser"]
        m.angle_min, m.angle_increment = scan.angle_min, scan.angle_increment
        m.angle_max = scan.angle_min + scan.angle_increment * (len(scan.ranges) - 1)
        m.range_min, m.range_max, m.scan_time, m.ranges = scan.range_min, scan.range_max, self.dt, scan.ranges
        self.scan_pub.publish(m)

    def publish_map(self) -> None:
        import numpy as np

        from .bag import occupancy, world_bounds

        w = self.world[0:1]
        pose = self.sim.pose[0, :2].numpy()
        goal = self.state.goal[0].numpy()
        cells, res, origin = occupancy(w, world_bounds(w, np.stack((pose, goal))))
        g = self.msgs["OccupancyGrid"]()
        g.header.stamp, g.header.frame_id = self.rospy.Time.now(), self.frames["map"]
        g.info.resolution, g.info.height, g.info.width = res, cells.shape[0], cells.shape[1]
        g.info.origin.position.x, g.info.origin.position.y = origin
        g.info.origin.orientation.w = 1.0
        g.data = cells.reshape(-1).tolist()
        self.map_pub.publish(g)


def main(argv: list[str] | None = None) -> int:
    return run_node("sim_node", "torchnav_sim", SimNode, argv)


if __name__ == "__main__":
    sys.exit(main(sys.argv))


__all__ = ["SimNode", "main", "sim_config"]
