"""Which arm: the PUMA 560 from its DH table and arms from a URDF (:class:`ArmSpec`), and the
plain DH product the tests compare pinocchio with."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

#: The repository root (robot model files are found from it).
ROOT = Path(__file__).resolve().parents[2]


# ----------------------------------------------------------------------------------------------
# The PUMA 560 as published
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DHLink:
    """One row of a standard DH table: ``T = Rz(theta) Tz(d) Tx(a) Rx(alpha)``."""

    a: float
    """link length (m)"""
    alpha: float
    """link twist (rad)"""
    d: float
    """link offset (m)"""


#: Standard DH parameters of the PUMA 560 (Corke, "A simple and systematic approach to assigning
#: Denavit-Hartenberg parameters", IEEE T-RO 2007; values of Corke & Armstrong-Helouvry 1994 as in
#: the Robotics Toolbox's mdl_puma560).
PUMA560_DH: tuple[DHLink, ...] = (
    DHLink(a=0.0, alpha=np.pi / 2, d=0.0),
    DHLink(a=0.4318, alpha=0.0, d=0.0),
    DHLink(a=0.0203, alpha=-np.pi / 2, d=0.15005),
    DHLink(a=0.0, alpha=np.pi / 2, d=0.4318),
    DHLink(a=0.0, alpha=-np.pi / 2, d=0.0),
    DHLink(a=0.0, alpha=0.0, d=0.0),
)

#: Joint limits in degrees (mdl_puma560 of Corke's Robotics Toolbox, after Wang & Chen 1991).
PUMA560_QLIM_DEG: tuple[tuple[float, float], ...] = (
    (-160.0, 160.0), (-45.0, 225.0), (-225.0, 45.0), (-110.0, 170.0), (-100.0, 100.0),
    (-266.0, 266.0),
)

#: Height of DH frame 0 (the shoulder) above the arm's mounting plate (body ``base``). A modelling
#: choice for the simple-shape column; the DH table starts at the shoulder.
PUMA560_SHOULDER_HEIGHT = 0.54

#: Pose of the wrist camera (OpenCV convention) in the flange frame (DH frame 6): 75 mm off the
#: approach axis along -y6 and 70 mm forward, looking along z6; image "down" (+y) points at the
#: gripper, which stays below the image's lower edge (checked in tests/test_robot.py).
PUMA560_T_FLANGE_CAMERA = np.array([
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, -0.075],
    [0.0, 0.0, 1.0, 0.070],
    [0.0, 0.0, 0.0, 1.0],
])

#: Grasp site in the flange frame: between the fingertips, on the approach axis.
PUMA560_GRASP_OFFSET = np.array([0.0, 0.0, 0.125])

#: Wrist camera (Logitech QuickCam Pro 5000 class): 640 x 480, 60 degrees horizontal field of view,
#: fx = fy = 320 / tan(30 deg) = 554.26 px, principal point at the image centre.
CAMERA_WIDTH, CAMERA_HEIGHT = 640, 480
CAMERA_FOCAL_PX = 320.0 / np.tan(np.deg2rad(30.0))


@dataclass(frozen=True)
class ArmSpec:
    """Which arm a scene uses and how its MJCF names things."""

    name: str
    """model name, e.g. ``"puma560"``"""
    prefix: str
    """prefix of the ``<attach>`` in scenes/stage.xml, e.g. ``"puma_"``"""
    camera: str
    """MuJoCo camera in the arm MJCF (scene name: prefix + camera)"""
    grasp_site: str
    """site at the gripper, in the arm MJCF"""
    rail_joint: str = "rail"
    """hinge of the rail carriage in the stage (not prefixed)"""
    joints: tuple[str, ...] = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6")
    """arm joints in the arm MJCF, base to flange"""
    base_body: str = "base"
    """the arm's root body (mounting plate) in the arm MJCF"""
    flange_body: str = "link6"
    """the body whose frame is DH frame 6"""
    dh: tuple[DHLink, ...] = PUMA560_DH
    """standard DH table, one row per arm joint"""
    qlim_deg: tuple[tuple[float, float], ...] = PUMA560_QLIM_DEG
    """joint limits (degrees), one pair per arm joint"""
    shoulder_height: float = PUMA560_SHOULDER_HEIGHT
    """DH frame 0 above the base body's origin, along its z axis (m)"""
    home: tuple[float, ...] = field(default=(0.115, 1.143, -3.755, 1.072, 0.272, -2.333))
    """home configuration of the arm joints (rad), the MJCF's ``home`` keyframe: on the stage,
    with the rail at 0, the wrist camera looks at the table centre from 0.45 m, 50 degrees up
    (at 40 degrees, as for the Panda, the PUMA on the 0.80 m rail is 2 degrees from a limit)"""
    urdf: str | None = None
    """URDF of the arm, relative to the repository root; None: the kinematics come from ``dh``"""
    urdf_joints: tuple[str, ...] = ()
    """the URDF's names of ``joints`` (same order), for a URDF arm"""
    wrist_flip: bool = True
    """the arm has a spherical wrist (joints 4-6) whose flipped solution (q4 +- pi, -q5,
    q6 +- pi) solve_view_ik tries before random restarts"""


PUMA560 = ArmSpec(name="puma560", prefix="puma_", camera="wrist_cam", grasp_site="grasp")

#: Pose of the Panda's wrist camera (OpenCV convention) in its hand frame (URDF ``panda_hand``,
#: z along the fingers, y the direction the fingers open): 50 mm off the hand's centre along -x
#: (just outside the hand's 32 mm half-thickness) and 40 mm forward, looking along z; image
#: "down" (+y) points at the gripper, whose fingertips stay 35 deg off the optical axis, below the
#: image's lower edge (23.4 deg).
PANDA_T_HAND_CAMERA = np.array([
    [0.0, 1.0, 0.0, -0.050],
    [-1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.040],
    [0.0, 0.0, 0.0, 1.0],
])
#: Grasp site in the Panda's hand frame: the URDF's ``panda_hand_tcp``, between the fingertips.
PANDA_GRASP_OFFSET = np.array([0.0, 0.0, 0.1034])
#: The Panda's fingers are welded open at this travel each (the URDF's upper limit, m).
PANDA_FINGER_OPENING = 0.04

#: Franka Emika Panda on the rail, kinematics from example-robot-data's URDF (robots/panda).
PANDA = ArmSpec(
    name="panda", prefix="panda_", camera="wrist_cam", grasp_site="grasp",
    joints=tuple(f"joint{i}" for i in range(1, 8)), base_body="link0", flange_body="link7",
    dh=(), qlim_deg=(), shoulder_height=0.0,
    home=(-2.239, 0.906, 2.239, -2.646, -1.447, 2.567, -1.366),
    urdf="robots/panda/panda.urdf", urdf_joints=tuple(f"panda_joint{i}" for i in range(1, 8)),
    wrist_flip=False)

#: Arms a scene can choose, by name.
ARMS: dict[str, ArmSpec] = {PUMA560.name: PUMA560, PANDA.name: PANDA}
#: Name of the MJCF ``<custom><text>`` that chooses the arm (its data: a key of ARMS).
ARM_TEXT = "artrecon:arm"


def arm_spec(model) -> ArmSpec:
    """The arm a compiled scene chooses: its ``<custom><text name="artrecon:arm" data=NAME/>``,
    or the PUMA 560 if it has none.

    Raises
    ------
    ValueError
        The text names an arm that is not in :data:`ARMS`.
    """
    t = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, ARM_TEXT)
    if t < 0:
        return PUMA560
    adr, size = int(model.text_adr[t]), int(model.text_size[t])
    name = bytes(model.text_data[adr:adr + size]).split(b"\0")[0].decode().strip()
    if name not in ARMS:
        raise ValueError(f'<custom><text name="{ARM_TEXT}" data="{name}"/> names an unknown arm; '
                         f"fix: use one of {sorted(ARMS)}")
    return ARMS[name]


# ----------------------------------------------------------------------------------------------
# Plain DH formulas
# ----------------------------------------------------------------------------------------------


def dh_transform(link: DHLink, theta: float) -> np.ndarray:
    """Standard DH transform ``T_{i-1}_{i} = Rz(theta) Tz(d) Tx(a) Rx(alpha)`` : (4, 4) float."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(link.alpha), np.sin(link.alpha)
    return np.array([
        [ct, -st * ca, st * sa, link.a * ct],
        [st, ct * ca, -ct * sa, link.a * st],
        [0.0, sa, ca, link.d],
        [0.0, 0.0, 0.0, 1.0],
    ])


def dh_forward(dh: tuple[DHLink, ...], q: np.ndarray) -> list[np.ndarray]:
    """Poses of DH frames 1..n in frame 0 by the plain DH product.

    Parameters
    ----------
    dh : n DH rows
    q : (n,) float
        Joint angles (rad).

    Returns
    -------
    frames : list of n (4, 4) float
        ``T_0_i`` for i = 1..n.
    """
    q = np.asarray(q, dtype=float)
    if q.shape != (len(dh),):
        raise ValueError(f"expected q of shape ({len(dh)},), got {q.shape}")
    T = np.eye(4)
    out = []
    for link, theta in zip(dh, q, strict=True):
        T = T @ dh_transform(link, theta)
        out.append(T)
    return out
