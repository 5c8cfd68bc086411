"""Sample context-target triples from posed chunks into Arrow shards with a manifest.

Modes:
  interp  context gap in [--gap-min, --gap-max], targets inside the pair (the peers' sampler)
  extrap  targets up to --extrap-frames (default 45; 0 and 90 for the ablation) before and after the
          pair, clipped to the scene; --interp-ratio of the targets are drawn inside instead

Context pairs (--pairs): gap, by frame gap as above (the peers' protocol for video: it skips scenes
too short for the gaps); overlap, by the scene's view overlap (the overlap table of the posed data):
a pair whose overlap is in [--min-overlap, --max-overlap], interpolation targets seen by both
contexts at least as well as they see each other, extrapolation targets partly outside both but
sharing at least --min-overlap with one; auto (default): gap for scenes whose frame order is a
camera path (told from the poses) with frames enough for the gaps, overlap for the others (photo
sets in any order, short scenes). The overlap rule ignores how frames are numbered or named.
  eval    exactly the entries of an evaluation index (pixelSplat JSON, latentSplat list-per-scene,
          MVSplat DTU `scanN_train_0K`); null entries are skipped and counted, entries naming a
          missing scene or frame are reported and not written

The same inputs and seed give byte-identical shards with either engine; a re-run resumes (shards
already written for the same plan are kept while they have the size and mtime recorded with their
sha256; --verify hashes them and the inputs; unchanged inputs and options: nothing is read). Scenes
too short for the gaps are skipped and counted. Writes are atomic (temporary name, rename, manifest
last); --fsync also fsyncs every shard and the manifest before their rename, for durability across
a power loss.

Examples:
  seeu build data/posed/clip --out data/shards/interp --mode interp --gap-min 25 --gap-max 45
  seeu build data/posed/re10k --out data/shards/extrap --mode extrap --extrap-frames 45 --resize 256x256
  seeu build data/posed/re10k_test --out data/shards/eval --mode eval \\
      --index seeu_data/assets/evaluation_index_re10k.json --resize 256x256
  seeu build data/posed/re10k --out data/shards/x --engine ray --ray-address auto
  seeu build data/posed/photos --out data/shards/photos --pairs overlap --min-overlap 0.3 --max-overlap 0.8
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import Any

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_force, add_fsync, add_max_pixels, add_out, add_progress, shared_values
from seeu_data.errors import SeeUError

# The shared flags (pipelines/cli/options.py) and the BuildConfig fields they set; every other flag
# comes from a `setting` of BuildConfig or its nested configs (SamplingConfig, ImageOptions) but
# `sampling.mode`, which is --mode (SKIP).
SHARED_FLAGS = {"out": "out", "force": "force", "progress": "progress", "fsync": "fsync", "max_pixels": "max_pixels"}
SKIP = ("sampling.mode",)


def config_with_sampling(cls: type, args: argparse.Namespace, prefix: str = "", **given: Any) -> Any:
    """`config_from_args`, a bad sampler option (SamplingConfig's ValueError) as one line naming it."""
    try:
        return config_from_args(cls, args, prefix, **given)
    except ValueError as exc:
        raise SeeUError(f"invalid sampling options: {exc}") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.build import BuildConfig

    add_config_flags(p, BuildConfig, skip=SKIP)
    add_out(p, "output shards directory")
    add_force(p, also=" (every shard is written anew)")
    add_progress(p)
    add_fsync(p)
    add_max_pixels(p)


def run(args: argparse.Namespace) -> int:
    from pipelines.build import BuildConfig, build
    from seeu_data.build.sampling import SamplingConfig

    cfg = config_from_args(BuildConfig, args, sampling=SamplingConfig(), **shared_values(args, SHARED_FLAGS))
    if cfg.mode != "eval":  # the sampler's flags (eval mode draws nothing: they are not read)
        sampling = config_with_sampling(SamplingConfig, args, "sampling.", **{"sampling.mode": cfg.mode})
        cfg = replace(cfg, sampling=sampling)
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
    else:
        if rep.get("scenes_skipped_too_short"):
            print(
                f"skipped {rep['scenes_skipped_too_short']} of {rep['scenes']} scenes with fewer than "
                f"{rep['min_scene_frames']} frames (e.g. {', '.join(rep['skipped_scene_examples'][:3])})"
            )
        pairs = rep.get("pairs")
        if pairs and pairs["overlap"] + pairs["overlap_scenes_without_a_pair"]:
            lo, hi = pairs["overlap_range"]
            print(
                f"context pairs: {pairs['gap']} scenes by frame gap, {pairs['overlap']} by view overlap {lo:g}..{hi:g}"
                + (
                    f"; {pairs['overlap_scenes_without_a_pair']} scenes without such a pair skipped "
                    f"(e.g. {', '.join(pairs['overlap_scenes_without_a_pair_examples'][:3])})"
                    if pairs["overlap_scenes_without_a_pair"]
                    else ""
                )
            )
    return 0
