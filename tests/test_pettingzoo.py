"""The PettingZoo adapter (torchnav/pettingzoo.py): PettingZoo's own API test, seeding, agents leaving."""

import numpy as np
import pytest

pytest.importorskip("pettingzoo")
from pettingzoo.test import parallel_api_test  # noqa: E402

from torchnav.pettingzoo import MultiNavParallelEnv, parallel_env  # noqa: E402


@pytest.mark.parametrize("kwargs", [{"n_robots": 3, "max_steps": 40}, {"n_robots": 4, "robots": {"min_n": 2, "scenario": "circle_swap"}, "max_steps": 30},
                                    {"n_robots": 2, "action": {"mode": "discrete"}, "max_steps": 30}])
def test_parallel_api(kwargs):
    parallel_api_test(parallel_env(**kwargs), num_cycles=100)


def test_seeded_and_agents_leave_when_done():
    runs = []
    for _ in range(2):
        env = MultiNavParallelEnv(n_robots=3, max_steps=15)
        obs, _ = env.reset(seed=7)
        trace = [np.stack([obs[a] for a in env.agents])]
        while env.agents:
            obs, rew, term, trunc, info = env.step({a: np.array([1.0, 0.3], dtype=np.float32) for a in env.agents})
            assert set(term) == set(rew) == set(info)
            for a in term:
                assert (a in env.agents) == (not (term[a] or trunc[a]))
            trace.append(np.array(sorted(rew.values())))
        runs.append(trace)
    assert len(runs[0]) == len(runs[1]) <= 16
    assert all(np.array_equal(x, y) for x, y in zip(*runs))
    assert env.state().shape == (3 * env.observation_space("robot_0").shape[0],)
