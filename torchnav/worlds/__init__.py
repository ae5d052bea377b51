"""Procedural worlds: seeded, batched generators that write ``World`` tensors directly.

>>> import torch
>>> from torchnav.worlds import make_worlds, mix_worlds
>>> gen = torch.Generator().manual_seed(0)
>>> batch = make_worlds("rooms", 256, difficulty=0.5, generator=gen)
>>> batch.world, batch.start, batch.goal, batch.path_length   # World, (B, 3), (B, 2), (B,)
>>> mixed = mix_worlds(256, ["rooms", "cave", "map:warehouse"], torch.rand(256, generator=gen), gen)

Families (one file each): ``rooms``, ``corridors``, ``cave``, ``forest``, ``open``;
every one maps a difficulty in [0, 1] to documented parameters (``<family>.params``).
Every episode's goal is reachable by the robot's disc. See ``docs/worlds.md``.
"""

from .batch import WorldBatch, cat_batches
from .placement import goal_band, place_episodes
from .registry import FAMILIES, MAP_PREFIX, make_worlds, mix_worlds, slot_counts

__all__ = ["FAMILIES", "MAP_PREFIX", "WorldBatch", "cat_batches", "goal_band", "make_worlds", "mix_worlds", "place_episodes", "slot_counts"]
