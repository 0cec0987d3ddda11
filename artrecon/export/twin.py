"""The twin: an articulated model prepared for export (metres, link frames, meshes, inertias,
joint limits), written by the format writers (:mod:`artrecon.export.mjcf`, ``urdf``, ``glb``,
``ply``).

Everything is in metres: model points are multiplied by ``ArticulatedModel.scale`` (metres per
model unit). A model whose scale is not known yet (``scale_known`` False, i.e. not registered) is
exported in model units as if they were metres, with a warning in the log and a comment in the
file; its masses and inertias then mean nothing.

The twin's base frame is the model frame (configuration A) in metres: after
``artrecon.register.apply_registration`` (or a reconstruction from known camera poses) that is
the robot's world frame already, so the default puts the twin where the object is. With
``ExportConfig.base_frame`` (e.g. ``"T_world_model"``, set by registration) the base is placed at
that pose of ``ArticulatedModel.frames``: a rigid 4x4 ``T_world_model`` with its translation in
metres, applied to the scaled points (p_world = R @ (scale * p_model) + t).

Each link gets a frame whose axes are the base frame's axes in configuration A. The root link's
frame *is* the base frame and is welded to the world (MJCF: a body without joint; URDF: a fixed
joint from a ``world`` link). A child link's frame sits on its joint: a revolute joint's axis point,
or, for a prismatic joint, whose line is free, the child's centroid. So a joint's origin in its
parent's frame is the difference of the two frame origins and its axis, in both frames, is the
estimated axis direction. Joint zero is configuration A (the model's points), and positive values
move toward configuration B (``Joint.axis_direction`` is oriented that way); the joint limits
cover [0, motion] plus a margin (see the constants below).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from artrecon.errors import InputError
from artrecon.export.mesh import (
    auto_voxel_size,
    check_points,
    collision_hulls,
    voxel_inertia,
    voxel_surface,
)
from artrecon.geometry import transform_points
from artrecon.model import ArticulatedModel

log = logging.getLogger(__name__)

__all__ = ["ExportConfig", "TwinLink", "TwinJoint", "Twin", "build_twin"]

#: Revolute limits extend beyond the observed motion [0, motion] by this fraction of |motion|...
LIMIT_MARGIN_FRACTION = 0.1
#: ...and by at least this angle (rad): the estimated state is off by a degree or two, and a twin
#: that cannot quite reach configuration B (or A) is useless to a planner. 5 degrees is several
#: times the joint-state error of the reconstruction while keeping the range tight.
REVOLUTE_MARGIN_MIN = np.deg2rad(5.0)
#: Prismatic limits: at least this fraction of the scene size (the link's own size scale) on
#: each side, for the same reason as above; translation errors scale with the scene.
PRISMATIC_MARGIN_MIN_FRACTION = 0.02

#: Default density (kg/m^3) of the links for masses and inertias: the mean of wood (600) and
#: hollow plastic (400), the materials of household articulated objects. The twin only needs
#: plausible, positive-definite inertias; the true density is not observable from images.
DEFAULT_DENSITY = 500.0

#: Most faces of a visual mesh. MuJoCo's STL reader refuses more than 200000; a link whose
#: surface needs more at the chosen voxel size gets a coarser voxel (with a warning).
MAX_VISUAL_FACES = 150_000

#: Collision hulls per link (k-means clusters); fewer when the link has few points.
COLLISION_CLUSTERS = 12

#: Link colours when the points have none (RGB, cycled).
PALETTE = np.array(
    [[31, 119, 180], [255, 127, 14], [44, 160, 44], [148, 103, 189], [140, 86, 75],
     [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]], dtype=np.uint8
)


@dataclass(frozen=True)
class ExportConfig:
    """Settings of the exports."""

    voxel_size: float | None = None
    """Edge of the voxels of the visual meshes and inertias, metres; None: per link from the
    point spacing (artrecon.export.mesh.VOXEL_SPACING_FACTOR)."""
    density: float = DEFAULT_DENSITY
    """Uniform density of the links, kg/m^3."""
    collision_clusters: int = COLLISION_CLUSTERS
    """Convex hulls per link for collision (at most)."""
    base_frame: str | None = None
    """Name of a pose in ArticulatedModel.frames (e.g. "T_world_model") where the base is
    placed; None: the model frame is the world frame."""
    glb_geometry: str = "points"
    """GLB content per link: "points" (coloured points) or "mesh" (visual mesh, vertex colours)."""
    seed: int = 0
    """Seed of the k-means clustering."""

    def __post_init__(self) -> None:
        if self.voxel_size is not None and not self.voxel_size > 0:
            raise ValueError(f"voxel_size must be > 0 metres or None, got {self.voxel_size}")
        if not self.density > 0:
            raise ValueError(f"density must be > 0 kg/m^3, got {self.density}")
        if self.collision_clusters < 1:
            raise ValueError(f"collision_clusters must be >= 1, got {self.collision_clusters}")
        if self.glb_geometry not in ("points", "mesh"):
            raise ValueError(f"glb_geometry must be 'points' or 'mesh', got {self.glb_geometry!r}")


@dataclass
class TwinLink:
    """One link of the twin, in its own frame (metres).

    Attributes
    ----------
    name : str
        Sanitised unique name (XML and file names).
    index : int
        Index of the link in the model.
    origin : (3,) float
        Origin of the link frame in the base frame (configuration A; axes are the base's).
    points : (n, 3) float
        The link's points in the link frame.
    colours : (n, 3) uint8 or None
    normals : (n, 3) float or None
        In the link (= base) axes.
    rgba : (4,) float
        Mean colour in [0, 1].
    visual : trimesh.Trimesh
        Visual mesh, link frame.
    collision : list of trimesh.Trimesh
        Convex hulls, link frame.
    mass : float
        kg.
    com : (3,) float
        Centre of mass, link frame.
    inertia : (3, 3) float
        Inertia tensor about the centre of mass, link axes, kg m^2.
    voxel_size : float
        Metres.
    """

    name: str
    index: int
    origin: np.ndarray
    points: np.ndarray
    colours: np.ndarray | None
    normals: np.ndarray | None
    rgba: np.ndarray
    visual: trimesh.Trimesh
    collision: list[trimesh.Trimesh]
    mass: float
    com: np.ndarray
    inertia: np.ndarray
    voxel_size: float


@dataclass
class TwinJoint:
    """One joint of the twin.

    Attributes
    ----------
    name : str
    type : str
        "revolute" or "prismatic".
    parent, child : int
        Indices into Twin.links.
    axis : (3,) float
        Unit axis in the parent's (= the child's) frame axes.
    origin_in_parent : (3,) float
        Child frame origin in the parent frame (metres).
    motion : float
        Joint value of configuration B (rad or metres); configuration A is 0.
    lower, upper : float
        Limits (rad or metres).
    """

    name: str
    type: str
    parent: int
    child: int
    axis: np.ndarray
    origin_in_parent: np.ndarray
    motion: float
    lower: float
    upper: float


@dataclass
class Twin:
    """The model prepared for export: metres, link frames, meshes, inertias, limits.

    Attributes
    ----------
    name : str
    links : list of TwinLink
        In the model's link order.
    joints : list of TwinJoint
        Parents before children (breadth-first from the root).
    root : int
    T_world_base : (4, 4) float
        Where the base (root link frame) is welded to the world.
    metric : bool
        False when the model's scale was not known (units are model units).
    """

    name: str
    links: list[TwinLink]
    joints: list[TwinJoint]
    root: int
    T_world_base: np.ndarray = field(default_factory=lambda: np.eye(4))
    metric: bool = True

    def joint_of(self, link: int) -> TwinJoint | None:
        for j in self.joints:
            if j.child == link:
                return j
        return None

    def children_of(self, link: int) -> list[TwinJoint]:
        return [j for j in self.joints if j.parent == link]

    def points_in_base(self, link: int) -> np.ndarray:
        """(n, 3) float: the link's points in the base frame at configuration A (metres)."""
        lk = self.links[link]
        return lk.points + lk.origin

    def points_in_world(self, link: int) -> np.ndarray:
        """(n, 3) float: the link's points in the world frame at configuration A (metres)."""
        return transform_points(self.T_world_base, self.points_in_base(link))


def _sanitise(name: str, fallback: str, taken: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9_\-]", "_", name) or fallback
    if base[0].isdigit() or base[0] == "-":
        base = f"_{base}"
    out, k = base, 1
    while out in taken:
        out, k = f"{base}_{k}", k + 1
    taken.add(out)
    return out


def _tree_order(model: ArticulatedModel) -> list[int]:
    """Joint indices, parents before children; checks that the joints form a tree at root."""
    n = len(model.links)
    if n == 0:
        raise InputError("the model has no links; nothing to export")
    child_of = {}
    for i, j in enumerate(model.joints):
        if j.child == model.root:
            raise InputError(f"joint {j.name!r} has the root link {model.root} as its child; "
                             "the root must be welded to the world. Rebuild the model.")
        if j.child in child_of:
            other = model.joints[child_of[j.child]].name
            raise InputError(f"link {j.child} is the child of two joints ({other!r}, {j.name!r});"
                             " a kinematic tree gives each link one parent joint")
        child_of[j.child] = i
    order, frontier, seen = [], [model.root], {model.root}
    while frontier:
        nxt = []
        for p in frontier:
            for i, j in enumerate(model.joints):
                if j.parent == p and j.child not in seen:
                    seen.add(j.child)
                    order.append(i)
                    nxt.append(j.child)
        frontier = nxt
    if len(seen) != n:
        missing = sorted(set(range(n)) - seen)
        raise InputError(f"links {missing} are not connected to the root link {model.root} by "
                         "joints; export needs one kinematic tree (drop or re-attach them)")
    return order


def _base_pose(model: ArticulatedModel, base_frame: str | None) -> np.ndarray:
    if base_frame is None:
        return np.eye(4)
    if base_frame not in model.frames:
        raise InputError(f"the model has no frame {base_frame!r} (it has {sorted(model.frames)}); "
                         "register the model first or export without a base frame")
    T = np.array(model.frames[base_frame], dtype=float)
    R = T[:3, :3]
    if (np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0
            or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-12):
        raise InputError(f"frame {base_frame!r} is not a rigid pose (rotation not orthonormal or "
                         "bottom row not 0 0 0 1); its scale belongs in ArticulatedModel.scale")
    return T


def _limits(kind: str, motion: float, size: float) -> tuple[float, float]:
    lo, hi = min(0.0, motion), max(0.0, motion)
    if kind == "revolute":
        margin = max(LIMIT_MARGIN_FRACTION * abs(motion), REVOLUTE_MARGIN_MIN)
    else:
        margin = max(LIMIT_MARGIN_FRACTION * abs(motion), PRISMATIC_MARGIN_MIN_FRACTION * size)
    return lo - margin, hi + margin


def build_twin(model: ArticulatedModel, config: ExportConfig | None = None,
               name: str = "artrecon_twin") -> Twin:
    """Prepare a model for export: metres, link frames, meshes, inertias and joint limits.

    Parameters
    ----------
    model : ArticulatedModel
    config : ExportConfig, optional
    name : str
        Model name written into the files.

    Returns
    -------
    Twin

    Raises
    ------
    InputError
        No links, an empty link, joints that do not form a tree at the root, an unknown or
        non-rigid base frame, a non-positive scale.
    """
    config = config or ExportConfig()
    order = _tree_order(model)
    if not (np.isfinite(model.scale) and model.scale > 0):
        raise InputError(f"model scale must be a positive number of metres per unit, got "
                         f"{model.scale}")
    if not model.scale_known:
        log.warning("the model's scale is not known (not registered): exporting model units as "
                    "metres; sizes, masses and inertias are not physical")
    s = float(model.scale)
    pts_base = []
    for k, lk in enumerate(model.links):
        if len(lk) == 0:
            raise InputError(f"link {k} ({lk.name!r}) has no points; cannot build its geometry")
        pts_base.append(check_points(f"link {k} points", lk.points) * s)
    all_pts = np.concatenate(pts_base)
    size = float(np.median(np.linalg.norm(all_pts - np.median(all_pts, axis=0), axis=1)))
    if not size > 0:
        size = float(np.max(np.ptp(all_pts, axis=0))) or 1.0

    origins = [np.zeros(3) for _ in model.links]
    for i in order:
        j = model.joints[i]
        if j.type == "revolute":
            origins[j.child] = j.axis_point * s
        else:
            origins[j.child] = pts_base[j.child].mean(axis=0)

    taken: set[str] = {"world"}
    links = []
    for k, lk in enumerate(model.links):
        pts = pts_base[k] - origins[k]
        h = config.voxel_size if config.voxel_size is not None else auto_voxel_size(pts)
        visual, occ, grid_origin = voxel_surface(pts, h)
        while len(visual.faces) > MAX_VISUAL_FACES:
            # faces grow as 1/h^2: coarsen just enough (plus 5%) and try again
            h_new = h * 1.05 * np.sqrt(len(visual.faces) / MAX_VISUAL_FACES)
            log.warning("link %r: %d faces at voxel %.4g m exceed %d (MuJoCo's mesh limit); "
                        "using voxel %.4g m", lk.name, len(visual.faces), h, MAX_VISUAL_FACES,
                        h_new)
            h = h_new
            visual, occ, grid_origin = voxel_surface(pts, h)
        mass, com, inertia = voxel_inertia(occ, grid_origin, h, config.density)
        hulls = collision_hulls(pts, config.collision_clusters, h, seed=config.seed + k)
        if lk.colours is not None:
            rgb = lk.colours.astype(float).mean(axis=0) / 255.0
            tree = cKDTree(pts)
            _, nearest = tree.query(visual.vertices)
            visual.visual.vertex_colors = np.column_stack(
                [lk.colours[nearest], np.full(len(nearest), 255, np.uint8)])
        else:
            rgb = PALETTE[k % len(PALETTE)] / 255.0
            visual.visual.vertex_colors = np.append(PALETTE[k % len(PALETTE)], 255)
        links.append(TwinLink(
            name=_sanitise(lk.name, f"link_{k}", taken), index=k, origin=origins[k], points=pts,
            colours=lk.colours, normals=lk.normals, rgba=np.append(rgb, 1.0), visual=visual,
            collision=hulls, mass=mass, com=com, inertia=inertia, voxel_size=h))
        log.info("link %s: %d points, voxel %.4g m, %d visual faces, %d hulls, mass %.4g kg",
                 links[-1].name, len(pts), h, len(visual.faces), len(hulls), mass)

    joints = []
    for i in order:
        j = model.joints[i]
        motion = (j.state_b - j.state_a) * (s if j.type == "prismatic" else 1.0)
        lower, upper = _limits(j.type, motion, size)
        joints.append(TwinJoint(
            name=_sanitise(j.name, f"joint_{i}", taken), type=j.type, parent=j.parent,
            child=j.child, axis=j.axis_direction / np.linalg.norm(j.axis_direction),
            origin_in_parent=origins[j.child] - origins[j.parent], motion=motion,
            lower=lower, upper=upper))
    return Twin(name=_sanitise(name, "artrecon_twin", set()), links=links, joints=joints,
                root=model.root, T_world_base=_base_pose(model, config.base_frame),
                metric=bool(model.scale_known))
