"""Manipulation in MuJoCo physics along the ground-truth axis, and a deliberately wrong axis.

The true axis must move the joint by the requested amount (within 10%) with moderate grasp forces;
the same axis tilted by 20 degrees must score clearly worse (the arm fights the joint).
"""

import numpy as np
import pytest

import sim  # noqa: F401
from sim.manipulate import (
    GraspCandidate,
    JointEstimate,
    build_world,
    joint_estimate_from_scene,
    manipulate,
)
from sim.scene import load_scene

#: Requested motions: the scenes' own configuration change (30 deg, 30 deg, 10 cm).
REQUESTS = {"truck": np.deg2rad(30.0), "drawer": 0.10, "pliers": np.deg2rad(30.0)}
#: Largest tracking error of the arm's joints (commanded vs actual). The pliers lie flat at table
#: height, where the arm works near the edge of its reach and its servos lag more (measured 5.9 deg
#: peak against 1.7 deg for the truck); the achieved-motion gate is the same for all.
TRACKING_MAX = {"truck": np.deg2rad(5.0), "drawer": np.deg2rad(5.0), "pliers": np.deg2rad(8.0)}


@pytest.fixture(scope="module")
def runs():
    out = {}
    for name in ("truck", "drawer", "pliers"):
        scene = load_scene(name)
        world = build_world(scene)
        est = joint_estimate_from_scene(scene)
        true = manipulate(scene, est, REQUESTS[name], world=world)
        tilted = manipulate(scene, est.tilted(20.0), REQUESTS[name], world=world)
        out[name] = (true, tilted)
    return out


@pytest.mark.parametrize("name", ["truck", "drawer", "pliers"])
def test_true_axis_moves_joint_as_requested(runs, name):
    true, _ = runs[name]
    assert true.joint == load_scene(name).joints[0].name
    assert abs(true.achieved - true.requested) < 0.1 * abs(true.requested)
    assert true.tracking_max < TRACKING_MAX[name]
    assert true.path_error_max < 0.02
    assert true.peak_force > 0.0  # the weld carried the load


@pytest.mark.parametrize("name", ["truck", "drawer", "pliers"])
def test_tilted_axis_scores_clearly_worse(runs, name):
    true, tilted = runs[name]
    assert "tilted 20 deg" in tilted.estimate["source"]
    worse_force = tilted.peak_force > 3.0 * true.peak_force
    worse_motion = abs(tilted.achieved - tilted.requested) > 0.1 * abs(tilted.requested)
    assert worse_force or worse_motion
    assert tilted.path_error_max > true.path_error_max


def test_truck_default_grasp_is_hidden(runs):
    true, _ = runs["truck"]
    assert true.grasp_hidden and true.grasp_visibility != "visible"
    assert any("HIDDEN" in m for m in true.log)
    assert true.grasp_body == "truck_bed"


def test_grasp_on_wrong_link_does_not_move_joint():
    """A grasp point on the fixed cabinet welds the gripper to the cabinet: nothing opens."""
    scene = load_scene("drawer")
    est = joint_estimate_from_scene(scene)
    # front of the cabinet below the drawer
    res = manipulate(scene, est, 0.05, grasp_point=[0.12, 0.05, 0.58], grasp_normal=[1, 0, 0])
    assert res.grasp_body == "object"
    assert res.joint == ""
    assert res.achieved == 0.0
    assert res.peak_force > 50.0  # the arm pulls against a fixed cabinet


def test_joint_estimate_validation_and_tilt():
    with pytest.raises(ValueError, match="revolute"):
        JointEstimate("ball", [0, 0, 1], [0, 0, 0])
    with pytest.raises(ValueError, match=r"\(3,\)"):
        JointEstimate("revolute", [0, 1], [0, 0, 0])
    est = JointEstimate("revolute", [0, 0, 2.0], [0.1, 0, 0])
    np.testing.assert_allclose(est.axis, [0, 0, 1])
    t = est.tilted(20.0)
    assert np.rad2deg(np.arccos(t.axis @ est.axis)) == pytest.approx(20.0)
    # the motion turns points about the axis through its point
    T = est.motion(np.pi / 2)
    np.testing.assert_allclose(T[:3, :3] @ [0.2, 0, 0] + T[:3, 3], [0.1, 0.1, 0], atol=1e-12)
    GraspCandidate(np.zeros(3), np.array([0, 0, 1.0]))
