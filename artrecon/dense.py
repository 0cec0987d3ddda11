"""Dense oriented points per configuration, on the CPU (the method's PMVS step).

pycolmap's PatchMatch stereo needs CUDA, so this stage uses two-view stereo instead:

1. every registered image is paired with a neighbour to its right (baseline mostly along the
   image x axis, triangulation angle in a useful range, most shared sparse points); by default
   only a cover of those pairs is kept, about every second one, such that every image is still
   in a pair (:func:`cover_pairs`; :attr:`DenseConfig.pair_cover`);
2. the pair is rectified with the SfM poses (OpenCV ``stereoRectify``) at a reduced resolution
   and OpenCV semi-global matching (``StereoSGBM``) gives a disparity map, its search range taken
   from the sparse points the two images share;
3. disparities are back-projected to 3D (only those near the object: within
   ``crop_radius`` of the cameras' focus point); each image gets a depth map of its pair's
   points;
4. the points are merged on a voxel grid (position and colour averaged);
5. depth fusion: every merged point is checked against every depth map. A view whose depth
   agrees with the point's (relative tolerance) sees it; a view whose depth map shows a surface
   clearly *behind* the point looked through it. A point is kept when at least
   ``min_consistent`` other views agree and few looked through it: the rim of foreground depth
   that block matching leaves beside thin parts (edge fattening) floats in free space seen from
   other directions. The views that agree are the images that see the point;
6. normals come from local PCA, oriented toward the cameras that see the point.

All thresholds are relative (depth ratios, pixels), so the stage works in the arbitrary scale of
an SfM model. Because the views ring the object, the point set covers it all around, the back
side included.

:func:`object_region` then separates the object from the static background (see its docstring).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

from artrecon.errors import ReconstructionError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DenseConfig:
    """Settings of the dense stage."""

    downsample: int = 2
    """Stereo runs on images shrunk by this factor (2: 640x480 -> 320x240; 4x fewer pixels).
    1 (full resolution) halves the point spacing, for objects whose parts are only a few
    millimetres thick (scissors: 0.966 of the points on the right link against 0.947 at 2), at
    about 5x the dense stage's time."""
    min_pair_angle_deg: float = 4.0
    """Smallest triangulation angle of a stereo pair (smaller: depth too noisy)."""
    max_pair_angle_deg: float = 25.0
    """Largest triangulation angle (larger: the views differ too much for block matching)."""
    block_size: int = 5
    """SGBM block size in (downsampled) pixels."""
    uniqueness_ratio: int = 10
    """SGBM uniqueness margin in percent."""
    disparity_margin: float = 8.0
    """Pixels added on both sides of the sparse points' disparity range."""
    edge_erosion_px: int = 2
    """Pixels (downsampled) dropped on the near side of a depth edge in each disparity map: the
    rim of foreground that block matching spreads onto the background (about half the block).
    0 keeps them."""
    edge_jump_px: float = 0.5
    """Disparity step (pixels) that marks a depth edge for :attr:`edge_erosion_px` (at the
    default rings a 0.5 px step is about 4 mm of depth, half a pliers' thickness)."""
    depth_tolerance: float = 0.01
    """Two depths agree when they differ by less than this fraction of the depth (1%: a few
    SGBM sub-pixel steps at the ring's baselines)."""
    min_consistent: int = 2
    """A point must agree with the depth maps of at least this many other images."""
    max_free_space_ratio: float = 0.25
    """... and no more than this share of those images' count may have looked *through* it (their
    depth map shows a surface further than the point along the ray, beyond the tolerance): the
    rim of foreground depth SGBM leaves beside thin parts floats in free space seen from other
    directions."""
    crop_radius: float = 0.9
    """Only points within this fraction of the median camera distance from the cameras' focus
    point are kept (the object, the table around it and anything that can hide it; the room
    beyond is background that no later stage needs densely)."""
    voxel_pixels: float = 1.5
    """Merge voxel edge, in downsampled pixels at the median camera distance to the focus."""
    normal_neighbours: int = 16
    """Neighbours for the PCA normal."""
    pair_cover: bool = True
    """Stereo on a cover of the pairs only: few pairs that still hold every image, reference or
    partner (:func:`cover_pairs`: about every second image of a ring gets a depth
    map). False: every image is a reference. On a ring of views 10 degrees apart each image's
    neighbours see the same surface, so the cover halves the stage's stereo at nearly the same
    points: on the seven scenes at half resolution (seeds 0-2) every axis within 0.025 deg of
    all pairs', dense stereo 10.8-13.2 -> 5.7-7.4 CPU s per scene; pliers at full resolution
    19.5 -> ~10 CPU s per configuration, same axis. Thin parts reconstructed at full resolution
    lose the most from the fewer depth maps that check each point: scissors' hinge axis
    0.04 -> 0.31 deg, so ``scenes/scissors.xml`` turns the cover off."""

    def __post_init__(self) -> None:
        if self.downsample < 1:
            raise ValueError(f"DenseConfig.downsample must be 1 (full resolution) or more, got "
                             f"{self.downsample}")


@dataclass
class DensePoints:
    """Oriented points of one configuration.

    Attributes
    ----------
    points : (n, 3) float
        Positions in the SfM world frame.
    normals : (n, 3) float
        Unit normals, pointing toward the cameras that see the point.
    colors : (n, 3) uint8
        RGB colour.
    visibility : (n, m) bool
        ``visibility[p, k]``: image ``image_names[k]`` sees point ``p``.
    image_names : list of str
    """

    points: np.ndarray
    normals: np.ndarray
    colors: np.ndarray
    visibility: np.ndarray
    image_names: list[str]

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, mask: np.ndarray) -> DensePoints:
        """The points selected by a boolean or index array."""
        return DensePoints(self.points[mask], self.normals[mask], self.colors[mask],
                           self.visibility[mask], list(self.image_names))


@dataclass
class _View:
    name: str
    K: np.ndarray  # (3, 3) at full resolution, OpenCV
    T_cw: np.ndarray  # (4, 4) camera from world
    centre: np.ndarray  # (3,)
    axis: np.ndarray  # (3,) viewing direction in the world
    point_ids: set


def _views(sfm) -> list[_View]:
    rec = sfm.reconstruction
    views = []
    for img in sorted(rec.images.values(), key=lambda im: im.name):
        if not img.has_pose:
            continue
        T_cw = np.eye(4)
        T_cw[:3, :] = img.cam_from_world().matrix()
        R = T_cw[:3, :3]
        ids = {p.point3D_id for p in img.points2D if p.has_point3D()}
        views.append(_View(img.name, sfm.intrinsics(img.name), T_cw, -R.T @ T_cw[:3, 3], R[2],
                           ids))
    return views


def _scaled_K(K: np.ndarray, f: int) -> np.ndarray:
    """K of an image shrunk by ``f`` (pixel centres stay at integer coordinates)."""
    Ks = K.copy()
    Ks[:2, :2] /= f
    Ks[:2, 2] = (K[:2, 2] + 0.5) / f - 0.5
    return Ks


def _load(path, f: int) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ReconstructionError(f"dense: cannot read image {path}")
    if f > 1:
        img = cv2.resize(img, (img.shape[1] // f, img.shape[0] // f), interpolation=cv2.INTER_AREA)
    return img


def choose_partners(views: list[_View], centre: np.ndarray, config: DenseConfig) -> dict:
    """For each view index, the partner view index to its right (or missing if none fits)."""
    partners = {}
    for i, vi in enumerate(views):
        best, best_score = None, 0
        for j, vj in enumerate(views):
            if j == i:
                continue
            b = vi.T_cw[:3, :3] @ (vj.centre - vi.centre)  # baseline in camera i
            if b[0] <= 0 or abs(b[1]) > 0.5 * b[0]:
                continue
            ri, rj = centre - vi.centre, centre - vj.centre
            cosang = ri @ rj / (np.linalg.norm(ri) * np.linalg.norm(rj))
            ang = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
            if not config.min_pair_angle_deg <= ang <= config.max_pair_angle_deg:
                continue
            score = len(vi.point_ids & vj.point_ids)
            if score > best_score:
                best, best_score = j, score
        if best is not None:
            partners[i] = best
    return partners


def cover_pairs(partners: dict) -> dict:
    """Few of the stereo ``partners`` (reference view index -> partner index, from
    :func:`choose_partners`) that still hold every image they hold, as reference or partner.

    A greedy edge cover (not always the smallest one): first a maximal set of pairs that share
    no image (in reference order), then, for each image left out, its own pair (or, if it is
    only ever a partner, the first pair it is the partner of). On a ring whose neighbours pair
    up that keeps every second pair (one more on an odd ring), whichever way round the ring the
    partners lie."""
    keep, held = {}, set()
    for i, j in sorted(partners.items()):
        if i not in held and j not in held:
            keep[i] = j
            held.update((i, j))
    for i, j in sorted(partners.items()):
        if i not in held or j not in held:
            keep[i] = j
            held.update((i, j))
    return keep


def _disparity_range(vi: _View, vj: _View, R1, R2, P1, P2, sparse: np.ndarray,
                     margin: float) -> tuple[int, int]:
    """SGBM's ``(minDisparity, numDisparities)`` for the pair rectified by ``R1, R2, P1, P2``
    (OpenCV ``stereoRectify``), from the ``sparse`` (m, 3) world points both images see,
    widened by ``margin`` pixels on both sides; at most 256 disparities."""
    # The range's far end, a known flaw kept on purpose: P2 expects points in the first
    # rectified frame (R1 @ X_i), so projecting R2 @ X_j counts the baseline twice and the far
    # end sits at about twice the true disparity of the farthest shared points (room, far
    # table): the stereo searches no further than about half their depth. Correcting that alone
    # made the dense points less accurate (pliers, known cameras: median distance to the true
    # surface 1.59 -> 2.06 mm, share beyond 3 mm 14% -> 28%), because the too-high range cuts
    # small-disparity outliers; it should change only together with an outlier filter that does
    # that job on purpose. (On pliers at 12 views per ring with a self-calibrated camera the
    # range missed the object: 47 consistent dense points instead of ~100k.) The range holds
    # the object only while the shared points spread to the far table: with the features in the
    # object's region alone it missed it (pliers: 2k points instead of 26k), so SfM keeps coarse
    # background features beside the region's (artrecon.sfm.SfMConfig.background_features).
    # The near end is the shared points' true disparity (R1 @ X_i through P2): the doubled one
    # searched down to half the nearest point's depth, empty space holding no surface, for
    # about half of SGBM's work (scissors A at full resolution: 164 -> 86 disparities per pair
    # on average, the dense step 24.5 -> 20.0 CPU s, 98.3% of the object's points the same bit
    # for bit and as many of them).
    # The doubled far end also drops the upper ring's view of the object: looking down, the
    # farthest shared points are the table just around the object, twice their disparity is
    # nearer than the object's top, and SGBM finds nothing of it (benchmarks/bench_stereo.py,
    # seeds 0-2: the range holds less than 90% of the object in 25-26 of 61 pairs per
    # configuration of pliers and pliers_panda, 49 of 121 of scissors, 13-23 of 43-61 of the
    # cabinets' and drawer's A, 7 of barrett_hand and truck_panda, 0-3 of the trucks; on pliers
    # and scissors exactly the upper ring's pairs). Holding the shared points within the crop
    # in the range too (their true disparities) gave those pairs the object, and made the thin
    # objects' joints worse on seeds 0-2: scissors' hinge 0.03-0.12 -> 0.16-0.41 deg, its
    # moving link's motion 0.01-0.06 -> 0.07-0.20 deg off (the surface refit), pliers seed 1
    # 0.26 -> 0.28; over the 39 joints median 0.029 -> 0.033, max 0.26 -> 0.41 deg (a higher
    # surface weight does not mend it: 1 and 3 worse still). Not for SGBM's bias (from above,
    # -0.16 to -0.24 px at disparities near 50 px, 1.2-1.8 mm of depth along the faces'
    # normals): with it cut to a third (P1, below) the upper ring's points still took scissors'
    # hinge to 0.35-0.53 deg. So the upper ring serves SfM, matching and registration, and the
    # dense surface comes from the side rings; a range that says so on purpose should replace
    # this accident once it is known why the view from above hurts the flat parts.
    Xi = (vi.T_cw[:3, :3] @ sparse.T).T + vi.T_cw[:3, 3]
    Xj = (vj.T_cw[:3, :3] @ sparse.T).T + vj.T_cw[:3, 3]
    rect_i = R1 @ Xi.T  # the points in the first rectified frame
    xl = (P1[:, :3] @ rect_i).T
    xr = (P2[:, :3] @ (R2 @ Xj.T)).T + P2[:, 3]
    xt = (P2[:, :3] @ rect_i).T + P2[:, 3]
    left_x = xl[:, 0] / xl[:, 2]
    lo = float(np.percentile(left_x - xr[:, 0] / xr[:, 2], 1))
    hi = float(np.percentile(left_x - xt[:, 0] / xt[:, 2], 99))
    min_disp = int(np.floor(lo - margin))
    num = int(np.ceil((hi + margin - min_disp) / 16.0)) * 16
    num = max(16, min(num, 256))
    return min_disp, num


@dataclass(frozen=True)
class PairDisparity:
    """One stereo pair's SGBM disparity, in the first image rectified (:func:`pair_disparity`)."""

    disparity: np.ndarray
    """(h, w) float32, pixels (left x minus right x)."""
    valid: np.ndarray
    """(h, w) bool: inside the image and strictly inside the searched range."""
    kept: np.ndarray
    """(h, w) bool: valid and not dropped beside a depth edge (the pixels the stage turns into
    points)."""
    left: np.ndarray
    """The first image, rectified (BGR)."""
    R1: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    """OpenCV ``stereoRectify``'s rotations, projections and reprojection matrix."""
    search: tuple[int, int]
    """SGBM's ``(minDisparity, numDisparities)``."""


def pair_disparity(vi: _View, vj: _View, img_i, img_j, sparse: np.ndarray,
                   config: DenseConfig) -> PairDisparity | None:
    """The SGBM disparity of images ``img_i`` and ``img_j`` (at ``config.downsample``) of views
    ``vi`` and ``vj``, its range from the ``sparse`` (m, 3) world points both see; None for a
    pair that rectifies vertically or shares fewer than 10 points."""
    f = config.downsample
    h, w = img_i.shape[:2]
    Ki, Kj = _scaled_K(vi.K, f), _scaled_K(vj.K, f)
    T_ji = vj.T_cw @ np.linalg.inv(vi.T_cw)
    no_dist = np.zeros(5)
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(Ki, no_dist, Kj, no_dist, (w, h),
                                                T_ji[:3, :3].copy(), T_ji[:3, 3].reshape(3, 1),
                                                flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1)
    if abs(P2[1, 3]) > abs(P2[0, 3]):
        return None  # vertical rectification; the partner choice should prevent this
    # Disparity range from the sparse points seen by both images.
    if len(sparse) < 10:
        return None
    min_disp, num = _disparity_range(vi, vj, R1, R2, P1, P2, sparse, config.disparity_margin)
    m1x, m1y = cv2.initUndistortRectifyMap(Ki, no_dist, R1, P1, (w, h), cv2.CV_32FC1)
    m2x, m2y = cv2.initUndistortRectifyMap(Kj, no_dist, R2, P2, (w, h), cv2.CV_32FC1)
    left = cv2.remap(img_i, m1x, m1y, cv2.INTER_LINEAR)
    right = cv2.remap(img_j, m2x, m2y, cv2.INTER_LINEAR)
    inside = (m1x >= 0) & (m1x <= w - 1) & (m1y >= 0) & (m1y <= h - 1)
    bs = config.block_size
    # P1 = 8 x 3 bs^2 (OpenCV's suggestion) pulls the disparities toward whole pixels and biases
    # them on slanted surfaces: against the rendered depth the object's median error was -0.07
    # to -0.38 px on pliers and scissors (full resolution) and +0.04 to +0.15 px on truck (half),
    # the fused points 0.6-1.2 mm behind the pliers' surface. P1 = 1 x 3 bs^2 cut that to -0.14
    # to -0.02 and -0.03 to +0.06 px at the same spread, and the joints were no better (seeds 0-2:
    # axis median 0.029 -> 0.033 deg, RMS 0.077 -> 0.083, max 0.262 -> 0.247; pliers seed 1 0.26
    # -> 0.17, scissors seed 1 0.03 -> 0.25): the stereo's bias is not what limits them.
    sgbm = cv2.StereoSGBM_create(minDisparity=min_disp, numDisparities=num, blockSize=bs,
                                 P1=8 * 3 * bs * bs, P2=32 * 3 * bs * bs, disp12MaxDiff=1,
                                 uniquenessRatio=config.uniqueness_ratio, speckleWindowSize=100,
                                 speckleRange=2, mode=cv2.StereoSGBM_MODE_SGBM_3WAY)
    # SGBM leaves the first min_disp + num columns of the left image without a match (their
    # candidates fall off the right image): pad both images so every real column gets its range.
    pad_l, pad_r = max(0, min_disp + num), max(0, -min_disp)
    padded = [cv2.copyMakeBorder(im, 0, 0, pad_l, pad_r, cv2.BORDER_CONSTANT, value=0)
              for im in (left, right)]
    disp = sgbm.compute(*padded)[:, pad_l:pad_l + w].astype(np.float32) / 16.0
    valid = inside & (disp > min_disp) & (disp < min_disp + num - 1)
    if config.edge_erosion_px > 0:
        # Block matching fattens the foreground: near a depth edge the window is dominated by
        # the nearer surface, whose disparity spills a few pixels onto the farther one. Drop the
        # pixels within edge_erosion_px of a clearly smaller disparity (a farther surface); other
        # views, whose edges fall elsewhere on the object, see those points cleanly.
        r = config.edge_erosion_px
        far = np.where(valid, disp, np.float32(1e6))
        nearest_far = cv2.erode(far, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
        kept = valid & (disp - nearest_far <= config.edge_jump_px)
    else:
        kept = valid
    return PairDisparity(disp, valid, kept, left, R1, P1, P2, Q, (min_disp, num))


def _pair_points(vi: _View, vj: _View, img_i, img_j, sparse: np.ndarray, config: DenseConfig):
    """World points and colours of the SGBM disparity of one rectified pair."""
    pair = pair_disparity(vi, vj, img_i, img_j, sparse, config)
    if pair is None:
        return None
    pts_rect = cv2.reprojectImageTo3D(pair.disparity, pair.Q)[pair.kept]
    cols = pair.left[pair.kept][:, ::-1]  # BGR -> RGB
    X_cam = pts_rect @ pair.R1  # rectified -> camera i (R1 maps camera i to rectified)
    T_wc = np.linalg.inv(vi.T_cw)
    X_w = X_cam @ T_wc[:3, :3].T + T_wc[:3, 3]
    ok = X_cam[:, 2] > 0
    return X_w[ok], cols[ok]


def _project(view: _View, K: np.ndarray, X: np.ndarray, w: int, h: int):
    Xc = X @ view.T_cw[:3, :3].T + view.T_cw[:3, 3]
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.rint(K[0, 0] * Xc[:, 0] / z + K[0, 2]).astype(np.int64, copy=False)
        v = np.rint(K[1, 1] * Xc[:, 1] / z + K[1, 2]).astype(np.int64, copy=False)
    inside = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return u, v, z, inside


def _zbuffer(u: np.ndarray, v: np.ndarray, z: np.ndarray, w: int, h: int) -> np.ndarray:
    """(h, w) depth map holding the nearest of the depths ``z`` at pixels ``(u, v)`` (inf where
    none falls)."""
    pix = v * w + u
    order = np.lexsort((z, pix))
    pix, z = pix[order], z[order]
    first = np.r_[True, pix[1:] != pix[:-1]]
    D = np.full(h * w, np.inf)
    D[pix[first]] = z[first]
    return D.reshape(h, w)


def _fuse_depths(P: np.ndarray, views: list[_View], Ks: list[np.ndarray], depth: dict,
                 w: int, h: int, tol: float, chunk: int = 1 << 17
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every point of ``P`` (n, 3) against every depth map (``depth``: view index -> (h, w)):
    how many views' depths agree with it (within ``tol`` of its depth), how many show a surface
    clearly behind it (looked through it), and which views agree, view-major ((views, n) bool:
    one view's row is written at a time, where a point-major (n, views) array took a strided
    write per view, most of this loop's time with ~10^6 points).

    Only the points that project into a view are looked up there: a point outside it has no
    depth there (neither agrees nor is looked through), as before when the whole array was
    compared against an infinite depth.

    The points go through in blocks of ``chunk`` against every view: a block's dozen
    temporaries stay in the processor's cache, where the whole cloud's (pliers at full
    resolution: 1.3 M points) went through memory once per view and operation (5.8 -> 4.5 CPU
    s over 121 views; the same figures, bit for bit)."""
    n = len(P)
    agree = np.zeros(n, dtype=np.int32)
    through = np.zeros(n, dtype=np.int32)
    vis = np.zeros((len(views), n), dtype=bool)
    for start in range(0, n, chunk):
        block = P[start:start + chunk]
        for k, Dk in depth.items():
            u, v, z, inside = _project(views[k], Ks[k], block, w, h)
            idx = np.flatnonzero(inside)
            d = Dk.ravel()[v[idx] * w + u[idx]]
            z = z[idx]
            seen = np.isfinite(d)
            ok = seen & (np.abs(d - z) < tol * z)
            idx += start
            vis[k, idx] = ok
            agree[idx] += ok
            through[idx] += seen & (d > (1.0 + tol) * z)
    return agree, through, vis


def _voxel_merge(P: np.ndarray, C: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) and colours (n, 3) averaged per cubic voxel of edge ``voxel`` (float64;
    the colours may be uint8: summed in float64, the same sums as of their float64 copies).

    The voxels' linear indices are sorted as int32 when they fit (the same stable order as
    int64's), and the colours are gathered as given: a full-resolution configuration merges
    ~7 M stereo points, whose colours as float64, and their sorted copy, took 2 x 169 MB
    (pliers A, in the pipeline: the dense step's time the same within its run-to-run spread,
    21.5-22.1 against 21.4-23.5 CPU s; dense.ply the same bytes)."""
    keys = np.floor(P / voxel).astype(np.int64)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    lin = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    if int(np.prod(dims, dtype=np.float64)) < np.iinfo(np.int32).max:
        lin = lin.astype(np.int32)
    order = np.argsort(lin, kind="stable")
    lin = lin[order]
    starts = np.flatnonzero(np.r_[True, lin[1:] != lin[:-1]])
    counts = np.diff(np.r_[starts, len(lin)])[:, None]
    Pm = np.add.reduceat(P[order], starts, axis=0) / counts
    Cm = np.add.reduceat(C[order], starts, axis=0, dtype=np.float64) / counts
    return Pm, Cm


@dataclass
class FusedPoints:
    """The dense stage's points before their normals (:func:`fused_points`): every point the depth
    fusion kept, the object's and the background's.

    Attributes
    ----------
    points : (n, 3) float
    colors : (n, 3) uint8
    visibility : (n, m) bool
    image_names : list of str
    centres : (m, 3) float
        Camera centres of ``image_names``.
    normal_neighbours : int
        Neighbours of the PCA normal (:attr:`DenseConfig.normal_neighbours`).
    """

    points: np.ndarray
    colors: np.ndarray
    visibility: np.ndarray
    image_names: list[str]
    centres: np.ndarray
    normal_neighbours: int

    def oriented(self, mask: np.ndarray | None = None) -> DensePoints:
        """The points selected by ``mask`` (default: all) with their normals, each from its
        neighbours among *all* the points: the same normals as for the whole cloud, at the cost
        of the selection (the object is a few percent of a full-resolution cloud)."""
        idx = np.arange(len(self.points)) if mask is None else np.asarray(mask)
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        P, vis = self.points[idx], self.visibility[idx]
        normals = estimate_normals(P, vis, self.centres, self.normal_neighbours,
                                   neighbours=self.points)
        return DensePoints(P, normals, self.colors[idx], vis, list(self.image_names))


def dense_points(sfm, config: DenseConfig = DenseConfig(), progress=None) -> DensePoints:
    """Dense oriented points of one SfM model (see the module docstring for the method): all of
    :func:`fused_points`, with normals."""
    return fused_points(sfm, config, progress).oriented()


@dataclass(frozen=True)
class StereoPlan:
    """The stereo pairs of one SfM model as the dense stage forms them (:func:`stereo_plan`)."""

    views: list[_View]
    """The registered images, by name."""
    pairs: list[tuple[int, int]]
    """(reference, partner) indices into ``views``, sorted: steps 1 and 2 of the module
    docstring."""
    centres: np.ndarray
    """(m, 3) the views' camera centres."""
    centre: np.ndarray
    """The cameras' focus point (:func:`focus_point`)."""
    image_dir: Path
    downsample: int
    points: np.ndarray
    """(m, 3) the SfM points."""
    point_index: dict
    """SfM point id -> row of ``points``."""

    @property
    def cam_dist(self) -> float:
        """The cameras' median distance to the focus point."""
        return float(np.median(np.linalg.norm(self.centres - self.centre, axis=1)))

    def shared_points(self, i: int, j: int) -> np.ndarray:
        """The SfM points views ``i`` and ``j`` both see, (k, 3)."""
        rows = [self.point_index[p] for p in self.views[i].point_ids & self.views[j].point_ids
                if p in self.point_index]
        return self.points[rows]

    def image(self, k: int) -> np.ndarray:
        """View ``k``'s image at the stereo's resolution (BGR)."""
        return _load(self.image_dir / self.views[k].name, self.downsample)


def stereo_plan(sfm, config: DenseConfig = DenseConfig()) -> StereoPlan:
    """The dense stage's stereo pairs of ``sfm`` (an :class:`artrecon.sfm.SfMResult`).

    Raises
    ------
    ReconstructionError
        No two registered images form a stereo pair.
    """
    views = _views(sfm)
    rec = sfm.reconstruction
    pid = np.array(list(rec.point3D_ids()))
    xyz = np.array([rec.points3D[i].xyz for i in pid]) if len(pid) else np.zeros((0, 3))
    centres = np.array([v.centre for v in views])
    centre = focus_point(centres, np.array([v.axis for v in views]))
    partners = choose_partners(views, centre, config)
    if config.pair_cover:
        partners = cover_pairs(partners)
    if not partners:
        raise ReconstructionError("dense: no stereo pair among the registered images (neighbours"
                                  " too close, too far apart, or above/below each other); use a "
                                  "ring of views 5-20 degrees apart")
    return StereoPlan(views, sorted(partners.items()), centres, centre,
                      Path(sfm.image_dir), config.downsample, xyz,
                      {int(p): k for k, p in enumerate(pid)})


def fused_points(sfm, config: DenseConfig = DenseConfig(), progress=None) -> FusedPoints:
    """Dense points of one SfM model, without normals (steps 1-5 of the module docstring); their
    normals (step 6) by :meth:`FusedPoints.oriented`, for the points that need them.

    Parameters
    ----------
    sfm : artrecon.sfm.SfMResult
    config : DenseConfig
    progress : text stream, optional
        Where to draw a tqdm bar (None: no bar).

    Returns
    -------
    FusedPoints

    Raises
    ------
    ReconstructionError
        No stereo pair could be formed or no point survived the consistency check.
    """
    plan = stereo_plan(sfm, config)
    views, centres, centre, cam_dist = plan.views, plan.centres, plan.centre, plan.cam_dist
    f = config.downsample
    images = {}

    def img(k):
        if k not in images:
            images[k] = plan.image(k)
        return images[k]

    h, w = img(plan.pairs[0][0]).shape[:2]
    Ks = [_scaled_K(v.K, f) for v in views]
    clouds, colours, depth = [], [], {}
    it = plan.pairs
    if progress is not None:
        it = tqdm(it, desc="dense stereo", unit="pair", leave=False, file=progress)
    for i, j in it:
        out = _pair_points(views[i], views[j], img(i), img(j), plan.shared_points(i, j), config)
        if out is None or len(out[0]) == 0:
            continue
        X, c = out
        u, v, z, inside = _project(views[i], Ks[i], X, w, h)
        near = inside & (np.linalg.norm(X - centre, axis=1) < config.crop_radius * cam_dist)
        if not near.any():
            continue
        depth[i] = _zbuffer(u[near], v[near], z[near], w, h)
        clouds.append(X[near])
        colours.append(c[near])
    if not clouds:
        raise ReconstructionError("dense: stereo matching gave no points on any image pair")
    P = np.concatenate(clouds)
    C = np.concatenate(colours)  # uint8: _voxel_merge averages them in float64
    # Merge on a voxel grid about 1.5 downsampled pixels wide at the cameras' distance, then check
    # every merged point against every depth map (depth fusion): views whose depth agrees see it;
    # a view that sees a surface clearly *behind* it looked through it (free space), as at the
    # foreground-fattened rim SGBM leaves beside thin parts.
    voxel = config.voxel_pixels * cam_dist / Ks[0][0, 0]
    Pm, Cm = _voxel_merge(P, C, voxel)
    n = len(Pm)
    agree, through, vis = _fuse_depths(Pm, views, Ks, depth, w, h, config.depth_tolerance)
    good = (agree >= config.min_consistent + 1) & (through <= config.max_free_space_ratio * agree)
    if good.sum() < 10:
        raise ReconstructionError(f"dense: only {int(good.sum())} points agree across views; the "
                                  "SfM poses may be wrong or the surfaces lack texture")
    Pm, Cm = Pm[good], Cm[good]
    vis = np.ascontiguousarray(vis[:, good].T)  # (points, views), as the rest reads it
    log.info("dense: %d pairs, %d points, %d merged, %d consistent (voxel %.4g; %d dropped as "
             "seen through)", len(depth), len(P), n, len(Pm), voxel,
             int(((agree >= config.min_consistent + 1) & ~good).sum()))
    return FusedPoints(Pm, np.clip(np.rint(Cm), 0, 255).astype(np.uint8), vis,
                       [v.name for v in views], centres, config.normal_neighbours)


def estimate_normals(points: np.ndarray, visibility: np.ndarray, centres: np.ndarray,
                     k: int = 16, neighbours: np.ndarray | None = None) -> np.ndarray:
    """Unit normals (n, 3) by PCA of the ``k`` nearest neighbours, turned toward the mean
    direction to the cameras that see each point (``visibility`` (n, m), ``centres`` (m, 3)).
    ``neighbours`` (N, 3): the cloud the neighbours are taken from, holding ``points`` (default:
    ``points`` itself)."""
    points = np.asarray(points, float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points: expected shape (n, 3), got {points.shape}")
    cloud = points if neighbours is None else np.asarray(neighbours, float)
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise ValueError(f"neighbours: expected shape (N, 3), got {cloud.shape}")
    k = min(k, len(cloud))
    _, nb = cKDTree(cloud).query(points, k=k)
    nbrs = cloud[nb]
    d = nbrs - nbrs.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", d, d)
    _, vecs = np.linalg.eigh(cov)
    normals = vecs[:, :, 0]
    counts = visibility.sum(1, keepdims=True).clip(min=1)
    to_cam = (visibility.astype(float) @ centres) / counts - points
    flip = np.einsum("ij,ij->i", normals, to_cam) < 0
    normals[flip] *= -1
    return normals


def focus_point(centres: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """The point (3,) closest, in least squares, to all cameras' optical axes.

    Parameters
    ----------
    centres : (m, 3) float
        Camera centres.
    axes : (m, 3) float
        Unit viewing directions.
    """
    centres = np.asarray(centres, float)
    axes = np.asarray(axes, float)
    if centres.shape != axes.shape or centres.ndim != 2 or centres.shape[1] != 3:
        raise ValueError(f"centres and axes: expected two (m, 3) arrays, got {centres.shape} and "
                         f"{axes.shape}")
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c, a in zip(centres, axes, strict=True):
        M = np.eye(3) - np.outer(a, a)
        A += M
        b += M @ c
    return np.linalg.lstsq(A, b, rcond=None)[0]


#: Points the support plane's RANSAC counts each hypothesis's inliers on, at most
#: (:func:`fit_support_plane`): a random sample of the cloud. Measured on a full-resolution
#: pliers cloud (853k points, seeds 0-2): object_region 2.7-3.2 s -> 0.2-0.3 s; its object
#: points differ by 8, 0 and 3 of 26338 (the region's own seed-to-seed spread is of that size).
PLANE_SCORE_SAMPLE = 20_000


@dataclass(frozen=True)
class RegionConfig:
    """How the object is told from the static background (table, room)."""

    radius_fraction: float = 0.6
    """Keep points within this fraction of the median camera distance from the focus point
    (the cameras circle the object and look at it; the room is farther out)."""
    plane_tolerance: float = 0.01
    """Support plane inlier distance, as a fraction of the median camera distance."""
    plane_min_fraction: float = 0.15
    """A plane is taken for the table only if it holds this share of the cropped points."""
    plane_iterations: int = 500
    """RANSAC hypotheses for the support plane."""
    plane_noise_factor: float = 3.0
    """Points up to this many times the table's own noise (robust spread of its inliers' heights)
    above the plane are the table; the cut never exceeds 1.5 x the inlier distance."""
    plane_min_height: float = 0.005
    """Floor of that cut, as a fraction of the median camera distance (2 mm at 0.39 m: the
    sparse points of a clean table scatter by a few tenths of a mm, and their tail must not join
    the object)."""


def fit_support_plane(P: np.ndarray, centres: np.ndarray, tol: float, iterations: int,
                      min_fraction: float, seed: int = 0):
    """The plane the object stands on among points ``P`` (m, 3): RANSAC for the dominant plane
    (inlier band ``tol``, ``iterations`` triplets from ``seed``), refitted to its inliers.

    Returns ``(normal (3,), centroid (3,), inliers (m,) bool)``, the normal towards the cameras,
    or None when the plane holds fewer than ``min_fraction`` of the points or the cameras
    (``centres`` (k, 3)) lie on both sides of it (not a support plane)."""
    rng = np.random.default_rng(seed)
    # hypotheses scored on a sample: a full-resolution cloud holds ~10^6 points, and 500 counts
    # over all of them were seconds, where a sample of 20k ranks the planes alike (the chosen
    # one is then refitted to its inliers among all the points)
    S = P
    if len(P) > PLANE_SCORE_SAMPLE:
        S = P[np.random.default_rng((seed, 1)).choice(len(P), PLANE_SCORE_SAMPLE, replace=False)]
    best, best_n = None, 0
    for _ in range(iterations):
        a, b, c = P[rng.choice(len(P), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-12:
            continue
        n /= np.linalg.norm(n)
        cnt = int((np.abs((S - a) @ n) < tol).sum())
        if cnt > best_n:
            best, best_n = (n, a), cnt
    if best is None or best_n < min_fraction * len(S):
        return None
    n, a = best
    inl = np.abs((P - a) @ n) < tol
    # refine the plane on its inliers
    q = P[inl]
    cen = q.mean(0)
    n = np.linalg.svd(q - cen, full_matrices=False)[2][2]
    side = (centres - cen) @ n
    if not (np.all(side > 0) or np.all(side < 0)):
        return None  # cameras on both sides: not a support plane
    return (n if np.median(side) > 0 else -n), cen, inl


def object_region(points: np.ndarray, centres: np.ndarray, axes: np.ndarray,
                  config: RegionConfig = RegionConfig(), seed: int = 0) -> np.ndarray:
    """Mask (n,) of the points that belong to the object rather than the background.

    The cameras ring the object and look at it, so (1) points farther from the focus point of
    the optical axes than ``radius_fraction`` x the median camera distance (walls, far table) are
    dropped, and (2) the dominant plane of what remains, if the cameras all lie on one side of
    it, is the table the object stands on: its inliers and everything beyond it are dropped.

    Parameters
    ----------
    points : (n, 3) float
    centres, axes : (m, 3) float
        Camera centres and unit viewing directions.
    config : RegionConfig
    seed : int

    Returns
    -------
    mask : (n,) bool
    """
    points = np.asarray(points, float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points: expected shape (n, 3), got {points.shape}")
    focus = focus_point(centres, axes)
    cam_dist = float(np.median(np.linalg.norm(centres - focus, axis=1)))
    mask = np.linalg.norm(points - focus, axis=1) < config.radius_fraction * cam_dist
    idx = np.flatnonzero(mask)
    if len(idx) < 10:
        return mask
    P = points[idx]
    tol = config.plane_tolerance * cam_dist
    plane = fit_support_plane(P, centres, tol, config.plane_iterations,
                              config.plane_min_fraction, seed)
    if plane is None:
        return mask
    n, cen, inl = plane
    height = (P - cen) @ n
    # Cut just above the table's own noise rather than at the RANSAC band: a thin object lying
    # on the table (scissors: 0.5 - 9 mm high, cameras 0.39 m away, band 3.9 mm) would lose all
    # of its lower half at 1.5 x the band. The spread is robust (MAD) to the object's few points
    # inside the band.
    h_in = height[inl]
    level = float(np.median(h_in))
    sigma = 1.4826 * float(np.median(np.abs(h_in - level)))
    cut = min(1.5 * tol, max(config.plane_noise_factor * sigma,
                             config.plane_min_height * cam_dist))
    mask[idx[height - level < cut]] = False
    log.info("object region: %d of %d points (table plane removed: %d, cut %.3g above it, "
             "table noise %.3g)", int(mask.sum()), len(points), int(inl.sum()), cut, sigma)
    return mask
