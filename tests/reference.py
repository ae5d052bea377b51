"""Naive pure-Python references for the simulator tests.

Everything here works on plain floats with the ``math`` module and explicit
loops over envs, rays and obstacles, and is written independently of the
tensor code it checks: boxes are ray-cast as their four edge segments (not the
slab method), box distances come from edge distances plus a point-in-polygon
test (not the box-frame SDF), and arcs use the textbook ``v/omega`` formula.
"""

from __future__ import annotations

import math
import random

import torch

INF = math.inf


# --------------------------------------------------------------------------- kinematics


def arc_pose(x: float, y: float, th: float, v: float, w: float, t: float) -> tuple[float, float, float]:
    """Pose after driving the constant twist ``(v, w)`` for ``t`` seconds, theta not wrapped."""
    if w == 0.0:
        return x + v * t * math.cos(th), y + v * t * math.sin(th), th
    r = v / w
    return x + r * (math.sin(th + w * t) - math.sin(th)), y - r * (math.cos(th + w * t) - math.cos(th)), th + w * t


def wrap(a: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


# --------------------------------------------------------------------------- ray casting


def ray_segment(ox, oy, dx, dy, ax, ay, bx, by) -> float:
    """Distance along the unit ray to the segment, ``inf`` on a miss (parallel rays miss)."""
    ex, ey = bx - ax, by - ay
    den = dx * ey - dy * ex
    if abs(den) < 1e-12:
        return INF
    wx, wy = ax - ox, ay - oy
    t = (wx * ey - wy * ex) / den
    s = (wx * dy - wy * dx) / den
    if t >= 0.0 and 0.0 <= s <= 1.0:
        return t
    return INF


def ray_circle(ox, oy, dx, dy, cx, cy, r) -> float:
    """Nearest non-negative intersection with the circle (the exit point from inside)."""
    # Solve |o + t d - c|^2 = r^2 for t: t^2 + 2 b t + c0 = 0.
    fx, fy = ox - cx, oy - cy
    b = fx * dx + fy * dy
    c0 = fx * fx + fy * fy - r * r
    disc = b * b - c0
    if disc <= 0.0:
        return INF
    roots = sorted((-b - math.sqrt(disc), -b + math.sqrt(disc)))
    for t in roots:
        if t >= 0.0:
            return t
    return INF


def box_corner_list(cx, cy, hx, hy, yaw) -> list[tuple[float, float]]:
    """The four corners, counter-clockwise, starting at local ``(+hx, +hy)``."""
    c, s = math.cos(yaw), math.sin(yaw)
    out = []
    for lx, ly in ((hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy)):
        out.append((cx + c * lx - s * ly, cy + s * lx + c * ly))
    return out


def box_edges(cx, cy, hx, hy, yaw) -> list[tuple[float, float, float, float]]:
    cs = box_corner_list(cx, cy, hx, hy, yaw)
    return [(*cs[i], *cs[(i + 1) % 4]) for i in range(4)]


def ray_box(ox, oy, dx, dy, cx, cy, hx, hy, yaw) -> float:
    """Nearest hit on any of the four edges: the entry point from outside, the exit from inside."""
    return min(ray_segment(ox, oy, dx, dy, *e) for e in box_edges(cx, cy, hx, hy, yaw))


def valid_obstacles(world, env: int) -> tuple[list, list, list]:
    """The valid (unmasked) segments, circles and boxes of one env as lists of float tuples."""

    def rows(t, m):
        return [tuple(float(v) for v in t[env, i].tolist()) for i in range(t.shape[1]) if bool(m[env, i])]

    return (
        rows(world.segments, world.segment_mask),
        rows(world.circles, world.circle_mask),
        rows(world.boxes, world.box_mask),
    )


def lidar_angles(lidar) -> list[float]:
    """Sensor-frame ray angles straight from the LidarParams docstring."""
    n = lidar.n_rays
    if lidar.fov >= 2 * math.pi - 1e-9:
        return [-math.pi + i * 2 * math.pi / n for i in range(n)]
    if n == 1:
        return [0.0]
    return [-lidar.fov / 2 + i * lidar.fov / (n - 1) for i in range(n)]


def naive_scan(pose: torch.Tensor, world, lidar) -> list[list[float]]:
    """Lidar ranges for every env and ray with explicit loops, misses and min range clamped."""
    out = []
    angles = lidar_angles(lidar)
    mx, my, myaw = lidar.offset
    for b in range(pose.shape[0]):
        x, y, th = (float(v) for v in pose[b].tolist())
        sx = x + math.cos(th) * mx - math.sin(th) * my
        sy = y + math.sin(th) * mx + math.cos(th) * my
        segs, circs, boxes = valid_obstacles(world, b)
        row = []
        for a in angles:
            phi = th + myaw + a
            dx, dy = math.cos(phi), math.sin(phi)
            best = INF
            for s in segs:
                best = min(best, ray_segment(sx, sy, dx, dy, *s))
            for c in circs:
                best = min(best, ray_circle(sx, sy, dx, dy, *c))
            for k in boxes:
                best = min(best, ray_box(sx, sy, dx, dy, *k))
            row.append(min(max(best, lidar.min_range), lidar.max_range))
        out.append(row)
    return out


# --------------------------------------------------------------------------- distances


def point_seg_dist(px, py, ax, ay, bx, by) -> float:
    ex, ey = bx - ax, by - ay
    ee = ex * ex + ey * ey
    t = 0.0 if ee == 0.0 else max(0.0, min(1.0, ((px - ax) * ex + (py - ay) * ey) / ee))
    return math.hypot(px - ax - t * ex, py - ay - t * ey)


def point_in_convex(px, py, corners) -> bool:
    """Inside a counter-clockwise convex polygon: left of (or on) every edge."""
    for i in range(len(corners)):
        (ax, ay), (bx, by) = corners[i], corners[(i + 1) % len(corners)]
        if (bx - ax) * (py - ay) - (by - ay) * (px - ax) < 0.0:
            return False
    return True


def point_box_dist(px, py, cx, cy, hx, hy, yaw) -> float:
    """Signed distance: distance to the nearest edge, negated inside."""
    d = min(point_seg_dist(px, py, *e) for e in box_edges(cx, cy, hx, hy, yaw))
    return -d if point_in_convex(px, py, box_corner_list(cx, cy, hx, hy, yaw)) else d


def naive_point_clearance(px: float, py: float, world, env: int) -> float:
    segs, circs, boxes = valid_obstacles(world, env)
    best = INF
    for s in segs:
        best = min(best, point_seg_dist(px, py, *s))
    for cx, cy, r in circs:
        best = min(best, math.hypot(px - cx, py - cy) - r)
    for k in boxes:
        best = min(best, point_box_dist(px, py, *k))
    return best


def naive_clearance(pose: torch.Tensor, world, radius: float) -> list[float]:
    """Signed gap between each env's robot disc and its nearest valid obstacle (``inf`` if none)."""
    return [naive_point_clearance(float(pose[b, 0]), float(pose[b, 1]), world, b) - radius for b in range(pose.shape[0])]


# --------------------------------------------------------------------------- random worlds


def random_world(
    batch: int,
    n_slots: tuple[int, int, int],
    seed: int,
    dtype: torch.dtype = torch.float64,
    extent: float = 4.0,
):
    """A padded World with ``n_slots = (S, C, K)`` slots per kind and a random number of
    valid obstacles per env (env 0 has all slots valid, env 1 none of the circles).

    Masked-out slots hold real-looking obstacles right next to the origin, so a
    caster that ignored the mask would read them.
    """
    from torchnav.sim import World

    rng = random.Random(seed)
    n_s, n_c, n_k = n_slots

    def u(lo, hi):
        return rng.uniform(lo, hi)

    segs, circs, boxes, ms, mc, mk = [], [], [], [], [], []
    for b in range(batch):
        def count(n, kind):
            if b == 0:
                return n
            if b == 1 and kind == "c":
                return 0
            return rng.randint(0, n)

        vs, vc, vk = count(n_s, "s"), count(n_c, "c"), count(n_k, "k")
        row_s, row_c, row_k = [], [], []
        for i in range(n_s):
            if i < vs:
                row_s.append([u(-extent, extent), u(-extent, extent), u(-extent, extent), u(-extent, extent)])
            else:
                row_s.append([0.3, -1.0, 0.3, 1.0])  # decoy wall right in front of the origin
        for i in range(n_c):
            row_c.append([u(-extent, extent), u(-extent, extent), u(0.2, 1.0)] if i < vc else [0.0, 0.0, 0.5])
        for i in range(n_k):
            row_k.append(
                [u(-extent, extent), u(-extent, extent), u(0.1, 1.0), u(0.1, 1.0), u(-math.pi, math.pi)]
                if i < vk
                else [0.0, 0.0, 0.4, 0.4, 0.0]
            )
        # Shuffle valid and padded slots so validity is not just a prefix.
        for rows, n_valid, dst, mdst in ((row_s, vs, segs, ms), (row_c, vc, circs, mc), (row_k, vk, boxes, mk)):
            flags = [i < n_valid for i in range(len(rows))]
            order = list(range(len(rows)))
            rng.shuffle(order)
            dst.append([rows[i] for i in order])
            mdst.append([flags[i] for i in order])

    def tens(rows, width):
        return torch.tensor(rows, dtype=dtype).reshape(batch, -1, width)

    return World(
        segments=tens(segs, 4),
        segment_mask=torch.tensor(ms, dtype=torch.bool).reshape(batch, -1),
        circles=tens(circs, 3),
        circle_mask=torch.tensor(mc, dtype=torch.bool).reshape(batch, -1),
        boxes=tens(boxes, 5),
        box_mask=torch.tensor(mk, dtype=torch.bool).reshape(batch, -1),
        batch_size=[batch],
    )
