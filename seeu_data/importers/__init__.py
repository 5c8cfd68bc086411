"""Dataset importers: peer formats -> posed-frames directories (`seeu import FORMAT ...`).

Every importer is a generator of `PosedScene` (a usable scene) or `SkippedScene` (a scene that is
left out, with the reason); `write_import` streams them into a `PosedDatasetWriter`, so memory stays
bounded by what one importer holds at a time (one pixelSplat chunk, one scene of files).

Policy for bad input: a problem that concerns one scene (an image that fails to decode, a missing
frame file, frame and camera counts that disagree, a non-finite or non-orthonormal pose) skips
that scene; it is counted and named in the manifest's `report` and in the one-line summary. A
problem with the input as a whole (a missing directory, an unreadable index, an unknown camera
model) raises `SeeUError`. When no usable scene remains the import fails (exit 2) and writes no
manifest.

Modules: `pixelsplat` (RE10K/ACID/DTU chunks), `re10k_text` (raw RealEstate10K/ACID text files),
`dtu` (MVSNet layout), `colmap` (pycolmap models), `nerfstudio` (`transforms.json`).
"""

from __future__ import annotations

from seeu_data.importers.common import ImportReport, SkippedScene, probe_images, write_import

__all__ = ["ImportReport", "SkippedScene", "probe_images", "write_import"]
