"""The simulator step as a short chain of named, pure stages.

``step(state, action, world, params) -> state`` changes nothing in place and
never synchronises with the host, so it can be differentiated, compiled with
``torch.compile`` and captured in CUDA graphs.

    limits -> kinematics -> odometry -> collision -> lidar
"""

from __future__ import annotations

import torch
from torch import Tensor

from .geometry import disc_clearance
from .kinematics import apply_limits, integrate, wheels_to_unicycle
from .lidar import lidar_scan
from .params import SimParams
from .state import SimState, World, check_world, planar_world


def check_action(action: Tensor, state: SimState) -> None:
    """Raise a ValueError if ``action`` is not a ``(B, 2)`` tensor matching the state's dtype and device."""
    if not isinstance(action, Tensor):
        raise TypeError(f"action must be a torch.Tensor, got {type(action).__name__}")
    b = state.pose.shape[0]
    if action.shape != (b, 2):
        raise ValueError(f"action must have shape ({b}, 2), got {tuple(action.shape)}")
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
    Returns:
        The new state; ``state`` is left untouched.
    """
    check_action(action, state)
    check_world(world, state.pose.shape[0], state.pose.dtype, state.pose.device)
    world = planar_world(world)
    cmd = wheels_to_unicycle(action, params.track_width) if wheel_speeds else action
    vel = apply_limits(cmd, state.vel, params)
    pose = integrate(state.pose, vel, params)
    odom = step_odometry(state.odom, vel, params, generator)
    clearance = disc_clearance(pose, world, params.robot_radius)
    return SimState(
        pose=pose,
        vel=vel,
        odom=odom,
        ranges=lidar_scan(pose, world, params.lidar, generator, unroll=unroll),
        clearance=clearance,
        collided=clearance <= 0,
        time=state.time + params.dt,
        batch_size=state.batch_size,
        device=state.device,
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
) -> SimState:
    """A state at ``pose`` ``(B, 3)`` at rest (or moving at ``vel`` ``(B, 2)``), with its lidar
    scan and clearance already computed. Odometry starts at the true pose."""
    if pose.dim() != 2 or pose.shape[-1] != 3:
        raise ValueError(f"pose must have shape (B, 3), got {tuple(pose.shape)}")
    b = pose.shape[0]
    check_world(world, b, pose.dtype, pose.device)
    if vel is None:
        vel = pose.new_zeros(b, 2)
    elif vel.shape != (b, 2) or vel.dtype != pose.dtype or vel.device != pose.device:
        raise ValueError(f"vel must be a ({b}, 2) tensor of the pose's dtype and device, got {vel.dtype} {tuple(vel.shape)} on {vel.device}")
    clearance = disc_clearance(pose, world, params.robot_radius)
    return SimState(
        pose=pose,
        vel=vel,
        odom=pose.clone(),  # not aliased with pose (aliasing makes torch.compile specialise)
        ranges=lidar_scan(pose, world, params.lidar),
        clearance=clearance,
        collided=clearance <= 0,
        time=pose.new_zeros(b),
        batch_size=[b],
        device=pose.device,
    )
