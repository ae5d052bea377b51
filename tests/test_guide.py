"""Geodesic distance to the goal (torchnav/worlds/guide.py) and the geodesic progress reward:
distances against an independent planner, no shortcut through a thin wall, the reward's sum,
unchanged episodes, configuration errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchnav.config import ConfigError
from torchnav.controllers.planning import Obstacles, OccupancyGrid, plan_astar
from torchnav.envs import NavEnv
from torchnav.evaluation import eval_config
from torchnav.tasks import NavConfig
from torchnav.worlds import goal_distance, goal_distance_grid, make_worlds
from torchnav.worlds.layout import walled_world

SAFE = 0.2  # the wavefront passes cells whose centre is clear of the default robot


def wall_world() -> tuple:
    """A 10 x 10 m room split by a wall along x = 0 from the bottom edge up to y = 3 (a 2 m gap at the top)."""
    half = torch.tensor([5.0])
    wall = torch.tensor([[[0.0, -5.0, 0.0, 3.0]]])
    return walled_world(half, half, segments=(wall, torch.ones(1, 1, dtype=torch.bool)))


def test_distance_goes_round_a_wall_and_never_through_it():
    world, bounds = wall_world()
    goal = torch.tensor([[2.0, -3.0]])
    field, frame = goal_distance_grid(world, bounds, goal)
    around = lambda p: math.dist(p, (0.0, 3.0 + SAFE)) + math.dist((0.0, 3.0 + SAFE), (2.0, -3.0))  # noqa: E731
    for p in [(-2.0, -3.0), (-0.21, -3.0), (-0.21, -4.5), (-4.0, 2.0)]:  # (-0.21, ...): beside the wall, 0.42 m from the goal's side
        d = float(goal_distance(field, frame, goal, torch.tensor([p]))[0])
        assert around(p) - 0.05 < d < around(p) * 1.09, (p, d, around(p))  # octile paths are at most 8.2% long
    # On the goal's side the distance is the straight line (up to the grid's round-off), and 0 at the goal.
    for p in [(3.0, -1.0), (0.5, -3.0)]:
        d = float(goal_distance(field, frame, goal, torch.tensor([p]))[0])
        assert math.dist(p, (2.0, -3.0)) - 0.05 < d < math.dist(p, (2.0, -3.0)) * 1.09 + 0.1
    assert float(goal_distance(field, frame, goal, goal)[0]) == pytest.approx(0.0, abs=1e-5)
    # Inside the wall's unsafe band no coarse centre is reached: unknown, not a wrong number.
    assert math.isinf(float(goal_distance(field, frame, goal, torch.tensor([[0.0, -2.0]]))[0]))


def test_margin_closes_gaps_the_robot_would_only_scrape_through():
    """A wall along x = 0 with a 0.6 m gap at y = 0: a 0.4 m robot passes it; with a 0.15 m margin
    (0.7 m needed) no path is left and the distance is unknown."""
    half = torch.tensor([5.0])
    walls = torch.tensor([[[0.0, -5.0, 0.0, -0.3], [0.0, 0.3, 0.0, 5.0]]])
    world, bounds = walled_world(half, half, segments=(walls, torch.ones(1, 2, dtype=torch.bool)))
    goal, robot = torch.tensor([[2.0, 0.0]]), torch.tensor([[-2.0, 0.0]])
    d = float(goal_distance(*goal_distance_grid(world, bounds, goal), goal, robot)[0])
    assert 4.0 - 0.05 < d < 4.0 * 1.09
    assert math.isinf(float(goal_distance(*goal_distance_grid(world, bounds, goal, margin=0.15), goal, robot)[0]))
    with pytest.raises(ValueError, match="guide_margin must be >= 0"):
        make_worlds("open", 1, 0.5, torch.Generator().manual_seed(0), guide_cells=8, guide_margin=-0.1)


def test_goal_distance_grid_refuses_an_unsafe_goal():
    world, bounds = wall_world()
    with pytest.raises(ValueError, match="not on a cell where"):
        goal_distance_grid(world, bounds, torch.tensor([[0.05, -3.0]]))


@pytest.mark.parametrize("family", ["rooms", "corridors", "cave", "forest"])
def test_start_distance_matches_an_independent_planner(family):
    """Each start's distance on the coarse grid against A* (with shortcuts) on a 0.05 m occupancy grid."""
    batch = make_worlds(family, 8, 0.6, torch.Generator().manual_seed(11), guide_cells=64)
    d = goal_distance(batch.goal_field, batch.goal_frame, batch.goal, batch.start[:, :2])
    w = batch.world
    for e in range(len(batch)):
        pick = lambda t, m: t[e][m[e]].double().numpy()  # noqa: E731
        obs = Obstacles(pick(w.segments, w.segment_mask), pick(w.circles, w.circle_mask), pick(w.boxes, w.box_mask), tuple(batch.bounds[e].tolist()))
        path = plan_astar(OccupancyGrid.build(obs, 0.05), batch.start[e, :2].double().numpy(), batch.goal[e].double().numpy(), inflate=0.2)
        assert path is not None
        length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
        # The planner may pass closer to obstacles (0.2 m against 0.27 m), so it is at most a little shorter.
        assert 0.97 * length - 0.15 < float(d[e]) < 1.1 * length + 0.3, (family, e, float(d[e]), length)


def test_open_world_distance_is_the_straight_line():
    batch = make_worlds("open", 16, 0.0, torch.Generator().manual_seed(2), guide_cells=64)
    clear = ~batch.world.box_mask.any(1) & ~batch.world.circle_mask.any(1)
    x = torch.linspace(0, 1, 9)
    for e in clear.nonzero()[:, 0].tolist()[:3]:
        pts = batch.start[e, None, :2] + x[:, None] * (batch.goal[e] - batch.start[e, :2])
        d = goal_distance(batch.goal_field[e].expand(9, -1, -1), batch.goal_frame[e].expand(9, -1), batch.goal[e].expand(9, -1), pts)
        line = (pts - batch.goal[e]).norm(dim=-1)
        assert torch.all(d >= line - 0.05) and torch.all(d <= line * 1.09 + 0.1)


def geodesic_cfg(progress_distance: str = "geodesic", margin: float = 0.0) -> NavConfig:
    return NavConfig.from_dict({"worlds": {"families": {"corridors": 1.0, "rooms": 1.0}, "difficulty": 0.5}, "max_steps": 400,
                                "reward": {"preset": "progress", "progress_distance": progress_distance, "geodesic_margin": margin}})


@pytest.mark.parametrize("margin", [0.0, 0.1])
def test_progress_rewards_sum_to_the_decrease_of_the_path_distance(margin):
    env = NavEnv(geodesic_cfg(margin=margin), num_envs=8, seed=1)
    env.reset()
    task, state = env.task, env.state
    first = state.goal_path.clone()
    assert first.isfinite().all() and (first >= state.goal_dist - 0.05).all()
    total = torch.zeros(8)
    gen = torch.Generator().manual_seed(0)
    for _ in range(30):
        state, out = task.step(state, torch.rand(8, 2, generator=gen) * 2 - 1)
        total += out["terms"]["progress"]
    weight = task.weights["progress"]
    live = ~out["terminated"]  # envs that ended keep stepping in this raw loop; compare the others
    torch.testing.assert_close(total[live] / weight, (first - state.goal_path)[live], atol=1e-4, rtol=1e-4)


def test_geodesic_progress_leaves_the_episodes_unchanged():
    a, b = NavEnv(geodesic_cfg("euclidean"), num_envs=6, seed=5), NavEnv(geodesic_cfg(), num_envs=6, seed=5)
    a.reset(), b.reset()
    assert torch.equal(a.state.start, b.state.start) and torch.equal(a.state.goal, b.state.goal)
    assert torch.equal(a.state.world.segments, b.state.world.segments)
    assert a.state.goal_field.shape[1:] == (0, 0) and b.state.goal_field.shape[1:] == (64, 64)
    torch.testing.assert_close(a.state.goal_path, a.state.goal_dist)


def test_progress_distance_config_errors_and_evaluation():
    with pytest.raises(ConfigError, match="reward.progress_distance='manhattan': must be euclidean or geodesic"):
        NavConfig.from_dict({"reward": {"progress_distance": "manhattan"}})
    with pytest.raises(ConfigError, match="geodesic needs worlds.families"):
        NavConfig.from_dict({"reward": {"progress_distance": "geodesic"}})
    with pytest.raises(ConfigError, match="reward.geodesic_margin=-0.1: must be a finite number >= 0"):
        NavConfig.from_dict({"reward": {"geodesic_margin": -0.1}})
    cfg = geodesic_cfg()
    assert eval_config(cfg).reward.progress_distance == "euclidean"
    assert eval_config(cfg, map="arena").map == "arena"  # a map has no wavefront: evaluation there works too
