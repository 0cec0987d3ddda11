"""Rings of wrist-camera views around the object are reachable, within limits, without contacts.

The capture photographs the object at the table centre from rings of 36 views at about 20, 40 and
60 degrees elevation and 0.35 to 0.6 m away, every camera looking at the object's centre. The arm
rides the stage's circular rail, which turns it to each view's azimuth (sim.robot.solve_view_ik).
This test fixes the rail radius, pedestal height and base yaw chosen in scenes/stage.xml.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

import sim  # noqa: F401
from sim.robot import (
    arm_contacts,
    load_arm_kinematics,
    qpos_indices,
    ring_camera_poses,
    solve_view_ik,
)

ROOT = Path(__file__).resolve().parents[1]
#: Table top centre (0, 0, 0.45) plus 5 cm: the object centre the cameras look at.
TARGET = np.array([0.0, 0.0, 0.50])
ELEVATIONS_DEG = (20.0, 40.0, 60.0)
DISTANCES = (0.35, 0.45, 0.6)
VIEWS_PER_RING = 36


def _scene_files():
    """The stage alone and every scene built on it."""
    files = [ROOT / "scenes" / "stage.xml"]
    files += sorted(p for p in (ROOT / "scenes").glob("*.xml")
                    if p.name != "stage.xml" and 'file="stage.xml"' in p.read_text())
    return files


@pytest.mark.parametrize("scene", _scene_files(), ids=lambda p: p.stem)
def test_view_rings_are_reachable(scene):
    model = mujoco.MjModel.from_xml_path(str(scene))
    data = mujoco.MjData(model)
    kin = load_arm_kinematics(model)
    idx = qpos_indices(model, kin)
    failures, pos_err, rot_err = [], [], []
    for elevation in ELEVATIONS_DEG:
        for distance in DISTANCES:
            q_prev = None
            poses = ring_camera_poses(TARGET, distance, np.deg2rad(elevation), VIEWS_PER_RING)
            for k, T in enumerate(poses):
                res = solve_view_ik(kin, T, q_prev)
                where = f"elevation {elevation:g} deg, distance {distance:g} m, view {k}"
                if not res.success:
                    failures.append(f"{where}: IK error {res.position_error:.2g} m, "
                                    f"{res.rotation_error:.2g} rad")
                    continue
                assert np.all(res.q >= kin.lower) and np.all(res.q <= kin.upper), where
                data.qpos[:] = model.qpos0
                data.qpos[idx] = res.q
                mujoco.mj_forward(model, data)
                contacts = arm_contacts(model, data, kin)
                if contacts:
                    failures.append(f"{where}: arm touches {contacts}")
                    continue
                # The camera really is where the view asks (MuJoCo's own camera, not pinocchio).
                cam = model.camera(kin.spec.prefix + kin.spec.camera).id
                np.testing.assert_allclose(data.cam_xpos[cam], T[:3, 3], atol=1e-4)
                pos_err.append(res.position_error)
                rot_err.append(res.rotation_error)
                q_prev = res.q
    n = len(ELEVATIONS_DEG) * len(DISTANCES) * VIEWS_PER_RING
    print(f"{scene.name}: {len(pos_err)}/{n} views reachable; max IK error "
          f"{max(pos_err, default=np.nan):.2g} m, {max(rot_err, default=np.nan):.2g} rad")
    assert not failures, f"{len(failures)} of {n} views unreachable in {scene.name}:\n" + "\n".join(
        failures[:10])
