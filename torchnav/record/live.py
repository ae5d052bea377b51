"""Live view: chosen envs of a batch streamed to the Foxglove app over foxglove-sdk's WebSocket server.

The same messages, topics and schemas as an MCAP recording (``EpisodeRecorder``), sent as they
are made; ``realtime`` paces the stream. Connecting and the layout: docs/foxglove.md.

    with LiveView(env, envs=(0, 1), port=8765) as view:   # view.port: where to connect
        record_rollout(env, policy, max_steps=1000, recorder=view)"""

from __future__ import annotations

import json
import time
from typing import Any, Iterable

import numpy as np

from .mcap_writer import EpisodeRecorder


class LiveView(EpisodeRecorder):
    """An :class:`EpisodeRecorder` whose sink is a Foxglove WebSocket server instead of an MCAP file.

    Args:
        env: the env whose steps are streamed (as for ``EpisodeRecorder``).
        envs: indices of the streamed envs in the batch.
        port: the server's TCP port (0: any free port; ``.port`` says which).
        host: the address to listen on (default: this machine only).
        episodes: stop streaming an env after this many finished episodes (None: no limit).
        realtime: simulated seconds per wall-clock second (None: no pacing).
    """

    def __init__(self, env: Any, envs: Iterable[int] = (0,), *, port: int = 8765, host: str = "127.0.0.1",
                 episodes: int | None = None, realtime: float | None = 1.0):
        if realtime is not None and not realtime > 0:
            raise ValueError(f"realtime must be > 0 or None, got {realtime!r}")
        self.host, self.requested_port, self.realtime = host, int(port), realtime
        self.server: Any = None
        self.port: int | None = None
        self._wall0 = time.monotonic()
        super().__init__(f"ws://{host}:{port}", env, envs, episodes=episodes, flush_steps=1, flush_seconds=0.0,
                         on_error="raise", handle_sigterm=False)

    def _open(self, metadata: Any) -> None:
        import foxglove

        self._context = foxglove.Context()
        self.server = foxglove.start_server(name="torchnav", host=self.host, port=self.requested_port, context=self._context)
        self.port = self.server.port
        schemas = {k: foxglove.Schema(name=s["title"], encoding="jsonschema", data=json.dumps(s).encode()) for k, s in self.schemas().items()}
        for st in self.streams:
            st.channels = {name: foxglove.Channel(f"/env{st.env}/{name}", schema=schemas[kind], message_encoding="json", context=self._context)
                           for name, kind in st.topic_kinds()}
        self._wall0 = time.monotonic()

    def add_message(self, channel: Any, t_ns: int, payload: str) -> None:
        """One JSON message ``payload`` on ``channel`` at ``t_ns`` ns, as ``EpisodeRecorder.add_message``."""
        channel.log(payload.encode(), log_time=t_ns)

    def _flush_file(self) -> None:
        pass

    def _encode(self, a: dict[str, np.ndarray]) -> bool:
        ended = super()._encode(a)
        if self.realtime is not None and self.streams:
            ahead = self.streams[0].t / 1e9 / self.realtime - (time.monotonic() - self._wall0)
            if ahead > 0:
                time.sleep(ahead)
        return ended

    def _finish(self) -> None:
        self.server.stop()
        self.enabled = False
