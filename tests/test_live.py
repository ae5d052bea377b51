"""LiveView: chosen envs streamed over foxglove-sdk's WebSocket server; a client connects and receives them."""

from __future__ import annotations

import json
import struct

import pytest

websockets = pytest.importorskip("websockets")

from websockets.sync.client import connect  # noqa: E402

from torchnav.envs import make_nav_env  # noqa: E402
from torchnav.record import LiveView, record_rollout  # noqa: E402


def _advertised(ws) -> dict[str, dict]:
    channels: dict[str, dict] = {}
    while True:
        msg = json.loads(ws.recv(timeout=10))
        if msg["op"] == "advertise":
            channels.update({c["topic"]: c for c in msg["channels"]})
            if len(channels) >= len(LiveView.TOPICS):
                return channels


def test_live_view_streams_an_episode_to_a_websocket_client():
    env = make_nav_env("arena", num_envs=2, max_steps=20)
    with LiveView(env, envs=(1,), port=0, realtime=None) as view:
        assert view.port and view.port > 0
        with connect(f"ws://127.0.0.1:{view.port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]) as ws:
            info = json.loads(ws.recv(timeout=10))
            assert info["op"] == "serverInfo" and info["name"] == "torchnav"
            channels = _advertised(ws)
            assert {f"/env1/{t}" for t in LiveView.TOPICS} <= set(channels)
            scan = channels["/env1/scan"]
            assert scan["encoding"] == "json" and scan["schemaName"] == "foxglove.LaserScan"
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 3, "channelId": scan["id"]}]}))
            import time

            time.sleep(0.3)  # the subscription reaches the server before the first scan is logged
            record_rollout(env, None, max_steps=5, recorder=view)
            data = ws.recv(timeout=10)
            while isinstance(data, str):  # skip any further JSON notices
                data = ws.recv(timeout=10)
            opcode, sub_id = data[0], struct.unpack_from("<I", data, 1)[0]
            assert opcode == 1 and sub_id == 3  # message data for our subscription
            msg = json.loads(data[13:])
            assert len(msg["ranges"]) == env.cfg.lidar.n_rays and msg["frame_id"] == "env1/laser"


def test_live_view_refuses_a_bad_pace():
    with pytest.raises(ValueError, match="realtime must be > 0"):
        LiveView(make_nav_env("arena", num_envs=1), realtime=0)


def test_evaluate_live_option_streams_and_says_where(capsys):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "recipes"))
    import evaluate

    evaluate.main(["--episodes", "4", "--threads", "1", "--live", "0", "--live-episodes", "2", "--realtime", "1000"])
    assert "live: 2 episodes on ws://localhost:" in capsys.readouterr().out
