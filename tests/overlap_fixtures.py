"""The scenes of the view-overlap tests: a synthetic orbit of 24 views (in order, and shuffled and
renamed) and a wide-baseline set of 10 views, with exact cameras, exact tracks (so their stored
overlap is measured from tracks, as an ingest's) and their exact overlap
(`seeu_data.synthetic.true_overlap`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from seeu_data.store.manifest import provenance
from seeu_data.store.posed import PosedDatasetWriter, PosedScene, TrackedScene
from seeu_data.synthetic import make_orbit_scene, synthetic_posed_scene, true_overlap, wide_camera_set

H, W = 120, 160


def write_posed(root: Path, scene: PosedScene) -> Path:
    with PosedDatasetWriter(root, {"test": True}, provenance("tests")) as w:
        w.add(scene)
    return root


def shuffled(scene: TrackedScene, order: np.ndarray, names: list[str]) -> TrackedScene:
    """The scene's frames in `order` (new frame k = old frame order[k]), named `names`."""
    assert scene.observations is not None
    frame, point = scene.observations
    return replace(
        scene,
        observations=(np.argsort(order)[frame], point),
        images=[scene.images[i] for i in order],
        width=scene.width[order],
        height=scene.height[order],
        intrinsics_norm=scene.intrinsics_norm[order],
        cam_to_world=scene.cam_to_world[order],
        source_frame=np.arange(len(order), dtype=np.int64),
        source_name=list(names),
    )


def make_overlap_scenes(root: Path) -> dict:
    orbit = synthetic_posed_scene(24, H, W, seed=0, scene_id="orbit", world="orbit", tracks=True)
    orbit = replace(orbit, source_name=[f"IMG_{i:04d}.jpg" for i in range(24)])
    order = np.random.default_rng(7).permutation(24)
    names = [f"photo_{chr(97 + (5 * k) % 26)}{k}.jpg" for k in range(24)]
    wide = synthetic_posed_scene(
        10, H, W, seed=0, scene_id="wide", world="orbit", poses=wide_camera_set(10, seed=0), tracks=True
    )
    wide = replace(wide, source_name=[f"DSC_{i:04d}.jpg" for i in range(10)])
    world = make_orbit_scene(0)
    return {
        "orbit": write_posed(root / "orbit", orbit),
        "shuffled": write_posed(root / "shuffled", shuffled(orbit, order, names)),
        "shuffled_order": order,
        "wide": write_posed(root / "wide", wide),
        "truth_orbit": true_overlap(world, orbit.cam_to_world, orbit.intrinsics_norm),
        "truth_wide": true_overlap(world, wide.cam_to_world, wide.intrinsics_norm),
    }
