"""The angular broad phase of the ray cast: equal to every-ray-every-obstacle wherever
``scan_is_exact`` says so, including masked slots, sensors inside obstacles and grazing rays;
the same gradients; deterministic; a batch equals its envs one at a time."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from params import lidar_params

from torchnav.sim import World, lidar_scan, scan_is_exact
from torchnav.sim.raycast import BROAD_PHASE_RATIO

F64 = torch.float64
BRUTE = 10**9  # dense_slots large enough that every slot is tested on every ray


def dense_world(batch: int, seed: int, dtype=F64, counts=(40, 120, 60), half=6.0) -> World:
    """Walls around a square room plus many short walls, posts and boxes, ~10% of slots masked."""
    g = torch.Generator().manual_seed(seed)

    def u(lo, hi, *shape):
        return (lo + (hi - lo) * torch.rand(*shape, generator=g, dtype=F64)).to(dtype)

    ns, nc, nb = counts
    h = half
    walls = torch.tensor([[-h, -h, h, -h], [h, -h, h, h], [h, h, -h, h], [-h, h, -h, -h]], dtype=dtype).expand(batch, 4, 4)
    mid, ang, length = torch.stack((u(-h, h, batch, ns), u(-h, h, batch, ns)), -1), u(-3.2, 3.2, batch, ns), u(0.05, 0.6, batch, ns)
    d = torch.stack((ang.cos(), ang.sin()), -1) * length[..., None]
    segments = torch.cat((walls, torch.cat((mid - d, mid + d), -1)), 1)
    circles = torch.stack((u(-h, h, batch, nc), u(-h, h, batch, nc), u(0.03, 0.25, batch, nc)), -1)
    boxes = torch.stack((u(-h, h, batch, nb), u(-h, h, batch, nb), u(0.03, 0.3, batch, nb), u(0.03, 0.3, batch, nb), u(-3.2, 3.2, batch, nb)), -1)

    def mask(n):
        return torch.rand(batch, n, generator=g) > 0.1

    return World(segments=segments, segment_mask=mask(ns + 4), circles=circles, circle_mask=mask(nc), boxes=boxes, box_mask=mask(nb), batch_size=[batch])


def poses(batch: int, seed: int, dtype=F64, half=5.5) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed + 1000)
    return torch.cat((torch.rand(batch, 2, generator=g, dtype=F64) * 2 * half - half, torch.rand(batch, 1, generator=g, dtype=F64) * 6.4 - 3.2), -1).to(dtype)


LIDARS = {  # dense_slots below every kind's slot count, so the broad phase runs for all kinds
    "20 rays 180 deg": lidar_params(n_rays=20, fov=math.pi, max_range=8.0, dense_slots=16),
    "72 rays 360 deg, offset": lidar_params(n_rays=72, fov=2 * math.pi, max_range=8.0, offset=(0.1, -0.05, 0.3), window=4, dense_slots=16),
    "45 rays 270 deg": lidar_params(n_rays=45, fov=math.radians(270), max_range=8.0, window=3, dense_slots=16),
    "20 sectors 360 deg": lidar_params(n_rays=20, fov=2 * math.pi, max_range=8.0, scan="sectors", window=0, dense_slots=16),
    "12 sectors 120 deg": lidar_params(n_rays=12, fov=math.radians(120), max_range=8.0, scan="sectors", window=1, dense_slots=16),
}


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("name", list(LIDARS))
def test_broad_phase_equals_brute_force_where_exact(name, seed):
    lidar = LIDARS[name]
    world, pose = dense_world(48, seed), poses(48, seed)
    fast = lidar_scan(pose, world, lidar)
    brute = lidar_scan(pose, world, replace(lidar, dense_slots=BRUTE))
    exact = scan_is_exact(pose, world, lidar)
    assert exact.float().mean() > 0.9  # the defaults cover these worlds nearly everywhere
    # Some sensors sit inside obstacles and every kind of reading occurs.
    assert (brute == lidar.max_range).any() and (brute < 1.0).any()
    torch.testing.assert_close(fast[exact], brute[exact], atol=1e-12, rtol=0)


def test_scan_is_exact_flags_an_overflowing_env():
    # Env 0: 20 posts in a ring of radius 0.5 m around the sensor, all of them wide for a
    # 2-ray window, and 10 far posts; env 1: 30 far posts (1.1 deg half angle: not wide).
    a = torch.linspace(0, 2 * math.pi, 21, dtype=F64)[:-1]
    ring = torch.stack((0.5 * a.cos(), 0.5 * a.sin(), torch.full_like(a, 0.04)), -1)
    far = torch.tensor([[5.0, 0.0, 0.1]] * 30, dtype=F64)
    circles = torch.stack((torch.cat((ring, far[:10])), far))
    world = World(segments=torch.zeros(2, 0, 4, dtype=F64), segment_mask=torch.zeros(2, 0, dtype=torch.bool),
                  circles=circles, circle_mask=torch.ones(2, 30, dtype=torch.bool),
                  boxes=torch.zeros(2, 0, 5, dtype=F64), box_mask=torch.zeros(2, 0, dtype=torch.bool), batch_size=[2])
    lidar = lidar_params(n_rays=360, fov=2 * math.pi, dense_slots=8)
    pose = torch.zeros(2, 3, dtype=F64)
    assert scan_is_exact(pose, world, lidar).tolist() == [False, True]
    # With room for every wide post the same scan is exact and equals brute force.
    roomy = replace(lidar, dense_slots=20)
    assert scan_is_exact(pose, world, roomy).all()
    torch.testing.assert_close(lidar_scan(pose, world, roomy), lidar_scan(pose, world, replace(lidar, dense_slots=BRUTE)), atol=1e-12, rtol=0)
    # At most BROAD_PHASE_RATIO times dense_slots slots of a kind: no broad phase, every ray tests
    # every slot, exact although env 0 has more wide posts (20) than dense_slots (15).
    assert 30 <= BROAD_PHASE_RATIO * 15
    assert scan_is_exact(pose, world, replace(lidar, dense_slots=15)).all()
    torch.testing.assert_close(lidar_scan(pose, world, replace(lidar, dense_slots=15)), lidar_scan(pose, world, replace(lidar, dense_slots=BRUTE)), atol=1e-12, rtol=0)


def _padded(special: list[list[float]], tiny, n: int = 40) -> torch.Tensor:
    """``special`` obstacles, then tiny far ones up to ``n`` slots (so the broad phase runs)."""
    a = torch.linspace(0.3, 0.3 + 2 * math.pi, n - len(special) + 1, dtype=F64)[:-1]
    return torch.cat((torch.tensor(special, dtype=F64), torch.stack([tiny(5.5 * x.cos(), 5.5 * x.sin()) for x in a])), 0)


def test_grazing_rays_and_sensors_inside_obstacles_match_brute_force():
    # 8 rays 45 degrees apart; ray 4 looks along +x, ray 0 along -x, ray 6 along +y.
    lidar = lidar_params(n_rays=8, fov=2 * math.pi, dense_slots=4, window=1)
    seg = _padded([[2.0, 0.0, 5.0, 0.0], [3.0, -1.0, 3.0, 1.0]], lambda x, y: torch.stack((x, y, x + 0.02, y)))  # collinear with ray 4; across it
    circ = _padded([[0.0, 3.0, 1.0], [-3.0, 1.0, 1.0]], lambda x, y: torch.stack((x, y, torch.tensor(0.01, dtype=F64))))  # hit by ray 6; tangent to ray 0
    box = _padded([[-6.0, -1.0, 1.0, 1.0, 0.0]], lambda x, y: torch.stack((x, y, *torch.tensor([0.01, 0.01, 0.0], dtype=F64))))  # top side along ray 0
    world = World(segments=seg.expand(2, 40, 4), segment_mask=torch.ones(2, 40, dtype=torch.bool),
                  circles=circ.expand(2, 40, 3), circle_mask=torch.ones(2, 40, dtype=torch.bool),
                  boxes=box.expand(2, 40, 5), box_mask=torch.ones(2, 40, dtype=torch.bool), batch_size=[2])
    pose = torch.tensor([[0.0, 0.0, 0.0], [0.2, 3.1, 0.3]], dtype=F64)  # env 1 starts inside a circle
    brute = lidar_scan(pose, world, replace(lidar, dense_slots=BRUTE))
    assert scan_is_exact(pose, world, lidar).all()
    torch.testing.assert_close(lidar_scan(pose, world, lidar), brute, atol=1e-12, rtol=0)
    assert brute[0, 4] == pytest.approx(3.0) and brute[0, 6] == pytest.approx(2.0)
    assert brute[1].max() < 2.0  # inside the circle: every ray reads its exit


def test_gradients_equal_brute_force():
    world, pose = dense_world(6, 3), poses(6, 3)
    lidar = LIDARS["72 rays 360 deg, offset"]
    grads = []
    for lid in (lidar, replace(lidar, dense_slots=BRUTE)):
        p = pose.clone().requires_grad_(True)
        c = world.circles.clone().requires_grad_(True)
        w = World(segments=world.segments, segment_mask=world.segment_mask, circles=c, circle_mask=world.circle_mask,
                  boxes=world.boxes, box_mask=world.box_mask, batch_size=world.batch_size)
        r = lidar_scan(p, w, lid)
        (r * torch.linspace(0.5, 1.5, r.shape[1], dtype=F64)).sum().backward()
        grads.append((p.grad, c.grad))
    assert scan_is_exact(pose, world, lidar).all()
    assert grads[0][0].abs().sum() > 0 and grads[0][1].abs().sum() > 0
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b, atol=1e-9, rtol=1e-9)


def test_deterministic_and_batch_equals_one_env_at_a_time():
    world, pose = dense_world(8, 4, dtype=torch.float32), poses(8, 4, dtype=torch.float32)
    for lidar in (LIDARS["72 rays 360 deg, offset"], LIDARS["20 sectors 360 deg"]):
        batch = lidar_scan(pose, world, lidar)
        assert torch.equal(batch, lidar_scan(pose, world, lidar))
        for i in range(8):
            assert torch.equal(lidar_scan(pose[i : i + 1], world[i : i + 1], lidar)[0], batch[i])


@pytest.mark.parametrize("family", ["rooms", "corridors", "cave", "forest", "open"])
def test_defaults_are_exact_on_generated_worlds(family):
    # The default dense_slots keeps the task's lidars exact on every family, easy to hard.
    from torchnav.worlds import make_worlds

    for d in (0.0, 0.5, 1.0):
        b = make_worlds(family, 32, d, torch.Generator().manual_seed(5))
        for lidar in (lidar_params(n_rays=20, fov=math.pi), lidar_params(n_rays=180, fov=math.pi),
                      lidar_params(n_rays=20, fov=2 * math.pi, scan="sectors", window=0)):
            assert scan_is_exact(b.start, b.world, lidar).all(), (family, d, lidar)


def test_first_wide_picks_the_first_k_wide_slots_in_order():
    from torchnav.sim.raycast import _first_wide

    wide = torch.tensor([[0, 1, 0, 1, 1, 0, 1], [0, 0, 0, 0, 0, 0, 0], [1, 1, 1, 1, 1, 1, 1]])
    picked, taken = _first_wide(wide, 3)
    assert taken.tolist() == [[True, True, True], [False, False, False], [True, True, True]]
    assert picked[0].tolist() == [1, 3, 4] and picked[2].tolist() == [0, 1, 2]
    assert (picked >= 0).all() and (picked < wide.shape[1]).all()  # unfilled entries still index a real slot
    picked, taken = _first_wide(wide, 5)
    assert taken[0].tolist() == [True, True, True, True, False] and picked[0, :4].tolist() == [1, 3, 4, 6]
