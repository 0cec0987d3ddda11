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
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from artrecon.geometry import pose, quat_wxyz_to_matrix
from sim.camera import T_GL_CV

log = logging.getLogger(__name__)

#: The repository root: ArmSpec.urdf paths are relative to it.
ROOT = Path(__file__).resolve().parents[1]


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
    import mujoco

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


# ----------------------------------------------------------------------------------------------
# Camera geometry helpers
# ----------------------------------------------------------------------------------------------


def look_at_pose(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera pose (OpenCV convention) at ``eye`` looking at ``target``, image "up" towards ``up``.

    Parameters
    ----------
    eye, target, up : (3,) float
        Camera centre, the point on the optical axis, and the world direction that appears upwards
        in the image (``-y`` of the camera lies in the plane of ``up`` and the optical axis).

    Returns
    -------
    T_world_camera : (4, 4) float
    """
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    for name, v in (("eye", eye), ("target", target), ("up", up)):
        if v.shape != (3,):
            raise ValueError(f"look_at_pose: expected {name} of shape (3,), got {v.shape}")
    z = target - eye
    if np.linalg.norm(z) < 1e-12:
        raise ValueError("look_at_pose: eye and target coincide; give distinct points")
    z /= np.linalg.norm(z)
    y = -(up - np.dot(up, z) * z)
    if np.linalg.norm(y) < 1e-9:
        raise ValueError("look_at_pose: up is parallel to the viewing direction; pass another up")
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


def ring_camera_poses(target, distance: float, elevation: float, n: int = 36,
                      azimuth0: float = 0.0) -> np.ndarray:
    """Cameras on a horizontal ring around ``target``, all looking at it (OpenCV convention).

    Parameters
    ----------
    target : (3,) float
        The point every camera looks at (world frame).
    distance : float
        Camera centre to target (m).
    elevation : float
        Angle of the camera above the target's horizontal plane (rad).
    n : int
        Number of views, equally spaced in azimuth.
    azimuth0 : float
        Azimuth of the first view (rad), measured about world z from world x.

    Returns
    -------
    T_world_cameras : (n, 4, 4) float
    """
    target = np.asarray(target, dtype=float)
    if target.shape != (3,):
        raise ValueError(f"ring_camera_poses: expected target of shape (3,), got {target.shape}")
    out = np.empty((n, 4, 4))
    for i, az in enumerate(azimuth0 + 2.0 * np.pi * np.arange(n) / n):
        direction = np.array([np.cos(elevation) * np.cos(az), np.cos(elevation) * np.sin(az),
                              np.sin(elevation)])
        out[i] = look_at_pose(target + distance * direction, target)
    return out


# ----------------------------------------------------------------------------------------------
# Pinocchio model of rail + arm in a compiled MuJoCo scene
# ----------------------------------------------------------------------------------------------

#: IK stopping tolerances. 1e-6 m / 1e-6 rad is far below anything a camera pose or a grasp needs
#: and still reached in a few damped Newton steps (the PUMA's wrist is spherical).
IK_TOL_POSITION = 1e-6
IK_TOL_ROTATION = 1e-6
#: A solve that stops short of the tolerances still counts as a success below these errors
#: (0.1 mm, 0.1 mrad: a tenth of a pixel at 0.5 m for the 554 px wrist camera).
IK_ACCEPT_POSITION = 1e-4
IK_ACCEPT_ROTATION = 1e-4
#: An IK descent gives up when its error (m + rad) has not fallen by 5% (to this share) within
#: IK_STALL_ITERATIONS iterations: a converging descent gains far more (damped Gauss-Newton)
IK_STALL_IMPROVEMENT = 0.95
IK_STALL_ITERATIONS = 30


@dataclass(frozen=True)
class IKResult:
    """Outcome of :meth:`ArmKinematics.solve_ik`."""

    q: np.ndarray
    """(n,) float, the best configuration found (always within the joint limits)"""
    success: bool
    """errors below IK_ACCEPT_POSITION / IK_ACCEPT_ROTATION"""
    position_error: float
    """distance between the frame and the target (m)"""
    rotation_error: float
    """angle between the frame and the target orientation (rad); 0 for position-only solves"""


def _check_pose(T, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"expected {name} of shape (4, 4), got {T.shape}")
    return T


def _mj_id(model, kind, name: str, what: str) -> int:
    import mujoco

    idx = mujoco.mj_name2id(model, kind, name)
    if idx < 0:
        raise ValueError(f"no {what} named {name!r} in the MuJoCo model: is the arm attached with "
                         "the ArmSpec's prefix (scenes/stage.xml) and the rail joint named as in "
                         "the spec?")
    return idx


class ArmKinematics:
    """Pinocchio model of the rail and the arm, expressed in a MuJoCo scene's world frame.

    Build it with :func:`load_arm_kinematics`. All methods take ``q`` : (n,) float in the order of
    :attr:`joint_names` (rail first) and return world-frame quantities.
    """

    def __init__(self, pin_model, joint_names: tuple[str, ...], frames: dict[str, int],
                 spec: ArmSpec, azimuth_at_zero: float):
        import pinocchio as pin

        self._pin = pin
        self.model = pin_model
        """the pinocchio model (one revolute joint per entry of joint_names)"""
        self.data = pin_model.createData()
        self.spec = spec
        self.joint_names = joint_names
        self.frames = dict(frames)
        self.lower = np.array(pin_model.lowerPositionLimit, dtype=float)
        self.upper = np.array(pin_model.upperPositionLimit, dtype=float)
        #: azimuth (about world z, from world x) of DH frame 0 when the rail is at 0
        self.azimuth_at_zero = float(azimuth_at_zero)

    @property
    def nq(self) -> int:
        return self.model.nq

    def _q(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.nq,):
            raise ValueError(f"expected q of shape ({self.nq},) in the order {self.joint_names}, "
                             f"got {q.shape}")
        return q

    def _frame_id(self, frame: str) -> int:
        if frame not in self.frames:
            raise ValueError(f"unknown frame {frame!r}; known frames: {sorted(self.frames)}")
        return self.frames[frame]

    def frame_pose(self, q, frame: str) -> np.ndarray:
        """Pose of a named frame in the world.

        Parameters
        ----------
        q : (n,) float
        frame : str
            ``"camera"`` (OpenCV convention), ``"grasp"``, ``"flange"``, ``"rail"`` or
            ``"frame0"`` .. ``"frame6"`` (DH frames).

        Returns
        -------
        T_world_frame : (4, 4) float
        """
        q = self._q(q)
        fid = self._frame_id(frame)
        self._pin.forwardKinematics(self.model, self.data, q)
        return self._pin.updateFramePlacement(self.model, self.data, fid).homogeneous.copy()

    def camera_pose(self, q) -> np.ndarray:
        """``T_world_camera`` : (4, 4) float of the wrist camera, OpenCV convention."""
        return self.frame_pose(q, "camera")

    def jacobian(self, q, frame: str) -> np.ndarray:
        """Frame Jacobian, world-aligned, rows ``[linear; angular]`` : (6, n) float."""
        q = self._q(q)
        fid = self._frame_id(frame)
        return self._pin.computeFrameJacobian(self.model, self.data, q, fid,
                                              self._pin.LOCAL_WORLD_ALIGNED).copy()

    def clip(self, q) -> np.ndarray:
        """``q`` clipped to the joint limits."""
        return np.clip(self._q(q), self.lower, self.upper)

    def nearest_equivalent(self, q, q_ref) -> np.ndarray:
        """``q`` with each joint turned by whole turns to lie as near ``q_ref`` as its limits
        allow: the same pose of every link (all joints are revolute), reached by a shorter move
        from ``q_ref``. Matters for joints whose range exceeds a turn (the PUMA's wrist roll,
        +-266 degrees). : (n,) float"""
        q, ref = self._q(q).copy(), self._q(q_ref)
        for i in range(self.nq):
            turns = q[i] + 2.0 * np.pi * np.arange(-2, 3)
            turns = turns[(turns >= self.lower[i]) & (turns <= self.upper[i])]
            if len(turns):
                q[i] = turns[np.argmin(np.abs(turns - ref[i]))]
        return q

    def solve_ik(self, T_world_target, frame: str = "camera", q0=None, *,
                 position_only: bool = False, locked=(), max_iter: int = 300,
                 restarts: int = 8, seed: int = 0, damping: float = 1e-4) -> IKResult:
        """Damped least squares IK for one frame, joint limits respected throughout.

        Starts at ``q0`` (default: the middle of the joint ranges, rail 0), then at ``restarts``
        configurations drawn uniformly within the limits from ``seed``; returns the first success,
        or the best attempt. Deterministic for given arguments.

        Parameters
        ----------
        T_world_target : (4, 4) float
            Target pose of ``frame`` in the world (only its translation if ``position_only``).
        frame : str
            A frame name of :meth:`frame_pose`.
        q0 : (n,) float, optional
            Initial guess; it is clipped to the limits.
        position_only : bool
            Solve for the frame's position only.
        locked : iterable of int
            Indices into ``q`` of joints held at their ``q0`` value (e.g. ``(0,)`` for the rail).
        max_iter, restarts, seed, damping
            Iterations per attempt, number of random restarts, their seed, and the squared damping
            of the least squares step.

        Returns
        -------
        IKResult
        """
        pin = self._pin
        T_target = _check_pose(T_world_target, "T_world_target")
        fid = self._frame_id(frame)
        free = np.ones(self.nq, dtype=bool)
        free[list(locked)] = False
        mid = np.where(np.isfinite(self.lower + self.upper), 0.5 * (self.lower + self.upper), 0.0)
        start = self.clip(mid if q0 is None else q0)
        M_target = pin.SE3(T_target[:3, :3].copy(), T_target[:3, 3].copy())
        rng = np.random.default_rng(seed)
        best = None
        for attempt in range(restarts + 1):
            q = start.copy()
            if attempt > 0:
                q[free] = rng.uniform(self.lower[free], self.upper[free])
            result = self._descend(q, fid, M_target, position_only, free, max_iter, damping)
            if best is None or (result.position_error + result.rotation_error
                                < best.position_error + best.rotation_error):
                best = result
            if result.success:
                return result
        log.debug("IK for frame %s did not converge: %.3g m, %.3g rad", frame,
                  best.position_error, best.rotation_error)
        return best

    def _descend(self, q, fid, M_target, position_only, free, max_iter, damping) -> IKResult:
        """Damped least squares from ``q`` until converged, stalled or ``max_iter``.

        Written for speed (view planning runs ~10^6 iterations for a large object): one
        kinematics pass per iteration (joint Jacobians, then the frame's placement and Jacobian
        from them), the error twist computed once and reused for the convergence test."""
        pin = self._pin
        model, data = self.model, self.data
        max_step = 0.3  # rad per iteration: keeps the linearisation valid far from the target
        frame = pin.LOCAL_WORLD_ALIGNED if position_only else pin.LOCAL
        lower, upper = self.lower[free], self.upper[free]
        D = damping * np.eye(3 if position_only else 6)
        t_target = np.asarray(M_target.translation)
        q = np.array(q, dtype=float)
        reference, since = np.inf, 0
        for it in range(max_iter + 1):
            pin.computeJointJacobians(model, data, q)
            M = pin.updateFramePlacement(model, data, fid)
            dp = t_target - M.translation
            p_err = math.sqrt(float(dp @ dp))
            if position_only:
                err, r_err = dp, 0.0
            else:
                err = pin.log6(M.actInv(M_target)).vector
                r_err = math.sqrt(float(err[3:] @ err[3:]))
            if it == max_iter or (p_err < IK_TOL_POSITION and r_err < IK_TOL_ROTATION):
                break
            # stalled (against a joint limit, in a local minimum, or at the solver's precision):
            # the rest of the iterations would not change the outcome. Most attempts of a view
            # plan are at targets out of reach, and they used to spend every iteration here
            error = p_err + r_err
            if error < IK_STALL_IMPROVEMENT * reference:
                reference, since = error, it
            elif it - since >= IK_STALL_ITERATIONS:
                break
            J = pin.getFrameJacobian(model, data, fid, frame)
            J = (J[:3] if position_only else J)[:, free]
            dq_free = J.T @ np.linalg.solve(J @ J.T + D, err)
            norm = math.sqrt(float(dq_free @ dq_free))
            if norm > max_step:
                dq_free *= max_step / norm
            q[free] = np.minimum(np.maximum(q[free] + dq_free, lower), upper)
        ok = p_err < IK_ACCEPT_POSITION and r_err < IK_ACCEPT_ROTATION
        return IKResult(q=q, success=bool(ok), position_error=p_err, rotation_error=r_err)

    def rail_angle_for_azimuth(self, azimuth: float) -> float:
        """Rail angle that puts DH frame 0 (the arm's shoulder axis) at ``azimuth`` (rad), wrapped
        into the rail's range."""
        rail = azimuth - self.azimuth_at_zero
        lo, hi = self.lower[0], self.upper[0]
        rail = (rail + np.pi) % (2 * np.pi) - np.pi
        if rail < lo:
            rail += 2 * np.pi
        elif rail > hi:
            rail -= 2 * np.pi
        return float(np.clip(rail, lo, hi))


def load_arm_kinematics(model, spec: ArmSpec | None = None) -> ArmKinematics:
    """Pinocchio model of the rail and arm of a compiled MuJoCo scene.

    The arm's kinematics come from ``spec.dh`` or ``spec.urdf`` (not from the MJCF); from the
    MuJoCo model come the rail joint (axis, position, range), the pose of the arm's base body on
    the carriage, the camera and grasp site placements on the flange body, and the body inertias.
    Joint limits: the DH arm's ``spec.qlim_deg``, the URDF arm's URDF.

    Parameters
    ----------
    model : mujoco.MjModel
        A compiled scene that contains ``spec.rail_joint`` and the arm attached with
        ``spec.prefix``.
    spec : ArmSpec, optional
        Default: the arm the scene chooses (:func:`arm_spec`).

    Returns
    -------
    ArmKinematics
    """
    import mujoco
    import pinocchio as pin

    if spec is None:
        spec = arm_spec(model)
    obj = mujoco.mjtObj
    p = spec.prefix
    rail_j = _mj_id(model, obj.mjOBJ_JOINT, spec.rail_joint, "rail joint")
    if model.jnt_type[rail_j] != mujoco.mjtJoint.mjJNT_HINGE:
        raise ValueError(f"rail joint {spec.rail_joint!r} must be a hinge")
    arm_j = [_mj_id(model, obj.mjOBJ_JOINT, p + j, "arm joint") for j in spec.joints]
    base_b = _mj_id(model, obj.mjOBJ_BODY, p + spec.base_body, "arm base body")
    flange_b = _mj_id(model, obj.mjOBJ_BODY, p + spec.flange_body, "flange body")
    cam = _mj_id(model, obj.mjOBJ_CAMERA, p + spec.camera, "camera")
    site = _mj_id(model, obj.mjOBJ_SITE, p + spec.grasp_site, "grasp site")
    rail_b = int(model.jnt_bodyid[rail_j])
    if model.cam_bodyid[cam] != flange_b or model.site_bodyid[site] != flange_b:
        raise ValueError(f"camera {p + spec.camera!r} and site {p + spec.grasp_site!r} must sit on "
                         f"the flange body {p + spec.flange_body!r}")

    # Poses at the reference configuration (all joints at 0): the rail body and the arm's base.
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    for j in [rail_j, *arm_j]:
        data.qpos[model.jnt_qposadr[j]] = 0.0
    mujoco.mj_kinematics(model, data)

    def body_pose(b):
        return pose(data.xmat[b].reshape(3, 3).copy(), data.xpos[b].copy())

    T_world_railbody = body_pose(rail_b)
    T_world_base = body_pose(base_b)
    T_railbody_joint = pose(np.eye(3), model.jnt_pos[rail_j].copy())
    T_world_railjoint = T_world_railbody @ T_railbody_joint
    # Arm bodies between the rail and the base must be rigid: everything on the carriage.
    b = base_b
    while b != rail_b:
        if b == 0:
            raise ValueError(f"arm base {p + spec.base_body!r} is not carried by the rail joint "
                             f"{spec.rail_joint!r}; mount the arm inside the rail's body")
        if model.body_jntnum[b] and b != base_b:
            raise ValueError(f"body {model.body(b).name!r} between rail and arm has joints")
        b = int(model.body_parentid[b])
    if model.body_jntnum[base_b]:
        raise ValueError(f"arm base body {p + spec.base_body!r} must be fixed to the carriage")
    T_base_frame0 = pose(np.eye(3), np.array([0.0, 0.0, spec.shoulder_height]))
    T_railjoint_frame0 = np.linalg.inv(T_world_railjoint) @ T_world_base @ T_base_frame0

    def se3(T):
        return pin.SE3(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]))

    def inertia(body):
        if model.body_mass[body] <= 0:
            return pin.Inertia.Zero()
        R = quat_wxyz_to_matrix(model.body_iquat[body])
        return pin.Inertia(float(model.body_mass[body]), model.body_ipos[body].copy(),
                           R @ np.diag(model.body_inertia[body]) @ R.T)

    pm = pin.Model()
    pm.name = f"rail+{spec.name}"
    frames: dict[str, int] = {}
    rail_lim = model.jnt_range[rail_j] if model.jnt_limited[rail_j] else np.array([-np.pi, np.pi])
    axis = model.jnt_axis[rail_j].copy()
    jid = pm.addJoint(0, pin.JointModelRevoluteUnaligned(axis), se3(T_world_railjoint),
                      spec.rail_joint, np.array([1e3]), np.array([10.0]),
                      np.array([rail_lim[0]]), np.array([rail_lim[1]]))
    # Everything rigidly on the carriage (carriage, mount, arm base) rides on the rail joint.
    carried = [b for b in range(model.nbody) if _rigidly_on(model, b, rail_b)]
    for body in carried:
        T_joint_body = np.linalg.inv(T_world_railjoint) @ body_pose(body)
        pm.appendBodyToJoint(jid, inertia(body), se3(T_joint_body))
    frames["rail"] = pm.addFrame(pin.Frame("rail", jid, pin.SE3.Identity(),
                                           pin.FrameType.OP_FRAME))
    frames["frame0"] = pm.addFrame(pin.Frame("frame0", jid, se3(T_railjoint_frame0),
                                             pin.FrameType.OP_FRAME))
    T_link_camgl = pose(quat_wxyz_to_matrix(model.cam_quat[cam]), model.cam_pos[cam].copy())
    T_link_site = pose(quat_wxyz_to_matrix(model.site_quat[site]), model.site_pos[site].copy())
    if spec.urdf is not None:
        add_chain = _add_urdf_chain
    else:
        add_chain = _add_dh_chain
    jid, T_joint_flange, T_joint_body = add_chain(pm, jid, T_railjoint_frame0, spec, model, arm_j,
                                                  frames, se3, inertia)
    # Camera and site placements are read relative to the MuJoCo flange body, whose frame is the
    # last joint's frame turned by its angle (for the PUMA: DH frame 6 up to the last row's
    # constant part, identity since alpha6 = a6 = d6 = 0).
    frames["flange"] = pm.addFrame(pin.Frame("flange", jid, se3(T_joint_flange),
                                             pin.FrameType.OP_FRAME))
    frames["camera"] = pm.addFrame(pin.Frame(
        "camera", jid, se3(T_joint_body @ T_link_camgl @ T_GL_CV), pin.FrameType.OP_FRAME))
    frames["grasp"] = pm.addFrame(pin.Frame(
        "grasp", jid, se3(T_joint_body @ T_link_site), pin.FrameType.OP_FRAME))

    names = (spec.rail_joint, *(p + j for j in spec.joints))
    p0 = (T_world_railjoint @ T_railjoint_frame0)[:3, 3]
    az0 = float(np.arctan2(p0[1], p0[0]))
    return ArmKinematics(pm, names, frames, spec, az0)


def _add_dh_chain(pm, parent, placement, spec, model, arm_j, frames, se3, inertia):
    """Append the DH arm's joints to ``pm`` after joint ``parent`` (DH frame 0 at ``placement``
    in that joint's frame); returns the last joint's id, the flange (DH frame 6) and the MuJoCo
    flange body in its frame."""
    import pinocchio as pin

    p = spec.prefix
    jid = parent
    for i, (link, j) in enumerate(zip(spec.dh, arm_j, strict=True)):
        lo, hi = np.deg2rad(spec.qlim_deg[i])
        jid = pm.addJoint(parent, pin.JointModelRZ(), se3(placement), p + spec.joints[i],
                          np.array([1e3]), np.array([10.0]), np.array([lo]), np.array([hi]))
        # MuJoCo's body of joint i+1 has the frame of DH frame i turned by q_i: same as here.
        pm.appendBodyToJoint(jid, inertia(int(model.jnt_bodyid[j])), pin.SE3.Identity())
        T_i = dh_transform(link, 0.0)
        frames[f"frame{i + 1}"] = pm.addFrame(pin.Frame(f"frame{i + 1}", jid, se3(T_i),
                                                        pin.FrameType.OP_FRAME))
        parent, placement = jid, T_i
    # DH frame 6 in joint 6's frame; MuJoCo's flange body is joint 6's frame itself (identity).
    return jid, dh_transform(spec.dh[-1], 0.0), np.eye(4)


def _add_urdf_chain(pm, parent, placement, spec, model, arm_j, frames, se3, inertia):
    """Append the URDF arm's joints ``spec.urdf_joints`` (a serial chain from the URDF's root
    link, which is the MJCF's base body) to ``pm`` after joint ``parent``, the root link at
    ``placement`` in that joint's frame; returns the last joint's id, the flange and the MuJoCo
    flange body in its frame (both identity: the flange body is the last joint's child link)."""
    import pinocchio as pin

    path = ROOT / spec.urdf
    if not path.is_file():
        raise ValueError(f"{path}: URDF of arm {spec.name!r} not found; regenerate it with "
                         f"robots/{spec.name}/generate_mjcf.py")
    um = pin.buildModelFromUrdf(str(path))
    if len(spec.urdf_joints) != len(spec.joints):
        raise ValueError(f"ArmSpec {spec.name!r}: {len(spec.joints)} joints but "
                         f"{len(spec.urdf_joints)} urdf_joints; give one URDF name per joint")
    jid, previous = parent, 0
    for i, (uname, j) in enumerate(zip(spec.urdf_joints, arm_j, strict=True)):
        if not um.existJointName(uname):
            raise ValueError(f"{path}: no joint {uname!r} (ArmSpec {spec.name!r}); its joints "
                             f"are {list(um.names)[1:]}")
        uj = um.getJointId(uname)
        if um.parents[uj] != previous:
            raise ValueError(f"{path}: joint {uname!r} does not follow {um.names[previous]!r}; "
                             f"urdf_joints must be a serial chain from the root link")
        jm = um.joints[uj]
        if jm.nq != 1:
            raise ValueError(f"{path}: joint {uname!r} has {jm.nq} coordinates; only 1-dof "
                             f"joints are supported")
        T = placement @ um.jointPlacements[uj].homogeneous
        jid = pm.addJoint(jid, jm, se3(T), spec.prefix + spec.joints[i],
                          np.array(um.effortLimit[jm.idx_v:jm.idx_v + 1]),
                          np.array(um.velocityLimit[jm.idx_v:jm.idx_v + 1]),
                          np.array(um.lowerPositionLimit[jm.idx_q:jm.idx_q + 1]),
                          np.array(um.upperPositionLimit[jm.idx_q:jm.idx_q + 1]))
        pm.appendBodyToJoint(jid, inertia(int(model.jnt_bodyid[j])), pin.SE3.Identity())
        frames[f"frame{i + 1}"] = pm.addFrame(pin.Frame(f"frame{i + 1}", jid, pin.SE3.Identity(),
                                                        pin.FrameType.OP_FRAME))
        placement, previous = np.eye(4), uj
    return jid, np.eye(4), np.eye(4)


def _rigidly_on(model, body: int, root: int) -> bool:
    """True if ``body`` is ``root`` or welded to it through joint-free bodies."""
    b = body
    while True:
        if b == root:
            return True
        if b == 0 or model.body_jntnum[b]:
            return False
        b = int(model.body_parentid[b])


def qpos_indices(model, kin: ArmKinematics) -> np.ndarray:
    """qpos addresses of ``kin.joint_names`` in a MuJoCo model : (n,) int."""
    import mujoco

    ids = [_mj_id(model, mujoco.mjtObj.mjOBJ_JOINT, n, "joint") for n in kin.joint_names]
    return np.array([model.jnt_qposadr[j] for j in ids], dtype=int)


def actuator_indices(model, kin: ArmKinematics) -> np.ndarray:
    """Indices into ``data.ctrl`` of the position actuators of ``kin.joint_names`` : (n,) int."""
    import mujoco

    out = []
    for name in kin.joint_names:
        j = _mj_id(model, mujoco.mjtObj.mjOBJ_JOINT, name, "joint")
        hits = [a for a in range(model.nu)
                if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
                and model.actuator_trnid[a, 0] == j]
        if len(hits) != 1:
            raise ValueError(f"expected one actuator on joint {name!r}, found {len(hits)}; every "
                             "rail and arm joint needs exactly one position actuator")
        out.append(hits[0])
    return np.array(out, dtype=int)


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

    Parameters
    ----------
    kin : ArmKinematics
    T_world_camera : (4, 4) float
        Camera pose, OpenCV convention (e.g. from :func:`look_at_pose`).
    q0 : (n,) float, optional
        Initial guess (e.g. the previous view's solution); its rail entry is replaced.
    restarts, seed
        Random restarts per attempt and their seed.

    Returns
    -------
    IKResult
    """
    T = _check_pose(T_world_camera, "T_world_camera")
    rail_axis_point = kin.frame_pose(np.zeros(kin.nq), "rail")[:3, 3]
    rel = T[:3, 3] - rail_axis_point
    start = np.zeros(kin.nq)
    start[1:] = kin.spec.home if q0 is None else np.asarray(q0, dtype=float)[1:]
    start[0] = kin.rail_angle_for_azimuth(np.arctan2(rel[1], rel[0]))
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


def arm_contacts(model, data, kin: ArmKinematics) -> list[tuple[str, str]]:
    """Contacts in ``data`` that involve the rail carriage or the arm.

    Call after setting ``data.qpos`` and ``mujoco.mj_forward``. An empty list means the arm touches
    nothing (neither the table, the object, the floor nor itself).

    Returns
    -------
    pairs : list of (geom name or id, geom name or id)
    """
    import mujoco

    rail_b = int(model.jnt_bodyid[_mj_id(model, mujoco.mjtObj.mjOBJ_JOINT,
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
