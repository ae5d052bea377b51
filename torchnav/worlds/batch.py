"""WorldBatch: generated worlds with one episode (start, goal, path length) per env."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import torch
from torch import Tensor

from ..sim import World, cat_worlds


@dataclass(frozen=True)
class WorldBatch:
    """``B`` generated worlds, each with a start and a reachable goal."""

    world: World  # the obstacles, padded (B, N, ...) tensors with masks
    start: Tensor  # (B, 3) start pose [x m, y m, theta rad]; (B, N, 3) with N robots per world (make_worlds(robots=...))
    goal: Tensor  # (B, 2) goal [x, y] m; (B, N, 2) with N robots
    path_length: Tensor  # (B,) m (or (B, N)) of a collision-free path for the robot's disc: never below the shortest (docs/worlds.md)
    bounds: Tensor  # (B, 4) [xmin, ymin, xmax, ymax] m of each world (walls run along them)
    difficulty: Tensor  # (B,) in [0, 1], the difficulty each env was generated at
    family: tuple[str, ...]  # B family names ("rooms", ..., or "map:<name>" for a shipped map)
    robot_radius: float  # m, the disc the paths were planned for
    goal_field: Tensor | None = None  # (B, G, G) int16 cm geodesic distance to the goal (make_worlds(guide_cells=G)); see guide.py
    goal_frame: Tensor | None = None  # (B, 3) [x0, y0, cell m] of goal_field

    def __len__(self) -> int:
        return self.start.shape[0]

    def select(self, index: Tensor) -> WorldBatch:
        """The envs at ``index`` ``(n,)`` (int64), in that order."""
        pick: Callable[[Tensor], Tensor] = lambda t: t[index]  # noqa: E731
        return WorldBatch(
            world=self.world[index], start=pick(self.start), goal=pick(self.goal), path_length=pick(self.path_length),
            bounds=pick(self.bounds), difficulty=pick(self.difficulty),
            family=tuple(self.family[i] for i in index.tolist()), robot_radius=self.robot_radius,
            goal_field=None if self.goal_field is None else pick(self.goal_field),
            goal_frame=None if self.goal_frame is None else pick(self.goal_frame),
        )


def cat_batches(batches: Sequence[WorldBatch]) -> WorldBatch:
    """Concatenate batches along the env dim; each obstacle kind is padded to the largest slot count."""
    if not batches:
        raise ValueError("cat_batches needs at least one WorldBatch")
    radii = {b.robot_radius for b in batches}
    if len(radii) > 1:
        raise ValueError(f"cat_batches: the batches were planned for different robot radii {sorted(radii)}")
    guided = {b.goal_field is not None for b in batches}
    if len(guided) > 1:
        raise ValueError("cat_batches: some batches have goal-distance grids and some do not")
    shapes = {b.goal_field.shape[1:] for b in batches if b.goal_field is not None}
    if len(shapes) > 1:
        raise ValueError(f"cat_batches: goal-distance grids of different sizes {sorted(shapes)}")
    cat = lambda key: torch.cat([getattr(b, key) for b in batches])  # noqa: E731
    return WorldBatch(
        world=cat_worlds([b.world for b in batches]), start=cat("start"), goal=cat("goal"), path_length=cat("path_length"),
        bounds=cat("bounds"), difficulty=cat("difficulty"), family=sum((b.family for b in batches), ()),
        robot_radius=batches[0].robot_radius,
        goal_field=cat("goal_field") if guided == {True} else None, goal_frame=cat("goal_frame") if guided == {True} else None,
    )
