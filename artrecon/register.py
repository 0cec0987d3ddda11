"""Registration: metric scale and the robot frame of a reconstructed model.

The reconstruction lives in the SfM frame of configuration A, in arbitrary units. The arm needs it
in its own frame (the "robot" frame: the frame the arm's forward kinematics report poses in), in
metres. Two independent routes are implemented and can be cross-checked on the same data:

(a) :func:`register_camera_centres` — the method's capture gives, for every image, the camera
    centre in the SfM model (``C_model``) and the camera pose from the arm's forward kinematics
    (``C_robot``). The similarity ``C_robot ~ s R C_model + t`` (Umeyama inside a 3-point RANSAC,
    then refitted on the inliers) is ``T_robot_model``: its scale is the metric scale (metres per
    model unit). A few badly registered cameras are rejected as outliers.

(b) the paper's route, :func:`register_by_pnp`:

    1. hand-eye calibration (:func:`calibrate_hand_eye`): from the capture's pairs (flange pose
       from FK, camera pose from SfM) the camera-to-flange transform ``T_flange_camera`` is
       *estimated* (AX = XB), not read from the robot model;
    2. a fresh image from the arm's current pose: SIFT keypoints (:func:`sift_features`) matched to
       the model's 3D points by descriptor, PnP with RANSAC (:func:`localize_image`) gives
       ``T_camera_model`` — up to the model's scale: PnP's translation is in model units;
    3. ``T_robot_model = T_robot_flange(FK now) @ T_flange_camera @ S(s) T_camera_model``.

    Route (b) needs the metric scale ``s`` from elsewhere: monocular images cannot give it. Pass a
    known length (``metric_scale_from_length``: a distance measured on the object, in metres,
    divided by the same distance in the model) or the scale of route (a). Hand-eye calibration
    needs the scale too (the camera translations must be metric to be compared with the flange's).

:func:`compare_registrations` reports the disagreement of two registrations (translation in mm at
the model's points, rotation in degrees, scale ratio); :func:`apply_registration` returns a copy
of an :class:`~artrecon.model.ArticulatedModel` in the robot frame, in metres.

OpenCV: ``cv2.calibrateHandEye`` is used when the installed OpenCV exposes it. OpenCV 5.0's
Python bindings (the version this project was developed with) do not, so the same Park & Martin
(1994) solver OpenCV uses by default (``CALIB_HAND_EYE_PARK`` -- closed form over all motion
pairs) is implemented here in numpy; :data:`HAND_EYE_BACKEND` says which one runs.
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass

import cv2
import numpy as np

from artrecon.confidence import rescale_confidence
from artrecon.errors import DegenerateError, InputError, ReconstructionError
from artrecon.geometry import invert_pose, log_so3, pose, rotation_angle
from artrecon.model import ArticulatedModel
from artrecon.procrustes import Similarity, similarity_transform

log = logging.getLogger(__name__)

__all__ = [
    "CentreRegistration",
    "PnPResult",
    "HandEyeResult",
    "RegistrationComparison",
    "register_camera_centres",
    "sift_features",
    "match_descriptors",
    "localize_image",
    "calibrate_hand_eye",
    "register_by_pnp",
    "metric_scale_from_length",
    "compare_registrations",
    "apply_registration",
    "landmarks_from_tracks",
]

# --- thresholds (each with why) ----------------------------------------------------------------

#: Inlier distance (metres, robot frame) of a camera centre after the similarity. FK camera
#: positions are exact to well under a millimetre; SfM centres of a 0.5 m ring are good to a few
#: mm. 1 cm keeps every honest camera and rejects a camera registered at a wrong place (off by cm
#: to dm).
CENTRE_INLIER_DISTANCE = 0.01
#: RANSAC hypotheses for the camera-centre similarity (3-point samples). With 30% bad cameras a
#: clean triplet is drawn with probability 0.34 per sample: 200 samples miss one with 1e-36.
CENTRE_RANSAC_ITERATIONS = 200
#: Fewer inlier cameras than this fraction of all is a failure, not a registration.
CENTRE_MIN_INLIER_FRACTION = 0.5
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
#: Hand-eye motion pairs with a relative rotation below this (rad) carry no rotation-axis
#: information (AX = XB is degenerate for pure translations) and are skipped: 2 degrees.
HAND_EYE_MIN_ROTATION = np.deg2rad(2.0)

HAND_EYE_BACKEND = "cv2.calibrateHandEye" if hasattr(cv2, "calibrateHandEye") else \
    "numpy Park-Martin (cv2.calibrateHandEye is missing from this OpenCV build)"


# --- small helpers ----------------------------------------------------------------------------


def _poses(name: str, T) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"{name} must have shape (n, 4, 4), got {T.shape}")
    return T


def _points(name: str, p, cols: int = 3) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    if p.ndim != 2 or p.shape[1] != cols:
        raise ValueError(f"{name} must have shape (n, {cols}), got {p.shape}")
    return p


# --- (a) camera centres -----------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class CentreRegistration:
    """Result of :func:`register_camera_centres`.

    Attributes
    ----------
    T_robot_model : Similarity
        ``p_robot = T_robot_model.apply(p_model)``; ``.scale`` is metres per model unit.
    residuals : (n,) float
        Distance (m, robot frame) of every mapped model centre to its robot centre.
    inliers : (n,) bool
        Cameras used in the final fit.
    rms, median, max : float
        Residual statistics over the inliers (m).
    """

    T_robot_model: Similarity
    residuals: np.ndarray
    inliers: np.ndarray
    rms: float
    median: float
    max: float

    def summary(self) -> dict:
        """JSON-ready statistics (mm)."""
        return {"scale_m_per_unit": self.T_robot_model.scale,
                "inliers": int(self.inliers.sum()), "cameras": int(len(self.inliers)),
                "rms_mm": 1e3 * self.rms, "median_mm": 1e3 * self.median,
                "max_inlier_mm": 1e3 * self.max}


def register_camera_centres(centres_model, cameras_robot, *,
                            inlier_distance: float = CENTRE_INLIER_DISTANCE,
                            iterations: int = CENTRE_RANSAC_ITERATIONS,
                            seed: int = 0) -> CentreRegistration:
    """Scale and model-to-robot transform from camera centres (route (a)).

    Parameters
    ----------
    centres_model : (n, 3) float
        Camera centres in the SfM model of configuration A (model units), n >= 3.
    cameras_robot : (n, 4, 4) or (n, 3) float
        The same cameras' ``T_robot_camera`` from the arm's forward kinematics, or just their
        centres (m).
    inlier_distance : float
        RANSAC inlier threshold (m, robot frame).
    iterations : int
        RANSAC 3-point hypotheses.
    seed : int
        Seed of the sampling (deterministic result).

    Returns
    -------
    CentreRegistration

    Raises
    ------
    DegenerateError
        Fewer than 3 cameras, collinear centres, or fewer than
        ``CENTRE_MIN_INLIER_FRACTION`` of the cameras agree.
    """
    src = _points("centres_model", centres_model)
    dst = np.asarray(cameras_robot, dtype=float)
    if dst.ndim == 3:
        dst = _poses("cameras_robot", dst)[:, :3, 3]
    dst = _points("cameras_robot (centres)", dst)
    if len(src) != len(dst):
        raise ValueError(f"centres_model and cameras_robot must describe the same cameras: got "
                         f"{len(src)} and {len(dst)}")
    n = len(src)
    if n < 3:
        raise DegenerateError(f"camera-centre registration needs >= 3 cameras, got {n}")
    rng = np.random.default_rng(seed)
    best, best_count, best_err = None, -1, np.inf
    for _ in range(iterations if n > 3 else 1):
        idx = rng.choice(n, 3, replace=False) if n > 3 else np.arange(3)
        try:
            T = similarity_transform(src[idx], dst[idx])
        except DegenerateError:
            continue
        err = np.linalg.norm(T.apply(src) - dst, axis=1)
        inl = err < inlier_distance
        count, total = int(inl.sum()), float(np.minimum(err, inlier_distance).sum())
        if count > best_count or (count == best_count and total < best_err):
            best, best_count, best_err = inl, count, total
    if best is None or best_count < max(3, CENTRE_MIN_INLIER_FRACTION * n):
        raise DegenerateError(
            f"camera-centre registration: only {max(best_count, 0)} of {n} cameras agree within "
            f"{inlier_distance * 1e3:.1f} mm; check that centres_model and cameras_robot list "
            "the same images in the same order, or raise inlier_distance")
    inliers = best
    for _ in range(3):  # refit on inliers, re-select, until stable
        T = similarity_transform(src[inliers], dst[inliers])
        err = np.linalg.norm(T.apply(src) - dst, axis=1)
        new = err < inlier_distance
        if new.sum() < 3 or np.array_equal(new, inliers):
            break
        inliers = new
    T = similarity_transform(src[inliers], dst[inliers])
    err = np.linalg.norm(T.apply(src) - dst, axis=1)
    e = err[inliers]
    out = CentreRegistration(T, err, inliers, float(np.sqrt(np.mean(e ** 2))),
                             float(np.median(e)), float(e.max()))
    log.info("camera-centre registration: scale %.6g m/unit, %d/%d inliers, rms %.2f mm",
             T.scale, int(inliers.sum()), n, 1e3 * out.rms)
    return out


def metric_scale_from_length(length_m: float, model_a, model_b) -> float:
    """Metres per model unit from one known length: the distance between two model points.

    Parameters
    ----------
    length_m : float
        The true distance (m) between the two points, measured on the object.
    model_a, model_b : (3,) float
        The two points in the model (model units).
    """
    a, b = (np.asarray(v, dtype=float).reshape(-1) for v in (model_a, model_b))
    if a.shape != (3,) or b.shape != (3,):
        raise ValueError(f"model points must have shape (3,), got {a.shape} and {b.shape}")
    d = float(np.linalg.norm(a - b))
    if not length_m > 0 or d == 0:
        raise DegenerateError(f"known length {length_m} m between model points {d} units apart: "
                              "give a positive length between two distinct points")
    return float(length_m) / d


# --- (b) PnP ----------------------------------------------------------------------------------


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
    sift = cv2.SIFT_create(nfeatures=max_features)
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


# --- hand-eye ---------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class HandEyeResult:
    """Result of :func:`calibrate_hand_eye`.

    Attributes
    ----------
    T_flange_camera : (4, 4) float
        Estimated camera pose on the flange (m).
    T_robot_target : (4, 4) float
        The fixed target (here: the scaled model frame) in the robot frame, from the estimate.
    rotation_residual_deg, translation_residual_mm : float
        RMS over the images of the disagreement of ``T_robot_flange_i X T_camera_target_i`` with
        its mean: how consistent the pairs are with one rigid mount.
    backend : str
    """

    T_flange_camera: np.ndarray
    T_robot_target: np.ndarray
    rotation_residual_deg: float
    translation_residual_mm: float
    backend: str


def _park_martin(A: list[np.ndarray], B: list[np.ndarray]) -> np.ndarray:
    """AX = XB by Park & Martin (1994): closed-form rotation, least-squares translation."""
    M = np.zeros((3, 3))
    for a, b in zip(A, B, strict=True):
        M += np.outer(log_so3(b[:3, :3]), log_so3(a[:3, :3]))
    w, V = np.linalg.eigh(M.T @ M)
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        raise DegenerateError("hand-eye: the gripper motions rotate about fewer than two distinct "
                              "axes; capture views with different orientations")
    Rx = V @ np.diag(w ** -0.5) @ V.T @ M.T
    u, _, vt = np.linalg.svd(Rx)
    Rx = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    C = np.vstack([a[:3, :3] - np.eye(3) for a in A])
    d = np.concatenate([Rx @ b[:3, 3] - a[:3, 3] for a, b in zip(A, B, strict=True)])
    tx = np.linalg.lstsq(C, d, rcond=None)[0]
    return pose(Rx, tx)


def calibrate_hand_eye(T_robot_flange, T_model_camera, scale: float) -> HandEyeResult:
    """Estimate the camera-to-flange transform from the capture (eye-in-hand, AX = XB).

    Parameters
    ----------
    T_robot_flange : (n, 4, 4) float
        Flange (gripper) poses from forward kinematics at each image (m), n >= 3.
    T_model_camera : (n, 4, 4) float
        The same images' camera poses in the SfM model (OpenCV convention, model units).
    scale : float
        Metres per model unit (route (a) or a known length): hand-eye needs metric translations.

    Returns
    -------
    HandEyeResult
    """
    G = _poses("T_robot_flange", T_robot_flange)
    C = _poses("T_model_camera", T_model_camera)
    if len(G) != len(C):
        raise ValueError(f"T_robot_flange and T_model_camera must pair up: {len(G)} vs {len(C)}")
    if len(G) < 3:
        raise DegenerateError(f"hand-eye calibration needs >= 3 poses, got {len(G)}")
    if not scale > 0:
        raise ValueError(f"scale must be > 0 (metres per model unit), got {scale}")
    Cm = C.copy()
    Cm[:, :3, 3] *= scale
    T_ct = np.array([invert_pose(c) for c in Cm])  # target (scaled model) in camera
    calib = getattr(cv2, "calibrateHandEye", None)
    if calib is not None:
        R, t = calib(G[:, :3, :3], G[:, :3, 3], T_ct[:, :3, :3], T_ct[:, :3, 3],
                     method=cv2.CALIB_HAND_EYE_PARK)
        X = pose(np.asarray(R), np.asarray(t).reshape(3))
    else:
        A, B = [], []
        n = len(G)
        for i in range(n):
            for j in range(i + 1, n):
                a = invert_pose(G[j]) @ G[i]
                b = T_ct[j] @ invert_pose(T_ct[i])
                if rotation_angle(a[:3, :3]) >= HAND_EYE_MIN_ROTATION:
                    A.append(a)
                    B.append(b)
        if len(A) < 2:
            raise DegenerateError("hand-eye: fewer than 2 motion pairs rotate by more than "
                                  f"{np.rad2deg(HAND_EYE_MIN_ROTATION):.0f} deg")
        X = _park_martin(A, B)
    targets = np.array([G[i] @ X @ T_ct[i] for i in range(len(G))])
    mean_t = targets[:, :3, 3].mean(axis=0)
    u, _, vt = np.linalg.svd(targets[:, :3, :3].sum(axis=0))
    mean_R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    rot = [np.rad2deg(rotation_angle(mean_R.T @ T[:3, :3])) for T in targets]
    tr = np.linalg.norm(targets[:, :3, 3] - mean_t, axis=1) * 1e3
    out = HandEyeResult(X, pose(mean_R, mean_t), float(np.sqrt(np.mean(np.square(rot)))),
                        float(np.sqrt(np.mean(tr ** 2))), HAND_EYE_BACKEND)
    log.info("hand-eye (%s): camera %.1f mm from the flange, consistency %.2f mm / %.3f deg",
             out.backend, 1e3 * np.linalg.norm(X[:3, 3]), out.translation_residual_mm,
             out.rotation_residual_deg)
    return out


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


# --- comparison and application ---------------------------------------------------------------


@dataclass(frozen=True)
class RegistrationComparison:
    """Disagreement of two model-to-robot similarities (see :func:`compare_registrations`)."""

    translation_mm: float
    """RMS distance (mm) between the two images of the model points"""
    max_translation_mm: float
    """largest such distance (mm)"""
    rotation_deg: float
    """angle of the relative rotation (deg)"""
    scale_ratio: float
    """scale of the first over scale of the second"""

    def to_dict(self) -> dict:
        return {k: float(v) for k, v in self.__dict__.items()}


def compare_registrations(T1: Similarity, T2: Similarity, points) -> RegistrationComparison:
    """How far apart two registrations put the model.

    Parameters
    ----------
    T1, T2 : Similarity
        Two estimates of ``T_robot_model``.
    points : (n, 3) float
        Model points (model frame) at which the translation difference is measured (the object's
        points: where the arm will grasp).
    """
    p = _points("points", points)
    d = np.linalg.norm(T1.apply(p) - T2.apply(p), axis=1) * 1e3
    return RegistrationComparison(float(np.sqrt(np.mean(d ** 2))), float(d.max()),
                                  float(np.rad2deg(rotation_angle(T1.rotation.T @ T2.rotation))),
                                  float(T1.scale / T2.scale))


def apply_registration(model: ArticulatedModel, T_robot_model: Similarity) -> ArticulatedModel:
    """A copy of ``model`` in the robot frame, in metres.

    Points are mapped by the similarity, normals and axis directions rotated, axis points mapped,
    prismatic joint states and residuals scaled to metres (revolute states are angles and stay);
    each link's A-to-B transform and each joint's relative transform are conjugated into the robot
    frame. The result has ``scale = 1.0`` (metres per unit) and ``scale_known = True``;
    ``frames["T_robot_sfm"]`` holds the similarity's (4, 4) matrix, which maps the input model's
    frame (scaled) to the robot frame. Named frames of the input that map *from* the model frame
    (``T_x_model``) are re-expressed so they map from the new frame.

    Parameters
    ----------
    model : ArticulatedModel
        In its SfM frame (``scale`` may already be set: it is ignored; the similarity's scale is
        the one used).
    T_robot_model : Similarity

    Returns
    -------
    ArticulatedModel
    """
    if not isinstance(T_robot_model, Similarity):
        raise TypeError(f"T_robot_model must be an artrecon Similarity, got "
                        f"{type(T_robot_model).__name__}")
    T = T_robot_model
    T_inv = T.inverse()
    s, R = T.scale, T.rotation
    out = copy.deepcopy(model)
    for lk in out.links:
        lk.points = T.apply(lk.points) if len(lk.points) else lk.points.copy()
        if lk.normals is not None and len(lk.normals):
            lk.normals = lk.normals @ R.T
        lk.transform_a_to_b = T @ lk.transform_a_to_b @ T_inv
    for j in out.joints:
        j.axis_direction = R @ j.axis_direction
        j.axis_point = T.apply(j.axis_point)
        if j.type == "prismatic":
            j.state_a *= s
            j.state_b *= s
        j.residual *= s
        j.confidence = rescale_confidence(j.confidence, s)  # its lengths to metres
        j.relative_transform = T @ j.relative_transform @ T_inv
    frames = {}
    for name, M in model.frames.items():
        frames[name] = M @ T_inv.matrix if name.endswith("_model") else M.copy()
    frames["T_robot_sfm"] = T.matrix
    out.frames = frames
    out.scale = 1.0
    out.scale_known = True
    out.metadata = dict(out.metadata)
    out.metadata["registration"] = {"frame": "robot", "units": "m",
                                    "scale_m_per_sfm_unit": s,
                                    "T_robot_sfm": T.to_dict()}
    return out

