"""Viewpoint planning for eye-in-hand capture: rings of views around the object, reached by the arm.

The object's bounding sphere (from its visible geoms in the compiled model) fixes the ring centre
and, with the wrist camera's field of view, the ring radius so that the object fills a chosen share
of the image. Every view looks at the sphere's centre; each is solved with the arm's inverse
kinematics (rail and arm together, joint limits respected, :func:`sim.robot.solve_view_ik`) and
checked for collisions of the arm links in MuJoCo (contacts after ``mj_forward``). Views that the
arm cannot reach are reported with the reason, never silently dropped.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import mujoco
import numpy as np

from sim import robot

log = logging.getLogger(__name__)

#: The method needs at most about 10 degrees between neighbouring views (issue 3): 36 per ring.
MAX_NEIGHBOUR_ANGLE_DEG = 10.0

#: Image rolls (rotation about the optical axis, degrees) tried in this order when the arm cannot
#: reach a view upright: any roll shows the same scene, so it is a free choice of the planner.
ROLL_CANDIDATES_DEG = (0.0, 90.0, -90.0, 180.0, 45.0, -45.0, 135.0, -135.0)

#: Random IK restarts for the upright view (sim.robot.solve_view_ik); rolled fallbacks get 2.
IK_RESTARTS = 8

#: Smallest ring radius (m): the wrist camera's near clipping distance (sim.render.ZNEAR, 0.15 m)
#: plus room for the gripper, whatever the object's size.
MIN_RING_DISTANCE = 0.25


@dataclass(frozen=True)
class ViewPlanConfig:
    """How the views are laid out."""

    views_per_ring: int = 36
    """views on each ring of `elevations_deg` (36 keeps neighbours 10 degrees apart)"""
    elevations_deg: tuple[float, ...] = (20.0, 40.0, 60.0)
    """elevations (degrees above the horizontal plane through the object's centre) of full rings"""
    top_elevations_deg: tuple[float, ...] = (70.0,)
    """rings near the top; they get fewer views, as many as keep neighbours as close as on the
    full rings"""
    fill: float = 0.6
    """diameter of the object's bounding sphere as a share of the shorter image side"""
    top_fill: float = 0.8
    """the same for the top rings, which are planned closer: the arm on its rail reaches less
    high than far (at fill 0.6 the truck's 70 degree ring is out of reach)"""
    seed: int = 0
    """seeds the azimuth of each ring's first view and the IK restarts"""

    def __post_init__(self):
        if self.views_per_ring < 3:
            raise ValueError(f"views_per_ring must be at least 3, got {self.views_per_ring}")
        for name in ("fill", "top_fill"):
            if not 0.05 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must lie in [0.05, 1], got {getattr(self, name)}")
        for e in (*self.elevations_deg, *self.top_elevations_deg):
            if not -80.0 <= e <= 85.0:
                raise ValueError(f"ring elevations must lie in [-80, 85] degrees, got {e}")
        if not self.elevations_deg and not self.top_elevations_deg:
            raise ValueError("give at least one ring elevation")


@dataclass
class View:
    """One planned view and, once planned, how the arm reaches it."""

    index: int
    """position in the plan (capture order)"""
    ring: int
    """ring number, in the order of the config's elevations then top elevations"""
    azimuth: float
    """radians about world z from world x, seen from the object centre"""
    elevation: float
    """radians above the horizontal plane through the object centre"""
    distance: float
    """camera centre to object centre (m)"""
    T_world_camera: np.ndarray
    """(4, 4) target camera pose, OpenCV convention, looking at the object centre"""
    q: np.ndarray | None = None
    """(n,) joint angles (rail first) that reach it, None if unreachable"""
    roll_deg: float = 0.0
    """image roll used to reach it"""
    reason: str = ""
    """why the view is unreachable (empty when reachable)"""

    @property
    def reachable(self) -> bool:
        return self.q is not None


@dataclass
class ViewPlan:
    """The planned views of one capture."""

    centre: np.ndarray
    """(3,) the object's bounding-sphere centre, every camera looks at it"""
    radius: float
    """bounding-sphere radius (m)"""
    distance: float
    """camera centre to object centre on the full rings (m)"""
    top_distance: float
    """the same on the top rings (m)"""
    views: list[View] = field(default_factory=list)

    @property
    def reachable(self) -> list[View]:
        return [v for v in self.views if v.reachable]

    @property
    def unreachable(self) -> list[View]:
        return [v for v in self.views if not v.reachable]


def object_bodies(model: mujoco.MjModel, root: str = "object") -> list[int]:
    """Body ids of the object: ``root`` and every body below it, in model order."""
    root_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, root)
    if root_id < 0:
        raise ValueError(f"the model has no body named {root!r}; a scene's object must have its "
                         "root body named 'object' (scenes/stage.xml)")
    out = []
    for b in range(model.nbody):
        c = b
        while c > 0 and c != root_id:
            c = int(model.body_parentid[c])
        if c == root_id:
            out.append(b)
    return out


def object_bounding_sphere(model: mujoco.MjModel, data: mujoco.MjData,
                           root: str = "object", visible_groups=(0, 1, 2)):
    """Bounding sphere of the object's visible geoms in the current state (after ``mj_forward``).

    Returns
    -------
    centre : (3,) float
    radius : float
    """
    bodies = set(object_bodies(model, root))
    pts = []
    for g in range(model.ngeom):
        if (int(model.geom_bodyid[g]) not in bodies
                or int(model.geom_group[g]) not in visible_groups):
            continue
        R, p = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g]
        if int(model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_MESH):
            mid = int(model.geom_dataid[g])
            a, n = int(model.mesh_vertadr[mid]), int(model.mesh_vertnum[mid])
            pts.append(model.mesh_vert[a:a + n] @ R.T + p)
        else:
            # conservative for primitives: the corners of the geom's bounding box
            lo = model.geom_aabb[g, :3] - model.geom_aabb[g, 3:]
            hi = model.geom_aabb[g, :3] + model.geom_aabb[g, 3:]
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                for z in (lo[2], hi[2])])
            pts.append(corners @ R.T + p)
    if not pts:
        raise ValueError(f"the object {root!r} has no visible geom "
                         f"(groups {tuple(visible_groups)})")
    pts = np.concatenate(pts)
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    return centre, float(np.max(np.linalg.norm(pts - centre, axis=1)))


def ring_distance(radius: float, K: np.ndarray, width: int, height: int, fill: float) -> float:
    """Camera distance at which a sphere of ``radius`` spans ``fill`` of the shorter image side."""
    K = np.asarray(K, dtype=float)
    # half the shorter side, as an angle
    half = min(np.arctan(0.5 * width / K[0, 0]), np.arctan(0.5 * height / K[1, 1]))
    # the sphere's silhouette has angular radius asin(r / d)
    d = radius / np.sin(np.arctan(fill * np.tan(half)))
    return float(max(d, MIN_RING_DISTANCE))


def ring_sizes(config: ViewPlanConfig) -> list[tuple[float, int]]:
    """(elevation in radians, number of views) of every ring."""
    out = [(np.deg2rad(e), config.views_per_ring) for e in config.elevations_deg]
    step = 2.0 * np.pi / config.views_per_ring
    for e in config.top_elevations_deg:
        el = np.deg2rad(e)
        # neighbours on a ring of elevation el with n views are 2 asin(cos(el) sin(pi / n)) apart
        chord = np.sin(step / 2.0) / max(np.cos(el), 1e-9)
        n = config.views_per_ring if chord >= 1 else int(np.ceil(np.pi / np.arcsin(chord)))
        out.append((el, max(3, min(n, config.views_per_ring))))
    return out


def plan_views(centre, distance: float, config: ViewPlanConfig,
               top_distance: float | None = None) -> list[View]:
    """Target camera poses on rings around ``centre`` (not yet checked against the arm).

    ``distance`` is the radius of the full rings, ``top_distance`` (default ``distance``) that of
    the top rings.
    """
    centre = np.asarray(centre, dtype=float)
    n_full = len(config.elevations_deg)
    if centre.shape != (3,):
        raise ValueError(f"expected centre of shape (3,), got {centre.shape}")
    rng = np.random.default_rng(config.seed)
    views = []
    for ring, (el, n) in enumerate(ring_sizes(config)):
        az0 = rng.uniform(0.0, 2.0 * np.pi / n)
        dist = distance if ring < n_full or top_distance is None else top_distance
        for k in range(n):
            az = az0 + 2.0 * np.pi * k / n
            eye = centre + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                                np.sin(el)])
            views.append(View(index=len(views), ring=ring, azimuth=float(az), elevation=float(el),
                              distance=float(dist),
                              T_world_camera=robot.look_at_pose(eye, centre)))
    return views


def order_for_rail(views: list[View], kin: robot.ArmKinematics) -> list[View]:
    """Capture order: ring by ring, each ring swept in one direction of the rail (alternating
    between rings), so that the rail never turns a full circle back between neighbouring views.
    Views are re-indexed in that order.
    """
    out = []
    for ring in sorted({v.ring for v in views}):
        members = [v for v in views if v.ring == ring]
        members.sort(key=lambda v: (kin.rail_angle_for_azimuth(v.azimuth), v.azimuth))
        if ring % 2:
            members.reverse()
        out.extend(members)
    for i, v in enumerate(out):
        v.index = i
    return out


def rolled(T_world_camera: np.ndarray, roll_deg: float) -> np.ndarray:
    """The same camera turned by ``roll_deg`` about its optical axis (OpenCV z)."""
    a = np.deg2rad(roll_deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    T = np.array(T_world_camera, dtype=float)
    T[:3, :3] = T[:3, :3] @ Rz
    return T


def arm_link_bodies(model: mujoco.MjModel, kin: robot.ArmKinematics) -> set[int]:
    """Bodies moved by the arm joints.

    Not the rail carriage and the arm's base on it: they ride on the floor by design.
    """
    first = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, kin.joint_names[1])
    root = int(model.jnt_bodyid[first])
    out = set()
    for b in range(model.nbody):
        c = b
        while c > 0 and c != root:
            c = int(model.body_parentid[c])
        if c == root:
            out.add(b)
    return out


def arm_collisions(model: mujoco.MjModel, data: mujoco.MjData, links: set[int]) -> list[str]:
    """Contacts of the arm links with anything (table, object, floor, other links), after
    ``mj_forward``; as readable ``"geom1/geom2"`` strings."""
    def name(g):
        return (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
                or f"geom{g}@{model.body(model.geom_bodyid[g]).name}")

    out = []
    for c in data.contact[: data.ncon]:
        g1, g2 = int(c.geom[0]), int(c.geom[1])
        if int(model.geom_bodyid[g1]) in links or int(model.geom_bodyid[g2]) in links:
            out.append(f"{name(g1)}/{name(g2)}")
    return sorted(set(out))


def solve_views(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                views: list[View], *, seed: int = 0, progress=None) -> None:
    """Fill in ``q`` (or ``reason``) of every view: IK with joint limits, then a collision check.

    ``data`` holds the scene state (object configuration); its arm joints are changed.
    """
    qidx = robot.qpos_indices(model, kin)
    links = arm_link_bodies(model, kin)
    saved = data.qpos.copy()
    q_prev = None
    for view in views:
        reasons = []
        found = False
        for roll in ROLL_CANDIDATES_DEG:
            T = rolled(view.T_world_camera, roll)
            # start from the previous view (short moves), else from the arm's default seed; the
            # upright view gets the full IK effort, the rolled fallbacks a few restarts each
            starts = [q_prev, None] if q_prev is not None else [None]
            for q0 in starts if roll == 0.0 else starts[:1]:
                res = robot.solve_view_ik(kin, T, q0, seed=seed + view.index,
                                          restarts=IK_RESTARTS if roll == 0.0 else 2)
                if not res.success:
                    reasons.append(f"roll {roll:+.0f}: IK {res.position_error * 1e3:.1f} mm "
                                   f"{np.rad2deg(res.rotation_error):.2f} deg off")
                    continue
                data.qpos[:] = saved
                data.qpos[qidx] = res.q
                mujoco.mj_forward(model, data)
                hits = arm_collisions(model, data, links)
                if hits:
                    reasons.append(f"roll {roll:+.0f}: collision {', '.join(hits[:3])}")
                    continue
                view.q, view.roll_deg, view.reason = res.q.copy(), roll, ""
                view.T_world_camera = T
                q_prev = res.q
                found = True
                break
            if found:
                break
        if not found:
            view.reason = "; ".join(reasons)
            log.info("view %d (ring %d, azimuth %.0f deg) unreachable: %s", view.index, view.ring,
                     np.rad2deg(view.azimuth), view.reason)
        if progress is not None:
            progress.update(1)
    data.qpos[:] = saved
    mujoco.mj_forward(model, data)
