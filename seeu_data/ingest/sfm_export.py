"""The SfM child's last step: each kept model written to sparse/<k>/, undistorted when its distortion
matters, and exported as result.json's "models" + points_depth_<k>.npy / points3d_<k>.npy."""

from __future__ import annotations

from pathlib import Path

from seeu_data.ingest.sfm import Job, emit, model_cameras

_UNDISTORTED_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")


def _camera_dict(camera) -> dict:
    K = camera.calibration_matrix()
    return {
        "model": camera.model.name,
        "width": int(camera.width),
        "height": int(camera.height),
        "params": [float(p) for p in camera.params],
        "fx": float(K[0, 0]),
        "fy": float(K[1, 1]),
        "cx": float(K[0, 2]),
        "cy": float(K[1, 2]),
    }


def _max_distortion_px(camera) -> float:
    """Largest distance (pixels) between where a border pixel is and where the pinhole part of the
    camera alone would put its ray: 0 for pinhole models."""
    import numpy as np

    w, h = float(camera.width), float(camera.height)
    ts = np.linspace(0.0, 1.0, 9)
    border = np.concatenate(
        [
            np.stack([ts * w, np.zeros_like(ts)], 1),
            np.stack([ts * w, np.full_like(ts, h)], 1),
            np.stack([np.zeros_like(ts), ts * h], 1),
            np.stack([np.full_like(ts, w), ts * h], 1),
        ]
    )
    rays = np.asarray(camera.cam_from_img(border), np.float64)
    K = np.asarray(camera.calibration_matrix(), np.float64)
    pinhole = rays @ K[:2, :2].T + K[:2, 2]
    return float(np.linalg.norm(pinhole - border, axis=1).max())


def _export_model(rec, index: int, image_dir: str, out: Path, cameras: dict[int, dict], undistorted: bool) -> dict:
    """Cameras (`cameras`: {camera id: dict} of the registered images), poses and point depths of one
    reconstruction, as plain JSON/npy (and its observations, the tracks the view overlap is measured from)."""
    import numpy as np

    camera_ids = sorted(cameras)
    position = {cid: j for j, cid in enumerate(camera_ids)}
    images, depths, obs = [], [], []
    points = {pid: p.xyz for pid, p in rec.points3D.items()}
    for iid in sorted(rec.reg_image_ids()):
        img = rec.image(iid)
        w2c = img.cam_from_world().matrix()
        images.append({"name": img.name, "world_to_cam": np.asarray(w2c).tolist(), "camera": position[img.camera_id]})
        pids = [p.point3D_id for p in img.points2D if p.has_point3D()]
        obs.append(np.stack([np.full(len(pids), len(images) - 1), np.asarray(pids, np.int64)], 1).reshape(-1, 2))
        if pids:
            xyz = np.stack([points[p] for p in pids])
            depths.append(xyz @ np.asarray(w2c)[:, :3].T[:, 2] + np.asarray(w2c)[2, 3])
    depth = np.concatenate(depths) if depths else np.zeros(0)
    np.save(out / f"points_depth_{index}.npy", depth.astype(np.float64))
    ids = sorted(points)
    xyz = np.array([points[p] for p in ids], np.float64).reshape(-1, 3)
    rgb = np.array([rec.points3D[p].color for p in ids], np.float64).reshape(-1, 3)
    np.save(out / f"points3d_{index}.npy", np.concatenate([xyz, rgb], 1))  # (M, 6) world xyz + RGB 0-255
    names = np.array([im["name"] for im in images])
    np.savez(
        out / f"observations_{index}.npz", names=names, obs=np.concatenate(obs) if obs else np.zeros((0, 2), np.int64)
    )
    uses = [sum(im["camera"] == j for im in images) for j in range(len(camera_ids))]
    return {
        "index": index,
        "cameras": [cameras[c] for c in camera_ids],
        "camera": cameras[camera_ids[uses.index(max(uses))]],  # the camera of most frames
        "undistorted": undistorted,
        "image_dir": image_dir,
        "images": images,
        "num_points3D": int(rec.num_points3D()),
        "mean_reprojection_error": float(rec.compute_mean_reprojection_error()),
    }


def export_models(job: Job, recs: dict, kept: list[int]) -> list[dict]:
    """Each kept model written to sparse/<k>/, undistorted when its distortion matters, and exported;
    returns result.json's "models"."""
    from seeu_data.undistort import undistort_files

    cfg, clock, out, image_dir = job.cfg, job.clock, job.out, job.image_dir
    emit("stage", "export")
    models = []
    for k in sorted(kept):
        rec = recs[k]
        t0 = clock.mark()
        model_dir = out / "sparse" / str(k)
        model_dir.mkdir(exist_ok=True)
        rec.write(model_dir)
        cameras = {int(c.camera_id): c for c in model_cameras(rec)}  # one per frame size
        distortion = max(_max_distortion_px(c) for c in cameras.values())
        as_mapped = {cid: _camera_dict(c) for cid, c in cameras.items()}
        pinhole_models = all(c.model.name in _UNDISTORTED_MODELS for c in cameras.values())
        if pinhole_models or distortion < cfg.max_negligible_distortion_px:
            # Pinhole already, or distortion below a fraction of a pixel everywhere: the frames are
            # used as they are (no resampling, no crop, no second JPEG generation).
            models.append(_export_model(rec, k, image_dir, out, as_mapped, undistorted=False))
            models[-1]["distortion_max_px"] = distortion
            clock.add("export_s", t0)
            continue
        # Same-size undistortion (seeu_data.undistort), each camera's frames with it: the frames keep
        # W x H, only the focal changes.
        und = out / "undistorted" / str(k) / "images"
        clock.add("export_s", t0)
        t0 = clock.mark()
        pinholes = {}
        for cid, camera in cameras.items():
            names = sorted(rec.image(i).name for i in rec.reg_image_ids() if rec.image(i).camera_id == cid)
            pinholes[cid] = undistort_files(camera, image_dir, names, und, jpeg_quality=95)
        clock.add("undistort_s", t0)
        t0 = clock.mark()
        model = _export_model(rec, k, str(und), out, {c: p.as_dict() for c, p in pinholes.items()}, undistorted=True)
        primary = next(c for c in cameras if pinholes[c].as_dict() == model["camera"])
        model["camera_distorted"] = as_mapped[primary]
        model["cameras_distorted"] = [as_mapped[c] for c in sorted(cameras)]
        model["distortion_max_px"] = distortion
        model["undistortion"] = {
            "method": "same-size pinhole, focal x scale",
            "scale": pinholes[primary].scale,
            "scales": [pinholes[c].scale for c in sorted(cameras)],
        }
        models.append(model)
        clock.add("export_s", t0)
    return models
