"""Manipulation: the arm grasps the object's moving link and moves it along an estimated joint.

``python -m sim.manipulate SCENE [--model MODEL.json] [--angle DEG | --distance M] --out DIR``

Given a scene, an estimated joint in the world frame (type, axis direction, a point on the axis:
:class:`JointEstimate`, from a registered :class:`~artrecon.model.ArticulatedModel` or from the
scene's ground truth) and a grasp point on the moving link, :func:`manipulate` runs, in MuJoCo
physics at the scene's timestep:

1. **plan** (pinocchio, :mod:`sim.robot`): the grasp frame sits ``GRASP_STANDOFF`` off the surface
   along its normal, approaching along ``-normal`` (the fingertips stop just short of the
   surface); several rolls about the approach axis are tried. For each: IK of the grasp pose,
   of the pre-grasp pose (``PREGRASP_DISTANCE`` further out), and of every waypoint of the
   motion (an arc about the revolute axis or a line along the prismatic axis, the gripper's
   orientation turning with the arc, small steps, each IK started at the previous solution,
   joint limits respected); the arm must touch nothing at pre-grasp and grasp.
2. **travel and approach**: the position servos follow a joint-space line to the pre-grasp
   configuration, then the straight approach.
3. **grasp**. The PUMA's gripper is a fixed two-finger shape with no actuated fingers, so the
   grasp is *not* a frictional grip: it is a MuJoCo ``<equality><weld>`` between the flange body
   and the body under the fingertips, switched on (``data.eq_active``) once the grasp frame is
   within ``GRASP_ACTIVATION_DISTANCE`` of its planned pose -- i.e. an idealised gripper that
   holds whatever it touches, rigidly, with unlimited strength. The welds (one per object body,
   all off) are added to the scene with ``MjSpec`` before compiling; the body to weld is the one
   a ray along the approach direction hits, so a grasp point that is not on the moving link
   really grasps whatever is there.
4. **motion**: the servos follow the planned waypoints with a minimum-jerk time law; then the
   arm holds, the weld is switched off and the object is left to settle.

Measured (:class:`ManipulationResult`): the object's joint displacement (read from its qpos)
against the requested one; the peak force and torque in the weld (``data.efc_force`` of its
equality rows: what the arm has to push against the joint); the arm's tracking error (actual vs
commanded joint angles, actual vs planned grasp-frame path). A wrong axis makes the arm fight the
joint: the forces grow and/or the joint moves less.

Grasp points: any point on the moving link. By default the candidates are points on the moving
link's surfaces (collision geoms of the scene, or the points of a registered model), and the
default *prefers a point the wrist camera cannot see from the arm's current pose* (ray cast with
``mj_ray`` from the camera centre against the collision geoms, or outside the image): the
occlusion-aware grasp the method exists for. The result and the log say whether the chosen point
is hidden, and why.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from artrecon.geometry import rotation_about
from sim import robot, views
from sim.camera import mujoco_camera_intrinsics
from sim.scene import Scene, load_scene

log = logging.getLogger(__name__)

# --- constants (each with why) ----------------------------------------------------------------

#: Grasp frame (the "grasp" site, 15 mm behind the fingertips) is placed this far off the surface
#: along the normal: the fingertips stop 3 mm short of it, so they do not press into the link.
GRASP_STANDOFF = 0.018
#: Pre-grasp pose: this much further out along the normal (clear of the surface for any roll).
PREGRASP_DISTANCE = 0.07
#: The weld is switched on when the grasp frame is this close to its planned pose: the servos
#: settle within about a millimetre; 5 mm still means "the fingers are at the surface".
GRASP_ACTIVATION_DISTANCE = 0.005
#: The ray from the grasp frame along the approach must hit the body to grasp within the standoff
#: plus this margin (m).
GRASP_REACH_MARGIN = 0.01
#: A point is hidden when the camera ray meets another surface at least this much before it (m):
#: the collision geoms are simple shapes, a few mm off the rendered meshes.
OCCLUSION_TOLERANCE = 0.003
#: Candidate surface points: a grid of this many points per side on each face of a box, inset by
#: INSET of the half-size from the edges (the fingers need some surface around the point).
FACE_GRID = 3
FACE_INSET = 0.6
#: Revolute joints: candidate points nearer the axis than this are not used (a short lever turns
#: the gripper a lot for little motion and needs large forces) ...
MIN_LEVER = 0.06
#: ... unless the link reaches no farther than MIN_LEVER from its axis (a Barrett finger turning
#: about its own spread axis reaches 4.7 cm): then points beyond this fraction of its reach.
MIN_LEVER_FRACTION = 0.6
#: Candidates whose normal points down more steeply than this (z component) are not approached
#: (from below the object, i.e. through the table).
MIN_NORMAL_Z = -0.3
#: Free space in front of a candidate: rays along the normal, one from the point and four
#: APPROACH_RADIUS around it (the fingertips sit 3 cm off the approach axis; IK + a contact
#: check at the grasp pose judge the rest), must be free for APPROACH_FREE_LENGTH (gripper, wrist).
APPROACH_RADIUS = 0.025
APPROACH_FREE_LENGTH = 0.3
#: Rolls of the gripper about the approach axis tried for each candidate (deg).
ROLLS_DEG = (0, 45, 90, 135, 180, 225, 270, 315)
#: At most this many candidates are planned (in order of preference) before giving up.
MAX_CANDIDATES = 40
#: Motion waypoints: one per this much of the motion (rad or m), at least MIN_WAYPOINTS.
WAYPOINT_ANGLE = np.deg2rad(1.0)
WAYPOINT_DISTANCE = 0.002
MIN_WAYPOINTS = 20
#: Largest joint change between motion waypoints (rad): larger means the IK jumped branches.
MAX_WAYPOINT_JOINT_STEP = 0.15
#: Average speed of the grasp point during the motion (m/s; minimum-jerk peaks at 1.9x), and the
#: shortest motion time (s).
MOTION_SPEED = 0.04
MIN_MOTION_TIME = 1.5
#: Joint-space travel speed to the pre-grasp pose (rad/s, as in sim.capture) and approach time (s).
TRAVEL_SPEED = 1.0
APPROACH_TIME = 0.8
#: Settling: until joint speeds fall below SETTLE_SPEED (rad/s) or SETTLE_MAX_TIME (s) passes.
SETTLE_SPEED = 1e-3
SETTLE_MAX_TIME = 1.0
#: Hold with the weld on after the motion, and settle after release (s).
HOLD_TIME = 0.3
RELEASE_TIME = 0.3
#: Contacts along the travel line are checked at this many configurations.
TRAVEL_CHECKS = 12
#: Tilt of the deliberately wrong axis used by the tests and the CLI comparison (deg).
WRONG_AXIS_TILT_DEG = 20.0


class ManipulationError(RuntimeError):
    """No grasp could be planned, or the grasp could not be made."""


# --- inputs -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class JointEstimate:
    """A joint in the world frame (metres, radians).

    Attributes
    ----------
    type : str
        ``"revolute"`` or ``"prismatic"``.
    axis : (3,) float
        Unit direction; positive motion is right-handed about it / along it.
    point : (3,) float
        A point on the axis.
    source : str
        Where it came from (``"ground truth"``, ``"model"``, ``"tilted ..."``).
    name : str
    """

    type: str
    axis: np.ndarray
    point: np.ndarray
    source: str = "ground truth"
    name: str = ""

    def __post_init__(self):
        if self.type not in ("revolute", "prismatic"):
            raise ValueError(f"JointEstimate.type must be 'revolute' or 'prismatic', got "
                             f"{self.type!r}")
        axis = np.asarray(self.axis, dtype=float).reshape(-1)
        point = np.asarray(self.point, dtype=float).reshape(-1)
        if axis.shape != (3,) or point.shape != (3,):
            raise ValueError(f"axis and point must have shape (3,), got {axis.shape} and "
                             f"{point.shape}")
        n = np.linalg.norm(axis)
        if not np.isfinite(n) or n == 0:
            raise ValueError("JointEstimate.axis must be a non-zero finite vector")
        object.__setattr__(self, "axis", axis / n)
        object.__setattr__(self, "point", point)

    def tilted(self, degrees: float = WRONG_AXIS_TILT_DEG) -> JointEstimate:
        """The same joint with its axis turned by ``degrees`` about a fixed perpendicular
        (world z x axis, or world x if the axis is vertical), through the same point."""
        perp = np.cross(self.axis, [0.0, 0.0, 1.0])
        if np.linalg.norm(perp) < 1e-6:
            perp = np.cross(self.axis, [1.0, 0.0, 0.0])
        perp /= np.linalg.norm(perp)
        axis = rotation_about(perp, np.deg2rad(degrees)) @ self.axis
        return JointEstimate(self.type, axis, self.point, f"{self.source}, tilted {degrees:g} deg",
                             self.name)

    def motion(self, amount: float) -> np.ndarray:
        """``T_world`` (4, 4) of the motion by ``amount`` (rad or m) about/along the axis."""
        T = np.eye(4)
        if self.type == "revolute":
            R = rotation_about(self.axis, amount)
            T[:3, :3], T[:3, 3] = R, self.point - R @ self.point
        else:
            T[:3, 3] = amount * self.axis
        return T


def default_joint(scene: Scene):
    """The scene joint moved when none is named: the first one that moves between the two
    configurations (:attr:`sim.scene.Scene.moving_joints`). A static joint did not move, so no
    reconstruction estimates it and there is nothing to follow (cabinet_door_only's drawer); only
    a scene whose joints are all static falls back to its first joint.

    Raises
    ------
    ManipulationError
        The scene has no object joint.
    """
    if not scene.joints:
        raise ManipulationError(f"scene {scene.name!r} has no object joint: nothing to move")
    return (scene.moving_joints or scene.joints)[0]


def joint_estimate_from_scene(scene: Scene, joint: str | None = None) -> JointEstimate:
    """The ground-truth joint of a scene (configuration A) as a :class:`JointEstimate`; default
    :func:`default_joint`."""
    j = default_joint(scene) if joint is None else scene.joint(joint)
    return JointEstimate(j.type, j.axis, j.point, "ground truth", j.name)


def joint_estimate_from_model(model, joint: int = 0):
    """Joint and moving-link points of a *registered* ArticulatedModel (robot frame, metres).

    Returns
    -------
    estimate : JointEstimate
    points : (n, 3) float
        The child link's points (grasp candidates).
    normals : (n, 3) float or None
    """
    if not model.scale_known:
        raise ValueError("the model is not registered (scale_known is False): apply "
                         "artrecon.register.apply_registration first so it is in the robot "
                         "frame, in metres")
    if not model.joints:
        raise ValueError("the model has no joints: nothing to move")
    j = model.joints[joint]
    link = model.links[j.child]
    est = JointEstimate(j.type, j.axis_direction, j.axis_point, "model", j.name)
    return est, np.asarray(link.points, float), (None if link.normals is None
                                                 else np.asarray(link.normals, float))


# --- small geometry ---------------------------------------------------------------------------


def _pose(model, data, body: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = data.xmat[body].reshape(3, 3)
    T[:3, 3] = data.xpos[body]
    return T


def _min_jerk(tau: float) -> float:
    tau = min(max(tau, 0.0), 1.0)
    return tau ** 3 * (10 - 15 * tau + 6 * tau * tau)


# --- the harness's model: the scene plus welds ------------------------------------------------


@dataclass
class _World:
    scene: Scene
    model: mujoco.MjModel
    kin: robot.ArmKinematics
    qidx: np.ndarray
    vidx: np.ndarray
    aidx: np.ndarray
    arm_links: set
    flange_body: int
    weld_of_body: dict
    object_bodies: set


def build_world(scene: Scene) -> _World:
    """Compile the scene with one inactive weld (flange body to object body) per object body."""
    spec = mujoco.MjSpec.from_file(str(scene.path))
    arm = robot.arm_spec(scene.model)  # the scene's arm (PUMA 560, Panda, ...), not a fixed one
    flange = arm.prefix + arm.flange_body
    bodies = [scene.model.body(b).name for li in scene.links for b in li.body_ids]
    for name in bodies:
        if not name:
            continue
        eq = spec.add_equality(type=mujoco.mjtEq.mjEQ_WELD, objtype=mujoco.mjtObj.mjOBJ_BODY,
                               name=f"grasp_weld:{name}", name1=flange, name2=name, active=False)
        eq.data = np.r_[np.zeros(3), np.zeros(3), [1.0, 0, 0, 0], 1.0,
                        np.zeros(len(eq.data) - 11)]
    model = spec.compile()
    if model.nq != scene.model.nq or model.nbody != scene.model.nbody:
        raise RuntimeError("adding the grasp welds changed the model's layout; report this bug")
    kin = robot.load_arm_kinematics(model)
    weld = {}
    for i in range(model.neq):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_EQUALITY, i) or ""
        if name.startswith("grasp_weld:"):
            weld[model.body(name.split(":", 1)[1]).id] = i
    vidx = np.array([model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]
                     for n in kin.joint_names])
    return _World(scene, model, kin, robot.qpos_indices(model, kin), vidx,
                  robot.actuator_indices(model, kin), views.arm_link_bodies(model, kin),
                  model.body(flange).id, weld, {b for li in scene.links for b in li.body_ids})


def _fresh_data(world: _World, q_start=None) -> mujoco.MjData:
    m = world.model
    d = mujoco.MjData(m)
    if m.nkey > 0:
        mujoco.mj_resetDataKeyframe(m, d, 0)
    for j in world.scene.joints:
        d.qpos[j.qpos_adr] = j.value_a
    if q_start is not None:
        d.qpos[world.qidx] = q_start
        d.ctrl[world.aidx] = q_start
    d.eq_active[:] = 0
    mujoco.mj_forward(m, d)
    return d


# --- grasp candidates and visibility ----------------------------------------------------------


@dataclass(frozen=True)
class GraspCandidate:
    """A point on the moving link with its outward surface normal (world frame)."""

    point: np.ndarray
    normal: np.ndarray
    hidden: bool = False
    visibility: str = ""
    """``"visible"``, ``"occluded by <geom>"`` or ``"outside the image"``"""


def _inside_geom(model, data, g: int, p: np.ndarray, margin: float = 1e-4) -> bool:
    local = data.geom_xmat[g].reshape(3, 3).T @ (p - data.geom_xpos[g])
    s = model.geom_size[g]
    t = model.geom_type[g]
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        return bool(np.all(np.abs(local) < s - margin))
    if t == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return bool(np.hypot(local[0], local[1]) < s[0] - margin and abs(local[2]) < s[1] - margin)
    if t == mujoco.mjtGeom.mjGEOM_SPHERE:
        return bool(np.linalg.norm(local) < s[0] - margin)
    return False


def scene_grasp_candidates(world: _World, data, link: str) -> list[GraspCandidate]:
    """Points on the surfaces of a link's collision geoms (box faces, cylinder caps), with outward
    normals; points buried in another collision geom are dropped."""
    m = world.model
    bodies = set(world.scene.link(link).body_ids)
    collision = [g for g in range(m.ngeom) if int(m.geom_contype[g]) or int(m.geom_conaffinity[g])]
    out = []
    grid = np.linspace(-FACE_INSET, FACE_INSET, FACE_GRID)
    for g in collision:
        if int(m.geom_bodyid[g]) not in bodies:
            continue
        R, c, s = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g], m.geom_size[g]
        local = []
        if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            for ax in range(3):
                u, v = [k for k in range(3) if k != ax]
                for sign in (-1.0, 1.0):
                    n = np.zeros(3)
                    n[ax] = sign
                    for a in grid:
                        for b in grid:
                            p = n * s[ax]
                            p[u], p[v] = a * s[u], b * s[v]
                            local.append((p, n))
        elif m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CYLINDER:
            for sign in (-1.0, 1.0):
                n = np.array([0.0, 0.0, sign])
                for a in grid:
                    local.append((np.array([a * s[0], 0.0, sign * s[1]]), n))
        for p, n in local:
            pw, nw = c + R @ p, R @ n
            if any(_inside_geom(m, data, h, pw) for h in collision if h != g):
                continue
            out.append(GraspCandidate(pw, nw))
    return out


def classify_visibility(world: _World, data, q, candidates) -> list[GraspCandidate]:
    """Mark each candidate hidden or visible from the wrist camera at arm configuration ``q``.

    Hidden: outside the image, or the ray from the camera centre meets another collision surface
    more than ``OCCLUSION_TOLERANCE`` before the point (``mujoco.mj_ray``).
    """
    m = world.model
    cam = world.kin.spec.prefix + world.kin.spec.camera
    K, (w, h) = mujoco_camera_intrinsics(m, cam)
    T = world.kin.camera_pose(q)
    saved = data.qpos.copy()
    data.qpos[world.qidx] = q
    mujoco.mj_forward(m, data)
    groups = np.zeros(6, dtype=np.uint8)
    groups[3] = 1  # collision geoms: the stage's, the object's and the arm's
    out = []
    geomid = np.zeros(1, dtype=np.int32)
    for c in candidates:
        pc = T[:3, :3].T @ (c.point - T[:3, 3])
        uv = K @ pc
        if pc[2] <= 0 or not (0 <= uv[0] / uv[2] < w and 0 <= uv[1] / uv[2] < h):
            out.append(GraspCandidate(c.point, c.normal, True, "outside the image"))
            continue
        ray = c.point - T[:3, 3]
        dist = float(np.linalg.norm(ray))
        hit = mujoco.mj_ray(m, data, T[:3, 3], ray / dist, groups, 1, world.flange_body, geomid)
        if 0 <= hit < dist - OCCLUSION_TOLERANCE:
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(geomid[0])) or \
                f"geom {int(geomid[0])}"
            out.append(GraspCandidate(c.point, c.normal, True, f"occluded by {name}"))
        else:
            out.append(GraspCandidate(c.point, c.normal, False, "visible"))
    data.qpos[:] = saved
    mujoco.mj_forward(m, data)
    return out


# --- planning ---------------------------------------------------------------------------------


@dataclass
class _Plan:
    candidate: GraspCandidate
    roll_deg: float
    T_grasp: np.ndarray
    q_pre: np.ndarray
    q_grasp: np.ndarray
    approach: np.ndarray  # (k, n) joint waypoints pre-grasp -> grasp
    s: np.ndarray  # (N+1,) path parameter of the motion waypoints
    q_path: np.ndarray  # (N+1, n)
    p_path: np.ndarray  # (N+1, 3) planned grasp-frame positions


def _grasp_frame(point, normal, roll_deg: float) -> np.ndarray:
    z = -np.asarray(normal, float)
    z /= np.linalg.norm(z)
    ref = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    x = rotation_about(z, np.deg2rad(roll_deg)) @ x
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, np.cross(z, x), z
    T[:3, 3] = np.asarray(point, float) + GRASP_STANDOFF * np.asarray(normal, float)
    return T


def _contacts_at(world: _World, data, q) -> list[str]:
    data.qpos[world.qidx] = q
    mujoco.mj_forward(world.model, data)
    return views.arm_collisions(world.model, data, world.arm_links)


def _plan_candidate(world: _World, data, cand: GraspCandidate, est: JointEstimate,
                    amount: float, q_start: np.ndarray, seed: int) -> tuple[_Plan | None, str]:
    kin = world.kin
    n_way = max(MIN_WAYPOINTS, int(np.ceil(abs(amount) / (
        WAYPOINT_ANGLE if est.type == "revolute" else WAYPOINT_DISTANCE))))
    s = np.linspace(0.0, 1.0, n_way + 1)
    reasons = []
    best = None
    # cheap first test: can the grasp frame's origin get there at all (any orientation)?
    reach = kin.solve_ik(_grasp_frame(cand.point, cand.normal, 0.0), "grasp", q_start,
                         position_only=True, restarts=2, seed=seed)
    if not reach.success:
        return None, (f"out of reach: the grasp frame gets no closer than "
                      f"{1e3 * reach.position_error:.0f} mm")
    for roll in ROLLS_DEG:
        T_g = _grasp_frame(cand.point, cand.normal, roll)
        ik = kin.solve_ik(T_g, "grasp", reach.q, restarts=2, seed=seed)
        if not ik.success:
            reasons.append(f"roll {roll}: grasp pose unreachable")
            continue
        T_pre = T_g.copy()
        T_pre[:3, 3] += PREGRASP_DISTANCE * cand.normal
        pre = kin.solve_ik(T_pre, "grasp", ik.q, restarts=0)
        if not pre.success:
            reasons.append(f"roll {roll}: pre-grasp unreachable")
            continue
        hits = _contacts_at(world, data, ik.q) or _contacts_at(world, data, pre.q)
        if hits:
            reasons.append(f"roll {roll}: arm touches {hits[0]}")
            continue
        # the approach, pre-grasp -> grasp, in 8 small steps
        approach, q = [pre.q], pre.q
        ok = True
        for f in np.linspace(0, 1, 9)[1:]:
            T = T_g.copy()
            T[:3, 3] += (1 - f) * PREGRASP_DISTANCE * cand.normal
            r = kin.solve_ik(T, "grasp", q, restarts=0)
            if not r.success or np.max(np.abs(r.q - q)) > MAX_WAYPOINT_JOINT_STEP:
                ok = False
                break
            approach.append(r.q)
            q = r.q
        if not ok:
            reasons.append(f"roll {roll}: approach line not followable")
            continue
        q_path, p_path, q = [q], [T_g[:3, 3].copy()], q
        for sk in s[1:]:
            T = est.motion(sk * amount) @ T_g
            r = kin.solve_ik(T, "grasp", q, restarts=0)
            if not r.success or np.max(np.abs(r.q - q)) > MAX_WAYPOINT_JOINT_STEP:
                ok = False
                break
            q_path.append(r.q)
            p_path.append(T[:3, 3].copy())
            q = r.q
        if not ok:
            reasons.append(f"roll {roll}: motion leaves the workspace or joint limits at "
                           f"{sk * 100:.0f}% of the path")
            continue
        # travel line from the start pose must be free
        clear = True
        for f in np.linspace(0, 1, TRAVEL_CHECKS + 2)[1:-1]:
            hits = _contacts_at(world, data, q_start + f * (pre.q - q_start))
            if hits:
                reasons.append(f"roll {roll}: travel to pre-grasp touches {hits[0]}")
                clear = False
                break
        if not clear:
            continue
        cost = float(np.sum(np.abs(pre.q - q_start)))
        plan = _Plan(cand, float(roll), T_g, pre.q, ik.q, np.array(approach), s,
                     np.array(q_path), np.array(p_path))
        if best is None or cost < best[0]:
            best = (cost, plan)
    if best is None:
        return None, "; ".join(reasons[:3])
    return best[1], ""


def _clear(world: _World, data, cands: list[GraspCandidate]) -> list[GraspCandidate]:
    """Candidates with free space in front of them: a bundle of rays along the normal (the
    centre and four around it, APPROACH_RADIUS off) must meet nothing for APPROACH_FREE_LENGTH."""
    groups = np.zeros(6, dtype=np.uint8)
    groups[3] = 1
    geomid = np.zeros(1, dtype=np.int32)
    out = []
    for c in cands:
        ref = np.array([0.0, 0.0, 1.0]) if abs(c.normal[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        u = np.cross(c.normal, ref)
        u /= np.linalg.norm(u)
        v = np.cross(c.normal, u)
        starts = [c.point + 1e-3 * c.normal]
        starts += [c.point + (GRASP_STANDOFF + 1e-3) * c.normal + APPROACH_RADIUS * w
                   for w in (u, -u, v, -v)]
        if all(not 0 <= mujoco.mj_ray(world.model, data, p0, c.normal, groups, 1, -1, geomid)
               < APPROACH_FREE_LENGTH for p0 in starts):
            out.append(c)
    return out


def _rank(cands: list[GraspCandidate], est: JointEstimate, prefer_hidden: bool):
    def lever(c):
        v = c.point - est.point
        return float(np.linalg.norm(v - np.dot(v, est.axis) * est.axis))

    reach = max((lever(c) for c in cands), default=0.0)
    min_lever = min(MIN_LEVER, MIN_LEVER_FRACTION * reach)
    usable = [c for c in cands if c.normal[2] >= MIN_NORMAL_Z
              and (est.type != "revolute" or lever(c) >= min_lever)]

    def key(c):
        hidden_rank = 0 if (c.hidden == prefer_hidden) else 1
        return (hidden_rank, -lever(c) if est.type == "revolute" else -c.point[2])

    return sorted(usable, key=key)


# --- result -----------------------------------------------------------------------------------


@dataclass
class ManipulationResult:
    """What one manipulation did, measured in the simulation (SI units; degrees/mm in to_dict)."""

    scene: str
    joint: str
    """the scene joint that actually moved (the one whose child holds the welded body)"""
    joint_type: str
    estimate: dict
    """the joint the arm followed: type, axis, point, source"""
    requested: float
    """requested displacement (rad or m) about/along the estimate"""
    achieved: float
    """measured joint displacement (rad or m), in the estimate's sense"""
    grasp_point: list
    grasp_normal: list
    grasp_hidden: bool
    grasp_visibility: str
    grasp_body: str
    grasp_roll_deg: float
    peak_force: float
    """peak norm of the weld's constraint force (N) during motion and hold"""
    peak_torque: float
    """peak norm of the weld's constraint torque (N m)"""
    mean_force: float
    tracking_rms: float
    """RMS of actual minus commanded arm joint angles during the motion (rad)"""
    tracking_max: float
    path_error_max: float
    """largest distance of the grasp frame from its planned path during the motion (m)"""
    arm_contacts: list
    simulated_time: float
    candidates: dict
    log: list = field(default_factory=list)
    frames: list = field(default_factory=list, repr=False)
    """(time, phase, qpos copy) snapshots, if recording was asked for"""

    @property
    def achieved_fraction(self) -> float:
        return self.achieved / self.requested if self.requested else float("nan")

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("frames")
        rev = self.joint_type == "revolute"
        d["units"] = "rad" if rev else "m"
        d["requested_display"] = (f"{np.rad2deg(self.requested):.2f} deg" if rev
                                  else f"{1e3 * self.requested:.1f} mm")
        d["achieved_display"] = (f"{np.rad2deg(self.achieved):.2f} deg" if rev
                                 else f"{1e3 * self.achieved:.1f} mm")
        d["achieved_fraction"] = self.achieved_fraction
        d["tracking_rms_deg"] = float(np.rad2deg(self.tracking_rms))
        d["tracking_max_deg"] = float(np.rad2deg(self.tracking_max))
        d["path_error_max_mm"] = 1e3 * self.path_error_max
        return d


# --- the run ----------------------------------------------------------------------------------


class _Sim:
    def __init__(self, world: _World, data, record_every: float | None):
        self.w, self.d = world, data
        self.dt = world.model.opt.timestep
        self.record_every = record_every
        self.frames: list = []
        self._next_rec = 0.0
        self.weld: int | None = None
        self.forces: list = []
        self.contacts: set = set()

    def step(self, phase: str):
        m, d = self.w.model, self.d
        mujoco.mj_step(m, d)
        if self.weld is not None:
            rows = np.flatnonzero((d.efc_type[:d.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY)
                                  & (d.efc_id[:d.nefc] == self.weld))
            f = d.efc_force[rows]
            if len(f) == 6:
                self.forces.append((phase, float(np.linalg.norm(f[:3])),
                                    float(np.linalg.norm(f[3:]))))
        if self.record_every is not None and d.time >= self._next_rec:
            self.frames.append((float(d.time), phase, d.qpos.copy()))
            self._next_rec = d.time + self.record_every

    def check_contacts(self):
        """Record arm contacts, except the gripper with the body it holds."""
        m, d = self.w.model, self.d
        held = None if self.weld is None else int(m.eq_obj2id[self.weld])
        for c in d.contact[: d.ncon]:
            b = {int(m.geom_bodyid[c.geom[0]]), int(m.geom_bodyid[c.geom[1]])}
            if not b & self.w.arm_links or (held is not None and b == {self.w.flange_body, held}):
                continue
            names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(g)) or f"geom{int(g)}"
                     for g in c.geom]
            self.contacts.add("/".join(sorted(names)))

    def settle(self, phase: str, seconds: float = SETTLE_MAX_TIME):
        for _ in range(int(seconds / self.dt)):
            self.step(phase)
            if np.max(np.abs(self.d.qvel[self.w.vidx])) < SETTLE_SPEED:
                break

    def follow(self, q_points: np.ndarray, duration: float, phase: str, law=lambda t: t):
        """Servo targets along joint waypoints (uniform in path parameter) over ``duration``."""
        n = len(q_points) - 1
        steps = max(1, int(np.ceil(duration / self.dt)))
        for i in range(1, steps + 1):
            x = law(i / steps) * n
            k = min(int(x), n - 1)
            self.d.ctrl[self.w.aidx] = q_points[k] + (x - k) * (q_points[k + 1] - q_points[k])
            self.step(phase)
            if i % 25 == 0:
                self.check_contacts()


def manipulate(scene: Scene | str, estimate: JointEstimate, amount: float, *,
               candidates: list[GraspCandidate] | None = None, grasp_point=None,
               grasp_normal=None, q_start=None, prefer_hidden: bool = True,
               record_every: float | None = None, seed: int = 0,
               world: _World | None = None, joint: str | None = None) -> ManipulationResult:
    """Grasp the moving link and move it by ``amount`` along ``estimate``; measure the outcome.

    Parameters
    ----------
    scene : Scene or str
        The scene (object in configuration A).
    estimate : JointEstimate
        The joint to follow, world frame.
    amount : float
        Requested displacement: rad (revolute) or m (prismatic), positive about/along the axis.
    candidates : list of GraspCandidate, optional
        Grasp points to choose from (e.g. a registered model's moving-link points with normals).
        Default: points on the surfaces of the collision geoms of ``joint``'s child link.
    grasp_point, grasp_normal : (3,) float, optional
        Grasp exactly here (overrides ``candidates``); the normal defaults to +z (from above).
    q_start : (7,) float, optional
        The arm's current configuration (rail, joint1..6); default the scene's home keyframe.
        Visibility of grasp points is judged from the wrist camera at this pose.
    prefer_hidden : bool
        Prefer points the camera cannot see from ``q_start`` (the default; the method's case).
    record_every : float, optional
        Keep a qpos snapshot every this many simulated seconds (for an image strip).
    seed : int
        Seed of the IK restarts.
    world : optional
        A :func:`build_world` result to reuse (saves compiling the scene again).
    joint : str, optional
        The scene joint whose child link the default candidates lie on (the joint that
        ``estimate`` estimates); default :func:`default_joint`, the first joint that moved.

    Returns
    -------
    ManipulationResult

    Raises
    ------
    ManipulationError
        No candidate can be grasped and moved (the reasons of the first candidates are given),
        or the gripper did not arrive at the grasp point.
    """
    scene = load_scene(scene) if isinstance(scene, str) else scene
    if world is None:
        world = build_world(scene)
    target = default_joint(scene) if joint is None else scene.joint(joint)
    m, kin = world.model, world.kin
    messages: list[str] = []

    def say(msg, *args):
        text = msg % args if args else msg
        log.info(text)
        messages.append(text)

    data = _fresh_data(world)
    if q_start is None:
        q_start = data.qpos[world.qidx].copy()
    q_start = kin.clip(np.asarray(q_start, dtype=float))
    data = _fresh_data(world, q_start)

    if grasp_point is not None:
        n = np.array([0.0, 0.0, 1.0]) if grasp_normal is None else np.asarray(grasp_normal, float)
        candidates = [GraspCandidate(np.asarray(grasp_point, float), n / np.linalg.norm(n))]
        ranked_from = "given grasp point"
    elif candidates is None:
        link = target.child
        candidates = scene_grasp_candidates(world, data, link)
        ranked_from = f"surfaces of link {link!r}"
    else:
        ranked_from = "given candidates"
    candidates = classify_visibility(world, data, q_start, candidates)
    n_hidden = sum(c.hidden for c in candidates)
    ranked = (_rank(_clear(world, data, candidates), estimate, prefer_hidden)
              if grasp_point is None else candidates)
    say("grasp candidates: %d from %s, %d hidden from the camera at the current pose, %d usable",
        len(candidates), ranked_from, n_hidden, len(ranked))

    plan, tried = None, []
    for k, cand in enumerate(ranked[:MAX_CANDIDATES]):
        plan, why = _plan_candidate(world, data, cand, estimate, amount, q_start, seed + k)
        if plan is not None:
            break
        tried.append(f"{np.round(cand.point, 3).tolist()}: {why}")
    if plan is None:
        raise ManipulationError(
            f"scene {scene.name!r}: no grasp candidate could be grasped and moved by {amount:g} "
            f"along the {estimate.type} axis ({len(ranked)} usable candidates, "
            f"{min(len(ranked), MAX_CANDIDATES)} tried). First reasons: " + " | ".join(tried[:4]))
    c = plan.candidate
    if c.hidden:
        say("grasp point %s is HIDDEN from the wrist camera at the current pose (%s)",
            np.round(c.point, 3).tolist(), c.visibility)
    else:
        say("grasp point %s is visible from the current pose (%s)",
            np.round(c.point, 3).tolist(),
            "no hidden point could be planned" if prefer_hidden and n_hidden else "as chosen")

    data = _fresh_data(world, q_start)
    sim = _Sim(world, data, record_every)
    obj_q0 = {j.name: float(data.qpos[j.qpos_adr]) for j in scene.joints}

    # travel and approach
    travel = max(0.5, float(np.max(np.abs(plan.q_pre - q_start))) / TRAVEL_SPEED)
    sim.follow(np.array([q_start, plan.q_pre]), travel, "travel")
    sim.settle("travel")
    sim.follow(plan.approach, APPROACH_TIME, "approach")
    sim.settle("approach")
    mujoco.mj_forward(m, data)
    q_now = data.qpos[world.qidx].copy()
    T_now = kin.frame_pose(q_now, "grasp")
    miss = float(np.linalg.norm(T_now[:3, 3] - plan.T_grasp[:3, 3]))
    if miss > GRASP_ACTIVATION_DISTANCE:
        raise ManipulationError(f"the gripper stopped {1e3 * miss:.1f} mm from the grasp pose "
                                f"(more than {1e3 * GRASP_ACTIVATION_DISTANCE:.0f} mm): no grasp")
    # what is under the fingertips?
    geomid = np.zeros(1, dtype=np.int32)
    groups = np.zeros(6, dtype=np.uint8)
    groups[3] = 1
    hit = mujoco.mj_ray(m, data, T_now[:3, 3], T_now[:3, 2], groups, 1, world.flange_body, geomid)
    if hit < 0 or hit > GRASP_STANDOFF + GRASP_REACH_MARGIN:
        raise ManipulationError(f"nothing under the fingertips at {np.round(c.point, 3).tolist()} "
                                f"(ray {'missed' if hit < 0 else f'hit at {hit:.3f} m'}); the "
                                "grasp point is not on a surface")
    body = int(m.geom_bodyid[int(geomid[0])])
    if body not in world.weld_of_body:
        raise ManipulationError(f"the fingertips touch {m.body(body).name!r}, which is not part "
                                "of the object")
    eq = world.weld_of_body[body]
    anchor_w = T_now[:3, 3] + hit * T_now[:3, 2]
    T1, T2 = _pose(m, data, world.flange_body), _pose(m, data, body)
    anchor2 = T2[:3, :3].T @ (anchor_w - T2[:3, 3])
    anchor1 = T1[:3, :3].T @ (anchor_w - T1[:3, 3])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, (T1[:3, :3].T @ T2[:3, :3]).reshape(-1))
    m.eq_data[eq, 0:3], m.eq_data[eq, 3:6], m.eq_data[eq, 6:10] = anchor2, anchor1, quat
    data.eq_active[eq] = 1
    sim.weld = eq
    say("grasp: weld switched on between the flange and %r at %s (%.1f mm from the plan)",
        m.body(body).name, np.round(anchor_w, 3).tolist(), 1e3 * miss)
    moved = next((j for j in scene.joints
                  if body in scene.link(j.child).body_ids), None)

    # motion along the estimated joint
    if estimate.type == "revolute":
        length = abs(amount) * float(np.linalg.norm(np.cross(
            estimate.axis, plan.T_grasp[:3, 3] - estimate.point)))
    else:
        length = abs(amount)
    duration = max(MIN_MOTION_TIME, length / MOTION_SPEED)
    n = len(plan.q_path) - 1
    steps = int(np.ceil(duration / sim.dt))
    errs, path_err = [], 0.0
    for i in range(1, steps + 1):
        x = _min_jerk(i / steps) * n
        k = min(int(x), n - 1)
        f = x - k
        q_cmd = plan.q_path[k] + f * (plan.q_path[k + 1] - plan.q_path[k])
        data.ctrl[world.aidx] = q_cmd
        sim.step("motion")
        errs.append(data.qpos[world.qidx] - q_cmd)
        if i % 10 == 0:
            p_plan = plan.p_path[k] + f * (plan.p_path[k + 1] - plan.p_path[k])
            p_now = kin.frame_pose(data.qpos[world.qidx], "grasp")[:3, 3]
            path_err = max(path_err, float(np.linalg.norm(p_now - p_plan)))
        if i % 25 == 0:
            sim.check_contacts()
    for _ in range(int(HOLD_TIME / sim.dt)):
        sim.step("hold")
    data.eq_active[eq] = 0
    sim.weld = None
    for _ in range(int(RELEASE_TIME / sim.dt)):
        sim.step("release")
    mujoco.mj_forward(m, data)

    errs = np.array(errs)
    forces = np.array([(f, t) for _, f, t in sim.forces]) if sim.forces else np.zeros((1, 2))
    if moved is not None:
        true = scene.joint(moved.name)
        raw = float(data.qpos[true.qpos_adr]) - obj_q0[true.name]
        sense = 1.0 if (true.type != estimate.type or np.dot(true.axis, estimate.axis) >= 0) \
            else -1.0
        achieved = sense * raw
        joint_name, joint_type = true.name, true.type
    else:
        achieved, joint_name, joint_type = 0.0, "", estimate.type
        say("the welded body %r is not on a moving link: the object cannot move",
            m.body(body).name)
    if sim.contacts:
        say("arm contacts during the run: %s", sorted(sim.contacts)[:6])
    result = ManipulationResult(
        scene=scene.name, joint=joint_name, joint_type=joint_type,
        estimate={"type": estimate.type, "axis": estimate.axis.tolist(),
                  "point": estimate.point.tolist(), "source": estimate.source},
        requested=float(amount), achieved=float(achieved),
        grasp_point=c.point.tolist(), grasp_normal=c.normal.tolist(), grasp_hidden=bool(c.hidden),
        grasp_visibility=c.visibility, grasp_body=m.body(body).name,
        grasp_roll_deg=plan.roll_deg,
        peak_force=float(forces[:, 0].max()), peak_torque=float(forces[:, 1].max()),
        mean_force=float(forces[:, 0].mean()),
        tracking_rms=float(np.sqrt(np.mean(errs ** 2))), tracking_max=float(np.abs(errs).max()),
        path_error_max=path_err, arm_contacts=sorted(sim.contacts),
        simulated_time=float(data.time),
        candidates={"total": len(candidates), "hidden": n_hidden, "usable": len(ranked),
                    "rejected_before_choice": tried[:10]},
        log=messages, frames=sim.frames)
    say("%s: requested %s, achieved %s (%.1f%%); peak weld force %.1f N, torque %.2f N m; "
        "tracking rms %.3f deg, grasp path error max %.1f mm", scene.name,
        result.to_dict()["requested_display"], result.to_dict()["achieved_display"],
        100 * result.achieved_fraction, result.peak_force, result.peak_torque,
        np.rad2deg(result.tracking_rms), 1e3 * result.path_error_max)
    result.log = messages
    return result


# --- command line -----------------------------------------------------------------------------

#: Scene camera of the image strip: looks at STRIP_TARGET from STRIP_DISTANCE, STRIP_ELEVATION up,
#: from the side (90 degrees in azimuth from the grasp point), so neither the arm nor the object
#: hides the gripper; fixed for the whole strip.
STRIP_TARGET = np.array([0.0, 0.0, 0.55])
STRIP_DISTANCE = 1.0
STRIP_ELEVATION = np.deg2rad(30.0)
STRIP_FRAMES = 6


def render_strip(world: _World, result: ManipulationResult, path: Path,
                 n: int = STRIP_FRAMES) -> Path:
    """Render ``n`` snapshots of the approach and motion side by side into one PNG."""
    from PIL import Image

    from sim import render

    frames = [f for f in result.frames if f[1] != "travel"] or result.frames
    if not frames:
        raise ValueError("no frames recorded: run manipulate with record_every")
    g = np.asarray(result.grasp_point)
    az = np.arctan2(g[1], g[0]) + np.pi / 2
    eye = STRIP_TARGET + STRIP_DISTANCE * np.array([
        np.cos(STRIP_ELEVATION) * np.cos(az), np.cos(STRIP_ELEVATION) * np.sin(az),
        np.sin(STRIP_ELEVATION)])
    K = np.array([[554.26, 0, 319.5], [0, 554.26, 239.5], [0, 0, 1]])
    T = robot.look_at_pose(eye, STRIP_TARGET)
    r = render.MjRenderer(world.model)
    data = mujoco.MjData(world.model)
    picks = np.linspace(0, len(frames) - 1, n).round().astype(int)
    tiles = []
    for i in picks:
        data.qpos[:] = frames[i][2]
        mujoco.mj_forward(world.model, data)
        tiles.append(r.render(data, K, T, 640, 480).color)
    Image.fromarray(np.concatenate(tiles, axis=1)).save(path)
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim.manipulate", description=__doc__.split("\n")[0])
    p.add_argument("scene", help="bundled scene name or MJCF path")
    p.add_argument("--model", type=Path, help="registered ArticulatedModel JSON (robot frame, m); "
                   "default: the scene's ground-truth joint")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--angle", type=float, help="requested rotation (deg) for a revolute joint "
                   "(default: the scene's own motion A -> B of its first moving joint)")
    g.add_argument("--distance", type=float, help="requested translation (m), prismatic joint "
                   "(default: the scene's own motion A -> B)")
    p.add_argument("--visible", action="store_true", help="prefer a grasp point the camera sees")
    p.add_argument("--tilt", type=float, default=0.0,
                   help="tilt the followed axis by this many degrees (a deliberately wrong axis)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        scene = load_scene(args.scene)
        candidates = None
        if args.model is not None:
            from artrecon.model import ArticulatedModel

            est, pts, normals = joint_estimate_from_model(ArticulatedModel.load(args.model))
            if normals is None:
                normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
            candidates = [GraspCandidate(a, b) for a, b in zip(pts, normals, strict=True)]
        else:
            est = joint_estimate_from_scene(scene)
            log.warning("no --model: following the GROUND-TRUTH axis of joint %r", est.name)
        if args.tilt:
            est = est.tilted(args.tilt)
        # default: the scene's own A -> B motion (of the joint of that type moved first)
        own = default_joint(scene)
        own_motion = own.motion if own.type == est.type else None
        if est.type == "revolute":
            if args.distance is not None:
                p.error("the joint is revolute: give --angle")
            amount = (np.deg2rad(args.angle) if args.angle is not None else
                      own_motion if own_motion is not None else np.deg2rad(30.0))
        else:
            if args.angle is not None:
                p.error("the joint is prismatic: give --distance")
            amount = (args.distance if args.distance is not None else
                      own_motion if own_motion is not None else 0.10)
        world = build_world(scene)
        res = manipulate(scene, est, amount, candidates=candidates,
                         prefer_hidden=not args.visible, record_every=0.05, seed=args.seed,
                         world=world)
    except (ManipulationError, ValueError, OSError) as err:
        log.error("%s", err)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    out = res.to_dict()
    out["axis_source_note"] = ("ground-truth axis from the scene file" if args.model is None
                               else f"estimated axis from {args.model}")
    out["created"] = time.strftime("%Y-%m-%dT%H:%M:%S")
    (args.out / "manipulation.json").write_text(json.dumps(out, indent=2) + "\n")
    strip = render_strip(world, res, args.out / "strip.png")
    summary = {k: out[k] for k in ("scene", "joint", "requested_display", "achieved_display",
                                   "peak_force", "grasp_hidden", "grasp_visibility")}
    sys.stdout.write(json.dumps(summary, indent=2) + "\n")
    sys.stdout.write(f"wrote {args.out / 'manipulation.json'} and {strip}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
