"""Route (a): metric scale and robot frame from camera centres.

The method's capture gives, for every image, the camera centre in the SfM model (``C_model``) and
the camera pose from the arm's forward kinematics (``C_robot``). The similarity
``C_robot ~ s R C_model + t`` (Umeyama inside a 3-point RANSAC, then refitted on the inliers) is
``T_robot_model``: its scale is the metric scale (metres per model unit). A few badly registered
cameras are rejected as outliers.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from artrecon.errors import DegenerateError
from artrecon.procrustes import Similarity, similarity_transform
from artrecon.register._checks import _points, _poses

log = logging.getLogger(__name__)

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
