"""Viewpoint planning for eye-in-hand capture: rings of views around the object, reached by the arm.

The object's bounding sphere (from its visible geoms in the compiled model) fixes the ring centre
and, with the wrist camera's field of view, the band of camera distances at which the object fills
a good share of the image (:attr:`ViewPlanConfig.fill_range`). Every view looks at the sphere's
centre; each is solved with the arm's inverse kinematics (rail and arm together, joint limits
respected, :func:`sim.robot.solve_view_ik`) and checked for collisions of the arm links in MuJoCo
(contacts after ``mj_forward``: with the table, the object, the floor and the arm itself).

:func:`plan_capture` chooses each ring before committing to it: the distance in the band nearest
the preferred fill and, only if no distance gives a ring the arm reaches everywhere without a
collision, the elevation nearest the desired one (within
:attr:`ViewPlanConfig.max_elevation_shift_deg`). A candidate ring is first probed at a few
azimuths, then solved in full. Views that the arm cannot reach on the best ring found are reported
with the reason, never silently dropped.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, fields, replace

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
#: Random IK restarts while probing a candidate ring. Most rings the arm reaches are reached from
#: the neighbouring view's solution at once, so the probe spends little on hopeless rings; the
#: price is that a ring at the very edge of the workspace may fail its probe and give way to the
#: next candidate (another distance in the band), never that an unreachable view is planned.
PROBE_IK_RESTARTS = 2
#: Views of a candidate ring probed (evenly spread in azimuth) before it is solved in full.
PROBE_VIEWS = 6

#: Smallest ring radius (m): the wrist camera's near clipping distance (sim.render.ZNEAR, 0.15 m)
#: plus room for the gripper, whatever the object's size.
MIN_RING_DISTANCE = 0.25

#: Largest joint step (rad) between the configurations checked for contacts along the straight
#: joint-space move from one view to the next (sim.capture drives the servos along that line):
#: 0.02 rad moves a point 1 m from the joint by 2 cm, less than the links' thickness.
PATH_CHECK_STEP = 0.02

#: Clearance (m) the planned arm keeps from everything that is not the robot (object, table,
#: floor) at every view and at every checked step of the moves between views. The servos follow
#: the planned joint-space line within a few millimetres (sim.capture feeds each one its own lag
#: forward), but a plan that merely avoided contact could pass a few millimetres from a thin
#: part: scraper_truck's configuration B had a move 9.8 mm from the blade that the rail's lag
#: (0.3 s behind the wrist) turned into a contact, and the capture failed. 1 cm is also a
#: fifth of the 5 cm a joint step of :data:`PATH_CHECK_STEP` moves the wrist at most, the
#: margin between two checked configurations.
CLEARANCE_M = 0.01

#: Step (share of the image) between the candidate fills of a ring, and (degrees) between its
#: candidate elevations: 0.05 of fill is 2-4 cm of distance for the bundled objects, 2.5 degrees
#: a quarter of the 10 degree view spacing.
FILL_STEP = 0.05
ELEVATION_STEP_DEG = 2.5


#: Fewest views per full ring a capture may ask for (``--views`` of sim.capture and sim.evaluate,
#: :attr:`ViewPlanConfig.views_per_ring`): with fewer, neighbours on a ring are more than 90
#: degrees apart and no two views of the object share enough of it to be matched.
MIN_VIEWS = 4


def views_problem(n_views: int, flag: str = "--views") -> str | None:
    """The message for a views-per-ring value below :data:`MIN_VIEWS` (None when it is fine):
    one wording for every command."""
    if n_views >= MIN_VIEWS:
        return None
    return (f"{flag} must be at least {MIN_VIEWS} (views per full ring; 36 keeps neighbours 10 "
            f"degrees apart), got {n_views}")


@dataclass(frozen=True)
class ViewPlanConfig:
    """How the views are laid out."""

    views_per_ring: int = 36
    """views on each ring of `elevations_deg` (36 keeps neighbours 10 degrees apart)"""
    elevations_deg: tuple[float, ...] = (20.0, 40.0, 60.0)
    """desired elevations (degrees above the horizontal plane through the object's centre) of the
    full rings"""
    top_elevations_deg: tuple[float, ...] = (70.0,)
    """rings near the top; they get fewer views, as many as keep neighbours as close as on the
    full rings"""
    fill: float = 0.6
    """preferred diameter of the object's bounding sphere as a share of the shorter image side"""
    fill_range: tuple[float, float] = (0.45, 0.75)
    """the band of fills a ring may take when the arm cannot reach it at the preferred one (the
    object still fills a good part of the image and stays sharp and whole in it)"""
    max_elevation_shift_deg: float = 10.0
    """how far a ring may move from its desired elevation when no distance in the band gives a
    ring the arm reaches everywhere"""
    seed: int = 0
    """seeds the azimuth of each ring's first view and the IK restarts"""

    def __post_init__(self):
        problem = views_problem(self.views_per_ring, "views_per_ring (--views)")
        if problem:
            raise ValueError(problem)
        lo, hi = self.fill_range
        if not 0.05 <= lo <= hi <= 1.0:
            raise ValueError(f"fill_range must satisfy 0.05 <= low <= high <= 1, got "
                             f"{self.fill_range}")
        if not lo <= self.fill <= hi:
            raise ValueError(f"fill must lie in fill_range {self.fill_range}, got {self.fill}")
        if not 0.0 <= self.max_elevation_shift_deg <= 30.0:
            raise ValueError(f"max_elevation_shift_deg must lie in [0, 30], got "
                             f"{self.max_elevation_shift_deg}")
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


@dataclass(frozen=True)
class Ring:
    """One ring of views as chosen by :func:`plan_capture`."""

    index: int
    """ring number"""
    desired_elevation: float
    """the configuration's elevation for it (rad)"""
    elevation: float
    """the elevation chosen (rad)"""
    distance: float
    """camera centre to object centre (m)"""
    fill: float
    """the object's bounding-sphere diameter as a share of the shorter image side"""
    n_views: int
    """views on the ring"""
    azimuth0: float
    """azimuth of its first view before ordering (rad)"""
    top: bool = False
    """a top ring (fewer views)"""
    candidates_tried: int = 0
    """(elevation, distance) pairs probed before this one was chosen"""


@dataclass
class ViewPlan:
    """The planned views of one capture."""

    centre: np.ndarray
    """(3,) the object's bounding-sphere centre, every camera looks at it"""
    radius: float
    """bounding-sphere radius (m)"""
    rings: list[Ring] = field(default_factory=list)
    """the rings chosen, in capture order"""
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


def _half_fov(K: np.ndarray, width: int, height: int) -> float:
    """Half the field of view across the shorter image side (rad)."""
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3):
        raise ValueError(f"expected K of shape (3, 3), got {K.shape}")
    return float(min(np.arctan(0.5 * width / K[0, 0]), np.arctan(0.5 * height / K[1, 1])))


def ring_distance(radius: float, K: np.ndarray, width: int, height: int, fill: float) -> float:
    """Camera distance at which a sphere of ``radius`` spans ``fill`` of the shorter image side
    (at least :data:`MIN_RING_DISTANCE`)."""
    # the sphere's silhouette has angular radius asin(r / d)
    d = radius / np.sin(np.arctan(fill * np.tan(_half_fov(K, width, height))))
    return float(max(d, MIN_RING_DISTANCE))


def fill_at_distance(radius: float, K: np.ndarray, width: int, height: int,
                     distance: float) -> float:
    """Share of the shorter image side that a sphere of ``radius`` spans from ``distance``: the
    inverse of :func:`ring_distance`."""
    if distance <= radius:
        raise ValueError(f"distance {distance:.3f} m lies inside the sphere of radius "
                         f"{radius:.3f} m")
    return float(np.tan(np.arcsin(radius / distance)) / np.tan(_half_fov(K, width, height)))


def ring_size(elevation: float, views_per_ring: int, top: bool) -> int:
    """Views on a ring at ``elevation`` (rad): ``views_per_ring`` on a full ring; on a top ring
    as few as keep neighbours as close as on a full ring (at least 3)."""
    if not top:
        return views_per_ring
    step = 2.0 * np.pi / views_per_ring
    # neighbours on a ring of elevation el with n views are 2 asin(cos(el) sin(pi / n)) apart
    chord = np.sin(step / 2.0) / max(np.cos(elevation), 1e-9)
    n = views_per_ring if chord >= 1 else int(np.ceil(np.pi / np.arcsin(chord)))
    return max(3, min(n, views_per_ring))


def ring_sizes(config: ViewPlanConfig) -> list[tuple[float, int]]:
    """(desired elevation in radians, number of views) of every ring."""
    out = [(np.deg2rad(e), config.views_per_ring) for e in config.elevations_deg]
    for e in config.top_elevations_deg:
        out.append((np.deg2rad(e), ring_size(np.deg2rad(e), config.views_per_ring, True)))
    return out


def ring_views(centre, ring: Ring, first_index: int = 0) -> list[View]:
    """Target camera poses of ``ring`` around ``centre`` (not yet checked against the arm)."""
    centre = np.asarray(centre, dtype=float)
    if centre.shape != (3,):
        raise ValueError(f"expected centre of shape (3,), got {centre.shape}")
    out = []
    el = ring.elevation
    for k in range(ring.n_views):
        az = ring.azimuth0 + 2.0 * np.pi * k / ring.n_views
        eye = centre + ring.distance * np.array([np.cos(el) * np.cos(az),
                                                 np.cos(el) * np.sin(az), np.sin(el)])
        out.append(View(index=first_index + k, ring=ring.index, azimuth=float(az),
                        elevation=float(el), distance=float(ring.distance),
                        T_world_camera=robot.look_at_pose(eye, centre)))
    return out


def _ring_phases(config: ViewPlanConfig) -> list[float]:
    """Azimuth of each ring's first view, seeded: one draw per ring in ring order."""
    rng = np.random.default_rng(config.seed)
    return [float(rng.uniform(0.0, 2.0 * np.pi / n)) for _, n in ring_sizes(config)]


def plan_views(centre, distance: float, config: ViewPlanConfig) -> list[View]:
    """Target camera poses on all rings at their desired elevations and one ``distance`` (not
    yet checked against the arm; :func:`plan_capture` chooses each ring's distance and
    elevation)."""
    out: list[View] = []
    n_full = len(config.elevations_deg)
    for i, ((el, n), az0) in enumerate(zip(ring_sizes(config), _ring_phases(config),
                                           strict=True)):
        ring = Ring(index=i, desired_elevation=el, elevation=el, distance=float(distance),
                    fill=float("nan"), n_views=n, azimuth0=az0, top=i >= n_full)
        out.extend(ring_views(centre, ring, len(out)))
    return out


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
    return _bodies_moved_by(model, kin.joint_names[1])


def _bodies_moved_by(model: mujoco.MjModel, joint: str) -> set[int]:
    """The body of ``joint`` and every body below it."""
    root = int(model.jnt_bodyid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)])
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
    out = []
    for c in data.contact[: data.ncon]:
        g1, g2 = int(c.geom[0]), int(c.geom[1])
        if int(model.geom_bodyid[g1]) in links or int(model.geom_bodyid[g2]) in links:
            out.append(f"{_geom_name(model, g1)}/{_geom_name(model, g2)}")
    return sorted(set(out))


def _geom_name(model: mujoco.MjModel, g: int) -> str:
    return (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
            or f"geom{g}@{model.body(model.geom_bodyid[g]).name}")


def robot_bodies(model: mujoco.MjModel, kin: robot.ArmKinematics) -> set[int]:
    """Every body the rail joint carries: the carriage, the arm's base and its links."""
    return _bodies_moved_by(model, kin.joint_names[0])


def clearance_violations(model: mujoco.MjModel, data: mujoco.MjData, links: set[int],
                         robot_body_ids: set[int], clearance: float = CLEARANCE_M) -> list[str]:
    """What the arm links come closer to than ``clearance`` at ``data.qpos``.

    Runs MuJoCo's collision detection itself (kinematics and collision, with the arm links'
    geom margins raised to ``clearance`` for the call and restored after). A link closer than
    ``clearance`` to anything outside the robot (object, table, floor), or touching another
    part of the robot, is a violation; as readable ``"geom1/geom2 (d mm)"`` strings.

    Parameters
    ----------
    links : set of int
        Bodies moved by the arm joints (:func:`arm_link_bodies`).
    robot_body_ids : set of int
        Bodies carried by the rail (:func:`robot_bodies`): near them only contact counts.
    clearance : float
        Metres.
    """
    return _ClearanceCheck(model, links, robot_body_ids, clearance)(data)


class _ClearanceCheck:
    """:func:`clearance_violations` with its masks and margins prepared once: a large object's
    plan checks ~10^5 configurations, and preparing them per call (body masks, the arm geoms'
    margins read and raised) was 60% of a check's CPU (28 of 47 us, drawer). The same contacts
    and strings as the function; the margins are restored after every call."""

    def __init__(self, model: mujoco.MjModel, links: set[int], robot_body_ids: set[int],
                 clearance: float = CLEARANCE_M):
        self.model, self.clearance = model, float(clearance)
        self.is_link, self.is_robot = _body_masks(model, links, robot_body_ids)
        self.arm_geom = np.flatnonzero(self.is_link[model.geom_bodyid])
        self.saved = model.geom_margin[self.arm_geom].copy()
        self.raised = np.maximum(self.saved, self.clearance)

    def __call__(self, data: mujoco.MjData) -> list[str]:
        model, clearance = self.model, self.clearance
        model.geom_margin[self.arm_geom] = self.raised
        try:
            mujoco.mj_kinematics(model, data)
            mujoco.mj_collision(model, data)
            n = data.ncon
            if n == 0:
                return []
            geoms = data.contact.geom[:n]
            dist = data.contact.dist[:n]
            bodies = model.geom_bodyid[geoms]
            near = self.is_link[bodies].any(axis=1)
            limit = np.where(self.is_robot[bodies].all(axis=1), 0.0, clearance)
            out = [f"{_geom_name(model, int(g1))}/{_geom_name(model, int(g2))} ({d * 1e3:.1f} mm)"
                   for (g1, g2), d in zip(geoms[near & (dist < limit)],
                                          dist[near & (dist < limit)], strict=True)]
        finally:
            model.geom_margin[self.arm_geom] = self.saved
        return sorted(set(out))


_BODY_MASKS: dict = {}


def _body_masks(model: mujoco.MjModel, links: set[int], robot_body_ids: set[int]
                ) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks over the bodies of ``model``: the arm links, the robot's bodies."""
    key = (model.nbody, frozenset(links), frozenset(robot_body_ids))  # all the masks hold
    masks = _BODY_MASKS.get(key)
    if masks is None:
        if len(_BODY_MASKS) > 64:
            _BODY_MASKS.clear()
        is_link = np.zeros(model.nbody, dtype=bool)
        is_link[sorted(links)] = True
        is_robot = np.zeros(model.nbody, dtype=bool)
        is_robot[sorted(robot_body_ids)] = True
        masks = _BODY_MASKS[key] = (is_link, is_robot)
    return masks


def _solve_one(model, data, kin, view: View, q_prev, *, seed: int, restarts: int,
               rolls, check: _ClearanceCheck, qidx: np.ndarray,
               saved: np.ndarray) -> list[str]:
    """Try to reach ``view`` (upright first, then rolled), starting from ``q_prev`` and from the
    arm's default seed. Fills ``view.q`` (and its roll and pose) on success; returns the reasons
    of the failed attempts."""
    reasons = []
    for roll in rolls:
        T = rolled(view.T_world_camera, roll)
        # start from the previous view (short moves), else from the arm's default seed; the
        # upright view gets the full IK effort, the rolled fallbacks a few restarts each
        starts = [q_prev, None] if q_prev is not None else [None]
        for q0 in starts if roll == 0.0 else starts[:1]:
            res = robot.solve_view_ik(kin, T, q0, seed=seed,
                                      restarts=restarts if roll == 0.0 else min(2, restarts))
            if not res.success:
                reasons.append(f"roll {roll:+.0f}: IK {res.position_error * 1e3:.1f} mm "
                               f"{np.rad2deg(res.rotation_error):.2f} deg off")
                continue
            q = res.q if q_prev is None else kin.nearest_equivalent(res.q, q_prev)
            data.qpos[:] = saved
            data.qpos[qidx] = q
            hits = check(data)
            if hits:
                reasons.append(f"roll {roll:+.0f}: too close (clearance "
                               f"{CLEARANCE_M * 1e3:.0f} mm, contact within the arm): "
                               f"{', '.join(hits[:3])}")
                continue
            view.q, view.roll_deg, view.reason = q.copy(), roll, ""
            view.T_world_camera = T
            return []
    return reasons


def solve_views(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                views: list[View], *, seed: int = 0, progress=None, q_start=None,
                restarts: int = IK_RESTARTS, rolls=ROLL_CANDIDATES_DEG,
                stop_at_first_failure: bool = False) -> None:
    """Fill in ``q`` (or ``reason``) of every view: IK with joint limits, then a collision check.

    Views are solved in their order, each IK started at the previous view's solution (the rail
    makes neighbouring views of a ring need nearly the same arm configuration); a view that fails
    is tried once more from the solution of its nearest reachable neighbour on the other side.

    Parameters
    ----------
    model, data
        The scene; ``data`` holds its state (object configuration). Its arm joints are changed
        while solving and restored at the end.
    kin : robot.ArmKinematics
    views : list of View
        Solved in place.
    seed : int
        IK restarts of view ``v`` are seeded with ``seed + v.index``.
    progress : tqdm-like, optional
        ``update(1)`` per view.
    q_start : (n,) float, optional
        Solution of the view before the first (e.g. the previous ring's last view).
    restarts : int
        Random IK restarts of the upright view.
    rolls : sequence of float
        Image rolls (degrees) tried in order.
    stop_at_first_failure : bool
        Leave the remaining views unsolved (``q`` None, reason ``"not tried"``) after the first
        unreachable one (to probe candidate rings quickly).
    """
    qidx = robot.qpos_indices(model, kin)
    links = arm_link_bodies(model, kin)
    saved = data.qpos.copy()
    kw = dict(restarts=restarts, rolls=tuple(rolls),
              check=_ClearanceCheck(model, links, robot_bodies(model, kin)), qidx=qidx,
              saved=saved)
    q_prev = None if q_start is None else np.asarray(q_start, dtype=float)
    failed = False
    for view in views:
        view.q, view.reason = None, ""
        if failed and stop_at_first_failure:
            view.reason = "not tried"
            continue
        reasons = _solve_one(model, data, kin, view, q_prev, seed=seed + view.index, **kw)
        if view.reachable:
            q_prev = view.q
        else:
            view.reason = "; ".join(reasons)
            failed = True
        if progress is not None:
            progress.update(1)
    if not stop_at_first_failure:
        # second chance: start from the next reachable view (the pass came from the other side)
        for i, view in enumerate(views):
            if view.reachable:
                continue
            after = [v for v in views[i + 1:] if v.reachable]
            if after:
                _solve_one(model, data, kin, view, after[0].q, seed=seed + view.index, **kw)
    for view in views:
        if not view.reachable and view.reason != "not tried":
            log.info("view %d (ring %d, azimuth %.0f deg) unreachable: %s", view.index,
                     view.ring, np.rad2deg(view.azimuth), view.reason)
    data.qpos[:] = saved
    mujoco.mj_forward(model, data)


def check_paths(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                views: list[View], q_start=None) -> None:
    """Check the straight joint-space move into every reachable view: the arm keeps
    :data:`CLEARANCE_M` from everything outside the robot and does not touch itself.

    The arm travels from ``q_start`` (if given) to the first reachable view, then from each
    reachable view to the next, as :mod:`sim.capture` drives it. A view whose incoming move
    comes too close to something (the table, the object, the floor) or makes the arm touch
    itself is made unreachable with the reason, and the next move starts from the last view
    kept.
    """
    qidx = robot.qpos_indices(model, kin)
    links = arm_link_bodies(model, kin)
    check = _ClearanceCheck(model, links, robot_bodies(model, kin))
    saved = data.qpos.copy()
    q_prev = None if q_start is None else np.asarray(q_start, dtype=float)
    for view in views:
        if not view.reachable:
            continue
        if q_prev is not None:
            n = max(1, int(np.ceil(np.max(np.abs(view.q - q_prev)) / PATH_CHECK_STEP)))
            for t in np.arange(1, n) / n:
                data.qpos[:] = saved
                data.qpos[qidx] = q_prev + t * (view.q - q_prev)
                hits = check(data)
                if hits:
                    view.q = None
                    view.reason = (f"the move from the previous view comes closer than "
                                   f"{CLEARANCE_M * 1e3:.0f} mm to {', '.join(hits[:3])} "
                                   f"({t:.0%} of the way)")
                    break
        if view.reachable:
            q_prev = view.q
    data.qpos[:] = saved
    mujoco.mj_forward(model, data)


def _candidates(config: ViewPlanConfig, desired_deg: float, radius: float, K, width: int,
                height: int, lowest_deg: float, highest_deg: float):
    """(elevation in degrees, distance, fill) of the candidate rings for one desired elevation:
    the desired elevation first with every distance in the fill band (nearest the preferred fill
    first, the closer of two equally near), then elevations further and further off (towards
    45 degrees first), each with every distance."""
    lo, hi = config.fill_range
    fills = np.round(np.arange(lo, hi + 1e-9, FILL_STEP), 6).tolist() + [config.fill]
    fills = sorted(set(fills), key=lambda f: (abs(f - config.fill), -f))
    distances = []
    for f in fills:
        d = ring_distance(radius, K, width, height, f)
        if all(abs(d - e) > 1e-3 for e in distances):  # the minimum distance clamps small objects
            distances.append(d)
    shifts = [0.0]
    k = 1
    while k * ELEVATION_STEP_DEG <= config.max_elevation_shift_deg + 1e-9:
        step = k * ELEVATION_STEP_DEG
        shifts += [-step, step] if desired_deg > 45.0 else [step, -step]
        k += 1
    for shift in shifts:
        el = desired_deg + shift
        if not lowest_deg <= el <= highest_deg:
            continue
        for d in distances:
            yield el, d, fill_at_distance(radius, K, width, height, d)


def plan_capture(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                 K: np.ndarray, width: int, height: int, config: ViewPlanConfig, *,
                 progress=None) -> ViewPlan:
    """Choose every ring so that the arm reaches all its views without a collision, and solve them.

    For each ring (full rings, then top rings) the candidates of :func:`_candidates` are tried in
    order: a candidate is probed at :data:`PROBE_VIEWS` evenly spread views (few IK restarts,
    stopping at the first failure), then solved view by view up to its first unreachable view
    (:func:`solve_views`) and the moves into its views checked (:func:`check_paths`); the first
    whose views are all reachable, and whose moves touch nothing, is taken. If none is, the
    candidates that passed their probe are solved in full (second chances included) and the
    ring with the most reachable views is taken; its other views are reported unreachable.

    Parameters
    ----------
    model, data
        The scene in the configuration to photograph (``data`` after ``mj_forward``).
    kin : robot.ArmKinematics
    K : (3, 3) float
        Wrist camera intrinsics; ``width``, ``height`` its image size (px).
    config : ViewPlanConfig
    progress : tqdm-like, optional
        ``update(n)`` with the views of each ring once it is chosen.

    Returns
    -------
    ViewPlan
        Rings and views in capture order (ring by ring, each swept in one rail direction).
    """
    centre, radius = object_bounding_sphere(model, data)
    lowest = min((*config.elevations_deg, *config.top_elevations_deg))
    highest = max((*config.elevations_deg, *config.top_elevations_deg))
    lowest = max(-80.0, lowest - config.max_elevation_shift_deg)
    highest = min(85.0, highest + config.max_elevation_shift_deg)
    n_full = len(config.elevations_deg)
    plan = ViewPlan(centre=centre, radius=radius)
    q_last = None
    for i, (desired, az0) in enumerate(zip((*config.elevations_deg, *config.top_elevations_deg),
                                           _ring_phases(config), strict=True)):
        top = i >= n_full
        best: tuple[int, Ring, list[View]] | None = None
        screened: list[tuple[Ring, list[View]]] = []  # passed the probe, not whole
        tried = 0
        for el_deg, d, fill in _candidates(config, desired, radius, K, width, height, lowest,
                                           highest):
            tried += 1
            el = float(np.deg2rad(el_deg))
            ring = Ring(index=i, desired_elevation=float(np.deg2rad(desired)), elevation=el,
                        distance=float(d), fill=float(fill),
                        n_views=ring_size(el, config.views_per_ring, top), azimuth0=az0,
                        top=top, candidates_tried=tried)
            members = order_for_rail(ring_views(centre, ring), kin)
            first = len(plan.views)
            for k, v in enumerate(members):
                v.index = first + k
            step = max(1, len(members) // PROBE_VIEWS)
            probe = members[::step]
            solve_views(model, data, kin, probe, seed=config.seed, q_start=q_last,
                        restarts=PROBE_IK_RESTARTS, stop_at_first_failure=True)
            if not all(v.reachable for v in probe):
                log.debug("ring %d at %.1f deg, %.3f m: probe failed (%s)", i, el_deg, d,
                          next(v.reason for v in probe if not v.reachable))
                if best is None:
                    best = (-1, ring, members)
                continue
            # screened in full, stopping at its first unreachable view: a ring is taken only
            # whole, and a failing view costs every IK restart, so solving the rest of a ring
            # that already failed (as this did until 2026-11) spent most of a large object's
            # plan (drawer: 42 candidates for its lowest ring)
            solve_views(model, data, kin, members, seed=config.seed, q_start=q_last,
                        stop_at_first_failure=True)
            if all(v.reachable for v in members):
                check_paths(model, data, kin, members, q_last)
                if all(v.reachable for v in members):
                    best = (len(members), ring, members)
                    break
            log.debug("ring %d at %.1f deg, %.3f m: not every view reachable", i, el_deg, d)
            screened.append((ring, members))
        else:
            # no candidate is whole: the one with the most reachable views, each solved in full
            # (with its second chances from the other side)
            for ring_c, members_c in screened:
                solve_views(model, data, kin, members_c, seed=config.seed, q_start=q_last)
                check_paths(model, data, kin, members_c, q_last)
                n_ok = sum(v.reachable for v in members_c)
                if best is None or n_ok > best[0]:
                    best = (n_ok, ring_c, members_c)
                if n_ok == len(members_c):
                    break
        n_ok, ring, members = best
        if n_ok < 0:
            # no candidate passed its probe: solve the preferred one in full, to report why
            solve_views(model, data, kin, members, seed=config.seed, q_start=q_last)
            check_paths(model, data, kin, members, q_last)
        if any(not v.reachable for v in members):
            log.warning("ring %d (desired %.0f deg): no ring within %.0f deg and fills %s is "
                        "reachable everywhere; %d of %d views unreachable at %.1f deg, %.3f m",
                        i, desired, config.max_elevation_shift_deg, config.fill_range,
                        sum(not v.reachable for v in members), len(members),
                        np.rad2deg(ring.elevation), ring.distance)
        ring = replace(ring, candidates_tried=tried)
        log.info("ring %d: %d views at %.1f deg (desired %.0f), %.3f m (fill %.2f), %d "
                 "candidates tried", i, ring.n_views, np.rad2deg(ring.elevation), desired,
                 ring.distance, ring.fill, tried)
        plan.rings.append(ring)
        plan.views.extend(members)
        reached = [v for v in members if v.reachable]
        if reached:
            q_last = reached[-1].q
        if progress is not None:
            progress.update(len(members))
    return plan


# ------------------------------------------------------------------------------------ plan files
#: Format tag of a view plan written by :func:`plan_to_json`.
PLAN_FORMAT = "artrecon-view-plan/1"


def _floats(a) -> list:
    """A float array as nested lists of Python floats (JSON writes them with ``repr``, which
    reads back to the same double: a plan from a file is bit for bit the plan that was solved)."""
    return np.asarray(a, dtype=float).tolist()


def plan_to_json(plan: ViewPlan) -> dict:
    """``plan`` as a JSON-serialisable dict that :func:`plan_from_json` reads back exactly."""
    return {
        "format": PLAN_FORMAT,
        "centre": _floats(plan.centre), "radius": float(plan.radius),
        "rings": [{f.name: getattr(r, f.name) for f in fields(Ring)} for r in plan.rings],
        "views": [{"index": v.index, "ring": v.ring, "azimuth": float(v.azimuth),
                   "elevation": float(v.elevation), "distance": float(v.distance),
                   "T_world_camera": _floats(v.T_world_camera),
                   "q": None if v.q is None else _floats(v.q),
                   "roll_deg": float(v.roll_deg), "reason": v.reason} for v in plan.views],
    }


def plan_from_json(obj: dict) -> ViewPlan:
    """The :class:`ViewPlan` of a dict written by :func:`plan_to_json`.

    Raises
    ------
    ValueError
        ``obj`` is not a plan of this format.
    """
    if not isinstance(obj, dict) or obj.get("format") != PLAN_FORMAT:
        raise ValueError(f"not a view plan of format {PLAN_FORMAT!r}")
    views = []
    for v in obj["views"]:
        views.append(View(index=int(v["index"]), ring=int(v["ring"]), azimuth=v["azimuth"],
                          elevation=v["elevation"], distance=v["distance"],
                          T_world_camera=np.array(v["T_world_camera"], dtype=float),
                          q=None if v["q"] is None else np.array(v["q"], dtype=float),
                          roll_deg=v["roll_deg"], reason=v["reason"]))
    return ViewPlan(centre=np.array(obj["centre"], dtype=float), radius=obj["radius"],
                    rings=[Ring(**r) for r in obj["rings"]], views=views)
