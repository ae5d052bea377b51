"""Run a navigation policy open-loop on a recorded bag: what would it have commanded?

    python -m torchnav.ros.replay_bag BAG --policy actor.pt --scan-topic /scan --odom-topic /odom --goal X Y --out cmd.csv

Reads a ROS 1 ``.bag`` or a ROS 2 bag directory (``rosbags``' AnyReader), and at every scan (the
control tick) feeds the scan, the latest odometry at or before it and the goal (``--goal``, in the
odometry's frame; default: the bag's ``/goal`` as ``recipes/evaluate.py --record-bag`` writes it) to
the policy through ``torchnav.observation.PolicyDriver``, as ``torchnav.ros.policy_node`` does live.
Writes a CSV, one row per scan: ``t`` (s), the pose, the commanded ``v`` and ``omega``, the goal
distance, how many simulated lidar bins the scan did not cover, and ``bag_v``/``bag_omega``, the
twist the bag's ``--cmd-topic`` holds at that time (empty where none) for comparison. ``--out`` ending
in anything but ``.csv`` writes a ROS 2 bag with ``/cmd_vel`` (geometry_msgs/msg/Twist) instead.
Odometry never seen before a scan, or a scan the builder refuses, is reported and skipped.
"""

from __future__ import annotations

import argparse
import bisect
import csv
import math
import sys
from pathlib import Path

from ..observation import PolicyDriver
from ..policy import load_policy
from .bag import read_messages
from .convert import odom_of, scan_of

FIELDS = ("t", "x", "y", "yaw", "v", "omega", "goal_distance", "unseen_bins", "bag_v", "bag_omega")


def stamp_ns(msg, t_ns: int) -> int:
    """A message's header stamp in ns (the bag's time when it has none)."""
    h = getattr(msg, "header", None)
    if h is None:
        return t_ns
    s = h.stamp
    sec = getattr(s, "sec", None)
    if sec is None:  # ROS 1 (rospy-style Time through rosbags: secs/nsecs)
        sec, nsec = getattr(s, "secs", 0), getattr(s, "nsecs", 0)
    else:
        nsec = s.nanosec
    return int(sec) * 1_000_000_000 + int(nsec) or t_ns


def replay(bag: str | Path, driver: PolicyDriver, scan_topic: str = "/scan", odom_topic: str = "/odom",
           goal: tuple[float, float] | None = None, cmd_topic: str = "/cmd_vel", goal_topic: str = "/goal") -> list[dict]:
    """The rows of the CSV (see the module docstring) for ``bag``, driven by ``driver`` from a fresh episode."""
    msgs = read_messages(bag, {scan_topic, odom_topic, cmd_topic, goal_topic})
    topics = {t for t, _, _ in msgs}
    for name, topic in (("--scan-topic", scan_topic), ("--odom-topic", odom_topic)):
        if topic not in topics:
            raise ValueError(f"{bag}: no messages on {name} {topic} (topics here: {sorted(topics) or 'none'})")
    if goal is None:
        goals = [m for t, _, m in msgs if t == goal_topic]
        if not goals:
            raise ValueError(f"{bag}: no --goal given and no {goal_topic} message in the bag")
        goal = (float(goals[0].pose.position.x), float(goals[0].pose.position.y))
    odoms = sorted((stamp_ns(m, t), odom_of(m)) for tp, t, m in msgs if tp == odom_topic)
    odom_t = [t for t, _ in odoms]
    cmds = {stamp_ns(m, t): m for tp, t, m in msgs if tp == cmd_topic}
    driver.reset()
    rows, skipped = [], 0
    for tp, t, m in msgs:
        if tp != scan_topic:
            continue
        ts = stamp_ns(m, t)
        i = bisect.bisect_right(odom_t, ts) - 1
        if i < 0:
            skipped += 1
            continue
        pose, vel = odoms[i][1]
        try:
            v, w = driver.act(scan_of(m), pose, vel, goal)
        except ValueError as e:
            print(f"replay_bag: scan at {ts / 1e9:.3f} s skipped: {e}", file=sys.stderr)
            skipped += 1
            continue
        c = cmds.get(t)
        rows.append({"t": ts / 1e9, "x": pose[0], "y": pose[1], "yaw": pose[2], "v": v, "omega": w,
                     "goal_distance": driver.builder.goal_distance, "unseen_bins": int(driver.builder.unseen.sum()),
                     "bag_v": "" if c is None else float(c.linear.x), "bag_omega": "" if c is None else float(c.angular.z)})
    if skipped:
        print(f"replay_bag: {skipped} scans skipped (no odometry yet, or refused readings)", file=sys.stderr)
    return rows


def write_rows(rows: list[dict], out: Path) -> None:
    """The rows as a CSV file, or as a ROS 2 bag of ``/cmd_vel`` when ``out`` does not end in ``.csv``."""
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix == ".csv":
        with open(out, "w", newline="") as f:
            wr = csv.DictWriter(f, fieldnames=FIELDS)
            wr.writeheader()
            wr.writerows(rows)
        return
    from rosbags.rosbag2 import StoragePlugin, Writer

    from .bag import Messages

    if out.exists():
        raise FileExistsError(f"{out}: already exists (a bag is written to a new directory)")
    m = Messages()
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/cmd_vel", "geometry_msgs/msg/Twist", typestore=m.ts)
        for r in rows:
            w.write(conn, round(r["t"] * 1e9), m.ts.serialize_cdr(m.twist(r["v"], r["omega"]), "geometry_msgs/msg/Twist"))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m torchnav.ros.replay_bag", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", help="a ROS 1 .bag file or a ROS 2 bag directory")
    p.add_argument("--policy", required=True, help="actor.pt of a navigation policy")
    p.add_argument("--scan-topic", default="/scan")
    p.add_argument("--odom-topic", default="/odom")
    p.add_argument("--cmd-topic", default="/cmd_vel", help="the bag's recorded commands, compared in the CSV (default /cmd_vel)")
    p.add_argument("--goal", nargs=2, type=float, default=None, metavar=("X", "Y"), help="goal in the odometry's frame, m (default: the bag's /goal)")
    p.add_argument("--scan-yaw", type=float, default=0.0, help="rad: how the scan's frame is turned from the robot's heading (CCW)")
    p.add_argument("--out", required=True, help="CSV path, or a new directory for a ROS 2 bag of /cmd_vel")
    a = p.parse_args(argv)
    if a.goal is not None and not all(math.isfinite(g) for g in a.goal):
        p.error(f"--goal must be finite, got {a.goal}")
    try:
        driver = PolicyDriver(load_policy(a.policy), scan_yaw=a.scan_yaw)
        rows = replay(a.bag, driver, a.scan_topic, a.odom_topic, None if a.goal is None else tuple(a.goal), a.cmd_topic)
        write_rows(rows, Path(a.out))
    except (ValueError, FileNotFoundError, FileExistsError, ImportError) as e:
        print(f"replay_bag: {e}", file=sys.stderr)
        return 2
    print(f"replay_bag: {len(rows)} commands from {a.bag} written to {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
