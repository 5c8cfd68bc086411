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
from pathlib import Path

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_out, shared_values

SHARED_FLAGS = {"out": "out"}  # the shared flags and the ConvertConfig fields they set


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pipelines.convert_checkpoint import ConvertConfig

    add_config_flags(parser, ConvertConfig)
    add_out(parser, "a new directory for the SeeU checkpoint (ckpt-00000000.pt + conversion-report.txt)")


def run(args: argparse.Namespace) -> int:
    from pipelines.convert_checkpoint import ConvertConfig, convert

    written, report, report_path = convert(config_from_args(ConvertConfig, args, **shared_values(args, SHARED_FLAGS)))
    for line in report.lines():
        if not line.startswith("mapped "):
            print(line)
    print(f"{report.summary()}; report: {report_path}")
    print(f"wrote {written}  (run it: seeu eval --checkpoint {Path(args.out)} --data ...)")
    return 0
