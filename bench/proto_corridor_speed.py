"""Diagnose the generalist on corridors/medium with its speed scaled down after the network.

    python bench/proto_corridor_speed.py corridors 0.5 200 1.0,0.7,0.5
"""
import sys, time, torch
from torchnav.policy import load_policy
from torchnav.evaluation import eval_config, run_episodes, summarize
torch.set_num_threads(1)
sp = load_policy(__import__("pathlib").Path(__file__).resolve().parents[1] / "checkpoints" / "ppo_generalist_actor.pt")
cfg0 = sp.config()
fam, diff, n = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
scales = [float(s) for s in sys.argv[4].split(",")]
cfg = eval_config(cfg0, worlds={"families": {fam: 1.0}, "difficulty": diff})
seed = 2170819 if fam == "corridors" else 2010707
for k in scales:
    def pol(td, k=k):
        td = sp.policy(td)
        a = td["action"].clone()
        a[..., 0] = k * (a[..., 0] + 1.0) - 1.0
        td["action"] = a
        return td
    t = time.time()
    s = summarize(run_episodes(pol, cfg, n, seed=seed))
    print(fam, diff, "speed x", k, {kk: (round(v["rate"]*100,1) if isinstance(v, dict) and "rate" in v else v) for kk, v in s.items() if kk in ("success","collision","timeout")}, f"{time.time()-t:.0f}s", flush=True)
