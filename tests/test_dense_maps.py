"""Maps with many fixed obstacles: polygons, compact circle rows, occupancy images, and
worlds, lidar and reset sampling on a map with hundreds of circles (fast, CPU)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from params import lidar_params
from reference import naive_point_clearance, naive_scan
from torchnav.maps import MapError, load_map, parse_map
from torchnav.maps.occupancy import mask_boxes, mask_rectangles
from torchnav.sim import lidar_scan, points_clearance
from torchnav.tasks import sampling

DATA = Path(__file__).resolve().parent / "data"


def write(tmp_path: Path, text: str, name: str = "m.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def save_png(path: Path, occupied: np.ndarray) -> None:
    """Black occupied pixels on white, as an 8-bit grey PNG."""
    Image.fromarray(np.where(occupied, 0, 255).astype(np.uint8)).save(path)


def forest_yaml(n_side: int = 20, spacing: float = 1.5, seed: int = 0) -> str:
    """A square world with ``n_side**2`` circles on a jittered grid (compact row form) and random objects."""
    rng = np.random.default_rng(seed)
    size = n_side * spacing
    rows = []
    for i in range(n_side):
        for j in range(n_side):
            x = -size / 2 + spacing * (i + 0.5) + rng.uniform(-0.2, 0.2)
            y = -size / 2 + spacing * (j + 0.5) + rng.uniform(-0.2, 0.2)
            rows.append(f"  - [{x:.3f}, {y:.3f}, {rng.uniform(0.1, 0.2):.3f}]")
    head = f"name: forest\nsize: [{size}, {size}]\nwalls: boundary\ncircles:\n"
    tail = "\nrandom_circles: {count: 4, radius: [0.1, 0.2], clearance: 0.5}\nrandom_boxes: {count: 2, size_x: [0.3, 0.5], size_y: [0.3, 0.5]}\n"
    return head + "\n".join(rows) + tail


# --------------------------------------------------------------------------- polygons and circle rows


def test_polygons_become_walls(tmp_path):
    text = """
size: [10, 10]
walls: [[-5, 0, -4, 0]]
polygons:
  - [[0, 0], [2, 0], [2, 1]]
  - {points: [[-3, -3], [-3, -1], [-1, -1]], closed: false}
  - {points: [[3, 3], [4, 3], [4, 4], [3, 4]]}
"""
    spec = load_map(write(tmp_path, text))
    assert spec.segments == (
        (-5.0, 0.0, -4.0, 0.0),  # walls first
        (0.0, 0.0, 2.0, 0.0), (2.0, 0.0, 2.0, 1.0), (2.0, 1.0, 0.0, 0.0),  # closed: back to the first vertex
        (-3.0, -3.0, -3.0, -1.0), (-3.0, -1.0, -1.0, -1.0),  # open: n - 1 walls
        (3.0, 3.0, 4.0, 3.0), (4.0, 3.0, 4.0, 4.0), (4.0, 4.0, 3.0, 4.0), (3.0, 4.0, 3.0, 3.0),  # closed by default
    )
    assert spec.build_world(2).segments.shape == (2, 10, 4)


def test_circle_rows_equal_mappings(tmp_path):
    rows = load_map(write(tmp_path, "size: [10, 10]\ncircles: [[1, 2, 0.3], [-1, 0.5, 1e-1]]\n", "a.yaml"))
    maps = load_map(write(tmp_path, "size: [10, 10]\ncircles: [{center: [1, 2], radius: 0.3}, {center: [-1, 0.5], radius: 0.1}]\n", "b.yaml"))
    mixed = load_map(write(tmp_path, "size: [10, 10]\ncircles: [[1, 2, 0.3], {center: [-1, 0.5], radius: 0.1}]\n", "c.yaml"))
    assert rows.circles == maps.circles == mixed.circles == ((1.0, 2.0, 0.3), (-1.0, 0.5, 0.1))


# --------------------------------------------------------------------------- occupancy images


def rasterise(rects: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """How many rectangles ``[row0, col0, row1, col1]`` cover each pixel ``(H, W)``."""
    out = np.zeros(shape, dtype=np.int64)
    for r0, c0, r1, c1 in rects:
        out[r0:r1, c0:c1] += 1
    return out


def floor_plan(h: int = 200, w: int = 200) -> np.ndarray:
    m = np.zeros((h, w), dtype=bool)
    m[:4], m[-4:], m[:, :4], m[:, -4:] = True, True, True, True  # outer walls
    m[60:64, :120] = m[140:144, 80:] = True  # inner walls with doors
    m[:60, 100:104] = True
    yy, xx = np.mgrid[:h, :w]
    m |= np.hypot(yy - 100, xx - 50) < 15  # a round column
    m[170:190, 20:60] = True  # a desk
    return m


@pytest.mark.parametrize("case", ["empty", "full", "random sparse", "random dense", "floor plan", "one row", "one column"])
def test_rectangles_cover_exactly_the_occupied_pixels(case):
    rng = np.random.default_rng(1)
    mask = {
        "empty": np.zeros((5, 7), bool),
        "full": np.ones((9, 4), bool),
        "random sparse": rng.random((37, 53)) < 0.1,
        "random dense": rng.random((41, 29)) < 0.8,
        "floor plan": floor_plan(),
        "one row": rng.random((1, 64)) < 0.5,
        "one column": rng.random((64, 1)) < 0.5,
    }[case]
    rects = mask_rectangles(mask)
    assert rects.dtype == np.int64 and rects.shape == (len(rects), 4)
    assert (rects[:, 2] > rects[:, 0]).all() and (rects[:, 3] > rects[:, 1]).all()
    cover = rasterise(rects, mask.shape)
    assert cover.max(initial=0) <= 1  # disjoint
    np.testing.assert_array_equal(cover == 1, mask)  # union == occupied pixels
    if case == "floor plan":
        assert mask.sum() > 5000 and 10 < len(rects) <= 40  # tens of boxes, not one per pixel


def test_mask_boxes_cover_the_pixels_in_world_coordinates():
    mask = floor_plan(60, 80)
    res, origin = 0.05, (-1.0, 2.0)
    boxes = mask_boxes(mask, res, origin)
    assert (boxes[:, 4] == 0).all()
    h, w = mask.shape
    col, row = np.meshgrid(np.arange(w), np.arange(h))
    x, y = origin[0] + (col + 0.5) * res, origin[1] + (h - row - 0.5) * res  # pixel centres, row 0 on top
    inside = (np.abs(x[..., None] - boxes[:, 0]) < boxes[:, 2]) & (np.abs(y[..., None] - boxes[:, 1]) < boxes[:, 3])
    np.testing.assert_array_equal(inside.sum(-1), mask.astype(int))
    assert np.isclose((4 * boxes[:, 2] * boxes[:, 3]).sum(), mask.sum() * res**2)


def test_occupancy_key_builds_boxes(tmp_path):
    mask = np.zeros((10, 20), bool)
    mask[2:4, 3:8] = mask[6:9, 15:17] = True
    save_png(tmp_path / "plan.png", mask)
    spec = load_map(write(tmp_path, "size: [4, 4]\nboxes: [{center: [1, 1], size: [0.2, 0.2]}]\noccupancy: {image: plan.png, resolution: 0.1}\n"))
    assert spec.boxes[0] == (1.0, 1.0, 0.1, 0.1, 0.0)  # listed boxes first
    np.testing.assert_allclose(spec.boxes[1:], mask_boxes(mask, 0.1, (-1.0, -0.5)))  # centred by default
    # invert: light pixels are occupied; origin places the lower-left corner.
    save_png(tmp_path / "neg.png", ~mask)
    inv = load_map(write(tmp_path, "size: [4, 4]\noccupancy: {image: neg.png, resolution: 0.1, invert: true, origin: [-2, -2], threshold: 0.3}\n", "inv.yaml"))
    np.testing.assert_allclose(inv.boxes, mask_boxes(mask, 0.1, (-2.0, -2.0)))
    # parse_map resolves a relative image against base_dir.
    same = parse_map({"size": [4, 4], "occupancy": {"image": "plan.png", "resolution": 0.1}}, "inline", base_dir=tmp_path)
    assert same.boxes == spec.boxes[1:]


def test_example_map_in_tests_data():
    spec = load_map(DATA / "dense_room.yaml")
    assert spec.name == "dense_room" and len(spec.segments) == 4 + 4 + 2
    assert spec.n_fixed_circles == 5 and spec.n_fixed_boxes == 1 + 10
    world = spec.build_world(3)
    assert world.boxes.shape == (3, 11, 5) and world.circles.shape == (3, 5 + 3, 3)


BAD = {
    "polygons not a list": ("polygons: {points: [[0, 0], [1, 0], [1, 1]]}\n", "polygons: expected a list of outlines"),
    "too few vertices": ("polygons: [[[0, 0], [1, 0]]]\n", "polygons[0]: expected a list of at least 3 [x, y] vertices"),
    "open needs two": ("polygons: [{points: [[0, 0]], closed: false}]\n", "polygons[0].points: expected a list of at least 2"),
    "vertex not a pair": ("polygons: [[[0, 0], [1, 0, 2], [1, 1]]]\n", "polygons[0][1]: expected 2 numbers"),
    "zero-length edge": ("polygons: [[[0, 0], [1, 0], [1, 0], [1, 1]]]\n", "polygons[0]: edge from vertex 1 to vertex 2 has zero length"),
    "first vertex repeated": (
        "polygons: [[[0, 0], [1, 0], [1, 1], [0, 0]]]\n",
        "polygons[0]: edge from vertex 3 to vertex 0 has zero length at (0, 0) (a closed outline must not repeat",
    ),
    "vertex outside": ("polygons: [[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 0], [6, 0]]]\n", "polygons[1][2]: the vertex (6, 0) lies outside"),
    "polygon unknown key": ("polygons: [{points: [[0, 0], [1, 0], [1, 1]], close: false}]\n", "polygons[0].close: unknown key (did you mean 'closed'?)"),
    "closed not a bool": ("polygons: [{points: [[0, 0], [1, 0], [1, 1]], closed: 0}]\n", "polygons[0].closed: expected true or false"),
    "circle row length": ("circles: [[0, 0, 0.1], [1, 1]]\n", "circles[1]: expected 3 numbers"),
    "circle row radius": ("circles: [[0, 0, -0.1]]\n", "circles[0]: expected [cx, cy, r] with a positive radius"),
    "circle row outside": ("circles: [[4.9, 0, 0.2]]\n", "circles[0]: the circle's edge point (5.1, 0) lies outside"),
    "circle neither form": ("circles: [pole]\n", "circles[0]: expected {center, radius} or [cx, cy, r]"),
    "occupancy missing image": ("occupancy: {resolution: 0.1}\n", "occupancy.image: required key is missing"),
    "occupancy unknown key": ("occupancy: {image: plan.png, resolution: 0.1, negate: true}\n", "occupancy.negate: unknown key"),
    "occupancy image type": ("occupancy: {image: 3, resolution: 0.1}\n", "occupancy.image: expected a path to a PNG file"),
    "occupancy file missing": ("occupancy: {image: nope.png, resolution: 0.1}\n", "occupancy.image: "),
    "occupancy not an image": ("occupancy: {image: m.yaml, resolution: 0.1}\n", "occupancy.image: "),
    "occupancy resolution": ("occupancy: {image: plan.png, resolution: -0.1}\n", "occupancy.resolution: expected a positive number"),
    "occupancy threshold": ("occupancy: {image: plan.png, resolution: 0.1, threshold: 1}\n", "occupancy.threshold: expected a grey level in (0, 1)"),
    "occupancy invert": ("occupancy: {image: plan.png, resolution: 0.1, invert: yes please}\n", "occupancy.invert: expected true or false"),
    "occupancy origin": ("occupancy: {image: plan.png, resolution: 0.1, origin: [0]}\n", "occupancy.origin: expected 2 numbers"),
    "occupancy outside": ("occupancy: {image: plan.png, resolution: 0.1, origin: [4, 0]}\n", "occupancy: a corner of an occupied pixel"),
    "occupancy all free": ("occupancy: {image: blank.png, resolution: 0.1}\n", "blank.png: no pixel has a grey level below the threshold 0.5"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_dense_keys_name_file_and_key(tmp_path, case):
    mask = np.zeros((10, 20), bool)
    mask[2:4, 3:18] = True
    save_png(tmp_path / "plan.png", mask)
    save_png(tmp_path / "blank.png", np.zeros_like(mask))
    body, expected = BAD[case]
    path = write(tmp_path, "size: [10, 10]\n" + body)
    with pytest.raises(MapError) as e:
        load_map(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and expected in msg, msg
    if case == "occupancy file missing":
        assert "nope.png: image file not found" in msg
    if case == "occupancy not an image":
        assert "cannot read image" in msg


# --------------------------------------------------------------------------- hundreds of circles


@pytest.fixture(scope="module")
def forest(tmp_path_factory):
    return load_map(write(tmp_path_factory.mktemp("forest"), forest_yaml()))


def test_forest_world_shape_and_lidar_against_naive(forest):
    assert forest.n_fixed_circles == 400 and forest.n_circle_slots == 404 and forest.n_box_slots == 2
    world = forest.build_world(3, dtype=torch.float64)
    assert world.circles.shape == (3, 404, 3) and world.circle_mask[:, :400].all()
    assert world.segments.shape == (3, 4, 4) and world.boxes.shape == (3, 2, 5)
    world.boxes[2, 0] = torch.tensor([0.0, 0.0, 0.4, 0.2, 0.5], dtype=torch.float64)  # one random box on, in env 2
    world.box_mask[2, 0] = True
    lidar = lidar_params(n_rays=12, fov=2 * math.pi, max_range=8.0)
    pose = torch.tensor([[0.1, 0.2, 0.3], [-7.3, 4.4, -2.0], [0.0, -0.75, 1.6]], dtype=torch.float64)
    got = lidar_scan(pose, world, lidar)
    assert torch.allclose(got, torch.tensor(naive_scan(pose, world, lidar), dtype=torch.float64), atol=1e-9)
    assert (got < lidar.max_range).sum() > 12  # the rays do hit trees


def test_chunked_clearance_equals_one_call(forest, monkeypatch):
    world = forest.build_world(4)
    pts = torch.rand(4, 50, 2, generator=torch.Generator().manual_seed(0)) * 30 - 15
    whole = points_clearance(pts, world)
    monkeypatch.setattr(sampling, "_CHUNK_ELEMENTS", 4 * 404 * 7)  # 7 points per chunk, the last one short
    assert torch.equal(sampling.obstacle_clearance(pts, world), whole)
    monkeypatch.setattr(sampling, "_CHUNK_ELEMENTS", 1)  # still one point at a time
    assert torch.equal(sampling.obstacle_clearance(pts, world), whole)
    assert whole[0, 0].item() == pytest.approx(naive_point_clearance(*pts[0, 0].tolist(), world, 0), abs=1e-5)


def test_reset_on_a_dense_map_never_starts_in_collision(forest):
    from torchnav.tasks import CurriculumState, NavConfig, NavTask

    cfg = NavConfig(map=forest.source)
    task = NavTask(cfg, num_envs=256)
    gen = torch.Generator().manual_seed(3)
    state, _ = task.initial_state(CurriculumState.initial(cfg.curriculum), gen)
    need = cfg.robot.radius + cfg.reset.start_clearance
    assert (state.sim.clearance >= cfg.reset.start_clearance - 1e-5).all() and not state.sim.collided.any()
    assert task.static is not None  # 400 fixed circles: the map is held once for the batch (shared_map: auto)
    world = task.full_world(state.world)  # each env's obstacles: the map's and the episode's random ones
    start_gap = points_clearance(state.start[:, None, :2], world)[:, 0]
    assert (start_gap >= need - 1e-5).all()  # random objects included
    goal_gap = points_clearance(state.goal[:, None], world)[:, 0]
    assert (goal_gap >= cfg.reset.goal_clearance - 1e-5).all()
    assert world.circle_mask[:, 400:].float().mean() > 0.9  # random objects found room


def test_docs_show_the_example_map_verbatim():
    docs = (Path(__file__).resolve().parents[1] / "docs" / "maps.md").read_text()
    assert (DATA / "dense_room.yaml").read_text() in docs
