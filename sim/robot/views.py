"""Reaching a camera view with the arm (several IK starts and rolls) and the arm's contacts."""

from __future__ import annotations

import logging
import math

import mujoco
import numpy as np

from artrecon.geometry import rotation_angle
from sim.robot.closed_form import Unreachable
from sim.robot.kinematics import (
    IK_ACCEPT_POSITION,
    IK_ACCEPT_ROTATION,
    ArmKinematics,
    IKResult,
    check_pose,
    mj_id,
)
from sim.robot.spec import PUMA560

log = logging.getLogger(__name__)

# ----------------------------------------------------------------------------------------------
# Views: IK for a camera pose, and collision checks in the MuJoCo scene
# ----------------------------------------------------------------------------------------------

#: Arm configuration (joint1..joint6) from which view IK starts when no guess is given: the home
#: pose, where the camera looks at the table centre from 0.45 m and 50 degrees elevation.
PUMA560_VIEW_SEED = PUMA560.home


def solve_view_ik(kin: ArmKinematics, T_world_camera, q0=None, *, restarts: int = 16,
                  seed: int = 0) -> IKResult:
    """IK for a camera pose, the rail turned to the view's azimuth.

    The rail is first held at the angle that puts the arm's shoulder at the camera's azimuth about
    the rail axis (the stage is symmetric about that axis, so every view of a ring then needs the
    same arm configuration); if the arm cannot reach the view from there, the rail is freed.

    An arm with a spherical wrist (the PUMA: :attr:`ArmKinematics.closed_form`) is solved in
    closed form: of its (up to eight) configurations at that rail angle and at every other,
    the one whose largest joint step from there (the guess's arm joints, the azimuth's rail
    angle) is smallest, exact to round-off; a failure says why (out of reach, or no
    configuration within the joint limits). Other arms (the
    Panda) by damped least squares from the guess, its wrist flipped, and random restarts.

    Parameters
    ----------
    kin : ArmKinematics
    T_world_camera : (4, 4) float
        Camera pose, OpenCV convention (e.g. from :func:`look_at_pose`).
    q0 : (n,) float, optional
        Initial guess (e.g. the previous view's solution); its rail entry is replaced.
    restarts, seed
        Random restarts per attempt and their seed (damped least squares only).

    Returns
    -------
    IKResult
    """
    T = check_pose(T_world_camera, "T_world_camera")
    rail_axis_point = kin.frame_pose(np.zeros(kin.nq), "rail")[:3, 3]
    rel = T[:3, 3] - rail_axis_point
    start = np.zeros(kin.nq)
    start[1:] = kin.spec.home if q0 is None else np.asarray(q0, dtype=float)[1:]
    start[0] = kin.rail_angle_for_azimuth(np.arctan2(rel[1], rel[0]))
    if kin.closed_form is not None:
        return _closed_form_view(kin, T, start)
    attempts = [(start, 0)]
    if kin.spec.wrist_flip:
        # A spherical wrist (the PUMA's) reaches the same orientation with the wrist flipped
        # (q4 +- pi, -q5, q6 +- pi): try both from the guess before random restarts, so that a
        # guess whose wrist runs into the joint 4 limit does not send the solver far off.
        flipped = start.copy()
        flipped[4] += -np.pi if start[4] > 0 else np.pi
        flipped[5] = -start[5]
        flipped[6] += -np.pi if start[6] > 0 else np.pi
        attempts.append((flipped, 0))
    attempts.append((start, restarts))
    result = None
    for guess, n_restarts in attempts:
        attempt = kin.solve_ik(T, "camera", guess, locked=(0,), restarts=n_restarts, seed=seed)
        if result is None or attempt.success or (
                attempt.position_error + attempt.rotation_error
                < result.position_error + result.rotation_error):
            result = attempt
        if result.success:
            break
    if not result.success:
        free = kin.solve_ik(T, "camera", result.q, restarts=restarts, seed=seed + 1)
        if free.position_error + free.rotation_error < (result.position_error
                                                        + result.rotation_error):
            result = free
    return result


def _closed_form_view(kin: ArmKinematics, T: np.ndarray, start: np.ndarray) -> IKResult:
    """:func:`solve_view_ik` for an arm with a closed form: ``start`` holds the rail angle at
    the view's azimuth and the guess."""
    q = kin.closed_form.solve(T, float(start[0]), start)
    if isinstance(q, Unreachable):
        return IKResult(q=kin.clip(start), success=False, position_error=math.inf,
                        rotation_error=math.inf, reason=q.reason)
    T_q = kin.camera_pose(q)
    p_err = float(np.linalg.norm(T_q[:3, 3] - T[:3, 3]))
    r_err = rotation_angle(T_q[:3, :3].T @ T[:3, :3])
    return IKResult(q=q, success=bool(p_err < IK_ACCEPT_POSITION and r_err < IK_ACCEPT_ROTATION),
                    position_error=p_err, rotation_error=r_err)


def arm_contacts(model, data, kin: ArmKinematics) -> list[tuple[str, str]]:
    """Contacts in ``data`` that involve the rail carriage or the arm.

    Call after setting ``data.qpos`` and ``mujoco.mj_forward``. An empty list means the arm touches
    nothing (neither the table, the object, the floor nor itself).

    Returns
    -------
    pairs : list of (geom name or id, geom name or id)
    """
    rail_b = int(model.jnt_bodyid[mj_id(model, mujoco.mjtObj.mjOBJ_JOINT,
                                         kin.spec.rail_joint, "rail joint")])
    moving = {b for b in range(model.nbody) if _descends_from(model, b, rail_b)}

    def name(g):
        n = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
        return n if n else f"geom {g} of body {model.body(model.geom_bodyid[g]).name!r}"

    out = []
    for c in data.contact[: data.ncon]:
        g1, g2 = int(c.geom[0]), int(c.geom[1])
        if model.geom_bodyid[g1] in moving or model.geom_bodyid[g2] in moving:
            out.append((name(g1), name(g2)))
    return out


def _descends_from(model, body: int, root: int) -> bool:
    b = body
    while b != 0:
        if b == root:
            return True
        b = int(model.body_parentid[b])
    return root == 0
