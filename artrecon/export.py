"""The recovered model as a digital twin: MJCF, URDF, GLB and PLY per link.

Frames and units
----------------
Everything is written in metres: model points are multiplied by ``ArticulatedModel.scale``
(metres per model unit). A model whose scale is not known yet (``scale_known`` False, i.e. not
registered) is exported in model units as if they were metres, with a warning in the log and a
comment in the file; its masses and inertias then mean nothing.

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

Meshes (why these and not Poisson or ball pivoting)
---------------------------------------------------
Dense SfM points are noisy, unevenly dense and have holes where no camera looked, and the project
uses scipy and trimesh only (no Open3D, no scikit-image), so each link's meshes are built in two
ways that cannot fail on such input:

- visual: the boundary of the link's voxel occupancy ("cuberille"). Voxels holding a point are
  occupied; a morphological closing bridges gaps up to one voxel, enclosed cavities are filled,
  voxels touching only along an edge are joined (so every edge has exactly two faces), and the
  boundary faces of the occupied voxels are a closed, consistently oriented surface whatever the
  holes of the input: the boundary of a union of cubes. Taubin smoothing then removes the
  staircase without shrinking. The surface stays within about one voxel of the points; a hole
  wider than two voxels stays a hole (as the data says), and thin parts down to one voxel (the
  8 mm pliers at the default voxel size of a few mm) survive, unlike a convex hull. Masses and
  inertias come from the same occupancy (a union of cubes has an exact inertia), with a uniform
  density.
- collision: MuJoCo collides with the convex hull of a mesh geom, so each link gets the convex
  hulls of k-means clusters of its points (a convex decomposition by clustering): a pair of
  pliers is a chain of hulls along its length instead of one hull that fills the gap between
  the jaws. Flat clusters are thickened to one voxel so that every hull has a volume. Every
  point of the link lies inside the union of its hulls.

Writes are whole or not at all: every file is first written to a temporary file beside its final
path; only when all files are written are they renamed into place (meshes first, the MJCF/URDF
file last, so a model file never names a missing mesh).
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import trimesh
from scipy import ndimage
from scipy.cluster.vq import kmeans2
from scipy.spatial import ConvexHull, cKDTree
from scipy.spatial.transform import Rotation

from artrecon.errors import ArtreconError, InputError
from artrecon.io import umask
from artrecon.model import ArticulatedModel

log = logging.getLogger(__name__)

__all__ = [
    "FORMATS",
    "ExportConfig",
    "TwinLink",
    "TwinJoint",
    "Twin",
    "build_twin",
    "voxel_surface",
    "collision_hulls",
    "voxel_inertia",
    "export_model",
    "export_mjcf",
    "export_urdf",
    "export_glb",
    "export_ply",
    "add_export_parser",
    "export_main",
]

FORMATS = ("mjcf", "urdf", "glb", "ply")

# --- Constants (every number of the export, with why) -----------------------------------------

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

#: The automatic voxel size is this many times the median nearest-neighbour spacing of the
#: link's points: 2 lets a one-voxel closing bridge gaps of up to about 4 point spacings
#: (dense-stereo holes) while keeping thin parts.
VOXEL_SPACING_FACTOR = 2.0
#: ...but never finer than the link's largest extent / this, bounding the grid (and the mesh) to
#: at most this many voxels per axis (memory and time of the morphology, faces of the mesh).
MAX_VOXELS_PER_AXIS = 160

#: Iterations of the morphological closing (3x3x3) of the occupancy: it fills every hole of a
#: sampled surface narrower than about 2 x this many voxels, so that enclosed volumes are closed
#: and get filled, at the price of rounding inner corners at that scale. 2 closes the gaps of
#: a surface sampled at the spacing the voxel size is derived from (random sampling leaves
#: empty 3 x 3 voxel patches, which one iteration cannot close).
CLOSING_ITERATIONS = 2

#: Most faces of a visual mesh. MuJoCo's STL reader refuses more than 200000; a link whose
#: surface needs more at the chosen voxel size gets a coarser voxel (with a warning).
MAX_VISUAL_FACES = 150_000

#: Taubin smoothing of the voxel surface: iterations and its two factors (lamb > 0 smooths,
#: nu slightly larger undoes the shrinking); 10 removes the one-voxel staircase, little more.
SMOOTHING_ITERATIONS = 10
SMOOTHING_LAMBDA = 0.5
SMOOTHING_NU = 0.53

#: After smoothing, each surface vertex moves inward until it is this many voxels outside its
#: nearest point along its normal: the surface hugs the points (a quarter voxel: 0.5 mm at 2 mm
#: voxels) yet keeps them inside despite their noise along the surface.
SHRINK_MARGIN = 0.25

#: Collision hulls per link (k-means clusters); fewer when the link has few points.
COLLISION_CLUSTERS = 12
#: A cluster needs at least this many points (a hull of fewer is noise-dominated).
MIN_CLUSTER_POINTS = 16

#: URDF needs effort (N or N m) and velocity (rad/s or m/s) on every limit; the twin cannot know
#: its actuators, so generous placeholders that never bind in a kinematic use.
URDF_EFFORT = 100.0
URDF_VELOCITY = 10.0

#: Colours of the GLB: estimated axes red (RGBA).
AXIS_RGBA = (230, 25, 25, 255)
#: Axis cylinder radius, as a fraction of the scene size.
AXIS_RADIUS_FRACTION = 0.006

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
    point spacing (VOXEL_SPACING_FACTOR)."""
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
        return _apply(self.T_world_base, self.points_in_base(link))


# --- Geometry ---------------------------------------------------------------------------------


def _apply(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ T[:3, :3].T + T[:3, 3]


def _check_points(name: str, points) -> np.ndarray:
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise InputError(f"{name} holds non-finite coordinates; drop them before exporting")
    return points


def auto_voxel_size(points: np.ndarray) -> float:
    """Voxel edge for a link: VOXEL_SPACING_FACTOR x the median nearest-neighbour spacing, no
    finer than the largest extent / MAX_VOXELS_PER_AXIS.

    Parameters
    ----------
    points : (n, 3) float

    Returns
    -------
    voxel_size : float
        In the units of `points`; > 0.
    """
    points = _check_points("points", points)
    extent = float(np.max(np.ptp(points, axis=0))) if len(points) else 0.0
    spacing = 0.0
    if len(points) >= 2:
        d, _ = cKDTree(points).query(points, k=2)
        spacing = float(np.median(d[:, 1]))
    h = max(VOXEL_SPACING_FACTOR * spacing, extent / MAX_VOXELS_PER_AXIS)
    if not h > 0:
        raise InputError(
            f"cannot size voxels for {len(points)} points that all coincide; a link needs points "
            "that span its surface"
        )
    return h


def _occupancy(points: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed, filled, edge-manifold occupancy grid of the points and the grid origin."""
    pad = CLOSING_ITERATIONS + 2  # room for the closing, an empty border, the edge fix
    # centre the points in the grid: (ceil(e/h) + 1) cells leave a slack in [h, 2h) per axis, so
    # the outermost points lie at least h/2 inside their voxels' boundary (not on the surface)
    lo_pts, extent = points.min(axis=0), np.ptp(points, axis=0)
    slack = (np.ceil(extent / h) + 1) * h - extent
    lo = lo_pts - 0.5 * slack - pad * h
    idx = np.floor((points - lo) / h).astype(np.int64)
    shape = idx.max(axis=0) + pad + 1
    occ = np.zeros(shape, dtype=bool)
    occ[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    occ = ndimage.binary_closing(occ, structure=np.ones((3, 3, 3), bool),
                                 iterations=CLOSING_ITERATIONS)
    occ = ndimage.binary_fill_holes(occ)
    _join_edge_contacts(occ)
    return occ, lo


def _join_edge_contacts(occ: np.ndarray) -> None:
    """Add voxels (in place) until no two voxels share only an edge: each edge of the boundary
    surface then has exactly two faces (MuJoCo and trimesh reject other meshes)."""
    for _ in range(1000):
        changed = False
        for axis in range(3):
            o = np.moveaxis(occ, axis, 0)  # a view: edges along axis 0; (1, 2) is the plane
            a, b = o[:, :-1, :-1], o[:, 1:, 1:]
            c, d = o[:, 1:, :-1], o[:, :-1, 1:]
            diag = a & b & ~c & ~d
            anti = c & d & ~a & ~b
            if diag.any():
                o[:, 1:, :-1] |= diag  # fill c
                changed = True
            if anti.any():
                o[:, :-1, :-1] |= anti  # fill a
                changed = True
        if not changed:
            return
    raise ArtreconError("voxel occupancy did not become edge-manifold in 1000 passes (a bug)")


def _boundary_faces(occ: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boundary quads of the occupied voxels as triangles on the corner lattice, oriented out."""
    nx, ny, nz = occ.shape
    corner_shape = np.array([nx + 1, ny + 1, nz + 1])
    tris = []
    eye = np.eye(3, dtype=np.int64)
    for axis in range(3):
        u, v = eye[(axis + 1) % 3], eye[(axis + 2) % 3]
        for direction in (1, -1):
            nb = np.roll(occ, -direction, axis=axis)  # the border is empty: no wrap-around hit
            vox = np.argwhere(occ & ~nb)
            c = vox.copy()
            if direction > 0:
                c[:, axis] += 1
            quad = np.stack([c, c + u, c + u + v, c + v], axis=1)  # normal u x v = +axis
            if direction < 0:
                quad = quad[:, ::-1]
            tris.append(quad[:, [0, 1, 2]])
            tris.append(quad[:, [0, 2, 3]])
    tri = np.concatenate(tris)  # (m, 3, 3) corner indices
    flat = np.ravel_multi_index(tri.reshape(-1, 3).T, corner_shape)
    uniq, inverse = np.unique(flat, return_inverse=True)
    corners = np.stack(np.unravel_index(uniq, corner_shape), axis=1).astype(float)
    return corners, inverse.reshape(-1, 3)


def voxel_surface(points: np.ndarray, voxel_size: float, smooth: bool = True):
    """Closed surface around points: boundary of their closed, filled voxel occupancy.

    Parameters
    ----------
    points : (n, 3) float
    voxel_size : float
        Voxel edge, units of `points`.
    smooth : bool
        Taubin-smooth the staircase (vertices stay within a voxel of the grid surface).

    Returns
    -------
    mesh : trimesh.Trimesh
        Watertight, consistently oriented (outward), every edge shared by two faces.
    occupancy : (nx, ny, nz) bool
    origin : (3,) float
        Corner of voxel (0, 0, 0); voxel (i, j, k) spans origin + [i, i+1] x h ...
    """
    points = _check_points("points", points)
    if len(points) == 0:
        raise InputError("voxel_surface needs at least one point, got none")
    if not voxel_size > 0:
        raise ValueError(f"voxel_size must be > 0, got {voxel_size}")
    occ, origin = _occupancy(points, voxel_size)
    corners, faces = _boundary_faces(occ)
    mesh = trimesh.Trimesh(origin + corners * voxel_size, faces, process=False)
    if smooth:
        trimesh.smoothing.filter_taubin(mesh, lamb=SMOOTHING_LAMBDA, nu=SMOOTHING_NU,
                                        iterations=SMOOTHING_ITERATIONS)
        # shrink-wrap: the voxel boundary lies about a voxel outside the points; move each vertex
        # inward along its normal to SHRINK_MARGIN voxels outside its nearest point (never more
        # than one voxel, never outward)
        _, nearest = cKDTree(points).query(mesh.vertices)
        normals = mesh.vertex_normals
        out = np.einsum("ij,ij->i", mesh.vertices - points[nearest], normals)
        step = np.clip(out - SHRINK_MARGIN * voxel_size, 0.0, voxel_size)
        mesh.vertices = mesh.vertices - step[:, None] * normals
    return mesh, occ, origin


def voxel_inertia(occupancy: np.ndarray, origin: np.ndarray, voxel_size: float,
                  density: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, centre of mass and inertia of a union of solid cubes (exact).

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool
    origin : (3,) float
    voxel_size : float
        Metres.
    density : float
        kg/m^3.

    Returns
    -------
    mass : float
    com : (3,) float
    inertia : (3, 3) float
        About the centre of mass, kg m^2; positive definite (each cube has h^2/6 m on its
        diagonal).
    """
    centres = origin + (np.argwhere(occupancy) + 0.5) * voxel_size
    if len(centres) == 0:
        raise InputError("voxel_inertia: the occupancy is empty")
    m_vox = density * voxel_size**3
    mass = m_vox * len(centres)
    com = centres.mean(axis=0)
    r = centres - com
    inertia = m_vox * (np.eye(3) * np.einsum("ij,ij->", r, r) - r.T @ r)
    inertia += np.eye(3) * mass * voxel_size**2 / 6.0
    return float(mass), com, 0.5 * (inertia + inertia.T)


def _thicken(points: np.ndarray, min_thickness: float) -> np.ndarray:
    """Add copies of the points offset +-min_thickness/2 along every principal direction in
    which the points are thinner than min_thickness (flat or linear clusters get a volume)."""
    centred = points - points.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    extra = [points]
    for axis in vt:
        proj = centred @ axis
        if np.ptp(proj) < min_thickness:
            half = 0.5 * (min_thickness - np.ptp(proj))  # hull thickness becomes min_thickness
            extra.append(points + half * axis)
            extra.append(points - half * axis)
    if len(vt) < 3:  # fewer than 3 points: pad every missing direction
        for axis in np.eye(3):
            extra.append(points + 0.5 * min_thickness * axis)
            extra.append(points - 0.5 * min_thickness * axis)
    return np.concatenate(extra)


def collision_hulls(points: np.ndarray, n_clusters: int, min_thickness: float,
                    seed: int = 0) -> list[trimesh.Trimesh]:
    """Convex hulls of k-means clusters of the points (collision geometry).

    Parameters
    ----------
    points : (n, 3) float
    n_clusters : int
        At most this many hulls (fewer if n / MIN_CLUSTER_POINTS is smaller).
    min_thickness : float
        Clusters thinner than this in some direction are thickened to it (units of `points`).
    seed : int

    Returns
    -------
    hulls : list of trimesh.Trimesh
        Closed convex meshes, outward faces; every input point is inside their union.
    """
    points = _check_points("points", points)
    if len(points) == 0:
        raise InputError("collision_hulls needs at least one point, got none")
    k = int(max(1, min(n_clusters, len(points) // MIN_CLUSTER_POINTS)))
    if k > 1:
        _, labels = kmeans2(points, k, minit="++", seed=np.random.default_rng(seed))
    else:
        labels = np.zeros(len(points), dtype=int)
    hulls = []
    for c in np.unique(labels):
        pts = _thicken(points[labels == c], min_thickness)
        hull = ConvexHull(pts)
        used, faces = np.unique(hull.simplices, return_inverse=True)
        mesh = trimesh.Trimesh(pts[used], faces.reshape(-1, 3), process=False)
        mesh.fix_normals()  # qhull's simplices are not consistently oriented
        hulls.append(mesh)
    return hulls


# --- The twin -----------------------------------------------------------------------------------


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
        pts_base.append(_check_points(f"link {k} points", lk.points) * s)
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


# --- Atomic multi-file writes -------------------------------------------------------------------


class _Staged:
    """Files written to temporaries beside their targets, renamed into place on commit()."""

    def __init__(self) -> None:
        self._pending: list[tuple[Path, Path]] = []

    def write(self, path: Path, data: bytes) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.chmod(tmp, 0o666 & ~umask())  # mkstemp makes 0600; give the usual mode
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        self._pending.append((Path(tmp), path))

    def commit(self) -> list[Path]:
        done = []
        for tmp, path in self._pending:  # in order of writing: the main file last
            os.replace(tmp, path)
            done.append(path)
        self._pending = []
        return done

    def abort(self) -> None:
        for tmp, _ in self._pending:
            tmp.unlink(missing_ok=True)
        self._pending = []


def _with_staging(fn):
    staged = _Staged()
    try:
        fn(staged)
    except BaseException:
        staged.abort()
        raise
    return staged.commit()


# --- MJCF / URDF ---------------------------------------------------------------------------------


def _f(x: float) -> str:
    """Shortest repr that round-trips a float64 (the twin is exact to the last bit)."""
    return repr(float(x))


def _v(a) -> str:
    return " ".join(_f(x) for x in np.asarray(a, dtype=float).reshape(-1))


def _mesh_bytes(mesh: trimesh.Trimesh) -> bytes:
    return trimesh.exchange.stl.export_stl(mesh)


def _mesh_files(twin: Twin) -> dict[str, tuple[str, trimesh.Trimesh]]:
    """{mesh name: (file name, mesh)} of every link's visual and collision meshes."""
    out = {}
    for lk in twin.links:
        out[f"{lk.name}_visual"] = (f"{lk.name}_visual.stl", lk.visual)
        for c, hull in enumerate(lk.collision):
            out[f"{lk.name}_collision_{c}"] = (f"{lk.name}_collision_{c}.stl", hull)
    return out


def _header(twin: Twin, fmt: str) -> str:
    units = "metres" if twin.metric else "MODEL UNITS written as metres (the scale was not known)"
    return (f"<!-- {fmt} digital twin written by artrecon.export. Units: {units}. Joint zero = "
            "configuration A (the reconstruction's points); positive values move toward "
            "configuration B. Meshes: visual = voxel surface of each link's points, collision "
            "= convex hulls of k-means clusters. -->\n")


def mjcf_string(twin: Twin, meshdir: str) -> str:
    """The MJCF text of a twin whose meshes are in `meshdir` (relative to the file)."""
    meshes = _mesh_files(twin)
    out = [_header(twin, "MJCF"), f"<mujoco model={quoteattr(twin.name)}>\n",
           f'  <compiler angle="radian" meshdir={quoteattr(meshdir)} inertiafromgeom="false" '
           'autolimits="true"/>\n\n  <asset>\n']
    for name, (fname, _) in meshes.items():
        out.append(f"    <mesh name={quoteattr(name)} file={quoteattr(fname)}/>\n")
    for lk in twin.links:
        out.append(f'    <material name="{lk.name}" rgba="{_v(lk.rgba)}"/>\n')
    out.append("  </asset>\n\n  <default>\n"
               '    <default class="visual">\n'
               '      <geom type="mesh" contype="0" conaffinity="0" group="2" density="0"/>\n'
               "    </default>\n"
               '    <default class="collision">\n'
               '      <geom type="mesh" group="3" density="0"/>\n'
               "    </default>\n  </default>\n\n  <worldbody>\n")

    def body(k: int, pos: np.ndarray, quat: np.ndarray | None, joint, depth: int) -> None:
        lk = twin.links[k]
        ind = "  " * depth
        q = "" if quat is None else f' quat="{_v(quat)}"'
        out.append(f'{ind}<body name="{lk.name}" pos="{_v(pos)}"{q}>\n')
        if joint is not None:
            kind = "hinge" if joint.type == "revolute" else "slide"
            out.append(f'{ind}  <joint name="{joint.name}" type="{kind}" pos="0 0 0" '
                       f'axis="{_v(joint.axis)}" range="{_f(joint.lower)} {_f(joint.upper)}"/>\n')
        I = lk.inertia
        out.append(f'{ind}  <inertial pos="{_v(lk.com)}" mass="{_f(lk.mass)}" fullinertia="'
                   f'{_v([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])}"/>\n')
        out.append(f'{ind}  <geom name="{lk.name}_visual" class="visual" mesh="{lk.name}_visual" '
                   f'material="{lk.name}"/>\n')
        for c in range(len(lk.collision)):
            out.append(f'{ind}  <geom name="{lk.name}_collision_{c}" class="collision" '
                       f'mesh="{lk.name}_collision_{c}" material="{lk.name}"/>\n')
        for cj in twin.children_of(k):
            body(cj.child, cj.origin_in_parent, None, cj, depth + 1)
        out.append(f"{ind}</body>\n")

    T = twin.T_world_base
    quat_xyzw = Rotation.from_matrix(T[:3, :3]).as_quat()
    body(twin.root, T[:3, 3], np.roll(quat_xyzw, 1), None, 2)  # MuJoCo quaternions are w x y z
    out.append("  </worldbody>\n")
    if twin.joints:
        # keyframes in body (= qpos) order, which is the depth-first order of the bodies above
        qa, qb = [], []

        def dfs(k: int) -> None:
            for cj in twin.children_of(k):
                qa.append(0.0)
                qb.append(cj.motion)
                dfs(cj.child)

        dfs(twin.root)
        out.append(f'\n  <keyframe>\n    <key name="configuration_a" qpos="{_v(qa)}"/>\n'
                   f'    <key name="configuration_b" qpos="{_v(qb)}"/>\n  </keyframe>\n')
    out.append("</mujoco>\n")
    return "".join(out)


def urdf_string(twin: Twin, meshdir: str) -> str:
    """The URDF text of a twin whose meshes are in `meshdir` (relative to the file)."""
    out = ['<?xml version="1.0"?>\n', _header(twin, "URDF"),
           f"<robot name={quoteattr(twin.name)}>\n", '  <link name="world"/>\n']
    T = twin.T_world_base
    rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")  # URDF rpy: fixed axes x, y, z
    root = twin.links[twin.root].name
    out.append(f'  <joint name="{root}_weld" type="fixed">\n    <parent link="world"/>\n'
               f'    <child link="{root}"/>\n    <origin xyz="{_v(T[:3, 3])}" rpy="{_v(rpy)}"/>\n'
               "  </joint>\n")
    for lk in twin.links:
        I = lk.inertia
        out.append(f'  <link name="{lk.name}">\n    <inertial>\n'
                   f'      <origin xyz="{_v(lk.com)}" rpy="0 0 0"/>\n'
                   f'      <mass value="{_f(lk.mass)}"/>\n'
                   f'      <inertia ixx="{_f(I[0, 0])}" ixy="{_f(I[0, 1])}" ixz="{_f(I[0, 2])}" '
                   f'iyy="{_f(I[1, 1])}" iyz="{_f(I[1, 2])}" izz="{_f(I[2, 2])}"/>\n'
                   "    </inertial>\n")
        out.append(f'    <visual>\n      <geometry>'
                   f'<mesh filename="{meshdir}/{lk.name}_visual.stl"/></geometry>\n'
                   f'      <material name="{lk.name}"><color rgba="{_v(lk.rgba)}"/>'
                   "</material>\n    </visual>\n")
        for c in range(len(lk.collision)):
            out.append(f'    <collision>\n      <geometry><mesh filename="{meshdir}/{lk.name}_'
                       f'collision_{c}.stl"/></geometry>\n    </collision>\n')
        out.append("  </link>\n")
    for j in twin.joints:
        out.append(f'  <joint name="{j.name}" type="{j.type}">\n'
                   f'    <parent link="{twin.links[j.parent].name}"/>\n'
                   f'    <child link="{twin.links[j.child].name}"/>\n'
                   f'    <origin xyz="{_v(j.origin_in_parent)}" rpy="0 0 0"/>\n'
                   f'    <axis xyz="{_v(j.axis)}"/>\n'
                   f'    <limit lower="{_f(j.lower)}" upper="{_f(j.upper)}" '
                   f'effort="{_f(URDF_EFFORT)}" velocity="{_f(URDF_VELOCITY)}"/>\n  </joint>\n')
    out.append("</robot>\n")
    return "".join(out)


def _export_robot(twin: Twin, path: Path, text_fn) -> list[Path]:
    path = Path(path)
    meshdir = f"{path.stem}_meshes"

    def write(staged: _Staged) -> None:
        for _, (fname, mesh) in _mesh_files(twin).items():
            staged.write(path.parent / meshdir / fname, _mesh_bytes(mesh))
        staged.write(path, text_fn(twin, meshdir).encode())

    return _with_staging(write)


def export_mjcf(model: ArticulatedModel | Twin, path: str | Path,
                config: ExportConfig | None = None) -> list[Path]:
    """Write the model as an MJCF file with its meshes in ``<stem>_meshes/`` beside it.

    Parameters
    ----------
    model : ArticulatedModel or Twin
    path : path of the .xml file
    config : ExportConfig, optional

    Returns
    -------
    paths : list of Path
        Every file written, the MJCF file last.
    """
    twin = model if isinstance(model, Twin) else build_twin(model, config, Path(path).stem)
    return _export_robot(twin, Path(path), mjcf_string)


def export_urdf(model: ArticulatedModel | Twin, path: str | Path,
                config: ExportConfig | None = None) -> list[Path]:
    """Write the model as a URDF file with its meshes in ``<stem>_meshes/`` beside it. See
    export_mjcf.

    Mesh file names are relative to the URDF's folder. ``pin.buildModelFromUrdf`` (kinematics,
    inertias) reads no mesh; pinocchio 4.1's ``pin.buildGeomFromUrdf`` resolves relative mesh
    paths against ``package_dirs``, so pass ``package_dirs=[<the URDF's folder>]``.
    """
    twin = model if isinstance(model, Twin) else build_twin(model, config, Path(path).stem)
    return _export_robot(twin, Path(path), urdf_string)


# --- GLB / PLY ----------------------------------------------------------------------------------


def _axis_arrow(start: np.ndarray, end: np.ndarray, radius: float) -> trimesh.Trimesh:
    """A red cylinder from start to end with a cone at `end` (the positive direction)."""
    d = end - start
    length = float(np.linalg.norm(d))
    head = min(6 * radius, 0.3 * length)
    shaft = trimesh.creation.cylinder(radius=radius,
                                      segment=np.array([start, end - head * d / length]))
    cone = trimesh.creation.cone(radius=2.5 * radius, height=head)
    # the cone stands on z = 0 pointing +z: rotate +z onto d and put its base at the shaft's end
    T = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d / length)
    T[:3, 3] = end - head * d / length
    cone.apply_transform(T)
    arrow = trimesh.util.concatenate([shaft, cone])
    arrow.visual.face_colors = AXIS_RGBA
    return arrow


def glb_scene(twin: Twin, geometry: str = "points") -> trimesh.Scene:
    """Scene of the twin in the world frame at configuration A: one node per link (coloured
    points or the visual mesh) and one red arrow per joint along its estimated axis."""
    scene = trimesh.Scene()
    all_pts = np.concatenate([twin.points_in_base(k) for k in range(len(twin.links))])
    size = float(np.median(np.linalg.norm(all_pts - np.median(all_pts, axis=0), axis=1))) or 1.0
    T = twin.T_world_base
    for lk in twin.links:
        pose = T @ _translation(lk.origin)
        if geometry == "points":
            colours = (np.column_stack([lk.colours, np.full(len(lk.colours), 255, np.uint8)])
                       if lk.colours is not None else np.tile((lk.rgba * 255).astype(np.uint8),
                                                              (len(lk.points), 1)))
            geom = trimesh.PointCloud(lk.points, colors=colours)
        else:
            geom = lk.visual
        scene.add_geometry(geom, node_name=lk.name, geom_name=lk.name, transform=pose)
    for j in twin.joints:
        child = twin.points_in_base(j.child)
        centre = child.mean(axis=0)
        a = twin.links[j.child].origin
        if j.type == "revolute":  # the axis line, centred where the child is, as long as the child
            proj = (child - a) @ j.axis
            half = max(0.5 * np.ptp(proj), 0.5 * float(np.max(np.ptp(child, axis=0))))
            mid = a + 0.5 * (proj.min() + proj.max()) * j.axis
        else:  # the slide direction through the child's centre, as long as the motion
            half = max(0.5 * abs(j.motion), 0.25 * float(np.max(np.ptp(child, axis=0))))
            mid = centre
        start, end = _apply(T, np.array([mid - half * j.axis, mid + half * j.axis]))
        scene.add_geometry(_axis_arrow(start, end, AXIS_RADIUS_FRACTION * size),
                           node_name=f"axis_{j.name}", geom_name=f"axis_{j.name}")
    return scene


def _translation(t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = t
    return T


def export_glb(model: ArticulatedModel | Twin, path: str | Path,
               config: ExportConfig | None = None) -> list[Path]:
    """Write a binary glTF (GLB) of the model with its axes drawn (red arrows pointing toward
    positive joint motion); see glb_scene. Returns [path]."""
    config = config or ExportConfig()
    twin = model if isinstance(model, Twin) else build_twin(model, config, Path(path).stem)
    data = glb_scene(twin, config.glb_geometry).export(file_type="glb")
    return _with_staging(lambda staged: staged.write(Path(path), data))


def ply_bytes(points: np.ndarray, colours: np.ndarray | None = None,
              normals: np.ndarray | None = None) -> bytes:
    """Binary little-endian PLY of points (double x y z), optional normals (double nx ny nz) and
    colours (uchar red green blue).

    Parameters
    ----------
    points : (n, 3) float
    colours : (n, 3) uint8, optional
    normals : (n, 3) float, optional
    """
    points = _check_points("points", points)
    n = len(points)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}",
              "property double x", "property double y", "property double z"]
    if normals is not None:
        normals = np.asarray(normals, dtype=float)
        if normals.shape != (n, 3):
            raise ValueError(f"normals must have shape ({n}, 3), got {normals.shape}")
        fields += [("nx", "<f8"), ("ny", "<f8"), ("nz", "<f8")]
        header += ["property double nx", "property double ny", "property double nz"]
    if colours is not None:
        colours = np.asarray(colours)
        if colours.shape != (n, 3):
            raise ValueError(f"colours must have shape ({n}, 3), got {colours.shape}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    header.append("end_header")
    rec = np.empty(n, dtype=fields)
    rec["x"], rec["y"], rec["z"] = points.T
    if normals is not None:
        rec["nx"], rec["ny"], rec["nz"] = normals.T
    if colours is not None:
        rec["red"], rec["green"], rec["blue"] = np.asarray(colours, dtype=np.uint8).T
    return ("\n".join(header) + "\n").encode("ascii") + rec.tobytes()


def export_ply(model: ArticulatedModel | Twin, out_dir: str | Path,
               config: ExportConfig | None = None) -> list[Path]:
    """Write one PLY per link into `out_dir` (``<link name>.ply``): the link's points in the
    world frame at configuration A (metres), with normals and colours when the model has them.
    Returns the paths, in link order."""
    twin = model if isinstance(model, Twin) else build_twin(model, config, Path(out_dir).name)
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir} is a file; PLY export writes one file per link into a folder")
    R = twin.T_world_base[:3, :3]

    def write(staged: _Staged) -> None:
        for k, lk in enumerate(twin.links):
            normals = None if lk.normals is None else lk.normals @ R.T
            staged.write(out_dir / f"{lk.name}.ply",
                         ply_bytes(twin.points_in_world(k), lk.colours, normals))

    return _with_staging(write)


def export_model(model: ArticulatedModel, fmt: str, out: str | Path,
                 config: ExportConfig | None = None) -> list[Path]:
    """Export in one of FORMATS ("mjcf", "urdf", "glb", "ply"); `out` is the file (a folder for
    "ply"). Returns the files written."""
    writers = {"mjcf": export_mjcf, "urdf": export_urdf, "glb": export_glb, "ply": export_ply}
    if fmt not in writers:
        raise ValueError(f"format must be one of {FORMATS}, got {fmt!r}")
    paths = writers[fmt](model, out, config)
    log.info("exported %s: %d files, main %s", fmt, len(paths), paths[-1])
    return paths


# --- Command line -------------------------------------------------------------------------------

_SUFFIX = {"mjcf": ".xml", "urdf": ".urdf", "glb": ".glb", "ply": ""}


def add_export_parser(subparsers=None) -> argparse.ArgumentParser:
    """The `export` command's parser: as a subparser of `subparsers` (from
    ArgumentParser.add_subparsers) or standalone when None. Its handler is in
    ``parser.get_default("handler")``: call ``handler(args)`` -> exit code."""
    kwargs = dict(
        description="Export an articulated model (JSON from the reconstruction) as MJCF, URDF, "
                    "GLB, or one PLY per link.",
    )
    if subparsers is None:
        parser = argparse.ArgumentParser(prog="artrecon export", **kwargs)
    else:
        parser = subparsers.add_parser("export", help="export a model as MJCF/URDF/GLB/PLY",
                                       **kwargs)
    parser.add_argument("model", type=Path, help="model JSON written by ArticulatedModel.save")
    parser.add_argument("--format", required=True, choices=FORMATS, dest="format")
    parser.add_argument("--out", required=True, type=Path,
                        help="output file (.xml for mjcf, .urdf, .glb); a folder for ply")
    parser.add_argument("--base-frame", default=None,
                        help="place the base at this pose of the model's frames "
                             "(e.g. T_world_model after registration)")
    parser.add_argument("--voxel-size", type=float, default=None,
                        help="voxel edge of the meshes in metres (default: from point spacing)")
    parser.add_argument("--density", type=float, default=DEFAULT_DENSITY,
                        help=f"link density, kg/m^3 (default {DEFAULT_DENSITY:g})")
    parser.add_argument("--collision-clusters", type=int, default=COLLISION_CLUSTERS,
                        help=f"convex hulls per link (default {COLLISION_CLUSTERS})")
    parser.add_argument("--glb-geometry", choices=("points", "mesh"), default="points")
    parser.add_argument("--seed", type=int, default=0)
    parser.set_defaults(handler=run_export)
    return parser


def run_export(args: argparse.Namespace) -> int:
    """Run the export command from parsed arguments; returns the exit code."""
    try:
        config = ExportConfig(voxel_size=args.voxel_size, density=args.density,
                              collision_clusters=args.collision_clusters,
                              base_frame=args.base_frame, glb_geometry=args.glb_geometry,
                              seed=args.seed)
        model = ArticulatedModel.load(args.model)
        paths = export_model(model, args.format, args.out, config)
    except (ArtreconError, ValueError, OSError) as exc:
        # the command's own output (this is the CLI layer; the library above only logs)
        sys.stderr.write(f"artrecon export: error: {exc}\n")
        return 2
    sys.stdout.write(f"wrote {len(paths)} files: {paths[-1]}\n")
    return 0


def export_main(argv: list[str] | None = None) -> int:
    """`artrecon export MODEL --format mjcf|urdf|glb|ply --out PATH` as a standalone entry
    point; returns the exit code."""
    parser = add_export_parser()
    args = parser.parse_args(argv)
    return args.handler(args)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    raise SystemExit(export_main())

