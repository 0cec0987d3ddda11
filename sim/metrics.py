"""Scores against ground truth, with the definitions used by Ditto and DigitalTwinArt.

Every function here is pure (numpy in, numbers out) so that the evaluation, the tests and the
benchmarks score the same way. Units: inputs in metres and radians; functions whose name ends in
``_deg`` or ``_mm`` return degrees or millimetres, the units of the reports.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

#: Below this sine of the angle between two lines, they are treated as parallel (the common
#: perpendicular is then ill-conditioned and the point-to-line distance is the right measure).
PARALLEL_SIN = 1e-6

#: Distance under which a true surface sample counts as covered by the reconstruction (the
#: completeness threshold of the evaluation issue: 5 mm).
COMPLETENESS_RADIUS_M = 0.005


def _unit(v: np.ndarray, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    if v.shape != (3,):
        raise ValueError(f"{name}: expected shape (3,), got {v.shape}")
    n = np.linalg.norm(v)
    if not n > 0:
        raise ValueError(f"{name}: zero-length direction")
    return v / n


def axis_angle_error_deg(direction_pred: np.ndarray, direction_true: np.ndarray) -> float:
    """Sign-free angle between two axis directions, ``arccos |d_pred . d_true|`` in degrees.

    Parameters
    ----------
    direction_pred, direction_true : (3,) float
        Axis directions (any length but zero).
    """
    a = _unit(direction_pred, "direction_pred")
    b = _unit(direction_true, "direction_true")
    return float(np.degrees(np.arccos(np.clip(abs(a @ b), 0.0, 1.0))))


def line_distance(point_a: np.ndarray, direction_a: np.ndarray,
                  point_b: np.ndarray, direction_b: np.ndarray) -> float:
    """Distance between two 3D lines (for parallel lines, point-to-line distance), in input units.

    Parameters
    ----------
    point_a, point_b : (3,) float
        A point on each line.
    direction_a, direction_b : (3,) float
        Each line's direction.
    """
    pa = np.asarray(point_a, dtype=float)
    pb = np.asarray(point_b, dtype=float)
    if pa.shape != (3,) or pb.shape != (3,):
        raise ValueError(f"points: expected shape (3,), got {pa.shape} and {pb.shape}")
    da = _unit(direction_a, "direction_a")
    db = _unit(direction_b, "direction_b")
    w = pb - pa
    cross = np.cross(da, db)
    s = np.linalg.norm(cross)
    if s < PARALLEL_SIN:
        return float(np.linalg.norm(w - (w @ da) * da))
    return float(abs(w @ cross) / s)


def joint_state_error(joint_type: str, state_pred: float, state_true: float,
                      direction_pred: np.ndarray, direction_true: np.ndarray) -> float:
    """Error of a joint's motion between the two configurations.

    The sign of a joint value depends on the sign of its axis, so the predicted value is first
    expressed about an axis pointing the same way as the true one. Revolute: absolute angle
    difference in radians (the geodesic distance between two rotations about one axis);
    prismatic: absolute displacement difference in metres.

    Parameters
    ----------
    joint_type : {"revolute", "prismatic"}
    state_pred, state_true : float
        Joint motion from configuration a to b (rad or m).
    direction_pred, direction_true : (3,) float
        The axes the two values refer to.
    """
    if joint_type not in ("revolute", "prismatic"):
        raise ValueError(f"joint_type must be 'revolute' or 'prismatic', got {joint_type!r}")
    sign = 1.0 if _unit(direction_pred, "direction_pred") @ _unit(
        direction_true, "direction_true") >= 0 else -1.0
    diff = sign * float(state_pred) - float(state_true)
    if joint_type == "revolute":
        diff = (diff + np.pi) % (2 * np.pi) - np.pi
    return float(abs(diff))


def angle_to_normal_deg(direction: np.ndarray, normal: np.ndarray = (0.0, 0.0, 1.0)) -> float:
    """The method's own figure: sign-free angle between an axis and the table normal, degrees."""
    return axis_angle_error_deg(direction, np.asarray(normal, dtype=float))


def rotation_error_deg(R_pred: np.ndarray, R_true: np.ndarray) -> float:
    """Geodesic angle between two rotation matrices (3, 3), degrees."""
    R_pred = np.asarray(R_pred, dtype=float)
    R_true = np.asarray(R_true, dtype=float)
    if R_pred.shape != (3, 3) or R_true.shape != (3, 3):
        raise ValueError(f"expected (3, 3) rotations, got {R_pred.shape} and {R_true.shape}")
    c = (np.trace(R_pred.T @ R_true) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def segmentation_accuracy(labels_pred: np.ndarray, labels_true: np.ndarray) -> float:
    """Share of points whose predicted link is the true one, after the best one-to-one matching
    of predicted to true link labels (Hungarian on the confusion matrix).

    Points predicted as outliers (label < 0) count as wrong; points without a true label
    (label < 0, e.g. background) are left out.

    Parameters
    ----------
    labels_pred, labels_true : (n,) int
    """
    p = np.asarray(labels_pred).astype(int)
    t = np.asarray(labels_true).astype(int)
    if p.shape != t.shape or p.ndim != 1:
        raise ValueError(f"expected two (n,) label arrays, got {p.shape} and {t.shape}")
    keep = t >= 0
    p, t = p[keep], t[keep]
    if len(t) == 0:
        raise ValueError("no point has a true link label: nothing to score")
    pred_ids = np.unique(p[p >= 0])
    true_ids = np.unique(t)
    if len(pred_ids) == 0:
        return 0.0
    confusion = np.array([[np.sum((p == a) & (t == b)) for b in true_ids] for a in pred_ids])
    rows, cols = linear_sum_assignment(-confusion)
    return float(confusion[rows, cols].sum() / len(t))


def accuracy_completeness(points_pred: np.ndarray, surface_samples: np.ndarray,
                          radius: float = COMPLETENESS_RADIUS_M) -> dict[str, float]:
    """Model accuracy and completeness against densely sampled true surfaces.

    Parameters
    ----------
    points_pred : (n, 3) float
        Reconstructed points, metric, world frame.
    surface_samples : (m, 3) float
        Points sampled densely (spacing well under ``radius``) on the true surfaces.
    radius : float
        Coverage threshold in metres.

    Returns
    -------
    dict with ``accuracy_median_mm`` (median distance of the prediction to the surface),
    ``accuracy_p90_mm``, ``completeness`` (share of surface samples within ``radius`` of a
    predicted point).
    """
    P = np.asarray(points_pred, dtype=float)
    S = np.asarray(surface_samples, dtype=float)
    for name, arr in (("points_pred", P), ("surface_samples", S)):
        if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0:
            raise ValueError(f"{name}: expected a non-empty (n, 3) array, got {arr.shape}")
    d_pred, _ = cKDTree(S).query(P)
    d_surf, _ = cKDTree(P).query(S)
    return {
        "accuracy_median_mm": float(np.median(d_pred) * 1e3),
        "accuracy_p90_mm": float(np.percentile(d_pred, 90) * 1e3),
        "completeness": float(np.mean(d_surf <= radius)),
    }


#: Joint matching cost (:func:`match_joints`): degrees of axis angle and millimetres of axis
#: position are scaled by the gates of the evaluation (2 deg, 5 mm) so that both count alike; a
#: type mismatch costs more than any plausible geometric error, so a pair of the right type wins.
MATCH_ANGLE_SCALE_DEG = 2.0
MATCH_POSITION_SCALE_MM = 5.0
MATCH_TYPE_MISMATCH_COST = 1000.0


def joint_match_cost(type_pred: str, point_pred: np.ndarray, direction_pred: np.ndarray,
                     type_true: str, point_true: np.ndarray, direction_true: np.ndarray) -> float:
    """Cost of pairing an estimated joint with a true one (inputs in metres).

    ``angle_deg / 2 + position_mm / 5 (revolute pairs only) + 1000 * (types differ)``; the axis
    position of a prismatic joint has no meaning (any parallel line moves the link alike), so
    it does not count when either joint is prismatic.
    """
    cost = axis_angle_error_deg(direction_pred, direction_true) / MATCH_ANGLE_SCALE_DEG
    if type_pred == "revolute" and type_true == "revolute":
        cost += 1e3 * line_distance(point_pred, direction_pred, point_true, direction_true) \
            / MATCH_POSITION_SCALE_MM
    if type_pred != type_true:
        cost += MATCH_TYPE_MISMATCH_COST
    return float(cost)


def match_joints(pred: list[tuple[str, np.ndarray, np.ndarray]],
                 true: list[tuple[str, np.ndarray, np.ndarray]]) -> list[tuple[int, int]]:
    """One-to-one pairing of estimated to true joints minimising :func:`joint_match_cost`
    (Hungarian). Each joint is ``(type, point (3,), direction (3,))``.

    Returns
    -------
    pairs : list of (pred index, true index)
        ``min(len(pred), len(true))`` pairs, sorted by true index; the joints left out are
        missed (true) or invented (pred).
    """
    if not pred or not true:
        return []
    cost = np.array([[joint_match_cost(tp, pp, dp, tt, pt, dt) for tt, pt, dt in true]
                     for tp, pp, dp in pred])
    rows, cols = linear_sum_assignment(cost)
    return sorted(((int(r), int(c)) for r, c in zip(rows, cols, strict=True)),
                  key=lambda rc: rc[1])


def camera_pose_errors(T_pred: np.ndarray, T_true: np.ndarray) -> dict[str, float]:
    """Camera pose errors of estimated against true ``T_world_camera`` (n, 4, 4), metres.

    Returns
    -------
    dict with ``position_median_mm``, ``position_max_mm``, ``rotation_median_deg``,
    ``rotation_max_deg`` and ``n``.
    """
    P = np.asarray(T_pred, dtype=float)
    T = np.asarray(T_true, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or P.shape != T.shape or len(P) == 0:
        raise ValueError(f"expected two non-empty (n, 4, 4) pose arrays of the same shape, got "
                         f"{P.shape} and {T.shape}")
    dp = np.linalg.norm(P[:, :3, 3] - T[:, :3, 3], axis=1) * 1e3
    dr = np.array([rotation_error_deg(a[:3, :3], b[:3, :3]) for a, b in zip(P, T, strict=True)])
    return {"position_median_mm": float(np.median(dp)), "position_max_mm": float(dp.max()),
            "rotation_median_deg": float(np.median(dr)), "rotation_max_deg": float(dr.max()),
            "n": int(len(P))}


#: A surface sample counts as seen by a camera when it lies no more than this behind the rendered
#: depth (m): the depth image is quantised to 0.1 mm and a sample lies on a triangle that is
#: rasterised at pixel centres, so 3 mm absorbs grazing angles without letting a 1 cm wall through.
VISIBILITY_DEPTH_TOLERANCE_M = 0.003


def visible_from_camera(points: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray,
                        depth: np.ndarray,
                        tolerance: float = VISIBILITY_DEPTH_TOLERANCE_M) -> np.ndarray:
    """Which points a camera sees: inside the image, in front, and not behind the rendered depth.

    Parameters
    ----------
    points : (n, 3) float
        World points (m).
    K : (3, 3) float
        OpenCV intrinsics.
    T_world_camera : (4, 4) float
        Camera pose, OpenCV convention.
    depth : (h, w) float
        Depth along the optical axis (m) of the same camera, 0 where nothing was rendered.
    tolerance : float
        How far behind the depth a point may lie and still count as seen (m).

    Returns
    -------
    visible : (n,) bool
    """
    X = np.asarray(points, dtype=float)
    K = np.asarray(K, dtype=float)
    T = np.asarray(T_world_camera, dtype=float)
    depth = np.asarray(depth, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"points: expected shape (n, 3), got {X.shape}")
    if K.shape != (3, 3) or T.shape != (4, 4) or depth.ndim != 2:
        raise ValueError(f"expected K (3, 3), T_world_camera (4, 4), depth (h, w); got "
                         f"{K.shape}, {T.shape}, {depth.shape}")
    Rt = T[:3, :3].T
    Xc = (X - T[:3, 3]) @ Rt.T
    z = Xc[:, 2]
    front = z > 1e-9
    uv = (Xc @ K.T)[:, :2] / np.where(front, z, 1.0)[:, None]
    u = np.round(uv[:, 0]).astype(np.int64)
    v = np.round(uv[:, 1]).astype(np.int64)
    h, w = depth.shape
    inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    out = np.zeros(len(X), dtype=bool)
    d = depth[v[inside], u[inside]]
    out[inside] = (d > 0) & (z[inside] <= d + tolerance)
    return out


def rendered_labels(points: np.ndarray, views, n_labels: int,
                    tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """True label of world points from rendered label images: the label that most of the views
    seeing a point show at its pixel.

    A view sees a point when the point projects into the image in front of the camera and lies
    within ``tolerance`` of the rendered depth at its pixel (nearer: the view saw free space
    there; farther: something hid the point). A point that no view sees, or whose majority label
    is not an object link (the table, the arm, the room), gets -1.

    Parameters
    ----------
    points : (n, 3) float
        World points (m), in the configuration the views show.
    views : iterable of (K, T_world_camera, depth, labels)
        OpenCV intrinsics (3, 3), camera pose (4, 4), rendered depth (h, w) in m (0: nothing),
        rendered labels (h, w) int: the object link at each pixel, < 0 for anything else.
    n_labels : int
        Number of object links (labels 0 .. n_labels - 1).
    tolerance : float
        Depth band (m).

    Returns
    -------
    labels : (n,) int
    votes : (n,) int
        How many views saw each point.
    """
    X = np.asarray(points, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"points: expected shape (n, 3), got {X.shape}")
    counts = np.zeros((len(X), n_labels + 1), dtype=np.int32)  # last column: not the object
    for K, T_world_camera, depth, labels in views:
        K, T = np.asarray(K, float), np.asarray(T_world_camera, float)
        depth, labels = np.asarray(depth, float), np.asarray(labels)
        if depth.shape != labels.shape or depth.ndim != 2:
            raise ValueError(f"depth and labels must be one (h, w) shape, got {depth.shape} and "
                             f"{labels.shape}")
        Xc = (X - T[:3, 3]) @ T[:3, :3]
        z = Xc[:, 2]
        front = z > 1e-9
        uv = (Xc @ K.T)[:, :2] / np.where(front, z, 1.0)[:, None]
        u, v = np.round(uv[:, 0]), np.round(uv[:, 1])
        h, w = depth.shape
        inside = np.flatnonzero(front & (u >= 0) & (u < w) & (v >= 0) & (v < h))
        ui, vi = u[inside].astype(np.int64), v[inside].astype(np.int64)
        d = depth[vi, ui]
        seen = (d > 0) & (np.abs(z[inside] - d) <= tolerance)
        lab = labels[vi[seen], ui[seen]].astype(np.int64)
        lab = np.where((lab >= 0) & (lab < n_labels), lab, n_labels)
        np.add.at(counts, (inside[seen], lab), 1)
    votes = counts.sum(axis=1)
    best = counts.argmax(axis=1)
    out = np.where((votes > 0) & (best < n_labels), best, -1)
    return out.astype(int), votes.astype(int)


def accuracy_completeness_on(points_pred: np.ndarray, surface_samples: np.ndarray,
                             mask: np.ndarray,
                             radius: float = COMPLETENESS_RADIUS_M) -> dict[str, float]:
    """:func:`accuracy_completeness` restricted to a part of the true surface (e.g. the side a
    camera cannot see).

    Completeness is the share of the samples in ``mask`` within ``radius`` of a predicted point;
    accuracy is taken over the predicted points whose nearest sample (among all samples) lies in
    ``mask``. Values are NaN where the part or its points are empty; ``n_samples`` and
    ``n_points`` say how many there were.

    Parameters
    ----------
    points_pred : (n, 3) float
    surface_samples : (m, 3) float
    mask : (m,) bool
        The part of the surface to score.
    radius : float
    """
    P = np.asarray(points_pred, dtype=float)
    S = np.asarray(surface_samples, dtype=float)
    mask = np.asarray(mask, dtype=bool)
    for name, arr in (("points_pred", P), ("surface_samples", S)):
        if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0:
            raise ValueError(f"{name}: expected a non-empty (n, 3) array, got {arr.shape}")
    if mask.shape != (len(S),):
        raise ValueError(f"mask: expected shape ({len(S)},), got {mask.shape}")
    d_pred, nearest = cKDTree(S).query(P)
    d_surf, _ = cKDTree(P).query(S[mask]) if mask.any() else (np.zeros(0), None)
    on = mask[nearest]
    return {
        "accuracy_median_mm": float(np.median(d_pred[on]) * 1e3) if on.any() else float("nan"),
        "accuracy_p90_mm": (float(np.percentile(d_pred[on], 90) * 1e3) if on.any()
                            else float("nan")),
        "completeness": float(np.mean(d_surf <= radius)) if mask.any() else float("nan"),
        "n_samples": int(mask.sum()),
        "n_points": int(on.sum()),
    }


def nearest_labels(points: np.ndarray, samples: np.ndarray, sample_labels: np.ndarray,
                   max_distance: float) -> np.ndarray:
    """Label of the nearest sample of every point, -1 where none lies within ``max_distance``.

    Parameters
    ----------
    points : (n, 3) float
    samples : (m, 3) float
    sample_labels : (m,) int
    max_distance : float
    """
    P = np.asarray(points, dtype=float)
    S = np.asarray(samples, dtype=float)
    L = np.asarray(sample_labels)
    if P.ndim != 2 or P.shape[1] != 3 or S.ndim != 2 or S.shape[1] != 3 or L.shape != (len(S),):
        raise ValueError(f"expected points (n, 3), samples (m, 3), sample_labels (m,); got "
                         f"{P.shape}, {S.shape}, {L.shape}")
    if len(P) == 0:
        return np.zeros(0, dtype=int)
    d, i = cKDTree(S).query(P)
    return np.where(d <= max_distance, L[i], -1).astype(int)
