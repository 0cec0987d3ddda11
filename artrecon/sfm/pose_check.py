"""Given camera poses against the images: refused when they disagree.

Poses from the arm's forward kinematics are held fixed by the known-pose triangulation; a camera
mount (hand-eye) error or encoder errors would then give a wrong model without any error.
:func:`pose_agreement` measures how far the images' verified matches lie from the epipolar lines
the poses predict and how many of them triangulate; :func:`check_pose_agreement` refuses poses
beyond :class:`~artrecon.sfm.config.SfMConfig`'s limits with a
:class:`~artrecon.errors.PoseMismatchError`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pycolmap

from artrecon.errors import PoseMismatchError
from artrecon.sfm.config import SfMConfig


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
