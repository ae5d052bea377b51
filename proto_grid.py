"""Prototype: obstacles sorted by grid cell once per world; each env scans the k x k cell block
around its sensor (k contiguous index ranges per kind, fixed padded length). Measures the
gathered scan against the whole scan (CPU time or wall time) and the share of exact sectors.
No fallback for inexact sectors is implemented: the gathered scan alone is the best case.
Recorded in docs/performance.md, "Dense worlds" ("A spatial order built once per world"):

    PYTHONPATH=. python proto_grid.py --k 5 --cell 2.0 --reps 3 --iters 10                 # per-row ranges, gather fused by inductor
    PYTHONPATH=. python proto_grid.py --k 5 --cell 2.0 --reps 3 --iters 10 --opaque        # gather materialised (an opaque op)
    PYTHONPATH=. python proto_grid.py --k 5 --cell 2.0 --reps 3 --iters 10 --opaque --sentinel --split               # no masks
    PYTHONPATH=. python proto_grid.py --k 5 --cell 2.0 --reps 3 --iters 10 --opaque --sentinel --segmented --split   # one padding per block
"""
import argparse, math, sys, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parent / "bench"))
import common  # noqa
import torch
from dataclasses import replace
from dense_lidar import make_dense, LOADS
from torchnav.sim import SimParams, World
from torchnav.sim.lidar import lidar_fan
from torchnav.sim.sector_scan import sector_ranges
from torchnav.sim.raycast import bounding_circles

p = argparse.ArgumentParser()
p.add_argument("--threads", type=int, default=1)
p.add_argument("--cell", type=float, default=1.6)
p.add_argument("--k", type=int, default=5)
p.add_argument("--n", type=int, default=4096)
p.add_argument("--reps", type=int, default=5)
p.add_argument("--iters", type=int, default=20)
p.add_argument("--wall", action="store_true")
p.add_argument("--stats", action="store_true")
p.add_argument("--opaque", action="store_true")
p.add_argument("--split", action="store_true")
p.add_argument("--sentinel", action="store_true")
p.add_argument("--segmented", action="store_true")
p.add_argument("--nocompile", action="store_true")
args = p.parse_args()
torch.set_num_threads(args.threads)
OPAQUE = args.opaque
SENTINEL = args.sentinel
SEGMENTED = args.segmented

params = replace(SimParams(), lidar=LOADS["dense-sectors"])
lid = params.lidar
state, world, _ = make_dense(args.n, params, 0)
pose = state.pose


def build(world, cell, k):
    """Per kind to grid: sorted obstacles, mask, starts (B, ncell+1), L; grid origin and dims."""
    cs = []
    for key, mkey in (("circles", "circle_mask"), ("boxes", "box_mask")):
        cx, cy, rho = bounding_circles(key, getattr(world, key))
        m = getattr(world, mkey)
        cs.append((cx[m], cy[m], rho[m]))
    allx = torch.cat([c[0] for c in cs]); ally = torch.cat([c[1] for c in cs])
    x0, y0 = float(allx.min()), float(ally.min())
    nx = int((float(allx.max()) - x0) // cell) + 1
    ny = int((float(ally.max()) - y0) // cell) + 1
    k = min(k, nx, ny)
    rho_max = float(torch.cat([c[2] for c in cs]).max())
    out = {}
    for key, mkey in (("circles", "circle_mask"), ("boxes", "box_mask")):
        obs, m = getattr(world, key), getattr(world, mkey)
        cx, cy, _ = bounding_circles(key, obs)
        ix = ((cx - x0) / cell).floor().clamp(0, nx - 1).long()
        iy = ((cy - y0) / cell).floor().clamp(0, ny - 1).long()
        cid = torch.where(m, iy * nx + ix, nx * ny)
        cid_s, perm = cid.sort(dim=1, stable=True)
        obs_s = obs.gather(1, perm.unsqueeze(-1).expand(-1, -1, obs.shape[-1]))
        m_s = m.gather(1, perm)
        starts = torch.searchsorted(cid_s, torch.arange(nx * ny + 1).expand(obs.shape[0], -1).contiguous())
        st = starts[:, :-1].reshape(-1, ny, nx); st = torch.cat((st, starts[:, 1:].reshape(-1, ny, nx)[:, :, -1:]), 2)  # (B, ny, nx+1) row starts incl row end
        L = int((st[:, :, k:] - st[:, :, :-k]).max())
        if SEGMENTED:
            L = int((st[:, :, k:] - st[:, :, :-k]).unfold(1, k, 1).sum(-1).max())  # the padded block total
        sent = obs_s.new_zeros(obs.shape[0], 1, obs.shape[-1]); sent[..., 0] = 1e6; sent[..., 1] = 1e6
        obs_s = torch.where(m_s.unsqueeze(-1), obs_s, sent)  # masked slots (past every range anyway) and the sentinel: zero-size, far
        obs_s = torch.cat((obs_s, sent), 1)
        out[key] = (obs_s.permute(2, 0, 1).contiguous().permute(1, 2, 0), m_s, starts, L)
    return out, (x0, y0, nx, ny, k, rho_max)


grid, (x0, y0, nx, ny, k, rho_max) = build(world, args.cell, args.k)
cell = args.cell
print(f"grid {nx}x{ny} cells of {cell} m, block {k}x{k}, L: circles {grid['circles'][3]} boxes {grid['boxes'][3]}, rho_max {rho_max:.2f}")
circ_s, cm_s, cstarts, Lc = grid["circles"]
box_s, bm_s, bstarts, Lb = grid["boxes"]


def block_of(origin):
    h = k // 2
    bx0 = ((origin[:, 0] - x0) / cell).floor().long().sub(h).clamp(0, nx - k)
    by0 = ((origin[:, 1] - y0) / cell).floor().long().sub(h).clamp(0, ny - k)
    return bx0, by0


@torch.library.custom_op("proto::take_rows", mutates_args=())
def take_rows(obs: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """(B, N, w) planar, (B, M) -> (B, M, w) planar materialised."""
    return torch.stack([obs[..., i].gather(1, idx) for i in range(obs.shape[-1])], 0).permute(1, 2, 0)


@take_rows.register_fake
def _(obs, idx):
    return obs.new_empty((obs.shape[2], idx.shape[0], idx.shape[1])).permute(1, 2, 0)


def gather_block(obs, starts, T, bx0, by0):
    """The k row ranges of the block packed into T slots (one padding for the whole block), rest sentinel."""
    rows = by0.unsqueeze(1) + torch.arange(k)
    first = rows * nx + bx0.unsqueeze(1)
    lo = starts.gather(1, first)
    n = starts.gather(1, first + k) - lo  # (B, k)
    cum = n.cumsum(1)  # (B, k): end of each row's part
    j = torch.arange(T).expand(obs.shape[0], T)
    r = sum((j >= cum[:, i:i + 1]).long() for i in range(k - 1))  # (B, T) the row of slot j
    before = torch.cat((torch.zeros_like(cum[:, :1]), cum[:, :-1]), 1)
    idx = lo.gather(1, r) + j - before.gather(1, r)
    idx = torch.where(j < cum[:, -1:], idx, obs.shape[1] - 1)
    return take_rows(obs, idx), torch.ones(1, 1, dtype=torch.bool).expand(idx.shape)


def gather_kind(obs, m, starts, L, bx0, by0):
    rows = by0.unsqueeze(1) + torch.arange(k)  # (B, k)
    first = rows * nx + bx0.unsqueeze(1)
    lo = starts.gather(1, first)
    hi = starts.gather(1, first + k)
    idx = lo.unsqueeze(-1) + torch.arange(L)  # (B, k, L)
    ok = idx < hi.unsqueeze(-1)
    if SENTINEL:
        idx = torch.where(ok, idx, obs.shape[1] - 1).reshape(obs.shape[0], -1)
        g = take_rows(obs, idx)
        return g, torch.ones(1, 1, dtype=torch.bool).expand(idx.shape)
    idx = idx.clamp(max=obs.shape[1] - 1).reshape(obs.shape[0], -1)
    g = take_rows(obs, idx) if OPAQUE else obs.gather(1, idx.unsqueeze(-1).expand(-1, -1, obs.shape[-1]))
    return g, ok.reshape(obs.shape[0], -1) & m.gather(1, idx)


def limits(fan, bx0, by0):
    """(B, S) distance below which a sector's reading from the block is exact."""
    ox, oy = fan.origin[:, 0], fan.origin[:, 1]
    inf = torch.full_like(ox, float("inf"))
    gaps = (  # (normal angle, gap) per border; borders on the grid's edge never cut anything
        (0.0, torch.where(bx0 + k < nx, x0 + (bx0 + k) * cell - ox, inf)),
        (math.pi, torch.where(bx0 > 0, ox - (x0 + bx0 * cell), inf)),
        (0.5 * math.pi, torch.where(by0 + k < ny, y0 + (by0 + k) * cell - oy, inf)),
        (-0.5 * math.pi, torch.where(by0 > 0, oy - (y0 + by0 * cell), inf)),
    )
    a0 = fan.angles  # (B, S) closed fan: sector j from a0[j] to a0[j] + spacing
    w = fan.spacing
    lim = torch.full_like(a0, float("inf"))
    for nrm, g in gaps:
        d = a0 - nrm
        d = d - 2 * math.pi * torch.floor(d / (2 * math.pi))  # in [0, 2pi): the normal lies in the wedge iff d + w >= 2pi or d == 0
        c = torch.maximum(torch.cos(d), torch.cos(d + w))
        c = torch.where(d + w >= 2 * math.pi, torch.ones_like(c), c)
        gg = (g - rho_max).unsqueeze(1)
        l = torch.where(c > 0, gg / c.clamp(min=1e-9), float("inf"))
        l = torch.where(gg < 0, -1.0, l)
        lim = torch.minimum(lim, l)
    return lim


def whole(pose):
    fan = lidar_fan(pose, lid)
    return sector_ranges(fan, world, lid.window, lid.dense_slots)


def gathered(pose):
    fan = lidar_fan(pose, lid)
    bx0, by0 = block_of(fan.origin)
    if SEGMENTED:
        c, cm = gather_block(circ_s, cstarts, Lc, bx0, by0)
        b, bm = gather_block(box_s, bstarts, Lb, bx0, by0)
    else:
        c, cm = gather_kind(circ_s, cm_s, cstarts, Lc, bx0, by0)
        b, bm = gather_kind(box_s, bm_s, bstarts, Lb, bx0, by0)
    w = World(segments=world.segments, segment_mask=world.segment_mask, circles=c, circle_mask=cm, boxes=b, box_mask=bm, batch_size=[pose.shape[0]])
    r = sector_ranges(fan, w, lid.window, lid.dense_slots)
    return r, r < limits(fan, bx0, by0)


ref = whole(pose)
r, ex = gathered(pose)
agree = (r - ref).abs() <= 1e-4 * (1 + ref)
print(f"exact sectors {ex.float().mean():.4f}, envs all exact {ex.all(1).float().mean():.4f}; wrong among exact: {(ex & ~agree).sum().item()}; agree overall {agree.float().mean():.4f}")
if args.stats:
    lim = limits(lidar_fan(pose, lid), *block_of(lidar_fan(pose, lid).origin))
    print("limit quantiles", torch.quantile(lim[lim.isfinite()].float(), torch.tensor([0.01, 0.1, 0.5])).tolist())
    print("reading quantiles", torch.quantile(ref.flatten(), torch.tensor([0.5, 0.9, 0.99])).tolist())
    print("inexact per env: hist", torch.bincount((~ex).sum(1))[:10].tolist())

fw, fg = (whole, gathered) if args.nocompile else (torch.compile(whole), torch.compile(gathered))
t0 = time.perf_counter(); fw(pose); fg(pose); print(f"compile {time.perf_counter() - t0:.0f}s", flush=True)
clock = time.perf_counter if args.wall else time.process_time
res = {"whole": [], "gathered": []}
for rep in range(args.reps):
    for name, f in (("whole", fw), ("gathered", fg)):
        f(pose)
        t = clock()
        for _ in range(args.iters):
            f(pose)
        res[name].append((clock() - t) / args.iters * 1000)
med = {k_: sorted(v)[len(v) // 2] for k_, v in res.items()}
print(f"threads {args.threads} {'wall' if args.wall else 'cpu'} ms/call: whole {med['whole']:.2f} {[round(x,1) for x in res['whole']]}, gathered {med['gathered']:.2f} {[round(x,1) for x in res['gathered']]}, x{med['whole']/med['gathered']:.2f}")

if args.split:
    fan0 = lidar_fan(pose, lid)
    bx0, by0 = block_of(fan0.origin)
    def gather_only(pose):
        fan = lidar_fan(pose, lid)
        bx0, by0 = block_of(fan.origin)
        if SEGMENTED:
            c, cm = gather_block(circ_s, cstarts, Lc, bx0, by0)
            b, bm = gather_block(box_s, bstarts, Lb, bx0, by0)
        else:
            c, cm = gather_kind(circ_s, cm_s, cstarts, Lc, bx0, by0)
            b, bm = gather_kind(box_s, bm_s, bstarts, Lb, bx0, by0)
        return c, cm, b, bm, limits(fan, bx0, by0)
    c, cm, b, bm, _ = gather_only(pose)
    wg = World(segments=world.segments, segment_mask=world.segment_mask, circles=c.permute(2,0,1).contiguous().permute(1,2,0), circle_mask=cm, boxes=b.permute(2,0,1).contiguous().permute(1,2,0), box_mask=bm, batch_size=[pose.shape[0]])
    def scan_only(pose):
        fan = lidar_fan(pose, lid)
        return sector_ranges(fan, wg, lid.window, lid.dense_slots)
    for name, f in (("gather_only", torch.compile(gather_only)), ("scan_only", torch.compile(scan_only))):
        f(pose); f(pose)
        ts = []
        for rep in range(args.reps):
            t = clock()
            for _ in range(args.iters):
                f(pose)
            ts.append((clock() - t) / args.iters * 1000)
        print(name, sorted(ts)[len(ts)//2], flush=True)
