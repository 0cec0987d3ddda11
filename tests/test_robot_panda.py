"""The second arm: a Franka Emika Panda from example-robot-data's URDF on the stage's rail
(robots/panda, scenes/stage_panda.xml, sim.robot.PANDA). The arm is a scene choice
(``<custom><text name="artrecon:arm">``); pinocchio (built from the URDF) and MuJoCo (the MJCF
generated from the same URDF) agree; the wrist camera has the PUMA's intrinsics and keeps the
gripper out of its image; the servos hold and track; the view rings are reachable from the rail.
"""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest

import sim  # noqa: F401  (sets the GL platform before anything else)
from sim.camera import T_GL_CV, mujoco_camera_intrinsics
from sim.robot import (
    ARM_TEXT,
    ARMS,
    PANDA,
    PUMA560,
    actuator_indices,
    arm_contacts,
    arm_spec,
    load_arm_kinematics,
    qpos_indices,
    ring_camera_poses,
    solve_view_ik,
)
from sim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
STAGE = ROOT / "scenes" / "stage_panda.xml"
PUMA_STAGE = ROOT / "scenes" / "stage.xml"

#: FK agreement: float64 round-off over 8 joints is ~1e-15 m; 1e-9 m is the issue's requirement
#: (the MJCF writes the URDF's numbers with 17 significant digits).
FK_TOL = 1e-9
#: Servo tests: a position servo with gravity compensation settles to well under a milliradian.
SERVO_TOL = 1e-3
#: The rings of tests/test_reachability.py: target 5 cm above the table centre.
TARGET = np.array([0.0, 0.0, 0.50])
ELEVATIONS_DEG = (20.0, 40.0, 60.0)
DISTANCES = (0.35, 0.45, 0.6)
VIEWS_PER_RING = 36


@pytest.fixture(scope="module")
def stage():
    model = mujoco.MjModel.from_xml_path(str(STAGE))
    return model, load_arm_kinematics(model)


def _pose(R, p):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.reshape(R, (3, 3)), p
    return T


def test_arm_is_a_scene_choice(stage):
    model, kin = stage
    assert arm_spec(model) is PANDA and kin.spec is PANDA and kin.nq == 8
    assert kin.joint_names == ("rail", *(f"panda_joint{i}" for i in range(1, 8)))
    puma = mujoco.MjModel.from_xml_path(str(PUMA_STAGE))
    assert arm_spec(puma) is PUMA560 and load_arm_kinematics(puma).nq == 7
    assert set(ARMS) == {"puma560", "panda"}
    scene = load_scene("pliers_panda")
    assert arm_spec(scene.model) is PANDA
    bad = STAGE.read_text().replace(f'name="{ARM_TEXT}" data="panda"',
                                    f'name="{ARM_TEXT}" data="kuka"')
    path = STAGE.with_name("_bad_arm_stage.xml")  # beside stage_panda.xml for its relative paths
    try:
        path.write_text(bad)
        with pytest.raises(ValueError, match="unknown arm.*panda"):
            arm_spec(mujoco.MjModel.from_xml_path(str(path)))
    finally:
        path.unlink()


@pytest.mark.parametrize("name", ["pliers", "truck"])
def test_a_panda_scene_is_its_puma_scene_with_the_other_stage(name):
    def body(path):
        root = ET.parse(path).getroot()
        return [ET.tostring(el) for el in root if el.tag != "include"]
    assert body(ROOT / "scenes" / f"{name}_panda.xml") == body(ROOT / "scenes" / f"{name}.xml")
    a, b = load_scene(name), load_scene(f"{name}_panda")
    assert arm_spec(b.model) is PANDA and arm_spec(a.model) is PUMA560
    for ja, jb in zip(a.joints, b.joints, strict=True):
        assert ja.name == jb.name and (ja.value_a, ja.value_b) == (jb.value_a, jb.value_b)
        np.testing.assert_array_equal(ja.axis, jb.axis)
        np.testing.assert_array_equal(ja.point, jb.point)


def _has_example_robot_data() -> bool:
    try:
        importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


@pytest.mark.skipif(not _has_example_robot_data(),
                    reason="example-robot-data (the generator's source) is not installed")
def test_generated_files_are_up_to_date():
    out = subprocess.run([sys.executable, str(ROOT / "robots/panda/generate_mjcf.py"), "--check"],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr


def test_limits_come_from_the_urdf(stage):
    model, kin = stage
    urdf = ET.parse(ROOT / PANDA.urdf).getroot()
    for i, name in enumerate(PANDA.urdf_joints, start=1):
        lim = next(j for j in urdf.iter("joint") if j.get("name") == name).find("limit")
        want = [float(lim.get("lower")), float(lim.get("upper"))]
        np.testing.assert_array_equal([kin.lower[i], kin.upper[i]], want)
        np.testing.assert_array_equal(model.joint(PANDA.prefix + PANDA.joints[i - 1]).range, want)


def test_fk_pinocchio_and_mujoco_agree(stage):
    """Camera, grasp site and every link frame, at random configurations within the limits."""
    model, kin = stage
    data = mujoco.MjData(model)
    idx = qpos_indices(model, kin)
    cam = model.camera(PANDA.prefix + PANDA.camera).id
    site = model.site(PANDA.prefix + PANDA.grasp_site).id
    links = [model.body(PANDA.prefix + f"link{i}").id for i in range(1, 8)]
    worst = 0.0
    for q in np.random.default_rng(7).uniform(kin.lower, kin.upper, size=(25, kin.nq)):
        data.qpos[:] = model.qpos0
        data.qpos[idx] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_camlight(model, data)  # camera poses are not part of mj_kinematics
        T_cam = _pose(data.cam_xmat[cam], data.cam_xpos[cam]) @ T_GL_CV
        T_site = _pose(data.site_xmat[site], data.site_xpos[site])
        pairs = [(kin.camera_pose(q), T_cam), (kin.frame_pose(q, "grasp"), T_site)]
        pairs += [(kin.frame_pose(q, f"frame{i}"), _pose(data.xmat[b], data.xpos[b]))
                  for i, b in enumerate(links, start=1)]
        pairs.append((kin.frame_pose(q, "flange"), pairs[-1][1]))
        for T_pin, T_mj in pairs:
            worst = max(worst, float(np.abs(T_pin - T_mj).max()))
            np.testing.assert_allclose(T_pin[:3, 3], T_mj[:3, 3], atol=FK_TOL)
            np.testing.assert_allclose(T_pin[:3, :3], T_mj[:3, :3], atol=FK_TOL)
    print(f"pinocchio vs MuJoCo, 25 configurations: max difference {worst:.1e}")


def test_camera_has_the_pumas_intrinsics_and_does_not_see_the_gripper(stage):
    model, kin = stage
    puma = mujoco.MjModel.from_xml_path(str(PUMA_STAGE))
    K, size = mujoco_camera_intrinsics(model, PANDA.prefix + PANDA.camera)
    K_puma, size_puma = mujoco_camera_intrinsics(puma, PUMA560.prefix + PUMA560.camera)
    assert size == size_puma == (640, 480)
    np.testing.assert_allclose(K, K_puma, atol=1e-9)
    np.testing.assert_allclose(K[0, 0], 554.2562584220408, atol=1e-6)
    # Every vertex of the hand, the fingers and the camera housing projects outside the image.
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    q = data.qpos[qpos_indices(model, kin)]
    T_cam_world = np.linalg.inv(kin.camera_pose(q))
    hand = model.body(PANDA.prefix + "hand").id
    bodies = {b for b in range(model.nbody) if b == hand or model.body_parentid[b] == hand}
    n_points = 0
    for g in range(model.ngeom):
        if int(model.geom_bodyid[g]) not in bodies:
            continue
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
            m = int(model.geom_dataid[g])
            local = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m]
                                    + model.mesh_vertnum[m]]
        else:
            corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
            local = corners * model.geom_size[g]
        p_world = local @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
        p_cam = p_world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        front = p_cam[:, 2] > 1e-3
        uv = p_cam[front, :2] / p_cam[front, 2:] * K[0, 0] + K[:2, 2]
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < 640) & (uv[:, 1] >= 0) & (uv[:, 1] < 480)
        assert not inside.any(), f"{model.geom(g).name or g} is in the image"
        n_points += len(local)
    assert n_points > 100


def test_home_looks_at_the_table_centre(stage):
    model, kin = stage
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    q = data.qpos[qpos_indices(model, kin)]
    T = kin.camera_pose(q)
    to_target = TARGET - T[:3, 3]
    assert np.linalg.norm(to_target) == pytest.approx(0.45, abs=1e-3)
    angle = np.arccos(np.dot(T[:3, 2], to_target / np.linalg.norm(to_target)))
    assert np.rad2deg(angle) < 0.1
    assert np.rad2deg(np.arcsin(-to_target[2] / np.linalg.norm(to_target))) == \
        pytest.approx(40.0, abs=0.1)


def test_servos_hold_home_and_track_a_view(stage):
    model, kin = stage
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    idx, act = qpos_indices(model, kin), actuator_indices(model, kin)
    home = data.qpos[idx].copy()
    mujoco.mj_step(model, data, nstep=500)  # 1 s
    assert np.abs(data.qpos[idx] - home).max() < SERVO_TOL
    # Track the IK solution of a 60 deg view on the far side of the table.
    T = ring_camera_poses(TARGET, 0.5, np.deg2rad(60.0), 1, azimuth0=2.5)[0]
    res = solve_view_ik(kin, T, home)
    assert res.success
    data.ctrl[act] = res.q
    mujoco.mj_step(model, data, nstep=3000)  # 6 s: the rail turns 143 degrees
    assert np.abs(data.qpos[idx] - res.q).max() < SERVO_TOL
    cam = model.camera(PANDA.prefix + PANDA.camera).id
    assert np.linalg.norm(data.cam_xpos[cam] - T[:3, 3]) < 2e-3
    assert all(int(data.warning[i].number) == 0 for i in range(len(data.warning)))


@pytest.mark.parametrize("scene", [STAGE, ROOT / "scenes" / "pliers_panda.xml"],
                         ids=lambda p: p.stem)
def test_view_rings_are_reachable(scene):
    """As tests/test_reachability.py for the PUMA: 3 elevations x 3 distances x 36 views."""
    model = mujoco.MjModel.from_xml_path(str(scene))
    data = mujoco.MjData(model)
    kin = load_arm_kinematics(model)
    assert kin.spec is PANDA
    idx = qpos_indices(model, kin)
    cam = model.camera(PANDA.prefix + PANDA.camera).id
    failures, summary, pos_err = [], [], []
    for elevation in ELEVATIONS_DEG:
        for distance in DISTANCES:
            q_prev, ok = None, 0
            poses = ring_camera_poses(TARGET, distance, np.deg2rad(elevation), VIEWS_PER_RING)
            for k, T in enumerate(poses):
                res = solve_view_ik(kin, T, q_prev)
                where = f"elevation {elevation:g} deg, distance {distance:g} m, view {k}"
                if not res.success:
                    failures.append(f"{where}: IK error {res.position_error:.2g} m")
                    continue
                assert np.all(res.q >= kin.lower) and np.all(res.q <= kin.upper), where
                data.qpos[:] = model.qpos0
                data.qpos[idx] = res.q
                mujoco.mj_forward(model, data)
                contacts = arm_contacts(model, data, kin)
                if contacts:
                    failures.append(f"{where}: arm touches {contacts}")
                    continue
                np.testing.assert_allclose(data.cam_xpos[cam], T[:3, 3], atol=1e-4)
                pos_err.append(res.position_error)
                q_prev, ok = res.q, ok + 1
            summary.append(f"{elevation:g} deg/{distance:g} m: {ok}/{VIEWS_PER_RING}")
    print(f"{scene.name}: " + ", ".join(summary)
          + f"; max IK error {max(pos_err, default=np.nan):.2g} m")
    n = len(ELEVATIONS_DEG) * len(DISTANCES) * VIEWS_PER_RING
    assert not failures, f"{len(failures)} of {n} views unreachable:\n" + "\n".join(failures[:10])
