"""Resets from a pool of pre-sampled episodes (reset.pool > 0)."""

import torch

from torchnav.tasks import CurriculumState, NavConfig, NavTask


def _run(pool: int, seed: int = 0, steps: int = 6):
    task = NavTask(NavConfig.from_dict({"map": "arena", "reset": {"pool": pool}}), 16)
    gen = torch.Generator().manual_seed(seed)
    state, cur = task.initial_state(CurriculumState.initial(task.cfg.curriculum), gen)
    history = []
    mask_gen = torch.Generator().manual_seed(123)  # the same masks whatever the sampler draws
    for i in range(steps):
        mask = torch.rand(16, generator=mask_gen) < 0.4
        before = state
        state, cur = task.reset(state, mask, cur, gen)
        # envs not reset are bit-identical; reset ones got fresh, collision-free episodes
        assert torch.equal(state.sim.pose[~mask], before.sim.pose[~mask])
        assert torch.equal(state.world.boxes[~mask], before.world.boxes[~mask])
        assert (state.steps[mask] == 0).all()
        assert not state.sim.collided.any()
        history.append((state.start.clone(), state.goal.clone(), int(cur.placements)))
    return history, task


def test_pool_resets_are_valid_and_reproducible():
    h1, task = _run(pool=8)
    h2, _ = _run(pool=8)
    for (s1, g1, p1), (s2, g2, p2) in zip(h1, h2):
        assert torch.equal(s1, s2) and torch.equal(g1, g2) and p1 == p2
    # placements count every reset env, pool or not
    h0, _ = _run(pool=0)
    assert [p for *_, p in h0] == [p for *_, p in h1]
    # the pool refills when it runs short (a request larger than the pool is served too)
    assert task._pool is not None


def test_pool_request_larger_than_pool():
    task = NavTask(NavConfig.from_dict({"map": "empty", "reset": {"pool": 2}}), 8)
    gen = torch.Generator().manual_seed(1)
    state, cur = task.initial_state(CurriculumState.initial(task.cfg.curriculum), gen)
    state, cur = task.reset(state, torch.ones(8, dtype=torch.bool), cur, gen)
    assert state.batch_size == torch.Size([8]) and not state.sim.collided.any()
    # distinct episodes, not one copied 8 times
    assert state.start[:, :2].unique(dim=0).shape[0] == 8


def test_pool_reuse_serves_each_episode_k_times_then_refills():
    task = NavTask(NavConfig.from_dict({"map": "arena", "reset": {"pool": 6, "reuse": 3}}), 2)
    gen = torch.Generator().manual_seed(2)
    state, cur = task.initial_state(CurriculumState.initial(task.cfg.curriculum), gen)
    goals = []
    for _ in range(12):  # 2 envs a reset: 3 resets per pass, 3 passes per pool, then a new pool
        state, cur = task.reset(state, torch.ones(2, dtype=torch.bool), cur, gen)
        goals.append(state.goal.clone())
    first = [torch.cat(goals[3 * p:3 * p + 3]) for p in range(4)]
    key = lambda g: sorted(map(tuple, g.tolist()))  # noqa: E731
    # passes 2 and 3 hand out exactly the episodes of pass 1, in another order; pass 4 is a new pool
    assert key(first[0]) == key(first[1]) == key(first[2])
    assert not torch.equal(first[0], first[1]) or not torch.equal(first[1], first[2])
    assert key(first[3]) != key(first[0])


def test_pool_reuse_is_validated():
    import pytest

    from torchnav.config import ConfigError

    with pytest.raises(ConfigError, match="reset.reuse=0: must be an integer >= 1"):
        NavConfig.from_dict({"reset": {"pool": 8, "reuse": 0}})
    with pytest.raises(ConfigError, match="reset.reuse > 1 needs a pool"):
        NavConfig.from_dict({"reset": {"reuse": 4}})
