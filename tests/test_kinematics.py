"""Differential-drive kinematics against closed-form motion, limits and odometry."""

from __future__ import annotations

import math

import pytest
import torch

from params import lidar_params, sim_params
from reference import arc_pose, wrap
from torchnav.sim import (
    apply_limits,
    init_state,
    integrate_euler,
    integrate_exact,
    make_world,
    step,
    unicycle_to_wheels,
    wheels_to_unicycle,
)

F64 = torch.float64


def rollout(fn, pose, twist, dt, n):
    for _ in range(n):
        pose = fn(pose, twist, dt)
    return pose


# --------------------------------------------------------------------------- analytic motion


@pytest.mark.parametrize("fn", [integrate_exact, integrate_euler], ids=["exact", "euler"])
@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_straight_drive_ends_at_x0_plus_vt(fn, dtype):
    pose0 = torch.tensor([[1.0, -2.0, 0.0], [0.5, 0.5, 2.0], [0.0, 0.0, -2.5]], dtype=dtype)
    v = torch.tensor([0.4, -0.3, 0.25], dtype=dtype)
    twist = torch.stack((v, torch.zeros_like(v)), -1)
    dt, n = 0.1, 40
    end = rollout(fn, pose0, twist, dt, n)
    t = dt * n
    expect = torch.stack(
        (pose0[:, 0] + v * t * torch.cos(pose0[:, 2]), pose0[:, 1] + v * t * torch.sin(pose0[:, 2]), pose0[:, 2]), -1
    )
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(end, expect, atol=tol, rtol=0)


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (F64, 1e-11)])
def test_exact_integrator_follows_the_circle(dtype, tol):
    x0, y0, th0, v, w = 0.3, -0.7, 0.4, 0.5, 0.8
    dt, n = 0.1, 50
    r = v / w
    cx, cy = x0 - r * math.sin(th0), y0 + r * math.cos(th0)
    pose = torch.tensor([[x0, y0, th0]], dtype=dtype)
    twist = torch.tensor([[v, w]], dtype=dtype)
    for k in range(1, n + 1):
        pose = integrate_exact(pose, twist, dt)
        # Every intermediate pose lies on the circle of radius v/omega, at angle omega*t.
        x, y, th = pose[0].tolist()
        assert math.hypot(x - cx, y - cy) == pytest.approx(r, abs=tol)
        assert abs(wrap(math.atan2(y - cy, x - cx) - (th0 - math.pi / 2 + w * k * dt))) < 10 * tol
        assert abs(wrap(th - (th0 + w * k * dt))) < 10 * tol
    ex, ey, eth = arc_pose(x0, y0, th0, v, w, n * dt)
    torch.testing.assert_close(pose[0], torch.tensor([ex, ey, wrap(eth)], dtype=dtype), atol=tol, rtol=0)


def test_euler_converges_to_the_arc_at_first_order():
    x0, y0, th0, v, w, t_end = 0.0, 0.0, 0.3, 0.5, 1.0, 2.0
    exact = torch.tensor(arc_pose(x0, y0, th0, v, w, t_end)[:2], dtype=F64)
    errors = []
    for n in (20, 40, 80, 160):
        pose = rollout(integrate_euler, torch.tensor([[x0, y0, th0]], dtype=F64), torch.tensor([[v, w]], dtype=F64), t_end / n, n)
        errors.append(float(torch.linalg.vector_norm(pose[0, :2] - exact)))
    assert errors[0] > 1e-3  # Euler really is off at coarse dt ...
    ratios = [errors[i] / errors[i + 1] for i in range(len(errors) - 1)]
    for ratio in ratios:  # ... and halving dt halves the error
        assert 1.8 < ratio < 2.2, (errors, ratios)
    # The exact integrator has no such error at any dt.
    pose = rollout(integrate_exact, torch.tensor([[x0, y0, th0]], dtype=F64), torch.tensor([[v, w]], dtype=F64), t_end / 20, 20)
    torch.testing.assert_close(pose[0, :2], exact, atol=1e-12, rtol=0)


@pytest.mark.parametrize("fn", [integrate_exact, integrate_euler], ids=["exact", "euler"])
def test_spin_in_place_keeps_position(fn):
    pose0 = torch.tensor([[1.5, -0.5, 3.0], [0.0, 2.0, -1.0]], dtype=F64)
    twist = torch.tensor([[0.0, 1.0], [0.0, -0.7]], dtype=F64)
    dt, n = 0.1, 30
    end = rollout(fn, pose0, twist, dt, n)
    assert torch.equal(end[:, :2], pose0[:, :2])
    expect = [wrap(3.0 + 1.0 * dt * n), wrap(-1.0 - 0.7 * dt * n)]
    torch.testing.assert_close(end[:, 2], torch.tensor(expect, dtype=F64), atol=1e-12, rtol=0)
    assert bool(((end[:, 2] >= -math.pi) & (end[:, 2] < math.pi)).all())


# --------------------------------------------------------------------------- omega -> 0


@pytest.mark.parametrize("w", [0.0, 1e-8, -1e-8, 1e-3, -1e-3])
@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_exact_integrator_near_zero_turn_rate(w, dtype):
    dt = 0.1
    pose = torch.tensor([[0.2, -0.1, 0.7]], dtype=dtype, requires_grad=True)
    twist = torch.tensor([[0.45, w]], dtype=dtype, requires_grad=True)
    out = integrate_exact(pose, twist, dt)
    assert torch.isfinite(out).all()
    tol = 1e-7 if dtype == torch.float32 else 1e-14
    # Matches the classic v/omega arc formula where that formula is itself accurate
    # (it cancels catastrophically below omega ~ 1e-4), ...
    if abs(w) >= 1e-4:
        ex, ey, eth = arc_pose(0.2, -0.1, 0.7, 0.45, w, dt)
        torch.testing.assert_close(out[0].detach(), torch.tensor([ex, ey, eth], dtype=dtype), atol=10 * tol, rtol=0)
    # ... and the Euler (straight) step up to the O(omega * v * dt^2) arc correction.
    euler = integrate_euler(pose, twist, dt).detach()
    assert float((out.detach() - euler).abs().max()) <= abs(w) * 0.45 * dt * dt + tol
    # Gradients are finite and equal the analytic Jacobian of the straight/arc step.
    for k in range(3):
        gp, gt = torch.autograd.grad(out[0, k], (pose, twist), retain_graph=True)
        assert torch.isfinite(gp).all() and torch.isfinite(gt).all()
    gp_x = torch.autograd.grad(out[0, 0], twist, retain_graph=True)[0][0]
    # d x / d v = dt cos(theta + w dt / 2) sinc(w dt / 2); d x / d omega -> -v dt^2 sin(theta) / 2 as w -> 0.
    u = w * dt / 2
    sinc = 1.0 if u == 0 else math.sin(u) / u
    assert float(gp_x[0]) == pytest.approx(dt * math.cos(0.7 + u) * sinc, abs=10 * tol)
    assert float(gp_x[1]) == pytest.approx(-0.45 * dt * dt * math.sin(0.7) / 2, abs=1e-5 if dtype == torch.float32 else 1e-6)


# --------------------------------------------------------------------------- conversions and limits


def test_wheel_unicycle_conversions():
    track = 0.3
    wheels = torch.tensor([[0.1, 0.3], [0.5, 0.5], [-0.2, 0.2], [0.4, -0.1]], dtype=F64)
    twist = wheels_to_unicycle(wheels, track)
    vl, vr = wheels[:, 0], wheels[:, 1]
    torch.testing.assert_close(twist[:, 0], (vl + vr) / 2, atol=1e-15, rtol=0)
    torch.testing.assert_close(twist[:, 1], (vr - vl) / track, atol=1e-15, rtol=0)
    assert twist[0].tolist() == pytest.approx([0.2, 0.2 / 0.3])
    assert twist[2, 0] == 0.0  # opposite wheels: spin in place
    torch.testing.assert_close(unicycle_to_wheels(twist, track), wheels, atol=1e-15, rtol=0)
    g = torch.Generator().manual_seed(0)
    tw = torch.randn(7, 5, 2, generator=g, dtype=F64)  # any leading shape
    torch.testing.assert_close(wheels_to_unicycle(unicycle_to_wheels(tw, 0.45), 0.45), tw, atol=1e-14, rtol=0)


def test_speed_limits_clamp():
    p = sim_params(v_min=-0.2, v_max=0.5, omega_max=1.0)
    cmd = torch.tensor([[2.0, 3.0], [-1.0, -3.0], [0.3, 0.5], [0.5, -1.0]])
    out = apply_limits(cmd, torch.zeros(4, 2), p)
    torch.testing.assert_close(out, torch.tensor([[0.5, 1.0], [-0.2, -1.0], [0.3, 0.5], [0.5, -1.0]]), atol=0, rtol=0)


def test_acceleration_limits_ramp_through_step():
    p = sim_params(dt=0.1, v_max=0.5, omega_max=1.0, lin_acc_max=1.0, ang_acc_max=4.0)
    world = make_world(1, dtype=F64)
    state = init_state(torch.zeros(1, 3, dtype=F64), world, p)
    vs, ws = [], []
    for _ in range(7):
        state = step(state, torch.tensor([[1.0, -1.0]], dtype=F64), world, p)
        vs.append(float(state.vel[0, 0]))
        ws.append(float(state.vel[0, 1]))
    # v rises by lin_acc_max * dt = 0.1 per step until v_max; omega by 0.4 per step until omega_max.
    assert vs == pytest.approx([0.1, 0.2, 0.3, 0.4, 0.5, 0.5, 0.5])
    assert ws == pytest.approx([-0.4, -0.8, -1.0, -1.0, -1.0, -1.0, -1.0])
    # Braking is limited the same way.
    state = step(state, torch.tensor([[-1.0, 1.0]], dtype=F64), world, p)
    assert state.vel[0].tolist() == pytest.approx([0.4, -0.6])


def test_non_finite_commands_mean_stop():
    p = sim_params()
    cmd = torch.tensor([[math.nan, 0.3], [math.inf, -math.inf], [0.2, math.nan]])
    out = apply_limits(cmd, torch.zeros(3, 2), p)
    assert out.tolist() == [[0.0, pytest.approx(0.3)], [0.0, 0.0], [pytest.approx(0.2), 0.0]]


# --------------------------------------------------------------------------- odometry


def _drive(params, gen, n=25):
    world = make_world(2, dtype=F64)
    state = init_state(torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], dtype=F64), world, params)
    action = torch.tensor([[0.4, 0.3], [0.2, -0.5]], dtype=F64)
    for _ in range(n):
        state = step(state, action, world, params, generator=gen)
    return state


def test_odometry_without_noise_equals_pose():
    state = _drive(sim_params(), torch.Generator().manual_seed(0))
    assert torch.equal(state.odom, state.pose)
    # Noise configured but no generator: still noise-free.
    state = _drive(sim_params(odom_v_noise=0.1, odom_omega_noise=0.1), None)
    assert torch.equal(state.odom, state.pose)


def test_odometry_noise_drifts_reproducibly():
    noisy = sim_params(odom_v_noise=0.05, odom_omega_noise=0.05)
    clean = _drive(sim_params(), None)
    a = _drive(noisy, torch.Generator().manual_seed(3))
    b = _drive(noisy, torch.Generator().manual_seed(3))
    c = _drive(noisy, torch.Generator().manual_seed(4))
    assert torch.equal(a.pose, clean.pose)  # noise never touches the true pose
    assert torch.equal(a.vel, clean.vel)
    drift = (a.odom - a.pose).abs()
    assert float(drift[:, :2].max()) > 1e-3 and float(drift[:, 2].max()) > 1e-3
    assert torch.equal(a.odom, b.odom)  # same seed, same drift
    assert not torch.equal(a.odom, c.odom)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_wrap_angle_never_returns_plus_pi(dtype):
    from torchnav.sim import wrap_angle

    eps = torch.finfo(dtype).eps
    a = torch.tensor([-math.pi, math.pi, -math.pi - eps, -math.pi * (1 + eps), 3 * math.pi, -3 * math.pi], dtype=dtype)
    a = torch.cat((a, torch.nextafter(a, torch.full_like(a, -10.0)), torch.rand(10_000, dtype=dtype) * 200 - 100))
    w = wrap_angle(a)
    assert (w >= -math.pi).all() and (w < math.pi).all()


def _guard_scan(scan: str, n: int = 20):

    return lidar_params(n_rays=n, fov=2 * math.pi, scan=scan, max_range=10.0)


def test_forward_speed_guard_against_points_in_the_path():
    from torchnav.sim.kinematics import forward_speed_guard

    lidar = _guard_scan("rays", 4)  # rays at -pi, -pi/2, 0, pi/2
    far = 10.0
    ranges = torch.tensor([
        [far, far, 1.0, far],  # a return 1 m straight ahead
        [0.1, far, far, far],  # behind: never in the path
        [far, far, far, 0.3],  # beside at 0.3 m: outside radius + clearance (0.25 m)
        [far, far, far, far],  # nothing: misses read max_range
    ], dtype=F64)
    cap = forward_speed_guard(ranges, lidar, 0.2, 0.05, 0.1)
    assert cap[0].item() == pytest.approx((1.0 - 0.25) / 0.1)
    assert cap[1:].tolist() == [math.inf, math.inf, math.inf]
    # A per-env radius (domain randomisation) moves the stop.
    cap = forward_speed_guard(ranges[:1].expand(2, 4), lidar, torch.tensor([0.2, 0.4], dtype=F64), 0.0, 0.1)
    torch.testing.assert_close(cap, torch.tensor([8.0, 6.0], dtype=F64))


def test_forward_speed_guard_takes_the_worst_bearing_in_each_sector():
    """A sector scan's return lies somewhere in its 18-degree sector: the guard's bound is the
    smallest free distance over every bearing in it, found here by brute force."""
    from torchnav.sim.kinematics import forward_speed_guard

    n, radius, clearance, dt = 20, 0.2, 0.05, 0.1
    lidar = _guard_scan("sectors", n)
    width = 2 * math.pi / n
    reach = radius + clearance
    for k in range(n):
        for r in (0.3, 0.6, 1.5):
            ranges = torch.full((1, n), 10.0, dtype=F64)
            ranges[0, k] = r
            lo = -math.pi + k * width  # sector k spans [lo, lo + width]
            bearings = torch.linspace(lo, lo + width, 2001, dtype=F64)
            x, y = r * torch.cos(bearings), (r * torch.sin(bearings)).abs()
            hit = (x > 0) & (y < reach)
            free = torch.where(hit, x - torch.sqrt((reach**2 - y**2).clamp(min=0)), torch.full_like(x, math.inf))
            want = free.min().clamp(min=0) / dt
            got = forward_speed_guard(ranges, lidar, radius, clearance, dt)[0]
            if math.isinf(want):
                assert math.isinf(got), (k, r)
            else:
                assert got.item() == pytest.approx(want.item(), abs=1e-9), (k, r)


def test_forward_speed_guard_leaves_room_to_brake_through_the_delay():
    """With a deceleration and an actuator delay the capped speed, driven for 1 + delay steps and then
    braked, stops exactly at the free distance; with neither it is the one-step bound."""
    from torchnav.sim.kinematics import forward_speed_guard

    lidar = _guard_scan("rays", 4)
    ranges = torch.tensor([[10.0, 10.0, 1.25, 10.0], [10.0, 10.0, 10.0, 10.0]], dtype=F64)  # 1 m free ahead, nothing
    free, dt = 1.0, 0.1
    for decel, delay in ((1.0, 0), (1.0, 2), (3.0, 1), (math.inf, 2)):
        v = forward_speed_guard(ranges, lidar, 0.2, 0.05, dt, decel=decel, delay=delay)
        stop = v[0] * (1 + delay) * dt + (v[0] ** 2 / (2 * decel) if math.isfinite(decel) else 0.0)
        assert stop.item() == pytest.approx(free, rel=1e-12) and math.isinf(v[1]), (decel, delay)
    slow = forward_speed_guard(ranges, lidar, 0.2, 0.05, dt, decel=1.0, delay=1)[0]
    assert slow < forward_speed_guard(ranges, lidar, 0.2, 0.05, dt)[0] / 2  # braking takes room


def test_the_guarded_robot_with_bounded_braking_stops_short_of_a_wall():
    """Full speed at a wall with 1 m/s^2 and a one-step delay: the guard that plans the stop keeps the robot
    off the wall (planned as an instant stop, it hit it)."""
    from torchnav.envs import make_nav_env

    env = make_nav_env("empty", num_envs=1, seed=0, robot={"lin_acc_max": 1.0}, randomize={"delay": [1, 1]},
                       action={"stop_clearance": 0.05}, max_steps=200)
    td = env.reset_to(torch.tensor([[0.0, 0.0, 0.0]]), torch.tensor([[-3.0, 3.0]]))  # facing the wall at x = 5, the goal behind
    for _ in range(150):
        td["action"] = torch.tensor([[1.0, 0.0]])
        td = env.step(td)
        assert not td["next", "collision"].any()
        td = td["next"]
    assert 4.0 < env.state.sim.pose[0, 0].item() < 5.0 - 0.2  # drove up to the wall and stopped short of it


def _first_touch(x: float, y: float, curvature: float, reach: float, length: float = 30.0) -> float:
    """Brute force: the first arc length (1e-4 m grid) at which the disc centre on the circle of ``curvature`` comes within
    ``reach`` of ``(x, y)``; inf if it never does within ``length`` m or one turn."""
    s = torch.linspace(0.0, length, 300_001, dtype=F64)
    cx, cy = (s, torch.zeros_like(s)) if curvature == 0 else (torch.sin(curvature * s) / curvature, (1 - torch.cos(curvature * s)) / curvature)
    hit = (torch.hypot(cx - x, cy - y) < reach).nonzero()
    turn = 2 * math.pi / abs(curvature) if curvature else math.inf
    return s[hit[0, 0]].item() if len(hit) and s[hit[0, 0]].item() < turn else math.inf


def test_arc_free_length_against_brute_force():
    from torchnav.sim.kinematics import arc_free_length

    g = torch.Generator().manual_seed(0)
    reach, checked = 0.3, 0
    for i in range(350):
        x, y = (torch.rand(2, generator=g, dtype=F64) * 6 - 3).tolist()
        k = (0.3, -0.3, 2.0, -2.0, 8.0, -5.0, 1e-7)[i % 7]
        if math.hypot(x, y) < reach:
            continue
        want = _first_touch(x, y, 0.0 if k == 1e-7 else k, reach)
        got = arc_free_length(*(torch.tensor(v, dtype=F64) for v in (x, y, k, reach))).item()
        if k != 1e-7 and got >= 2 * math.pi / abs(k):
            got = math.inf
        if math.isinf(want) and k == 1e-7:
            assert got > 29.9 or math.isinf(got), (x, y, k)
        elif math.isinf(want):
            assert math.isinf(got), (x, y, k, got)
        else:
            assert got == pytest.approx(want, abs=2e-4), (x, y, k)
            checked += 1
    assert checked >= 20  # enough points lie on the paths


def test_arc_free_length_near_the_start_and_straight():
    from torchnav.sim.kinematics import arc_free_length

    t = lambda *v: torch.tensor(v, dtype=torch.float32)  # noqa: E731
    reach = t(0.25)
    # already within reach: 0 if the first motion approaches it, inf if it leaves it
    assert arc_free_length(t(0.1), t(0.1), t(2.0), reach).tolist() == [0.0]
    assert arc_free_length(t(-0.1), t(0.1), t(2.0), reach).tolist() == [math.inf]
    # a vanishing curvature is the straight corridor: x - sqrt(reach^2 - y^2), in float32 too
    got = arc_free_length(t(1.0, 2.0, 3.0), t(0.0, 0.2, -0.3), t(0.0, 1e-9, -1e-8), reach)
    assert got[:2].tolist() == pytest.approx([0.75, 2.0 - math.sqrt(0.25**2 - 0.2**2)], abs=1e-5)
    assert math.isinf(got[2])


def test_arc_speed_guard_caps_a_turn_into_a_return():
    """Straight ahead the arc guard is the straight-line guard; turning towards a return beside the path
    it slows the robot, turning away it does not."""
    from torchnav.sim.kinematics import arc_free_length, arc_speed_guard, forward_speed_guard, stopping_speed

    lidar = _guard_scan("rays", 8)  # rays every 45 degrees from behind
    ranges = torch.full((3, 8), 10.0, dtype=F64)
    ranges[:, 5] = 0.8  # a return at 45 degrees left, 0.8 m away: beside the straight corridor
    ranges[0, 4] = 1.2  # and one 1.2 m ahead for the first env
    twist = torch.tensor([[2.0, 0.0], [2.0, 4.0], [2.0, -4.0]], dtype=F64)
    dt, decel, delay = 0.1, 2.0, 1
    straight = forward_speed_guard(ranges, lidar, 0.25, 0.05, dt, decel=decel, delay=delay)
    v = arc_speed_guard(ranges, lidar, 0.25, 0.05, dt, twist, decel=decel, delay=delay)
    assert straight[0] < 2.0 and v[0].item() == pytest.approx(straight[0].item())  # straight: the same bound
    assert math.isinf(straight[1]) and v[1] < 1.5  # turning left into it: slowed
    assert v[2].item() == 2.0  # turning right, away from it: the command
    one = arc_speed_guard(ranges, lidar, 0.25, 0.05, dt, twist, decel=decel, delay=delay, passes=1)
    x, y = 0.8 * math.cos(math.pi / 4), 0.8 * math.sin(math.pi / 4)
    free = arc_free_length(*(torch.tensor(a, dtype=F64) for a in (x, y, 4.0 / 2.0, 0.3)))
    assert one[1].item() == pytest.approx(stopping_speed(free, (1 + delay) * dt, decel).item())  # one pass: the command's arc
    assert v[1] <= one[1]  # each pass at the slower speed's tighter arc only lowers it


@pytest.mark.parametrize("start_y", [4.2, 4.4])
def test_the_arc_guard_keeps_a_hard_turn_off_the_wall(start_y):
    """Full speed and full turn towards a wall the robot drives beside, with 2 m/s^2 and a two-step delay: the
    straight-line guard sees the wall too late and hits it; the guard that checks the arc does not."""
    from torchnav.envs import make_nav_env

    hits = {}
    for path in ("straight", "arc"):
        env = make_nav_env("empty", num_envs=1, seed=0, robot={"v_max": 2.0, "omega_max": 4.0, "lin_acc_max": 2.0},
                           randomize={"delay": [2, 2]}, action={"stop_clearance": 0.05, "stop_path": path}, max_steps=200)
        td = env.reset_to(torch.tensor([[0.0, start_y, 0.0]]), torch.tensor([[-3.0, -3.0]]))  # the wall at y = 5 on the left
        hits[path] = False
        for _ in range(40):
            td["action"] = torch.tensor([[1.0, 1.0]])
            td = env.step(td)
            hits[path] |= bool(td["next", "collision"].any())
            td = td["next"]
    assert hits == {"straight": True, "arc": False}
