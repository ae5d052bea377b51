"""The pure step: purity, determinism, batch independence, input validation, compile and CUDA."""

from __future__ import annotations

import math

import pytest
import torch

from params import lidar_params, sim_params
from reference import random_world
from torchnav.sim import SimState, init_state, make_world, step, wheels_to_unicycle

F64 = torch.float64
NOISY = sim_params(
    odom_v_noise=0.05,
    odom_omega_noise=0.05,
    lin_acc_max=2.0,
    ang_acc_max=5.0,
    lidar=lidar_params(n_rays=16, fov=2 * math.pi, noise_std=0.02, max_range=6.0),
)
FIELDS = ("pose", "vel", "odom", "ranges", "clearance", "collided", "time")


def setup(batch=5, dtype=torch.float32, seed=0):
    world = random_world(batch, (2, 3, 3), seed=seed, dtype=dtype)
    g = torch.Generator().manual_seed(seed)
    pose = (torch.rand(batch, 3, generator=g) * 6 - 3).to(dtype)
    actions = (torch.rand(12, batch, 2, generator=g) * 2 - 1).to(dtype)  # (T, B, 2)
    return init_state(pose, world, NOISY), world, actions


def assert_states_equal(a: SimState, b: SimState, atol=0.0):
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        assert x.shape == y.shape and x.dtype == y.dtype, f
        if atol == 0.0 or x.dtype == torch.bool:
            assert torch.equal(x, y), f
        else:
            torch.testing.assert_close(x, y, atol=atol, rtol=0, msg=f)


def test_step_does_not_modify_its_inputs():
    state, world, actions = setup()
    state_before, world_before, action_before = state.clone(), world.clone(), actions[0].clone()
    new = step(state, actions[0], world, NOISY, generator=torch.Generator().manual_seed(0))
    assert_states_equal(state, state_before)
    for f in ("segments", "segment_mask", "circles", "circle_mask", "boxes", "box_mask"):
        assert torch.equal(getattr(world, f), getattr(world_before, f))
    assert torch.equal(actions[0], action_before)
    assert not torch.equal(new.pose, state.pose)
    torch.testing.assert_close(new.time, state.time + NOISY.dt)


def test_same_generator_seed_same_rollout():
    def run(seed):
        state, world, actions = setup()
        g = torch.Generator().manual_seed(seed)
        for a in actions:
            state = step(state, a, world, NOISY, generator=g)
        return state

    a, b, c = run(11), run(11), run(12)
    assert_states_equal(a, b)
    assert not torch.equal(a.odom, c.odom) and not torch.equal(a.ranges, c.ranges)
    assert torch.equal(a.pose, c.pose)  # noise only reaches odometry and lidar


@pytest.mark.parametrize("dtype,atol", [(torch.float32, 1e-6), (F64, 0.0)], ids=["f32", "f64"])
def test_batch_equals_envs_stepped_one_at_a_time(dtype, atol):
    batch = 5
    state, world, actions = setup(batch, dtype)
    params = sim_params(lin_acc_max=2.0, lidar=lidar_params(n_rays=16, fov=2 * math.pi, max_range=6.0))
    state = init_state(state.pose, world, params)
    singles = [state[i : i + 1] for i in range(batch)]
    for a in actions:
        state = step(state, a, world, params)
        singles = [step(s, a[i : i + 1], world[i : i + 1], params) for i, s in enumerate(singles)]
    assert bool(state.collided.any()) or bool((state.ranges < 6.0).any())  # something was in range
    assert_states_equal(state, torch.cat(singles), atol=atol)


def test_mismatches_raise_value_error_naming_the_argument():
    state, world, actions = setup(batch=3)
    a = actions[0]
    with pytest.raises(ValueError, match="action"):
        step(state, torch.zeros(3, 3), world, NOISY)
    with pytest.raises(ValueError, match="action"):
        step(state, torch.zeros(2, 2), world, NOISY)
    with pytest.raises(ValueError, match="action.*dtype"):
        step(state, a.double(), world, NOISY)
    with pytest.raises(ValueError, match="action.*meta"):
        step(state, a.to("meta"), world, NOISY)
    with pytest.raises(TypeError, match="action"):
        step(state, a.tolist(), world, NOISY)
    with pytest.raises(ValueError, match="world.segments.*dtype"):
        step(state, a, random_world(3, (2, 3, 3), seed=0, dtype=F64), NOISY)
    with pytest.raises(ValueError, match=r"world.segments.*\(3, N, 4\)"):
        step(state, a, world[:2], NOISY)
    bad = world.clone()
    bad.circles = bad.circles[..., :2]
    with pytest.raises(ValueError, match=r"world.circles.*\(3, N, 3\)"):
        step(state, a, bad, NOISY)
    with pytest.raises(ValueError, match="world.segments.*meta"):
        step(state, a, world.to("meta"), NOISY)
    bad = world.clone()
    bad.box_mask = bad.box_mask.float()
    with pytest.raises(ValueError, match="world.box_mask"):
        step(state, a, bad, NOISY)


def test_init_state_validates():
    world = make_world(2, circles=[[2.0, 0.0, 0.5]])
    ok = init_state(torch.zeros(2, 3), world, NOISY)
    assert ok.batch_size == torch.Size([2]) and ok.ranges.shape == (2, 16)
    assert torch.equal(ok.odom, ok.pose) and ok.time.eq(0).all() and ok.vel.eq(0).all()
    with pytest.raises(ValueError, match="pose"):
        init_state(torch.zeros(2, 2), world, NOISY)
    with pytest.raises(ValueError, match="pose"):
        init_state(torch.zeros(3), world, NOISY)
    with pytest.raises(ValueError, match=r"world.segments.*\(3, N, 4\)"):
        init_state(torch.zeros(3, 3), world, NOISY)
    with pytest.raises(ValueError, match="world.segments.*dtype"):
        init_state(torch.zeros(2, 3, dtype=F64), world, NOISY)
    with pytest.raises(ValueError, match="vel"):
        init_state(torch.zeros(2, 3), world, NOISY, vel=torch.zeros(2, 3))
    with pytest.raises(ValueError, match="vel"):
        init_state(torch.zeros(2, 3), world, NOISY, vel=torch.zeros(2, 2, dtype=F64))
    moving = init_state(torch.zeros(2, 3), world, NOISY, vel=torch.tensor([[0.3, 0.1], [0.0, 0.0]]))
    assert moving.vel.tolist() == [pytest.approx([0.3, 0.1]), [0.0, 0.0]]


def test_non_finite_actions_stop_and_keep_state_finite():
    world = make_world(3, boxes=[[2.0, 0.0, 0.5, 0.5, 0.2]])
    state = init_state(torch.zeros(3, 3), world, sim_params())
    state = step(state, torch.full((3, 2), 0.3), world, sim_params())
    bad = torch.tensor([[math.nan, 0.3], [math.inf, -math.inf], [math.nan, math.nan]])
    new = step(state, bad, world, sim_params())
    for f in FIELDS[:-2]:
        assert torch.isfinite(getattr(new, f)).all(), f
    torch.testing.assert_close(new.vel, torch.tensor([[0.0, 0.3], [0.0, 0.0], [0.0, 0.0]]))
    assert torch.equal(new.pose[1:, :2], state.pose[1:, :2])  # stopped


def test_a_non_finite_command_waits_in_the_delay_queue_as_a_stop():
    """With an actuator delay the command of two steps ago is applied: a NaN one is a stop when it comes due, and the
    queue holding it stays finite (the 1e9-step soak found NaN there)."""
    from torchnav.sim.randomize import nominal_env_params

    world = make_world(2)
    params = sim_params()
    ep = nominal_env_params(params, 2, torch.zeros(2))
    ep = ep.replace(delay=torch.tensor([2, 2]))
    state = init_state(torch.zeros(2, 3), world, params, env_params=ep, delay_steps=2)
    go = torch.tensor([[0.3, 0.0], [0.3, 0.0]])
    for a in (go, torch.tensor([[math.nan, math.nan], [0.3, 0.0]]), go, go):
        state = step(state, a, world, params, env_params=ep)
        assert torch.isfinite(state.cmd_queue).all()
    # the 4th step applies the 2nd command: env 0's NaN, a stop; env 1 drives on
    torch.testing.assert_close(state.vel, torch.tensor([[0.0, 0.0], [0.3, 0.0]]))


def test_wheel_speed_actions():
    params = sim_params(track_width=0.4)
    world = make_world(2, segments=[[3.0, -3.0, 3.0, 3.0]], dtype=F64)
    state = init_state(torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5]], dtype=F64), world, params)
    wheels = torch.tensor([[0.2, 0.4], [-0.1, 0.1]], dtype=F64)
    by_wheels = step(state, wheels, world, params, wheel_speeds=True)
    by_twist = step(state, wheels_to_unicycle(wheels, 0.4), world, params)
    assert_states_equal(by_wheels, by_twist)
    torch.testing.assert_close(by_wheels.vel, torch.tensor([[0.3, 0.5], [0.0, 0.5]], dtype=F64))
    assert torch.equal(by_wheels.pose[1, :2], state.pose[1, :2])  # opposite wheels spin in place


def test_driving_into_a_wall_collides():
    params = sim_params(robot_radius=0.2, v_max=0.5, dt=0.1)
    world = make_world(1, segments=[[1.0, -1.0, 1.0, 1.0]])
    state = init_state(torch.zeros(1, 3), world, params)
    flags = []
    for _ in range(20):
        state = step(state, torch.tensor([[0.5, 0.0]]), world, params)
        flags.append(bool(state.collided))
    # The disc front reaches x = 1 at x = 0.8, i.e. after 16 steps of 0.05 m.
    assert flags.index(True) in (15, 16) and all(flags[flags.index(True) :])
    torch.testing.assert_close(state.time, torch.tensor([2.0]))


def _rollout(step_fn, state, world, actions, params):
    out = []
    for a in actions:
        state = step_fn(state, a, world, params)
        out.append(state)
    return out


def _compile_case():
    params = sim_params(lin_acc_max=2.0, lidar=lidar_params(n_rays=16, fov=2 * math.pi, max_range=6.0))
    state, world, actions = setup(batch=8, dtype=F64)
    state = init_state(state.pose, world, params)
    # One eager step first: init_state's odom aliases its pose, which would cost a recompile.
    state = step(state, actions[0], world, params)
    return state, world, actions[1:4], params


def test_step_traces_as_one_graph():
    """Dynamo captures the whole step without graph breaks (cheap: no code generation)."""
    torch._dynamo.reset()
    state, world, actions, params = _compile_case()
    eager = _rollout(step, state, world, actions, params)
    traced = _rollout(torch.compile(step, backend="eager", fullgraph=True), state, world, actions, params)
    for e, c in zip(eager, traced):
        assert_states_equal(c, e)


@pytest.mark.slow
def test_torch_compile_matches_eager():
    """Inductor-compiled step on a batch of 8 (about 30 s of cold compilation on 2 CPU cores)."""
    torch._dynamo.reset()
    state, world, actions, params = _compile_case()
    eager = _rollout(step, state, world, actions, params)
    compiled = _rollout(torch.compile(step, fullgraph=True), state, world, actions, params)
    for e, c in zip(eager, compiled):
        assert_states_equal(c, e, atol=1e-9)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_cuda_step_matches_cpu():
    state, world, actions = setup(batch=64, dtype=F64)
    params = sim_params(lin_acc_max=2.0, lidar=lidar_params(n_rays=32, fov=2 * math.pi, max_range=6.0))
    state = init_state(state.pose, world, params)
    cpu = _rollout(step, state, world, actions, params)[-1]
    gpu_state = init_state(state.pose.cuda(), world.to("cuda"), params)
    gpu = _rollout(step, gpu_state, world.to("cuda"), actions.cuda(), params)[-1]
    assert gpu.pose.is_cuda and gpu.ranges.is_cuda
    assert_states_equal(gpu.to("cpu"), cpu, atol=1e-9)
