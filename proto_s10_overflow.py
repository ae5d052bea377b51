"""How often session 10's near-obstacle cache (commit 819d30c, torchnav/sim/near.py) fell back to the whole
scan of every env (its torch.cond overflow branch) on the dense bench's worlds, eager, 4,096 envs.

    mkdir -p /tmp/s10 && git archive 819d30c | tar -x -C /tmp/s10
    python proto_s10_overflow.py 280      # steps; prints the steps where the overflow branch ran
"""
import sys, math, torch
sys.path.insert(0, "/tmp/s10/bench"); sys.path.insert(0, "/tmp/s10")
torch.set_num_threads(1)
import common
from dataclasses import replace
import dense_lidar as dl
from torchnav.sim import SimParams, step
import torchnav.sim.near as near
assert near.__file__.startswith("/tmp/s10"), near.__file__
log = []
orig = torch.cond
def cond(pred, t, f, ops):
    log.append(bool(pred))
    return orig(pred, t, f, ops)
near.torch.cond = cond
params = replace(SimParams(), lidar=dl.LOADS["dense-near"], near_slots=96)
state, world, actions = dl.make_dense(4096, params, 0)
for i in range(int(sys.argv[1])):
    state = step(state, actions[i % len(actions)], world, params)
    if i % 40 == 39:
        print(i + 1, "steps, overflow steps so far:", sum(log), flush=True)
print("overflow at steps:", [i for i, x in enumerate(log) if x])
