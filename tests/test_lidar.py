"""Lidar: analytic readings, ray layouts, sectors, noise, and the batched caster against a naive loop."""

from __future__ import annotations

import math

import pytest
import torch

from params import lidar_params
from reference import naive_scan, random_world
from torchnav.sim import lidar_scan, make_world, ray_origins_and_angles, sectorize

F64 = torch.float64
ONE_RAY = lidar_params(n_rays=1, fov=0.1, max_range=10.0)  # a single ray straight ahead of the sensor


def scan(pose, lidar=ONE_RAY, dtype=F64, unroll=None, generator=None, **obstacles):
    pose = torch.tensor(pose, dtype=dtype).reshape(-1, 3)
    world = make_world(pose.shape[0], dtype=dtype, **obstacles)
    return lidar_scan(pose, world, lidar, generator=generator, unroll=unroll)


both_reductions = pytest.mark.parametrize("unroll", [True, False], ids=["unrolled", "batched"])


# --------------------------------------------------------------------------- analytic readings


@both_reductions
def test_ray_to_known_wall(unroll):
    wall = [[2.0, -5.0, 2.0, 5.0]]
    assert float(scan([0, 0, 0], segments=wall, unroll=unroll)) == pytest.approx(2.0, abs=1e-12)
    # Heading 30 deg: the ray meets the wall x = 2 after 2 / cos 30.
    assert float(scan([0, 0, math.radians(30)], segments=wall, unroll=unroll)) == pytest.approx(2 / math.cos(math.radians(30)), abs=1e-12)
    # Facing up at a wall y = 3 from (1, 0.5), and a wall behind the robot is not seen by a forward ray.
    up = float(scan([1.0, 0.5, math.pi / 2], segments=[[-4.0, 3.0, 4.0, 3.0], [-4.0, -1.0, 4.0, -1.0]], unroll=unroll))
    assert up == pytest.approx(2.5, abs=1e-12)


@both_reductions
def test_ray_to_circle_reads_distance_minus_radius(unroll):
    assert float(scan([0, 0, 0], circles=[[3.0, 0.0, 0.5]], unroll=unroll)) == pytest.approx(2.5, abs=1e-12)
    # Off-centre hit: chord half-width sqrt(r^2 - d^2) with d = 0.3.
    assert float(scan([0, 0, 0], circles=[[3.0, 0.3, 0.5]], unroll=unroll)) == pytest.approx(3.0 - 0.4, abs=1e-12)
    # Inside the circle the ray reads the exit point.
    assert float(scan([3.0, 0, 0], circles=[[3.0, 0.0, 0.5]], unroll=unroll)) == pytest.approx(0.5, abs=1e-12)


@both_reductions
def test_ray_to_rotated_box(unroll):
    s = math.sqrt(0.5)
    # A unit square turned 45 deg, corner towards the robot; a ray at height 0.1 meets the
    # edge x - y = 3 - sqrt(0.5) at x = 3 - sqrt(0.5) + 0.1.
    box = [[3.0, 0.0, 0.5, 0.5, math.pi / 4]]
    assert float(scan([0, 0.1, 0], boxes=box, unroll=unroll)) == pytest.approx(3 - s + 0.1, abs=1e-12)
    assert float(scan([0, -0.2, 0], boxes=box, unroll=unroll)) == pytest.approx(3 - s + 0.2, abs=1e-12)
    # Along the box's own x axis (the ray is parallel to two of its sides in the box frame).
    box = [[2.0, 2.0, 0.5, 1.0, math.pi / 4]]
    assert float(scan([0, 0, math.pi / 4], boxes=box, unroll=unroll)) == pytest.approx(2 * math.sqrt(2) - 0.5, abs=1e-12)
    # Axis-aligned box hit face-on, and from inside (exit point).
    box = [[4.0, 1.0, 1.0, 2.0, 0.0]]
    assert float(scan([0, 0, 0], boxes=box, unroll=unroll)) == pytest.approx(3.0, abs=1e-12)
    assert float(scan([4.5, 0, 0], boxes=box, unroll=unroll)) == pytest.approx(0.5, abs=1e-12)


@both_reductions
def test_misses_read_max_range_and_min_range_clamps(unroll):
    lidar = lidar_params(n_rays=1, fov=0.1, min_range=0.1, max_range=5.0)
    # Everything behind, beside, or beyond max_range misses.
    far = scan(
        [0, 0, 0],
        lidar,
        segments=[[-1.0, -1.0, -1.0, 1.0], [7.0, -1.0, 7.0, 1.0], [1.0, 0.5, 3.0, 0.5]],
        circles=[[0.0, 2.0, 0.5], [1.0, 0.6, 0.5]],  # the second passes 0.1 m above the ray
        boxes=[[-3.0, 0.0, 1.0, 1.0, 0.3], [3.0, 1.0, 0.5, 0.4, 0.0]],
        unroll=unroll,
    )
    assert float(far) == 5.0
    # An empty world (zero slots of every kind) misses everywhere.
    assert scan([[0, 0, 0], [1, 2, 3]], lidar_params(n_rays=8), unroll=unroll).eq(10.0).all()
    assert float(scan([0, 0, 0], lidar, segments=[[0.05, -1.0, 0.05, 1.0]], unroll=unroll)) == pytest.approx(0.1)
    assert float(scan([0, 0, 0], lidar, segments=[[4.0, -1.0, 4.0, 1.0]], unroll=unroll)) == pytest.approx(4.0)


def test_tangent_ray_to_circle_is_a_miss():
    # The ray y = 0 grazes the circle of radius 1 centred at (3, 1).
    assert float(scan([0, 0, 0], circles=[[3.0, 1.0, 1.0]])) == 10.0
    assert float(scan([0, 0, 0], circles=[[3.0, 0.999, 1.0]])) < 10.0


def test_offset_mount_shifts_readings():
    # Sensor 0.1 m ahead and 0.05 m left of the robot centre, turned 90 deg to the left.
    lidar = lidar_params(n_rays=1, fov=0.1, offset=(0.1, 0.05, math.pi / 2))
    walls = [[-5.0, 2.0, 5.0, 2.0], [-3.0, -5.0, -3.0, 5.0]]  # y = 2 and x = -3
    # Robot heading +x: the sensor sits at (0.1, 0.05) and looks along +y.
    assert float(scan([0, 0, 0], lidar, segments=walls)) == pytest.approx(1.95, abs=1e-12)
    # Robot heading +y: the sensor sits at (-0.05, 0.1) and looks along -x.
    assert float(scan([0, 0, math.pi / 2], lidar, segments=walls)) == pytest.approx(2.95, abs=1e-12)
    origin, angles = ray_origins_and_angles(torch.tensor([[1.0, 1.0, math.pi / 2]], dtype=F64), lidar)
    torch.testing.assert_close(origin, torch.tensor([[0.95, 1.1]], dtype=F64))
    torch.testing.assert_close(angles, torch.tensor([[math.pi]], dtype=F64))


# --------------------------------------------------------------------------- layouts


ROOM = [[-4.0, -1.0, 3.0, -1.0], [3.0, -1.0, 3.0, 2.0], [3.0, 2.0, -4.0, 2.0], [-4.0, 2.0, -4.0, -1.0]]


def room_range(phi: float) -> float:
    """Distance from the origin along angle ``phi`` to the room walls x=3, x=-4, y=-1, y=2."""
    c, s = math.cos(phi), math.sin(phi)
    ts = []
    if c > 1e-12:
        ts.append(3.0 / c)
    if c < -1e-12:
        ts.append(-4.0 / c)
    if s > 1e-12:
        ts.append(2.0 / s)
    if s < -1e-12:
        ts.append(-1.0 / s)
    return min(ts)


def test_180_degree_layout():
    lidar = lidar_params(n_rays=180, fov=math.pi)
    angles = lidar.angles()
    assert angles[0] == pytest.approx(-math.pi / 2) and angles[-1] == pytest.approx(math.pi / 2)
    assert all(b > a for a, b in zip(angles, angles[1:]))  # counter-clockwise order
    r = scan([0, 0, 0], lidar, segments=ROOM)[0]
    assert float(r[0]) == pytest.approx(1.0)  # ray 0 looks right (-y)
    assert float(r[-1]) == pytest.approx(2.0)  # the last ray looks left (+y)
    expect = torch.tensor([room_range(a) for a in angles], dtype=F64)
    torch.testing.assert_close(r, expect, atol=1e-9, rtol=0)
    # Heading rotates every ray: facing -y, ray 0 looks towards -x.
    assert float(scan([0, 0, -math.pi / 2], lidar, segments=ROOM)[0, 0]) == pytest.approx(4.0)


def test_360_degree_layout():
    lidar = lidar_params(n_rays=360, fov=2 * math.pi)
    angles = lidar.angles()
    assert angles[0] == pytest.approx(-math.pi) and angles[180] == pytest.approx(0.0, abs=1e-12)
    assert all(b > a for a, b in zip(angles, angles[1:])) and angles[-1] < math.pi
    r = scan([0, 0, 0], lidar, segments=ROOM)[0]
    assert [float(r[i]) for i in (0, 90, 180, 270)] == pytest.approx([4.0, 1.0, 3.0, 2.0])  # back, right, front, left
    expect = torch.tensor([room_range(a) for a in angles], dtype=F64)
    torch.testing.assert_close(r, expect, atol=1e-9, rtol=0)


def test_sectorize_takes_min_over_consecutive_groups():
    g = torch.Generator().manual_seed(0)
    ranges = torch.rand(3, 180, generator=g) * 10
    sectors = sectorize(ranges, 20)
    assert sectors.shape == (3, 20)
    for b in range(3):
        for k in range(20):
            assert float(sectors[b, k]) == min(float(v) for v in ranges[b, 9 * k : 9 * k + 9])
    assert torch.equal(sectorize(ranges, 180), ranges)
    with pytest.raises(ValueError, match="n_sectors"):
        sectorize(ranges, 7)


# --------------------------------------------------------------------------- noise


def test_noise_only_with_a_generator_and_reproducible():
    lidar = lidar_params(n_rays=200, fov=math.pi / 2, noise_std=0.05)
    clean_lidar = lidar_params(n_rays=200, fov=math.pi / 2)
    wall = [[3.0, -10.0, 3.0, 10.0]]
    clean = scan([0, 0, 0], clean_lidar, segments=wall)
    assert torch.equal(scan([0, 0, 0], lidar, segments=wall), clean)  # no generator, no noise
    a = scan([0, 0, 0], lidar, segments=wall, generator=torch.Generator().manual_seed(7))
    b = scan([0, 0, 0], lidar, segments=wall, generator=torch.Generator().manual_seed(7))
    c = scan([0, 0, 0], lidar, segments=wall, generator=torch.Generator().manual_seed(8))
    assert torch.equal(a, b) and not torch.equal(a, c)
    err = a - clean
    assert 0.03 < float(err.std()) < 0.07 and abs(float(err.mean())) < 0.02
    # Noise is applied before clamping: misses still read exactly max_range.
    miss = scan([0, 0, math.pi], lidar, segments=wall, generator=torch.Generator().manual_seed(7))
    assert miss.eq(lidar.max_range).all()


# --------------------------------------------------------------------------- batched against naive


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-4), (F64, 1e-9)], ids=["f32", "f64"])
@pytest.mark.parametrize("unroll", [True, False], ids=["unrolled", "batched"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_scan_matches_naive_loop(dtype, tol, unroll, seed):
    batch = 6
    world = random_world(batch, (3, 4, 4), seed=seed, dtype=dtype)
    g = torch.Generator().manual_seed(100 + seed)
    pose = torch.cat((torch.rand(batch, 2, generator=g) * 6 - 3, torch.rand(batch, 1, generator=g) * 6 - 3), -1).to(dtype)
    lidar = lidar_params(n_rays=72, fov=2 * math.pi, min_range=0.05, max_range=8.0, offset=(0.1, -0.05, 0.2))
    got = lidar_scan(pose, world, lidar, unroll=unroll)
    want = torch.tensor(naive_scan(pose, world, lidar), dtype=F64)
    assert got.shape == (batch, 72) and got.dtype == dtype
    # The worlds are rich enough that every kind of reading occurs.
    assert (want == 8.0).any() and (want < 8.0).sum() > batch * 20
    torch.testing.assert_close(got.to(F64), want, atol=tol, rtol=0)


def test_scan_with_only_one_kind_and_half_fov():
    for slots in ((4, 0, 0), (0, 4, 0), (0, 0, 4)):
        world = random_world(4, slots, seed=5, dtype=F64)
        pose = torch.tensor([[0.0, 0.0, 0.0], [1.0, -1.0, 2.0], [-2.0, 0.5, -1.0], [0.5, 2.0, 3.0]], dtype=F64)
        lidar = lidar_params(n_rays=45, fov=math.radians(270))
        for unroll in (True, False):
            got = lidar_scan(pose, world, lidar, unroll=unroll)
            torch.testing.assert_close(got, torch.tensor(naive_scan(pose, world, lidar), dtype=F64), atol=1e-9, rtol=0)


# --------------------------------------------------------------------------- precision and degenerate cases


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["f32", "f64"])
@pytest.mark.parametrize("wall", [[1.0, 0.0, 3.0, 0.0], [3.0, 0.0, 1.0, 0.0], [0.7, 0.35, 2.3, 1.15]])
def test_ray_along_a_walls_line_misses_it(wall, dtype):
    # From the origin on the wall's line: looking away from it, and looking along it through it.
    # Both are parallel rays and miss; the parallel test is relative to the wall's length and
    # to the dtype's precision (an absolute 1e-9 read 0 m in float32).
    th = math.atan2(wall[3] - wall[1], wall[2] - wall[0])
    if wall[2] < wall[0]:
        th += math.pi
    for heading in (th + math.pi, th):
        assert float(scan([0.0, 0.0, heading], dtype=dtype, segments=[wall])) == 10.0
    # From the wall's own end point, looking away along its line.
    x1, y1, x2, y2 = wall
    assert float(scan([x1, y1, math.atan2(y1 - y2, x1 - x2)], dtype=dtype, segments=[wall])) == 10.0


def test_zero_size_box_is_invisible_but_a_zero_width_box_is_a_wall():
    assert float(scan([0, 0, math.pi / 4], boxes=[[1.0, 1.0, 0.0, 0.0, 0.0]])) == 10.0  # a ray right through it
    assert float(scan([0, 0, 0], boxes=[[2.0, 0.0, 0.0, 0.5, 0.0]])) == pytest.approx(2.0)


def test_far_circle_is_precise_in_float32():
    circle = [[5000.0, 0.5, 1.0]]
    want = 5000.0 - math.sqrt(1.0 - 0.25)  # the half chord, 0.87 m, is lost in b^2 - c at 5 km
    far = lidar_params(n_rays=1, fov=0.1, max_range=6000.0)
    assert float(scan([0, 0, 0], far, dtype=torch.float32, circles=circle)) == pytest.approx(want, abs=2e-3)
    assert float(scan([0, 0, 0], far, dtype=F64, circles=circle)) == pytest.approx(want, abs=1e-9)


def test_default_reduction_unrolls_few_slots_in_large_eager_batches_only():
    from torchnav.sim.raycast import EAGER_UNROLL_MIN_RAYS, EAGER_UNROLL_SLOTS, unrolled

    assert unrolled(EAGER_UNROLL_SLOTS, EAGER_UNROLL_MIN_RAYS)
    assert not unrolled(EAGER_UNROLL_SLOTS + 1, EAGER_UNROLL_MIN_RAYS)  # many slots: one (B, R, N) pass
    assert not unrolled(EAGER_UNROLL_SLOTS, 128 * 20)  # 128 envs x 20 rays: launches cost more than memory
    # the default gives what either explicit reduction gives, on both sides of the threshold
    g = torch.Generator().manual_seed(5)
    for b in (8, EAGER_UNROLL_MIN_RAYS // 20 + 1):
        world = random_world(b, (4, 3, 2), seed=b, dtype=torch.float32)
        pose = torch.cat((torch.rand(b, 2, generator=g) * 4 - 2, torch.rand(b, 1, generator=g) * 6 - 3), 1)
        default = lidar_scan(pose, world, lidar_params(n_rays=20))
        for unroll in (True, False):
            torch.testing.assert_close(lidar_scan(pose, world, lidar_params(n_rays=20), unroll=unroll), default, rtol=0, atol=1e-5)
