"""Analytic policy gradients (recipes/apg_lidar.py): the horizon loss's gradient against finite
differences, the critic's TD(lambda) targets, and finite gradients over a long run with collisions.
The recipe's end-to-end runs are in tests/test_recipes.py."""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from tensordict import TensorDict

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "recipes"))
import apg_lidar  # noqa: E402

from torchnav.config import merge, to_dict  # noqa: E402
from torchnav.envs import NavEnv  # noqa: E402
from torchnav.policy import Actor  # noqa: E402
from torchnav.tasks import NavConfig, NavTask  # noqa: E402
from torchnav.train_config import NavSmoothConfig  # noqa: E402

SMOOTH = NavSmoothConfig(ramp_frames=0, contact=-10.0, contact_margin=0.3)


def nav_env(num_envs: int, dtype=torch.float32, seed: int = 0, **overrides) -> NavEnv:
    cfg = NavConfig.from_dict(merge(to_dict(NavConfig()), {"map": "arena", "curriculum": {"mode": "off"}, **overrides}))
    env = NavEnv(cfg, num_envs=num_envs, seed=seed)
    if dtype != torch.float32:
        env.task = NavTask(cfg, num_envs, dtype=dtype)
    env.reset()
    return env


def test_horizon_loss_gradient_matches_finite_differences():
    """d(horizon loss)/d(policy parameters), backpropagated through 6 steps of the simulator (lidar
    against walls and boxes, clearance, goal distance) and the critic at the horizon's end, against
    central differences along random directions, in float64."""
    torch.manual_seed(0)
    env = nav_env(4, torch.float64, max_steps=500)
    start = env.state_dict()  # episodes, generator, curriculum: every loss starts from them
    policy = Actor(env.task.obs_size, 2, [16], "tanh", output="linear").double()
    value = Actor(env.task.obs_size, 1, [16], "tanh", output="linear").double().requires_grad_(False)
    smooth = apg_lidar.make_smooth("nav", SMOOTH, env)
    params = list(policy.parameters())

    def loss() -> torch.Tensor:
        env.load_state_dict(start)
        torch.manual_seed(1)  # the same exploration noise every time
        batch = apg_lidar.rollout(env, policy, value, smooth, 6, 0.99, 0.2, ("success", "collision"))
        assert not batch["next", "done"].any(), "an episode ended inside the horizon: pick other starts"
        return apg_lidar.horizon_loss(batch)

    grads = torch.autograd.grad(loss(), params)
    assert all(torch.isfinite(g).all() for g in grads) and sum(g.abs().sum() for g in grads) > 0
    gen_dir = torch.Generator().manual_seed(2)
    for _ in range(3):
        dirs = [torch.randn(p.shape, generator=gen_dir, dtype=p.dtype) for p in params]
        analytic = sum((g * d).sum() for g, d in zip(grads, dirs))
        eps = 1e-6
        with torch.no_grad():
            for p, d in zip(params, dirs):
                p.add_(eps * d)
            up = loss()
            for p, d in zip(params, dirs):
                p.sub_(2 * eps * d)
            down = loss()
            for p, d in zip(params, dirs):
                p.add_(eps * d)
        numeric = (up - down) / (2 * eps)
        assert torch.allclose(analytic, numeric, rtol=1e-5, atol=1e-8), (float(analytic), float(numeric))


def test_lambda_returns_by_hand():
    """TD(lambda) targets: a terminal event cuts the bootstrap, the last step bootstraps fully."""
    g, lam = 0.5, 0.5
    reward = torch.tensor([[1.0, 2.0, 3.0]])
    boot = torch.tensor([[10.0, 0.0, 20.0]])  # step 1 ended in a terminal event: its bootstrap is 0
    done = torch.tensor([[False, True, False]])
    out = apg_lidar.lambda_returns(reward, boot, done, g, lam)
    g2 = 3.0 + g * 20.0
    g1 = 2.0 + g * 0.0
    g0 = 1.0 + g * ((1 - lam) * 10.0 + lam * g1)
    assert torch.allclose(out, torch.tensor([[g0, g1, g2]]))


def test_action_reg_pulls_the_pre_tanh_actions_towards_zero():
    """``horizon_loss(batch, action_reg)`` adds ``action_reg * mean(loc^2)``: with the return's share
    zeroed, one gradient step shrinks every saturated pre-tanh action."""
    loc = torch.tensor([[[3.0, -2.5], [2.0, 0.5]]], requires_grad=True)  # (N=1, H=2, 2)
    batch = TensorDict({"apg": torch.zeros(1, 2), "loc": loc}, batch_size=[1, 2])
    assert apg_lidar.horizon_loss(batch) == 0.0
    loss = apg_lidar.horizon_loss(batch, action_reg=0.5)
    assert torch.isclose(loss, 0.5 * loc.detach().square().mean())
    (grad,) = torch.autograd.grad(loss, loc)
    assert torch.allclose(grad, 0.5 * 2 * loc.detach() / loc.numel())
    assert ((loc - grad).abs() < loc.abs()).all()


def test_long_run_with_collisions_stays_finite():
    """16 horizons of 32 steps with a policy that drives into things: many collisions and resets
    inside horizons, yet every loss, gradient and state stays finite."""
    torch.manual_seed(0)
    env = nav_env(32, seed=3, max_steps=200)
    policy = Actor(env.task.obs_size, 2, [32, 32], "tanh", output="linear")
    value = Actor(env.task.obs_size, 1, [32, 32], "tanh", output="linear").requires_grad_(False)
    with torch.no_grad():
        policy.net[-1].bias.copy_(torch.tensor([3.0, 0.3]))  # full speed, a gentle turn: walls and boxes get hit
    smooth = apg_lidar.make_smooth("nav", SMOOTH, env)
    opt = torch.optim.Adam(policy.parameters(), lr=1e-3)
    collisions = 0
    for _ in range(16):
        batch = apg_lidar.rollout(env, policy, value, smooth, 32, 0.99, 0.3, ("success", "collision"))
        loss = apg_lidar.horizon_loss(batch)
        opt.zero_grad()
        loss.backward()
        assert torch.isfinite(loss)
        assert all(torch.isfinite(p.grad).all() for p in policy.parameters())
        opt.step()
        collisions += int(batch["next", "collision"].sum())
        assert torch.isfinite(batch["observation"]).all() and torch.isfinite(batch["reward"]).all()
    assert collisions > 50, collisions
    assert torch.isfinite(env.state.sim.pose).all() and not env.state.sim.pose.requires_grad


def test_config_is_checked_before_the_run(tmp_path):
    """APG's own keys are validated with the others, before any run directory exists."""
    import pytest

    from torchnav.config import ConfigError

    run = tmp_path / "run"
    with pytest.raises(ConfigError) as e:
        apg_lidar.main(["train.horizon=0", "smooth.contact_margin=0", "smooth.ramp_frames=-1", "train.lr_decay=maybe",
                        "smooth.contact=x", "train.action_reg=-1", f"logger.run_dir={run}"])
    for want in ("train.horizon=0: must be an integer >= 1", "smooth.contact_margin=0: must be a finite number > 0",
                 "smooth.ramp_frames=-1: must be an integer >= 0", "train.lr_decay='maybe': must be true or false",
                 "smooth.contact='x': must be a float", "train.action_reg=-1: must be a finite number >= 0"):
        assert want in str(e.value), str(e.value)
    with pytest.raises(ConfigError, match="smooth.contcat"):
        apg_lidar.main(["smooth.contcat=-1", f"logger.run_dir={run}"])
    assert not run.exists()


def test_saturation_bench_counts_full_speed_steps_and_collisions(tmp_path):
    """bench/apg_saturation.py: a policy biased to full speed and a gentle turn spends every step
    above 95% of the top speed and collides there; one biased to half speed never does."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
    import apg_saturation

    from torchnav.policy import save_policy

    cfg = merge(to_dict(NavConfig()), {"map": "arena", "curriculum": {"mode": "off"}, "max_steps": 100})
    obs_size = nav_env(1, max_steps=100).task.obs_size
    rows = {}
    for name, bias in (("fast", [3.0, 0.3]), ("half", [0.0, 0.3])):
        actor = Actor(obs_size, 2, [8], "tanh", output="tanh")
        with torch.no_grad():
            actor.net[-1].weight.zero_()
            actor.net[-1].bias.copy_(torch.tensor(bias))
        save_policy(tmp_path / f"{name}.pt", actor, task="nav", task_config=cfg, algorithm="apg")
        rows[name] = apg_saturation.measure(str(tmp_path / f"{name}.pt"), 16, 0)
    assert rows["fast"]["fast_steps"] == 1.0 and rows["fast"]["collisions"] > 0
    assert rows["fast"]["fast_collisions"] == rows["fast"]["collisions"]
    assert rows["half"]["fast_steps"] == 0.0 and rows["half"]["fast_collisions"] == 0
