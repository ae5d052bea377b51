"""MCAP recording: round trip, schemas, timestamps, step counts, crash safety, replay."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from collections import Counter

import numpy as np
import pytest
from mcap.reader import make_reader

from torchnav.envs.nav_env import make_nav_env
from torchnav.record import EpisodeRecorder, JsonDecoderFactory, RecordingWarning, read_recording, record_rollout, validate
from torchnav.record.replay import main as replay_main

STEPS = 60


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    env = make_nav_env("arena", num_envs=6, max_steps=25, seed=1)
    path = tmp_path_factory.mktemp("rec") / "episodes.mcap"
    with EpisodeRecorder(path, env, envs=(0, 4), metadata={"seed": 1, "checkpoint": "none.pt"}) as rec:
        td = record_rollout(env, None, STEPS, rec)
    return env, path, td


def test_round_trip_decodes_every_message_with_its_schema(recorded):
    env, path, _ = recorded
    counts = Counter()
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[JsonDecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 0
        assert all(c.compression == "zstd" for c in summary.chunk_indexes)
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            validate(decoded, json.loads(schema.data))
            counts[schema.name] += 1
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    for name in ("foxglove.FrameTransforms", "foxglove.LaserScan", "foxglove.SceneUpdate", "foxglove.Odometry",
                 "torchnav.Action", "torchnav.Reward", "torchnav.EpisodeEvent"):
        assert counts[name] > 0, name
    m = meta["torchnav"]
    assert m["map"] == "arena" and m["seed"] == "1" and m["checkpoint"] == "none.pt" and m["version"]
    assert json.loads(m["config"])["max_steps"] == 25


def test_schema_validator_rejects_wrong_messages():
    from torchnav.record import foxglove_schema

    s = foxglove_schema("LaserScan")
    validate({"frame_id": "a", "ranges": [1.0, 2.0], "start_angle": 0.0}, s)
    with pytest.raises(ValueError, match="unknown key"):
        validate({"frame": "a"}, s)
    with pytest.raises(ValueError, match="expected array"):
        validate({"ranges": 1.0}, s)


def test_laser_scan_matches_lidar(recorded):
    env, path, td = recorded
    li = env.task.params.lidar
    ang = li.angles()
    rec = read_recording(path)
    scans = rec.topic("/env4/scan")
    assert scans
    for m in scans:
        d = m.data
        assert len(d["ranges"]) == li.n_rays
        got = np.linspace(d["start_angle"], d["end_angle"], len(d["ranges"]))
        np.testing.assert_allclose(got, ang, atol=1e-9)
        assert d["frame_id"] == "env4/laser"
    # the scan after step t equals the rollout's raw lidar of env 4 (first episode: no reset in between)
    first = [m for m in scans][1]
    np.testing.assert_allclose(first.data["ranges"], td["next", "ranges"][4, 0].numpy(), atol=1e-4)


def test_timestamps_increase_per_channel(recorded):
    _, path, _ = recorded
    last: dict[str, int] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            if channel.topic in last:
                assert message.log_time > last[channel.topic], channel.topic
            last[channel.topic] = message.log_time
    assert len(last) == 2 * 8


def test_steps_in_file_equal_steps_in_rollout(recorded):
    env, path, td = recorded
    rec = read_recording(path)
    assert td.shape == (6, STEPS)
    for e in (0, 4):
        assert len(rec.topic(f"/env{e}/action")) == STEPS
        assert len(rec.topic(f"/env{e}/reward")) == STEPS
        eps = [x for x in rec.episodes() if x.env == e]
        assert sum(x.steps for x in eps) == STEPS
        done = td["next", "done"][e, :, 0]
        assert sum(x.outcome != "incomplete" for x in eps) == int(done.sum())
        # rewards match the rollout step by step
        np.testing.assert_allclose([m.data["reward"] for m in rec.topic(f"/env{e}/reward")],
                                   td["next", "reward"][e, :, 0].numpy(), atol=1e-5)
        # outcomes match the rollout's flags
        ends = done.nonzero().squeeze(-1).tolist()
        for x, t in zip([x for x in eps if x.outcome != "incomplete"], ends):
            want = "success" if td["next", "success"][e, t] else "collision" if td["next", "collision"][e, t] else "timeout"
            assert x.outcome == want


def test_episode_world_is_recorded(recorded):
    env, path, _ = recorded
    rec = read_recording(path)
    starts = [m.data for m in rec.events() if m.data["event"] == "start" and m.data["env"] == 0]
    assert len(starts) >= 2
    spec_boxes = env.task.spec.random_boxes.count if env.task.spec.random_boxes else 0
    for s in starts:
        assert len(s["world"]["segments"]) >= 4 * 4 and not s["world"]["fixed_only"]  # flat rows of 4
        assert len(s["world"]["boxes"]) <= 5 * (spec_boxes + len(env.task.spec.boxes))
    if spec_boxes:
        assert starts[0]["world"]["boxes"] != starts[1]["world"]["boxes"]  # re-placed at reset


def test_write_rollout_from_env_rollout(tmp_path):
    env = make_nav_env("arena", num_envs=4, max_steps=15, seed=2)
    td = env.rollout(40, break_when_any_done=False)
    path = tmp_path / "r.mcap"
    with EpisodeRecorder(path, env, envs=(1,)) as rec:
        rec.write_rollout(td)
    r = read_recording(path)
    assert len(r.topic("/env1/action")) == 40
    assert not r.topic("/env1/odom_estimate")  # a rollout carries no odometry estimate
    assert all(m.data["world"]["fixed_only"] for m in r.events() if m.data["event"] == "start")


def test_episode_limit_stops_recording(tmp_path):
    env = make_nav_env("arena", num_envs=3, max_steps=10, seed=0)
    with EpisodeRecorder(tmp_path / "n.mcap", env, envs=(0, 2), episodes=2, flush_steps=4) as rec:
        td = record_rollout(env, None, 500, rec)
    assert td.shape[1] < 500
    eps = read_recording(tmp_path / "n.mcap").episodes()
    assert Counter(e.env for e in eps) == {0: 2, 2: 2} and all(e.outcome != "incomplete" for e in eps)


def test_unwritable_path_warns_and_does_not_raise(tmp_path):
    env = make_nav_env("arena", num_envs=2, max_steps=10, seed=0)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.warns(RecordingWarning, match="recording to"):
        rec = EpisodeRecorder(blocker / "sub" / "e.mcap", env)
    assert not rec.enabled and rec.error
    record_rollout(env, None, 5, rec)  # no-op, no error
    rec.close()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_full_disk_warns_and_training_continues():
    env = make_nav_env("arena", num_envs=2, max_steps=10, seed=0)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        rec = EpisodeRecorder("/dev/full", env)
        td = record_rollout(env, None, 30, rec)
        rec.close()
    assert td.shape == (2, 30)
    assert not rec.enabled and "No space" in rec.error
    assert sum(issubclass(x.category, RecordingWarning) for x in w) == 1


CHILD = textwrap.dedent("""
    import sys, torch
    from torchnav.envs.nav_env import make_nav_env
    from torchnav.record import EpisodeRecorder
    from torchrl.envs.utils import step_mdp
    env = make_nav_env("arena", num_envs=2, max_steps=8, seed=0)
    rec = EpisodeRecorder(sys.argv[1], env, envs=(0,), flush_steps=1)
    td = env.reset()
    while True:
        td = env.step(env.rand_action(td))
        rec.write_step(td, env.state)
        print(rec.streams[0].finished_episodes, flush=True)
        td = env.maybe_reset(step_mdp(td))
""")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_killed_writer_leaves_readable_episodes(tmp_path, sig):
    path = tmp_path / "killed.mcap"
    path.write_bytes(b"the previous recording")  # replaced only by a complete recording
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        for line in proc.stdout:
            if int(line) >= 3 or time.monotonic() > deadline:
                break
        proc.send_signal(sig)
        proc.wait(timeout=30)
    finally:
        proc.kill()
    if sig == signal.SIGKILL:  # no close(): the steps so far are in the partial file, the previous one is untouched
        assert path.read_bytes() == b"the previous recording"
        path = tmp_path / "killed.partial.mcap"
    else:
        assert not (tmp_path / "killed.partial.mcap").exists()
    rec = read_recording(path)
    assert rec.complete == (sig == signal.SIGTERM)  # SIGTERM unwinds through close()
    finished = [e for e in rec.episodes() if e.outcome != "incomplete"]
    assert len(finished) >= 3
    for e in finished:
        assert e.steps == len([m for m in rec.topic("/env0/action") if m.data["episode"] == e.episode])
    assert rec.info["map"] == "arena"


def test_replay_prints_summary_and_writes_gif(recorded, tmp_path, capsys):
    _, path, _ = recorded
    out = tmp_path / "ep.gif"
    assert replay_main([str(path), "--env", "4", "--episode", "0", "--out", str(out), "--stride", "3", "--dpi", "40"]) == 0
    text = capsys.readouterr().out
    assert "episodes" in text and "env" in text and "wrote" in text
    assert out.stat().st_size > 0
    from PIL import Image

    with Image.open(out) as im:
        assert im.format == "GIF" and im.n_frames > 1


def test_replay_draws_every_episode_path_to_png(recorded, tmp_path, capsys):
    _, path, _ = recorded
    rec = read_recording(path)
    out = tmp_path / "paths.png"
    assert replay_main([str(path), "--out", str(out), "--dpi", "40"]) == 0
    assert "wrote" in capsys.readouterr().out
    from PIL import Image

    with Image.open(out) as im:  # one panel per episode, four to a row
        rows = -(-len(rec.episodes()) // 4)
        assert im.format == "PNG" and im.width > im.height / rows
    assert replay_main([str(path), "--out", str(tmp_path / "paths.jpg")]) == 2  # refused before the file is read
    assert "unknown format '.jpg'" in capsys.readouterr().err


def test_render_batch_trajectories_and_learning_curves(recorded, tmp_path):
    from torchnav.render import plot_env, plot_learning_curves, plot_trajectories, read_scalars

    env, _, td = recorded
    fig = plot_env(env, envs=(0, 1, 2), ncols=2)
    assert len(fig.axes) == 3
    fig.savefig(tmp_path / "batch.png")
    ax = plot_trajectories(td["next", "pose"], env.state.world, envs=(0, 4), done=td["next", "done"], goal=td["goal"])
    assert len(ax.lines) > 2
    ax.figure.savefig(tmp_path / "traj.png")
    run = tmp_path / "run"
    (run / "logs" / "scalars" / "eval").mkdir(parents=True)
    (run / "logs" / "scalars" / "eval" / "return.csv").write_text("0,1.0\n10,2.0\n20,3.5\n")
    (run / "logs" / "scalars" / "loss.csv").write_text("0,0.5\n10,0.25\n")
    scalars = read_scalars(run)
    assert set(scalars) == {"eval/return", "loss"} and scalars["eval/return"].shape == (3, 2)
    fig = plot_learning_curves(run, smooth=2)
    assert len(fig.axes) == 2
    fig.savefig(tmp_path / "curves.png")
    with pytest.raises(FileNotFoundError):
        plot_learning_curves(tmp_path / "empty")


def _arrays_of_arrays(schema, path="$"):
    """Paths in a JSON schema where an array's items are arrays (Foxglove's and Lichtblick's parsers reject them)."""
    found = []
    if isinstance(schema, dict):
        items = schema.get("items")
        if schema.get("type") == "array" and isinstance(items, dict) and items.get("type") == "array":
            found.append(path)
        for k, v in schema.items():
            found += _arrays_of_arrays(v, f"{path}.{k}")
    elif isinstance(schema, list):
        for i, v in enumerate(schema):
            found += _arrays_of_arrays(v, f"{path}[{i}]")
    return found


def test_every_recorded_schema_is_one_foxglove_can_parse(tmp_path):
    """No channel's JSON schema nests arrays in arrays, and the events' worlds are flat rows."""
    from mcap.reader import make_reader

    from torchnav.envs import make_nav_env
    from torchnav.record import EpisodeRecorder, read_recording, record_rollout

    env = make_nav_env("arena", num_envs=2, max_steps=10)
    path = tmp_path / "e.mcap"
    with EpisodeRecorder(path, env, envs=(0, 1), episodes=1) as rec:
        record_rollout(env, None, max_steps=10, recorder=rec)
    with open(path, "rb") as f:
        schemas = {s.name: json.loads(s.data) for s in make_reader(f).get_summary().schemas.values()}
    assert len(schemas) >= 7
    for name, schema in schemas.items():
        assert not _arrays_of_arrays(schema), f"{name}: arrays of arrays at {_arrays_of_arrays(schema)}"
    rec = read_recording(path)
    roots = {}
    for name in ("/env0/tf", "/env1/tf"):
        root = rec.topic(name)[0].data["transforms"][0]
        assert root["parent_frame_id"] == "world"
        roots[root["child_frame_id"]] = root["translation"]["x"]
    assert roots == {"env0/world": 0.0, "env1/world": 30.0}  # one tree: no missing transform between envs
    start = next(ep for ep in rec.episodes()).start
    world = start["world"]
    assert all(isinstance(x, float) for x in world["segments"]) and len(world["segments"]) % 4 == 0 and len(world["boxes"]) % 5 == 0
