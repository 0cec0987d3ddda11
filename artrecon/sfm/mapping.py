"""From verified matches to cameras and points: the three ways of the SfM stage.

- :func:`map_incremental`: incremental SfM from the images alone (the method's default);
- :func:`map_calibrated`: its second pass when the focal length was not given, with the focal
  length the first pass converged to held fixed (recorded in ``OUT/calibration.json``): the
  points triangulated again from the first pass's cameras, or mapping again when it missed
  images;
- :func:`triangulate_known_poses`: camera poses given (the arm's forward kinematics), held
  fixed; points triangulated and refined.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pycolmap
from tqdm import tqdm

from artrecon.errors import PoseMismatchError, ReconstructionError
from artrecon.files import write_json_atomic
from artrecon.io import ImageSet, Intrinsics
from artrecon.sfm.config import CALIBRATION_FILE, SfMConfig
from artrecon.sfm.pairs import match

log = logging.getLogger(__name__)


def _mapping_options(intrinsics: Intrinsics | None, config: SfMConfig, seed: int
                     ) -> pycolmap.IncrementalPipelineOptions:
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = config.num_threads
    opts.random_seed = seed
    opts.mapper.random_seed = seed
    opts.triangulation.random_seed = seed
    opts.ba_global_frames_ratio = config.global_ba_growth
    opts.ba_global_points_ratio = config.global_ba_growth
    if intrinsics is not None:
        opts.ba_refine_focal_length = False
        opts.ba_refine_principal_point = False
        opts.ba_refine_extra_params = False
        opts.mapper.abs_pose_refine_focal_length = False
        opts.mapper.abs_pose_refine_extra_params = False
    return opts


def map_incremental(image_set: ImageSet, database_path: Path, out_dir: Path,
                    intrinsics: Intrinsics | None, config: SfMConfig, seed: int,
                    progress) -> pycolmap.Reconstruction:
    """Incremental SfM from the images alone (pose search); the largest model, which must hold
    ``config.min_registered_fraction`` of the images. ``progress``: a text stream for a tqdm bar
    fed from COLMAP's callbacks, or None."""
    opts = _mapping_options(intrinsics, config, seed)
    work = out_dir / "mapping"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    bar = None
    if progress:
        bar = tqdm(total=len(image_set.names), desc=f"SfM {image_set.root.name}", unit="img",
                   leave=False, file=progress)
    count = {"n": 0}

    def _initial():
        count["n"] += 2
        if bar is not None:
            bar.update(2)

    def _next():
        count["n"] += 1
        if bar is not None:
            bar.update(1)

    try:
        models = pycolmap.incremental_mapping(database_path, image_set.image_dir, work, opts,
                                              initial_image_pair_callback=_initial,
                                              next_image_callback=_next)
    finally:
        if bar is not None:
            bar.close()
    shutil.rmtree(work, ignore_errors=True)
    n = len(image_set.names)
    if not models:
        raise ReconstructionError(
            f"SfM on {image_set.image_dir} found no initial image pair: 0 of {n} images "
            "registered. Check that neighbouring photos overlap (>60%), that the object and "
            "background are textured, or pass the camera intrinsics (--intrinsics).")
    sizes = {k: m.num_reg_images() for k, m in models.items()}
    best = max(sizes, key=sizes.get)
    rec = models[best]
    need = int(np.ceil(config.min_registered_fraction * n))
    if rec.num_reg_images() < need:
        others = sorted((v for k, v in sizes.items() if k != best), reverse=True)
        raise ReconstructionError(
            f"SfM on {image_set.image_dir}: only {rec.num_reg_images()} of {n} images registered in"
            f" the largest model (need {need})" + (f"; {len(others)} other model(s) with "
                                                   f"{others} images" if others else "")
            + ". Try: more overlapping views (smaller steps around the object), "
            "SfMConfig(matching='exhaustive'), known intrinsics (--intrinsics), or the arm's "
            "camera poses (--use-poses).")
    return rec


def map_calibrated(image_set: ImageSet, database_path: Path, out_dir: Path,
                   first: pycolmap.Reconstruction, pairs: list[tuple[str, str]],
                   config: SfMConfig, seed: int, progress) -> pycolmap.Reconstruction:
    """Self-calibration, second pass: the focal length held at the value the first pass
    (:func:`map_incremental` with the focal length refined) converged to.

    The first pass starts from EXIF or COLMAP's guess of 1.2 x the longer side (768 px for 640 x
    480 images whose focal length is 554 px) and refines it, but the points it triangulated and
    filtered while the focal length was unknown stay lost, and the two-view geometries were
    verified without a calibration (fundamental matrices): on pliers captures at 12 views per
    ring it kept 3959 points, 195 on the object, and the run failed for lack of matches (84).
    So the database's camera takes the converged focal length as known and the image pairs are
    verified again with it (essential matrices; the SIFT matches are kept). When the first pass
    registered every image, its cameras are kept: the points are triangulated again from them
    with the focal length held (:func:`_retriangulate`), then cameras and points adjusted
    together. Otherwise incremental mapping runs again with the focal length held fixed, which
    may register the images the first pass missed (pliers at 12 views per ring: 4310 points,
    352 on the object).

    The second mapping from scratch was most of the photo route's time: pliers at 36 views per
    ring (121 images), 42.8 CPU s per configuration against 21.2 for re-verifying,
    re-triangulating and adjusting, with 13227 points against 12882 and the hinge's axis 0.42
    deg from the truth against 0.45 (one run each). Re-triangulating with the first pass's
    fundamental-matrix inliers instead (no second verification: 10 CPU s) kept fewer points
    (12185) and took the axis to 0.62 deg.
    """
    cameras = list(first.cameras.values())
    if len(cameras) != 1:
        return first
    camera = cameras[0]
    K = np.asarray(camera.calibration_matrix(), dtype=float)
    K[0, 2] -= 0.5  # COLMAP centres the top-left pixel at (0.5, 0.5); OpenCV at (0, 0)
    K[1, 2] -= 0.5
    every_image = first.num_reg_images() == len(image_set.names)
    log.info("%s: self-calibrated focal length %.2f px; %s with it held fixed", image_set.root,
             camera.mean_focal_length(), "triangulating again from the first pass's cameras"
             if every_image else "mapping again")
    with pycolmap.Database.open(database_path) as db:
        stored = db.read_camera(camera.camera_id)
        write_json_atomic(out_dir / CALIBRATION_FILE, {
            "source": "EXIF" if stored.has_prior_focal_length else "self-calibrated",
            "initial_focal_px": float(stored.mean_focal_length()),
            "focal_px": float(camera.mean_focal_length())})
        stored.params = camera.params
        # a known focal length: the mapper then registers images by P3P, not P4Pf (which
        # estimates a focal length per image)
        stored.has_prior_focal_length = True
        db.update_camera(stored)
        db.clear_two_view_geometries()
    match(database_path, pairs, out_dir, config)  # verification only: the matches are there
    intrinsics = Intrinsics(K, image_set.size)
    if every_image:
        return _retriangulate(image_set, database_path, out_dir, first, intrinsics, config, seed)
    return map_incremental(image_set, database_path, out_dir, intrinsics, config, seed,
                           progress)


def _retriangulate(image_set: ImageSet, database_path: Path, out_dir: Path,
                   rec: pycolmap.Reconstruction, intrinsics: Intrinsics, config: SfMConfig,
                   seed: int) -> pycolmap.Reconstruction:
    """``rec``'s points triangulated again from its cameras with the database's (re-verified)
    matches, filtered and refined with the cameras held (as with known poses), then cameras and
    points adjusted together, the intrinsics held."""
    rec = _triangulate(rec, image_set, database_path, out_dir, intrinsics, config, seed)
    pycolmap.bundle_adjustment(rec, adjustment_options(config, refine_focal_length=False))
    return rec


def adjustment_options(config: SfMConfig, refine_focal_length: bool
                       ) -> pycolmap.BundleAdjustmentOptions:
    """A bundle adjustment of cameras and points, the principal point and distortion held, the
    focal length refined or held, quiet, on ``config.num_threads``."""
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = refine_focal_length
    options.refine_principal_point = False
    options.refine_extra_params = False
    options.print_summary = False
    options.ceres.solver_options.num_threads = config.num_threads
    return options


def _triangulate(rec: pycolmap.Reconstruction, image_set: ImageSet, database_path: Path,
                 out_dir: Path, intrinsics: Intrinsics, config: SfMConfig, seed: int
                 ) -> pycolmap.Reconstruction:
    """``rec``'s cameras held, its points (cleared) triangulated from the database's verified
    matches, then filtered and refined in ``config.pose_ba_refinements`` rounds."""
    opts = _mapping_options(intrinsics, config, seed)
    opts.ba_global_max_refinements = config.pose_ba_refinements
    work = out_dir / "triangulation"
    work.mkdir(parents=True, exist_ok=True)
    try:
        return pycolmap.triangulate_points(rec, database_path, image_set.image_dir, work,
                                           clear_points=True, options=opts,
                                           refine_intrinsics=False)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def triangulate_known_poses(image_set: ImageSet, database_path: Path, out_dir: Path,
                            intrinsics: Intrinsics, poses: dict[str, np.ndarray],
                            config: SfMConfig, seed: int) -> pycolmap.Reconstruction:
    """Points triangulated and refined with the given ``T_world_camera`` poses held fixed (no
    pose search); images without a pose are left out."""
    missing = [n for n in image_set.names if n not in poses]
    known = len(image_set.names) - len(missing)
    if known < 3:
        raise ReconstructionError(f"camera poses known for only {known}"
                                  f" of {len(image_set.names)} images of {image_set.image_dir}; "
                                  "give a pose per image or run without poses (SfM)")
    if missing:
        log.warning("%s: no pose for %d image(s) (e.g. %s); they are left out of the "
                    "known-pose triangulation", image_set.image_dir, len(missing), missing[0])
    rec = pycolmap.Reconstruction()
    with pycolmap.Database.open(database_path) as db:
        for cam in db.read_all_cameras():
            rec.add_camera_with_trivial_rig(cam)
        for img in db.read_all_images():
            if img.name not in poses:
                continue
            T_cw = np.linalg.inv(poses[img.name])
            pose = pycolmap.Rigid3d(T_cw[:3, :])
            new = pycolmap.Image(name=img.name, camera_id=img.camera_id, image_id=img.image_id)
            rec.add_image_with_trivial_frame(new, pose)
    rec = _triangulate(rec, image_set, database_path, out_dir, intrinsics, config, seed)
    if rec.num_points3D() == 0:
        raise PoseMismatchError(
            f"triangulation with the given camera poses on {image_set.image_dir} gave no points: "
            "the poses do not agree with the images. Check that the poses belong to these images "
            "(T_world_camera, OpenCV convention) and the intrinsics, or run without the poses "
            "(without --use-poses) so SfM recovers the cameras from the images.")
    return rec
