"""``make_worlds`` (one family) and ``mix_worlds`` (a family drawn per env), by name."""

from __future__ import annotations

from types import ModuleType
from typing import Mapping, Sequence

import torch
from torch import Tensor

from ..maps import MapError, available_maps, load_map
from ..sim import World
from . import cave, corridors, fences, forest, open_space, rooms
from .batch import WorldBatch, cat_batches
from .layout import as_difficulty, centred_bounds
from .placement import RobotPlacement, place_episodes, place_robots

FAMILIES: dict[str, ModuleType] = {"rooms": rooms, "corridors": corridors, "cave": cave, "forest": forest, "open": open_space, "fences": fences}
MAP_PREFIX = "map:"  # "map:<name>" is a shipped map (or a .yaml path) as a family
MAP_RESOLUTION = 0.1  # m, placement grid for maps (coarser for maps over 24 m, see _map_layout)


def _device(generator: torch.Generator, device: torch.device | str | None) -> torch.device:
    dev = torch.device(device) if device is not None else generator.device
    if dev.type != generator.device.type:
        raise ValueError(f"the generator is on {generator.device} but the worlds are asked for on {dev}; pass a generator on {dev}")
    return dev


def _map_layout(name: str, num_envs: int, device: torch.device, dtype: torch.dtype) -> tuple[World, Tensor, float]:
    """A shipped map's fixed obstacles in every env, its bounds ``(B, 4)`` and a placement
    resolution (m) that keeps the wavefront grid within 240 cells a side."""
    try:
        spec = load_map(name)
    except MapError as e:
        raise ValueError(f"unknown world family {MAP_PREFIX}{name}: {e}") from None
    world = spec.build_world(num_envs, device=device, dtype=dtype)
    w, h = spec.size
    bounds = centred_bounds(torch.full((num_envs,), w / 2, dtype=dtype, device=device), torch.full((num_envs,), h / 2, dtype=dtype, device=device))
    return world, bounds, max(MAP_RESOLUTION, max(w, h) / 240)


def _layout(family: str, d: Tensor, generator: torch.Generator, dtype: torch.dtype) -> tuple[World, Tensor, float]:
    """The worlds of ``family`` at difficulties ``d`` ``(B,)``, their bounds and the placement resolution (m)."""
    if family.startswith(MAP_PREFIX):
        return _map_layout(family[len(MAP_PREFIX) :], d.shape[0], d.device, dtype)
    if family in FAMILIES:
        world, bounds = FAMILIES[family].layout(d, generator)
        return world, bounds, FAMILIES[family].RESOLUTION
    raise ValueError(f"unknown world family {family!r}; known: {', '.join(FAMILIES)}, or {MAP_PREFIX}<name> with a map of {available_maps()}")


def slot_counts(families: Sequence[str]) -> dict[str, int]:
    """Obstacle slots ``{"segments": S, "circles": C, "boxes": K}`` that worlds of any of ``families``
    fit into (each family's counts are the same at every difficulty). Raises ValueError on an
    unknown family."""
    worlds = [_layout(name, torch.zeros(1), torch.Generator().manual_seed(0), torch.float32)[0] for name in families]
    return {key: max(getattr(w, key).shape[1] for w in worlds) for key in ("segments", "circles", "boxes")}


def make_worlds(
    family: str,
    num_envs: int,
    difficulty: float | Tensor,
    generator: torch.Generator,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
    robot_radius: float = 0.2,
    anywhere_goals: float = 0.0,
    below_level: float = 0.0,
    guide_cells: int = 0,
    guide_margin: float = 0.0,
    robots: RobotPlacement | None = None,
) -> WorldBatch:
    """``num_envs`` worlds of one family (a name of :data:`FAMILIES` or ``"map:<name>"``), each with a
    start and a reachable goal; the arguments up to ``anywhere_goals``: docs/worlds.md, "Generating
    a batch". At ``anywhere_goals=0`` no number is drawn for it, so the worlds are those of earlier
    versions. ``below_level``: the fraction of envs (drawn per env) whose difficulty is drawn
    uniformly in ``[0, d)`` (a curriculum keeps easier worlds in training as it rises); the batch's
    ``difficulty`` holds each env's own. ``guide_cells > 0``: also each env's grid of geodesic
    distances to its goal, ``guide_cells`` a side (``goal_field``, ``goal_frame``; torchnav/worlds/guide.py),
    for paths that keep ``guide_margin`` m more than the robot's radius from obstacles.
    ``robots``: several robots per world (:func:`~.placement.place_robots`); the batch's ``start``,
    ``goal`` and ``path_length`` are then ``(B, N, 3)``, ``(B, N, 2)`` and ``(B, N)`` (no goal grids).
    Worlds of one family share their slot counts.
    """
    for name, share in (("anywhere_goals", anywhere_goals), ("below_level", below_level)):
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"{name} must be in [0, 1], got {share}")
    dev = _device(generator, device)
    d = as_difficulty(difficulty, num_envs, dev, dtype)
    if below_level > 0:
        below = torch.rand(num_envs, generator=generator, device=dev) < below_level
        d = torch.where(below, d * torch.rand(num_envs, generator=generator, device=dev, dtype=dtype), d)
    world, bounds, resolution = _layout(family, d, generator, dtype)
    anywhere = torch.rand(num_envs, generator=generator, device=dev) < anywhere_goals if anywhere_goals > 0 else None
    if guide_cells < 0 or guide_margin < 0:
        raise ValueError(f"guide_cells and guide_margin must be >= 0, got {guide_cells} and {guide_margin}")
    if robots is not None:
        if guide_cells:
            raise ValueError("make_worlds: goal-distance grids (guide_cells) are for one robot per world, not with robots")
        start, goal, length, *field = place_robots(world, bounds, d, generator, robots, robot_radius=robot_radius, resolution=resolution,
                                                   anywhere=anywhere)
    else:
        start, goal, length, *field = place_episodes(world, bounds, d, generator, robot_radius=robot_radius, resolution=resolution,
                                                     anywhere=anywhere, guide_cells=guide_cells, guide_margin=guide_margin)
    return WorldBatch(
        world=world, start=start, goal=goal, path_length=length, bounds=bounds, difficulty=d,
        family=(family,) * num_envs, robot_radius=robot_radius, goal_field=field[0] if field else None, goal_frame=field[1] if field else None,
    )


def mix_worlds(
    num_envs: int,
    families: Sequence[str] | Mapping[str, float],
    difficulty: float | Tensor | Mapping[str, float | Tensor],
    generator: torch.Generator,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
    **placement: float | int | RobotPlacement | None,
) -> WorldBatch:
    """``num_envs`` worlds whose family is drawn per env from ``families`` (names, drawn uniformly, or
    ``{name: weight}``; docs/worlds.md, "Several families in one batch"). ``difficulty``: as for
    :func:`make_worlds`, or ``{family: difficulty}`` (a per-family curriculum). ``placement``:
    ``robot_radius``, ``anywhere_goals``, ``below_level``, ``guide_cells``, ``guide_margin`` and ``robots`` as for :func:`make_worlds`."""
    names = list(families)
    if not names:
        raise ValueError("mix_worlds needs at least one family")
    weights = [float(families[k]) for k in names] if isinstance(families, Mapping) else [1.0] * len(names)
    if min(weights) < 0 or sum(weights) <= 0:
        raise ValueError(f"family weights must be >= 0 with a positive sum, got {dict(zip(names, weights))}")
    dev = _device(generator, device)
    if isinstance(difficulty, Mapping):
        missing = [k for k in names if k not in difficulty]
        if missing:
            raise ValueError(f"mix_worlds: no difficulty for families {missing}")
        d = None
    else:
        d = as_difficulty(difficulty, num_envs, dev, dtype)
    drawn = torch.multinomial(torch.tensor(weights, device=dev), num_envs, replacement=True, generator=generator)
    parts, order = [], []
    for k, name in enumerate(names):
        idx = (drawn == k).nonzero()[:, 0]
        if idx.numel():
            level = difficulty[name] if d is None else d[idx]
            parts.append(make_worlds(name, idx.numel(), level, generator, dev, dtype, **placement))
            order.append(idx)
    return cat_batches(parts).select(torch.cat(order).argsort())
