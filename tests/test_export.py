"""Export to ONNX and C99: both reproduce the PyTorch actor within 1e-5, and the CLI fails clearly."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from torchnav.checkpoint import save_checked
from torchnav.export import (VerificationError, compare, compile_test, export, export_c, export_cortex_m4f, export_onnx,
                             find_compiler, missing_tools, network_of, quantize, quantized_actor, random_observations,
                             reference, run_onnx, verify_c, verify_cortex_m4f)
from torchnav.export.__main__ import main
from torchnav.export.c import c_float, check_name, run_c
from torchnav.export.cortex_m import PACKAGES
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
    save_checked(ck, {"policy": torch.load(path, weights_only=True), "step": 3})
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
    save_checked(junk, {"weights": torch.zeros(3)})
    assert main([str(junk), "--c", str(tmp_path / "c")]) == 2
    assert "not a torchnav policy checkpoint: format None, expected 'torchnav-actor-v2' or 'torchnav-actor-v3'" in capsys.readouterr().err
    unhashed = tmp_path / "unhashed.pt"  # an actor.pt saved by hand, or by a torchnav older than the content hash
    torch.save({k: v for k, v in torch.load(SHIPPED, weights_only=True).items() if k != "sha256"}, unhashed)
    assert main([str(unhashed), "--c", str(tmp_path / "c")]) == 2
    assert "no 'sha256' content hash (format 'torchnav-actor-v2')" in capsys.readouterr().err
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


# --- weight formats (float16, int8 per channel) and the Cortex-M4F build in QEMU -------------------------------------

HAS_M4 = not missing_tools()
needs_m4 = pytest.mark.skipif(not HAS_M4, reason=f"cortex-m4f toolchain or QEMU missing ({', '.join(missing_tools())}); "
                                                 f"install: apt-get install {' '.join(PACKAGES)}")


def test_quantize_formats():
    actor, _ = make_actor("relu")
    net = network_of(actor)
    with pytest.raises(ValueError, match="unknown weight format 'int4'"):
        quantize(net, "int4")
    assert quantize(net, "float32") is net
    h = quantize(net, "float16")
    for (w, _), (d, _), bits in zip(net.layers, h.layers, h.stored):
        assert bits.dtype == np.uint16 and bits.shape == w.shape
        np.testing.assert_array_equal(bits.view(np.float16).astype(np.float32), d)  # what C stores is what PyTorch uses
        assert np.abs(d - w).max() <= np.abs(w).max() * 2.0 ** -11  # round to nearest: half an ulp of 10 mantissa bits
    q8 = quantize(net, "int8")
    for (w, _), (d, _), (q, s) in zip(net.layers, q8.layers, q8.stored):
        assert q.dtype == np.int8 and s.shape == (w.shape[0],) and np.abs(q).max() == 127  # each row uses the full range
        np.testing.assert_array_equal(q.astype(np.float32) * s[:, None], d)
        assert (np.abs(d - w) <= s[:, None] / 2 * (1 + 1e-6)).all()  # rounding error at most half a step per row
    fp, params = q8.footprint(), sum(w.size for w, _ in net.layers)
    assert net.footprint()["flash_bytes"] - fp["flash_bytes"] == 3 * params - 4 * sum(w.shape[0] for w, _ in net.layers)
    assert net.footprint()["flash_bytes"] - h.footprint()["flash_bytes"] == 2 * params
    big = Actor(3, 2, (4,), "relu", "tanh")
    with torch.no_grad():
        big.net[0].weight[0, 0] = 70000.0
    with pytest.raises(ValueError, match="beyond float16's range"):
        quantize(network_of(big), "float16")
    qa = quantized_actor(actor, "int8")  # PyTorch with the dequantised weights, the original untouched
    assert torch.equal(qa.linear_layers()[0].weight, torch.from_numpy(q8.layers[0][0]))
    assert torch.equal(actor.linear_layers()[0].weight, torch.from_numpy(net.layers[0][0]))


@needs_cc
@pytest.mark.parametrize("kind", ["relu", "tanh", "argmax"])
@pytest.mark.parametrize("weights", ["float16", "int8"])
def test_quantized_c_matches_quantized_pytorch(tmp_path, kind, weights):
    actor, table = make_actor(kind)
    net = quantize(network_of(actor, table), weights)
    export_c(net, tmp_path / "c")
    src = (tmp_path / "c" / "policy.c").read_text()
    assert ("static const uint16_t policy_w0" in src) == (weights == "float16")
    assert ("static const int8_t policy_w0" in src) == (weights == "int8")
    assert "static const float policy_w0" not in src and "double" not in src
    obs = random_observations(net, 300, seed=2)
    err = verify_c(tmp_path / "c", net, reference(quantized_actor(actor, weights), obs, net.action_table), obs, TOL)
    assert err is not None and err["ok"], err
    # and the quantisation is a real change: the float32 network differs by more than the tolerance
    assert not compare(reference(actor, obs, net.action_table), reference(quantized_actor(actor, weights), obs, net.action_table), TOL)["ok"]


@needs_cc
def test_float16_conversion_is_exact_in_c(tmp_path):
    """Every kind of half: zero, -0, subnormals, normals, the largest finite; one weight per output so each Q is exact."""
    halves = np.array([0.0, -0.0, 2.0 ** -24, -3 * 2.0 ** -24, 1023 * 2.0 ** -24, 2.0 ** -14, 0.333251953125, -1.5,
                       1.0, 65504.0], dtype=np.float16)
    n = len(halves)
    actor = Actor(n, n, (), "relu", "argmax")
    with torch.no_grad():
        actor.linear_layers()[0].weight.copy_(torch.diag(torch.from_numpy(halves.astype(np.float32))))
        actor.linear_layers()[0].bias.zero_()
    net = quantize(network_of(actor, torch.zeros(n, 2)), "float16")
    export_c(net, tmp_path / "c")
    obs = (np.eye(n) * 2.0 ** 20).astype(np.float32)  # Q[j] of observation j = half_j * 2^20, exact in float
    got = run_c(compile_test(tmp_path / "c", workdir=tmp_path), obs, net)
    # %.9g round-trips float32: compare as float32
    np.testing.assert_array_equal(np.diag(got["q"]).astype(np.float32), (halves.astype(np.float32) * np.float32(2.0 ** 20)))


def test_m4_files_without_toolchain_and_option_errors(tmp_path, capsys, monkeypatch):
    r = export(SHIPPED, c_dir=tmp_path / "m4", target="cortex-m4f", weights="int8", verify=0)
    names = sorted(p.name for p in r["files"])
    assert names == ["Makefile", "mps2_an386.ld", "policy.c", "policy.h", "policy_m4.c", "policy_test.c", "startup_m4.c"]
    assert r["cortex_m4f"] is None and r["footprint"]["flash_bytes"] == 72192 + 4 * (514 + 514 + 2 * 24)  # int8 + scales + floats
    make = (tmp_path / "m4" / "Makefile").read_text()
    assert "-mfloat-abi=hard -mfpu=fpv4-sp-d16" in make and "qemu-system-arm -M mps2-an386" in make
    for argv, msg in (([str(SHIPPED), "--c", str(tmp_path / "x"), "--weights", "int4"], "unknown --weights 'int4'"),
                      ([str(SHIPPED), "--c", str(tmp_path / "x"), "--target", "avr"], "unknown --target 'avr'"),
                      ([str(SHIPPED), "--onnx", str(tmp_path / "x.onnx"), "--weights", "int8"], "give --c DIR")):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2 and msg in capsys.readouterr().err
    import torchnav.export.cortex_m as cm

    monkeypatch.setattr(cm.shutil, "which", lambda tool: None)  # as if no toolchain were installed
    assert main([str(SHIPPED), "--c", str(tmp_path / "none"), "--target", "cortex-m4f"]) == 2
    err = capsys.readouterr().err
    assert "apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm" in err and "--verify 0" in err
    assert not (tmp_path / "none").exists()  # nothing written


@needs_m4
@pytest.mark.parametrize("kind", ["relu", "tanh", "argmax"])
@pytest.mark.parametrize("weights", ["float32", "float16", "int8"])
def test_cortex_m4f_in_qemu_matches_pytorch(tmp_path, kind, weights):
    """Cross-compiled with hardware float, run in QEMU's mps2-an386: outputs within 1e-5 of PyTorch (with the same weights)."""
    actor, table = make_actor(kind)
    net = quantize(network_of(actor, table), weights)
    export_c(net, tmp_path / "c")
    export_cortex_m4f(net, tmp_path / "c")
    obs = random_observations(net, 200, seed=3)
    ref = reference(actor if weights == "float32" else quantized_actor(actor, weights), obs, net.action_table)
    r = verify_cortex_m4f(tmp_path / "c", net, ref, obs, TOL)
    assert r["ok"], r
    if kind == "argmax":
        assert r["index_mismatches"] == 0
    macs, fp = net.footprint()["macs"], net.footprint()
    assert 2 * macs < r["instructions"] < 20 * macs  # every multiply-add executes (no skipped layer), in a few instructions
    # the constants land in flash (.rodata; gcc may move a tiny array such as a 2-float bias into the code's literal pool) ...
    assert 0.95 * fp["flash_bytes"] < r["policy_rodata_bytes"] < fp["flash_bytes"] + 64
    assert fp["flash_bytes"] < r["policy_rodata_bytes"] + r["policy_text_bytes"]
    assert r["policy_bss_bytes"] == fp["ram_bytes"] and r["policy_data_bytes"] == 0  # ... the two buffers in RAM
    assert r["flash_bytes"] > r["policy_rodata_bytes"] + r["policy_text_bytes"]  # the whole firmware: + startup, harness, libm
    assert 0 < r["stack_bytes"] < 1024 and r["ram_bytes"] == r["static_ram_bytes"] + r["stack_bytes"] and r["fits"]


@needs_m4
def test_shipped_navigation_policy_fits_only_quantised(tmp_path, capsys):
    rc = main([str(SHIPPED), "--c", str(tmp_path / "f32"), "--target", "cortex-m4f", "--verify", "20"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "Cortex-M4F (qemu mps2-an386) vs PyTorch on 20 observations" in out and "does NOT fit MSP432P401R" in out
    rc = main([str(SHIPPED), "--c", str(tmp_path / "i8"), "--target", "cortex-m4f", "--weights", "int8", "--verify", "20"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "vs PyTorch with the int8 weights on 20 observations" in out and "; fits MSP432P401R" in out
    assert "int8 weights vs float32 (PyTorch) on 20 observations" in out
    if shutil.which("make"):  # the generated Makefile builds the same firmware
        p = subprocess.run(["make", "-C", str(tmp_path / "i8")], capture_output=True, text=True)
        assert p.returncode == 0, p.stdout + p.stderr
        assert (tmp_path / "i8" / "policy_m4.elf").is_file()


def test_export_report_lists_every_shipped_checkpoint():
    """docs/scripts/export_report.py measures "every shipped policy": its list is checkpoints/*.pt."""
    spec = importlib.util.spec_from_file_location("export_report", ROOT / "docs" / "scripts" / "export_report.py")
    report = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(report)
    assert sorted(report.CHECKPOINTS) == sorted(p.stem for p in (ROOT / "checkpoints").glob("*.pt"))
