"""Several differential-drive robots per env in one world (docs/sim.md, "Several robots").

The ``N`` robots of ``B`` envs are ``B * N`` rows of the single-robot simulator, row ``b * N + i``
robot ``i`` of env ``b``: every stage of ``step.py`` (actuator delay, limits, wheel noise,
kinematics, odometry, IMU, lidar rays and exact sector scan, clearance, camera) runs on those rows
as it runs on ``B * N`` single-robot envs. What is new is what a row sees besides the static world:
the movers of its env and the other robots of its env, as discs of their radius (its own disc
excluded), gathered into one small world of circles and boxes per row (:func:`seen_world`) that
takes the place of the movers' world of the single-robot step. A robot-robot contact so makes the
clearance of both robots <= 0: both are collided.

The state (:class:`RobotsState`) holds the robots as a ``SimState`` of batch ``(B, N)`` (its
tensors are the rows, viewed ``(B, N, ...)``) and the movers, which belong to the env, once per
env: stepped once per env, they push their pedestrians away from every present robot.

``Robots`` says which robots exist (``present``: envs of one batch may hold fewer than ``N``;
an absent robot does not move, is seen by nothing and never collides) and which are ``parked``
(a parked robot ignores its action and stands still, but stays an obstacle that the others see
and can hit).
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import torch
from tensordict import tensorclass
from torch import Tensor

from .math import safe_hypot
from .movers import Movers, mover_world, no_movers, step_movers
from .params import SimParams
from .randomize import EnvParams
from .state import _KIND_MASKS, SimState, World, check_world, planar_rows, planar_world
from .step import _canonical_movers, _drive, _sense, check_action


class Robots(NamedTuple):
    """Which of the ``N`` robot slots of each env exist and which stand still, each ``(B, N)`` bool."""

    present: Tensor  # the robot exists: it moves, is seen and can collide
    parked: Tensor  # the robot ignores its action and stands still, but is seen and can be hit


@tensorclass
class RobotsState:
    """``B`` envs of ``N`` robots each: the robots as one ``SimState`` of batch ``(B, N)`` (every field
    of docs/sim.md, "State and units", with a robot axis; no mover slots of their own), and the env's
    movers, ``(B, ...)`` as the ``SimState`` mover fields of the single-robot step."""

    robots: SimState  # batch (B, N): pose (B, N, 3), ranges (B, N, n_rays), clearance (B, N), ...
    movers: Tensor  # (B, M, 9) moving obstacles (movers.py)
    mover_mask: Tensor  # (B, M) bool
    mover_plan: Tensor  # (B, M, 4 + 2P) or (B, M, 0)
    mover_target: Tensor  # (B, M) or (B, 0)
    mover_boxes: Tensor  # (B, K, 3)


def make_robots(batch_size: int, n: int, counts: Sequence[int] | Tensor | None = None,
                device: torch.device | str | None = None) -> Robots:
    """``n`` robot slots per env, none parked: all present, or in env ``b`` the first ``counts[b]``
    (``counts`` ``(B,)``, each in ``[0, n]``)."""
    if not isinstance(n, int) or n < 1:
        raise ValueError(f"robots: n must be a positive int, got {n!r}")
    present = torch.ones(batch_size, n, dtype=torch.bool, device=device)
    if counts is not None:
        c = torch.as_tensor(counts, device=device)
        if c.shape != (batch_size,) or c.is_floating_point() or bool(((c < 0) | (c > n)).any()):
            raise ValueError(f"robots: counts must be {batch_size} whole numbers in [0, {n}], got {counts!r}")
        present = torch.arange(n, device=device) < c[:, None]
    return Robots(present, torch.zeros_like(present))


def check_robots(robots: Robots, batch_size: int, n: int, device: torch.device) -> None:
    """Raise a ValueError naming the field of ``robots`` that is not a ``(batch_size, n)`` bool tensor on ``device``."""
    if not isinstance(robots, Robots):
        raise TypeError(f"robots must be a Robots (make_robots), got {type(robots).__name__}")
    for name, t in zip(Robots._fields, robots):
        if not isinstance(t, Tensor) or t.shape != (batch_size, n) or t.dtype != torch.bool or t.device != device:
            got = f"{t.dtype} {tuple(t.shape)} on {t.device}" if isinstance(t, Tensor) else type(t).__name__
            raise ValueError(f"robots.{name} must be a ({batch_size}, {n}) bool tensor on {device}, got {got}")


def robot_world(world: World, n: int) -> World:
    """``world`` (batch ``B``) with each env's obstacles repeated for its ``n`` robot rows: a world of batch
    ``B * n`` (row ``b * n + i`` holds env ``b``'s obstacles), stored component-major like
    ``planar_world``. ``step_robots`` makes it from a world of batch ``B`` at every call; a caller that
    steps one static world many times makes it once and passes it instead (the same results)."""
    out = {}
    for key, mkey, _ in _KIND_MASKS:
        t, m = planar_rows(getattr(world, key)), getattr(world, mkey)
        b, s, k = t.shape
        out[key] = t.permute(2, 0, 1)[:, :, None].expand(k, b, n, s).reshape(k, b * n, s).permute(1, 2, 0)
        out[mkey] = m[:, None].expand(b, n, s).reshape(b * n, s)
    return World(**out, batch_size=[world.batch_size[0] * n], device=world.device)


def seen_world(xy: Tensor, radius: float | Tensor, present: Tensor, movers: World | None = None) -> World | None:
    """What moves around each robot row: a world of batch ``B * N`` whose circles are the env's moving
    discs followed by the ``N - 1`` other robots, and whose boxes are the env's moving boxes.

    ``xy`` ``(B, N, 2)`` robot positions (m), ``radius`` m or ``(B, N)``, ``present`` ``(B, N)`` bool
    (absent robots are masked off), ``movers`` the env's movers as a world of batch ``B``
    (``mover_world``; ``None``: none). Row ``b * N + i``'s robot slot ``s`` (``1 <= s < N``) holds
    robot ``(i + s) mod N``, so no robot meets its own disc and no slot is spent on it. ``None``
    when nothing moves (one robot, no movers). Built by one gather per component: ``(B * N, M + N - 1)``
    slots, the discs the lidar and clearance test anyway."""
    b, n = present.shape
    md = 0 if movers is None else movers.circles.shape[1]
    k = 0 if movers is None else movers.boxes.shape[1]
    if n == 1 and md == 0 and k == 0:
        return None
    r = radius if isinstance(radius, Tensor) else torch.full_like(xy[..., 0], radius)
    comps, mask = [xy[..., 0], xy[..., 1], r.to(xy.dtype)], present
    if md:
        comps = [torch.cat((movers.circles[..., c], comps[c]), 1) for c in range(3)]
        mask = torch.cat((movers.circle_mask, present), 1)
    robot = torch.arange(n, device=xy.device)
    slot = torch.cat((torch.arange(md, device=xy.device).expand(n, md), md + (robot[:, None] + robot[None, 1:]) % n), 1)  # (N, M + N - 1)
    circles = torch.stack([c[:, slot].reshape(b * n, -1) for c in comps], 0).permute(1, 2, 0)  # component-major
    circle_mask = mask[:, slot].reshape(b * n, -1)
    if k:
        boxes = torch.stack([movers.boxes[..., c][:, None].expand(b, n, k).reshape(b * n, k) for c in range(5)], 0).permute(1, 2, 0)
        box_mask = movers.box_mask[:, None].expand(b, n, k).reshape(b * n, k)
    else:
        boxes, box_mask = xy.new_zeros(b * n, 0, 5), present.new_zeros(b * n, 0)
    return World(segments=xy.new_zeros(b * n, 0, 4), segment_mask=present.new_zeros(b * n, 0), circles=circles,
                 circle_mask=circle_mask, boxes=boxes, box_mask=box_mask, batch_size=[b * n], device=xy.device)


def robot_clearance(xy: Tensor, radius: float | Tensor, present: Tensor) -> Tensor:
    """``(B, N)`` signed gap (m) between each robot's disc and the nearest other present robot's disc of its
    env (negative when they overlap); ``+inf`` for an absent robot and for one with no other present robot.

    ``xy`` ``(B, N, 2)`` (m), ``radius`` m or ``(B, N)``, ``present`` ``(B, N)`` bool. The robot-robot part
    of ``SimState.clearance`` (which also counts the world and the movers): a task tells a robot-robot
    collision from others by it."""
    b, n = present.shape
    if n == 1:
        return torch.full_like(xy[..., 0], torch.inf)
    r = radius if isinstance(radius, Tensor) else torch.full_like(xy[..., 0], radius)
    robot = torch.arange(n, device=xy.device)
    other = (robot[:, None] + robot[None, 1:]) % n  # (N, N - 1): robot i's others, as in seen_world
    x, y = xy[..., 0], xy[..., 1]
    gap = safe_hypot(x[:, other] - x[..., None], y[:, other] - y[..., None]) - r[:, other] - r[..., None]
    gap = torch.where(present[:, other], gap, torch.inf).amin(-1)
    return torch.where(present, gap, torch.inf)


def _row_world(world: World, b: int, n: int, like: Tensor) -> World:
    """The static world of every robot row (batch ``B * N``), from a world of batch ``B`` or ``B * N``."""
    size = world.batch_size[0] if len(world.batch_size) else None
    if size == b * n:
        check_world(world, b * n, like.dtype, like.device)
        return planar_world(world)
    if size != b:
        raise ValueError(f"world must have batch {b} (one per env) or {b * n} (robot_world: one per robot), got {tuple(world.batch_size)}")
    check_world(world, b, like.dtype, like.device)
    return robot_world(world, n)


def _row_env_params(env_params: EnvParams | None, b: int, n: int) -> EnvParams | None:
    if env_params is None:
        return None
    if tuple(env_params.batch_size) != (b, n):
        raise ValueError(f"env_params must have batch ({b}, {n}), one row per robot (sample_env_params(..., {b * n}, ...).reshape({b}, {n})), "
                         f"got {tuple(env_params.batch_size)}")
    return env_params.reshape(b * n)


def _radius(params: SimParams, env_params: EnvParams | None) -> float | Tensor:
    """Every robot's radius: m, or ``(B, N)`` with per-robot ``env_params``."""
    return params.robot_radius if env_params is None else env_params.robot_radius


def init_robots(
    pose: Tensor,
    world: World,
    params: SimParams,
    robots: Robots | None = None,
    vel: Tensor | None = None,
    movers: Movers | tuple[Tensor, Tensor] | None = None,
    env_params: EnvParams | None = None,
    delay_steps: int = 0,
) -> RobotsState:
    """``N`` robots per env at ``pose`` ``(B, N, 3)``, at rest (or moving at ``vel`` ``(B, N, 2)``), with
    their lidar scans, clearances and camera depths already computed, as ``init_state`` makes one.

    ``world`` has batch ``B`` (or ``B * N``, :func:`robot_world`); ``robots`` says which robots exist
    and which are parked (``None``: all present, none parked); ``movers`` are the env's (batch ``B``,
    as for ``init_state``); ``env_params`` has batch ``(B, N)``, one row per robot."""
    if not isinstance(pose, Tensor) or pose.dim() != 3 or pose.shape[-1] != 3:
        raise ValueError(f"pose must have shape (B, N, 3), got {tuple(pose.shape) if isinstance(pose, Tensor) else type(pose).__name__}")
    b, n = pose.shape[:2]
    robots = make_robots(b, n, device=pose.device) if robots is None else robots
    check_robots(robots, b, n, pose.device)
    if vel is None:
        vel = pose.new_zeros(b, n, 2)
    elif vel.shape != (b, n, 2) or vel.dtype != pose.dtype or vel.device != pose.device:
        raise ValueError(f"vel must be a ({b}, {n}, 2) tensor of the pose's dtype and device, got {vel.dtype} {tuple(vel.shape)} on {vel.device}")
    world = _row_world(world, b, n, pose)
    rows, mask, plan, boxes, target = _canonical_movers(movers, b, pose)
    ep = _row_env_params(env_params, b, n)
    seen = seen_world(pose[..., :2], _radius(params, env_params), robots.present, mover_world(rows, mask, boxes) if rows.shape[1] else None)
    flat, m = pose.reshape(b * n, 3), b * n
    n_imu = 0 if params.imu is None else 3
    sim = _sense(
        flat, vel.reshape(m, 2), flat.clone(), pose.new_zeros(m), pose.new_zeros(m, n_imu), pose.new_zeros(m, n_imu),
        no_movers(m, pose), pose.new_zeros(m, 0), pose.new_zeros(m, delay_steps, 2), world, params, env=ep, seen=seen,
        present=robots.present.reshape(m),
    )
    return RobotsState(robots=sim.reshape(b, n), movers=rows, mover_mask=mask, mover_plan=plan, mover_target=target, mover_boxes=boxes,
                       batch_size=[b], device=pose.device)


def step_robots(
    state: RobotsState,
    action: Tensor,
    world: World,
    params: SimParams,
    robots: Robots,
    *,
    wheel_speeds: bool = False,
    generator: torch.Generator | None = None,
    unroll: bool | None = None,
    env_params: EnvParams | None = None,
) -> RobotsState:
    """Advance every robot of every env by ``params.dt``: ``step`` for ``N`` robots per env.

    Args:
        state: current state, ``B`` envs of ``N`` robots (:func:`init_robots`).
        action: ``(B, N, 2)`` twists ``[v m/s, omega rad/s]`` (or wheel speeds with ``wheel_speeds=True``);
            ignored for parked and absent robots.
        world: the static obstacles, batch ``B``, or batch ``B * N`` from :func:`robot_world`
            (made once for a world stepped many times).
        robots: which robots exist and which are parked, each ``(B, N)`` bool.
        generator, unroll: as for ``step``; the draws are those of ``step`` on the ``B * N`` robot rows.
        env_params: per-robot parameters, batch ``(B, N)``.
    Returns:
        The new state; ``state`` is left untouched. Absent robots keep their pose, odometry and
        zero twist, read ``clearance`` +inf and are never collided; their ranges are not meaningful.
    """
    group = state.robots
    b, n = group.batch_size
    device = group.pose.device
    check_robots(robots, b, n, device)
    check_action(action, group)
    world = _row_world(world, b, n, group.pose)
    ep = _row_env_params(env_params, b, n)
    flat = group.reshape(b * n)
    present = robots.present.reshape(b * n)
    pose, vel, odom, imu, imu_bias, queue = _drive(flat, action.reshape(b * n, 2), params, wheel_speeds, generator, ep,
                                                   frozen=~present | robots.parked.reshape(b * n))
    radius = _radius(params, env_params)
    movers, target = step_movers(state.movers, state.mover_plan, state.mover_mask, params.dt, group.pose[..., :2], radius,
                                 state.mover_target, robots.present)
    around = mover_world(movers, state.mover_mask, state.mover_boxes) if movers.shape[1] else None
    seen = seen_world(pose.reshape(b, n, 3)[..., :2], radius, robots.present, around)
    empty = Movers(flat.movers, flat.mover_mask, flat.mover_plan, flat.mover_boxes)  # the rows hold no movers of their own
    sim = _sense(pose, vel, odom, flat.time + params.dt, imu, imu_bias, empty, flat.mover_target, queue, world, params, generator, unroll,
                 ep, seen=seen, present=present)
    return RobotsState(robots=sim.reshape(b, n), movers=movers, mover_mask=state.mover_mask, mover_plan=state.mover_plan,
                       mover_target=target, mover_boxes=state.mover_boxes, batch_size=[b], device=device)
