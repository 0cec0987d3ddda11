"""PUMA 560: MJCF vs pinocchio vs plain DH, camera, IK, servos (robots/puma560, sim/robot.py)."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

import sim  # noqa: F401  (sets the GL platform before anything else)
from sim.camera import T_GL_CV, mujoco_camera_intrinsics
from sim.robot import (
    CAMERA_FOCAL_PX,
    PANDA,
    PUMA560,
    PUMA560_GRASP_OFFSET,
    PUMA560_T_FLANGE_CAMERA,
    DHLink,
    actuator_indices,
    closed_form,
    dh_forward,
    dh_transform,
    load_arm_kinematics,
    look_at_pose,
    qpos_indices,
    ring_camera_poses,
    solve_view_ik,
)

ROOT = Path(__file__).resolve().parents[1]
STAGE = ROOT / "scenes" / "stage.xml"
ARM_SCENE = ROOT / "robots" / "puma560" / "scene.xml"

# Why these tolerances: FK agreement is limited by float64 round-off over 7 joints (~1e-15 m);
# 1e-9 m is the requirement. Finite-difference Jacobians with h = 1e-6 carry O(h^2)
# truncation and O(eps/h) round-off errors, both below 1e-7.
FK_TOL = 1e-9
FD_STEP = 1e-6
FD_TOL = 1e-7


@pytest.fixture(scope="module")
def stage():
    model = mujoco.MjModel.from_xml_path(str(STAGE))
    return model, load_arm_kinematics(model)


def _random_q(kin, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(kin.lower, kin.upper, size=(n, kin.nq))


def test_generated_mjcf_is_up_to_date():
    out = subprocess.run([sys.executable, str(ROOT / "robots/puma560/generate_mjcf.py"), "--check"],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr


def test_mjcf_joint_limits_are_the_published_ones():
    model = mujoco.MjModel.from_xml_path(str(ARM_SCENE))
    for name, (lo, hi) in zip(PUMA560.joints, PUMA560.qlim_deg, strict=True):
        np.testing.assert_allclose(np.rad2deg(model.joint(name).range), [lo, hi], atol=1e-9)


def test_fk_pinocchio_mujoco_and_dh_agree(stage):
    model, kin = stage
    data = mujoco.MjData(model)
    idx = qpos_indices(model, kin)
    # DH frame 0 in the world at rail = 0, read once from MuJoCo (body link1 at q = 0).
    data.qpos[:] = model.qpos0
    data.qpos[idx] = 0.0
    mujoco.mj_kinematics(model, data)
    link1 = model.body(PUMA560.prefix + "link1").id
    T0 = np.eye(4)
    T0[:3, :3], T0[:3, 3] = data.xmat[link1].reshape(3, 3), data.xpos[link1]
    cam = model.camera(PUMA560.prefix + PUMA560.camera).id
    site = model.site(PUMA560.prefix + PUMA560.grasp_site).id
    for q in _random_q(kin, 20, seed=1):
        c, s = np.cos(q[0]), np.sin(q[0])
        Rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        dh_frames = [Rz @ T0] + [Rz @ T0 @ T for T in dh_forward(PUMA560.dh, q[1:])]
        data.qpos[idx] = q
        mujoco.mj_forward(model, data)
        for i, T_dh in enumerate(dh_frames):
            T_pin = kin.frame_pose(q, f"frame{i}")
            np.testing.assert_allclose(T_pin, T_dh, atol=FK_TOL)
            if i < 6:  # MuJoCo body link(i+1) is DH frame i turned by q[i+1] about its z
                body = model.body(f"{PUMA560.prefix}link{i + 1}").id
                R_mj = data.xmat[body].reshape(3, 3)
                np.testing.assert_allclose(data.xpos[body], T_dh[:3, 3], atol=FK_TOL)
                Rz_joint = dh_transform(DHLink(a=0.0, alpha=0.0, d=0.0), q[i + 1])[:3, :3]
                np.testing.assert_allclose(R_mj, T_dh[:3, :3] @ Rz_joint, atol=FK_TOL)
        # The camera: pinocchio, MuJoCo (converted from OpenGL), and the documented mount.
        T_cam = kin.camera_pose(q)
        T_mj = np.eye(4)
        T_mj[:3, :3], T_mj[:3, 3] = data.cam_xmat[cam].reshape(3, 3), data.cam_xpos[cam]
        np.testing.assert_allclose(T_cam, T_mj @ T_GL_CV, atol=FK_TOL)
        np.testing.assert_allclose(T_cam, dh_frames[6] @ PUMA560_T_FLANGE_CAMERA, atol=FK_TOL)
        np.testing.assert_allclose(kin.frame_pose(q, "grasp")[:3, 3], data.site_xpos[site],
                                   atol=FK_TOL)
        np.testing.assert_allclose(kin.frame_pose(q, "grasp")[:3, 3],
                                   (dh_frames[6] @ np.append(PUMA560_GRASP_OFFSET, 1.0))[:3],
                                   atol=FK_TOL)


@pytest.mark.parametrize("frame", ["camera", "grasp", "frame3"])
def test_jacobian_matches_finite_differences(stage, frame):
    _, kin = stage
    for q in _random_q(kin, 5, seed=2):
        J = kin.jacobian(q, frame)
        J_fd = np.zeros_like(J)
        for k in range(kin.nq):
            dq = np.zeros(kin.nq)
            dq[k] = FD_STEP
            Tp, Tm = kin.frame_pose(q + dq, frame), kin.frame_pose(q - dq, frame)
            J_fd[:3, k] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * FD_STEP)
            dR = Tp[:3, :3] @ Tm[:3, :3].T  # world-frame rotation increment
            w = 0.5 * np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
            J_fd[3:, k] = w / (2 * FD_STEP)
        np.testing.assert_allclose(J, J_fd, atol=FD_TOL)


def test_camera_intrinsics_are_explicit_and_agree():
    model = mujoco.MjModel.from_xml_path(str(ARM_SCENE))
    K, size = mujoco_camera_intrinsics(model, PUMA560.camera)
    assert size == (640, 480)
    # MuJoCo stores intrinsics in float32: agreement to 1e-3 px.
    np.testing.assert_allclose(K, [[CAMERA_FOCAL_PX, 0, 319.5], [0, CAMERA_FOCAL_PX, 239.5],
                                   [0, 0, 1]], atol=1e-3)
    np.testing.assert_allclose(K[0, 0], 554.26, atol=0.01)
    hfov = 2 * np.degrees(np.arctan(320 / K[0, 0]))
    np.testing.assert_allclose(hfov, 60.0, atol=1e-3)


def test_gripper_is_out_of_the_camera_view():
    """Every corner of every flange geom's bounding box projects outside the image or lies
    behind the camera, so the gripper never appears in the wrist images."""
    model = mujoco.MjModel.from_xml_path(str(ARM_SCENE))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    K, (w, h) = mujoco_camera_intrinsics(model, PUMA560.camera)
    cam = model.camera(PUMA560.camera).id
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3], T_world_cam[:3, 3] = data.cam_xmat[cam].reshape(3, 3), data.cam_xpos[cam]
    T_cam_world = np.linalg.inv(T_world_cam @ T_GL_CV)
    flange = model.body(PUMA560.flange_body).id
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    checked = 0
    for g in np.flatnonzero(model.geom_bodyid == flange):
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        corners = centre + signs * half
        T_world_geom = np.eye(4)
        T_world_geom[:3, :3] = data.geom_xmat[g].reshape(3, 3)
        T_world_geom[:3, 3] = data.geom_xpos[g]
        p = (T_cam_world @ T_world_geom @ np.c_[corners, np.ones(8)].T)[:3]
        in_front = p[2] > 1e-6
        uv = (K @ p[:, in_front]) / p[2, in_front]
        inside = (uv[0] > -0.5) & (uv[0] < w - 0.5) & (uv[1] > -0.5) & (uv[1] < h - 0.5)
        assert not inside.any(), f"geom {g} of the flange is visible in the wrist camera"
        checked += 1
    assert checked >= 6


def test_ik_converges_within_limits(stage):
    _, kin = stage
    solved = 0
    for i, q_true in enumerate(_random_q(kin, 12, seed=3)):
        for frame in ("camera", "grasp"):
            T = kin.frame_pose(q_true, frame)
            res = kin.solve_ik(T, frame, seed=i)
            assert np.all(res.q >= kin.lower) and np.all(res.q <= kin.upper)
            if res.success:
                solved += 1
                np.testing.assert_allclose(kin.frame_pose(res.q, frame), T, atol=1e-4)
    # Random targets from random configurations: all are reachable by construction.
    assert solved == 24
    res = kin.solve_ik(kin.frame_pose(_random_q(kin, 1, 4)[0], "grasp"), "grasp",
                       position_only=True)
    assert res.success and res.rotation_error == 0.0


def test_nearest_equivalent_is_the_same_pose_by_the_shortest_turns(stage):
    """Whole turns of a joint whose range exceeds one (the PUMA's wrist roll, +-266 deg) give the
    same pose; the planner takes the one nearest the previous view's configuration."""
    _, kin = stage
    wide = np.flatnonzero(kin.upper - kin.lower > 2 * np.pi)
    assert len(wide) >= 1  # the wrist roll at least
    for q, ref in zip(_random_q(kin, 20, seed=7), _random_q(kin, 20, seed=8), strict=True):
        near = kin.nearest_equivalent(q, ref)
        np.testing.assert_allclose(kin.camera_pose(near), kin.camera_pose(q), atol=1e-9)
        assert np.all(near >= kin.lower) and np.all(near <= kin.upper)
        turns = (near - q) / (2 * np.pi)
        np.testing.assert_allclose(turns, np.round(turns), atol=1e-9)
        for i in range(kin.nq):  # no other whole turn within the limits is nearer
            for k in (-1, 1):
                other = near[i] + 2 * np.pi * k
                if kin.lower[i] <= other <= kin.upper[i]:
                    assert abs(near[i] - ref[i]) <= abs(other - ref[i]) + 1e-12
    q = np.r_[0.0, kin.spec.home]
    j = wide[-1]
    q[j] = kin.upper[j] - 0.1
    ref = q.copy()
    ref[j] = q[j] - 2 * np.pi + 0.05  # a turn away, nearly
    assert kin.nearest_equivalent(q, ref)[j] == pytest.approx(q[j] - 2 * np.pi)


def test_ik_reports_failure_for_unreachable_target(stage):
    _, kin = stage
    T = np.eye(4)
    T[:3, 3] = [5.0, 0.0, 1.0]
    res = kin.solve_ik(T, "grasp", restarts=2)
    assert not res.success and res.position_error > 1.0
    assert np.all(res.q >= kin.lower) and np.all(res.q <= kin.upper)


def test_look_at_pose_is_opencv():
    eye, target = np.array([1.0, 0.5, 1.2]), np.array([0.0, 0.0, 0.5])
    T = look_at_pose(eye, target)
    R = T[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) > 0
    np.testing.assert_allclose(R[:, 2], (target - eye) / np.linalg.norm(target - eye))
    assert R[2, 1] < 0  # image down (+y) points down in the world
    assert abs(R[2, 0]) < 1e-12  # no roll: image x is horizontal
    poses = ring_camera_poses(target, 0.5, np.deg2rad(40), n=36)
    d = np.linalg.norm(poses[:, :3, 3] - target, axis=1)
    np.testing.assert_allclose(d, 0.5)
    np.testing.assert_allclose(poses[:, 2, 3], 0.5 + 0.5 * np.sin(np.deg2rad(40)))
    with pytest.raises(ValueError, match="up is parallel"):
        look_at_pose([0, 0, 1], [0, 0, 0])
    with pytest.raises(ValueError, match=r"\(3,\)"):
        look_at_pose([0, 0], [0, 0, 0])


def test_indices_follow_joint_names(stage):
    model, kin = stage
    qi, ai = qpos_indices(model, kin), actuator_indices(model, kin)
    for name, qa, a in zip(kin.joint_names, qi, ai, strict=True):
        assert model.jnt_qposadr[model.joint(name).id] == qa
        assert model.actuator_trnid[a, 0] == model.joint(name).id


def _simulate(model, data, seconds):
    for _ in range(int(round(seconds / model.opt.timestep))):
        mujoco.mj_step(model, data)


def test_servos_hold_home_and_track_a_step():
    model = mujoco.MjModel.from_xml_path(str(ARM_SCENE))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    home = np.array(PUMA560.home)
    _simulate(model, data, 1.0)
    # Hold: gravity compensation and the servos keep every joint within 1 mrad of home.
    assert np.abs(data.qpos - home).max() < 1e-3
    # Step of 0.2 rad on every joint: settled within 1 s to 1 % of the step, little overshoot.
    data.ctrl[:] = home + 0.2
    peak = np.zeros(6)
    for _ in range(int(1.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
        peak = np.maximum(peak, data.qpos - home)
    assert np.abs(data.qpos - (home + 0.2)).max() < 2e-3
    assert peak.max() < 0.2 * 1.1


def test_rail_servo_turns_the_arm_on_the_stage(stage):
    model, kin = stage
    data = mujoco.MjData(model)
    qi, ai = qpos_indices(model, kin), actuator_indices(model, kin)
    q = np.array([0.0, *PUMA560.home])
    data.qpos[qi], data.ctrl[ai] = q, q
    data.ctrl[ai[0]] = 1.0  # turn the carriage by 1 rad, arm joints held
    _simulate(model, data, 2.0)
    assert abs(data.qpos[qi[0]] - 1.0) < 1e-3
    assert np.abs(data.qpos[qi[1:]] - q[1:]).max() < 1e-3
    assert not any(w.number for w in data.warning)
    # The camera followed the rail: it is where the kinematics put it.
    mujoco.mj_forward(model, data)
    cam = model.camera(PUMA560.prefix + PUMA560.camera).id
    np.testing.assert_allclose(data.cam_xpos[cam], kin.camera_pose(data.qpos[qi])[:3, 3],
                               atol=1e-9)


def test_closed_form_finds_every_configuration_of_a_flange_pose(stage):
    """The closed form's solutions (shoulder, elbow, wrist flip) at a rail angle all put the
    flange where asked, and the configuration the pose came from is one of them."""
    _, kin = stage
    ik = kin.closed_form
    assert ik is not None and closed_form.supports(kin.spec)
    counts = []
    for q in _random_q(kin, 200, seed=11):
        T = kin.frame_pose(q, "flange")
        sols, valid = ik.solutions(T, [q[0]], q)
        counts.append(int(valid.sum()))
        assert valid.any()
        # the source configuration, each joint the whole turn nearest itself
        assert np.min(np.max(np.abs(sols[0][valid[0]] - q), axis=1)) < 1e-9
        for s in sols[0][valid[0]]:
            assert np.all(s >= kin.lower) and np.all(s <= kin.upper)
            np.testing.assert_allclose(kin.frame_pose(s, "flange"), T, atol=FK_TOL)
    # the eight branches exist for most poses; joint limits remove some
    assert max(counts) == 8 and np.mean(counts) > 3


def test_closed_form_view_ik_is_exact_and_says_why_it_fails(stage):
    _, kin = stage
    for q in _random_q(kin, 30, seed=12):
        T = kin.camera_pose(q)
        res = solve_view_ik(kin, T, q)
        assert res.success and res.reason == ""
        assert res.position_error < 1e-12 and res.rotation_error < 1e-6
        np.testing.assert_allclose(kin.camera_pose(res.q), T, atol=FK_TOL)
        # from a guess at the true configuration the solution is that configuration, unless
        # another rail angle was needed (the azimuth's rail angle is tried first)
        rel = T[:3, 3] - kin.frame_pose(np.zeros(kin.nq), "rail")[:3, 3]
        if abs(kin.rail_angle_for_azimuth(np.arctan2(rel[1], rel[0])) - q[0]) < 1e-9:
            np.testing.assert_allclose(res.q, q, atol=1e-9)
    far = look_at_pose(np.array([3.0, 0.0, 1.0]), np.array([4.0, 0.0, 1.0]))
    res = solve_view_ik(kin, far)
    assert not res.success and "out of reach" in res.reason
    assert np.all(res.q >= kin.lower) and np.all(res.q <= kin.upper)


def test_closed_form_is_only_for_the_structure_it_solves():
    assert closed_form.supports(PUMA560)
    assert not closed_form.supports(PANDA)  # a URDF arm, no spherical wrist
    bent = PUMA560.dh[:3] + (DHLink(a=0.05, alpha=np.pi / 2, d=0.4318),) + PUMA560.dh[4:]
    assert not closed_form.supports(replace(PUMA560, dh=bent))


def test_closed_form_keeps_the_home_posture_where_the_view_allows(stage):
    """Of the solutions for a view, the one on the home posture's shoulder and elbow comes first,
    even when another branch is a shorter step from the guess: a capture that wandered onto
    the other shoulder started cabinet_door_only's manipulation there, and its grasp let go."""
    _, kin = stage
    ik = kin.closed_form
    home = np.r_[0.0, kin.spec.home]
    assert ik._branch(home) == ik.home_arm_branch
    kept = 0
    for q in _random_q(kin, 60, seed=13):
        T_cam = kin.camera_pose(q)
        T = T_cam @ np.linalg.inv(ik.T_flange_camera)
        sols, valid = ik.solutions(T, [q[0]], q)
        on_home = valid[0] & (np.arange(8) // 2 == ik.home_arm_branch)
        res = ik.solve(T_cam, q[0], q, free_rail=False)
        if on_home.any():
            assert ik._branch(res) == ik.home_arm_branch
            kept += 1
        elif valid.any():
            np.testing.assert_allclose(kin.camera_pose(res), T_cam, atol=FK_TOL)
    assert kept >= 10
