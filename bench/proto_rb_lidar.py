"""Prototype: the standard load's lidar vectorised along the batch ((R, B) rays) vs the current (B, R) cast."""
import sys, time, torch
torch.set_num_threads(int(sys.argv[1]) if len(sys.argv) > 1 else 1)
sys.path.insert(0, __import__("os").path.dirname(__file__))
from torchnav.sim import raycast as rc
from torchnav.sim.lidar import ray_origins_and_angles
from torchnav.sim.state import planar_world
import sim_throughput as st
B = 4096
params = st.bench_params()
state, world, _ = st.make_load(B, "cpu", seed=0, params=params)
world = planar_world(world)
origin, angles = ray_origins_and_angles(state.pose, params.lidar)
INF = float("inf")
def cur(origin, angles, world):
    return rc.cast_rays(origin, angles, world)
def rb(origin, angles, world):
    a = angles.t()  # (R, B) view
    dx, dy = torch.cos(a), torch.sin(a)
    ox, oy = origin[:, 0][None], origin[:, 1][None]  # (1, B)
    best = torch.full_like(dx, INF)
    for key, mkey, fn, rows in rc.KINDS:
        obs, mask = getattr(world, key), getattr(world, mkey)
        r = rows(obs)  # (B, N, w)
        comp = r.permute(2, 1, 0).contiguous()  # (w, N, B)
        mk = mask.t().contiguous()  # (N, B)
        for i in range(obs.shape[1]):
            best = torch.minimum(best, fn(ox, oy, dx, dy, comp[:, i].t()[None], mk[i][None]))
    return best
def rb_t(origin, angles, world):
    return rb(origin, angles, world).t()
def rb_tc(origin, angles, world):
    return rb(origin, angles, world).t().contiguous()
fns = {"current (B,R)": torch.compile(cur), "(R,B) result": torch.compile(rb), "(R,B) then .t().contiguous()": torch.compile(rb_tc)}
ref = fns["current (B,R)"](origin, angles, world)
for k, f in fns.items():
    out = f(origin, angles, world)
    out = out.t() if out.shape != ref.shape else out
    fin = torch.isfinite(ref)
    assert torch.equal(fin, torch.isfinite(out)), k
    print(k, "max diff", float((ref[fin] - out[fin]).abs().max()))
res = {k: [] for k in fns}
for rep in range(15):
    for k, f in fns.items():
        t = time.process_time() if torch.get_num_threads() == 1 else time.perf_counter()
        for _ in range(20): f(origin, angles, world)
        res[k].append(((time.process_time() if torch.get_num_threads() == 1 else time.perf_counter()) - t) / 20 * 1e3)
for k, v in res.items():
    v.sort(); print(f"{k:32s} median {v[len(v)//2]:.3f} ms  min {v[0]:.3f}")
