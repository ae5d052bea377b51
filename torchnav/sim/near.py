"""Nearby obstacles carried in the state, so that a step in a dense world scans only them.

With ``SimParams.near_slots > 0`` each env keeps its obstacles nearest the robot in
``SimState.near``, chosen by the lower bound ``|p - c| - rho`` of each obstacle's
bounding circle (centre ``c``, radius ``rho``) from the robot's position ``p`` at
that time (``SimState.near_centre``), together with the bound of the nearest
obstacle left out (``SimState.near_bound``). Static obstacles stay where they are, so
from any later point ``q`` every obstacle left out lies at least
``near_bound - |q - near_centre|`` away (the triangle inequality). A lidar reading or
clearance over the near obstacles (and the movers, always scanned whole) that is at
most that far is the reading over the whole world.

Each step the ``ceil(B / REFRESH_SHARE)`` envs with the least slack (how far the
bound reaches beyond their farthest reading, or beyond their clearance) are scanned
over the whole world instead and choose their near obstacles again where they are.
When more envs than that fall short, every env is scanned over the whole world (a
``torch.cond`` branch: no host synchronisation). The result is the full scan's up to
rounding, in every env and every step; choosing is not differentiated, gradients
flow through the narrow phase as before. Kinds with at most ``KEEP_WHOLE`` slots
(the walls of a room) are always scanned whole; the others share ``near_slots`` in
proportion to their slot counts. docs/sim.md, "Dense worlds: the near obstacles".
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .geometry import points_clearance
from .lidar import fan_scan, lidar_fan
from .math import safe_hypot
from .params import LidarParams
from .raycast import RayFan, bounding_circles
from .state import _KIND_MASKS, World, planar_rows

KEEP_WHOLE = 16  # kinds with at most this many slots are scanned whole
REFRESH_SHARE = 32  # each step, 1/32 of the batch (those with the least slack) is scanned whole and chooses again
MARGIN = 1e-3  # m taken off the bound, for rounding: the narrow phase and the bound compute distances differently


def near_counts(world: World, near_slots: int) -> dict[str, int]:
    """Per obstacle kind, how many slots ``SimState.near`` keeps (0: the kind is scanned whole)."""
    slots = {key: getattr(world, key).shape[1] for key, _, _ in _KIND_MASKS}
    shared = sum(n for n in slots.values() if n > KEEP_WHOLE)
    counts = {}
    for key, n in slots.items():
        k = math.ceil(near_slots * n / shared) if near_slots > 0 and n > KEEP_WHOLE else 0
        counts[key] = k if k < n else 0
    return counts


def select_near(centre: Tensor, world: World, counts: dict[str, int]) -> tuple[World, Tensor]:
    """The near obstacles of every env around ``centre`` ``(B, 2)`` (``counts[kind]`` slots of each
    kind, the nearest by bounding-circle lower bound; ``(B, 0, w)`` for kinds scanned whole), and
    ``(B,)`` the lower bound (m) of the distance from ``centre`` to every obstacle left out, less
    ``MARGIN`` (``inf`` when none is left out)."""
    bound = torch.full_like(centre[:, 0], math.inf)
    out = {}
    for key, mkey, width in _KIND_MASKS:
        obs, mask, k = getattr(world, key), getattr(world, mkey), counts[key]
        if not k:
            out[key], out[mkey] = obs.new_zeros(obs.shape[0], 0, width), mask.new_zeros(mask.shape[0], 0)
            continue
        with torch.no_grad():
            cx, cy, rho = bounding_circles(key, obs.detach())
            lower = torch.where(mask, safe_hypot(cx - centre[:, 0:1], cy - centre[:, 1:2]) - rho, math.inf)
            value, index = lower.topk(k + 1, dim=1, largest=False)
            index = index[:, :k]
            bound = torch.minimum(bound, value[:, k])
        out[key] = planar_rows(obs.gather(1, index.unsqueeze(-1).expand(-1, -1, width)))
        out[mkey] = mask.gather(1, index)
    return World(**out, batch_size=world.batch_size, device=centre.device), bound.detach() - MARGIN


def check_near(near: World, world: World, near_slots: int) -> None:
    """Raise a ValueError when ``near`` (a state's) does not hold the slots ``near_slots`` asks for on ``world``."""
    want = near_counts(world, near_slots)
    have = {key: getattr(near, key).shape[1] for key in want}
    if have != want:
        raise ValueError(f"state.near holds {have} obstacle slots, but params.near_slots={near_slots} on this world needs {want}: "
                         "make the state with init_state(pose, world, params) for these params and world")


def _with_near(world: World, near: World, counts: dict[str, int]) -> World:
    """``world`` with each kind that keeps near slots replaced by them."""
    out = {}
    for key, mkey, _ in _KIND_MASKS:
        src = near if counts[key] else world
        out[key], out[mkey] = getattr(src, key), getattr(src, mkey)
    return World(**out, batch_size=world.batch_size, device=near.device)


def _rows(world: World, index: Tensor) -> World:
    out = {}
    for key, mkey, _ in _KIND_MASKS:
        out[key], out[mkey] = planar_rows(getattr(world, key).index_select(0, index)), getattr(world, mkey).index_select(0, index)
    return World(**out, batch_size=[index.shape[0]], device=index.device)


def _replace_rows(x: Tensor, index: Tensor, rows: Tensor) -> Tensor:
    """``x`` with its envs ``index`` replaced by ``rows``; obstacle rows ``(B, N, k)`` stay component-major
    (copied as ``(k, B, N)``: compiled, a plain ``index_copy`` returns them row-major, which made every
    later loop over them read strided memory)."""
    if x.dim() == 2:
        return x.index_copy(0, index, rows)
    return x.permute(2, 0, 1).index_copy(1, index, rows.permute(2, 0, 1)).permute(1, 2, 0)


def _scan_and_clearance(fan: RayFan, centre: Tensor, world: World, lidar: LidarParams, unroll: bool | None) -> tuple[Tensor, Tensor]:
    """Raw lidar readings ``(B, n)`` of ``fan`` and the distance ``(B,)`` from ``centre`` to the nearest obstacle."""
    return fan_scan(fan, world, lidar, unroll), points_clearance(centre.unsqueeze(1), world)[:, 0]


def near_sense(
    pose: Tensor, lidar_pose: Tensor, world: World, near: World, near_centre: Tensor, near_bound: Tensor,
    lidar: LidarParams, near_slots: int, movers: World | None = None, unroll: bool | None = None,
) -> tuple[Tensor, Tensor, World, Tensor, Tensor]:
    """The distance ``(B,)`` from each robot's centre to its nearest obstacle (clearance plus radius)
    and its raw lidar readings ``(B, n)`` (before noise and clamping), both over ``world`` and
    ``movers``, computed over the near obstacles where they suffice; and the state's next
    ``near``, ``near_centre`` and ``near_bound`` (module docstring)."""
    counts = near_counts(world, near_slots)
    fan = lidar_fan(lidar_pose, lidar)
    centre = pose[:, :2]
    b = centre.shape[0]
    ranges, dist = _scan_and_clearance(fan, centre, _with_near(world, near, counts), lidar, unroll)
    if movers is not None:
        mover_ranges, mover_dist = _scan_and_clearance(fan, centre, movers, lidar, unroll)
    with torch.no_grad():
        seen = ranges if movers is None else torch.minimum(ranges, mover_ranges)
        near_dist = dist if movers is None else torch.minimum(dist, mover_dist)
        farthest = seen.clamp(max=lidar.max_range).amax(1)
        slack = torch.minimum(near_bound - safe_hypot(fan.origin[:, 0] - near_centre[:, 0], fan.origin[:, 1] - near_centre[:, 1]) - farthest,
                              near_bound - safe_hypot(centre[:, 0] - near_centre[:, 0], centre[:, 1] - near_centre[:, 1]) - near_dist)
        n_refresh = -(-b // REFRESH_SHARE)
        index = slack.topk(n_refresh, largest=False).indices
        overflow = (slack < 0).sum() > n_refresh
    # The envs with the least slack: scanned over their whole world, and their near obstacles chosen again.
    rows = _rows(world, index)
    part = RayFan(fan.origin.index_select(0, index), fan.angles.index_select(0, index), fan.first.index_select(0, index), fan.spacing, fan.closed)
    part_ranges, part_dist = _scan_and_clearance(part, centre.index_select(0, index), rows, lidar, unroll)
    ranges, dist = ranges.index_copy(0, index, part_ranges), dist.index_copy(0, index, part_dist)
    part_near, part_bound = select_near(centre.index_select(0, index), rows, counts)
    near = World(**{k: _replace_rows(v, index, getattr(part_near, k)) if counts[_KIND_OF[k]] else v for k, v in _fields(near)},
                 batch_size=[b], device=centre.device)
    near_centre = near_centre.index_copy(0, index, centre.index_select(0, index).detach())
    near_bound = near_bound.index_copy(0, index, part_bound)

    # More envs fall short than were refreshed: every env over the whole world.
    def whole(ranges, dist, origin, angles, first, centre, *obs):
        w = World(**dict(zip(_FIELD_NAMES, obs)), batch_size=[b], device=origin.device)
        return _scan_and_clearance(RayFan(origin, angles, first, fan.spacing, fan.closed), centre, w, lidar, unroll)

    def kept(ranges, dist, *_):
        return ranges.clone(), dist.clone()

    ranges, dist = torch.cond(overflow, whole, kept, (ranges, dist, fan.origin, fan.angles, fan.first, centre, *(v for _, v in _fields(world))))
    if movers is not None:
        ranges, dist = torch.minimum(ranges, mover_ranges), torch.minimum(dist, mover_dist)
    return dist, ranges, near, near_centre, near_bound


_FIELD_NAMES = tuple(k for key, mkey, _ in _KIND_MASKS for k in (key, mkey))
_KIND_OF = {k: key for key, mkey, _ in _KIND_MASKS for k in (key, mkey)}


def _fields(world: World) -> list[tuple[str, Tensor]]:
    return [(k, getattr(world, k)) for k in _FIELD_NAMES]
