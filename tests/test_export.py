"""Export to ONNX and C99: both reproduce the PyTorch actor within 1e-5, and the CLI fails clearly."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from torchnav.export import (VerificationError, compare, export, export_c, export_onnx, find_compiler, network_of,
                             random_observations, reference, run_onnx, verify_c)
from torchnav.export.__main__ import main
from torchnav.export.c import c_float, check_name
from torchnav.policy import Actor, load_policy, save_policy

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "checkpoints" / "td3_arena_actor.pt"
TOL = 1e-5
HAS_CC = find_compiler() is not None
needs_cc = pytest.mark.skipif(not HAS_CC, reason="no C compiler (cc/gcc/clang) on PATH; the C export is written but cannot be compiled")
TABLE = torch.tensor([[1.0, 0.0], [1.0, 0.5], [1.0, -0.5], [0.0, 1.0], [0.0, -1.0]])


def make_actor(kind: str, seed: int = 0) -> tuple[Actor, torch.Tensor | None]:
    """A small actor with non-trivial normalisation: ``relu``/``tanh`` continuous, or ``argmax`` over ``TABLE``."""
    torch.manual_seed(seed)
    obs = 30
    if kind == "argmax":
        actor, table = Actor(obs, len(TABLE), (48, 32), "relu", "argmax"), TABLE
    else:
        actor, table = Actor(obs, 2, (64, 32, 16), kind, "tanh"), None
    actor.set_normalization(torch.randn(obs) * 3.0, torch.rand(obs) * 5.0 + 0.1)
    with torch.no_grad():  # larger weights than the default init, so outputs span [-1, 1] and errors show
        for m in actor.linear_layers():
            m.weight.mul_(2.0)
    return actor.eval(), table


def saved(tmp_path: Path, kind: str) -> Path:
    actor, table = make_actor(kind)
    path = tmp_path / f"{kind}_actor.pt"
    save_policy(path, actor, task="nav", task_config={}, algorithm="dqn" if kind == "argmax" else "td3", action_table=table)
    return path


@pytest.mark.parametrize("kind", ["relu", "tanh", "argmax"])
def test_onnx_matches_pytorch(tmp_path, kind):
    import onnx

    actor, table = make_actor(kind)
    net = network_of(actor, table)
    path = export_onnx(net, tmp_path / "a.onnx")
    for n in (1, 300):  # dynamic batch dimension
        obs = random_observations(net, n, seed=n)
        ref, got = reference(actor, obs, net.action_table), run_onnx(path, obs)
        err = compare(ref, got, TOL)
        assert err["ok"], err
        assert got["action"].shape == (n, 2) and got["action"].dtype == np.float32
        if kind == "argmax":
            np.testing.assert_array_equal(got["index"], ref["index"])
            np.testing.assert_array_equal(got["action"], TABLE.numpy()[ref["index"]])
    model = onnx.load(str(path))
    assert [i.name for i in model.graph.input] == ["observation"]
    assert model.graph.output[0].name == "action"
    meta = {p.key: p.value for p in model.metadata_props}
    assert meta["obs_size"] == "30" and meta["output"] == ("argmax" if kind == "argmax" else "tanh")
    assert "torchnav_version" in meta


@needs_cc
@pytest.mark.parametrize("kind", ["relu", "tanh", "argmax"])
def test_c_compiles_and_matches_pytorch(tmp_path, kind):
    actor, table = make_actor(kind)
    net = network_of(actor, table)
    files = export_c(net, tmp_path / "c", name="nav_policy")
    assert sorted(f.name for f in files) == ["nav_policy.c", "nav_policy.h", "nav_policy_test.c"]
    src = (tmp_path / "c" / "nav_policy.c").read_text()
    assert "malloc" not in src and "double" not in src
    assert ("#include <math.h>" in src) == (kind != "argmax")  # relu + argmax needs no libm at all
    header = (tmp_path / "c" / "nav_policy.h").read_text()
    assert "void nav_policy_forward(const float *obs, float *action);" in header
    assert "#define NAV_POLICY_OBS_SIZE 30" in header
    obs = random_observations(net, 500, seed=1)
    ref = reference(actor, obs, net.action_table)
    err = verify_c(tmp_path / "c", net, ref, obs, TOL, name="nav_policy")  # -std=c99 -Wall -Wextra -Werror -pedantic
    assert err is not None and err["ok"], err
    if kind == "argmax":
        assert err["index_mismatches"] == 0
    if kind == "relu":  # a short observation is refused with a message naming both counts
        import subprocess

        exe = tmp_path / "policy_test"
        subprocess.run([find_compiler(), "-std=c99", "-O2", str(tmp_path / "c" / "nav_policy.c"), str(tmp_path / "c" / "nav_policy_test.c"),
                        "-o", str(exe), "-lm"], check=True)
        p = subprocess.run([str(exe)], input="0.5 " * 24, capture_output=True, text=True)
        assert p.returncode == 1 and "has 24 values, expected NAV_POLICY_OBS_SIZE = 30" in p.stderr


@pytest.mark.parametrize("x", [0.0, -0.0, 1.0, -2.5, 1 / 3, 1e-45, 1.17549435e-38, 3.4028235e38, -7e-12, 123456789.0])
def test_c_literals_round_trip_float32(x):
    s = c_float(x)
    assert s.endswith("f") and any(ch in s for ch in ".e")
    assert np.float32(float(s[:-1])) == np.float32(x)


def test_cli_on_shipped_checkpoint(tmp_path, capsys):
    rc = main([str(SHIPPED), "--onnx", str(tmp_path / "out.onnx"), "--c", str(tmp_path / "c"), "--verify", "200"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert (tmp_path / "out.onnx").is_file() and (tmp_path / "c" / "policy.c").is_file()
    assert "ONNX (onnxruntime) vs PyTorch on 200 observations" in out
    assert ("C (" in out) == HAS_CC
    assert "72706 parameters" in out


def test_discrete_checkpoint_and_embedded_policy(tmp_path):
    """A recipe checkpoint embedding the actor under "policy" exports like an actor.pt."""
    path = saved(tmp_path, "argmax")
    ck = tmp_path / "checkpoint.pt"
    torch.save({"policy": torch.load(path, weights_only=True), "step": 3}, ck)
    r = export(ck, onnx_path=tmp_path / "d.onnx", c_dir=tmp_path / "c", verify=100)
    assert r["onnx"]["ok"] and r["onnx"]["index_mismatches"] == 0
    assert r["c"] is None if not HAS_CC else r["c"]["ok"]
    assert r["footprint"]["flash_bytes"] == 4 * (30 * 48 + 48 + 48 * 32 + 32 + 32 * 5 + 5 + 2 * 30 + 10)


def test_verification_failure_is_loud(tmp_path, capsys):
    rc = main([str(saved(tmp_path, "tanh")), "--onnx", str(tmp_path / "a.onnx"), "--tolerance", "1e-30", "--verify", "50"])
    err = capsys.readouterr().err
    assert rc == 1 and "does not match PyTorch" in err and "exceeds tolerance" in err
    with pytest.raises(VerificationError):
        export(saved(tmp_path, "relu"), onnx_path=tmp_path / "b.onnx", tolerance=1e-30, verify=50)


def test_cli_errors(tmp_path, capsys, monkeypatch):
    assert main([str(tmp_path / "missing.pt"), "--c", str(tmp_path / "c")]) == 2
    assert "checkpoint not found" in capsys.readouterr().err
    junk = tmp_path / "junk.pt"
    torch.save({"weights": torch.zeros(3)}, junk)
    assert main([str(junk), "--c", str(tmp_path / "c")]) == 2
    assert "not a torchnav policy" in capsys.readouterr().err
    text = tmp_path / "text.pt"
    text.write_text("hello")
    assert main([str(text), "--c", str(tmp_path / "c")]) == 2
    assert "cannot load" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # nothing to export
        main([str(SHIPPED)])
    assert "nothing to export" in capsys.readouterr().err
    assert main([str(SHIPPED), "--c", str(tmp_path / "c"), "--name", "2bad"]) == 2
    assert "C identifier" in capsys.readouterr().err
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main([str(SHIPPED), "--c", str(blocker / "sub"), "--verify", "0"]) == 2
    assert "cannot write output" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # as if not installed
    assert main([str(SHIPPED), "--onnx", str(tmp_path / "x.onnx")]) == 2
    assert "pip install 'torchnav[export]'" in capsys.readouterr().err
    assert not (tmp_path / "x.onnx").exists()


def test_name_check_and_no_table():
    assert check_name("_p1") == "_p1"
    for bad in ("", "1p", "a-b", "int", "p p"):
        with pytest.raises(ValueError):
            check_name(bad)
    actor, _ = make_actor("argmax")
    with pytest.raises(ValueError, match="action_table"):
        network_of(actor, None)


def test_shipped_policy_loads_as_expected():
    p = load_policy(SHIPPED)
    assert network_of(p).footprint()["parameters"] == 72706
