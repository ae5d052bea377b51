"""Moving obstacles: discs and boxes with velocities, stepped inside the batched simulator step.

Each env holds ``M`` mover slots as one ``(B, M, 9)`` tensor (``SimState.movers``)
with a ``(B, M)`` bool mask; the columns are ``MOVER_FIELDS``:

    x, y (m), vx, vy (m/s), radius (m), xmin, ymin, xmax, ymax (m: the region)

The last ``K`` slots may be oriented boxes: their shapes are a second ``(B, K, 3)``
tensor (``SimState.mover_boxes``, ``Movers.boxes``), one row of ``BOX_FIELDS`` per box:

    half_x, half_y (m), yaw (rad)

so slots ``0`` to ``M - K - 1`` are discs and slots ``M - K`` to ``M - 1`` boxes, fixed by
the tensors' shapes: the lidar, the camera and collision test each disc only as a circle
and each box only as a box, and the step never asks the data which kind a slot is. A box
is centred at ``x, y`` and translates without turning; its ``radius`` is its bounding
circle's (``hypot(half_x, half_y)``), which is what the motion below uses (a box bounces
when its bounding circle meets the region's edge; pedestrians keep that circle clear).
Without boxes ``K = 0`` and the step costs what it did.

Three kinds of motion:

* **ballistic** (the default): constant velocity; inside a finite region the mover
  bounces off the region's edges (its disc stays inside: the position is mirrored at
  ``edge +- radius`` and that velocity component flips). An unbounded region
  (``+-inf``) gives plain constant-velocity motion.
* **patrol**: drives at its cruising speed straight to its next waypoint, and on
  reaching it (within one step's travel) heads for the following one, cyclically.
* **pedestrian**: walks towards its next waypoint like a patrol, but steers: its
  velocity relaxes towards the desired one over ``PED_TAU`` s and is pushed away from
  the other movers and the robot by exponential social forces
  (``PED_PUSH * exp((r_i + r_j - d_ij) / PED_RANGE)``, Helbing-Molnar), its speed capped
  at ``PED_MAX_SPEED`` times the cruising speed. It reaches a waypoint within ``PED_ARRIVE`` m.

Patrols and pedestrians keep their plan in ``SimState.mover_plan`` ``(B, M, 4 + 2P)``:
``kind`` (``BALLISTIC``, ``PATROL``, ``PEDESTRIAN``), cruising ``speed`` (m/s), the
index of the waypoint to head for first, the number of waypoints ``n`` (1 to ``P``), then ``P``
waypoints ``x, y`` (m). The plan is carried unchanged from step to step (never copied); the
index of the waypoint each mover heads for now is ``SimState.mover_target`` ``(B, M)``, which
``init_state`` takes from the plan and the step advances. Without any patrol or pedestrian
the plan is ``(B, M, 0)``, the target ``(B, 0)``, and they cost nothing. Every mover
also applies its region (unbounded for most patrols).
Masked slots move too but are seen by nothing. The lidar, the camera and collision
treat a mover like a static circle (or box) at its position after the step; movers
pass through walls and static obstacles.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import torch
from torch import Tensor

from .math import safe_hypot
from .state import World, _planar_copy, stack_rows

MOVER_FIELDS = ("x", "y", "vx", "vy", "radius", "xmin", "ymin", "xmax", "ymax")
N_MOVER_FIELDS = len(MOVER_FIELDS)
BOX_FIELDS = ("half_x", "half_y", "yaw")  # the columns of Movers.boxes / SimState.mover_boxes
BALLISTIC, PATROL, PEDESTRIAN = 0, 1, 2
PLAN_FIELDS = ("kind", "speed", "target", "n")  # then P waypoints (x, y)
PED_TAU = 0.5  # s, relaxation time of a pedestrian's velocity towards the desired one
PED_PUSH = 2.0  # m/s^2, social force at contact
PED_RANGE = 0.3  # m, decay length of the social force
PED_MAX_SPEED = 1.3  # times the cruising speed
PED_ARRIVE = 0.3  # m, a pedestrian has reached a waypoint this close to it
# The social force's exponent is floored here: past about 18 m of gap the force is below 1e-25 m/s^2,
# and farther still exp() would return subnormal float32 numbers, which x86 CPUs compute about 10x slower.
PED_EXP_FLOOR = -60.0


class Movers(NamedTuple):
    """Moving obstacles of a batch: ``rows`` ``(B, M, 9)``, ``mask`` ``(B, M)`` bool, ``plan``
    ``(B, M, 4 + 2P)`` or ``(B, M, 0)``, and ``boxes`` ``(B, K, 3)``, the shapes of the last ``K``
    movers, which are boxes (``None``: ``K = 0``, all discs; module docstring)."""

    rows: Tensor
    mask: Tensor
    plan: Tensor
    boxes: Tensor | None = None


def make_movers(
    batch_size: int,
    discs: Sequence[Sequence[float]] | Tensor | None = None,
    region: Sequence[float] | None = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
    *,
    waypoints: Sequence[Sequence[Sequence[float]]] | None = None,
    pedestrians: bool = False,
    boxes: Sequence[Sequence[float]] | Tensor | None = None,
) -> Movers:
    """The same movers in every env: ``discs`` ``(M, 5)`` rows ``[x, y, vx, vy, radius]``,
    bouncing inside ``region`` ``(xmin, ymin, xmax, ymax)`` (``None``: unbounded, constant velocity).

    ``boxes`` ``(K, 7)`` rows ``[x, y, vx, vy, half_x, half_y, yaw]`` add moving boxes after
    the discs (slots ``M`` to ``M + K - 1``; their shapes are ``Movers.boxes``, module docstring).

    ``waypoints``, one list of ``[x, y]`` per mover, makes the movers with a non-empty list
    patrols (or, with ``pedestrians=True``, pedestrians) whose cruising speed is the
    norm of their ``(vx, vy)``; movers with an empty list stay ballistic."""
    d = torch.as_tensor(discs if discs is not None and len(discs) else [], dtype=dtype, device=device)
    d = d.reshape(0, 5) if d.numel() == 0 else d
    if d.dim() != 2 or d.shape[1] != 5:
        raise ValueError(f"movers must have shape (M, 5) [x, y, vx, vy, radius], got {tuple(d.shape)}")
    if (d[:, 4] <= 0).any() or not torch.isfinite(d).all():
        raise ValueError("movers: radius must be > 0 and every value finite")
    shape = d.new_zeros(0, len(BOX_FIELDS))
    if boxes is not None:
        bx = torch.as_tensor(boxes if len(boxes) else [], dtype=dtype, device=device)
        bx = bx.reshape(0, 7) if bx.numel() == 0 else bx
        if bx.dim() != 2 or bx.shape[1] != 7:
            raise ValueError(f"movers: boxes must have shape (K, 7) [x, y, vx, vy, half_x, half_y, yaw], got {tuple(bx.shape)}")
        if (bx[:, 4:6] < 0).any() or ((bx[:, 4] == 0) & (bx[:, 5] == 0)).any() or not torch.isfinite(bx).all():
            raise ValueError("movers: boxes need half extents >= 0, not both 0, and every value finite")
        d = torch.cat((d, torch.cat((bx[:, :4], torch.hypot(bx[:, 4], bx[:, 5])[:, None]), 1)))
        shape = bx[:, 4:]
    reg = (-math.inf, -math.inf, math.inf, math.inf) if region is None else tuple(float(v) for v in region)
    if len(reg) != 4 or not (reg[0] < reg[2] and reg[1] < reg[3]):
        raise ValueError(f"movers: region must be (xmin, ymin, xmax, ymax) with xmin < xmax and ymin < ymax, got {region!r}")
    if d.shape[0] and region is not None:
        r = d[:, 4]
        inside = (d[:, 0] - r >= reg[0]) & (d[:, 0] + r <= reg[2]) & (d[:, 1] - r >= reg[1]) & (d[:, 1] + r <= reg[3])
        if not inside.all():
            raise ValueError(f"movers: every disc must start inside its region {reg}")
    m = d.shape[0]
    rows = torch.cat((d, torch.tensor(reg, dtype=dtype, device=device).expand(m, 4)), 1)
    plan = torch.zeros(m, 0, dtype=dtype, device=device)
    if waypoints is not None:
        if len(waypoints) != m:
            raise ValueError(f"movers: waypoints needs one list per mover ({m}), got {len(waypoints)}")
        p = max(1, max((len(w) for w in waypoints), default=1))
        plan = torch.zeros(m, 4 + 2 * p, dtype=dtype, device=device)
        for i, w in enumerate(waypoints):
            if not len(w):
                continue
            pts = torch.as_tensor(w, dtype=dtype, device=device)
            if pts.dim() != 2 or pts.shape[1] != 2 or not torch.isfinite(pts).all():
                raise ValueError(f"movers: waypoints[{i}] must be a list of finite [x, y], got {w!r}")
            plan[i, 0] = PEDESTRIAN if pedestrians else PATROL
            plan[i, 1] = d[i, 2:4].norm()
            plan[i, 3] = len(w)
            plan[i, 4 : 4 + 2 * len(w)] = pts.reshape(-1)
    return Movers(
        rows.unsqueeze(0).expand(batch_size, -1, -1).clone(),
        torch.ones(batch_size, m, dtype=torch.bool, device=device),
        plan.unsqueeze(0).expand(batch_size, -1, -1).clone(),
        shape.unsqueeze(0).expand(batch_size, -1, -1).clone(),
    )


def no_movers(batch_size: int, like: Tensor) -> Movers:
    """Zero mover slots: ``(B, 0, 9)``, ``(B, 0)``, ``(B, 0, 0)`` and ``(B, 0, 3)``."""
    return Movers(like.new_zeros(batch_size, 0, N_MOVER_FIELDS), torch.zeros(batch_size, 0, dtype=torch.bool, device=like.device),
                  like.new_zeros(batch_size, 0, 0), like.new_zeros(batch_size, 0, len(BOX_FIELDS)))


def step_movers(movers: Tensor, plan: Tensor, mask: Tensor, dt: float, robot_xy: Tensor, robot_radius: float | Tensor,
                target: Tensor, robot_mask: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Every mover ``(B, M, 9)`` advanced by ``dt`` s, and the waypoint index ``target`` ``(B, M)`` each
    patrol and pedestrian heads for after it (module docstring). Pure; ``plan`` is only read.

    ``robot_xy`` ``(B, 2)`` and ``robot_radius`` (m, or ``(B,)``) are what pedestrians avoid besides each
    other; for several robots per env (``robots.py``) ``robot_xy`` is ``(B, N, 2)``, ``robot_radius`` m or
    ``(B, N)``, and ``robot_mask`` ``(B, N)`` bool the robots that exist (``None``: all).

    The results have the shapes of the inputs but are stored mover-major (``mover_major``:
    ``movers[..., k]`` and ``target`` are contiguous ``(M, B)`` blocks), the layout the maths runs
    in, so a state stepped again is read without a copy."""
    if movers.shape[-1] != N_MOVER_FIELDS:
        raise ValueError(f"movers must have {N_MOVER_FIELDS} columns {MOVER_FIELDS}, got {tuple(movers.shape)} (boxes' shapes are a separate tensor)")
    if plan.shape[-1] and target.shape != plan.shape[:2]:
        raise ValueError(f"movers: target must have shape {tuple(plan.shape[:2])} (one waypoint index per mover), got {tuple(target.shape)}")
    if movers.shape[1] == 0:
        return movers, target
    cols = mover_major(movers)  # (B, M, 9) viewed from (9, M, B) storage
    x, y, vx, vy, r, xmin, ymin, xmax, ymax = (cols[..., k].t() for k in range(N_MOVER_FIELDS))  # (M, B) each
    if plan.shape[-1]:
        (vx, vy), target = _steer((x, y, vx, vy, r), mover_major(plan), target.t(), mask, dt, robot_xy, robot_radius, robot_mask)
        target = target.t()
    x, vx = _bounce(x + vx * dt, vx, xmin + r, xmax - r)
    y, vy = _bounce(y + vy * dt, vy, ymin + r, ymax - r)
    return torch.stack((x, y, vx, vy, r, xmin, ymin, xmax, ymax)).permute(2, 1, 0), target


def is_mover_major(x: Tensor) -> bool:
    """Whether ``x`` ``(B, M, k)`` is stored as a contiguous ``(k, M, B)`` tensor."""
    return x.permute(2, 1, 0).is_contiguous()


def mover_major(x: Tensor) -> Tensor:
    """``x`` ``(B, M, k)`` (same shape and values) stored mover-major: ``x`` itself when it already
    is, else a copy made by an opaque op (``torch.compile`` would otherwise fuse the transposed
    reads into its loops and iterate over the batch's few movers innermost, unvectorised)."""
    return x if is_mover_major(x) else _planar_copy(x.transpose(0, 1)).permute(2, 1, 0)


def _steer(cols: tuple[Tensor, ...], plan: Tensor, target: Tensor, mask: Tensor, dt: float, robot_xy: Tensor,
           robot_radius: float | Tensor, robot_mask: Tensor | None = None) -> tuple[tuple[Tensor, Tensor], Tensor]:
    """New velocities ``(M, B)`` of patrols and pedestrians (ballistic movers keep theirs) and the
    waypoint index ``target`` ``(M, B)`` with reached waypoints advanced.

    Written on ``(M, B)`` components ``cols`` = ``x, y, vx, vy, r`` (the batch the contiguous
    inner dimension) with short Python loops over the waypoints and the other movers:
    compiled, this fuses into vectorised passes, about 2.5x faster than the same maths on
    ``(B, M, M + 1, 2)`` pair tensors, whose inner dimension of a few movers does not vectorise."""
    kind, speed, n = plan[..., 0].t(), plan[..., 1].t(), plan[..., 3].t()
    x, y, vx, vy, r = cols
    gx, gy = torch.zeros_like(x), torch.zeros_like(y)
    for k in range((plan.shape[-1] - 4) // 2):  # the next waypoint
        here = target == k
        gx, gy = torch.where(here, plan[..., 4 + 2 * k].t(), gx), torch.where(here, plan[..., 5 + 2 * k].t(), gy)
    tx, ty = gx - x, gy - y
    dist = safe_hypot(tx, ty)
    ped = kind == PEDESTRIAN
    reach = torch.where(ped, torch.full_like(speed, PED_ARRIVE), speed * dt)
    arrived = (kind != BALLISTIC) & (dist <= reach * (1 + 1e-4) + 1e-6)  # with float slack: no pause on a waypoint
    scale = speed / dist.clamp(min=1e-9)
    dvx, dvy = scale * tx, scale * ty  # desired velocity
    # A patrol that arrives this step lands exactly on its waypoint.
    land = arrived & ~ped
    pvx, pvy = torch.where(land, tx / dt, dvx), torch.where(land, ty / dt, dvy)
    patrol = kind == PATROL
    nvx, nvy = torch.where(patrol, pvx, vx), torch.where(patrol, pvy, vy)
    # Pedestrians: relax towards the desired velocity, pushed by the other movers and the robot.
    # Mover i meets mover (i - s) mod M for s = 1 .. M - 1 (the rows rolled: an index, not a copy), so no
    # pair of a mover with itself is computed and masked off.
    mask = mask.t()
    others = [(x.roll(s, 0), y.roll(s, 0), r.roll(s, 0), mask.roll(s, 0)) for s in range(1, x.shape[0])]
    if robot_xy.dim() == 2:  # one robot per env
        rr = robot_radius[None, :].to(x.dtype) if isinstance(robot_radius, Tensor) else robot_radius
        others.append((robot_xy[None, :, 0], robot_xy[None, :, 1], rr, None))
    else:  # robots (B, N, 2): one more (1, B) row of others per robot
        for k in range(robot_xy.shape[1]):
            rr = robot_radius[None, :, k].to(x.dtype) if isinstance(robot_radius, Tensor) else robot_radius
            others.append((robot_xy[None, :, k, 0], robot_xy[None, :, k, 1], rr, None if robot_mask is None else robot_mask[None, :, k]))
    fx, fy = torch.zeros_like(x), torch.zeros_like(y)
    for ox, oy, orad, present in others:
        ax, ay = x - ox, y - oy
        d = safe_hypot(ax, ay)
        push = social_push(r + orad - d, d)
        if present is not None:  # only movers that exist
            push = torch.where(present, push, 0.0)
        fx, fy = fx + push * ax, fy + push * ay
    qx = vx + ((dvx - vx) / PED_TAU + fx) * dt
    qy = vy + ((dvy - vy) / PED_TAU + fy) * dt
    cap = torch.minimum(torch.ones_like(speed), PED_MAX_SPEED * speed / safe_hypot(qx, qy).clamp(min=1e-9))
    nvx, nvy = torch.where(ped, qx * cap, nvx), torch.where(ped, qy * cap, nvy)
    after = target + 1  # the following waypoint, cyclically (a select, not a float remainder: target < n)
    return (nvx, nvy), torch.where(arrived, torch.where(after >= n, 0.0, after), target)


def social_push(gap: Tensor, dist: Tensor) -> Tensor:
    """Social force per metre of separation (1/s^2) between two bodies ``dist`` m apart whose discs
    overlap by ``gap`` m (negative when apart): ``PED_PUSH * exp(gap / PED_RANGE) / dist``, with the
    exponent floored at ``PED_EXP_FLOOR`` so that no subnormal number enters the step."""
    return PED_PUSH * torch.exp((gap * (1 / PED_RANGE)).clamp(min=PED_EXP_FLOOR)) / dist.clamp(min=1e-9)


def _bounce(p: Tensor, v: Tensor, lo: Tensor, hi: Tensor) -> tuple[Tensor, Tensor]:
    """Mirror positions that left ``[lo, hi]`` back inside and flip their velocity (one reflection per
    step: a mover crosses its region in more than one step)."""
    below, above = p < lo, p > hi
    p = torch.where(below, 2 * lo - p, torch.where(above, 2 * hi - p, p))
    v = torch.where(below | above, -v, v)
    return p, v


def check_mover_boxes(boxes: Tensor, b: int, m: int) -> int:
    """Check the shapes ``(b, K, 3)`` of the last ``K <= m`` movers, which are boxes; returns ``K``."""
    if boxes.dim() != 3 or boxes.shape[0] != b or boxes.shape[2] != len(BOX_FIELDS) or boxes.shape[1] > m:
        raise ValueError(f"mover boxes must have shape ({b}, K, {len(BOX_FIELDS)}) with K <= {m} (the last K movers are "
                         f"boxes), got {tuple(boxes.shape)}")
    return boxes.shape[1]


def mover_world(movers: Tensor, mask: Tensor, boxes: Tensor | None = None) -> World:
    """The movers ``(B, M, 9)`` as a :class:`World` of circles ``[x, y, radius]`` (the first
    ``M - K`` slots) and boxes ``[x, y, half_x, half_y, yaw]`` (the last ``K``, whose shapes are
    ``boxes`` ``(B, K, 3)``; ``None``: no boxes); no walls; stored component-major in the movers' own
    ``(M, B)`` block order (``stack_rows``): built and read without a transpose."""
    b, m = movers.shape[:2]
    k = 0 if boxes is None else check_mover_boxes(boxes, b, m)
    disc, box = movers[:, : m - k], movers[:, m - k :]
    circles = stack_rows((disc[..., 0], disc[..., 1], disc[..., 4]), disc)
    box_rows = movers.new_zeros(b, 0, 5)
    if k:
        box_rows = stack_rows((box[..., 0], box[..., 1], boxes[..., 0], boxes[..., 1], boxes[..., 2]), box)
    return World(
        segments=movers.new_zeros(b, 0, 4), segment_mask=mask[:, :0],
        circles=circles, circle_mask=mask[:, : m - k], boxes=box_rows, box_mask=mask[:, m - k :],
        batch_size=[b], device=movers.device,
    )
