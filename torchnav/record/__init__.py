"""Episode recording to MCAP (opens in Foxglove) and replay with matplotlib.

    from torchnav.record import EpisodeRecorder, record_rollout
    with EpisodeRecorder("episodes.mcap", env, envs=(0,), metadata={"seed": 0}) as rec:
        rollout = record_rollout(env, policy, max_steps=1000, recorder=rec)

See docs/foxglove.md for the topics and ``python -m torchnav.record.replay`` to
summarise or animate a recording without Foxglove.
"""

from .live import LiveView
from .mcap_writer import EpisodeRecorder, RecordingWarning, record_rollout
from .reader import Episode, JsonDecoderFactory, Recording, read_recording
from .schemas import foxglove_schema, validate

__all__ = [
    "EpisodeRecorder", "LiveView", "RecordingWarning", "record_rollout", "read_recording", "Recording", "Episode",
    "JsonDecoderFactory", "foxglove_schema", "validate",
]
