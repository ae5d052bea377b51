"""Curve construction (numpy, once per track) and arc-length projection (torch, every step).

Build: polylines with filleted corners (exact circular arcs of a given radius) or
Catmull-Rom splines through the points, resampled to a uniform spacing along
their arc length. Step: :func:`project_on_path` finds each robot's arc-length
position on the lap path by searching only a window of segments around its
previous position, so that a crossing of the track with itself (or with another
line) never makes the projection jump to the other branch.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

ARC_STEP = 0.002  # m, chord length used to sample arcs and splines before resampling
MAX_CURVE_POINTS = 1_000_000  # points of one dense or resampled line (2 km of arcs, 20 km of line at the default spacing)


def _check_count(n: float, what: str) -> None:
    """Refuse a curve of more than :data:`MAX_CURVE_POINTS` points before allocating it."""
    if not n <= MAX_CURVE_POINTS:
        raise CurveError(f"{what} would need {n:,.0f} points, more than the {MAX_CURVE_POINTS:,} allowed per line")


class CurveError(ValueError):
    """A curve cannot be built (message says why); loaders add the file and key."""


def fillet_polyline(points: np.ndarray, radii: np.ndarray, closed: bool) -> np.ndarray:
    """Dense polyline ``(N, 2)`` through ``points`` ``(n, 2)`` whose corner ``i`` is replaced by a
    circular arc of radius ``radii[i]`` (m; 0 keeps the sharp corner) tangent to both edges.

    Open polylines keep their end points (their end radii are ignored). Raises
    :class:`CurveError` if two fillets overlap on an edge or an edge has zero length.
    """
    n = len(points)
    edges = (np.roll(points, -1, axis=0) - points) if closed else np.diff(points, axis=0)
    lengths = np.linalg.norm(edges, axis=1)
    if (lengths < 1e-9).any():
        i = int(np.argmax(lengths < 1e-9))
        raise CurveError(f"points {i} and {(i + 1) % n} coincide")
    dirs = edges / lengths[:, None]
    corners = range(n) if closed else range(1, n - 1)
    fillets: dict[int, tuple[float, np.ndarray]] = {}
    total = 0
    for i in corners:
        r = float(radii[i])
        a, b = dirs[i - 1], dirs[i % len(dirs)]
        turn = math.atan2(a[0] * b[1] - a[1] * b[0], float(a @ b))
        if r <= 0 or abs(turn) < 1e-9:
            continue
        if abs(turn) > math.pi - 1e-3:
            raise CurveError(f"point {i}: the line turns back on itself, no fillet is possible")
        t = r * math.tan(abs(turn) / 2)
        start = points[i] - a * t
        normal = np.array((-a[1], a[0])) * (1.0 if turn > 0 else -1.0)
        centre = start + r * normal
        arc = r * abs(turn)
        total += arc / ARC_STEP
        _check_count(total, f"the fillets (corner_radius, sampled every {ARC_STEP} m) up to point {i}")
        k = max(2, int(math.ceil(arc / ARC_STEP)) + 1)
        phi0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
        phi = phi0 + np.linspace(0.0, turn, k)
        fillets[i] = (t, centre + r * np.stack((np.cos(phi), np.sin(phi)), axis=1))
    for e in range(len(edges)):
        used = fillets.get(e, (0.0,))[0] + fillets.get((e + 1) % n if closed else e + 1, (0.0,))[0]
        if used > lengths[e] + 1e-9:
            raise CurveError(
                f"corner radii at points {e} and {(e + 1) % n} need {used:.4g} m of the edge between them, "
                f"which is only {lengths[e]:.4g} m long"
            )
    out = [] if closed else [points[:1]]
    for i in (range(n) if closed else range(1, n - 1)):
        out.append(fillets[i][1] if i in fillets else points[i:i + 1])
    if not closed:
        out.append(points[-1:])
    return np.concatenate(out, axis=0)


def catmull_rom(points: np.ndarray, closed: bool) -> np.ndarray:
    """Dense centripetal Catmull-Rom spline ``(N, 2)`` through every point (no cusps or loops
    within a span). Open splines extend their end tangents by mirrored phantom points."""
    p = np.asarray(points, dtype=np.float64)
    if closed:
        ext = np.concatenate((p[-1:], p, p[:2]))
    else:
        ext = np.concatenate((2 * p[:1] - p[1:2], p, 2 * p[-1:] - p[-2:-1]))
    _check_count(float(np.linalg.norm(np.diff(ext[1:-1], axis=0), axis=1).sum()) / ARC_STEP, f"the spline (sampled every {ARC_STEP} m)")
    out = []
    for j in range(len(ext) - 3):
        p0, p1, p2, p3 = ext[j:j + 4]
        d01, d12, d23 = (max(float(np.linalg.norm(q - r)), 1e-9) ** 0.5 for q, r in ((p1, p0), (p2, p1), (p3, p2)))
        t0, t1 = 0.0, d01
        t2, t3 = t1 + d12, t1 + d12 + d23
        k = max(2, int(math.ceil(np.linalg.norm(p2 - p1) / ARC_STEP)) + 1)
        t = np.linspace(t1, t2, k)[:, None]
        a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1
        a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2
        a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3
        b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2
        b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3
        c = (t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2
        out.append(c[:-1])
    out.append(p[:1] if closed else p[-1:])
    return np.concatenate(out, axis=0)


def resample(dense: np.ndarray, spacing: float, closed: bool) -> np.ndarray:
    """Points ``(P, 2)`` evenly spaced by arc length along the polyline ``dense`` at most ``spacing``
    apart. A closed result repeats its first point at the end (``P - 1`` segments)."""
    pts = np.concatenate((dense, dense[:1])) if closed and not np.allclose(dense[0], dense[-1]) else dense
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    keep = np.concatenate(([True], seg > 1e-12))  # drop repeated points
    pts = pts[keep]
    s = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))))
    if s[-1] <= 0:
        raise CurveError("the line has zero length")
    _check_count(s[-1] / spacing, f"a line {s[-1]:.6g} m long at spacing {spacing:g} m")
    n = max(1, int(math.ceil(s[-1] / spacing - 1e-9)))
    if closed and n < 3:  # two points of a closed line are one point twice: a lap of zero length
        raise CurveError(f"a closed line {s[-1]:.6g} m long at spacing {spacing:g} m would have {n} segment{'s' * (n > 1)}; a lap needs "
                         "at least 3 (lower the spacing, or check the track's scale: its points or the image's resolution)")
    q = np.linspace(0.0, s[-1], n + 1)
    out = np.stack((np.interp(q, s, pts[:, 0]), np.interp(q, s, pts[:, 1])), axis=1)
    if closed:
        out[-1] = out[0]
    return out


def arc_lengths(path: np.ndarray) -> np.ndarray:
    """Cumulative arc length ``(P,)`` (m) at the vertices of a polyline ``(P, 2)``."""
    return np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))))


# --------------------------------------------------------------------------- torch, per step


def path_pose(path: Tensor, path_s: Tensor, s: Tensor) -> Tensor:
    """Point and tangent heading ``(B, 3)`` ``[x, y, theta]`` at arc lengths ``s`` ``(B,)`` (m)
    on the closed path with vertices ``path`` ``(P, 2)`` and arc lengths ``path_s`` ``(P,)``."""
    length = path_s[-1]
    s = torch.remainder(s, length)
    i = (torch.searchsorted(path_s, s.contiguous(), right=True) - 1).clamp(0, path.shape[0] - 2)
    a, b = path[i], path[i + 1]
    seg_len = (path_s[i + 1] - path_s[i]).clamp(min=1e-12)
    t = ((s - path_s[i]) / seg_len)[:, None]
    p = a + t * (b - a)
    d = b - a
    return torch.cat((p, torch.atan2(d[:, 1], d[:, 0])[:, None]), dim=-1)


def project_on_path(points: Tensor, path: Tensor, path_s: Tensor, s_prev: Tensor, window: int) -> tuple[Tensor, Tensor]:
    """Arc length ``s`` ``(B,)`` (m, in [0, L)) and distance ``(B,)`` (m) of the nearest point to
    ``points`` ``(B, 2)`` on the closed path, searched over the ``2 * window + 1`` segments around
    the segment holding ``s_prev`` ``(B,)``.

    ``path`` ``(P, 2)`` repeats its first vertex at the end; ``path_s`` ``(P,)`` are its
    cumulative arc lengths. Differentiable in ``points`` (the segment choice is not).
    """
    n = path.shape[0] - 1
    length = path_s[-1]
    i0 = (torch.searchsorted(path_s, torch.remainder(s_prev, length).contiguous(), right=True) - 1).clamp(0, n - 1)
    k = torch.arange(-window, window + 1, device=points.device)
    idx = torch.remainder(i0[:, None] + k, n)  # (B, W)
    a, b = path[idx], path[idx + 1]  # (B, W, 2)
    e = b - a
    w = points[:, None, :] - a
    ee = (e * e).sum(-1).clamp(min=1e-12)
    t = ((w * e).sum(-1) / ee).clamp(0.0, 1.0)
    diff = w - t[..., None] * e
    sq = (diff * diff).sum(-1)
    j = sq.argmin(-1, keepdim=True)
    best_sq = sq.gather(-1, j)[:, 0]
    best_t = t.gather(-1, j)[:, 0]
    seg = idx.gather(-1, j)[:, 0]
    s = path_s[seg] + best_t * (path_s[seg + 1] - path_s[seg])
    pos = best_sq > 1e-12
    dist = torch.where(pos, torch.sqrt(torch.where(pos, best_sq, torch.ones_like(best_sq))), torch.zeros_like(best_sq))
    return torch.remainder(s, length), dist


def wrap_delta(ds: Tensor, length: Tensor | float) -> Tensor:
    """Signed arc-length change wrapped into ``[-L/2, L/2)`` (crossing the start line is not a lap jump)."""
    return torch.remainder(ds + 0.5 * length, length) - 0.5 * length
