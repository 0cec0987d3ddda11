"""Registration: scale and robot frame from camera centres, PnP + hand-eye, their agreement.

Synthetic data with a known answer: a ring of eye-in-hand cameras (the PUMA's camera mount), a
known model-to-robot similarity, SfM-like noise on the model side, a few bad cameras; PnP on
projections of known points with pixel noise and wrong matches.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from artrecon.errors import DegenerateError, ReconstructionError
from artrecon.model import ArticulatedModel, Joint, Link
from artrecon.procrustes import Similarity, rotation_angle
from artrecon.register import (
    apply_registration,
    calibrate_hand_eye,
    compare_registrations,
    localize_image,
    metric_scale_from_length,
    register_by_pnp,
    register_camera_centres,
)
from sim.robot import PUMA560_T_FLANGE_CAMERA, look_at_pose

K = np.array([[554.26, 0.0, 319.5], [0.0, 554.26, 239.5], [0.0, 0.0, 1.0]])
TARGET = np.array([0.0, 0.0, 0.5])


def _truth(seed: int) -> Similarity:
    """A random model-to-robot similarity: SfM units are about 1/3 m."""
    rng = np.random.default_rng(seed)
    return Similarity(Rotation.random(random_state=seed).as_matrix(), rng.normal(0, 0.5, 3),
                      float(rng.uniform(0.2, 0.5)))


def _capture(seed: int, n: int = 36):
    """Eye-in-hand capture: camera poses on two rings, their flange poses, and the truth."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        az = 2 * np.pi * i / n
        el = np.deg2rad(25.0 if i % 2 else 50.0)
        d = 0.45 + 0.1 * rng.random()
        eye = TARGET + d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        T = look_at_pose(eye, TARGET + rng.normal(0, 0.02, 3))
        roll = Rotation.from_rotvec([0, 0, rng.uniform(-0.4, 0.4)]).as_matrix()
        T[:3, :3] = T[:3, :3] @ roll
        cams.append(T)
    T_robot_camera = np.array(cams)
    X = PUMA560_T_FLANGE_CAMERA
    T_robot_flange = np.array([T @ np.linalg.inv(X) for T in T_robot_camera])
    return T_robot_camera, T_robot_flange


def _to_model(truth: Similarity, T_robot_camera: np.ndarray, noise_m: float, seed: int):
    """SfM camera poses (model frame, model units) with position and rotation noise."""
    rng = np.random.default_rng(seed)
    inv = truth.inverse()
    out = []
    for T in T_robot_camera:
        M = np.eye(4)
        dR = Rotation.from_rotvec(rng.normal(0, 1e-4, 3)).as_matrix()
        M[:3, :3] = inv.rotation @ T[:3, :3] @ dR
        M[:3, 3] = inv.apply(T[:3, 3] + rng.normal(0, noise_m, 3))
        out.append(M)
    return np.array(out)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("as_poses", [True, False])
def test_camera_centres_recover_known_similarity(seed, as_poses):
    truth = _truth(seed)
    T_rc, _ = _capture(seed)
    T_mc = _to_model(truth, T_rc, noise_m=0.001, seed=seed)
    centres = T_mc[:, :3, 3].copy()
    bad = [3, 11, 20, 29]
    rng = np.random.default_rng(seed + 100)
    for b in bad:  # badly registered cameras: 5-15 cm off
        centres[b] += truth.inverse().scale * rng.uniform(0.05, 0.15) * Rotation.random(
            random_state=b).as_matrix()[:, 0]
    robot = T_rc if as_poses else T_rc[:, :3, 3]
    res = register_camera_centres(centres, robot, seed=seed)
    assert not res.inliers[bad].any()
    assert res.inliers.sum() == len(centres) - len(bad)
    cmp = compare_registrations(res.T_robot_model, truth, centres)
    assert cmp.max_translation_mm < 1.5
    assert cmp.rotation_deg < 0.2
    assert abs(cmp.scale_ratio - 1) < 2e-3
    assert 0.5 < res.rms * 1e3 < 2.5  # 1 mm per axis: rms of the norm about sqrt(3) mm


def test_camera_centres_errors():
    line = np.c_[np.arange(5.0), np.zeros(5), np.zeros(5)]
    with pytest.raises(DegenerateError):
        register_camera_centres(line, line)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        register_camera_centres(np.zeros((5, 2)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="same cameras"):
        register_camera_centres(np.zeros((5, 3)), np.zeros((4, 3)))
    rng = np.random.default_rng(0)
    with pytest.raises(DegenerateError, match="agree"):  # unrelated point sets
        register_camera_centres(rng.normal(size=(20, 3)), rng.normal(size=(20, 3)))


def _landmarks(seed: int, n: int = 400):
    """Model points (model units) with distinct random descriptors."""
    rng = np.random.default_rng(seed)
    X_robot = TARGET + rng.uniform(-0.12, 0.12, (n, 3))
    desc = rng.random((n, 128)).astype(np.float32) * 100
    return X_robot, desc


def _image(truth: Similarity, T_robot_camera, X_robot, desc, *, px_noise, outlier_fraction,
           seed):
    """Keypoints and descriptors of a fresh image: projections with noise, some wrong matches."""
    rng = np.random.default_rng(seed)
    Xc = (X_robot - T_robot_camera[:3, 3]) @ T_robot_camera[:3, :3]
    uv = Xc @ K.T
    uv = uv[:, :2] / uv[:, 2:3]
    keep = (Xc[:, 2] > 0) & (uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 480)
    idx = np.flatnonzero(keep)
    kp = uv[idx] + rng.normal(0, px_noise, (len(idx), 2))
    n_bad = int(outlier_fraction * len(idx))
    kp[:n_bad] = rng.uniform([0, 0], [640, 480], (n_bad, 2))  # descriptor matches, wrong place
    d = desc[idx] + rng.normal(0, 2.0, (len(idx), 128)).astype(np.float32)
    return kp, d


@pytest.mark.parametrize("seed", [0, 1])
def test_pnp_recovers_pose_up_to_scale(seed):
    truth = _truth(seed)
    X_robot, desc = _landmarks(seed)
    T_rc = look_at_pose(TARGET + [0.35, 0.2, 0.3], TARGET)
    kp, d = _image(truth, T_rc, X_robot, desc, px_noise=0.5, outlier_fraction=0.3, seed=seed)
    X_model = truth.inverse().apply(X_robot)
    res = localize_image(kp, d, X_model, desc, K, seed=seed)
    # truth: p_cam (metres) = T_camera_robot @ truth @ p_model; PnP's translation is in model units
    T_cr = np.linalg.inv(T_rc)
    R_true = T_cr[:3, :3] @ truth.rotation
    t_true = (T_cr[:3, :3] @ truth.translation + T_cr[:3, 3]) / truth.scale
    assert np.rad2deg(rotation_angle(res.T_camera_model[:3, :3].T @ R_true)) < 0.1
    assert np.linalg.norm(res.T_camera_model[:3, 3] - t_true) < 2e-3 * np.linalg.norm(t_true)
    assert res.reprojection_rms < 1.0
    assert res.inliers.sum() >= 0.6 * len(kp)


def test_pnp_too_few_matches():
    rng = np.random.default_rng(0)
    with pytest.raises(ReconstructionError, match="descriptor matches"):
        localize_image(rng.uniform(0, 400, (5, 2)), rng.random((5, 128)), rng.random((50, 3)),
                       rng.random((50, 128)), K)


@pytest.mark.parametrize("seed", [0, 1])
def test_hand_eye_recovers_known_mount(seed):
    truth = _truth(seed)
    T_rc, T_rf = _capture(seed)
    T_mc = _to_model(truth, T_rc, noise_m=0.0005, seed=seed)
    he = calibrate_hand_eye(T_rf, T_mc, truth.scale)
    X = PUMA560_T_FLANGE_CAMERA
    assert np.linalg.norm(he.T_flange_camera[:3, 3] - X[:3, 3]) < 2e-3
    assert np.rad2deg(rotation_angle(he.T_flange_camera[:3, :3].T @ X[:3, :3])) < 0.1
    assert he.translation_residual_mm < 2.0
    # exact data: exact answer
    T_mc0 = _to_model(truth, T_rc, noise_m=0.0, seed=seed)
    T_mc0[:, :3, :3] = np.einsum("ij,njk->nik", truth.inverse().rotation, T_rc[:, :3, :3])
    he0 = calibrate_hand_eye(T_rf, T_mc0, truth.scale)
    np.testing.assert_allclose(he0.T_flange_camera, X, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hand_eye_estimates_the_scale_with_the_mount(seed):
    """Without a scale, the flange's metric motions give it: the paper's route needs no other
    source of scale than the robot."""
    truth = _truth(seed)
    T_rc, T_rf = _capture(seed)
    T_mc = _to_model(truth, T_rc, noise_m=0.0005, seed=seed)
    he = calibrate_hand_eye(T_rf, T_mc)
    assert he.scale_estimated
    assert abs(he.scale / truth.scale - 1.0) < 0.005
    X = PUMA560_T_FLANGE_CAMERA
    # 0.5 mm of camera noise: the mount's offset along the optical axis trades with the scale
    assert np.linalg.norm(he.T_flange_camera[:3, 3] - X[:3, 3]) < 3e-3
    assert np.rad2deg(rotation_angle(he.T_flange_camera[:3, :3].T @ X[:3, :3])) < 0.1
    # the same data with the scale given agrees
    given = calibrate_hand_eye(T_rf, T_mc, truth.scale)
    assert not given.scale_estimated and given.scale == truth.scale
    assert np.linalg.norm(given.T_flange_camera[:3, 3] - he.T_flange_camera[:3, 3]) < 3e-3


def test_hand_eye_refuses_camera_poses_that_do_not_follow_the_flange():
    """Camera poses of other images (here: shuffled) give no positive scale or an inconsistent
    mount; the estimate must not be silently returned as good."""
    truth = _truth(4)
    T_rc, T_rf = _capture(4)
    T_mc = _to_model(truth, T_rc, noise_m=0.0005, seed=4)
    rng = np.random.default_rng(0)
    shuffled = T_mc[rng.permutation(len(T_mc))]
    try:
        he = calibrate_hand_eye(T_rf, shuffled)
    except DegenerateError:
        return
    assert he.translation_residual_mm > 20.0 or he.rotation_residual_deg > 5.0


def test_hand_eye_needs_rotation():
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, 0, 3] = np.arange(5) * 0.1
    with pytest.raises(DegenerateError):
        calibrate_hand_eye(T, T, 1.0)


@pytest.mark.parametrize("seed", [0, 3])
def test_both_routes_agree(seed):
    """Route (a) and route (b) (hand-eye + PnP with (a)'s scale) on the same synthetic data."""
    truth = _truth(seed)
    T_rc, T_rf = _capture(seed)
    T_mc = _to_model(truth, T_rc, noise_m=0.001, seed=seed)
    a = register_camera_centres(T_mc[:, :3, 3], T_rc, seed=seed)
    he = calibrate_hand_eye(T_rf, T_mc, a.T_robot_model.scale)
    X_robot, desc = _landmarks(seed)
    T_rc_now = look_at_pose(TARGET + [-0.3, 0.3, 0.25], TARGET)
    kp, d = _image(truth, T_rc_now, X_robot, desc, px_noise=0.5, outlier_fraction=0.2, seed=seed)
    pnp = localize_image(kp, d, truth.inverse().apply(X_robot), desc, K, seed=seed)
    b = register_by_pnp(T_rc_now @ np.linalg.inv(PUMA560_T_FLANGE_CAMERA), he.T_flange_camera,
                        pnp.T_camera_model, a.T_robot_model.scale)
    X_model = truth.inverse().apply(X_robot)
    ab = compare_registrations(a.T_robot_model, b, X_model)
    assert ab.translation_mm < 3.0 and ab.rotation_deg < 0.3
    for est in (a.T_robot_model, b):
        err = compare_registrations(est, truth, X_model)
        assert err.translation_mm < 3.0 and err.rotation_deg < 0.3


def test_metric_scale_from_length():
    assert metric_scale_from_length(0.3, [0, 0, 0], [0, 2.0, 0]) == pytest.approx(0.15)
    with pytest.raises(DegenerateError):
        metric_scale_from_length(0.3, [1, 1, 1], [1, 1, 1])


def _model() -> ArticulatedModel:
    rng = np.random.default_rng(5)
    links = [Link(rng.normal(size=(30, 3)), np.arange(30), normals=np.tile([0, 0, 1.0], (30, 1))),
             Link(rng.normal(size=(20, 3)) + 3, np.arange(20)),
             Link(rng.normal(size=(10, 3)) - 3, np.arange(10))]
    joints = [Joint("revolute", [0, 0, 1], [1, 2, 3], 0, 1, 0.0, 0.5),
              Joint("prismatic", [1, 0, 0], [0, 1, 0], 0, 2, 0.0, 2.0, residual=0.01)]
    return ArticulatedModel(links, joints, frames={"T_world_model": np.eye(4)})


def test_apply_registration_maps_everything():
    model = _model()
    T = _truth(7)
    reg = apply_registration(model, T)
    np.testing.assert_allclose(reg.links[1].points, T.apply(model.links[1].points))
    np.testing.assert_allclose(reg.links[0].normals, model.links[0].normals @ T.rotation.T)
    rev, pri = reg.joints
    np.testing.assert_allclose(rev.axis_direction, T.rotation @ [0, 0, 1])
    np.testing.assert_allclose(rev.axis_point, T.apply(np.array([1.0, 2, 3])))
    assert rev.state_b == 0.5  # angles keep their value
    assert pri.state_b == pytest.approx(2.0 * T.scale)
    assert pri.residual == pytest.approx(0.01 * T.scale)
    assert reg.scale_known and reg.scale == 1.0
    np.testing.assert_allclose(reg.frames["T_robot_sfm"], T.matrix)
    np.testing.assert_allclose(reg.frames["T_world_model"], T.inverse().matrix, atol=1e-12)
    # a point of link 1 moved A->B in the model frame maps to the robot-frame A->B image
    p = model.links[1].points[:3]
    np.testing.assert_allclose(reg.links[1].transform_a_to_b.apply(T.apply(p)),
                               T.apply(model.links[1].transform_a_to_b.apply(p)), atol=1e-12)
    # input untouched, JSON round trip intact
    assert model.joints[1].state_b == 2.0 and not model.scale_known
    again = ArticulatedModel.from_dict(reg.to_dict())
    np.testing.assert_array_equal(again.links[2].points, reg.links[2].points)
    with pytest.raises(TypeError):
        apply_registration(model, T.matrix)


def test_fresh_view_keypoints_are_not_shifted():
    """PnP's keypoints turn with the image: those of the image rotated by 180 deg, mapped back
    (OpenCV's x -> width - 1 - x), land on the image's own; OpenCV's default upsampling put
    them 0.5 px apart (+0.25 px each, see artrecon.sfm.extraction._opencv_features)."""
    import cv2

    from artrecon.register.pnp import sift_features

    rng = np.random.default_rng(3)
    img = np.full((150, 200), 128, np.float32)
    for _ in range(60):
        c = (int(rng.integers(0, 200)), int(rng.integers(0, 150)))
        cv2.circle(img, c, int(rng.integers(2, 14)), float(rng.integers(0, 256)), -1)
    img = np.clip(cv2.GaussianBlur(img, (0, 0), 1.2), 0, 255).astype(np.uint8)
    own, _ = sift_features(img)
    turned, _ = sift_features(img[::-1, ::-1].copy())
    back = np.array([199.0, 149.0]) - turned
    d = np.linalg.norm(own[:, None] - back[None], axis=2)
    j = d.argmin(axis=1)
    close = d[np.arange(len(own)), j] < 0.75
    assert close.sum() > 20
    np.testing.assert_allclose(np.median(own[close] - back[j[close]], axis=0), 0.0, atol=0.05)
