"""The registration stage: a reconstruction folder in, the model in the robot frame out.

``artrecon register MODEL_DIR --camera-poses POSES.json`` (route (a): the SfM camera centres of
configuration A against the arm's camera positions) and/or ``--image IMG --flange-pose POSE.json``
(route (b): PnP of a fresh image against the model, turned into model-to-robot by the flange pose
and the hand-eye transform, given or calibrated from a capture). With both, route (a) is the
registration and route (b) checks it: routes that disagree are refused
(:class:`artrecon.errors.RegistrationMismatchError`), never handed to the arm.

The stage's folder (default ``MODEL_DIR/registration``) is written whole or not at all::

    model.json          the registered model: robot frame, metres (scale_known)
    registration.json   the report: per route its transform, scale, residuals or inliers and
                        reprojection error; the hand-eye estimate; the routes' agreement

Pose files are JSON. A capture's ``cameras.json`` (format ``artrecon-capture/1``) is read as is:
``images`` is a list of ``{"file", "T_world_camera", "T_world_flange"}`` (4x4, metres, OpenCV
camera: x right, y down, z forward; ``T_a_b`` maps b coordinates to a coordinates). A fresh
image's pose file holds ``{"T_world_flange": 4x4}`` (and may hold ``"T_world_camera"``: then no
hand-eye transform is needed).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pycolmap

from artrecon.errors import InputError, ReconstructionError
from artrecon.files import (
    check_output_dir,
    publish_dir,
    read_json,
    work_dir,
    write_json_atomic,
)
from artrecon.model import ArticulatedModel
from artrecon.procrustes import Similarity
from artrecon.register.agreement import check_registration_agreement, registration_agreement
from artrecon.register.apply import apply_registration, compare_registrations
from artrecon.register.centres import (
    CENTRE_INLIER_DISTANCE,
    CENTRE_RANSAC_ITERATIONS,
    register_camera_centres,
)
from artrecon.register.hand_eye import HandEyeResult, calibrate_hand_eye
from artrecon.register.pnp import (
    PNP_REPROJECTION_PX,
    SIFT_RATIO,
    landmarks_from_tracks,
    localize_image,
    register_by_pnp,
    sift_features,
)
from artrecon.sfm import camera_poses, read_features

log = logging.getLogger(__name__)

#: Version of ``registration.json``.
FORMAT = "artrecon-registration/1"


@dataclass(frozen=True)
class RegisterConfig:
    """Settings of the registration stage."""

    centre_inlier_distance: float = CENTRE_INLIER_DISTANCE
    """route (a): RANSAC inlier distance of a camera centre after the similarity (m)"""
    centre_ransac_iterations: int = CENTRE_RANSAC_ITERATIONS
    """route (a): 3-point RANSAC hypotheses"""
    sift_ratio: float = SIFT_RATIO
    """route (b): Lowe's ratio of the fresh image's matches to the model's points"""
    pnp_reprojection_px: float = PNP_REPROJECTION_PX
    """route (b): PnP RANSAC inlier threshold (px)"""


@dataclass(frozen=True)
class FreshImage:
    """An image taken after the reconstruction, with where the arm was."""

    path: Path
    """the image file"""
    T_world_flange: np.ndarray | None = None
    """the flange pose from the arm's forward kinematics (m)"""
    T_world_camera: np.ndarray | None = None
    """the camera pose, when known directly (then no hand-eye transform is needed)"""


@dataclass
class Registration:
    """What :func:`register` found."""

    model: ArticulatedModel
    """the model in the robot frame, metres"""
    T_robot_model: Similarity
    """the chosen registration"""
    route: str
    """``"camera_centres"`` or ``"pnp"``: which one is ``T_robot_model``"""
    routes: dict = field(default_factory=dict)
    """per route: ``T_robot_model`` (Similarity) and its report (JSON-ready)"""
    agreement: dict | None = None
    """the two routes' agreement (:func:`artrecon.register.agreement.registration_agreement`)"""

    def report(self) -> dict:
        """``registration.json``."""
        return {"format": FORMAT, "route": self.route,
                "T_robot_model": self.T_robot_model.to_dict(),
                "scale_m_per_unit": self.T_robot_model.scale,
                "routes": {k: {**v["report"], "T_robot_model": v["T"].to_dict()}
                           for k, v in self.routes.items()},
                "agreement": self.agreement}


# ------------------------------------------------------------------------------ inputs


def read_matrix(value, where: str) -> np.ndarray:
    try:
        T = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: not a 4x4 matrix of numbers ({exc})") from exc
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"{where}: expected a finite 4x4 matrix, got shape {T.shape}")
    if not np.allclose(T[3], [0, 0, 0, 1]) or not np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3),
                                                              atol=1e-6):
        raise InputError(f"{where}: not a rigid transform (rotation not orthonormal or last row "
                         "not 0 0 0 1)")
    return T


def read_pose_file(path) -> dict[str, dict[str, np.ndarray]]:
    """``{image file: {"T_world_camera": (4, 4), "T_world_flange": (4, 4)}}`` of a pose file
    (a capture's ``cameras.json`` or any JSON with an ``images`` list of such entries); entries
    without a pose (a free camera) are left out.

    Raises
    ------
    InputError
        Unreadable, no ``images`` list, or a malformed matrix (named by file and image).
    """
    path = Path(path)
    data = read_json(path)
    images = data.get("images") if isinstance(data, dict) else None
    if not isinstance(images, (list, dict)):
        raise InputError(f"{path}: expected a JSON object with an 'images' list of "
                         "{'file', 'T_world_camera', 'T_world_flange'} entries (a capture's "
                         "cameras.json)")
    if isinstance(images, dict):  # {name: T_world_camera}, as load_cameras_json accepts
        images = [{"name": k, "T_world_camera": v} for k, v in images.items()]
    out = {}
    for k, im in enumerate(images):
        name = im.get("file") or im.get("name") if isinstance(im, dict) else None
        if name is None:
            raise InputError(f"{path}: images[{k}] has no 'file' (or 'name')")
        entry = {}
        for key in ("T_world_camera", "T_world_flange"):
            if im.get(key) is not None:
                entry[key] = read_matrix(im[key], f"{path}: images[{k}] ({name}) {key}")
        if entry:
            out[Path(str(name)).name] = entry
    return out


def read_fresh_pose(path) -> dict[str, np.ndarray]:
    """A fresh image's pose file: ``{"T_world_flange": (4, 4)}`` and/or ``"T_world_camera"``."""
    path = Path(path)
    data = read_json(path)
    if not isinstance(data, dict) or not ({"T_world_flange", "T_world_camera"} & set(data)):
        raise InputError(f"{path}: expected a JSON object with 'T_world_flange' (the arm's flange "
                         "pose when the image was taken) or 'T_world_camera'")
    return {k: read_matrix(data[k], f"{path}: {k}") for k in ("T_world_flange", "T_world_camera")
            if data.get(k) is not None}


class _ModelFolder:
    """A reconstruction folder's model and configuration A's SfM (read lazily)."""

    def __init__(self, model_dir):
        self.dir = Path(model_dir)
        path = self.dir / "model.json"
        if not path.is_file():
            raise InputError(f"{self.dir} holds no model.json: give the folder that "
                             "'artrecon reconstruct' wrote")
        self.model = ArticulatedModel.load(path)
        self.sparse = self.dir / "a" / "sparse" / "0"
        if not self.sparse.is_dir():
            raise InputError(f"{self.dir}: no SfM model of configuration A at {self.sparse}; "
                             "give the folder that 'artrecon reconstruct' wrote")
        self._rec = None

    @property
    def rec(self) -> pycolmap.Reconstruction:
        if self._rec is None:
            self._rec = pycolmap.Reconstruction(str(self.sparse))
        return self._rec

    def camera_poses(self) -> dict[str, np.ndarray]:
        """``{image name: T_model_camera}`` of configuration A."""
        return camera_poses(self.rec)

    def K(self) -> np.ndarray:
        cam = next(iter(self.rec.cameras.values()))
        return np.asarray(cam.calibration_matrix(), float)

    def landmarks(self) -> tuple[np.ndarray, np.ndarray]:
        db = self.dir / "a" / "database.db"
        if not db.is_file():
            raise InputError(f"{self.dir}: no feature database at {db}; the PnP route matches "
                             "the fresh image to the model's SIFT features")
        names = {int(i): im.name for i, im in self.rec.images.items()}
        return landmarks_from_tracks(self.rec.points3D, read_features(db), names)


# ------------------------------------------------------------------------------ routes


def _camera_centres_route(folder: _ModelFolder, poses: dict, config: RegisterConfig,
                          seed: int) -> tuple[Similarity, dict]:
    sfm = folder.camera_poses()
    names = sorted(n for n in sfm if "T_world_camera" in poses.get(n, {}))
    if len(names) < 3:
        raise InputError(f"route (a): only {len(names)} images of configuration A have both an "
                         "SfM pose and a camera pose in the pose file (need 3); give the "
                         "cameras.json of the image set A was reconstructed from")
    reg = register_camera_centres(np.array([sfm[n][:3, 3] for n in names]),
                                  np.array([poses[n]["T_world_camera"] for n in names]),
                                  inlier_distance=config.centre_inlier_distance,
                                  iterations=config.centre_ransac_iterations, seed=seed)
    return reg.T_robot_model, {"method": "camera centres (SfM of A vs the arm's FK), RANSAC "
                                         "Umeyama", "images_used": len(names), **reg.summary()}


def _hand_eye(folder: _ModelFolder, poses: dict, scale: float | None) -> HandEyeResult:
    sfm = folder.camera_poses()
    names = sorted(n for n in sfm if "T_world_flange" in poses.get(n, {}))
    if len(names) < 3:
        raise InputError(f"hand-eye calibration: only {len(names)} images of configuration A "
                         "have both an SfM pose and a flange pose (need 3); give the capture's "
                         "cameras.json with T_world_flange per image, or the mount itself "
                         "(--hand-eye)")
    return calibrate_hand_eye(np.array([poses[n]["T_world_flange"] for n in names]),
                              np.array([sfm[n] for n in names]), scale)


def _read_image(path: Path) -> np.ndarray:
    if not path.is_file():
        raise InputError(f"fresh image {path} does not exist")
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"fresh image {path} cannot be read as an image (PNG or JPEG)")
    return img


def _pnp_route(folder: _ModelFolder, images: list[FreshImage], T_flange_camera, he_report,
               scale: float, scale_from: str, K, config: RegisterConfig,
               seed: int) -> tuple[Similarity, dict]:
    L, LD = folder.landmarks()
    K = folder.K() if K is None else np.asarray(K, float)
    estimates, per_image = [], []
    for im in images:
        kp, desc = sift_features(_read_image(im.path))
        try:
            pnp = localize_image(kp, desc, L, LD, K, ratio=config.sift_ratio,
                                 reprojection_px=config.pnp_reprojection_px, seed=seed)
        except ReconstructionError as exc:
            raise ReconstructionError(f"route (b), fresh image {im.path}: {exc}") from exc
        if im.T_world_camera is not None:
            T_robot_camera = im.T_world_camera
        elif im.T_world_flange is not None and T_flange_camera is not None:
            T_robot_camera = im.T_world_flange @ T_flange_camera
        else:
            raise InputError(f"fresh image {im.path}: give its flange pose and the hand-eye "
                             "transform (or a capture to calibrate it from), or its camera pose")
        T = register_by_pnp(T_robot_camera, np.eye(4), pnp.T_camera_model, scale)
        estimates.append(T)
        per_image.append({"image": str(im.path), "matches": int(len(pnp.matches)),
                          "inliers": int(pnp.inliers.sum()),
                          "reprojection_rms_px": pnp.reprojection_rms})
    T = estimates[0] if len(estimates) == 1 else _mean_similarity(estimates)
    return T, {"method": "PnP of fresh images + hand-eye", "images": per_image,
               "scale_from": scale_from, "hand_eye": he_report}


def _mean_similarity(Ts: list[Similarity]) -> Similarity:
    """Chordal mean rotation, mean translation and scale of several estimates."""
    u, _, vt = np.linalg.svd(sum(T.rotation for T in Ts))
    R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return Similarity(R, np.mean([T.translation for T in Ts], axis=0),
                      float(np.mean([T.scale for T in Ts])))


# ------------------------------------------------------------------------------ the stage


def register(model_dir, *, camera_poses=None, images: list[FreshImage] | None = None,
             hand_eye=None, hand_eye_poses=None, scale: float | None = None, K=None,
             out_dir=None, overwrite: bool = False, config: RegisterConfig = RegisterConfig(),
             seed: int = 0) -> Registration:
    """Register a reconstruction into the robot frame, in metres.

    Parameters
    ----------
    model_dir : path
        A folder written by :func:`artrecon.reconstruct` (model.json, a/sparse/0, a/database.db).
    camera_poses : path or dict, optional
        Route (a): the arm's camera poses of configuration A's images (:func:`read_pose_file`).
    images : list of FreshImage, optional
        Route (b): fresh images with the flange (or camera) pose they were taken from.
    hand_eye : (4, 4) float, optional
        ``T_flange_camera``, the camera's mount on the flange, when calibrated elsewhere.
    hand_eye_poses : path or dict, optional
        A capture's poses with ``T_world_flange`` per image (default: ``camera_poses``): the
        hand-eye transform is calibrated from them and configuration A's SfM poses, with the
        model's scale (unless ``scale`` is given).
    scale : float, optional
        Metres per model unit for route (b) when known (e.g. a known length:
        :func:`artrecon.register.centres.metric_scale_from_length`). Default: the hand-eye
        calibration's estimate, else route (a)'s.
    K : (3, 3) float, optional
        Intrinsics of the fresh images (default: configuration A's camera).
    out_dir : path, optional
        Where to write model.json and registration.json (default ``MODEL_DIR/registration``);
        ``False``: write nothing.
    overwrite : bool
        Replace an existing ``out_dir``.
    config : RegisterConfig
    seed : int

    Returns
    -------
    Registration

    Raises
    ------
    InputError
        Missing or malformed inputs (named), nothing to register with, an existing output.
    DegenerateError, ReconstructionError
        A route cannot give an answer (too few cameras agree, too few PnP inliers).
    RegistrationMismatchError
        Both routes ran and disagree.
    """
    folder = _ModelFolder(model_dir)
    images = list(images or [])
    if camera_poses is None and not images:
        raise InputError("nothing to register with: give the arm's camera poses of the images "
                         "(--camera-poses) and/or a fresh image with its flange pose (--image, "
                         "--flange-pose)")
    if out_dir is None:
        out_dir = folder.dir / "registration"
    if out_dir is not False:
        # the model's own files, the pose files and the images are inputs: the output (which
        # --overwrite replaces whole) may be none of them, hold one or lie inside one; the
        # default, MODEL_DIR/registration, is the reconstruction folder's registration stage
        inputs = [folder.dir / "model.json", *(folder.dir / c for c in ("a", "b")),
                  *(p for p in (camera_poses, hand_eye_poses) if isinstance(p, (str, Path))),
                  *(im.path for im in images)]
        out_dir = check_output_dir(out_dir, [p for p in inputs if Path(p).exists()],
                                   overwrite=overwrite, marker="registration.json",
                                   example=folder.dir / "registration")
    poses = None
    if camera_poses is not None:
        poses = camera_poses if isinstance(camera_poses, dict) else read_pose_file(camera_poses)
    routes: dict[str, dict] = {}
    if poses is not None:
        T, rep = _camera_centres_route(folder, poses, config, seed)
        routes["camera_centres"] = {"T": T, "report": rep}
    if images:
        he_poses = hand_eye_poses if hand_eye_poses is not None else poses
        if he_poses is not None and not isinstance(he_poses, dict):
            he_poses = read_pose_file(he_poses)
        he = he_report = None
        T_fc = None if hand_eye is None else read_matrix(hand_eye, "hand_eye (T_flange_camera)")
        if T_fc is None and any(im.T_world_camera is None for im in images):
            if he_poses is None:
                raise InputError("route (b): the fresh image's flange pose needs the camera's "
                                 "mount on the flange: give --hand-eye, or a capture's poses "
                                 "to calibrate it from (--hand-eye-poses)")
            he = _hand_eye(folder, he_poses, scale)
            T_fc, he_report = he.T_flange_camera, he.summary()
        if scale is not None:
            s, scale_from = float(scale), "given"
        elif he is not None:
            s, scale_from = he.scale, "hand-eye calibration (flange motions)"
        elif "camera_centres" in routes:
            s, scale_from = routes["camera_centres"]["T"].scale, "route (a)"
        else:
            raise InputError("route (b) needs the model's metric scale: give --scale (e.g. from "
                             "a known length), the capture's poses to calibrate the hand-eye "
                             "transform from, or the camera poses (route (a))")
        T, rep = _pnp_route(folder, images, T_fc, he_report, s, scale_from, K, config, seed)
        routes["pnp"] = {"T": T, "report": rep}
    route = "camera_centres" if "camera_centres" in routes else "pnp"
    T = routes[route]["T"]
    registered = apply_registration(folder.model, T)
    agreement = None
    if len(routes) == 2:
        agreement = registration_agreement(folder.model, T, routes["pnp"]["T"],
                                           registered=registered)
        pts = np.concatenate([lk.points for lk in folder.model.links if len(lk.points)])
        agreement["comparison"] = compare_registrations(T, routes["pnp"]["T"], pts).to_dict()
        check_registration_agreement(agreement)
    registered.metadata["registration"] = {**registered.metadata.get("registration", {}),
                                           "route": route}
    result = Registration(registered, T, route, routes, agreement)
    if out_dir is not False:
        with work_dir(out_dir) as work:
            registered.save(work / "model.json")
            write_json_atomic(work / "registration.json", result.report())
            publish_dir(work, out_dir)
        log.info("registered %s (%s) into %s", folder.dir, route, out_dir)
    return result


def true_registration_error(T: Similarity, T_true: Similarity, points) -> dict:
    """A registration's error against a reference (rotation deg, translation mm at ``points``,
    scale %): for scoring in simulation, where the true transform is known."""
    cmp = compare_registrations(T, T_true, points)
    return {"rotation_deg": cmp.rotation_deg, "translation_mm": cmp.translation_mm,
            "max_translation_mm": cmp.max_translation_mm,
            "scale_percent": 100.0 * abs(cmp.scale_ratio - 1.0)}
