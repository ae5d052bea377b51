"""MultiNavEnv: TorchRL's multi-agent layout, specs, seeding, auto-reset and partial resets."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from torchnav.envs import MultiNavEnv, make_multi_nav_env


@pytest.mark.parametrize("num_envs,n,extra", [(1, 2, {}), (3, 4, {"min_n": 2}), (2, 8, {"scenario": "circle_swap"}),
                                                (2, 3, {"scenario": "crossing", "on_collision": "team"})])
def test_check_env_specs(num_envs, n, extra):
    env = make_multi_nav_env("arena", num_envs, n, robots=extra)
    check_env_specs(env)
    assert env.full_action_spec["agents", "action"].shape == (num_envs, n, 2)
    assert set(env.done_keys) >= {"done", ("agents", "done"), ("agents", "terminated"), ("agents", "truncated")}
    assert env.reward_key == ("agents", "reward")


def test_discrete_actions():
    env = make_multi_nav_env("arena", 2, 3, action={"mode": "discrete"})
    check_env_specs(env)
    assert env.full_action_spec["agents", "action"].shape == (2, 3, 7)


def test_same_seed_same_rollout():
    rollouts = []
    for _ in range(2):
        env = make_multi_nav_env("arena", 2, 3, seed=5, max_steps=10)
        torch.manual_seed(0)
        rollouts.append(env.rollout(25, break_when_any_done=False))
    assert (rollouts[0] == rollouts[1]).all()
    other = make_multi_nav_env("arena", 2, 3, seed=6, max_steps=10).reset()
    assert not torch.equal(other["agents", "pose"], rollouts[0][0]["agents", "pose"])


def test_rollout_auto_resets_finished_envs_only():
    env = make_multi_nav_env("arena", 4, 3, max_steps=6, robots={"min_n": 2})
    r = env.rollout(20, break_when_any_done=False)
    done = r["next", "done"][..., 0]
    length = r["next", "episode_length"][..., 0]
    assert done.any()
    assert (length <= 6).all() and done[length == 6].all()  # truncated at max_steps at the latest
    after = done[:, :-1]
    assert (r["episode_length"][:, 1:, 0][after] == 0).all()  # a finished env starts a new episode
    assert (r["episode_length"][:, 1:, 0][~after] > 0).all()  # the others go on
    # a parked robot stays terminated (and still) while its env runs on
    term = r["next", "agents", "terminated"][..., 0]
    running = ~done[:, :-1, None].expand_as(term[:, :-1])
    assert (term[:, 1:][term[:, :-1] & running]).all()


def test_partial_reset_and_state_dict():
    env = make_multi_nav_env("arena", 3, 2)
    td = env.reset()
    td["agents", "action"] = torch.ones(3, 2, 2)
    env.step(td)
    sd = env.state_dict()
    before = env.state.start.clone()
    env.reset(TensorDict({"_reset": torch.tensor([[True], [False], [False]])}, batch_size=[3]))
    assert torch.equal(env.state.start[1:], before[1:]) and not torch.equal(env.state.start[0], before[0])
    assert (env.state.steps[1:] == 1).all() and env.state.steps[0] == 0
    assert int(env.curriculum.placements) == 8  # 6 robots placed, then 2 more
    again = MultiNavEnv(env.cfg, num_envs=3)
    again.load_state_dict(sd)
    assert torch.equal(again.state.start, before) and int(again.curriculum.placements) == 6
    resumed = again.reset(set_state=True)
    assert (resumed["episode_length"][:, 0] == 1).all()


def test_bad_action_shape_is_named():
    env = make_multi_nav_env("arena", 2, 3)
    td = env.reset()
    td["agents", "action"] = torch.zeros(2, 3, 2)
    env.step(td)
    with pytest.raises(ValueError, match="3 robots"):
        env._step(TensorDict({"agents": TensorDict({"action": torch.zeros(2, 2, 2)}, batch_size=[2, 2])}, batch_size=[2]))


def test_torchrl_multi_agent_policy_runs_on_any_robot_count():
    """TorchRL's MultiAgentMLP runs on the agent group; a parameter-shared network made for 4 robots
    steps envs of 2 and 8 robots too: the observation's size does not depend on N."""
    from tensordict.nn import TensorDictModule
    from torchrl.modules import MLP, MultiAgentMLP

    sizes = {n: make_multi_nav_env("arena", 2, n).task.obs_size for n in (2, 4, 8)}
    assert len(set(sizes.values())) == 1
    mappo = MultiAgentMLP(n_agent_inputs=sizes[4], n_agent_outputs=2, n_agents=4, centralised=False, share_params=True, depth=1, num_cells=16)
    shared = MLP(in_features=sizes[4], out_features=2, depth=1, num_cells=16)  # one network for every robot, any count
    for net, counts in ((mappo, (4,)), (shared, (2, 4, 8))):
        policy = TensorDictModule(torch.nn.Sequential(net, torch.nn.Tanh()), in_keys=[("agents", "observation")], out_keys=[("agents", "action")])
        for n in counts:
            env = make_multi_nav_env("arena", 2, n, max_steps=5)
            with torch.no_grad():
                r = env.rollout(8, policy, break_when_any_done=False)
            assert r["agents", "action"].shape == (2, 8, n, 2) and r["agents", "action"].abs().max() <= 1
            assert r["next", "done"].any()  # went through an auto-reset


def test_ranges_and_velocity_for_classical_controllers():
    # ("agents", "ranges") is each robot's raw lidar and ("agents", "velocity") its planar velocity in the world frame
    env = make_multi_nav_env("arena", 2, 3)
    td = env.reset()
    assert td["agents", "ranges"].shape == (2, 3, env.cfg.lidar.n_rays) and (td["agents", "velocity"] == 0).all()
    td["agents", "action"] = torch.tensor([1.0, 0.5]).expand(2, 3, 2)
    nxt = env.step(td)["next"]
    r = env.state.sim.robots
    assert torch.equal(nxt["agents", "ranges"], r.ranges)
    heading = r.pose[..., 2]
    assert torch.allclose(nxt["agents", "velocity"], r.vel[..., :1] * torch.stack((heading.cos(), heading.sin()), -1))
    assert torch.allclose(nxt["agents", "velocity"].norm(dim=-1), torch.full((2, 3), env.cfg.robot.v_max))
