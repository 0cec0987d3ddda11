"""What a render gives: the colour image and, for scoring, metric depth and the label of the geom
at every pixel; and depth back to world points (:func:`backproject`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Label of pixels that show no geom at all.
LABEL_BACKGROUND = -1

#: Label codes are stored in a 24-bit flat colour as ``label + LABEL_OFFSET``; colour 0 (the
#: cleared buffer) is the background, so labels must lie in (-LABEL_OFFSET, LABEL_OFFSET).
LABEL_OFFSET = 1 << 23

#: Near/far clipping distances (m). With a 24-bit depth buffer the depth resolution at distance
#: d is about d**2 / (znear * 2**24): 0.4 um at 1 m with znear = 0.15, far below the 1 mm
#: back-projection tolerance; the wrist camera never sees anything closer than 15 cm.
ZNEAR = 0.15
ZFAR = 30.0


@dataclass
class RenderOutput:
    """One rendered view.

    Attributes
    ----------
    color : (h, w, 3) uint8
        RGB image.
    depth : (h, w) float32 or None
        Metric depth along the optical axis (z of the OpenCV camera frame), 0 where no surface.
    labels : (h, w) int32 or None
        Per-pixel label of the geom seen there (see ``geom_labels`` of :class:`MjRenderer`),
        ``LABEL_BACKGROUND`` where no surface.
    """

    color: np.ndarray
    depth: np.ndarray | None = None
    labels: np.ndarray | None = None


def check_K(K: np.ndarray) -> np.ndarray:
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3):
        raise ValueError(f"expected intrinsics K of shape (3, 3), got {K.shape}")
    if K[0, 1] != 0.0 or np.any(K[2] != [0.0, 0.0, 1.0]) or K[1, 0] != 0.0:
        raise ValueError(f"expected a pinhole K without skew ([[fx,0,cx],[0,fy,cy],[0,0,1]]), "
                         f"got {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
    return K


def backproject(depth: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray,
                mask: np.ndarray | None = None) -> np.ndarray:
    """World points of the pixels of a depth image.

    Parameters
    ----------
    depth : (h, w) float
        Depth along the optical axis (OpenCV z), 0 where no surface.
    K : (3, 3) float
    T_world_camera : (4, 4) float, OpenCV convention.
    mask : (h, w) bool, optional
        Pixels to use (default: all with depth > 0).

    Returns
    -------
    points : (n, 3) float
        In row-major pixel order.
    """
    depth = np.asarray(depth, dtype=float)
    if depth.ndim != 2:
        raise ValueError(f"expected a (h, w) depth image, got shape {depth.shape}")
    K = check_K(K)
    sel = depth > 0 if mask is None else (np.asarray(mask, bool) & (depth > 0))
    v, u = np.nonzero(sel)
    z = depth[v, u]
    p_cam = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
    T = np.asarray(T_world_camera, dtype=float)
    return p_cam @ T[:3, :3].T + T[:3, 3]
