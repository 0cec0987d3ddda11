"""The one copy of the small rotation and pose helpers (artrecon and sim both use these).

Conventions (see DESIGN.md): metres and radians; poses are (4, 4) homogeneous matrices named
``T_a_b`` (``p_a = T_a_b @ p_b``); quaternions in MuJoCo's order (w, x, y, z) unless a function
says otherwise.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "skew",
    "rotation_about",
    "rotation_angle",
    "log_so3",
    "exp_so3",
    "axis_angle",
    "quat_wxyz_to_matrix",
    "pose",
    "invert_pose",
    "transform_points",
    "point_spacing",
    "group_sums",
]


def skew(v) -> np.ndarray:
    """The (3, 3) cross-product matrix of a (3,) vector, ``skew(a) @ b == cross(a, b)``, or the
    (n, 3, 3) stack of an (n, 3) stack of vectors."""
    v = np.asarray(v, dtype=float)
    if v.shape[-1] != 3:
        raise ValueError(f"skew needs vectors of 3 components, got shape {v.shape}")
    out = np.zeros(v.shape + (3,))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    out[..., 0, 1], out[..., 0, 2] = -z, y
    out[..., 1, 0], out[..., 1, 2] = z, -x
    out[..., 2, 0], out[..., 2, 1] = -y, x
    return out


def rotation_about(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` (rad, right-handed) about ``axis`` (any length > 0)."""
    a = np.asarray(axis, dtype=float).reshape(3)
    n = np.linalg.norm(a)
    if not np.isfinite(n) or n == 0.0:
        raise ValueError(f"rotation axis must be a non-zero finite vector, got {a}")
    K = skew(a / n)
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def rotation_angle(rotation: np.ndarray) -> float:
    """Geodesic angle of a rotation matrix in [0, pi] (atan2 form: accurate near 0 and pi)."""
    r = np.asarray(rotation, dtype=float)
    if r.shape != (3, 3):
        raise ValueError(f"rotation must have shape (3, 3), got {r.shape}")
    s = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return float(np.arctan2(0.5 * np.linalg.norm(s), 0.5 * (np.trace(r) - 1.0)))


def log_so3(rotation: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of a rotation matrix (robust near 0; near pi via the eigenvector)."""
    R = np.asarray(rotation, dtype=float)
    angle = rotation_angle(R)
    if angle < 1e-12:
        return np.zeros(3)
    if np.pi - angle < 1e-6:
        w, v = np.linalg.eigh(0.5 * (R + R.T))
        return angle * v[:, np.argmax(w)]
    s = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return angle * s / np.linalg.norm(s)


def exp_so3(rotvec) -> np.ndarray:
    """(3, 3) rotation of a rotation vector (3,): by its length about it (the inverse of
    :func:`log_so3`); ``I + skew(w)`` below 1e-12 rad."""
    w = np.asarray(rotvec, dtype=float).reshape(3)
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        return np.eye(3) + skew(w)
    K = skew(w)
    return np.eye(3) + np.sin(theta) / theta * K + (1 - np.cos(theta)) / theta ** 2 * K @ K


def axis_angle(rotation: np.ndarray) -> tuple[np.ndarray, float]:
    """Unit axis (3,) and angle in [0, pi] of a rotation matrix; +z and 0 for the identity."""
    rotvec = log_so3(rotation)
    theta = float(np.linalg.norm(rotvec))
    if theta == 0.0:
        return np.array([0.0, 0.0, 1.0]), 0.0
    return rotvec / theta, theta


def quat_wxyz_to_matrix(quat) -> np.ndarray:
    """(3, 3) rotation of a quaternion in MuJoCo's order (w, x, y, z), normalised first."""
    q = np.asarray(quat, dtype=float).reshape(4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def pose(rotation: np.ndarray, translation) -> np.ndarray:
    """(4, 4) homogeneous pose from a (3, 3) rotation and a (3,) translation."""
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = np.asarray(translation, dtype=float).reshape(3)
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4, 4) pose, without a general matrix inverse."""
    R, t = T[:3, :3], T[:3, 3]
    return pose(R.T, -R.T @ t)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n, 3) points mapped by a (4, 4) pose: ``p_a = T_a_b @ p_b`` for each row of ``points``
    (given in frame b)."""
    T = np.asarray(T, dtype=float)
    return np.asarray(points, dtype=float) @ T[:3, :3].T + T[:3, 3]


def point_spacing(points: np.ndarray, tree: cKDTree | None = None) -> float:
    """Median distance of the points (n, 3) to their nearest neighbour: the sampling step of a
    dense point cloud, which the thresholds of its users are multiples of (0.0 for fewer than two
    points). ``tree``: a KD-tree of ``points`` already built."""
    if len(points) < 2:
        return 0.0
    d, _ = (cKDTree(points) if tree is None else tree).query(points, k=2)
    return float(np.median(d[:, 1]))


def group_sums(groups: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(n, k) float64 sums of the rows of ``values`` (m, k) by their group (``groups``: (m,) ints
    in [0, n)): ``np.add.at(out, groups, values)``, the same sums bit for bit (both add each
    group's rows in their order, in float64), by one ``np.bincount`` per column, several times
    faster than ``np.add.at`` on rows."""
    values = np.asarray(values)
    out = np.empty((n, values.shape[1]), np.float64)
    for c in range(values.shape[1]):
        out[:, c] = np.bincount(groups, weights=values[:, c], minlength=n)
    return out
