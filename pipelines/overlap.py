"""`seeu overlap`: add the view-overlap table to a posed-frames directory written without one.

Ingest and every importer write the table as they write the posed files (`store.overlap_table`);
this stage measures it for data made before that (`posed.scene_overlap`: from the cameras and
near/far, the SfM tracks being gone), one posed file at a time, and rewrites the manifest with its
`overlap` block last. Resumable: each finished overlap file is recorded in `.overlap-progress.jsonl`
(stamped with its posed file's sha256) and kept by a re-run while intact; `force` measures again.

Example:
    from pipelines.overlap import OverlapConfig, add_overlap

    summary = add_overlap(OverlapConfig(path="data/posed/old"))   # {"scenes", "files", "computed", "resumed"}
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from seeu_data.settings import setting
from seeu_data.store.out_lock import locks_output

PROGRESS_NAME = ".overlap-progress.jsonl"


@dataclass(frozen=True, kw_only=True)
class OverlapConfig:
    """One `seeu overlap` run: `path` a posed-frames directory; `force`: measure every table again."""

    path: Path = setting(help="posed-frames directory (holds manifest.json)", positional=True)
    force: bool = False
    fsync: bool = False
    progress: bool = False


@locks_output(lambda cfg: cfg.path)
def add_overlap(cfg: OverlapConfig) -> dict:
    """Measure and store the overlap tables of `cfg.path`; returns {"scenes", "files", "computed", "resumed",
    "already"} (already: the dataset had its tables and nothing was done)."""
    from tqdm import tqdm

    from seeu_data.store.manifest import FileEntry, read_manifest, write_manifest
    from seeu_data.store.overlap_table import (
        MANIFEST_KEY,
        OVERLAP_FILES,
        manifest_block,
        overlap_file_name,
        write_overlap_file,
    )
    from seeu_data.store.posed import SCHEMA, PosedDataset, scene_overlap
    from seeu_data.store.resume import Journal, file_intact, sweep

    root = Path(cfg.path)
    manifest = read_manifest(root, expect_schema=SCHEMA, verify=True)
    scenes = manifest.get("scenes", [])
    if manifest.get(MANIFEST_KEY) and not cfg.force:
        return {"scenes": len(scenes), "files": len(manifest["files"]), "computed": 0, "resumed": 0, "already": True}
    journal = Journal(root / PROGRESS_NAME, cfg.fsync)
    known = {} if cfg.force else {r["unit"]: r for r in journal.read()}
    ds = PosedDataset(root)
    entries, computed, resumed = [], 0, 0
    with tqdm(total=len(scenes), unit="scene", desc="seeu overlap", file=sys.stderr, disable=not cfg.progress) as bar:
        for f in manifest["files"]:
            ids = [s["scene_id"] for s in scenes if s["file"] == f["path"]]
            rec = known.get(f["path"])
            kept = rec["overlap"] if rec and rec["stamp"] == f["sha256"] else None
            if kept and file_intact(root / kept["path"], kept["bytes"], kept["sha256"]):
                entries.append(kept)
                resumed += len(ids)
            else:
                rows = [(sid, scene_overlap(ds.load_scene(sid))) for sid in ids]
                entries.append(write_overlap_file(root, f["path"], rows, cfg.fsync))
                journal.add({"unit": f["path"], "stamp": f["sha256"], "overlap": entries[-1]})
                computed += len(ids)
            bar.update(len(ids))
    sweep(root, OVERLAP_FILES, keep={Path(overlap_file_name(f["path"])).name for f in manifest["files"]})
    write_manifest(
        root,
        manifest["schema"],
        manifest["schema_version"],
        [FileEntry(**f) for f in manifest["files"]],
        manifest["params"],
        manifest["provenance"],
        scenes=scenes,
        report=manifest.get("report"),
        fsync=cfg.fsync,
        overlap=manifest_block(entries),
    )
    journal.remove()
    return {"scenes": len(scenes), "files": len(entries), "computed": computed, "resumed": resumed, "already": False}
