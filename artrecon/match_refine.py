"""The matches' points made the same physical point in both configurations: their keypoints
refined photometrically, their 3D points triangulated again.

A 3D-3D match pairs an SfM point of A with one of B, each triangulated from SIFT keypoints of its
own configuration. SIFT places a keypoint at a blob's centre at the blob's scale, a few tenths of
a pixel from where the same blob lies in another view, differently in each image and each
configuration; so a match's two points are not quite the same physical point (the links' motion
fits see 0.2-0.7 mm of spread around their motions, where the images hold far less). The
images themselves say where one point is in every view:

- each match's point of A gets a small square patch on its surface's tangent plane (the nearest
  dense point's normal), seen in the A image that views it most squarely (the reference): the
  patch's centre is the physical point, wherever SIFT put the keypoints;
- the patch, moved by the match's link motion into configuration B, is projected into every
  other image of the point's two tracks (the plane-induced warp: it looks there as it should, up
  to a shift), and each image's shift is found by Lucas-Kanade on zero-mean, unit-variance
  intensities (gain and offset between views and configurations drop out);
- the point is triangulated again in each configuration from the shifted projections (the
  reference's own centre in A), robustly: views more than ``max_residual`` pixels off are
  dropped, and a point with fewer than ``min_views`` views left in either configuration keeps its
  SfM position.

The same physical point in A and B, each triangulated from tracks of a dozen views or more: the
spread of the matches around the links' true motions falls by about half on the bases and the
wide links and by up to a third on the long narrow ones (the bundled scenes, seeds 0-2), and
SfM points a few millimetres off in depth come back to a few tenths (README, issue 23).

Needs the links' motions (for the warp: the patch's shape in B) and the posed images; it changes
no labels. Any frame and scale: the patch's size is set in the reference image's pixels.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from artrecon.refine import tracks_of

log = logging.getLogger(__name__)

__all__ = ["PhotometricConfig", "refine_link_matches", "refine_match_points"]


@dataclass(frozen=True)
class PhotometricConfig:
    """Settings of the matches' photometric refinement (:func:`refine_match_points`)."""

    enabled: bool = True
    """Refine the matches' points (False: the SfM points as triangulated)."""
    half_size: int = 5
    """The patch's half-width in the reference image's pixels (an 11 x 11 patch): larger
    patches reach past a thin link's edge onto what moves differently (7 measured worse on the
    pliers), smaller ones hold too little texture (3: worse)."""
    blur: float = 0.0
    """Gaussian sigma (pixels) of the images before alignment (0: none). On a synthetic
    textured plane a blur of 0.8 px left the refined pairs 3 times farther apart (0.042 against
    0.012 mm at 0.5 mm of noise on the SfM points), on the bundled scenes 10-20% farther."""
    min_ncc: float = 0.8
    """A view's aligned patch must correlate with the reference at least this much."""
    max_shift: float = 3.0
    """A view's shift larger than this (pixels) is a failed alignment."""
    iterations: int = 12
    """Lucas-Kanade iterations at most (steps of a thousandth of a pixel end it)."""
    max_residual: float = 0.4
    """A view whose aligned point lies farther than this (pixels) from the point triangulated
    from the others is dropped."""
    min_views: int = 3
    """Views (the reference counted) a point needs in each configuration to be refined."""
    min_contrast: float = 2.0
    """Grey levels of standard deviation the reference patch needs (flat patches align to
    anything)."""



def _patch_weights(half: int) -> np.ndarray:
    k = np.arange(-half, half + 1)
    gu, gv = np.meshgrid(k, k)
    return np.exp(-(gu ** 2 + gv ** 2).ravel() / (2 * (half / 1.5) ** 2))


def _tangent_grids(centres: np.ndarray, normals: np.ndarray, spacing: np.ndarray, half: int
                   ) -> np.ndarray:
    """(n, P, 3) square grids on the tangent planes, ``spacing`` (n,) apart."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    a = np.cross(normals, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(normals, a)
    k = np.arange(-half, half + 1, dtype=float)
    gu, gv = (g.ravel() for g in np.meshgrid(k, k))
    return (centres[:, None, :] + spacing[:, None, None]
            * (gu[None, :, None] * a[:, None, :] + gv[None, :, None] * b[:, None, :]))


def _project(view, X: np.ndarray) -> np.ndarray:
    """Pixel coordinates (..., 2) of points (..., 3) (:meth:`artrecon.assign.CameraView.project`,
    any leading shape)."""
    u, v, _ = view.project(X.reshape(-1, 3))
    return np.stack([u, v], -1).reshape(*X.shape[:-1], 2)


def _sample(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img`` at ``uv`` (m, P, 2); (m, P) float32."""
    if uv.size == 0:
        return np.zeros(uv.shape[:-1], np.float32)
    return cv2.remap(img, np.ascontiguousarray(uv[..., 0], np.float32),
                     np.ascontiguousarray(uv[..., 1], np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def _normalise(values: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zero-mean, unit-variance rows under the weights ``w`` (P,); and each row's std."""
    W = w.sum()
    mu = (values * w).sum(1, keepdims=True) / W
    sd = np.sqrt(((values - mu) ** 2 * w).sum(1, keepdims=True) / W)
    return (values - mu) / np.maximum(sd, 1e-6), sd[:, 0]


def _align(img: np.ndarray, grad: tuple[np.ndarray, np.ndarray], uv0: np.ndarray,
           templates: np.ndarray, w: np.ndarray, config: PhotometricConfig
           ) -> tuple[np.ndarray, np.ndarray]:
    """Lucas-Kanade shifts (m, 2) of the patches sampled at ``uv0`` (m, P, 2) onto their
    zero-mean unit-variance ``templates`` (m, P), and the final correlations (m,).

    The Jacobian is the one at the start (the shifts are a pixel or two: a constant Jacobian
    converges to the same shift, each iteration one image sample instead of three)."""
    m = len(uv0)
    shift = np.zeros((m, 2), np.float32)
    W = w.sum()
    _, sd = _normalise(_sample(img, uv0), w)
    sd = np.maximum(sd, 1e-6)[:, None]
    J = np.stack([_sample(grad[0], uv0) / sd, _sample(grad[1], uv0) / sd], -1)
    J -= (J * w[None, :, None]).sum(1, keepdims=True) / W
    Jw = J * w[None, :, None]
    H = np.einsum("mpi,mpj->mij", Jw, J)
    det = H[:, 0, 0] * H[:, 1, 1] - H[:, 0, 1] ** 2
    active = det > 1e-12
    inv = np.zeros_like(H)
    inv[active, 0, 0] = H[active, 1, 1] / det[active]
    inv[active, 1, 1] = H[active, 0, 0] / det[active]
    inv[active, 0, 1] = inv[active, 1, 0] = -H[active, 0, 1] / det[active]
    for _ in range(config.iterations):
        if not active.any():
            break
        idx = np.flatnonzero(active)
        values, _ = _normalise(_sample(img, uv0[idx] + shift[idx, None, :]), w)
        g = np.einsum("mpi,mp->mi", Jw[idx], values - templates[idx])
        step = np.clip(-np.einsum("mij,mj->mi", inv[idx], g), -1.0, 1.0)
        shift[idx] += step
        active[idx] = (np.abs(step).max(1) > 1e-3) & (np.abs(shift[idx]).max(1)
                                                      < config.max_shift)
    values, _ = _normalise(_sample(img, uv0 + shift[:, None, :]), w)
    ncc = (values * templates * w).sum(1) / W
    return shift.astype(float), ncc


def _triangulate(views, rows: np.ndarray, vidx: np.ndarray, uv: np.ndarray, X0: np.ndarray,
                 iterations: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton triangulation of every point from its observations (``rows`` the point,
    ``vidx`` the view, ``uv`` (k, 2) pixels) from ``X0`` (n, 3); the points and each
    observation's reprojection error (pixels)."""
    R = np.stack([v.T_cw[:3, :3] for v in views])[vidx]
    t = np.stack([v.T_cw[:3, 3] for v in views])[vidx]
    f = np.stack([v.K[[0, 1], [0, 1]] for v in views])[vidx]
    c = np.stack([v.K[:2, 2] for v in views])[vidx]
    X = X0.copy()
    n = len(X0)
    for it in range(iterations + 1):
        Xc = np.einsum("kij,kj->ki", R, X[rows]) + t
        z = Xc[:, 2:3]
        res = f * Xc[:, :2] / z + c - uv
        if it == iterations:
            break
        # d proj / d X = f (R[:2] - (Xc[:2] / z) R[2]) / z
        J = (f / z)[:, :, None] * (R[:, :2, :] - (Xc[:, :2] / z)[:, :, None] * R[:, 2:3, :])
        H = np.zeros((n, 3, 3))
        g = np.zeros((n, 3))
        np.add.at(H, rows, np.einsum("kai,kaj->kij", J, J))
        np.add.at(g, rows, np.einsum("kai,ka->ki", J, res))
        good = np.linalg.det(H) > 1e-12
        step = np.zeros((n, 3))
        step[good] = np.linalg.solve(H[good], g[good][..., None])[..., 0]
        X = X - step
    return X, np.linalg.norm(res, axis=1)


def refine_match_points(views_a: list, views_b: list, obs_a: tuple[np.ndarray, np.ndarray],
                        obs_b: tuple[np.ndarray, np.ndarray], points_a: np.ndarray,
                        points_b: np.ndarray, normals_a: np.ndarray, motions: np.ndarray,
                        config: PhotometricConfig = PhotometricConfig()
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The matches' points triangulated again from photometrically aligned projections (see the
    module docstring).

    Parameters
    ----------
    views_a, views_b : list of :class:`artrecon.assign.CameraView`
        The posed grey images of the two configurations.
    obs_a, obs_b : ((k,) int, (k,) int)
        (match row, view index) of each point's track (the ``point`` and ``view`` of
        :func:`artrecon.refine.tracks_of`).
    points_a, points_b : (n, 3) float
        The matches' SfM points.
    normals_a : (n, 3) float
        A's surface normal at each point of A (toward the cameras that see it).
    motions : (n, 4, 4) float
        Each match's link motion A -> B (its shape in B only: a tenth of a degree off changes
        nothing).
    config : PhotometricConfig

    Returns
    -------
    points_a, points_b : (n, 3) float
        The refined points where ``refined``, the given ones elsewhere.
    refined : (n,) bool
    """
    n = len(points_a)
    pa, pb = np.array(points_a, float), np.array(points_b, float)
    refined = np.zeros(n, bool)
    if n == 0:
        return pa, pb, refined
    half = config.half_size
    w = _patch_weights(half)
    rows_a, views_ia = (np.asarray(x, np.int64) for x in obs_a)
    rows_b, views_ib = (np.asarray(x, np.int64) for x in obs_b)
    centres_a = np.stack([v.centre for v in views_a])
    normals = np.asarray(normals_a, float)
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    # the reference: the A view that sees the point most squarely
    to_cam = centres_a[views_ia] - pa[rows_a]
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    cosine = np.einsum("ki,ki->k", to_cam, normals[rows_a])
    order = np.lexsort((-np.abs(cosine), rows_a))
    first = np.ones(len(order), bool)
    first[1:] = rows_a[order][1:] != rows_a[order][:-1]
    ref_obs = order[first]
    has_ref = np.zeros(n, bool)
    has_ref[rows_a[ref_obs]] = True
    ref_view = np.full(n, -1)
    ref_view[rows_a[ref_obs]] = views_ia[ref_obs]
    flip = np.zeros(n, bool)
    flip[rows_a[ref_obs]] = cosine[ref_obs] < 0
    normals[flip] *= -1
    # the patches: one reference-image pixel apart at the point
    depth = np.ones(n)
    focal = np.ones(n)
    for v in np.unique(ref_view[has_ref]):
        sel = ref_view == v
        view = views_a[v]
        depth[sel] = (pa[sel] @ view.T_cw[2, :3]) + view.T_cw[2, 3]
        focal[sel] = view.K[0, 0]
    grids = _tangent_grids(pa, normals, depth / focal, half)
    # images blurred, and their gradients, once per view that is used, on the part of the image
    # the view's points lie in (the patches' coordinates shifted to it)
    cache: dict = {}
    margin = 4 * half + config.max_shift + 4 * config.blur + 4
    points_by = {"a": (pa, rows_a, views_ia), "b": (pb, rows_b, views_ib)}

    def image(views, key, v):
        if (key, v) not in cache:
            X, rows, vidx = points_by[key]
            uv = _project(views[v], X[rows[vidx == v]])
            img = views[v].image
            h, wd = img.shape
            x0, y0 = (max(int(np.floor(uv[:, i].min() - margin)), 0) for i in (0, 1))
            x1 = min(int(np.ceil(uv[:, 0].max() + margin)) + 1, wd)
            y1 = min(int(np.ceil(uv[:, 1].max() + margin)) + 1, h)
            crop = np.ascontiguousarray(img[y0:y1, x0:x1], np.float32)
            if config.blur > 0:
                crop = cv2.GaussianBlur(crop, (0, 0), config.blur)
            gx = cv2.Sobel(crop, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)
            gy = cv2.Sobel(crop, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
            cache[key, v] = (crop, (gx, gy), np.array([x0, y0], float))
        return cache[key, v]

    templates = np.zeros((n, len(w)))
    contrast = np.zeros(n)
    for v in np.unique(ref_view[has_ref]):
        sel = np.flatnonzero(ref_view == v)
        img, _, origin = image(views_a, "a", v)
        templates[sel], contrast[sel] = _normalise(
            _sample(img, _project(views_a[v], grids[sel]) - origin), w)
    usable = has_ref & (contrast >= config.min_contrast)
    # the patch in B: moved by the match's link motion, centred on B's point
    moved = np.einsum("nij,npj->npi", motions[:, :3, :3], grids) + motions[:, None, :3, 3]
    moved_centre = np.einsum("nij,nj->ni", motions[:, :3, :3], pa) + motions[:, :3, 3]
    grids_b = moved - moved_centre[:, None, :] + pb[:, None, :]

    def measure(views, key, rows, vidx, grid, centre):
        keep = usable[rows]
        if key == "a":
            keep &= vidx != ref_view[rows]
        rows, vidx = rows[keep], vidx[keep]
        uv = np.zeros((len(rows), 2))
        good = np.zeros(len(rows), bool)
        for v in np.unique(vidx):
            sel = np.flatnonzero(vidx == v)
            r = rows[sel]
            img, grad, origin = image(views, key, v)
            shift, ncc = _align(img, grad, _project(views[v], grid[r]) - origin, templates[r], w,
                                config)
            uv[sel] = _project(views[v], centre[r]) + shift
            good[sel] = (ncc >= config.min_ncc) & (np.abs(shift).max(1) < config.max_shift)
        return rows[good], vidx[good], uv[good]

    ra, va, uva = measure(views_a, "a", rows_a, views_ia, grids, pa)
    # the reference's own centre: the physical point
    refs = np.flatnonzero(usable)
    ra = np.concatenate([ra, refs])
    va = np.concatenate([va, ref_view[refs]])
    uva = np.concatenate([uva, np.stack([_project(views_a[ref_view[r]], pa[r]) for r in refs])
                          if len(refs) else np.zeros((0, 2))])
    rb, vb, uvb = measure(views_b, "b", rows_b, views_ib, grids_b, pb)
    cache.clear()

    def triangulate(views, rows, vidx, uv, X0):
        keep = np.ones(len(rows), bool)
        for _ in range(3):
            X, err = _triangulate(views, rows[keep], vidx[keep], uv[keep], X0)
            worst = np.zeros(n)
            np.maximum.at(worst, rows[keep], err)
            bad = err > config.max_residual
            if not bad.any():
                break
            # drop each point's worst view when it is over the limit, and try again
            kk = np.flatnonzero(keep)
            drop = bad & (err >= worst[rows[keep]])
            keep[kk[drop]] = False
        X, err = _triangulate(views, rows[keep], vidx[keep], uv[keep], X0)
        count = np.bincount(rows[keep], minlength=n)
        worst = np.zeros(n)
        np.maximum.at(worst, rows[keep], err)
        return X, (count >= config.min_views) & (worst <= config.max_residual)

    Xa, ok_a = triangulate(views_a, ra, va, uva, pa)
    Xb, ok_b = triangulate(views_b, rb, vb, uvb, pb)
    # the same feature: within max_shift pixels of the SfM point in every view of its track
    # (a point triangulated from a few close views alone can slide far along their rays)
    for views, rows, vidx, X, X0, ok in ((views_a, rows_a, views_ia, Xa, pa, ok_a),
                                         (views_b, rows_b, views_ib, Xb, pb, ok_b)):
        moved = np.zeros(n)
        for v in np.unique(vidx):
            r = rows[vidx == v]
            d = np.linalg.norm(_project(views[v], X[r]) - _project(views[v], X0[r]), axis=1)
            np.maximum.at(moved, r, d)
        ok &= moved <= config.max_shift
    refined = usable & ok_a & ok_b
    pa[refined], pb[refined] = Xa[refined], Xb[refined]
    return pa, pb, refined


def nearest_normals(dense_points: np.ndarray, dense_normals: np.ndarray, points: np.ndarray
                    ) -> np.ndarray:
    """The normal of the nearest dense point to each of ``points``."""
    if len(dense_points) == 0:
        return np.tile([0.0, 0.0, 1.0], (len(points), 1))
    _, idx = cKDTree(dense_points).query(points)
    return dense_normals[idx]


def refine_link_matches(points_a: np.ndarray, points_b: np.ndarray, labels: np.ndarray,
                        transforms: list, ids_a: np.ndarray, ids_b: np.ndarray,
                        reconstruction_a, reconstruction_b, views_a: list, views_b: list,
                        dense_a, config: PhotometricConfig = PhotometricConfig()
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`refine_match_points` for the segmented matches: each match's patch moved by its
    link's motion (``transforms[labels[i]]``, :class:`artrecon.procrustes.Similarity`), its
    track's views from the two SfM reconstructions (``ids_a``, ``ids_b``: the matches' 3D
    point ids), A's normals from A's dense points. Matches of no link (label -1) are left as
    they are. Returns the points and which were refined."""
    labels = np.asarray(labels)
    pa, pb = np.array(points_a, float), np.array(points_b, float)
    sel = np.flatnonzero(labels >= 0)
    refined = np.zeros(len(labels), bool)
    if len(sel) == 0 or not config.enabled:
        return pa, pb, refined
    obs = []
    for rec, ids, views in ((reconstruction_a, ids_a, views_a), (reconstruction_b, ids_b, views_b)):
        index = {v.name: k for k, v in enumerate(views)}
        rows = {iid: index[im.name] for iid, im in rec.images.items() if im.name in index}
        tracks = tracks_of(rec, np.asarray(ids)[sel], rows)
        obs.append((tracks.point, tracks.view))
    motions = np.stack([T.matrix for T in transforms])
    normals = nearest_normals(dense_a.points, dense_a.normals, pa[sel])
    ra, rb, ok = refine_match_points(views_a, views_b, *obs, pa[sel], pb[sel], normals,
                                     motions[labels[sel]], config)
    pa[sel], pb[sel] = ra, rb
    refined[sel] = ok
    return pa, pb, refined
