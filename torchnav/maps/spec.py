"""Map data types: :class:`MapSpec` and the random-object settings, and :class:`MapError`.

Frames and units: x right, y up, metres; the world spans ``[-w/2, w/2] x [-h/2, h/2]``;
yaw in radians counter-clockwise from +x.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import torch

from torchnav.sim.camera import ObstacleStyles
from torchnav.sim.state import World, make_world, pad_world
from torchnav.sim.static_map import StaticMap, build_static_map

from .map_server import IDENTITY, from_map_frame, to_map_frame


class MapError(ValueError):
    """A map file could not be found, parsed or validated. The message names the file and key."""


@dataclass(frozen=True)
class RandomBoxes:
    """Oriented boxes the task re-places on every reset (``random_boxes`` in YAML)."""

    count: int  # number of boxes per env
    size_x: tuple[float, float]  # m, (min, max) FULL extent along the box's own x axis
    size_y: tuple[float, float]  # m, (min, max) FULL extent along the box's own y axis
    yaw: tuple[float, float] = (-math.pi, math.pi)  # rad, (min, max)
    clearance: float = 1.0  # m, min distance from the robot start and from the goal
    margin: float = 0.1  # m, min gap to fixed obstacles, walls and other random objects


@dataclass(frozen=True)
class RandomCircles:
    """Circles the task re-places on every reset (``random_circles`` in YAML)."""

    count: int  # number of circles per env
    radius: tuple[float, float]  # m, (min, max)
    clearance: float = 1.0  # m, min distance from the robot start and from the goal
    margin: float = 0.1  # m, min gap to fixed obstacles, walls and other random objects


MOTIONS = ("bounce", "constant", "patrol", "pedestrian")


@dataclass(frozen=True)
class RandomMovers:
    """Moving discs or moving boxes the task places at random on every reset (``moving_circles``,
    ``moving_boxes`` in YAML; ``worlds.movers`` of procedural worlds).

    Each gets a speed in ``speed``. ``bounce``: a uniformly random heading, bouncing inside
    ``region`` (default: the whole map); ``constant``: the same, driving straight on (through
    walls, out of the map); ``patrol``: cycles through ``waypoints`` random points of the
    region; ``pedestrian``: the same, steering around the other movers and the robot
    (``torchnav/sim/movers.py``)."""

    count: int  # movers per env
    radius: tuple[float, float]  # m, (min, max)
    speed: tuple[float, float]  # m/s, (min, max)
    motion: str = "bounce"  # "bounce" inside `region` | "constant" velocity
    region: tuple[float, float, float, float] | None = None  # (xmin, ymin, xmax, ymax) m; None: the map's bounds
    clearance: float = 1.0  # m, min distance from the robot start and from the goal at reset
    margin: float = 0.1  # m, min gap to obstacles, walls and other movers at reset
    waypoints: int = 4  # random waypoints per mover ("patrol", "pedestrian")
    # Moving boxes (``moving_boxes`` in YAML) instead of discs: FULL extents along the box's own axes,
    # m (min, max), and a yaw drawn once per reset (a box translates without turning). ``radius`` is
    # then the largest bounding circle's, fixed: it places and bounces the boxes. None: discs.
    size_x: tuple[float, float] | None = None
    size_y: tuple[float, float] | None = None
    yaw: tuple[float, float] = (-math.pi, math.pi)  # rad, (min, max)


@dataclass(frozen=True)
class MapSpec:
    """A validated map. Geometry is in world metres, in the layouts of :class:`World`; the fields are
    tabled in docs/maps.md, "Loading a map". ``movers``: the moving discs (``moving_circles``) or
    boxes (``moving_boxes``) the task places on reset, or None. ``styles``: the camera heights and colours
    of the fixed circles and boxes that declare ``height`` or ``color`` (slot ``i`` of a kind is its
    ``i``-th fixed obstacle). ``frame``: the pose ``(x m, y m, yaw rad)`` of the world's origin in the ROS
    ``map`` frame of a map_server map (docs/maps.md, "ROS map_server maps"); the identity for other maps."""

    name: str
    source: str
    size: tuple[float, float]
    segments: tuple[tuple[float, float, float, float], ...] = ()
    circles: tuple[tuple[float, float, float], ...] = ()
    boxes: tuple[tuple[float, float, float, float, float], ...] = ()
    random_boxes: RandomBoxes | None = None
    random_circles: RandomCircles | None = None
    movers: RandomMovers | None = None
    styles: ObstacleStyles = ObstacleStyles()
    frame: tuple[float, float, float] = IDENTITY

    @property
    def n_fixed_boxes(self) -> int:
        return len(self.boxes)

    @property
    def n_fixed_circles(self) -> int:
        return len(self.circles)

    @property
    def n_box_slots(self) -> int:
        """Box slots per env in :meth:`build_world`: fixed boxes, then random ones."""
        return len(self.boxes) + (self.random_boxes.count if self.random_boxes else 0)

    @property
    def n_circle_slots(self) -> int:
        """Circle slots per env in :meth:`build_world`: fixed circles, then random ones."""
        return len(self.circles) + (self.random_circles.count if self.random_circles else 0)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of the world rectangle in m."""
        w, h = self.size
        return (-w / 2, -h / 2, w / 2, h / 2)

    def build_world(
        self,
        batch_size: int,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
        fixed: bool = True,
    ) -> World:
        """The map's world for ``batch_size`` envs: the fixed obstacles in every env, then the random
        objects' slots, zeroed and masked off until the task fills them at reset (docs/maps.md,
        "What build_world makes"). ``fixed=False``: the random slots only, for a task that holds the
        fixed obstacles once in a :meth:`static_map`."""
        if not fixed:
            return pad_world(make_world(batch_size, device=device, dtype=dtype), circles=self.n_circle_slots - self.n_fixed_circles,
                             boxes=self.n_box_slots - self.n_fixed_boxes)
        world = make_world(batch_size, self.segments, self.circles, self.boxes, device=device, dtype=dtype)
        return pad_world(world, circles=self.n_circle_slots, boxes=self.n_box_slots)

    @property
    def n_fixed(self) -> int:
        """Fixed obstacles of every kind: walls and polygon edges, circles, boxes."""
        return len(self.segments) + len(self.circles) + len(self.boxes)

    def static_map(self, reach: float, device: torch.device | str | None = None, dtype: torch.dtype = torch.float32) -> StaticMap:
        """The fixed obstacles held once for a whole batch, indexed for sensors that see ``reach`` m
        (``torchnav.sim.static_map``; ``reach=0`` indexes for clearance only)."""
        t = lambda rows, width: torch.tensor(rows, dtype=torch.float64).reshape(-1, width)  # noqa: E731
        return build_static_map(self.bounds, t(self.segments, 4), t(self.circles, 3), t(self.boxes, 5), reach=reach, device=device, dtype=dtype)

    def to_map_frame(self, points: Any) -> Any:
        """Points ``(..., 2)`` ``[x, y]`` m or poses ``(..., 3)`` ``[x, y, yaw rad]`` of this world in the
        ROS ``map`` frame (:func:`.map_server.to_map_frame`; a tensor stays a tensor)."""
        return to_map_frame(self.frame, points)

    def from_map_frame(self, points: Any) -> Any:
        """Points or poses of the ROS ``map`` frame (an RViz goal) in this world: the inverse of :meth:`to_map_frame`."""
        return from_map_frame(self.frame, points)

    def to_dict(self) -> dict[str, Any]:
        """Plain python types (lists, floats, None) for logging and config dumps."""

        def plain(x: Any) -> Any:
            if isinstance(x, dict):
                return {k: plain(v) for k, v in x.items()}
            if isinstance(x, (list, tuple)):
                return [plain(v) for v in x]
            return x

        return plain(asdict(self))
