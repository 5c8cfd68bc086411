"""Statistics of a triples directory and a contact sheet of sample triples (`seeu inspect`).

`inspect_triples(InspectConfig(path=...))` is `seeu inspect`: the statistics, and the contact sheet
when `sheet` is given. `triple_statistics` reports rows, shards, bytes, scenes, modes, views per example, the context gap
distribution, the target offsets (inside the pair / before / after, range), image sizes and bytes per
view, and the build report; it reads no image pixels. `contact_sheet` draws N evenly spaced examples,
one row each: contexts then targets, labelled with frame index and offset.

Example:
    from pathlib import Path
    from pipelines.inspect_triples import contact_sheet, triple_statistics

    stats = triple_statistics(Path("data/shards/extrap"))      # stats["gap"]["median"], stats["modes"], ...
    contact_sheet(Path("data/shards/extrap"), Path("sheet.png"), n_rows=6)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seeu_data.settings import setting


@dataclass(frozen=True)
class InspectConfig:
    """One `seeu inspect` run: `path` a triples directory; `verify` checks every shard's sha256;
    `sheet` a PNG to draw `sheet_rows` examples on (None: no sheet)."""

    path: Path = setting(help="triples directory (holds manifest.json)", positional=True)
    sheet: Path | None = setting(None, "write a contact sheet of sample triples", metavar="OUT.png")
    sheet_rows: int = setting(6, "examples on the contact sheet")
    verify: bool = setting(False, "check every shard's sha256 against the manifest")


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

    from seeu_data.build.triples import TripleShards

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
    """Write a PNG of `n_rows` evenly spaced examples (masked pixels tinted magenta); return their sample ids."""
    import io

    from matplotlib.figure import Figure

    from seeu_data.build.triples import TripleShards
    from seeu_data.errors import SeeUError
    from seeu_data.image_ops import decode_rgb
    from seeu_data.masks import tint_masked
    from seeu_data.store.arrow_io import atomic_write_bytes
    from seeu_data.store.triple_row import TripleRow

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
                ax.imshow(tint_masked(decode_rgb(row.images[c]), row.masks[c] if row.masks else None))
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


def inspect_triples(cfg: InspectConfig) -> dict:
    """`triple_statistics` of `cfg.path`, with stats["sheet"] = {"path", "samples"} when a sheet was drawn."""
    stats = triple_statistics(cfg.path, verify=cfg.verify)
    if cfg.sheet is not None:
        stats["sheet"] = {"path": str(cfg.sheet), "samples": contact_sheet(cfg.path, cfg.sheet, cfg.sheet_rows)}
    return stats
