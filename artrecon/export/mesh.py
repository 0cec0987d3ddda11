"""Meshes and inertias of a link's points: the voxel surface (visual), convex hulls of k-means
clusters (collision), and the exact inertia of the voxel occupancy.

Why these and not Poisson or ball pivoting: dense SfM points are noisy, unevenly dense and have
holes where no camera looked, and the project uses scipy and trimesh only (no Open3D, no
scikit-image), so each link's meshes are built in two ways that cannot fail on such input:

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
"""

from __future__ import annotations

import logging

import numpy as np
import trimesh
from scipy import ndimage
from scipy.cluster.vq import kmeans2
from scipy.spatial import ConvexHull, cKDTree

from artrecon.errors import ArtreconError, InputError
from artrecon.geometry import point_spacing

log = logging.getLogger(__name__)

__all__ = ["auto_voxel_size", "voxel_surface", "voxel_inertia", "collision_hulls",
           "check_points"]

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

#: Taubin smoothing of the voxel surface: iterations and its two factors (lamb > 0 smooths,
#: nu slightly larger undoes the shrinking); 10 removes the one-voxel staircase, little more.
SMOOTHING_ITERATIONS = 10
SMOOTHING_LAMBDA = 0.5
SMOOTHING_NU = 0.53

#: After smoothing, each surface vertex moves inward until it is this many voxels outside its
#: nearest point along its normal: the surface hugs the points (a quarter voxel: 0.5 mm at 2 mm
#: voxels) yet keeps them inside despite their noise along the surface.
SHRINK_MARGIN = 0.25

#: A cluster needs at least this many points (a hull of fewer is noise-dominated).
MIN_CLUSTER_POINTS = 16


def check_points(name: str, points) -> np.ndarray:
    """``points`` as an (n, 3) float array; ValueError for another shape, InputError when a
    coordinate is not finite (``name`` says whose points)."""
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
    points = check_points("points", points)
    extent = float(np.max(np.ptp(points, axis=0))) if len(points) else 0.0
    spacing = point_spacing(points)
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
    points = check_points("points", points)
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
    points = check_points("points", points)
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
