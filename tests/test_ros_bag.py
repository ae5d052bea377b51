"""Episodes as ROS 2 bags (torchnav.ros.bag, evaluate.py --record-bag) and the open-loop replay of a policy on one."""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import pytest

pytest.importorskip("rosbags", reason="needs rosbags: pip install 'torchnav[ros]'")

from torchnav.ros import replay_bag  # noqa: E402
from torchnav.ros.bag import TOPICS, occupancy, read_messages  # noqa: E402
from torchnav.ros.convert import quaternion_yaw  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
POLICY = ROOT / "checkpoints" / "td3_arena_actor.pt"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Three evaluation episodes of the arena policy as bags, and evaluate.py's summary of the same episodes."""
    sys.path.insert(0, str(ROOT / "recipes"))
    import evaluate

    where = tmp_path_factory.mktemp("bags")
    out = evaluate.main([str(POLICY), "--episodes", "3", "--threads", "1", "--record-bag", str(where), "--bag-episodes", "3"])
    return where, out


def test_bags_hold_every_topic_and_the_evaluated_outcomes(recorded):
    where, out = recorded
    bags = sorted(where.glob("episode_*"))
    assert [b.name for b in bags] == ["episode_000", "episode_001", "episode_002"]
    outcomes = []
    for bag in bags:
        assert (bag / "metadata.yaml").is_file() and list(bag.glob("*.mcap"))
        msgs = read_messages(bag)
        by = {}
        for topic, t, m in msgs:
            by.setdefault(topic, []).append((t, m))
        assert set(by) == set(TOPICS)
        info = json.loads(by["/torchnav/episode"][0][1].data)
        steps = info["steps"]
        assert len(by["/scan"]) == len(by["/odom"]) == len(by["/tf"]) == steps + 1 and len(by["/cmd_vel"]) == steps
        assert len(by["/map"]) == len(by["/goal"]) == len(by["/path"]) == 1 and len(by["/path"][0][1].poses) == steps + 1
        scan = by["/scan"][0][1]
        assert len(scan.ranges) == 20 and math.isclose(scan.angle_min, -math.pi / 2, abs_tol=1e-6) and scan.range_max == 10.0
        assert scan.header.frame_id == "laser" and by["/odom"][0][1].child_frame_id == "base_link"
        grid = by["/map"][0][1]
        assert grid.info.width * grid.info.height == len(grid.data) and (grid.data == 100).any() and (grid.data == 0).any()
        dt = [b[0] - a[0] for a, b in zip(by["/scan"], by["/scan"][1:])]
        assert set(dt) == {100_000_000}  # the task's dt, 0.1 s
        end = by["/path"][0][1].poses[-1].pose
        goal = by["/goal"][0][1].pose.position
        dist = math.hypot(end.position.x - goal.x, end.position.y - goal.y)
        assert (dist < 0.3) == (info["outcome"] == "success")  # the goal tolerance
        o = by["/odom"][-1][1].pose.pose.orientation
        assert math.isfinite(quaternion_yaw(o.x, o.y, o.z, o.w))
        outcomes.append(info["outcome"])
    for k in ("success", "collision", "timeout"):
        assert outcomes.count(k) == out[k]["count"], (outcomes, k)


def test_replay_reproduces_the_recorded_commands(recorded, tmp_path):
    where, _ = recorded
    bag = where / "episode_000"
    csv_path = tmp_path / "cmd.csv"
    assert replay_bag.main([str(bag), "--policy", str(POLICY), "--out", str(csv_path)]) == 0
    rows = list(csv.DictReader(open(csv_path)))
    compared = [r for r in rows if r["bag_v"] != ""]
    assert len(compared) == len(rows) - 1 >= 5  # the last scan (the episode's end) has no recorded command
    for r in compared:  # same observation; the network on a batch of one rounds a little differently
        assert abs(float(r["v"]) - float(r["bag_v"])) < 1e-5 and abs(float(r["omega"]) - float(r["bag_omega"])) < 1e-5
    out_bag = tmp_path / "cmd_bag"
    assert replay_bag.main([str(bag), "--policy", str(POLICY), "--goal", "0", "0", "--out", str(out_bag)]) == 0
    cmds = read_messages(out_bag, ["/cmd_vel"])
    assert len(cmds) == len(rows) and all(math.isfinite(m.linear.x) for _, _, m in cmds)


def test_replay_names_bad_input(recorded, tmp_path, capsys):
    where, _ = recorded
    bag = where / "episode_000"
    assert replay_bag.main([str(bag), "--policy", str(POLICY), "--scan-topic", "/laser", "--out", str(tmp_path / "x.csv")]) == 2
    assert "no messages on --scan-topic /laser" in capsys.readouterr().err
    assert replay_bag.main([str(tmp_path / "missing"), "--policy", str(POLICY), "--out", str(tmp_path / "x.csv")]) == 2
    assert "bag not found" in capsys.readouterr().err
    dqn = ROOT / "checkpoints" / "dqn_course_actor.pt"
    assert replay_bag.main([str(bag), "--policy", str(dqn), "--out", str(tmp_path / "x.csv")]) == 2
    assert "not a navigation policy" in capsys.readouterr().err


def test_record_bag_refuses_other_tasks(capsys):
    sys.path.insert(0, str(ROOT / "recipes"))
    import evaluate

    with pytest.raises(SystemExit):
        evaluate.main([str(ROOT / "checkpoints" / "dqn_course_actor.pt"), "--episodes", "1", "--record-bag", "/nonexistent"])
    assert "--record-bag records navigation episodes" in capsys.readouterr().err


def test_replay_reads_a_ros1_bag(recorded, tmp_path):
    """The same episode as a ROS 1 bag (scan and odometry, converted with rosbags): the same commands."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    where, _ = recorded
    ros2 = where / "episode_000"
    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    ros1 = tmp_path / "episode.bag"
    with Writer(ros1) as w:
        conns = {t: w.add_connection(t, k, typestore=ts) for t, k in (("/scan", "sensor_msgs/msg/LaserScan"), ("/odom", "nav_msgs/msg/Odometry"))}
        for topic, t, m in read_messages(ros2, ["/scan", "/odom"]):
            h = T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=m.header.stamp.sec, nanosec=m.header.stamp.nanosec),
                                         frame_id=m.header.frame_id)
            if topic == "/scan":
                msg = T["sensor_msgs/msg/LaserScan"](header=h, angle_min=m.angle_min, angle_max=m.angle_max, angle_increment=m.angle_increment,
                                                     time_increment=0.0, scan_time=m.scan_time, range_min=m.range_min, range_max=m.range_max,
                                                     ranges=m.ranges, intensities=m.intensities)
            else:
                p, q, tw = m.pose.pose.position, m.pose.pose.orientation, m.twist.twist
                G = lambda n: T[f"geometry_msgs/msg/{n}"]  # noqa: E731
                msg = T["nav_msgs/msg/Odometry"](
                    header=h, child_frame_id="base_link",
                    pose=G("PoseWithCovariance")(pose=G("Pose")(position=G("Point")(x=p.x, y=p.y, z=0.0),
                                                                orientation=G("Quaternion")(x=q.x, y=q.y, z=q.z, w=q.w)), covariance=m.pose.covariance),
                    twist=G("TwistWithCovariance")(twist=G("Twist")(linear=G("Vector3")(x=tw.linear.x, y=0.0, z=0.0),
                                                                    angular=G("Vector3")(x=0.0, y=0.0, z=tw.angular.z)), covariance=m.twist.covariance))
            w.write(conns[topic], t, ts.serialize_ros1(msg, msg.__msgtype__))
    goal = read_messages(ros2, ["/goal"])[0][2].pose.position
    a, b = tmp_path / "ros1.csv", tmp_path / "ros2.csv"
    assert replay_bag.main([str(ros1), "--policy", str(POLICY), "--goal", str(goal.x), str(goal.y), "--out", str(a)]) == 0
    assert replay_bag.main([str(ros2), "--policy", str(POLICY), "--out", str(b)]) == 0
    r1, r2 = list(csv.DictReader(open(a))), list(csv.DictReader(open(b)))
    assert len(r1) == len(r2) > 5
    assert [(r["t"], r["v"], r["omega"]) for r in r1] == [(r["t"], r["v"], r["omega"]) for r in r2]


def test_the_map_grid_marks_every_wall_even_on_a_cell_boundary():
    """arena's walls (x, y = +-5 m) lie exactly on cell boundaries of a grid from -5.5 m at 0.05 m: each marks
    a full line of cells (with half a cell's distance, two of the four were lost to rounding)."""
    from torchnav.envs import make_nav_env

    env = make_nav_env("arena", num_envs=1)
    env.reset()
    cells, res, (x0, y0) = occupancy(env.state.world[0:1], (-5.5, -5.5, 5.5, 5.5))
    index = lambda v, o: int(round((v - o) / res))  # noqa: E731 - the cell boundary at v
    span = slice(index(-4.5, y0), index(4.5, y0))
    for x in (-5.0, 5.0):
        i = index(x, x0)
        assert (cells[span, i - 1 : i + 1] == 100).any(1).all(), f"wall x = {x}"
    for y in (-5.0, 5.0):
        j = index(y, y0)
        assert (cells[j - 1 : j + 1, span] == 100).any(0).all(), f"wall y = {y}"
