"""Procedural worlds: the wavefront and the clearance raster against naive versions."""

from __future__ import annotations

import heapq

import numpy as np
import torch

from torchnav.maps import load_map
from torchnav.sim import cat_worlds, points_clearance
from torchnav.worlds.raster import clearance_grid
from torchnav.worlds.wavefront import DIAG, ORTHO, UNREACHED, geodesic_distance


def gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


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
