"""Several robots per env (torchnav.sim.robots): one robot is the single-robot step bit for bit; robots see
each other as discs and collide with each other; absent and parked robots; batch against one env at a time
and against a naive per-robot reference; gradients; compile."""

from __future__ import annotations

import math

import pytest
import torch

from reference import (
    arc_pose, point_box_dist, point_seg_dist, random_world, ray_box, ray_circle, ray_segment,
    valid_obstacles, wrap,
)
from params import camera_params, lidar_params, sim_params
from torchnav.sim import (
    ImuParams, Robots, init_robots, init_state, make_movers,
    make_robots, make_world, robot_clearance, robot_world, sample_env_params, step, step_robots,
)

F64 = torch.float64
SIM_FIELDS = ("pose", "vel", "odom", "ranges", "clearance", "collided", "time", "imu", "imu_bias", "cam_depth", "cmd_queue")
MOVER_FIELDS = ("movers", "mover_mask", "mover_plan", "mover_target", "mover_boxes")
RAYS = lidar_params(n_rays=36, fov=2 * math.pi, max_range=8.0)


def _equal(a, b, fields, n=None):
    for f in fields:
        x, y = getattr(a, f), getattr(b, f)
        if n is not None:
            x = x.reshape(y.shape)
        assert x.dtype == y.dtype and x.shape == y.shape, f
        assert torch.equal(x, y), f


# -- one robot is the single-robot step ---------------------------------------------------------------


NOISY = sim_params(odom_v_noise=0.05, odom_omega_noise=0.05, lin_acc_max=2.0, ang_acc_max=5.0,
                  lidar=lidar_params(n_rays=16, fov=2 * math.pi, noise_std=0.02, max_range=6.0))
EVERYTHING = sim_params(lin_acc_max=2.0, imu=ImuParams(accel_noise=0.1, gyro_noise=0.01, accel_bias_walk=0.01),
                       camera=camera_params(n_cols=8), lidar=lidar_params(n_rays=12, fov=math.pi, scan="sectors", max_range=6.0))
RANDOMIZE = {"v_max": (0.3, 0.5), "delay": (0, 2), "wheel_noise": (0.0, 0.05), "range_noise": (0.0, 0.05), "dropout": (0.0, 0.2),
             "angle_offset": (-0.05, 0.05), "max_range": (4.0, 6.0), "robot_radius": (0.15, 0.25)}


def _movers(b, dtype=torch.float32):
    discs = [[1.5, 0.0, -0.3, 0.1, 0.25], [-1.0, 1.0, 0.4, 0.0, 0.2]]
    boxes = [[0.0, -2.0, 0.2, 0.2, 0.3, 0.2, 0.4]]
    paths = [[[2.0, 2.0], [-2.0, 2.0]], [[1.0, -1.0], [-1.0, -1.0]], []]
    return make_movers(b, discs, region=(-3.0, -3.0, 3.0, 3.0), waypoints=paths, pedestrians=True, boxes=boxes, dtype=dtype)


@pytest.mark.parametrize("case", ["noisy", "everything"])
def test_one_robot_equals_step_bit_for_bit(case):
    """N = 1 is the single-robot step, bit for bit: noise draws, delay, per-env parameters, IMU, camera,
    the exact sector scan and pedestrians that avoid the robot."""
    b = 6
    world = random_world(b, (2, 3, 3), seed=3, dtype=torch.float32)
    g = torch.Generator().manual_seed(0)
    pose = torch.rand(b, 3, generator=g) * 6 - 3
    actions = torch.rand(8, b, 2, generator=g) * 2 - 1
    if case == "noisy":
        params, movers, ep, delay = NOISY, None, None, 0
    else:
        params, movers, delay = EVERYTHING, _movers(b), 2
        ep = sample_env_params(RANDOMIZE, params, b, torch.Generator().manual_seed(1), pose)
    one = init_state(pose, world, params, movers=movers, env_params=ep, delay_steps=delay)
    many = init_robots(pose[:, None], world, params, movers=movers, env_params=None if ep is None else ep.reshape(b, 1), delay_steps=delay)
    robots = make_robots(b, 1)
    g1, g2 = torch.Generator().manual_seed(7), torch.Generator().manual_seed(7)
    for a in [None, *actions]:
        if a is not None:
            one = step(one, a, world, params, generator=g1, env_params=ep)
            many = step_robots(many, a[:, None], world, params, robots, generator=g2, env_params=None if ep is None else ep.reshape(b, 1))
        assert many.robots.batch_size == torch.Size([b, 1])
        _equal(many.robots, one, SIM_FIELDS, n=1)
        _equal(many, one, MOVER_FIELDS)
    assert bool((one.ranges < 6.0).any())


def test_robots_draw_the_noise_of_single_robot_envs():
    """Three robots per env 20 m apart (out of each other's lidar and camera range) step exactly like the
    B * N single-robot envs of their rows: the same odometry, IMU, wheel and lidar noise from the same
    generator, per-robot limits, delay, radius and lidar imperfections, the same readings."""
    b, n = 2, 3
    params = sim_params(odom_v_noise=0.05, odom_omega_noise=0.05, imu=ImuParams(accel_noise=0.1, gyro_bias_walk=0.01),
                       camera=camera_params(n_cols=6, max_range=5.0), lidar=lidar_params(n_rays=10, fov=math.pi, noise_std=0.02, max_range=6.0))
    world = make_world(b, circles=[[20.0 * i + 1.0, 0.4, 0.3] for i in range(n)], boxes=[[20.0 * i - 1.0, 0.0, 0.2, 0.5, 0.3] for i in range(n)])
    g = torch.Generator().manual_seed(4)
    pose = torch.rand(b, n, 3, generator=g) - 0.5
    pose[..., 0] += 20.0 * torch.arange(n)
    actions = torch.rand(6, b, n, 2, generator=g) * 2 - 1
    ep = sample_env_params(RANDOMIZE, params, b * n, torch.Generator().manual_seed(5), pose)
    many = init_robots(pose, world, params, env_params=ep.reshape(b, n), delay_steps=2)
    rows = robot_world(world, n)
    one = init_state(pose.reshape(b * n, 3), rows, params, env_params=ep, delay_steps=2)
    robots = make_robots(b, n)
    g1, g2 = torch.Generator().manual_seed(9), torch.Generator().manual_seed(9)
    for a in actions:
        many = step_robots(many, a, world, params, robots, generator=g1, env_params=ep.reshape(b, n))
        one = step(one, a.reshape(b * n, 2), rows, params, generator=g2, env_params=ep)
        _equal(many.robots, one, SIM_FIELDS, n=n)
    assert bool((one.ranges < 6.0).any()) and bool((one.cam_depth < 5.0).any())


# -- robots see each other -----------------------------------------------------------------------------


def test_ray_towards_another_robot_reads_the_analytic_distance():
    """Robot 0 at the origin facing +x, robot 1 at (d, h) of radius 0.3 (per-robot radii): the ray
    straight ahead reads the near side of robot 1's disc, d - sqrt(r^2 - h^2), and robot 1's ray
    backwards reads robot 0's (radius 0.2); the exact sector scan reads the nearest point, D - r."""
    d = torch.tensor([1.0, 2.5, 4.0], dtype=F64)
    h = torch.tensor([0.0, 0.1, -0.15], dtype=F64)
    b = len(d)
    pose = torch.zeros(b, 2, 3, dtype=F64)
    pose[:, 1, 0], pose[:, 1, 1], pose[:, 1, 2] = d, h, math.pi  # robot 1 faces robot 0
    world = make_world(b, dtype=F64)
    ep = sample_env_params({}, sim_params(lidar=RAYS), 2 * b, torch.Generator().manual_seed(0), pose).reshape(b, 2)
    ep.robot_radius[:, 1] = 0.3
    for scan in ("rays", "sectors"):
        lidar = lidar_params(n_rays=36, fov=2 * math.pi, max_range=8.0, scan=scan)
        s = init_robots(pose, world, sim_params(lidar=lidar), env_params=ep)
        ranges = s.robots.ranges
        if scan == "rays":  # ray 18 of 36 looks straight ahead
            torch.testing.assert_close(ranges[:, 0, 18], d - torch.sqrt(0.3**2 - h**2), atol=1e-12, rtol=0)
            # Robot 1's ray straight ahead (at pi) runs along y = h, at h from robot 0's centre.
            torch.testing.assert_close(ranges[:, 1, 18], d - torch.sqrt(0.2**2 - h**2), atol=1e-12, rtol=0)
        else:
            gap = torch.hypot(d, h)
            torch.testing.assert_close(ranges[:, 0].amin(-1), gap - 0.3, atol=1e-12, rtol=0)
            torch.testing.assert_close(ranges[:, 1].amin(-1), gap - 0.2, atol=1e-12, rtol=0)
        torch.testing.assert_close(s.robots.clearance, (torch.hypot(d, h) - 0.5)[:, None].expand(b, 2), atol=1e-12, rtol=0)
        assert ranges[:, 0].amax() == 8.0  # it sees nothing else


def test_overlapping_robots_are_both_collided_and_an_absent_robot_is_invisible():
    """Robots 0 and 1 overlap: both collided, with the same clearance. Robot 2 is absent, placed on
    top of robot 0 and in front of robot 1's rays: it never collides, nobody sees it, and its action
    does not move it; the two others read what they read in an env of two robots."""
    params = sim_params(lidar=RAYS)
    pose = torch.tensor([[[0.0, 0.0, 0.0], [0.3, 0.0, math.pi / 2], [0.05, 0.0, 0.0]]], dtype=F64)
    world = make_world(1, segments=[[3.0, -3.0, 3.0, 3.0]], dtype=F64)
    robots = Robots(torch.tensor([[True, True, False]]), torch.zeros(1, 3, dtype=torch.bool))
    s3 = init_robots(pose, world, params, robots)
    s2 = init_robots(pose[:, :2], world, params)
    assert s3.robots.collided.tolist() == [[True, True, False]]
    torch.testing.assert_close(s3.robots.clearance[0, :2], torch.full((2,), 0.3 - 0.4, dtype=F64), atol=1e-12, rtol=0)
    assert s3.robots.clearance[0, 2] == math.inf
    gap = robot_clearance(pose[..., :2], params.robot_radius, robots.present)  # the robot-robot part alone
    assert torch.equal(gap[0, :2], s3.robots.clearance[0, :2]) and gap[0, 2] == math.inf
    assert robot_clearance(pose[:, :1, :2], 0.2, robots.present[:, :1]).tolist() == [[math.inf]]
    action = torch.tensor([[[0.2, 0.0], [0.0, 0.3], [0.5, 0.5]]], dtype=F64)
    for _ in range(5):
        s3 = step_robots(s3, action, world, params, robots)
        s2 = step_robots(s2, action[:, :2], world, params, make_robots(1, 2))
        _equal(s3.robots[:, :2], s2.robots, ("pose", "ranges", "clearance", "collided"))
        assert torch.equal(s3.robots.pose[0, 2], pose[0, 2]) and s3.robots.vel[0, 2].tolist() == [0.0, 0.0]
        assert not s3.robots.collided[0, 2] and s3.robots.clearance[0, 2] == math.inf


def test_parked_robot_does_not_move_but_is_seen_and_hit():
    """Robot 1 is parked 1.52 m ahead of robot 0 with a command to drive (and acceleration limits): it
    stays put, while robot 0's ray straight ahead shortens by v dt a step until both collide."""
    params = sim_params(lidar=RAYS, lin_acc_max=1.0, v_max=0.5)
    pose = torch.tensor([[[0.0, 0.0, 0.0], [1.52, 0.0, 0.5]]], dtype=F64)
    world = make_world(1, dtype=F64)
    robots = Robots(torch.ones(1, 2, dtype=torch.bool), torch.tensor([[False, True]]))
    s = init_robots(pose, world, params, robots, vel=torch.tensor([[[0.5, 0.0], [0.5, 0.2]]], dtype=F64))
    action = torch.tensor([[[0.5, 0.0], [-0.5, 1.0]]], dtype=F64)
    hit = None
    for k in range(1, 26):
        s = step_robots(s, action, world, params, robots)
        assert torch.equal(s.robots.pose[0, 1], pose[0, 1]) and torch.equal(s.robots.odom[0, 1], pose[0, 1])
        assert s.robots.vel[0, 1].tolist() == [0.0, 0.0]
        torch.testing.assert_close(s.robots.ranges[0, 0, 18], torch.tensor(1.52 - 0.2 - 0.05 * k, dtype=F64), atol=1e-12, rtol=0)
        if hit is None and bool(s.robots.collided[0, 0]):
            hit = k
            assert s.robots.collided[0].tolist() == [True, True]  # the parked robot is hit too
    assert hit == 23  # the discs touch when robot 0 has driven 1.12 m


def test_pedestrians_avoid_every_present_robot():
    """A pedestrian walking at two robots swerves around the second one only while it is present."""
    params, world = sim_params(), make_world(1)
    movers = make_movers(1, [[-3.0, 0.05, 0.6, 0.0, 0.25]], waypoints=[[[3.0, 0.0]]], pedestrians=True)
    pose = torch.tensor([[[0.0, 5.0, 0.0], [0.0, 0.0, 0.0]]])
    both = Robots(torch.ones(1, 2, dtype=torch.bool), torch.zeros(1, 2, dtype=torch.bool))
    first = Robots(torch.tensor([[True, False]]), torch.zeros(1, 2, dtype=torch.bool))
    a, b = init_robots(pose, world, params, both, movers=movers), init_robots(pose, world, params, first, movers=movers)
    alone = init_state(pose[:, 0], world, params, movers=movers)
    swerve, closest = 0.0, math.inf
    for _ in range(100):
        a = step_robots(a, torch.zeros(1, 2, 2), world, params, both)
        b = step_robots(b, torch.zeros(1, 2, 2), world, params, first)
        alone = step(alone, torch.zeros(1, 2), world, params)
        torch.testing.assert_close(b.movers, alone.movers)  # an absent robot is not avoided
        swerve = max(swerve, (a.movers[0, 0, :2] - b.movers[0, 0, :2]).norm().item())
        closest = min(closest, a.robots.clearance[0, 1].item())
    assert swerve > 0.1 and closest > 0


# -- batch against one env at a time and a naive reference ---------------------------------------------


def _naive_robot(pose, world, radii, present, b, i, lidar):
    """Ranges and clearance of robot ``i`` of env ``b``: the env's valid obstacles plus the other present
    robots as circles, with explicit loops (tests/reference.py's casts and distances)."""
    segs, circs, boxes = valid_obstacles(world, b)
    circs = circs + [(float(pose[b, j, 0]), float(pose[b, j, 1]), float(radii[b, j])) for j in range(pose.shape[1]) if j != i and bool(present[b, j])]
    x, y, th = (float(v) for v in pose[b, i])
    row = []
    for a in lidar.angles():
        dx, dy = math.cos(th + a), math.sin(th + a)
        best = min([math.inf] + [ray_segment(x, y, dx, dy, *s) for s in segs] + [ray_circle(x, y, dx, dy, *c) for c in circs]
                   + [ray_box(x, y, dx, dy, *k) for k in boxes])
        row.append(min(max(best, lidar.min_range), lidar.max_range))
    gap = min([math.inf] + [point_seg_dist(x, y, *s) for s in segs] + [math.hypot(x - cx, y - cy) - r for cx, cy, r in circs]
              + [point_box_dist(x, y, *k) for k in boxes])
    return row, gap - float(radii[b, i])


def test_batch_equals_each_env_alone_and_a_naive_per_robot_reference():
    """Four envs of three robots in random padded worlds (one robot absent, one parked, per-robot
    radii): the batched step equals each env stepped alone bit for bit, and every robot's pose, ranges
    and clearance equal a per-robot Python loop over rays, obstacles and the other robots."""
    b, n = 4, 3
    params = sim_params(lidar=lidar_params(n_rays=24, fov=2 * math.pi, max_range=6.0))
    world = random_world(b, (2, 3, 2), seed=5)
    g = torch.Generator().manual_seed(2)
    pose = torch.rand(b, n, 3, generator=g, dtype=F64) * 3 - 1.5
    actions = torch.rand(6, b, n, 2, generator=g, dtype=F64) * 2 - 1
    present = torch.ones(b, n, dtype=torch.bool)
    present[1, 2] = False
    parked = torch.zeros(b, n, dtype=torch.bool)
    parked[2, 0] = True
    robots = Robots(present, parked)
    ep = sample_env_params({"robot_radius": (0.15, 0.3)}, params, b * n, torch.Generator().manual_seed(3), pose).reshape(b, n)
    state = init_robots(pose, world, params, robots, env_params=ep)
    alone = [init_robots(pose[k : k + 1], world[k : k + 1], params, Robots(present[k : k + 1], parked[k : k + 1]), env_params=ep[k : k + 1])
             for k in range(b)]
    seen = 0
    for a in actions:
        before = state.robots.pose
        state = step_robots(state, a, world, params, robots, env_params=ep)
        alone = [step_robots(s, a[k : k + 1], world[k : k + 1], params, Robots(present[k : k + 1], parked[k : k + 1]), env_params=ep[k : k + 1])
                 for k, s in enumerate(alone)]
        _equal(state.robots, torch.cat([s.robots for s in alone]), SIM_FIELDS)
        p = state.robots.pose
        gaps = robot_clearance(p[..., :2], ep.robot_radius, present)
        for k in range(b):
            for i in range(n):
                if not present[k, i]:
                    assert state.robots.clearance[k, i] == math.inf and not state.robots.collided[k, i]
                    continue
                v, w = (0.0, 0.0) if parked[k, i] else (max(min(float(a[k, i, 0]), 0.5), -0.5), max(min(float(a[k, i, 1]), 1.0), -1.0))
                x, y, th = arc_pose(*(float(c) for c in before[k, i]), v, w, params.dt)
                assert p[k, i].tolist() == pytest.approx([x, y, wrap(th)], abs=1e-12)
                ranges, clearance = _naive_robot(p, world, ep.robot_radius, present, k, i, params.lidar)
                assert state.robots.ranges[k, i].tolist() == pytest.approx(ranges, abs=1e-9)
                assert state.robots.clearance[k, i].item() == pytest.approx(clearance, abs=1e-12)
                others = [math.hypot(*(p[k, i, :2] - p[k, j, :2]).tolist()) - float(ep.robot_radius[k, i] + ep.robot_radius[k, j])
                          for j in range(n) if j != i and present[k, j]]
                assert gaps[k, i].item() == pytest.approx(min(others, default=math.inf), abs=1e-12)
                seen += sum(r < 6.0 for r in ranges)
    assert seen > 50


def test_static_world_made_once_equals_made_per_call():
    """``robot_world`` made once gives what a per-env world repeated at every call gives."""
    b, n = 3, 4
    params = sim_params(lidar=RAYS)
    world = random_world(b, (2, 2, 2), seed=1, dtype=torch.float32)
    pose = torch.rand(b, n, 3, generator=torch.Generator().manual_seed(0)) * 4 - 2
    robots = make_robots(b, n)
    rows = robot_world(world, n)
    assert rows.batch_size == torch.Size([b * n]) and torch.equal(rows.circles[n + 1], world.circles[1])
    a, c = init_robots(pose, world, params, robots), init_robots(pose, rows, params, robots)
    for _ in range(3):
        a = step_robots(a, torch.full((b, n, 2), 0.3), world, params, robots)
        c = step_robots(c, torch.full((b, n, 2), 0.3), rows, params, robots)
        _equal(a.robots, c.robots, SIM_FIELDS)


def test_bad_inputs_name_the_problem():
    params, world = sim_params(), make_world(2)
    state = init_robots(torch.zeros(2, 3, 3), world, params)
    robots = make_robots(2, 3)
    a = torch.zeros(2, 3, 2)
    with pytest.raises(ValueError, match=r"action must have shape \(2, 3, 2\)"):
        step_robots(state, torch.zeros(6, 2), world, params, robots)
    with pytest.raises(ValueError, match=r"robots.present must be a \(2, 3\) bool"):
        step_robots(state, a, world, params, make_robots(2, 2))
    with pytest.raises(ValueError, match=r"robots.parked must be a \(2, 3\) bool"):
        step_robots(state, a, world, params, Robots(robots.present, torch.zeros(2, 3)))
    with pytest.raises(ValueError, match=r"world must have batch 2 \(one per env\) or 6"):
        step_robots(state, a, make_world(3), params, robots)
    with pytest.raises(ValueError, match=r"env_params must have batch \(2, 3\)"):
        step_robots(state, a, world, params, robots, env_params=sample_env_params({}, params, 6, torch.Generator(), a))
    with pytest.raises(ValueError, match=r"pose must have shape \(B, N, 3\)"):
        init_robots(torch.zeros(2, 3), world, params)
    with pytest.raises(ValueError, match=r"counts must be 2 whole numbers in \[0, 3\]"):
        make_robots(2, 3, counts=[1, 4])
    assert make_robots(2, 3, counts=[1, 3]).present.tolist() == [[True, False, False], [True, True, True]]


# -- gradients ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("scan", ["rays", "sectors"])
def test_gradcheck_through_robot_robot_ranges(scan):
    """gradcheck in float64 of every robot's ranges and clearance after one step, with respect to the
    start poses and the actions of all robots: the other robots' discs pass gradients along."""
    lidar = lidar_params(n_rays=16, fov=2 * math.pi, max_range=5.0, scan=scan)
    params = sim_params(lidar=lidar, robot_radius=0.3)
    world = make_world(1, circles=[[0.3, 2.0, 0.4]], dtype=F64)
    robots = make_robots(1, 3)
    start = torch.tensor([[[0.0, 0.0, 0.1], [1.6, 0.17, 2.9], [0.9, -1.3, 1.7]]], dtype=F64, requires_grad=True)
    action = torch.tensor([[[0.3, 0.2], [0.2, -0.3], [0.4, 0.1]]], dtype=F64, requires_grad=True)

    def f(pose, act, robots=robots):
        s = step_robots(init_robots(pose, world, params, robots), act, world, params, robots)
        return s.robots.ranges, s.robots.clearance

    with torch.no_grad():  # readings of robots: those that change when the others are absent
        alone = [f(start, action, Robots((torch.arange(3) == i)[None], torch.zeros(1, 3, dtype=torch.bool)))[0][0, i] for i in range(3)]
        seen = sum(int((f(start, action)[0][0, i] != alone[i]).sum()) for i in range(3))
    assert seen >= 5
    assert torch.autograd.gradcheck(f, (start, action), eps=1e-6, atol=1e-6)


def test_gradients_through_many_steps_are_finite_and_cross_robots():
    """Through 25 steps, robot 0's nearest range has a finite, non-zero gradient with respect to robot 1's
    actions (robot 1 is what robot 0 sees), and grad mode leaves every value unchanged."""
    params = sim_params(lidar=lidar_params(n_rays=16, fov=math.pi, max_range=5.0))
    world = make_world(2, segments=[[4.0, -4.0, 4.0, 4.0]])
    pose = torch.tensor([[[0.0, 0.0, 0.0], [2.0, 0.3, math.pi]], [[0.0, 0.0, 0.0], [1.5, -0.4, 3.0]]])
    robots = make_robots(2, 2)
    actions = torch.full((25, 2, 2, 2), 0.05, requires_grad=True)

    def run():
        s = init_robots(pose, world, params, robots)
        for a in actions:
            s = step_robots(s, a, world, params, robots)
        return s

    s = run()
    s.robots.ranges[:, 0].amin(-1).sum().backward()
    grad = actions.grad
    assert torch.isfinite(grad).all() and grad[:, :, 1].abs().sum() > 0
    with torch.no_grad():
        _equal(run().robots, s.robots.detach(), SIM_FIELDS)


# -- compile -----------------------------------------------------------------------------------------


def _compile_case():
    params = sim_params(lidar=lidar_params(n_rays=12, fov=2 * math.pi, max_range=6.0))
    b, n = 4, 3
    world = random_world(b, (2, 2, 2), seed=2)
    pose = torch.rand(b, n, 3, generator=torch.Generator().manual_seed(1), dtype=F64) * 4 - 2
    robots = Robots(torch.tensor([[True, True, False]] + [[True] * 3] * 3), torch.zeros(b, n, dtype=torch.bool))
    state = init_robots(pose, robot_world(world, n), params, robots, movers=_movers(b, F64))
    actions = torch.rand(3, b, n, 2, generator=torch.Generator().manual_seed(2), dtype=F64) - 0.5
    return state, robot_world(world, n), actions, params, robots


def _rollout(fn, state, world, actions, params, robots):
    out = []
    for a in actions:
        state = fn(state, a, world, params, robots)
        out.append(state)
    return out


def test_step_robots_traces_as_one_graph():
    """Dynamo captures the whole multi-robot step, movers included, without graph breaks."""
    torch._dynamo.reset()
    state, world, actions, params, robots = _compile_case()
    eager = _rollout(step_robots, state, world, actions, params, robots)
    traced = _rollout(torch.compile(step_robots, backend="eager", fullgraph=True), state, world, actions, params, robots)
    for e, c in zip(eager, traced):
        _equal(c.robots, e.robots, SIM_FIELDS)


@pytest.mark.slow
def test_torch_compile_matches_eager():
    """Inductor-compiled step_robots (tens of seconds of cold compilation on 2 CPU cores)."""
    torch._dynamo.reset()
    state, world, actions, params, robots = _compile_case()
    eager = _rollout(step_robots, state, world, actions, params, robots)
    compiled = _rollout(torch.compile(step_robots, fullgraph=True), state, world, actions, params, robots)
    for e, c in zip(eager, compiled):
        for f in SIM_FIELDS:
            torch.testing.assert_close(getattr(c.robots, f), getattr(e.robots, f), atol=1e-9, rtol=0)
