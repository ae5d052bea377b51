"""Evaluate a saved policy on any map: success, collision and timeout rates, steps to goal and
path-length ratio, with 95% confidence intervals. Line-following policies are evaluated
on lap completion from random starts (``--track``, ``--laps``); multi-robot policies (``multi_nav``,
recipes/mappo_nav.py) on team success, robots at their goal and collisions, with any robot count
(``--set robots.n=8``). ``--controller`` evaluates a classical controller instead (docs/controllers.md;
``orca`` for several robots), on a checkpoint's task and episodes when one is given.

    python recipes/evaluate.py                                  # the shipped checkpoint on arena
    python recipes/evaluate.py runs/td3_lidar_.../actor.pt --map warehouse --episodes 1000 --json out.json
    python recipes/evaluate.py CKPT --record 5                  # also write 5 episodes to an MCAP file (--record-path)
    python recipes/evaluate.py CKPT --record-bag runs/bags --bag-episodes 3   # 3 episodes as ROS 2 bags (docs/ros.md)
    python recipes/evaluate.py CKPT --episodes-file my_episodes.yaml   # given starts and goals (a map)
    python recipes/evaluate.py runs/mappo_nav_.../actor.pt --set robots.n=8      # a multi-robot policy with 8 robots
    python recipes/evaluate.py --controller orca --set robots.n=4 robots.scenario=circle_swap
    python recipes/evaluate.py runs/mappo_nav_.../actor.pt --controller orca    # ORCA on that policy's episodes

Accepts the ``actor.pt`` any recipe writes (format ``torchnav-actor-v2``, or ``-v3`` for a recurrent policy; see
``torchnav/policy.py``) and the recipes' training checkpoints (``checkpoint.pt``).
Episodes use seeds ``seed, seed+1, ...`` through the env generator, so the same
arguments give the same scenarios for every policy.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import builders as B  # noqa: E402

from torchnav.checkpoint import write_atomic  # noqa: E402
from torchnav.config import to_dict  # noqa: E402
from torchnav.controllers import CONTROLLERS, MULTI_CONTROLLERS, make_controller  # noqa: E402
from torchnav.evaluation import FINAL_EVAL_SEED, load_episodes  # noqa: E402
from torchnav.policy import load_policy  # noqa: E402
from torchnav.protocol import PROTOCOLS  # noqa: E402
from torchnav.tasks.robots import override_config  # noqa: E402
from torchnav.train_config import parse_override  # noqa: E402

DEFAULT_CHECKPOINT = Path(__file__).resolve().parent.parent / "checkpoints" / "td3_arena_actor.pt"


def load_actor(path: Path):
    """Deterministic navigation policy and the NavConfig it was trained with, from ``actor.pt`` or ``checkpoint.pt``."""
    sp = load_policy(path)
    if sp.task != "nav":
        raise ValueError(f"{path}: a {sp.task!r} policy, not a navigation policy")
    return sp.policy, sp.config()


def parse_sets(p: argparse.ArgumentParser, flag: str, items: list[str]) -> dict:
    """``["a.b=1", "c=x"]`` -> ``{"a": {"b": 1}, "c": "x"}``, values read as the recipes' command lines read
    them (``parse_override``: ``off`` stays a string); a bad item is a usage error."""
    over: dict = {}
    for kv in items:
        if "=" not in kv:
            p.error(f"{flag} expects KEY=VALUE, got {kv!r}")
        k, v = parse_override(kv)
        node = over
        parts = k.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = v
    return over


def default_record_path(ckpt: Path, where: str) -> Path:
    """``eval_episodes.mcap`` beside a run's checkpoint (a directory with ``config.yaml``); for any
    other checkpoint (the shipped ones in ``checkpoints/``) under ``runs/eval/``, never in a tracked folder."""
    if (ckpt.parent / "config.yaml").is_file():
        return ckpt.parent / "eval_episodes.mcap"
    return Path("runs") / "eval" / f"{ckpt.stem}_{Path(str(where)).stem}.mcap"


def main(argv: list[str]) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", nargs="?", default=None,
                   help="actor.pt or checkpoint.pt (default: the shipped arena policy; with --controller: none, the task's defaults)")
    p.add_argument("--controller", default=None, metavar="NAME",
                   help=f"evaluate this classical controller instead ({', '.join(CONTROLLERS)}: navigation; {', '.join(MULTI_CONTROLLERS)}: "
                        "several robots), on the checkpoint's task and episodes if one is given")
    p.add_argument("--gains", nargs="*", default=[], metavar="KEY=VALUE", help="--controller's gains, e.g. time_horizon=3 (docs/controllers.md)")
    p.add_argument("--map", "--track", dest="map", default=None, help="map (navigation) or track (line following) name or YAML path (default: where it was trained: its map, or its procedural worlds at their top difficulty)")
    p.add_argument("--laps", type=int, default=None, help="line following: laps an episode must complete to succeed (default 1)")
    p.add_argument("--episodes", type=int, default=None, help="number of episodes (default 1000)")
    p.add_argument("--episodes-file", default=None, metavar="YAML",
                   help="navigation on a map: play these episodes instead of sampled ones (episodes: [{start: [x, y, heading], goal: [x, y]}, ...], "
                        "optionally map: NAME; docs/training.md, 'Evaluating')")
    p.add_argument("--seed", type=int, default=FINAL_EVAL_SEED, help="scenario seed (default 20000)")
    p.add_argument("--curriculum", action="store_true", help="keep the training curriculum's goal radius instead of goals anywhere")
    p.add_argument("--device", default="cpu")
    p.add_argument("--threads", type=B.threads_arg, default="auto", help="torch CPU threads: auto (the cores other processes leave free) or a number")
    p.add_argument("--json", default=None, help="write the results as JSON to this path")
    p.add_argument("--record", type=int, default=0, help="write this many episodes to an MCAP file")
    p.add_argument("--record-path", default=None, help="MCAP path (default: eval_episodes.mcap beside a run's checkpoint, else runs/eval/<checkpoint>_<map>.mcap)")
    p.add_argument("--record-bag", default=None, metavar="DIR",
                   help="navigation: write the first --bag-episodes episodes as ROS 2 bags DIR/episode_000, ... (MCAP storage; "
                        "needs rosbags: pip install 'torchnav[ros]'; docs/ros.md)")
    p.add_argument("--bag-episodes", type=int, default=1, help="episodes written with --record-bag (default 1)")
    p.add_argument("--live", type=int, default=None, metavar="PORT",
                   help="after evaluating, stream --live-episodes episodes to the Foxglove app over a WebSocket server on PORT "
                        "(Foxglove: Open connection -> Foxglove WebSocket -> ws://localhost:PORT)")
    p.add_argument("--live-episodes", type=int, default=4, help="episodes streamed with --live (default 4, side by side)")
    p.add_argument("--realtime", type=float, default=1.0, help="--live pace: simulated seconds per wall-clock second (default 1)")
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="task overrides, e.g. max_steps=300 reward.preset=shaped robots.n=8")
    a = p.parse_args(argv)
    if a.gains and a.controller is None:
        p.error("--gains are a controller's: give --controller")
    kind = None
    if a.controller is not None:
        kinds = {**{n: "nav" for n in CONTROLLERS}, **{n: "multi_nav" for n in MULTI_CONTROLLERS}}
        if a.controller not in kinds:
            p.error(f"--controller {a.controller!r}: unknown; available: {', '.join(kinds)}")
        kind = kinds[a.controller]
    given = None
    if a.episodes_file:
        for flag, used in (("--episodes", a.episodes is not None), ("--curriculum", a.curriculum)):
            if used:
                p.error(f"{flag} does not go with --episodes-file (the file sets the episodes, their starts and goals)")
        try:
            file_map, starts, goals = load_episodes(a.episodes_file)
        except ValueError as e:
            p.error(str(e))
        given = (starts, goals)
        if file_map is not None and a.map is not None and a.map != file_map:
            p.error(f"--map {a.map} but {a.episodes_file} was written for map {file_map}")
        a.map = a.map or file_map
        a.episodes = len(given[0])
        for flag, n in (("--record", a.record), ("--live-episodes", a.live_episodes if a.live is not None else 0),
                        ("--bag-episodes", a.bag_episodes if a.record_bag else 0)):
            if n > a.episodes:
                p.error(f"{flag} {n}: {a.episodes_file} holds {a.episodes} episodes (it records the first ones)")
    a.episodes = 1000 if a.episodes is None else a.episodes
    if a.episodes < 1:
        p.error("--episodes must be >= 1")
    if a.live is not None and not (0 <= a.live <= 65535 and a.live_episodes >= 1 and a.realtime > 0):
        p.error("--live needs a port in [0, 65535], --live-episodes >= 1 and --realtime > 0")
    B.ThreadGovernor(a.threads)
    ckpt = Path(a.checkpoint) if a.checkpoint is not None else (None if kind else DEFAULT_CHECKPOINT)
    sp = None if ckpt is None else load_policy(ckpt)
    task_name = kind or sp.task
    if sp is not None and kind is not None and sp.task != kind:
        p.error(f"--controller {a.controller} drives the {kind!r} task; {ckpt} is a {sp.task!r} policy")
    over = parse_sets(p, "--set", a.set)
    P = PROTOCOLS[task_name]
    what = f"{ckpt} is a {task_name!r} policy" if a.controller is None else f"--controller {a.controller} drives the {task_name!r} task"
    for flag, used, task_kind in (("--laps", a.laps is not None, "line"), ("--curriculum", a.curriculum, "nav"), ("--episodes-file", given is not None, "nav")):
        if used and task_name != task_kind:
            p.error(f"{flag} is for {'line-following' if task_kind == 'line' else 'navigation'} policies; {what}")
    if a.record_bag and (task_name != "nav" or a.bag_episodes < 1):
        p.error(f"--record-bag records navigation episodes (--bag-episodes >= 1); {what}" if task_name != "nav" else "--bag-episodes must be >= 1")
    if a.laps is not None and a.laps < 1:
        p.error("--laps must be >= 1")
    trained = {} if sp is None else sp.task_config  # the task the checkpoint was trained on, or the defaults
    if task_name == "nav":  # the protocol moves it to the map (eval_config: procedural worlds off)
        config = P.config_class.from_dict(override_config(trained, over), where="--set")
        task = P(config, anywhere=not a.curriculum, map=a.map)
    else:
        config = P.config_class.from_dict(override_config(trained, {**over, **({P.place: a.map} if a.map else {})}), where="--set")
        task = P(config, laps=a.laps or 1) if task_name == "line" else P(config)
    if a.controller is not None:
        actor = make_controller(a.controller, nav=config, **parse_sets(p, "--gains", a.gains)).to(a.device)
        name = a.controller + ("" if sp is None else f" on the task of {ckpt.name}")
    else:
        actor, name = sp.policy.to(a.device), ckpt.name
    where = task.where()  # what is evaluated: a map, a track, or procedural worlds at a difficulty
    generated = task_name == "nav" and bool(task.eval_config.worlds.families)
    if given is not None and generated:
        p.error("--episodes-file needs a map: give --map for a policy trained on procedural worlds")
    if given is not None:
        title = f"{name} on {where}, the {a.episodes} episodes of {a.episodes_file}"
    elif task_name == "nav":
        title = f"{name} on {where}, seed {a.seed}" + (" (goals anywhere)" if not a.curriculum else "")
    elif task_name == "multi_nav":
        title = f"{name} on {where}, {config.robots.n} robots ({config.robots.scenario}), seed {a.seed}"
    else:
        title = f"{name} on {where}, {a.laps or 1} lap(s) from random starts, seed {a.seed}"
    res = task.evaluate(actor, a.episodes, a.seed, a.device, progress="evaluating", **({} if given is None else {"given": given}))
    print(task.format(res, title=title))
    if given is not None:
        print(f"outcomes per episode (S success, C collision, T timeout): {res['outcomes']}")
    out = {"checkpoint": None if sp is None else str(ckpt), **({} if a.controller is None else {"controller": a.controller}),
           "task": task_name, "map": where, "seed": a.seed, "episodes": a.episodes,
           **({} if given is None else {"episodes_file": a.episodes_file}), **({"task_config": to_dict(config)} if task_name == "multi_nav" else {}), **res}
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        write_atomic(Path(a.json), json.dumps(out, indent=2))
        print(f"wrote {a.json}")

    def first_of(n: int):  # with --episodes-file: recorded episodes are the file's first n
        return None if given is None else (lambda env: env.reset_to(given[0][:n], given[1][:n]))

    if a.record:
        path = Path(a.record_path) if a.record_path else default_record_path(ckpt or Path(a.controller), "worlds" if generated else where)
        rec = task.record(actor, path, a.record, a.seed, a.device, {"checkpoint": str(ckpt or a.controller), "map": where}, first_of(a.record))
        print(f"recorded {a.record} episodes to {path}" if rec.error is None else f"recording failed: {rec.error}")
    if a.record_bag:
        from torchnav.ros.bag import BagRecorder

        meta = {"checkpoint": str(ckpt or a.controller), "map": where, "seed": a.seed}
        rec = task.record_with(actor, a.bag_episodes, a.seed, a.device, lambda env: BagRecorder(a.record_bag, env, meta), first_of(a.bag_episodes))
        print(f"wrote {len(rec.written)} ROS 2 bags under {a.record_bag}" if rec.error is None else f"bag recording failed: {rec.error}")
    if a.live is not None:
        from torchnav.record import LiveView

        def live_view(env):
            view = LiveView(env, envs=range(a.live_episodes), port=a.live, episodes=1, realtime=a.realtime)
            print(f"live: {a.live_episodes} episodes on ws://localhost:{view.port} (Foxglove: Open connection -> Foxglove WebSocket; "
                  "layout docs/foxglove_layout.json); Ctrl-C stops", flush=True)
            return view

        task.record_with(actor, a.live_episodes, a.seed, a.device, live_view, first_of(a.live_episodes))
    return out


if __name__ == "__main__":
    from torchnav.memory import hold_freed_memory

    hold_freed_memory()  # big evaluation batches reuse their freed memory (docs/performance.md, "Memory allocator")
    B.main_guard(main)
