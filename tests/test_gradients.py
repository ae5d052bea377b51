"""Differentiability: gradcheck on kinematics, lidar and clearance per obstacle kind, and
finite, non-zero gradients through long rollouts of ``step``."""

from __future__ import annotations

import math

import pytest
import torch
from torch.autograd import gradcheck

from params import lidar_params, sim_params
from reference import random_world
from torchnav.sim import (
    World,
    disc_clearance,
    init_state,
    integrate_euler,
    integrate_exact,
    lidar_scan,
    step,
)

F64 = torch.float64
WIDTH = {"segments": 4, "circles": 3, "boxes": 5}
MASK = {"segments": "segment_mask", "circles": "circle_mask", "boxes": "box_mask"}


def one_kind_world(kind: str, obs: torch.Tensor, batch: int) -> World:
    """A world holding ``obs`` ``(N, width)`` of one kind in every env (differentiable in ``obs``)."""
    fields = {}
    for k, w in WIDTH.items():
        t = obs.unsqueeze(0).expand(batch, *obs.shape) if k == kind else obs.new_zeros(batch, 0, w)
        fields[k] = t
        fields[MASK[k]] = torch.ones(batch, t.shape[1], dtype=torch.bool)
    return World(**fields, batch_size=[batch])


def leaf(x):
    return torch.tensor(x, dtype=F64, requires_grad=True)


# --------------------------------------------------------------------------- kinematics


@pytest.mark.parametrize("w", [0.0, 1e-8, 1e-3, 0.7, -1.3])
def test_gradcheck_integrators(w):
    pose = leaf([[0.3, -0.2, 0.4], [1.0, 2.0, -2.0]])
    twist = leaf([[0.5, w], [-0.3, -w]])
    assert gradcheck(lambda p, t: integrate_exact(p, t, 0.1), (pose, twist))
    assert gradcheck(lambda p, t: integrate_euler(p, t, 0.1), (pose, twist))


# --------------------------------------------------------------------------- lidar per obstacle kind

# Each case: an obstacle and robot poses from which a narrow fan of rays hits it well away from
# edges, corners and tangents (the scan is only piecewise smooth). The last pose is inside the
# obstacle where that is possible (the ray then reads the exit point).
LIDAR_CASES = {
    "segments": ([[2.0, -3.0, 2.5, 3.0], [6.0, -3.0, 6.0, 3.0]], [[0.1, 0.2, 0.1], [-0.5, -0.4, -0.2]]),
    "circles": ([[3.0, 0.2, 1.0], [7.0, 0.0, 0.5]], [[0.0, 0.0, 0.05], [-0.2, 0.3, -0.1], [3.1, 0.1, 0.5]]),
    "boxes": ([[3.0, 0.0, 0.5, 1.5, 0.3], [7.0, 0.0, 1.0, 4.0, 0.0]], [[0.0, 0.1, 0.0], [0.3, -0.3, 0.1], [3.1, 0.1, 0.4]]),
}
FAN = lidar_params(n_rays=5, fov=math.radians(16), max_range=20.0, offset=(0.05, 0.02, 0.03))


@pytest.mark.parametrize("unroll", [True, False], ids=["unrolled", "batched"])
@pytest.mark.parametrize("kind", list(LIDAR_CASES))
def test_gradcheck_lidar_per_kind(kind, unroll):
    obs_rows, poses = LIDAR_CASES[kind]
    obs, pose = leaf(obs_rows), leaf(poses)

    def f(pose, obs):
        return lidar_scan(pose, one_kind_world(kind, obs, pose.shape[0]), FAN, unroll=unroll)

    ranges = f(pose, obs)
    assert (ranges < FAN.max_range).all()  # every ray hits, so the check is not about zeros
    assert gradcheck(f, (pose, obs))
    # Both arguments really receive gradient, and only the nearest obstacle does.
    gp, go = torch.autograd.grad(ranges.sum(), (pose, obs))
    assert gp.abs().sum() > 0 and go[0].abs().sum() > 0 and go[1].abs().sum() == 0


def test_lidar_gradient_is_zero_for_misses_and_clamps():
    obs = leaf([[3.0, 0.0, 0.5]])
    pose = leaf([[0.0, 0.0, math.pi], [2.4, 0.0, 0.0]])  # looking away; and closer than min_range
    lidar = lidar_params(n_rays=3, fov=0.1, min_range=0.2, max_range=5.0)
    ranges = lidar_scan(pose, one_kind_world("circles", obs, 2), lidar)
    assert ranges[0].eq(5.0).all() and ranges[1].eq(0.2).all()
    gp, go = torch.autograd.grad(ranges.sum(), (pose, obs))
    assert torch.equal(gp, torch.zeros_like(gp)) and torch.equal(go, torch.zeros_like(go))


CLEARANCE_CASES = {
    "segments": ([[1.0, -1.0, 1.5, 2.0]], [[0.2, 0.3, 0.0], [2.0, 3.0, 1.0]]),  # interior and end point
    "circles": ([[1.0, 1.0, 0.5]], [[0.0, 0.0, 0.0], [1.2, 0.9, 0.0]]),  # outside and inside
    "boxes": ([[1.0, 0.5, 0.6, 0.3, 0.4]], [[0.0, -1.0, 0.0], [3.0, 2.0, 0.0], [1.05, 0.45, 0.0]]),  # face, corner, inside
}


@pytest.mark.parametrize("kind", list(CLEARANCE_CASES))
def test_gradcheck_clearance_per_kind(kind):
    obs_rows, poses = CLEARANCE_CASES[kind]
    obs, pose = leaf(obs_rows), leaf(poses)
    assert gradcheck(lambda p, o: disc_clearance(p, one_kind_world(kind, o, p.shape[0]), 0.2), (pose, obs))


# --------------------------------------------------------------------------- through step


PARAMS = sim_params(lin_acc_max=3.0, ang_acc_max=6.0, lidar=lidar_params(n_rays=16, fov=2 * math.pi, max_range=12.0))
ROLLOUT_CASES = {
    "segments": [[5.0, -4.0, 5.5, 4.0]],
    "circles": [[5.0, 1.0, 1.5]],
    "boxes": [[5.0, 0.5, 1.0, 2.0, 0.3]],
}


def rollout_loss(pose0, actions, world, params=PARAMS):
    # clamp: an env without obstacles has clearance +inf (with zero gradient).
    state = init_state(pose0, world, params)
    loss = state.ranges.mean() + 0.1 * state.clearance.clamp(max=20.0).sum()
    for a in actions:
        state = step(state, a, world, params)
        loss = loss + state.ranges.mean() + 0.1 * state.clearance.clamp(max=20.0).sum() + 0.01 * state.odom.sum()
    return loss, state


@pytest.mark.parametrize("kind", list(ROLLOUT_CASES))
def test_gradients_through_60_steps(kind):
    steps, batch = 60, 2
    obs = leaf(ROLLOUT_CASES[kind])
    pose0 = leaf([[0.0, 0.0, 0.1], [0.5, -1.0, -0.2]])
    g = torch.Generator().manual_seed(0)
    # Inside the speed limits, where the limiter passes gradient through.
    actions = (torch.stack((torch.full((steps, batch), 0.3), 0.3 * torch.rand(steps, batch, generator=g) - 0.15), -1)).to(F64)
    actions.requires_grad_(True)
    loss, final = rollout_loss(pose0, actions, one_kind_world(kind, obs, batch))
    assert torch.isfinite(final.clearance).all() and (final.ranges < 12.0).any()
    g_pose, g_act, g_obs = torch.autograd.grad(loss, (pose0, actions, obs))
    for name, grad in (("pose0", g_pose), ("actions", g_act), ("obstacle", g_obs)):
        assert torch.isfinite(grad).all(), name
        assert grad.abs().sum() > 0, name
    # Every step's action, in every env, influences the loss.
    assert (g_act.abs().sum(-1) > 0).all()


def test_gradcheck_short_rollout_through_step():
    obs = leaf([[3.0, 0.3, 1.0]])
    pose0 = leaf([[0.0, 0.0, 0.05]])
    actions = leaf([[[0.3, 0.1]], [[0.25, -0.2]], [[0.4, 0.0]]])
    params = sim_params(lin_acc_max=5.0, lidar=FAN)

    def f(p, a, o):
        world = one_kind_world("circles", o, 1)
        state = init_state(p, world, params)
        for t in range(a.shape[0]):
            state = step(state, a[t], world, params)
        return state.pose, state.ranges, state.clearance

    assert gradcheck(f, (pose0, actions, obs))


def _messy_world_and_poses():
    """All three kinds, masked slots, an empty env, and deliberately degenerate spots: a robot on a
    circle's centre and a lidar ray exactly parallel to an axis-aligned box's sides."""
    world = random_world(4, (2, 3, 3), seed=3, dtype=F64)
    world.circles[2, 0] = torch.tensor([1.0, 1.0, 0.5], dtype=F64)
    world.circle_mask[2, 0] = True
    world.boxes[3, 0] = torch.tensor([3.0, 0.0, 0.5, 0.5, 0.0], dtype=F64)
    world.box_mask[3, 0] = True
    world.segment_mask[1] = False
    world.circle_mask[1] = False
    world.box_mask[1] = False
    pose0 = torch.tensor([[0.0, 0.0, 0.3], [1.0, 1.0, 0.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]], dtype=F64)
    return world, pose0


@pytest.mark.filterwarnings("ignore:Anomaly Detection has been enabled")
def test_backward_is_nan_free_in_messy_worlds():
    world, pose0 = _messy_world_and_poses()
    world = world.clone()
    world.circles.requires_grad_(True)
    world.boxes.requires_grad_(True)
    world.segments.requires_grad_(True)
    pose0.requires_grad_(True)
    actions = torch.tensor([0.2, 0.1], dtype=F64).repeat(8, 4, 1).requires_grad_(True)
    with torch.autograd.detect_anomaly(check_nan=True):
        loss, final = rollout_loss(pose0, actions, world)
        assert torch.isfinite(loss) and final.clearance[1] == math.inf
        grads = torch.autograd.grad(loss, (pose0, actions, world.segments, world.circles, world.boxes))
    for grad in grads:
        assert torch.isfinite(grad).all()


def test_grad_mode_leaves_values_unchanged():
    world, pose0 = _messy_world_and_poses()
    actions = torch.tensor([0.3, -0.2], dtype=F64).repeat(10, 4, 1)
    with torch.no_grad():
        _, plain = rollout_loss(pose0, actions, world)
    _, tracked = rollout_loss(pose0.clone().requires_grad_(True), actions.clone().requires_grad_(True), world)
    for f in ("pose", "vel", "odom", "ranges", "clearance", "collided", "time"):
        assert torch.equal(getattr(plain, f), getattr(tracked, f).detach()), f
    assert tracked.ranges.requires_grad and not plain.ranges.requires_grad
