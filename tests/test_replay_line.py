"""Replay of line-following recordings: the summary names the termination reasons and the
metadata, the animation draws the track and no goal; navigation recordings replay as before."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from torchnav.controllers.line_follower import LineFollower
from torchnav.envs import make_line_env
from torchnav.envs.nav_env import make_nav_env
from torchnav.record import EpisodeRecorder, read_recording, record_rollout
from torchnav.record.replay import main as replay_main
from torchnav.record.replay import render_episode, scene_lines, summary, task_kind


@pytest.fixture(scope="module")
def line_recording(tmp_path_factory):
    env = make_line_env("oval", num_envs=2, max_steps=20, seed=0)
    follower = LineFollower().bind(env)

    def policy(td):  # env 1 turns off the line; env 0 follows it until the time limit
        td = follower(td)
        td["action"][1] = torch.tensor([1.0, -0.2])
        return td

    path = tmp_path_factory.mktemp("line") / "line.mcap"
    with EpisodeRecorder(path, env, envs=(0, 1), episodes=1, on_error="raise", metadata={"seed": 0, "note": "pd"}) as rec:
        record_rollout(env, policy, max_steps=25, recorder=rec)
    return env, path


def _gif_frames(path) -> int:
    with Image.open(path) as im:
        assert im.format == "GIF"
        return im.n_frames


def test_line_summary_shows_reasons_and_metadata(line_recording, capsys):
    _, path = line_recording
    rec = read_recording(path)
    assert task_kind(rec.episodes()) == "line"
    text = summary(rec)
    assert "task=line" in text and "track=oval" in text and "seed=0" in text and "note=pd" in text
    assert "goal" not in text
    assert {e.env: e.outcome for e in rec.episodes()} == {0: "timeout", 1: "left_line"}
    assert "finished episodes: 2 (left_line 50%, stalled 0%, collision 0%, timeout 50%)" in text
    assert replay_main([str(path), "--json"]) == 0
    assert '"outcome": "left_line"' in capsys.readouterr().out


def test_line_track_is_read_from_the_scene(line_recording):
    env, path = line_recording
    rec = read_recording(path)
    ep = rec.episodes()[0]
    lines = scene_lines(rec, ep)
    assert list(lines) == ["track"]
    track = lines["track"]
    assert track["thickness"] == pytest.approx(env.track.width)
    np.testing.assert_allclose(track["segments"], env.track.segments.reshape(-1, 4), atol=1e-4)


def test_line_episode_renders_to_gif(line_recording, tmp_path, capsys):
    _, path = line_recording
    out = tmp_path / "line.gif"
    assert replay_main([str(path), "--env", "1", "--out", str(out), "--stride", "4", "--dpi", "40"]) == 0
    assert "wrote" in capsys.readouterr().out
    assert _gif_frames(out) > 1
    rec = read_recording(path)
    ep = next(e for e in rec.episodes() if e.env == 0)
    assert _gif_frames(render_episode(rec, ep, tmp_path / "line0.gif", stride=10, dpi=30)) > 1


def test_nav_recording_still_replays(tmp_path, capsys):
    env = make_nav_env("arena", num_envs=2, max_steps=10, seed=1)
    path = tmp_path / "nav.mcap"
    with EpisodeRecorder(path, env, envs=(0,), episodes=1, on_error="raise", metadata={"seed": 1}) as rec:
        record_rollout(env, None, 12, rec)
    r = read_recording(path)
    assert task_kind(r.episodes()) == "nav" and scene_lines(r, r.episodes()[0]) == {}
    out = tmp_path / "nav.gif"
    assert replay_main([str(path), "--out", str(out), "--stride", "3", "--dpi", "40"]) == 0
    text = capsys.readouterr().out
    assert "task=nav" in text and "map=arena" in text and "success" in text and "collision" in text and "wrote" in text
    assert _gif_frames(out) > 1
