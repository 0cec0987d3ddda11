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
