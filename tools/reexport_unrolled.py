"""Re-export an unrolled model with the same weights in today's format (issue 44: format v4 adds the
``upper`` input, the box's top per pixel, so that the model holds a robust design's light cap at
every stage as ``fast`` does; a v3 model runs uncapped).

    .venv/bin/python tools/reexport_unrolled.py models/default.onnx /tmp/default-v4.onnx --card /tmp/default-v4.md

The weights are read back from the file (:func:`vrcorrect.learn.unrolled_export.model_from_onnx`,
checked against it on a random case), saved as a checkpoint with the file's own training record as
its report, and exported as any trained model is (checked against torch; nothing is written when a
check fails).  With the unit box (``upper`` all ones) the new file computes what the old one does.
``--card``: write the model card, its held-out figures taken from the card beside the old file.

This is how models/default.onnx became v4 on 2026-12-02 (the run of 2026-11 re-exported; no retraining).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from vrcorrect.learn.unrolled_export import export_unrolled, model_from_onnx
from vrcorrect.learn.unrolled_train import save_unrolled
from vrcorrect.runtime.unrolled import UnrolledModel
from vrcorrect.studies.bench.unrolled import card_text

HELD_OUT = "## Held-out figures"


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("model", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--card", type=Path, help="write the model card here")
    p.add_argument("--force", action="store_true", help="overwrite OUT and the card")
    args = p.parse_args(argv)
    model, meta = model_from_onnx(args.model)
    train = json.loads(meta.get("vrcorrect.train") or "{}")
    old_card = args.model.with_suffix(".md")
    body = ""
    if args.card is not None:
        if args.card.exists() and not args.force:
            p.error(f"{args.card} exists (--force to overwrite)")
        text = old_card.read_text() if old_card.is_file() else ""
        if HELD_OUT not in text:
            p.error(f"{old_card}: no '{HELD_OUT}' section to carry over")
        body = HELD_OUT + "\n" + text.split(HELD_OUT, 1)[1].split("\n", 1)[1]   # card_text drops the heading
    with tempfile.TemporaryDirectory() as tmp:
        ckpt = Path(tmp) / "unrolled.pt"
        save_unrolled(model, ckpt, train.get("config"))
        (Path(tmp) / "report.json").write_text(json.dumps(train))
        report = export_unrolled(ckpt, args.out, force=args.force)
    print(f"{args.model} ({meta.get('vrcorrect.format')}) -> {args.out} ({report.metadata['vrcorrect.format']}, "
          f"{report.bytes} bytes; onnxruntime equals torch to {report.max_abs_error:.2g})")
    if args.card is not None:
        args.card.write_text(card_text(UnrolledModel(args.out), args.out, body.rstrip("\n")))
        print(f"card: {args.card}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
