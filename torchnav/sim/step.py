"""The simulator step as a short chain of named, pure stages (docs/sim.md, "The step").

``step(state, action, world, params) -> state`` changes nothing in place and never synchronises
with the host, so it can be differentiated, compiled with ``torch.compile`` and captured in CUDA graphs."""

from __future__ import annotations

import torch
from torch import Tensor

from .camera import camera_depth
from .geometry import disc_clearance
from .imu import step_imu
from .kinematics import apply_limits, integrate, unicycle_to_wheels, wheels_to_unicycle
from .lidar import lidar_scan
from .movers import BOX_FIELDS, N_MOVER_FIELDS, Movers, check_mover_boxes, mover_major, mover_world, no_movers, step_movers
from .params import SimParams
from .randomize import EnvParams
from .state import SimState, World, check_world, planar_world
from .static_map import StaticMap, static_reach, with_static


def check_action(action: Tensor, state: SimState) -> None:
    """Raise a ValueError if ``action`` is not a ``(B, 2)`` tensor (``(B, N, 2)`` for a state of batch
    ``(B, N)``, ``robots.py``) matching the state's dtype and device."""
    if not isinstance(action, Tensor):
        raise TypeError(f"action must be a torch.Tensor, got {type(action).__name__}")
    want = (*state.pose.shape[:-1], 2)
    if action.shape != want:
        raise ValueError(f"action must have shape {want}, got {tuple(action.shape)}")
    if action.dtype != state.pose.dtype:
        raise ValueError(f"action has dtype {action.dtype}, expected {state.pose.dtype} (the state's dtype)")
    if action.device != state.pose.device:
        raise ValueError(f"action is on {action.device}, expected {state.pose.device} (the state's device)")


def step(
    state: SimState,
    action: Tensor,
    world: World,
    params: SimParams,
    *,
    wheel_speeds: bool = False,
    generator: torch.Generator | None = None,
    unroll: bool | None = None,
    env_params: EnvParams | None = None,
    static: StaticMap | None = None,
) -> SimState:
    """Advance every env by ``params.dt``.

    Args:
        state: current state, batch ``B``.
        action: ``(B, 2)`` twist command ``[v m/s, omega rad/s]`` or, with
            ``wheel_speeds=True``, ``[v_left, v_right]`` in m/s. Non-finite entries are
            treated as 0 (stop); see ``kinematics.apply_limits``.
        world: obstacles, batch ``B``.
        params: robot, integrator and lidar parameters.
        generator: source of odometry and lidar noise; without one the step is noise-free.
        unroll: the lidar's every-ray reduction (``raycast.py``): a running minimum over
            obstacle slots (True), one ``(B, R, N)`` minimum (False), or chosen per set of
            slots by its size (None, the default); the result is the same up to rounding.
        env_params: per-env limits, actuator delay, wheel noise, lidar imperfections and
            robot radius (``randomize.py``) instead of ``params``' values.
        static: a map's fixed obstacles shared by the whole batch (``static_map.py``), seen in
            addition to ``world``'s per-env obstacles, with the same readings as if every env's
            ``world`` held them.
    Returns:
        The new state; ``state`` is left untouched.
    """
    check_action(action, state)
    check_world(world, state.pose.shape[0], state.pose.dtype, state.pose.device)
    world = planar_world(world)
    pose, vel, odom, imu, imu_bias, queue = _drive(state, action, params, wheel_speeds, generator, env_params)
    radius = params.robot_radius if env_params is None else env_params.robot_radius
    rows, target = step_movers(state.movers, state.mover_plan, state.mover_mask, params.dt, state.pose[:, :2], radius, state.mover_target)
    movers = Movers(rows, state.mover_mask, state.mover_plan, state.mover_boxes)  # the plan is carried unchanged
    return _sense(pose, vel, odom, state.time + params.dt, imu, imu_bias, movers, target, queue, world, params, generator, unroll, env_params,
                  static=static)


def _drive(state: SimState, action: Tensor, params: SimParams, wheel_speeds: bool = False, generator: torch.Generator | None = None,
          env_params: EnvParams | None = None, frozen: Tensor | None = None) -> tuple[Tensor, ...]:
    """The robot's part of the step: actuator delay, limits, wheel noise, kinematics, odometry and IMU.

    Returns ``(pose, vel, odom, imu, imu_bias, cmd_queue)`` after the step, each ``(B, ...)`` as in
    :class:`SimState`. ``frozen`` ``(B,)`` bool marks robots that do not move (parked or absent
    robots of ``robots.step_robots``): their command is replaced by 0, their applied twist is 0 and
    their pose and odometry stay as they were (random draws are made for them all the same, so the
    other rows' noise does not depend on which are frozen)."""
    cmd = wheels_to_unicycle(action, params.track_width) if wheel_speeds else action
    if frozen is not None:
        cmd = torch.where(frozen[:, None], 0.0, cmd)
    queue = state.cmd_queue
    if queue.shape[1]:  # actuator delay: apply the command of `delay` steps ago
        cmd = torch.where(torch.isfinite(cmd), cmd, 0.0)  # a non-finite command waits in the queue as the stop it is (apply_limits)
        full = torch.cat((cmd[:, None], queue), 1)  # (B, K + 1, 2), newest first
        delay = env_params.delay.clamp(0, queue.shape[1]) if env_params is not None else torch.zeros_like(cmd[:, 0], dtype=torch.int64)
        cmd, queue = full.gather(1, delay[:, None, None].expand(-1, 1, 2)).squeeze(1), full[:, :-1]
    vel = apply_limits(cmd, state.vel, params, env_params)
    if env_params is not None and generator is not None:  # wheel-speed noise: the robot really moves so
        wheels = unicycle_to_wheels(vel, params.track_width)
        wheels = wheels + env_params.wheel_noise[:, None] * torch.randn(wheels.shape, generator=generator, dtype=wheels.dtype, device=wheels.device)
        vel = wheels_to_unicycle(wheels, params.track_width)
    if frozen is not None:  # a frozen robot stands still, whatever its queue, limits and noise say
        vel = torch.where(frozen[:, None], 0.0, vel)
    pose = integrate(state.pose, vel, params)
    odom = step_odometry(state.odom, vel, params, generator)
    if frozen is not None:  # kept as they were (integrating a zero twist would re-wrap the heading)
        pose, odom = torch.where(frozen[:, None], state.pose, pose), torch.where(frozen[:, None], state.odom, odom)
    imu, imu_bias = state.imu, state.imu_bias
    if params.imu is not None:
        imu, imu_bias = step_imu(imu, imu_bias, vel, state.vel, state.time, params.imu, params.dt, generator)
    return pose, vel, odom, imu, imu_bias, queue


def _sense(pose, vel, odom, time, imu, imu_bias, movers: Movers, target, queue, world, params, generator=None, unroll=None,
           env: EnvParams | None = None, seen: World | None = None, present: Tensor | None = None, static: StaticMap | None = None) -> SimState:
    """The state at ``pose`` with its collision, lidar and camera readings (movers included; ``target``
    the waypoint index each patrol and pedestrian heads for).

    ``seen``, a world of batch ``B``, replaces the movers' own world as what moves around the robots
    (``robots.py``: each robot's movers and other robots); ``present`` ``(B,)`` bool marks the robots
    that exist: the others read ``clearance`` +inf and never collide. ``static``: the shared fixed
    obstacles, added to ``world`` near each robot."""
    if static is not None:  # the shared map's reach lists join each env's world (the lidar marches past them)
        need = static_reach(params, march=True)
        if static.reach < need - 1e-9:
            raise ValueError(f"static map: its reach lists reach {static.reach:g} m, these sensors need {need:g} m "
                             "(build_static_map(..., reach=static_reach(params)))")
        world = with_static(world, static, pose[:, :2])
    mw = seen if seen is not None else mover_world(movers.rows, movers.mask, movers.boxes) if movers.rows.shape[1] else None
    radius = params.robot_radius if env is None else env.robot_radius
    clearance = disc_clearance(pose, world, radius)
    if mw is not None:
        clearance = torch.minimum(clearance, disc_clearance(pose, mw, radius))
    if present is not None:
        clearance = torch.where(present, clearance, torch.inf)
    if env is None:
        ranges = lidar_scan(pose, world, params.lidar, generator, unroll=unroll, movers=mw, static=static)
    else:  # a misaligned sensor, per-env noise and dropout, a shorter range
        turned = torch.cat((pose[:, :2], pose[:, 2:] + env.angle_offset[:, None]), -1)
        ranges = lidar_scan(turned, world, params.lidar, generator, unroll=unroll, movers=mw, static=static)
        far = env.max_range[:, None]
        if generator is not None:
            ranges = ranges + env.range_noise[:, None] * torch.randn(ranges.shape, generator=generator, dtype=ranges.dtype, device=ranges.device)
            drop = torch.rand(ranges.shape, generator=generator, dtype=ranges.dtype, device=ranges.device) < env.dropout[:, None]
            ranges = torch.where(drop, far, ranges)
        ranges = torch.minimum(ranges.clamp(min=params.lidar.min_range), far)
    depth = camera_depth(pose, world, params.camera, mw) if params.camera is not None else pose.new_zeros(pose.shape[0], 0)
    return SimState(
        pose=pose, vel=vel, odom=odom, ranges=ranges, clearance=clearance, collided=clearance <= 0, time=time,
        imu=imu, imu_bias=imu_bias, cam_depth=depth, movers=movers.rows, mover_mask=movers.mask, mover_plan=movers.plan,
        mover_boxes=movers.boxes, mover_target=target,
        cmd_queue=queue, batch_size=[pose.shape[0]], device=pose.device,
    )


def step_odometry(odom: Tensor, vel: Tensor, params: SimParams, generator: torch.Generator | None) -> Tensor:
    """Dead-reckoning estimate: integrate the applied twist plus per-step Gaussian noise."""
    if generator is not None and (params.odom_v_noise > 0 or params.odom_omega_noise > 0):
        std = torch.tensor((params.odom_v_noise, params.odom_omega_noise), dtype=vel.dtype, device=vel.device)
        vel = vel + std * torch.randn(vel.shape, generator=generator, dtype=vel.dtype, device=vel.device)
    return integrate(odom, vel, params)


def init_state(
    pose: Tensor,
    world: World,
    params: SimParams,
    vel: Tensor | None = None,
    movers: Movers | tuple[Tensor, Tensor] | None = None,
    env_params: EnvParams | None = None,
    delay_steps: int = 0,
    static: StaticMap | None = None,
) -> SimState:
    """A state at ``pose`` ``(B, 3)`` at rest (or moving at ``vel`` ``(B, 2)``), with its lidar
    scan, clearance and camera depth already computed. Odometry starts at the true pose; the
    IMU reads zero with zero bias. ``movers`` is a :class:`~torchnav.sim.movers.Movers`
    (``make_movers``), or a pair ``(rows (B, M, 9), mask (B, M))`` of ballistic discs;
    ``None`` means no moving obstacles. ``env_params`` (``randomize.py``) gives per-env
    radius and lidar imperfections for the first scan and clearance; ``delay_steps`` is the
    length of the command queue of the actuator delay (the longest delay), filled with
    zeros (the robot is told to stand). ``static``: a map's fixed obstacles shared by the batch, as for :func:`step`."""
    if pose.dim() != 2 or pose.shape[-1] != 3:
        raise ValueError(f"pose must have shape (B, 3), got {tuple(pose.shape)}")
    b = pose.shape[0]
    check_world(world, b, pose.dtype, pose.device)
    if vel is None:
        vel = pose.new_zeros(b, 2)
    elif vel.shape != (b, 2) or vel.dtype != pose.dtype or vel.device != pose.device:
        raise ValueError(f"vel must be a ({b}, 2) tensor of the pose's dtype and device, got {vel.dtype} {tuple(vel.shape)} on {vel.device}")
    rows, mask, plan, boxes, target = _canonical_movers(movers, b, pose)
    n_imu = 0 if params.imu is None else 3
    return _sense(
        pose, vel, pose.clone(),  # odom not aliased with pose (aliasing makes torch.compile specialise)
        pose.new_zeros(b), pose.new_zeros(b, n_imu), pose.new_zeros(b, n_imu), Movers(rows, mask, plan, boxes), target,
        pose.new_zeros(b, delay_steps, 2), world, params, env=env_params, static=static,
    )


def _canonical_movers(movers: Movers | tuple[Tensor, Tensor] | None, b: int, pose: Tensor) -> tuple[Tensor, ...]:
    """``init_state``'s ``movers`` checked and stored in the layout the step returns: ``(rows, mask,
    plan, boxes, target)`` (``SimState``'s mover fields)."""
    if movers is None:
        movers = no_movers(b, pose)
    if len(movers) == 2:
        movers = Movers(*movers, movers[0].new_zeros(b, movers[0].shape[1], 0))
    rows, mask, plan, boxes = Movers(*movers)
    if boxes is None:
        boxes = rows.new_zeros(b, 0, len(BOX_FIELDS))
    if plan.dim() != 3 or plan.shape[:2] != rows.shape[:2] or (plan.shape[2] and (plan.shape[2] < 6 or plan.shape[2] % 2)):
        raise ValueError(f"movers.plan must be ({b}, M, 4 + 2P) with P >= 1, or ({b}, M, 0), got {tuple(plan.shape)}")
    if rows.dim() != 3 or rows.shape[0] != b or rows.shape[2] != N_MOVER_FIELDS or mask.shape != rows.shape[:2] or mask.dtype != torch.bool:
        raise ValueError(f"movers must be a ({b}, M, {N_MOVER_FIELDS}) tensor and a ({b}, M) bool mask, got {tuple(rows.shape)} and {mask.dtype} {tuple(mask.shape)}"
                         + (" (moving boxes' half extents and yaw now go in Movers.boxes, (B, K, 3))" if rows.dim() == 3 and rows.shape[2] == 12 else ""))
    check_mover_boxes(boxes, b, rows.shape[1])
    if rows.dtype != pose.dtype or rows.device != pose.device or boxes.dtype != pose.dtype or boxes.device != pose.device:
        raise ValueError(f"movers must have the pose's dtype and device, got {rows.dtype} on {rows.device} (boxes {boxes.dtype} on {boxes.device})")
    if plan.numel() == 0:  # canonical strides for an empty plan (an expanded one would make torch.compile recompile)
        plan, target = rows.new_zeros(plan.shape), rows.new_zeros(b, 0)
    else:  # the first waypoint to head for, stored (M, B) like the target the step returns (not a view of the plan)
        plan = mover_major(plan.to(rows.dtype))
        target = plan[..., 2].t().clone().t()
    if rows.shape[1]:  # the layout step_movers returns: the first step reads the same strides as the next ones
        rows = mover_major(rows)
    boxes = mover_major(boxes) if boxes.shape[1] else rows.new_zeros(boxes.shape)  # carried unchanged by every step
    return rows, mask, plan, boxes, target
