"""IMU, camera and moving obstacles of the simulator, against closed forms."""

import math

import numpy as np
import pytest
import torch

from params import camera_params, lidar_params, sim_params

from torchnav.sim import (
    ImuParams, camera_depth, camera_image, camera_rays, cast_rays,
    init_state, make_movers, make_world, step,
)


def _drive(params, world, action, n, b=1, gen=None, movers=None):
    state = init_state(torch.zeros(b, 3), world, params, movers=movers)
    states = [state]
    for _ in range(n):
        state = step(state, action.expand(b, 2), world, params, generator=gen)
        states.append(state)
    return states


# -- IMU ---------------------------------------------------------------------------------

def test_imu_off_by_default_gives_empty_readings():
    s = init_state(torch.zeros(4, 3), make_world(4), sim_params())
    assert s.imu.shape == (4, 0) and s.imu_bias.shape == (4, 0) and s.cam_depth.shape == (4, 0) and s.movers.shape == (4, 0, 9)


@pytest.mark.parametrize("integrator", ["exact", "euler"])
def test_imu_on_circular_motion(integrator):
    v, w = 0.5, 0.25  # a circle of radius v / w = 2 m
    params = sim_params(imu=ImuParams(), integrator=integrator, v_max=1.0)
    states = _drive(params, make_world(1), torch.tensor([[v, w]]), 40)
    # First step from rest: the forward acceleration is the jump in speed over dt.
    assert states[1].imu[0].tolist() == pytest.approx([v / params.dt, v * w, w], rel=1e-5)
    # Then uniform circular motion: no tangential acceleration, centripetal v^2 / r to the left.
    r = v / w
    for s in states[2:]:
        assert s.imu[0].tolist() == pytest.approx([0.0, v * v / r, w], abs=1e-6)
    if integrator == "exact":  # the path really is that circle: centre (0, r)
        xy = torch.stack([s.pose[0, :2] for s in states])
        assert torch.allclose((xy - torch.tensor([0.0, r])).norm(dim=-1), torch.tensor(r), atol=1e-5)


def test_imu_noise_and_bias_walk_statistics():
    b, n, dt = 4096, 100, 0.1
    params = sim_params(dt=dt, imu=ImuParams(accel_noise=0.3, gyro_noise=0.2, gyro_bias_walk=0.1))
    gen = torch.Generator().manual_seed(0)
    s = _drive(params, make_world(b), torch.tensor([[0.0, 0.5]]), n, b=b, gen=gen)[-1]
    bias = s.imu_bias
    assert torch.all(bias[:, :2] == 0)  # no accelerometer walk configured
    assert bias[:, 2].std().item() == pytest.approx(0.1 * math.sqrt(n * dt), rel=0.05)  # random walk: sigma sqrt(t)
    err = s.imu - torch.tensor([0.0, 0.0, 0.5]) - bias
    assert err[:, 0].std().item() == pytest.approx(0.3, rel=0.05)
    assert err[:, 2].std().item() == pytest.approx(0.2, rel=0.05)
    # Same seed, same readings; no generator, no noise.
    again = _drive(params, make_world(b), torch.tensor([[0.0, 0.5]]), n, b=b, gen=torch.Generator().manual_seed(0))[-1]
    assert torch.equal(again.imu, s.imu)
    clean = _drive(params, make_world(2), torch.tensor([[0.0, 0.5]]), 3, b=2)[-1]
    assert torch.allclose(clean.imu, torch.tensor([0.0, 0.0, 0.5]).expand(2, 3))


def test_imu_rate_holds_readings_between_samples():
    params = sim_params(dt=0.1, v_max=2.0, imu=ImuParams(rate=2.0))  # a sample every 5 steps
    acts = [torch.tensor([[0.1 * (k + 1), 0.0]]) for k in range(12)]
    world = make_world(1)
    s = init_state(torch.zeros(1, 3), world, params)
    seen = []
    for a in acts:
        s = step(s, a, world, params)
        seen.append(s.imu[0, 1].item() + s.imu[0, 0].item())
    # Ticks at t = 0.5 s and 1.0 s: steps 5 and 10 update, the others hold.
    changed = [k + 1 for k in range(1, 12) if seen[k] != seen[k - 1]]
    assert changed == [5, 10]


def test_imu_and_camera_params_reject_bad_values():
    for bad in ({"accel_noise": -0.1}, {"gyro_bias_walk": -1.0}, {"rate": 0.0}, {"gyro_noise": math.nan}):
        with pytest.raises(ValueError, match=f"{next(iter(bad))}="):  # names the refused field
            ImuParams(**bad)
    for bad in ({"n_cols": 0}, {"n_rows": 0}, {"fov": math.pi}, {"max_range": 0.0}, {"wall_color": (0, 0, 300)}, {"box_color": (True, 0, 0)}, {"height": -1.0}):
        with pytest.raises(ValueError, match=f"{next(iter(bad))}="):
            camera_params(**bad)


# -- camera --------------------------------------------------------------------------------

def test_camera_depth_of_a_facing_wall_is_flat():
    """A wall perpendicular to the optical axis is at the same depth in every column."""
    cam = camera_params(n_cols=64, fov=math.radians(90))
    world = make_world(1, segments=[[3.0, -10.0, 3.0, 10.0]])
    depth = camera_depth(torch.zeros(1, 3), world, cam)
    assert torch.allclose(depth, torch.full((1, 64), 3.0), atol=1e-5)
    assert camera_depth(torch.tensor([[0.0, 0.0, math.pi]]), world, cam).eq(cam.max_range).all()  # looking away: misses


def test_camera_depth_matches_lidar_on_the_same_rays():
    g = torch.Generator().manual_seed(1)
    b = 16
    circles = torch.cat((torch.rand(6, 2, generator=g) * 8 - 4, torch.rand(6, 1, generator=g) * 0.5 + 0.2), 1)
    boxes = torch.cat((torch.rand(4, 2, generator=g) * 8 - 4, torch.rand(4, 2, generator=g) * 0.4 + 0.1, torch.rand(4, 1, generator=g) * 6), 1)
    world = make_world(b, segments=[[-5, -5, 5, -5], [5, -5, 5, 5], [5, 5, -5, 5], [-5, 5, -5, -5]], circles=circles, boxes=boxes)
    pose = torch.cat((torch.rand(b, 2, generator=g) * 2 - 1, torch.rand(b, 1, generator=g) * 6 - 3), 1)
    cam = camera_params(n_cols=48, fov=1.5, max_range=20.0, offset=(0.1, 0.0, 0.2))
    origin, angles, local = camera_rays(pose, cam)
    lidar = cast_rays(origin, angles, world)
    assert torch.isfinite(lidar).all()
    depth = camera_depth(pose, world, cam)
    assert torch.allclose(depth, lidar * torch.cos(local), atol=1e-5)
    depth2, rgb = camera_image(pose, world, cam)
    assert torch.equal(depth2, depth) and rgb.shape == (b, cam.n_rows, 48, 3) and rgb.dtype == torch.uint8
    # Differentiable in the pose.
    p = pose.clone().requires_grad_(True)
    camera_depth(p, world, cam).sum().backward()
    assert torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0


def test_camera_image_rows_of_a_wall():
    """A 1 m wall at 2 m seen from 0.3 m: exactly the rows whose ray meets it between 0 and 1 m."""
    cam = camera_params(n_cols=8, n_rows=64, fov=math.radians(90), wall_height=1.0, height=0.3)
    world = make_world(1, segments=[[2.0, -50.0, 2.0, 50.0]])
    _, rgb = camera_image(torch.zeros(1, 3), world, cam)
    col = rgb[0, :, 3].to(torch.int64)
    f = cam.focal
    tan_e = [(32 - i - 0.5) / f for i in range(64)]
    wall_rows = [i for i in range(64) if 0.0 <= 0.3 + 2.0 * tan_e[i] <= 1.0]
    sky = torch.tensor(cam.sky_color)
    is_wall = [bool((col[i] * 1.0 - torch.tensor(cam.wall_color) / (1 + 0.08 * 2.0)).abs().max() <= 1) for i in range(64)]
    assert [i for i in range(64) if is_wall[i]] == wall_rows
    assert torch.equal(col[0], sky) and all(torch.equal(col[i], sky) for i in range(wall_rows[0]))
    assert col[-1, 0] < cam.sky_color[0]  # floor at the bottom


# -- moving obstacles -------------------------------------------------------------------

def test_moving_circle_lidar_return_matches_geometry():
    r, vy, dt = 0.5, 0.3, 0.1
    lidar = lidar_params(n_rays=360, fov=2 * math.pi, max_range=20.0)
    params = sim_params(dt=dt, lidar=lidar)
    movers = make_movers(1, [[4.0, -0.45, 0.0, vy, r]])
    states = _drive(params, make_world(1), torch.zeros(1, 2), 30, movers=movers)
    ahead = lidar.n_rays // 2  # ray along +x
    for k, s in enumerate(states):
        cy = -0.45 + vy * dt * k
        assert s.movers[0, 0, 1].item() == pytest.approx(cy, abs=1e-5)
        want = 4.0 - math.sqrt(r * r - cy * cy) if abs(cy) < r else lidar.max_range
        assert s.ranges[0, ahead].item() == pytest.approx(want, abs=1e-4)
        assert s.clearance[0].item() == pytest.approx(math.hypot(4.0, cy) - r - params.robot_radius, abs=1e-5)


def test_mover_collides_with_robot():
    params = sim_params(dt=0.1)
    movers = make_movers(1, [[2.0, 0.0, -1.0, 0.0, 0.3]])
    states = _drive(params, make_world(1), torch.zeros(1, 2), 20, movers=movers)
    hit = [k for k, s in enumerate(states) if s.collided[0]]
    assert hit and hit[0] == 15  # centre at 2 - 0.1 k reaches 0.5 m (0.3 + 0.2) at k = 15
    assert states[14].clearance[0].item() == pytest.approx(0.1, abs=1e-5)


def test_bouncing_movers_stay_in_region_and_keep_speed():
    g = torch.Generator().manual_seed(3)
    m = 8
    xy = torch.rand(m, 2, generator=g) * 2 - 1
    v = torch.randn(m, 2, generator=g)
    discs = torch.cat((xy, v, torch.full((m, 1), 0.3)), 1)
    movers = make_movers(2, discs, region=(-2.0, -1.5, 2.0, 1.5))
    states = _drive(sim_params(), make_world(2), torch.zeros(1, 2), 200, b=2, movers=movers)
    for s in states:
        x, y, vx, vy, rad = s.movers[..., :5].unbind(-1)
        assert (x - rad >= -2.0 - 1e-5).all() and (x + rad <= 2.0 + 1e-5).all()
        assert (y - rad >= -1.5 - 1e-5).all() and (y + rad <= 1.5 + 1e-5).all()
        assert torch.allclose(torch.stack((vx, vy), -1).norm(dim=-1), v.norm(dim=-1).expand(2, m), atol=1e-5)
    assert not torch.equal(states[-1].movers[..., 2:4], states[0].movers[..., 2:4])  # they did bounce


def test_camera_sees_movers():
    cam = camera_params(n_cols=1, fov=0.1)
    params = sim_params(camera=cam)
    movers = make_movers(1, [[3.0, 0.0, -0.5, 0.0, 0.5]])
    states = _drive(params, make_world(1), torch.zeros(1, 2), 4, movers=movers)
    for k, s in enumerate(states):
        assert s.cam_depth[0, 0].item() == pytest.approx(2.5 - 0.05 * k, abs=1e-5)


def test_make_movers_rejects_bad_input():
    with pytest.raises(ValueError, match="radius"):
        make_movers(1, [[0.0, 0.0, 1.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="region"):
        make_movers(1, [[0.0, 0.0, 1.0, 0.0, 0.5]], region=(1.0, 0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="inside"):
        make_movers(1, [[0.0, 0.0, 1.0, 0.0, 0.5]], region=(-0.2, -1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="shape"):
        make_movers(1, [[0.0, 0.0, 1.0]])


# -- the task's observation options ------------------------------------------------------

def test_task_observation_with_imu_and_camera():
    from torchnav.config import ConfigError
    from torchnav.envs import make_nav_env

    env = make_nav_env("arena", num_envs=8, imu={"enabled": True, "gyro_noise": 0.01}, camera={"enabled": True, "n_cols": 16},
                   observation={"imu": True, "camera": True})
    td = env.reset()
    assert td["observation"].shape == (8, 20 + 4 + 3 + 16)
    td = env.rand_step(td)
    obs = td["next", "observation"]
    s = env._state.sim
    assert obs.shape == (8, 43) and s.imu.shape == (8, 3) and s.cam_depth.shape == (8, 16)
    cfg = env.cfg
    assert torch.allclose(obs[:, 24:27], s.imu * torch.tensor([1 / (cfg.robot.v_max * cfg.robot.omega_max)] * 2 + [1 / cfg.robot.omega_max]))
    assert torch.allclose(obs[:, 27:], s.cam_depth / cfg.camera.max_range)
    # The default config observes exactly what it did before.
    assert make_nav_env("arena", num_envs=2).reset()["observation"].shape == (2, 24)
    with pytest.raises(ConfigError, match="observation.imu needs imu.enabled"):
        make_nav_env("arena", num_envs=2, observation={"imu": True})
    with pytest.raises(ConfigError, match="camera.n_cols"):
        make_nav_env("arena", num_envs=2, camera={"enabled": True, "n_cols": 0})
    with pytest.raises(ConfigError, match="imu.accel_noise"):
        make_nav_env("arena", num_envs=2, imu={"enabled": True, "accel_noise": -1.0})
    with pytest.raises(ConfigError, match="unknown key"):
        make_nav_env("arena", num_envs=2, camera={"colums": 3})


# -- recording -----------------------------------------------------------------------------

def test_imu_and_camera_are_recorded_with_schemas(tmp_path):
    import base64
    import json

    import numpy as np
    from mcap.reader import make_reader

    from torchnav.envs import make_nav_env
    from torchnav.record import EpisodeRecorder, JsonDecoderFactory, record_rollout, validate

    env = make_nav_env("arena", num_envs=3, max_steps=50, imu={"enabled": True}, camera={"enabled": True, "n_cols": 24, "n_rows": 10})
    path = tmp_path / "s.mcap"
    with EpisodeRecorder(path, env, envs=(1,)) as rec:
        record_rollout(env, None, 4, rec)
    last = {}
    with open(path, "rb") as f:
        for schema, channel, _, msg in make_reader(f, decoder_factories=[JsonDecoderFactory()]).iter_decoded_messages():
            validate(msg, json.loads(schema.data))
            last[channel.topic] = (schema.name, msg)
    assert last["/env1/imu"][0] == "torchnav.Imu" and last["/env1/camera"][0] == "foxglove.RawImage"
    sim = env._state.sim[1]
    imu = last["/env1/imu"][1]
    assert [imu["linear_acceleration"]["x"], imu["linear_acceleration"]["y"], imu["angular_velocity"]["z"]] == pytest.approx(sim.imu.tolist(), abs=1e-5)
    img = last["/env1/camera"][1]
    assert (img["width"], img["height"], img["encoding"]) == (24, 10, "rgb8")
    assert len(base64.b64decode(img["data"])) == 24 * 10 * 3
    depth = np.frombuffer(base64.b64decode(last["/env1/camera_depth"][1]["data"]), dtype="<f4")
    assert np.allclose(depth, sim.cam_depth.numpy(), atol=1e-5)


# -- moving obstacles in maps and the task -------------------------------------------------

MOVING_MAP = """
name: moving
size: [10.0, 10.0]
walls: boundary
random_boxes: {count: 4, size_x: [0.4, 0.6], size_y: [0.3, 0.5], clearance: 1.5, margin: 0.1}
moving_circles: {count: 4, radius: [0.2, 0.3], speed: [0.2, 0.5], clearance: 1.5, margin: 0.1}
"""


def test_task_places_movers_with_clearance_and_collides_with_them(tmp_path):
    from torchnav.envs import make_nav_env
    from torchnav.sim import points_clearance

    path = tmp_path / "moving.yaml"
    path.write_text(MOVING_MAP)
    env = make_nav_env(str(path), num_envs=512, seed=3)
    env.reset()
    s = env._state
    m, mask = s.sim.movers, s.sim.mover_mask
    assert m.shape == (512, 4, 9) and mask.float().mean() > 0.99
    r = m[..., 4]
    assert ((r >= 0.2) & (r <= 0.3))[mask].all()
    speed = m[..., 2:4].norm(dim=-1)
    assert ((speed >= 0.2 - 1e-5) & (speed <= 0.5 + 1e-5))[mask].all()
    assert ((m[..., :2] - s.start[:, None, :2]).norm(dim=-1) - r)[mask].min() >= 1.5 - 1e-4
    assert ((m[..., :2] - s.goal[:, None]).norm(dim=-1) - r)[mask].min() >= 1.5 - 1e-4
    assert (points_clearance(m[..., :2], s.world) - r)[mask].min() >= 0.1 - 1e-4  # walls and this episode's boxes
    for i in range(4):
        for j in range(i):
            gap = (m[:, i, :2] - m[:, j, :2]).norm(dim=-1) - r[:, i] - r[:, j]
            assert gap[mask[:, i] & mask[:, j]].min() >= 0.1 - 1e-4
    assert (m[..., 5:] == torch.tensor([-5.0, -5.0, 5.0, 5.0])).all()  # bounce inside the map
    # The task's collision flag is the simulator's, which includes the movers: drive a mover onto the robot.
    sim = s.sim
    hit = sim.movers.clone()
    hit[:, 0, :2] = sim.pose[:, :2] + torch.tensor([0.45, 0.0])
    hit[:, 0, 2:4] = 0.0
    hit[:, 0, 4] = 0.3
    state = s.clone()
    state.sim.movers = hit
    state.sim.mover_mask = torch.ones_like(mask)
    _, out = env.task.step(state, torch.tensor([[-1.0, 0.0]]).expand(512, 2))
    assert out["collision"].all()


def test_map_rejects_bad_moving_circles(tmp_path):
    from torchnav.maps import MapError, parse_map

    base = {"size": [10.0, 10.0], "walls": ["boundary"]}
    for bad, key in (({"count": 2, "radius": [0.2, 0.3]}, "speed"), ({"count": 2, "radius": [0.2, 0.3], "speed": [0.1, 0.2], "motion": "zigzag"}, "motion"),
                     ({"count": 2, "radius": [0.2, 0.3], "speed": [0.1, 0.2], "region": [1.0, 0.0, 0.0, 1.0]}, "region"),
                     ({"count": 2, "radius": [0.2, 0.3], "speed": [-0.1, 0.2]}, "speed"),
                     ({"count": 2, "radius": [0.2, 0.3], "speed": [0.1, 0.2], "sped": 1}, "sped")):
        with pytest.raises(MapError, match=key):
            parse_map({**base, "moving_circles": bad})
    spec = parse_map({**base, "moving_circles": {"count": 3, "radius": [0.2, 0.3], "speed": [0.1, 0.2], "region": [-2, -2, 2, 2], "motion": "constant"}})
    assert spec.movers.count == 3 and spec.movers.region == (-2.0, -2.0, 2.0, 2.0)


def test_replay_draws_movers_and_camera(tmp_path):
    from conftest import record_episode
    from torchnav.envs import make_nav_env
    from torchnav.record.replay import render_episode

    path = tmp_path / "moving.yaml"
    path.write_text(MOVING_MAP)
    env = make_nav_env(str(path), num_envs=2, max_steps=6, camera={"enabled": True, "n_cols": 16, "n_rows": 8})
    rec, ep, fr = record_episode(env, tmp_path / "m.mcap", 6)
    n = len(fr["pose"])
    assert fr["movers"].shape == (n, 4, 5) and fr["camera"].shape == (n, 8, 16, 3) and fr["camera"].dtype.name == "uint8"
    assert np.allclose(fr["movers"][2][:, :2], fr["movers"][1][:, :2] + env.cfg.robot.dt * fr["movers"][2][:, 2:4], atol=1e-4)  # they move
    gif = render_episode(rec, ep, tmp_path / "m.gif", dpi=40)
    assert gif.stat().st_size > 0


# -- patrols and pedestrians -----------------------------------------------------------------

def test_patrol_follows_its_waypoints_at_its_speed():
    """A patrol on a 1 m square at 0.5 m/s: 20 steps per side, exactly on the path, cyclically."""
    square = [[1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.0, 0.0]]
    movers = make_movers(1, [[0.0, 0.0, 0.5, 0.0, 0.2]], waypoints=[square])
    world = make_world(1)
    params = sim_params()
    states = _drive(params, world, torch.zeros(1, 2), 100, movers=movers)
    corners = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
    for k, s in enumerate(states):
        side, along = divmod(k % 80, 20)
        (ax, ay), (bx, by) = corners[side], corners[(side + 1) % 4]
        want = (ax + (bx - ax) * along / 20, ay + (by - ay) * along / 20)
        assert s.movers[0, 0, :2].tolist() == pytest.approx(want, abs=1e-4), k
    assert states[30].mover_target[0, 0].item() == 1  # heading for the second waypoint
    assert all(s.mover_plan.data_ptr() == states[0].mover_plan.data_ptr() for s in states)  # the plan is carried, never copied


def test_pedestrians_avoid_each_other_and_the_robot():
    """Two pedestrians walking head-on, slightly offset, and one walking through a standing robot:
    nobody touches, and everybody still gets past."""
    discs = [[-3.0, 0.05, 0.6, 0.0, 0.25], [3.0, -0.05, -0.6, 0.0, 0.25], [0.0, -3.0, 0.0, 0.6, 0.25]]
    paths = [[[3.0, 0.0]], [[-3.0, 0.0]], [[0.0, 3.0]]]
    movers = make_movers(1, discs, waypoints=paths, pedestrians=True)
    params = sim_params()
    world = make_world(1)
    robot = torch.tensor([[0.0, 1.5, 0.0]])
    state = init_state(robot, world, params, movers=movers)
    closest, robot_gap = math.inf, math.inf
    for _ in range(150):
        state = step(state, torch.zeros(1, 2), world, params)
        p = state.movers[0, :, :2]
        closest = min(closest, (p[0] - p[1]).norm().item() - 0.5)
        robot_gap = min(robot_gap, state.clearance[0].item())
    assert closest > 0 and robot_gap > 0
    p = state.movers[0, :, :2]
    assert p[0, 0] > 2.5 and p[1, 0] < -2.5 and p[2, 1] > 2.5  # they got where they were going
    # Patrols do not steer: the same head-on patrols would meet.
    patrols = make_movers(1, discs[:2], waypoints=paths[:2])
    s = init_state(torch.tensor([[0.0, 5.0, 0.0]]), world, params, movers=patrols)
    touched = False
    for _ in range(80):
        s = step(s, torch.zeros(1, 2), world, params)
        touched |= (s.movers[0, 0, :2] - s.movers[0, 1, :2]).norm().item() < 0.5
    assert touched


def test_social_push_is_the_exponential_force_and_never_subnormal():
    """The pedestrians' social force is PED_PUSH exp(gap / PED_RANGE) / d, and far apart (a gap of tens
    of metres, where float32 exp() would return a subnormal number, about 10x slower on x86) it stays
    a normal float32 number, within 1e-24 of 0."""
    from torchnav.sim.movers import PED_PUSH, PED_RANGE, social_push

    gap = torch.tensor([0.1, 0.0, -0.5, -3.0, -10.0, -26.0, -40.0, -300.0])
    dist = 0.5 - gap
    push = social_push(gap, dist)
    want = PED_PUSH * torch.exp(gap.double() / PED_RANGE) / dist.double()
    near = gap > -15
    torch.testing.assert_close(push[near].double(), want[near], rtol=1e-5, atol=0)
    assert (push >= torch.finfo(torch.float32).tiny).all() and (push[gap < -20] < 1e-24).all()


def test_pedestrians_ignore_movers_that_are_masked_off():
    """A pedestrian walks as if alone past a masked-off mover in its way, and swerves when it exists."""
    discs = [[-2.0, 0.05, 0.6, 0.0, 0.25], [0.0, 0.0, 0.0, 0.0, 0.25]]
    paths = [[[2.0, 0.0]], [[0.0, 0.0]]]
    params, world, robot = sim_params(), make_world(1), torch.tensor([[0.0, 5.0, 0.0]])
    alone = init_state(robot, world, params, movers=make_movers(1, discs[:1], waypoints=paths[:1], pedestrians=True))
    rows, mask, plan, boxes = make_movers(1, discs, waypoints=paths, pedestrians=True)
    masked = init_state(robot, world, params, movers=(rows, torch.tensor([[True, False]]), plan, boxes))
    present = init_state(robot, world, params, movers=(rows, mask, plan, boxes))
    swerve = 0.0
    for _ in range(40):
        alone, masked, present = (step(s, torch.zeros(1, 2), world, params) for s in (alone, masked, present))
        torch.testing.assert_close(masked.movers[:, :1], alone.movers)
        swerve = max(swerve, (present.movers[0, 0, :2] - alone.movers[0, 0, :2]).norm().item())
    assert swerve > 0.05


def test_task_places_pedestrians_with_waypoints_in_their_region(tmp_path):
    from torchnav.envs import make_nav_env

    path = tmp_path / "peds.yaml"
    path.write_text(MOVING_MAP.replace("speed: [0.2, 0.5], clearance: 1.5, margin: 0.1}",
                                       "speed: [0.2, 0.5], clearance: 1.5, margin: 0.1, motion: pedestrian, waypoints: 3, region: [-4, -3, 4, 3]}"))
    env = make_nav_env(str(path), num_envs=64, seed=0)
    td = env.reset()
    s = env._state.sim
    assert s.mover_plan.shape == (64, 4, 4 + 6)
    assert (s.mover_plan[..., 0] == 2).all() and (s.mover_plan[..., 3] == 3).all() and (s.mover_plan[..., 2] == 0).all()
    pts = s.mover_plan[..., 4:].unflatten(-1, (3, 2))
    r = s.movers[..., 4:5, None].squeeze(-1)
    assert (pts[..., 0] >= -4 + r - 1e-5).all() and (pts[..., 0] <= 4 - r + 1e-5).all()
    assert (pts[..., 1] >= -3 + r - 1e-5).all() and (pts[..., 1] <= 3 - r + 1e-5).all()
    assert ((s.movers[..., 2:4].norm(dim=-1) - s.mover_plan[..., 1]).abs() < 1e-5).all()  # speed in the plan
    for _ in range(5):
        td = env.step_and_maybe_reset(env.rand_action(td))[1]
    assert env._state.sim.mover_plan.shape == (64, 4, 10)


# -- domain randomisation ---------------------------------------------------------------------

RANDOMIZE = {"v_max": [0.5, 1.0], "omega_max": [0.5, 1.5], "lin_acc_max": [1.0, 3.0], "ang_acc_max": [2.0, 4.0], "delay": [0, 2],
             "wheel_noise": [0.0, 0.05], "range_noise": [0.0, 0.03], "dropout": [0.0, 0.1], "angle_offset": [-0.05, 0.05],
             "max_range": [6.0, 10.0], "robot_radius": [0.15, 0.25]}


def test_randomized_parameters_lie_in_their_ranges_and_follow_the_seed():
    from torchnav.envs import make_nav_env

    env = make_nav_env("arena", num_envs=512, seed=7, randomize=RANDOMIZE)
    env.reset()
    p = env._state.env_params
    for name, (lo, hi) in RANDOMIZE.items():
        v = getattr(p, name).double()
        assert (v >= lo).all() and (v <= hi).all(), name
        assert v.std() > 0, name  # really varies between envs
    assert set(p.delay.unique().tolist()) == {0, 1, 2}
    again = make_nav_env("arena", num_envs=512, seed=7, randomize=RANDOMIZE)
    again.reset()
    assert all(torch.equal(getattr(p, k), getattr(again._state.env_params, k)) for k in RANDOMIZE)
    other = make_nav_env("arena", num_envs=512, seed=8, randomize=RANDOMIZE)
    other.reset()
    assert not torch.equal(p.v_max, other._state.env_params.v_max)
    # A new episode draws new parameters.
    state, _ = env.task.reset(env.state, torch.ones(512, dtype=torch.bool), env.curriculum, env.generator, env.pool)
    assert not torch.equal(state.env_params.v_max, p.v_max)


def test_randomized_step_applies_limits_delay_radius_and_lidar_range():
    from torchnav.sim import EnvParams, nominal_env_params

    params = sim_params(v_max=2.0, omega_max=2.0, lidar=lidar_params(n_rays=3, fov=math.pi / 2, max_range=10.0))
    world = make_world(3, segments=[[3.0, -10.0, 3.0, 10.0]])
    base = nominal_env_params(params, 3, torch.zeros(1))
    d = base.to_dict()
    d.update(v_max=torch.tensor([0.5, 1.0, 2.0]), delay=torch.tensor([0, 1, 2]), max_range=torch.tensor([10.0, 2.0, 10.0]),
             robot_radius=torch.tensor([0.2, 0.5, 3.1]), angle_offset=torch.tensor([0.0, 0.0, 0.1]))
    ep = EnvParams(**d, batch_size=[3])
    s = init_state(torch.zeros(3, 3), world, params, env_params=ep, delay_steps=2)
    assert s.cmd_queue.shape == (3, 2, 2)
    assert s.ranges[1].tolist() == pytest.approx([2.0, 2.0, 2.0])  # its lidar reaches 2 m
    assert s.ranges[0, 1].item() == pytest.approx(3.0, abs=1e-5) and s.ranges[2, 1].item() == pytest.approx(3.0 / math.cos(0.1), abs=1e-4)
    assert s.clearance.tolist() == pytest.approx([2.8, 2.5, -0.1], abs=1e-5)  # each env's robot radius
    assert s.collided.tolist() == [False, False, True]
    cmd = torch.tensor([[3.0, 0.0]]).expand(3, 2)
    vs = []
    s = init_state(torch.tensor([[-5.0, 0.0, 0.0]]).expand(3, 3), world, params, env_params=ep, delay_steps=2)
    for _ in range(3):
        s = step(s, cmd, world, params, env_params=ep)
        vs.append(s.vel[:, 0].tolist())
    # env 0: no delay, 0.5 m/s at once; env 1: one step late, 1 m/s; env 2: two steps late, 2 m/s.
    assert vs == [[0.5, 0.0, 0.0], [0.5, 1.0, 0.0], [0.5, 1.0, 2.0]]


def test_randomized_noise_dropout_and_wheel_noise_statistics():
    from torchnav.sim import EnvParams, nominal_env_params

    b = 2048
    params = sim_params(lidar=lidar_params(n_rays=8, fov=math.pi / 4, max_range=10.0))
    world = make_world(b, segments=[[3.0, -10.0, 3.0, 10.0]])
    d = nominal_env_params(params, b, torch.zeros(1)).to_dict()
    d.update(range_noise=torch.full((b,), 0.05), dropout=torch.full((b,), 0.2), wheel_noise=torch.full((b,), 0.1))
    ep = EnvParams(**d, batch_size=[b])
    s = init_state(torch.zeros(b, 3), world, params, env_params=ep)
    s = step(s, torch.tensor([[0.2, 0.0]]).expand(b, 2), world, params, env_params=ep, generator=torch.Generator().manual_seed(0))
    dropped = s.ranges == 10.0
    assert dropped.float().mean().item() == pytest.approx(0.2, abs=0.01)
    # Wheel noise of std 0.1 on each wheel: v = mean of the wheels has std 0.1 / sqrt(2).
    assert s.vel[:, 0].std().item() == pytest.approx(0.1 / math.sqrt(2), rel=0.06)
    assert s.vel[:, 0].mean().item() == pytest.approx(0.2, abs=0.01)


def test_randomize_config_errors_and_evaluation_switch():
    from torchnav.config import ConfigError
    from torchnav.envs import make_nav_env
    from torchnav.evaluation import eval_config
    from torchnav.tasks import NavConfig

    for bad, key in (({"dropout": [0.0, 1.5]}, "dropout"), ({"v_max": [1.0, 0.5]}, "v_max"), ({"delay": [0, 1.5]}, "delay"),
                     ({"max_range": [5.0, 20.0]}, "max_range"), ({"wheel_noise": [-0.1, 0.1]}, "wheel_noise")):
        with pytest.raises(ConfigError, match=key):
            make_nav_env("arena", num_envs=2, randomize=bad)
    with pytest.raises(ConfigError, match="unknown key"):
        make_nav_env("arena", num_envs=2, randomize={"mass": [1.0, 2.0]})
    cfg = NavConfig.from_dict({"randomize": RANDOMIZE})
    assert eval_config(cfg, randomize_off=True).randomize.ranges() == {}
    assert set(eval_config(cfg, randomize_off=["delay", "dropout"]).randomize.ranges()) == set(RANDOMIZE) - {"delay", "dropout"}
    with pytest.raises(ValueError, match="unknown"):
        eval_config(cfg, randomize_off=["mass"])


def test_movers_are_stepped_mover_major_with_the_same_results():
    """step_movers returns (and init_state holds) movers and waypoint targets stored mover-major, so the
    next step reads them without a copy; a contiguous input gives bit-identical values."""
    from torchnav.sim.movers import is_mover_major, mover_major, step_movers

    discs = [[-1.0, 0.0, 0.4, 0.1, 0.3], [1.0, 0.2, -0.3, 0.0, 0.25], [0.0, 1.0, 0.0, -0.5, 0.2]]
    rows, mask, plan, _ = make_movers(5, discs, region=(-3, -3, 3, 3), waypoints=[[[2.0, 2.0], [-2.0, 0.0]], [[0.0, -2.0]], []],
                                   pedestrians=True)
    robot = torch.tensor([[0.5, 0.5]]).expand(5, 2)
    assert not is_mover_major(rows) and is_mover_major(mover_major(rows)) and torch.equal(mover_major(rows), rows)
    target = plan[..., 2]
    a_rows, a_target = step_movers(rows, plan, mask, 0.1, robot, 0.2, target)
    b_rows, b_target = step_movers(mover_major(rows), mover_major(plan), mask, 0.1, robot, 0.2, target.t().contiguous().t())
    assert torch.equal(a_rows, b_rows) and torch.equal(a_target, b_target)
    assert is_mover_major(a_rows) and a_target.t().is_contiguous() and a_rows.shape == rows.shape and a_target.shape == target.shape
    s = init_state(torch.zeros(5, 3), make_world(5), sim_params(), movers=(rows, mask, plan))
    assert is_mover_major(s.movers) and is_mover_major(s.mover_plan) and torch.equal(s.movers, rows)
    assert s.mover_target.stride() == a_target.stride() and torch.equal(s.mover_target, target)  # the step's layout, not a view
    assert s.mover_target.data_ptr() != s.mover_plan.data_ptr() + 2 * s.mover_plan.stride(2) * s.mover_plan.element_size()
    with pytest.raises(ValueError, match=r"target must have shape \(5, 3\)"):
        step_movers(rows, plan, mask, 0.1, robot, 0.2, target[:, :2])
