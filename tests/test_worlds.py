"""Procedural worlds: shapes, reachability (checked by an independent planner), seeding,
difficulty, errors, the mixture, and the wavefront and rasteriser against naive versions."""

from __future__ import annotations

import heapq
import math
import time

import numpy as np
import pytest
import torch

from torchnav.controllers.planning import Obstacles, OccupancyGrid, plan_astar
from torchnav.maps import load_map
from torchnav.sim import World, cat_worlds, check_world, points_clearance
from torchnav.worlds import FAMILIES, cat_batches, goal_band, goal_distance, goal_distance_grid, make_worlds, mix_worlds, slot_counts
from torchnav.worlds import cave, corridors, fences, forest, open_space, rooms
from torchnav.worlds.raster import clearance_grid
from torchnav.worlds.wavefront import DIAG, ORTHO, UNREACHED, geodesic_distance

NAMES = list(FAMILIES)
DIFFS = torch.linspace(0.0, 1.0, 6)


def gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


@pytest.fixture(scope="module")
def batches():
    """Six envs of every family (and a shipped map), at difficulties 0, 0.2, ..., 1."""
    return {name: make_worlds(name, 6, DIFFS, gen(1)) for name in NAMES + ["map:maze"]}


def obstacles_of(batch, e: int) -> Obstacles:
    w = batch.world
    pick = lambda t, m: t[e][m[e]].double().numpy()  # noqa: E731
    return Obstacles(pick(w.segments, w.segment_mask), pick(w.circles, w.circle_mask), pick(w.boxes, w.box_mask), tuple(batch.bounds[e].tolist()))


# ------------------------------------------------------------------ episodes and reachability


@pytest.mark.parametrize("name", NAMES + ["map:maze"])
def test_every_episode_is_reachable_by_an_independent_planner(batches, name):
    b = batches[name]
    r = b.robot_radius
    assert (points_clearance(b.start[:, None, :2], b.world)[:, 0] > r).all()
    assert (points_clearance(b.goal[:, None], b.world)[:, 0] > r).all()
    for xy in (b.start[:, :2], b.goal):
        assert ((xy > b.bounds[:, :2] + r) & (xy < b.bounds[:, 2:] - r)).all()
    for e in range(len(b)):
        # numpy geometry and A* on a finer grid, inflated by the bare robot radius
        grid = OccupancyGrid.build(obstacles_of(b, e), 0.05)
        path = plan_astar(grid, b.start[e, :2].numpy(), b.goal[e].numpy(), inflate=r, snap=0.1)
        assert path is not None, f"{name} env {e}: no path"
        shortest = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
        straight = float((b.goal[e] - b.start[e, :2]).norm())
        # Ours is an octile path on a coarser, more inflated grid: never shorter, at most ~20% longer.
        assert straight - 1e-4 <= float(b.path_length[e]) and shortest - 0.05 <= float(b.path_length[e]) <= 1.25 * shortest + 0.3


@pytest.mark.parametrize("name", NAMES)
def test_shapes_masks_and_bounds_do_not_depend_on_difficulty(name):
    easy, hard = make_worlds(name, 3, 0.0, gen()), make_worlds(name, 3, 1.0, gen())
    for b in (easy, hard):
        check_world(b.world, 3, torch.float32, torch.device("cpu"))
        assert b.start.shape == (3, 3) and b.goal.shape == (3, 2) and b.path_length.shape == (3,) and b.bounds.shape == (3, 4)
        assert b.family == (name,) * 3 and b.difficulty.shape == (3,)
        w = b.world
        # Bounded by walls: the first four segments run along the bounds.
        assert w.segment_mask[:, :4].all()
        lo, hi = b.bounds[:, None, :2], b.bounds[:, None, 2:]
        ends = w.segments[:, :4].reshape(3, 8, 2)
        assert (((ends - lo).abs() < 1e-5) | ((ends - hi).abs() < 1e-5)).all(-1).all()
        # Every obstacle switched on lies inside the bounds.
        eps = 1e-4
        seg = w.segments.reshape(3, -1, 2)
        inside = lambda p, pad: ((p - pad >= lo - eps) & (p + pad <= hi + eps)).all(-1)  # noqa: E731
        assert (inside(seg, 0) | ~w.segment_mask.repeat_interleave(2, 1)).all()
        assert (inside(w.circles[..., :2], w.circles[..., 2:]) | ~w.circle_mask).all()
        c, s = w.boxes[..., 4:].cos().abs(), w.boxes[..., 4:].sin().abs()
        hx, hy = w.boxes[..., 2:3], w.boxes[..., 3:4]
        assert (inside(w.boxes[..., :2], torch.cat((c * hx + s * hy, s * hx + c * hy), -1)) | ~w.box_mask).all()
    for key in ("segments", "circles", "boxes"):
        assert getattr(easy.world, key).shape == getattr(hard.world, key).shape
    assert easy.world.segment_mask.sum() + easy.world.circle_mask.sum() + easy.world.box_mask.sum() > 12


def test_worlds_in_float64():
    for name in NAMES + ["map:street"]:
        b = make_worlds(name, 2, 0.7, gen(), dtype=torch.float64)
        check_world(b.world, 2, torch.float64, torch.device("cpu"))
        assert b.start.dtype == b.goal.dtype == b.path_length.dtype == b.bounds.dtype == torch.float64


# ------------------------------------------------------------------------------ seeding


def test_same_seed_same_worlds_and_other_seeds_other_worlds():
    for name in NAMES:
        a, b, c = (make_worlds(name, 4, DIFFS[:4], gen(s)) for s in (7, 7, 8))
        for key in ("segments", "segment_mask", "circles", "circle_mask", "boxes", "box_mask"):
            assert torch.equal(getattr(a.world, key), getattr(b.world, key)), (name, key)
        for key in ("start", "goal", "path_length", "bounds"):
            assert torch.equal(getattr(a, key), getattr(b, key)), (name, key)
        assert not torch.equal(a.start, c.start), name
        assert not all(torch.equal(getattr(a.world, k), getattr(c.world, k)) for k in ("segments", "circles", "boxes")), name


def test_generation_leaves_the_global_rng_alone():
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    make_worlds("forest", 2, 0.5, gen())
    assert torch.equal(torch.rand(3), expected)


# ----------------------------------------------------------------------------- difficulty


def test_parameters_move_monotonically_with_difficulty():
    d = torch.linspace(0, 1, 11)
    up = lambda t: bool((t[1:] >= t[:-1]).all() and t[-1] > t[0])  # noqa: E731
    down = lambda t: up(-t)  # noqa: E731
    r, c, k, f, o, g = rooms.params(d), corridors.params(d), cave.params(d), forest.params(d), open_space.params(d), fences.params(d)
    assert up(r["rooms_per_side"]) and down(r["door_width"]) and r["door_width"][0] == 1.6 and r["door_width"][-1] == 0.8
    assert up(c["cells_per_side"]) and down(c["corridor_width"]) and down(c["loop_prob"])
    assert up(k["fill"])
    assert up(f["posts"]) and down(f["radius_min"]) and down(f["radius_max"]) and abs(float(f["radius_min"][-1]) - 0.05) < 1e-6
    assert up(o["side"]) and up(o["boxes"]) and float(o["side"][-1]) == 20.0
    assert up(g["fences"]) and down(g["gaps"]) and down(g["gap_min"]) and down(g["gap_max"]) and up(g["post_prob"]) and up(g["thickness_max"])
    assert abs(float(g["gap_min"][-1]) - 0.55) < 1e-6 and (g["gap_min"] < g["gap_max"]).all()
    lo, hi = goal_band(d)
    assert up(lo) and up(hi) and (lo < hi).all()


def test_measured_geometry_follows_difficulty():
    easy, hard = torch.zeros(16), torch.ones(16)
    # rooms: the gap between the two segments of a wall with a door is the door width
    for d, width in ((easy, 1.6), (hard, 0.8)):
        w, _ = rooms.layout(d, gen())
        seg, mask = w.segments[:, 4:].reshape(16, -1, 2, 4), w.segment_mask[:, 4:].reshape(16, -1, 2)
        door = mask[..., 1]
        gap = (seg[..., 1, :2] - seg[..., 0, 2:]).norm(dim=-1)[door]
        assert door.any() and torch.allclose(gap, torch.full_like(gap, width), atol=1e-4)
    (we, _), (wh, _) = rooms.layout(easy, gen()), rooms.layout(hard, gen())
    assert wh.segment_mask.sum() > we.segment_mask.sum()
    # forest: more and thinner posts
    (fe, _), (fh, _) = forest.layout(easy, gen()), forest.layout(hard, gen())
    assert (fh.circle_mask.sum(1) > fe.circle_mask.sum(1)).all()
    assert fh.circles[..., 2][fh.circle_mask].mean() < fe.circles[..., 2][fe.circle_mask].mean()
    assert fh.circles[..., 2][fh.circle_mask].min() >= 0.05 - 1e-6
    # cave: more rock
    rock = lambda w: (4 * w.boxes[..., 2] * w.boxes[..., 3] * w.box_mask).sum(1).mean()  # noqa: E731
    assert rock(cave.layout(hard, gen())[0]) > 1.5 * rock(cave.layout(easy, gen())[0])
    # corridors: narrower (the maze side is cells * width)
    (_, be), (_, bh) = corridors.layout(easy, gen()), corridors.layout(hard, gen())
    assert torch.allclose(be[:, 2] * 2, torch.full((16,), 8.0)) and torch.allclose(bh[:, 2] * 2, torch.full((16,), 7.2))


def fence_gaps(world: World, half: float, e: int) -> list[float]:
    """The free widths along every fence of env ``e`` of a ``fences`` world: each opening between two
    solid pieces (or a piece and the wall), split in two where a post stands in it."""
    per = fences.MAX_GAPS + 1
    gaps = []
    for k in range(fences.MAX_FENCES):
        on = world.box_mask[e, k * per:(k + 1) * per]
        if not on.any():
            continue
        box = world.boxes[e, k * per:(k + 1) * per][on].double()
        axis = int(box[:, 2:4].amax(0).argmax())  # a fence runs along its pieces' long side
        cuts = sorted([-half] + [v for c, hl in zip(box[:, axis].tolist(), box[:, 2 + axis].tolist()) for v in (c - hl, c + hl)] + [half])
        posts = world.circles[e, k * fences.MAX_GAPS:(k + 1) * fences.MAX_GAPS][world.circle_mask[e, k * fences.MAX_GAPS:(k + 1) * fences.MAX_GAPS]]
        for lo, hi in zip(cuts[::2], cuts[1::2]):
            inside = [(float(p[axis]), float(p[2])) for p in posts if lo < float(p[axis]) < hi]
            edges = [lo] + [v for c, r in inside for v in (c - r, c + r)] + [hi]
            gaps += [b - a for a, b in zip(edges[::2], edges[1::2]) if b - a > 1e-6]
    return gaps


def test_fence_gaps_narrow_with_difficulty_and_posts_split_openings():
    for d in (0.0, 0.5, 0.8, 1.0):
        p = {k: float(v) for k, v in fences.params(torch.tensor([d])).items()}
        world, bounds = fences.layout(torch.full((32,), d), gen(4))
        gaps = [g for e in range(32) for g in fence_gaps(world, float(bounds[e, 2]), e)]
        # Each gap's width is drawn in [gap_min, gap_max]; a piece shorter than MIN_PIECE is left out,
        # which widens a gap at a wall by at most that.
        assert len(gaps) >= 32 and min(gaps) >= p["gap_min"] - 1e-4 and max(gaps) <= p["gap_max"] + fences.MIN_PIECE + 1e-4, (d, min(gaps), max(gaps))
        assert (world.box_mask.reshape(32, fences.MAX_FENCES, -1).any(-1).sum(1) == int(p["fences"])).all()
        if d >= 0.8:
            assert world.circle_mask.any(1).float().mean() > 0.5 and min(gaps) < 0.7  # posts, and gaps as narrow as warehouse's 0.65 m


@pytest.mark.parametrize("name", NAMES)
def test_goals_get_farther_with_difficulty(name):
    easy, hard = make_worlds(name, 16, 0.0, gen(2)), make_worlds(name, 16, 1.0, gen(2))
    assert hard.path_length.mean() > 1.5 * easy.path_length.mean()
    assert (easy.path_length >= 1.0).all()


def test_anywhere_goals_leave_the_band_and_zero_leaves_the_worlds_alone():
    banded = make_worlds("rooms", 256, 0.8, gen(4))
    default = make_worlds("rooms", 256, 0.8, gen(4), anywhere_goals=0.0)
    assert torch.equal(banded.goal, default.goal) and torch.equal(banded.start, default.start)
    anywhere = make_worlds("rooms", 256, 0.8, gen(4), anywhere_goals=1.0)
    # difficulty 0.8 bands goals to 52-92% of the farthest path (over 6 m in these rooms); anywhere ones start at 0.5 m
    assert banded.path_length.min() > 5.0
    assert anywhere.path_length.min() >= 0.5 - 0.15 and (anywhere.path_length < 3.0).sum() >= 5
    assert (points_clearance(anywhere.goal[:, None], anywhere.world)[:, 0] > anywhere.robot_radius).all()
    half = mix_worlds(512, {"rooms": 1.0, "open": 1.0}, 0.8, gen(5), anywhere_goals=0.5)
    assert 0.05 < float((half.path_length < 5.0).float().mean()) < 0.5
    with pytest.raises(ValueError, match=r"anywhere_goals must be in \[0, 1\], got 1.5"):
        make_worlds("rooms", 2, 0.5, gen(), anywhere_goals=1.5)


def test_below_level_draws_easier_worlds_and_records_each_difficulty():
    at_level = make_worlds("corridors", 64, 0.8, gen(6), below_level=0.0)
    assert torch.equal(at_level.world.segments, make_worlds("corridors", 64, 0.8, gen(6)).world.segments)
    mixed = make_worlds("corridors", 400, 0.8, gen(6), below_level=0.5)
    d = mixed.difficulty
    below = d < 0.8 - 1e-6
    assert (d >= 0).all() and (d <= 0.8 + 1e-6).all()
    assert 0.4 < float(below.float().mean()) < 0.6 and float(d[below].mean()) == pytest.approx(0.4, abs=0.06)
    # each env's world is generated at its own difficulty: the maze's cells grow 4 -> 9 with it
    side = mixed.bounds[:, 2] - mixed.bounds[:, 0]
    width = FAMILIES["corridors"].params(d)["corridor_width"]
    cells = FAMILIES["corridors"].params(d)["cells_per_side"]
    assert torch.allclose(side, width * cells, atol=1e-4)
    with pytest.raises(ValueError, match=r"below_level must be in \[0, 1\], got -0.1"):
        mix_worlds(2, ["rooms"], 0.5, gen(), below_level=-0.1)


# ---------------------------------------------------------------------------------- errors


def test_bad_arguments_raise_errors_that_name_the_problem():
    with pytest.raises(ValueError, match="unknown world family 'room'.*rooms"):
        make_worlds("room", 2, 0.5, gen())
    with pytest.raises(ValueError, match=r"unknown world family map:nowhere"):
        make_worlds("map:nowhere", 2, 0.5, gen())
    with pytest.raises(ValueError, match=r"difficulty must lie in \[0, 1\], got 1.5"):
        make_worlds("rooms", 2, 1.5, gen())
    with pytest.raises(ValueError, match=r"difficulty must lie in \[0, 1\], got nan"):
        make_worlds("rooms", 2, torch.tensor([0.2, math.nan]), gen())
    with pytest.raises(ValueError, match=r"difficulty must be a number or a \(2,\) tensor, got shape \(3,\)"):
        make_worlds("rooms", 2, torch.zeros(3), gen())
    with pytest.raises(ValueError, match="num_envs must be >= 1"):
        make_worlds("rooms", 0, 0.5, gen())
    with pytest.raises(ValueError, match="generator is on cpu"):
        make_worlds("rooms", 2, 0.5, gen(), device="meta")
    with pytest.raises(ValueError, match="at least one family"):
        mix_worlds(4, [], 0.5, gen())
    with pytest.raises(ValueError, match="weights must be >= 0"):
        mix_worlds(4, {"rooms": -1.0, "cave": 1.0}, 0.5, gen())
    with pytest.raises(ValueError, match="no free space for a robot of radius 4"):
        make_worlds("corridors", 1, 0.5, gen(), robot_radius=4.0)
    a, b = make_worlds("open", 1, 0.0, gen()), make_worlds("open", 1, 0.0, gen(), robot_radius=0.3)
    with pytest.raises(ValueError, match="different robot radii"):
        cat_batches([a, b])


# --------------------------------------------------------------------------------- mixture


def test_mixture_draws_a_family_per_env_and_pads_slots():
    weights = {"rooms": 1.0, "forest": 1.0, "map:arena": 1.0}
    d = torch.rand(24, generator=gen(5))
    m = mix_worlds(24, weights, d, gen(3))
    assert len(m) == 24 and set(m.family) == set(weights) and torch.equal(m.difficulty, d)
    w = m.world
    arena = load_map("arena").build_world(1)
    for e, fam in enumerate(m.family):
        n_seg, n_circ = int(w.segment_mask[e].sum()), int(w.circle_mask[e].sum())
        if fam == "forest":
            assert n_seg == 4 and n_circ > 0
        elif fam == "rooms":
            assert n_seg > 4 and n_circ == 0
        else:
            assert torch.equal(w.segments[e][w.segment_mask[e]], arena.segments[0]) and n_circ == 0 and not w.box_mask[e].any()
    assert w.circles.shape[1] == forest.MAX_POSTS and w.segments.shape[1] == rooms_slots()
    assert slot_counts(list(weights)) == {k: getattr(w, k).shape[1] for k in ("segments", "circles", "boxes")}
    assert (points_clearance(m.start[:, None, :2], w)[:, 0] > m.robot_radius).all()
    again = mix_worlds(24, weights, d, gen(3))
    assert again.family == m.family and torch.equal(again.goal, m.goal) and torch.equal(again.world.segments, w.segments)


def rooms_slots() -> int:
    return 4 + 2 * 2 * rooms.MAX_ROOMS * (rooms.MAX_ROOMS - 1)


# ---------------------------------------------------------------------- vectorised vs naive


def dijkstra(free: np.ndarray, source: int) -> np.ndarray:
    h, w = free.shape
    dist = np.full(h * w, UNREACHED, dtype=np.int64)
    dist[source] = 0
    heap = [(0, source)]
    while heap:
        d, u = heapq.heappop(heap)
        if d > dist[u]:
            continue
        j, i = divmod(u, w)
        for dj in (-1, 0, 1):
            for di in (-1, 0, 1):
                jj, ii = j + dj, i + di
                if (dj or di) and 0 <= jj < h and 0 <= ii < w and free[jj, ii]:
                    nd = d + (DIAG if dj and di else ORTHO)
                    if nd < dist[jj * w + ii]:
                        dist[jj * w + ii] = nd
                        heapq.heappush(heap, (nd, jj * w + ii))
    return dist.reshape(h, w)


def test_corridor_slots_hold_every_closed_wall():
    """A hard maze (9 x 9 cells, no loops) closes exactly (9 - 1)**2 wall pieces between cells:
    the merged walls in its slots add up to that many corridor widths, so none was dropped."""
    batch = make_worlds("corridors", 64, 1.0, gen(9))
    w, width = batch.world, corridors.params(torch.ones(1))["corridor_width"]
    inner, on = w.segments[:, 4:], w.segment_mask[:, 4:]
    assert inner.shape[1] == corridors.MAX_SEGMENTS == 64
    pieces = ((inner[..., 2:] - inner[..., :2]).norm(dim=-1) * on).sum(1) / width
    torch.testing.assert_close(pieces, torch.full_like(pieces, 64.0), atol=1e-3, rtol=0)


def test_wavefront_equals_dijkstra_on_random_grids():
    g = gen(4)
    free = torch.rand(5, 23, 37, generator=g) > 0.35
    free[:, 11, :] = True  # a long corridor, so that long paths exist
    free[3] = torch.rand(23, 37, generator=g) > 0.6  # many small components
    free[4, :, 18] = False  # a wall cutting the grid in two
    source = torch.where(free.reshape(5, -1), torch.rand(5, 23 * 37, generator=g), -1.0).argmax(1)
    got = geodesic_distance(free, source)
    for e in range(5):
        assert np.array_equal(got[e].numpy(), dijkstra(free[e].numpy(), int(source[e]))), e
    assert (got[~free] == UNREACHED).all()


def test_wavefront_is_exact_when_envs_settle_at_different_passes():
    # Open grids settle after two passes; a serpentine needs a pass per turn, so the sweep drops
    # the settled envs part-way (wavefront.SETTLED_SHARE) and must keep their results.
    h, w = 21, 30
    free = torch.ones(6, h, w, dtype=torch.bool)
    for row in range(2, h - 1, 4):  # walls across the serpentine env, open at alternating ends
        free[4, row, 1:] = False
        free[4, row + 2, :-1] = False
    free[5, 7:9, 3:25] = False  # one obstacle: a few passes
    source = torch.tensor([0, 5 * w + 7, h * w - 1, 17, 0, 10 * w + 2])
    got = geodesic_distance(free, source)
    for e in range(6):
        assert np.array_equal(got[e].numpy(), dijkstra(free[e].numpy(), int(source[e]))), e
        assert torch.equal(got[e], geodesic_distance(free[e : e + 1], source[e : e + 1])[0]), e
    assert got[4][free[4]].max() < UNREACHED and got[4, h - 1, w - 1] > 5 * ORTHO * w  # the serpentine is one long path


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_wavefront_goal_grids_and_generation_on_cuda():
    """The wavefront is integer arithmetic: the GPU's distances equal the CPU's bit for bit. Goal
    grids of the same worlds equal the CPU's but where a clearance rounds differently; and
    generation with a GPU generator gives reachable episodes with a known path distance."""
    g = gen(4)
    free = torch.rand(6, 40, 57, generator=g) > 0.3
    free[5, 20, :] = True
    source = torch.where(free.reshape(6, -1), torch.rand(6, 40 * 57, generator=g), -1.0).argmax(1)
    assert torch.equal(geodesic_distance(free.cuda(), source.cuda()).cpu(), geodesic_distance(free, source))
    batch = make_worlds("rooms", 16, 0.7, gen(3))
    field, frame = goal_distance_grid(batch.world.to("cuda"), batch.bounds.cuda(), batch.goal.cuda())
    cpu_field, cpu_frame = goal_distance_grid(batch.world, batch.bounds, batch.goal)
    assert field.is_cuda and torch.allclose(frame.cpu(), cpu_frame)
    assert (field.cpu() == cpu_field).float().mean() > 0.99
    gpu = mix_worlds(64, {"rooms": 1.0, "corridors": 1.0, "forest": 1.0}, 0.6, torch.Generator("cuda").manual_seed(0), guide_cells=64)
    assert gpu.start.is_cuda and gpu.goal_field.is_cuda
    d = goal_distance(gpu.goal_field, gpu.goal_frame, gpu.goal, gpu.start[:, :2])
    assert torch.isfinite(d).all() and (d >= (gpu.goal - gpu.start[:, :2]).norm(dim=-1) - 0.05).all()


def test_clearance_grid_is_exact_below_reach_and_above_it_elsewhere():
    # walls, circles and rotated boxes of two maps of different sizes in one batch
    world = cat_worlds([load_map("street").build_world(1), load_map("warehouse").build_world(1)])
    reach, res, lo, shape = 0.35, 0.1, (-10.0, -10.0), (203, 198)
    got = clearance_grid(world, lo, shape, res, reach)
    ys = lo[1] + (torch.arange(shape[0]) + 0.5) * res
    xs = lo[0] + (torch.arange(shape[1]) + 0.5) * res
    pts = torch.stack(torch.meshgrid(ys, xs, indexing="ij")[::-1], -1).reshape(1, -1, 2).expand(2, -1, 2)
    dense = points_clearance(pts, world).reshape(got.shape)
    near = dense <= reach
    # equal up to float32 round-off in the cell coordinates
    assert near.any() and torch.allclose(got[near], dense[near], atol=1e-5) and (got[~near] > reach - 1e-5).all()


def test_batches_concatenate_and_select():
    a, b = make_worlds("corridors", 2, 0.5, gen()), make_worlds("forest", 3, 0.5, gen())
    c = cat_batches([a, b])
    assert len(c) == 5 and c.family == ("corridors",) * 2 + ("forest",) * 3
    assert isinstance(c.world, World) and c.world.circles.shape[1] == forest.MAX_POSTS
    s = c.select(torch.tensor([4, 0]))
    assert s.family == ("forest", "corridors") and torch.equal(s.goal, torch.stack((c.goal[4], c.goal[0])))


# ---------------------------------------------------------------------------------- timing


@pytest.mark.parametrize("name", NAMES)
def test_a_batch_of_64_generates_in_seconds(name):
    t = time.perf_counter()
    make_worlds(name, 64, torch.rand(64, generator=gen()), gen())
    assert time.perf_counter() - t < 20.0


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_1024_envs_generate_in_under_a_minute(name):
    t = time.perf_counter()
    b = make_worlds(name, 1024, torch.rand(1024, generator=gen()), gen())
    assert time.perf_counter() - t < 60.0
    assert (points_clearance(b.start[:, None, :2], b.world)[:, 0] > b.robot_radius).all()
