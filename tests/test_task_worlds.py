"""NavTask and NavEnv on procedurally generated worlds (cfg.worlds) instead of a map."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from torchnav.config import ConfigError
from torchnav.envs import make_env
from torchnav.sim import disc_clearance
from torchnav.tasks import CurriculumState, NavConfig, NavTask
from torchnav.worlds import slot_counts

FAMILIES = {"rooms": 1.0, "forest": 1.0, "map:maze": 0.5}


def task(num_envs: int = 6, **worlds) -> NavTask:
    return NavTask(NavConfig.from_dict({"worlds": {"families": FAMILIES, **worlds}}), num_envs)


def cur(t: NavTask) -> CurriculumState:
    return CurriculumState.initial(t.cfg.curriculum)


def test_episodes_bring_their_own_worlds_of_fixed_shapes():
    t = task()
    s, _ = t.initial_state(cur(t), torch.Generator().manual_seed(0))
    slots = slot_counts(list(FAMILIES))
    assert t.spec is None and s.world.segments.shape == (6, slots["segments"], 4) and s.world.circles.shape[1] == slots["circles"]
    assert (disc_clearance(s.sim.pose, s.world, t.cfg.robot.radius) > 0).all() and not s.sim.collided.any()
    assert torch.equal(s.start, s.sim.pose) and (s.goal_dist > 0).all()
    # different envs, different worlds
    assert not torch.equal(s.world.segments[0], s.world.segments[1]) or not torch.equal(s.world.circles[0], s.world.circles[1])


def test_partial_reset_regenerates_only_the_masked_envs():
    t = task()
    g = torch.Generator().manual_seed(1)
    s, c = t.initial_state(cur(t), g)
    mask = torch.tensor([True, False, False, True, False, False])
    r, _ = t.reset(s, mask, c, g)
    keep = ~mask
    for key in ("segments", "segment_mask", "circles", "circle_mask", "boxes", "box_mask"):
        assert torch.equal(getattr(r.world, key)[keep], getattr(s.world, key)[keep])
        assert getattr(r.world, key).shape == getattr(s.world, key).shape
    assert torch.equal(r.sim.pose[keep], s.sim.pose[keep]) and not torch.equal(r.goal[mask], s.goal[mask])


def test_episode_pool_hands_out_generated_episodes():
    t = NavTask(NavConfig.from_dict({"worlds": {"families": {"open": 1.0}}, "reset": {"pool": 8}}), 4)
    g = torch.Generator().manual_seed(2)
    s, c = t.initial_state(cur(t), g)
    for _ in range(3):
        s, c = t.reset(s, torch.tensor([True, True, False, True]), c, g)
        assert not s.sim.collided.any()


def test_env_with_worlds_meets_the_torchrl_contract_and_the_map_path_is_unchanged():
    env = make_env("arena", num_envs=4, seed=0, worlds={"families": {"corridors": 1.0}, "difficulty": 0.3})
    check_env_specs(env)
    td = env.rollout(20, break_when_any_done=False)
    assert td["next", "reward"].shape == (4, 20, 1)
    assert make_env("arena", num_envs=2).task.spec.name == "arena"


def test_bad_worlds_config_names_the_key():
    with pytest.raises(ConfigError, match=r"worlds.difficulty must be in \[0, 1\]"):
        NavConfig.from_dict({"worlds": {"families": {"rooms": 1.0}, "difficulty": 1.2}})
    with pytest.raises(ConfigError, match="worlds.families weights"):
        NavConfig.from_dict({"worlds": {"families": {"rooms": -1.0}}})
    with pytest.raises(ConfigError, match="worlds.families: unknown world family 'room'"):
        task(families={"room": 1.0})
