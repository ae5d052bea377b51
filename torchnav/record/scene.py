"""Per-env message encoding: one ``EnvStream`` turns one env's steps into JSON messages.

Kept free of tensors: it receives numpy rows of one step of one env (see
``EpisodeRecorder._select`` for the keys). The static part of the scene (walls,
boxes, circles, goal) is encoded once per episode and spliced into every step's
``SceneUpdate``, so a step costs a handful of small ``json.dumps``. ``MultiEnvStream`` does the
same for an env of several robots, with the per-robot pieces (transforms, scan, disc, trail,
odometry) built by the same functions.
"""

from __future__ import annotations

import base64
import json
import math
from typing import Any

import numpy as np

WALL_HEIGHT = 0.5  # m, only for the 3D view
ROOT_FRAME = "world"  # parent of every recorded env's env<i>/world
ENV_SPACING = 30.0  # m between the recorded envs' worlds along x under ROOT_FRAME
ROBOT_HEIGHT = 0.25  # m
COLORS = {
    "wall": (0.25, 0.25, 0.25, 1.0), "box": (0.55, 0.55, 0.55, 1.0), "circle": (0.55, 0.55, 0.55, 1.0),
    "goal": (0.2, 0.75, 0.3, 0.6), "robot": (0.12, 0.47, 0.71, 1.0), "trail": (0.12, 0.47, 0.71, 0.8),
    "arrow": (0.0, 0.0, 0.0, 1.0), "estimate": (0.96, 0.62, 0.0, 1.0), "mover": (0.82, 0.24, 0.24, 1.0),
}
MOVER_HEIGHT = 1.0  # m, only for the 3D view
_SHARED = {"odom_estimate": "odom", "camera_depth": "camera"}  # topics that use another topic's schema
_EMPTY = {"arrows": [], "cubes": [], "spheres": [], "cylinders": [], "lines": [], "triangles": [], "texts": [], "models": []}


def stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def color(name: str) -> dict:
    r, g, b, a = COLORS[name]
    return {"r": r, "g": g, "b": b, "a": a}


def pose(x: float, y: float, yaw: float = 0.0, z: float = 0.0) -> dict:
    return {"position": {"x": x, "y": y, "z": z}, "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}}


def _f(x: Any) -> float:
    return round(float(x), 6)


def _rows(a: np.ndarray, mask: np.ndarray) -> list[list[float]]:
    return np.round(a[mask].astype(np.float64), 6).tolist()


def line_list(segments: Any, thickness: float, rgba: tuple[float, float, float, float], z: float = 0.001) -> dict:
    """A Foxglove LinePrimitive (LINE_LIST) drawing segments ``(S, 4)`` ``[x1, y1, x2, y2]`` (m) on the floor."""
    seg = np.round(np.asarray(segments, dtype=np.float64).reshape(-1, 4), 6).tolist()
    pts = [{"x": x, "y": y, "z": z} for s in seg for x, y in ((s[0], s[1]), (s[2], s[3]))]
    r, g, b, a = rgba
    return {"type": 2, "pose": pose(0.0, 0.0), "thickness": float(thickness), "scale_invariant": False, "points": pts,
            "color": {"r": r, "g": g, "b": b, "a": a}, "colors": [], "indices": []}


def cylinder(x: float, y: float, diameter: float, height: float, name: str, yaw: float = 0.0) -> dict:
    """A Foxglove CylinderPrimitive standing on the floor, coloured ``COLORS[name]``."""
    return {"pose": pose(x, y, yaw, height / 2), "size": {"x": diameter, "y": diameter, "z": height},
            "bottom_scale": 1.0, "top_scale": 1.0, "color": color(name)}


def cube(x: float, y: float, half_x: float, half_y: float, yaw: float, height: float, name: str) -> dict:
    """A Foxglove CubePrimitive: an oriented box standing on the floor, coloured ``COLORS[name]``."""
    return {"pose": pose(x, y, yaw, height / 2), "size": {"x": 2 * half_x, "y": 2 * half_y, "z": height}, "color": color(name)}


def _is_box(movers: np.ndarray) -> np.ndarray:
    """Which recorded mover rows (``mover_rows``) are boxes: those with a half extent."""
    return (movers[:, 6] > 0) | (movers[:, 7] > 0) if movers.shape[1] > 6 else np.zeros(len(movers), dtype=bool)


def entity(ns: int, frame: str, ident: str, **prims: list) -> dict:
    return {"timestamp": stamp(ns), "frame_id": frame, "id": ident, "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False, "metadata": [], **_EMPTY, **prims}


ROBOT_PALETTE = ((0.12, 0.47, 0.71), (1.0, 0.5, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16), (0.58, 0.4, 0.74),
                 (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.5, 0.5, 0.5), (0.74, 0.74, 0.13), (0.09, 0.75, 0.81))  # robot j: j % 10


def robot_rgba(j: int, alpha: float = 1.0) -> dict:
    """Robot ``j``'s colour in a multi-robot scene (robot 0 has the single robot's)."""
    r, g, b = ROBOT_PALETTE[j % len(ROBOT_PALETTE)]
    return {"r": r, "g": g, "b": b, "a": alpha}


def transforms(ts: dict, frame: str, base: str, laser: str, x: float, y: float, yaw: float, laser_tf: tuple) -> list[dict]:
    """The ``frame`` -> ``base`` (the robot's pose) and ``base`` -> ``laser`` (``lidar.offset``) transforms."""
    ox, oy, oyaw = laser_tf
    return [
        {"timestamp": ts, "parent_frame_id": frame, "child_frame_id": base,
         "translation": {"x": x, "y": y, "z": 0.0}, "rotation": pose(0, 0, yaw)["orientation"]},
        {"timestamp": ts, "parent_frame_id": base, "child_frame_id": laser,
         "translation": {"x": ox, "y": oy, "z": ROBOT_HEIGHT}, "rotation": pose(0, 0, oyaw)["orientation"]},
    ]


def scan_head(laser: str, lidar: Any) -> dict:
    """The fixed part of a ``foxglove.LaserScan`` in frame ``laser`` (the lidar's first and last ray angles)."""
    ang = lidar.angles()
    return {"frame_id": laser, "pose": pose(0.0, 0.0), "start_angle": ang[0], "end_angle": ang[-1]}


def laser_scan(ts: dict, head: dict, ranges: np.ndarray) -> dict:
    return {"timestamp": ts, **head, "ranges": np.round(ranges.astype(np.float64), 5).tolist(), "intensities": []}


def robot_entity(t: int, frame: str, ident: str, x: float, y: float, yaw: float, radius: float, rgba: dict) -> dict:
    """A robot disc of ``radius`` m with its heading arrow."""
    return entity(t, frame, ident, cylinders=[{**cylinder(x, y, 2 * radius, ROBOT_HEIGHT, "robot", yaw), "color": rgba}], arrows=[{
        "pose": pose(x, y, yaw, ROBOT_HEIGHT + 0.01), "shaft_length": radius, "shaft_diameter": 0.04,
        "head_length": 0.1, "head_diameter": 0.1, "color": color("arrow")}])


def odometry(ts: dict, frame: str, body: str, at: dict, vel: tuple[float, float]) -> dict:
    """A ``foxglove.Odometry``: the pose ``at`` of ``body`` in ``frame`` with the twist ``vel`` (m/s, rad/s)."""
    return {"timestamp": ts, "frame_id": frame, "body_frame_id": body, "pose": at,
            "linear_velocity": {"x": _f(vel[0]), "y": 0.0, "z": 0.0}, "angular_velocity": {"x": 0.0, "y": 0.0, "z": _f(vel[1])},
            "pose_covariance": [0.0] * 36, "velocity_covariance": [0.0] * 36, "metadata": []}


class Trail:
    """One robot's path so far, as JSON points: every ``stride``-th step, halving the resolution when it grows too long."""

    MAX = 256  # points; longer trails keep every 2nd, 4th, ... point

    def __init__(self) -> None:
        self.points: list[str] = []
        self.stride = 1

    def add(self, x: float, y: float, step: int) -> None:
        if step % self.stride == 0:
            self.points.append(f'{{"x":{x},"y":{y},"z":0.02}}')
            if len(self.points) > self.MAX:
                self.points, self.stride = self.points[::2], self.stride * 2

    def entity(self, t: int, frame: str, ident: str, x: float, y: float, rgba: dict) -> str:
        """The trail as a LINE_STRIP entity (JSON) ending at the robot's current point ``(x, y)``."""
        last = f'{{"x":{x},"y":{y},"z":0.02}}'
        return json.dumps(entity(t, frame, ident, lines=[{
            "type": 0, "pose": pose(0.0, 0.0), "thickness": 0.04, "scale_invariant": False, "points": "@PTS@",
            "color": rgba, "colors": [], "indices": []}])).replace('"@PTS@"', "[" + ",".join(self.points + [last]) + "]")


class EnvStream:
    """Encoder state of one recorded env: clock, episode counters, trail, static scene."""

    def __init__(self, env_index: int, env: Any, rec: Any):
        self.env = env_index
        self.rec = rec
        self.channels: dict[str, Any] = {}
        self.frame = f"env{env_index}/world"
        # every env's world hangs off one root frame, side by side, so that a viewer can place
        # any recorded env in any other's view (no "missing transform" between env trees)
        self.offset_x = ENV_SPACING * list(rec.envs).index(env_index)
        self.base = f"env{env_index}/base_link"
        self.laser = f"env{env_index}/laser"
        self.radius = float(env.cfg.robot.radius)
        self.goal_tol = float(getattr(env.cfg, "goal_tolerance", 0.0))
        li = rec.lidar
        self.scan_head = scan_head(self.laser, li)
        self.laser_tf = (li.offset[0], li.offset[1], li.offset[2])
        # fallback world when the env has no state to read worlds from: the map's fixed obstacles
        # (NavTask on a map; None on procedural worlds, whose worlds always come with the state)
        # or the env's only world (LineTask)
        bw = getattr(env.task, "base_world", None)
        self.base_world = bw if bw is not None else getattr(env.task, "world", None)
        self.clock = 0  # ticks of dt
        self.episode = -1
        self.in_episode = False
        self.ep_step = 0
        self.ep_return = 0.0
        self.finished_episodes = 0
        self.steps_written = 0
        self.static = ""
        self.trail = Trail()

    def topic_kinds(self) -> list[tuple[str, str]]:
        """``(topic under /env{i}/, kind of message)`` of every channel of this env (the kinds are ``rec.schemas()``'s keys)."""
        return [(name, _SHARED.get(name, name)) for name in self.rec.topics]

    @property
    def t(self) -> int:
        return self.clock * self.rec.dt_ns

    def _add(self, name: str, msg: dict | str) -> None:
        self.rec.add_message(self.channels[name], self.t, msg if isinstance(msg, str) else json.dumps(msg))

    def _limit_reached(self) -> bool:
        lim = self.rec.max_episodes
        return lim is not None and self.finished_episodes >= lim

    def _ended(self) -> bool:
        """Close the episode in progress: the reset takes one tick, so the next start is strictly later."""
        self.in_episode = False
        self.finished_episodes += 1
        self.clock += 1
        return True

    # -- one step ---------------------------------------------------------------------------

    def step(self, r: dict[str, np.ndarray]) -> bool:
        """Encode one step of this env; True if its episode ended here."""
        if self._limit_reached():
            return False
        if not self.in_episode:
            self._start(r)
        v1, w1 = float(r["vel1"][0]), float(r["vel1"][1])
        self._add("action", {"env": self.env, "episode": self.episode, "step": self.ep_step,
                             "v": _f(v1), "omega": _f(w1), "action": [_f(x) for x in r["action"]]})
        self.clock += 1
        self.ep_step += 1
        self.steps_written += 1
        p1 = r["pose1"]
        self._frame(p1, r["ranges1"], (v1, w1), r.get("odom1"), r.get("movers1"))
        self._sensors(r)
        reward = float(r["reward"])
        self.ep_return = float(r["ret"])
        terms = {k: _f(x) for k, x in zip(self.rec.term_names, r["terms"])} if "terms" in r else {}
        success, collision = bool(r["success"]), bool(r["collision"])
        msg = {
            "env": self.env, "episode": self.episode, "step": self.ep_step, "reward": _f(reward), "return": _f(self.ep_return),
            "v": _f(v1), "omega": _f(w1), "terms": terms, "curriculum_radius": _f(r["radius"]),
            "goal_distance": _f(math.hypot(p1[0] - self.goal[0], p1[1] - self.goal[1])), "success": success, "collision": collision,
        }
        if not self.rec.optional["goal"]:
            del msg["goal_distance"]
        self._add("reward", msg)
        if bool(r["terminated"]) or bool(r["truncated"]):
            kind = "success" if success else "collision" if collision else "timeout" if bool(r["truncated"]) or not bool(r["terminated"]) else "terminated"
            event = {"env": self.env, "episode": self.episode, "event": kind, "steps": self.ep_step,
                     "return": _f(self.ep_return), "path_length": _f(r["path"]), "straight_line": _f(r["straight"])}
            if kind == "terminated":
                event["reason"] = next((k for k in self.rec.end_reasons if bool(r[f"reason_{k}"])), "other")
            self._add("events", event)
            return self._ended()
        return False

    def _world(self, r: dict[str, np.ndarray]) -> tuple[list, list, list, bool]:
        """The episode's walls, circles and boxes as rows, and whether they are only the map's fixed obstacles."""
        keys = ("segments", "segment_mask", "circles", "circle_mask", "boxes", "box_mask")
        fixed_only = "segments" not in r
        if fixed_only:
            world = {k: getattr(self.base_world, k)[self.env].detach().cpu().numpy() for k in keys}
        else:
            world = {k: r[k] for k in keys}
        return (_rows(world["segments"], world["segment_mask"]), _rows(world["circles"], world["circle_mask"]),
                _rows(world["boxes"], world["box_mask"]), fixed_only)

    def _begin(self, r: dict[str, np.ndarray]) -> dict:
        """Start a new episode: counters, the static scene; returns the start event's ``world``."""
        self.episode += 1
        self.in_episode = True
        self.ep_step, self.ep_return = 0, 0.0
        seg, cir, box, fixed_only = self._world(r)
        self.static = ",".join(json.dumps(e) for e in self._static_entities(seg, cir, box))
        # rows flattened: Foxglove's and Lichtblick's JSON-schema parsers reject arrays of arrays
        return {"segments": sum(seg, []), "circles": sum(cir, []), "boxes": sum(box, []), "fixed_only": fixed_only}

    def _start(self, r: dict[str, np.ndarray]) -> None:
        self.goal = (float(r["goal"][0]), float(r["goal"][1]))
        world = self._begin(r)
        self.trail = Trail()
        p0 = r["pose0"]
        start = {"env": self.env, "episode": self.episode, "event": "start",
                 "start": [_f(x) for x in p0], "goal": [_f(x) for x in self.goal], "world": world}
        if not self.rec.optional["goal"]:
            del start["goal"]
        self._add("events", start)
        self._frame(p0, r["ranges0"], (0.0, 0.0), p0 if "odom1" in r else None)

    def _static_entities(self, seg: list, cir: list, box: list) -> list[dict]:
        t = self.t
        cubes = [cube(b[0], b[1], b[2], b[3], b[4], WALL_HEIGHT, "box") for b in box]
        out = [
            entity(t, self.frame, "walls", lines=[line_list(seg, 0.05, COLORS["wall"], z=0.0)] if seg else []),
            entity(t, self.frame, "boxes", cubes=cubes),
            entity(t, self.frame, "circles", cylinders=[cylinder(c[0], c[1], 2 * c[2], WALL_HEIGHT, "circle") for c in cir]),
        ]
        out += self._goal_entities(t)
        for name, spec in self.rec.scene_lines.items():
            out.append(entity(t, self.frame, name, lines=[line_list(spec["segments"], spec["thickness"], spec["color"])]))
        return out

    def _goal_entities(self, t: int) -> list[dict]:
        if not self.rec.optional["goal"]:
            return []
        return [entity(t, self.frame, "goal", cylinders=[cylinder(*self.goal, 2 * self.goal_tol, 0.02, "goal")])]

    def _root_tf(self, ts: dict) -> dict:
        return {"timestamp": ts, "parent_frame_id": ROOT_FRAME, "child_frame_id": self.frame,
                "translation": {"x": self.offset_x, "y": 0.0, "z": 0.0}, "rotation": pose(0, 0, 0.0)["orientation"]}

    def _sensors(self, r: dict[str, np.ndarray]) -> None:
        """IMU reading, camera images and movers of the state after the step, if recorded."""
        ts = stamp(self.t)
        if "imu1" in r:
            ax, ay, wz = (_f(x) for x in r["imu1"])
            self._add("imu", {"timestamp": ts, "frame_id": self.base, "linear_acceleration": {"x": ax, "y": ay, "z": 0.0},
                              "angular_velocity": {"x": 0.0, "y": 0.0, "z": wz}})
        if "rgb1" in r:
            rgb, depth = np.ascontiguousarray(r["rgb1"], dtype=np.uint8), np.ascontiguousarray(r["depth1"], dtype="<f4")
            h, w = rgb.shape[:2]
            frame = f"env{self.env}/camera"
            self._add("camera", {"timestamp": ts, "frame_id": frame, "width": w, "height": h, "encoding": "rgb8",
                                 "step": 3 * w, "data": base64.b64encode(rgb.tobytes()).decode()})
            self._add("camera_depth", {"timestamp": ts, "frame_id": frame, "width": w, "height": 1, "encoding": "32FC1",
                                       "step": 4 * w, "data": base64.b64encode(depth.tobytes()).decode()})
        if "movers1" in r:
            m = r["movers1"]
            exists, box = m[:, 5] > 0.5, _is_box(m)
            msg = {"env": self.env, "episode": self.episode, "discs": sum(_rows(m[:, :5], exists & ~box), [])}
            if m.shape[1] > 6:  # moving boxes: [x, y, vx, vy, half_x, half_y, yaw]
                msg["boxes"] = sum(_rows(m[:, [0, 1, 2, 3, 6, 7, 8]], exists & box), [])
            self._add("movers", msg)

    def _frame(self, p: np.ndarray, ranges: np.ndarray, vel: tuple[float, float], odom: np.ndarray | None,
               movers: np.ndarray | None = None) -> None:
        """tf, scan, scene and odometry of the state at the current tick."""
        x, y, yaw = _f(p[0]), _f(p[1]), _f(p[2])
        ts = stamp(self.t)
        self._add("tf", {"transforms": [self._root_tf(ts), *transforms(ts, self.frame, self.base, self.laser, x, y, yaw, self.laser_tf)]})
        self._add("scan", laser_scan(ts, self.scan_head, ranges))
        self.trail.add(x, y, self.ep_step)
        robot = robot_entity(self.t, self.frame, "robot", x, y, yaw, self.radius, color("robot"))
        trail = self.trail.entity(self.t, self.frame, "trail", x, y, color("trail"))
        extra = ""
        if odom is not None:  # the odometry estimate as a scene arrow too: viewers without foxglove.Odometry still draw it
            extra = "," + json.dumps(entity(self.t, self.frame, "estimate", arrows=[{
                "pose": pose(_f(odom[0]), _f(odom[1]), _f(odom[2]), ROBOT_HEIGHT + 0.02), "shaft_length": self.radius,
                "shaft_diameter": 0.03, "head_length": 0.08, "head_diameter": 0.08, "color": color("estimate")}]))
        if movers is not None:  # moving discs and boxes, redrawn every step
            exists, box = movers[:, 5] > 0.5, _is_box(movers)
            extra += "," + json.dumps(entity(self.t, self.frame, "movers", cylinders=[
                cylinder(c[0], c[1], 2 * c[4], MOVER_HEIGHT, "mover") for c in _rows(movers, exists & ~box)], cubes=[
                cube(c[0], c[1], c[6], c[7], c[8], MOVER_HEIGHT, "mover") for c in _rows(movers, exists & box)]))
        self._add("scene", '{"deletions":[],"entities":[' + self.static + "," + json.dumps(robot) + "," + trail + extra + "]}")
        self._add("odom", odometry(ts, self.frame, self.base, pose(x, y, yaw), vel))
        if odom is not None:
            self._add("odom_estimate", odometry(ts, self.frame, f"{self.base}_estimate", pose(_f(odom[0]), _f(odom[1]), _f(odom[2])), vel))


class MultiEnvStream(EnvStream):
    """Encoder state of one recorded env of several robots (``MultiNavEnv``): one clock and episode
    counter for the env, and per robot slot ``j`` its frames ``env{i}/robot{j}/base_link`` and
    ``.../laser``, topics ``/env{i}/robot{j}/{scan, odom, action, reward}``, goal, trail and path length.
    The env's ``tf``, ``scene`` and ``events`` carry every present robot (docs/foxglove.md)."""

    ROBOT_TOPICS = ("scan", "odom", "action", "reward")

    def __init__(self, env_index: int, env: Any, rec: Any):
        super().__init__(env_index, env, rec)
        self.n = int(env.n_robots)
        self.bases = [f"env{env_index}/robot{j}/base_link" for j in range(self.n)]
        self.lasers = [f"env{env_index}/robot{j}/laser" for j in range(self.n)]
        self.heads = [scan_head(laser, rec.lidar) for laser in self.lasers]
        self.present: list[int] = []

    def topic_kinds(self) -> list[tuple[str, str]]:
        return [(k, k) for k in ("tf", "scene", "events")] + [(f"robot{j}/{k}", k) for j in range(self.n) for k in self.ROBOT_TOPICS]

    def step(self, r: dict[str, np.ndarray]) -> bool:
        if self._limit_reached():
            return False
        if not self.in_episode:
            self._start(r)
        for j in self.present:
            v, w = float(r["vel1"][j, 0]), float(r["vel1"][j, 1])
            self._add(f"robot{j}/action", {"env": self.env, "robot": j, "episode": self.episode, "step": self.ep_step,
                                           "v": _f(v), "omega": _f(w), "action": [_f(x) for x in r["action"][j]]})
        self.clock += 1
        self.ep_step += 1
        self.steps_written += 1
        p1 = r["pose1"]
        for j in self.present:
            if not self.parked[j]:
                self.path[j] += math.hypot(p1[j, 0] - self.last[j][0], p1[j, 1] - self.last[j][1])
                self.steps[j] = self.ep_step
            self.last[j] = (float(p1[j, 0]), float(p1[j, 1]))
        self._frame(p1, r["ranges1"], r["vel1"])
        for j in self.present:
            terms = {k: _f(x) for k, x in zip(self.rec.term_names, r["terms"][j])} if "terms" in r else {}
            self._add(f"robot{j}/reward", {
                "env": self.env, "robot": j, "episode": self.episode, "step": self.ep_step, "reward": _f(r["reward"][j]),
                "return": _f(r["ret"][j]), "v": _f(r["vel1"][j, 0]), "omega": _f(r["vel1"][j, 1]), "terms": terms,
                "curriculum_radius": _f(r["radius"]), "goal_distance": _f(math.hypot(p1[j, 0] - self.goals[j][0], p1[j, 1] - self.goals[j][1])),
                "success": bool(r["success"][j]), "collision": bool(r["collision"][j]), "robot_collision": bool(r["robot_collision"][j])})
            self.parked[j] = bool(r["arrived"][j] or r["crashed"][j])
        if not (bool(r["terminated"]) or bool(r["truncated"])):
            return False
        team = bool(r["team_success"])
        outcomes = []
        for j in self.present:
            # a robot still driving when its env ended: the time limit, or (robots.on_collision: team) another robot's collision
            kind = "success" if r["arrived"][j] else "collision" if r["crashed"][j] else "timeout" if bool(r["truncated"]) else "ended"
            outcomes.append({"robot": j, "outcome": kind, "steps": self.steps[j], "return": _f(r["ret"][j]),
                             "path_length": _f(self.path[j]), "straight_line": _f(self.straight[j])})
        self.ep_return = float(sum(float(r["ret"][j]) for j in self.present))
        kind = "success" if team else "timeout" if bool(r["truncated"]) else "collision"
        self._add("events", {"env": self.env, "episode": self.episode, "event": kind, "steps": self.ep_step,
                             "return": _f(self.ep_return), "team_success": team, "outcomes": outcomes})
        return self._ended()

    def _start(self, r: dict[str, np.ndarray]) -> None:
        self.present = [int(j) for j in np.flatnonzero(r["present"])]
        p0, g = r["pose0"], r["goal"]
        self.goals = {j: (float(g[j, 0]), float(g[j, 1])) for j in self.present}
        world = self._begin(r)
        self.trails = {j: Trail() for j in self.present}
        self.parked = {j: False for j in self.present}
        self.path = {j: 0.0 for j in self.present}
        self.steps = {j: 0 for j in self.present}
        self.last = {j: (float(p0[j, 0]), float(p0[j, 1])) for j in self.present}
        self.straight = {j: math.hypot(self.goals[j][0] - p0[j, 0], self.goals[j][1] - p0[j, 1]) for j in self.present}
        self._add("events", {"env": self.env, "episode": self.episode, "event": "start", "robots": self.present,
                             "starts": [_f(x) for j in self.present for x in p0[j]],
                             "goals": [_f(x) for j in self.present for x in self.goals[j]], "world": world})
        self._frame(p0, r["ranges0"], np.zeros_like(p0[:, :2]))

    def _goal_entities(self, t: int) -> list[dict]:
        return [entity(t, self.frame, f"goal{j}", cylinders=[{**cylinder(*self.goals[j], 2 * self.goal_tol, 0.02, "goal"), "color": robot_rgba(j, 0.6)}])
                for j in self.present]

    def _frame(self, p: np.ndarray, ranges: np.ndarray, vel: np.ndarray) -> None:
        """tf, every present robot's scan and odometry, and the scene, at the current tick: ``p`` ``(N, 3)``,
        ``ranges`` ``(N, R)`` m, ``vel`` ``(N, 2)`` (m/s, rad/s)."""
        ts = stamp(self.t)
        tfs, ents = [self._root_tf(ts)], []
        for j in self.present:
            x, y, yaw = _f(p[j, 0]), _f(p[j, 1]), _f(p[j, 2])
            tfs += transforms(ts, self.frame, self.bases[j], self.lasers[j], x, y, yaw, self.laser_tf)
            self.trails[j].add(x, y, self.ep_step)
            ents += [json.dumps(robot_entity(self.t, self.frame, f"robot{j}", x, y, yaw, self.radius, robot_rgba(j))),
                     self.trails[j].entity(self.t, self.frame, f"trail{j}", x, y, robot_rgba(j, 0.8))]
        self._add("tf", {"transforms": tfs})
        self._add("scene", '{"deletions":[],"entities":[' + ",".join([self.static, *ents]) + "]}")
        for j in self.present:
            self._add(f"robot{j}/scan", laser_scan(ts, self.heads[j], ranges[j]))
            at = pose(_f(p[j, 0]), _f(p[j, 1]), _f(p[j, 2]))
            self._add(f"robot{j}/odom", odometry(ts, self.frame, self.bases[j], at, (float(vel[j, 0]), float(vel[j, 1]))))
