"""Smoke test of the benchmark scripts: ``--quick --json`` runs end to end and emits the documented keys.

Both scripts run as subprocesses, side by side, with 1 thread and eager modes only
(compiling takes tens of seconds), so the test stays within a few seconds of
the scripts' start-up time.
"""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
SIM_KEYS = {"device", "num_envs", "mode", "env_steps_per_s", "peak_mem_bytes", "peak_mem_method", "env_steps_per_s_min", "env_steps_per_s_max"}
ENV_KEYS = {"device", "num_envs", "mode", "env_steps_per_s", "peak_mem_bytes"}


def _json_lines(stdout: str) -> list[dict]:
    lines = [ln for ln in stdout.splitlines() if ln.strip()]
    assert lines, "no output on stdout"
    return [json.loads(ln) for ln in lines]  # with --json, stdout holds only JSON lines


def _positive(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x) and x > 0


@pytest.mark.slow  # about 15-25 s: tools' end-to-end runs, outside the default suite's budget
def test_bench_scripts_quick_json():
    cmds = {
        "sim": [sys.executable, str(ROOT / "bench" / "sim_throughput.py"), "--quick", "--json", "--device", "cpu", "--threads", "1", "--sizes", "1,64",
                "--modes", "eager,eager-batched,eager-unrolled", "--options", "imu,camera16,movers4", "--cpu-time"],
        "env": [sys.executable, str(ROOT / "bench" / "env_throughput.py"), "--quick", "--json", "--threads", "1", "--num-envs", "32"],
    }
    procs = {k: subprocess.Popen(c, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for k, c in cmds.items()}
    out = {}
    for k, p in procs.items():
        stdout, stderr = p.communicate(timeout=180)
        assert p.returncode == 0, f"{k} bench failed:\n{stderr[-3000:]}"
        out[k] = (_json_lines(stdout), stderr)

    sim, sim_log = out["sim"]
    rows = [r for r in sim if r.get("bench") == "sim_throughput"]
    assert {(r["num_envs"], r["mode"], r["option"]) for r in rows} == {
        (n, m, o) for n in (1, 64) for m in ("eager", "eager-batched", "eager-unrolled") for o in ("plain", "imu", "camera16", "movers4")}
    for r in rows:
        assert SIM_KEYS <= r.keys(), SIM_KEYS - r.keys()
        assert "error" not in r, r["error"]
        assert r["device"] == "cpu" and _positive(r["env_steps_per_s"]) and r["clock"] == "cpu"  # --cpu-time
        assert r["env_steps_per_s_min"] <= r["env_steps_per_s"] <= r["env_steps_per_s_max"]
        assert isinstance(r["peak_mem_bytes"], int) and r["peak_mem_bytes"] >= 0 and r["peak_mem_method"]
    assert "ratios against eager" in sim_log and "env-steps/s" in sim_log  # the table went to stderr
    assert "camera16 x" in sim_log and "options against the plain step" in sim_log

    env, env_log = out["env"]
    rows = {r["mode"]: r for r in env if r.get("bench") == "env_throughput"}
    gym = importlib.util.find_spec("gymnasium") is not None
    assert set(rows) == {"raw-sim", "env-step", "collector"} | ({"gym-vector"} if gym else set())
    for r in rows.values():
        assert ENV_KEYS <= r.keys(), ENV_KEYS - r.keys()
        assert r["num_envs"] == 32 and _positive(r["env_steps_per_s"])
    (ratio,) = [r for r in env if r.get("bench") == "env_ratio"]
    assert _positive(ratio["collector_over_raw"]) and _positive(ratio["env_step_over_raw"])
    assert "collector / raw-sim" in env_log


@pytest.mark.slow  # about 15-25 s: tools' end-to-end runs, outside the default suite's budget
def test_sim_ab_compares_two_trees_in_one_process(tmp_path):
    """bench/sim_ab.py imports a second tree's simulator under another name and times both trees'
    plain and option steps in turns (eager here, a smoke test); a path without torchnav/sim is refused."""
    cmd = [sys.executable, str(ROOT / "bench" / "sim_ab.py"), str(ROOT), "--eager", "--envs", "8", "--rounds", "2", "--steps", "2",
           "--options", "boxmovers4"]
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-3000:]
    rows = [ln.split() for ln in out.stdout.splitlines() if ln.startswith(("this ", "other "))]
    assert [(r[0], r[1]) for r in rows] == [("this", "plain"), ("this", "boxmovers4"), ("other", "plain"), ("other", "boxmovers4")]
    for r in rows:
        assert float(r[2]) > 0 and (r[1] == "plain" or 0 < float(r[4]) < 5)
    bad = subprocess.run(cmd[:2] + [str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "no torchnav/sim/step.py" in bad.stderr


def test_dense_lidar_quick_json():
    cmd = [sys.executable, str(ROOT / "bench" / "dense_lidar.py"), "--quick", "--json", "--threads", "1", "--cpu-time"]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    rows = {r["load"]: r for r in _json_lines(p.stdout)}
    assert set(rows) == {"standard", "dense-sectors", "dense-rays", "dense-brute"}
    assert rows["standard"]["obstacles"] == 12 and rows["dense-sectors"]["obstacles"] == 404
    assert all(_positive(r["env_steps_per_s"]) and r["mode"] == "eager" and r["clock"] == "cpu" for r in rows.values())
    assert all(0.0 <= rows[k]["exact_envs_frac"] <= 1.0 for k in ("standard", "dense-sectors", "dense-rays"))
    assert "standard / dense-sectors" in p.stderr  # the ratios went to stderr


def test_dense_lidar_generalist_load():
    """The generalist recipe's step: its worlds padded to the mixture's slots, its sector scan."""
    cmd = [sys.executable, str(ROOT / "bench" / "dense_lidar.py"), "--quick", "--json", "--threads", "1", "--loads", "generalist"]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    (row,) = _json_lines(p.stdout)
    lidar = yaml.safe_load((ROOT / "recipes" / "configs" / "ppo_generalist.yaml").read_text())["task"]["lidar"]
    assert row["load"] == "generalist" and row["scan"] == "sectors" and row["readings"] == lidar["n_rays"] == 36
    assert 0 < row["obstacles"] <= 68 + 70 + 48 and _positive(row["env_steps_per_s"]) and row["exact_envs_frac"] == 1.0


@pytest.mark.slow
def test_compiled_options_compile_once_each():
    """Each option's compiled step is compiled once, before the timed runs: none recompiles inside them
    (a dynamo reset per option used to drop the earlier options' graphs, and past the recompile limit
    an option ran eager)."""
    spec = importlib.util.spec_from_file_location("sim_throughput", ROOT / "bench" / "sim_throughput.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    from torch._dynamo.utils import counters

    counters.clear()
    rows = bench.main(["--device", "cpu", "--threads", "1", "--sizes", "8", "--modes", "compiled", "--options", "imu,movers4",
                       "--repeats", "2", "--steps", "2", "--warmup", "0"])
    rows = [r for r in rows if r.get("bench") == "sim_throughput"]
    assert [r["option"] for r in rows] == ["plain", "imu", "movers4"] and not [r for r in rows if r.get("error")]
    assert counters["frames"]["ok"] == 3, dict(counters["frames"])


@pytest.mark.slow  # about 15-25 s: tools' end-to-end runs, outside the default suite's budget
def test_worlds_bench_json_and_bad_difficulty():
    cmd = [sys.executable, str(ROOT / "bench" / "worlds.py"), "--num-envs", "8", "--families", "forest,open", "--difficulties", "0.5,mixed",
           "--guide-cells", "16", "--cpu-time", "--repeats", "1", "--json"]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=180)
    assert p.returncode == 0, p.stderr[-3000:]
    rows = [r for r in _json_lines(p.stdout) if r.get("bench") == "worlds"]
    assert {(r["family"], r["difficulty"]) for r in rows} == {(f, d) for f in ("forest", "open") for d in ("0.5", "mixed")}
    assert all(r["guide_cells"] == 16 and r["clock"] == "cpu" and _positive(r["envs_per_s"]) for r in rows)
    bad = subprocess.run(cmd[:2] + ["--difficulties", "0.5,hard"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "hard" in bad.stderr


def test_multi_robot_bench_runs():
    """bench/multi_robot.py end to end at a tiny size (eager, VMAS off): one JSON row per N with agent-steps/s
    N times env-steps/s and the per-agent scaling relative to the smallest N."""
    cmd = [sys.executable, str(ROOT / "bench" / "multi_robot.py"), "--envs", "8", "--robots", "1,3", "--rays", "4", "--modes", "eager",
           "--vmas", "off", "--repeats", "1", "--steps", "2", "--warmup", "1", "--threads", "1", "--json", "--walls"]
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-3000:]
    rows = [r for r in _json_lines(out.stdout) if r.get("bench") == "multi_robot"]
    assert [(r["sim"], r["mode"], r["robots"]) for r in rows] == [("torchnav", "eager", 1), ("torchnav", "eager", 3)]
    for r in rows:
        assert _positive(r["env_steps_per_s"]) and r["agent_steps_per_s"] == pytest.approx(r["robots"] * r["env_steps_per_s"], rel=1e-3)
    assert rows[0]["per_agent_vs_first"] == 1.0 and "agent-steps/s" in out.stderr


@pytest.mark.slow  # about 15 s: a tool's end-to-end run, outside the default suite's budget
def test_big_map_quick_json(tmp_path):
    cmd = [sys.executable, str(ROOT / "bench" / "big_map.py"), "--quick", "--json", "--threads", "1", "--hold-memory"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    recs = [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]
    machine = next(r for r in recs if r.get("bench") == "big_map_machine")
    assert machine["malloc"] == ("held" if sys.platform == "linux" else "system")
    cells = {(r["map"], r["mode"]) for r in recs if r.get("bench") == "big_map"}
    assert cells == {(m, k) for m in ("arena", "big_warehouse") for k in ("build", "raw-sim", "env-step")}
    big = next(r for r in recs if r.get("bench") == "big_map" and r["map"] == "big_warehouse" and r["mode"] == "build")
    assert big["fixed_obstacles"] > 2000 and big["shared_map_bytes"] > 0 and big["per_env_world_bytes"] == 0
    assert all(r["env_steps_per_s"] > 0 for r in recs if r.get("mode") in ("raw-sim", "env-step"))
    assert all(0 <= r["reset_fraction"] <= 1 for r in recs if r.get("mode") == "env-step")
    # --write-map writes the map_server map that loads as it is
    written = subprocess.run([sys.executable, str(ROOT / "bench" / "big_map.py"), "--write-map", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert written.returncode == 0 and (tmp_path / "big_warehouse.pgm").exists()
