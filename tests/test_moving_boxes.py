"""Moving boxes: lidar, camera and collision against closed forms; their motion and validation."""

import math

import pytest
import torch

from params import camera_params, lidar_params, sim_params

from torchnav.sim import init_state, make_movers, make_world, mover_world, step


def _drive(params, movers, n, b=1):
    world = make_world(b)
    state = init_state(torch.zeros(b, 3), world, params, movers=movers)
    states = [state]
    for _ in range(n):
        state = step(state, torch.zeros(b, 2), world, params)
        states.append(state)
    return states


def test_moving_box_lidar_and_camera_return_match_geometry():
    """A 1 x 0.6 m box sliding across the ray along +x: the ray reads its near face while the
    box covers y = 0, the camera's middle columns the same depth, then both miss."""
    hx, hy, vy, dt = 0.5, 0.3, 0.2, 0.1
    lidar = lidar_params(n_rays=360, fov=2 * math.pi, max_range=20.0)
    cam = camera_params(n_cols=1, fov=0.02, max_range=20.0)  # one column, along the axis
    params = sim_params(dt=dt, lidar=lidar, camera=cam)
    movers = make_movers(1, boxes=[[4.0, -0.5, 0.0, vy, hx, hy, 0.0]])
    assert movers.rows.shape == (1, 1, 9) and movers.boxes.shape == (1, 1, 3)
    ahead = lidar.n_rays // 2
    for k, s in enumerate(_drive(params, movers, 30)):
        cy = -0.5 + vy * dt * k
        assert s.movers[0, 0, 1].item() == pytest.approx(cy, abs=1e-5)
        covers = abs(cy) < hy - 1e-4
        want = 4.0 - hx if covers else lidar.max_range
        if covers or abs(cy) > hy + 1e-4:  # not grazing an edge
            assert s.ranges[0, ahead].item() == pytest.approx(want, abs=1e-4)
            assert s.cam_depth[0, 0].item() == pytest.approx(want, abs=1e-4)
        # Clearance: the nearest point of the box is on its near face (or its corner).
        dy = max(abs(cy) - hy, 0.0)
        assert s.clearance[0].item() == pytest.approx(math.hypot(4.0 - hx, dy) - params.robot_radius, abs=1e-5)


def test_rotated_moving_box_lidar_hits_its_corner():
    """A square box turned 45 degrees shows the ray along +x its corner at ``x - h sqrt(2)``."""
    h = 0.4
    params = sim_params(lidar=lidar_params(n_rays=360, fov=2 * math.pi, max_range=20.0))
    movers = make_movers(1, boxes=[[3.0, 0.0, 0.5, 0.0, h, h, math.pi / 4]])
    for k, s in enumerate(_drive(params, movers, 5)):
        assert s.ranges[0, 180].item() == pytest.approx(3.0 + 0.05 * k - h * math.sqrt(2), abs=1e-4)


def test_moving_box_collides_with_robot():
    """A box of half length 0.3 m driving at the robot at 1 m/s touches the 0.2 m robot when its
    centre reaches 0.5 m: after 15 steps of 0.1 s from 2 m."""
    params = sim_params(dt=0.1)
    movers = make_movers(1, boxes=[[2.0, 0.0, -1.0, 0.0, 0.3, 0.6, 0.0]])
    states = _drive(params, movers, 20)
    hit = [k for k, s in enumerate(states) if s.collided[0]]
    assert hit and hit[0] == 15
    assert states[14].clearance[0].item() == pytest.approx(0.1, abs=1e-5)


def test_moving_boxes_bounce_inside_their_region_and_keep_shape():
    movers = make_movers(2, [[0.0, 0.0, 0.7, -0.4, 0.2]], region=(-2.0, -1.5, 2.0, 1.5),
                         boxes=[[0.5, 0.5, -0.9, 0.6, 0.3, 0.2, 0.4]])
    start = movers.boxes.clone()
    states = _drive(sim_params(), movers, 100, b=2)
    for s in states:
        x, y, r = s.movers[..., 0], s.movers[..., 1], s.movers[..., 4]
        assert (x - r >= -2.0 - 1e-5).all() and (x + r <= 2.0 + 1e-5).all()
        assert (y - r >= -1.5 - 1e-5).all() and (y + r <= 1.5 + 1e-5).all()
        assert torch.equal(s.mover_boxes, start)  # half extents and yaw are carried
    assert s.movers[0, 1, 4].item() == pytest.approx(math.hypot(0.3, 0.2))
    world = mover_world(s.movers, s.mover_mask, s.mover_boxes)  # slot 0 a disc, slot 1 (the last K = 1) a box: by shape
    assert world.circle_mask.tolist() == [[True]] * 2 and world.box_mask.tolist() == [[True]] * 2
    assert world.circles.shape == (2, 1, 3) and world.boxes.shape == (2, 1, 5)



def test_mover_world_is_component_major_with_the_movers_values():
    """The lidar and camera read mover_world's rows without a copy (``planar_rows``: each component a contiguous block)."""
    from torchnav.sim.state import is_planar

    movers = make_movers(3, [[0.0, 0.0, 0.7, -0.4, 0.2]], boxes=[[0.5, 0.5, -0.9, 0.6, 0.3, 0.2, 0.4]])
    s = init_state(torch.zeros(3, 3), make_world(3), sim_params(), movers=movers)
    world = mover_world(s.movers, s.mover_mask, s.mover_boxes)
    assert is_planar(world.circles) and is_planar(world.boxes)
    assert torch.allclose(world.circles[2], torch.tensor([[0.0, 0.0, 0.2]]))
    assert torch.allclose(world.boxes[2, 0], torch.tensor([0.5, 0.5, 0.3, 0.2, 0.4]))

def test_make_movers_rejects_bad_boxes():
    with pytest.raises(ValueError, match="shape"):
        make_movers(1, boxes=[[0.0, 0.0, 1.0, 0.0, 0.5]])
    with pytest.raises(ValueError, match="half extents"):
        make_movers(1, boxes=[[0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="half extents"):
        make_movers(1, boxes=[[0.0, 0.0, 1.0, 0.0, -0.1, 0.3, 0.0]])


def test_box_shapes_in_the_wrong_place_are_refused_naming_the_layout():
    """The rows of the old layout (12 columns, the box columns appended) and box shapes that do not
    fit the movers are errors that say where the shapes go, not silently dropped columns."""
    from torchnav.sim import Movers, step_movers

    rows, mask, plan, boxes = make_movers(2, [[0.0, 0.0, 0.5, 0.0, 0.2]], boxes=[[1.0, 1.0, 0.0, 0.5, 0.3, 0.2, 0.1]])
    old = torch.cat((rows, torch.cat((torch.zeros(2, 1, 3), boxes), 1)), -1)  # (2, 2, 12)
    with pytest.raises(ValueError, match=r"Movers\.boxes"):
        init_state(torch.zeros(2, 3), make_world(2), sim_params(), movers=Movers(old, mask, plan))
    with pytest.raises(ValueError, match="separate tensor"):
        step_movers(old, plan, mask, 0.1, torch.zeros(2, 2), 0.2, torch.zeros(2, 0))
    with pytest.raises(ValueError, match=r"the last K movers are boxes"):
        init_state(torch.zeros(2, 3), make_world(2), sim_params(), movers=Movers(rows, mask, plan, torch.zeros(2, 3, 3)))
    with pytest.raises(ValueError, match=r"mover boxes must have shape \(2, K, 3\)"):
        mover_world(rows, mask, torch.zeros(2, 1, 5))


# -- moving boxes in maps and the task ------------------------------------------------------

BOX_MAP = """
name: moving_boxes
size: [10.0, 10.0]
walls: boundary
moving_boxes: {count: 3, size_x: [0.4, 0.8], size_y: [0.2, 0.4], speed: [0.2, 0.5], motion: pedestrian, clearance: 1.5, margin: 0.1}
"""


def _env_on(tmp_path, text: str, **kw):
    from torchnav.envs import make_nav_env

    (tmp_path / "map.yaml").write_text(text)
    return make_nav_env(str(tmp_path / "map.yaml"), **kw)


def test_task_places_moving_boxes_with_clearance_and_steps_them(tmp_path):
    from torchnav.sim import points_clearance

    env = _env_on(tmp_path, BOX_MAP, num_envs=256, seed=4)
    env.reset()
    s = env._state
    m, mask = s.sim.movers, s.sim.mover_mask
    assert m.shape == (256, 3, 9) and s.sim.mover_boxes.shape == (256, 3, 3) and mask.float().mean() > 0.99
    hx, hy, r = s.sim.mover_boxes[..., 0], s.sim.mover_boxes[..., 1], m[..., 4]
    assert ((hx >= 0.2 - 1e-6) & (hx <= 0.4 + 1e-6) & (hy >= 0.1 - 1e-6) & (hy <= 0.2 + 1e-6))[mask].all()
    assert torch.allclose(r, torch.hypot(hx, hy))
    # Placed by the largest box's bounding circle: its clearance from the start, the goal and the walls holds for every box.
    for far_from in (s.start[:, :2], s.goal):
        assert ((m[..., :2] - far_from[:, None]).norm(dim=-1) - r)[mask].min() >= 1.5 - 1e-4
    assert (points_clearance(m[..., :2], s.world) - r)[mask].min() >= 0.1 - 1e-4
    assert (s.sim.clearance > 0).all()
    for _ in range(3):
        env.rand_step()
    assert env._state.sim.mover_boxes.shape == (256, 3, 3) and torch.equal(env._state.sim.mover_boxes, s.sim.mover_boxes)


def test_map_rejects_bad_moving_boxes():
    from torchnav.maps import MapError, parse_map

    base = {"size": [10.0, 10.0], "walls": ["boundary"]}
    good = {"count": 2, "size_x": [0.2, 0.4], "size_y": [0.2, 0.3], "speed": [0.1, 0.2]}
    for bad, key in (({**good, "radius": [0.2, 0.3]}, "moving_boxes.radius"), ({k: v for k, v in good.items() if k != "size_y"}, "moving_boxes.size_y"),
                     ({**good, "size_x": [0.4, 0.2]}, "moving_boxes.size_x"), ({**good, "size_x": [0.2, 40.0]}, "moving_boxes.size_x")):
        with pytest.raises(MapError, match=key):
            parse_map({**base, "moving_boxes": bad})
    with pytest.raises(MapError, match="not both"):
        parse_map({**base, "moving_boxes": good, "moving_circles": {"count": 2, "radius": [0.2, 0.3], "speed": [0.1, 0.2]}})
    spec = parse_map({**base, "moving_boxes": {**good, "yaw": [0.0, 0.5]}})
    assert spec.movers.size_x == (0.2, 0.4) and spec.movers.yaw == (0.0, 0.5)
    assert spec.movers.radius == pytest.approx((0.5 * math.hypot(0.4, 0.3),) * 2)


def test_generated_worlds_take_moving_boxes_from_worlds_movers():
    from torchnav.config import ConfigError
    from torchnav.envs import NavEnv
    from torchnav.tasks import NavConfig

    movers = {"count": 2, "size_x": [0.4, 0.6], "size_y": [0.3, 0.5], "speed": [0.2, 0.4]}
    cfg = NavConfig.from_dict({"worlds": {"families": {"forest": 1.0}, "difficulty": 0.3, "movers": movers}, "max_steps": 50})
    env = NavEnv(cfg, num_envs=8, seed=1)
    env.reset()
    m, mask = env.state.sim.mover_boxes, env.state.sim.mover_mask
    assert m.shape == (8, 2, 3) and mask.any()
    assert ((m[..., 0] >= 0.2 - 1e-6) & (m[..., 0] <= 0.3 + 1e-6))[mask].all()
    with pytest.raises(ConfigError, match=r"worlds\.movers\.size_y"):
        NavConfig.from_dict({"worlds": {"families": {"forest": 1.0}, "movers": {**movers, "size_y": [0.5, 0.3]}}}).worlds.mover_spec()


def test_recording_draws_moving_boxes_as_boxes(tmp_path):
    """The movers topic carries each moving box's half extents and yaw; the scene draws it as a cube
    and the replay frames hold it as ``mover_boxes``."""
    import json

    import numpy as np

    from conftest import record_episode
    from torchnav.record.replay import render_episode

    env = _env_on(tmp_path, BOX_MAP, num_envs=2, max_steps=5)
    rec, ep, fr = record_episode(env, tmp_path / "boxes.mcap", 5)
    n, dt = len(fr["pose"]), env.cfg.robot.dt
    assert fr["movers"].shape == (n, 0, 5) and fr["mover_boxes"].shape == (n, 3, 7)
    hx, hy = fr["mover_boxes"][..., 4], fr["mover_boxes"][..., 5]
    assert ((hx >= 0.2 - 1e-6) & (hx <= 0.4 + 1e-6) & (hy >= 0.1 - 1e-6) & (hy <= 0.2 + 1e-6)).all()
    assert np.allclose(fr["mover_boxes"][2][:, :2], fr["mover_boxes"][1][:, :2] + dt * fr["mover_boxes"][2][:, 2:4], atol=1e-4)
    scene = [m.data for m in rec.topic(f"/env{ep.env}/scene", ep.start_time, ep.end_time)]
    movers = [e for s in scene for e in (json.loads(s) if isinstance(s, str) else s)["entities"] if e["id"] == "movers"]
    assert movers and all(len(e["cubes"]) == 3 and not e["cylinders"] for e in movers)
    assert movers[-1]["cubes"][0]["size"]["x"] == pytest.approx(2 * fr["mover_boxes"][-1][0, 4], abs=1e-5)
    assert render_episode(rec, ep, tmp_path / "boxes.gif", dpi=40).stat().st_size > 0
