"""Navigation episodes as ROS 2 bags: MCAP storage, CDR-encoded standard messages (``rosbags``).

Each recorded episode becomes one bag directory (``metadata.yaml`` and an ``.mcap`` file) that
``ros2 bag play``, Foxglove, RViz (through ``ros2 bag play``) and :mod:`torchnav.ros.replay_bag` read:

==========================  ============================  =====================================================
topic                       type                          content
==========================  ============================  =====================================================
``/scan``                   sensor_msgs/msg/LaserScan     the lidar at every step, frame ``laser`` (the simulator's layout)
``/odom``                   nav_msgs/msg/Odometry         odometry pose and the driven twist, ``odom`` -> ``base_link``
``/cmd_vel``                geometry_msgs/msg/Twist       the twist driven over each step (policy, speed guard, limits)
``/tf``                     tf2_msgs/msg/TFMessage        ``map`` -> ``odom`` (the odometry's drift) and ``odom`` -> ``base_link``
``/tf_static``              tf2_msgs/msg/TFMessage        ``base_link`` -> ``laser`` (the lidar's mount)
``/map``                    nav_msgs/msg/OccupancyGrid    the episode's fixed obstacles, frame ``map``, once at the start
``/goal``                   geometry_msgs/msg/PoseStamped the goal, frame ``map``, once at the start
``/path``                   nav_msgs/msg/Path             the true path driven, frame ``map``, once at the end
``/torchnav/episode``       std_msgs/msg/String           JSON: seed, checkpoint, outcome, steps, at the end
==========================  ============================  =====================================================

Stamps start at 1 s and advance by the task's ``dt``; the message stamps are the bag's times.
The odometry starts at the true start pose, so without odometry noise ``odom`` and ``map`` coincide.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np
import torch

from ..observation import Scan
from ..sim.geometry import points_clearance
from .convert import relative, yaw_quaternion

T0_NS = 1_000_000_000  # ns, the first stamp (a zero stamp reads as "no time" to many ROS tools)
INSTALL = "pip install 'torchnav[ros]' (rosbags==0.11.9)"
TOPICS = {
    "/scan": "sensor_msgs/msg/LaserScan", "/odom": "nav_msgs/msg/Odometry", "/cmd_vel": "geometry_msgs/msg/Twist",
    "/tf": "tf2_msgs/msg/TFMessage", "/tf_static": "tf2_msgs/msg/TFMessage", "/map": "nav_msgs/msg/OccupancyGrid",
    "/goal": "geometry_msgs/msg/PoseStamped", "/path": "nav_msgs/msg/Path", "/torchnav/episode": "std_msgs/msg/String",
}


def typestore():
    """The ROS 2 Humble message types of ``rosbags``; ``ImportError`` with the install command without it."""
    try:
        from rosbags.typesys import Stores, get_typestore
    except ImportError as e:
        raise ImportError(f"torchnav.ros.bag needs rosbags: {INSTALL}") from e
    return get_typestore(Stores.ROS2_HUMBLE)


def occupancy(world: Any, bounds: tuple[float, float, float, float], resolution: float = 0.05, max_cells: int = 1_000_000
              ) -> tuple[np.ndarray, float, tuple[float, float]]:
    """The obstacles of a one-env ``World`` as an occupancy grid over ``bounds`` ``(xmin, ymin, xmax, ymax)`` m:
    ``(cells (H, W) int8, 100 occupied / 0 free, row 0 at ymin; resolution m; origin (x, y) m)``. A cell is
    occupied when an obstacle touches it (lies within half a cell's diagonal of its centre: a thin wall on
    a cell boundary marks the cells on both sides); the resolution grows past ``max_cells`` cells."""
    xmin, ymin, xmax, ymax = bounds
    res = max(resolution, math.sqrt((xmax - xmin) * (ymax - ymin) / max_cells))
    w, h = max(1, math.ceil((xmax - xmin) / res)), max(1, math.ceil((ymax - ymin) / res))
    xs = xmin + res * (torch.arange(w, dtype=torch.float32) + 0.5)
    ys = ymin + res * (torch.arange(h, dtype=torch.float32) + 0.5)
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    pts = torch.stack((gx.reshape(-1), gy.reshape(-1)), -1)[None].to(world.segments.dtype)
    clear = points_clearance(pts, world)[0].reshape(h, w)
    return np.where((clear <= 0.5 * math.sqrt(2.0) * res).numpy(), 100, 0).astype(np.int8), res, (xmin, ymin)


def world_bounds(world: Any, points: np.ndarray, margin: float = 0.5) -> tuple[float, float, float, float]:
    """A box around a one-env ``World``'s valid obstacles and ``points`` ``(P, 2)`` (the path and goal), ``margin`` m wider."""
    xs, ys = [points[:, 0]], [points[:, 1]]
    seg = world.segments[0][world.segment_mask[0]].numpy()
    xs += [seg[:, 0], seg[:, 2]]
    ys += [seg[:, 1], seg[:, 3]]
    c = world.circles[0][world.circle_mask[0]].numpy()
    xs += [c[:, 0] - c[:, 2], c[:, 0] + c[:, 2]]
    ys += [c[:, 1] - c[:, 2], c[:, 1] + c[:, 2]]
    b = world.boxes[0][world.box_mask[0]].numpy()
    reach = np.hypot(b[:, 2], b[:, 3])
    xs += [b[:, 0] - reach, b[:, 0] + reach]
    ys += [b[:, 1] - reach, b[:, 1] + reach]
    x, y = np.concatenate(xs), np.concatenate(ys)
    return float(x.min()) - margin, float(y.min()) - margin, float(x.max()) + margin, float(y.max()) + margin


class Messages:
    """Builders of the bag's messages from plain numbers (ROS 2 Humble types of ``rosbags``)."""

    def __init__(self, ts: Any = None) -> None:
        self.ts = ts or typestore()
        self.T = self.ts.types

    def stamp(self, t_ns: int) -> Any:
        return self.T["builtin_interfaces/msg/Time"](sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))

    def header(self, t_ns: int, frame: str) -> Any:
        return self.T["std_msgs/msg/Header"](stamp=self.stamp(t_ns), frame_id=frame)

    def pose(self, x: float, y: float, yaw: float) -> Any:
        qx, qy, qz, qw = yaw_quaternion(yaw)
        return self.T["geometry_msgs/msg/Pose"](position=self.T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
                                                orientation=self.T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))

    def vector(self, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Any:
        return self.T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))

    def twist(self, v: float, omega: float) -> Any:
        return self.T["geometry_msgs/msg/Twist"](linear=self.vector(v), angular=self.vector(z=omega))

    def scan(self, t_ns: int, scan: Scan, frame: str = "laser", scan_time: float = 0.0) -> Any:
        ranges = np.asarray(scan.ranges, dtype=np.float32)
        return self.T["sensor_msgs/msg/LaserScan"](
            header=self.header(t_ns, frame), angle_min=float(scan.angle_min),
            angle_max=float(scan.angle_min + scan.angle_increment * (len(ranges) - 1)), angle_increment=float(scan.angle_increment),
            time_increment=0.0, scan_time=float(scan_time), range_min=float(scan.range_min), range_max=float(scan.range_max),
            ranges=ranges, intensities=np.zeros(0, dtype=np.float32))

    def odometry(self, t_ns: int, x: float, y: float, yaw: float, v: float, omega: float, frame: str = "odom", child: str = "base_link") -> Any:
        T = self.T
        return T["nav_msgs/msg/Odometry"](
            header=self.header(t_ns, frame), child_frame_id=child,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=self.pose(x, y, yaw), covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=self.twist(v, omega), covariance=np.zeros(36)))

    def transform(self, t_ns: int, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
        T = self.T
        qx, qy, qz, qw = yaw_quaternion(yaw)
        return T["geometry_msgs/msg/TransformStamped"](
            header=self.header(t_ns, parent), child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](translation=self.vector(x, y), rotation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)))

    def tf(self, transforms: list) -> Any:
        return self.T["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def pose_stamped(self, t_ns: int, frame: str, x: float, y: float, yaw: float = 0.0) -> Any:
        return self.T["geometry_msgs/msg/PoseStamped"](header=self.header(t_ns, frame), pose=self.pose(x, y, yaw))

    def path(self, t_ns: int, frame: str, poses: Iterable[tuple[int, float, float, float]]) -> Any:
        return self.T["nav_msgs/msg/Path"](header=self.header(t_ns, frame), poses=[self.pose_stamped(t, frame, x, y, a) for t, x, y, a in poses])

    def grid(self, t_ns: int, frame: str, cells: np.ndarray, resolution: float, origin: tuple[float, float]) -> Any:
        T = self.T
        h, w = cells.shape
        info = T["nav_msgs/msg/MapMetaData"](map_load_time=self.stamp(t_ns), resolution=float(resolution), width=w, height=h,
                                             origin=self.pose(origin[0], origin[1], 0.0))
        return T["nav_msgs/msg/OccupancyGrid"](header=self.header(t_ns, frame), info=info, data=cells.reshape(-1))

    def string(self, text: str) -> Any:
        return self.T["std_msgs/msg/String"](data=text)


def write_episode(path: str | Path, episode: Mapping[str, Any], lidar: Any, dt: float, metadata: Mapping[str, Any] | None = None,
                  overwrite: bool = True) -> Path:
    """Write one episode as a ROS 2 bag directory at ``path`` (see the module docstring).

    ``episode``: ``pose``, ``odom`` ``(T + 1, 3)`` (the start, then after each step), ``vel`` ``(T + 1, 2)``
    (the twist driven over the step that ended there; zeros at the start), ``ranges`` ``(T + 1, R)`` in
    ``lidar``'s layout, ``goal`` ``(2,)``, ``world`` (a one-env ``World``), ``outcome`` (``"success"``,
    ``"collision"`` or ``"timeout"``). An existing bag at ``path`` is replaced (``overwrite``) or refused."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = Path(path)
    if path.exists():
        if not overwrite:
            raise FileExistsError(f"{path}: a bag is already there")
        shutil.rmtree(path) if path.is_dir() else path.unlink()
    path.parent.mkdir(parents=True, exist_ok=True)
    m = Messages()
    pose, odom, vel, ranges = (np.asarray(episode[k], dtype=np.float64) for k in ("pose", "odom", "vel", "ranges"))
    goal = np.asarray(episode["goal"], dtype=np.float64)
    steps = len(pose) - 1
    t = [T0_NS + round(k * dt * 1e9) for k in range(steps + 1)]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {topic: w.add_connection(topic, kind, typestore=m.ts) for topic, kind in TOPICS.items()}

        def put(topic: str, t_ns: int, msg: Any) -> None:
            w.write(conns[topic], t_ns, m.ts.serialize_cdr(msg, TOPICS[topic]))

        ox, oy, oyaw = lidar.offset
        put("/tf_static", t[0], m.tf([m.transform(t[0], "base_link", "laser", ox, oy, oyaw)]))
        cells, res, origin = occupancy(episode["world"], world_bounds(episode["world"], np.concatenate((pose[:, :2], goal[None]))))
        put("/map", t[0], m.grid(t[0], "map", cells, res, origin))
        put("/goal", t[0], m.pose_stamped(t[0], "map", goal[0], goal[1]))
        for k in range(steps + 1):
            put("/tf", t[k], m.tf([m.transform(t[k], "map", "odom", *relative(tuple(pose[k]), tuple(odom[k]))),
                                   m.transform(t[k], "odom", "base_link", *odom[k])]))
            put("/odom", t[k], m.odometry(t[k], *odom[k], *vel[k]))
            put("/scan", t[k], m.scan(t[k], Scan.of_sim(ranges[k].astype(np.float32), lidar), scan_time=dt))
            if k < steps:
                put("/cmd_vel", t[k], m.twist(*vel[k + 1]))
        put("/path", t[-1], m.path(t[-1], "map", [(t[k], *pose[k]) for k in range(steps + 1)]))
        info = {**(metadata or {}), "outcome": episode["outcome"], "steps": steps, "dt": dt, "goal": goal.tolist()}
        put("/torchnav/episode", t[-1], m.string(json.dumps(info)))
    return path


class BagRecorder:
    """Record the first episode of each of an env's envs as a ROS 2 bag, ``DIR/episode_000`` on
    (:func:`write_episode`): a recorder of ``torchnav.evaluation.record_with`` (``recipes/evaluate.py
    --record-bag DIR``), as ``EpisodeRecorder`` is for MCAP files. A failed write sets :attr:`error`
    (the evaluation's figures are printed already) and stops recording."""

    def __init__(self, directory: str | Path, env: Any, metadata: Mapping[str, Any] | None = None) -> None:
        typestore()  # rosbags missing: named now, before any episode runs
        if getattr(env, "n_robots", None) is not None or not hasattr(env.task, "goal_vector"):
            raise ValueError("BagRecorder records navigation envs (NavEnv) of one robot")
        self.directory, self.env, self.metadata = Path(directory), env, dict(metadata or {})
        self.lidar, self.dt = env.task.params.lidar, env.task.params.dt
        self.steps: dict[int, dict[str, list]] = {}
        self.written: list[Path] = []
        self.done = torch.zeros(env.num_envs, dtype=torch.bool)
        self.error: str | None = None

    @property
    def finished(self) -> bool:
        return bool(self.done.all()) or self.error is not None

    def write_step(self, td: Any, state: Any, before: Any = None) -> None:
        """One env step ``(B,)`` (root keys before it, ``"next"`` after it) and the state right after it."""
        if self.finished:
            return
        nxt = td.get("next")
        done = nxt.get("done").reshape(-1).cpu()
        for e in (~self.done).nonzero().flatten().tolist():
            rec = self.steps.get(e)
            if rec is None:  # the episode's start: the state before this step
                s = before.sim[e].cpu() if before is not None else None
                rec = self.steps[e] = {
                    "pose": [td.get("pose")[e].cpu().numpy()], "ranges": [td.get("ranges")[e].cpu().numpy()],
                    "odom": [(s.odom if s is not None else td.get("pose")[e]).cpu().numpy()],
                    "vel": [(s.vel if s is not None else torch.zeros(2)).cpu().numpy()], "goal": td.get("goal")[e].cpu().numpy(),
                    "world": state.world[e:e + 1].cpu(),
                }
            sim = state.sim[e].cpu()
            rec["pose"].append(sim.pose.numpy())
            rec["odom"].append(sim.odom.numpy())
            rec["vel"].append(sim.vel.numpy())
            rec["ranges"].append(sim.ranges.numpy())
            if bool(done[e]):
                self.done[e] = True
                outcome = "success" if bool(nxt.get("success")[e]) else "collision" if bool(nxt.get("collision")[e]) else "timeout"
                self._write(e, {**rec, "outcome": outcome})

    def _write(self, e: int, rec: dict[str, Any]) -> None:
        path = self.directory / f"episode_{e:03d}"
        try:
            write_episode(path, {k: np.stack(v) if isinstance(v, list) else v for k, v in rec.items()}, self.lidar, self.dt,
                          {**self.metadata, "env": e})
        except Exception as ex:  # noqa: BLE001 - reported, the evaluation's results stand
            self.error = f"{path}: {type(ex).__name__}: {ex}"
            return
        self.written.append(path)
        del self.steps[e]

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self) -> "BagRecorder":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def read_messages(path: str | Path, topics: Iterable[str] | None = None) -> list[tuple[str, int, Any]]:
    """Every message of the bag at ``path`` (ROS 1 ``.bag`` or ROS 2 directory, through ``rosbags``' AnyReader) on
    ``topics`` (all when None), in time order: ``(topic, t_ns, message)``."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError as e:
        raise ImportError(f"reading bags needs rosbags: {INSTALL}") from e
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"bag not found: {path}")
    out = []
    with AnyReader([path], default_typestore=typestore()) as reader:
        wanted = None if topics is None else set(topics)
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for conn, t_ns, raw in reader.messages(connections=conns):
            out.append((conn.topic, t_ns, reader.deserialize(raw, conn.msgtype)))
    return out


__all__ = ["BagRecorder", "Messages", "TOPICS", "occupancy", "read_messages", "typestore", "world_bounds", "write_episode"]
