"""Downward reflectance sensors: coverage on constructed positions, the segment grid against
brute force, modes, noise from an explicit generator, and gradients."""

from __future__ import annotations

import math

import pytest
import torch

from torchnav.sim.floor import (
    FloorSensorParams,
    band_coverage,
    build_segment_grid,
    floor_readings,
    nearest_distance,
    nearest_distance_brute,
    sensor_points,
)

W, R = 0.025, 0.005  # line width, footprint radius (m)
LINE = torch.tensor([[-1.0, 0.0, 1.0, 0.0]], dtype=torch.float64)  # the x axis from -1 to 1 m


def readings_at(ys, mode="analog", **kw):
    """Readings of single sensors centred at (0, y) above the x-axis line."""
    p = FloorSensorParams(count=1, forward=0.0, radius=R, mode=mode, **kw)
    pose = torch.tensor([[0.0, y, 0.0] for y in ys], dtype=torch.float64)
    grid = build_segment_grid(LINE, reach=0.05)
    d = nearest_distance(sensor_points(pose, p), grid)
    return floor_readings(d, W / 2, p)[:, 0]


def test_readings_centred_half_over_the_edge_and_off():
    r = readings_at([0.0, W / 2, -W / 2, W / 2 + R, W / 2 + R + 0.001, 0.3])
    torch.testing.assert_close(r, torch.tensor([1.0, 0.5, 0.5, 0.0, 0.0, 0.0], dtype=torch.float64))


def test_partial_coverage_is_the_circular_segment_area():
    # The sensor's centre R/2 outside the edge: the line covers a circular segment of height R/2.
    h = R / 2
    seg_area = R * R * math.acos((R - h) / R) - (R - h) * math.sqrt(2 * R * h - h * h)
    r = readings_at([W / 2 + h])
    assert r.item() == pytest.approx(seg_area / (math.pi * R * R), rel=1e-9)


def test_narrow_line_under_a_wide_footprint():
    # A line narrower than the footprint: coverage = area of the band inside the disc.
    c = band_coverage(torch.tensor([0.0], dtype=torch.float64), half_width=0.002, radius=0.01)
    u = 0.2  # half width / radius
    exact = 2 * (math.asin(u) + u * math.sqrt(1 - u * u)) / math.pi
    assert c.item() == pytest.approx(exact, rel=1e-9)


def test_sensor_layout_right_to_left_ahead_of_the_axle():
    p = FloorSensorParams(count=5, spacing=0.01, forward=0.08)
    pts = sensor_points(torch.tensor([[1.0, 2.0, math.pi / 2]]), p)[0]
    expected = torch.tensor([[1.0 + 0.02, 2.08], [1.01, 2.08], [1.0, 2.08], [0.99, 2.08], [0.98, 2.08]])
    torch.testing.assert_close(pts, expected, atol=1e-6, rtol=0)


def test_binary_mode_thresholds_the_coverage():
    r = readings_at([0.0, W / 2 - 0.001, W / 2 + 0.001, 0.1], mode="binary", threshold=0.5)
    assert r.tolist() == [1.0, 1.0, 0.0, 0.0]


def test_smooth_mode_is_monotone_with_nonzero_gradient():
    y = torch.tensor([0.0, 0.01, 0.02, 0.03], dtype=torch.float64, requires_grad=True)
    p = FloorSensorParams(count=1, forward=0.0, mode="smooth")
    pose = torch.stack((torch.zeros_like(y), y, torch.zeros_like(y)), -1)
    d = nearest_distance(sensor_points(pose, p), build_segment_grid(LINE, reach=0.1))
    r = floor_readings(d, W / 2, p)[:, 0]
    assert (r[:-1] > r[1:]).all() and r[0] > 0.9 and r[-1] < 0.1
    r.sum().backward()
    assert torch.isfinite(y.grad).all() and (y.grad[1:] < 0).all()


def test_noise_comes_from_the_generator_and_is_clamped():
    p = FloorSensorParams(count=1, noise_std=0.1)
    d = torch.full((1000, 1), W / 2)
    a = floor_readings(d, W / 2, p, torch.Generator().manual_seed(3))
    b = floor_readings(d, W / 2, p, torch.Generator().manual_seed(3))
    torch.testing.assert_close(a, b)
    assert a.min() >= 0 and a.max() <= 1 and a.std() > 0.05 and abs(a.mean() - 0.5) < 0.02
    torch.testing.assert_close(floor_readings(d, W / 2, p), torch.full_like(d, 0.5))  # no generator: no noise


def test_grid_distance_equals_brute_force_within_reach():
    gen = torch.Generator().manual_seed(0)
    seg = torch.rand(60, 4, generator=gen, dtype=torch.float64) * 2 - 1
    grid = build_segment_grid(seg, reach=0.07, cell=0.03)
    pts = torch.rand(4000, 2, generator=gen, dtype=torch.float64) * 2.4 - 1.2
    exact = nearest_distance_brute(pts, seg)
    fast = nearest_distance(pts, grid)
    torch.testing.assert_close(fast, exact.clamp(max=0.07))
    assert grid.cand.shape[1] < seg.shape[0]


def test_disc_coverage_gradcheck():
    d = torch.tensor([0.0, 0.004, 0.011, 0.0126, 0.016, 0.03], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: band_coverage(x, W / 2, R), (d,))
    # exactly at the footprint's edge (|u| = 1) the gradient is finite
    e = torch.tensor([W / 2 + R, W / 2 - R], dtype=torch.float64, requires_grad=True)
    band_coverage(e, W / 2, R).sum().backward()
    assert torch.isfinite(e.grad).all()


def test_params_validation():
    with pytest.raises(ValueError, match="mode='digital': must be analog or binary or smooth"):
        FloorSensorParams(mode="digital")
    with pytest.raises(ValueError, match="threshold"):
        FloorSensorParams(threshold=1.0)
