"""Shared test settings."""

import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def _one_thread():
    # Small tensors gain nothing from intra-op threads, and on a busy 2-core machine
    # OpenMP threads spinning against each other slow tests down many times over.
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


def record_episode(env, path, steps: int):
    """Record env 0's first episode of a ``steps``-step random rollout to ``path``; the recording,
    that episode and its frames (``torchnav.record.replay.episode_frames``)."""
    from torchnav.record import EpisodeRecorder, read_recording, record_rollout
    from torchnav.record.replay import episode_frames

    with EpisodeRecorder(path, env, envs=(0,), episodes=1) as rec:
        record_rollout(env, None, steps, rec)
    rec = read_recording(path)
    ep = rec.episodes()[0]
    return rec, ep, episode_frames(rec, ep)
