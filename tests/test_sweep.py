"""recipes/sweep.py: a grid x seeds through submitit's local executor with 2 workers, then the table."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

pytest.importorskip("submitit")
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "recipes"))

TINY = ["threads=1", "env.num_envs=16", "task.max_steps=60", "eval.interval_frames=128", "eval.episodes=8", "eval.final_episodes=16",
        "eval.record_episodes=0", "train.frames_per_batch=128", "train.init_random_frames=128", "train.updates_per_batch=2",
        "train.batch_size=32", "train.hidden=[16,16]", "train.buffer_size=1000", "train.total_frames=256"]


@pytest.mark.slow  # about 15-25 s: tools' end-to-end runs, outside the default suite's budget
def test_sweep_runs_a_grid_in_parallel_and_aggregates(tmp_path, capsys):
    import sweep

    out = tmp_path / "sweep"
    sweep.main(["run", "td3_lidar", "--seeds", "0", "1", "--grid", "task.curriculum.growth=0.004,0.008", "--set", *TINY,
                "--workers", "2", "--out", str(out)])
    rows = json.loads((out / "sweep.json").read_text())
    assert sorted(r["setting"] for r in rows) == ["growth=0.004", "growth=0.008"]
    for r in rows:
        assert r["seeds"] == 2 and r["episodes"] == 32 and 0 <= r["ci95"][0] <= r["mean"] <= r["ci95"][1] <= 1
    for run in out.glob("*/seed*"):
        assert (run / "summary.json").is_file() and (run / "config.yaml").is_file()
    assert (out / "curves.png").stat().st_size > 0
    assert "final success (mean, 95% CI over seeds)" in capsys.readouterr().out
    again = sweep.main(["aggregate", str(out)])
    assert [r["mean"] for r in again] == [r["mean"] for r in rows]


def test_sweep_refuses_bad_values_before_launching(tmp_path):
    import sweep

    from torchnav.config import ConfigError

    with pytest.raises(ConfigError, match="train.lr_actor"):
        sweep.main(["run", "td3_lidar", "--seeds", "0", "--grid", "train.lr_actor=0.001,-1", "--out", str(tmp_path / "s")])
    assert not (tmp_path / "s").exists()
    with pytest.raises(SystemExit):  # a Slurm partition on the local executor would be dropped
        sweep.main(["run", "td3_lidar", "--seeds", "0", "--slurm-partition", "gpu", "--out", str(tmp_path / "s")])
    assert not (tmp_path / "s").exists()
