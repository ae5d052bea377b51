"""MCAP recording of several robots per env (MultiNavEnv): every robot's topics and frames, the outcomes,
a file cut short, the protocol and the recipe, replay, the Foxglove layout and the live view."""

from __future__ import annotations

import importlib
import json
import shutil
import sys
from collections import Counter
from pathlib import Path

import pytest
import torch

from torchnav.envs import make_multi_nav_env
from torchnav.record import EpisodeRecorder, read_recording, record_rollout, validate
from torchnav.record.replay import main as replay_main
from torchnav.record.replay import summary

ROOT = Path(__file__).resolve().parent.parent
ROBOT_TOPICS = ("scan", "odom", "action", "reward")


def _env(**kw):
    # min_n=1: some envs have fewer robots than slots, whose absent robots must not appear
    return make_multi_nav_env("arena", num_envs=2, n_robots=3, robots={"min_n": 1}, max_steps=12, seed=3, **kw)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    env = _env()
    path = tmp_path_factory.mktemp("multi") / "episodes.mcap"
    with EpisodeRecorder(path, env, envs=(0, 1), episodes=1, metadata={"seed": 3}) as rec:
        td = record_rollout(env, None, 40, rec)
    return env, path, td


def test_every_robot_has_its_topics_frames_and_messages(recorded):
    env, path, td = recorded
    rec = read_recording(path)
    assert rec.complete and rec.info["n_robots"] == "3"
    for m in rec.messages:
        validate(m.data, rec.schemas[m.schema])
    count = Counter(m.topic for m in rec.messages)
    eps = rec.episodes()
    assert sorted(e.env for e in eps) == [0, 1] and all(e.outcome != "incomplete" for e in eps)
    mask = td["agents", "mask"][:, 0, :, 0]  # (E, N) the robots of each env's first episode
    assert not bool(mask.all()), "the seed should give an env with an absent robot"
    for e in eps:
        present = [j for j in range(3) if mask[e.env, j]]
        assert e.start["robots"] == present and len(e.start["starts"]) == 3 * len(present) and len(e.start["goals"]) == 2 * len(present)
        assert [r["robot"] for r in e.robots] == present
        n = e.steps
        assert n == int(td["next", "episode_length"][e.env, n - 1, 0])  # the steps of the env's first episode
        for j in range(3):
            want = {"scan": n + 1, "odom": n + 1, "action": n, "reward": n} if j in present else dict.fromkeys(ROBOT_TOPICS, 0)
            assert {k: count[f"/env{e.env}/robot{j}/{k}"] for k in ROBOT_TOPICS} == want, (e.env, j)
        for j in present:  # each robot's true pose after each step, and its scan in its own laser frame
            odom = rec.topic(f"/env{e.env}/robot{j}/odom")
            xy = torch.tensor([[m.data["pose"]["position"]["x"], m.data["pose"]["position"]["y"]] for m in odom[1:]])
            assert torch.allclose(xy, td["next", "agents", "pose"][e.env, :n, j, :2], atol=1e-5)
            scans = rec.topic(f"/env{e.env}/robot{j}/scan")
            assert all(s.data["frame_id"] == f"env{e.env}/robot{j}/laser" and len(s.data["ranges"]) == env.cfg.lidar.n_rays for s in scans)
        tf = rec.topic(f"/env{e.env}/tf")[-1].data["transforms"]
        children = {t["child_frame_id"] for t in tf}
        assert children == {f"env{e.env}/world"} | {f"env{e.env}/robot{j}/{f}" for j in present for f in ("base_link", "laser")}
        ids = {ent["id"] for ent in rec.topic(f"/env{e.env}/scene")[-1].data["entities"]}
        assert {"walls", "boxes"} | {f"{k}{j}" for j in present for k in ("robot", "trail", "goal")} <= ids
        assert not any(f"robot{j}" in ids for j in range(3) if j not in present)
        trail = next(ent for ent in rec.topic(f"/env{e.env}/scene")[-1].data["entities"] if ent["id"] == f"trail{present[0]}")
        # the path so far: the start and every step's point, then the current point again (the line's end while it is thinned)
        assert len(trail["lines"][0]["points"]) == n + 2


def test_outcomes_are_the_env_flags(recorded):
    env, path, td = recorded
    for e in read_recording(path).episodes():
        t = e.steps - 1  # the step the env's episode ended
        nxt = td["next"][e.env, t]
        assert e.team_success == bool(nxt["team_success"])
        assert e.outcome == ("success" if e.team_success else "timeout" if bool(nxt["truncated"]) else "collision")
        for r in e.robots:
            j = r["robot"]
            hit_goal = bool(td["next", "agents", "success"][e.env, : t + 1, j].any())
            crashed = bool(td["next", "agents", "collision"][e.env, : t + 1, j].any())
            assert r["outcome"] == ("success" if hit_goal else "collision" if crashed else "timeout" if bool(nxt["truncated"]) else "ended")
            assert r["return"] == pytest.approx(float(nxt["agents", "episode_return"][j]), abs=1e-5)
        assert e.ret == pytest.approx(sum(r["return"] for r in e.robots), abs=1e-4)


def test_replay_summarises_and_draws_every_robot(recorded, tmp_path, capsys, monkeypatch):
    import torchnav.render as render

    _, path, _ = recorded
    eps = read_recording(path).episodes()
    text = summary(read_recording(path))
    assert "task=multi_nav" in text and "team success" in text
    for e in eps:
        for r in e.robots:
            assert f"r{r['robot']}" in text
    drawn = []
    draw = render.draw_robots
    monkeypatch.setattr(render, "draw_robots", lambda ax, pose, radius, env=0, color=render.ROBOT_COLOR, **kw:
                        drawn.append((tuple(round(float(x), 4) for x in pose[0][:2]), str(color))) or draw(ax, pose, radius, env, color, **kw))
    e = max(eps, key=lambda e: len(e.robots))
    out = tmp_path / "ep.gif"
    assert replay_main([str(path), "--env", str(e.env), "--out", str(out), "--dpi", "30", "--stride", "4"]) == 0
    assert "wrote" in capsys.readouterr().out
    from PIL import Image

    with Image.open(out) as im:
        frames = im.n_frames
    assert frames > 1
    assert len({c for _, c in drawn}) == len(e.robots)  # one colour per robot
    assert len(drawn) % len(e.robots) == 0 and len(drawn) >= frames * len(e.robots)  # every robot in every frame


def test_a_file_cut_short_reads_back_with_its_robots(tmp_path):
    env = _env()
    path, cut = tmp_path / "e.mcap", tmp_path / "cut.mcap"
    rec = EpisodeRecorder(path, env, envs=(0,), episodes=1)
    record_rollout(env, None, 5, rec)  # flushes; the episodes (max_steps 12) are still running
    shutil.copy(rec.partial_path, cut)  # what a killed writer leaves (the recording so far, beside the path): no summary
    rec.close()
    r = read_recording(cut)
    assert not r.complete
    (e,) = r.episodes()
    assert e.outcome == "incomplete" and e.steps == 5 and e.team_success is None
    assert [x["outcome"] for x in e.robots] == ["incomplete"] * len(e.start["robots"])
    last = [r.topic(f"/env0/robot{j}/reward")[-1].data["return"] for j in e.start["robots"]]
    assert e.ret == pytest.approx(sum(last))


def test_steps_without_states_are_refused():
    env = _env()
    rec = EpisodeRecorder("/dev/null", env, envs=(0,), on_error="raise")
    try:
        td = env.rollout(2, break_when_any_done=False)
        with pytest.raises(ValueError, match="before="):
            rec.write_step(td[:, 0], env.state)
        with pytest.raises(ValueError, match="record_rollout"):
            rec.write_rollout(td)
    finally:
        rec.close()


def _arena_policy_task(n_robots: int = 3, max_steps: int = 150):
    """The shipped single-robot arena policy driving every robot (no neighbour features: the observation is its own)."""
    from torchnav.config import to_dict
    from torchnav.policy import load_policy
    from torchnav.protocol import task_protocol
    from torchnav.tasks import MultiNavConfig

    sp = load_policy(ROOT / "checkpoints" / "ppo_arena_actor.pt")
    d = {**to_dict(sp.config()), "robots": {"n": n_robots, "neighbours": 0}, "curriculum": {"mode": "off"}, "max_steps": max_steps}
    return sp.policy, task_protocol(MultiNavConfig.from_dict(d))


def test_protocol_records_what_it_evaluates(tmp_path):
    policy, task = _arena_policy_task()
    s = task.run(policy, 2, 11, "cpu")
    rec = task.record(policy, tmp_path / "p.mcap", 2, 11, "cpu", {"checkpoint": "ppo_arena_actor.pt"})
    assert rec.error is None
    r = read_recording(tmp_path / "p.mcap")
    eps = r.episodes()
    assert len(eps) == s["episodes"] == 2 and r.info["checkpoint"] == "ppo_arena_actor.pt" and r.info["seed"] == "11"
    robots = [x for e in eps for x in e.robots]
    assert len(robots) == s["robots"]
    assert sum(e.team_success for e in eps) == s["team_success"]["count"]
    assert sum(x["outcome"] == "success" for x in robots) == s["at_goal"]["count"] > 0
    assert sum(x["outcome"] == "collision" for x in robots) == s["collision"]["count"]
    assert sum(e.outcome == "timeout" for e in eps) == s["timeout"]["count"]
    hit_robot = {(m.data["env"], m.data["robot"]) for m in r.messages if m.topic.endswith("/reward") and m.data["robot_collision"]}
    assert len(hit_robot) == s["robot_collision"]["count"]

    # record_with takes any recorder, as for one robot
    seen = []

    def make(env):
        seen.append(env.n_robots)
        return EpisodeRecorder(tmp_path / "w.mcap", env, envs=(1,), episodes=1)

    task.record_with(policy, 2, 11, "cpu", make)
    assert seen == [3] and [e.robots for e in read_recording(tmp_path / "w.mcap").episodes()] == [next(e.robots for e in eps if e.env == 1)]


def test_mappo_recipe_writes_the_episodes(tmp_path):
    sys.path.insert(0, str(ROOT / "recipes"))
    run = tmp_path / "run"
    res = importlib.import_module("mappo_nav").main([
        "threads=1", "env.num_envs=8", "task.max_steps=10", "train.frames_per_batch=64", "train.minibatch_size=32", "train.epochs=1",
        "train.hidden=[16,16]", "train.obs_stats_steps=2", "eval.interval_frames=0", "eval.final_episodes=4", "eval.record_episodes=2",
        "train.total_frames=64", "logger.progress=false", f"logger.run_dir={run}"])
    assert res["episodes_mcap"] == str(run / "episodes.mcap")
    assert json.loads((run / "summary.json").read_text())["episodes_mcap"] == str(run / "episodes.mcap")
    r = read_recording(run / "episodes.mcap")
    eps = r.episodes()
    assert len(eps) == 2 and all(len(e.robots) == 4 and e.outcome != "incomplete" for e in eps)  # circle_swap, 4 robots
    assert r.info["checkpoint"] == str(run / "actor.pt")


def test_multi_robot_layout_shows_every_robot_of_a_recording(tmp_path):
    layout = json.loads((ROOT / "docs" / "foxglove_multi_robot_layout.json").read_text())
    env = make_multi_nav_env("arena", num_envs=1, n_robots=4, max_steps=3)
    path = tmp_path / "l.mcap"
    with EpisodeRecorder(path, env, envs=(0,), episodes=1) as rec:
        record_rollout(env, None, 3, rec)
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        written = {c.topic for c in make_reader(f).get_summary().channels.values()}
    used = set()
    for cfg in layout["configById"].values():
        used |= set(cfg.get("topics", {}))
        used |= {p["value"].split(".")[0] for p in cfg.get("paths", [])}
        if "topicPath" in cfg:
            used.add(cfg["topicPath"])
    assert used <= written, used - written
    view = layout["configById"]["3D!world"]
    assert view["followMode"] == "follow-none" and view["followTf"] == "env0/world"
    shown = {t for t, c in view["topics"].items() if c.get("visible")}
    assert shown == {"/env0/scene"} | {f"/env0/robot{j}/scan" for j in range(4)}  # the scene draws every robot, goal and path
    assert len({view["topics"][f"/env0/robot{j}/scan"]["flatColor"] for j in range(4)}) == 4


def test_live_view_streams_every_robot():
    pytest.importorskip("websockets")
    import struct
    import time

    from websockets.sync.client import connect

    from torchnav.record import LiveView

    env = make_multi_nav_env("arena", num_envs=2, n_robots=2, max_steps=10)
    want = {f"/env1/{t}" for t in ("tf", "scene", "events")} | {f"/env1/robot{j}/{t}" for j in range(2) for t in ROBOT_TOPICS}
    with LiveView(env, envs=(1,), port=0, realtime=None) as view:
        with connect(f"ws://127.0.0.1:{view.port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]) as ws:
            channels: dict[str, dict] = {}
            while not want <= set(channels):
                msg = json.loads(ws.recv(timeout=10))
                if msg["op"] == "advertise":
                    channels.update({c["topic"]: c for c in msg["channels"]})
            scan = channels["/env1/robot1/scan"]
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 5, "channelId": scan["id"]}]}))
            time.sleep(0.3)  # the subscription reaches the server before the first scan is logged
            record_rollout(env, None, max_steps=3, recorder=view)
            data = ws.recv(timeout=10)
            while isinstance(data, str):
                data = ws.recv(timeout=10)
            assert data[0] == 1 and struct.unpack_from("<I", data, 1)[0] == 5
            assert json.loads(data[13:])["frame_id"] == "env1/robot1/laser"
