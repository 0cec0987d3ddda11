"""sim.camera: the OpenGL <-> OpenCV camera conversion and MuJoCo camera intrinsics."""

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sim.camera import convert_camera_pose, intrinsics_matrix, mujoco_camera_intrinsics


def _random_pose(rng):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.uniform(-2, 2, 3)
    return T


def test_conversion_is_an_involution():
    rng = np.random.default_rng(0)
    for _ in range(20):
        T = _random_pose(rng)
        once = convert_camera_pose(T)
        assert not np.allclose(once, T)
        np.testing.assert_allclose(convert_camera_pose(once), T, atol=1e-12)
        # still a rigid transform with the same centre
        np.testing.assert_allclose(once[:3, :3] @ once[:3, :3].T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(once[:3, :3]), 1.0, atol=1e-12)
        np.testing.assert_allclose(once[:3, 3], T[:3, 3])


def test_point_in_front_of_gl_camera_is_in_front_of_cv_camera():
    rng = np.random.default_rng(1)
    for _ in range(20):
        T_world_gl = _random_pose(rng)
        p_gl = np.r_[rng.uniform(-1, 1, 2), -rng.uniform(0.1, 3.0), 1.0]  # in front: z < 0
        p_world = T_world_gl @ p_gl
        T_world_cv = convert_camera_pose(T_world_gl)
        p_cv = np.linalg.inv(T_world_cv) @ p_world
        assert p_cv[2] > 0
        np.testing.assert_allclose(p_cv[:3], [p_gl[0], -p_gl[1], -p_gl[2]], atol=1e-12)


def test_conversion_rejects_bad_shape():
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        convert_camera_pose(np.eye(3))


def _camera_model(cam_attrs: str) -> mujoco.MjModel:
    xml = f"""<mujoco><worldbody>
      <body pos="0.1 0.2 0.3" euler="10 20 30">
        <camera name="cam" {cam_attrs}/>
      </body>
    </worldbody></mujoco>"""
    return mujoco.MjModel.from_xml_string(xml)


def _project(K, T_world_cv, p_world):
    p = np.linalg.inv(T_world_cv) @ np.r_[p_world, 1.0]
    uv = K @ p[:3]
    return uv[:2] / uv[2]


def test_fovy_camera_intrinsics_put_the_fov_edge_on_the_image_edge():
    model = _camera_model('fovy="60" resolution="64 48"')
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    K, (w, h) = mujoco_camera_intrinsics(model, "cam")
    assert (w, h) == (64, 48)
    T_world_gl = np.eye(4)
    T_world_gl[:3, :3] = data.cam_xmat[0].reshape(3, 3)
    T_world_gl[:3, 3] = data.cam_xpos[0]
    T_world_cv = convert_camera_pose(T_world_gl)
    # MuJoCo looks down the camera's -z; a ray fovy/2 above the axis meets the top image edge,
    # which is v = -0.5 when pixel centres are at integer coordinates.
    half = np.deg2rad(30.0)
    for dist in (0.5, 2.0):
        top = T_world_gl @ np.r_[0.0, np.tan(half) * dist, -dist, 1.0]
        u, v = _project(K, T_world_cv, top[:3])
        np.testing.assert_allclose([u, v], [(w - 1) / 2, -0.5], atol=1e-9)
        bottom = T_world_gl @ np.r_[0.0, -np.tan(half) * dist, -dist, 1.0]
        np.testing.assert_allclose(_project(K, T_world_cv, bottom[:3])[1], h - 0.5, atol=1e-9)
        # square pixels: the horizontal edge is at the same focal length
        right = T_world_gl @ np.r_[np.tan(half) * dist * w / h, 0.0, -dist, 1.0]
        np.testing.assert_allclose(_project(K, T_world_cv, right[:3])[0], w - 0.5, atol=1e-9)


def test_sensor_camera_intrinsics_match_focal_length_and_principal_point():
    # 8 mm focal length on a 6.4 x 4.8 mm sensor at 640 x 480: 800 px; principal point offset
    # 0.32 mm right and 0.24 mm up of the sensor centre: +32 px in u, -24 px in v.
    model = _camera_model('resolution="640 480" sensorsize="0.0064 0.0048" '
                          'focal="0.008 0.008" principal="0.00032 0.00024"')
    K, size = mujoco_camera_intrinsics(model, 0)
    assert size == (640, 480)
    np.testing.assert_allclose(K, intrinsics_matrix(800, 800, 320 + 32 - 0.5, 240 - 24 - 0.5))
    # MuJoCo derives the vertical field of view from the same numbers
    fovy = np.deg2rad(model.cam_fovy[0])
    np.testing.assert_allclose(K[1, 1], 240 / np.tan(fovy / 2), rtol=1e-6)


def test_unknown_camera_is_a_clear_error():
    model = _camera_model('fovy="45"')
    with pytest.raises(ValueError, match="no camera named 'nope'"):
        mujoco_camera_intrinsics(model, "nope")
