"""The near obstacles carried in the state (sim/near.py): the step over them equals the step over the whole world."""

import math
from dataclasses import replace

import pytest
import torch

from torchnav.sim import LidarParams, SimParams, World, init_state, make_movers, make_world, step
from torchnav.sim.near import REFRESH_SHARE, near_counts

HALF = 6.0
SECTORS = LidarParams(n_rays=20, fov=2 * math.pi, max_range=8.0, scan="sectors", window=0, dense_slots=10**6)
RAYS = LidarParams(n_rays=36, fov=math.pi, max_range=8.0, offset=(0.1, 0.05, 0.2), window=1, dense_slots=10**6)


def dense_world(b: int, seed: int = 0, dtype=torch.float32) -> World:
    """A walled room of 2 * HALF m with 90 posts and 30 boxes per env, a fifth of the slots masked off."""
    g = torch.Generator().manual_seed(seed)

    def u(lo, hi, *shape):
        return (lo + (hi - lo) * torch.rand(*shape, generator=g)).to(dtype)

    h = HALF
    base = make_world(b, segments=[[-h, -h, h, -h], [h, -h, h, h], [h, h, -h, h], [-h, h, -h, -h]], dtype=dtype)
    posts = torch.stack((u(-h, h, b, 90), u(-h, h, b, 90), u(0.05, 0.3, b, 90)), -1)
    boxes = torch.stack((u(-h, h, b, 30), u(-h, h, b, 30), u(0.1, 0.4, b, 30), u(0.1, 0.4, b, 30), u(-math.pi, math.pi, b, 30)), -1)
    return World(segments=base.segments, segment_mask=base.segment_mask, circles=posts, circle_mask=torch.rand(b, 90, generator=g) > 0.2,
                 boxes=boxes, box_mask=torch.rand(b, 30, generator=g) > 0.2, batch_size=[b])


def start(b: int, seed: int = 1, dtype=torch.float32) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.cat((torch.rand(b, 2, generator=g) * 2 * (HALF - 1) - (HALF - 1), torch.rand(b, 1, generator=g) * 2 * math.pi - math.pi), 1).to(dtype)


def twists(b: int, n: int, seed: int = 2) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return [torch.stack((torch.rand(b, generator=g) * 1.0 - 0.3, torch.rand(b, generator=g) * 2 - 1), -1) for _ in range(n)]


def assert_same_readings(a, b, same_pose: bool = True):
    torch.testing.assert_close(a.ranges, b.ranges, atol=1e-4, rtol=0)
    torch.testing.assert_close(a.clearance, b.clearance, atol=1e-4, rtol=0)
    if same_pose:  # both eager: the kinematics are the same computation
        assert torch.equal(a.collided, b.collided) and torch.equal(a.pose, b.pose)


@pytest.mark.parametrize("lidar", [SECTORS, RAYS], ids=["sectors", "rays"])
def test_near_step_equals_the_whole_world_step_over_random_motion_resets_teleports_and_movers(lidar):
    b, n_steps = 64, 60
    world = dense_world(b)
    full = replace(SimParams(v_max=1.0, v_min=-0.3), lidar=lidar)
    near = replace(full, near_slots=24)  # small enough that refreshes and whole-world steps both happen
    movers = make_movers(b, [[0.0, 0.0, 0.6, 0.3, 0.3], [1.0, -2.0, -0.4, 0.5, 0.2]], region=(-HALF, -HALF, HALF, HALF))
    pose = start(b)
    a, c = init_state(pose, world, full, movers=movers), init_state(pose, world, near, movers=movers)
    assert c.near.circles.shape == (b, 18, 3) and c.near.boxes.shape == (b, 6, 5) and c.near.segments.shape == (b, 0, 4)
    assert_same_readings(a, c)
    first_centre = c.near_centre.clone()
    for i, act in enumerate(twists(b, n_steps)):
        if i == 20:  # new episodes for a third of the envs
            idx = torch.arange(0, b, 3)
            fresh = start(idx.numel(), seed=7)
            sub = world[idx]
            a = a.apply(lambda old, new: old.index_put((idx,), new), init_state(fresh, sub, full, movers=(a.movers[idx], a.mover_mask[idx])))
            c = c.apply(lambda old, new: old.index_put((idx,), new), init_state(fresh, sub, near, movers=(c.movers[idx], c.mover_mask[idx])))
        if i == 40:  # teleports: poses set by hand, the state's near obstacles left as they were
            jump = start(b, seed=9)
            a, c = a.clone(), c.clone()
            a.pose, c.pose = jump, jump.clone()
        a, c = step(a, act, world, full), step(c, act, world, near)
        assert_same_readings(a, c)
    assert (c.near_centre != first_centre).any(1).float().mean() > 0.5  # the near obstacles were chosen again on the way


def test_near_slots_that_keep_every_slot_scan_the_whole_world():
    world = make_world(4, segments=[[-3, -3, 3, -3]], circles=[[1.0, 0.0, 0.3]])
    params = SimParams(near_slots=64)
    assert near_counts(world, params.near_slots) == {"segments": 0, "circles": 0, "boxes": 0}
    s = init_state(torch.zeros(4, 3), world, params)
    assert s.near.circles.shape == (4, 0, 3) and torch.isinf(s.near_bound).all()
    torch.testing.assert_close(step(s, torch.ones(4, 2), world, params).ranges, step(init_state(torch.zeros(4, 3), world, SimParams()), torch.ones(4, 2), world, SimParams()).ranges)


def test_near_gradients_equal_the_whole_world_gradients():
    b = 16
    world = dense_world(b, dtype=torch.float64)
    full = replace(SimParams(), lidar=SECTORS)
    near = replace(full, near_slots=24)
    pose = start(b, dtype=torch.float64)
    grads = []
    for params in (full, near):
        circles = world.circles.clone().requires_grad_()
        w = World(segments=world.segments, segment_mask=world.segment_mask, circles=circles, circle_mask=world.circle_mask,
                  boxes=world.boxes, box_mask=world.box_mask, batch_size=[b])
        act = torch.tensor([[0.4, 0.3]], dtype=torch.float64).repeat(b, 1).requires_grad_()
        s = init_state(pose, w, params)
        for _ in range(5):
            s = step(s, act, w, params)
        (s.ranges.clamp(max=7.9).sum() + s.clearance.sum()).backward()
        grads.append((act.grad, circles.grad))
    assert grads[0][0].abs().sum() > 0 and grads[0][1].abs().sum() > 0
    torch.testing.assert_close(grads[1][0], grads[0][0], atol=1e-8, rtol=1e-6)
    torch.testing.assert_close(grads[1][1], grads[0][1], atol=1e-8, rtol=1e-6)


def test_near_batch_equals_envs_stepped_one_at_a_time_and_is_deterministic():
    b = 2 * REFRESH_SHARE + 3  # three refreshed envs a step
    world = dense_world(b, seed=3)
    params = replace(SimParams(v_max=1.0), lidar=SECTORS, near_slots=24)
    pose = start(b, seed=4)
    acts = twists(b, 15, seed=5)

    def run(idx):
        s = init_state(pose[idx], world[idx], params)
        for act in acts:
            s = step(s, act[idx], world[idx], params)
        return s

    batch = run(slice(None))
    assert torch.equal(run(slice(None)).ranges, batch.ranges)
    for i in range(0, b, 11):
        one = run(slice(i, i + 1))
        torch.testing.assert_close(one.ranges, batch.ranges[i : i + 1], atol=1e-4, rtol=0)
        torch.testing.assert_close(one.clearance, batch.clearance[i : i + 1], atol=1e-4, rtol=0)


def test_near_state_must_match_the_params_and_near_slots_is_checked():
    world = dense_world(4)
    s = init_state(start(4), world, SimParams())
    with pytest.raises(ValueError, match="near_slots=24"):
        step(s, torch.zeros(4, 2), world, SimParams(near_slots=24))
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match="near_slots must be an int"):
            SimParams(near_slots=bad)


@pytest.mark.slow  # compiling the near step takes minutes (docs/performance.md, "Dense worlds")
def test_near_step_compiled_equals_the_whole_world_step():
    b = 32
    world = dense_world(b, seed=6)
    full = replace(SimParams(v_max=1.0), lidar=SECTORS)
    near = replace(full, near_slots=24)
    fn = torch.compile(lambda s, a: step(s, a, world, near), fullgraph=True)
    a = c = None
    for i, act in enumerate(twists(b, 12, seed=8)):
        if i == 0:
            a, c = init_state(start(b, seed=6), world, full), init_state(start(b, seed=6), world, near)
        a, c = step(a, act, world, full), fn(c, act)
        assert_same_readings(a, c, same_pose=False)  # compiled kinematics round differently
        c = c.clone()
        c.pose = a.pose.clone()  # so that the readings of the next step are taken at the same pose
