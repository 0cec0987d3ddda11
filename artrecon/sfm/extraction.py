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


#: The corner of a feature box (:func:`region_boxes`) lies on a multiple of this many pixels:
#: SIFT halves the image from octave to octave, so a crop whose corner is a multiple of 2^k
#: pixels samples octave k (and those below it) on the whole image's grid.
BOX_ALIGN = 16


def region_boxes(region: np.ndarray, poses: dict[str, np.ndarray], intrinsics: Intrinsics,
                 size: tuple[int, int], margin: int) -> dict[str, tuple[int, int, int, int]]:
    """Per posed image, the pixel box ``(x0, y0, x1, y1)`` (x1, y1 exclusive) around the
    projection of the object's region, widened by ``margin`` pixels and clipped to the image.

    Parameters
    ----------
    region : (k, 3) float
        Points whose convex hull holds the object (world frame of ``poses``).
    poses : dict of str to (4, 4) float
        ``T_world_camera`` per image name (OpenCV).
    intrinsics : Intrinsics
    size : (width, height)
    margin : int

    Returns
    -------
    dict of str to (int, int, int, int)
        An image whose camera has a region point at or behind its image plane gets the whole
        image (the projection is unbounded there).
    """
    width, height = size
    K = intrinsics.K
    region = np.asarray(region, float)
    boxes = {}
    for name, T in poses.items():
        T_cw = np.linalg.inv(np.asarray(T, float))
        P = region @ T_cw[:3, :3].T + T_cw[:3, 3]
        if np.any(P[:, 2] <= 1e-6):
            boxes[name] = (0, 0, int(width), int(height))
            continue
        u = K[0, 0] * P[:, 0] / P[:, 2] + K[0, 2]
        v = K[1, 1] * P[:, 1] / P[:, 2] + K[1, 2]
        # the corner on a multiple of BOX_ALIGN: SIFT's octaves then sample the crop on the
        # whole image's grid, and a keypoint away from the box's edges is the whole image's
        x0 = int(np.clip(np.floor(u.min()) - margin, 0, width)) // BOX_ALIGN * BOX_ALIGN
        y0 = int(np.clip(np.floor(v.min()) - margin, 0, height)) // BOX_ALIGN * BOX_ALIGN
        x1 = int(np.clip(np.ceil(u.max()) + margin + 1, 0, width))
        y1 = int(np.clip(np.ceil(v.max()) + margin + 1, 0, height))
        boxes[name] = (x0, y0, x1, y1)
    return boxes


def sift_extractor(config: SfMConfig, features: int | None = None):
    """OpenCV's SIFT as :func:`extract` runs it (see :func:`_opencv_features`), keeping at most
    ``features`` keypoints (default ``config.max_num_features``)."""
    return cv2.SIFT_create(nfeatures=config.max_num_features if features is None else features,
                           contrastThreshold=config.opencv_contrast,
                           enable_precise_upscale=True)


def image_features(gray: np.ndarray, sift, config: SfMConfig,
                   box: tuple[int, int, int, int] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints of one grey image as COLMAP rows (n, 6) in the whole image's COLMAP pixel
    coordinates, and their float descriptors (n, 128); only inside ``box`` (x0, y0, x1, y1) when
    given. Images larger than ``config.max_image_size`` are searched downscaled."""
    factor = min(1.0, config.max_image_size / max(gray.shape))
    x0, y0, x1, y1 = box if box is not None else (0, 0, gray.shape[1], gray.shape[0])
    gray = np.ascontiguousarray(gray[y0:y1, x0:x1])
    if factor < 1.0 and gray.size:
        gray = cv2.resize(gray, None, fx=factor, fy=factor, interpolation=cv2.INTER_AREA)
    kps, desc = sift.detectAndCompute(gray, None) if gray.size else ((), None)
    if desc is None:
        kps, desc = (), np.zeros((0, 128), np.float32)
    rows = _colmap_keypoints(kps, factor)
    rows[:, 0] += x0
    rows[:, 1] += y0
    return rows, desc


def _opencv_features(image_set: ImageSet, database_path: Path, config: SfMConfig,
                     boxes: dict[str, tuple[int, int, int, int]] | None = None) -> None:
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
    and B, its axis 1.64 deg off the table normal.

    ``boxes`` (:func:`region_boxes`): an image named there is searched at full scale only inside
    its box (the crop's keypoints are put back into the whole image's pixel coordinates), and
    outside it only coarsely (:func:`_with_background`): the table and the room the base's
    motion is anchored to."""
    sift = sift_extractor(config)
    background = None
    if boxes is not None and config.background_features > 0:
        background = sift_extractor(config, config.background_features)
    with pycolmap.Database.open(database_path) as db:
        images = db.read_all_images()
        db.clear_keypoints()
        db.clear_descriptors()
        for img in images:
            path = image_set.image_dir / img.name
            gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if gray is None:
                raise ReconstructionError(f"cannot read image {path}")
            box = (boxes or {}).get(img.name)
            rows, desc = image_features(gray, sift, config, box)
            if box is not None and background is not None:
                rows, desc = _with_background(gray, box, rows, desc, background, config)
            db.write_keypoints(img.image_id, rows)
            db.write_descriptors(img.image_id, pycolmap.FeatureDescriptors(
                pycolmap.FeatureExtractorType.SIFT, colmap_descriptors(desc)))


def _with_background(gray, box, rows, desc, sift, config: SfMConfig):
    """``rows, desc`` and the features of the image scaled by ``config.background_scale`` that
    lie outside ``box`` (by more than the box's own features' reach, 8 px)."""
    f = config.background_scale
    small = cv2.resize(gray, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
    kps, d = sift.detectAndCompute(small, None)
    if d is None or not len(kps):
        return rows, desc
    r = _colmap_keypoints(kps, f)
    x0, y0, x1, y1 = box
    pad = 8
    out = ((r[:, 0] < x0 - pad) | (r[:, 0] > x1 + pad) | (r[:, 1] < y0 - pad)
           | (r[:, 1] > y1 + pad))
    return np.concatenate([rows, r[out]]), np.concatenate([desc, d[out]])


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
            config: SfMConfig, boxes: dict[str, tuple[int, int, int, int]] | None = None
            ) -> None:
    """SIFT keypoints and descriptors of every image into a fresh COLMAP database.

    With ``config.extractor == "opencv"`` and known intrinsics the database's camera, rig,
    frames and images are written directly (:func:`_write_images`) and OpenCV's SIFT fills in
    the features. Otherwise COLMAP's extractor makes the database (focal length from EXIF when
    there is one); with ``"opencv"`` it runs on tiny images (the cost of reading them) and
    OpenCV's SIFT then replaces its features.

    ``boxes`` (:func:`region_boxes`, OpenCV's extractor only): each image's features only
    inside its box, and up to ``config.background_features`` outside it, found in the image
    scaled by ``config.background_scale``.
    """
    if config.extractor not in ("colmap", "opencv"):
        raise ValueError(f"SfMConfig.extractor: expected 'colmap' or 'opencv', got "
                         f"{config.extractor!r}")
    if boxes is not None and config.extractor != "opencv":
        raise ValueError("extract: features inside the object's region (boxes) need "
                         "SfMConfig.extractor 'opencv'")
    if database_path.exists():
        database_path.unlink()
    if config.extractor == "opencv" and intrinsics is not None:
        # the camera is known: no image to read for EXIF, so the database is written directly
        # (COLMAP's extractor would read and decode every image once more, ~3 s for 121 images)
        _write_images(image_set, database_path, intrinsics)
        _opencv_features(image_set, database_path, config, boxes)
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
        _opencv_features(image_set, database_path, config, boxes)


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
