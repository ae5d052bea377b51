#!/usr/bin/env bash
# The picture in docs/ros.md: RViz (docs/torchnav.rviz) on the ROS bridge's topics while policy_node drives
# sim_node's robot across arena, on a virtual display.
#     bash docs/scripts/ros_rviz_picture.sh [OUT.png]      # default docs/img/ros_rviz.png
# Needs Debian's ROS 1 (docs/ros.md), rviz, Xvfb and ImageMagick's import:
#     apt-get install rviz xvfb imagemagick
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
OUT="$(realpath -m "${1:-$ROOT/docs/img/ros_rviz.png}")"
for cmd in roscore rviz Xvfb import; do
    command -v "$cmd" >/dev/null || { echo "needs $cmd: apt-get install ros-core python3-rospy python3-tf2-ros rviz xvfb imagemagick" >&2; exit 2; }
done
PY="${PYTHON:-$ROOT/.venv/bin/python}"
TMP="$(mktemp -d)"
PORT=$("$PY" -c "import socket; s = socket.socket(); s.bind(('127.0.0.1', 0)); print(s.getsockname()[1])")
export ROS_MASTER_URI="http://127.0.0.1:$PORT" ROS_IP=127.0.0.1 ROS_HOME="$TMP" ROS_LOG_DIR="$TMP/log"
export PYTHONPATH="$ROOT:/usr/lib/python3/dist-packages" DISPLAY=":$((PORT % 1000 + 100))" LIBGL_ALWAYS_SOFTWARE=1
POLICY="$ROOT/checkpoints/td3_arena_actor.pt"
PIDS=()
cleanup() { kill "${PIDS[@]}" 2>/dev/null || true; wait 2>/dev/null || true; rm -rf "$TMP"; }
trap cleanup EXIT
Xvfb "$DISPLAY" -screen 0 1400x900x24 >"$TMP/xvfb.log" 2>&1 & PIDS+=($!)
roscore -p "$PORT" >"$TMP/roscore.log" 2>&1 & PIDS+=($!)
"$PY" -c "
import time, xmlrpc.client
for _ in range(100):
    try:
        xmlrpc.client.ServerProxy('$ROS_MASTER_URI').getSystemState('/x'); break
    except OSError:
        time.sleep(0.1)"
cd "$ROOT"
"$PY" -m torchnav.ros.sim_node _policy:="$POLICY" __name:=torchnav_sim >"$TMP/sim.log" 2>&1 & PIDS+=($!)
"$PY" -m torchnav.ros.policy_node _policy:="$POLICY" __name:=torchnav_policy >"$TMP/policy.log" 2>&1 & PIDS+=($!)
rviz -d "$ROOT/docs/torchnav.rviz" >"$TMP/rviz.log" 2>&1 & PIDS+=($!)
# a start and a goal as RViz's "2D Pose Estimate" and "2D Nav Goal" send them; the picture 3 s into the episode
"$PY" - <<'PYEOF'
import time, rospy
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from std_msgs.msg import String
rospy.init_node("picture_client")
status = []
rospy.Subscriber("/torchnav_policy/status", String, lambda m: status.append(m.data))
start = rospy.Publisher("/initialpose", PoseWithCovarianceStamped, queue_size=1, latch=True)
goal = rospy.Publisher("/move_base_simple/goal", PoseStamped, queue_size=1, latch=True)
t = time.time()
while (start.get_num_connections() < 1 or goal.get_num_connections() < 3 or not status) and time.time() - t < 60:
    time.sleep(0.1)  # sim_node, policy_node and RViz's goal display subscribe
time.sleep(3)  # RViz draws its first frames
m = PoseWithCovarianceStamped()
m.header.frame_id = "map"
m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.orientation.w = -3.5, -3.5, 1.0
start.publish(m)
time.sleep(1)
g = PoseStamped()
g.header.frame_id, g.header.stamp = "map", rospy.Time.now()
g.pose.position.x, g.pose.position.y, g.pose.orientation.w = 3.5, 3.0, 1.0
goal.publish(g)
time.sleep(3)
PYEOF
import -window root "$OUT"
echo "wrote $OUT"
