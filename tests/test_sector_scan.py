"""The exact sector scan: the limit of infinitely dense rays min-pooled per sector, thin
obstacles never missed, sensors inside obstacles, zero-size obstacles, gradients."""

from __future__ import annotations

import math

import pytest
import torch
from torch.autograd import gradcheck

from params import lidar_params
from reference import random_world
from torchnav.sim import LidarParams, World, cast_rays, disc_clearance, lidar_scan, make_world
from torchnav.sim.lidar import lidar_fan

F64 = torch.float64


def pooled_rays(pose: torch.Tensor, world: World, lidar: LidarParams, per_sector: int) -> torch.Tensor:
    """Min over ``per_sector`` rays spread evenly over each sector's wedge, both edges included."""
    fan = lidar_fan(pose, lidar)  # the sector boundary rays
    width = lidar.fov / lidar.n_rays
    steps = torch.linspace(0.0, width, per_sector, dtype=pose.dtype)
    angles = (fan.first[:, None, None] + width * torch.arange(lidar.n_rays, dtype=pose.dtype)[None, :, None] + steps).flatten(1)
    hits = cast_rays(fan.origin, angles, world, unroll=True).clamp(lidar.min_range, lidar.max_range)
    return hits.reshape(pose.shape[0], lidar.n_rays, per_sector).amin(-1)


def outside_poses(world: World, n: int, seed: int, half: float = 3.5) -> torch.Tensor:
    """One pose per env whose sensor lies outside every circle and box (at least 1 cm away)."""
    g = torch.Generator().manual_seed(seed)
    pose = torch.zeros(world.batch_size[0], 3, dtype=F64)
    todo = torch.ones(world.batch_size[0], dtype=torch.bool)
    for _ in range(200):
        cand = torch.cat((torch.rand(n, 2, generator=g, dtype=F64) * 2 * half - half, torch.rand(n, 1, generator=g, dtype=F64) * 6.2 - 3.1), -1)
        ok = disc_clearance(cand, world, 0.01) > 0
        pose = torch.where((todo & ok)[:, None], cand, pose)
        todo &= ~ok
        if not todo.any():
            return pose
    raise RuntimeError("no free pose")


@pytest.mark.parametrize("fov_deg,n", [(360, 20), (180, 20), (90, 6)])
@pytest.mark.parametrize("seed", [0, 1])
def test_equals_dense_rays_min_pooled_on_circles_and_boxes(fov_deg, n, seed):
    world = random_world(12, (0, 8, 8), seed=seed, dtype=F64)
    pose = outside_poses(world, 12, seed)
    lidar = lidar_params(n_rays=n, fov=math.radians(fov_deg), max_range=8.0, scan="sectors")
    got = lidar_scan(pose, world, lidar)
    dense = pooled_rays(pose, world, lidar, per_sector=10_000 // n)
    assert (got < lidar.max_range).sum() > 12 * n // 3  # most sectors see something
    assert (got <= dense + 1e-9).all()  # a sector never reads farther than any ray inside it
    torch.testing.assert_close(got, dense, atol=2e-3, rtol=0)


def test_walls_never_read_farther_than_dense_rays():
    world = random_world(12, (6, 0, 0), seed=3, dtype=F64)
    pose = outside_poses(world, 12, 3)
    lidar = lidar_params(n_rays=16, fov=2 * math.pi, max_range=8.0, scan="sectors")
    got, dense = lidar_scan(pose, world, lidar), pooled_rays(pose, world, lidar, per_sector=600)
    assert (got <= dense + 1e-9).all()
    # Walls seen nearly end-on converge slowly under ray sampling; elsewhere they agree.
    assert ((dense - got) < 1e-3).float().mean() > 0.95


def test_thin_post_between_rays_is_seen():
    # A 5 cm post 2 m ahead, half-way between two of 20 rays over 180 degrees (9.5 degrees apart).
    lidar_rays = lidar_params(n_rays=20, fov=math.pi, max_range=10.0)
    gap = math.pi / 19
    a = -math.pi / 2 + 9.5 * gap
    post = [[2.0 * math.cos(a), 2.0 * math.sin(a), 0.025]]
    pose = torch.zeros(1, 3, dtype=F64)
    world = make_world(1, circles=post, dtype=F64)
    assert lidar_scan(pose, world, lidar_rays).eq(10.0).all()  # every ray misses it
    sectors = lidar_scan(pose, world, lidar_params(n_rays=20, fov=math.pi, max_range=10.0, scan="sectors"))
    # Sector k spans [-90 + 9 k, -90 + 9 (k + 1)] degrees; the post sits at 0 degrees (the edge of 9 and 10).
    assert sectors[0, 9:11].tolist() == pytest.approx([2.0 - 0.025] * 2)
    assert sectors[0, :9].eq(10.0).all() and sectors[0, 11:].eq(10.0).all()


def test_wall_end_on_is_seen_at_its_near_end():
    pose = torch.zeros(1, 3, dtype=F64)
    world = make_world(1, segments=[[1.5, 0.001, 4.0, 0.001]], dtype=F64)  # almost along the middle ray
    got = lidar_scan(pose, world, lidar_params(n_rays=5, fov=math.pi, max_range=10.0, scan="sectors"))
    assert got[0, 2].item() == pytest.approx(math.hypot(1.5, 0.001)) and got[0, [0, 1, 3, 4]].eq(10.0).all()


def test_sensor_inside_a_circle_or_box_reads_min_range_everywhere():
    lidar = lidar_params(n_rays=12, fov=2 * math.pi, min_range=0.05, max_range=6.0, scan="sectors")
    pose = torch.tensor([[0.1, 0.0, 0.3], [3.0, 3.0, 0.0]], dtype=F64)
    world = make_world(2, circles=[[0.0, 0.0, 0.5]], boxes=[[3.2, 3.0, 0.5, 0.3, 0.4]], dtype=F64)
    assert lidar_scan(pose, world, lidar).eq(0.05).all()


def test_zero_size_obstacles_are_invisible():
    lidar = lidar_params(n_rays=8, fov=2 * math.pi, max_range=6.0, scan="sectors")
    world = make_world(1, segments=[[1.0, 1.0, 1.0, 1.0]], circles=[[2.0, 0.0, 0.0]], boxes=[[0.0, 2.0, 0.0, 0.0, 0.3]], dtype=F64)
    assert lidar_scan(torch.zeros(1, 3, dtype=F64), world, lidar).eq(6.0).all()


SECTOR_CASES = {  # obstacles seen from the poses with their nearest point inside a sector, and across a boundary
    "segments": [[2.0, -0.3, 2.5, 0.4], [-1.0, 2.0, 1.5, 2.2]],
    "circles": [[2.0, 0.3, 0.4], [0.2, -2.5, 0.5]],
    "boxes": [[2.5, 0.2, 0.3, 0.6, 0.3], [-0.5, -2.5, 0.8, 0.3, -0.2]],
}


@pytest.mark.parametrize("kind", list(SECTOR_CASES))
def test_gradcheck_sector_scan(kind):
    width = {"segments": 4, "circles": 3, "boxes": 5}
    obs = torch.tensor(SECTOR_CASES[kind], dtype=F64, requires_grad=True)
    pose = torch.tensor([[0.0, 0.1, 0.05], [0.2, -0.1, -0.3]], dtype=F64, requires_grad=True)
    lidar = lidar_params(n_rays=7, fov=2 * math.pi, max_range=20.0, scan="sectors")

    def f(pose, obs):
        fields = {}
        for k, w in width.items():
            t = obs.unsqueeze(0).expand(2, *obs.shape) if k == kind else obs.new_zeros(2, 0, w)
            fields[k] = t
            fields[{"segments": "segment_mask", "circles": "circle_mask", "boxes": "box_mask"}[k]] = torch.ones(2, t.shape[1], dtype=torch.bool)
        return lidar_scan(pose, World(**fields, batch_size=[2]), lidar)

    r = f(pose, obs)
    assert (r < 20.0).sum() >= 4
    assert gradcheck(f, (pose, obs))


def test_backward_is_nan_free_in_dense_worlds():
    world = random_world(16, (30, 60, 40), seed=7, dtype=torch.float32)
    pose = (torch.rand(16, 3, generator=torch.Generator().manual_seed(1)) * 8 - 4).requires_grad_(True)
    lidar = lidar_params(n_rays=20, fov=2 * math.pi, max_range=8.0, scan="sectors", window=0, dense_slots=8)
    lidar_scan(pose, world, lidar).sum().backward()
    assert torch.isfinite(pose.grad).all()


def test_sector_bearing_is_the_fan_and_guard_layout():
    """LidarParams.sector_bearing is the one layout: the fan's sector edges and the guard's sector centres read it."""
    import math

    from torchnav.sim.kinematics import guard_bearings
    from torchnav.sim.lidar import lidar_fan
    from torchnav.sim.params import LidarParams

    for fov, n in ((math.pi, 20), (2 * math.pi, 20), (math.radians(270), 7)):
        lidar = lidar_params(n_rays=n, fov=fov, scan="sectors")
        edges = [lidar.sector_bearing(k) for k in range(n + 1)]
        assert edges[0] == (-math.pi if lidar.full_circle else -fov / 2)
        assert math.isclose(edges[-1] - edges[0], fov, rel_tol=1e-12)
        fan = lidar_fan(torch.zeros(1, 3), lidar)
        assert torch.allclose(fan.angles[0], torch.tensor(edges[: fan.n]), atol=1e-6)
        # the guard's bearing of a sector lies inside it, at its point nearest straight ahead
        g = guard_bearings(lidar, torch.float64)
        for k in range(n):
            assert edges[k] - 1e-9 <= float(g[k]) <= edges[k + 1] + 1e-9
            nearest = min(abs(b) for b in (edges[k], edges[k + 1], 0.0) if edges[k] - 1e-9 <= b <= edges[k + 1] + 1e-9)
            assert math.isclose(abs(float(g[k])), nearest, abs_tol=1e-12)
