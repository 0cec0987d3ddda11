"""Route (b), the paper's: a fresh image localised against the model (SIFT 2D-3D matches, PnP
with RANSAC), turned into model-to-robot by the flange pose and the hand-eye transform.

``T_robot_model = T_robot_flange(FK now) @ T_flange_camera @ S(s) T_camera_model``: PnP's
translation is in model units, so the metric scale ``s`` comes from elsewhere (the hand-eye
calibration with the scale unknown, :func:`artrecon.register.hand_eye.calibrate_hand_eye`; a known
length; or route (a)).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from artrecon.errors import InputError, ReconstructionError
from artrecon.geometry import pose
from artrecon.procrustes import Similarity
from artrecon.register._checks import _points

log = logging.getLogger(__name__)

#: Lowe's ratio test for SIFT matches (0.8 as in Lowe 2004: rejects 90% of false matches while
#: keeping 95% of correct ones).
SIFT_RATIO = 0.8
#: PnP RANSAC inlier threshold (pixels): SIFT keypoints are good to about a pixel; 4 px keeps them
#: at 640x480 while rejecting wrong matches.
PNP_REPROJECTION_PX = 4.0
#: PnP RANSAC iterations and confidence (OpenCV defaults are 100 / 0.99; matches against a whole
#: model can have < 30% inliers, so more iterations).
PNP_ITERATIONS = 2000
PNP_CONFIDENCE = 0.9999
#: Fewest PnP inliers accepted: 6 points over-determine the 6-DoF pose; fewer is chance.
PNP_MIN_INLIERS = 12


def sift_features(image, *, max_features: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints and descriptors of one image (OpenCV).

    Parameters
    ----------
    image : (h, w, 3) uint8 RGB or (h, w) uint8 grey
    max_features : int

    Returns
    -------
    keypoints : (m, 2) float
        Pixel coordinates (x, y), OpenCV convention (pixel centres at integers).
    descriptors : (m, 128) float32
    """
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(np.ascontiguousarray(img[:, :, :3]), cv2.COLOR_RGB2GRAY)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise ValueError(f"image must be (h, w, 3) or (h, w) uint8, got {img.shape} {img.dtype}")
    # precise upscaling: OpenCV's default places every keypoint +0.25 px off (see
    # artrecon.sfm.extraction._opencv_features)
    sift = cv2.SIFT_create(nfeatures=max_features, enable_precise_upscale=True)
    kps, desc = sift.detectAndCompute(img, None)
    if desc is None:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    return np.array([k.pt for k in kps], dtype=float), np.asarray(desc, dtype=np.float32)


def match_descriptors(query, train, ratio: float = SIFT_RATIO) -> np.ndarray:
    """Lowe-ratio matches of query descriptors to train descriptors.

    Parameters
    ----------
    query : (m, d) float
    train : (n, d) float

    Returns
    -------
    pairs : (k, 2) int
        (query index, train index).
    """
    q = np.ascontiguousarray(query, dtype=np.float32)
    t = np.ascontiguousarray(train, dtype=np.float32)
    if q.ndim != 2 or t.ndim != 2 or q.shape[1] != t.shape[1]:
        raise ValueError(f"descriptors must be (m, d) and (n, d) with the same d, got {q.shape} "
                         f"and {t.shape}")
    if len(q) == 0 or len(t) < 2:
        return np.zeros((0, 2), dtype=int)
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(q, t, k=2)
    out = [(m[0].queryIdx, m[0].trainIdx) for m in knn
           if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    return np.array(out, dtype=int).reshape(-1, 2)


@dataclass(frozen=True, eq=False)
class PnPResult:
    """Result of :func:`localize_image`.

    Attributes
    ----------
    T_camera_model : (4, 4) float
        Model to camera (OpenCV convention); translation in *model units*.
    matches : (k, 2) int
        (keypoint index, landmark index) descriptor matches.
    inliers : (k,) bool
        PnP RANSAC inliers among the matches.
    reprojection_rms : float
        RMS reprojection error of the inliers (px).
    """

    T_camera_model: np.ndarray
    matches: np.ndarray
    inliers: np.ndarray
    reprojection_rms: float


def localize_image(keypoints, descriptors, landmarks, landmark_descriptors, K, *,
                   ratio: float = SIFT_RATIO, reprojection_px: float = PNP_REPROJECTION_PX,
                   seed: int = 0) -> PnPResult:
    """Pose of a fresh image against the model: SIFT 2D-3D matches, PnP with RANSAC, LM refine.

    Parameters
    ----------
    keypoints : (m, 2) float
        Keypoints of the fresh image (pixels, OpenCV convention).
    descriptors : (m, 128) float
        Their descriptors.
    landmarks : (n, 3) float
        Model points (model frame and units) ...
    landmark_descriptors : (n, 128) float
        ... and one descriptor each (e.g. from :func:`landmarks_from_tracks`).
    K : (3, 3) float
        Intrinsics of the fresh image.
    ratio, reprojection_px : float
        Lowe ratio; RANSAC inlier threshold (px).
    seed : int
        Seeds OpenCV's RNG (RANSAC sampling) for a deterministic result.

    Returns
    -------
    PnPResult

    Raises
    ------
    ReconstructionError
        Fewer than ``PNP_MIN_INLIERS`` inliers.
    """
    kp = _points("keypoints", keypoints, 2)
    X = _points("landmarks", landmarks)
    desc = np.asarray(descriptors)
    ldesc = np.asarray(landmark_descriptors)
    if desc.shape[0] != len(kp):
        raise ValueError(f"descriptors must have {len(kp)} rows (one per keypoint), got "
                         f"{desc.shape}")
    if ldesc.shape[0] != len(X):
        raise ValueError(f"landmark_descriptors must have {len(X)} rows (one per landmark), got "
                         f"{ldesc.shape}")
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3):
        raise ValueError(f"K must have shape (3, 3), got {K.shape}")
    matches = match_descriptors(desc, ldesc, ratio)
    if len(matches) < PNP_MIN_INLIERS:
        raise ReconstructionError(
            f"PnP: only {len(matches)} descriptor matches between the image ({len(kp)} "
            f"keypoints) and the model ({len(X)} landmarks); need {PNP_MIN_INLIERS}. Take the "
            "image closer to a view of the capture, or give landmarks with descriptors")
    obj = np.ascontiguousarray(X[matches[:, 1]], dtype=np.float64)
    img = np.ascontiguousarray(kp[matches[:, 0]], dtype=np.float64)
    cv2.setRNGSeed(int(seed))
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        obj, img, K, None, iterationsCount=PNP_ITERATIONS, reprojectionError=reprojection_px,
        confidence=PNP_CONFIDENCE, flags=cv2.SOLVEPNP_EPNP)
    n_inl = 0 if inl is None else len(inl)
    if not ok or n_inl < PNP_MIN_INLIERS:
        raise ReconstructionError(
            f"PnP RANSAC found {n_inl} inliers among {len(matches)} matches (need "
            f"{PNP_MIN_INLIERS}); the image may not show the object or the model's descriptors "
            "do not come from similar views")
    idx = inl.reshape(-1)
    rvec, tvec = cv2.solvePnPRefineLM(obj[idx], img[idx], K, None, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    T = pose(R, tvec.reshape(3))
    proj = (obj @ R.T + tvec.reshape(3)) @ K.T
    proj = proj[:, :2] / proj[:, 2:3]
    err = np.linalg.norm(proj - img, axis=1)
    inliers = err < reprojection_px
    rms = float(np.sqrt(np.mean(err[inliers] ** 2))) if inliers.any() else float("nan")
    log.info("PnP: %d matches, %d inliers, %.2f px rms", len(matches), int(inliers.sum()), rms)
    return PnPResult(T, matches, inliers, rms)


def landmarks_from_tracks(points: dict, features: dict, image_names: dict
                          ) -> tuple[np.ndarray, np.ndarray]:
    """3D points with one descriptor each, from an SfM model's tracks.

    Works with pycolmap's data without importing it: ``points`` maps a point id to an object with
    ``.xyz`` and ``.track.elements`` (each with ``.image_id`` and ``.point2D_idx``) — i.e.
    ``reconstruction.points3D``; ``features`` is :func:`artrecon.sfm.read_features`'s
    ``{image name: (image_id, keypoints, descriptors)}``; ``image_names`` maps image id to name.
    The descriptor of a point is the mean of its observations' descriptors.

    Returns
    -------
    landmarks : (n, 3) float
    descriptors : (n, 128) float32
    """
    X, D = [], []
    for p in points.values():
        ds = []
        for el in p.track.elements:
            name = image_names.get(el.image_id)
            if name in features:
                desc = features[name][2]
                if el.point2D_idx < len(desc):
                    ds.append(np.asarray(desc[el.point2D_idx], dtype=np.float32))
        if ds:
            X.append(np.asarray(p.xyz, dtype=float))
            D.append(np.mean(ds, axis=0))
    if not X:
        raise InputError("no 3D point has an observation with a descriptor; pass the features "
                         "of the same database the reconstruction was built from")
    return np.array(X), np.array(D, dtype=np.float32)


def register_by_pnp(T_robot_flange_now, T_flange_camera, T_camera_model, scale: float
                    ) -> Similarity:
    """``T_robot_model`` from a fresh image's PnP pose, the hand-eye estimate and a metric scale.

    Parameters
    ----------
    T_robot_flange_now : (4, 4) float
        Flange pose from forward kinematics when the fresh image was taken (m).
    T_flange_camera : (4, 4) float
        Hand-eye estimate (m).
    T_camera_model : (4, 4) float
        PnP pose of the model in the camera, translation in model units.
    scale : float
        Metres per model unit.

    Returns
    -------
    T_robot_model : Similarity
    """
    G = np.asarray(T_robot_flange_now, dtype=float)
    X = np.asarray(T_flange_camera, dtype=float)
    P = np.asarray(T_camera_model, dtype=float)
    for name, T in (("T_robot_flange_now", G), ("T_flange_camera", X), ("T_camera_model", P)):
        if T.shape != (4, 4):
            raise ValueError(f"{name} must have shape (4, 4), got {T.shape}")
    if not scale > 0:
        raise ValueError(f"scale must be > 0 (metres per model unit), got {scale}")
    T_robot_camera = G @ X
    cam_from_model = Similarity(P[:3, :3], scale * P[:3, 3], scale)
    robot_from_cam = Similarity(T_robot_camera[:3, :3], T_robot_camera[:3, 3], 1.0)
    return robot_from_cam @ cam_from_model
