"""Which link each dense point belongs to: occlusion- and photo-consistent labelling.

The segmentation (:mod:`artrecon.segment`) labels only the matched SIFT points. Every dense point
of configuration A (and of B) must then join one link. For a point ``p`` of A, the hypothesis
"``p`` is on link k" predicts where ``p`` is in B: ``q = T_k(p)``. Four cues weigh each hypothesis:

1. **Geometric fit.** ``q`` lies on B's dense surface (within a few residuals or point spacings).
   Fails to decide where a link slides within its own surface (a drawer's floor and sides along
   the pull; flat pliers turning in their plane) or near the joint, where all links move alike,
   and where ``q`` is hidden in B.
2. **Free space (occlusion reasoning).** If a camera of B would see ``q`` *in front of* the
   surface B observed along that ray, nothing was there: the hypothesis is violated. This is what
   decides points whose counterpart is hidden: the inside of a drawer pulled out in B cannot stay
   where the drawer was in A (B's cameras see through that place) but can hide inside the cabinet.
   The surfaces are z-buffers of the dense points, background included, in each camera.
3. **Photo-consistency.** A small patch on ``p``'s tangent plane, seen in the A image that sees it
   best, must look like the same patch moved by ``T_k`` in the B image that sees ``q`` best
   (normalised cross-correlation, plane-induced sampling). This decides sliding surfaces, which
   the geometry cannot. "Sees" is the dense stage's word (:func:`seen_by`: the view's own depth
   map agreed with the point; for ``q``, with B's point it lands on), not the z-buffers' alone:
   the arm that carries the camera is in front of the object in some views and in no z-buffer,
   and its patches (cabinet's carcass and door walls: median NCC 0.05-0.12 for the right link)
   said nothing about the object.
4. **Nearest match.** A weak prior for the link of the nearest segmented SIFT match.

Labels are smooth on the surface: the costs are the unary terms of a Potts model on the
k-nearest-neighbour graph of the points, minimised by alpha-expansion graph cuts
(:mod:`artrecon.potts`), which flip a whole wrongly labelled region at once where per-point
updates stop at its border. Symmetrically for the points of B with the inverse transforms.

The table the object stands on is in that graph too: the dense points next to the object that the
object region took for the table (static, so they move as the base link does). Without them the
Potts term is lopsided where a thin strip of the base lies between the table and another link (the
fixed half's pivot wall under the moving half of a pair of pliers): the strip's only labelled
neighbours are the other link's, so it flips to that link whatever its own evidence says (near the
joint, where the motions hardly differ, it says little). With them, the strip's border with the
table costs as much as its border with the link above. But the table is not a link: another link
may rest on it or hang just above it (the moving half of scissors, whose fattened lower edge
reaches the table), and a table that pulls every neighbour to the base pulls those too. So a table
edge counts against link k only where k moves the point as the base does, within what the point's
own cues resolve (the two fit thresholds plus the photo patch's width), or where the geometric fit
is silent (neither motion lands the point on the other configuration's surface: 678 points of
cabinet_door_only in B, low on the cabinet, where the evidence was a tie): there the point's
evidence cannot decide and the smoothness must; elsewhere its evidence decides alone, as without
the table. A silence is a tie only when link k's is as telling as the base's: where k moves the
point behind what the other configuration saw (hidden: its lack of fit says nothing) and the base
leaves it in view on no surface of the base, the point leans to k (chest's drawer pulled out in
B: its floor just outside the carcass, next to the table, went to the carcass in the second pass,
and 1476 points of the floor inside with it; B's accuracy 0.921, 0.992 without).

The geometric fit runs twice. First ``q`` need only land on B's surface; that is fooled where
links touch or stack (the lower jaw of closed pliers under the upper one: a point of one moved by
the other's transform lands on the other). Then, with both configurations labelled, hypothesis k
fits only where ``q`` lands on B's points *of link k*: the labels of each configuration check
those of the other.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import partial

import cv2
import numpy as np
from scipy.ndimage import map_coordinates, minimum_filter
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from artrecon.errors import ReconstructionError
from artrecon.geometry import point_spacing
from artrecon.potts import potts_expansion
from artrecon.workers import side_by_side

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AssignConfig:
    """Settings of the dense-point labelling. Costs are in units of one failed cue."""

    residual_factor: float = 3.0
    """A hypothesis fits when ``q`` is within this many times the link's match residual of the
    other configuration's dense surface ..."""
    spacing_factor: float = 2.0
    """... or within this many dense point spacings, whichever is larger."""
    zbuffer_cell: int = 4
    """Z-buffer cell edge in pixels (the dense points are ~2-3 px apart in the images)."""
    depth_tolerance: float = 0.01
    """Relative depth band (1%, the dense stage's own consistency tolerance) within which ``q``
    counts as on the observed surface; the band is at least ``spacing_factor`` spacings."""
    violation_window: int = 3
    """A free-space violation needs ``q`` in front of every surface observed within this many
    z-buffer cells around its own (odd; 1: its cell alone). The dense points of a wall have
    holes wider than the one cell the z-buffer closes, and a ray through one of them meets the
    room behind: "seen through". Drawer's drawer, pulled out in B, has its floor's back part
    still in the carcass; moved back to A by the drawer's motion it lies inside the closed
    drawer, where A's cameras saw through holes in the drawer front and carcass walls, and
    1216 of its 9084 points in B went to the carcass (B's accuracy 0.961; 0.991 with a window
    of 3 cells, 0.987 with 9)."""
    violations_saturate: int = 3
    """Free-space violations (cameras) at which the violation cost is full."""
    cost_no_fit: float = 1.0
    cost_violation: float = 1.0
    cost_photo: float = 1.0
    """Times ``(1 - NCC) / 2``, for every hypothesis with a patch in both configurations ..."""
    photo_unknown: float = 0.35
    """... and a hypothesis whose counterpart is hidden (no patch to compare) costs this share of
    ``cost_photo`` where another has one: what NCC 0.3 costs. A patch that matches beats not
    knowing; one that clearly does not (a drawer's floor where the drawer slid away over it)
    loses to it."""
    cost_match: float = 0.3
    """Cost of disagreeing with the nearest segmented match's link ..."""
    match_reach: float = 10.0
    """... fading with the distance to that match (e-fold at this many point spacings): a match
    says little about a point far from it, such as the inside of a drawer that only one
    configuration shows."""
    smoothness: float = 0.7
    """Potts weight per neighbour with another label (0.5-1.0 all work; at 1.0 thin links
    stacked on each other start to merge, under 0.5 a drawer's inside breaks into islands)."""
    neighbours: int = 8
    neighbour_radius: float = 2.5
    """Graph edges only up to this many median point spacings."""
    expansion_cycles: int = 4
    """At most this many alpha-expansion passes over the links (it stops when none helps)."""
    passes: int = 2
    """Labelling passes: the first fits against the other configuration's whole surface, each
    later one against its points of the same link (as the previous pass labelled them)."""
    patch_half: int = 3
    """Patch of (2 h + 1)^2 samples ..."""
    patch_step_px: float = 1.5
    """... this many pixels apart in the source image."""

    def __post_init__(self) -> None:
        if self.violation_window < 1 or self.violation_window % 2 == 0:
            raise ValueError("AssignConfig.violation_window must be an odd number of z-buffer "
                             f"cells >= 1 (a window centred on the cell), got "
                             f"{self.violation_window}")


@dataclass
class CameraView:
    """One posed image: ``K`` (3, 3) OpenCV, ``T_cw`` (4, 4) camera from world, grey image
    (float32) and, optionally, the colour image (h, w, 3) uint8 (the table free-space test,
    :mod:`artrecon.freespace`, needs it) and its name (then the photo patches come only from
    views that the dense stage found to see the point: :func:`seen_by`)."""

    K: np.ndarray
    T_cw: np.ndarray
    image: np.ndarray
    colour: np.ndarray | None = None
    name: str | None = None
    """the image's name (a column of :attr:`artrecon.dense.DensePoints.image_names`)"""

    @property
    def centre(self) -> np.ndarray:
        return -self.T_cw[:3, :3].T @ self.T_cw[:3, 3]

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel coordinates ``u, v`` and depth ``z`` of points (n, 3)."""
        Xc = X @ self.T_cw[:3, :3].T + self.T_cw[:3, 3]
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.K[0, 0] * Xc[:, 0] / z + self.K[0, 2]
            v = self.K[1, 1] * Xc[:, 1] / z + self.K[1, 2]
        return u, v, z


#: libpng's RGB -> grey weights in its 15-bit fixed point, as OpenCV's PNG reader asks for them
#: (``png_set_rgb_to_gray(png, 1, 0.299, 0.587)``: red and green truncated, blue the rest).
_PNG_GREY_WEIGHTS = (9797, 19234, 3737)


def png_grey(bgr: np.ndarray) -> np.ndarray:
    """The grey image ``cv2.imread(path, cv2.IMREAD_GRAYSCALE)`` decodes from an 8-bit colour
    PNG, computed from its colour decode (``IMREAD_COLOR``, BGR): libpng's fixed-point weights,
    the sum truncated (not ``cv2.cvtColor``, which rounds and differs in 4 of 10 pixels)."""
    wr, wg, wb = _PNG_GREY_WEIGHTS
    b, g, r = (bgr[:, :, i].astype(np.uint32) for i in range(3))
    return ((wr * r + wg * g + wb * b) >> 15).astype(np.uint8)


def views_from_sfm(sfm) -> list[CameraView]:
    """The registered images of an :class:`artrecon.sfm.SfMResult`, grey and colour, full
    resolution.

    The grey image is the one OpenCV reads (``IMREAD_GRAYSCALE``: its PNG reader's own
    conversion), not ``cvtColor`` of the colour one. For PNG images it is computed from the
    colour decode (:func:`png_grey`) once the first PNG's own grey decode has confirmed the
    formula on this machine's OpenCV (else every image is decoded twice, as before): one decode
    per image instead of two."""
    poses = sfm.T_world_camera()
    views = []
    png_formula = None  # png_grey confirmed on this set's first PNG (None: not checked yet)
    for name in sorted(poses):
        path = sfm.image_dir / name
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        grey = None
        if img is not None and path.suffix.lower() == ".png" and png_formula is not False:
            if png_formula is None:
                grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
                png_formula = grey is not None and np.array_equal(grey, png_grey(img))
            else:
                grey = png_grey(img)
        if grey is None:
            grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None or grey is None:
            # a missing view would silently weaken the labels (and change the tree)
            raise ReconstructionError(f"cannot read image {sfm.image_dir / name} of the "
                                      "reconstruction; put it back or reconstruct again")
        views.append(CameraView(sfm.intrinsics(name), np.linalg.inv(poses[name]),
                                grey.astype(np.float32), img[:, :, ::-1].copy(), name))
    return views


def seen_by(dense, views: list[CameraView]) -> np.ndarray | None:
    """(n, len(views)) bool: which views saw each dense point, by the dense stage's depth
    fusion (``dense.visibility``: the view's own depth map agreed with the point), the columns
    matched to the views by image name; None when a view has no name.

    The z-buffers hold only what was reconstructed. Whatever stands between a camera and the
    object but was not reconstructed (the arm carrying the camera, its own links in front of
    the lens) is missing from them, so they call a point visible in views that did not see
    it; the depth fusion did not count those views."""
    if not views or any(v.name is None for v in views):
        return None
    column = {name: k for k, name in enumerate(dense.image_names)}
    out = np.zeros((len(dense), len(views)), bool)
    for c, v in enumerate(views):
        if v.name in column:  # a view the dense stage did not use saw none of them
            out[:, c] = dense.visibility[:, column[v.name]]
    return out


#: Points per block of a z-buffer's projection (:class:`_Surface`). Scissors' 0.93 M occluders
#: into 121 views, both configurations' z-buffers side by side in the links stage: 2.9 s against
#: 3.5-4.1 s in one block (the projection's dozen (n,) temporaries of 7 MB each fall out of the
#: cache); 16 k points took 3.6-4.2 s (more small numpy calls of the two threads).
ZBUFFER_BLOCK = 1 << 16


class _Surface:
    """The dense surface of one configuration as seen by its cameras (z-buffer per view)."""

    def __init__(self, views: list[CameraView], points: np.ndarray, cell: int, window: int = 1):
        self.views, self.cell = views, cell
        self.zbuf = []
        self.znear = []
        for v in views:
            h, w = v.image.shape[0] // cell, v.image.shape[1] // cell
            zb = np.full(h * w, np.inf)
            # the cells as flat indices, of the points in view only: the same minima as
            # _cells' (row, column) pairs over every point, at half the time (0.9 M occluders
            # of scissors: 4.96 -> 2.74 CPU s for 30 views); in blocks of ZBUFFER_BLOCK points,
            # whose temporaries stay in the cache (the same minima: a minimum is a minimum in
            # any order)
            for start in range(0, len(points), ZBUFFER_BLOCK):
                u, vv, z = v.project(points[start:start + ZBUFFER_BLOCK])
                i, j, ok = self._cell_floats(u, vv, z, w, h)
                np.minimum.at(zb, j[ok].astype(np.int64) * w + i[ok].astype(np.int64), z[ok])
            zb = zb.reshape(h, w)
            # close one-cell holes between points (never pushes a surface back)
            self.zbuf.append(np.where(np.isfinite(zb), zb, minimum_filter(zb, 3)))
            self.znear.append(minimum_filter(self.zbuf[-1], window) if window > 1
                              else self.zbuf[-1])

    def _cell_floats(self, u, v, z, w, h):
        """Column and row (floats, floored) of each pixel's cell, and whether the point is in
        front of the camera and inside the (w, h) cells."""
        with np.errstate(invalid="ignore"):
            i = np.floor(u / self.cell)
            j = np.floor(v / self.cell)
        return i, j, (z > 0) & (i >= 0) & (i < w) & (j >= 0) & (j < h)

    def _cells(self, u, v, z, w, h):
        """:meth:`_cell_floats` as int64 indices, 0 where the point is not in view."""
        i, j, ok = self._cell_floats(u, v, z, w, h)
        return np.where(ok, i, 0).astype(np.int64), np.where(ok, j, 0).astype(np.int64), ok

    def status(self, X: np.ndarray, rel: float, floor: float):
        """Per view and point: visible (on the observed surface) and violating (in front of it
        and of every surface observed within :attr:`AssignConfig.violation_window` cells).

        Returns (visible, violating), both (views, n) bool.
        """
        vis = np.zeros((len(self.views), len(X)), bool)
        bad = np.zeros_like(vis)
        for c, (v, zb, zn) in enumerate(zip(self.views, self.zbuf, self.znear, strict=True)):
            u, vv, z = v.project(X)
            i, j, ok = self._cells(u, vv, z, zb.shape[1], zb.shape[0])
            zz = np.where(ok, zb[j, i], np.inf)
            known = ok & np.isfinite(zz)
            tol = np.maximum(rel * np.where(known, zz, 0.0), floor)
            vis[c] = known & (np.abs(z - zz) <= tol)
            near = np.where(ok, zn[j, i], np.inf)
            bad[c] = known & (z < near - np.maximum(rel * np.where(known, near, 0.0), floor))
        return vis, bad

    def best_view(self, visible: np.ndarray, X: np.ndarray, N: np.ndarray) -> np.ndarray:
        """Index of the view that sees each point most head-on (-1: none sees it)."""
        best = np.full(len(X), -1)
        score = np.full(len(X), -np.inf)
        for c, v in enumerate(self.views):
            d = v.centre - X
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            s = np.abs(np.sum(d * N, axis=1))
            m = visible[c] & (s > score)
            best[m], score[m] = c, s[m]
        return best

    def sample(self, best: np.ndarray, G: np.ndarray) -> np.ndarray:
        """Intensities (n, s) of patch points G (n, s, 3) in each point's view (nan: none)."""
        out = np.full(G.shape[:2], np.nan, np.float32)
        for c in np.unique(best[best >= 0]):
            m = best == c
            u, v, _ = self.views[c].project(G[m].reshape(-1, 3))
            out[m] = map_coordinates(self.views[c].image, [v, u], order=1,
                                     mode="nearest").reshape(int(m.sum()), -1)
        return out


def _patch_grid(X, N, step, half):
    """Points (n, (2 half + 1)^2, 3) on each point's tangent plane, ``step`` (n,) apart."""
    t1 = np.cross(N, [0.0, 0.0, 1.0])
    flat = np.linalg.norm(t1, axis=1) < 1e-3
    t1[flat] = np.cross(N[flat], [1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(N, t1)
    g = np.arange(-half, half + 1, dtype=float)
    gi, gj = (a.ravel() for a in np.meshgrid(g, g))
    offs = gi[None, :, None] * t1[:, None, :] + gj[None, :, None] * t2[:, None, :]
    return X[:, None, :] + step[:, None, None] * offs


def _ncc(a, b):
    a = a - a.mean(1, keepdims=True)
    b = b - b.mean(1, keepdims=True)
    return np.sum(a * b, 1) / (np.sqrt(np.sum(a * a, 1) * np.sum(b * b, 1)) + 1e-6)


def _graph(X, k, radius):
    d, i = cKDTree(X).query(X, k=k + 1)
    spacing = float(np.median(d[:, 1]))
    keep = (d[:, 1:] < radius * spacing).ravel()
    rows = np.repeat(np.arange(len(X)), k)[keep]
    cols = i[:, 1:].ravel()[keep]
    G = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(X), len(X))).tocsr()
    return ((G + G.T) > 0).astype(np.float64)


def _matches_along_surface(X, graph, matches, labels, K, limit):
    """Distance from each point of X to the nearest segmented match, along the surface, and
    that match's link.

    Along the edges of the points' graph (:func:`_graph`), from the point nearest each match
    (plus the distance to it). A straight line passes through the solid: the inside of a drawer
    still in its carcass lies a few centimetres under the carcass's top and beside its walls,
    whose matches were the nearest in a straight line (and its own link's, on its front, further
    away), so the prior of the carcass outweighed what the drawer's visible inside says through
    the smoothness (drawer: 2366 of its 9010 points in B labelled as the carcass).

    Returns
    -------
    distance : (n,) float, inf beyond ``limit`` (and where no match's surface reaches)
    link : (n,) int, the nearest match's link (-1: none within ``limit``)
    """
    n = len(X)
    rows, cols = graph.nonzero()
    length = np.linalg.norm(X[rows] - X[cols], axis=1)
    snap, at = cKDTree(X).query(matches)
    dist = np.full((K, n), np.inf)
    for k in range(K):
        mine = labels == k
        if not mine.any():
            continue
        # a source node (index n) joined to each of link k's matches' nearest points (once
        # each: coo_matrix adds duplicate entries up)
        start = np.full(n, np.inf)
        np.minimum.at(start, at[mine], snap[mine])
        seeds = np.flatnonzero(np.isfinite(start))
        r = np.r_[rows, np.full(len(seeds), n)]
        c = np.r_[cols, seeds]
        w = np.r_[length, start[seeds]] + 1e-12  # a zero weight would be no edge
        G = coo_matrix((w, (r, c)), shape=(n + 1, n + 1)).tocsr()
        dist[k] = dijkstra(G, directed=True, indices=n, limit=limit)[:n]
    link = np.where(np.isfinite(dist).any(0), dist.argmin(0), -1)
    return dist.min(0), link


def _static_edges(X, S, k, radius) -> np.ndarray:
    """(n,) float: how many neighbours each point of X has among the static points S, by the rule
    of :func:`_graph` on X and S together (an edge where either end is among the other's k
    nearest, up to ``radius`` x X's median point spacing). They add to X's own graph, whose
    edges they leave as they are."""
    n = len(X)
    if S is None or len(S) == 0 or n < 2:
        return np.zeros(n)
    tree = cKDTree(X)
    reach = radius * point_spacing(X, tree)
    S = np.asarray(S, float)
    S = S[tree.query(S, distance_upper_bound=reach)[0] < reach]  # only these can be neighbours
    if len(S) == 0:
        return np.zeros(n)
    both = cKDTree(np.vstack([X, S]))
    rows, cols = [], []
    for start, pts in ((0, X), (n, S)):
        d, i = both.query(pts, k=k + 1)
        own = np.repeat(np.arange(start, start + len(pts)), k)
        hit = ((d[:, 1:] < reach) & ((i[:, 1:] >= n) != (start >= n))).ravel()
        ends = np.sort(np.c_[own[hit], i[:, 1:].ravel()[hit]], axis=1)  # (object, static)
        rows.append(ends[:, 0])
        cols.append(ends[:, 1] - n)
    r, c = np.concatenate(rows), np.concatenate(cols)
    E = coo_matrix((np.ones(len(r)), (r, c)), shape=(n, len(S))).tocsr()
    E.data[:] = 1.0  # an edge found from both ends counts once
    return np.asarray(E.sum(axis=1)).ravel()


class _Evidence:
    """The cues for labelling the points of one configuration (src) against the other (dst).

    Everything but the geometric fit is computed once; the fit is redone per pass, against the
    other configuration's labels once they exist (:meth:`label`).
    """

    def __init__(self, src, src_normals, dst, transforms, residuals, match_src, match_labels,
                 surface_src: _Surface | None, surface_dst: _Surface | None,
                 config: AssignConfig, static: np.ndarray | None = None,
                 base: int | None = None, seen_src: np.ndarray | None = None,
                 seen_dst: np.ndarray | None = None):
        K, n = len(transforms), len(src)
        self.K, self.n, self.dst, self.config = K, n, dst, config
        #: the link the static points (the table) move with, each point's edges to them, and
        #: (K, n) where hypothesis k moves the point as the base would, within what its own cues
        #: resolve (there the table's edges count against k)
        self.base_link = base
        self.static_edges = np.zeros(n)
        self.like_base = np.zeros((K, n), bool)
        good = match_labels >= 0
        if not good.any():
            raise ValueError("assign: no segmented match to anchor the links (every match is "
                             "an outlier); the segmentation found no link")
        if K == 1:
            return
        tree = cKDTree(dst)
        spacing = point_spacing(dst, tree)
        floor = config.spacing_factor * spacing
        self.moved = [T.apply(src) for T in transforms]
        self.threshold = [max(config.residual_factor * float(r), floor) for r in residuals]
        landing = [tree.query(q) for q in self.moved]  # (distance, index) of dst's nearest point
        self.fits_any = np.stack([d < thr for (d, _), thr in zip(landing, self.threshold,
                                                                 strict=True)])
        violations = np.zeros((K, n))
        ncc = np.full((K, n), np.nan)
        #: hypothesis k's counterpart is hidden from every camera of the other configuration
        #: (behind what they saw, never in front of it): its lack of fit says nothing
        self.hidden = np.zeros((K, n), bool)
        patch_width = np.zeros(n)  # the photo patch's width on the surface (none: no patch)
        if surface_src is not None and surface_dst is not None:
            vis_src, _ = surface_src.status(src, config.depth_tolerance, floor)
            if seen_src is not None:  # a view hidden by what was not reconstructed: no patch
                vis_src &= seen_src.T
            best_src = surface_src.best_view(vis_src, src, src_normals)
            depth = np.full(n, np.nan)
            for c in np.unique(best_src[best_src >= 0]):
                m = best_src == c
                depth[m] = surface_src.views[c].project(src[m])[2]
            step = config.patch_step_px * depth / np.array(
                [surface_src.views[max(c, 0)].K[0, 0] for c in best_src])
            G = _patch_grid(src, src_normals, np.nan_to_num(step), config.patch_half)
            patch_width = 2 * config.patch_half * np.nan_to_num(step)
            patch_src = surface_src.sample(best_src, G)
            for k, (T, q) in enumerate(zip(transforms, self.moved, strict=True)):
                vis, bad = surface_dst.status(q, config.depth_tolerance, floor)
                violations[k] = bad.sum(0)
                self.hidden[k] = ~vis.any(0) & ~bad.any(0)
                if seen_dst is not None:
                    # q on the other configuration's points: only the views that saw the point
                    # it lands on (elsewhere, on the table or in between, the z-buffer alone)
                    on = self.fits_any[k]
                    vis[:, on] &= seen_dst[landing[k][1][on]].T
                best = surface_dst.best_view(vis, q, src_normals @ T.rotation.T)
                patch = surface_dst.sample(best, T.apply(G.reshape(-1, 3)).reshape(G.shape))
                ok = (best_src >= 0) & (best >= 0)
                ncc[k, ok] = _ncc(patch_src[ok], patch[ok])
        U = config.cost_violation * np.minimum(violations, config.violations_saturate) \
            / config.violations_saturate
        has = np.isfinite(ncc)
        self.photo_share = float(np.mean(has.all(0)))
        photo = np.where(has, (1.0 - np.nan_to_num(ncc)) / 2.0, config.photo_unknown)
        U = U + config.cost_photo * np.where(has.any(0), photo, 0.0)
        src_spacing = point_spacing(src)
        self.graph = _graph(src, config.neighbours, config.neighbour_radius)
        reach = config.match_reach * src_spacing
        # no match within reach along the surface: no prior (nearest -1, its weight 0)
        d_match, nearest = _matches_along_surface(src, self.graph, match_src[good],
                                                  match_labels[good], K, 5.0 * reach)
        prior = config.cost_match * np.exp(-d_match / reach)
        self.base = U + prior[None, :] * (np.arange(K)[:, None] != nearest[None, :])
        if base is not None:
            self.static_edges = _static_edges(src, static, config.neighbours,
                                              config.neighbour_radius)
            # Where two motions move the point less apart than its cues resolve (the two
            # predictions can both fit the same surface, each within its threshold; their photo
            # patches overlap), its evidence cannot tell them apart and the smoothness decides:
            # there the table counts (and, per pass, where neither motion fits: :meth:`label`).
            # Elsewhere the point's own evidence decides and the table stays out: it is not a
            # link, and a link other than the base can lie on it or hang just above it (the
            # moving blade of scissors, away from the pivot).
            for k in range(K):
                apart = np.linalg.norm(self.moved[k] - self.moved[base], axis=1)
                self.like_base[k] = apart < (self.threshold[k] + self.threshold[base]
                                             + patch_width)

    def fits(self, dst_labels: np.ndarray | None = None) -> np.ndarray:
        """(K, n) bool: hypothesis k puts the point on the other configuration's surface (on
        its points labelled k, given ``dst_labels``)."""
        if dst_labels is None:
            return self.fits_any
        out = np.zeros((self.K, self.n), bool)
        for k, (q, thr) in enumerate(zip(self.moved, self.threshold, strict=True)):
            own = self.dst[dst_labels == k]
            if len(own):
                out[k] = cKDTree(own).query(q)[0] < thr
        return out

    def label(self, dst_labels: np.ndarray | None = None) -> np.ndarray:
        """(n,) int: the labels of least Potts energy."""
        if self.K == 1:
            return np.zeros(self.n, int)
        fits = self.fits(dst_labels)
        U = self.base + self.config.cost_no_fit * (~fits & fits.any(0) & ~self.hidden)
        if self.static_edges.any():  # Potts edges to the table, which moves as the base does
            b = self.base_link
            # the point's cues cannot tell k from the base: the motions move it alike, or the
            # geometric fit is silent (neither lands it on the other configuration's surface)
            # and k's silence is no less telling than the base's. Where k's counterpart is
            # hidden (its lack of fit says nothing) and the base's in view, the cues lean to k:
            # no tie (chest's drawer floor pulled out in B: under the carcass at A by the
            # drawer's motion, where A's cameras saw nothing by the base's)
            silent = ~fits & ~fits[b] & ~(self.hidden & ~self.hidden[b])
            alike = self.like_base | silent
            U = U + self.config.smoothness * self.static_edges[None, :] \
                * (np.arange(self.K)[:, None] != b) * alike
        log.debug("assign: %d points, fit by one link %.0f%%, several %.0f%%, none %.0f%%; "
                  "patches compared %.0f%%", self.n, 100 * np.mean(fits.sum(0) == 1),
                  100 * np.mean(fits.sum(0) > 1), 100 * np.mean(fits.sum(0) == 0),
                  100 * self.photo_share)
        return potts_expansion(U, self.graph, self.config.smoothness,
                               self.config.expansion_cycles)


def label_points(src, src_normals, dst, transforms, residuals, match_src, match_labels, *,
                 dst_labels: np.ndarray | None = None,
                 surface_src: _Surface | None = None, surface_dst: _Surface | None = None,
                 config: AssignConfig = AssignConfig(), static: np.ndarray | None = None,
                 base: int | None = None) -> np.ndarray:
    """Link label of every point of one configuration (one pass).

    Parameters
    ----------
    src, src_normals : (n, 3) dense points (and unit normals) to label.
    dst : (m, 3) the other configuration's dense points.
    transforms : list of transforms (``apply``, ``rotation``) from src's frame to dst's, per link.
    residuals : per link, the match residual in dst's units.
    match_src, match_labels : segmented matches in src's frame and their links (-1: outlier).
    dst_labels : (m,) int, optional
        The other configuration's labels: then hypothesis k fits only on dst's points of link k.
    surface_src, surface_dst : cameras and z-buffers of the two configurations; without them only
        the geometric fit, the match prior and the smoothness decide.
    static, base : (m, 3) points that move with link ``base`` (the table), optional: neighbours
        in the Potts graph that count against a link only where the point's cues cannot tell
        it from the base (see the module's notes).

    Returns
    -------
    (n,) int, a link per point.
    """
    return _Evidence(src, src_normals, dst, transforms, residuals, match_src, match_labels,
                     surface_src, surface_dst, config, static, base).label(dst_labels)


def assign_dense_to_links(dense_a, dense_b, points_a, points_b, segmentation, *,
                          views_a: list[CameraView] | None = None,
                          views_b: list[CameraView] | None = None,
                          occluders_a: np.ndarray | None = None,
                          occluders_b: np.ndarray | None = None,
                          config: AssignConfig = AssignConfig(),
                          base: int | None = None,
                          static_a: np.ndarray | None = None,
                          static_b: np.ndarray | None = None):
    """Link label of every dense point of A and of B.

    ``dense_a``/``dense_b`` are :class:`artrecon.dense.DensePoints`; ``points_a``/``points_b``
    the segmented matches (``segmentation.labels``). With the posed images of both
    configurations (``views_a``, ``views_b``), free-space and photo-consistency cues join the
    geometric fit; ``occluders_*`` are the points the z-buffers are built from (default: the
    dense points; pass the dense points before the background was removed, so that the table
    and walls occlude too). ``config.passes`` passes label both configurations, each after the
    first fitting against the other's labels of the previous one. ``static_a``/``static_b``
    ((m, 3), optional) are points of each configuration that move with link ``base`` (the table
    next to the object; the base stands on it): neighbours in the Potts graph, counted against a
    link only where the point's cues cannot tell it from the base (see the module's notes).
    Deterministic.

    Returns
    -------
    labels_a : (len(dense_a),) int
    labels_b : (len(dense_b),) int
    """
    if config.passes < 1:
        raise ValueError(f"AssignConfig.passes must be >= 1, got {config.passes}")
    labels = np.asarray(segmentation.labels)
    Ts = list(segmentation.transforms)
    inv = [T.inverse() for T in Ts]
    rms = np.zeros(len(Ts))
    rms[:len(segmentation.rms)] = np.asarray(segmentation.rms, float)[:len(Ts)]
    surf_a = surf_b = None
    if views_a and views_b:
        occ_a = dense_a.points if occluders_a is None else occluders_a
        occ_b = dense_b.points if occluders_b is None else occluders_b
        surf_a, surf_b = side_by_side(
            lambda: _Surface(views_a, occ_a, config.zbuffer_cell, config.violation_window),
            lambda: _Surface(views_b, occ_b, config.zbuffer_cell, config.violation_window))
    seen_a = seen_b = None
    if views_a and views_b:
        seen_a, seen_b = seen_by(dense_a, views_a), seen_by(dense_b, views_b)
    # A's and B's cues and labels are independent within a pass: side by side
    ev_a, ev_b = side_by_side(
        lambda: _Evidence(dense_a.points, dense_a.normals, dense_b.points, Ts, rms, points_a,
                          labels, surf_a, surf_b, config, static_a, base, seen_a, seen_b),
        lambda: _Evidence(dense_b.points, dense_b.normals, dense_a.points, inv,
                          rms / segmentation.scale, points_b, labels, surf_b, surf_a, config,
                          static_b, base, seen_b, seen_a))
    lab_a = lab_b = None
    for _ in range(config.passes):
        lab_a, lab_b = side_by_side(partial(ev_a.label, lab_b), partial(ev_b.label, lab_a))
    return lab_a, lab_b
