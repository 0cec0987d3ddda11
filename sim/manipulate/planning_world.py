"""The planning world: the scene's stage and arm with the object replaced by the registered model.

:class:`PlanningWorld` holds one small sphere per voxel of the model's points (every link,
configuration A), which MuJoCo's collision detection and ray casting then treat like any other
geom. Every question the plan asks is asked there:

- whether a candidate is hidden from the wrist camera at the arm's current pose: a ray from the
  camera centre meets the model (or the stage) before the point, or the point is outside the
  image (:meth:`PlanningWorld.classify_visibility`);
- free space in front of a candidate (:meth:`PlanningWorld.clear`) and its clearance from the
  parts that do not move with it (:meth:`PlanningWorld.fixed_clearance`);
- contacts of the arm at a configuration (:meth:`PlanningWorld.arm_contacts`; during the
  motion with the links the joint moves carried by it, each link's spheres being one mocap
  body), along the travel to the pre-grasp pose (:meth:`PlanningWorld.travel_contacts`) and
  along the approach from there to the grasp (:meth:`PlanningWorld.approach_contacts`).
"""

from __future__ import annotations

import dataclasses
import logging

import mujoco
import numpy as np
from scipy.spatial import cKDTree

from sim import robot, views
from sim.camera import mujoco_camera_intrinsics
from sim.manipulate.candidates import GraspCandidate, tangents, voxel_centres
from sim.manipulate.planning_config import PlanningConfig
from sim.manipulate.world import World
from sim.scene import body_subtree

log = logging.getLogger(__name__)

#: Geom group of collision geoms (stage, arm, and in a PlanningWorld the model's spheres): the
#: rays of the plan see these and nothing else.
COLLISION_GROUP = 3
#: Group the true object's geoms are moved to in a model-based PlanningWorld (no ray sees them,
#: nothing collides with them).
HIDDEN_GROUP = 5


class PlanningWorld:
    """The stage and the arm, with the object as the robot knows it (see the module docstring).

    Build with :meth:`from_model` (the registered model: what the harness uses) or
    :meth:`from_scene` (the true object: demonstrations only).
    """

    def __init__(self, world: World, model: mujoco.MjModel, source: str, config: PlanningConfig,
                 model_geoms: dict, occlusion_tolerance: float, contact_margin: float = 0.0,
                 link_mocap: dict[int, int] | None = None):
        self.world = world
        self.model = model
        self.data = mujoco.MjData(model)
        self.data.qpos[:] = world.qpos_start
        mujoco.mj_forward(model, self.data)
        self.kin = robot.load_arm_kinematics(model)
        self.qidx = robot.qpos_indices(model, self.kin)
        self.q_home = np.array(world.qpos_start[self.qidx], float)
        """the arm's home configuration (its keyframe): a second start of the plan's IK"""
        self.arm_links = views.arm_link_bodies(model, self.kin)
        arm = robot.arm_spec(model)
        self.flange_body = model.body(arm.prefix + arm.flange_body).id
        self.gripper_bodies = set(body_subtree(model, self.flange_body))
        self.source = source
        self.config = config
        self.model_geoms = model_geoms
        """model sphere geom id -> the model link it stands for"""
        self.occlusion_tolerance = occlusion_tolerance
        self.contact_margin = contact_margin
        """the model geoms' compiled contact margin (m): the clearance the travel can be checked
        with (the registered model's spheres: ``travel_clearance``; the true object: none)"""
        self._groups = np.zeros(6, dtype=np.uint8)
        self._groups[COLLISION_GROUP] = 1
        self.link_mocap: dict[int, int] = dict(link_mocap or {})
        """model link -> its mocap body's index (a world planned on the registered model: the
        links the motion carries are moved there, :meth:`arm_contacts`' ``carry``)"""

    @classmethod
    def from_model(cls, world: World, registered,
                   config: PlanningConfig | None = None) -> PlanningWorld:
        """The stage and arm of the scene file, the object replaced by ``registered`` (an
        ArticulatedModel in the robot frame, metres): spheres at its points' voxels."""
        config = config or PlanningConfig()
        if not registered.scale_known:
            raise ValueError("plan from a registered model (robot frame, metres)")
        spec = mujoco.MjSpec.from_file(str(world.path))
        n_points = 0
        for li, lk in enumerate(registered.links):
            # one mocap body per link, at the world's origin: a link carried by the motion
            # (:meth:`arm_contacts`, ``carry``) moves with its body, its spheres' bounding
            # volumes with it
            body = spec.worldbody.add_body(name=f"registered_link{li}", mocap=True)
            pts = np.asarray(lk.points, float)
            n_points += len(pts)
            for k, c in enumerate(voxel_centres(pts, config.voxel, config.min_sphere_points)):
                body.add_geom(name=f"model_link{li}_{k}", type=mujoco.mjtGeom.mjGEOM_SPHERE,
                              size=[config.sphere_radius, 0, 0], pos=c, contype=1,
                              conaffinity=1, group=COLLISION_GROUP, rgba=[0.9, 0.6, 0.1, 1.0],
                              margin=config.travel_clearance, gap=config.travel_clearance)
        # the margin (compiled in: MuJoCo's bounding boxes include it, a margin set after
        # compiling finds nothing) makes MuJoCo report the arm's passes closer than
        # travel_clearance as contacts of positive distance; arm_contacts counts those only
        # on the travel (travel_contacts), every other check only contacts of negative distance
        model = spec.compile()
        # the true object is no part of the robot's knowledge: nothing collides with it and no
        # ray of the plan sees it
        obj = world.object_bodies
        for g in range(model.ngeom):
            if int(model.geom_bodyid[g]) in obj:
                model.geom_contype[g] = 0
                model.geom_conaffinity[g] = 0
                model.geom_group[g] = HIDDEN_GROUP
        link_of = {model.body(f"registered_link{li}").id: li
                   for li in range(len(registered.links))}
        geoms = {g: link_of[int(model.geom_bodyid[g])] for g in range(model.ngeom)
                 if int(model.geom_bodyid[g]) in link_of}
        log.info("planning world: %d model spheres (%.0f mm voxels) for %d model points",
                 len(geoms), 1e3 * config.voxel, n_points)
        return cls(world, model, "registered model", config, geoms,
                   config.sphere_radius + config.occlusion_margin, config.travel_clearance,
                   {li: int(model.body_mocapid[b]) for b, li in link_of.items()})

    @classmethod
    def from_scene(cls, world: World, config: PlanningConfig | None = None
                   ) -> PlanningWorld:
        """The true world (demonstrations along the true joint and scoring's force reference;
        never the harness's plan). The object's geoms stand in for the model's spheres, each
        under its body's id (``moving_links`` are then body ids)."""
        config = config or PlanningConfig()
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

        lens = self.config.camera_ray_start

        def blocked(p) -> bool:
            ray = p - T[:3, 3]
            dist = float(np.linalg.norm(ray))
            hit = mujoco.mj_ray(m, d, T[:3, 3] + lens * ray / dist, ray / dist, self._groups, 1,
                                self.flange_body, geomid)
            return 0 <= hit < dist - lens - self.occlusion_tolerance

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
                u, v = tangents(c.normal)
                lifted = c.point + margin * c.normal
                around = [lifted] + [lifted + margin * t for t in (u, -u, v, -v)]
                if not all(blocked(p) for p in around):
                    out.append(GraspCandidate(c.point, c.normal, False,
                                              f"visible at the edge of {what}"))
                    continue
            out.append(GraspCandidate(c.point, c.normal, True, f"occluded by {what}"))
        return out

    def _past_own_spheres(self, point: np.ndarray, normal: np.ndarray, start: float,
                          spheres: tuple) -> float:
        """Where a ray from ``point`` along ``normal`` starts: ``start`` out, or beyond the model
        spheres that hold that start (the surface's own layer of spheres, each up to a sphere's
        radius plus the points' noise off the surface: a ray begun inside one meets it at
        distance 0 and calls the surface's own noise an obstacle in front of it). ``spheres``:
        the model spheres' (KD-tree of centres, centres, radii), as :meth:`_model_spheres`."""
        tree, centres, radius = spheres
        if tree is None:
            return start
        for _ in range(4):
            p0 = point + start * normal
            near = np.asarray(tree.query_ball_point(p0, float(radius.max())), dtype=int)
            near = near[np.linalg.norm(centres[near] - p0, axis=1) < radius[near]]
            if len(near) == 0:
                break
            # the farthest exit along the ray of the spheres that hold its start
            d = centres[near] - point
            along = d @ normal
            off = np.sqrt(np.maximum(np.sum(d * d, axis=1) - along ** 2, 0.0))
            start = float(np.max(along + np.sqrt(np.maximum(radius[near] ** 2 - off ** 2,
                                                            0.0)))) + 1e-4
        return start

    def _model_spheres(self) -> tuple:
        """(KD-tree of the model spheres' centres where they are now, the centres, their radii);
        (None, None, None) without model spheres."""
        if not self.model_geoms:
            return None, None, None
        ids = np.fromiter(self.model_geoms, dtype=np.int64)
        centres = np.array(self.data.geom_xpos[ids])
        return cKDTree(centres), centres, np.array(self.model.geom_size[ids, 0])

    def clear(self, candidates) -> list[GraspCandidate]:
        """Candidates with free space in front of them: a bundle of rays along the normal (the
        centre and four around it) meets nothing for ``approach_free_length``. The centre ray
        starts beyond the spheres its start lies in (:meth:`_past_own_spheres`)."""
        cfg = self.config
        geomid = np.zeros(1, dtype=np.int32)
        start = max(1e-3, 1.5 * (self.occlusion_tolerance - cfg.occlusion_margin))
        spheres = self._model_spheres()
        out = []
        for c in candidates:
            u, v = tangents(c.normal)
            starts = [c.point + self._past_own_spheres(c.point, c.normal, start, spheres)
                      * c.normal]
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
        dist, _ = cKDTree(self.data.geom_xpos[fixed]).query(
            np.array([c.point for c in candidates]))
        return [dataclasses.replace(c, clearance=float(d))
                for c, d in zip(candidates, dist, strict=True)]

    def _on_grasped_face(self, p, contact_dist, grasp_point, grasp_normal) -> bool:
        """A model sphere at ``p``, met at ``contact_dist`` (m, MuJoCo's contact distance:
        negative when the geoms overlap), that the gripper at the grasp pose may touch: within
        ``gripper_contact_radius`` of the grasp point and no deeper than
        ``gripper_contact_depth``, or (``grasp_normal`` given) grazed by the fingertips on the
        grasped face (:attr:`PlanningConfig.face_contact_radius`, ``face_contact_depth``): the
        fingertips stop 3 mm short of the surface and the spheres stand 4 mm out of it. With
        ``grasp_normal``, either only for a sphere on the grasped face, no more than
        :attr:`PlanningConfig.face_height` out of it (a handle beside the grasp point is not)."""
        cfg = self.config
        offset = np.asarray(p, float) - grasp_point
        if grasp_normal is not None and float(offset @ grasp_normal) > cfg.face_height:
            return False
        dist = float(np.linalg.norm(offset))
        if dist < cfg.gripper_contact_radius and contact_dist > -cfg.gripper_contact_depth:
            return True
        return bool(grasp_normal is not None and dist < cfg.face_contact_radius
                    and contact_dist > -cfg.face_contact_depth)

    def _contacts_now(self) -> None:
        """The plan's world posed at its ``qpos`` and mocap bodies, and its contacts found:
        MuJoCo's kinematics and collision detection, the part of ``mj_forward`` that the
        contacts come from (not the dynamics and the constraint solver after it, which planning
        never reads)."""
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_collision(self.model, self.data)

    def gripper_contacts(self, q) -> int:
        """How many contacts the gripper (the bodies below the flange) has with the model (every
        link; in a world planned on the true object, the object's geoms) at configuration
        ``q``, the allowed ones included (:meth:`arm_contacts`)."""
        m, d = self.model, self.data
        d.qpos[self.qidx] = q
        self._contacts_now()
        return sum(1 for c in d.contact[: d.ncon]
                   if c.dist < 0
                   and {int(m.geom_bodyid[c.geom[0]]), int(m.geom_bodyid[c.geom[1]])}
                   & self.gripper_bodies
                   and (int(c.geom[0]) in self.model_geoms or int(c.geom[1]) in self.model_geoms))

    def arm_contacts(self, q, grasp_point=None, grasp_links=(), moving_links=(),
                     grasp_normal=None, clearance: float = 0.0,
                     carry: np.ndarray | None = None) -> list[str]:
        """Contacts of the arm at configuration ``q`` in the plan's world. With ``grasp_point``,
        the gripper touching the grasped link (a model link of ``grasp_links``) within
        ``gripper_contact_radius`` of it, no deeper than ``gripper_contact_depth``, is allowed
        -- never another link, nor the stage. With ``grasp_normal`` too, the gripper may also
        touch the grasped face under its fingers (:meth:`_on_grasped_face`). With ``clearance``
        (m, at most :attr:`contact_margin`), a pass of the arm closer than that to a model geom
        counts as a contact too.

        ``moving_links`` (the grasped link and those it carries, during the motion) with
        ``carry`` ((4, 4), the motion so far in the world frame): those links' spheres are moved
        by it and are obstacles like any other (``grasp_point`` and ``grasp_normal`` are then
        where the motion has taken them); they are put back afterwards. Without ``carry``, or in
        a world planned on the true object (:meth:`from_scene`, whose links this cannot move),
        they are no obstacle (they move with the gripper)."""
        m, d = self.model, self.data
        d.qpos[self.qidx] = q
        moving = set(moving_links)
        carried = [self.link_mocap[li] for li in sorted(moving) if li in self.link_mocap] \
            if carry is not None else []
        if carried:
            T = np.asarray(carry, float)
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, np.ascontiguousarray(T[:3, :3]).ravel())
            d.mocap_pos[carried] = T[:3, 3]
            d.mocap_quat[carried] = quat
            exempt: set[int] = set()
        else:
            exempt = moving
        try:
            self._contacts_now()
            out = []
            for c in d.contact[: d.ncon]:
                if c.dist >= clearance:
                    continue
                g1, g2 = int(c.geom[0]), int(c.geom[1])
                b1, b2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
                if b1 not in self.arm_links and b2 not in self.arm_links:
                    continue
                arm_b, other = (b1, g2) if b1 in self.arm_links else (b2, g1)
                if other in self.model_geoms and self.model_geoms[other] in exempt:
                    continue
                if (grasp_point is not None and arm_b in self.gripper_bodies
                        and self.model_geoms.get(other) in set(grasp_links)
                        and self._on_grasped_face(d.geom_xpos[other], float(c.dist),
                                                  grasp_point, grasp_normal)):
                    continue
                name = [(f"model link {self.model_geoms[g]}" if g in self.model_geoms else
                         mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}")
                        for g in (g1, g2)]
                out.append("/".join(name))
        finally:
            if carried:  # the links back where configuration A has them
                d.mocap_pos[carried] = 0.0
                d.mocap_quat[carried] = (1.0, 0.0, 0.0, 0.0)
                mujoco.mj_kinematics(m, d)
        return sorted(set(out))

    def travel_contacts(self, q_from, q_to) -> tuple[list[str], float]:
        """Contacts of the arm along the straight joint-space line from ``q_from`` to ``q_to``
        (the travel to the pre-grasp pose, as execution follows it), its ends left out (the
        start is where the arm is; the end is checked on its own): configurations no more than
        :attr:`PlanningConfig.travel_joint_step` apart in any joint; a pass of the arm closer
        than :attr:`PlanningConfig.travel_clearance` to the model counts as a contact (in a
        world planned on the true object: a touch).

        Returns
        -------
        hits : list of str
            The contacts (:meth:`arm_contacts`) at the first configuration that has any; empty
            when the line is clear.
        at : float
            Where along the line (0 at ``q_from``, 1 at ``q_to``; 1.0 when clear).
        """
        return self._path_contacts([q_from, q_to], min_steps=2)

    def path_contacts(self, q_points) -> tuple[list[str], float]:
        """:meth:`travel_contacts` along straight joint-space lines through ``q_points`` ((k, n)
        waypoints, as execution follows them); ``at`` from 0 to 1 by joint-space length along
        the whole path."""
        return self._path_contacts(list(np.asarray(q_points, float)), min_steps=2)

    def approach_contacts(self, approach, grasp_point, grasp_links=(), grasp_normal=None
                          ) -> tuple[list[str], float]:
        """Contacts of the arm along the approach (``approach``: (k, n) joint waypoints from the
        pre-grasp pose to the grasp pose, followed in straight joint-space lines), checked like
        the travel (:meth:`travel_contacts`: a configuration every
        :attr:`PlanningConfig.travel_joint_step`, a pass closer than ``travel_clearance`` to
        the model counts), its ends left out (each is checked on its own). What the grasp must
        touch is allowed as at the grasp pose (:meth:`arm_contacts` with ``grasp_point``,
        ``grasp_links``, ``grasp_normal``): the gripper on the grasped link near the grasp point
        no deeper than ``gripper_contact_depth``, or grazing its face; anything else -- another
        link, the grasped link away from the grasp point, the stage -- is a collision.

        Returns
        -------
        hits : list of str
            The contacts at the first configuration that has any; empty when the approach is
            clear.
        at : float
            Where along the approach (0 at the pre-grasp pose, 1 at the grasp pose, by joint-space
            length; 1.0 when clear).
        """
        return self._path_contacts(approach, min_steps=1,
                                   grasp_point=np.asarray(grasp_point, float),
                                   grasp_links=grasp_links, grasp_normal=grasp_normal)

    def _path_contacts(self, waypoints, min_steps: int, **allowed) -> tuple[list[str], float]:
        """Contacts of the arm along joint-space waypoints followed in straight lines, its ends
        left out: on each line a configuration every :attr:`PlanningConfig.travel_joint_step`
        in any joint (at least ``min_steps`` steps; the waypoints between the lines are
        checked), a pass closer than ``travel_clearance`` counting; ``allowed`` goes to
        :meth:`arm_contacts` (the contacts a grasp may make). Returns the contacts at the first
        configuration that has any (empty: clear) and where it lies (0 to 1 by joint-space
        length; the line's own fraction when the waypoints do not move; 1.0 when clear)."""
        way = np.atleast_2d(np.asarray(waypoints, float))
        if len(way) < 2:
            return [], 1.0
        seg = (np.max(np.abs(np.diff(way, axis=0)), axis=1) if way.shape[1]
               else np.zeros(len(way) - 1))
        done = np.concatenate([[0.0], np.cumsum(seg)])
        total = float(done[-1])
        clearance = min(self.config.travel_clearance, self.contact_margin)
        for k in range(len(seg)):
            n = max(min_steps, int(np.ceil(seg[k] / self.config.travel_joint_step)))
            last = k == len(seg) - 1
            for f in np.arange(1, n + (0 if last else 1)) / n:
                hits = self.arm_contacts(way[k] + f * (way[k + 1] - way[k]),
                                         clearance=clearance, **allowed)
                if hits:
                    return hits, float((done[k] + f * seg[k]) / total if total > 0 else f)
        return [], 1.0


__all__ = ["COLLISION_GROUP", "HIDDEN_GROUP", "PlanningWorld"]
