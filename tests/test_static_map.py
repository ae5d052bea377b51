"""A map held once for the batch (torchnav/sim/static_map.py): the same readings as the brute-force
world in every env, for every obstacle kind, scan mode and sensor; gradients; the task and env on it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

import torchnav.maps.free_space as free_space
from torchnav.envs import make_nav_env
from torchnav.maps import load_map
from torchnav.maps.occupancy import mask_boxes
from torchnav.sim import init_state, make_world, pad_world, points_clearance, step
from torchnav.sim.static_map import build_static_map, local_world, static_clearance, static_reach
from torchnav.tasks.config import NavConfig

BOUNDS = (-6.0, -4.0, 6.0, 4.0)
WALLS = torch.tensor([(-6, -4, 6, -4), (6, -4, 6, 4), (6, 4, -6, 4), (-6, 4, -6, -4), (-2, -4, -2, 1.5), (1, 0.5, 4, 3)], dtype=torch.float64)


def _obstacles(seed: int = 0, n_circles: int = 25, n_boxes: int = 40) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    u = lambda lo, hi, *s: lo + (hi - lo) * torch.rand(*s, generator=g, dtype=torch.float64)  # noqa: E731
    circles = torch.stack((u(-5.5, 5.5, n_circles), u(-3.5, 3.5, n_circles), u(0.05, 0.4, n_circles)), -1)
    boxes = torch.stack((u(-5.5, 5.5, n_boxes), u(-3.5, 3.5, n_boxes), u(0.05, 0.5, n_boxes), u(0.05, 0.3, n_boxes), u(-math.pi, math.pi, n_boxes)), -1)
    return WALLS, circles, boxes


def _params(scan: str = "rays", max_range: float = 3.0, camera: bool = False, offset=(0.0, 0.0, 0.0)):
    cfg = NavConfig()
    cfg = dataclasses.replace(cfg, lidar=dataclasses.replace(cfg.lidar, scan=scan, max_range=max_range, offset=offset),
                              camera=dataclasses.replace(cfg.camera, enabled=camera, max_range=4.0, n_cols=8))
    return cfg.sim_params()


def _poses(n: int, seed: int = 1, dtype=torch.float64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    lo, hi = torch.tensor([-5.9, -3.9, -math.pi], dtype=dtype), torch.tensor([5.9, 3.9, math.pi], dtype=dtype)
    return lo + (hi - lo) * torch.rand(n, 3, generator=g, dtype=dtype)


def _both(params, obstacles, n: int, dtype=torch.float64, cell=None, march=False):
    """The same envs twice: every obstacle in every env's world, and the obstacles in a StaticMap
    with one per-env random box in the world (``march``: reach lists as short as a ray scan that
    marches past them needs)."""
    segments, circles, boxes = (o.to(dtype) for o in obstacles)
    extra = torch.tensor([[0.5, -0.5, 0.3, 0.2, 0.4]], dtype=dtype)
    full = make_world(n, segments, circles, torch.cat((boxes, extra)), dtype=dtype)
    dyn = pad_world(make_world(n, dtype=dtype), boxes=1)
    dyn.boxes[:, 0] = extra[0]
    dyn.box_mask[:, 0] = True
    static = build_static_map(BOUNDS, segments, circles, boxes, reach=static_reach(params, march), cell=cell, dtype=dtype)
    return full, dyn, static


@pytest.mark.parametrize("scan, march", [("rays", False), ("rays", True), ("sectors", False)])
@pytest.mark.parametrize("cell", [None, 0.7])
def test_step_reads_the_same_as_every_obstacle_in_every_env(scan, march, cell):
    params = _params(scan, offset=(0.1, 0.05, 0.2))
    full, dyn, static = _both(params, _obstacles(), 300, cell=cell, march=march)
    assert static.reach == pytest.approx(static_reach(params, march))
    assert static.slots["boxes"] < 40 and static.slots["circles"] < 25  # the lists are shorter than the map
    pose = _poses(300)
    a, b = init_state(pose, full, params), init_state(pose, dyn, params, static=static)
    twist = torch.tensor([0.4, 0.7], dtype=torch.float64).expand(300, 2)
    for _ in range(3):
        a, b = step(a, twist, full, params), step(b, twist, dyn, params, static=static)
        for field in ("pose", "ranges", "clearance", "collided"):
            assert torch.equal(getattr(a, field), getattr(b, field)), field


def test_camera_and_far_clearance_are_the_whole_maps():
    params = _params(camera=True, max_range=1.0)  # the camera sees farther than the lidar
    assert static_reach(params) == pytest.approx(4.0 / math.cos(params.camera.fov / 2))
    obstacles = _obstacles(seed=3, n_circles=4, n_boxes=3)  # sparse: many places are far from everything
    full, dyn, static = _both(params, obstacles, 200)
    pose = _poses(200, seed=4)
    a, b = init_state(pose, full, params), init_state(pose, dyn, params, static=static)
    assert torch.equal(a.cam_depth, b.cam_depth)
    assert torch.equal(a.clearance, b.clearance)
    assert (a.clearance > 1.0).any()  # nearest obstacles beyond the lidar's range are found too


def test_clearance_of_points_is_the_whole_maps():
    segments, circles, boxes = _obstacles(seed=5)
    static = build_static_map(BOUNDS, segments, circles, boxes, reach=0.0, dtype=torch.float64)
    pts = _poses(2000, seed=6)[:, :2].reshape(4, 500, 2)
    want = points_clearance(pts, make_world(4, segments, circles, boxes, dtype=torch.float64))
    assert torch.equal(static_clearance(static, pts), want)
    assert torch.equal(static_clearance(static, pts, chunk=7), want)  # chunking changes nothing


def test_clearance_against_a_floor_decides_it_as_the_exact_values_do():
    """With ``floor``, the clearance grid answers for points far from it: the same side of the floor
    as the exact clearance at every point, inside the grid and outside it; points near it are measured."""
    segments, circles, boxes = _obstacles(seed=5)
    static = build_static_map(BOUNDS, segments, circles, boxes, reach=0.0, dtype=torch.float64)
    grid = static.clearance_grid
    assert grid is not None and grid.values.shape == (math.ceil(8.0 / grid.cell), math.ceil(12.0 / grid.cell))
    pts = torch.cat((_poses(3000, seed=6)[:, :2], torch.tensor([[9.0, 0.0], [-7.0, 5.0]], dtype=torch.float64))).reshape(1, -1, 2)
    exact = static_clearance(static, pts)
    for floor in (0.0, 0.3, 1.0):
        got = static_clearance(static, pts, floor=floor)
        assert torch.equal(got >= floor, exact >= floor)
        low, high = grid.bounds(pts[0])
        undecided = ~((low >= floor) | (high < floor))[None]  # the grid cannot tell these from the floor: measured
        assert undecided.any() and torch.equal(got[undecided], exact[undecided])
        assert (low <= exact[0]).all() and (high >= exact[0]).all()
        assert (got[exact >= floor] <= exact[exact >= floor]).all() and (got[exact < floor] >= exact[exact < floor]).all()  # bounds
        assert (got != exact).float().mean() > 0.5  # most points were answered by the grid
    no_grid = build_static_map(BOUNDS, segments, circles, boxes, reach=0.0, dtype=torch.float64, clearance_grid=False)
    assert no_grid.clearance_grid is None and torch.equal(static_clearance(no_grid, pts, floor=0.3), exact)


def test_samplers_place_the_same_episodes_with_the_clearance_grid_as_without():
    """The reset samplers read the grid's bounds only to decide which candidates are clear: the same
    starts and goals as exact clearance, also where no candidate is clear (the fallbacks rank them)."""
    from torchnav.tasks.sampling import sample_goals, sample_starts

    spec = load_map("warehouse")
    segments, circles, boxes = (torch.tensor(rows, dtype=torch.float32).reshape(-1, w) for rows, w in
                                ((spec.segments, 4), (spec.circles, 3), (spec.boxes, 5)))
    static = build_static_map(spec.bounds, segments, circles, boxes, reach=0.0)
    exact = dataclasses.replace(static, clearance_grid=None)
    world = make_world(64, dtype=torch.float32)
    for need in (0.3, 3.0):  # 3 m: most envs find no clear candidate
        runs = []
        for sm in (static, exact):
            g = torch.Generator().manual_seed(0)
            start, found = sample_starts(world, spec, need, 16, g, static=sm)
            goal, near = sample_goals(world, spec, start[:, :2], 0.5, torch.tensor(4.0), need, 16, g, static=sm)
            runs.append((start, found, goal, near))
        for x, y in zip(*runs):
            assert torch.equal(x, y)
        assert bool(runs[0][1].all()) == (need < 1.0)


def test_grid_bounds_hold_rotated_boxes_tightly():
    box = torch.tensor([[0.0, 0.0, 3.0, 0.1, math.pi / 2]])  # a 6 m wall standing along y
    static = build_static_map((-1.0, -1.0, 1.0, 1.0), boxes=box, reach=0.0, dtype=torch.float64)
    assert static.bounds == pytest.approx((-1.0, -3.0, 1.0, 3.0), abs=1e-6)  # not the box's bounding circle (3 m each way)


@pytest.mark.parametrize("march", [False, True])
def test_image_map_boxes(march):
    """An occupancy image's boxes (many, touching, axis-aligned), in float32 as the tasks use them."""
    rng = np.random.default_rng(0)
    mask = np.zeros((160, 240), bool)
    for _ in range(200):
        r, c = rng.integers(0, 160), rng.integers(0, 240)
        mask[r:r + rng.integers(1, 12), c:c + rng.integers(1, 12)] = True
    boxes = torch.tensor(mask_boxes(mask, 0.05, (-6.0, -4.0)))
    assert len(boxes) > 128  # more than the broad phase's threshold: the full world scans through it
    params = _params(max_range=2.5)
    full, dyn, static = _both(params, (WALLS, torch.zeros(0, 3), boxes), 256, dtype=torch.float32, march=march)
    pose = _poses(256, seed=7, dtype=torch.float32)
    a, b = init_state(pose, full, params), init_state(pose, dyn, params, static=static)
    assert torch.equal(a.clearance, b.clearance)
    # The full world goes through the angular broad phase, the local one through every ray: equal up to rounding.
    assert torch.allclose(a.ranges, b.ranges, rtol=0, atol=1e-4)


@pytest.mark.parametrize("march", [False, True])
def test_gradients_to_the_pose_are_the_same(march):
    params = _params()
    full, dyn, static = _both(params, _obstacles(seed=8), 64, march=march)
    pose_a = _poses(64, seed=9).requires_grad_()
    pose_b = pose_a.detach().clone().requires_grad_()
    a, b = init_state(pose_a, full, params), init_state(pose_b, dyn, params, static=static)
    (a.ranges.sum() + a.clearance.sum()).backward()
    (b.ranges.sum() + b.clearance.sum()).backward()
    assert torch.isfinite(pose_b.grad).all() and pose_b.grad.abs().sum() > 0
    # The same terms, summed over another number of slots: equal up to float64 rounding.
    torch.testing.assert_close(pose_a.grad, pose_b.grad, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("march", [False, True])
def test_batch_equals_one_env_at_a_time(march):
    params = _params()
    _, dyn, static = _both(params, _obstacles(seed=10), 16, march=march)
    pose = _poses(16, seed=11)
    batch = init_state(pose, dyn, params, static=static)
    for i in range(16):
        one = init_state(pose[i:i + 1], dyn[i:i + 1], params, static=static)
        assert torch.equal(one.ranges[0], batch.ranges[i]) and torch.equal(one.clearance[0], batch.clearance[i])


def test_outside_the_grid_uses_the_nearest_cell():
    segments, circles, boxes = _obstacles(seed=12)
    static = build_static_map(BOUNDS, segments, circles, boxes, reach=1.0, dtype=torch.float64)
    far = local_world(static, torch.tensor([[100.0, -100.0]], dtype=torch.float64))
    corner = local_world(static, torch.tensor([[5.99, -3.99]], dtype=torch.float64))
    assert torch.equal(far.boxes, corner.boxes) and torch.equal(far.box_mask, corner.box_mask)


def test_memory_does_not_grow_with_envs():
    params = _params()
    segments, circles, boxes = _obstacles()
    static = build_static_map(BOUNDS, segments, circles, boxes, reach=static_reach(params))
    size = static.nbytes()
    assert static.n_obstacles == {"segments": len(segments), "circles": len(circles), "boxes": len(boxes)}
    for n in (1, 64, 512):  # the per-env part holds only the cell lists' slots, whatever the map
        world = local_world(static, _poses(n, dtype=torch.float32)[:, :2])
        assert world.boxes.shape == (n, static.slots["boxes"], 5)
    assert static.nbytes() == size


@pytest.mark.parametrize("kwargs, match", [
    ({"bounds": (1.0, 0.0, 0.0, 1.0)}, "xmin < xmax"),
    ({"reach": -1.0}, "reach"),
    ({"reach": math.inf}, "reach"),
    ({"cell": 0.0}, "cell"),
    ({"cell": math.nan}, "cell"),
    ({"ray_cell": -0.1}, "ray_cell"),
    ({"boxes": torch.tensor([[0.0, math.inf, 1.0, 1.0, 0.0]])}, "boxes must be finite"),
])
def test_bad_arguments_are_named(kwargs, match):
    args = {"bounds": BOUNDS, "reach": 1.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        build_static_map(args.pop("bounds"), WALLS, **args)


def test_free_space_distances_through_the_index_equal_brute_force(monkeypatch):
    spec = load_map("warehouse")
    xy = np.random.default_rng(0).uniform(spec.bounds[:2], spec.bounds[2:], (3000, 2))
    monkeypatch.setattr(free_space, "INDEX_FROM", 0)
    indexed = free_space.obstacle_distance(spec, xy)
    monkeypatch.setattr(free_space, "INDEX_FROM", 10**9)
    assert np.array_equal(indexed, free_space.obstacle_distance(spec, xy))


def test_env_on_a_shared_map_plays_the_same_episodes():
    """warehouse with shared_map on and off: the same starts, goals, boxes, observations, rewards and
    ends over steps with resets; the per-env world holds only the random objects."""
    runs = {}
    for mode in ("on", "off"):
        env = make_nav_env("warehouse", 48, seed=3, shared_map=mode, max_steps=25)
        td = env.reset()
        g = torch.Generator().manual_seed(0)
        trace = []
        for _ in range(60):
            td["action"] = 2 * torch.rand(48, 2, generator=g) - 1
            out, td = env.step_and_maybe_reset(td)
            trace += [out["next", "observation"], out["next", "reward"], out["next", "done"]]
        runs[mode] = (env, trace)
    (on, a), (off, b) = runs["on"], runs["off"]
    assert on.task.static is not None and off.task.static is None
    assert sum(bool(x.any()) for x in a[2::3]) > 0  # some episodes ended and were reset
    for x, y in zip(a, b):
        assert torch.equal(x, y)
    spec = on.task.spec
    assert on.state.world.boxes.shape[1] == spec.random_boxes.count and on.state.world.segments.shape[1] == 0
    full = on.task.full_world(on.state.world)
    for key in ("segments", "circles", "boxes", "box_mask"):
        assert torch.equal(getattr(full, key), getattr(off.state.world, key)), key


def test_auto_shares_big_maps_only(tmp_path):
    rows = "\n".join(f"  - {{center: [{-4.5 + 0.3 * (i % 30):.2f}, {-4.5 + 0.9 * (i // 30):.2f}], size: [0.1, 0.1]}}" for i in range(300))
    (tmp_path / "many.yaml").write_text(f"size: [10, 10]\nwalls: boundary\nboxes:\n{rows}\n")
    assert make_nav_env(str(tmp_path / "many.yaml"), 4).task.static is not None
    assert make_nav_env("arena", 4).task.static is None
    assert make_nav_env(str(tmp_path / "many.yaml"), 4, shared_map="off").task.static is None


def test_march_alone_equals_every_ray_against_every_obstacle():
    """No reach lists at all: every ray marches from its origin, from inside the map and from outside
    its grid (rays that enter it and rays that miss it)."""
    from torchnav.sim.raycast import cast_rays
    from torchnav.sim.static_map import static_ray_hits

    segments, circles, boxes = _obstacles(seed=13)
    static = build_static_map(BOUNDS, segments, circles, boxes, reach=0.0, dtype=torch.float64)
    assert static.reach_lists is None and static.ray_lists.slots["boxes"] < len(boxes)
    g = torch.Generator().manual_seed(14)
    origin = torch.cat((_poses(200, seed=15)[:, :2], torch.tensor([[9.0, 0.5], [-8.0, -6.0], [0.0, 7.0]], dtype=torch.float64)))
    angles = (2 * torch.rand(len(origin), 24, generator=g, dtype=torch.float64) - 1) * math.pi
    want = cast_rays(origin, angles, make_world(len(origin), segments, circles, boxes, dtype=torch.float64))
    for max_range in (2.0, 30.0):
        got = static_ray_hits(static, origin, angles, max_range)
        assert torch.equal(got, torch.where(want < max_range, want, math.inf))
    assert torch.isfinite(got[-3:]).any() and torch.isinf(got[-3:]).any()  # from outside: some rays enter the grid, some miss it
    done = torch.rand(angles.shape, generator=g) < 0.5
    assert torch.equal(static_ray_hits(static, origin, angles, 30.0, done=done), torch.where(done, math.inf, got))


@pytest.mark.slow  # compiles the step and the march (about a minute)
def test_compiled_march_reads_as_eager():
    """``compiled_march``: eager calls march with the compiled steps (a compiled task's fresh episodes)."""
    from torchnav.sim.static_map import compiled_march

    params = _params(max_range=4.0)
    _, dyn, static = _both(params, _obstacles(seed=16), 128, dtype=torch.float32, march=True)
    pose = _poses(128, seed=18, dtype=torch.float32)
    a = init_state(pose, dyn, params, static=static)
    with compiled_march():
        b = init_state(pose, dyn, params, static=static)
    assert torch.allclose(a.ranges, b.ranges, rtol=0, atol=1e-5) and ((a.ranges > 2.0) & (a.ranges < 4.0)).any()


@pytest.mark.slow  # compiles the step and the march (about a minute)
def test_compiled_step_marches_as_eager():
    params = _params(max_range=4.0)
    full, dyn, static = _both(params, _obstacles(seed=16), 128, dtype=torch.float32, march=True)
    pose = _poses(128, seed=17, dtype=torch.float32)
    twist = torch.tensor([0.4, 0.7]).expand(128, 2)
    a = init_state(pose, dyn, params, static=static)
    b = torch.compile(step)(a, twist, dyn, params, static=static)
    a = step(a, twist, dyn, params, static=static)
    assert torch.allclose(a.ranges, b.ranges, rtol=0, atol=1e-5) and torch.equal(a.collided, b.collided)
    assert ((a.ranges > 2.0) & (a.ranges < 4.0)).any()  # some returns come from the march


def test_sensors_that_see_past_the_reach_lists_are_refused():
    params = _params("sectors")
    _, dyn, static = _both(_params("rays"), _obstacles(), 4, march=True)  # built for a marching ray scan
    with pytest.raises(ValueError, match="reach lists reach"):
        init_state(_poses(4), dyn, params, static=static)
    clearance_only = build_static_map(BOUNDS, WALLS, reach=static_reach(_params("rays"), True), rays=False)
    with pytest.raises(ValueError, match="no ray lists"):
        init_state(_poses(4, dtype=torch.float32), pad_world(make_world(4), boxes=1), _params("rays"), static=clearance_only)
