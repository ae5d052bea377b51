"""Batched wavefronts on occupancy grids: geodesic distances from a source cell.

Each pass sweeps whole grid lines (rows, columns, both diagonals, both directions) with a
segmented running minimum, so the number of passes grows with the turns of the longest shortest
path, not its length; envs stop once a pass changes nothing. Distances are exact integers: an
axis step costs :data:`ORTHO`, a diagonal :data:`DIAG` (99/70 > sqrt(2)); see docs/worlds.md."""

from __future__ import annotations

import torch
from torch import Tensor

ORTHO = 70  # cost of an axis step, in distance units (1 cell = ORTHO units)
DIAG = 99  # cost of a diagonal step, in distance units
UNREACHED = 2**23  # distance of cells no free path reaches (and of blocked cells); > DIAG * cells of a 250 x 250 grid
_BIG = 2**24  # > UNREACHED + DIAG * line length: separates the free runs of a line in the running minimum
_MAX_LINE = 250  # longest grid line: at most 127 runs of 2**24 keep every key inside int32


def _line_tables(h: int, w: int, device: torch.device) -> list[tuple[Tensor, Tensor, int]]:
    """Rows, columns, diagonals and anti-diagonals as ``(index (L, M), cut (L, M), step cost)``.

    ``index[l, p]`` is the flat index of the ``p``-th cell of line ``l``. Diagonals wrap
    around the grid's sides (line ``l`` holds the cells ``(j, (l +- j) mod w)``), so
    every table holds each cell once; ``cut`` marks the cells where a line wraps,
    which are no neighbours of the cell before them.
    """
    j, i = torch.meshgrid(torch.arange(h, device=device), torch.arange(w, device=device), indexing="ij")
    flat = j * w + i
    no_cut = torch.zeros(h, w, dtype=torch.bool, device=device)
    tables = [(flat, no_cut, ORTHO), (flat.T.contiguous(), no_cut.T.contiguous(), ORTHO)]
    line, pos = torch.meshgrid(torch.arange(w, device=device), torch.arange(h, device=device), indexing="ij")
    for col, wrap in (((line + pos) % w, 0), ((line - pos) % w, w - 1)):
        tables.append((pos * w + col, (pos > 0) & (col == wrap), DIAG))
    return tables


def _run_bases(free: Tensor, cut: Tensor, cost: int) -> tuple[Tensor, Tensor]:
    """Offsets (int32, ``(L, M, B)``) that turn a running minimum into a segmented one, for lines
    ``free`` ``(L, M, B)`` swept forwards and backwards.

    Forwards, a new run starts at a ``cut`` ``(L, M)`` and at the first blocked cell after
    a free stretch: blocked cells share the run of the free cells after them, so they
    never pass on or receive a value. Each run's keys sit ``_BIG`` below the previous
    run's, so a running minimum never carries a value into a later run. Backwards the
    same, mirrored.
    """
    m = free.shape[1]
    cut = cut[..., None]
    prev = torch.cat((torch.zeros_like(free[:, :1]), free[:, :-1]), 1)
    nxt = torch.cat((free[:, 1:], torch.zeros_like(free[:, :1])), 1)
    cut_after = torch.cat((cut[:, 1:], torch.zeros_like(cut[:, :1])), 1)
    run_f = torch.cumsum((~free & prev) | cut, dim=1, dtype=torch.int32)
    run_b = torch.cumsum(((~free & nxt) | cut_after).flip(1), dim=1, dtype=torch.int32).flip(1)
    p = cost * torch.arange(m, device=free.device, dtype=torch.int32)[:, None]
    return run_f * _BIG + p, run_b * _BIG - p


def _running_min(x: Tensor, spare: Tensor, backwards: bool) -> tuple[Tensor, Tensor]:
    """Running minimum along dim 1 of ``x`` (a log-step scan: several times faster than
    ``torch.cummin`` on CPU, which also computes indices). Each step writes into the other
    buffer, ``spare`` (same shape), with ``out=``, so no step allocates or copies a whole tensor.
    Returns ``(result, spare)``: which of the two buffers holds the result depends on the steps."""
    step, m = 1, x.shape[1]
    while step < m:
        if backwards:
            torch.minimum(x[:, :-step], x[:, step:], out=spare[:, :-step])
            spare[:, m - step :] = x[:, m - step :]
        else:
            torch.minimum(x[:, step:], x[:, :-step], out=spare[:, step:])
            spare[:, :step] = x[:, :step]
        x, spare = spare, x
        step *= 2
    return x, spare


SETTLED_SHARE = 0.5  # the envs still being swept are compacted once this share of them has settled


def propagate(value: Tensor, free: Tensor, cost_scale: int = 1) -> Tensor:
    """Min-propagate ``value`` ``(B, H, W)`` over the 8-connected free cells ``free`` ``(B, H, W)``.

    A step costs ``cost_scale * ORTHO`` (axis) or ``cost_scale * DIAG`` (diagonal):
    each free cell ends with the least ``value[k] + cost of a free path from k``.
    Blocked cells, and values at or above :data:`UNREACHED`, read :data:`UNREACHED`.
    Returns int32 ``(B, H, W)``. Grids are limited to 250 cells a side.
    """
    b, h, w = free.shape
    if max(h, w) > _MAX_LINE:
        raise ValueError(f"wavefront grids are limited to {_MAX_LINE} cells a side, got {h} x {w}; use a coarser resolution")
    tables = _line_tables(h, w, free.device)
    # Cells first, envs last: gathering a line copies whole rows of envs at once.
    free_t = free.reshape(b, -1).T
    cur = torch.where(free_t, value.reshape(b, -1).T.clamp(max=UNREACHED), UNREACHED).int().contiguous()
    # Per table: the forward run bases, the shift from the forward to the backward keys, the backward bases.
    bases = []
    for index, cut, cost in tables:
        fwd, bwd = _run_bases(free_t[index], cut, cost_scale * cost)
        bases.append((fwd, fwd - bwd, bwd))
    # Each table is a permutation of the cells: gathering by its inverse writes a line layout back
    # (index_select is several times faster than an index_put here).
    perms = [(index.reshape(-1), torch.argsort(index.reshape(-1))) for index, _, _ in tables]
    out = torch.empty_like(cur)
    cols = torch.arange(b, device=free.device)  # the envs still being swept, into the full batch
    while True:
        before = cur
        for (index, _, _), (fwd, shift, bwd), (order, inverse) in zip(tables, bases, perms):
            v = cur.index_select(0, order).reshape(*index.shape, -1)  # (L, M, B)
            # A running minimum includes the cell itself, so min(v, scan) is the scan: keys in place.
            v -= fwd
            v, spare = _running_min(v, torch.empty_like(v), backwards=False)
            v += shift
            v, _ = _running_min(v, spare, backwards=True)
            v += bwd
            cur = v.reshape(-1, v.shape[-1]).index_select(0, inverse)
        moving = (cur != before).any(0)
        if not moving.any():
            out[:, cols] = cur
            break
        # A pass that changes nothing in an env changes nothing there again: once enough envs have
        # settled, keep their result and sweep only the others (compacting copies every table's bases).
        if (~moving).sum() >= SETTLED_SHARE * moving.numel():
            out[:, cols[~moving]] = cur[:, ~moving]
            keep = lambda t: t[..., moving].contiguous()  # noqa: E731
            cols, cur, bases = cols[moving], keep(cur), [tuple(keep(t) for t in table) for table in bases]
    return out.T.reshape(b, h, w)


def geodesic_distance(free: Tensor, source: Tensor) -> Tensor:
    """Octile path length from the cell ``source`` ``(B,)`` (flat index ``row * W + col``) to every
    cell of ``free`` ``(B, H, W)``, in units of ``1 / ORTHO`` cell; :data:`UNREACHED` where no path is."""
    b, h, w = free.shape
    start = torch.full((b, h * w), UNREACHED, dtype=torch.int32, device=free.device)
    start.scatter_(1, source[:, None], 0)
    return propagate(start.reshape(b, h, w), free)
