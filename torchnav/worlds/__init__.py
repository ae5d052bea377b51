"""Procedural worlds: seeded, batched generators that write ``World`` tensors directly.

``make_worlds(family, num_envs, difficulty, generator)`` for one family (``rooms``, ``corridors``,
``cave``, ``forest``, ``open``, or ``map:<name>``), ``mix_worlds`` for a family drawn per env; every
episode's goal is reachable by the robot's disc. See docs/worlds.md."""

from .batch import WorldBatch, cat_batches
from .guide import goal_distance
from .placement import RobotPlacement, goal_band, goal_distance_grid, place_episodes, place_robots
from .registry import FAMILIES, MAP_PREFIX, make_worlds, mix_worlds, slot_counts

__all__ = [
    "FAMILIES", "MAP_PREFIX", "RobotPlacement", "WorldBatch", "cat_batches", "goal_band", "goal_distance", "goal_distance_grid", "make_worlds",
    "mix_worlds", "place_episodes", "place_robots", "slot_counts",
]
