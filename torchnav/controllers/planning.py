"""Path planning for one env at a time, in numpy: occupancy grid, A*, RRT-Connect, shortcutting.

Planners run on the CPU when an episode starts (see ``PlannerController``); the
tracker that follows their waypoints runs batched. Frames and units: world frame,
x right, y up, metres. A path is an ``(N, 2)`` float array of waypoints from the
start to the goal, or ``None`` when no path exists (A*: the goal's free region
does not hold the start; RRT: none found within ``max_iters``).

Obstacles are "inflated" by ``inflate`` m: a point is free when its distance to
every obstacle and to the world edge is more than ``inflate`` (the robot radius
plus a safety margin), so the robot's centre can follow any free path.
"""

from __future__ import annotations

import hashlib
import heapq
import math
from dataclasses import dataclass

import numpy as np

from ..maps.free_space import obstacle_distance_arrays

SQRT2 = math.sqrt(2.0)


@dataclass(frozen=True)
class Obstacles:
    """One env's obstacles as float64 arrays in the layouts of ``World`` (masked slots removed).

    Attributes: segments ``(S, 4)``, circles ``(C, 3)``, boxes ``(K, 5)`` (m, half extents,
    yaw rad); bounds ``(xmin, ymin, xmax, ymax)`` m of the world rectangle.
    """

    segments: np.ndarray
    circles: np.ndarray
    boxes: np.ndarray
    bounds: tuple[float, float, float, float]

    def clearance(self, xy: np.ndarray) -> np.ndarray:
        """Signed distance in m of points ``(N, 2)`` to the nearest obstacle or world edge, ``(N,)``."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        d = obstacle_distance_arrays(xy, self.segments, self.circles, self.boxes)
        xmin, ymin, xmax, ymax = self.bounds
        edge = np.minimum(np.minimum(xy[:, 0] - xmin, xmax - xy[:, 0]), np.minimum(xy[:, 1] - ymin, ymax - xy[:, 1]))
        return np.minimum(d, edge)


@dataclass
class OccupancyGrid:
    """Clearance sampled at cell centres: ``clearance[j, i]`` is the signed distance (m) of the
    point ``(xs[i], ys[j])`` to the nearest obstacle or world edge. Cells are ``resolution`` m."""

    clearance: np.ndarray  # (ny, nx) m
    xs: np.ndarray  # (nx,) m, cell centres
    ys: np.ndarray  # (ny,) m
    resolution: float  # m

    @classmethod
    def build(cls, obstacles: Obstacles, resolution: float, base: np.ndarray | None = None, window: float | None = None) -> "OccupancyGrid":
        """Grid of ``obstacles``. ``base`` ``(ny, nx)``: a precomputed clearance of obstacles that
        are not in ``obstacles`` (e.g. the map's fixed ones), combined by a minimum.

        With ``base`` and ``window`` (m), each obstacle is rasterised only within ``window`` of
        its bounding box: values above ``window`` may then overstate the clearance, which
        is harmless for every test against a threshold below ``window`` (inflation) and
        several times cheaper for a few small objects on a large map.
        """
        xmin, ymin, xmax, ymax = obstacles.bounds
        xs = np.arange(xmin + resolution / 2, xmax, resolution)
        ys = np.arange(ymin + resolution / 2, ymax, resolution)
        if base is not None and window is not None:
            return cls(cls._stamp(base.copy(), obstacles, xs, ys, resolution, window), xs, ys, resolution)
        gx, gy = np.meshgrid(xs, ys)
        c = obstacles.clearance(np.stack([gx.ravel(), gy.ravel()], -1)).reshape(gx.shape)
        return cls(c if base is None else np.minimum(c, base), xs, ys, resolution)

    @staticmethod
    def _stamp(c: np.ndarray, obs: Obstacles, xs: np.ndarray, ys: np.ndarray, res: float, window: float) -> np.ndarray:
        """Lower ``c`` in place by each obstacle's distance within ``window`` m of its bounding box."""
        items = [((min(s[0], s[2]), min(s[1], s[3]), max(s[0], s[2]), max(s[1], s[3])), (s[None], (), ())) for s in obs.segments]
        items += [((x - r, y - r, x + r, y + r), ((), ci[None], ())) for ci in obs.circles for x, y, r in [ci]]
        items += [((b[0] - e, b[1] - e, b[0] + e, b[1] + e), ((), (), b[None])) for b in obs.boxes for e in [math.hypot(b[2], b[3])]]
        for (x0, y0, x1, y1), (seg, circ, box) in items:
            i0, i1 = np.searchsorted(xs, [x0 - window, x1 + window])
            j0, j1 = np.searchsorted(ys, [y0 - window, y1 + window])
            if i1 <= i0 or j1 <= j0:
                continue
            gx, gy = np.meshgrid(xs[i0:i1], ys[j0:j1])
            d = obstacle_distance_arrays(np.stack([gx.ravel(), gy.ravel()], -1), seg, circ, box).reshape(gx.shape)
            np.minimum(c[j0:j1, i0:i1], d, out=c[j0:j1, i0:i1])
        return c

    def cell(self, xy) -> tuple[int, int]:
        """``(row j, column i)`` of the cell holding point ``xy`` (clamped into the grid)."""
        i = int(np.clip(round((xy[0] - self.xs[0]) / self.resolution), 0, len(self.xs) - 1))
        j = int(np.clip(round((xy[1] - self.ys[0]) / self.resolution), 0, len(self.ys) - 1))
        return j, i

    def nearest_free(self, free: np.ndarray, xy, max_dist: float) -> tuple[int, int] | None:
        """The free cell nearest to ``xy`` within ``max_dist`` m, or None."""
        j, i = self.cell(xy)
        if free[j, i]:
            return j, i
        k = int(math.ceil(max_dist / self.resolution))
        j0, i0 = max(0, j - k), max(0, i - k)
        win = free[j0 : j + k + 1, i0 : i + k + 1]
        cand = np.argwhere(win)
        if len(cand) == 0:
            return None
        pts = np.stack([self.xs[cand[:, 1] + i0], self.ys[cand[:, 0] + j0]], -1)
        d = np.hypot(pts[:, 0] - xy[0], pts[:, 1] - xy[1])
        best = int(d.argmin())
        return (int(cand[best, 0] + j0), int(cand[best, 1] + i0)) if d[best] <= max_dist else None


def astar_cells(free: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> list[tuple[int, int]] | None:
    """8-connected A* on a bool grid ``free`` ``(ny, nx)`` from cell ``start`` to ``goal`` (row, col).

    Step costs 1 and sqrt(2) cells, octile heuristic (admissible, so paths are shortest
    on the grid); diagonal steps may not cut a blocked corner. Returns the cells of the
    path, start and goal included, or None when the goal is unreachable.
    """
    if not (free[start] and free[goal]):
        return None
    ny, nx = free.shape
    w = nx + 2  # pad with a blocked border: no bounds checks in the inner loop
    padded = np.zeros((ny + 2, w), dtype=bool)
    padded[1:-1, 1:-1] = free
    free_ = padded.ravel().tolist()  # the obstacle map, for corner checks
    ok = list(free_)  # free and not yet closed
    s, g = (start[0] + 1) * w + start[1] + 1, (goal[0] + 1) * w + goal[1] + 1
    gj, gi = divmod(g, w)
    # (offset, cost, the two orthogonal cells a diagonal step must not cut through, or 0)
    steps = ((1, 1.0, 0, 0), (-1, 1.0, 0, 0), (w, 1.0, 0, 0), (-w, 1.0, 0, 0),
             (w + 1, SQRT2, 1, w), (w - 1, SQRT2, -1, w), (-w + 1, SQRT2, 1, -w), (-w - 1, SQRT2, -1, -w))
    cost = {s: 0.0}
    parent = {s: -1}
    # Ties in f go to the deeper node (larger g): on open ground far fewer cells are expanded.
    heap = [(0.0, -0.0, s)]
    push, pop = heapq.heappush, heapq.heappop
    c_diag = SQRT2 - 1.0
    while heap:
        _, neg_g, u = pop(heap)
        if not ok[u]:  # already closed: a stale heap entry
            continue
        if u == g:
            break
        ok[u] = False  # close u: it is never entered again
        gc = -neg_g
        for d, c, a, b in steps:
            v = u + d
            if ok[v] and (a == 0 or (free_[u + a] and free_[u + b])):
                nc = gc + c
                if nc < cost.get(v, math.inf):
                    cost[v] = nc
                    parent[v] = u
                    vj, vi = divmod(v, w)
                    dj, di = abs(vj - gj), abs(vi - gi)
                    push(heap, (nc + (dj + c_diag * di if dj > di else di + c_diag * dj), -nc, v))
    else:
        return None
    path = []
    u = g
    while u != -1:
        j, i = divmod(u, w)
        path.append((j - 1, i - 1))
        u = parent[u]
    return path[::-1]


def _segments_free(grid: OccupancyGrid, free: np.ndarray, a: np.ndarray, bs: np.ndarray) -> np.ndarray:
    """Whether the straight lines from point ``a`` ``(2,)`` to each of ``bs`` ``(M, 2)`` stay in free cells."""
    n = max(2, int(np.ceil(np.hypot(*(bs - a).T).max() / (0.5 * grid.resolution))) + 1)
    t = np.linspace(0.0, 1.0, n)[None, :, None]
    pts = a + t * (bs[:, None, :] - a)  # (M, n, 2)
    i = np.clip(np.rint((pts[..., 0] - grid.xs[0]) / grid.resolution).astype(int), 0, len(grid.xs) - 1)
    j = np.clip(np.rint((pts[..., 1] - grid.ys[0]) / grid.resolution).astype(int), 0, len(grid.ys) - 1)
    return free[j, i].all(-1)


def shortcut(path: np.ndarray, visible) -> np.ndarray:
    """Greedy shortcutting: from each kept waypoint jump to the farthest later one in sight.

    ``visible(a (2,), bs (M, 2)) -> (M,) bool`` tests straight lines. Start and end are kept.
    """
    out, k = [path[0]], 0
    while k < len(path) - 1:
        later = path[k + 1 :]
        vis = visible(path[k], later)
        seen = np.flatnonzero(vis)
        k = k + 1 + (int(seen[-1]) if len(seen) else 0)
        out.append(path[k])
    return np.asarray(out)


def plan_astar(grid: OccupancyGrid, start, goal, inflate: float, snap: float = 0.5) -> np.ndarray | None:
    """A* on ``grid`` with obstacles inflated by ``inflate`` m, then shortcut.

    Start and goal are moved to the nearest free cell within ``snap`` m when their own
    cell is blocked (a robot close to a wall). Returns waypoints ``(N, 2)`` m, the first
    being ``start`` and the last ``goal`` exactly, or None.
    """
    free = grid.clearance > inflate
    s = grid.nearest_free(free, start, snap)
    g = grid.nearest_free(free, goal, snap)
    if s is None or g is None:
        return None
    cells = astar_cells(free, s, g)
    if cells is None:
        return None
    c = np.asarray(cells)
    pts = np.stack([grid.xs[c[:, 1]], grid.ys[c[:, 0]]], -1)
    pts = shortcut(pts, lambda a, bs: _segments_free(grid, free, a, bs))
    return np.concatenate([np.asarray(start, float)[None, :2], pts[1:-1], np.asarray(goal, float)[None, :2]])


@dataclass(frozen=True)
class RRTParams:
    step: float = 0.5  # m, longest edge added by one extension
    max_iters: int = 3000  # sampling iterations before giving up (returns None)
    check_step: float = 0.05  # m, spacing of collision checks along an edge


def _seed_of(seed: int, start, goal) -> int:
    """A seed that depends only on ``seed`` and the query, so a scenario always gets the same plan."""
    data = np.asarray([*np.asarray(start, np.float64)[:2], *np.asarray(goal, np.float64)[:2]]).round(6).tobytes()
    return int.from_bytes(hashlib.blake2b(data + seed.to_bytes(8, "little", signed=True), digest_size=8).digest(), "little")


def plan_rrt(obstacles: Obstacles, start, goal, inflate: float, params: RRTParams = RRTParams(), seed: int = 0) -> np.ndarray | None:
    """RRT-Connect in continuous space with exact clearance checks against ``obstacles``, then shortcut.

    Two trees grow from start and goal; each iteration extends one towards a uniform sample
    by at most ``params.step`` m, then pulls the other straight towards the new node as far
    as the line stays free. Points along edges every ``params.check_step`` m must have
    clearance above ``inflate`` m. Returns waypoints ``(N, 2)`` (start first, goal last) or
    None after ``params.max_iters`` iterations (and at once if start or goal is not free).
    """
    start, goal = np.asarray(start, np.float64)[:2], np.asarray(goal, np.float64)[:2]
    if (obstacles.clearance(np.stack([start, goal])) <= inflate).any():
        return None

    def free_prefix(a: np.ndarray, b: np.ndarray) -> float:
        """Fraction in [0, 1] of the line a -> b that is free from a onwards."""
        n = max(2, int(math.ceil(math.hypot(*(b - a)) / params.check_step)) + 1)
        t = np.linspace(0.0, 1.0, n)
        bad = np.flatnonzero(obstacles.clearance(a + t[:, None] * (b - a)) <= inflate)
        return 1.0 if len(bad) == 0 else t[max(bad[0] - 1, 0)]

    def visible(a: np.ndarray, bs: np.ndarray) -> np.ndarray:
        return np.array([free_prefix(a, b) >= 1.0 for b in bs])

    if free_prefix(start, goal) >= 1.0:
        return np.stack([start, goal])
    rng = np.random.default_rng(_seed_of(seed, start, goal))
    xmin, ymin, xmax, ymax = obstacles.bounds
    cap = 2 + params.max_iters * (2 + int(math.ceil(math.hypot(xmax - xmin, ymax - ymin) / params.step)))
    trees = []
    for root in (start, goal):
        nodes = np.empty((cap, 2))
        nodes[0] = root
        trees.append({"nodes": nodes, "parent": np.full(cap, -1, np.int64), "n": 1})

    def add(tree, p, parent) -> int:
        k = tree["n"]
        tree["nodes"][k], tree["parent"][k] = p, parent
        tree["n"] = k + 1
        return k

    def nearest(tree, p) -> int:
        d = tree["nodes"][: tree["n"]] - p
        return int(np.einsum("ij,ij->i", d, d).argmin())

    def branch(tree, k) -> list[np.ndarray]:
        out = []
        while k >= 0:
            out.append(tree["nodes"][k])
            k = tree["parent"][k]
        return out

    a, b = trees
    for _ in range(params.max_iters):
        q = rng.uniform((xmin, ymin), (xmax, ymax))
        ka = nearest(a, q)
        pa = a["nodes"][ka]
        d = math.hypot(*(q - pa))
        if d > params.step:
            q = pa + (q - pa) * (params.step / d)
        if free_prefix(pa, q) >= 1.0:
            ka = add(a, q, ka)
            # Connect: pull tree b straight towards q, adding nodes every `step` along the free part.
            kb = nearest(b, q)
            pb = b["nodes"][kb]
            frac = free_prefix(pb, q)
            length = frac * math.hypot(*(q - pb))
            n_new = int(math.ceil(length / params.step - 1e-9))
            for i in range(1, n_new + 1):
                kb = add(b, pb + (q - pb) * (frac * i / n_new), kb)
            if frac >= 1.0:
                pa_branch, pb_branch = branch(a, ka), branch(b, kb)[1:]  # kb's last node is q itself
                path = pa_branch[::-1] + pb_branch
                path = np.asarray(path if a is trees[0] else path[::-1])
                return shortcut(path, visible)
        a, b = b, a
    return None


def shortest_paths(world, start, goal, radius: float, resolution: float = 0.05, chunk: int = 16) -> np.ndarray:
    """The length ``(B,)`` m of each env's shortest collision-free path for a disc of ``radius`` m from
    ``start`` ``(B, 2)`` to ``goal`` ``(B, 2)`` among the obstacles of ``world`` (a batch of ``B``, all its
    obstacles; moving ones are not in a ``World``): A* on a ``resolution`` m grid of the points whose
    clearance exceeds ``radius`` (:func:`plan_astar`, shortcut, start and goal exact); ``inf`` where the
    grid has no path. The shortcut passes through free cells, so round each obstacle's corner the path
    keeps up to a cell more than ``radius`` away: 2.8% longer than the exact detour round a wall's end
    at 0.05 m (tests/test_controllers.py). The reference that ``recipes/benchmark.py`` times episodes against (at the
    robot's top speed). The grid covers the obstacles, the starts and the goals of ``chunk`` envs at a
    time, two radii wider, so a world with no outer walls keeps a way around its obstacles."""
    import torch

    from ..worlds.raster import clearance_grid

    start = torch.as_tensor(start, dtype=torch.float64)[:, :2]
    goal = torch.as_tensor(goal, dtype=torch.float64)
    out = np.full(start.shape[0], math.inf)
    for first in range(0, start.shape[0], chunk):
        idx = torch.arange(first, min(first + chunk, start.shape[0]))
        w = world[idx].to("cpu")
        lo, hi = _extent(w, torch.cat((start[idx], goal[idx])))
        lo, hi = lo - 2 * radius - resolution, hi + 2 * radius + resolution
        shape = (int(math.ceil((hi[1] - lo[1]) / resolution)), int(math.ceil((hi[0] - lo[0]) / resolution)))
        clear = clearance_grid(w, (lo[0], lo[1]), shape, resolution, reach=radius + 2 * resolution).numpy()
        xs = lo[0] + resolution * (np.arange(shape[1]) + 0.5)
        ys = lo[1] + resolution * (np.arange(shape[0]) + 0.5)
        for k, e in enumerate(idx.tolist()):
            path = plan_astar(OccupancyGrid(clear[k], xs, ys, resolution), start[e].numpy(), goal[e].numpy(), radius, snap=2 * resolution)
            if path is None:
                continue
            out[e] = float(np.hypot(*np.diff(path, axis=0).T).sum())
    return out


def _extent(world, points) -> tuple[np.ndarray, np.ndarray]:
    """``(lo (2,), hi (2,))`` m: the box around every valid obstacle of ``world`` and ``points`` ``(P, 2)``."""
    parts = [points.numpy()]
    seg, sm = world.segments.numpy(), world.segment_mask.numpy()
    parts += [seg[sm][:, :2], seg[sm][:, 2:]]
    c, cm = world.circles.numpy(), world.circle_mask.numpy()
    parts += [c[cm][:, :2] - c[cm][:, 2:], c[cm][:, :2] + c[cm][:, 2:]]
    b, bm = world.boxes.numpy(), world.box_mask.numpy()
    reach = np.hypot(b[bm][:, 2], b[bm][:, 3])[:, None]
    parts += [b[bm][:, :2] - reach, b[bm][:, :2] + reach]
    pts = np.concatenate(parts)
    return pts.min(0), pts.max(0)
