"""Convert a released checkpoint of another model into a SeeU checkpoint.

  seeu convert-checkpoint mvsplat checkpoints/re10k.ckpt --out runs/mvsplat-re10k/checkpoints
  seeu eval --checkpoint runs/mvsplat-re10k/checkpoints --data data/re10k/test_eval
  seeu render --checkpoint runs/mvsplat-re10k/checkpoints --data data/re10k/test_eval --sample 0 --out out/mv

``mvsplat``: MVSplat's PyTorch-Lightning checkpoint (``state_dict`` with the encoder under ``encoder.``).
It is read without running any code stored in the file (tensors and plain containers only; other
pickled objects, e.g. hyper-parameters, are replaced by inert stand-ins and dropped). Every key is
reported as mapped, missing, unexpected or ignored (the training losses' LPIPS network) in
OUT/conversion-report.txt; a file that is not an MVSplat checkpoint is refused. The result is a SeeU
checkpoint (step 0) with ``encoder: "mvsplat"`` and no refiner: "SeeU w/o refinement", i.e. MVSplat.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("format", choices=["mvsplat"], help="the checkpoint's model")
    parser.add_argument("checkpoint", help="the checkpoint file to convert (e.g. MVSplat's re10k.ckpt)")
    parser.add_argument(
        "--out",
        required=True,
        help="a new directory for the SeeU checkpoint (ckpt-00000000.pt + conversion-report.txt)",
    )
    parser.add_argument(
        "--allow-incomplete",
        action="store_true",
        help="write the checkpoint even with missing or unexpected keys (they are listed)",
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from seeu_data.store.arrow_io import atomic_write_bytes
    from seeu_model.mvsplat.convert import convert_checkpoint

    written, report = convert_checkpoint(args.checkpoint, args.out, allow_incomplete=args.allow_incomplete)
    report_path = Path(args.out) / "conversion-report.txt"
    atomic_write_bytes(report_path, ("\n".join(report.lines()) + "\n").encode())
    for line in report.lines():
        if not line.startswith("mapped "):
            print(line)
    print(f"{report.summary()}; report: {report_path}")
    print(f"wrote {written}  (run it: seeu eval --checkpoint {Path(args.out)} --data ...)")
    return 0
