"""pad_world / cat_worlds: envs of one batch holding different worlds."""

import torch

from params import lidar_params, sim_params

from torchnav.maps import load_map
from torchnav.sim import World, cat_worlds, make_world, lidar_scan, pad_world, points_clearance


def test_pad_world_adds_masked_slots_and_changes_nothing_seen():
    w = load_map("arena").build_world(3)
    p = pad_world(w, segments=10, circles=7, boxes=9)
    assert p.segments.shape == (3, 10, 4) and p.circles.shape == (3, 7, 3) and p.boxes.shape[1] == 9
    assert not p.segment_mask[:, w.segments.shape[1]:].any()
    pose = torch.tensor([[0.3, -1.0, 0.4]] * 3)
    lidar = lidar_params(n_rays=36)
    assert torch.equal(lidar_scan(pose, p, lidar), lidar_scan(pose, w, lidar))
    pts = torch.rand(3, 50, 2) * 8 - 4
    assert torch.equal(points_clearance(pts, p), points_clearance(pts, w))


def test_cat_worlds_keeps_each_env_its_own_world():
    a, m = load_map("arena").build_world(2), load_map("maze").build_world(3)
    w = cat_worlds([a, m])
    assert w.batch_size == torch.Size([5])
    pose = torch.tensor([[0.5, 0.5, 0.0]] * 5)
    lidar = lidar_params(n_rays=90, fov=6.283185307179586)
    both = lidar_scan(pose, w, lidar)
    assert torch.equal(both[:2], lidar_scan(pose[:2], a, lidar))
    assert torch.equal(both[2:], lidar_scan(pose[2:], m, lidar))
    assert not torch.equal(both[0], both[2])


def test_planar_world_same_values_component_major_and_differentiable():
    from torchnav.sim.state import planar_world

    base = make_world(3, segments=[[-3, -3, 3, -3], [3, -3, 3, 3]], circles=[[1.0, 1.0, 0.3], [-1.5, 0.0, 0.1]],
                      boxes=[[-1.0, 1.0, 0.3, 0.2, 0.4], [1.0, -1.5, 0.5, 0.1, -0.2], [0.0, 2.0, 0.2, 0.2, 0.0]])
    boxes = base.boxes.clone().requires_grad_(True)
    w = World(segments=base.segments, segment_mask=base.segment_mask, circles=base.circles, circle_mask=base.circle_mask,
              boxes=boxes, box_mask=base.box_mask, batch_size=base.batch_size)
    p = planar_world(w)
    for key in ("segments", "circles", "boxes"):
        assert torch.equal(getattr(p, key), getattr(w, key)) and getattr(p, key).shape == getattr(w, key).shape
    assert p.segments[..., 0].is_contiguous() and p.boxes[..., 4].is_contiguous()
    pose = torch.tensor([[0.5, 0.5, 0.0]] * 3)
    lidar = lidar_params(n_rays=36, fov=6.283185307179586, max_range=50.0)
    assert torch.equal(lidar_scan(pose, p, lidar), lidar_scan(pose, w, lidar))
    (g_planar,) = torch.autograd.grad(lidar_scan(pose, p, lidar).sum(), boxes)
    (g_plain,) = torch.autograd.grad(lidar_scan(pose, w, lidar).sum(), boxes)
    assert torch.equal(g_planar, g_plain) and g_plain.abs().sum() > 0


def test_planar_world_keeps_a_planar_world_and_step_gives_the_same_state():
    from torchnav.sim import init_state, planar_world, step

    base = make_world(2, segments=[[-3, -3, 3, -3]], circles=[[1.0, 1.0, 0.3]], boxes=[[-1.0, 1.0, 0.3, 0.2, 0.4]])
    p = planar_world(base)
    again = planar_world(p)
    for key in ("segments", "circles", "boxes"):  # converted once, then used as it is
        assert getattr(again, key).data_ptr() == getattr(p, key).data_ptr()
        assert getattr(p, key).data_ptr() != getattr(base, key).data_ptr()
    params = sim_params()
    pose = torch.tensor([[0.0, 0.0, 0.3], [0.5, -0.5, -1.0]])
    action = torch.tensor([[0.3, 0.5], [0.2, -0.4]])
    a = step(init_state(pose, base, params), action, base, params)
    b = step(init_state(pose, p, params), action, p, params)
    assert torch.equal(a.ranges, b.ranges) and torch.equal(a.clearance, b.clearance)
