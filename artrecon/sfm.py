"""Structure from motion per configuration, with pycolmap.

Stage input: one checked image folder (:class:`artrecon.io.ImageSet`), optional intrinsics,
optional camera poses. Stage output: :class:`SfMResult` holding a ``pycolmap.Reconstruction``
(cameras, sparse points with their observing keypoints) written in COLMAP's folder layout
``OUT/sparse/0`` beside ``OUT/database.db`` (SIFT keypoints and descriptors, reused for the matches
across configurations) and ``OUT/colmap.log`` (and ``OUT/calibration.json`` when the focal length
was not given: see :func:`_map_calibrated`).

Image pairs. Exhaustive matching costs n^2/2 pairs and, on repeated texture, can fold a ring of
cameras onto itself. With camera poses (the arm's forward kinematics) each image is matched with
the images whose optical axes are nearest to its own (:func:`pose_pairs`: the views that overlap,
neighbours on a ring and across rings). Without poses we match a union of (a) a window of
neighbours in file-name order (captures are written in order) and (b) retrieval pairs: for each
image the images sharing most mutual nearest neighbours among a sample of its descriptors (a
cheap stand-in for a vocabulary tree; it also closes the loop of a ring).
``matching="exhaustive"`` is available for small sets.

Two modes:

* default, the method's: incremental SfM from the images alone (pose search).
* ``poses`` given (the arm's forward kinematics): the poses are held fixed, points are triangulated
  and refined by bundle adjustment; no pose search. Much faster, and metric. The poses are then
  checked against the images (:func:`pose_agreement`: epipolar distance of the verified matches,
  share that triangulates); poses that disagree, as a camera mount (hand-eye) error or encoder
  errors make them, are refused with a :class:`~artrecon.errors.PoseMismatchError`: wrong
  cameras would give a wrong model without any error.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pycolmap

from artrecon.errors import PoseMismatchError, ReconstructionError
from artrecon.files import write_json_atomic
from artrecon.io import ImageSet, Intrinsics

log = logging.getLogger(__name__)

#: Written into the SfM folder by the self-calibration (:func:`_map_calibrated`): where the focal
#: length came from (EXIF or self-calibrated), its starting value and the converged one.
CALIBRATION_FILE = "calibration.json"


@dataclass(frozen=True)
class SfMConfig:
    """Settings of the SfM stage."""

    max_num_features: int = 4096
    """SIFT features per image (COLMAP default 8192; 4096 halves matching time at 640x480)."""
    max_image_size: int = 1600
    """Longer image side used for extraction; larger photos are downscaled."""
    extractor: str = "opencv"
    """SIFT implementation: ``"opencv"`` (OpenCV's ``SIFT_create``, written into the same COLMAP
    database; see :func:`extract`) or ``"colmap"`` (COLMAP's, on the CPU). Measured on a pliers
    capture (121 images, one core, under load): COLMAP's 140 s against OpenCV's 63 s, for 14351
    and 13406 triangulated points."""
    opencv_contrast: float = 0.02
    """OpenCV SIFT's contrast threshold (its default 0.04 keeps about 60% of the keypoints of
    COLMAP's peak threshold on the bundled scenes; 0.02 about as many)."""
    first_octave: int = -1
    """SIFT's first octave (COLMAP default -1: the image is upsampled 2x first). 0 extracts ~3x
    faster (measured 0.28 -> 0.09 s per 640x480 image) but finds half the keypoints, and the
    small, flat links (pliers, scissors) already have the fewest cross-configuration matches."""
    matching: str = "auto"
    """'auto' (with camera poses: :func:`pose_pairs`; without: sequential window + retrieval
    pairs), 'exhaustive', or 'sequential' (window only)."""
    pose_neighbours: int = 8
    """With camera poses: images matched with each image, those whose optical axes are nearest
    (8: on the default rings, 10 degrees apart, the two neighbours on each side and the nearest
    views of the rings above and below)."""
    pose_max_angle_deg: float = 35.0
    """With camera poses: no pair whose optical axes are further apart than this (SIFT matches
    thin out beyond ~30 degrees of viewpoint change)."""
    sequential_window: int = 4
    """Neighbours in file-name order matched with each image."""
    retrieval_neighbours: int = 8
    """Most similar images matched with each image (loop closure, second ring)."""
    retrieval_sample: int = 300
    """Descriptors per image used to score image similarity (cost grows with its square and
    with n^2 image pairs; 300 still ranks ring neighbours correctly)."""
    min_registered_fraction: float = 0.7
    """Fewer registered images than this share of the set is a failure (views would be missing)."""
    num_threads: int = 1
    """Threads for COLMAP (-1 = all cores). One: COLMAP's geometric verification runs its
    RANSAC per thread, so with several the inlier sets (and every later figure) change from run
    to run (measured: 14051-14056 points of the same images); the reconstruction runs the two
    configurations side by side instead (:func:`artrecon.reconstruct.reconstruct`, ``jobs``)."""
    max_layout_error: float = 0.05
    """When reference poses exist (cameras.json) but SfM ran from the images, the SfM camera
    centres, aligned by a similarity, must match them within this fraction of the cameras' spread
    (a folded ring of cameras is far off; a good model is ~0.1% off)."""
    max_pose_epipolar_px: float = 0.45
    """Given camera poses (known-pose triangulation) are refused when the images' verified
    two-view matches of either configuration lie further than this (median Sampson distance,
    pixels) from the epipolar lines the poses predict (:func:`pose_agreement`). The known-pose
    path needs poses about as exact as the images: measured with ``python -m sim.evaluate pliers
    --views 18 --use-poses`` (640x480, 60 images per set) and sim.perturb's errors of the arm's
    poses (figures for A / B): exact poses 0.13 / 0.13 px (0.09-0.14 on cabinet, barrett_hand,
    scissors, pliers_panda); good models at 0.39 / 0.36 px (encoder noise 0.02 deg, axis 0.6 deg)
    and 0.50 / 0.51 (1 mm / 0.2 deg mount error, 0.7 deg); wrong axes without any error at
    0.51 / 0.46 (2 mm / 0.4 deg, seed 1: 3.5 deg), 0.89 / 0.79 (encoder 0.05 deg: 3.2 deg) and
    1.32 / 1.39 (5 mm / 1 deg, seed 2: 7.4 deg), while 5 mm / 1 deg gave good axes at seeds 0
    and 1 (2.2 and 1.1 px): from ~0.5 px on, the answer is a coin toss. 0.45 px refuses every
    wrong answer measured and keeps the 0.39 px one (the 1 mm mount error is refused too)."""
    min_pose_triangulated_share: float = 0.8
    """... or when fewer than this share of those matches end in one triangulated 3D point
    (COLMAP keeps a track only within 4 px of every view): a second, coarser sign of the same.
    Same runs: 0.95-0.97 with exact poses and up to 0.5 px; 0.92-0.94 at 0.5-0.9 px; 0.44-0.69
    at 1-2.3 px; below 0.4 beyond (encoder noise 0.1 deg and more, mount errors of 10 mm and
    more)."""
    suspect_pose_epipolar_px: float = 0.3
    """Given poses that pass the check but agree with the images worse than this (median
    epipolar distance, pixels; 2.3 x the 0.13 px of exact poses) are named as the likely cause
    when segmentation or a joint's evidence fails later
    (:func:`artrecon.reconstruct.blame_poses`)."""


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
        With given camera poses: how well they agree with the images (:func:`pose_agreement`).
    """

    reconstruction: pycolmap.Reconstruction
    database_path: Path
    image_dir: Path
    model_dir: Path
    num_images: int
    timings: dict = field(default_factory=dict)
    pose_agreement: dict | None = None

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


def colmap_descriptors(desc: np.ndarray) -> np.ndarray:
    """COLMAP's uint8 SIFT descriptors (L1-root normalised, x 512, rounded, capped at 255) from
    float SIFT descriptors (n, 128), as COLMAP's own extractor stores them."""
    d = np.maximum(np.asarray(desc, dtype=np.float64), 0.0)
    d /= np.maximum(d.sum(axis=1, keepdims=True), 1e-12)
    return np.minimum(np.rint(512.0 * np.sqrt(d)), 255).astype(np.uint8)


def _opencv_features(image_set: ImageSet, database_path: Path, config: SfMConfig) -> None:
    """Replace the keypoints and descriptors of every image of a COLMAP database by OpenCV's
    SIFT (upsampled first octave, as COLMAP's first_octave -1): about as many keypoints as
    COLMAP's at a third of its time on one core.

    The upsampling is OpenCV's precise one (``enable_precise_upscale``): by default OpenCV doubles
    the image with pixel centres aligned but halves the keypoints' coordinates as if the corners
    were, so every keypoint lies +0.25 px off in x and y (measured: 0.24 px against the precise
    upscale on a pliers image; 0.24 / 0.26 px fitted from the table's points at their true
    height). With known poses that shift is a small tilt of every ray, which a point seen from
    one side only (the edges and sides of a thin link) turns into a 3D error that differs
    between the configurations: the pliers' handle rolled 0.85 deg about its length between A
    and B, its axis 1.64 deg off the table normal."""
    sift = cv2.SIFT_create(nfeatures=config.max_num_features,
                           contrastThreshold=config.opencv_contrast,
                           enable_precise_upscale=True)
    with pycolmap.Database.open(database_path) as db:
        images = db.read_all_images()
        db.clear_keypoints()
        db.clear_descriptors()
        for img in images:
            path = image_set.image_dir / img.name
            gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if gray is None:
                raise ReconstructionError(f"cannot read image {path}")
            factor = min(1.0, config.max_image_size / max(gray.shape))
            if factor < 1.0:
                gray = cv2.resize(gray, None, fx=factor, fy=factor, interpolation=cv2.INTER_AREA)
            kps, desc = sift.detectAndCompute(gray, None)
            if desc is None:
                kps, desc = (), np.zeros((0, 128), np.float32)
            kp = np.zeros((len(kps), 6), np.float32)
            for i, k in enumerate(kps):
                scale, angle = k.size / (2.0 * factor), np.deg2rad(k.angle)
                c, s_ = scale * np.cos(angle), scale * np.sin(angle)
                # COLMAP puts pixel centres at (0.5, 0.5), OpenCV at (0, 0)
                kp[i] = ((k.pt[0] + 0.5) / factor, (k.pt[1] + 0.5) / factor, c, -s_, s_, c)
            db.write_keypoints(img.image_id, kp)
            db.write_descriptors(img.image_id, pycolmap.FeatureDescriptors(
                pycolmap.FeatureExtractorType.SIFT, colmap_descriptors(desc)))


def extract(image_set: ImageSet, database_path: Path, intrinsics: Intrinsics | None,
            config: SfMConfig) -> None:
    """SIFT keypoints and descriptors of every image into a fresh COLMAP database.

    COLMAP's extractor always makes the database (cameras, rigs, frames, images; focal length
    from EXIF when there is one). With ``config.extractor == "opencv"`` it runs on tiny images
    (the cost of reading them) and OpenCV's SIFT then replaces its features.
    """
    if config.extractor not in ("colmap", "opencv"):
        raise ValueError(f"SfMConfig.extractor: expected 'colmap' or 'opencv', got "
                         f"{config.extractor!r}")
    if database_path.exists():
        database_path.unlink()
    reader = pycolmap.ImageReaderOptions()
    if intrinsics is not None:
        reader.camera_model = "PINHOLE"
        reader.camera_params = ",".join(f"{v:.6f}" for v in intrinsics.params)
    else:
        # Self-calibration: one camera shared by all images (CameraMode.SINGLE below), its
        # focal length from EXIF when the photos have one, else COLMAP's guess of 1.2 x the
        # longer side, refined by bundle adjustment; the principal point stays at the centre.
        # A pinhole (SIMPLE_PINHOLE), the model the dense stage rectifies with: with
        # SIMPLE_RADIAL, COLMAP gave undistorted captures (pliers, 12 views per ring) a radial
        # term of 0.0019 that the poses absorbed, so the pinhole camera the dense stage uses
        # put the sparse points 0.74 px (median; 1.7 px at the 90th percentile) from their
        # keypoints, against 0.45 px in COLMAP's own model. (Photos with strong lens
        # distortion need undistorting first, or their intrinsics given.)
        reader.camera_model = "SIMPLE_PINHOLE"
    ext = pycolmap.FeatureExtractionOptions()
    ext.max_image_size = config.max_image_size
    ext.num_threads = config.num_threads
    ext.sift.max_num_features = config.max_num_features
    ext.sift.first_octave = config.first_octave
    if config.extractor == "opencv":
        ext.max_image_size = 32
        ext.sift.first_octave = 0
    pycolmap.extract_features(database_path, image_set.image_dir, image_names=image_set.names,
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=ext, device=pycolmap.Device.cpu)
    if config.extractor == "opencv":
        _opencv_features(image_set, database_path, config)


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


def read_features(database_path: Path) -> dict[str, tuple[int, np.ndarray, np.ndarray]]:
    """Per image name: (image_id, keypoints (n, 2) xy in OpenCV pixels, descriptors (n, 128) u8)."""
    out = {}
    with pycolmap.Database.open(database_path) as db:
        for img in db.read_all_images():
            kp = np.asarray(db.read_keypoints(img.image_id))[:, :2] - 0.5
            desc = db.read_descriptors(img.image_id)
            desc = np.asarray(desc.data if hasattr(desc, "data") else desc)
            out[img.name] = (img.image_id, kp, desc)
    return out


def pose_pairs(names: list[str], poses: dict[str, np.ndarray], config: SfMConfig
               ) -> list[tuple[str, str]]:
    """Image pairs from camera poses: each image with the ``config.pose_neighbours`` images
    whose optical axes are nearest to its own, within ``config.pose_max_angle_deg``.

    Parameters
    ----------
    names : list of str
        Images with a pose (in matching order).
    poses : dict of str to (4, 4) float
        ``T_world_camera`` per image (OpenCV: the optical axis is the third column).

    Returns
    -------
    list of (str, str)
        Each unordered pair once, in name order.
    """
    if len(names) < 2:
        return []
    axes = np.array([poses[n][:3, 2] for n in names], dtype=float)
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    cos = np.clip(axes @ axes.T, -1.0, 1.0)
    np.fill_diagonal(cos, -np.inf)
    min_cos = np.cos(np.deg2rad(config.pose_max_angle_deg))
    pairs = set()
    k = min(config.pose_neighbours, len(names) - 1)
    for i in range(len(names)):
        for j in np.argsort(-cos[i], kind="stable")[:k]:
            if cos[i, j] >= min_cos:
                pairs.add((min(i, int(j)), max(i, int(j))))
    return [(names[i], names[j]) for i, j in sorted(pairs)]


def select_pairs(names: list[str], features: dict, config: SfMConfig, seed: int = 0,
                 poses: dict[str, np.ndarray] | None = None) -> list[tuple[str, str]]:
    """Image pairs to match: from the poses when given (:func:`pose_pairs`), else a window in
    name order plus retrieval neighbours (see the module docstring)."""
    n = len(names)
    if config.matching == "auto" and poses is not None:
        posed = [name for name in names if name in poses]
        return pose_pairs(posed, poses, config)
    if config.matching == "exhaustive":
        return [(names[i], names[j]) for i in range(n) for j in range(i + 1, n)]
    pairs = set()
    for i in range(n):
        for d in range(1, config.sequential_window + 1):
            if i + d < n:
                pairs.add((i, i + d))
    if config.matching == "auto":
        rng = np.random.default_rng(seed)
        samples = []
        for name in names:
            desc = features[name][2].astype(np.float32)
            if len(desc) > config.retrieval_sample:
                desc = desc[rng.choice(len(desc), config.retrieval_sample, replace=False)]
            desc /= np.linalg.norm(desc, axis=1, keepdims=True) + 1e-9
            samples.append(desc)
        score = np.zeros((n, n))
        for i in range(n):
            for j in range(i + 1, n):
                if len(samples[i]) == 0 or len(samples[j]) == 0:
                    continue
                sim = samples[i] @ samples[j].T
                a = sim.argmax(1)
                b = sim.argmax(0)
                mutual = b[a] == np.arange(len(a))
                good = mutual & (sim[np.arange(len(a)), a] > 0.85)
                score[i, j] = score[j, i] = good.sum()
        for i in range(n):
            for j in np.argsort(-score[i])[: config.retrieval_neighbours]:
                if j != i and score[i, j] > 0:
                    pairs.add((min(i, j), max(i, j)))
    elif config.matching != "sequential":
        raise ValueError(f"SfMConfig.matching: expected 'auto', 'exhaustive' or 'sequential', "
                         f"got {config.matching!r}")
    return [(names[i], names[j]) for i, j in sorted(pairs)]


def match(database_path: Path, pairs: list[tuple[str, str]], out_dir: Path,
          config: SfMConfig) -> None:
    """Match SIFT features of the listed pairs and verify them geometrically."""
    pairs_file = out_dir / "pairs.txt"
    pairs_file.write_text("".join(f"{a} {b}\n" for a, b in pairs))
    mopt = pycolmap.FeatureMatchingOptions()
    mopt.num_threads = config.num_threads
    popt = pycolmap.ImportedPairingOptions()
    popt.match_list_path = str(pairs_file)
    pycolmap.match_image_pairs(database_path, matching_options=mopt, pairing_options=popt,
                               device=pycolmap.Device.cpu)


def _mapping_options(intrinsics: Intrinsics | None, config: SfMConfig, seed: int
                     ) -> pycolmap.IncrementalPipelineOptions:
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = config.num_threads
    opts.random_seed = seed
    opts.mapper.random_seed = seed
    opts.triangulation.random_seed = seed
    if intrinsics is not None:
        opts.ba_refine_focal_length = False
        opts.ba_refine_principal_point = False
        opts.ba_refine_extra_params = False
        opts.mapper.abs_pose_refine_focal_length = False
        opts.mapper.abs_pose_refine_extra_params = False
    return opts


def _map_incremental(image_set: ImageSet, database_path: Path, out_dir: Path,
                     intrinsics: Intrinsics | None, config: SfMConfig, seed: int,
                     progress) -> pycolmap.Reconstruction:
    opts = _mapping_options(intrinsics, config, seed)
    work = out_dir / "mapping"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    bar = None
    if progress:
        from tqdm import tqdm

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


def _map_calibrated(image_set: ImageSet, database_path: Path, out_dir: Path,
                    first: pycolmap.Reconstruction, pairs: list[tuple[str, str]],
                    config: SfMConfig, seed: int, progress) -> pycolmap.Reconstruction:
    """Self-calibration, second pass: incremental mapping again, the focal length held at the
    value the first pass (:func:`_map_incremental` with the focal length refined) converged to.

    The first pass starts from EXIF or COLMAP's guess of 1.2 x the longer side (768 px for 640 x
    480 images whose focal length is 554 px) and refines it, but the points it triangulated and
    filtered while the focal length was unknown stay lost, and the two-view geometries were
    verified without a calibration (fundamental matrices): on pliers captures at 12 views per
    ring it kept 3959 points, 195 on the object, and the run failed for lack of matches (84).
    So the database's camera takes the converged focal length as known, the image pairs are
    verified again with it (essential matrices; the SIFT matches are kept), and mapping runs
    with it held fixed, as with a known focal length: 4310 points, 352 on the object.
    """
    cameras = list(first.cameras.values())
    if len(cameras) != 1:
        return first
    camera = cameras[0]
    K = np.asarray(camera.calibration_matrix(), dtype=float)
    K[0, 2] -= 0.5  # COLMAP centres the top-left pixel at (0.5, 0.5); OpenCV at (0, 0)
    K[1, 2] -= 0.5
    log.info("%s: self-calibrated focal length %.2f px; mapping again with it held fixed",
             image_set.root, camera.mean_focal_length())
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
    return _map_incremental(image_set, database_path, out_dir, Intrinsics(K, image_set.size),
                            config, seed, progress)


def _triangulate_known_poses(image_set: ImageSet, database_path: Path, out_dir: Path,
                             intrinsics: Intrinsics, poses: dict[str, np.ndarray],
                             config: SfMConfig, seed: int) -> pycolmap.Reconstruction:
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
    opts = _mapping_options(intrinsics, config, seed)
    work = out_dir / "triangulation"
    work.mkdir(parents=True, exist_ok=True)
    rec = pycolmap.triangulate_points(rec, database_path, image_set.image_dir, work,
                                      clear_points=True, options=opts, refine_intrinsics=False)
    shutil.rmtree(work, ignore_errors=True)
    if rec.num_points3D() == 0:
        raise PoseMismatchError(
            f"triangulation with the given camera poses on {image_set.image_dir} gave no points: "
            "the poses do not agree with the images. Check that the poses belong to these images "
            "(T_world_camera, OpenCV convention) and the intrinsics, or run without the poses "
            "(without --use-poses) so SfM recovers the cameras from the images.")
    return rec


def pose_agreement(reconstruction: pycolmap.Reconstruction, database_path: Path) -> dict:
    """How well a reconstruction's camera poses agree with the images' own two-view geometry.

    The verified matches of each image pair (COLMAP's two-view geometries, RANSAC inliers of the
    images alone) must lie on the epipolar lines that the poses predict; with poses fixed to wrong
    values they do not, and COLMAP's triangulation (which keeps a track only within a few pixels
    of every view) drops them. Both are measured; neither needs the poses to be right.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
        Images with poses (held fixed) and triangulated points.
    database_path : Path
        The COLMAP database the reconstruction was triangulated from (keypoints, two-view
        geometries).

    Returns
    -------
    dict
        ``epipolar_median_px``, ``epipolar_p90_px``: Sampson distance (pixels) of the verified
        matches to the poses' epipolar geometry; ``triangulated_share``: share of those matches
        whose two keypoints belong to one triangulated 3D point; ``reprojection_mean_px`` of the
        kept points; ``pairs``, ``matches`` counted.
    """
    rec = reconstruction
    posed = {i for i in rec.reg_image_ids() if rec.images[i].has_pose}
    point_of: dict[int, np.ndarray] = {}
    for i in posed:
        point_of[i] = np.full(rec.images[i].num_points2D(), -1, dtype=np.int64)
    for pid, point in rec.points3D.items():
        for el in point.track.elements:
            if el.image_id in point_of:
                point_of[el.image_id][el.point2D_idx] = pid
    errors, together = [], []
    pairs = 0
    with pycolmap.Database.open(database_path) as db:
        keypoints: dict[int, np.ndarray] = {}

        def rays(image_id: int, idx: np.ndarray) -> np.ndarray:
            if image_id not in keypoints:
                cam = rec.cameras[rec.images[image_id].camera_id]
                xy = np.asarray(db.read_keypoints(image_id), dtype=float)[:, :2]
                keypoints[image_id] = np.c_[cam.cam_from_img(xy), np.ones(len(xy))]
            return keypoints[image_id][idx]

        pair_ids, geometries = db.read_two_view_geometries()
        for pair_id, geometry in zip(pair_ids, geometries, strict=True):
            m = np.asarray(geometry.inlier_matches, dtype=np.int64).reshape(-1, 2)
            i1, i2 = pycolmap.pair_id_to_image_pair(pair_id)
            if len(m) == 0 or i1 not in posed or i2 not in posed:
                continue
            T1 = rec.images[i1].cam_from_world().matrix()
            T2 = rec.images[i2].cam_from_world().matrix()
            R = T2[:, :3] @ T1[:, :3].T  # cam2_from_cam1
            t = T2[:, 3] - R @ T1[:, 3]
            if np.linalg.norm(t) < 1e-12:  # no baseline: no epipolar constraint
                continue
            t = t / np.linalg.norm(t)
            E = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ R
            x1, x2 = rays(i1, m[:, 0]), rays(i2, m[:, 1])
            Ex1, Etx2 = x1 @ E.T, x2 @ E
            num = np.sum(x2 * Ex1, axis=1) ** 2
            den = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
            f = 0.5 * (rec.cameras[rec.images[i1].camera_id].mean_focal_length()
                       + rec.cameras[rec.images[i2].camera_id].mean_focal_length())
            errors.append(f * np.sqrt(num / np.maximum(den, 1e-300)))
            p1, p2 = point_of[i1][m[:, 0]], point_of[i2][m[:, 1]]
            together.append((p1 >= 0) & (p1 == p2))
            pairs += 1
    if not errors:
        return {"pairs": 0, "matches": 0, "epipolar_median_px": None, "epipolar_p90_px": None,
                "triangulated_share": None,
                "reprojection_mean_px": float(rec.compute_mean_reprojection_error())}
    err = np.concatenate(errors)
    return {"pairs": pairs, "matches": int(len(err)),
            "epipolar_median_px": float(np.median(err)),
            "epipolar_p90_px": float(np.percentile(err, 90)),
            "triangulated_share": float(np.concatenate(together).mean()),
            "reprojection_mean_px": float(rec.compute_mean_reprojection_error())}


def check_pose_agreement(agreement: dict, config: SfMConfig, where) -> None:
    """Refuse given camera poses that disagree with the images (:func:`pose_agreement`).

    Raises
    ------
    PoseMismatchError
        The median epipolar distance is above ``config.max_pose_epipolar_px`` or the share of
        matches that triangulate is below ``config.min_pose_triangulated_share``. The message
        gives the figures, the likely cause and what to do.
    """
    epi, share = agreement.get("epipolar_median_px"), agreement.get("triangulated_share")
    if epi is None:
        raise PoseMismatchError(
            f"{where}: no image pair with verified matches between two posed images, so the given "
            "camera poses cannot be checked against the images. Check that the poses belong to "
            "these images, or run without the poses (without --use-poses) so SfM recovers the "
            "cameras from the images.", agreement)
    bad_epi = epi > config.max_pose_epipolar_px
    bad_share = share < config.min_pose_triangulated_share
    if not (bad_epi or bad_share):
        return
    raise PoseMismatchError(
        f"{where}: the given camera poses do not agree with the images, refused rather than "
        f"reconstructed from wrong cameras: the images' verified feature matches "
        f"({agreement['matches']} in {agreement['pairs']} image pairs) lie a median "
        f"{epi:.2f} px from the epipolar lines the poses predict (limit "
        f"{config.max_pose_epipolar_px:g} px; exact poses give ~0.1 px), and "
        f"{100 * share:.0f}% of them triangulate into a 3D point (need "
        f"{100 * config.min_pose_triangulated_share:.0f}%; exact poses ~95%). Likely cause: a "
        "hand-eye (camera mount) calibration error or arm encoder errors, or poses that belong "
        "to other images or another convention (T_world_camera, OpenCV). What to do: recalibrate "
        "the camera mount (hand-eye) and the arm, or run without the poses (without "
        "--use-poses): SfM then recovers the cameras from the images, and the robot's camera "
        "positions only give the scale and the world frame.", agreement)


def run_sfm(image_set: ImageSet, out_dir: str | Path, intrinsics: Intrinsics | None = None,
            poses: dict[str, np.ndarray] | None = None, config: SfMConfig = SfMConfig(),
            seed: int = 0, progress: bool = True) -> SfMResult:
    """Cameras and sparse points of one configuration.

    Parameters
    ----------
    image_set : ImageSet
    out_dir : str or Path
        Working folder; receives ``database.db``, ``pairs.txt``, ``colmap.log``, ``sparse/0``.
    intrinsics : Intrinsics, optional
        Known pinhole intrinsics, held fixed. Without them COLMAP self-calibrates one
        SIMPLE_PINHOLE camera shared by all images (focal length from EXIF or guessed, refined;
        see :func:`extract` and :func:`camera_summary`).
    poses : dict of str to (4, 4) float, optional
        ``T_world_camera`` per image name (OpenCV). Given, the poses are held fixed and only
        points are triangulated and refined (requires ``intrinsics``).
    config : SfMConfig
    seed : int
    progress : bool
        Show a tqdm bar fed from COLMAP's mapping callbacks.

    Returns
    -------
    SfMResult

    Raises
    ------
    ReconstructionError
        Too few images registered, or the images split into several models.
    PoseMismatchError
        Given ``poses`` that disagree with the images (:func:`check_pose_agreement`).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if poses is not None and intrinsics is None:
        raise ValueError("run_sfm: known poses need known intrinsics too")
    pycolmap.set_random_seed(seed)
    timings = {}
    db_path = out_dir / "database.db"
    with colmap_log(out_dir / "colmap.log") as console:
        t = time.perf_counter()
        extract(image_set, db_path, intrinsics, config)
        timings["extract"] = time.perf_counter() - t
        t = time.perf_counter()
        feats = read_features(db_path)
        pairs = select_pairs(image_set.names, feats, config, seed, poses)
        timings["pairs"] = time.perf_counter() - t
        t = time.perf_counter()
        match(db_path, pairs, out_dir, config)
        timings["match"] = time.perf_counter() - t
        log.info("%s: %d images, %d pairs matched", image_set.root, len(image_set.names),
                 len(pairs))
        t = time.perf_counter()
        if poses is None:
            rec = _map_incremental(image_set, db_path, out_dir, intrinsics, config, seed,
                                   console if progress else None)
            if intrinsics is None:
                rec = _map_calibrated(image_set, db_path, out_dir, rec, pairs, config, seed,
                                      console if progress else None)
                timings["map_calibrated"] = time.perf_counter() - t
        else:
            rec = _triangulate_known_poses(image_set, db_path, out_dir, intrinsics, poses, config,
                                           seed)
        timings["map"] = time.perf_counter() - t
    agreement = None
    if poses is not None:
        t = time.perf_counter()
        agreement = pose_agreement(rec, db_path)
        timings["pose_check"] = time.perf_counter() - t
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
                     agreement)


def layout_error(result: SfMResult, poses: dict[str, np.ndarray]) -> float:
    """RMS distance between the SfM camera centres, aligned by a similarity (Umeyama), and the
    reference centres, as a fraction of the reference centres' RMS spread.

    Reprojection error cannot reveal a ring of cameras folded onto itself (every image registers
    at 0.1 px); this can, when the capture comes with reference poses.
    """
    from artrecon.procrustes import similarity_transform

    T = result.T_world_camera()
    names = sorted(n for n in T if n in poses)
    if len(names) < 3:
        raise ValueError(f"layout_error: need 3 or more images with both poses, got {len(names)}")
    src = np.array([T[n][:3, 3] for n in names])
    dst = np.array([poses[n][:3, 3] for n in names])
    S = similarity_transform(src, dst)
    spread = np.sqrt(np.mean(np.sum((dst - dst.mean(0)) ** 2, axis=1)))
    return float(np.sqrt(np.mean(np.sum((S.apply(src) - dst) ** 2, axis=1))) / spread)
