"""The camera-frame column caster (camera.py) against a brute-force reference: the lidar's ray
caster on the camera's rays, and the RGB render as it was built on it."""

import math

import pytest
import torch

from params import camera_params

from torchnav.sim import World, camera_depth, camera_image, camera_rays, cast_rays, make_movers, mover_world
from torchnav.sim.camera import ObstacleStyles
from torchnav.sim.raycast import KINDS
from torchnav.sim.state import planar_rows

CAM = camera_params(n_cols=40, n_rows=12, fov=1.6, max_range=12.0, offset=(0.05, -0.02, 0.1))


def reference_depth(pose, world, cam, movers=None):
    """Every column cast as a lidar ray (``cast_rays``), its range times the column angle's cosine."""
    origin, angles, local = camera_rays(pose, cam)
    dist = cast_rays(origin, angles, world)
    if movers is not None:
        dist = torch.minimum(dist, cast_rays(origin, angles, movers))
    return (dist * torch.cos(local)).clamp(max=cam.max_range)


def reference_looks(pose, world, cam, movers=None, styles=None):
    """The nearest obstacle's depth and ``[height, r, g, b]`` per column, from the lidar's hit functions."""
    origin, angles, local = camera_rays(pose, cam)
    dx, dy = torch.cos(angles)[..., None], torch.sin(angles)[..., None]
    ox, oy = origin[:, 0, None, None], origin[:, 1, None, None]
    defaults = {"segments": (cam.wall_height, cam.wall_color), "circles": (cam.circle_height, cam.circle_color),
                "boxes": (cam.box_height, cam.box_color)}
    dists, looks = [], []
    for source, kind_styles in ((world, styles or ObstacleStyles()), (movers, None)):
        for key, mkey, fn, rows in KINDS if source is not None else ():
            obs = getattr(source, key)
            if obs.shape[1]:
                dist, idx = fn(ox, oy, dx, dy, planar_rows(rows(obs))[:, None], getattr(source, mkey)[:, None]).min(-1)
                height, color = defaults[key] if kind_styles else (cam.mover_height, cam.mover_color)
                dists.append(dist * torch.cos(local))
                looks.append((kind_styles or ObstacleStyles()).table(key, obs.shape[1], height, color, pose)[idx])
    z, kind = torch.stack(dists).min(0)
    return z, torch.stack(looks).gather(0, kind[None, ..., None].expand(1, *kind.shape, 4))[0]


def random_world(b, g, n_seg=5, n_circ=3, n_box=6):
    """Walls, circles and boxes at random in every env, a quarter of each kind's slots masked;
    some boxes are thin walls (one zero half extent) or invisible (both zero)."""
    def u(lo, hi, *shape):
        return lo + (hi - lo) * torch.rand(*shape, generator=g)
    seg = torch.cat((u(-6, 6, b, n_seg, 2), u(-6, 6, b, n_seg, 2)), -1)
    circ = torch.cat((u(-4, 4, b, n_circ, 2), u(0.1, 0.8, b, n_circ, 1)), -1)
    box = torch.cat((u(-4, 4, b, n_box, 2), u(0.05, 0.8, b, n_box, 2), u(-math.pi, math.pi, b, n_box, 1)), -1)
    box[:, 0, 3] = 0.0  # a thin wall
    box[:, 1, 2:4] = 0.0  # invisible
    masks = [torch.rand(b, n, generator=g) > 0.25 for n in (n_seg, n_circ, n_box)]
    return World(segments=seg, segment_mask=masks[0], circles=circ, circle_mask=masks[1], boxes=box, box_mask=masks[2],
                 batch_size=[b])


def poses_inside(world, b, g):
    """Random poses; env 0's camera sits inside its box 2, env 1's inside its circle 0 (both unmasked)."""
    pose = torch.cat((torch.rand(b, 2, generator=g) * 8 - 4, torch.rand(b, 1, generator=g) * 2 * math.pi - math.pi), 1)
    world.box_mask[0, 2] = True
    world.boxes[0, 2, 2:4] = torch.tensor([0.9, 0.6])
    world.circle_mask[1, 0] = True
    ox, oy, _ = CAM.offset
    for env, target in ((0, world.boxes[0, 2, :2] + 0.1), (1, world.circles[1, 0, :2] - 0.1)):
        c, s = math.cos(pose[env, 2]), math.sin(pose[env, 2])  # the camera at target: pose = target - R(th) offset
        pose[env, :2] = target - torch.tensor([c * ox - s * oy, s * ox + c * oy])
    return pose


MASKS = {"segments": "segment_mask", "circles": "circle_mask", "boxes": "box_mask"}


@pytest.mark.parametrize("seed", [0, 1])
def test_depth_and_image_equal_the_reference_on_random_worlds(seed):
    g = torch.Generator().manual_seed(seed)
    b = 96
    world = random_world(b, g)
    pose = poses_inside(world, b, g)
    movers = make_movers(1, [[0.0, 0.0, 0.0, 0.0, 0.3]] * 2, boxes=[[0.0, 0.0, 0.0, 0.0, 0.3, 0.2, 0.5]])
    mrows = movers.rows.expand(b, -1, -1).clone()
    mrows[..., :2] = torch.rand(b, 3, 2, generator=g) * 6 - 3  # 2 discs and a box at random
    mw = mover_world(mrows, movers.mask.expand(b, -1), movers.boxes.expand(b, -1, -1))
    assert mw.boxes.shape[1] and mw.circles.shape[1]  # movers of both kinds
    ref = reference_depth(pose, world, CAM, mw)
    depth = camera_depth(pose, world, CAM, mw)
    torch.testing.assert_close(depth, ref, rtol=0, atol=1e-4)
    # the cameras inside an obstacle read its exit point (within its bounding circle), not the far walls
    assert (depth[0] < math.hypot(0.9, 0.6) + 0.2).all() and (depth[1] < world.circles[1, 0, 2] + 0.2).all()
    styles = ObstacleStyles(circles=((2.0, (1, 2, 3)),), boxes=((None, (9, 8, 7)), (0.1, None)))
    depth2, rgb = camera_image(pose, world, CAM, mw, styles)
    assert torch.equal(depth2, depth)
    z, look = reference_looks(pose, world, CAM, mw, styles)
    torch.testing.assert_close(depth2, z.clamp(max=CAM.max_range), rtol=0, atol=1e-4)
    # the same obstacle drawn in every column (its height and colour), so the same pixels
    # up to the shading's rounding
    ref_img = _render(z, look, CAM)
    assert (rgb.to(torch.int64) - ref_img.to(torch.int64)).abs().max() <= 1


def _render(z, look, cam):
    """The image of columns at depths ``z`` whose nearest obstacles have ``look`` (camera_image's shading)."""
    h = cam.n_rows
    tan_e = (0.5 * h - 0.5 - torch.arange(h, dtype=z.dtype)) / cam.focal
    seen = cam.height + z[:, None, :] * tan_e[None, :, None]
    hit = torch.isfinite(z)[:, None, :] & (z[:, None, :] <= cam.max_range) & (seen >= 0) & (seen <= look[..., 0][:, None, :])
    shade = (1.0 / (1.0 + 0.08 * z.clamp(max=cam.max_range)))[:, None, :, None]
    down = tan_e < 0
    floor_z = torch.where(down, cam.height / torch.where(down, -tan_e, 1.0), 0.0)
    floor = torch.tensor(cam.floor_color, dtype=z.dtype) * (0.6 + 0.4 / (1.0 + 0.15 * floor_z))[None, :, None, None]
    back = torch.where(down[None, :, None, None], floor, torch.tensor(cam.sky_color, dtype=z.dtype).expand(1, h, 1, 3))
    img = torch.where(hit[..., None], look[..., 1:][:, None] * shade, back.expand(*hit.shape, 3))
    return img.round().clamp(0, 255).to(torch.uint8)


def test_unrolled_and_batched_slots_agree(monkeypatch):
    """Kinds of up to 4 slots run one slot at a time in eager mode (here in a small batch too), larger
    ones as one (B, W, N) pass."""
    from torchnav.sim import raycast

    monkeypatch.setattr(raycast, "EAGER_UNROLL_MIN_RAYS", 0)
    assert raycast.unrolled(4, 32 * CAM.n_cols) and not raycast.unrolled(5, 32 * CAM.n_cols)
    g = torch.Generator().manual_seed(3)
    world = random_world(32, g, n_seg=4, n_circ=4, n_box=4)
    pose = poses_inside(world, 32, g)
    wide = World(**{k: torch.cat((v, v[:, :1]), 1) for k, v in world.items()}, batch_size=[32])  # 5 slots each
    torch.testing.assert_close(camera_depth(pose, wide, CAM), camera_depth(pose, world, CAM), rtol=0, atol=0)


def _world(**given):
    """One env with the given obstacle rows (all unmasked) and none of the other kinds."""
    fields = {}
    for key, width in (("segments", 4), ("circles", 3), ("boxes", 5)):
        rows = torch.tensor(given.get(key, []), dtype=torch.float32).reshape(1, -1, width)
        fields[key], fields[MASKS[key]] = rows, torch.ones(1, rows.shape[1], dtype=torch.bool)
    return World(**fields, batch_size=[1])


def test_grazing_columns_read_either_side_of_the_edge():
    """Columns aimed exactly at a segment's end, a box's corner and along a circle's tangent may hit
    or miss under rounding: each reads the grazed point's depth or what lies behind the obstacle."""
    cam = camera_params(n_cols=9, fov=1.2, max_range=20.0)
    m = (4.5 - 2 - 0.5) / cam.focal  # column 2 looks along y = m x
    n = [-m / math.hypot(1.0, m), 1.0 / math.hypot(1.0, m)]  # the line's normal
    back = [8.0, -20.0, 8.0, 20.0]
    cases = [  # (world, kind of the grazed obstacle (slot 0), depth of the grazed point)
        (_world(segments=[[3.0, 3.0 * m, 3.0, 2.0], back]), "segments", 3.0),
        (_world(segments=[[3.0, 3.0 * m - 2.0, 3.0, 3.0 * m], back]), "segments", 3.0),
        (_world(segments=[back], boxes=[[4.5, 4.0 * m + 0.5, 0.5, 0.5, 0.0]]), "boxes", 4.0),
        (_world(segments=[back], circles=[[5.0 + 0.5 * n[0], 5.0 * m + 0.5 * n[1], 0.5]]), "circles", 5.0),
    ]
    pose = torch.zeros(1, 3)
    for world, key, graze in cases:
        depth = camera_depth(pose, world, cam)
        mask = getattr(world, MASKS[key]).clone()
        mask[:, 0] = False
        behind = reference_depth(pose, World(**{**dict(world.items()), MASKS[key]: mask}, batch_size=[1]), cam)
        ref = reference_depth(pose, world, cam)
        assert torch.allclose(depth[:, [0, 1, 3, 4, 5, 6, 7, 8]], ref[:, [0, 1, 3, 4, 5, 6, 7, 8]], atol=1e-4), key
        assert min(abs(depth[0, 2] - graze), abs(depth[0, 2] - behind[0, 2])) <= 1e-3, (key, depth, behind)


def test_gradients_equal_the_reference():
    g = torch.Generator().manual_seed(5)
    b = 48
    world = random_world(b, g)
    pose = poses_inside(world, b, g)
    grads = []
    for fn in (camera_depth, reference_depth):
        p = pose.clone().requires_grad_(True)
        obs = {k: getattr(world, k).clone().requires_grad_(True) for k in ("segments", "circles", "boxes")}
        w = World(**{**dict(world.items()), **obs}, batch_size=[b])
        fn(p, w, CAM).sum().backward()
        grads.append([p.grad] + [obs[k].grad for k in ("segments", "circles", "boxes")])
    for new, ref in zip(*grads):
        assert torch.isfinite(new).all()
        torch.testing.assert_close(new, ref, rtol=1e-3, atol=2e-3)
    assert grads[0][0].abs().sum() > 0
