"""Resets from a pool of pre-sampled episodes (reset.pool > 0)."""

import torch

from torchnav.tasks import CurriculumState, EpisodePool, NavConfig, NavTask


def _run(pool: int, seed: int = 0, steps: int = 6):
    task = NavTask(NavConfig.from_dict({"map": "arena", "reset": {"pool": pool}}), 16)
    gen = torch.Generator().manual_seed(seed)
    state, cur = task.initial_state(CurriculumState.initial(task.cfg.curriculum), gen)
    pool = EpisodePool()
    history = []
    mask_gen = torch.Generator().manual_seed(123)  # the same masks whatever the sampler draws
    for i in range(steps):
        mask = torch.rand(16, generator=mask_gen) < 0.4
        before = state
        state, cur = task.reset(state, mask, cur, gen, pool)
        # envs not reset are bit-identical; reset ones got fresh, collision-free episodes
        assert torch.equal(state.sim.pose[~mask], before.sim.pose[~mask])
        assert torch.equal(state.world.boxes[~mask], before.world.boxes[~mask])
        assert (state.steps[mask] == 0).all()
        assert not state.sim.collided.any()
        history.append((state.start.clone(), state.goal.clone(), int(cur.placements)))
    return history, pool


def test_pool_resets_are_valid_and_reproducible():
    h1, pool = _run(pool=8)
    h2, _ = _run(pool=8)
    for (s1, g1, p1), (s2, g2, p2) in zip(h1, h2):
        assert torch.equal(s1, s2) and torch.equal(g1, g2) and p1 == p2
    # placements count every reset env, pool or not
    h0, _ = _run(pool=0)
    assert [p for *_, p in h0] == [p for *_, p in h1]
    # the pool refills when it runs short (a request larger than the pool is served too)
    assert pool.episodes is not None and pool.passes == 1 and pool.pos > 0


def test_pool_request_larger_than_pool():
    task = NavTask(NavConfig.from_dict({"map": "empty", "reset": {"pool": 2}}), 8)
    gen = torch.Generator().manual_seed(1)
    state, cur = task.initial_state(CurriculumState.initial(task.cfg.curriculum), gen)
    state, cur = task.reset(state, torch.ones(8, dtype=torch.bool), cur, gen, EpisodePool())
    assert state.batch_size == torch.Size([8]) and not state.sim.collided.any()
    # distinct episodes, not one copied 8 times
    assert state.start[:, :2].unique(dim=0).shape[0] == 8


def test_pool_reuse_serves_each_episode_k_times_then_refills():
    task = NavTask(NavConfig.from_dict({"map": "arena", "reset": {"pool": 6, "reuse": 3}}), 2)
    gen = torch.Generator().manual_seed(2)
    state, cur = task.initial_state(CurriculumState.initial(task.cfg.curriculum), gen)
    goals, pool = [], EpisodePool()
    for _ in range(12):  # 2 envs a reset: 3 resets per pass, 3 passes per pool, then a new pool
        state, cur = task.reset(state, torch.ones(2, dtype=torch.bool), cur, gen, pool)
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


def test_a_pooled_task_needs_its_pool_and_a_plain_one_ignores_it():
    import pytest

    task = NavTask(NavConfig.from_dict({"map": "arena", "reset": {"pool": 4}}), 2)
    gen = torch.Generator().manual_seed(3)
    state, cur = task.initial_state(CurriculumState.initial(task.cfg.curriculum), gen)
    assert task.pooled
    with pytest.raises(ValueError, match="pass pool=EpisodePool"):
        task.reset(state, torch.ones(2, dtype=torch.bool), cur, gen)
    plain = NavTask(NavConfig.from_dict({"map": "arena"}), 2)
    pool = EpisodePool()
    plain.reset(state, torch.ones(2, dtype=torch.bool), cur, gen, pool)
    assert not plain.pooled and pool.episodes is None


def test_env_pool_is_public_state_saved_with_the_env():
    """NavEnv owns its pool (``env.pool``); a full reset starts a new one; it round-trips through state_dict."""
    from torchnav.envs import make_nav_env

    env = make_nav_env("arena", 4, seed=1, max_steps=3, reset={"pool": 6})
    env.rollout(7, break_when_any_done=False)
    assert env.pool.episodes is not None and env.pool.episodes.batch_size == (6,) and env.pool.pos > 0
    sd = env.state_dict()["_extra_state"]["pool"]
    assert sd["pos"] == env.pool.pos and sd["passes"] == env.pool.passes
    other = make_nav_env("arena", 4, seed=2, max_steps=3, reset={"pool": 6})
    other.load_state_dict(env.state_dict())
    assert (other.pool.pos, other.pool.passes) == (env.pool.pos, env.pool.passes)
    assert torch.equal(other.pool.episodes.goal, env.pool.episodes.goal)
    env.reset()
    assert env.pool.episodes is None and env.pool.pos == 0
