"""Sample context-target triples from posed chunks into Arrow shards with a manifest.

Modes:
  interp  context gap in [--gap-min, --gap-max], targets inside the pair (the peers' sampler)
  extrap  targets up to --extrap-frames (default 45; 0 and 90 for the ablation) before and after the
          pair, clipped to the scene; --interp-ratio of the targets are drawn inside instead
  eval    exactly the entries of an evaluation index (pixelSplat JSON, latentSplat list-per-scene,
          MVSplat DTU `scanN_train_0K`); null entries are skipped and counted, entries naming a
          missing scene or frame are reported and not written

The same inputs and seed give byte-identical shards with either engine; a re-run resumes (shards
already written for the same plan are kept once their recorded size and sha256 check out). Scenes
too short for the gaps are skipped and counted. Writes are atomic (temporary name, rename, manifest
last); --fsync also fsyncs every shard and the manifest before their rename, for durability across
a power loss.

Examples:
  seeu build data/posed/clip --out data/shards/interp --mode interp --gap-min 25 --gap-max 45
  seeu build data/posed/re10k --out data/shards/extrap --mode extrap --extrap-frames 45 --resize 256x256
  seeu build data/posed/re10k_test --out data/shards/eval --mode eval \\
      --index seeu_data/assets/evaluation_index_re10k.json --resize 256x256
  seeu build data/posed/re10k --out data/shards/x --engine ray --ray-address auto
"""

from __future__ import annotations

import argparse

from pipelines.cli.options import (
    add_fsync,
    add_max_pixels,
    add_out,
    add_progress,
    add_workers,
    max_pixels,
    progress_wanted,
)
from seeu_data.build.eval_index import FORMATS as EVAL_INDEX_FORMATS
from seeu_data.errors import SeeUError
from seeu_data.settings import parse_bytes, parse_dims


def add_sampling_arguments(p: argparse.ArgumentParser) -> None:
    """Sampler options shared by `seeu build` and `seeu index`."""
    g = p.add_argument_group("sampling")
    g.add_argument("--num-context", "-V", type=int, default=2, help="context views per example (default 2)")
    g.add_argument("--num-target", "-T", type=int, default=3, help="target views per example (default 3)")
    g.add_argument("--gap-min", type=int, default=25, help="smallest context gap in frames (default 25)")
    g.add_argument("--gap-max", type=int, default=45, help="largest context gap in frames (default 45)")
    g.add_argument(
        "--extrap-frames",
        type=int,
        default=45,
        help="extrap: targets at most this many frames before/after the pair (default 45)",
    )
    g.add_argument(
        "--interp-ratio",
        type=float,
        default=0.0,
        help="extrap: probability that a target is drawn inside the pair instead (default 0)",
    )
    g.add_argument("--samples-per-scene", type=int, default=4, help="examples drawn per scene (default 4)")
    g.add_argument("--seed", type=int, default=0, help="random seed (default 0)")


def sampling_config(args: argparse.Namespace, mode: str):
    """The SamplingConfig of the `add_sampling_arguments` flags (a bad value: one line naming it)."""
    from seeu_data.build.sampling import SamplingConfig

    try:
        return SamplingConfig(
            mode=mode,
            num_context=args.num_context,
            num_target=args.num_target,
            gap_min=args.gap_min,
            gap_max=args.gap_max,
            extrap_frames=args.extrap_frames,
            interp_ratio=args.interp_ratio,
            samples_per_scene=args.samples_per_scene,
        )
    except ValueError as exc:
        raise SeeUError(f"invalid sampling options: {exc}") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", help="posed-frames directories (hold manifest.json)")
    add_out(p, "output shards directory")
    p.add_argument("--mode", choices=["interp", "extrap", "eval"], default="interp")
    p.add_argument("--index", help="eval: evaluation index JSON file")
    p.add_argument(
        "--index-format",
        choices=["auto", *EVAL_INDEX_FORMATS],
        default="auto",
        help="eval: format of --index (default: detected)",
    )
    add_sampling_arguments(p)
    g = p.add_argument_group("images and shards")
    g.add_argument(
        "--resize",
        metavar="HxW",
        help="resize + centre-crop at build time (intrinsics updated), e.g. 256x256; "
        "default: copy the encoded images as they are",
    )
    g.add_argument(
        "--interpolation",
        choices=["area", "lanczos", "linear", "cubic"],
        default="area",
        help="resize filter (default area: INTER_AREA when shrinking)",
    )
    g.add_argument("--jpeg-quality", type=int, default=95, help="JPEG quality of resized images (default 95)")
    g.add_argument(
        "--near",
        type=float,
        default=None,
        help="near plane for every view instead of the posed data's (e.g. 1 with --far 100: the "
        "peers' RealEstate10K values); default: the data's",
    )
    g.add_argument("--far", type=float, default=None, help="far plane for every view (with --near)")
    g.add_argument("--shard-size", default="128MB", help="target shard size (default 128MB)")
    g.add_argument("--rows-per-batch", type=int, default=64, help="rows per Arrow record batch (default 64)")
    e = p.add_argument_group("execution")
    e.add_argument(
        "--engine",
        choices=["local", "ray"],
        default="local",
        help="local process pool (default) or Ray Data; identical shards",
    )
    add_workers(
        e,
        "the local engine's processes (default: the CPU count, at most 8; 1 when copying images on up to 4 "
        "cores, where one process hashes on threads while it writes)",
        default=None,
    )
    e.add_argument("--ray-address", default=None, help="Ray cluster address (default: start a local instance)")
    e.add_argument("--verify-inputs", action="store_true", help="check the posed files' sha256 first")
    add_progress(e)
    add_fsync(e)
    add_max_pixels(e)


def run(args: argparse.Namespace) -> int:
    from pipelines.build import BuildConfig, build, default_workers
    from seeu_data.build.sampling import SamplingConfig
    from seeu_data.build.triples import ImageOptions

    if (args.near is None) != (args.far is None):
        raise SeeUError("--near and --far go together")
    cfg = BuildConfig(
        inputs=tuple(args.inputs),
        out=str(args.out),
        mode=args.mode,
        sampling=sampling_config(args, args.mode) if args.mode != "eval" else SamplingConfig(),
        index_path=args.index,
        index_format=args.index_format,
        seed=args.seed,
        image=ImageOptions(
            resize=parse_dims(args.resize, "--resize") if args.resize else None,
            interpolation=args.interpolation,
            jpeg_quality=args.jpeg_quality,
        ),
        shard_bytes=parse_bytes(args.shard_size, "--shard-size"),
        rows_per_batch=args.rows_per_batch,
        engine=args.engine,
        workers=args.workers if args.workers is not None else default_workers(args.resize is not None),
        ray_address=args.ray_address,
        progress=progress_wanted(args),
        verify_inputs=args.verify_inputs,
        near_far=None if args.near is None else (args.near, args.far),
        fsync=args.fsync,
        max_pixels=max_pixels(args),
    )
    manifest = build(cfg, "seeu build")
    rep = manifest["report"]
    size = sum(f["bytes"] for f in manifest["files"]) / 1e6
    shards = len(manifest["files"])
    print(
        f"wrote {manifest['total_rows']} triples in {shards} shard{'s' * (shards != 1)} ({size:.1f} MB) to {args.out}"
        + (f"; {rep['shards_resumed']} kept from a previous run" if rep.get("shards_resumed") else "")
    )
    if args.mode == "eval":
        print(
            f"index {rep['index_format']}: {rep['index_keys']} keys, {rep['index_null_skipped']} null skipped, "
            f"{rep['index_entries']} entries, {rep['written']} written, {rep['not_written']} not written"
        )
        for prob in rep["problems"][:10]:
            print(f"  not written: {prob['key']}: {prob['problem']}")
        if rep["not_written"] > 10:
            kinds = ", ".join(f"{n} {k}" for k, n in rep["problems_by_kind"].items())
            print(f"  ... {rep['not_written'] - 10} more ({kinds}; see manifest.json report.problems)")
    elif rep.get("scenes_skipped_too_short"):
        print(
            f"skipped {rep['scenes_skipped_too_short']} of {rep['scenes']} scenes with fewer than "
            f"{rep['min_scene_frames']} frames (e.g. {', '.join(rep['skipped_scene_examples'][:3])})"
        )
    return 0
