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
