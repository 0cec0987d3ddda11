"""Hand-eye calibration of an eye-in-hand camera from a capture (AX = XB).

From the capture's pairs (flange pose from forward kinematics, camera pose from SfM) the
camera-to-flange transform ``T_flange_camera`` is *estimated*, not read from the robot model.
OpenCV: ``cv2.calibrateHandEye`` is used when the installed OpenCV exposes it. OpenCV 5.0's
Python bindings (the version this project was developed with) do not, so the same Park & Martin
(1994) solver OpenCV uses by default (``CALIB_HAND_EYE_PARK`` -- closed form over all motion
pairs) is implemented here in numpy; :data:`HAND_EYE_BACKEND` says which one runs.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from artrecon.errors import DegenerateError
from artrecon.geometry import invert_pose, log_so3, pose, rotation_angle
from artrecon.register._checks import _poses

log = logging.getLogger(__name__)

#: Hand-eye motion pairs with a relative rotation below this (rad) carry no rotation-axis
#: information (AX = XB is degenerate for pure translations) and are skipped: 2 degrees.
HAND_EYE_MIN_ROTATION = np.deg2rad(2.0)

#: The solver: rotation by Park & Martin (1994) in closed form over all motion pairs (what
#: OpenCV's ``calibrateHandEye`` does by default; OpenCV 5.0's Python bindings lack it), then the
#: translation -- and the model's scale when it is not given -- by linear least squares.
HAND_EYE_BACKEND = "numpy Park-Martin"


@dataclass(frozen=True, eq=False)
class HandEyeResult:
    """Result of :func:`calibrate_hand_eye`.

    Attributes
    ----------
    T_flange_camera : (4, 4) float
        Estimated camera pose on the flange (m).
    T_robot_target : (4, 4) float
        The fixed target (here: the scaled model frame) in the robot frame, from the estimate.
    scale : float
        Metres per model unit: the one given, or estimated with the mount (``scale_estimated``).
    rotation_residual_deg, translation_residual_mm : float
        RMS over the images of the disagreement of ``T_robot_flange_i X T_camera_target_i`` with
        its mean: how consistent the pairs are with one rigid mount.
    backend : str
    scale_estimated : bool
    """

    T_flange_camera: np.ndarray
    T_robot_target: np.ndarray
    scale: float
    rotation_residual_deg: float
    translation_residual_mm: float
    backend: str
    scale_estimated: bool = False

    def summary(self) -> dict:
        """JSON-ready figures."""
        return {"T_flange_camera": self.T_flange_camera.tolist(), "scale_m_per_unit": self.scale,
                "scale_estimated": self.scale_estimated,
                "consistency_mm": self.translation_residual_mm,
                "consistency_deg": self.rotation_residual_deg, "backend": self.backend}


def _rotation_angles(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`artrecon.geometry.rotation_angle` of many rotations (m, 3, 3) at once, and their
    skew parts (m, 3)."""
    s = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    return np.arctan2(0.5 * np.linalg.norm(s, axis=1),
                      0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0)), s


def _log_so3_many(R: np.ndarray) -> np.ndarray:
    """:func:`artrecon.geometry.log_so3` of many rotations (m, 3, 3) at once."""
    angle, s = _rotation_angles(R)
    out = np.zeros((len(R), 3))
    plain = (angle >= 1e-12) & (np.pi - angle >= 1e-6)
    out[plain] = angle[plain, None] * s[plain] / np.linalg.norm(s[plain], axis=1)[:, None]
    for k in np.flatnonzero((angle >= 1e-12) & ~plain):  # near pi: by the eigenvector
        out[k] = log_so3(R[k])
    return out


def _park_martin_rotation(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The rotation of X in AX = XB by Park & Martin (1994), closed form (A, B: (m, 4, 4))."""
    A, B = np.asarray(A), np.asarray(B)
    M = np.einsum("ki,kj->ij", _log_so3_many(B[:, :3, :3]), _log_so3_many(A[:, :3, :3]))
    w, V = np.linalg.eigh(M.T @ M)
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        raise DegenerateError("hand-eye: the gripper motions rotate about fewer than two distinct "
                              "axes; capture views with different orientations")
    Rx = V @ np.diag(w ** -0.5) @ V.T @ M.T
    u, _, vt = np.linalg.svd(Rx)
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def _translation_and_scale(A, B, Rx: np.ndarray, scale: float | None) -> tuple[np.ndarray, float]:
    """The translation of X (and the scale of B's translations, unless given) in AX = XB:
    ``(R_A - I) t_X - s R_X t_B = -t_A``, linear least squares over all pairs."""
    C = np.vstack([a[:3, :3] - np.eye(3) for a in A])
    tb = np.concatenate([Rx @ b[:3, 3] for b in B])
    ta = np.concatenate([a[:3, 3] for a in A])
    if scale is not None:
        return np.linalg.lstsq(C, scale * tb - ta, rcond=None)[0], float(scale)
    sol = np.linalg.lstsq(np.c_[C, -tb], -ta, rcond=None)[0]
    return sol[:3], float(sol[3])


def calibrate_hand_eye(T_robot_flange, T_model_camera, scale: float | None = None
                       ) -> HandEyeResult:
    """Estimate the camera-to-flange transform from the capture (eye-in-hand, AX = XB).

    Parameters
    ----------
    T_robot_flange : (n, 4, 4) float
        Flange (gripper) poses from forward kinematics at each image (m), n >= 3.
    T_model_camera : (n, 4, 4) float
        The same images' camera poses in the SfM model (OpenCV convention, model units).
    scale : float, optional
        Metres per model unit, when known (a known length, or route (a)). Without it the scale
        is estimated with the mount: the flange's metric motions fix it.

    Returns
    -------
    HandEyeResult

    Raises
    ------
    DegenerateError
        Too few poses, motions that do not rotate about two distinct axes, or an estimated scale
        that is not positive.
    """
    G = _poses("T_robot_flange", T_robot_flange)
    C = _poses("T_model_camera", T_model_camera)
    if len(G) != len(C):
        raise ValueError(f"T_robot_flange and T_model_camera must pair up: {len(G)} vs {len(C)}")
    if len(G) < 3:
        raise DegenerateError(f"hand-eye calibration needs >= 3 poses, got {len(G)}")
    if scale is not None and not scale > 0:
        raise ValueError(f"scale must be > 0 (metres per model unit), got {scale}")
    T_ct = np.array([invert_pose(c) for c in C])  # target (model, model units) in camera
    # every pair i < j of poses (all at once): the flange's motion and the camera's
    i, j = np.triu_indices(len(G), k=1)
    A = np.matmul(np.array([invert_pose(g) for g in G])[j], G[i])
    turns = _rotation_angles(A[:, :3, :3])[0] >= HAND_EYE_MIN_ROTATION
    i, j, A = i[turns], j[turns], A[turns]
    B = np.matmul(T_ct[j], np.array([invert_pose(t) for t in T_ct])[i])
    if len(A) < 2:
        raise DegenerateError("hand-eye: fewer than 2 motion pairs rotate by more than "
                              f"{np.rad2deg(HAND_EYE_MIN_ROTATION):.0f} deg")
    Rx = _park_martin_rotation(A, B)
    tx, s = _translation_and_scale(A, B, Rx, scale)
    if not s > 0:
        raise DegenerateError(f"hand-eye: the estimated scale is {s:.3g} (not positive): the "
                              "camera poses do not move like the flange; check that they belong "
                              "to the same images")
    X = pose(Rx, tx)
    Tm = T_ct.copy()
    Tm[:, :3, 3] *= s
    targets = np.array([G[i] @ X @ Tm[i] for i in range(len(G))])
    mean_t = targets[:, :3, 3].mean(axis=0)
    u, _, vt = np.linalg.svd(targets[:, :3, :3].sum(axis=0))
    mean_R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    rot = [np.rad2deg(rotation_angle(mean_R.T @ T[:3, :3])) for T in targets]
    tr = np.linalg.norm(targets[:, :3, 3] - mean_t, axis=1) * 1e3
    out = HandEyeResult(X, pose(mean_R, mean_t), s, float(np.sqrt(np.mean(np.square(rot)))),
                        float(np.sqrt(np.mean(tr ** 2))), HAND_EYE_BACKEND, scale is None)
    log.info("hand-eye (%s): camera %.1f mm from the flange, scale %.6g m/unit%s, consistency "
             "%.2f mm / %.3f deg", out.backend, 1e3 * np.linalg.norm(X[:3, 3]), s,
             " (estimated)" if scale is None else "", out.translation_residual_mm,
             out.rotation_residual_deg)
    return out
