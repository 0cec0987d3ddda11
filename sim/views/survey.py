"""Where the object is, from the robot's own photographs: the survey before a capture.

A capture's rings look at the object's bounding sphere, and their distance follows from its
radius. The robot is not told that sphere: it knows its cell (the stage's table top, where an
object is put down, and its own arm) and finds the object in it. From a few arm poses around the
table it photographs the table top, marks the pixels that differ from the photograph of the empty
cell taken from the same pose (the background plate, taken before the object was put down), and
carves the volume above the table by those silhouettes, at the camera poses of the arm's forward
kinematics: what is left is the object's visual hull, which holds the object. The hull's
bounding sphere is the sphere the capture plans with.

The simulator's part is only to make the photographs: the plate is the same scene rendered with
the object's geoms moved out of sight, as the empty table would have been photographed. No
decision reads the object's geometry: the survey's views are reached and checked in a
:class:`~sim.views.known.KnownCell` (the first pass's against the stage and the arm only, the
second's against the first pass's hull as well), and the survey's result holds the hull's convex
hull (:attr:`Survey.hull`), which the capture's rings keep their clearance from. A survey pose at
which the arm would touch the true object is reported (:class:`SurveyError`), not avoided.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import mujoco
import numpy as np

from sim import robot
from sim.camera import true_camera_pose
from sim.views.clearance import robot_bodies
from sim.views.known import KnownCell, hull_vertices, object_contacts
from sim.views.records import View, ViewPlanConfig
from sim.views.rings import object_bodies, ring_distance
from sim.views.solve import solve_views

log = logging.getLogger(__name__)

#: The geom of the stage whose top face is the table the object stands on (scenes/stage.xml).
TABLE_GEOM = "table_top"


class SurveyError(RuntimeError):
    """The survey cannot say where the object is (no view reachable, no object seen, an object
    larger than the views take in)."""


@dataclass(frozen=True)
class SurveyConfig:
    """The survey's views and the carving; every field is part of the view plan's cache key."""

    elevations_deg: tuple[float, ...] = (35.0, 65.0)
    """elevations of the survey's views above the table's aim point"""
    views_per_elevation: int = 6
    """views at each elevation, evenly spread in azimuth"""
    distances: tuple[float, ...] = (0.75, 0.7, 0.65, 0.6, 0.55, 0.5)
    """camera distances to the aim point tried in order at each view (the farthest reachable
    takes in the most of the table)"""
    aim_height: float = 0.12
    """height of the aim point above the table top's centre (m)"""
    height: float = 0.6
    """height of the carved volume above the table top (m): the tallest object the survey finds"""
    reach: float = 0.1
    """how far beyond the table top's rim the carved volume reaches (m): an object may overhang"""
    voxel: float = 0.003
    """edge of the carving's voxels (m)"""
    coarse_voxel: float = 0.009
    """edge of the first pass's voxels (m): it only finds the box the second pass carves"""
    threshold: int = 10
    """a pixel is the object's where a colour channel differs from the plate by more (of 255)"""
    dilate_px: int = 1
    """silhouettes are widened by this many pixels before carving (the hull must hold the object:
    a pixel's worth of antialiasing must not carve it)"""
    min_views: int = 3
    """a voxel is kept only if at least this many views see it (inside their image) and every
    view that sees it sees the object there"""
    min_pixels: int = 30
    """an object's silhouette has at least this many pixels in a view (of the survey's images:
    see ``image_scale``)"""
    image_scale: float = 1.0
    """the survey photographs at this fraction of the camera's image size (its intrinsics
    scaled alike). Measured at 0.5, not adopted: the plan's CPU per configuration 5.5-9.7 ->
    2.4-6.5 s on the bench and the ten scenes passed at seed 0 (median 67.4 -> 58.3 s with the
    other changes of 2fdffd3), but the new view plans moved every scene's images and two runs
    off the gates' margins: the imported chest's lid needed the planner's 55th grasp candidate
    (``sim.manipulate.PlanningConfig.max_candidates``), and scissors at seed 1 fell to
    segmentation 0.966 (0.975 at full size; gate 0.97)"""
    frame_elevations_deg: tuple[float, ...] = (12.0, 45.0, 75.0)
    """elevations of the second pass's views, which frame the first pass's hull"""
    frame_fill: float = 0.85
    """share of the shorter image side the first hull's sphere fills in the second pass"""
    frame_distance_step: float = 0.05
    """the second pass steps closer by this much (m) where the arm cannot reach a view"""
    frame_min_distance: float = 0.35
    """the closest the second pass tries (m)"""


@dataclass(frozen=True)
class Survey:
    """What the survey found."""

    centre: np.ndarray
    """(3,) centre of the visual hull's bounding box (world, m)"""
    radius: float
    """distance from ``centre`` to the farthest kept voxel's centre (m)"""
    lower: np.ndarray
    """(3,) lower corner of the hull's bounding box (world, m)"""
    upper: np.ndarray
    """(3,) upper corner"""
    voxels: int
    """voxels in the hull"""
    views: int
    """views photographed"""
    q: list = field(default_factory=list)
    """the arm's joint angles at each view"""
    hull: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    """(k, 3) vertices of the convex hull of the visual hull's voxels (world, m): the object as
    the robot knows it when it plans (:class:`~sim.views.known.KnownCell`)"""

    def to_json(self) -> dict:
        return {"centre": [float(x) for x in self.centre], "radius": float(self.radius),
                "lower": [float(x) for x in self.lower], "upper": [float(x) for x in self.upper],
                "voxels": int(self.voxels), "views": int(self.views),
                "hull_vertices": np.round(self.hull, 6).tolist(),
                "method": "visual hull of the survey's silhouettes against the empty cell"}


def table_top(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, float]:
    """Centre of the table's top face (world, m) and its radius: the stage's geom
    :data:`TABLE_GEOM`, a vertical cylinder."""
    g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, TABLE_GEOM)
    if g < 0 or int(model.geom_type[g]) != int(mujoco.mjtGeom.mjGEOM_CYLINDER):
        raise SurveyError(f"the scene has no cylinder geom {TABLE_GEOM!r}: the survey looks for "
                          "the object on the stage's table (include scenes/stage.xml or "
                          "stage_panda.xml)")
    radius, half = (float(x) for x in model.geom_size[g, :2])
    axis = data.geom_xmat[g].reshape(3, 3)[:, 2]
    return data.geom_xpos[g] + half * axis, radius


def scaled_camera(K: np.ndarray, width: int, height: int,
                  scale: float) -> tuple[np.ndarray, int, int]:
    """The intrinsics and size of the camera's images resized by ``scale`` (OpenCV intrinsics,
    pixel centres at integer coordinates: a pixel edge at -0.5 stays at the image's edge)."""
    if scale == 1.0:
        return K, int(width), int(height)
    if not 0.0 < scale <= 1.0:
        raise ValueError(f"SurveyConfig.image_scale: expected a fraction in (0, 1], got {scale}")
    S = K.copy()
    S[0, 0], S[1, 1] = K[0, 0] * scale, K[1, 1] * scale
    S[0, 2], S[1, 2] = (K[0, 2] + 0.5) * scale - 0.5, (K[1, 2] + 0.5) * scale - 0.5
    return S, max(1, round(width * scale)), max(1, round(height * scale))


def _silhouette(color: np.ndarray, plate: np.ndarray, own: np.ndarray,
                config: SurveyConfig) -> np.ndarray:
    """Pixels where the photograph differs from the empty cell's, closed and widened, and the
    pixels ``own`` of the robot's body (they carve nothing)."""
    diff = np.abs(color.astype(np.int16) - plate.astype(np.int16)).max(axis=2)
    mask = (diff > config.threshold).astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    if config.dilate_px > 0:
        k = 2 * config.dilate_px + 1
        mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
        own = cv2.dilate(own.astype(np.uint8),
                         cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))).astype(bool)
    return mask.astype(bool) | own


def _carve(masks, cameras, K, width, height, lower, upper, config: SurveyConfig,
           column=None, voxel: float | None = None):
    """Voxel centres (n, 3) of the visual hull within the box ``lower``-``upper`` (and, with
    ``column`` = (centre xy, radius), within that vertical cylinder)."""
    v = config.voxel if voxel is None else voxel
    xs, ys, zs = (np.arange(lo + v / 2, hi, v) for lo, hi in zip(lower, upper, strict=True))
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    inside = np.ones(X.shape, dtype=bool)
    if column is not None:
        inside = (X - column[0][0]) ** 2 + (Y - column[0][1]) ** 2 <= column[1] ** 2
    columns = np.c_[X[inside], Y[inside]]
    projections = []
    for T in cameras:
        Tcw = np.linalg.inv(T)
        projections.append((K @ Tcw[:3, :3], K @ Tcw[:3, 3]))
    kept = []
    for z in zs:  # slab by slab: a few hundred thousand points at a time
        P = np.c_[columns, np.full(len(columns), z)]
        seen = np.zeros(len(P), dtype=np.int32)
        # the points no view has carved yet, in order: a carved point stays carved, so the
        # later views project only these (cabinet B's fine pass keeps 41% of its 2.7 M voxels,
        # and still went 2.35 -> 1.85 s)
        alive = np.arange(len(P))
        for mask, (A, b) in zip(masks, projections, strict=True):
            h = P[alive] @ A.T + b
            front = h[:, 2] > 1e-6
            zz = np.where(front, h[:, 2], 1.0)
            u = np.where(front, np.round(h[:, 0] / zz), -1).astype(np.int64)
            w = np.where(front, np.round(h[:, 1] / zz), -1).astype(np.int64)
            inimg = front & (u >= 0) & (u < width) & (w >= 0) & (w < height)
            seen[alive] += inimg
            carved = np.zeros(len(alive), dtype=bool)
            carved[inimg] = ~mask[w[inimg], u[inimg]]
            alive = alive[~carved]
            if len(alive) == 0:
                break
        keep = alive[seen[alive] >= config.min_views]
        if len(keep):
            kept.append(P[keep])
    return np.concatenate(kept) if kept else np.empty((0, 3))


def _border_touched(masks) -> list[int]:
    """Views whose silhouette reaches the image's border (the object may go on beyond it)."""
    return [i for i, m in enumerate(masks)
            if m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any()]


def _reach_views(model, data, kin, aim, elevations_deg, n, distances, plan_config,
                 first_index: int, q_start) -> list[View]:
    """Views looking at ``aim``, ``n`` per elevation, each at the first of ``distances`` the arm
    reaches without a collision; the unreachable ones are left out."""
    solved: list[View] = []
    q_prev = q_start
    for k, el_deg in enumerate(elevations_deg):
        el = np.deg2rad(el_deg)
        for j in range(n):
            az = 2.0 * np.pi * (j + 0.5 * (k % 2)) / n
            for d in distances:
                eye = aim + d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                          np.sin(el)])
                view = View(first_index + len(solved), k, az, el, float(d),
                            robot.look_at_pose(eye, aim))
                solve_views(model, data, kin, [view], seed=plan_config.seed, q_start=q_prev,
                            restarts=plan_config.probe_ik_restarts, config=plan_config)
                if view.reachable:
                    solved.append(view)
                    q_prev = view.q
                    break
    return solved


class _Camera:
    """The wrist camera photographing the scene and the empty cell from the arm's poses."""

    def __init__(self, model, data, kin, K, width, height):
        from sim.render import MjRenderer  # the OpenGL context only when surveying

        self.model, self.data, self.kin = model, data, kin
        self.K, self.width, self.height = K, width, height
        self.cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA,
                                        kin.spec.prefix + kin.spec.camera)
        self.qidx = robot.qpos_indices(model, kin)
        self.renderer = MjRenderer(model)
        hidden = set(object_bodies(model))
        self.object_geoms = [g for g in self.renderer.geom_nodes
                             if int(model.geom_bodyid[g]) in hidden]
        own = robot_bodies(model, kin)
        self.robot_geoms = [g for g in self.renderer.geom_nodes
                            if int(model.geom_bodyid[g]) in own]

    def photograph(self, q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The photograph at joint angles ``q``, the empty cell's from the same pose, and the
        pixels the robot's own body covers there (the robot knows its body: a pixel it covers
        says nothing of the object behind it)."""
        model, data, r = self.model, self.data, self.renderer
        data.qpos[self.qidx] = q
        mujoco.mj_forward(model, data)
        T = true_camera_pose(data, self.cam_id)
        color = r.render(data, self.K, T, self.width, self.height).color
        far = np.eye(4)
        far[:3, 3] = [0.0, 0.0, -1.0e3]
        for g in self.object_geoms:  # the empty cell: the object out of sight
            r.scene.set_pose(r.geom_nodes[g], far)
        plate = r.render(None, self.K, T, self.width, self.height).color
        for g in self.robot_geoms:  # and the robot too: where it shows in the plate
            r.scene.set_pose(r.geom_nodes[g], far)
        bare = r.render(None, self.K, T, self.width, self.height).color
        return color, plate, np.any(plate != bare, axis=2)


def survey_object(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                  K: np.ndarray, width: int, height: int,
                  plan_config: ViewPlanConfig = ViewPlanConfig(),
                  config: SurveyConfig = SurveyConfig(), *, cell: KnownCell) -> Survey:
    """Photograph the object from the survey's views and carve its visual hull.

    Two passes. The first looks at :attr:`SurveyConfig.aim_height` above the table top's centre
    from :attr:`SurveyConfig.elevations_deg`, each view at the farthest of
    :attr:`SurveyConfig.distances` the arm reaches, and carves the volume above the table: a
    first hull, loose where no view took in the whole object. The second looks at that hull's
    centre from :attr:`SurveyConfig.frame_elevations_deg` (a low one bounds the height), at the
    distance where the first hull's sphere fills :attr:`SurveyConfig.frame_fill` of the image or
    the farthest the arm reaches short of it, and both passes' silhouettes carve the first hull's
    box again. IK and clearance are ``plan_config``'s (its seed and probe restarts), checked in
    ``cell`` (the scene as the robot knows it, :class:`~sim.views.known.KnownCell`: without the
    object for the first pass, with the first pass's hull for the second); unreachable views
    are skipped. ``model`` and ``data`` (the simulated world) only take the photographs, and
    say whether a chosen pose touches the object (a :class:`SurveyError`). The arm's joints in
    ``data`` are restored.

    Raises
    ------
    SurveyError
        Fewer than :attr:`SurveyConfig.min_views` views reachable, no object in the
        photographs, a hull that reaches the edge of the carved volume, or a survey pose at
        which the arm touches the object.
    """
    K, width, height = scaled_camera(np.asarray(K, dtype=float), width, height,
                                     config.image_scale)
    top, table_radius = table_top(model, data)
    saved = data.qpos.copy()
    masks, cameras = [], []
    cell = cell.at(saved)
    try:
        camera = _Camera(model, data, kin, K, width, height)

        def photograph(views_):
            for view in views_:
                hits = object_contacts(model, data, kin, view.q)
                if hits:
                    raise SurveyError(
                        f"at survey view {view.index} the arm touches the object "
                        f"({', '.join(hits[:3])}): the object reaches where the survey's views "
                        "pass, beyond what the robot knew of it when it chose them (nothing "
                        "for the first pass, the first pass's hull for the second); put it "
                        "nearer the table's centre")
                color, plate, own = camera.photograph(view.q)
                masks.append(_silhouette(color, plate, own, config))
                cameras.append(kin.camera_pose(view.q))  # what the robot knows of the pose

        aim = top + np.array([0.0, 0.0, config.aim_height])
        first = _reach_views(cell.model, cell.data, kin, aim, config.elevations_deg,
                             config.views_per_elevation, config.distances, plan_config, 0,
                             None)
        if len(first) < config.min_views:
            raise SurveyError(
                f"only {len(first)} of the survey's "
                f"{len(config.elevations_deg) * config.views_per_elevation} views of the table "
                "are reachable: the arm cannot look for the object")
        photograph(first)
        n_seen = sum(int(m.sum()) >= config.min_pixels for m in masks)
        if n_seen < config.min_views:
            raise SurveyError(f"the object shows in {n_seen} of the survey's {len(masks)} "
                              "views only: is there an object on the table?")
        r_vol = table_radius + config.reach
        lower = np.r_[top[:2] - r_vol, top[2]]
        upper = np.r_[top[:2] + r_vol, top[2] + config.height]
        pts = _carve(masks, cameras, K, width, height, lower, upper, config,
                     column=(top[:2], r_vol), voxel=config.coarse_voxel)
        if len(pts) == 0:
            raise SurveyError("the survey's silhouettes do not agree on any point above the "
                              "table: the object could not be located")
        centre1, radius1 = _sphere(pts, config.coarse_voxel)
        d_frame = ring_distance(radius1, K, width, height, config.frame_fill,
                                plan_config.min_ring_distance)
        distances = [d for d in np.arange(d_frame, config.frame_min_distance - 1e-9,
                                          -config.frame_distance_step)]
        framing = cell.with_hull(hull_vertices(pts, config.coarse_voxel)).at(saved)
        second = _reach_views(framing.model, framing.data, kin, centre1,
                              config.frame_elevations_deg,
                              config.views_per_elevation, distances or [d_frame], plan_config,
                              len(first), first[-1].q)
        photograph(second)
        # the coarse hull's box, a coarse voxel wider on every side (a part thinner than a coarse
        # voxel may have slipped between its centres)
        lo1 = pts.min(axis=0) - 1.5 * config.coarse_voxel
        hi1 = pts.max(axis=0) + 1.5 * config.coarse_voxel
        pts = _carve(masks, cameras, K, width, height, np.maximum(lo1, lower),
                     np.minimum(hi1, upper), config, column=(top[:2], r_vol))
    finally:
        data.qpos[:] = saved
        mujoco.mj_forward(model, data)
    if len(pts) == 0:
        raise SurveyError("the survey's second pass carved the object's hull away: its "
                          "silhouettes disagree")
    half = config.voxel / 2
    lower_h, upper_h = pts.min(axis=0) - half, pts.max(axis=0) + half
    rim = np.hypot(*(pts[:, :2] - top[:2]).T).max() + half
    if rim >= r_vol - config.voxel or upper_h[2] >= top[2] + config.height - config.voxel:
        raise SurveyError(f"the object's hull reaches the edge of the surveyed volume (radius "
                          f"{r_vol:.2f} m, height {config.height:.2f} m above the table): the "
                          "object is larger than the survey takes in")
    touched = _border_touched(masks[len(first):])
    if touched:
        log.info("survey: the object reaches the image border in %d of the framing views",
                 len(touched))
    # to the voxels' centres: the silhouettes were widened (dilate_px) to keep the hull a hull,
    # and a voxel whose centre is in the hull holds the object's edge within half a voxel
    centre, radius = _sphere(pts, config.voxel, corner=0.0)
    log.info("survey: %d + %d views, hull of %d voxels, centre %s, radius %.3f m", len(first),
             len(second), len(pts), np.round(centre, 3), radius)
    return Survey(centre=centre, radius=radius, lower=lower_h, upper=upper_h, voxels=len(pts),
                  views=len(masks), q=[v.q.copy() for v in (*first, *second)],
                  hull=hull_vertices(pts, config.voxel))


def _sphere(pts: np.ndarray, voxel: float, corner: float = 1.0) -> tuple[np.ndarray, float]:
    """Centre of the voxels' bounding box and the distance from it to the farthest voxel
    corner (``corner`` 1; 0: the farthest voxel centre)."""
    half = voxel / 2
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    far = np.abs(pts - centre) + half * corner  # the farthest corner of each voxel (or its centre)
    return centre, float(np.sqrt((far ** 2).sum(axis=1).max()))
