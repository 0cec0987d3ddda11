"""The arm's kinematics in pinocchio, read from a compiled MuJoCo scene
(:func:`load_arm_kinematics`), its inverse kinematics, and where its joints and actuators sit in
MuJoCo's arrays."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import mujoco
import numpy as np
import pinocchio as pin

from artrecon.geometry import pose, quat_wxyz_to_matrix
from sim.camera import T_GL_CV
from sim.robot.spec import ROOT, ArmSpec, arm_spec, dh_transform

try:  # np.linalg.solve's own gufunc (numpy 1.x and 2.x), without the wrapper's checks
    from numpy.linalg import _umath_linalg

    def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return _umath_linalg.solve1(a, b, signature="dd->d")
except (ImportError, AttributeError):  # pragma: no cover - a numpy without it
    _solve = np.linalg.solve

log = logging.getLogger(__name__)

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
#: Descents an arm remembers (:meth:`ArmKinematics.solve_ik`): a descent is a function of its
#: start, target and settings, and a view plan by damped least squares repeats a quarter of them
#: exactly (each candidate ring's probe views are solved again from the same starts; rolled
#: fallbacks and second chances): drawer config a, 5138 of 20262 descents, when the PUMA's views
#: were solved so (now in closed form, :mod:`sim.robot.closed_form`; the Panda's still are). The
#: memory is cleared when full.
IK_MEMO_SIZE = 50_000


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
    reason: str = ""
    """why it failed, where the solver knows (the closed form: out of reach, or no
    configuration within the joint limits); empty on success"""


def check_pose(T, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"expected {name} of shape (4, 4), got {T.shape}")
    return T


def mj_id(model, kind, name: str, what: str) -> int:
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
        self._memo: dict[tuple, IKResult] = {}
        self._closed_form = None

    @property
    def closed_form(self):
        """:class:`sim.robot.closed_form.SphericalWristIK` of this arm, or None if its
        kinematics are not of the structure it solves (a URDF arm: the Panda)."""
        if self._closed_form is None:
            from sim.robot.closed_form import SphericalWristIK, supports
            self._closed_form = SphericalWristIK(self) if supports(self.spec) else False
        return self._closed_form or None

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
        T_target = check_pose(T_world_target, "T_world_target")
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
            key = (q.tobytes(), T_target.tobytes(), fid, position_only, free.tobytes(),
                   max_iter, damping, self.lower.tobytes(), self.upper.tobytes())
            result = self._memo.get(key)
            if result is None:
                result = self._descend(q, fid, M_target, position_only, free, max_iter,
                                       damping)
                if len(self._memo) >= IK_MEMO_SIZE:
                    self._memo.clear()
                self._memo[key] = result
            result = replace(result, q=result.q.copy())  # callers own the q they get
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
        # every joint free (view planning): J[:, free] is J itself in Fortran order and q[free]
        # is q; the copies by boolean index were ~15% of an iteration. Fortran order as the
        # indexed copy had: matmul takes another path for C order, with other rounding
        all_free = bool(free.all())
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
            J = J[:3] if position_only else J
            J = np.asfortranarray(J) if all_free else J[:, free]
            # numpy's gufunc behind np.linalg.solve, without its checks (a quarter of the
            # iteration's time, ~10^6 iterations in a large object's view plan): same LAPACK
            # call, same numbers
            dq_free = J.T @ _solve(J @ J.T + D, err)
            norm = math.sqrt(float(dq_free @ dq_free))
            if norm > max_step:
                dq_free *= max_step / norm
            if all_free:
                q = np.minimum(np.maximum(q + dq_free, lower), upper)
            else:
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
    if spec is None:
        spec = arm_spec(model)
    obj = mujoco.mjtObj
    p = spec.prefix
    rail_j = mj_id(model, obj.mjOBJ_JOINT, spec.rail_joint, "rail joint")
    if model.jnt_type[rail_j] != mujoco.mjtJoint.mjJNT_HINGE:
        raise ValueError(f"rail joint {spec.rail_joint!r} must be a hinge")
    arm_j = [mj_id(model, obj.mjOBJ_JOINT, p + j, "arm joint") for j in spec.joints]
    base_b = mj_id(model, obj.mjOBJ_BODY, p + spec.base_body, "arm base body")
    flange_b = mj_id(model, obj.mjOBJ_BODY, p + spec.flange_body, "flange body")
    cam = mj_id(model, obj.mjOBJ_CAMERA, p + spec.camera, "camera")
    site = mj_id(model, obj.mjOBJ_SITE, p + spec.grasp_site, "grasp site")
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
    ids = [mj_id(model, mujoco.mjtObj.mjOBJ_JOINT, n, "joint") for n in kin.joint_names]
    return np.array([model.jnt_qposadr[j] for j in ids], dtype=int)


def actuator_indices(model, kin: ArmKinematics) -> np.ndarray:
    """Indices into ``data.ctrl`` of the position actuators of ``kin.joint_names`` : (n,) int."""
    out = []
    for name in kin.joint_names:
        j = mj_id(model, mujoco.mjtObj.mjOBJ_JOINT, name, "joint")
        hits = [a for a in range(model.nu)
                if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
                and model.actuator_trnid[a, 0] == j]
        if len(hits) != 1:
            raise ValueError(f"expected one actuator on joint {name!r}, found {len(hits)}; every "
                             "rail and arm joint needs exactly one position actuator")
        out.append(hits[0])
    return np.array(out, dtype=int)
