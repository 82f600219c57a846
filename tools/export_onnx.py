#!/usr/bin/env python3
"""Export a trained learned-correction checkpoint to ONNX (see vrcorrect.learn.export).

    .venv/bin/python tools/export_onnx.py RUN/checkpoint.pt -o models/NAME.onnx [--fp16] [--force]

Pinned opset, dynamic N/H/W, vrcorrect.* metadata (ranges, display, version, training);
the export is written only if onnxruntime equals torch within 1e-4 (fp32).  --fp16 stores the
weights in float16 and prints the measured error.  Bad input: one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv: list[str] | None = None) -> int:
    from vrcorrect.plumbing.errors import VrcorrectError

    ap = argparse.ArgumentParser(prog="export_onnx.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoint", metavar="CHECKPOINT", help="checkpoint.pt written by vrcorrect train")
    ap.add_argument("-o", "--output", required=True, metavar="OUT.onnx")
    ap.add_argument("--fp16", action="store_true", help="float16 weights (cast to float32 in the graph)")
    ap.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    args = ap.parse_args(argv)
    try:
        from vrcorrect.learn.export import FP32_TOLERANCE, OPSET, export_onnx

        r = export_onnx(args.checkpoint, args.output, fp16=args.fp16, force=args.force)
    except VrcorrectError as exc:
        print(f"export_onnx: error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # never a traceback for a command-line user
        if os.environ.get("VRCORRECT_DEBUG"):
            raise
        print(f"export_onnx: internal error: {type(exc).__name__}: {exc} (set VRCORRECT_DEBUG=1)", file=sys.stderr)
        return 3
    print(f"wrote {r.path} ({r.bytes / 1e6:.2f} MB, opset {OPSET}, {r.precision}); onnxruntime vs torch "
          f"max abs error {r.max_abs_error_fp32:.2e} (fp32, tolerance {FP32_TOLERANCE:g})"
          + (f"; fp16 weights: max abs error {r.max_abs_error_fp16:.2e}" if r.max_abs_error_fp16 is not None else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
