"""Structure from motion per configuration, with pycolmap.

Stage input: one checked image folder (:class:`artrecon.io.ImageSet`), optional intrinsics,
optional camera poses. Stage output: :class:`SfMResult` holding a ``pycolmap.Reconstruction``
(cameras, sparse points with their observing keypoints) written in COLMAP's folder layout
``OUT/sparse/0`` beside ``OUT/database.db`` (SIFT keypoints and descriptors, reused for the matches
across configurations) and ``OUT/colmap.log``.

Image pairs. Exhaustive matching costs n^2/2 pairs and, on repeated texture, can fold a ring of
cameras onto itself. We match instead a union of (a) a window of neighbours in file-name order
(captures are written in order) and (b) retrieval pairs: for each image the images sharing most
mutual nearest neighbours among a sample of its descriptors (a cheap stand-in for a vocabulary
tree; it also closes the loop of a ring). ``matching="exhaustive"`` is available for small sets.

Two modes:

* default, the method's: incremental SfM from the images alone (pose search).
* ``poses`` given (the arm's forward kinematics): the poses are held fixed, points are triangulated
  and refined by bundle adjustment; no pose search. Much faster, and metric.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pycolmap

from artrecon.errors import ReconstructionError
from artrecon.io import ImageSet, Intrinsics

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SfMConfig:
    """Settings of the SfM stage."""

    max_num_features: int = 4096
    """SIFT features per image (COLMAP default 8192; 4096 halves matching time at 640x480)."""
    max_image_size: int = 1600
    """Longer image side used for extraction; larger photos are downscaled."""
    first_octave: int = -1
    """SIFT's first octave (COLMAP default -1: the image is upsampled 2x first). 0 extracts ~3x
    faster (measured 0.28 -> 0.09 s per 640x480 image) but finds half the keypoints, and the
    small, flat links (pliers, scissors) already have the fewest cross-configuration matches."""
    matching: str = "auto"
    """'auto' (sequential window + retrieval pairs), 'exhaustive', or 'sequential' (window only)."""
    sequential_window: int = 4
    """Neighbours in file-name order matched with each image."""
    retrieval_neighbours: int = 8
    """Most similar images matched with each image (loop closure, second ring)."""
    retrieval_sample: int = 300
    """Descriptors per image used to score image similarity (cost grows with its square and
    with n^2 image pairs; 300 still ranks ring neighbours correctly)."""
    min_registered_fraction: float = 0.7
    """Fewer registered images than this share of the set is a failure (views would be missing)."""
    num_threads: int = -1
    """Threads for COLMAP (-1 = all cores)."""
    max_layout_error: float = 0.05
    """When reference poses exist (cameras.json) but SfM ran from the images, the SfM camera
    centres, aligned by a similarity, must match them within this fraction of the cameras' spread
    (a folded ring of cameras is far off; a good model is ~0.1% off)."""


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
    """

    reconstruction: pycolmap.Reconstruction
    database_path: Path
    image_dir: Path
    model_dir: Path
    num_images: int
    timings: dict = field(default_factory=dict)

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


def extract(image_set: ImageSet, database_path: Path, intrinsics: Intrinsics | None,
            config: SfMConfig) -> None:
    """SIFT keypoints and descriptors of every image into a fresh COLMAP database."""
    if database_path.exists():
        database_path.unlink()
    reader = pycolmap.ImageReaderOptions()
    if intrinsics is not None:
        reader.camera_model = "PINHOLE"
        reader.camera_params = ",".join(f"{v:.6f}" for v in intrinsics.params)
    else:
        reader.camera_model = "SIMPLE_RADIAL"
    ext = pycolmap.FeatureExtractionOptions()
    ext.max_image_size = config.max_image_size
    ext.num_threads = config.num_threads
    ext.sift.max_num_features = config.max_num_features
    ext.sift.first_octave = config.first_octave
    pycolmap.extract_features(database_path, image_set.image_dir, image_names=image_set.names,
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=ext, device=pycolmap.Device.cpu)


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


def select_pairs(names: list[str], features: dict, config: SfMConfig, seed: int = 0
                 ) -> list[tuple[str, str]]:
    """Image pairs to match: a window in name order plus retrieval neighbours (see module doc)."""
    n = len(names)
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
        raise ReconstructionError(f"triangulation with known poses on {image_set.image_dir} gave "
                                  "no points: check that the poses belong to these images "
                                  "(T_world_camera, OpenCV convention) and the intrinsics")
    return rec


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
        Known pinhole intrinsics, held fixed. Without them COLMAP estimates a SIMPLE_RADIAL camera.
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
        pairs = select_pairs(image_set.names, feats, config, seed)
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
        else:
            rec = _triangulate_known_poses(image_set, db_path, out_dir, intrinsics, poses, config,
                                           seed)
        timings["map"] = time.perf_counter() - t
    model_dir = out_dir / "sparse" / "0"
    model_dir.mkdir(parents=True, exist_ok=True)
    rec.write(model_dir)
    log.info("%s: %d/%d images registered, %d points, reprojection error %.2f px",
             image_set.root, rec.num_reg_images(), len(image_set.names), rec.num_points3D(),
             rec.compute_mean_reprojection_error())
    return SfMResult(rec, db_path, image_set.image_dir, model_dir, len(image_set.names), timings)


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
