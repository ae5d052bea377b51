"""Reading recordings back: complete files, and files cut short by a crash.

``read_recording(path)`` returns every decodable message, the ``torchnav``
metadata and the episodes (from the ``/env{i}/events`` topics). A complete file is read through
its summary; a file without one (the writer was killed) is scanned from the
start and reading stops at the first incomplete record, so every chunk that was
fully written is recovered.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Optional

from mcap.decoder import DecoderFactory
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Schema


class JsonDecoderFactory(DecoderFactory):
    """mcap decoder for ``json`` messages (any schema): ``bytes -> dict``."""

    def decoder_for(self, message_encoding: str, schema: Optional[Schema]) -> Optional[Callable[[bytes], Any]]:
        if message_encoding == "json":
            return lambda data: json.loads(data)
        return None


@dataclass
class Message:
    topic: str
    schema: str  # schema name, e.g. foxglove.LaserScan
    log_time: int  # ns of simulation time
    data: dict


@dataclass
class Episode:
    env: int
    episode: int
    start_time: int  # ns
    end_time: int | None  # ns; None if the recording stopped mid-episode
    outcome: str  # success | collision | timeout | incomplete, or the reason of a "terminated" event (left_line, ...)
    steps: int
    ret: float
    start: dict  # the start event (pose, goal, world; several robots: robots, starts, goals, world)
    # several robots per env: one entry per present robot, {"robot", "outcome", "steps", "return", ...} of the end
    # event (outcome success | collision | timeout | ended, or incomplete); None for one robot per env
    robots: list[dict] | None = None
    team_success: bool | None = None  # several robots: every present robot reached its goal (None: one robot, or incomplete)


@dataclass
class Recording:
    path: Path
    metadata: dict[str, dict[str, str]]
    messages: list[Message]
    schemas: dict[str, dict] = field(default_factory=dict)  # schema name -> JSON Schema
    complete: bool = True  # False: the file had no summary (the writer did not close it)

    def topic(self, name: str, t0: int | None = None, t1: int | None = None) -> list[Message]:
        return [m for m in self.messages if m.topic == name and (t0 is None or m.log_time >= t0) and (t1 is None or m.log_time <= t1)]

    def events(self) -> list[Message]:
        """Episode events of every recorded env, in time order."""
        return sorted((m for m in self.messages if m.topic.endswith("/events")), key=lambda m: m.log_time)

    @property
    def info(self) -> dict[str, Any]:
        """The ``torchnav`` metadata with JSON values decoded."""
        out: dict[str, Any] = {}
        for k, v in self.metadata.get("torchnav", {}).items():
            try:
                out[k] = json.loads(v) if k in ("config", "lidar", "envs", "reward_terms") else v
            except ValueError:
                out[k] = v
        return out

    def episodes(self) -> list[Episode]:
        """Episodes in file order; the last one of an env is ``incomplete`` if the file ends inside it."""
        eps: dict[tuple[int, int], Episode] = {}
        steps: dict[tuple[int, int], int] = {}
        for m in self.messages:
            if m.topic.endswith("/action"):  # several robots: one per robot and step, so count the steps
                key = (m.data["env"], m.data["episode"])
                steps[key] = max(steps.get(key, 0), m.data["step"] + 1)
        for m in self.events():
            d = m.data
            key = (d["env"], d["episode"])
            if d["event"] == "start":
                eps[key] = Episode(d["env"], d["episode"], m.log_time, None, "incomplete", 0, 0.0, d)
                if "robots" in d:
                    eps[key].robots = [{"robot": j, "outcome": "incomplete"} for j in d["robots"]]
            elif key in eps:
                e = eps[key]
                outcome = d.get("reason", "terminated") if d["event"] == "terminated" else d["event"]
                e.end_time, e.outcome, e.ret = m.log_time, outcome, d.get("return", 0.0)
                if "outcomes" in d:
                    e.robots, e.team_success = d["outcomes"], d["team_success"]
        for key, e in eps.items():
            e.steps = steps.get(key, 0)
            if e.outcome == "incomplete":  # the return so far (several robots: their sum)
                e.ret = 0.0
                for prefix in [f"/robot{r['robot']}" for r in e.robots] if e.robots is not None else [""]:
                    rewards = [m for m in self.topic(f"/env{e.env}{prefix}/reward", e.start_time) if m.data["episode"] == e.episode]
                    e.ret += rewards[-1].data["return"] if rewards else 0.0
        return list(eps.values())


def _iter(stream, complete: bool) -> Iterator:
    reader = make_reader(stream, decoder_factories=[JsonDecoderFactory()]) if complete else \
        NonSeekingReader(stream, decoder_factories=[JsonDecoderFactory()])
    yield from reader.iter_decoded_messages(log_time_order=complete)


def read_recording(path: str | Path) -> Recording:
    """All messages and metadata of a recording, recovering what a crash left behind."""
    path = Path(path)
    with open(path, "rb") as f:
        reader = make_reader(f)
        try:
            reader.get_summary()
            complete = True
        except Exception:  # no footer or summary: the writer was stopped before close()
            complete = False
    rec = Recording(path=path, metadata={}, messages=[], complete=complete)
    with open(path, "rb") as f:
        try:
            for schema, channel, message, decoded in _iter(f, complete):
                if schema is not None and schema.name not in rec.schemas and schema.encoding == "jsonschema":
                    rec.schemas[schema.name] = json.loads(schema.data)
                rec.messages.append(Message(channel.topic, schema.name if schema else "", message.log_time, decoded))
        except Exception:  # a torn record at the end of a crashed file ends the scan
            if complete:
                raise
    with open(path, "rb") as f:
        try:
            for m in (make_reader(f).iter_metadata() if complete else _scan_metadata(f)):
                rec.metadata[m.name] = dict(m.metadata)
        except Exception:
            if complete:
                raise
    if not complete:
        rec.messages.sort(key=lambda m: m.log_time)  # stable: keeps per-channel order
    return rec


def _scan_metadata(f) -> Iterator:
    from mcap.records import Metadata
    from mcap.stream_reader import StreamReader

    for record in StreamReader(f).records:
        if isinstance(record, Metadata):
            yield record
