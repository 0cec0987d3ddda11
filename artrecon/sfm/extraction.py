"""SIFT features of one image set into a fresh COLMAP database, and read back.

:func:`extract` writes ``OUT/database.db``: the camera (given, or one shared camera COLMAP
self-calibrates), an image per file and its keypoints and descriptors, by OpenCV's SIFT (the
default; see :class:`~artrecon.sfm.config.SfMConfig` ``extractor``) or COLMAP's.
:func:`read_features` reads keypoints and descriptors per image (the image pairs' retrieval, the
PnP registration).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pycolmap

from artrecon.errors import ReconstructionError
from artrecon.io import ImageSet, Intrinsics
from artrecon.sfm.config import SfMConfig


def colmap_descriptors(desc: np.ndarray) -> np.ndarray:
    """COLMAP's uint8 SIFT descriptors (L1-root normalised, x 512, rounded, capped at 255) from
    float SIFT descriptors (n, 128), as COLMAP's own extractor stores them."""
    d = np.maximum(np.asarray(desc, dtype=np.float64), 0.0)
    d /= np.maximum(d.sum(axis=1, keepdims=True), 1e-12)
    return np.minimum(np.rint(512.0 * np.sqrt(d)), 255).astype(np.uint8)


def _colmap_keypoints(kps, factor: float) -> np.ndarray:
    """COLMAP's keypoint rows (x, y, a11, a12, a21, a22), float32 (n, 6), from OpenCV keypoints
    found in an image scaled by ``factor``: the affine shape is the scale (half OpenCV's size)
    turned by the orientation, and COLMAP puts pixel centres at (0.5, 0.5), OpenCV at (0, 0)."""
    if len(kps) == 0:
        return np.zeros((0, 6), np.float32)
    pt = np.array([k.pt for k in kps], dtype=np.float64)
    size = np.array([k.size for k in kps], dtype=np.float64)
    angle = np.deg2rad(np.array([k.angle for k in kps], dtype=np.float64))
    scale = size / (2.0 * factor)
    c, s = scale * np.cos(angle), scale * np.sin(angle)
    return np.stack([(pt[:, 0] + 0.5) / factor, (pt[:, 1] + 0.5) / factor, c, -s, s, c],
                    axis=1).astype(np.float32)


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
            db.write_keypoints(img.image_id, _colmap_keypoints(kps, factor))
            db.write_descriptors(img.image_id, pycolmap.FeatureDescriptors(
                pycolmap.FeatureExtractorType.SIFT, colmap_descriptors(desc)))


def _write_images(image_set: ImageSet, database_path: Path, intrinsics: Intrinsics) -> None:
    """A new COLMAP database holding what COLMAP's extractor writes for a set taken with one
    known pinhole camera (``CameraMode.SINGLE``): the camera (its parameters rounded to 6
    decimals, as the extractor's reader parses them), a rig with it as the reference sensor, and
    one frame and image per file, numbered from 1 in ``image_set.names`` order."""
    width, height = image_set.size
    camera = pycolmap.Camera.create_from_model_name(
        1, "PINHOLE", 0.0, int(width), int(height))
    camera.params = [float(f"{v:.6f}") for v in intrinsics.params]
    camera.has_prior_focal_length = True
    with pycolmap.Database.open(database_path) as db:
        camera_id = db.write_camera(camera)
        camera.camera_id = camera_id
        rig = pycolmap.Rig()
        rig.add_ref_sensor(camera.sensor_id)
        rig_id = db.write_rig(rig)
        for name in image_set.names:
            image = pycolmap.Image(name=name, camera_id=camera_id)
            image_id = db.write_image(image)
            image.image_id = image_id
            frame = pycolmap.Frame()
            frame.rig_id = rig_id
            frame.add_data_id(image.data_id)
            db.write_frame(frame)


def extract(image_set: ImageSet, database_path: Path, intrinsics: Intrinsics | None,
            config: SfMConfig) -> None:
    """SIFT keypoints and descriptors of every image into a fresh COLMAP database.

    With ``config.extractor == "opencv"`` and known intrinsics the database's camera, rig,
    frames and images are written directly (:func:`_write_images`) and OpenCV's SIFT fills in
    the features. Otherwise COLMAP's extractor makes the database (focal length from EXIF when
    there is one); with ``"opencv"`` it runs on tiny images (the cost of reading them) and
    OpenCV's SIFT then replaces its features.
    """
    if config.extractor not in ("colmap", "opencv"):
        raise ValueError(f"SfMConfig.extractor: expected 'colmap' or 'opencv', got "
                         f"{config.extractor!r}")
    if database_path.exists():
        database_path.unlink()
    if config.extractor == "opencv" and intrinsics is not None:
        # the camera is known: no image to read for EXIF, so the database is written directly
        # (COLMAP's extractor would read and decode every image once more, ~3 s for 121 images)
        _write_images(image_set, database_path, intrinsics)
        _opencv_features(image_set, database_path, config)
        return
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
