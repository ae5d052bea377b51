"""Per-env message encoding: one ``EnvStream`` turns one env's steps into JSON messages.

Kept free of tensors: it receives numpy rows of one step of one env (see
``EpisodeRecorder._select`` for the keys). The static part of the scene (walls,
boxes, circles, goal) is encoded once per episode and spliced into every step's
``SceneUpdate``, so a step costs a handful of small ``json.dumps``.
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


class EnvStream:
    """Encoder state of one recorded env: clock, episode counters, trail, static scene."""

    MAX_TRAIL = 256  # points; longer trails keep every 2nd, 4th, ... point

    def __init__(self, env_index: int, env: Any, rec: Any):
        self.env = env_index
        self.rec = rec
        self.channels: dict[str, int] = {}
        self.frame = f"env{env_index}/world"
        # every env's world hangs off one root frame, side by side, so that a viewer can place
        # any recorded env in any other's view (no "missing transform" between env trees)
        self.offset_x = ENV_SPACING * list(rec.envs).index(env_index)
        self.base = f"env{env_index}/base_link"
        self.laser = f"env{env_index}/laser"
        self.radius = float(env.cfg.robot.radius)
        self.goal_tol = float(getattr(env.cfg, "goal_tolerance", 0.0))
        li = env.task.params.lidar
        ang = li.angles()
        self.scan_head = {"frame_id": self.laser, "pose": pose(0.0, 0.0), "start_angle": ang[0], "end_angle": ang[-1]}
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
        self.trail: list[str] = []
        self.trail_stride = 1

    @property
    def t(self) -> int:
        return self.clock * self.rec.dt_ns

    def _add(self, name: str, msg: dict | str) -> None:
        self.rec.add_message(self.channels[name], self.t, msg if isinstance(msg, str) else json.dumps(msg))

    # -- one step ---------------------------------------------------------------------------

    def step(self, r: dict[str, np.ndarray]) -> bool:
        """Encode one step of this env; True if its episode ended here."""
        lim = self.rec.max_episodes
        if lim is not None and self.finished_episodes >= lim:
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
            self.in_episode = False
            self.finished_episodes += 1
            self.clock += 1  # the reset takes one tick, so the next start is strictly later
            return True
        return False

    def _start(self, r: dict[str, np.ndarray]) -> None:
        self.episode += 1
        self.in_episode = True
        self.ep_step, self.ep_return = 0, 0.0
        self.goal = (float(r["goal"][0]), float(r["goal"][1]))
        keys = ("segments", "segment_mask", "circles", "circle_mask", "boxes", "box_mask")
        fixed_only = "segments" not in r
        if fixed_only:
            world = {k: getattr(self.base_world, k)[self.env].detach().cpu().numpy() for k in keys}
        else:
            world = {k: r[k] for k in keys}
        seg = _rows(world["segments"], world["segment_mask"])
        cir = _rows(world["circles"], world["circle_mask"])
        box = _rows(world["boxes"], world["box_mask"])
        self.static = ",".join(json.dumps(e) for e in self._static_entities(seg, cir, box))
        self.trail, self.trail_stride = [], 1
        p0 = r["pose0"]
        start = {"env": self.env, "episode": self.episode, "event": "start",
                 "start": [_f(x) for x in p0], "goal": [_f(x) for x in self.goal],
                 # rows flattened: Foxglove's and Lichtblick's JSON-schema parsers reject arrays of arrays
                 "world": {"segments": sum(seg, []), "circles": sum(cir, []), "boxes": sum(box, []), "fixed_only": fixed_only}}
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
        if self.rec.optional["goal"]:
            out.append(entity(t, self.frame, "goal", cylinders=[cylinder(*self.goal, 2 * self.goal_tol, 0.02, "goal")]))
        for name, spec in self.rec.scene_lines.items():
            out.append(entity(t, self.frame, name, lines=[line_list(spec["segments"], spec["thickness"], spec["color"])]))
        return out

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
        ox, oy, oyaw = self.laser_tf
        self._add("tf", {"transforms": [
            {"timestamp": ts, "parent_frame_id": ROOT_FRAME, "child_frame_id": self.frame,
             "translation": {"x": self.offset_x, "y": 0.0, "z": 0.0}, "rotation": pose(0, 0, 0.0)["orientation"]},
            {"timestamp": ts, "parent_frame_id": self.frame, "child_frame_id": self.base,
             "translation": {"x": x, "y": y, "z": 0.0}, "rotation": pose(0, 0, yaw)["orientation"]},
            {"timestamp": ts, "parent_frame_id": self.base, "child_frame_id": self.laser,
             "translation": {"x": ox, "y": oy, "z": ROBOT_HEIGHT}, "rotation": pose(0, 0, oyaw)["orientation"]},
        ]})
        self._add("scan", {"timestamp": ts, **self.scan_head, "ranges": np.round(ranges.astype(np.float64), 5).tolist(), "intensities": []})
        # trail: keep every stride-th point, halving the resolution when it grows too long
        if self.ep_step % self.trail_stride == 0:
            self.trail.append(f'{{"x":{x},"y":{y},"z":0.02}}')
            if len(self.trail) > self.MAX_TRAIL:
                self.trail, self.trail_stride = self.trail[::2], self.trail_stride * 2
        robot = entity(self.t, self.frame, "robot", cylinders=[cylinder(x, y, 2 * self.radius, ROBOT_HEIGHT, "robot", yaw)], arrows=[{
            "pose": pose(x, y, yaw, ROBOT_HEIGHT + 0.01), "shaft_length": self.radius, "shaft_diameter": 0.04,
            "head_length": 0.1, "head_diameter": 0.1, "color": color("arrow")}])
        last = f'{{"x":{x},"y":{y},"z":0.02}}'
        trail = json.dumps(entity(self.t, self.frame, "trail", lines=[{
            "type": 0, "pose": pose(0.0, 0.0), "thickness": 0.04, "scale_invariant": False, "points": "@PTS@",
            "color": color("trail"), "colors": [], "indices": []}])).replace('"@PTS@"', "[" + ",".join(self.trail + [last]) + "]")
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
        def odometry(body: str, at: dict) -> dict:  # the true pose and the odometry estimate, with the applied twist
            return {"timestamp": ts, "frame_id": self.frame, "body_frame_id": body, "pose": at,
                    "linear_velocity": {"x": _f(vel[0]), "y": 0.0, "z": 0.0}, "angular_velocity": {"x": 0.0, "y": 0.0, "z": _f(vel[1])},
                    "pose_covariance": [0.0] * 36, "velocity_covariance": [0.0] * 36, "metadata": []}

        self._add("odom", odometry(self.base, pose(x, y, yaw)))
        if odom is not None:
            self._add("odom_estimate", odometry(f"{self.base}_estimate", pose(_f(odom[0]), _f(odom[1]), _f(odom[2]))))
