"""Exact 2D ray casting against segments, circles and oriented boxes, with an angular broad phase.

Each obstacle kind has one hit function written on broadcastable tensors. Two
narrow-phase reductions test every ray against every slot of a kind:

* ``batched``: all rays of all envs against all slots at once, as ``(B, R, N)``
  tensors reduced by a minimum (fewest kernel launches in eager mode);
* ``unrolled``: a running minimum over the slots, each a ``(B, R)`` pass. Under
  ``torch.compile`` this fuses into one loop over contiguous memory and never
  materialises ``(B, R, N)`` temporaries (see docs/performance.md).

By default (:func:`unrolled`) each set of slots (one kind of obstacle, or a broad
phase's dense set) is unrolled when it holds at most ``UNROLL_SLOTS`` slots under
``torch.compile``; in eager mode, where every unrolled slot costs a few dozen kernel
launches, only when it holds at most ``EAGER_UNROLL_SLOTS`` slots and the batch casts
at least ``EAGER_UNROLL_MIN_RAYS`` rays (below that, launches cost more than the
``(B, R, N)`` temporaries). Otherwise it is batched.

For worlds with many obstacles, :func:`cast_fan` adds a broad phase for evenly
spaced rays (a lidar fan), to kinds with more than ``BROAD_PHASE_RATIO * dense_slots``
slots (below that its selection costs more than the tests it saves): an obstacle can only be hit by the rays that pass
through its bounding circle, which from the sensor spans ``phi +- asin(rho/D)``.
Each obstacle is tested on the ``2 * window + 1`` rays nearest its direction, and
the results are scattered into the scan by a minimum. Obstacles that look too wide
for that window (near or large ones) go to a small dense set of ``dense_slots``
per env and kind, tested against every ray. The scan equals the
every-ray-every-slot scan whenever an env has at most ``dense_slots`` wide
obstacles of a kind; :func:`fan_is_exact` says where that holds. Selection is not
differentiated; gradients flow through the narrow phase as before.

Every division and square root is guarded (see ``math.py``) and masking uses
``torch.where`` out of place, so backward never meets inf or NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .state import World, planar_rows, stack_rows

_INF = float("inf")
_TINY = 1e-12
# A ray whose cross product with a wall is below this many float epsilons times the
# wall's length is parallel to it (rounding alone makes |d x e| that large).
_PARALLEL_EPS = 8.0
# The broad phase runs for a kind with more than this many times ``dense_slots`` slots. Closer
# to ``dense_slots`` it saves few tests and its selection (wide test, running count, search,
# gather, window hits) costs more: the generalist's padded mixture (then 84 wall, 70 circle slots,
# 20 sector boundaries, dense_slots 64) stepped in 37-40 ms with it and 18-25 ms without (2,048 envs,
# compiled, 2 CPU threads; docs/performance.md).
BROAD_PHASE_RATIO = 2


def hit_segment(ox: Tensor, oy: Tensor, dx: Tensor, dy: Tensor, seg: Tensor, mask: Tensor) -> Tensor:
    """Distance along unit rays to segments ``[x1, y1, x2, y2]``, ``inf`` where missed.

    All arguments broadcast: ray origin ``ox, oy``, unit direction ``dx, dy``, and the
    segment's components in ``seg[..., k]`` with a bool ``mask``. Rays parallel to a
    segment, up to rounding relative to its length, miss it; so do zero-length segments.
    """
    ax, ay, bx, by = seg.unbind(-1)
    ex, ey = bx - ax, by - ay
    wx, wy = ax - ox, ay - oy
    # Solve o + t d = a + s e with 2D cross products.
    denom = dx * ey - dy * ex
    tol = _PARALLEL_EPS * torch.finfo(denom.dtype).eps
    ok = denom * denom > (tol * tol) * (ex * ex + ey * ey)
    inv = 1.0 / torch.where(ok, denom, torch.ones_like(denom))
    t = (wx * ey - wy * ex) * inv
    s = (wx * dy - wy * dx) * inv
    return torch.where(ok & (t >= 0) & (s >= 0) & (s <= 1) & mask, t, _INF)


def hit_circle(ox: Tensor, oy: Tensor, dx: Tensor, dy: Tensor, circ: Tensor, mask: Tensor) -> Tensor:
    """Distance along unit rays to circles ``[cx, cy, r]``, ``inf`` where missed (broadcasting).

    A ray starting inside a circle reports the exit point. Tangent rays and circles of
    radius 0 miss. The half chord is computed as ``(r - h)(r + h)`` with ``h`` the
    ray line's distance from the centre (a cross product), which keeps float32 precise
    far from the circle.
    """
    cx, cy, r = circ.unbind(-1)
    fx, fy = ox - cx, oy - cy
    b = fx * dx + fy * dy
    h = (fx * dy - fy * dx).abs()
    disc = (r - h) * (r + h)
    ok = disc > 0
    sq = torch.sqrt(torch.where(ok, disc, torch.ones_like(disc)))
    t_in, t_out = -b - sq, -b + sq
    t = torch.where(t_in >= 0, t_in, t_out)
    return torch.where(ok & (t >= 0) & mask, t, _INF)


def hit_box(ox: Tensor, oy: Tensor, dx: Tensor, dy: Tensor, box: Tensor, mask: Tensor) -> Tensor:
    """Distance along unit rays to oriented boxes ``[cx, cy, hx, hy, yaw]``, ``inf`` where missed.

    The slab method in the box frame. A ray parallel to a slab gets a tiny
    stand-in direction, which turns that slab's entry and exit into huge numbers
    of the right signs, exactly what +-inf would do, but finite for backward.
    A ray starting inside a box reports the exit point. A box with both half
    extents 0 is invisible; one with a single zero half extent is a thin wall.
    """
    return _hit_box_rows(ox, oy, dx, dy, _box_rows(box), mask)


def _box_rows(box: Tensor) -> Tensor:
    """Boxes ``[cx, cy, hx, hy, yaw]`` -> ``[cx, cy, hx, hy, cos yaw, sin yaw]``: the rotation computed
    once per box, not once per ray and box, when many rays meet the same boxes."""
    cx, cy, hx, hy, yaw = box.unbind(-1)
    # Stacked component-major (each component a contiguous block), so that compiled loops vectorise.
    return stack_rows((cx, cy, hx, hy, torch.cos(yaw), torch.sin(yaw)), box)


def _hit_box_rows(ox: Tensor, oy: Tensor, dx: Tensor, dy: Tensor, rows: Tensor, mask: Tensor) -> Tensor:
    """:func:`hit_box` on boxes given as :func:`_box_rows`."""
    cx, cy, hx, hy, c, s = rows.unbind(-1)
    px, py = ox - cx, oy - cy
    lox, loy = c * px + s * py, c * py - s * px
    ldx, ldy = c * dx + s * dy, c * dy - s * dx
    ix = 1.0 / torch.where(ldx.abs() > _TINY, ldx, torch.full_like(ldx, _TINY))
    iy = 1.0 / torch.where(ldy.abs() > _TINY, ldy, torch.full_like(ldy, _TINY))
    # Each slab is entered at (-lo -+ h) / ld, the sign taken from ld's: written with |1 / ld|, so no
    # minimum or maximum is needed per slab (12-17% faster compiled than min/max of both ends).
    ax, ay = lox * ix, loy * iy
    bx, by = hx * ix.abs(), hy * iy.abs()
    t_near = torch.maximum(-ax - bx, -ay - by)
    t_far = torch.minimum(bx - ax, by - ay)
    t = torch.where(t_near >= 0, t_near, t_far)
    visible = mask & ((hx > 0) | (hy > 0))
    return torch.where((t_near <= t_far) & (t_far >= 0) & visible, t, _INF)


def _same(obs: Tensor) -> Tensor:
    return obs


# Per obstacle kind: the world's field, its mask, and the hit function on that kind's rows as
# returned by its row function (which precomputes per-obstacle terms shared by many rays).
KINDS = (
    ("segments", "segment_mask", hit_segment, _same),
    ("circles", "circle_mask", hit_circle, _same),
    ("boxes", "box_mask", _hit_box_rows, _box_rows),
)


def bounding_circles(key: str, obs: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Centre ``x, y`` and radius (m) of a circle around each obstacle of kind ``key``, each ``obs.shape[:-1]``."""
    if key == "segments":
        ax, ay, bx, by = obs.unbind(-1)
        return 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * torch.hypot(bx - ax, by - ay)
    if key == "circles":
        return obs.unbind(-1)
    cx, cy, hx, hy, _ = obs.unbind(-1)
    return cx, cy, torch.hypot(hx, hy)


UNROLL_SLOTS = 32  # compiled: sets of at most this many slots are unrolled unless the caller says otherwise
EAGER_UNROLL_SLOTS = 4  # the same in eager mode ...
EAGER_UNROLL_MIN_RAYS = 8192  # ... when the batch casts at least this many rays (docs/performance.md, "Unrolled or batched lidar")


def unrolled(n_slots: int, n_rays: int) -> bool:
    """The default reduction of a set of ``n_slots`` slots met by ``n_rays`` rays in all (module docstring)."""
    if torch.compiler.is_compiling():
        return n_slots <= UNROLL_SLOTS
    return n_slots <= EAGER_UNROLL_SLOTS and n_rays >= EAGER_UNROLL_MIN_RAYS


def _cast_all(ox: Tensor, oy: Tensor, dx: Tensor, dy: Tensor, obs: Tensor, mask: Tensor, fn, rows, unroll: bool | None) -> Tensor:
    """Every ray ``(B, R)`` against every slot ``(B, N, w)`` of one kind -> nearest hit ``(B, R)``.

    The slots are first turned into the kind's rows (``KINDS``), materialised component-major."""
    obs = planar_rows(rows(obs))
    if unroll is None:
        unroll = unrolled(obs.shape[1], dx.numel())
    if unroll:
        best = torch.full_like(dx, _INF)
        for i in range(obs.shape[1]):
            best = torch.minimum(best, fn(ox, oy, dx, dy, obs[:, i].unsqueeze(1), mask[:, i : i + 1]))
        return best
    hits = fn(ox.unsqueeze(-1), oy.unsqueeze(-1), dx.unsqueeze(-1), dy.unsqueeze(-1), obs.unsqueeze(1), mask.unsqueeze(1))
    return hits.amin(-1)


def cast_rays(origin: Tensor, angles: Tensor, world: World, unroll: bool | None = None) -> Tensor:
    """Nearest hit distance ``(B, R)`` of rays from ``origin`` ``(B, 2)`` at world ``angles`` ``(B, R)``;
    ``inf`` where a ray hits nothing. Every ray against every slot (no broad phase).

    ``unroll`` picks the reduction (see the module docstring); ``None`` lets :func:`unrolled`
    choose for each kind.
    """
    dx, dy = torch.cos(angles), torch.sin(angles)
    ox, oy = origin[:, 0:1], origin[:, 1:2]  # (B, 1)
    best = torch.full_like(dx, _INF)
    for key, mkey, fn, rows in KINDS:
        obs, mask = getattr(world, key), getattr(world, mkey)
        if obs.shape[1]:
            best = torch.minimum(best, _cast_all(ox, oy, dx, dy, obs, mask, fn, rows, unroll))
    return best


@dataclass(frozen=True)
class RayFan:
    """Evenly spaced rays from one origin per env.

    Ray ``i`` points at ``first + i * spacing`` (rad, world frame); ``angles`` holds
    those directions as computed by the caller. A ``closed`` fan covers the full
    circle (``n * spacing = 2 pi``), so ray indices wrap around.
    """

    origin: Tensor  # (B, 2) m
    angles: Tensor  # (B, n) rad, world frame
    first: Tensor  # (B,) rad, direction of ray 0
    spacing: float  # rad between neighbouring rays
    closed: bool

    @property
    def n(self) -> int:
        return self.angles.shape[1]

    def index_of(self, phi: Tensor) -> Tensor:
        """Fractional ray index of world directions ``phi`` ``(B, ...)``: ray ``i`` lies at
        index ``i``. For a closed fan the index is not wrapped; reduce integer indices modulo ``n``."""
        first = self.first.reshape(-1, *([1] * (phi.dim() - 1)))
        if self.closed:
            return (phi - first) / self.spacing
        half = 0.5 * (self.n - 1) * self.spacing  # the fan's middle ray
        d = phi - first - half
        d = d - (2 * math.pi) * torch.round(d / (2 * math.pi))  # into [-pi, pi] around the middle
        return (d + half) / self.spacing


def _wide(fan: RayFan, key: str, obs: Tensor, mask: Tensor, window: int) -> Tensor:
    """Whether each obstacle of kind ``key`` may reach rays outside the window of ``2 * window + 1``
    rays around its bounding circle's centre: ``(B, N)`` int64, 0 or 1 (compiled CPU kernels
    store bool tensors about 20x slower than integers, see docs/performance.md).

    The rays just outside the window lie at least ``(window + 1/2) * spacing`` from the
    centre's direction; an obstacle is safe when its bounding circle's half angle
    ``asin(rho / D)`` is below that (compared as ``rho^2 < D^2 sin^2``, no asin; the
    1e-3 margin absorbs rounding in the angles). Masked slots are never wide.
    """
    cx, cy, rho = bounding_circles(key, obs)
    rx, ry = cx - fan.origin[:, 0:1], cy - fan.origin[:, 1:2]
    limit = min((window + 0.5) * fan.spacing * (1.0 - 1e-3), 0.5 * math.pi)
    return (mask & (rho * rho >= (rx * rx + ry * ry) * math.sin(limit) ** 2)).long()


def _centre_index(fan: RayFan, key: str, obs: Tensor) -> Tensor:
    """Fractional ray index ``(B, N)`` of the direction of each obstacle's bounding-circle centre."""
    cx, cy, _ = bounding_circles(key, obs)
    return fan.index_of(torch.atan2(cy - fan.origin[:, 1:2], cx - fan.origin[:, 0:1]))


def cast_fan(fan: RayFan, world: World, window: int = 2, dense_slots: int = 64, unroll: bool | None = None) -> Tensor:
    """Nearest hit distance ``(B, n)`` along every ray of ``fan``, ``inf`` on a miss.

    Kinds with at most ``BROAD_PHASE_RATIO * dense_slots`` slots are tested against every
    ray; larger ones go through the angular broad phase (module docstring). ``unroll``
    picks the reduction of the every-ray tests.
    """
    dx, dy = torch.cos(fan.angles), torch.sin(fan.angles)
    ox, oy = fan.origin[:, 0:1], fan.origin[:, 1:2]
    best = torch.full_like(dx, _INF)
    b = dx.shape[0]
    for key, mkey, fn, rows in KINDS:
        obs, mask = getattr(world, key), getattr(world, mkey)
        n_slots, width = obs.shape[1], obs.shape[-1]
        if n_slots == 0:
            continue
        if not _broad_phase(n_slots, dense_slots):
            best = torch.minimum(best, _cast_all(ox, oy, dx, dy, obs, mask, fn, rows, unroll))
            continue
        with torch.no_grad():
            dense, dense_ok = _first_wide(_wide(fan, key, obs.detach(), mask, window), dense_slots)
        dense_obs = obs.gather(1, dense.unsqueeze(-1).expand(-1, -1, width))
        best = torch.minimum(best, _cast_all(ox, oy, dx, dy, dense_obs, dense_ok & mask.gather(1, dense), fn, rows, unroll))
        with torch.no_grad():
            # Window ray indices (B, 2 window + 1, N), kept in floating point (integer division is
            # slow on CPU); the obstacle axis is the last one so that compiled loops run along it.
            u = _centre_index(fan, key, obs.detach())
            k = torch.round(u).unsqueeze(1) + torch.arange(-window, window + 1, device=obs.device, dtype=u.dtype).view(1, -1, 1)
            if fan.closed:
                k = k - fan.n * torch.floor(k / fan.n)
            flat = k.clamp(0, fan.n - 1).reshape(b, -1).long()  # (B, (2 window + 1) * N)
        angle = fan.first.reshape(b, 1, 1) + k * fan.spacing  # differentiable in the sensor's heading
        wdx, wdy = torch.cos(angle), torch.sin(angle)
        hits = fn(ox.unsqueeze(-1), oy.unsqueeze(-1), wdx, wdy, rows(obs).unsqueeze(1), mask.unsqueeze(1))
        if not fan.closed:  # window rays past the fan's ends do not exist
            hits = torch.where((k >= 0) & (k <= fan.n - 1), hits, _INF)
        best = best.scatter_reduce(1, flat, hits.reshape(b, -1), "amin", include_self=True)
    return best


def _broad_phase(n_slots: int, dense_slots: int) -> bool:
    """Whether :func:`cast_fan` uses the broad phase for a kind of ``n_slots`` slots."""
    return n_slots > BROAD_PHASE_RATIO * dense_slots


def _first_wide(wide: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """Slot indices ``(B, k)`` of the first ``k`` nonzero entries of ``wide`` ``(B, N)`` (int64, 0 or 1)
    per row, and which of them are real (rows with fewer than ``k`` fill with the last slot, marked False).

    The ``j``-th wide slot is where the running count first reaches ``j + 1``: a binary search
    of the count for each ``j``, cheaper than ``topk`` or a scatter and free of host syncs.
    """
    b, n = wide.shape
    count = wide.cumsum(1)
    wanted = torch.arange(1, k + 1, device=wide.device, dtype=count.dtype).expand(b, k).contiguous()
    picked = torch.searchsorted(count, wanted)
    return picked.clamp(max=n - 1), picked < n


def fan_is_exact(fan: RayFan, world: World, window: int = 2, dense_slots: int = 64) -> Tensor:
    """``(B,)`` bool: True where :func:`cast_fan` equals the every-ray-every-slot cast, i.e. no
    kind of the env has more than ``dense_slots`` obstacles too wide for their window."""
    ok = torch.ones(fan.origin.shape[0], dtype=torch.bool, device=fan.origin.device)
    for key, mkey, _, _ in KINDS:
        obs, mask = getattr(world, key), getattr(world, mkey)
        if _broad_phase(obs.shape[1], dense_slots):
            ok &= _wide(fan, key, obs.detach(), mask, window).sum(1) <= dense_slots
    return ok
