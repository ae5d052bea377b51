"""The observation a robot's data makes (torchnav.observation) is the simulator's, for every shipped policy."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from torchrl.envs.utils import step_mdp

from torchnav.config import to_dict
from torchnav.envs import NavEnv, make_nav_env
from torchnav.observation import ObservationBuilder, PolicyDriver, Scan, command, resample_scan
from torchnav.policy import load_policy
from torchnav.sim import LidarParams, lidar_scan, make_world
from torchnav.tasks import NavConfig

CHECKPOINTS = Path(__file__).resolve().parent.parent / "checkpoints"
NAV_POLICIES = [p.name for p in sorted(CHECKPOINTS.glob("*.pt")) if load_policy(p).task == "nav"]


def test_every_navigation_checkpoint_is_covered():
    assert {"ppo_generalist_actor.pt", "td3_arena_actor.pt", "ppo_movers_actor.pt"} <= set(NAV_POLICIES)


@pytest.mark.parametrize("name", NAV_POLICIES)
def test_builder_matches_the_env(name):
    """Step a NavEnv with the policy; feed each env's ranges (as a LaserScan of the simulator's layout), pose,
    twist and goal to a builder per env: the same observation, bit for bit, and the same twist the simulator
    drives for the env's action, over episodes that end and restart. A policy trained on a randomised robot
    (ppo_generalist_jackal_actor) drives its robot without the randomisation, the acceleration limits and
    the delay here: the builder has no episode's draw to know, and its queue under a delay is tested below."""
    sp = load_policy(CHECKPOINTS / name)
    trained = sp.config()
    d = to_dict(trained)
    if any(v is not None for v in d["randomize"].values()) or math.isfinite(trained.robot.lin_acc_max) or math.isfinite(trained.robot.ang_acc_max):
        d = {**d, "randomize": {}, "robot": {**d["robot"], "preset": "default", "lin_acc_max": math.inf, "ang_acc_max": math.inf}}
    # Pooled episodes (the generalists') compute their first observation in refills of the pool's size. On
    # a batch that long torch's atan2 runs vectorised and rounds 16% of its results a bit off the scalar
    # atan2 a builder's batch of one runs; refills of 8 stay scalar, so the comparison can be bit for bit.
    cfg = NavConfig.from_dict({**d, "reset": {**d["reset"], "pool": min(d["reset"]["pool"], 8)}})
    assert (cfg.robot.radius, cfg.robot.v_max) == (trained.robot.radius, trained.robot.v_max)  # its body and speeds
    n, steps = 3, 240
    env = NavEnv(cfg, num_envs=n, seed=7)
    builders = [ObservationBuilder(cfg) for _ in range(n)]
    driver = PolicyDriver(sp)
    lidar = cfg.sim_params().lidar
    td = env.reset()
    resets = guarded = 0
    with torch.no_grad():
        for _ in range(steps):
            vel = env.state.sim.vel
            for b in range(n):
                scan = Scan.of_sim(td["ranges"][b].tolist(), lidar)
                obs = builders[b].observe(scan, td["pose"][b].tolist(), vel[b].tolist(), td["goal"][b].tolist())
                assert torch.equal(obs, td["observation"][b]), (name, b)
            # The driver (builder and network, batch of one) on env 0: the env's action up to the batch's rounding.
            driver.act(Scan.of_sim(td["ranges"][0].tolist(), lidar), td["pose"][0].tolist(), vel[0].tolist(), td["goal"][0].tolist())
            td = sp.policy(td)
            torch.testing.assert_close(driver.action.float(), td["action"][0].float(), atol=1e-5, rtol=0)
            td = env.step(td)
            applied = env.state.sim.vel  # what the simulator drove (no noise, no delay in these tasks)
            for b in range(n):
                v, w = builders[b].twist(td["action"][b])
                assert (v, w) == (float(applied[b, 0]), float(applied[b, 1])), (name, b)
                guarded += v < float(command(cfg, td["action"][b:b + 1], builders[b].twists)[0, 0]) - 1e-6
            done = td["next", "done"].reshape(-1)
            for b in done.nonzero().flatten().tolist():
                builders[b].reset()
                resets += 1
                if b == 0:
                    driver.reset()
            td = env.maybe_reset(step_mdp(td))
    assert resets >= 2, f"{name}: the run should cross episode ends (got {resets})"
    if cfg.action.stop_clearance is not None:
        assert guarded > 0, f"{name}: the speed guard never capped a command"


LIDAR = LidarParams(n_rays=20, fov=math.pi, min_range=0.0, max_range=10.0, offset=(0.0, 0.0, 0.0), noise_std=0.0, scan="rays",
                    window=2, dense_slots=64)


def test_denser_scan_takes_the_minimum_of_each_bin():
    """A real scan four times as fine: each simulated ray reads the nearest of the beams within half a
    ray spacing of it; with the simulator's rays among them and the others farther, exactly its ranges."""
    sim = torch.linspace(1.0, 9.0, 20)
    spacing = math.pi / 19
    inc = spacing / 4
    dense = [float(sim[j]) if i % 4 == 0 else 9.5 for j in range(20) for i in range(4)][:77]
    got, unseen = resample_scan(Scan(dense, -math.pi / 2, inc, 0.05, 12.0), LIDAR)
    assert torch.equal(got, sim) and not unseen.any()
    dense[5] = 0.5  # beam 5 lies 1.25 spacings past ray 0: ray 1's bin
    assert resample_scan(Scan(dense, -math.pi / 2, inc, 0.05, 12.0), LIDAR)[0][1] == 0.5


def test_rep117_readings():
    """+inf: no return (max_range); -inf: too close (min_range); NaN and readings outside the message's
    [range_min, range_max] (0 from many drivers): ignored; a bin with nothing valid reads max_range."""
    base = [5.0] * 20
    cases = {0: (math.inf, 10.0), 1: (-math.inf, 0.0), 2: (math.nan, 10.0), 3: (0.0, 10.0), 4: (30.0, 10.0), 5: (11.0, 10.0)}
    ranges = list(base)
    for j, (r, _) in cases.items():
        ranges[j] = r
    got, _ = resample_scan(Scan(ranges, -math.pi / 2, math.pi / 19, 0.05, 12.0), LIDAR)
    for j, (_, want) in cases.items():
        assert float(got[j]) == want, (j, ranges[j])
    assert torch.equal(got[6:], torch.full((14,), 5.0))


def test_other_orientation_and_field_of_view():
    """A 360-degree scan starting straight ahead (a TurtleBot3's LDS) gives the simulator's 180-degree layout;
    a coarser scan fills bins from the nearest beam; a narrower one flags the bins it does not see."""
    sim = torch.arange(20, dtype=torch.float32) * 0.4 + 1.0
    angles = torch.tensor(LIDAR.angles(), dtype=torch.float64)
    n = 360
    beams = torch.full((n,), 9.0, dtype=torch.float64)  # farther than every simulated reading
    for j in range(20):
        beams[int(round(float(angles[j] % (2 * math.pi)) / (2 * math.pi / n))) % n] = float(sim[j])
    got, unseen = resample_scan(Scan(beams.tolist(), 0.0, 2 * math.pi / n, 0.1, 9.0), LIDAR)
    assert torch.equal(got, sim) and not unseen.any()
    coarse, _ = resample_scan(Scan(sim[::2].tolist(), -math.pi / 2, 2 * math.pi / 19, 0.0, 10.0), LIDAR)
    assert torch.equal(coarse[::2], sim[::2])
    narrow, unseen = resample_scan(Scan(sim[5:15].tolist(), float(angles[5]), math.pi / 19, 0.0, 10.0), LIDAR)
    assert torch.equal(narrow[5:15], sim[5:15])
    assert unseen.tolist() == [True] * 5 + [False] * 10 + [True] * 5 and (narrow[unseen] == 10.0).all()


def test_dense_rays_converge_to_the_exact_sector_scan():
    """The generalist's exact sector scan (36 wedges over 360 degrees) from a dense real ray scan: each
    wedge reads the nearest of its beams, which is never nearer than the exact reading and close to it."""
    world = make_world(1, segments=[(2.0, -3.0, 2.0, 3.0), (-1.0, 1.5, 1.0, 1.5)], circles=[(-2.0, -1.0, 0.4)], boxes=[(0.5, -2.0, 0.3, 0.2, 0.5)])
    pose = torch.tensor([[0.1, 0.2, 0.3]])
    exact_lidar = LidarParams(n_rays=36, fov=2 * math.pi, min_range=0.0, max_range=10.0, offset=(0.0, 0.0, 0.0), noise_std=0.0,
                              scan="sectors", window=0, dense_slots=64)
    dense_lidar = LidarParams(n_rays=3600, fov=2 * math.pi, min_range=0.0, max_range=10.0, offset=(0.0, 0.0, 0.0), noise_std=0.0,
                              scan="rays", window=2, dense_slots=64)
    exact = lidar_scan(pose, world, exact_lidar)[0]
    dense = lidar_scan(pose, world, dense_lidar)[0]
    got, unseen = resample_scan(Scan(dense.tolist(), -math.pi, 2 * math.pi / 3600, 0.0, 10.0), exact_lidar)
    assert not unseen.any()
    assert (got >= exact - 1e-5).all() and (got - exact).abs().max() < 0.02
    assert torch.equal(resample_scan(Scan.of_sim(exact.tolist(), exact_lidar), exact_lidar)[0], exact)


def test_bad_inputs_are_named():
    cfg = load_policy(CHECKPOINTS / "td3_arena_actor.pt").config()
    b = ObservationBuilder(cfg)
    scan = Scan([5.0] * 20, -math.pi / 2, math.pi / 19, 0.0, 10.0)
    with pytest.raises(ValueError, match="pose must be 3 finite"):
        b.observe(scan, (0.0, math.nan, 0.0), (0.0, 0.0), (1.0, 1.0))
    with pytest.raises(ValueError, match="goal must be 2 finite"):
        b.observe(scan, (0.0, 0.0, 0.0), (0.0, 0.0), (1.0,))
    with pytest.raises(ValueError, match="no ranges"):
        b.observe(Scan([], 0.0, 0.1, 0.0, 10.0), (0.0, 0.0, 0.0), (0.0, 0.0), (1.0, 1.0))
    with pytest.raises(ValueError, match="angle_increment"):
        b.observe(Scan([1.0, 2.0], 0.0, math.nan, 0.0, 10.0), (0.0, 0.0, 0.0), (0.0, 0.0), (1.0, 1.0))
    with pytest.raises(RuntimeError, match="no observation yet"):
        b.twist(torch.zeros(2))
    b.observe(scan, (0.0, 0.0, 0.0), (0.0, 0.0), (1.0, 1.0))
    assert b.twist(torch.tensor([math.nan, 0.5])) == (0.0, 0.5)  # a non-finite action is a stop (apply_limits)
    with pytest.raises(ValueError, match="not a navigation policy"):
        PolicyDriver(load_policy(CHECKPOINTS / "dqn_course_actor.pt"))


def test_builder_guards_the_arc_after_the_twists_it_sent():
    """With the arc guard and an actuator delay the builder's twist is the one the simulator queues, step
    after step, because it drives the twists it returned before as the simulator drives its queue; the
    guard without them would have returned other twists."""
    from torchnav.observation import guarded

    cfg_over = dict(robot={"v_max": 2.0, "omega_max": 4.0}, randomize={"delay": [2, 2]},
                    action={"stop_clearance": 0.05, "stop_path": "arc"}, max_steps=60)
    env = make_nav_env("warehouse", num_envs=1, seed=3, **cfg_over)
    builder = ObservationBuilder(env.cfg)
    assert builder.queued == 2 and builder.sent.shape == (1, 2, 2)
    g = torch.Generator().manual_seed(0)
    td = env.reset()
    capped = differs = 0
    for _ in range(300):
        builder.observe(td["ranges"][0], td["pose"][0].tolist(), env.state.sim.vel[0].tolist(), td["goal"][0].tolist())
        before = builder.sent.clone()
        td["action"] = torch.tensor([[1.0, 2 * float(torch.rand((), generator=g)) - 1]])
        td = env.step(td)
        v, w = builder.twist(td["action"][0])
        queued = env.state.sim.cmd_queue[0, 0]  # the command the simulator's guard let through this step
        assert (v, w) == (float(queued[0]), float(queued[1]))
        assert torch.equal(builder.sent[0, 0], queued) and torch.equal(builder.sent[0, 1], before[0, 0])
        plain = command(env.cfg, td["action"][:1], builder.twists)
        capped += v < float(plain[0, 0]) - 1e-6
        alone = guarded(env.cfg, plain, builder.ranges[None], builder.lidar, builder.params.robot_radius, builder.params.dt, builder.bearings)
        differs += abs(float(alone[0, 0]) - v) > 1e-6
        if bool(td["next", "done"].any()):
            builder.reset()
            assert not builder.sent.any()
        td = env.maybe_reset(step_mdp(td))
    assert capped > 0 and differs > 0
