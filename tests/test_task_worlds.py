"""Navigation on procedural worlds: episodes drawn per family, the per-family difficulty
curriculum, its saved state, and configuration errors."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from torchnav.config import ConfigError
from torchnav.envs import NavEnv
from torchnav.sim import disc_clearance
from torchnav.tasks import CurriculumState, NavConfig, WorldsConfig, after_family_episodes

FAMILIES = {"forest": 1.0, "corridors": 1.0, "map:arena": 1.0}


def worlds_cfg(**worlds) -> NavConfig:
    return NavConfig.from_dict({"worlds": {"families": FAMILIES, "difficulty": 0.3, **worlds}, "max_steps": 50})


def test_env_draws_every_family_with_free_starts_and_passes_specs():
    env = NavEnv(worlds_cfg(), num_envs=24, seed=0)
    check_env_specs(env)
    env.reset()
    s = env.state
    assert set(s.family.tolist()) == {0, 1, 2} and s.difficulty.eq(0.3).all()
    assert (disc_clearance(s.sim.pose, s.world, 0.0) > env.cfg.robot.radius).all()
    # Envs of different families hold different worlds in one batch.
    forest, corridors = (s.family == 0).nonzero()[0, 0], (s.family == 1).nonzero()[0, 0]
    assert s.world.circle_mask[forest].any() and not s.world.circle_mask[corridors].any()
    td = env.rollout(60, break_when_any_done=False)  # resets come from the pool of generated episodes
    assert td["next", "done"].any()


def test_same_seed_same_episodes():
    a, b = NavEnv(worlds_cfg(), num_envs=8, seed=3), NavEnv(worlds_cfg(), num_envs=8, seed=3)
    a.reset(), b.reset()
    assert torch.equal(a.state.start, b.state.start) and torch.equal(a.state.world.segments, b.state.world.segments)
    c = NavEnv(worlds_cfg(), num_envs=8, seed=4)
    c.reset()
    assert not torch.equal(a.state.start, c.state.start)


def test_family_curriculum_raises_only_the_families_above_threshold():
    cfg = WorldsConfig(families={"forest": 1.0, "rooms": 1.0}, difficulty=0.2, curriculum=True, success_threshold=0.5, difficulty_step=0.1, success_smoothing=1.0)
    cur = CurriculumState.initial(NavConfig().curriculum, worlds=cfg)
    done = torch.tensor([True, True, True, False])
    success = torch.tensor([True, True, False, True])
    family = torch.tensor([0, 0, 1, 1])
    cur = after_family_episodes(cur, cfg, done, success, family)
    assert cur.difficulty.tolist() == pytest.approx([0.3, 0.2])
    assert cur.family_success.tolist() == pytest.approx([0.0, 0.0])  # forest was raised: its average restarts
    cur = after_family_episodes(cur, cfg, torch.tensor([True, False, True, True]), torch.tensor([False, False, True, True]), family)
    assert cur.difficulty.tolist() == pytest.approx([0.3, 0.3]) and cur.family_success.tolist() == pytest.approx([0.0, 0.0])
    off = WorldsConfig(families=cfg.families, curriculum=False)
    assert after_family_episodes(cur, off, done, success, family) is cur


def test_family_curriculum_ignores_episodes_below_the_current_level():
    # pooled episodes generated before a raise must not raise the family again
    cfg = WorldsConfig(families={"forest": 1.0}, difficulty=0.2, curriculum=True, success_threshold=0.5, difficulty_step=0.1, success_smoothing=1.0)
    cur = CurriculumState.initial(NavConfig().curriculum, worlds=cfg)
    cur = after_family_episodes(cur, cfg, torch.tensor([True]), torch.tensor([True]), torch.tensor([0]), torch.tensor([0.2]))
    assert cur.difficulty.tolist() == pytest.approx([0.3])
    stale = after_family_episodes(cur, cfg, torch.tensor([True, True]), torch.tensor([True, True]), torch.tensor([0, 0]), torch.tensor([0.2, 0.2]))
    assert stale.difficulty.tolist() == pytest.approx([0.3]) and stale.family_success.tolist() == pytest.approx([0.0])
    fresh = after_family_episodes(cur, cfg, torch.tensor([True, True]), torch.tensor([True, True]), torch.tensor([0, 0]), torch.tensor([0.2, 0.3]))
    assert fresh.difficulty.tolist() == pytest.approx([0.4])  # the one episode at 0.3 counts


def test_curriculum_state_round_trips_and_refuses_a_partial_one():
    env = NavEnv(worlds_cfg(curriculum=True), num_envs=4, seed=0)
    env.curriculum.difficulty = torch.tensor([0.4, 0.5, 0.6])
    sd = env.state_dict()
    fresh = NavEnv(worlds_cfg(curriculum=True), num_envs=4, seed=0)
    fresh.load_state_dict(sd)
    assert fresh.curriculum.difficulty.tolist() == pytest.approx([0.4, 0.5, 0.6])
    cur = sd["_extra_state"]["curriculum"]
    partial = {k: v for k, v in cur.items() if k not in ("difficulty", "family_success")}
    with pytest.raises(KeyError, match=r"missing \['difficulty', 'family_success'\]"):
        fresh.curriculum.load_state_dict(partial)
    with pytest.raises(ValueError, match="one per world family"):
        NavEnv(NavConfig(), num_envs=4).curriculum.load_state_dict(cur)


@pytest.mark.parametrize("worlds,match", [
    ({"families": {"forset": 1.0}}, "unknown family 'forset'"),
    ({"families": {"map:nowhere": 1.0}}, "map:nowhere"),
    ({"families": {"forest": -1.0}}, "weights must be >= 0"),
    ({"families": {"forest": 1.0}, "difficulty": 1.5}, "difficulty"),
    ({"families": {"forest": 1.0}, "curriculum": True, "success_threshold": 1.0}, "success_threshold"),
    ({"families": {"forest": 1.0}, "movers": {"count": 2, "speed": [0.1, 0.2]}}, r"worlds\.movers.*radius"),
    ({"families": {"forest": 1.0}, "movers": {"count": 2, "radius": [0.2, 0.3], "speed": [0.1, 0.2], "region": [0, 0, 1, 1]}},
     r"worlds\.movers\.region: not allowed"),
    ({"families": {"forest": 1.0}, "movers": {"count": 2, "radius": [0.2, 0.3], "speed": [0.1, 0.2], "motion": "fly"}},
     r"worlds\.movers\.motion"),
    ({"movers": {"count": 2, "radius": [0.2, 0.3], "speed": [0.1, 0.2]}}, "worlds.movers needs worlds.families"),
])
def test_bad_worlds_config_is_named(worlds, match):
    with pytest.raises(ConfigError, match=match):
        NavConfig.from_dict({"worlds": worlds})


def test_partial_reset_regenerates_only_the_masked_envs_and_map_path_is_unchanged():
    from torchnav.envs import make_nav_env
    from torchnav.tasks import EpisodePool, NavTask
    from torchnav.worlds import slot_counts

    t = NavTask(worlds_cfg(), 6)
    g = torch.Generator().manual_seed(1)
    s, c = t.initial_state(CurriculumState.initial(t.cfg.curriculum, worlds=t.cfg.worlds), g)
    assert t.spec is None and s.world.segments.shape == (6, slot_counts(list(FAMILIES))["segments"], 4)
    mask = torch.tensor([True, False, False, True, False, False])
    r, _ = t.reset(s, mask, c, g, EpisodePool())  # procedural worlds: always pooled
    keep = ~mask
    for key in ("segments", "segment_mask", "circles", "circle_mask", "boxes", "box_mask"):
        assert torch.equal(getattr(r.world, key)[keep], getattr(s.world, key)[keep])
    assert torch.equal(r.sim.pose[keep], s.sim.pose[keep]) and not torch.equal(r.goal[mask], s.goal[mask])
    assert make_nav_env("arena", num_envs=2).task.spec.name == "arena"


def test_planners_refuse_procedural_worlds_by_name():
    from torchnav.controllers import make_controller

    env = NavEnv(worlds_cfg(), num_envs=2, seed=0)
    with pytest.raises(ValueError, match="astar planner needs a map"):
        make_controller("astar", nav=env.cfg).bind(env)


@pytest.mark.parametrize("movers", [{}, {"count": 2, "radius": [0.2, 0.3], "speed": [0.2, 0.4]}], ids=["static", "movers"])
def test_episodes_on_procedural_worlds_record_with_their_worlds(tmp_path, movers):
    from torchnav.controllers import make_controller
    from torchnav.evaluation import record_episodes
    from torchnav.record.reader import read_recording

    cfg = worlds_cfg(movers=movers)
    path = tmp_path / "worlds.mcap"
    record_episodes(make_controller("reactive", nav=cfg), cfg, path, 2, seed=0)
    rec = read_recording(path)
    episodes = rec.episodes()
    assert len(episodes) == 2 and all(ep.start["world"]["segments"] for ep in episodes)
    assert any(m.topic.endswith("/movers") for m in rec.messages) == bool(movers)


def test_generated_worlds_hold_their_movers_inside_their_own_bounds():
    """``worlds.movers``: every generated world gets the movers, placed clear of the start and the goal
    and moving inside that world's bounds (worlds of different sizes in one batch); eval_config
    on a map drops them (the map's own moving_circles apply)."""
    from torchnav.evaluation import eval_config

    movers = {"count": 3, "radius": [0.2, 0.3], "speed": [0.2, 0.4], "motion": "pedestrian", "clearance": 1.0}
    env = NavEnv(worlds_cfg(movers=movers), num_envs=24, seed=1)
    env.reset()
    s = env.state
    m, mask = s.sim.movers, s.sim.mover_mask
    assert m.shape == (24, 3, 9) and mask.float().mean() > 0.5 and s.sim.mover_plan.shape[-1] == 4 + 2 * 4
    x, y, r, reg = m[..., 0], m[..., 1], m[..., 4], m[..., 5:9]
    assert len({tuple(row) for row in reg[:, 0].tolist()}) > 1  # each env's own bounds
    inside = (x - r >= reg[..., 0] - 1e-5) & (x + r <= reg[..., 2] + 1e-5) & (y - r >= reg[..., 1] - 1e-5) & (y + r <= reg[..., 3] + 1e-5)
    assert inside[mask].all()
    to_start = (m[..., :2] - s.start[:, None, :2]).norm(dim=-1) - r
    to_goal = (m[..., :2] - s.goal[:, None]).norm(dim=-1) - r
    assert (to_start[mask] >= 1.0 - 1e-4).all() and (to_goal[mask] >= 1.0 - 1e-4).all()
    assert (disc_clearance(s.sim.pose, s.world, 0.0) > env.cfg.robot.radius).all()
    env.rollout(20, break_when_any_done=False)  # steps and resets with movers
    on_map = eval_config(env.cfg, map="arena")
    assert on_map.worlds.movers == {} and on_map.worlds.families == {}
