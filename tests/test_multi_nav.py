"""The multi-robot task (torchnav/tasks/multi_navigation.py): placement, observation, parking, team outcome."""

import math

import pytest
import torch

from torchnav.config import ConfigError
from torchnav.tasks import CurriculumState, MultiNavConfig, MultiNavTask


def make(n=4, num_envs=6, seed=0, curriculum=None, **robots):
    cfg = MultiNavConfig.from_dict({"robots": {"n": n, **robots}, "curriculum": curriculum or {"mode": "off"}})
    task = MultiNavTask(cfg, num_envs)
    g = torch.Generator().manual_seed(seed)
    return task, task.initial_state(CurriculumState.initial(cfg.curriculum), g)[0], g


def pair_gaps(xy):
    """(B, N, N) centre distances with +inf on the diagonal."""
    d = (xy[:, :, None] - xy[:, None]).norm(dim=-1)
    return d + torch.diag(torch.full((xy.shape[1],), math.inf))


@pytest.mark.parametrize("scenario", ["random", "crossing", "circle_swap"])
def test_reset_places_robots_and_goals_apart_and_clear(scenario):
    task, s, _ = make(n=6, scenario=scenario)
    r = task.cfg.robot.radius
    assert s.observation.shape == (6, 6, task.obs_size)
    assert pair_gaps(s.start[..., :2]).amin() >= 2 * r + task.cfg.robots.separation - 1e-5
    assert (s.sim.robots.clearance > 0).all()
    assert not s.sim.robots.collided.any()
    if scenario == "circle_swap":
        centre = s.start[..., :2].mean(1, keepdim=True)
        torch.testing.assert_close(s.goal, 2 * centre - s.start[..., :2])
    else:
        assert pair_gaps(s.goal).amin() >= 2 * task.cfg.goal_tolerance + task.cfg.robots.separation - 1e-5
    if scenario == "crossing":  # even robots start left and go right, odd ones the other way
        mid = 0.5 * (task.nav.spec.bounds[0] + task.nav.spec.bounds[2])
        assert (s.start[:, 0::2, 0] < mid).all() and (s.goal[:, 0::2, 0] > mid).all()
        assert (s.start[:, 1::2, 0] > mid).all() and (s.goal[:, 1::2, 0] < mid).all()


def test_counts_per_env_and_absent_robots():
    task, s, g = make(n=5, min_n=2, num_envs=16)
    counts = s.present.sum(-1)
    assert (counts >= 2).all() and (counts <= 5).all() and len(set(counts.tolist())) > 1
    assert (s.present == (torch.arange(5) < counts[:, None])).all()
    pose = s.sim.robots.pose.clone()
    s2, out = task.step(s, torch.ones(16, 5, 2), g)
    absent = ~s.present
    assert torch.equal(s2.sim.robots.pose[absent], pose[absent])  # absent robots do not move
    assert (out["reward"][absent] == 0).all() and not out["collision"][absent].any()
    assert torch.equal(out["terminated"][absent], out["team_terminated"][:, None].expand(16, 5)[absent])


def test_neighbour_features_are_permutation_invariant_and_padded():
    task, s, _ = make(n=4, neighbours=5, neighbour_range=100.0)
    f = task.observe(s.sim, s.goal, s.present)
    perm = torch.tensor([2, 0, 3, 1])
    ps = s[:]
    ps.sim.robots = s.sim.robots[:, perm]
    ps.goal, ps.present = s.goal[:, perm], s.present[:, perm]
    fp = task.observe(ps.sim, ps.goal, ps.present)
    torch.testing.assert_close(fp, f[:, perm])
    k = task.nav.obs_size
    neigh = f[..., k:].reshape(6, 4, 5, 5)
    assert (neigh[..., :3, 4] == 1).all() and (neigh[..., 3:, :] == 0).all()  # 3 others, then padding
    d = neigh[..., :3, :2].norm(dim=-1)
    assert (d[..., 1:] >= d[..., :-1]).all()  # nearest first


def test_robot_at_goal_parks_and_team_succeeds_when_all_arrive():
    task, s, g = make(n=3, num_envs=2)
    # put robot 0 of env 0 on its goal: it succeeds on the next step, then stands still
    s.goal[0, 0] = s.sim.robots.pose[0, 0, :2]
    s, out = task.step(s, -torch.ones(2, 3, 2), g)  # v = 0 with forward_only
    assert out["success"][0, 0] and out["terminated"][0, 0] and not out["terminated"][0, 1]
    assert out["reward"][0, 0] > 50 and not out["team_terminated"][0]
    pose = s.sim.robots.pose[0, 0].clone()
    s, out = task.step(s, torch.ones(2, 3, 2), g)
    assert torch.equal(s.sim.robots.pose[0, 0], pose) and out["reward"][0, 0] == 0 and out["terminated"][0, 0]
    s.goal[0] = s.sim.robots.pose[0, :, :2]
    s, out = task.step(s, -torch.ones(2, 3, 2), g)
    assert out["team_terminated"][0] and out["team_success"][0] and not out["team_success"][1]


@pytest.mark.parametrize("on_collision", ["robot", "team"])
def test_robot_robot_collision_parks_or_ends_the_team(on_collision):
    task, s, g = make(n=3, num_envs=2, on_collision=on_collision)
    s.sim.robots.pose[0, 1, :2] = s.sim.robots.pose[0, 0, :2] + torch.tensor([0.3, 0.0])  # discs overlap (radius 0.2)
    s, out = task.step(s, -torch.ones(2, 3, 2), g)
    assert out["collision"][0, :2].all() and out["robot_collision"][0, :2].all()
    assert out["reward"][0, 0] < -50
    assert out["team_terminated"][0] == (on_collision == "team")
    assert out["terminated"][0, 2] == (on_collision == "team")
    assert not out["team_terminated"][1]


def test_truncation_at_max_steps():
    cfg = MultiNavConfig.from_dict({"max_steps": 3, "robots": {"n": 2}})
    task = MultiNavTask(cfg, 2)
    g = torch.Generator().manual_seed(1)
    s = task.initial_state(CurriculumState.initial(cfg.curriculum), g)[0]
    for _ in range(3):
        s, out = task.step(s, torch.tensor([-1.0, 0.0]).expand(2, 2, 2), g)
    assert out["team_truncated"].all() and out["truncated"].all() and not out["terminated"].any()


def test_partial_reset_keeps_other_envs_and_is_seeded():
    task, s, g = make(n=3, num_envs=4, seed=3)
    _, s_again, _ = make(n=3, num_envs=4, seed=3)
    assert torch.equal(s.start, s_again.start) and torch.equal(s.observation, s_again.observation)
    cur = CurriculumState.initial(task.cfg.curriculum)
    r, cur2 = task.reset(s, torch.tensor([True, False, True, False]), cur, g)
    assert cur2.placements == cur.placements + 6  # 2 envs of 3 robots
    assert torch.equal(r.start[1], s.start[1]) and torch.equal(r.start[3], s.start[3])
    assert not torch.equal(r.start[0], s.start[0])


def test_unsupported_options_are_refused():
    with pytest.raises(ConfigError, match="observation.history"):
        MultiNavTask(MultiNavConfig.from_dict({"observation": {"history": 2}}), 2)
    with pytest.raises(ConfigError, match="min_n"):
        MultiNavConfig.from_dict({"robots": {"n": 2, "min_n": 3}})
    with pytest.raises(ConfigError, match="robots.n"):
        MultiNavConfig.from_dict({"robots": {"n": 17}})


def test_goal_curriculum_bounds_random_goals_and_grows_per_robot():
    task, s, g = make(n=3, num_envs=8, curriculum={"init_radius": 1.0, "min_radius": 0.5, "growth": 0.01})
    d = (s.goal - s.start[..., :2]).norm(dim=-1)
    assert (d <= 1.0 + 1e-5).float().mean() > 0.9  # the fallback may go further where there is no room
    cur = CurriculumState.initial(task.cfg.curriculum)
    _, cur = task.initial_state(cur, g)
    assert int(cur.placements) == 24 and abs(float(cur.radius) - 1.24) < 1e-5
    assert int(task.initial_state(cur, g)[1].placements) == 48
    swap, _, g2 = make(n=3, num_envs=2, scenario="circle_swap", curriculum={"init_radius": 1.0})
    start = CurriculumState.initial(swap.cfg.curriculum)
    assert int(swap.initial_state(start, g2)[1].placements) == 0  # its goals are not drawn from the curriculum


def test_robots_beyond_the_neighbour_range_are_not_observed():
    task, s, _ = make(n=3, num_envs=2, neighbours=2, neighbour_range=1.0)
    s.sim.robots.pose[0, :, :2] = torch.tensor([[0.0, 0.0], [0.8, 0.0], [0.0, 1.5]])  # robot 1 in range of 0, robot 2 not
    neigh = task.observe(s.sim, s.goal, s.present)[0, 0, task.nav.obs_size:].reshape(2, 5)
    assert neigh[0, 4] == 1 and neigh[1].eq(0).all()
    torch.testing.assert_close(neigh[0, :2].norm(), torch.tensor(0.8 / 1.0))  # position in neighbour ranges (normalize on)
    # the neighbour block keeps its scale through observation statistics: empty slots stay 0
    unit = task.unit_features
    assert unit.shape == (task.obs_size,) and unit[task.nav.obs_size:].all() and not unit[: task.nav.obs_size].any()
