"""Counts and statistics of a triples directory, and a contact sheet of sample triples.

Reports rows, shards, bytes, scenes, modes, views per example, the context gap distribution, the
target offsets (inside the pair / before / after, range), image sizes and bytes per view, and the
build report (skipped scenes, evaluation-index problems). --sheet draws N examples (evenly spaced
over the dataset): one row per example, contexts then targets, each labelled with its frame index
and offset, the row with mode, scene and gap.

Examples:
  seeu inspect data/shards/extrap
  seeu inspect data/shards/extrap --json
  seeu inspect data/shards/eval --sheet eval_sheet.png --sheet-rows 8
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", type=Path, help="triples directory (holds manifest.json)")
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")
    p.add_argument("--sheet", type=Path, metavar="OUT.png", help="write a contact sheet of sample triples")
    p.add_argument("--sheet-rows", type=int, default=6, help="examples on the contact sheet (default 6)")
    p.add_argument("--verify", action="store_true", help="check every shard's sha256 against the manifest")


def _hist(values: np.ndarray, bins: int = 10) -> dict:
    if values.size == 0:
        return {"edges": [], "counts": []}
    lo, hi = int(values.min()), int(values.max())
    edges = np.linspace(lo, hi + 1, min(bins, hi - lo + 1) + 1)
    counts, edges = np.histogram(values, bins=edges)
    return {"edges": [float(e) for e in edges], "counts": [int(c) for c in counts]}


def _summary(values: np.ndarray) -> dict:
    if values.size == 0:
        return {"count": 0}
    return {
        "count": int(values.size),
        "min": int(values.min()),
        "max": int(values.max()),
        "mean": round(float(values.mean()), 3),
        "median": float(np.median(values)),
        "histogram": _hist(values),
    }


def triple_statistics(root: Path, verify: bool = False) -> dict:
    """Statistics of a triples directory (reads no image pixels; image bytes via Arrow offsets)."""
    import pyarrow.compute as pc

    from seeu_data.triples import TripleShards

    shards = TripleShards(root, verify=verify)
    cols = ["scene_id", "mode", "num_context", "gap", "target_offset", "width", "height", "image"]
    table = shards.read_columns(cols)
    modes, mode_counts = (
        np.unique(np.asarray(table.column("mode").to_pylist(), dtype=object), return_counts=True)
        if table.num_rows
        else ([], [])
    )
    gaps = table.column("gap").to_numpy() if table.num_rows else np.zeros(0, int)
    offsets = pc.list_flatten(table.column("target_offset")).to_numpy() if table.num_rows else np.zeros(0, int)
    views = pc.list_value_length(table.column("width")).to_numpy() if table.num_rows else np.zeros(0, int)
    nctx = table.column("num_context").to_numpy() if table.num_rows else np.zeros(0, int)
    widths = pc.list_flatten(table.column("width")).to_numpy() if table.num_rows else np.zeros(0, int)
    heights = pc.list_flatten(table.column("height")).to_numpy() if table.num_rows else np.zeros(0, int)
    img_bytes = pc.binary_length(pc.list_flatten(table.column("image"))).to_numpy() if table.num_rows else np.zeros(0)
    sizes, size_counts = (
        np.unique(np.stack([widths, heights], 1), axis=0, return_counts=True) if widths.size else ([], [])
    )
    outside = offsets[offsets != 0]
    return {
        "path": str(root),
        "rows": int(table.num_rows),
        "shards": len(shards.files),
        "bytes": int(sum(e["bytes"] for e in shards.manifest["files"])),
        "scenes": int(len(set(table.column("scene_id").to_pylist()))),
        "modes": {str(m): int(c) for m, c in zip(modes, mode_counts)},  # type: ignore[call-overload]
        "num_context": {str(int(k)): int(c) for k, c in zip(*np.unique(nctx, return_counts=True))},
        "num_target": {str(int(k)): int(c) for k, c in zip(*np.unique(views - nctx, return_counts=True))},
        "gap": _summary(gaps),
        "target_offset": {
            "inside": int((offsets == 0).sum()),
            "before": int((offsets < 0).sum()),
            "after": int((offsets > 0).sum()),
            "outside": _summary(outside),
            "max_abs": int(np.abs(offsets).max()) if offsets.size else 0,
        },
        "image_sizes": {f"{int(w)}x{int(h)}": int(c) for (w, h), c in zip(sizes, size_counts)},  # type: ignore[call-overload]
        "image_bytes_per_view_mean": round(float(img_bytes.mean()), 1) if img_bytes.size else 0.0,
        "params": shards.manifest.get("params", {}),
        "report": shards.manifest.get("report", {}),
    }


def contact_sheet(root: Path, out: Path, n_rows: int = 6) -> list[str]:
    """Write a PNG of `n_rows` evenly spaced examples; return their sample ids."""
    import io

    from matplotlib.figure import Figure

    from seeu_data.arrow_io import atomic_write_bytes
    from seeu_data.errors import SeeUError
    from seeu_data.image_ops import decode_rgb
    from seeu_data.triple_row import TripleRow
    from seeu_data.triples import TripleShards

    shards = TripleShards(root)
    total = len(shards)
    if total == 0:
        raise SeeUError("no rows to draw", root)
    n = max(1, min(n_rows, total))
    wanted = sorted(set(np.linspace(0, total - 1, n).round().astype(int).tolist()))
    rows: list[TripleRow] = []
    start = 0
    for i, entry in enumerate(shards.manifest["files"]):
        stop = start + entry["rows"]
        local = [w - start for w in wanted if start <= w < stop]
        if local:
            table = shards.read_shard(i).take(local)
            rows.extend(TripleRow.from_pydict(d) for d in table.to_pylist())
        start = stop
    cols = max(len(r.frame_index) for r in rows)
    aspect = float(np.median(np.concatenate([r.height / np.maximum(r.width, 1) for r in rows])))  # h / w
    fig = Figure(figsize=(2.2 * cols, (2.2 * min(max(aspect, 0.3), 3.0) + 0.5) * len(rows)), dpi=80)
    axes = np.atleast_2d(fig.subplots(len(rows), cols, squeeze=False))
    for r_i, row in enumerate(rows):
        v = row.num_context
        for c in range(cols):
            ax = axes[r_i, c]
            ax.set_xticks([])
            ax.set_yticks([])
            if c >= len(row.frame_index):
                ax.axis("off")
                continue
            try:
                ax.imshow(decode_rgb(row.images[c]))
            except ValueError:
                ax.text(0.5, 0.5, "undecodable", ha="center", va="center", transform=ax.transAxes)
            if c < v:
                ax.set_title(f"context f={row.frame_index[c]}", fontsize=8, color="tab:blue")
            else:
                off = int(row.target_offset[c - v])
                ax.set_title(
                    f"target f={row.frame_index[c]} ({off:+d})" if off else f"target f={row.frame_index[c]}",
                    fontsize=8,
                    color="tab:red" if off else "tab:green",
                )
        axes[r_i, 0].set_ylabel(f"{row.mode}\n{row.scene_id[:18]}\ngap {row.gap}", fontsize=8)
    fig.suptitle(f"{root.name}: {total} triples", fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(out, buf.getvalue())
    return [r.sample_id for r in rows]


def _print_text(s: dict) -> None:
    print(f"{s['path']}: {s['rows']} triples, {s['shards']} shards, {s['bytes'] / 1e6:.1f} MB, {s['scenes']} scenes")
    print("modes: " + ", ".join(f"{m} {c}" for m, c in s["modes"].items()))
    print(f"views: context {s['num_context']}, target {s['num_target']}")
    g = s["gap"]
    if g["count"]:
        print(f"context gap: min {g['min']}, median {g['median']:g}, mean {g['mean']:g}, max {g['max']}")
    t = s["target_offset"]
    line = f"targets: {t['inside']} inside the pair, {t['before']} before, {t['after']} after"
    if t["outside"]["count"]:
        line += f" (offsets {t['outside']['min']}..{t['outside']['max']})"
    print(line)
    print(
        "image sizes (WxH: views): "
        + ", ".join(f"{k}: {v}" for k, v in s["image_sizes"].items())
        + f"; {s['image_bytes_per_view_mean'] / 1e3:.1f} kB per view"
    )
    rep = s["report"]
    if rep.get("scenes_skipped_too_short"):
        print(
            f"build skipped {rep['scenes_skipped_too_short']} scenes shorter than {rep.get('min_scene_frames')} frames"
        )
    if "index_entries" in rep:
        print(
            f"eval index: {rep['index_entries']} entries, {rep['index_null_skipped']} null skipped, "
            f"{rep['not_written']} not written"
        )


def run(args: argparse.Namespace) -> int:
    stats = triple_statistics(args.path, verify=args.verify)
    if args.sheet:
        stats["sheet"] = {"path": str(args.sheet), "samples": contact_sheet(args.path, args.sheet, args.sheet_rows)}
    if args.json:
        print(json.dumps(stats, indent=1))
    else:
        _print_text(stats)
        if args.sheet:
            print(f"contact sheet: {args.sheet} ({len(stats['sheet']['samples'])} examples)")
    return 0
