"""Several robots on procedural worlds: torchnav.worlds.place_robots (every robot's goal reachable from
its start, checked by an independent planner; starts and goals apart), and MultiNavTask / MultiNavEnv
on worlds.families (clear and separated resets, seeding, the episode pool, the world curriculum per
robot, refused combinations)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from torchnav.config import ConfigError
from torchnav.controllers.planning import Obstacles, OccupancyGrid, plan_astar
from torchnav.envs import MultiNavEnv
from torchnav.sim import points_clearance
from torchnav.tasks import CurriculumState, EpisodePool, MultiNavConfig, MultiNavTask
from torchnav.worlds import RobotPlacement, make_worlds

START_APART, GOAL_APART = 0.6, 0.8  # the task's defaults: 2 * 0.2 + 0.2 and 2 * 0.3 + 0.2


def gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def obstacles_of(world, bounds, e: int) -> Obstacles:
    pick = lambda t, m: t[e][m[e]].double().numpy()  # noqa: E731
    return Obstacles(pick(world.segments, world.segment_mask), pick(world.circles, world.circle_mask), pick(world.boxes, world.box_mask),
                     tuple(float(v) for v in bounds))


def min_pair_gap(xy: torch.Tensor) -> torch.Tensor:
    """``(B,)`` least distance between two of the ``N`` points ``(B, N, 2)``."""
    n = xy.shape[1]
    return ((xy[:, :, None] - xy[:, None]).norm(dim=-1) + torch.diag(torch.full((n,), math.inf))).flatten(1).amin(1)


def assert_reachable(world, bounds: torch.Tensor, start: torch.Tensor, goal: torch.Tensor, radius: float, what: str) -> None:
    """Every robot's goal has a path from its start for the bare disc (numpy geometry, A* on a 0.05 m grid)."""
    for e in range(start.shape[0]):
        grid = OccupancyGrid.build(obstacles_of(world, bounds[e], e), 0.05)
        for i in range(start.shape[1]):
            path = plan_astar(grid, start[e, i, :2].numpy(), goal[e, i].numpy(), inflate=radius, snap=0.1)
            assert path is not None, f"{what}: env {e} robot {i} has no path to its goal"


@pytest.mark.parametrize("family, difficulty, n", [("rooms", 0.5, 8), ("cave", 0.8, 16), ("forest", 0.2, 2), ("corridors", 1.0, 8),
                                                   ("fences", 0.5, 16), ("map:maze", 0.5, 8)])
def test_every_robots_goal_is_reachable_and_robots_and_goals_are_apart(family, difficulty, n):
    b = make_worlds(family, 3, difficulty, gen(1), robots=RobotPlacement(n, START_APART, GOAL_APART))
    r = b.robot_radius
    assert b.start.shape == (3, n, 3) and b.goal.shape == (3, n, 2) and b.path_length.shape == (3, n)
    for xy in (b.start[..., :2], b.goal):
        assert (points_clearance(xy, b.world) > r).all()
        assert ((xy > b.bounds[:, None, :2] + r) & (xy < b.bounds[:, None, 2:] - r)).all()
    assert (min_pair_gap(b.start[..., :2]) >= START_APART).all()
    assert (min_pair_gap(b.goal) >= GOAL_APART).all()
    straight = (b.goal - b.start[..., :2]).norm(dim=-1)
    assert (b.path_length >= straight - 1e-4).all()
    assert_reachable(b.world, b.bounds, b.start, b.goal, r, family)


def test_goals_follow_the_difficulty_band_for_every_robot():
    easy = make_worlds("open", 6, 0.0, gen(2), robots=RobotPlacement(8, START_APART, GOAL_APART))
    hard = make_worlds("open", 6, 1.0, gen(2), robots=RobotPlacement(8, START_APART, GOAL_APART))
    assert hard.path_length.mean() > 2 * easy.path_length.mean()


def test_sides_send_even_robots_left_to_right_and_odd_ones_back():
    b = make_worlds("forest", 3, 0.3, gen(3), robots=RobotPlacement(6, START_APART, GOAL_APART, sides=True))
    third = (b.bounds[:, 2] - b.bounds[:, 0])[:, None] / 3
    left, right = b.bounds[:, 0:1] + third + 0.1, b.bounds[:, 2:3] - third - 0.1  # jitter: half a cell
    x0, x1 = b.start[..., 0], b.goal[..., 0]
    assert (x0[:, 0::2] <= left).all() and (x1[:, 0::2] >= right).all()
    assert (x0[:, 1::2] >= right).all() and (x1[:, 1::2] <= left).all()
    assert_reachable(b.world, b.bounds, b.start, b.goal, b.robot_radius, "forest sides")


def test_placement_errors_name_the_problem():
    with pytest.raises(ValueError, match="RobotPlacement"):
        RobotPlacement(0)
    with pytest.raises(ValueError, match="guide_cells"):
        make_worlds("open", 2, 0.5, gen(), robots=RobotPlacement(2), guide_cells=16)


# ------------------------------------------------------------------ the task and the env


FAMILIES = {"rooms": 1.0, "forest": 1.0, "map:arena": 1.0}


def cfg_of(n=8, scenario="random", **worlds) -> MultiNavConfig:
    return MultiNavConfig.from_dict({"robots": {"n": n, "scenario": scenario}, "max_steps": 20,
                                     "worlds": {"families": FAMILIES, "difficulty": 0.5, **worlds}})


def initial(cfg: MultiNavConfig, num_envs: int, seed: int = 0):
    task = MultiNavTask(cfg, num_envs)
    g = gen(seed)
    cur = CurriculumState.initial(cfg.curriculum, worlds=cfg.worlds)
    state, cur = task.initial_state(cur, g)
    return task, state, cur, g


def world_bounds(world) -> torch.Tensor:
    """``(B, 4)`` extent of each world's walls (every family's walls run along its bounds)."""
    seg = torch.where(world.segment_mask[..., None], world.segments, torch.nan).reshape(world.batch_size[0], -1, 2)
    lo, hi = seg.nan_to_num(math.inf).amin(1), seg.nan_to_num(-math.inf).amax(1)
    return torch.cat((lo, hi), -1)


@pytest.mark.parametrize("scenario", ["random", "crossing"])
def test_task_resets_place_every_robot_clear_apart_and_with_a_path(scenario):
    task, s, _, _ = initial(cfg_of(8, scenario), 4)
    r, sep = task.cfg.robot.radius, task.cfg.robots.separation
    assert set(s.family.tolist()) <= {0, 1, 2} and (s.difficulty == 0.5).all()
    assert s.observation.shape == (4, 8, task.obs_size)
    assert (s.sim.robots.clearance > 0).all() and not s.sim.robots.collided.any()
    assert (min_pair_gap(s.start[..., :2]) >= 2 * r + sep).all()
    assert (min_pair_gap(s.goal) >= 2 * task.cfg.goal_tolerance + sep).all()
    assert_reachable(s.world, world_bounds(s.world), s.start, s.goal, r, scenario)


def test_task_resets_are_seeded_and_pooled_partial_resets_keep_the_other_envs():
    task, s, cur, g = initial(cfg_of(4), 4, seed=5)
    _, again, _, _ = initial(cfg_of(4), 4, seed=5)
    _, other, _, _ = initial(cfg_of(4), 4, seed=6)
    assert torch.equal(s.start, again.start) and torch.equal(s.goal, again.goal) and torch.equal(s.world.segments, again.world.segments)
    assert not torch.equal(s.start, other.start)
    assert task.pooled
    with pytest.raises(ValueError, match="pool"):
        task.reset(s, torch.tensor([True, False, False, False]), cur, g)
    pool = EpisodePool()
    mask = torch.tensor([True, False, True, False])
    r, cur2 = task.reset(s, mask, cur, g, pool)
    assert pool.episodes.batch_size[0] == 4  # a pool of num_envs episodes, 2 handed out
    assert torch.equal(r.start[1], s.start[1]) and torch.equal(r.start[3], s.start[3])
    assert not torch.equal(r.start[0], s.start[0])
    assert int(cur2.placements) == int(cur.placements) + 8


def test_world_curriculum_counts_each_robots_finished_episode():
    cfg = cfg_of(3, curriculum=True, success_threshold=0.5, difficulty_step=0.1, success_smoothing=1.0)
    task, s, cur, g = initial(cfg, 2)
    s.family[:] = torch.tensor([1, 2])
    # env 0 (forest): robots 0 and 1 arrive, robot 2 crashes; env 1 (map:arena): one robot crashes
    done = torch.tensor([[True, True, True], [True, False, False]])
    success = torch.tensor([[True, True, False], [False, False, False]])
    out = {"terminated": done, "truncated": torch.zeros_like(done), "success": success}
    cur = task.after_step(cur, s, out)
    assert cur.difficulty.tolist() == pytest.approx([0.5, 0.6, 0.5])  # forest: 2 of 3 robots at their goal > 0.5
    assert cur.family_success.tolist() == pytest.approx([0.0, 0.0, 0.0])  # forest raised (restarts), arena 0 of 1
    s2, _ = task.initial_state(cur, g)
    assert s2.difficulty[s2.family == 1].eq(0.6).all() and s2.difficulty[s2.family != 1].eq(0.5).all()


def test_env_on_worlds_passes_specs_resets_from_its_pool_and_restores_its_state():
    cfg = cfg_of(3, curriculum=True)
    env = MultiNavEnv(cfg, num_envs=4, seed=0)
    check_env_specs(env)
    assert env.curriculum.difficulty.shape == (3,)
    torch.manual_seed(0)
    td = env.rollout(30, break_when_any_done=False)  # max_steps 20: every env resets once from the pool
    assert td["next", "done"].any() and env.pool.episodes is not None
    saved = env.state_dict()
    twin = MultiNavEnv(cfg, num_envs=4, seed=1)
    twin.load_state_dict(saved)
    assert torch.equal(twin.state.start, env.state.start) and twin.pool.pos == env.pool.pos
    torch.testing.assert_close(twin.curriculum.difficulty, env.curriculum.difficulty)


MOVING_MAP = """
name: moving
size: [10.0, 10.0]
walls: boundary
random_boxes: {count: 3, size_x: [0.4, 0.6], size_y: [0.3, 0.5], clearance: 1.0, margin: 0.1}
moving_circles: {count: 4, radius: [0.2, 0.3], speed: [0.2, 0.5], motion: pedestrian, clearance: 0.5, margin: 0.1}
"""


def mover_gaps(s, radius: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Least gap (m) of each env's placed movers' discs to its robots' discs at the start, and to its goals."""
    m, mask = s.sim.movers, s.sim.mover_mask
    def gap(xy):  # (B, N, 2) -> (B,)
        d = (xy[:, :, None] - m[:, None, :, :2]).norm(dim=-1) - m[:, None, :, 4]
        return torch.where(mask[:, None], d, math.inf).flatten(1).amin(1)
    return gap(s.start[..., :2]) - radius, gap(s.goal)


@pytest.mark.parametrize("where", ["map", "worlds"])
def test_movers_keep_clear_of_every_robots_start_and_goal_and_move(where, tmp_path):
    cfg_map = tmp_path / "moving.yaml"
    cfg_map.write_text(MOVING_MAP)
    movers = {"count": 3, "radius": [0.2, 0.3], "speed": [0.2, 0.5], "clearance": 0.5, "margin": 0.1}
    if where == "map":
        cfg = MultiNavConfig.from_dict({"map": str(cfg_map), "robots": {"n": 6}, "max_steps": 20})
    else:
        cfg = cfg_of(6, movers=movers)
    task, s, _, g = initial(cfg, 4)
    m, mask = s.sim.movers, s.sim.mover_mask
    assert m.shape[:2] == (4, 4 if where == "map" else 3) and mask.any()
    start_gap, goal_gap = mover_gaps(s, task.cfg.robot.radius)
    rc = task.cfg.reset
    assert (start_gap >= rc.start_clearance - 1e-5).all() and (goal_gap >= rc.goal_clearance - 1e-5).all()
    assert not s.sim.robots.collided.any()
    s2, _ = task.step(s, -torch.ones(4, 6, 2), g)  # the robots stand still, the movers walk
    moved = (s2.sim.movers[..., :2] - m[..., :2]).norm(dim=-1)
    assert (moved[mask] > 0).all()


def test_refused_combinations_name_the_problem():
    with pytest.raises(ConfigError, match="circle_swap"):
        MultiNavTask(cfg_of(4, "circle_swap"), 2)
    with pytest.raises(ConfigError, match="geodesic"):
        MultiNavTask(MultiNavConfig.from_dict({"robots": {"n": 2}, "worlds": {"families": FAMILIES},
                                               "reward": {"progress_distance": "geodesic"}}), 2)
