"""Shared test settings."""

import os

import pytest
import torch

MAX_WORKERS = 4  # test processes of `-n auto` (pyproject.toml's addopts): more buy little and each holds its own torch


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config):
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(MAX_WORKERS, cores))


def alone_on_the_machine() -> bool:
    """Whether this test process is the only one of the run (no pytest-xdist workers beside it)."""
    return int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) <= 1


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
