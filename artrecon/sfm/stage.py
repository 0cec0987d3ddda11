"""The SfM stage of one configuration: :func:`run_sfm` and its result (:class:`SfMResult`).

Its steps, each in its own module: features (:mod:`artrecon.sfm.extraction`), image pairs and
their matching (:mod:`artrecon.sfm.pairs`), mapping (:mod:`artrecon.sfm.mapping`) and, with given
camera poses, their check against the images (:mod:`artrecon.sfm.pose_check`). The folder it
writes is described in :mod:`artrecon.sfm`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pycolmap

from artrecon.io import ImageSet, Intrinsics
from artrecon.procrustes import similarity_transform
from artrecon.sfm.config import CALIBRATION_FILE, SfMConfig
from artrecon.sfm.extraction import extract, read_features, region_boxes
from artrecon.sfm.focal_check import check_given_focal, supported_focal
from artrecon.sfm.mapping import map_calibrated, map_incremental, triangulate_known_poses
from artrecon.sfm.pairs import match, select_pairs
from artrecon.sfm.pose_check import check_pose_agreement, pose_agreement

log = logging.getLogger(__name__)


def camera_poses(reconstruction) -> dict[str, np.ndarray]:
    """``{image name: T_world_camera (4, 4)}`` of the registered images of a
    ``pycolmap.Reconstruction`` (OpenCV convention, the reconstruction's world frame)."""
    out = {}
    for img in reconstruction.images.values():
        if not img.has_pose:
            continue
        T = np.eye(4)
        T[:3, :] = img.cam_from_world().matrix()
        out[img.name] = np.linalg.inv(T)
    return out


@dataclass
class SfMResult:
    """Output of :func:`run_sfm`.

    Attributes
    ----------
    reconstruction : pycolmap.Reconstruction
    database_path : Path
        COLMAP database holding keypoints and descriptors of every image.
    image_dir : Path
    model_dir : Path
        ``sparse/0`` folder the reconstruction was written to.
    num_images : int
        Images in the set (registered or not).
    timings : dict of str to float
        Seconds per step.
    pose_agreement : dict or None
        With given camera poses: how well they agree with the images
        (:func:`~artrecon.sfm.pose_check.pose_agreement`).
    focal_check : dict or None
        With ``check_focal``: the focal length the images support against the given one
        (:func:`~artrecon.sfm.focal_check.supported_focal`).
    """

    reconstruction: pycolmap.Reconstruction
    database_path: Path
    image_dir: Path
    model_dir: Path
    num_images: int
    timings: dict = field(default_factory=dict)
    pose_agreement: dict | None = None
    focal_check: dict | None = None

    def T_world_camera(self) -> dict[str, np.ndarray]:
        """Pose (4, 4) per registered image name, OpenCV convention, SfM world frame."""
        return camera_poses(self.reconstruction)

    def intrinsics(self, image_name: str) -> np.ndarray:
        """(3, 3) OpenCV K of an image (distortion, if modelled, is ignored here)."""
        img = self.reconstruction.find_image_with_name(image_name)
        cam = self.reconstruction.cameras[img.camera_id]
        K = np.asarray(cam.calibration_matrix(), dtype=float)
        K[0, 2] -= 0.5  # COLMAP centres the top-left pixel at (0.5, 0.5); OpenCV at (0, 0)
        K[1, 2] -= 0.5
        return K


@contextlib.contextmanager
def colmap_log(path: Path):
    """Send COLMAP's log (glog, written to the process's stderr) to ``path`` for the block.

    glog's own file sink appends a time stamp to every file name, so the stderr descriptor is
    redirected instead. Yields a text stream on the original stderr for progress bars.
    """
    path = Path(path)
    sys.stderr.flush()
    saved = os.dup(2)
    with open(path, "a") as sink:
        os.dup2(sink.fileno(), 2)
        console = os.fdopen(os.dup(saved), "w")
        try:
            yield console
        finally:
            console.flush()
            console.close()
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)


def camera_summary(reconstruction, given: bool, folder: str | Path | None = None) -> dict:
    """The intrinsics SfM worked with, for the model's metadata.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
    given : bool
        Whether the intrinsics were given (a capture's cameras.json or ``--intrinsics``).
    folder : path, optional
        The SfM folder; its ``calibration.json`` (written by the self-calibration) says where
        the focal length came from and where it started.

    Returns
    -------
    dict
        ``source``: "given" (held fixed), "EXIF" (the photos' focal length as the starting value,
        refined by bundle adjustment) or "self-calibrated" (no focal length known: COLMAP starts
        from 1.2 x the longer image side, and bundle adjustment refines the one camera all
        images share); ``model`` (COLMAP camera model), ``focal_px`` (mean focal length, pixels),
        ``principal_point`` (OpenCV pixels), ``params`` (COLMAP's), ``cameras`` (how many).
    """
    cams = list(reconstruction.cameras.values())
    if not cams:
        return {"source": "given" if given else "unknown", "cameras": 0}
    cam = cams[0]
    source = ("given" if given else "EXIF" if cam.has_prior_focal_length
              else "self-calibrated")
    record = Path(folder) / CALIBRATION_FILE if folder is not None else None
    extra = {}
    if not given and record is not None and record.is_file():
        calibration = json.loads(record.read_text())
        source = calibration.get("source", source)
        extra = {"initial_focal_px": calibration.get("initial_focal_px")}
    K = np.asarray(cam.calibration_matrix(), dtype=float)
    return {"source": source, "model": cam.model.name, "focal_px": float(cam.mean_focal_length()),
            "principal_point": [float(K[0, 2] - 0.5), float(K[1, 2] - 0.5)],
            "params": [float(v) for v in cam.params], "cameras": len(cams), **extra}


class _StepClock:
    """``with clock("step"):`` records the step's wall seconds as ``timings["step"]`` and its CPU
    seconds (this process, all threads) as ``timings["step_cpu"]``: wall time alone says little
    on a shared machine."""

    def __init__(self, timings: dict):
        self.timings = timings

    @contextlib.contextmanager
    def __call__(self, step: str):
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.timings[step] = time.perf_counter() - wall
            self.timings[f"{step}_cpu"] = time.process_time() - cpu


def run_sfm(image_set: ImageSet, out_dir: str | Path, intrinsics: Intrinsics | None = None,
            poses: dict[str, np.ndarray] | None = None, config: SfMConfig = SfMConfig(),
            seed: int = 0, progress: bool = True, check_focal: bool = False) -> SfMResult:
    """Cameras and sparse points of one configuration.

    Parameters
    ----------
    image_set : ImageSet
    out_dir : str or Path
        Working folder; receives ``database.db``, ``pairs.txt``, ``colmap.log``, ``sparse/0``.
    intrinsics : Intrinsics, optional
        Known pinhole intrinsics, held fixed. Without them COLMAP self-calibrates one
        SIMPLE_PINHOLE camera shared by all images (focal length from EXIF or guessed, refined;
        see :func:`~artrecon.sfm.extraction.extract` and :func:`camera_summary`).
    poses : dict of str to (4, 4) float, optional
        ``T_world_camera`` per image name (OpenCV). Given, the poses are held fixed and only
        points are triangulated and refined (requires ``intrinsics``). With them, an
        ``image_set.region`` (the object's, in the poses' frame) keeps each image's full-scale
        features to the box around its projection (``config.region_margin_px``), with a few
        coarse ones of the background beside them (``config.background_features``).
    config : SfMConfig
    seed : int
    progress : bool
        Show a tqdm bar fed from COLMAP's mapping callbacks.
    check_focal : bool
        With given intrinsics and no poses: check the given focal length against the one the
        images support (:mod:`~artrecon.sfm.focal_check`), for image folders without reference
        poses to check the cameras' layout against. A few seconds.

    Returns
    -------
    SfMResult

    Raises
    ------
    ReconstructionError
        Too few images registered, or the images split into several models.
    PoseMismatchError
        Given ``poses`` that disagree with the images
        (:func:`~artrecon.sfm.pose_check.check_pose_agreement`).
    MismatchError
        With ``check_focal``: the images support a clearly different focal length than the
        given one (:func:`~artrecon.sfm.focal_check.check_given_focal`).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if poses is not None and intrinsics is None:
        raise ValueError("run_sfm: known poses need known intrinsics too")
    pycolmap.set_random_seed(seed)
    timings: dict[str, float] = {}
    clock = _StepClock(timings)
    db_path = out_dir / "database.db"
    with colmap_log(out_dir / "colmap.log") as console:
        with clock("extract"):
            boxes = None
            if (poses is not None and image_set.region is not None
                    and config.region_margin_px >= 0 and config.extractor == "opencv"):
                boxes = region_boxes(image_set.region, poses, intrinsics, image_set.size,
                                     config.region_margin_px)
                share = np.mean([(x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in boxes.values()])
                log.info("%s: features inside the object's region (%.0f%% of the image area "
                         "on average), at most %d outside it at %.2f scale", image_set.root,
                         100 * share / (image_set.size[0] * image_set.size[1]),
                         config.background_features, config.background_scale)
            extract(image_set, db_path, intrinsics, config, boxes)
        with clock("pairs"):
            feats = read_features(db_path)
            pairs = select_pairs(image_set.names, feats, config, seed, poses)
        with clock("match"):
            match(db_path, pairs, out_dir, config, posed=poses is not None)
        log.info("%s: %d images, %d pairs matched", image_set.root, len(image_set.names),
                 len(pairs))
        with clock("map"):
            if poses is None:
                rec = map_incremental(image_set, db_path, out_dir, intrinsics, config, seed,
                                      console if progress else None)
                if intrinsics is None:
                    with clock("map_calibrated"):
                        rec = map_calibrated(image_set, db_path, out_dir, rec, pairs, config,
                                             seed, console if progress else None)
            else:
                rec = triangulate_known_poses(image_set, db_path, out_dir, intrinsics, poses,
                                              config, seed)
        focal = None
        if check_focal and intrinsics is not None and poses is None:
            with clock("focal_check"):
                focal = supported_focal(rec, config)
    if focal:
        log.info("%s: the given focal length %.2f px; the images support %.2f px (mean "
                 "reprojection error %.3f px freed, %.3f px given)", image_set.root,
                 focal["given_focal_px"], focal["supported_focal_px"],
                 focal["reprojection_free_px"], focal["reprojection_given_px"])
        check_given_focal(focal, config, f"SfM on {image_set.image_dir}")
    agreement = None
    if poses is not None:
        with clock("pose_check"):
            agreement = pose_agreement(rec, db_path)
        log.info("%s: given camera poses vs the images: verified matches %.2f px (median) from "
                 "the poses' epipolar lines, %.0f%% triangulated", image_set.root,
                 agreement["epipolar_median_px"] or float("nan"),
                 100 * (agreement["triangulated_share"] or 0.0))
        check_pose_agreement(agreement, config, f"camera poses of {image_set.image_dir}")
    model_dir = out_dir / "sparse" / "0"
    model_dir.mkdir(parents=True, exist_ok=True)
    rec.write(model_dir)
    log.info("%s: %d/%d images registered, %d points, reprojection error %.2f px",
             image_set.root, rec.num_reg_images(), len(image_set.names), rec.num_points3D(),
             rec.compute_mean_reprojection_error())
    return SfMResult(rec, db_path, image_set.image_dir, model_dir, len(image_set.names), timings,
                     agreement, focal)


def layout_error(result: SfMResult, poses: dict[str, np.ndarray]) -> float:
    """RMS distance between the SfM camera centres, aligned by a similarity (Umeyama), and the
    reference centres, as a fraction of the reference centres' RMS spread.

    Reprojection error cannot reveal a ring of cameras folded onto itself (every image registers
    at 0.1 px); this can, when the capture comes with reference poses.
    """
    T = result.T_world_camera()
    names = sorted(n for n in T if n in poses)
    if len(names) < 3:
        raise ValueError(f"layout_error: need 3 or more images with both poses, got {len(names)}")
    src = np.array([T[n][:3, 3] for n in names])
    dst = np.array([poses[n][:3, 3] for n in names])
    S = similarity_transform(src, dst)
    spread = np.sqrt(np.mean(np.sum((dst - dst.mean(0)) ** 2, axis=1)))
    return float(np.sqrt(np.mean(np.sum((S.apply(src) - dst) ** 2, axis=1))) / spread)
