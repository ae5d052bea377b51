"""Tracks from PNG masks: threshold, thin to a one-pixel centreline (Zhang-Suen), connect neighbours.

Every pair of 8-connected centreline pixels becomes a segment (diagonal pairs only where no
orthogonal path joins them), so crossings need no special handling. The width is the line area
over the centreline length unless given; the lap is the file's ``lap`` or, for a single loop,
the loop traced, smoothed over 5 pixels and oriented counter-clockwise (docs/line.md)."""

from __future__ import annotations

import numpy as np

from .geometry import CurveError, resample
from .track import Track, TrackError


def skeletonize(mask: np.ndarray) -> np.ndarray:
    """Zhang-Suen thinning of a bool image ``(H, W)`` to one-pixel-wide lines (vectorised sub-passes)."""
    img = np.pad(mask.astype(np.uint8), 1)
    while True:
        changed = False
        for sub in (0, 1):
            c = img[1:-1, 1:-1]
            p2, p3, p4, p5 = img[:-2, 1:-1], img[:-2, 2:], img[1:-1, 2:], img[2:, 2:]
            p6, p7, p8, p9 = img[2:, 1:-1], img[2:, :-2], img[1:-1, :-2], img[:-2, :-2]
            ring = (p2, p3, p4, p5, p6, p7, p8, p9, p2)
            b = sum(r.astype(np.int32) for r in ring[:8])
            a = sum(((ring[k] == 0) & (ring[k + 1] == 1)).astype(np.int32) for k in range(8))
            if sub == 0:
                cond = (p2 * p4 * p6 == 0) & (p4 * p6 * p8 == 0)
            else:
                cond = (p2 * p4 * p8 == 0) & (p2 * p6 * p8 == 0)
            kill = (c == 1) & (b >= 2) & (b <= 6) & (a == 1) & cond
            if kill.any():
                c[kill] = 0
                changed = True
        if not changed:
            return img[1:-1, 1:-1].astype(bool)


def _edges(skel: np.ndarray) -> np.ndarray:
    """Undirected 8-neighbour pairs ``(E, 4)`` ``[r1, c1, r2, c2]`` of centreline pixels, without
    diagonals that an orthogonal two-step path already joins."""
    h, w = skel.shape
    p = np.pad(skel, 1)
    s = lambda dr, dc: p[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]  # noqa: E731
    out = []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        m = skel & s(dr, dc)
        if dr and dc:
            m &= ~(s(dr, 0) | s(0, dc))
        r, c = np.nonzero(m)
        out.append(np.stack((r, c, r + dr, c + dc), axis=1))
    return np.concatenate(out)


def _trace_loop(edges: np.ndarray, n_pixels: int) -> np.ndarray | None:
    """Pixel ``(row, col)`` chain ``(N, 2)`` around a single loop, or None if the graph is not one."""
    nbrs: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for r1, c1, r2, c2 in edges.tolist():
        nbrs.setdefault((r1, c1), []).append((r2, c2))
        nbrs.setdefault((r2, c2), []).append((r1, c1))
    if not nbrs:
        return None
    start = min(nbrs)
    chain, seen, cur = [start], {start}, start
    while True:
        nxt = [q for q in nbrs[cur] if q not in seen]
        if not nxt:
            break
        cur = min(nxt, key=lambda q: (abs(q[0] - cur[0]) + abs(q[1] - cur[1]), q))  # orthogonal steps first
        chain.append(cur)
        seen.add(cur)
    closes = start in nbrs[cur] and len(chain) > 8
    return np.asarray(chain, dtype=np.float64) if closes and len(chain) >= 0.9 * n_pixels else None


def track_from_mask(
    mask: np.ndarray,
    resolution: float,
    origin: tuple[float, float] | None = None,
    width: float | None = None,
    lap: np.ndarray | None = None,
    spacing: float = 0.02,
    walls: np.ndarray | None = None,
    name: str = "mask",
    source: str = "<mask>",
    description: str = "",
) -> Track:
    """A :class:`Track` from a bool line mask ``(H, W)`` (row 0 at the top).

    Args:
        resolution: m per pixel. origin: world ``(x, y)`` (m) of the image's lower-left
            corner; default centres the image on (0, 0).
        width: line width in m (default: estimated from the mask).
        lap: resampled closed lap path ``(P, 2)`` (m, first point repeated), or None to trace
            the centreline (single loops only).
    """
    h, w = mask.shape
    ox, oy = origin if origin is not None else (-w * resolution / 2, -h * resolution / 2)
    to_xy = lambda rc: np.stack((ox + (rc[..., 1] + 0.5) * resolution, oy + (h - 0.5 - rc[..., 0]) * resolution), -1)  # noqa: E731
    if not mask.any():
        raise TrackError(f"{source}: the mask has no line pixels (check threshold and invert)")
    skel = skeletonize(mask)
    e = _edges(skel)
    if len(e) == 0:
        raise TrackError(f"{source}: the mask's line thins to isolated pixels; is the resolution right?")
    a, b = to_xy(e[:, :2].astype(np.float64)), to_xy(e[:, 2:].astype(np.float64))
    segments = np.concatenate((a, b), axis=1)
    if width is None:
        width = float(mask.sum()) * resolution**2 / float(np.linalg.norm(b - a, axis=1).sum())
    if lap is None:
        chain = _trace_loop(e, int(skel.sum()))
        if chain is None:
            raise TrackError(
                f"{source}: the line is not a single loop (crossings or branches), so the lap cannot be traced; "
                "give the lap path as `lap: {points: [[x, y], ...]}`"
            )
        xy = to_xy(chain)
        k = 5  # circular moving average over 5 pixels removes the staircase
        xy = sum(np.roll(xy, s, axis=0) for s in range(-(k // 2), k // 2 + 1)) / k
        area = 0.5 * float(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]))
        try:
            lap = resample(xy if area > 0 else xy[::-1], spacing, closed=True)
        except CurveError as e:
            raise TrackError(f"{source}: spacing: the traced lap: {e}") from None
    return Track(
        name=name, width=float(width), segments=segments, lines=(), lap=lap,
        walls=np.zeros((0, 4)) if walls is None else walls, spacing=spacing, source=source, description=description,
    )
