"""The arm: its kinematics (pinocchio) on the stage's circular rail, in a MuJoCo scene's frame.

Which arm a scene uses is the scene's choice: its stage names an :class:`ArmSpec` in
``<custom><text name="artrecon:arm" data="panda"/>`` (no such text: the PUMA 560), and
:func:`arm_spec` / :func:`load_arm_kinematics` pick it up. Two kinds of arm:

- the PUMA 560, defined once by its standard Denavit-Hartenberg table (:data:`PUMA560_DH`,
  sources in ``robots/puma560/README.md``); ``robots/puma560/generate_mjcf.py`` writes the
  MuJoCo model from these constants and the pinocchio model is built from the same table;
- arms from a URDF (:data:`PANDA`, the Franka Emika Panda of example-robot-data,
  ``robots/panda/``): ``robots/panda/generate_mjcf.py`` writes the MuJoCo model from the URDF and
  the pinocchio model is built from the same file (``pinocchio.buildModelFromUrdf``).

Either way :func:`load_arm_kinematics` reads from the compiled MuJoCo scene only what the scene
decides: where the rail is, where the arm is mounted on the rail carriage, and where the camera and
the grasp site sit on the flange. The tests check that pinocchio and MuJoCo (and, for the PUMA,
the plain DH product) agree.

Frames (all ``T_a_b``, metres): for the PUMA ``frame0`` .. ``frame6`` are the standard DH frames
(``frame0`` at the shoulder, ``frame6`` at the wrist centre, z along the approach direction) and
``flange`` is ``frame6``; for a URDF arm ``frame0`` is the arm's base link and ``frame<i>`` the
frame of its joint i (the URDF child link of joint i), ``flange`` the last joint's frame. For
every arm ``camera`` is the wrist camera in the OpenCV convention, ``grasp`` the grasp site
between the fingertips, ``rail`` the rail carriage.

Joint vector ``q`` : (1 + n,) float, radians, order ``(rail, joint1, ..., joint<n>)`` (n = 6 for the
PUMA, 7 for the Panda); MuJoCo takes it through ``data.qpos[qpos_indices(model, kin)]`` and the
position actuators through ``data.ctrl[actuator_indices(model, kin)]``.

Rooms: :mod:`~sim.robot.spec` (which arm: specs, the DH table), :mod:`~sim.robot.kinematics`
(pinocchio model, forward and inverse kinematics, MuJoCo indices), :mod:`~sim.robot.views`
(reaching a camera view), :mod:`~sim.robot.poses` (look-at and ring poses).
"""

from sim.robot.kinematics import (
    IK_ACCEPT_POSITION,
    IK_ACCEPT_ROTATION,
    IK_STALL_IMPROVEMENT,
    IK_STALL_ITERATIONS,
    IK_TOL_POSITION,
    IK_TOL_ROTATION,
    ArmKinematics,
    IKResult,
    actuator_indices,
    check_pose,
    load_arm_kinematics,
    mj_id,
    qpos_indices,
)
from sim.robot.poses import (
    look_at_pose,
    ring_camera_poses,
)
from sim.robot.spec import (
    ARM_TEXT,
    ARMS,
    CAMERA_FOCAL_PX,
    CAMERA_HEIGHT,
    CAMERA_WIDTH,
    PANDA,
    PANDA_FINGER_OPENING,
    PANDA_GRASP_OFFSET,
    PANDA_T_HAND_CAMERA,
    PUMA560,
    PUMA560_DH,
    PUMA560_GRASP_OFFSET,
    PUMA560_QLIM_DEG,
    PUMA560_SHOULDER_HEIGHT,
    PUMA560_T_FLANGE_CAMERA,
    ROOT,
    ArmSpec,
    DHLink,
    arm_spec,
    dh_forward,
    dh_transform,
)
from sim.robot.views import (
    PUMA560_VIEW_SEED,
    arm_contacts,
    solve_view_ik,
)

__all__ = [
    "CAMERA_HEIGHT",
    "CAMERA_WIDTH",
    "ARMS",
    "ARM_TEXT",
    "ArmKinematics",
    "ArmSpec",
    "CAMERA_FOCAL_PX",
    "DHLink",
    "IKResult",
    "IK_ACCEPT_POSITION",
    "IK_ACCEPT_ROTATION",
    "IK_STALL_IMPROVEMENT",
    "IK_STALL_ITERATIONS",
    "IK_TOL_POSITION",
    "IK_TOL_ROTATION",
    "PANDA",
    "PANDA_FINGER_OPENING",
    "PANDA_GRASP_OFFSET",
    "PANDA_T_HAND_CAMERA",
    "PUMA560",
    "PUMA560_DH",
    "PUMA560_GRASP_OFFSET",
    "PUMA560_QLIM_DEG",
    "PUMA560_SHOULDER_HEIGHT",
    "PUMA560_T_FLANGE_CAMERA",
    "PUMA560_VIEW_SEED",
    "ROOT",
    "actuator_indices",
    "arm_contacts",
    "arm_spec",
    "check_pose",
    "dh_forward",
    "dh_transform",
    "load_arm_kinematics",
    "look_at_pose",
    "mj_id",
    "qpos_indices",
    "ring_camera_poses",
    "solve_view_ik",
]
