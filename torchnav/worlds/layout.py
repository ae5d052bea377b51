"""Building blocks shared by the world families: difficulty, random draws, walls, mazes, slots.

Everything is batched over envs: a family draws all its envs' layouts at once,
with per-env tensors for every parameter, so envs of one call may have
different difficulties.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..sim import World


def as_difficulty(difficulty: float | Tensor, num_envs: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    """``difficulty`` (a number, or a ``(num_envs,)`` tensor) as a ``(num_envs,)`` tensor in [0, 1].

    Raises ValueError naming the problem: a value outside [0, 1] or NaN, or a wrong shape.
    """
    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
    d = torch.as_tensor(difficulty, dtype=dtype, device=device)
    if d.dim() == 0:
        d = d.expand(num_envs)
    if d.shape != (num_envs,):
        raise ValueError(f"difficulty must be a number or a ({num_envs},) tensor, got shape {tuple(d.shape)}")
    bad = torch.isnan(d) | (d < 0) | (d > 1)
    if bad.any():
        raise ValueError(f"difficulty must lie in [0, 1], got {d[bad][0].item()!r} (env {int(bad.nonzero()[0])})")
    return d.clone()


def lerp(easy: float, hard: float, d: Tensor) -> Tensor:
    """The parameter at difficulty ``d`` ``(B,)``: ``easy`` at 0, ``hard`` at 1, linear between."""
    return easy + (hard - easy) * d


def uniform(lo: Tensor | float, hi: Tensor | float, shape: tuple[int, ...], generator: torch.Generator, like: Tensor) -> Tensor:
    """Uniform draws in ``[lo, hi)`` of ``shape`` (``lo``/``hi`` broadcast), from ``generator`` only."""
    return lo + (hi - lo) * torch.rand(shape, generator=generator, dtype=like.dtype, device=like.device)


def boundary_walls(half_w: Tensor, half_h: Tensor) -> Tensor:
    """The 4 walls ``(B, 4, 4)`` of the rectangles ``[-half_w, half_w] x [-half_h, half_h]`` ``(B,)`` m."""
    xa, ya = -half_w, -half_h
    return torch.stack(
        (
            torch.stack((xa, ya, half_w, ya), -1),
            torch.stack((half_w, ya, half_w, half_h), -1),
            torch.stack((half_w, half_h, xa, half_h), -1),
            torch.stack((xa, half_h, xa, ya), -1),
        ),
        1,
    )


def centred_bounds(half_w: Tensor, half_h: Tensor) -> Tensor:
    """``(B, 4)`` bounds ``[xmin, ymin, xmax, ymax]`` m of rectangles centred on the origin."""
    return torch.stack((-half_w, -half_h, half_w, half_h), -1)


Slots = tuple[Tensor, Tensor]  # obstacle rows (B, N, k) and their mask (B, N)


def walled_world(half_w: Tensor, half_h: Tensor, segments: Slots | None = None, circles: Slots | None = None,
                 boxes: Slots | None = None) -> tuple[World, Tensor]:
    """A family's worlds: the 4 walls of the rectangles ``[-half_w, half_w] x [-half_h, half_h]``
    ``(B,)`` m, then the given slots of each obstacle kind (none: no slots of that kind); and
    the rectangles' bounds ``(B, 4)`` m."""
    b, like = half_w.shape[0], half_w
    mask = lambda n, on: torch.full((b, n), on, dtype=torch.bool, device=like.device)  # noqa: E731
    empty = lambda width: (like.new_zeros(b, 0, width), mask(0, False))  # noqa: E731
    seg, seg_on = segments if segments is not None else empty(4)
    circ, circ_on = circles if circles is not None else empty(3)
    box, box_on = boxes if boxes is not None else empty(5)
    world = World(segments=torch.cat((boundary_walls(half_w, half_h), seg), 1), segment_mask=torch.cat((mask(4, True), seg_on), 1),
                  circles=circ, circle_mask=circ_on, boxes=box, box_mask=box_on, batch_size=[b], device=like.device)
    return world, centred_bounds(half_w, half_h)


def grid_edges(rows: int, cols: int, device: torch.device) -> tuple[Tensor, Tensor, Tensor]:
    """The edges between 4-neighbour cells of a ``rows x cols`` grid (cell index ``r * cols + c``).

    Returns ``(a, b, vertical)``, each ``(E,)``: the two cells of every edge and
    whether it joins a cell to its right-hand neighbour (its wall is vertical).
    First the ``rows * (cols - 1)`` vertical walls (row-major), then the
    ``(rows - 1) * cols`` horizontal ones.
    """
    r, c = torch.meshgrid(torch.arange(rows, device=device), torch.arange(cols - 1, device=device), indexing="ij")
    va = (r * cols + c).reshape(-1)
    r, c = torch.meshgrid(torch.arange(rows - 1, device=device), torch.arange(cols, device=device), indexing="ij")
    ha = (r * cols + c).reshape(-1)
    a = torch.cat((va, ha))
    b = torch.cat((va + 1, ha + cols))
    vertical = torch.cat((torch.ones_like(va, dtype=torch.bool), torch.zeros_like(ha, dtype=torch.bool)))
    return a, b, vertical


def random_spanning_tree(a: Tensor, b: Tensor, active: Tensor, num_cells: int, generator: torch.Generator) -> Tensor:
    """Randomised Kruskal over the edges ``a -> b`` ``(E,)`` of a graph, in every env at once.

    ``active`` ``(B, E)`` says which edges exist in each env. Edges are tried in a
    random order per env; one joins two components when they differ (component
    labels are relabelled in one ``where``). Returns ``(B, E)`` bool: the tree's
    edges, connecting all cells that active edges touch. Loops over edges, not envs.
    """
    n, e = active.shape
    dev = active.device
    label = torch.arange(num_cells, device=dev).expand(n, num_cells).clone()
    order = torch.rand((n, e), generator=generator, device=dev).argsort(dim=1)
    tree = torch.zeros(n, e, dtype=torch.bool, device=dev)
    rows = torch.arange(n, device=dev)
    for k in range(e):
        edge = order[:, k]
        la, lb = label[rows, a[edge]], label[rows, b[edge]]
        join = active[rows, edge] & (la != lb)
        label = torch.where(join[:, None] & (label == lb[:, None]), la[:, None], label)
        tree[rows, edge] = join
    return tree


def runs(values: Tensor) -> tuple[Tensor, Tensor]:
    """Maximal runs of one non-zero value along the last dim of ``values`` ``(..., n)`` (bool or int).

    Returns ``(start, length)``, both ``(..., n)``: ``start`` is True at the first
    cell of each run and ``length`` holds that run's length there (0 elsewhere).
    """
    n = values.shape[-1]
    on = values != 0
    goes_on = on[..., 1:] & (values[..., 1:] == values[..., :-1])  # cell i + 1 continues cell i's run
    no = torch.zeros_like(on[..., :1])
    start = on & ~torch.cat((no, goes_on), -1)
    end = on & ~torch.cat((goes_on, no), -1)
    idx = torch.arange(n, device=values.device).expand(on.shape)
    # Index of the end of the run each cell is in: the nearest end at or after it.
    end_at = torch.where(end, idx, n).flip(-1).cummin(-1).values.flip(-1)
    return start, torch.where(start, end_at - idx + 1, 0)


def take_slots(score: Tensor, slots: int) -> tuple[Tensor, Tensor]:
    """The ``slots`` best of ``N`` candidates per env by ``score`` ``(B, N)`` (> 0: a candidate).

    Returns ``(index (B, slots), valid (B, slots))``; ties keep the candidates'
    order. Candidates beyond ``slots`` are dropped (the lowest scores).
    """
    if score.shape[1] < slots:
        score = torch.cat((score, score.new_zeros(score.shape[0], slots - score.shape[1])), 1)
    order = torch.sort(score, dim=1, descending=True, stable=True).indices[:, :slots]
    return order, score.gather(1, order) > 0
