"""``python -m torchnav.export CHECKPOINT --onnx out.onnx --c out_dir/``: export a trained actor for deployment.

``--weights float16|int8`` shrinks the C export's weights; ``--target cortex-m4f`` adds a
bare-metal Cortex-M4F build, run in QEMU, with its flash, RAM and instructions per inference.

Exit status: 0 written and verified, 1 verification failed (files are left for
inspection), 2 bad arguments, unreadable checkpoint, unwritable output or a missing
dependency (Python extra, cross compiler or QEMU: the message names what to install).
"""

from __future__ import annotations

import argparse
import sys

from . import TARGETS, WEIGHT_FORMATS, MissingToolError, VerificationError, describe, describe_cost, export


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m torchnav.export",
        description="Export a torchnav actor (actor.pt or a recipe's checkpoint.pt) to ONNX and/or dependency-free C99, "
                    "verified against PyTorch on random observations. See docs/export.md.")
    p.add_argument("checkpoint", help="actor.pt or checkpoint.pt written by a torchnav recipe")
    p.add_argument("--onnx", metavar="PATH", help="write an ONNX model here (needs: pip install 'torchnav[export]')")
    p.add_argument("--c", metavar="DIR", dest="c_dir", help="write NAME.h, NAME.c and NAME_test.c into this folder")
    p.add_argument("--name", default="policy", help="C symbol and file prefix (default: policy -> policy_forward())")
    p.add_argument("--verify", type=int, default=1000, metavar="N",
                   help="random observations to compare against PyTorch (default 1000; 0 skips verification)")
    p.add_argument("--tolerance", type=float, default=1e-5, help="largest accepted absolute error (default 1e-5)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random verification observations")
    p.add_argument("--weights", default="float32", metavar="FORMAT",
                   help=f"C weight storage: {', '.join(WEIGHT_FORMATS)} (default float32; int8: one float scale per output row). "
                        "The C code is verified against PyTorch with the same dequantised weights; the ONNX model stays float32")
    p.add_argument("--target", default="host", metavar="TARGET",
                   help=f"{' or '.join(TARGETS)} (default host). cortex-m4f also writes a bare-metal build (startup, linker script, "
                        "Makefile, test firmware), runs it in qemu-system-arm and reports flash, RAM and instructions per inference")
    a = p.parse_args(argv)
    if a.onnx is None and a.c_dir is None:
        p.error("nothing to export: give --onnx PATH and/or --c DIR")
    if a.weights not in WEIGHT_FORMATS:
        p.error(f"unknown --weights {a.weights!r}: choose one of {', '.join(WEIGHT_FORMATS)}")
    if a.target not in TARGETS:
        p.error(f"unknown --target {a.target!r}: choose one of {', '.join(TARGETS)}")
    if a.c_dir is None and (a.weights != "float32" or a.target != "host"):
        p.error("--weights and --target apply to the C export: give --c DIR as well")
    if a.verify < 0 or not a.tolerance > 0:
        p.error("--verify must be >= 0 and --tolerance > 0")

    def fail(msg: str, code: int = 2) -> int:
        print(f"error: {msg}", file=sys.stderr)
        return code

    try:
        r = export(a.checkpoint, onnx_path=a.onnx, c_dir=a.c_dir, name=a.name, verify=a.verify,
                   tolerance=a.tolerance, seed=a.seed, weights=a.weights, target=a.target)
    except VerificationError as e:
        return fail(str(e), 1)
    except MissingToolError as e:
        return fail(str(e))
    except (FileNotFoundError, ValueError, ImportError) as e:
        return fail(str(e))
    except OSError as e:
        return fail(f"cannot write output: {e}")
    except RuntimeError as e:  # C compilation failed
        return fail(str(e), 1)

    for f in r["files"]:
        print(f"wrote {f}")
    fp = r["footprint"]
    print(f"network: {fp['parameters']} parameters, {fp['macs']} multiply-adds per call; "
          f"C constants {fp['flash_bytes'] / 1024:.1f} KiB (flash, {a.weights} weights), buffers {fp['ram_bytes']} bytes (RAM)")
    if r["quantization"] is not None:
        print(f"{a.weights} weights vs float32 (PyTorch) on {a.verify} observations: {describe(r['quantization'])} "
              "(the cost of quantising; measure it on the task, see docs/export.md)")
    if r["onnx"] is not None:
        print(f"ONNX (onnxruntime) vs PyTorch on {a.verify} observations: {describe(r['onnx'])} (tolerance {a.tolerance:g}) OK")
    ref = "PyTorch" if a.weights == "float32" else f"PyTorch with the {a.weights} weights"
    if r["c"] is not None:
        print(f"C ({r['c']['compiler']}) vs {ref} on {a.verify} observations: {describe(r['c'])} (tolerance {a.tolerance:g}) OK")
    if r["cortex_m4f"] is not None:
        m4 = r["cortex_m4f"]
        print(f"Cortex-M4F ({m4['board']}) vs {ref} on {a.verify} observations: {describe(m4)} (tolerance {a.tolerance:g}) OK")
        print(f"Cortex-M4F: {describe_cost(m4)}")
    elif a.target == "cortex-m4f":
        print("Cortex-M4F build written; not run (verification disabled): run `make` and `make run` in the output folder")
    if r["c_skipped"]:
        print(f"C verification skipped: {r['c_skipped']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
