"""ROS map_server maps: Nav2's pixel rules (modes, negate, thresholds, alpha), unknown cells, cropping,
the map-frame transform, the embedding key, tasks and worlds on such a map, and every malformed field."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from torchnav.maps import MapError, available_maps, load_map, parse_map
from torchnav.maps import map_server as ms
from torchnav.maps import occupancy
from torchnav.maps.occupancy import mask_rectangles
from torchnav.sim import points_clearance
from torchnav.yamlcheck import Ctx

ROOT = Path(__file__).resolve().parents[1]
LAB = ROOT / "examples" / "maps"
HEADER = {"resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196}


def image(tmp_path: Path, pixels, name: str = "map.pgm", mode: str | None = None) -> str:
    """Writes ``pixels`` (uint8 ``(H, W)`` grey, ``(H, W, 2)`` grey + alpha or ``(H, W, 4)`` RGBA) and returns its file name."""
    arr = np.asarray(pixels, dtype=np.uint8)
    im = Image.fromarray(arr) if mode is None else Image.fromarray(arr).convert(mode)
    im.save(tmp_path / name)
    return name


def write_map(tmp_path: Path, pixels=None, name: str = "map", img: str | None = None, **keys) -> Path:
    """A map_server YAML ``name``.yaml next to its image (``pixels`` written as ``name``.pgm unless ``img``
    names one), with :data:`HEADER` and ``keys`` (a value None drops that key)."""
    if img is None:
        img = image(tmp_path, pixels, f"{name}.pgm")
    fields = {"image": img, **HEADER, **keys}
    lines = [f"{k}: {v if not isinstance(v, list) else '[' + ', '.join(map(str, v)) + ']'}" for k, v in fields.items() if v is not None]
    path = tmp_path / f"{name}.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def grid(path: Path) -> np.ndarray:
    """The cells ``(H, W)`` (map_server.FREE, OCCUPIED, UNKNOWN) of a map_server YAML."""
    import yaml

    return ms.read_grid(Ctx(str(path), MapError), yaml.safe_load(path.read_text()), path.parent).cells


def occupied(spec) -> np.ndarray:
    """Rasterise a spec's (axis-aligned) boxes back onto its pixel grid (resolution 0.1 m), row 0 at the top."""
    w, h = (round(s / 0.1) for s in spec.size)
    out = np.zeros((h, w), dtype=bool)
    for cx, cy, hx, hy, yaw in spec.boxes:
        assert yaw == 0.0
        c0, c1 = round((cx - hx + spec.size[0] / 2) / 0.1), round((cx + hx + spec.size[0] / 2) / 0.1)
        r0, r1 = round((spec.size[1] / 2 - cy - hy) / 0.1), round((spec.size[1] / 2 - cy + hy) / 0.1)
        assert not out[r0:r1, c0:c1].any()  # disjoint
        out[r0:r1, c0:c1] = True
    return out


F, O, U = ms.FREE, ms.OCCUPIED, ms.UNKNOWN


# --------------------------------------------------------------------------- pixel rules


def test_trinary_thresholds_are_strict_and_read_occupancy_as_255_minus_v():
    # p = 1 - v / 255: 0 -> 1.0, 89 -> 0.651, 90 -> 0.647, 205 -> 0.196 (just above free_thresh 0.196), 206 -> 0.192, 254 -> 0.004
    v = np.array([[0, 89, 90, 205, 206, 254, 255]], dtype=np.uint8)
    cells = ms.classify(v / 255.0, None, "trinary", False, 0.65, 0.196)
    assert cells.tolist() == [[O, O, U, U, F, F, F]]
    # a pixel exactly at a threshold is neither occupied nor free (p > occupied_thresh, p < free_thresh)
    at = 1.0 - 100 / 255.0
    assert ms.classify(np.array([[100 / 255.0]]), None, "trinary", False, at, 0.1).tolist() == [[U]]
    assert ms.classify(np.array([[100 / 255.0]]), None, "trinary", False, 0.9, at).tolist() == [[U]]


def test_negate_reads_occupancy_as_v(tmp_path):
    v = [[0, 10, 120, 205, 254]]
    plain = grid(write_map(tmp_path, v, "plain"))
    negated = grid(write_map(tmp_path, v, "negated", negate=1))
    assert plain.tolist() == [[O, O, U, U, F]]
    assert negated.tolist() == [[F, F, U, O, O]]  # p = v / 255: 205 -> 0.80, occupied
    assert (grid(write_map(tmp_path, v, "as_bool", negate="true")) == negated).all()


def test_trinary_averages_alpha_in_and_scale_makes_transparent_pixels_unknown(tmp_path):
    # grey + alpha: trinary shade = (3 grey + alpha) / 4 (Nav2 averages the opacity in with R, G, B)
    px = np.array([[[0, 255], [0, 0], [254, 255], [254, 0], [150, 255]]], dtype=np.uint8)  # grey, alpha
    img = image(tmp_path, px, "la.png")
    # (0+...+255)/4 = 63.75 -> p 0.75 occupied; transparent black: p 1.0; opaque white: free;
    # transparent white: (762 + 0) / 4 = 190.5 -> p 0.253, unknown; opaque 150: p 0.41, unknown
    assert grid(write_map(tmp_path, name="tri", img=img)).tolist() == [[O, O, F, U, U]]
    # scale: any transparency is unknown; the opaque pixels by their grey alone; in between (150) unknown to torchnav
    assert grid(write_map(tmp_path, name="scale", img=img, mode="scale")).tolist() == [[O, U, F, U, U]]
    # RGBA: the mean of R, G, B, not luma: red (255, 0, 0) is p 0.667 (luma: 0.70), cyan (0, 255, 255) p 0.333 (luma: 0.30)
    rgba = image(tmp_path, [[[255, 0, 0, 255], [0, 255, 255, 255], [0, 0, 0, 255], [250, 250, 250, 255], [255, 255, 255, 128]]], "rgba.png")
    cells = grid(write_map(tmp_path, name="rgba", img=rgba, mode="scale", occupied_thresh=0.68, free_thresh=0.32))
    assert cells.tolist() == [[U, U, O, F, U]]
    # an RGB image without alpha: trinary and scale agree
    rgb = image(tmp_path, [[[255, 0, 0], [10, 10, 10], [250, 250, 250]]], "rgb.png")
    assert grid(write_map(tmp_path, name="rgb_t", img=rgb)).tolist() == grid(write_map(tmp_path, name="rgb_s", img=rgb, mode="scale")).tolist() == [[O, O, F]]


def test_raw_mode_reads_the_grey_level_as_percent_occupancy(tmp_path):
    # raw: the grid value is the grey level; 0..100 an occupancy in percent (the thresholds read it), above 100 unknown
    v = [[0, 19, 20, 50, 65, 66, 100, 101, 205, 255]]
    cells = grid(write_map(tmp_path, v, "raw", mode="raw"))
    assert cells.tolist() == [[F, F, U, U, U, O, O, U, U, U]]  # free below 0.196, occupied above 0.65
    assert (grid(write_map(tmp_path, v, "raw_negated", mode="raw", negate=1)) == cells).all()  # negate does not apply


def test_sixteen_bit_images_read_like_eight_bit(tmp_path):
    v8 = np.array([[0, 90, 205, 254]], dtype=np.uint8)
    Image.fromarray(v8.astype(np.uint16) * 257).save(tmp_path / "deep.png")
    assert Image.open(tmp_path / "deep.png").mode.startswith("I")
    assert grid(write_map(tmp_path, name="deep", img="deep.png")).tolist() == grid(write_map(tmp_path, v8, "flat")).tolist()


# --------------------------------------------------------------------------- unknown cells, cropping, frames


def room(unknown_inside: bool = False) -> np.ndarray:
    """A 12 x 16 px map_server image: unknown margin of 2 px, then a 1 px wall around free space; row 0 at the top."""
    px = np.full((12, 16), 205, dtype=np.uint8)
    px[2:10, 2:14] = 0
    px[3:9, 3:13] = 254
    px[5:7, 8:10] = 0  # a pillar
    if unknown_inside:
        px[4, 4] = 205
    return px


def test_unknown_cells_are_occupied_by_default_or_free(tmp_path):
    path = write_map(tmp_path, room(unknown_inside=True))
    spec = load_map(path)
    cells = grid(path)[2:10, 2:14]
    assert spec.size == pytest.approx((1.2, 0.8)) and spec.name == "map" and spec.source == str(path)
    assert (occupied(spec) == (cells != F)).all()  # the unknown pixel is an obstacle
    (tmp_path / "free.yaml").write_text("map_server: {yaml: map.yaml, unknown: free}\n")
    free = load_map(tmp_path / "free.yaml")
    assert (occupied(free) == (cells == O)).all()
    assert len(spec.segments) == len(free.segments) == 4  # the world's edges are walls


def test_crop_keeps_the_known_area_or_the_whole_image(tmp_path):
    write_map(tmp_path, room())
    cropped = load_map(tmp_path / "map.yaml")
    (tmp_path / "whole.yaml").write_text("map_server: {yaml: map.yaml, crop: false}\n")
    whole = load_map(tmp_path / "whole.yaml")
    assert cropped.size == pytest.approx((1.2, 0.8)) and whole.size == pytest.approx((1.6, 1.2))
    assert (occupied(whole) == (room() != 254)).all()  # unknown margin occupied
    assert (occupied(whole)[2:10, 2:14] == occupied(cropped)).all()
    # the same map-frame point either way: the pillar (cols 8-9, rows 5-6 of 12) has its centre at map (0.9, 0.6)
    pillar = np.array([0.9, 0.6])
    for spec in (cropped, whole):
        xy = torch.tensor(spec.from_map_frame(pillar), dtype=torch.float32)
        assert points_clearance(xy[None, None], spec.build_world(1))[0, 0] < 0  # inside the pillar
    assert cropped.frame == pytest.approx((0.8, 0.6, 0.0)) and whole.frame == pytest.approx((0.8, 0.6, 0.0))
    (tmp_path / "edgeless.yaml").write_text("map_server: {yaml: map.yaml, boundary: false}\n")
    assert load_map(tmp_path / "edgeless.yaml").segments == ()


def test_origin_with_yaw_places_pixels_in_the_map_frame(tmp_path):
    yaw = 0.7
    path = write_map(tmp_path, room(), origin=[2.0, -1.0, yaw])
    spec = load_map(path)
    c, s = math.cos(yaw), math.sin(yaw)
    # pixel (row 5, col 8) of the 12-row image: its centre in the image frame, then in the map frame
    gx, gy = (8 + 0.5) * 0.1, (12 - 5 - 0.5) * 0.1
    in_map = np.array([2.0 + c * gx - s * gy, -1.0 + s * gx + c * gy])
    # in torchnav's world (cropped to cols 2..13, rows 2..9; centred): x = (8.5 - 8) * 0.1, y = (6 - 5.5) * 0.1
    world = spec.from_map_frame(in_map)
    np.testing.assert_allclose(world, [0.05, 0.05], atol=1e-12)
    np.testing.assert_allclose(spec.to_map_frame(world), in_map, atol=1e-12)
    # poses: the heading turns by the map's yaw; tensors stay tensors
    pose = torch.tensor([[0.3, -0.2, 3.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    there = spec.to_map_frame(pose)
    assert torch.is_tensor(there) and there.dtype == torch.float64
    assert there[1].tolist() == pytest.approx(list(spec.frame))
    assert float(there[0, 2]) == pytest.approx(3.0 + yaw - 2 * math.pi)  # wrapped into [-pi, pi]
    torch.testing.assert_close(spec.from_map_frame(there), pose)
    assert spec.frame[2] == yaw
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        spec.to_map_frame([1.0, 2.0, 3.0, 4.0])
    # an ordinary map's frame is the identity
    arena = load_map("arena")
    assert arena.frame == (0.0, 0.0, 0.0) and arena.to_map_frame([1.5, -2.0]).tolist() == [1.5, -2.0]


def test_equals_the_same_picture_as_a_torchnav_occupancy_map(tmp_path):
    # Black and white, no unknown pixel: map_server's trinary rule and occupancy's threshold agree.
    rng = np.random.default_rng(0)
    px = np.where(rng.random((20, 30)) < 0.2, 0, 255).astype(np.uint8)
    px[0, :] = px[-1, :] = 0  # known everywhere anyway: no crop
    Image.fromarray(px).save(tmp_path / "plan.png")
    server = load_map(write_map(tmp_path, name="server", img="plan.png", origin=[5.0, 3.0, 0.0]))
    ours = parse_map({"size": [3.0, 2.0], "walls": "boundary", "occupancy": {"image": "plan.png", "resolution": 0.1}}, base_dir=tmp_path)
    assert server.size == pytest.approx(ours.size)
    np.testing.assert_allclose(server.boxes, ours.boxes, atol=1e-12)
    np.testing.assert_allclose(server.segments, ours.segments, atol=1e-12)
    assert len(server.boxes) == len(mask_rectangles(px == 0))


# --------------------------------------------------------------------------- the shipped example, tasks and worlds


def test_example_lab_is_what_make_lab_draws():
    spec = importlib.util.spec_from_file_location("make_lab", LAB / "make_lab.py")
    make_lab = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_lab)
    drawn = make_lab.draw()
    assert (np.asarray(Image.open(LAB / "lab.pgm")) == drawn).all()
    lab = load_map(LAB / "lab.yaml")
    cells = grid(LAB / "lab.yaml")
    assert set(np.unique(drawn)) == {0, 205, 254} and (cells == U).any()
    assert lab.size == pytest.approx((8.3, 6.3)) and lab.frame == pytest.approx((3.0, 1.25, 0.0))
    assert "lab" not in available_maps()  # examples/ is not the shipped maps' folder


def test_task_on_an_embedded_map_server_map_starts_collision_free():
    from torchnav.envs import NavEnv
    from torchnav.tasks import CurriculumState, NavConfig, NavTask

    spec = load_map(LAB / "lab_clutter.yaml")
    lab = load_map(LAB / "lab.yaml")
    assert spec.boxes == lab.boxes and spec.segments == lab.segments and spec.frame == lab.frame
    assert spec.random_boxes.count == 3 and spec.movers.count == 2
    cfg = NavConfig(map=str(LAB / "lab_clutter.yaml"))
    task = NavTask(cfg, num_envs=64)
    state, _ = task.initial_state(CurriculumState.initial(cfg.curriculum), torch.Generator().manual_seed(1))
    assert not state.sim.collided.any()
    start_gap = points_clearance(state.start[:, None, :2], state.world)[:, 0]
    assert (start_gap >= cfg.robot.radius + cfg.reset.start_clearance - 1e-5).all()  # random boxes included
    assert (points_clearance(state.goal[:, None], state.world)[:, 0] >= cfg.reset.goal_clearance - 1e-5).all()
    assert state.world.box_mask[:, lab.n_fixed_boxes:].all()  # the random boxes found room
    xmin, ymin, xmax, ymax = spec.bounds
    assert ((state.start[:, 0].abs() < xmax) & (state.start[:, 1].abs() < ymax)).all()
    env = NavEnv(cfg, num_envs=4, seed=0)
    td = env.rollout(5, break_when_any_done=False)
    assert td["next", "reward"].shape[:2] == (4, 5) and torch.isfinite(td["next", "reward"]).all()


def test_a_map_server_file_is_a_world_family():
    from torchnav.envs import NavEnv
    from torchnav.tasks import NavConfig
    from torchnav.worlds import make_worlds

    family = f"map:{LAB / 'lab.yaml'}"
    batch = make_worlds(family, 3, 0.5, torch.Generator().manual_seed(0))
    assert batch.world.boxes.shape == (3, load_map(LAB / "lab.yaml").n_fixed_boxes, 5)
    assert (points_clearance(batch.start[:, None, :2], batch.world)[:, 0] > 0.2).all()
    cfg = NavConfig.from_dict({"worlds": {"families": {family: 1.0, "rooms": 1.0}}})
    env = NavEnv(cfg, num_envs=4, seed=0)
    assert env.rollout(3, break_when_any_done=False)["next", "done"].shape[:2] == (4, 3)


# --------------------------------------------------------------------------- malformed input


BAD = {
    "missing image": ({"image": None}, None, "image: required key is missing"),
    "image not a string": ({"image": 3}, None, "image: expected the path of a PGM or PNG file"),
    "image missing": ({"image": "nowhere.pgm"}, None, "nowhere.pgm: image file not found"),
    "image not an image": ({"image": "map.yaml"}, None, "image: "),
    "missing resolution": ({"resolution": None}, None, "resolution: required key is missing"),
    "negative resolution": ({"resolution": -0.05}, None, "resolution: expected a positive number, got -0.05"),
    "resolution a string": ({"resolution": "fine"}, None, "resolution: expected a positive number"),
    "origin 2 numbers": ({"origin": [0, 0]}, None, "origin: expected 3 numbers, got [0, 0]"),
    "origin a string": ({"origin": "zero"}, None, "origin: expected 3 numbers"),
    "missing origin": ({"origin": None}, None, "origin: required key is missing"),
    "negate 2": ({"negate": 2}, None, "negate: expected 0 or 1"),
    "negate a string": ({"negate": "maybe"}, None, "negate: expected 0 or 1"),
    "occupied_thresh above 1": ({"occupied_thresh": 1.5}, None, "occupied_thresh: expected a number in [0, 1]"),
    "free_thresh negative": ({"free_thresh": -0.1}, None, "free_thresh: expected a number in [0, 1]"),
    "free_thresh above occupied": ({"free_thresh": 0.7}, None, "free_thresh: must be below occupied_thresh (0.65), got 0.7"),
    "free_thresh equal": ({"free_thresh": 0.65}, None, "free_thresh: must be below occupied_thresh"),
    "missing free_thresh": ({"free_thresh": None}, None, "free_thresh: required key is missing"),
    "unknown mode": ({"mode": "binary"}, None, "mode: expected one of trinary, scale, raw, got 'binary'"),
    "typo key": ({"occupied_tresh": 0.6}, None, "occupied_tresh: unknown key (did you mean 'occupied_thresh'?)"),
    "no free pixel": ({}, [[0, 205], [205, 0]], "image: ", ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_malformed_map_server_fields_name_the_file_and_key(tmp_path, case):
    keys, pixels, message = BAD[case]
    path = write_map(tmp_path, room() if pixels is None else pixels, **keys)
    with pytest.raises(MapError) as e:
        load_map(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and message in msg, msg
    if case == "no free pixel":
        assert "no pixel is free" in msg


def test_fields_are_checked_before_the_image_is_read(tmp_path, monkeypatch):
    def read(*a, **k):
        raise AssertionError("the image was read")

    monkeypatch.setattr(ms, "read_image", read)
    with pytest.raises(MapError, match="mode: expected one of"):
        load_map(write_map(tmp_path, room(), mode="binary"))
    (tmp_path / "outer.yaml").write_text("map_server: {yaml: map.yaml, unknown: maybe}\n")
    with pytest.raises(MapError, match=r"outer.yaml: map_server.unknown: expected one of occupied, free, got 'maybe'"):
        load_map(tmp_path / "outer.yaml")


def test_an_image_too_big_is_refused_from_its_header(tmp_path, monkeypatch):
    monkeypatch.setattr(occupancy, "MAX_PIXELS", 100)
    path = write_map(tmp_path, room())
    with pytest.raises(MapError, match=r"map.yaml: image: .*map.pgm: 16 x 12 pixels is more than the 100 allowed"):
        load_map(path)


EMBED_BAD = {
    "with size": ("map_server: {yaml: map.yaml}\nsize: [2, 2]\n", "size: not with map_server"),
    "no yaml": ("map_server: {crop: true}\n", "map_server.yaml: required key is missing"),
    "yaml missing": ("map_server: {yaml: gone.yaml}\n", "map_server.yaml: " ),
    "yaml not yaml": ("map_server: {yaml: map.pgm}\n", "map_server.yaml: "),
    "not a map_server file": ("map_server: {yaml: plain.yaml}\n", "not a map_server map"),
    "bad field inside": ("map_server: {yaml: bad.yaml}\n", "map_server.yaml: "),
    "a map_server key at the top": ("map_server: {yaml: map.yaml}\nresolution: 0.05\n", "resolution: unknown key"),
    "unknown option": ("map_server: {yaml: map.yaml, unkown: free}\n", "map_server.unkown: unknown key (did you mean 'unknown'?)"),
    "crop not a bool": ("map_server: {yaml: map.yaml, crop: 1}\n", "map_server.crop: expected true or false"),
    "boundary twice": ("map_server: {yaml: map.yaml}\nwalls: boundary\n", "walls[0]: map_server.boundary (true by default)"),
    "box outside": ("map_server: {yaml: map.yaml}\nboxes: [{center: [1.0, 0], size: [0.2, 0.2]}]\n", "boxes[0]: a corner of the box"),
    "random box too big": ("map_server: {yaml: map.yaml}\nrandom_boxes: {count: 1, size_x: [1.0, 1.0], size_y: [0.1, 0.1]}\n",
                           "random_boxes.size_x: the largest box, 1 m across"),
}


@pytest.mark.parametrize("case", sorted(EMBED_BAD))
def test_malformed_embedding_names_the_file_and_key(tmp_path, case):
    text, message = EMBED_BAD[case]
    write_map(tmp_path, room())
    write_map(tmp_path, room(), "bad", resolution=0)
    (tmp_path / "plain.yaml").write_text("size: [2, 2]\n")
    outer = tmp_path / "outer.yaml"
    outer.write_text(text)
    with pytest.raises(MapError) as e:
        load_map(outer)
    msg = str(e.value)
    assert msg.startswith(f"{outer}: ") and message in msg, msg
    if case == "bad field inside":  # names both files and the inner key
        assert f"map_server.yaml: {tmp_path / 'bad.yaml'}: resolution: expected a positive number" in msg
    if case == "yaml missing":
        assert "gone.yaml: map_server YAML file not found" in msg


def test_embedding_adds_obstacles_in_torchnav_coordinates(tmp_path):
    write_map(tmp_path, room())
    (tmp_path / "outer.yaml").write_text(
        "name: furnished\nmap_server: {yaml: map.yaml}\nboxes: [{center: [-0.3, 0.0], size: [0.2, 0.2]}]\ncircles: [[0.3, -0.2, 0.05]]\n")
    spec = load_map(tmp_path / "outer.yaml")
    plain = load_map(tmp_path / "map.yaml")
    assert spec.name == "furnished" and spec.size == plain.size and spec.frame == plain.frame
    assert spec.boxes == ((-0.3, 0.0, 0.1, 0.1, 0.0), *plain.boxes) and spec.circles == ((0.3, -0.2, 0.05),)


def test_docs_show_the_example_files_verbatim():
    docs = (ROOT / "docs" / "maps.md").read_text()
    for name in ("lab.yaml", "lab_clutter.yaml"):
        assert (LAB / name).read_text() in docs, name


def test_a_map_server_map_among_the_shipped_maps_is_listed_and_loads_by_name(tmp_path, monkeypatch):
    from torchnav import yamlcheck
    from torchnav.maps import loader

    write_map(tmp_path, room(), "site")
    (tmp_path / "plain.yaml").write_text("size: [2, 2]\n")
    for module in (yamlcheck, loader):  # the data folder, as importlib.resources finds it
        monkeypatch.setattr(module, "shipped_folder", lambda package: tmp_path)
    assert available_maps() == ["plain", "site"]
    site = load_map("site")
    assert site.name == "site" and site.size == pytest.approx((1.2, 0.8)) and site.frame == pytest.approx((0.8, 0.6, 0.0))
