"""The ROS 1 nodes against a real roscore: policy_node drives sim_node's robot to goals, with the outcomes of
the in-process evaluation of the same episodes; bad inputs stop the robot with a named warning."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time
import xmlrpc.client
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parent.parent
POLICY = ROOT / "checkpoints" / "td3_arena_actor.pt"
ROS_PYTHON = "/usr/lib/python3/dist-packages"  # Debian's ROS 1 Python packages, after the project's own
INSTALL = "apt-get install ros-core python3-rospy python3-tf2-ros python3-sensor-msgs python3-nav-msgs python3-geometry-msgs"

pytestmark = pytest.mark.ros


def _env(port: int, home: Path) -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), ROS_PYTHON]), "ROS_MASTER_URI": f"http://127.0.0.1:{port}",
            "ROS_IP": "127.0.0.1", "ROS_HOME": str(home), "ROS_LOG_DIR": str(home / "log"), "PYTHONUNBUFFERED": "1"}


def _have_ros() -> bool:
    if shutil.which("roscore") is None:
        return False
    env = {**os.environ, "PYTHONPATH": ROS_PYTHON}
    return subprocess.run([sys.executable, "-c", "import rospy, tf2_ros, sensor_msgs.msg, nav_msgs.msg"], env=env,
                          capture_output=True).returncode == 0


if not _have_ros():
    pytest.skip(f"needs ROS 1 (roscore, rospy): {INSTALL}", allow_module_level=True)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def ros(tmp_path):
    """A roscore on a free port; yields (env for ROS processes, a function starting more of them); stops them all."""
    port = _free_port()
    env = _env(port, tmp_path)
    procs = []

    def start(*args: str) -> subprocess.Popen:
        log = open(tmp_path / f"proc{len(procs)}.log", "w")
        p = subprocess.Popen(list(args), env=env, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        procs.append((p, log))
        return p

    start("roscore", "-p", str(port))
    master = xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"])
    for _ in range(200):
        try:
            master.getSystemState("/test")
            break
        except OSError:
            time.sleep(0.1)
    else:
        pytest.fail("roscore did not start")
    yield env, start, tmp_path
    for p, log in reversed(procs):
        if p.poll() is None:
            os.killpg(p.pid, 2)  # SIGINT: roslaunch and the nodes shut down (the policy node publishes a stop)
    for p, log in reversed(procs):
        try:
            p.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, 9)
            p.wait()
        log.close()


CLIENT = r'''
import json, sys, time, rospy
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from std_msgs.msg import String
from torchnav.ros.convert import yaw_quaternion
episodes = json.loads(sys.argv[1])
rospy.init_node("torchnav_test_client")
last, policy = {}, []
rospy.Subscriber("/torchnav_sim/episode", String, lambda m: last.update(json.loads(m.data)))
rospy.Subscriber("/torchnav_policy/status", String, lambda m: policy.append(m.data))
start_pub = rospy.Publisher("/initialpose", PoseWithCovarianceStamped, queue_size=1, latch=True)
policy_goal = rospy.Publisher("/move_base_simple/goal", PoseStamped, queue_size=1)
sim_goal = rospy.Publisher("/torchnav_sim/goal", PoseStamped, queue_size=1)
deadline = time.time() + 60
while (min(p.get_num_connections() for p in (start_pub, policy_goal, sim_goal)) < 1 or not last or not policy) and time.time() < deadline:
    time.sleep(0.05)
out = []
for ep in episodes:
    (x, y, yaw), (gx, gy) = ep["start"], ep["goal"]
    m = PoseWithCovarianceStamped()
    m.header.frame_id = "map"
    m.pose.pose.position.x, m.pose.pose.position.y = x, y
    q = m.pose.pose.orientation
    q.x, q.y, q.z, q.w = yaw_quaternion(yaw)
    start_pub.publish(m)
    t = time.time()
    while last.get("status") != "ready" and time.time() - t < 20:
        time.sleep(0.02)
    n = last.get("episode")
    g = PoseStamped()
    g.header.frame_id, g.header.stamp = "map", rospy.Time.now()
    g.pose.position.x, g.pose.position.y, g.pose.orientation.w = gx, gy, 1.0
    # the policy takes the goal first: were the simulator's first scan of the episode to reach it before the goal,
    # it would act on that scan with the last episode's goal, and the lock-step simulator would step on that command
    k = len(policy)
    policy_goal.publish(g)
    t = time.time()
    while not any(s.startswith("goal (") for s in policy[k:]) and time.time() - t < 20:
        time.sleep(0.01)
    sim_goal.publish(g)
    t = time.time()
    while not (last.get("episode") == n + 1 and last.get("status") in ("success", "collision", "timeout")) and time.time() - t < 120:
        time.sleep(0.02)
    out.append({k: last.get(k) for k in ("status", "steps", "episode", "start", "goal")})
print("RESULT " + json.dumps(out), flush=True)
'''


def _episodes(n: int, seed: int = 20000, map: str | None = None) -> list[dict]:
    """The starts and goals of ``n`` evaluation episodes of the arena policy (on ``map``: another map)."""
    from torchnav.envs import NavEnv
    from torchnav.evaluation import eval_config
    from torchnav.policy import load_policy

    td = NavEnv(eval_config(load_policy(POLICY).config(), map=map, anywhere=True), num_envs=n, seed=seed).reset()
    return [{"start": td["pose"][k].tolist(), "goal": td["goal"][k].tolist()} for k in range(n)]


def _in_process(got: list[dict], seed: int = 20000, map: str | None = None) -> list[dict]:
    """The in-process evaluation of the episodes the simulator node played (the start it reports: the heading came
    through a quaternion), each as the node plays it: one episode in a fresh env of the seed (``run_episodes``)."""
    from torchnav.evaluation import eval_config, run_episodes
    from torchnav.policy import load_policy

    sp = load_policy(POLICY)
    cfg = eval_config(sp.config(), map=map, anywhere=True)
    want = []
    for g in got:
        res = run_episodes(sp.policy, cfg, 1, seed=seed, given=(torch.tensor([g["start"]]), torch.tensor([g["goal"]])))
        status = "success" if bool(res["success"][0]) else "collision" if bool(res["collision"][0]) else "timeout"
        want.append({"status": status, "steps": int(res["length"][0])})
    return want


def _loop(ros, n: int, map: str | None = None) -> tuple[list[dict], list[dict]]:
    """``n`` episodes through the lock-step simulator node and the policy node, on the policy's map or ``map``:
    (theirs, the in-process ones)."""
    env, start, tmp = ros
    py = sys.executable
    start(py, "-m", "torchnav.ros.sim_node", f"_policy:={POLICY}", "_lockstep:=true", "_goal_topic:=/torchnav_sim/goal", "__name:=torchnav_sim",
          *([f"_map:={map}"] if map else []))
    start(py, "-m", "torchnav.ros.policy_node", f"_policy:={POLICY}", "_trigger:=scan", "__name:=torchnav_policy")
    out = subprocess.run([py, "-c", CLIENT, json.dumps(_episodes(n, map=map))], env=env, cwd=ROOT, capture_output=True, text=True, timeout=300 + 90 * n)
    result = [line for line in out.stdout.splitlines() if line.startswith("RESULT ")]
    logs = "\n".join(p.read_text()[-3000:] for p in sorted(tmp.glob("proc*.log")))
    assert result, f"client failed:\n{out.stdout[-2000:]}\n{out.stderr[-3000:]}\n{logs}"
    got = json.loads(result[0][len("RESULT "):])
    assert [g["episode"] for g in got] == list(range(1, n + 1)), got
    return got, _in_process(got, map=map)


def _same(got: list[dict], want: list[dict]) -> None:
    """The same outcome in every episode, and the same length up to 2 steps: the odometry's heading reaches the
    policy through a quaternion, which may move it by one float32 rounding step (most episodes match exactly)."""
    assert [g["status"] for g in got] == [w["status"] for w in want], (got, want)
    assert all(abs(g["steps"] - w["steps"]) <= 2 for g, w in zip(got, want)), (got, want)


def test_policy_node_drives_sim_node_to_the_goals(ros):
    got, want = _loop(ros, 3)
    _same(got, want)
    assert any(w["status"] == "success" for w in want)


@pytest.mark.slow
@pytest.mark.parametrize("map", [None, "street"])
def test_twenty_episodes_as_the_in_process_evaluation(ros, map):
    """The long check: 20 evaluation episodes through both nodes, on the policy's map (arena) and on another,
    each with the in-process outcome and length."""
    got, want = _loop(ros, 20, map)
    _same(got, want)
    print("episodes of the same length:", sum(g["steps"] == w["steps"] for g, w in zip(got, want)), "of 20")


BAD = r'''
import json, math, sys, time, rospy
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Odometry
from sensor_msgs.msg import LaserScan
from std_msgs.msg import String
rospy.init_node("torchnav_bad_inputs")
statuses, cmds = [], []
rospy.Subscriber("/torchnav_policy/status", String, lambda m: statuses.append(m.data))
rospy.Subscriber("/cmd_vel", Twist, lambda m: cmds.append((m.linear.x, m.angular.z)))
scan_pub = rospy.Publisher("/scan", LaserScan, queue_size=1)
odom_pub = rospy.Publisher("/odom", Odometry, queue_size=1)
goal_pub = rospy.Publisher("/move_base_simple/goal", PoseStamped, queue_size=1)
t = time.time()
while min(p.get_num_connections() for p in (scan_pub, odom_pub, goal_pub)) < 1 and time.time() - t < 60:
    time.sleep(0.05)
while not statuses and time.time() - t < 60:
    time.sleep(0.05)

def scan():  # a 360-beam scan from straight ahead (not the policy's 20 rays over 180 degrees), with NaN and inf
    m = LaserScan()
    m.header.stamp, m.header.frame_id = rospy.Time.now(), "base_scan"
    m.angle_min, m.angle_increment, m.range_min, m.range_max = 0.0, 2 * math.pi / 360, 0.12, 3.5
    m.ranges = [math.nan if i % 7 == 0 else math.inf if i % 5 == 0 else 3.0 for i in range(360)]
    scan_pub.publish(m)

def odom(x=0.0):
    m = Odometry()
    m.header.stamp, m.header.frame_id, m.child_frame_id = rospy.Time.now(), "odom", "base_footprint"
    m.pose.pose.position.x, m.pose.pose.orientation.w = x, 1.0
    odom_pub.publish(m)

def goal(frame):
    m = PoseStamped()
    m.header.stamp, m.header.frame_id = rospy.Time.now(), frame
    m.pose.position.x, m.pose.orientation.w = 3.0, 1.0
    goal_pub.publish(m)

def run(seconds, with_scan=True, with_odom=True, x=0.0):
    t = time.time()
    while time.time() - t < seconds:
        if with_odom:
            odom(x)
        if with_scan:
            scan()
        time.sleep(0.05)

out = {}
run(0.5)
goal("base_link")  # no tf is published: refused
run(1.0)
out["refused"] = [s for s in statuses if "goal refused" in s]
goal("odom")
run(1.5)
out["driving"] = "driving" in statuses
out["moving"] = [c for c in cmds[-5:] if c != (0.0, 0.0)]
run(1.5, with_odom=False)
out["stale"] = statuses[-1]
out["stale_cmd"] = cmds[-1]
run(1.0, x=math.nan)
out["nan"] = statuses[-1]
out["nan_cmd"] = cmds[-1]
print("RESULT " + json.dumps(out), flush=True)
run(1.0)
print("DRIVING " + json.dumps(cmds[-1]), flush=True)  # the test stops the node now
t = time.time()
while time.time() - t < 30:
    n = len(cmds)
    run(1.0)
    if len(cmds) == n:  # no command for a second: the node is gone
        break
print("LAST " + json.dumps(cmds[-1]), flush=True)
'''


def test_bad_inputs_stop_the_robot_with_a_named_reason(ros):
    env, start, tmp = ros
    node = start(sys.executable, "-m", "torchnav.ros.policy_node", f"_policy:={POLICY}", "_stale_timeout:=0.5", "__name:=torchnav_policy")
    client = subprocess.Popen([sys.executable, "-c", BAD], env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines, alive = [], False
    for line in client.stdout:
        lines.append(line.strip())
        if line.startswith("DRIVING "):
            alive = node.poll() is None
            os.killpg(node.pid, 2)  # Ctrl-C: the node's last command must be a stop
    client.wait(timeout=120)
    log = (tmp / "proc1.log").read_text()
    result = [line for line in lines if line.startswith("RESULT ")]
    assert result, f"{client.stderr.read()[-3000:]}\n{log[-3000:]}"
    got = json.loads(result[0][len("RESULT "):])
    assert got["refused"] and "frame 'base_link'" in got["refused"][0], got
    assert got["driving"] and got["moving"], got  # a scan of another layout, with NaN and inf, drives
    assert all(abs(v) <= 1.0 and abs(w) <= 1.0 for v, w in got["moving"])  # the policy's limits
    assert got["stale"].startswith("stopped: stale odometry") and got["stale_cmd"] == [0.0, 0.0], got
    assert "pose must be 3 finite numbers" in got["nan"] and got["nan_cmd"] == [0.0, 0.0], got
    assert alive  # every bad input above was survived
    driving = json.loads(next(line for line in lines if line.startswith("DRIVING "))[len("DRIVING "):])
    last = json.loads(next(line for line in lines if line.startswith("LAST "))[len("LAST "):])
    assert driving != [0.0, 0.0] and last == [0.0, 0.0], (driving, last)
    assert "Traceback" not in log, log[-3000:]
