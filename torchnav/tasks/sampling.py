"""Batched reset sampling: start poses, goals and random objects, without loops over envs.

Each sampler draws ``K`` candidates per env at once, tests them all with one
batched geometry call, and keeps a valid one. When no candidate of an env is
valid, each sampler has a defined fallback (documented per function), so a
reset never blocks and never loops an unbounded number of times. Memory stays
bounded on maps with hundreds of obstacles (:func:`obstacle_clearance`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..maps import MapSpec
from ..maps.free_space import free_points
from ..maps.spec import RandomCircles, RandomMovers
from ..sim import World, pad_world, points_clearance
from ..sim.movers import BOX_FIELDS, PATROL, PEDESTRIAN, Movers
from ..sim.static_map import StaticMap, static_clearance
from ..worlds.layout import uniform

_BIG = 1e9
# Most elements of one (n, candidates, obstacles) distance temporary: 4 MB in float32, and the
# box distance keeps about ten such temporaries alive at once. Smaller chunks stay in cache and
# were faster on CPU (a full reset of 1024 envs on a 400-circle map, one thread: about 1 s at 2**20,
# 2 s at 2**22, 5 s and a 2.3 GB peak unchunked), while each chunk still fills a GPU kernel.
_CHUNK_ELEMENTS = 1 << 20


def obstacle_clearance(points: Tensor, world: World, static: StaticMap | None = None, floor: float | None = None) -> Tensor:
    """:func:`points_clearance` of ``points`` ``(n, P, 2)`` -> ``(n, P)`` m, in chunks along ``P`` so that
    no ``(n, chunk, obstacles)`` temporary exceeds ``_CHUNK_ELEMENTS`` (at least one point per chunk);
    with ``static``, the nearer of ``world``'s obstacles and the shared map's (``sim/static_map.py``).
    ``floor`` m: the shared map's part is exact only near ``floor``, elsewhere a bound on the same side
    of it (:func:`static_clearance`): enough to decide ``clearance >= floor``, not to rank points."""
    if static is not None:
        return torch.minimum(obstacle_clearance(points, world), static_clearance(static, points, _CHUNK_ELEMENTS, floor))
    n, p = points.shape[:2]
    per_point = n * max(world.segments.shape[1], world.circles.shape[1], world.boxes.shape[1], 1)
    step = max(1, _CHUNK_ELEMENTS // per_point)
    if step >= p:
        return points_clearance(points, world)
    return torch.cat([points_clearance(points[:, i : i + step], world) for i in range(0, p, step)], dim=1)


def _measured_where_stuck(clear: Tensor, ok: Tensor, cand: Tensor, world: World, static: StaticMap | None, need: float,
                          avoid: Tensor | None, avoid_need: float) -> Tensor:
    """``clear`` ``(n, K)`` (``_away`` of the candidates' clearance, measured with ``floor=need``), measured
    exactly in the rows where no candidate is ``ok``: the samplers' fallbacks rank those by clearance."""
    stuck = ~ok.any(dim=1)
    if static is None or not bool(stuck.any()):
        return clear
    rows = stuck.nonzero()[:, 0]
    exact = _away(cand[rows], obstacle_clearance(cand[rows], world[rows], static), need, None if avoid is None else avoid[rows], avoid_need)
    return clear.index_copy(0, rows, exact)


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


def _away(cand: Tensor, clear: Tensor, need: float, avoid: Tensor | None, avoid_need: float) -> Tensor:
    """``clear`` ``(n, K)`` lowered where a candidate lies closer than ``avoid_need`` m to a point of ``avoid``
    ``(n, J, 2)`` (the robots and goals placed before it), so that ``clear >= need`` also asks that gap."""
    if avoid is None or avoid.shape[1] == 0:
        return clear
    gap = (cand[:, :, None, :] - avoid[:, None, :, :]).norm(dim=-1).amin(-1)  # (n, K)
    return torch.minimum(clear, gap - avoid_need + need)


def sample_starts(world: World, spec: MapSpec, need: float, k: int, generator: torch.Generator,
                  avoid: Tensor | None = None, avoid_need: float = 0.0, static: StaticMap | None = None) -> tuple[Tensor, Tensor]:
    """Start poses ``(n, 3)`` whose position is at least ``need`` m from every obstacle of ``world``
    and from the world's edge, with a uniform random heading; with ``avoid`` ``(n, J, 2)``, also at
    least ``avoid_need`` m from each of those points (the other robots' starts: multi_navigation.py).

    Fallback: the free cell of ``spec``'s room grid (``maps.free_space.free_points``) nearest the
    candidate with the largest clearance, which the world's fixed obstacles leave free when
    ``world`` holds only ``spec``'s fixed obstacles. Also returns whether a valid candidate was
    found ``(n,)``. ``static``: the map's fixed obstacles when ``world`` holds only its per-env objects
    (``sim/static_map.py``).
    """
    n = world.batch_size[0]
    like = world.segments
    xmin, ymin, xmax, ymax = spec.bounds
    m = min(need, 0.49 * min(xmax - xmin, ymax - ymin))
    xy = torch.stack((uniform(xmin + m, xmax - m, (n, k), generator, like), uniform(ymin + m, ymax - m, (n, k), generator, like)), -1)
    clear = _away(xy, obstacle_clearance(xy, world, static, floor=need), need, avoid, avoid_need)
    clear = _measured_where_stuck(clear, clear >= need, xy, world, static, need, avoid, avoid_need)
    idx, found = _pick(clear >= need, clear)
    pos = _gather(xy, idx)
    if not bool(found.all()):
        # On a map with little room all candidates of an env can miss it, and the clearest of them
        # may overlap an obstacle: start there instead at the free cell of the map's room grid
        # nearest to it (drawing nothing, so every other env's episode is unchanged).
        free = torch.as_tensor(free_points(spec, need), dtype=pos.dtype, device=pos.device)
        if len(free):
            pos = torch.where(found[:, None], pos, free[torch.cdist(pos, free).argmin(1)])
    heading = uniform(-math.pi, math.pi, (n,), generator, like)
    return torch.cat((pos, heading[:, None]), dim=-1), found


def sample_goals(
    world: World, spec: MapSpec, start_xy: Tensor, r_min: float, r_max: Tensor, need: float, k: int, generator: torch.Generator,
    avoid: Tensor | None = None, avoid_need: float = 0.0, static: StaticMap | None = None,
) -> tuple[Tensor, Tensor]:
    """Goals ``(n, 2)`` at a distance in ``[r_min, r_max]`` from ``start_xy`` ``(n, 2)``, inside the
    world and at least ``need`` m from every obstacle (and ``avoid_need`` m from each point of ``avoid``
    ``(n, J, 2)``, and ``static`` as for :func:`sample_starts`).

    ``r_max`` is a 0-d tensor (the curriculum radius). Distance and direction are
    uniform. Fallback, in order: a valid goal drawn uniformly over the whole world
    ignoring the radius, else the candidate with the largest clearance.
    """
    n = start_xy.shape[0]
    like = start_xy
    hi = torch.maximum(r_max.to(like), torch.as_tensor(r_min, dtype=like.dtype, device=like.device))
    dist = uniform(r_min, hi, (n, k), generator, like)
    ang = uniform(-math.pi, math.pi, (n, k), generator, like)
    near = start_xy[:, None, :] + torch.stack((dist * torch.cos(ang), dist * torch.sin(ang)), -1)
    xmin, ymin, xmax, ymax = spec.bounds
    anywhere = torch.stack((uniform(xmin, xmax, (n, k), generator, like), uniform(ymin, ymax, (n, k), generator, like)), -1)
    cand = torch.cat((near, anywhere), dim=1)  # (n, 2k): near candidates first
    clear = _away(cand, obstacle_clearance(cand, world, static, floor=need), need, avoid, avoid_need)
    sep = (cand - start_xy[:, None, :]).norm(dim=-1)
    ok = (clear >= need) & _inside(cand, spec.bounds, need) & (sep >= r_min)
    clear = _measured_where_stuck(clear, ok, cand, world, static, need, avoid, avoid_need)
    score = torch.where(_inside(cand, spec.bounds, 0.0), clear, torch.full_like(clear, -_BIG / 4))
    # Prefer valid near candidates, then valid anywhere-candidates, then the clearest.
    prio = torch.cat((torch.full((n, k), 2.0, dtype=like.dtype, device=like.device), torch.ones((n, k), dtype=like.dtype, device=like.device)), 1)
    key = torch.where(ok, _BIG * prio, score.clamp(-_BIG / 2, _BIG / 2))
    idx = key.argmax(dim=1)
    return _gather(cand, idx), ok[:, :k].any(dim=1)


def _nearest(xy: Tensor, points: Tensor) -> Tensor:
    """Distance ``(n, m, k)`` of candidates ``xy`` ``(n, m, k, 2)`` to ``points`` ``(n, 2)``, or to the nearest
    of ``points`` ``(n, J, 2)`` (the starts or goals of several robots)."""
    if points.dim() == 2:
        return (xy - points[:, None, None]).norm(dim=-1)
    return (xy[..., None, :] - points[:, None, None]).norm(dim=-1).amin(-1)


def place_random_objects(
    world: World, spec: MapSpec, start_xy: Tensor, goal_xy: Tensor, k: int, generator: torch.Generator,
    *, start_need: float = 0.0, goal_need: float = 0.0, static: StaticMap | None = None,
) -> World:
    """Fill the random box and circle slots of ``world`` (batch ``n``) with fresh objects.

    Each object keeps ``max(clearance, start_need)`` m from the start point ``start_xy`` ``(n, 2)``
    (or from each of ``(n, J, 2)``: several robots), ``max(clearance, goal_need)`` m from the goal
    ``goal_xy`` (likewise) and ``margin`` m from every fixed obstacle, wall and object placed
    before it (tested on its circumscribed circle, so the guarantee is conservative).
    ``start_need``/``goal_need`` are the task's own clearances, which a map's smaller
    ``clearance`` must not undo. ``static``: the map's fixed obstacles when ``world`` holds only the
    random slots (``sim/static_map.py``).
    Fallback: an object with no valid candidate is left out of this episode (its
    slot is masked off).
    """
    n, like = start_xy.shape[0], start_xy
    rb, rcirc = spec.random_boxes, spec.random_circles
    nb, nc = (rb.count if rb else 0), (rcirc.count if rcirc else 0)
    nb0, nc0 = (spec.n_fixed_boxes, spec.n_fixed_circles) if static is None else (0, 0)
    if nb + nc == 0:
        return world
    # Forget the previous episode's random objects: candidates are tested against fixed obstacles only.
    fixed = world.replace(circle_mask=torch.cat((world.circle_mask[:, :nc0], torch.zeros_like(world.circle_mask[:, nc0:])), 1),
                          box_mask=torch.cat((world.box_mask[:, :nb0], torch.zeros_like(world.box_mask[:, nb0:])), 1))
    xmin, ymin, xmax, ymax = spec.bounds
    m = nb + nc
    # All candidates of all objects at once: (n, m, k).
    xy = torch.stack((uniform(xmin, xmax, (n, m, k), generator, like), uniform(ymin, ymax, (n, m, k), generator, like)), -1)
    parts_r = []
    if nb:
        hx = uniform(rb.size_x[0] / 2, rb.size_x[1] / 2, (n, nb, k), generator, like)
        hy = uniform(rb.size_y[0] / 2, rb.size_y[1] / 2, (n, nb, k), generator, like)
        yaw = uniform(rb.yaw[0], rb.yaw[1], (n, nb, k), generator, like)
        parts_r.append(torch.hypot(hx, hy))
    if nc:
        rad = uniform(rcirc.radius[0], rcirc.radius[1], (n, nc, k), generator, like)
        parts_r.append(rad)
    rc = torch.cat(parts_r, 1)  # circumscribed radius (n, m, k)
    per_obj = ([(rb.clearance, rb.margin)] * nb if nb else []) + ([(rcirc.clearance, rcirc.margin)] * nc if nc else [])
    clear = torch.tensor([max(c, start_need) for c, _ in per_obj], dtype=like.dtype, device=like.device)[None, :, None]
    clear_g = torch.tensor([max(c, goal_need) for c, _ in per_obj], dtype=like.dtype, device=like.device)[None, :, None]
    margin = torch.tensor([mg for _, mg in per_obj], dtype=like.dtype, device=like.device)[None, :, None]
    gap = obstacle_clearance(xy.reshape(n, m * k, 2), fixed, static).reshape(n, m, k) - rc
    ok = (
        (gap >= margin)
        & (_nearest(xy, start_xy) - rc >= clear)
        & (_nearest(xy, goal_xy) - rc >= clear_g)
        & _inside(xy, spec.bounds, 0.0) & _inside(xy, spec.bounds, rc.clamp(min=0))
    )
    # Objects in order, each keeping `margin` from the circumscribed circles of those placed before it.
    centres, radii, found_all, chosen = [], [], [], []
    for j in range(m):
        okj = ok[:, j]
        if centres:
            c = torch.stack(centres, 1)  # (n, j, 2)
            sep = (xy[:, j, :, None] - c[:, None]).norm(dim=-1) - rc[:, j, :, None] - torch.stack(radii, 1)[:, None]  # (n, k, j)
            clash = (sep < margin[0, j, 0]) & torch.stack(found_all, 1)[:, None]
            okj = okj & ~clash.any(-1)
        idx, found = _pick(okj, gap[:, j])
        centres.append(_gather(xy[:, j], idx))
        radii.append(_gather(rc[:, j], idx))
        found_all.append(found)
        chosen.append(idx)
    boxes, box_mask = fixed.boxes, fixed.box_mask
    if nb:
        idx = torch.stack(chosen[:nb], 1)[..., None]  # (n, nb, 1)
        pick = lambda t: t.gather(2, idx)[..., 0]  # noqa: E731
        new = torch.stack((*torch.stack(centres[:nb], 1).unbind(-1), pick(hx), pick(hy), pick(yaw)), -1)
        boxes = torch.cat((boxes[:, :nb0], new, boxes[:, nb0 + nb :]), 1)
        box_mask = torch.cat((box_mask[:, :nb0], torch.stack(found_all[:nb], 1), box_mask[:, nb0 + nb :]), 1)
    circles, circle_mask = fixed.circles, fixed.circle_mask
    if nc:
        idx = torch.stack(chosen[nb:], 1)[..., None]
        new = torch.cat((torch.stack(centres[nb:], 1), rad.gather(2, idx)), -1)
        circles = torch.cat((circles[:, :nc0], new, circles[:, nc0 + nc :]), 1)
        circle_mask = torch.cat((circle_mask[:, :nc0], torch.stack(found_all[nb:], 1), circle_mask[:, nc0 + nc :]), 1)
    return world.replace(circles=circles, circle_mask=circle_mask, boxes=boxes, box_mask=box_mask)


@dataclass(frozen=True)
class _MoverPlacement:
    """What :func:`place_random_objects` reads of a map, set up to place movers as its random circles:
    every existing slot counts as fixed, and the movers' region is the bounds."""

    n_fixed_boxes: int
    n_fixed_circles: int
    bounds: tuple[float, float, float, float]
    random_circles: RandomCircles
    random_boxes: None = None


@dataclass(frozen=True)
class MoverSource:
    """What :func:`place_movers` reads of a map, for movers that are not a map's: the procedural
    worlds' ``worlds.movers`` inside each env's bounds (each edge a tensor broadcasting to ``(n, 1, 1)``)."""

    movers: RandomMovers
    bounds: tuple


def place_movers(
    world: World, spec: MapSpec | MoverSource, start_xy: Tensor, goal_xy: Tensor, k: int, generator: torch.Generator,
    *, start_need: float = 0.0, goal_need: float = 0.0, static: StaticMap | None = None,
) -> Movers:
    """The map's movers (``moving_circles`` or ``moving_boxes``) for a batch ``n`` of episodes (``rows (n, M, 9)``, ``mask (n, M)``,
    ``plan`` and ``boxes``: ``(n, M, 3)`` for ``moving_boxes``, every mover a box; ``(n, 0, 3)`` for discs).

    Positions are placed like random circles (:func:`place_random_objects`: ``clearance`` from
    the start and the goal, or from every robot's of ``(n, J, 2)`` starts and goals, ``margin`` from every obstacle of ``world``, including this
    episode's random objects, and from each other; inside the region); a mover with no valid
    candidate is left out (masked off). Headings are uniform, speeds uniform in ``speed``;
    patrols and pedestrians get ``waypoints`` points uniform in the region (shrunk by
    their radius) and head for the first. ``static`` as for :func:`place_random_objects`.
    """
    mc = spec.movers
    n, like = start_xy.shape[0], start_xy
    region = mc.region or spec.bounds
    shim = _MoverPlacement(world.boxes.shape[1], world.circles.shape[1], region,
                           RandomCircles(count=mc.count, radius=mc.radius, clearance=mc.clearance, margin=mc.margin))
    placed = place_random_objects(pad_world(world, circles=world.circles.shape[1] + mc.count), shim, start_xy, goal_xy, k, generator,
                                  start_need=start_need, goal_need=goal_need, static=static)
    disc, mask = placed.circles[:, -mc.count:], placed.circle_mask[:, -mc.count:]
    heading = uniform(-math.pi, math.pi, (n, mc.count), generator, like)
    speed = uniform(mc.speed[0], mc.speed[1], (n, mc.count), generator, like)
    box = (-math.inf, -math.inf, math.inf, math.inf) if mc.motion == "constant" else region
    box = torch.stack([torch.as_tensor(e, dtype=like.dtype, device=like.device).reshape(-1, 1).expand(n, mc.count) for e in box], -1)
    rows = torch.cat((disc[..., :2], torch.stack((speed * torch.cos(heading), speed * torch.sin(heading)), -1), disc[..., 2:3], box), -1)
    boxes = like.new_zeros(n, 0, len(BOX_FIELDS))
    if mc.size_x is not None:  # moving boxes, placed by the largest box's bounding circle
        hx, hy = (0.5 * uniform(lo, hi, (n, mc.count), generator, like) for lo, hi in (mc.size_x, mc.size_y))
        yaw = uniform(mc.yaw[0], mc.yaw[1], (n, mc.count), generator, like)
        rows = torch.cat((rows[..., :4], torch.hypot(hx, hy)[..., None], rows[..., 5:]), -1)
        boxes = torch.stack((hx, hy, yaw), -1)
        disc = torch.cat((disc[..., :2], rows[..., 4:5]), -1)  # waypoints keep each box's own bounding circle inside the region
    plan = like.new_zeros(n, mc.count, 0)
    if mc.motion in ("patrol", "pedestrian"):
        p, r = mc.waypoints, disc[..., 2:3]
        wx = region[0] + r + (region[2] - region[0] - 2 * r) * torch.rand((n, mc.count, p), generator=generator, dtype=like.dtype, device=like.device)
        wy = region[1] + r + (region[3] - region[1] - 2 * r) * torch.rand((n, mc.count, p), generator=generator, dtype=like.dtype, device=like.device)
        kind = PEDESTRIAN if mc.motion == "pedestrian" else PATROL
        head = torch.stack((torch.full_like(speed, kind), speed, torch.zeros_like(speed), torch.full_like(speed, p)), -1)
        plan = torch.cat((head, torch.stack((wx, wy), -1).flatten(-2)), -1)
    return Movers(rows, mask, plan, boxes)
