"""The navigation task without TorchRL: reset sampling and its fallbacks, curriculum,
observation, action mapping, reward terms, termination and the differentiable step."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from torchnav.maps import load_map
from torchnav.sim import World, box_corners, init_state, point_box_distance, point_circle_distance, points_clearance, sectorize
from torchnav.tasks import (
    PRESETS,
    TERMS,
    CurriculumConfig,
    CurriculumState,
    NavConfig,
    NavTask,
    after_episodes,
    after_placements,
    resolve_weights,
)
from torchnav.tasks.rewards import reward_terms
from torchnav.tasks.sampling import place_random_objects, sample_goals, sample_starts

EPS = 1e-4  # m, float32 slack on geometric guarantees



def make_task(map: str = "arena", n: int = 4, **over) -> NavTask:
    return NavTask(NavConfig.from_dict({"map": map, **over}), n)


def start(task: NavTask, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    state, cur = task.initial_state(CurriculumState.initial(task.cfg.curriculum), gen)
    return state, cur, gen


def place(task: NavTask, state, pose, goal):
    """``state`` with the robots at ``pose`` ``(B, 3)`` and goals at ``goal`` ``(B, 2)``, at rest."""
    pose = torch.as_tensor(pose, dtype=torch.float32)
    goal = torch.as_tensor(goal, dtype=torch.float32)
    s = state.clone()
    s.sim = init_state(pose, state.world, task.params)
    s.goal = goal
    s.goal_dist = task.goal_vector(pose, goal)[0]
    return s


def write_map(tmp_path: Path, text: str, name: str = "m.yaml") -> str:
    p = tmp_path / name
    p.write_text(text)
    return str(p)


# --------------------------------------------------------------------------- reset sampling


def _box_perimeter(boxes: torch.Tensor, per_edge: int = 48) -> torch.Tensor:
    """Points along the edges of boxes ``(B, 5)`` -> ``(B, 4 * per_edge, 2)``."""
    c = box_corners(boxes)  # (B, 4, 2)
    t = torch.linspace(0.0, 1.0, per_edge + 1, dtype=boxes.dtype)[:-1]
    pts = c[:, :, None, :] + t[None, None, :, None] * (c.roll(-1, dims=1) - c)[:, :, None, :]
    return pts.reshape(boxes.shape[0], -1, 2)


def _without(world: World, kind: str, slot: int) -> World:
    box_mask, circle_mask = world.box_mask.clone(), world.circle_mask.clone()
    (box_mask if kind == "box" else circle_mask)[:, slot] = False
    return World(
        segments=world.segments, segment_mask=world.segment_mask, circles=world.circles, circle_mask=circle_mask,
        boxes=world.boxes, box_mask=box_mask, batch_size=world.batch_size,
    )


def _box_distance_to_points(box: torch.Tensor, pts: torch.Tensor) -> torch.Tensor:
    """Signed distance from points ``(B, P, 2)`` to one box per env ``(B, 5)`` -> ``(B, P)``."""
    b, p = pts.shape[:2]
    return point_box_distance(pts.reshape(b * p, 2), box[:, None].expand(b, p, 5).reshape(b * p, 1, 5)).reshape(b, p)


def _check_random_objects(spec, state) -> tuple[int, int]:
    """Assert every placed random object keeps its clearance and margin; return (placed, slots)."""
    w, st, goal = state.world, state.start[:, :2], state.goal
    placed = slots = 0
    rb = spec.random_boxes
    for j in range(rb.count if rb else 0):
        slot = spec.n_fixed_boxes + j
        on = w.box_mask[:, slot]
        box = w.boxes[:, slot]
        # Random circles are placed after the boxes and keep their own margin from them
        # (checked below), so a box is checked against fixed obstacles and the other boxes.
        others = _without(w, "box", slot)
        others.circle_mask = others.circle_mask.clone()
        others.circle_mask[:, spec.n_fixed_circles :] = False
        # The real box (not its circumscribed circle) keeps `clearance` from start and goal ...
        assert (point_box_distance(st, box[:, None])[:, 0][on] >= rb.clearance - EPS).all()
        assert (point_box_distance(goal, box[:, None])[:, 0][on] >= rb.clearance - EPS).all()
        # ... and `margin` from every other obstacle, along its whole outline ...
        gap = points_clearance(_box_perimeter(box), others).amin(-1)
        assert (gap[on] >= rb.margin - EPS).all(), gap[on].min()
        # ... and no other obstacle lies wholly inside it.
        inner = [others.boxes[..., :2], others.circles[..., :2], others.segments[..., :2]]
        masks = [others.box_mask, others.circle_mask, others.segment_mask]
        for pts, m in zip(inner, masks):
            if pts.shape[1]:
                d = _box_distance_to_points(box, pts)
                assert ((d > 0) | ~m)[on].all()
        placed += int(on.sum())
        slots += on.numel()
    rc = spec.random_circles
    for j in range(rc.count if rc else 0):
        slot = spec.n_fixed_circles + j
        on = w.circle_mask[:, slot]
        circ = w.circles[:, slot]
        assert (point_circle_distance(st, circ[:, None])[:, 0][on] >= rc.clearance - EPS).all()
        assert (point_circle_distance(goal, circ[:, None])[:, 0][on] >= rc.clearance - EPS).all()
        gap = points_clearance(circ[:, None, :2], _without(w, "circle", slot))[:, 0] - circ[:, 2]
        assert (gap[on] >= rc.margin - EPS).all(), gap[on].min()
        placed += int(on.sum())
        slots += on.numel()
    return placed, slots


@pytest.mark.parametrize("map_name", ["warehouse", "street", "arena"])
def test_random_objects_keep_clearance_and_margin_over_many_resets(map_name):
    task = make_task(map_name, n=48)
    spec = task.spec
    state, cur, gen = start(task, seed=1)
    placed = slots = 0
    for i in range(8):
        # Alternate full and partial resets so that re-placed slots meet the old episode's objects.
        mask = torch.ones(48, dtype=torch.bool) if i % 2 else torch.rand(48, generator=gen) < 0.5
        state, cur = task.reset(state, mask, cur, gen)
        p, s = _check_random_objects(spec, state)
        placed, slots = placed + p, slots + s
        # Start poses: the robot disc keeps start_clearance from everything, random objects included.
        assert (state.sim.clearance >= task.cfg.reset.start_clearance - EPS).all()
        assert not state.sim.collided.any()
        # Goals keep goal_clearance from everything and lie inside the world.
        assert (points_clearance(state.goal[:, None], state.world)[:, 0] >= task.cfg.reset.goal_clearance - EPS).all()
        xmin, ymin, xmax, ymax = spec.bounds
        assert ((state.goal[:, 0] > xmin) & (state.goal[:, 0] < xmax) & (state.goal[:, 1] > ymin) & (state.goal[:, 1] < ymax)).all()
        assert ((state.start[:, 2] >= -math.pi) & (state.start[:, 2] <= math.pi)).all()
    # The guarantee is not vacuous: nearly every slot gets an object on these maps.
    assert placed >= 0.95 * slots


def test_start_poses_are_collision_free_on_every_shipped_map():
    for name in ("arena", "empty", "maze", "street", "warehouse"):
        task = make_task(name, n=32)
        state, _, _ = start(task, seed=2)
        assert not state.sim.collided.any(), name
        assert (state.sim.clearance >= task.cfg.reset.start_clearance - EPS).all(), name
        # Headings are random, not all equal.
        assert state.start[:, 2].std() > 0.5


def test_random_objects_respect_start_and_goal_clearance_when_map_clearance_is_small(tmp_path):
    # Map objects may ask for less clearance than the task's start/goal clearance; the
    # task's own guarantees (robot disc + start_clearance, goal_clearance) still hold.
    path = write_map(
        tmp_path,
        "size: [4.0, 4.0]\nwalls: boundary\n"
        "random_circles: {count: 12, radius: [0.1, 0.2], clearance: 0.0, margin: 0.0}\n"
        "random_boxes: {count: 4, size_x: [0.2, 0.3], size_y: [0.2, 0.3], clearance: 0.0, margin: 0.0}\n",
    )
    task = make_task(path, n=64)
    state, cur, gen = start(task, seed=3)
    for _ in range(3):
        assert not state.sim.collided.any()
        assert (state.sim.clearance >= task.cfg.reset.start_clearance - EPS).all(), state.sim.clearance.min()
        assert (points_clearance(state.goal[:, None], state.world)[:, 0] >= task.cfg.reset.goal_clearance - EPS).all()
        state, cur = task.reset(state, torch.ones(64, dtype=torch.bool), cur, gen)


def test_random_object_fallback_masks_the_slot_off(tmp_path):
    # A 2 x 2 m room cannot hold a box 5 m from both start and goal: every box slot is left out.
    path = write_map(
        tmp_path,
        "size: [2.0, 2.0]\nwalls: boundary\n"
        "random_boxes: {count: 2, size_x: [0.2, 0.2], size_y: [0.2, 0.2], clearance: 5.0}\n",
    )
    task = make_task(path, n=6)
    state, cur, gen = start(task, seed=0)
    assert task.spec.n_fixed_boxes == 0 and state.world.box_mask.shape == (6, 2)
    assert not state.world.box_mask.any()
    # The episode still runs: lidar and collision ignore the masked slots.
    s, out = task.step(state, torch.zeros(6, 2))
    assert torch.isfinite(out["observation"]).all() and not out["collision"].any()


def test_sample_starts_fallback_takes_the_clearest_candidate():
    spec = load_map("empty")
    world = spec.build_world(5)
    gen = torch.Generator().manual_seed(0)
    # 6 m from every wall is impossible in a 10 x 10 m room.
    pose, found = sample_starts(world, spec, 6.0, 16, gen)
    assert pose.shape == (5, 3) and not found.any()
    clear = points_clearance(pose[:, None, :2], world)[:, 0]
    assert (clear > 4.5).all()  # near the centre, the clearest place there is
    pose, found = sample_starts(world, spec, 0.5, 16, gen)
    assert found.all() and (points_clearance(pose[:, None, :2], world)[:, 0] >= 0.5).all()


def test_sample_goals_within_the_radius_when_found():
    spec = load_map("warehouse")
    world = spec.build_world(64)
    gen = torch.Generator().manual_seed(0)
    starts, _ = sample_starts(world, spec, 0.5, 32, gen)
    goals, found = sample_goals(world, spec, starts[:, :2], 0.5, torch.tensor(2.0), 0.4, 32, gen)
    assert found.float().mean() > 0.9
    d = (goals - starts[:, :2]).norm(dim=-1)
    assert ((d >= 0.5 - EPS) & (d <= 2.0 + EPS))[found].all()
    assert (points_clearance(goals[:, None], world)[:, 0] >= 0.4 - EPS).all()


def test_goal_fallback_when_the_radius_is_tiny():
    # Goals must be 3 m from every wall of the 10 x 10 room: only the central 4 x 4 m square
    # qualifies. With a 1 cm radius, robots starting outside it get a valid goal from the
    # fallback (uniform over the world, ignoring the radius); those inside get one within 1 cm.
    task = make_task("empty", n=64, curriculum={"min_radius": 0.0, "init_radius": 0.01, "growth": 0.0},
                     reset={"goal_clearance": 3.0, "candidates": 128})
    state, _, _ = start(task, seed=0)
    d = (state.goal - state.start[:, :2]).norm(dim=-1)
    assert (state.goal.abs() <= 2.0 + EPS).all()
    inner = (state.start[:, :2].abs() <= 1.98).all(-1)
    outer = (state.start[:, :2].abs() > 2.0).any(-1)
    assert inner.any() and outer.any()
    assert (d[inner] <= 0.01 + EPS).all()
    assert (d[outer] > 0.01).all()


def test_goal_fallback_when_no_place_is_valid():
    # Nowhere in a 10 x 10 m room is 6 m from the walls: the goal is the clearest candidate.
    spec = load_map("empty")
    world = spec.build_world(8)
    gen = torch.Generator().manual_seed(0)
    starts = torch.zeros(8, 2)
    goals, found = sample_goals(world, spec, starts, 0.5, torch.tensor(1.0), 6.0, 32, gen)
    assert not found.any() and torch.isfinite(goals).all()
    assert (goals.abs() < 5.0).all()
    assert (points_clearance(goals[:, None], world)[:, 0] > 3.0).all()


def test_place_random_objects_touches_only_random_slots():
    spec = load_map("street")
    world = spec.build_world(4)
    gen = torch.Generator().manual_seed(0)
    starts, _ = sample_starts(world, spec, 0.5, 32, gen)
    goals, _ = sample_goals(world, spec, starts[:, :2], 0.5, torch.tensor(3.0), 0.4, 32, gen)
    new = place_random_objects(world, spec, starts[:, :2], goals, 32, gen)
    nb, nc = spec.n_fixed_boxes, spec.n_fixed_circles
    assert torch.equal(new.boxes[:, :nb], world.boxes[:, :nb]) and new.box_mask[:, :nb].all()
    assert torch.equal(new.circles[:, :nc], world.circles[:, :nc]) and new.circle_mask[:, :nc].all()
    assert torch.equal(new.segments, world.segments)
    assert new.box_mask[:, nb:].any() and new.circle_mask[:, nc:].any()


def test_partial_reset_leaves_other_envs_bit_identical():
    task = make_task("street", n=6)
    state, cur, gen = start(task)
    for _ in range(3):
        state, _ = task.step(state, torch.full((6, 2), 0.3))
    mask = torch.tensor([False, True, False, False, True, False])
    new, cur2 = task.reset(state, mask, cur, gen)
    old_td, new_td = state.to_tensordict(), new.to_tensordict()
    for key, old in old_td.items(True, True):
        for i in range(6):
            if not mask[i]:
                assert torch.equal(old[i], new_td[key][i]), (key, i)
    assert (new.steps[mask] == 0).all() and not torch.equal(new.goal[mask], state.goal[mask])
    assert int(cur2.placements) == int(cur.placements) + 2
    # Nothing to reset: same state and curriculum.
    same, cur3 = task.reset(new, torch.zeros(6, dtype=torch.bool), cur2, gen)
    assert same is new and cur3 is cur2


# --------------------------------------------------------------------------- curriculum


def test_growth_radius_after_n_placements_equals_the_formula():
    cfg = CurriculumConfig()
    assert (cfg.init_radius, cfg.growth, cfg.max_radius) == (1.0, 0.004, 15.0)  # the classic schedule
    cur = CurriculumState.initial(cfg)
    total = 0
    for n in (4, 1, 0, 17, 250, 3000, 1000):
        cur = after_placements(cur, cfg, torch.tensor(n))
        total += n
        assert int(cur.placements) == total
        assert cur.radius.item() == pytest.approx(min(15.0, 1.0 + 0.004 * total), rel=1e-6)
    assert cur.radius.item() == 15.0  # capped


def test_goals_follow_the_curriculum_radius():
    task = make_task("empty", n=32, curriculum={"init_radius": 1.0, "growth": 0.05, "max_radius": 4.0})
    state, cur, gen = start(task)
    for _ in range(4):
        r = cur.radius.item()
        state, cur = task.reset(state, torch.ones(32, dtype=torch.bool), cur, gen)
        d = (state.goal - state.start[:, :2]).norm(dim=-1)
        # In an empty room a valid goal within the radius always exists among 32 candidates
        # for nearly every env; the fallback may place a few further away.
        within = (d >= 0.5 - EPS) & (d <= r + EPS)
        assert within.float().mean() > 0.9
        assert cur.radius.item() == pytest.approx(min(4.0, 1.0 + 0.05 * int(cur.placements)))


def test_curriculum_modes_off_and_success_ignore_placements():
    off = CurriculumConfig(mode="off")
    cur = CurriculumState.initial(off)
    assert cur.radius.item() == off.max_radius
    cur = after_placements(cur, off, torch.tensor(100))
    assert cur.radius.item() == off.max_radius and int(cur.placements) == 100
    succ = CurriculumConfig(mode="success")
    cur = after_placements(CurriculumState.initial(succ), succ, torch.tensor(100))
    assert cur.radius.item() == succ.init_radius and int(cur.placements) == 100
    # ... and growth mode ignores episode outcomes.
    grow = CurriculumConfig()
    cur = CurriculumState.initial(grow)
    assert after_episodes(cur, grow, torch.ones(4, dtype=torch.bool), torch.ones(4, dtype=torch.bool)) is cur


def test_success_gated_curriculum_grows_only_above_the_threshold():
    cfg = CurriculumConfig(mode="success", success_threshold=0.5, success_step=0.25, success_smoothing=0.05)
    cur = CurriculumState.initial(cfg)
    done = torch.tensor([True, True, False, True])
    # One success among three finished episodes (env 2's "success" does not count: not done).
    fail = torch.tensor([True, False, True, False])
    c1 = after_episodes(cur, cfg, done, fail)
    keep = 0.95**3
    assert c1.success_rate.item() == pytest.approx((1 - keep) * (1 / 3))
    assert c1.radius.item() == cfg.init_radius
    # All three succeed: the average rises above 0.5 only after a few batches, and only then grows.
    rates, radii = [], []
    c = c1
    for _ in range(8):
        c = after_episodes(c, cfg, done, torch.ones(4, dtype=torch.bool))
        rates.append(c.success_rate.item())
        radii.append(c.radius.item())
    expected = c1.success_rate.item()
    for rate, radius in zip(rates, radii):
        expected = keep * expected + (1 - keep)
        assert rate == pytest.approx(expected, rel=1e-5)
    grown = [r > 0.5 for r in rates]
    assert grown[0] is False and grown[-1] is True
    for i in range(8):
        assert radii[i] == pytest.approx(cfg.init_radius + 0.25 * sum(grown[: i + 1]))
    # A step in which nothing finished changes nothing.
    c2 = after_episodes(c, cfg, torch.zeros(4, dtype=torch.bool), torch.zeros(4, dtype=torch.bool))
    assert c2.radius.item() == c.radius.item() and c2.success_rate.item() == c.success_rate.item()
    # The radius never passes the cap.
    big = CurriculumConfig(mode="success", success_threshold=0.0, success_step=100.0, max_radius=3.0)
    c3 = after_episodes(CurriculumState.initial(big), big, done, done)
    assert c3.radius.item() == 3.0


def test_curriculum_state_dict_round_trip(tmp_path):
    cfg = CurriculumConfig()
    cur = after_placements(CurriculumState.initial(cfg), cfg, torch.tensor(1234))
    cur.success_rate = torch.tensor(0.37)
    path = tmp_path / "cur.pt"
    torch.save(cur.state_dict(), path)
    loaded = torch.load(path, weights_only=True)
    fresh = CurriculumState.initial(cfg)
    fresh.load_state_dict(loaded)
    assert fresh.radius.item() == pytest.approx(1.0 + 0.004 * 1234)
    assert int(fresh.placements) == 1234 and fresh.success_rate.item() == pytest.approx(0.37)
    assert fresh.placements.dtype == torch.int64
    # Growth continues from the restored count.
    nxt = after_placements(fresh, cfg, torch.tensor(10))
    assert nxt.radius.item() == pytest.approx(1.0 + 0.004 * 1244)
    with pytest.raises(KeyError, match="success_rate"):
        fresh.load_state_dict({"radius": torch.tensor(1.0), "placements": torch.tensor(0)})


# --------------------------------------------------------------------------- observation and actions


def test_observation_layout_and_normalisation():
    for normalize in (True, False):
        task = make_task("warehouse", n=3, observation={"normalize": normalize})
        state, _, _ = start(task)
        state, out = task.step(state, torch.tensor([[0.5, 0.2], [1.0, -1.0], [-1.0, 0.0]]))
        obs = out["observation"]
        assert obs.shape == (3, 24) and task.frame_size == 24
        pose, goal = state.sim.pose, state.goal
        dist = (goal - pose[:, :2]).norm(dim=-1)
        bearing = torch.atan2(goal[:, 1] - pose[:, 1], goal[:, 0] - pose[:, 0]) - pose[:, 2]
        bearing = torch.atan2(torch.sin(bearing), torch.cos(bearing))
        raw = torch.cat((sectorize(state.sim.ranges, 20), dist[:, None], bearing[:, None], state.sim.vel), -1)
        scale = torch.tensor([0.1] * 21 + [1 / math.pi, 1.0, 1.0]) if normalize else torch.ones(24)
        torch.testing.assert_close(obs, raw * scale, atol=1e-5, rtol=1e-5)
        # Commanded (v, omega): a[0] in [-1, 1] -> [0, 1] m/s, a[1] -> [-1, 1] rad/s.
        torch.testing.assert_close(state.sim.vel, torch.tensor([[0.75, 0.2], [1.0, -1.0], [0.0, 0.0]]))


def test_action_mapping():
    task = make_task(n=5)
    a = torch.tensor([[-1.0, -1.0], [0.0, 0.0], [1.0, 1.0], [3.0, -7.0], [0.5, 0.25]])
    torch.testing.assert_close(task.command(a), torch.tensor([[0.0, -1.0], [0.5, 0.0], [1.0, 1.0], [1.0, -1.0], [0.75, 0.25]]))
    both = make_task(n=5, action={"forward_only": False}, robot={"v_max": 0.5, "omega_max": 2.0})
    torch.testing.assert_close(both.command(a), torch.tensor([[-0.5, -2.0], [0.0, 0.0], [0.5, 2.0], [0.5, -2.0], [0.25, 0.5]]))
    assert both.params.v_min == -0.5 and task.params.v_min == 0.0
    disc = make_task(n=3, action={"mode": "discrete", "discrete_set": [[1.0, 0.0], [0.5, -1.0], [0.0, 1.0]]}, robot={"omega_max": 2.0})
    onehot = torch.eye(3)[[2, 0, 1]]
    torch.testing.assert_close(disc.command(onehot), torch.tensor([[0.0, 2.0], [1.0, 0.0], [0.5, -2.0]]))


def test_history_stacks_observations_newest_last():
    k = 3
    one, hist = make_task("arena", n=2), make_task("arena", n=2, observation={"history": k})
    s1, _, _ = start(one, seed=5)
    sk, _, _ = start(hist, seed=5)
    assert hist.obs_size == 24 * k and sk.history.shape == (2, k, 24)
    # At reset the history is k copies of the first observation.
    first = s1.history[:, 0]
    assert torch.equal(sk.history, first[:, None].expand(2, k, 24))
    obs1 = [first]
    for t in range(4):
        a = torch.tensor([[0.2, 0.5], [0.0, -0.3]])
        s1, o1 = one.step(s1, a)
        sk, ok = hist.step(sk, a)
        obs1.append(o1["observation"])
        assert ok["observation"].shape == (2, 24 * k)
        expected = torch.cat([obs1[max(0, len(obs1) - k + i)] for i in range(k)], dim=-1)
        torch.testing.assert_close(ok["observation"], expected)
        torch.testing.assert_close(ok["observation"][:, -24:], o1["observation"])


def test_goal_from_odometry_changes_the_observation_not_the_pose():
    noisy = {"odom_v_noise": 0.3, "odom_omega_noise": 0.3}
    true = make_task("arena", n=4, robot=noisy)
    odom = make_task("arena", n=4, robot=noisy, observation={"goal_from_odom": True})
    st, _, gt = start(true, seed=7)
    so, _, go = start(odom, seed=7)
    a = torch.tensor([[0.5, 0.3]] * 4)
    for _ in range(10):
        st, ot = true.step(st, a, gt)
        so, oo = odom.step(so, a, go)
    torch.testing.assert_close(so.sim.pose, st.sim.pose)  # noise drifts the estimate, never the robot
    assert not torch.allclose(so.sim.odom, so.sim.pose, atol=1e-3)
    torch.testing.assert_close(oo["observation"][:, :20], ot["observation"][:, :20])  # same lidar
    assert not torch.allclose(oo["observation"][:, 20:22], ot["observation"][:, 20:22], atol=1e-3)  # goal differs
    dist, bearing = odom.goal_vector(so.sim.odom, so.goal)
    torch.testing.assert_close(oo["observation"][:, 20], dist / 10.0)
    # The reward uses the true distance.
    assert torch.equal(oo["reward"], ot["reward"])


def test_goal_distance_cap_limits_only_the_observed_distance():
    # observation.goal_distance_cap: the goal distance entry reads min(distance, cap); the rest of the
    # observation and the reward are unchanged; a cap must be a positive number of metres
    from torchnav.config import ConfigError

    plain, capped = make_task("warehouse", n=6), make_task("warehouse", n=6, observation={"goal_distance_cap": 0.7})
    sp, _, gp = start(plain, seed=3)
    sc, _, gc = start(capped, seed=3)
    a = torch.tensor([[0.5, 0.1]] * 6)
    sp, op = plain.step(sp, a, gp)
    sc, oc = capped.step(sc, a, gc)
    dist, _ = plain.goal_vector(sp.sim.pose, sp.goal)
    assert (dist > 0.7).any() and (dist < 0.7).any()  # both sides of the cap are checked
    torch.testing.assert_close(oc["observation"][:, 20], dist.clamp(max=0.7) / 10.0)
    keep = [i for i in range(24) if i != 20]
    assert torch.equal(oc["observation"][:, keep], op["observation"][:, keep]) and torch.equal(oc["reward"], op["reward"])
    for bad in (0.0, -1.0, math.inf):
        with pytest.raises(ConfigError, match="goal_distance_cap"):
            make_task("arena", n=1, observation={"goal_distance_cap": bad})


def test_visit_features_closed_form():
    # Robot at the origin facing +y; breadcrumbs ahead (1 m), on the left (1 m), behind (1.5 m), one
    # beyond the radius and one unused slot: sector k is centred on bearing 2 pi k / S, a breadcrumb
    # weighs 1 - d / radius, a sector reads 1 - exp(-sum / 4).
    from torchnav.tasks.navigation import FAR, visit_features

    odom = torch.tensor([[0.0, 0.0, math.pi / 2]])
    crumbs = torch.tensor([[[0.0, 1.0], [-1.0, 0.0], [0.0, -1.5], [0.1, 3.5], [FAR, FAR]]])
    got = visit_features(odom, crumbs, 4, 3.0)
    w = torch.tensor([[2 / 3, 2 / 3, 0.5, 0.0]])
    torch.testing.assert_close(got, 1.0 - torch.exp(-w / 4.0))
    # Two breadcrumbs in one sector add up; a bearing on a sector's edge goes to one of the two.
    two = visit_features(odom, torch.tensor([[[0.0, 1.0], [0.2, 2.0]]]), 4, 3.0)
    d2 = math.hypot(0.2, 2.0)
    torch.testing.assert_close(two[0, 0], torch.tensor(1.0 - math.exp(-((2 / 3) + 1 - d2 / 3) / 4)))
    assert (two[0, 1:] == 0).all()


def test_drop_crumb_spacing_and_ring():
    from torchnav.tasks.navigation import FAR, drop_crumb

    k = 3
    crumbs = torch.full((2, k, 2), FAR)
    crumbs[:, 0] = 0.0
    count = torch.ones(2, dtype=torch.int64)
    # Env 0 drives 0.3 m steps along x, env 1 stands still: one breadcrumb per 0.5 m driven.
    for i in range(1, 8):
        crumbs, count = drop_crumb(crumbs, count, torch.tensor([[0.3 * i, 0.0, 0.0], [0.0, 0.0, 0.0]]), 0.5)
    assert count.tolist() == [4, 1]
    # Env 0 dropped at 0.6, 1.2 and 1.8 m; the fourth overwrote the oldest slot (the start).
    torch.testing.assert_close(crumbs[0, :, 0], torch.tensor([1.8, 0.6, 1.2]))
    assert torch.equal(crumbs[1, 0], torch.zeros(2)) and (crumbs[1, 1:] == FAR).all()


def test_visit_memory_in_the_task_observation_and_resets():
    from torchnav.config import ConfigError
    from torchnav.tasks.navigation import visit_features

    task = make_task("empty", n=3, observation={"visit_sectors": 8, "visit_memory": 16})
    assert task.frame_size == 32 and task.obs_size == 32
    assert task.unit_features.tolist() == [False] * 24 + [True] * 8
    state, cur, gen = start(task, seed=1)
    state = place(task, state, [[0.0, 0.0, 0.0]] * 3, [[9.0, 9.0]] * 3)
    state.crumbs[:, 0] = 0.0
    assert (state.crumb_count == 1).all() and state.crumbs.shape == (3, 16, 2)
    a = torch.tensor([[0.9, 0.0], [0.9, 0.0], [-1.0, 0.0]])  # two drive straight at 0.95 m/s, one stands
    for _ in range(22):
        state, out = task.step(state, a, gen)
    assert state.crumb_count.tolist() == [4, 4, 1]  # 2.09 m driven: breadcrumbs at 0, 0.57, 1.14, 1.71 m
    torch.testing.assert_close(state.crumbs[0, :4, 0], torch.tensor([0.0, 0.57, 1.14, 1.71]), atol=1e-4, rtol=0)
    obs = out["observation"][:, 24:]
    torch.testing.assert_close(obs, visit_features(state.sim.odom, state.crumbs, 8, 3.0))
    assert (obs[:2, 4] > 0.4).all() and (obs[:2, torch.arange(8) != 4] == 0).all()  # the trail lies behind
    assert obs[2, 4] == 0 and obs[2].sum() > 0  # standing on the start breadcrumb
    # A reset starts the memory again from the new start.
    state, cur = task.reset(state, torch.tensor([True, False, False]), cur, gen)
    assert state.crumb_count.tolist() == [1, 4, 1]
    torch.testing.assert_close(state.crumbs[0, 0], state.sim.odom[0, :2])
    with pytest.raises(ConfigError, match="visit_sectors"):
        make_task("arena", n=1, observation={"visit_sectors": -1})
    with pytest.raises(ConfigError, match="visit_spacing"):
        make_task("arena", n=1, observation={"visit_sectors": 4, "visit_spacing": 0.0})


def test_speed_guard_stops_the_robot_short_of_a_wall():
    from torchnav.config import ConfigError

    runs = {}
    for clearance in (None, 0.05):
        task = make_task("empty", n=2, action={"stop_clearance": clearance})
        state, cur, gen = start(task, seed=0)
        # Full speed at the wall x = 5 from 3 m away; robot 1 turns as it goes.
        state = place(task, state, [[2.0, 0.0, 0.0], [2.0, 0.0, 0.3]], [[-4.0, 0.0]] * 2)
        collided = torch.zeros(2, dtype=torch.bool)
        for _ in range(80):
            state, out = task.step(state, torch.tensor([[1.0, 0.0], [1.0, 0.2]]), gen)
            collided |= out["collision"]
        runs[clearance] = (collided, state)
    assert runs[None][0].all()
    collided, state = runs[0.05]
    assert not collided.any()
    # Robot 0 stopped facing the wall, within one step's travel (0.05 m) of radius + clearance. No ray
    # points straight ahead: the guard keeps its clearance from the returns 4.7 degrees either side,
    # so the wall between them comes about 1 mm nearer.
    gap = 5.0 - state.sim.pose[0, 0].item()
    assert 0.248 <= gap <= 0.25 + 0.05 + 1e-4 and state.sim.vel[0, 0].item() == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ConfigError, match="stop_clearance"):
        make_task("empty", n=1, action={"stop_clearance": -0.1})


def test_lidar_noise_changes_ranges_within_bounds():
    clean, noisy = make_task("arena", n=4), make_task("arena", n=4, lidar={"noise_std": 0.5})
    sc, _, gc = start(clean, seed=1)
    sn, _, gn = start(noisy, seed=1)
    sc, oc = clean.step(sc, torch.zeros(4, 2), gc)
    sn, on = noisy.step(sn, torch.zeros(4, 2), gn)
    assert not torch.allclose(sn.sim.ranges, sc.sim.ranges)
    assert (sn.sim.ranges >= 0.0).all() and (sn.sim.ranges <= 10.0).all()
    torch.testing.assert_close(sn.sim.pose, sc.sim.pose)


# --------------------------------------------------------------------------- rewards


def test_presets_and_weights():
    assert PRESETS == {
        "classic": {"goal": 100.0, "collision": -100.0, "velocity": 0.5, "turning": -0.5, "proximity": -0.5},
        "progress": {"goal": 100.0, "collision": -100.0, "progress": 10.0, "spin": -0.5, "proximity": -1.0},
        "shaped": {"goal": 50.0, "collision": -10.0, "progress": 1.0, "step": -0.01, "heading": 0.1},
    }
    cfg = NavConfig.from_dict({"reward": {"preset": "shaped", "weights": {"step": -0.1, "velocity": 2}}}).reward
    w = resolve_weights(cfg)
    assert w["step"] == -0.1 and w["velocity"] == 2.0 and w["goal"] == 50.0
    assert set(w) <= set(TERMS)


@pytest.mark.parametrize("preset", list(PRESETS))
def test_reward_terms_sum_to_reward(preset):
    task = make_task("street", n=8, reward={"preset": preset}, max_steps=15)
    state, cur, gen = start(task)
    assert task.term_names == tuple(PRESETS[preset])
    actions = torch.rand(30, 8, 2, generator=torch.Generator().manual_seed(3)) * 2 - 1
    for a in actions:
        prev = state
        state, out = task.step(state, a, gen)
        assert set(out["terms"]) == set(PRESETS[preset])
        total = torch.stack(list(out["terms"].values())).sum(0)
        torch.testing.assert_close(out["reward"], total)
        torch.testing.assert_close(state.ep_return, prev.ep_return + out["reward"])
        torch.testing.assert_close(state.ep_terms.sum(-1), state.ep_return, atol=1e-4, rtol=1e-5)
        done = out["terminated"] | out["truncated"]
        state, cur = task.reset(state, done, cur, gen)


def test_reward_term_formulas():
    cfg = NavConfig().reward  # proximity_distance 1.0 m, spin_threshold 0.5 rad/s
    ones = {k: 1.0 for k in TERMS}
    success = torch.tensor([False, True, False])
    collision = torch.tensor([False, False, True])
    vel = torch.tensor([[0.8, -0.9], [0.5, 0.1], [0.3, 0.7]])
    d_min = torch.tensor([0.4, 0.2, 3.0])
    progress = torch.tensor([0.05, -0.02, 0.1])
    bearing = torch.tensor([math.pi / 3, 0.0, 0.0])
    t = reward_terms(ones, cfg, success=success, collision=collision, vel=vel, d_min=d_min, progress=progress, bearing=bearing)
    exp = {
        "goal": [0.0, 1.0, 0.0],
        "collision": [0.0, 0.0, 1.0],
        "velocity": [0.8, 0.0, 0.0],  # 0 on terminal steps
        "turning": [0.9, 0.0, 0.0],
        "proximity": [0.6, 0.0, 0.0],  # max(0, 1 - d_min)
        "progress": [0.05, -0.02, 0.1],  # also on terminal steps
        "spin": [0.4, 0.0, 0.0],  # max(0, |omega| - 0.5)
        "step": [1.0, 1.0, 1.0],
        "heading": [0.5, 0.0, 0.0],  # cos(bearing)
    }
    for k, v in exp.items():
        torch.testing.assert_close(t[k], torch.tensor(v), msg=k)
    w = reward_terms({"velocity": 0.5, "goal": 100.0}, cfg, success=success, collision=collision, vel=vel, d_min=d_min, progress=progress, bearing=bearing)
    assert set(w) == {"velocity", "goal"}
    torch.testing.assert_close(w["goal"], torch.tensor([0.0, 100.0, 0.0]))


def test_unknown_preset_or_term_raises():
    from torchnav.config import ConfigError

    with pytest.raises(ConfigError, match="unknown preset 'fancy'.*classic"):
        make_task(reward={"preset": "fancy"})
    with pytest.raises(ConfigError, match="unknown term 'speed'"):
        make_task(reward={"weights": {"speed": 1.0}})


# --------------------------------------------------------------------------- termination


def test_goal_collision_and_timeout_flags():
    task = make_task("empty", n=4, max_steps=3)
    state, _, _ = start(task)
    # env 0: reaches the goal; 1: drives into the wall at x = 5; 2: reaches the goal but collides
    # in the same step (collision wins); 3: stands still until the step limit.
    pose = [[0.0, 0.0, 0.0], [4.72, 0.0, 0.0], [4.72, 0.0, 0.0], [-2.0, -2.0, 0.0]]
    goal = [[0.35, 0.0], [-3.0, -3.0], [4.9, 0.0], [2.0, 2.0]]
    state = place(task, state, pose, goal)
    a = torch.tensor([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0], [-1.0, 0.0]])
    s1, out = task.step(state, a)
    assert out["success"].tolist() == [True, False, False, False]
    assert out["collision"].tolist() == [False, True, True, False]
    assert out["terminated"].tolist() == [True, True, True, False]
    assert out["truncated"].tolist() == [False, False, False, False]
    torch.testing.assert_close(out["terms"]["goal"], torch.tensor([100.0, 0.0, 0.0, 0.0]))
    torch.testing.assert_close(out["terms"]["collision"], torch.tensor([0.0, -100.0, -100.0, 0.0]))
    assert (out["terms"]["velocity"][:3] == 0).all()  # shaping terms are 0 on terminal steps
    s2, out = task.step(s1, a)
    s3, out = task.step(s2, a)
    assert out["truncated"][3] and not out["terminated"][3] and int(s3.steps[3]) == 3
    # A terminal step is never also a truncation.
    assert not (out["terminated"] & out["truncated"]).any()


def test_episode_statistics_in_the_state():
    task = make_task("empty", n=2)
    state, _, _ = start(task)
    state = place(task, state, [[0.0, 0.0, 0.0], [0.0, 0.0, 0.5]], [[3.0, 0.0], [-3.0, 0.0]])
    state.straight = state.goal_dist.clone()
    a = torch.tensor([[1.0, 0.0], [0.0, 0.4]])
    rewards = torch.zeros(2)
    for _ in range(5):
        state, out = task.step(state, a)
        rewards += out["reward"]
    torch.testing.assert_close(state.ep_return, rewards)
    assert state.steps.tolist() == [5, 5]
    # env 0 drives 1 m/s straight for 0.5 s; env 1 drives 0.5 m/s on an arc (chords sum < arc length)
    torch.testing.assert_close(state.ep_path, torch.tensor([0.5, 0.25]), atol=1e-3, rtol=0)
    torch.testing.assert_close(state.straight, torch.tensor([3.0, 3.0]))


# --------------------------------------------------------------------------- pure, differentiable step


def test_step_is_pure():
    task = make_task("warehouse", n=3)
    state, _, _ = start(task)
    before = state.to_tensordict().clone()
    task.step(state, torch.full((3, 2), 0.5))
    for k, v in before.items(True, True):
        assert torch.equal(v, state.to_tensordict()[k]), k


def test_differentiable_rollout_through_the_task():
    task = make_task("arena", n=4, reward={"preset": "progress"})
    state, _, _ = start(task, seed=4)
    acts = (torch.rand(25, 4, 2, generator=torch.Generator().manual_seed(0)) * 0.8 - 0.4).requires_grad_()
    s, ret = state, torch.zeros(4)
    for a in acts:
        s, out = task.step(s, a)
        ret = ret + out["reward"]
    loss = -ret.sum() + s.goal_dist.sum()
    loss.backward()
    g = acts.grad
    assert torch.isfinite(g).all()
    # Every env's first action moves its final goal distance and return.
    assert (g[0].abs().sum(-1) > 0).all() and (g[-1].abs().sum(-1) > 0).all()
    # Gradient mode leaves values unchanged.
    with torch.no_grad():
        s2, ret2 = state, torch.zeros(4)
        for a in acts:
            s2, out = task.step(s2, a)
            ret2 = ret2 + out["reward"]
    torch.testing.assert_close(ret2, ret.detach())
    torch.testing.assert_close(s2.sim.pose, s.sim.pose.detach())


def test_task_validates_num_envs():
    with pytest.raises(ValueError, match="num_envs"):
        NavTask(NavConfig(), 0)
