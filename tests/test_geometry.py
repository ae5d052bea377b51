"""Signed distances, box corners and disc clearance."""

from __future__ import annotations

import math

import pytest
import torch

from params import sim_params
from reference import naive_clearance, naive_point_clearance, random_world
from torchnav.sim import (
    box_corners,
    disc_clearance,
    init_state,
    make_world,
    point_box_distance,
    point_circle_distance,
    point_segment_distance,
    points_clearance,
)

F64 = torch.float64


def pts(*xy):
    return torch.tensor(xy, dtype=F64).reshape(-1, 2)


def test_point_circle_distance_is_signed():
    circles = torch.tensor([[[1.0, 2.0, 0.5]]], dtype=F64).expand(4, 1, 3)
    d = point_circle_distance(pts([4.0, 6.0], [1.0, 2.0], [1.25, 2.0], [1.5, 2.0]), circles)[:, 0]
    torch.testing.assert_close(d, torch.tensor([4.5, -0.5, -0.25, 0.0], dtype=F64))


def test_point_box_distance_is_signed():
    # 2 x 1 box turned 90 deg: it spans x in [2.5, 3.5], y in [-1, 1].
    box = torch.tensor([[[3.0, 0.0, 1.0, 0.5, math.pi / 2]]], dtype=F64).expand(5, 1, 5)
    p = pts([3.0, 0.0], [3.2, 0.5], [0.5, 0.0], [3.0, 4.0], [5.5, 3.0])
    d = point_box_distance(p, box)[:, 0]
    want = [-0.5, -0.3, 2.0, 3.0, math.hypot(2.0, 2.0)]  # centre, inside near an edge, face, face, corner
    torch.testing.assert_close(d, torch.tensor(want, dtype=F64), atol=1e-12, rtol=0)


def test_point_segment_distance():
    seg = torch.tensor([[[0.0, 0.0, 2.0, 0.0], [1.0, 1.0, 1.0, 1.0]]], dtype=F64).expand(3, 2, 4)
    d = point_segment_distance(pts([1.0, 0.5], [-3.0, 4.0], [4.0, 0.0]), seg)
    torch.testing.assert_close(d[:, 0], torch.tensor([0.5, 5.0, 2.0], dtype=F64))  # perpendicular, beyond each end
    torch.testing.assert_close(d[:, 1], torch.tensor([0.5, 5.0, math.hypot(3, 1)], dtype=F64))  # zero-length segment


def test_box_corners_ccw():
    c = box_corners(torch.tensor([1.0, 2.0, 1.0, 0.5, math.pi / 2], dtype=F64))
    want = torch.tensor([[0.5, 3.0], [0.5, 1.0], [1.5, 1.0], [1.5, 3.0]], dtype=F64)
    torch.testing.assert_close(c, want, atol=1e-12, rtol=0)
    # Counter-clockwise: positive shoelace area equal to 4 hx hy.
    x, y = c[:, 0], c[:, 1]
    area = 0.5 * float((x * y.roll(-1) - x.roll(-1) * y).sum())
    assert area == pytest.approx(2.0)


@pytest.mark.parametrize(
    "obstacle",
    [
        {"circles": [[1.0, 0.0, 0.75]]},
        {"boxes": [[1.0, 0.0, 0.75, 3.0, 0.0]]},
        {"segments": [[0.25, -1.0, 0.25, 1.0]]},
    ],
    ids=["circle", "box", "segment"],
)
def test_collision_flag_when_disc_touches(obstacle):
    params = sim_params(robot_radius=0.25)
    # Exactly touching (all numbers are exact binary fractions), slightly apart, overlapping.
    pose = torch.tensor([[0.0, 0.0, 0.0], [-0.001, 0.0, 0.0], [0.1, 0.0, 1.0]], dtype=F64)
    state = init_state(pose, make_world(3, dtype=F64, **obstacle), params)
    torch.testing.assert_close(state.clearance, torch.tensor([0.0, 0.001, -0.1], dtype=F64), atol=1e-12, rtol=0)
    assert state.collided.tolist() == [True, False, True]


def test_clearance_inside_obstacles_is_negative():
    world = make_world(2, circles=[[0.0, 0.0, 1.0]], boxes=[[5.0, 0.0, 1.0, 2.0, 0.3]], dtype=F64)
    c = disc_clearance(torch.tensor([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]], dtype=F64), world, 0.2)
    torch.testing.assert_close(c, torch.tensor([-1.2, -1.2], dtype=F64))


def test_masked_slots_are_ignored_and_empty_envs_read_inf():
    world = make_world(3, circles=[[0.5, 0.0, 0.2], [3.0, 0.0, 0.5]], dtype=F64)
    world.circle_mask[1, 0] = False
    world.circle_mask[2] = False
    pose = torch.zeros(3, 3, dtype=F64)
    c = disc_clearance(pose, world, 0.1)
    assert c.tolist() == pytest.approx([0.2, 2.4, math.inf])
    state = init_state(pose, world, sim_params(robot_radius=0.1))
    assert state.collided.tolist() == [False, False, False]
    assert disc_clearance(pose, make_world(3, dtype=F64), 0.1).eq(math.inf).all()


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (F64, 1e-12)], ids=["f32", "f64"])
def test_clearance_matches_naive(seed, dtype, tol):
    batch = 6
    world = random_world(batch, (3, 4, 4), seed=seed, dtype=dtype)
    g = torch.Generator().manual_seed(seed)
    pose = (torch.rand(batch, 3, generator=g) * 8 - 4).to(dtype)
    got = disc_clearance(pose, world, 0.2)
    want = torch.tensor(naive_clearance(pose, world, 0.2), dtype=F64)
    torch.testing.assert_close(got.to(F64), want, atol=tol, rtol=0)
    # Many candidate points per env at once (the reset samplers' entry point).
    points = (torch.rand(batch, 20, 2, generator=g) * 8 - 4).to(dtype)
    got = points_clearance(points, world)
    want = torch.tensor(
        [[naive_point_clearance(float(points[b, i, 0]), float(points[b, i, 1]), world, b) for i in range(20)] for b in range(batch)],
        dtype=F64,
    )
    assert (want < 0).any()  # some candidates land inside obstacles
    torch.testing.assert_close(got.to(F64), want, atol=tol, rtol=0)
