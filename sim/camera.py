"""Camera conventions: the one place where OpenGL/MuJoCo and OpenCV camera frames meet.

MuJoCo and pyrender cameras look down -z with +y up (OpenGL). OpenCV and COLMAP cameras look
down +z with +y down. Both frames share the origin and the x axis; they differ by a rotation of
pi about x. Every conversion in the harness goes through :func:`convert_camera_pose`.
"""

from __future__ import annotations

import mujoco
import numpy as np

#: Maps OpenCV camera coordinates to OpenGL camera coordinates (and back: it is its own inverse).
T_GL_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def convert_camera_pose(T_world_camera: np.ndarray) -> np.ndarray:
    """Convert a camera pose between the OpenGL and the OpenCV camera convention.

    The map is an involution: it turns ``T_world_glcamera`` into ``T_world_cvcamera`` and
    ``T_world_cvcamera`` into ``T_world_glcamera``.

    Parameters
    ----------
    T_world_camera : (4, 4) float
        Pose of the camera in the world, in one convention.

    Returns
    -------
    T_world_camera : (4, 4) float
        The same camera in the other convention.
    """
    T = np.asarray(T_world_camera, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"expected a (4, 4) pose matrix, got shape {T.shape}")
    return T @ T_GL_CV


def true_camera_pose(data, cam_id: int) -> np.ndarray:
    """T_world_camera : (4, 4) float, the pose of MuJoCo camera ``cam_id`` in ``data`` (after
    ``mj_forward``), OpenCV convention: where the simulator renders it from."""
    return convert_camera_pose(np.r_[np.c_[data.cam_xmat[cam_id].reshape(3, 3),
                                           data.cam_xpos[cam_id]], [[0, 0, 0, 1]]])


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Pinhole matrix ``K`` : (3, 3) float from focal lengths and principal point in pixels."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def mujoco_camera_intrinsics(model, camera: str | int) -> tuple[np.ndarray, tuple[int, int]]:
    """Intrinsics of a MuJoCo camera in OpenCV form.

    Parameters
    ----------
    model : mujoco.MjModel
    camera : str or int
        Camera name or id.

    Returns
    -------
    K : (3, 3) float
        Pinhole matrix in pixels (OpenCV convention, pixel centres at integer coordinates).
    size : (width, height)
        Image size in pixels from the camera's ``resolution`` attribute.
    """
    cam_id = camera if isinstance(camera, int) else mujoco.mj_name2id(
        model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
    if cam_id < 0:
        raise ValueError(f"no camera named {camera!r} in the model")
    width, height = (int(v) for v in model.cam_resolution[cam_id])
    sensor = model.cam_sensorsize[cam_id]
    if sensor[0] > 0 and sensor[1] > 0:
        # Explicit intrinsics: focal length and principal point in length units on the sensor.
        fx_len, fy_len, cx_len, cy_len = model.cam_intrinsic[cam_id]
        fx = fx_len / sensor[0] * width
        fy = fy_len / sensor[1] * height
        # MuJoCo's principal point is an offset from the sensor centre, +y up.
        cx = width / 2.0 + cx_len / sensor[0] * width
        cy = height / 2.0 - cy_len / sensor[1] * height
    else:
        fovy = np.deg2rad(model.cam_fovy[cam_id])
        fy = height / 2.0 / np.tan(fovy / 2.0)
        fx = fy
        cx, cy = width / 2.0, height / 2.0
    # MuJoCo/OpenGL measure the principal point from the image corner at pixel edges; OpenCV
    # puts pixel centres at integer coordinates: shift by half a pixel.
    return intrinsics_matrix(fx, fy, cx - 0.5, cy - 0.5), (width, height)
