"""A recorded line-following episode: the track is drawn in every scene, every message
matches its schema, and terminations carry their reason."""

from __future__ import annotations

import json

import torch
from mcap.reader import make_reader

from torchnav.controllers.line_follower import LineFollower
from torchnav.envs import make_line_env
from torchnav.record import EpisodeRecorder, JsonDecoderFactory, read_recording, record_rollout, validate


def test_recorded_line_episode_contains_the_track(tmp_path):
    env = make_line_env("oval", num_envs=3, max_steps=30, seed=0)
    follower = LineFollower().bind(env)

    def policy(td):  # env 1 turns off the line; the others follow it
        td = follower(td)
        td["action"][1] = torch.tensor([1.0, -0.2])
        return td

    path = tmp_path / "line.mcap"
    with EpisodeRecorder(path, env, envs=(0, 1), episodes=1, on_error="raise", metadata={"seed": 0}) as rec:
        record_rollout(env, policy, max_steps=40, recorder=rec)
    with open(path, "rb") as f:
        for schema, _, _, decoded in make_reader(f, decoder_factories=[JsonDecoderFactory()]).iter_decoded_messages():
            validate(decoded, json.loads(schema.data))
    r = read_recording(path)
    assert r.metadata["torchnav"]["map"] == "oval"
    scene = r.topic("/env0/scene")[0].data
    track = next(e for e in scene["entities"] if e["id"] == "track")
    line = track["lines"][0]
    assert line["type"] == 2 and line["thickness"] == env.track.width
    assert len(line["points"]) == 2 * env.track.segments.shape[0]
    assert not any(e["id"] == "goal" for e in scene["entities"])
    outcomes = {e.env: e.outcome for e in r.episodes()}
    assert outcomes == {0: "timeout", 1: "left_line"}
