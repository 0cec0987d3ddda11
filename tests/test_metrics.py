"""Known-answer tests of the scoring functions."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sim import metrics


def test_axis_angle_is_sign_free_and_exact():
    assert metrics.axis_angle_error_deg([0, 0, 1], [0, 0, -3]) == pytest.approx(0.0, abs=1e-6)
    d = Rotation.from_euler("x", 20, degrees=True).apply([0, 0, 1])
    assert metrics.axis_angle_error_deg(d, [0, 0, 1]) == pytest.approx(20.0)
    assert metrics.axis_angle_error_deg(-d, [0, 0, 1]) == pytest.approx(20.0)


def test_line_distance_skew_and_parallel():
    # x axis and a line along y through (0, 0, 2): common perpendicular of length 2.
    assert metrics.line_distance([0, 0, 0], [1, 0, 0], [5, 0, 2], [0, 1, 0]) == pytest.approx(2.0)
    # Parallel lines 3 apart, points anywhere along them.
    assert metrics.line_distance([0, 0, 0], [0, 0, 1], [3, 0, 7], [0, 0, -1]) == pytest.approx(3.0)
    # The same line, described by different points.
    assert metrics.line_distance([1, 1, 1], [1, 1, 1], [4, 4, 4], [2, 2, 2]) == pytest.approx(0.0)


def test_state_error_follows_axis_sign():
    z = np.array([0.0, 0.0, 1.0])
    assert metrics.joint_state_error("revolute", -0.5, 0.5, -z, z) == pytest.approx(0.0)
    assert metrics.joint_state_error("revolute", 0.5, 0.4, z, z) == pytest.approx(0.1)
    assert metrics.joint_state_error("prismatic", 0.1, 0.12, z, z) == pytest.approx(0.02)
    # Angles wrap: +179 deg and -179 deg are 2 deg apart.
    err = metrics.joint_state_error("revolute", np.radians(179), np.radians(-179), z, z)
    assert np.degrees(err) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="revolute"):
        metrics.joint_state_error("ball", 0, 0, z, z)


def test_rotation_error():
    R = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    R2 = Rotation.from_rotvec([0.0, 0.0, np.radians(7)]).as_matrix() @ R
    assert metrics.rotation_error_deg(R2, R) == pytest.approx(7.0)


def test_segmentation_accuracy_matches_labels_up_to_renaming():
    truth = np.array([0, 0, 0, 1, 1, 1, -1, -1])
    pred = np.array([5, 5, 2, 2, 2, 2, 5, 2])  # renamed; one base point wrong; background ignored
    assert metrics.segmentation_accuracy(pred, truth) == pytest.approx(5 / 6)
    assert metrics.segmentation_accuracy(np.full(8, -1), truth) == 0.0


def test_accuracy_completeness_on_a_plane():
    g = np.linspace(0, 1, 201)
    surface = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    surface = np.c_[surface, np.zeros(len(surface))]
    # Half the plane reconstructed (grid spacing 5 mm), 2 mm above it.
    pred = surface[surface[:, 0] < 0.5] + [0, 0, 0.002]
    out = metrics.accuracy_completeness(pred, surface)
    assert out["accuracy_median_mm"] == pytest.approx(2.0, abs=0.01)
    assert out["completeness"] == pytest.approx(0.5, abs=0.03)


def test_match_joints_pairs_by_axis_and_type():
    z, x = np.array([0.0, 0, 1]), np.array([1.0, 0, 0])
    true = [("revolute", np.zeros(3), z), ("prismatic", np.zeros(3), x)]
    # estimates listed in the other order, slightly off
    pred = [("prismatic", np.ones(3), x + [0, 0.01, 0]), ("revolute", [0.001, 0, 0], z)]
    assert metrics.match_joints(pred, true) == [(1, 0), (0, 1)]
    # a wrong type costs more than a large angle: the revolute estimate still goes to the hinge
    assert metrics.match_joints([("revolute", np.zeros(3), x)], true) == [(0, 0)]
    assert metrics.match_joints([], true) == []
    # cost: 1 deg -> 0.5, 5 mm between revolute axes -> 1
    c = metrics.joint_match_cost("revolute", [0.005, 0, 0], z, "revolute", np.zeros(3), z)
    assert c == pytest.approx(1.0)


def test_camera_pose_errors_known_offsets():
    T_true = np.repeat(np.eye(4)[None], 3, axis=0)
    T_pred = T_true.copy()
    T_pred[1, :3, 3] = [0.002, 0, 0]
    T_pred[2, :3, :3] = Rotation.from_euler("z", 4, degrees=True).as_matrix()
    out = metrics.camera_pose_errors(T_pred, T_true)
    assert out["position_max_mm"] == pytest.approx(2.0)
    assert out["position_median_mm"] == pytest.approx(0.0)
    assert out["rotation_max_deg"] == pytest.approx(4.0)
    with pytest.raises(ValueError, match="n, 4, 4"):
        metrics.camera_pose_errors(T_pred[:, :3], T_true[:, :3])


def test_visible_from_camera_occlusion_and_frustum():
    K = np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]])
    depth = np.full((100, 100), 1.0)  # a wall 1 m in front of the camera
    pts = np.array([[0, 0, 1.0],      # on the wall: seen
                    [0, 0, 1.002],    # 2 mm behind it: within tolerance
                    [0, 0, 1.05],     # 5 cm behind it: hidden
                    [0, 0, -1.0],     # behind the camera
                    [5.0, 0, 1.0]])   # outside the image
    vis = metrics.visible_from_camera(pts, K, np.eye(4), depth)
    assert vis.tolist() == [True, True, False, False, False]


def test_accuracy_completeness_on_a_part_and_nearest_labels():
    g = np.linspace(0, 1, 201)
    surface = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    surface = np.c_[surface, np.zeros(len(surface))]
    left = surface[:, 0] < 0.5
    pred = surface[left] + [0, 0, 0.001]  # only the left half, 1 mm off
    on_right = metrics.accuracy_completeness_on(pred, surface, ~left)
    on_left = metrics.accuracy_completeness_on(pred, surface, left)
    assert on_left["completeness"] == pytest.approx(1.0)
    assert on_left["accuracy_median_mm"] == pytest.approx(1.0, abs=1e-6)
    assert on_right["completeness"] < 0.03  # only the strip within 5 mm of the cut
    assert on_right["n_points"] == 0 and np.isnan(on_right["accuracy_median_mm"])
    labels = metrics.nearest_labels(np.array([[0.1, 0.1, 0.0], [0.1, 0.1, 0.5]]), surface,
                                    left.astype(int), 0.01)
    assert labels.tolist() == [1, -1]


def test_rendered_labels_majority_of_the_views_that_hold_the_point():
    """One camera at the origin looking along +z at a wall 1 m away: left half link 0, right
    half link 1, one column the table (-2). A point on the wall takes the label at its pixel;
    a point in front of the wall (free space) or behind it (hidden) gets no vote; with two
    views that disagree, the majority of three wins."""
    K = np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]])
    depth = np.ones((101, 101))
    labels = np.zeros((101, 101), int)
    labels[:, 51:] = 1
    labels[:, 50] = -2
    T = np.eye(4)
    view = (K, T, depth, labels)
    P = np.array([[-0.2, 0.0, 1.0], [0.2, 0.0, 1.003], [0.0, 0.0, 1.0],
                  [0.2, 0.0, 0.9], [0.2, 0.0, 1.2], [0.0, 0.0, -1.0]])
    lab, votes = metrics.rendered_labels(P, [view], 2, 0.01)
    assert lab.tolist() == [0, 1, -1, -1, -1, -1]
    assert votes.tolist() == [1, 1, 1, 0, 0, 0]
    other = (K, T, depth, 1 - labels.clip(0, 1))  # halves swapped
    lab, votes = metrics.rendered_labels(P[:2], [view, other, view], 2, 0.01)
    assert lab.tolist() == [0, 1] and votes.tolist() == [3, 3]
    with pytest.raises(ValueError, match="shape"):
        metrics.rendered_labels(P, [(K, T, depth, labels[:5])], 2, 0.01)
