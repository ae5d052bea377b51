"""Tracks: shipped files, fillets and splines, strict YAML errors, PNG masks, arc-length
projection with a window that never jumps across a crossing."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from torchnav.tracks import (
    TrackError,
    available_tracks,
    load_track,
    parse_track,
    path_pose,
    project_on_path,
    track_from_mask,
    wrap_delta,
)


def write(tmp_path: Path, text: str, name: str = "t.yaml") -> str:
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def test_shipped_tracks_load_with_their_documented_lengths():
    assert available_tracks() == ["course", "loop", "oval"]
    oval = load_track("oval")
    assert oval.length == pytest.approx(2 * 1.2 + 2 * math.pi * 0.4, rel=1e-3)  # chords of a 2 cm resampling
    course = load_track("course")
    assert course.lap[0].tolist() == [-0.6, -0.5] and len(course.lines) == 3
    for name in available_tracks():
        t = load_track(name)
        steps = np.linalg.norm(np.diff(t.lap, axis=0), axis=1)
        assert steps.max() <= t.spacing + 1e-9 and np.allclose(t.lap[0], t.lap[-1])


def test_fillet_is_an_exact_circular_arc():
    t = parse_track({"width": 0.02, "spacing": 0.005, "lines": [
        {"points": [[0, 0], [1, 0], [1, 1], [0, 1]], "closed": True, "corner_radius": 0.5}]})
    # a 1 x 1 square with 0.5 m fillets is a circle of radius 0.5 around (0.5, 0.5)
    r = np.linalg.norm(t.lap - 0.5, axis=1)
    assert np.abs(r - 0.5).max() < 1e-5
    assert t.length == pytest.approx(math.pi, rel=1e-4)


def test_smooth_line_passes_through_its_points():
    pts = [[0, 0], [1, 0.3], [2, -0.2], [1, -1]]
    t = parse_track({"width": 0.02, "spacing": 0.001, "lines": [{"points": pts, "closed": True, "smooth": True}]})
    for p in pts:
        assert np.linalg.norm(t.lap - np.asarray(p, float), axis=1).min() < 1e-3


@pytest.mark.parametrize(
    "text, match",
    [
        ("width: 0.02\nlines:\n  - points: [[0, 0], [1, 0], [1, 1]]\n    clossed: true\n", r"t\.yaml: lines\[0\]\.clossed: unknown key \(did you mean 'closed'\?\)"),
        ("width: 0.02\nlines:\n  - points: [[0, 0], [1, 0]]\n", r"no closed line"),
        ("width: -1\nlines: []\n", r"t\.yaml: width: expected a positive number"),
        ("width: 0.02\nlines:\n  - points: [[0, 0], [1, 0], [1, 1]]\n    closed: true\n    corner_radius: 0.9\n", r"lines\[0\]\.corner_radius: corner radii"),
        ("width: 0.02\nlines:\n  - points: [[0, 0], [1, 0], [1, 1]]\n    closed: true\n    corner_radius: [0.1, 0.1]\n", r"lines\[0\]\.corner_radius: expected 3"),
        ("width: 0.02\nlines:\n  - points: [[0, 0], [1, zero], [1, 1]]\n    closed: true\n", r"lines\[0\]\.points: expected a list"),
        ("width: 0.02\nlines:\n  - {points: [[0, 0], [1, 0], [1, 1]], closed: true, lap: true}\n  - {points: [[0, 0], [1, 0], [0, 1]], closed: true, lap: true}\n", "only one line"),
        ("width: 0.02\nwidth: 0.03\n", r"width: duplicate key at line 2"),
        ("image: nothere.png\nresolution: 0.01\n", r"t\.yaml: image: .*not found"),
    ],
)
def test_malformed_track_files_name_the_file_and_key(tmp_path, text, match):
    with pytest.raises(TrackError, match=match):
        load_track(write(tmp_path, text))


def test_unknown_track_lists_the_shipped_ones():
    with pytest.raises(TrackError, match="available tracks: course, loop, oval"):
        load_track("ovall")


def test_unreadable_png_is_a_clear_error(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(TrackError, match=r"t\.yaml: image: .*bad\.png: cannot read image"):
        load_track(write(tmp_path, "image: bad.png\nresolution: 0.01\n"))


def ring_mask(size=160, radius=55, half_width=2.5):
    yy, xx = np.mgrid[:size, :size] + 0.5
    r = np.hypot(xx - size / 2, yy - size / 2)
    return np.abs(r - radius) <= half_width


def test_png_ring_track(tmp_path):
    from PIL import Image

    mask = ring_mask()
    Image.fromarray((mask * 255).astype(np.uint8)).save(tmp_path / "ring.png")
    t = load_track(write(tmp_path, "image: ring.png\nresolution: 0.01\nspacing: 0.02\n"))
    # centred on the origin: the centreline is the 0.55 m circle, traced counter-clockwise
    r = np.linalg.norm(t.segments[:, :2], axis=1)
    assert np.abs(r - 0.55).max() < 0.015
    assert t.width == pytest.approx(0.05, rel=0.15)
    assert t.length == pytest.approx(2 * math.pi * 0.55, rel=0.03)
    cross = t.lap[0, 0] * t.lap[3, 1] - t.lap[0, 1] * t.lap[3, 0]
    assert cross > 0


def test_png_with_a_crossing_needs_an_explicit_lap():
    mask = ring_mask()
    mask[78:83, :] = True  # a horizontal bar across the ring
    with pytest.raises(TrackError, match="not a single loop"):
        track_from_mask(mask, 0.01)
    lap = parse_track({"width": 0.02, "lines": [{"points": [[-0.55, 0], [0, -0.55], [0.55, 0], [0, 0.55]],
                                                  "closed": True, "smooth": True}]}).lap
    t = track_from_mask(mask, 0.01, lap=lap)
    assert t.length == pytest.approx(float(np.linalg.norm(np.diff(lap, axis=0), axis=1).sum()))


# --------------------------------------------------------------------------- projection


def square_path(side=1.0, n=40):
    """Closed CCW square path with ``n`` vertices per side, first point repeated."""
    s = np.linspace(0, 4 * side, 4 * n + 1)
    xy = []
    for v in s:
        k, f = int(min(v // side, 3)), (v % side) if v < 4 * side else side
        corners = [(0, 0), (side, 0), (side, side), (0, side), (0, 0)]
        a, b = np.asarray(corners[k], float), np.asarray(corners[k + 1], float)
        xy.append(a + (b - a) * (f / side))
    return torch.tensor(np.asarray(xy)), torch.tensor(np.linspace(0, 4 * side, 4 * n + 1))


def test_project_and_path_pose_are_inverse_on_a_known_path():
    path, s_path = square_path()
    s = torch.tensor([0.0, 0.3, 1.2, 1.7, 2.5, 3.99], dtype=torch.float64)
    pose = path_pose(path, s_path, s)
    torch.testing.assert_close(pose[:, :2], torch.tensor([[0, 0], [0.3, 0], [1, 0.2], [1, 0.7], [0.5, 1], [0, 0.01]], dtype=torch.float64))
    assert pose[1, 2].item() == pytest.approx(0.0) and pose[3, 2].item() == pytest.approx(math.pi / 2)
    off = pose[:, :2] + 0.02 * torch.stack((-torch.sin(pose[:, 2]), torch.cos(pose[:, 2])), -1)
    got, dist = project_on_path(off, path, s_path, s, window=3)
    torch.testing.assert_close(got[1:5], s[1:5])
    torch.testing.assert_close(dist[1:5], torch.full((4,), 0.02, dtype=torch.float64))


def test_progress_and_laps_on_a_known_path():
    """Driving the square counter-clockwise 2.5 times counts 10 m of progress and 2 laps;
    driving back the same way undoes it."""
    path, s_path = square_path()
    s_true = torch.arange(0, 10.0 + 1e-9, 0.013, dtype=torch.float64)
    pts = path_pose(path, s_path, s_true)[:, :2]
    s_prev, progress = torch.zeros(1, dtype=torch.float64), torch.zeros(1, dtype=torch.float64)
    for p in pts[1:]:
        s_new, _ = project_on_path(p[None], path, s_path, s_prev, window=2)
        progress = progress + wrap_delta(s_new - s_prev, 4.0)
        s_prev = s_new
    assert progress.item() == pytest.approx(s_true[-1].item(), abs=1e-6)
    assert int(progress.item() // 4.0) == 2
    for p in pts.flip(0)[1:]:
        s_new, _ = project_on_path(p[None], path, s_path, s_prev, window=2)
        progress = progress + wrap_delta(s_new - s_prev, 4.0)
        s_prev = s_new
    assert progress.item() == pytest.approx(0.0, abs=1e-6)


def test_windowed_projection_stays_on_its_branch_at_a_crossing():
    course = load_track("course")
    tt = course.tensors(0.06, dtype=torch.float64)
    # the lap crosses itself at (0, 0): once going up-right, once going up-left
    crossing = torch.zeros(1, 2, dtype=torch.float64)
    s_all = tt.lap_s[:-1]
    near = (path_pose(tt.lap, tt.lap_s, s_all)[:, :2].norm(dim=-1) < 0.011).nonzero().squeeze(-1)
    s_a, s_b = s_all[near].min(), s_all[near].max()
    assert s_b - s_a > 1.0  # two different passes
    for s0 in (s_a, s_b):
        s, d = project_on_path(crossing, tt.lap, tt.lap_s, s0.reshape(1) - 0.05, window=6)
        assert abs(s.item() - s0.item()) < 0.02 and d.item() < 0.01
