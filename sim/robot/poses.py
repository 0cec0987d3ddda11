"""Camera poses for viewing an object: looking at a point, rings around it."""

from __future__ import annotations

import numpy as np

# ----------------------------------------------------------------------------------------------
# Camera geometry helpers
# ----------------------------------------------------------------------------------------------


def look_at_pose(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera pose (OpenCV convention) at ``eye`` looking at ``target``, image "up" towards ``up``.

    Parameters
    ----------
    eye, target, up : (3,) float
        Camera centre, the point on the optical axis, and the world direction that appears upwards
        in the image (``-y`` of the camera lies in the plane of ``up`` and the optical axis).

    Returns
    -------
    T_world_camera : (4, 4) float
    """
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    for name, v in (("eye", eye), ("target", target), ("up", up)):
        if v.shape != (3,):
            raise ValueError(f"look_at_pose: expected {name} of shape (3,), got {v.shape}")
    z = target - eye
    if np.linalg.norm(z) < 1e-12:
        raise ValueError("look_at_pose: eye and target coincide; give distinct points")
    z /= np.linalg.norm(z)
    y = -(up - np.dot(up, z) * z)
    if np.linalg.norm(y) < 1e-9:
        raise ValueError("look_at_pose: up is parallel to the viewing direction; pass another up")
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


def ring_camera_poses(target, distance: float, elevation: float, n: int,
                      azimuth0: float = 0.0) -> np.ndarray:
    """Cameras on a horizontal ring around ``target``, all looking at it (OpenCV convention).

    Parameters
    ----------
    target : (3,) float
        The point every camera looks at (world frame).
    distance : float
        Camera centre to target (m).
    elevation : float
        Angle of the camera above the target's horizontal plane (rad).
    n : int
        Number of views, equally spaced in azimuth.
    azimuth0 : float
        Azimuth of the first view (rad), measured about world z from world x.

    Returns
    -------
    T_world_cameras : (n, 4, 4) float
    """
    target = np.asarray(target, dtype=float)
    if target.shape != (3,):
        raise ValueError(f"ring_camera_poses: expected target of shape (3,), got {target.shape}")
    out = np.empty((n, 4, 4))
    for i, az in enumerate(azimuth0 + 2.0 * np.pi * np.arange(n) / n):
        direction = np.array([np.cos(elevation) * np.cos(az), np.cos(elevation) * np.sin(az),
                              np.sin(elevation)])
        out[i] = look_at_pose(target + distance * direction, target)
    return out
