"""Batched reset sampling: start poses, goals and random objects, without loops over envs.

Each sampler draws ``K`` candidates per env at once, tests them all with one
batched geometry call, and keeps a valid one. When no candidate of an env is
valid, each sampler has a defined fallback (documented per function), so a
reset never blocks and never loops an unbounded number of times.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..maps import MapSpec
from ..sim import World, points_clearance

_BIG = 1e9


def _uniform(shape, lo, hi, gen: torch.Generator, like: Tensor) -> Tensor:
    return lo + (hi - lo) * torch.rand(shape, generator=gen, dtype=like.dtype, device=like.device)


def _pick(valid: Tensor, score: Tensor) -> tuple[Tensor, Tensor]:
    """Index ``(n,)`` of a valid candidate per row of ``(n, K)``, else of the best-scoring one;
    and whether a valid one was found ``(n,)``."""
    key = torch.where(valid, torch.full_like(score, _BIG), score.clamp(-_BIG / 2, _BIG / 2))
    return key.argmax(dim=1), valid.any(dim=1)


def _gather(x: Tensor, idx: Tensor) -> Tensor:
    """``x`` ``(n, K, ...)`` at candidate ``idx`` ``(n,)`` -> ``(n, ...)``."""
    return x[torch.arange(x.shape[0], device=x.device), idx]


def _inside(xy: Tensor, bounds, margin) -> Tensor:
    xmin, ymin, xmax, ymax = bounds
    x, y = xy[..., 0], xy[..., 1]
    return (x >= xmin + margin) & (x <= xmax - margin) & (y >= ymin + margin) & (y <= ymax - margin)


def sample_starts(world: World, spec: MapSpec, need: float, k: int, gen: torch.Generator) -> tuple[Tensor, Tensor]:
    """Start poses ``(n, 3)`` whose position is at least ``need`` m from every obstacle of ``world``
    and from the world's edge, with a uniform random heading.

    Fallback: the candidate with the largest clearance. Also returns whether a
    valid candidate was found ``(n,)``.
    """
    n = world.batch_size[0]
    like = world.segments
    xmin, ymin, xmax, ymax = spec.bounds
    m = min(need, 0.49 * min(xmax - xmin, ymax - ymin))
    xy = torch.stack((_uniform((n, k), xmin + m, xmax - m, gen, like), _uniform((n, k), ymin + m, ymax - m, gen, like)), -1)
    clear = points_clearance(xy, world)
    idx, found = _pick(clear >= need, clear)
    heading = _uniform((n,), -math.pi, math.pi, gen, like)
    return torch.cat((_gather(xy, idx), heading[:, None]), dim=-1), found


def sample_goals(
    world: World, spec: MapSpec, start_xy: Tensor, r_min: float, r_max: Tensor, need: float, k: int, gen: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Goals ``(n, 2)`` at a distance in ``[r_min, r_max]`` from ``start_xy`` ``(n, 2)``, inside the
    world and at least ``need`` m from every obstacle.

    ``r_max`` is a 0-d tensor (the curriculum radius). Distance and direction are
    uniform. Fallback, in order: a valid goal drawn uniformly over the whole world
    ignoring the radius, else the candidate with the largest clearance.
    """
    n = start_xy.shape[0]
    like = start_xy
    hi = torch.maximum(r_max.to(like), torch.as_tensor(r_min, dtype=like.dtype, device=like.device))
    dist = r_min + (hi - r_min) * torch.rand((n, k), generator=gen, dtype=like.dtype, device=like.device)
    ang = _uniform((n, k), -math.pi, math.pi, gen, like)
    near = start_xy[:, None, :] + torch.stack((dist * torch.cos(ang), dist * torch.sin(ang)), -1)
    xmin, ymin, xmax, ymax = spec.bounds
    anywhere = torch.stack((_uniform((n, k), xmin, xmax, gen, like), _uniform((n, k), ymin, ymax, gen, like)), -1)
    cand = torch.cat((near, anywhere), dim=1)  # (n, 2k): near candidates first
    clear = points_clearance(cand, world)
    sep = (cand - start_xy[:, None, :]).norm(dim=-1)
    ok = (clear >= need) & _inside(cand, spec.bounds, need) & (sep >= r_min)
    score = torch.where(_inside(cand, spec.bounds, 0.0), clear, torch.full_like(clear, -_BIG / 4))
    # Prefer valid near candidates, then valid anywhere-candidates, then the clearest.
    prio = torch.cat((torch.full((n, k), 2.0, dtype=like.dtype, device=like.device), torch.ones((n, k), dtype=like.dtype, device=like.device)), 1)
    key = torch.where(ok, _BIG * prio, score.clamp(-_BIG / 2, _BIG / 2))
    idx = key.argmax(dim=1)
    return _gather(cand, idx), ok[:, :k].any(dim=1)


def place_random_objects(
    world: World, spec: MapSpec, start_xy: Tensor, goal_xy: Tensor, k: int, gen: torch.Generator,
    *, start_need: float = 0.0, goal_need: float = 0.0,
) -> World:
    """Fill the random box and circle slots of ``world`` (batch ``n``) with fresh objects.

    Each object keeps ``max(clearance, start_need)`` m from the start point,
    ``max(clearance, goal_need)`` m from the goal and ``margin`` m from every fixed
    obstacle, wall and object placed before it (tested on its circumscribed
    circle, so the guarantee is conservative). ``start_need``/``goal_need`` are
    the task's own clearances, which a map's smaller ``clearance`` must not undo.
    Fallback: an object with no valid candidate is left out of this episode (its
    slot is masked off).
    """
    boxes, box_mask = world.boxes, world.box_mask
    circles, circle_mask = world.circles, world.circle_mask
    # Forget the previous episode's random objects before testing new candidates against the world.
    box_mask = torch.cat((box_mask[:, : spec.n_fixed_boxes], torch.zeros_like(box_mask[:, spec.n_fixed_boxes :])), 1)
    circle_mask = torch.cat((circle_mask[:, : spec.n_fixed_circles], torch.zeros_like(circle_mask[:, spec.n_fixed_circles :])), 1)
    n, like = start_xy.shape[0], start_xy
    xmin, ymin, xmax, ymax = spec.bounds

    def candidates(rc: Tensor, clearance: float, margin: float, cur: World):
        xy = torch.stack((_uniform((n, k), xmin, xmax, gen, like), _uniform((n, k), ymin, ymax, gen, like)), -1)
        gap = points_clearance(xy, cur) - rc
        d_start = (xy - start_xy[:, None]).norm(dim=-1) - rc
        d_goal = (xy - goal_xy[:, None]).norm(dim=-1) - rc
        ok = (gap >= margin) & (d_start >= max(clearance, start_need)) & (d_goal >= max(clearance, goal_need)) & _inside(xy, spec.bounds, 0.0) & _inside(xy, spec.bounds, rc.clamp(min=0))
        idx, found = _pick(ok, gap)
        return xy, idx, found

    rb = spec.random_boxes
    for j in range(rb.count if rb else 0):
        slot = spec.n_fixed_boxes + j
        hx = _uniform((n, k), rb.size_x[0] / 2, rb.size_x[1] / 2, gen, like)
        hy = _uniform((n, k), rb.size_y[0] / 2, rb.size_y[1] / 2, gen, like)
        yaw = _uniform((n, k), rb.yaw[0], rb.yaw[1], gen, like)
        cur = World(segments=world.segments, segment_mask=world.segment_mask, circles=circles, circle_mask=circle_mask, boxes=boxes, box_mask=box_mask, batch_size=[n])
        xy, idx, found = candidates(torch.hypot(hx, hy), rb.clearance, rb.margin, cur)
        new = torch.stack((_gather(xy, idx)[:, 0], _gather(xy, idx)[:, 1], _gather(hx, idx), _gather(hy, idx), _gather(yaw, idx)), -1)
        boxes = torch.cat((boxes[:, :slot], new[:, None], boxes[:, slot + 1 :]), 1)
        box_mask = torch.cat((box_mask[:, :slot], found[:, None], box_mask[:, slot + 1 :]), 1)
    rcirc = spec.random_circles
    for j in range(rcirc.count if rcirc else 0):
        slot = spec.n_fixed_circles + j
        r = _uniform((n, k), rcirc.radius[0], rcirc.radius[1], gen, like)
        cur = World(segments=world.segments, segment_mask=world.segment_mask, circles=circles, circle_mask=circle_mask, boxes=boxes, box_mask=box_mask, batch_size=[n])
        xy, idx, found = candidates(r, rcirc.clearance, rcirc.margin, cur)
        new = torch.cat((_gather(xy, idx), _gather(r, idx)[:, None]), -1)
        circles = torch.cat((circles[:, :slot], new[:, None], circles[:, slot + 1 :]), 1)
        circle_mask = torch.cat((circle_mask[:, :slot], found[:, None], circle_mask[:, slot + 1 :]), 1)
    return World(segments=world.segments, segment_mask=world.segment_mask, circles=circles, circle_mask=circle_mask, boxes=boxes, box_mask=box_mask, batch_size=[n], device=world.device)
