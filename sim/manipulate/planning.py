"""The robot's plan, made from what the robot knows: its own arm, the stage it works on, and the
registered model of the object.

:class:`PlanningWorld` is the scene's stage and arm with the object replaced by the registered
model: one small sphere per voxel of the model's points (every link, configuration A), which
MuJoCo's collision detection and ray casting then treat like any other geom. Every decision of
the plan is taken there:

- grasp candidates: points of the model's child link with their normals
  (:func:`model_grasp_candidates`);
- whether a candidate is hidden from the wrist camera at the arm's current pose: a ray from the
  camera centre meets the model (or the stage) before the point, or the point is outside the
  image (:meth:`PlanningWorld.classify_visibility`);
- free space in front of a candidate (:meth:`PlanningWorld.clear`), contacts of the arm at the
  pre-grasp and grasp poses and along the travel line (:meth:`PlanningWorld.arm_contacts`);
- the ranking (leverage about the estimated axis, hidden first) and the IK of the approach and
  of the motion along the estimated joint (:func:`plan_candidate`).

``PlanningWorld.from_scene`` keeps the true object instead (demonstrations that follow the
ground-truth joint, and the tests that compare the two); the harness never uses it.
"""

from __future__ import annotations

import dataclasses
import logging
from contextlib import contextmanager
from dataclasses import dataclass, field

import mujoco
import numpy as np

from artrecon.geometry import rotation_about
from sim import robot, views
from sim.camera import mujoco_camera_intrinsics
from sim.manipulate.estimate import JointEstimate
from sim.manipulate.world import World

log = logging.getLogger(__name__)

#: Geom group of collision geoms (stage, arm, and in a PlanningWorld the model's spheres): the
#: rays of the plan see these and nothing else.
COLLISION_GROUP = 3
#: Group the true object's geoms are moved to in a model-based PlanningWorld (no ray sees them,
#: nothing collides with them).
HIDDEN_GROUP = 5


@dataclass(frozen=True)
class PlanningConfig:
    """Settings of the plan."""

    voxel: float = 0.006
    """model points are merged per voxel of this size (m) into one sphere"""
    sphere_radius: float = 0.004
    """radius of a model sphere (m): with 6 mm voxels neighbouring spheres overlap, so rays do
    not slip through a surface"""
    candidate_voxel: float = 0.006
    """grasp candidates: one per voxel of this size (m) of the child link's points (1 cm voxels
    on scissors' 3 mm blades mixed top and side normals: 20 candidates, 3 usable, none
    graspable; 6 mm: 103, 20 usable)"""
    min_normal_agreement: float = 0.8
    """a voxel's mean normal shorter than this (its normals disagree: an edge or noise) and the
    voxel is no candidate"""
    normal_radius: float = 0.01
    """a candidate's normal is the normal of the plane fitted to the link's points within this
    distance (m) that face like the voxel's mean normal: the mean of a few noisy point normals
    tilted the approach (scissors' rings, flat on the table, had voxel normals up to 14 deg off
    the vertical, and one fingertip dipped into the ring beside: no grasp among 39 candidates;
    with the fitted plane, the blade grasped at its tip)"""
    support_radius: float = 0.015
    """a candidate must lie on a surface of the model: at least ``min_support`` of the link's
    points within this distance (m) of it (a few stray points of a reconstruction -- points off
    the object -- are no place to grasp) ..."""
    min_support: int = 20
    """... (about a 1.5 cm disc of a surface sampled every 2-3 mm holds 60-100)"""
    edge_margin: float = 0.004
    """a candidate's own face must reach this far (m) beyond it in four directions of its
    tangent plane: a point on the rim of a face is not grasped (cabinet's drawer handle, 16 mm
    high, grasped at its lower rim: the fingertips' ray passed under the true handle)"""
    min_sphere_points: int = 2
    """a model sphere stands for a voxel with at least this many points (a single stray point
    blocks no approach)"""
    grasp_standoff: float = 0.018
    """the grasp frame (15 mm behind the fingertips) sits this far off the surface along the
    normal: the fingertips stop 3 mm short of it"""
    pregrasp_distance: float = 0.07
    """pre-grasp pose: this much further out along the normal"""
    occlusion_margin: float = 0.003
    """a point is hidden when the camera ray meets a surface this much (m) before the point's
    own sphere"""
    hidden_margin: float = 0.006
    """a point counts as hidden only when the camera rays to it and to four points this far (m)
    around it, lifted this far off the surface, are all blocked: a point at the edge of what
    the camera sees (a back face seen over a panel's rim) is hidden from the model's spheres
    and visible on the true object by a hair, and is called visible"""
    gripper_contact_radius: float = 0.03
    """at the grasp pose the gripper may touch the model within this distance (m) of the grasp
    point (it is meant to) ..."""
    face_contact_radius: float = 0.05
    """... and on the grasped face (spheres of the grasped link within this distance (m) of the
    grasp point ...)"""
    face_contact_depth: float = 0.002
    """... and met no deeper than this (m): the fingertips graze the spheres, 4 mm high, of
    the face they stop 3 mm short of): the finger pads reach 4 cm from the grasp point, and on
    a flat face every grasp met the face's own spheres beyond 3 cm (the truck's bed side
    planned on its true surfaces: 40 candidates refused for it); any other contact of the arm
    is a collision (a finger against the side of a handle goes deeper)"""
    approach_radius: float = 0.025
    """free space in front of a candidate: rays along the normal from the point and from four
    points this far (m) around it (the fingertips sit 3 cm off the approach axis) ..."""
    approach_free_length: float = 0.3
    """... must meet nothing for this long (m): gripper and wrist"""
    min_lever: float = 0.06
    """revolute joints: candidates nearer the estimated axis than this (m) are not used (a
    short lever turns the gripper a lot for little motion and needs large forces) ..."""
    min_lever_fraction: float = 0.6
    """... unless the link reaches no farther than ``min_lever`` from its axis (a Barrett
    finger turning about its spread axis reaches 4.7 cm): then points beyond this fraction of
    its reach"""
    min_normal_z: float = -0.3
    """candidates whose normal points down more steeply than this are not approached (from
    below, through the table)"""
    rolls_deg: tuple[float, ...] = (0, 45, 90, 135, 180, 225, 270, 315)
    """rolls of the gripper about the approach axis tried per candidate (deg)"""
    max_candidates: int = 40
    """candidates planned, in order of preference, before giving up"""
    retry_spacing: float = 0.015
    """after a candidate failed, the next one tried lies at least this far (m) from every one
    tried (the nearer ones come after the others): what stops one candidate (out of reach,
    the table, a fixed part in the fingers' way) stops its neighbours too, and the 40 tries
    had gone to the voxels along one edge of chest's lid"""
    clear_of_fixed: float = 0.035
    """candidates at least this far (m) from every model surface that does not move with the
    grasped link come first (the fingertips sit 3 cm either side of the grasp point: a grasp
    this far from the fixed parts neither touches them nor passes them by a hair as it moves;
    cabinet_door_only's door grasped at its edge met the carcass's side early in the turn) ..."""
    min_clear_of_fixed: float = 0.008
    """... then those at least this far; nearer ones last (the model's surfaces lie a few mm
    from the true ones: a finger planned to pass a fixed part this close may touch it)"""
    waypoint_angle: float = np.deg2rad(1.0)
    """motion waypoints: one per this much rotation (rad) ..."""
    waypoint_distance: float = 0.002
    """... or translation (m) ..."""
    min_waypoints: int = 20
    """... and at least this many"""
    max_waypoint_joint_step: float = 0.15
    """largest joint change between waypoints (rad): larger means the IK jumped branches"""
    travel_checks: int = 12
    """configurations checked for contacts along the travel line to the pre-grasp pose"""
    max_path_kink: float = 0.3
    """the motion's joint path may change its step between waypoints by at most this share of
    its largest step: a joint that meets its limit mid-motion stops dead while the others take
    over in one step, and the arm's inertia turns that corner into a jolt of the grasp's force
    (cabinet's drawer planned on the true surfaces: the wrist's joint5 met its limit at 70% of
    the pull, 9.7 N for a joint that needs 0.7 N, the grasp lost in another plan; its door
    planned on the model: joint5 stopped within two waypoints, 21.9 N)"""
    joint_limit_margin: float = np.deg2rad(2.0)
    """the grasp, approach and motion keep every arm joint this far (rad) inside its limits:
    the IK puts a joint exactly on its limit when the target asks for more, and the servo, a
    hair behind or ahead of its command, would meet the limit's hard stop through the stiff
    grasp"""


@dataclass(frozen=True)
class GraspCandidate:
    """A point on the link to move, with its outward surface normal (world frame)."""

    point: np.ndarray
    normal: np.ndarray
    hidden: bool = False
    visibility: str = ""
    """``"visible"``, ``"occluded by <geom>"`` or ``"outside the image"``"""
    clearance: float = float("inf")
    """distance (m) to the nearest surface of the model that does not move with the grasped
    link (:meth:`PlanningWorld.fixed_clearance`; inf: not measured)"""


@dataclass
class Plan:
    """The grasp and motion the arm will execute."""

    candidate: GraspCandidate
    roll_deg: float
    T_grasp: np.ndarray
    q_pre: np.ndarray
    q_grasp: np.ndarray
    approach: np.ndarray
    """(k, n) joint waypoints pre-grasp -> grasp"""
    s: np.ndarray
    """(N+1,) path parameter of the motion waypoints"""
    q_path: np.ndarray
    """(N+1, n) joint waypoints of the motion"""
    p_path: np.ndarray
    """(N+1, 3) planned grasp-frame positions"""
    tried: list = field(default_factory=list)
    """why the candidates ranked before this one were passed over"""
    gripper_contacts: int = 0
    """contacts of the gripper with the model at the grasp pose (:meth:`PlanningWorld.
    gripper_contacts`): the fingers resting on the object, not straddling it"""


def grasp_frame(point, normal, roll_deg: float, standoff: float) -> np.ndarray:
    """``T_world_grasp``: approach along ``-normal``, ``standoff`` off the surface, rolled."""
    z = -np.asarray(normal, float)
    z /= np.linalg.norm(z)
    ref = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    x = rotation_about(z, np.deg2rad(roll_deg)) @ x
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, np.cross(z, x), z
    T[:3, 3] = np.asarray(point, float) + standoff * np.asarray(normal, float)
    return T


def _voxel_groups(points: np.ndarray, size: float) -> list[np.ndarray]:
    """Indices of ``points`` per occupied voxel of ``size``."""
    keys = np.floor(points / size).astype(np.int64)
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    order = np.argsort(inv.reshape(-1), kind="stable")
    bounds = np.flatnonzero(np.diff(inv.reshape(-1)[order])) + 1
    return np.split(order, bounds)


def voxel_centres(points: np.ndarray, size: float, min_points: int = 1) -> np.ndarray:
    """The mean point of every voxel of ``size`` holding at least ``min_points`` (m, 3)."""
    points = np.asarray(points, float)
    if len(points) == 0:
        return np.zeros((0, 3))
    return np.array([points[g].mean(axis=0) for g in _voxel_groups(points, size)
                     if len(g) >= min_points]).reshape(-1, 3)


def model_grasp_candidates(model, joint: int, config: PlanningConfig = PlanningConfig()
                           ) -> list[GraspCandidate]:
    """Grasp candidates on the child link of the registered model's joint ``joint``: one per
    voxel of its points (the point nearest the voxel's mean), with the normal of the surface
    around it (:func:`_plane_normal`); voxels whose normals disagree (edges, noise) are left
    out.

    The link's points cover its hidden sides too (points seen only in configuration B are
    brought to A by the link's motion): a candidate may lie where no camera sees it now.
    """
    link = model.links[model.joints[joint].child]
    pts = np.asarray(link.points, float)
    if link.normals is None or len(pts) == 0:
        raise ValueError(f"link {link.name!r} of the model has no points with normals: no grasp "
                         "candidates")
    nrm = np.asarray(link.normals, float)
    from scipy.spatial import cKDTree

    tree = cKDTree(pts)
    out = []
    for g in _voxel_groups(pts, config.candidate_voxel):
        n = nrm[g].mean(axis=0)
        length = float(np.linalg.norm(n))
        if length < config.min_normal_agreement:
            continue
        c = pts[g].mean(axis=0)
        p = pts[g][np.argmin(np.linalg.norm(pts[g] - c, axis=1))]
        if len(tree.query_ball_point(p, config.support_radius)) < config.min_support:
            continue
        n = _plane_normal(p, n / length, pts, nrm, tree, config)
        if not _surrounded(p, n, pts, nrm, tree, config):
            continue
        out.append(GraspCandidate(p, n))
    return out


def _plane_normal(p, n, pts, nrm, tree, config: PlanningConfig) -> np.ndarray:
    """The normal at ``p`` of the plane fitted (least squares) to the link's points within
    :attr:`PlanningConfig.normal_radius` whose normals face like ``n``, turned to ``n``'s side;
    ``n`` itself when fewer than three such points span a plane."""
    near = np.asarray(tree.query_ball_point(p, config.normal_radius), dtype=int)
    near = near[nrm[near] @ n > config.min_normal_agreement]
    if len(near) < 3:
        return n
    q = pts[near] - pts[near].mean(axis=0)
    w, v = np.linalg.eigh(q.T @ q)
    if w[1] <= 0:
        return n
    fitted = v[:, 0]
    return fitted if float(fitted @ n) >= 0 else -fitted


def _surrounded(p, n, pts, nrm, tree, config: PlanningConfig) -> bool:
    """``p`` lies inside its face, not at its rim: the link's points around it that face the
    same way (normals within ~37 deg) and lie in its tangent plane reach at least
    :attr:`PlanningConfig.edge_margin` beyond it in each of four directions of that plane."""
    near = np.asarray(tree.query_ball_point(p, 2.5 * config.edge_margin), dtype=int)
    if len(near) == 0:
        return False
    d = pts[near] - p
    on_face = (nrm[near] @ n > config.min_normal_agreement) & (np.abs(d @ n) < 0.5 *
                                                                config.edge_margin)
    d = d[on_face]
    u, v = _tangents(n)
    reach = config.edge_margin
    return bool(len(d) and (d @ u).max() >= reach and (d @ u).min() <= -reach
                and (d @ v).max() >= reach and (d @ v).min() <= -reach)


def scene_grasp_candidates(world: World, data, body_ids, grid: int = 3,
                           inset: float = 0.6) -> list[GraspCandidate]:
    """Points on the faces of the collision boxes and cylinder caps of the true bodies
    ``body_ids``, with outward normals (demonstrations along the true joint only: this reads the
    true geometry); points buried in another collision geom are dropped."""
    m = world.model
    bodies = set(body_ids)
    collision = [g for g in range(m.ngeom) if int(m.geom_contype[g]) or int(m.geom_conaffinity[g])]
    out = []
    ticks = np.linspace(-inset, inset, grid)
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
                    for a in ticks:
                        for b in ticks:
                            p = n * s[ax]
                            p[u], p[v] = a * s[u], b * s[v]
                            local.append((p, n))
        elif m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CYLINDER:
            for sign in (-1.0, 1.0):
                n = np.array([0.0, 0.0, sign])
                for a in ticks:
                    local.append((np.array([a * s[0], 0.0, sign * s[1]]), n))
        for p, n in local:
            pw, nw = c + R @ p, R @ n
            if any(_inside_geom(m, data, h, pw) for h in collision if h != g):
                continue
            out.append(GraspCandidate(pw, nw))
    return out


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


def _tangents(normal) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to ``normal`` and to each other. : (3,), (3,)"""
    ref = np.array([0.0, 0.0, 1.0]) if abs(normal[2]) < 0.9 else np.array([1.0, 0, 0])
    u = np.cross(normal, ref)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


class PlanningWorld:
    """The stage and the arm, with the object as the robot knows it (see the module docstring).

    Build with :meth:`from_model` (the registered model: what the harness uses) or
    :meth:`from_scene` (the true object: demonstrations only).
    """

    def __init__(self, world: World, model: mujoco.MjModel, source: str, config: PlanningConfig,
                 model_geoms: dict, occlusion_tolerance: float):
        self.world = world
        self.model = model
        self.data = mujoco.MjData(model)
        self.data.qpos[:] = world.qpos_start
        mujoco.mj_forward(model, self.data)
        self.kin = robot.load_arm_kinematics(model)
        self.qidx = robot.qpos_indices(model, self.kin)
        self.arm_links = views.arm_link_bodies(model, self.kin)
        arm = robot.arm_spec(model)
        self.flange_body = model.body(arm.prefix + arm.flange_body).id
        self.gripper_bodies = {b for b in range(model.nbody) if self._below(b, self.flange_body)}
        self.source = source
        self.config = config
        self.model_geoms = model_geoms
        """model sphere geom id -> the model link it stands for"""
        self.occlusion_tolerance = occlusion_tolerance
        self._groups = np.zeros(6, dtype=np.uint8)
        self._groups[COLLISION_GROUP] = 1

    def _below(self, b: int, root: int) -> bool:
        while b > 0 and b != root:
            b = int(self.model.body_parentid[b])
        return b == root

    @classmethod
    def from_model(cls, world: World, registered,
                   config: PlanningConfig = PlanningConfig()) -> PlanningWorld:
        """The stage and arm of the scene file, the object replaced by ``registered`` (an
        ArticulatedModel in the robot frame, metres): spheres at its points' voxels."""
        if not registered.scale_known:
            raise ValueError("plan from a registered model (robot frame, metres)")
        spec = mujoco.MjSpec.from_file(str(world.path))
        body = spec.worldbody.add_body(name="registered_model")
        n_points = 0
        for li, lk in enumerate(registered.links):
            pts = np.asarray(lk.points, float)
            n_points += len(pts)
            for k, c in enumerate(voxel_centres(pts, config.voxel, config.min_sphere_points)):
                body.add_geom(name=f"model_link{li}_{k}", type=mujoco.mjtGeom.mjGEOM_SPHERE,
                              size=[config.sphere_radius, 0, 0], pos=c, contype=1,
                              conaffinity=1, group=COLLISION_GROUP, rgba=[0.9, 0.6, 0.1, 1.0])
        model = spec.compile()
        # the true object is no part of the robot's knowledge: nothing collides with it and no
        # ray of the plan sees it
        obj = world.object_bodies
        for g in range(model.ngeom):
            if int(model.geom_bodyid[g]) in obj:
                model.geom_contype[g] = 0
                model.geom_conaffinity[g] = 0
                model.geom_group[g] = HIDDEN_GROUP
        bid = model.body("registered_model").id
        geoms = {g: int(model.geom(g).name.split("_")[1][4:]) for g in range(model.ngeom)
                 if int(model.geom_bodyid[g]) == bid}
        log.info("planning world: %d model spheres (%.0f mm voxels) for %d model points",
                 len(geoms), 1e3 * config.voxel, n_points)
        return cls(world, model, "registered model", config, geoms,
                   config.sphere_radius + config.occlusion_margin)

    @classmethod
    def from_scene(cls, world: World, config: PlanningConfig = PlanningConfig()
                   ) -> PlanningWorld:
        """The true world (demonstrations along the true joint and scoring's force reference;
        never the harness's plan). The object's geoms stand in for the model's spheres, each
        under its body's id (``moving_links`` are then body ids)."""
        m = world.model
        geoms = {g: int(m.geom_bodyid[g]) for g in range(m.ngeom)
                 if int(m.geom_bodyid[g]) in world.object_bodies}
        return cls(world, m, "true object (demonstration)", config, geoms,
                   config.occlusion_margin)

    # ------------------------------------------------------------------ questions to the world
    def classify_visibility(self, q, candidates) -> list[GraspCandidate]:
        """Each candidate hidden or visible from the wrist camera at arm configuration ``q``:
        hidden when outside the image, or when the ray from the camera centre meets a surface
        of the plan (the model, the stage, the arm) before the point and before the points
        around it (:attr:`PlanningConfig.hidden_margin`; the first ray's occluder is named)."""
        m, d = self.model, self.data
        cam = self.kin.spec.prefix + self.kin.spec.camera
        K, (w, h) = mujoco_camera_intrinsics(m, cam)
        T = self.kin.camera_pose(q)
        d.qpos[self.qidx] = q
        mujoco.mj_forward(m, d)
        out = []
        geomid = np.zeros(1, dtype=np.int32)
        margin = self.config.hidden_margin

        def blocked(p) -> bool:
            ray = p - T[:3, 3]
            dist = float(np.linalg.norm(ray))
            hit = mujoco.mj_ray(m, d, T[:3, 3], ray / dist, self._groups, 1, self.flange_body,
                                geomid)
            return 0 <= hit < dist - self.occlusion_tolerance

        for c in candidates:
            pc = T[:3, :3].T @ (c.point - T[:3, 3])
            uv = K @ pc
            if pc[2] <= 0 or not (0 <= uv[0] / uv[2] < w and 0 <= uv[1] / uv[2] < h):
                out.append(GraspCandidate(c.point, c.normal, True, "outside the image"))
                continue
            if not blocked(c.point):
                out.append(GraspCandidate(c.point, c.normal, False, "visible"))
                continue
            g = int(geomid[0])
            what = ("the model" if g in self.model_geoms else
                    mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom {g}")
            if margin > 0:
                u, v = _tangents(c.normal)
                lifted = c.point + margin * c.normal
                around = [lifted] + [lifted + margin * t for t in (u, -u, v, -v)]
                if not all(blocked(p) for p in around):
                    out.append(GraspCandidate(c.point, c.normal, False,
                                              f"visible at the edge of {what}"))
                    continue
            out.append(GraspCandidate(c.point, c.normal, True, f"occluded by {what}"))
        return out

    def clear(self, candidates) -> list[GraspCandidate]:
        """Candidates with free space in front of them: a bundle of rays along the normal (the
        centre and four around it) meets nothing for ``approach_free_length``."""
        cfg = self.config
        geomid = np.zeros(1, dtype=np.int32)
        start = max(1e-3, 1.5 * (self.occlusion_tolerance - cfg.occlusion_margin))
        out = []
        for c in candidates:
            u, v = _tangents(c.normal)
            starts = [c.point + start * c.normal]
            starts += [c.point + (cfg.grasp_standoff + 1e-3) * c.normal + cfg.approach_radius * w
                       for w in (u, -u, v, -v)]
            if all(not 0 <= mujoco.mj_ray(self.model, self.data, p0, c.normal, self._groups, 1,
                                          -1, geomid) < cfg.approach_free_length
                   for p0 in starts):
                out.append(c)
        return out

    def fixed_clearance(self, candidates, moving_links=()) -> list[GraspCandidate]:
        """Each candidate with its :attr:`GraspCandidate.clearance`: the distance to the nearest
        model sphere of a link not in ``moving_links`` (in a world planned on the true object:
        not measured)."""
        moving = set(moving_links)
        fixed = [g for g, link in self.model_geoms.items() if link not in moving]
        if self.source != "registered model" or not fixed or not candidates:
            return list(candidates)
        from scipy.spatial import cKDTree

        dist, _ = cKDTree(self.data.geom_xpos[fixed]).query(
            np.array([c.point for c in candidates]))
        return [dataclasses.replace(c, clearance=float(d))
                for c, d in zip(candidates, dist, strict=True)]

    def _on_grasped_face(self, p, depth, grasp_point, grasp_normal) -> bool:
        """A model sphere at ``p``, met ``depth`` deep (m, MuJoCo's contact distance), that the
        gripper at the grasp pose may touch: within ``gripper_contact_radius`` of the grasp
        point, or (``grasp_normal`` given) grazed by the fingertips on the grasped face
        (:attr:`PlanningConfig.face_contact_radius`, ``face_contact_depth``): the fingertips
        stop 3 mm short of the surface and the spheres stand 4 mm out of it."""
        cfg = self.config
        dist = float(np.linalg.norm(np.asarray(p, float) - grasp_point))
        if dist < cfg.gripper_contact_radius:
            return True
        return bool(grasp_normal is not None and dist < cfg.face_contact_radius
                    and depth > -cfg.face_contact_depth)

    def gripper_contacts(self, q) -> int:
        """How many contacts the gripper (the bodies below the flange) has with the model (every
        link; in a world planned on the true object, the object's geoms) at configuration
        ``q``, the allowed ones included (:meth:`arm_contacts`)."""
        m, d = self.model, self.data
        d.qpos[self.qidx] = q
        mujoco.mj_forward(m, d)
        return sum(1 for c in d.contact[: d.ncon]
                   if {int(m.geom_bodyid[c.geom[0]]), int(m.geom_bodyid[c.geom[1]])}
                   & self.gripper_bodies
                   and (int(c.geom[0]) in self.model_geoms or int(c.geom[1]) in self.model_geoms))

    def arm_contacts(self, q, grasp_point=None, grasp_links=(), moving_links=(),
                     grasp_normal=None) -> list[str]:
        """Contacts of the arm at configuration ``q`` in the plan's world. With ``grasp_point``,
        the gripper touching the grasped link (a model link of ``grasp_links``) within
        ``gripper_contact_radius`` of it is allowed -- never another link, nor the stage; the
        model links in ``moving_links`` (the grasped link and those it carries, during the
        motion: they move with the gripper) are not obstacles. With ``grasp_normal`` too, the
        gripper may also touch the grasped face under its fingers (:meth:`_on_grasped_face`)."""
        m, d = self.model, self.data
        d.qpos[self.qidx] = q
        mujoco.mj_forward(m, d)
        moving = set(moving_links)
        out = []
        for c in d.contact[: d.ncon]:
            g1, g2 = int(c.geom[0]), int(c.geom[1])
            b1, b2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
            if b1 not in self.arm_links and b2 not in self.arm_links:
                continue
            arm_b, other = (b1, g2) if b1 in self.arm_links else (b2, g1)
            if other in self.model_geoms and self.model_geoms[other] in moving:
                continue
            if (grasp_point is not None and arm_b in self.gripper_bodies
                    and self.model_geoms.get(other) in set(grasp_links)
                    and self._on_grasped_face(d.geom_xpos[other], float(c.dist), grasp_point,
                                              grasp_normal)):
                continue
            name = [(f"model link {self.model_geoms[g]}" if g in self.model_geoms else
                     mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}")
                    for g in (g1, g2)]
            out.append("/".join(name))
        return sorted(set(out))


def rank(candidates: list[GraspCandidate], est: JointEstimate, prefer_hidden: bool,
         config: PlanningConfig = PlanningConfig()) -> list[GraspCandidate]:
    """Usable candidates, best first: hidden ones first when ``prefer_hidden`` (the method's
    case: a point the camera cannot see now), then by their clearance from the fixed parts
    (:attr:`PlanningConfig.clear_of_fixed`, ``min_clear_of_fixed``), then the longest lever
    about the estimated axis (revolute) or the highest point (prismatic). Candidates facing the
    table and, for a revolute joint, too near its axis are left out."""
    def lever(c):
        v = c.point - est.point
        return float(np.linalg.norm(v - np.dot(v, est.axis) * est.axis))

    reach = max((lever(c) for c in candidates), default=0.0)
    min_lever = min(config.min_lever, config.min_lever_fraction * reach)
    usable = [c for c in candidates if c.normal[2] >= config.min_normal_z
              and (est.type != "revolute" or lever(c) >= min_lever)]

    def key(c):
        hidden_rank = 0 if (c.hidden == prefer_hidden) else 1
        tier = (0 if c.clearance >= config.clear_of_fixed else
                1 if c.clearance >= config.min_clear_of_fixed else 2)
        return (hidden_rank, tier, -lever(c) if est.type == "revolute" else -c.point[2])

    return sorted(usable, key=key)


def plan_candidate(pw: PlanningWorld, cand: GraspCandidate, est: JointEstimate, amount: float,
                   q_start: np.ndarray, seed: int, moving_links=(), rolls_deg=None
                   ) -> tuple[Plan | None, str]:
    """IK of the grasp, pre-grasp and approach, and of every waypoint of the motion by
    ``amount`` along ``est``, for each roll (``rolls_deg``, default
    :attr:`PlanningConfig.rolls_deg`); contacts checked in the plan's world (along the motion,
    the model links ``moving_links`` move with the gripper and are no obstacle); every arm joint
    kept :attr:`PlanningConfig.joint_limit_margin` inside its limits. Of the rolls that pass, those
    whose gripper touches nothing of the model at the grasp pose come first (the part under the
    grasp point between the fingers, not under them: a finger resting on the object 3 mm above
    the model's surface presses into it where the true surface lies further out -- the model
    rounds a sharp edge, and cabinet_door_only's door handle grasped at its corner with the
    fingers along it, 5 mm out of the model there, lost the grasp at 1% of the turn, 8.4 N and
    3.0 N m, where a roll with the fingers either side of the handle turned it at 3 N); then the
    shortest travel. The plan, or None and why."""
    rolls = pw.config.rolls_deg if rolls_deg is None else tuple(rolls_deg)
    with _limits_narrowed(pw.kin, pw.config.joint_limit_margin):
        return _plan_candidate(pw, cand, est, amount, q_start, seed, moving_links, rolls)


def _kink(q_path: np.ndarray, window: int = 3) -> tuple[float, int] | None:
    """The largest change of the joint steps between motion waypoints ``window`` apart, as a
    share of the largest step, and the waypoint where it happens (None: too few waypoints).
    Waypoints uniform along a smooth motion give a smooth joint path (shares of a few
    hundredths); a joint that runs into its limit stops within a waypoint or two while the
    others take over its part of the motion."""
    steps = np.diff(q_path, axis=0)
    w = min(window, len(steps) - 1)
    if w < 1:
        return None
    scale = float(np.abs(steps).max())
    if scale <= 0:
        return None
    change = np.abs(steps[w:] - steps[:-w]).max(axis=1)
    k = int(np.argmax(change))
    return float(change[k]) / scale, k + (w + 1) // 2


@contextmanager
def _limits_narrowed(kin, margin: float):
    """The IK of ``kin`` (the planning world's own) kept ``margin`` inside every joint limit
    (joints whose range is not at least four margins wide keep theirs)."""
    lower, upper = kin.lower, kin.upper
    span = upper - lower
    m = np.where(np.isfinite(span) & (span > 4 * margin), margin, 0.0)
    kin.lower, kin.upper = lower + m, upper - m
    try:
        yield
    finally:
        kin.lower, kin.upper = lower, upper


def _plan_candidate(pw: PlanningWorld, cand: GraspCandidate, est: JointEstimate, amount: float,
                    q_start: np.ndarray, seed: int, moving_links, rolls
                    ) -> tuple[Plan | None, str]:
    kin, cfg = pw.kin, pw.config
    n_way = max(cfg.min_waypoints, int(np.ceil(abs(amount) / (
        cfg.waypoint_angle if est.type == "revolute" else cfg.waypoint_distance))))
    s = np.linspace(0.0, 1.0, n_way + 1)
    reasons = []
    best = None
    # cheap first test: can the grasp frame's origin get there at all (any orientation)?
    reach = kin.solve_ik(grasp_frame(cand.point, cand.normal, 0.0, cfg.grasp_standoff), "grasp",
                         q_start, position_only=True, restarts=2, seed=seed)
    if not reach.success:
        return None, (f"out of reach: the grasp frame gets no closer than "
                      f"{1e3 * reach.position_error:.0f} mm")
    for roll in rolls:
        T_g = grasp_frame(cand.point, cand.normal, roll, cfg.grasp_standoff)
        ik = kin.solve_ik(T_g, "grasp", reach.q, restarts=2, seed=seed)
        if not ik.success:
            reasons.append(f"roll {roll}: grasp pose unreachable")
            continue
        T_pre = T_g.copy()
        T_pre[:3, 3] += cfg.pregrasp_distance * cand.normal
        pre = kin.solve_ik(T_pre, "grasp", ik.q, restarts=0)
        if not pre.success:
            reasons.append(f"roll {roll}: pre-grasp unreachable")
            continue
        hits = (pw.arm_contacts(ik.q, grasp_point=cand.point, grasp_links=moving_links,
                                grasp_normal=cand.normal)
                or pw.arm_contacts(pre.q))
        if hits:
            reasons.append(f"roll {roll}: arm touches {hits[0]}")
            continue
        approach, q, ok = [pre.q], pre.q, True
        for f in np.linspace(0, 1, 9)[1:]:
            T = T_g.copy()
            T[:3, 3] += (1 - f) * cfg.pregrasp_distance * cand.normal
            r = kin.solve_ik(T, "grasp", q, restarts=0)
            if not r.success or np.max(np.abs(r.q - q)) > cfg.max_waypoint_joint_step:
                ok = False
                break
            approach.append(r.q)
            q = r.q
        if not ok:
            reasons.append(f"roll {roll}: approach line not followable")
            continue
        q_path, p_path = [q], [T_g[:3, 3].copy()]
        for sk in s[1:]:
            T = est.motion(sk * amount) @ T_g
            r = kin.solve_ik(T, "grasp", q, restarts=0)
            if not r.success or np.max(np.abs(r.q - q)) > cfg.max_waypoint_joint_step:
                ok = False
                break
            q_path.append(r.q)
            p_path.append(T[:3, 3].copy())
            q = r.q
        if not ok:
            reasons.append(f"roll {roll}: motion leaves the workspace or joint limits at "
                           f"{sk * 100:.0f}% of the path")
            continue
        kink = _kink(np.array(q_path))
        if kink is not None and kink[0] > cfg.max_path_kink:
            reasons.append(f"roll {roll}: the motion's joint path kinks at "
                           f"{100 * s[kink[1]]:.0f}% of the path (a joint held at its limit)")
            continue
        step = max(1, len(q_path) // cfg.travel_checks)
        hits = next((h for h in (pw.arm_contacts(qk, moving_links=moving_links)
                                 for qk in q_path[step::step]) if h), [])
        if hits:
            reasons.append(f"roll {roll}: the arm touches {hits[0]} during the motion")
            continue
        clear = True
        for f in np.linspace(0, 1, cfg.travel_checks + 2)[1:-1]:
            hits = pw.arm_contacts(q_start + f * (pre.q - q_start))
            if hits:
                reasons.append(f"roll {roll}: travel to pre-grasp touches {hits[0]}")
                clear = False
                break
        if not clear:
            continue
        touch = pw.gripper_contacts(ik.q)
        cost = (touch > 0, float(np.sum(np.abs(pre.q - q_start))))
        plan = Plan(cand, float(roll), T_g, pre.q, ik.q, np.array(approach), s,
                    np.array(q_path), np.array(p_path), gripper_contacts=touch)
        if best is None or cost < best[0]:
            best = (cost, plan)
    if best is None:
        return None, "; ".join(reasons[:3])
    return best[1], ""


def _spread(ranked: list[GraspCandidate], spacing: float, budget: int):
    """``ranked`` in order, at most ``budget`` of them, each one after a failure at least
    ``spacing`` from every candidate tried before it (a generator: what it yields next depends
    on nothing but the order -- every candidate yielded before failed); the candidates it
    skipped follow, in order, when the others run out."""
    tried: list[np.ndarray] = []
    skipped = []
    for c in ranked:
        if len(tried) >= budget:
            return
        if tried and np.min(np.linalg.norm(np.array(tried) - c.point, axis=1)) < spacing:
            skipped.append(c)
            continue
        tried.append(c.point)
        yield c
    for c in skipped:
        if len(tried) >= budget:
            return
        tried.append(c.point)
        yield c


def plan_grasp(pw: PlanningWorld, candidates: list[GraspCandidate], est: JointEstimate,
               amount: float, q_start, *, prefer_hidden: bool = True, seed: int = 0,
               moving_links=()) -> tuple[Plan, dict]:
    """Classify, filter and rank ``candidates`` in the plan's world and plan the first that
    works. Returns the plan and a summary of the candidates.

    Raises
    ------
    ManipulationError
        No candidate can be grasped and moved (with the first reasons).
    """
    from sim.manipulate.estimate import ManipulationError

    q_start = np.asarray(q_start, float)
    cands = pw.classify_visibility(q_start, candidates)
    n_hidden = sum(c.hidden for c in cands)
    ranked = rank(pw.fixed_clearance(pw.clear(cands), moving_links), est, prefer_hidden,
                  pw.config)
    tried = []
    for cand in _spread(ranked, pw.config.retry_spacing, pw.config.max_candidates):
        # one seed for every candidate: the same grasp point planned again (the force reference
        # along the true joint, in scoring) gets the same IK
        plan, why = plan_candidate(pw, cand, est, amount, q_start, seed, moving_links)
        if plan is not None:
            plan.tried = tried
            return plan, {"total": len(cands), "hidden": n_hidden, "usable": len(ranked),
                          "rejected_before_choice": tried[:10], "planned_in": pw.source}
        tried.append(f"{np.round(cand.point, 3).tolist()}: {why}")
    raise ManipulationError(
        f"no grasp candidate could be grasped and moved by {amount:g} along the {est.type} axis "
        f"({len(cands)} candidates, {n_hidden} hidden, {len(ranked)} usable, "
        f"{min(len(ranked), pw.config.max_candidates)} tried, planned in the "
        f"{pw.source}). First reasons: " + " | ".join(tried[:4]))


__all__ = ["PlanningConfig", "GraspCandidate", "Plan", "PlanningWorld", "grasp_frame",
           "model_grasp_candidates", "scene_grasp_candidates", "rank", "plan_candidate",
           "plan_grasp", "voxel_centres"]
