"""Classical controllers: each reaches goals on `empty`, the potential field's local minimum,
planners find paths or report none, the tracker follows waypoints, batched == per env."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchnav.config import ConfigError
from torchnav.controllers import (
    CONTROLLERS, Obstacles, OccupancyGrid, RRTParams, TrackerGains, WaypointTracker, drive, make_controller, plan_astar, plan_rrt,
    shortest_paths,
)
from torchnav.envs import make_nav_env
from torchnav.evaluation import eval_config, run_episodes
from torchnav.tasks import NavConfig


def rollout(ctrl, map_: str, start, goal, steps: int = 400):
    """Run ``ctrl`` from poses ``start`` ``(B, 3)`` to goals ``(B, 2)``; returns (success, collision, poses)."""
    out = drive(ctrl, NavConfig.from_dict({"map": map_}), start, goal, steps)
    return out["success"], out["collision"], out["pose"]


STARTS = [[-3.0, -3.0, 0.0], [3.0, 3.0, math.pi], [0.0, 0.0, math.pi / 2], [-3.5, 3.0, -1.0], [2.0, -3.0, 2.5], [0.0, 3.5, 0.0]]
GOALS = [[3.0, 3.0], [-3.0, -2.0], [0.0, -3.0], [3.0, 0.0], [-2.0, 2.0], [0.0, 0.5]]  # several behind the robot


@pytest.mark.parametrize("name", list(CONTROLLERS))
def test_each_controller_reaches_goal_on_empty(name):
    success, collision, _ = rollout(make_controller(name), "empty", STARTS, GOALS)
    assert success.all(), f"{name}: failed from starts {[s for s, ok in zip(STARTS, success) if not ok]}"
    assert not collision.any()


CUP = """
name: cup
size: [10.0, 10.0]
walls:
  - boundary
  - [1.0, -1.5, 1.0, 1.5]     # the bottom of the cup, between the robot and the goal
  - [1.0, -1.5, -0.5, -1.5]   # its two sides, open towards the robot
  - [1.0, 1.5, -0.5, 1.5]
"""


def test_potential_field_trapped_in_cup_but_astar_escapes(tmp_path):
    """The textbook local minimum: pull to the goal and push from the cup cancel inside it."""
    path = tmp_path / "cup.yaml"
    path.write_text(CUP)
    start, goal = [[-3.0, 0.0, 0.0]], [[3.5, 0.0]]
    success, collision, poses = rollout(make_controller("potential_field"), str(path), start, goal, steps=300)
    assert not success.any() and not collision.any()
    assert poses[0, -1, 0] < 1.0, "the robot should still be on the start side of the cup"
    success, collision, _ = rollout(make_controller("astar"), str(path), start, goal, steps=300)
    assert success.all() and not collision.any()


def _box_world(enclosed: bool) -> Obstacles:
    walls = [[-5, -5, 5, -5], [5, -5, 5, 5], [5, 5, -5, 5], [-5, 5, -5, -5], [0, -5, 0, 3.0]]  # a wall with a gap at the top
    if enclosed:
        walls += [[2, 2, 4, 2], [4, 2, 4, 4], [4, 4, 2, 4], [2, 4, 2, 2]]  # a closed square around the goal
    return Obstacles(np.asarray(walls, float), np.zeros((0, 3)), np.asarray([[-2.5, 0.0, 0.5, 1.0, 0.3]]), (-5, -5, 5, 5))


def _check_path(obs: Obstacles, path: np.ndarray, start, goal, inflate: float):
    assert np.allclose(path[0], start) and np.allclose(path[-1], goal)
    pts = np.concatenate([a + np.linspace(0, 1, 50)[:, None] * (b - a) for a, b in zip(path[:-1], path[1:])])
    assert obs.clearance(pts).min() > inflate - 0.08  # grid sampling loses at most half a cell diagonal


def test_astar_finds_path_or_reports_none():
    start, goal, inflate = np.array([-3.0, -3.0]), np.array([3.0, 3.0]), 0.3
    obs = _box_world(enclosed=False)
    path = plan_astar(OccupancyGrid.build(obs, 0.1), start, goal, inflate)
    assert path is not None and path[:, 1].max() > 3.0  # through the gap above the dividing wall
    _check_path(obs, path, start, goal, inflate)
    assert len(path) <= 6  # shortcutting leaves a few corners, not a cell per step
    assert plan_astar(OccupancyGrid.build(_box_world(enclosed=True), 0.1), start, goal, inflate) is None


def test_rrt_finds_path_or_reports_none():
    start, goal, inflate = np.array([-3.0, -3.0]), np.array([3.0, 3.0]), 0.3
    obs = _box_world(enclosed=False)
    path = plan_rrt(obs, start, goal, inflate, RRTParams(max_iters=3000), seed=1)
    assert path is not None
    _check_path(obs, path, start, goal, inflate + 0.08)  # exact checks: no grid loss
    assert np.array_equal(path, plan_rrt(obs, start, goal, inflate, RRTParams(max_iters=3000), seed=1))  # deterministic
    assert plan_rrt(_box_world(enclosed=True), start, goal, inflate, RRTParams(max_iters=300)) is None


def _unicycle(pose, v, omega, dt=0.1):
    th = pose[:, 2] + omega * dt
    return torch.stack((pose[:, 0] + v * dt * torch.cos(pose[:, 2] + 0.5 * omega * dt),
                        pose[:, 1] + v * dt * torch.sin(pose[:, 2] + 0.5 * omega * dt), th), -1)


def test_tracker_follows_known_waypoints_and_batches():
    paths = [np.array([[0, 0], [3, 0], [3, 3], [0, 3]], float), np.array([[0, 0], [2, 2]], float), np.array([[0, 0], [-2, 1], [-2, -2]], float)]
    pose = torch.zeros(3, 3)
    tr = WaypointTracker(TrackerGains(), 3, dt=0.1)
    tr.set_paths([0, 1, 2], paths)
    single = [WaypointTracker(TrackerGains(), 1, dt=0.1) for _ in paths]
    for k, t in enumerate(single):
        t.set_paths([0], [paths[k]])
    poses = [pose]
    for _ in range(300):
        v, w = tr(pose)
        for k, t in enumerate(single):  # batched tracker == each env tracked alone
            vk, wk = t(pose[k : k + 1])
            assert torch.allclose(v[k : k + 1], vk) and torch.allclose(w[k : k + 1], wk)
        pose = _unicycle(pose, v.clamp(0, 1), w.clamp(-1, 1))
        poses.append(pose)
    traj = torch.stack(poses, 1)
    for k, p in enumerate(paths):
        assert np.hypot(*(traj[k, -1, :2].numpy() - p[-1])) < 0.15, f"path {k} not completed"
        # the robot stays near the polyline (cross-track error)
        seg = [a + np.linspace(0, 1, 200)[:, None] * (b - a) for a, b in zip(p[:-1], p[1:])]
        line = np.concatenate(seg)
        d = np.linalg.norm(traj[k, :, None, :2].numpy() - line[None], axis=-1).min(1)
        assert d.max() < 0.15, f"path {k}: cross-track error {d.max():.3f} m"


@pytest.mark.parametrize("name", ["go_to_goal", "reactive", "potential_field"])
def test_batched_equals_per_env(name):
    env = make_nav_env("arena", num_envs=16, seed=3, curriculum={"mode": "off"})
    td = env.reset()
    ctrl = make_controller(name).bind(env)
    batched = ctrl(td.clone())["action"]
    for e in range(16):
        one = ctrl(td[e : e + 1].clone())["action"]
        assert torch.allclose(one, batched[e : e + 1], atol=1e-6)
    assert batched.abs().max() <= 1.0


def test_planners_in_evaluation_are_bound_and_succeed():
    cfg = eval_config(NavConfig(), map="arena")
    for name in ("astar", "rrt"):
        ctrl = make_controller(name)
        res = run_episodes(ctrl, cfg, 12, seed=5)
        assert res["success"].float().mean() >= 0.9, name
        assert ctrl.stats["plans"] == 12


def test_planner_needs_binding_and_errors_are_clear():
    td = make_nav_env("empty", num_envs=2).reset()
    with pytest.raises(RuntimeError, match="bind"):
        make_controller("astar")(td)
    with pytest.raises(ConfigError, match="unknown controller 'astr'.*did you mean 'astar'"):
        make_controller("astr")
    with pytest.raises(ConfigError, match="unknown key 'k_vv'"):
        make_controller("go_to_goal", k_vv=1.0)
    with pytest.raises(ConfigError, match="tracker: unknown key 'kk'"):
        make_controller("astar", tracker={"kk": 1.0})
    with pytest.raises(ConfigError, match="use the 'rrt' controller"):
        make_controller("astar", planner="rrt")
    with pytest.raises(ConfigError, match="no_path"):
        make_controller("rrt", no_path="spin")
    with pytest.raises(ConfigError, match="continuous"):
        make_controller("reactive", nav=NavConfig.from_dict({"action": {"mode": "discrete"}}))


BOXED = "size: [10.0, 10.0]\nwalls:\n  - boundary\n  - [2, 2, 4, 2]\n  - [4, 2, 4, 4]\n  - [4, 4, 2, 4]\n  - [2, 4, 2, 2]\n"


def test_no_path_stops(tmp_path):
    """A goal walled in: the planner reports no path and the robot stands still (no_path='stop')."""
    p = tmp_path / "box.yaml"
    p.write_text(BOXED)
    ctrl = make_controller("astar")
    success, collision, poses = rollout(ctrl, str(p), [[-3.0, -3.0, 0.0]], [[3.0, 3.0]], steps=20)
    assert ctrl.stats["no_path"] == 1 and not success.any() and not collision.any()
    assert torch.allclose(poses[0, -1], poses[0, 0])


def test_windowed_grid_matches_full_grid_below_the_window():
    """Stamping random objects near themselves only equals the full rasterisation where it matters."""
    env = make_nav_env("street", num_envs=6, seed=2, curriculum={"mode": "off"})
    env.reset()
    ctrl = make_controller("astar").bind(env)
    world = env.state.world.to("cpu")
    for e in range(6):
        _, rand = ctrl.env_obstacles(world, e)
        full = OccupancyGrid.build(rand, 0.1, base=ctrl.fixed_grid.clearance).clearance
        fast = ctrl.grid(rand).clearance
        near = full <= 0.5
        assert np.allclose(full[near], fast[near]) and (fast >= full - 1e-12).all()


def test_no_path_go_to_goal_fallback_moves(tmp_path):
    p = tmp_path / "box.yaml"
    p.write_text(BOXED)
    ctrl = make_controller("rrt", no_path="go_to_goal", rrt_max_iters=200)
    _, _, poses = rollout(ctrl, str(p), [[-3.0, -3.0, 0.0]], [[3.0, 3.0]], steps=20)
    assert ctrl.stats["no_path"] == 1
    assert np.hypot(*(poses[0, -1, :2] - torch.tensor([3.0, 3.0])).tolist()) < np.hypot(6.0, 6.0) - 1.0


def test_shortest_paths_are_the_straight_line_in_the_open_and_the_tangent_detour_round_a_wall():
    """A wall x = 0, y in [-1, 1], a disc of 0.2 m from (-1, 0) to (1, 0): around the wall's end the shortest
    path is two tangents to the inflated end (a circle of 0.2 m at (0, 1)) and the arc between them, 3.171 m."""
    from torchnav.sim import make_world

    r = 0.2
    world = make_world(3, segments=[[0.0, -1.0, 0.0, 1.0]], dtype=torch.float64)
    start = torch.tensor([[-1.0, 0.0], [-1.0, 3.0], [-1.0, 0.0]], dtype=torch.float64)
    goal = torch.tensor([[1.0, 0.0], [2.0, 3.0], [-0.5, -0.5]], dtype=torch.float64)
    got = shortest_paths(world, start, goal, r)
    tangent = math.sqrt(2.0 - r * r)
    arc = r * (math.pi - 2 * (math.pi / 4 + math.acos(r / math.sqrt(2.0)) - math.pi / 2))  # between the two tangent points
    assert 1.0 <= got[0] / (2 * tangent + arc) < 1.04, got  # the grid keeps the path up to a cell wider round the end
    assert got[1] == pytest.approx(3.0, abs=1e-9) and got[2] == pytest.approx(math.hypot(0.5, 0.5), abs=1e-9)  # no wall in the way
    closed = make_world(1, segments=[[-2.0, -2.0, 2.0, -2.0], [2.0, -2.0, 2.0, 2.0], [2.0, 2.0, -2.0, 2.0], [-2.0, 2.0, -2.0, -2.0],
                                     [0.0, -2.0, 0.0, 2.0]], dtype=torch.float64)  # a wall across a closed room
    assert shortest_paths(closed, start[:1], goal[:1], r)[0] == math.inf


def test_time_efficiency_counts_time_against_the_shortest_path_at_top_speed():
    from torchnav.evaluation import time_efficiency

    cfg = NavConfig()  # v_max 1 m/s, 0.1 s a step: 10 steps a metre
    tol = cfg.goal_tolerance
    shortest = torch.tensor([2.0, 4.0, 3.0, math.inf], dtype=torch.float64) + tol  # 20, 40 and 30 optimal steps
    res = {"success": torch.tensor([True, True, False, True]), "length": torch.tensor([30.0, 40.0, 500.0, 10.0])}
    t = time_efficiency(res, shortest, cfg)
    assert t["no_reference"] == 1
    assert t["time_ratio"]["mean"] == pytest.approx(70 / 60)  # the successful episodes with a reference, summed
    assert t["time_ratio"]["ci95"][0] < 70 / 60 < t["time_ratio"]["ci95"][1]
    assert t["time_score"]["mean"] == pytest.approx((20 / 30 + 1.0 + 0.0) / 3)
