"""Map loading, validation, world building and rendering (fast, CPU)."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest
import torch
import yaml
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from params import lidar_params

from torchnav.maps import MapError, MapSpec, available_maps, load_map, parse_map
from torchnav.maps.free_space import obstacle_distance, reachable_fraction
from torchnav.sim.state import check_world

SHIPPED = ["arena", "empty", "maze", "street", "warehouse"]
DATA_DIR = Path(__file__).resolve().parents[1] / "torchnav" / "maps" / "data"


def write(tmp_path: Path, text: str, name: str = "bad.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


# --------------------------------------------------------------------------- shipped maps


def test_available_maps_lists_shipped_files():
    assert available_maps() == sorted(p.stem for p in DATA_DIR.glob("*.yaml"))
    assert set(SHIPPED) <= set(available_maps())


@pytest.mark.parametrize("name", SHIPPED)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_shipped_map_builds_world(name, dtype):
    spec = load_map(name)
    assert spec.name == name and Path(spec.source).name == f"{name}.yaml"
    world = spec.build_world(3, device="cpu", dtype=dtype)
    n_rb = spec.random_boxes.count if spec.random_boxes else 0
    n_rc = spec.random_circles.count if spec.random_circles else 0
    S, C, K = len(spec.segments), spec.n_fixed_circles + n_rc, spec.n_fixed_boxes + n_rb
    assert world.batch_size == torch.Size([3])
    check_world(world, 3, dtype, torch.device("cpu"))  # what the simulator checks before a step
    assert world.segments.shape == (3, S, 4) and world.segment_mask.shape == (3, S)
    assert world.circles.shape == (3, C, 3) and world.circle_mask.shape == (3, C)
    assert world.boxes.shape == (3, K, 5) and world.box_mask.shape == (3, K)
    assert (spec.n_box_slots, spec.n_circle_slots) == (K, C)
    for t in (world.segments, world.circles, world.boxes):
        assert t.dtype == dtype and t.device.type == "cpu"
    for m in (world.segment_mask, world.circle_mask, world.box_mask):
        assert m.dtype == torch.bool
    assert world.segment_mask.all()
    # Fixed obstacles first and on in every env; random slots after them, zeroed and off.
    nb, nc = spec.n_fixed_boxes, spec.n_fixed_circles
    assert world.box_mask[:, :nb].all() and not world.box_mask[:, nb:].any()
    assert world.circle_mask[:, :nc].all() and not world.circle_mask[:, nc:].any()
    assert (world.boxes[:, nb:] == 0).all() and (world.circles[:, nc:] == 0).all()
    expected = torch.tensor(spec.boxes, dtype=dtype).reshape(-1, 5)
    assert torch.equal(world.boxes[1, :nb], expected)
    # Envs own their tensors: the task writes random objects into one env at reset.
    world.segments[0].add_(1.0)
    assert not torch.equal(world.segments[0], world.segments[1])


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_build_world_on_cuda():
    world = load_map("street").build_world(4, device="cuda")
    for t in (world.segments, world.circles, world.boxes, world.box_mask, world.circle_mask):
        assert t.is_cuda
    assert world.device.type == "cuda"


def test_shipped_map_specifics():
    arena = load_map("arena")
    assert arena.size == (10.0, 10.0) and len(arena.segments) == 4
    rb = arena.random_boxes
    assert rb.count == 4 and rb.clearance == 1.5 and rb.margin == 0.1
    assert rb.yaw[0] <= -3.14159 and rb.yaw[1] >= 3.14159
    assert 0.4 <= rb.size_x[0] <= rb.size_x[1] <= 0.6 and 0.3 <= rb.size_y[0] <= rb.size_y[1] <= 0.5
    assert load_map("empty").to_dict()["boxes"] == []
    wh = load_map("warehouse")
    assert wh.n_fixed_boxes + wh.n_fixed_circles >= 25
    st = load_map("street")
    assert st.random_circles.count > 0 and st.random_boxes.count > 0


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_maps_free_space_is_connected(name):
    # A 0.2 m robot (plus a little slack) can get from any free place to any other.
    assert reachable_fraction(load_map(name), robot_radius=0.25, resolution=0.1) == 1.0


def _cross(a, b, c, d) -> bool:
    """Do segments ab and cd intersect (touching counts)?"""

    def orient(p, q, r):
        return np.sign((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))

    def on(p, q, r):
        return min(p[0], q[0]) <= r[0] <= max(p[0], q[0]) and min(p[1], q[1]) <= r[1] <= max(p[1], q[1])

    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    if o1 != o2 and o3 != o4:
        return True
    return any(o == 0 and on(*pts) for o, pts in ((o1, (a, b, c)), (o2, (a, b, d)), (o3, (c, d, a)), (o4, (c, d, b))))


def test_maze_every_cell_reachable():
    spec = load_map("maze")
    n, cell = 5, 2.0
    assert spec.size == (n * cell, n * cell) and len(spec.segments) > 4 + 6  # a maze, not a room
    centre = {(i, j): (-5 + cell * (i + 0.5), -5 + cell * (j + 0.5)) for i in range(n) for j in range(n)}
    seen, stack = {(0, 0)}, [(0, 0)]
    while stack:  # flood fill: neighbours are connected when no wall cuts the line between centres
        i, j = stack.pop()
        for nb in ((i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)):
            if nb in centre and nb not in seen:
                if not any(_cross(centre[(i, j)], centre[nb], s[:2], s[2:]) for s in spec.segments):
                    seen.add(nb)
                    stack.append(nb)
    assert len(seen) == n * n
    # Corridors are 2 m between zero-thickness walls: every cell centre has >= 0.75 m to a wall.
    assert obstacle_distance(spec, np.array(list(centre.values()))).min() >= 0.75


# --------------------------------------------------------------------------- parsing


def test_boundary_expands_to_world_edges(tmp_path):
    spec = load_map(write(tmp_path, "size: [4, 2]\nwalls: boundary\n", "room.yaml"))
    assert spec.name == "room" and spec.bounds == (-2.0, -1.0, 2.0, 1.0)
    assert len(spec.segments) == 4
    edges = {frozenset([s[:2], s[2:]]) for s in spec.segments}
    corners = [(-2.0, -1.0), (2.0, -1.0), (2.0, 1.0), (-2.0, 1.0)]
    assert edges == {frozenset([corners[k], corners[(k + 1) % 4]]) for k in range(4)}
    listed = load_map(write(tmp_path, "size: [4, 2]\nwalls: [boundary, [0, -1, 0, 1]]\n", "room2.yaml"))
    assert listed.segments[:4] == spec.segments and listed.segments[4] == (0.0, -1.0, 0.0, 1.0)


def test_full_schema_round_trip(tmp_path):
    text = """
name: lab
size: [6, 4]
walls: [[-1, -2, -1, 0.5]]
circles: [{center: [1, 1], radius: 0.3}]
boxes:
  - {center: [2, -1], size: [1.0, 0.5], yaw: 0.3}
  - {center: [-2, 1], size: [0.4, 0.4]}
random_boxes: {count: 2, size_x: [0.2, 0.3], size_y: [0.2, 0.2]}
random_circles: {count: 3, radius: [1e-1, 2e-1], clearance: 0.5, margin: 0}
"""
    spec = load_map(write(tmp_path, text, "lab_file.yaml"))
    assert spec.name == "lab" and spec.source.endswith("lab_file.yaml")
    assert spec.boxes == ((2.0, -1.0, 0.5, 0.25, 0.3), (-2.0, 1.0, 0.2, 0.2, 0.0))  # half extents
    assert spec.circles == ((1.0, 1.0, 0.3),)
    assert spec.random_boxes.yaw == (-math.pi, math.pi) and spec.random_boxes.clearance == 1.0
    assert spec.random_circles.radius == (0.1, 0.2)  # YAML 1.1 would read 1e-1 as a string
    assert spec.random_circles.margin == 0.0
    d = spec.to_dict()
    json.dumps(d)
    assert yaml.safe_dump(d) and d["random_boxes"]["size_x"] == [0.2, 0.3]
    with pytest.raises(Exception):
        spec.name = "other"  # frozen
    # parse_map takes an already-loaded dict (plain safe_load: write 0.1, not 1e-1, there).
    inline = parse_map(yaml.safe_load(text.replace("1e-1", "0.1").replace("2e-1", "0.2")), "inline")
    assert inline.boxes == spec.boxes and inline.source == "inline" and inline.name == "lab"


def test_load_by_path_str_and_pathlike(tmp_path):
    p = write(tmp_path, "size: [3, 3]\n", "tiny.yml")
    for arg in (p, str(p)):
        spec = load_map(arg)
        assert isinstance(spec, MapSpec) and spec.name == "tiny" and spec.source == str(p)
        assert spec.build_world(2).segments.shape == (2, 0, 4)
    with pytest.raises(MapError, match="not found"):
        load_map(tmp_path / "missing.yaml")


def test_unknown_map_name_lists_available():
    with pytest.raises(MapError) as e:
        load_map("areena")
    msg = str(e.value)
    assert "areena" in msg and all(n in msg for n in SHIPPED)


BAD_FILES = {
    "unknown top-level key": ("size: [10, 10]\ncolour: red\n", "colour: unknown key"),
    "unknown nested key": ("size: [10, 10]\nboxes:\n  - {center: [0, 0], size: [1, 1], yaw_deg: 30}\n", "boxes[0].yaw_deg"),
    "unknown random key": (
        "size: [10, 10]\nrandom_boxes: {count: 1, size_x: [1, 1], size_y: [1, 1], spacing: 2}\n",
        "random_boxes.spacing",
    ),
    "missing size": ("walls: boundary\n", "size: required key is missing"),
    "string number": ("size: [ten, 10]\n", "size: expected 2 positive numbers, got ['ten', 10]"),
    "bool number": ("size: [true, 10]\n", "size: expected 2 positive numbers"),
    "wrong type radius": ("size: [10, 10]\ncircles: [{center: [0, 0], radius: big}]\n", "circles[0].radius"),
    "wall wrong length": ("size: [10, 10]\nwalls: [boundary, [0, 0, 1]]\n", "walls[1]: expected 4 numbers"),
    "unknown wall string": ("size: [10, 10]\nwalls: outline\n", "walls: expected 'boundary'"),
    "zero-length wall": ("size: [10, 10]\nwalls: [[1, 1, 1, 1]]\n", "walls[0]: wall has zero length"),
    "boxes not a list": ("size: [10, 10]\nboxes: {center: [0, 0], size: [1, 1]}\n", "boxes: expected a list"),
    "negative box size": (
        "size: [10, 10]\nboxes:\n"
        "  - {center: [0, 0], size: [1, 1]}\n  - {center: [1, 1], size: [1, 1]}\n"
        "  - {center: [2, 2], size: [0.5, -1]}\n",
        "boxes[2].size: expected 2 positive numbers, got [0.5, -1]",
    ),
    "zero world size": ("size: [0, 10]\n", "size: expected 2 positive numbers"),
    "box outside world": ("size: [10, 10]\nboxes: [{center: [4.9, 0], size: [1, 1]}]\n", "boxes[0]: a corner of the box (5.4, -0.5) lies outside"),
    "turned box outside": ("size: [10, 10]\nboxes: [{center: [4.4, 0], size: [1, 1], yaw: 0.785}]\n", "boxes[0]: a corner"),
    "circle outside world": ("size: [10, 10]\ncircles: [{center: [0, -4.8], radius: 0.3}]\n", "circles[0]: the circle's edge point (0, -5.1) lies outside"),
    "wall outside world": ("size: [10, 10]\nwalls: [[0, 0, 6, 0]]\n", "walls[0]: an endpoint (6, 0) lies outside"),
    "min > max": (
        "size: [10, 10]\nrandom_boxes: {count: 1, size_x: [0.6, 0.4], size_y: [1, 1]}\n",
        "random_boxes.size_x: expected [min, max] with min <= max",
    ),
    "negative count": ("size: [10, 10]\nrandom_circles: {count: -1, radius: [0.1, 0.2]}\n", "random_circles.count: expected an integer in [0, 64]"),
    "float count": ("size: [10, 10]\nrandom_circles: {count: 2.5, radius: [0.1, 0.2]}\n", "random_circles.count"),
    "negative margin": ("size: [10, 10]\nrandom_circles: {count: 1, radius: [0.1, 0.2], margin: -0.1}\n", "random_circles.margin"),
    "random too big": ("size: [10, 10]\nrandom_boxes: {count: 1, size_x: [1, 12], size_y: [1, 1]}\n", "random_boxes.size_x: the largest box, 12 m across"),
    "name not a string": ("name: [a]\nsize: [10, 10]\n", "name: expected a non-empty string"),
    "top level not a mapping": ("- size\n", "expected a mapping"),
    "empty file": ("", "the map file is empty"),
    "yaml syntax": ("size: [10, 10\nwalls: boundary\n", "YAML syntax error at line"),
    "duplicate key": ("size: [10, 10]\nwalls: boundary\nsize: [5, 5]\n", "size: duplicate key at line 3"),
}


@pytest.mark.parametrize("case", list(BAD_FILES))
def test_malformed_file_names_file_and_key(tmp_path, case):
    text, expected = BAD_FILES[case]
    path = write(tmp_path, text, "bad_map.yaml")
    with pytest.raises(MapError) as e:
        load_map(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: "), msg
    assert expected in msg, msg
    assert isinstance(e.value, ValueError)


def test_obstacle_touching_the_edge_is_allowed(tmp_path):
    text = "size: [10, 10]\nboxes: [{center: [4.5, 0], size: [1, 1]}]\ncircles: [{center: [0, 4.7], radius: 0.3}]\n"
    spec = load_map(write(tmp_path, text, "edge.yaml"))
    assert spec.n_fixed_boxes == 1 and spec.n_fixed_circles == 1


# --------------------------------------------------------------------------- rendering


def _fig():
    fig = Figure(figsize=(4, 4))
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def test_render_functions_draw_on_agg():
    from torchnav.render import draw_goal, draw_rays, draw_robots, draw_world, plot_map

    spec = load_map("street")
    world = spec.build_world(2)
    k = spec.n_fixed_boxes
    world.boxes[1, k] = torch.tensor([1.0, -3.0, 0.5, 0.3, 0.4])  # fill one random slot in env 1 only
    world.box_mask[1, k] = True
    fig, ax = _fig()
    draw_world(ax, world, env=1)
    patches = ax.collections[-1].get_paths()
    assert len(patches) == spec.n_fixed_circles + spec.n_fixed_boxes + 1  # masked-out slots not drawn
    fig2, ax2 = _fig()
    draw_world(ax2, world, env=0)
    assert len(ax2.collections[-1].get_paths()) == spec.n_fixed_circles + spec.n_fixed_boxes

    pose = torch.tensor([[0.0, -3.0, 0.5], [1.0, 2.0, -1.0]], requires_grad=True)
    draw_robots(ax, pose, 0.2, env=[0, 1])
    draw_robots(ax, pose * 1.0, 0.2, env=None)
    for lidar in (lidar_params(n_rays=16, fov=2 * math.pi), lidar_params(n_rays=5, fov=math.pi, offset=(0.1, 0.0, 0.0))):
        ranges = torch.full((2, lidar.n_rays), 2.0, requires_grad=True)
        draw_rays(ax, pose, ranges, lidar, env=1)
    draw_goal(ax, torch.tensor([[3.0, 3.0], [-3.0, 1.0]]), env=0, radius=0.3)
    fig.savefig(io.BytesIO(), format="png")

    ax3 = plot_map(spec, n_samples=1)
    assert "street" in ax3.get_title() and "8 circles" in ax3.get_title()
    buf = io.BytesIO()
    ax3.figure.savefig(buf, format="png")
    assert buf.tell() > 1000


def test_draw_rays_geometry():
    from torchnav.render import draw_rays

    lidar = lidar_params(n_rays=3, fov=math.pi, max_range=5.0, offset=(0.5, 0.0, 0.0))
    pose = torch.tensor([[1.0, 2.0, math.pi / 2]], dtype=torch.float64)  # facing +y, so the sensor sits at (1, 2.5)
    ranges = torch.tensor([[1.0, 2.0, 5.0]])
    fig, ax = _fig()
    draw_rays(ax, pose, ranges, lidar)
    segs = np.asarray(ax.collections[-1].get_segments())
    np.testing.assert_allclose(segs[:, 0], [[1.0, 2.5]] * 3, atol=1e-9)
    # Ray 0 looks to the robot's right (+x), ray 1 ahead (+y), ray 2 to its left (-x).
    np.testing.assert_allclose(segs[:, 1], [[2.0, 2.5], [1.0, 4.5], [-4.0, 2.5]], atol=1e-9)
