"""``python -m torchnav.export CHECKPOINT --onnx out.onnx --c out_dir/``: export a trained actor for deployment.

Exit status: 0 written and verified, 1 verification failed (files are left for
inspection), 2 bad arguments, unreadable checkpoint, unwritable output or a missing
dependency.
"""

from __future__ import annotations

import argparse
import sys

from . import VerificationError, describe, export


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
    a = p.parse_args(argv)
    if a.onnx is None and a.c_dir is None:
        p.error("nothing to export: give --onnx PATH and/or --c DIR")
    if a.verify < 0 or not a.tolerance > 0:
        p.error("--verify must be >= 0 and --tolerance > 0")

    def fail(msg: str, code: int = 2) -> int:
        print(f"error: {msg}", file=sys.stderr)
        return code

    try:
        r = export(a.checkpoint, onnx_path=a.onnx, c_dir=a.c_dir, name=a.name, verify=a.verify,
                   tolerance=a.tolerance, seed=a.seed)
    except VerificationError as e:
        return fail(str(e), 1)
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
          f"C constants {fp['flash_bytes'] / 1024:.1f} KiB (flash), buffers {fp['ram_bytes']} bytes (RAM)")
    if r["onnx"] is not None:
        print(f"ONNX (onnxruntime) vs PyTorch on {a.verify} observations: {describe(r['onnx'])} (tolerance {a.tolerance:g}) OK")
    if r["c"] is not None:
        print(f"C ({r['c']['compiler']}) vs PyTorch on {a.verify} observations: {describe(r['c'])} (tolerance {a.tolerance:g}) OK")
    if r["c_skipped"]:
        print(f"C verification skipped: {r['c_skipped']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
