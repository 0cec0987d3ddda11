"""Dense points the table is seen through: a free-space test against the table's own image.

Block matching fattens thin parts: beside and under the edges of a link only a few millimetres
thick (pliers, scissors lying on the table) the dense stage leaves points a few millimetres
outside the surface, hovering over the table. The dense stage's own free-space check cannot see
them: its depth maps are a quarter of the pixels and eroded at depth edges, exactly where these
points are. The images, at full resolution, do see them: a camera whose ray through such a point
goes on to the table shows the table at that pixel.

What the table looks like there is known without the object: the table is a plane (the support
plane of :func:`artrecon.dense.object_region`) and every view's image, warped onto it (a
plane-induced homography), shows the same texture wherever the object does not hide it. Their
median per place on the plane (the *mosaic*) is the bare table wherever fewer than half of the
views see the object in front of it. Where more do (under a link held above the table, inside a
finger ring, between opened blades), the median is one of the object's colours or none, and few
views show it: a place is *known* only where at least ``min_views`` views agree on its colour.
Then, for a dense point P and a view c:

- the ray from c through P meets the table at T behind P (P lies above the table);
- if c's pixel at P has the mosaic's colour at T, c saw the table through P: nothing was at P.

A point seen through by at least ``min_share`` of the views whose ray through it meets the mosaic
where it is known is dropped. (A view whose ray meets a place that is not known cannot tell.
Counted as views that did not see the table, such views kept points floating beside the blades
and inside the finger rings of scissors: 5.1% of its model's points were off the object, 4.3%
without them; pliers 4.3% and 3.2%.)

A real surface point shows its own colour in the views that see it and hides the table from the
others; chance agreement of its colour with the table behind it is rare (about 1% of such views
on the bundled scenes, against 40% of the views that truly see the table there).

The plane's height is refined on the images themselves (the height at which the views agree
best on the table's texture): the dense table points lie a millimetre or two off the table, and a
misplaced plane smears the mosaic by the views' parallax.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from artrecon.dense import fit_support_plane, focus_point

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FreeSpaceConfig:
    """Settings of the table free-space test (:func:`seen_through_table`)."""

    enabled: bool = True
    """Drop the dense points the table is seen through (False: keep every dense point)."""
    colour_tolerance: float = 15.0
    """A view's pixel shows the table when its RGB differs from the mosaic's by less than this
    (sum of the three channels' absolute differences, 0-765): the rendered table agrees with its
    mosaic to about 1-2 per channel; object colours differ by tens."""
    min_share: float = 0.25
    """Drop a point when at least this share of the views whose ray through it meets the mosaic
    saw the table there. A point beside a link's edge is held by the table in about half of the
    views that see it, of which this test finds about 40%."""
    margin: float = 0.1
    """The mosaic covers the object's points' footprint on the plane and this much more on each
    side (fraction of the median camera distance)."""
    max_cells: int = 400_000
    """At most this many mosaic cells (the cell is one pixel's footprint at the median camera
    distance, larger if needed)."""
    height_search: float = 0.015
    """The plane's height is searched this far above and below the fitted plane (fraction of the
    median camera distance: 6 mm at 0.4 m) ..."""
    height_samples: int = 4000
    """... by the views' agreement at this many random places of the mosaic."""
    min_views: int = 3
    """A mosaic cell is known when at least this many views agree on its colour (within
    ``colour_tolerance`` of the median)."""


@dataclass
class Plane:
    """The support plane: unit ``normal`` (toward the cameras) and a ``point`` on it."""

    normal: np.ndarray
    point: np.ndarray

    def height(self, X: np.ndarray) -> np.ndarray:
        return (np.asarray(X, float) - self.point) @ self.normal


def support_plane(points: np.ndarray, centres: np.ndarray, axes: np.ndarray, *,
                  radius_fraction: float, tolerance: float, min_fraction: float,
                  iterations: int, seed: int = 0) -> Plane | None:
    """The plane the object stands on, as :func:`artrecon.dense.object_region` finds it.

    RANSAC for the dominant plane of the points within ``radius_fraction`` x the median camera
    distance of the cameras' focus point (inlier band ``tolerance`` x that distance), refitted to
    its inliers. None when it holds fewer than ``min_fraction`` of those points or when cameras
    lie on both sides of it (not a support plane).

    Parameters
    ----------
    points : (n, 3) float
        Dense points, background included.
    centres, axes : (m, 3) float
        Camera centres and unit viewing directions.
    """
    points = np.asarray(points, float)
    focus = focus_point(centres, axes)
    cam_dist = float(np.median(np.linalg.norm(centres - focus, axis=1)))
    P = points[np.linalg.norm(points - focus, axis=1) < radius_fraction * cam_dist]
    if len(P) < 10:
        return None
    found = fit_support_plane(P, centres, tolerance * cam_dist, iterations, min_fraction, seed)
    if found is None:
        return None
    n, cen, inl = found
    q = P[inl]
    h = (q - cen) @ n
    return Plane(n, cen + float(np.median(h)) * n)


class _Mosaic:
    """The table's colour on a grid of the plane: the median over the views (float32 RGB), and
    where it is known (:func:`table_mosaic`)."""

    def __init__(self, plane: Plane, origin: np.ndarray, e1: np.ndarray, e2: np.ndarray,
                 cell: float, shape: tuple[int, int]):
        self.plane, self.origin, self.e1, self.e2, self.cell = plane, origin, e1, e2, cell
        self.shape = shape
        self.colour = np.zeros((*shape, 3), np.float32)
        self.known = np.zeros(shape, bool)
        self.offset = 0.0

    def grid_points(self, offset: float = 0.0) -> np.ndarray:
        h, w = self.shape
        jj, ii = np.mgrid[0:h, 0:w].astype(float)
        return (self.origin + offset * self.plane.normal + ii[..., None] * self.cell * self.e1
                + jj[..., None] * self.cell * self.e2)

    def cell_of(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = X - self.origin
        return (d @ self.e1) / self.cell, (d @ self.e2) / self.cell


def _project(view, X: np.ndarray):
    Xc = X @ view.T_cw[:3, :3].T + view.T_cw[:3, 3]
    z = Xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = view.K[0, 0] * Xc[..., 0] / z + view.K[0, 2]
        v = view.K[1, 1] * Xc[..., 1] / z + view.K[1, 2]
    return u, v, z


def _remap(image: np.ndarray, u: np.ndarray, v: np.ndarray, interpolation: int,
           as_float: bool = True) -> np.ndarray:
    """``image`` (h, w[, c]) at the pixels (u, v) of any shape (outside: 0), float32 (or in the
    image's own type: ``as_float`` False)."""
    shape = np.shape(u)
    n = int(np.prod(shape))
    width = 1024  # remap's maps must stay under 32767 rows and columns
    rows = max(1, -(-n // width))
    mu = np.full(rows * width, -1, np.float32)
    mv = np.full(rows * width, -1, np.float32)
    mu[:n] = np.ravel(u)
    mv[:n] = np.ravel(v)
    out = cv2.remap(image, mu.reshape(rows, width), mv.reshape(rows, width), interpolation,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    out = out.reshape(rows * width, -1)[:n]
    out = out.reshape(*shape, *image.shape[2:])
    return out.astype(np.float32) if as_float else out


def _sample(image: np.ndarray, u: np.ndarray, v: np.ndarray, z: np.ndarray,
            as_float: bool = True):
    """Bilinear RGB (..., 3) float32 (``as_float`` False: the image's type) at pixels (u, v)
    and whether each is inside the image."""
    h, w = image.shape[:2]
    ok = (z > 0) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    return _remap(image, np.where(ok, u, -1), np.where(ok, v, -1), cv2.INTER_LINEAR,
                  as_float), ok


def _stack(views, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Colours (views, *P.shape[:-1], 3) of points P in every view, and where they are known.
    uint8 when the images are (OpenCV's bilinear sampling of a uint8 image rounds to uint8: the
    float32 figures are those integers), a quarter of float32's memory for the mosaic's views x
    cells; float32 otherwise."""
    cols, oks = [], []
    for view in views:
        c, ok = _sample(view.colour, *_project(view, P),
                        as_float=np.asarray(view.colour).dtype != np.uint8)
        cols.append(c)
        oks.append(ok)
    return np.stack(cols), np.stack(oks)


def nanmedian0(x: np.ndarray) -> np.ndarray:
    """``np.nanmedian(x, axis=0)``, the same figures bit for bit (the mean of the two middle
    values in ``x``'s own float type; NaN where a column has no value), without numpy's masked
    array route for short axes (about 20 times slower on the mosaic's views x cells)."""
    x = np.asarray(x)
    if x.shape[0] == 0:
        return np.full(x.shape[1:], np.nan, x.dtype)
    last = np.moveaxis(x, 0, -1)
    srt = np.sort(last, axis=-1)  # NaN sort last
    return _middle_of_sorted(srt, np.sum(~np.isnan(last), axis=-1), x.dtype.type)


def _middle_of_sorted(srt: np.ndarray, cnt: np.ndarray, dtype) -> np.ndarray:
    """The median of the first ``cnt`` values of each row of ``srt`` (sorted along its last
    axis, the values that do not count after them): the mean of the two middle values in
    ``dtype`` (their middle value for an odd count), NaN where ``cnt`` is 0."""
    n = srt.shape[-1]
    h = cnt // 2
    low = np.where(cnt % 2 == 1, h, h - 1)
    lo = np.take_along_axis(srt, np.maximum(low, 0)[..., None], -1)[..., 0]
    hi = np.take_along_axis(srt, np.minimum(h, n - 1)[..., None], -1)[..., 0]
    med = np.asarray((lo.astype(dtype, copy=False) + hi.astype(dtype, copy=False)) / dtype(2))
    med[cnt == 0] = np.nan
    return med


def _agreeing(cols: np.ndarray, oks: np.ndarray, colour: np.ndarray,
              tolerance: float) -> np.ndarray:
    """Per place, the number of views that see it in ``colour`` (RGB within ``tolerance``)."""
    out = np.zeros(oks.shape[1:], np.int32)
    for c, ok in zip(cols, oks, strict=True):  # one view at a time: no views x places temporary
        out += ok & (np.abs(c - colour).sum(-1) < tolerance)
    return out


def _median(cols: np.ndarray, oks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per place, the median colour (float32) over the views that see it, and their number."""
    count = oks.sum(0)
    if cols.dtype == np.uint8:
        return _median_uint8(cols, oks, count), count
    return nanmedian0(np.where(oks[..., None], cols, np.nan)), count


def _median_uint8(cols: np.ndarray, oks: np.ndarray, count: np.ndarray) -> np.ndarray:
    """:func:`nanmedian0` of the uint8 colours ``cols`` (views, ..., 3) where ``oks``, as
    float32, the same figures bit for bit: the views unseen get the key 256 (sorted last, as
    NaN), the sort runs on uint16 keys (half of float32's memory), the two middle values are
    whole numbers, so their float32 mean is exact either way."""
    keys = np.where(oks[..., None], cols, np.uint16(256))
    srt = np.sort(np.moveaxis(keys, 0, -1), axis=-1)
    return _middle_of_sorted(srt, np.broadcast_to(count[..., None], srt.shape[:-1]),
                             np.float32)


#: Offsets of the height search whose samples the views project together (memory: views x
#: offsets x samples x 3 float32, 46 MB for 121 views, 8 offsets, 4000 samples).
_OFFSETS_AT_ONCE = 8


def _refine_height(views, mosaic: _Mosaic, config: FreeSpaceConfig, cam_dist: float,
                   seed: int) -> float:
    """The offset along the normal at which the views agree best on the table's texture."""
    rng = np.random.default_rng(seed)
    h, w = mosaic.shape
    ij = rng.uniform([0, 0], [w - 1, h - 1], (config.height_samples, 2))
    base = mosaic.origin + ij[:, :1] * mosaic.cell * mosaic.e1 + ij[:, 1:] * mosaic.cell * mosaic.e2

    def spreads(offsets: np.ndarray) -> list[float]:
        """Per offset, the median over the samples of the views' spread about their median
        colour; the views project several offsets' samples at once (fewer, larger calls)."""
        out = []
        for first in range(0, len(offsets), _OFFSETS_AT_ONCE):
            chunk = offsets[first:first + _OFFSETS_AT_ONCE]
            P = base[None] + chunk[:, None, None] * mosaic.plane.normal
            cols, oks = _stack(views, P.reshape(-1, 3))
            cols = cols.reshape(len(views), len(chunk), len(base), 3)
            oks = oks.reshape(len(views), len(chunk), len(base))
            for m in range(len(chunk)):
                med, cnt = _median(cols[:, m], oks[:, m])
                per = nanmedian0(np.where(oks[:, m], np.abs(cols[:, m] - med[None]).sum(-1),
                                          np.nan))
                per = per[cnt >= config.min_views]
                out.append(float(np.median(per)) if len(per) else np.inf)
        return out

    reach = config.height_search * cam_dist
    step = mosaic.cell  # one pixel's footprint: the parallax that matters
    coarse = np.arange(-reach, reach + 0.5 * step, step)
    s = spreads(coarse)
    best = float(coarse[int(np.argmin(s))])
    fine = best + np.linspace(-step, step, 9)
    s = spreads(fine)
    return float(fine[int(np.argmin(s))])


def table_mosaic(points: np.ndarray, views, plane: Plane,
                 config: FreeSpaceConfig = FreeSpaceConfig(), seed: int = 0) -> _Mosaic:
    """The bare table's colour on the plane under and around ``points``, from the ``views``.

    The plane's height is refined on the images first (:func:`_refine_height`). Each cell holds
    the median colour over the views that see it (``colour``, float32 RGB) and whether it is
    ``known``: at least ``config.min_views`` views show that colour (within
    ``colour_tolerance``). Where the object stands in front of a cell in most views (under a
    link, inside a finger ring, between opened blades) the median is one of the object's colours
    or none at all and few views agree with it: such a cell is not known, so that the views whose
    ray meets the table there neither confirm nor deny that they saw the table through a point.

    Parameters
    ----------
    points : (n, 3) float
        The object's dense points (the mosaic covers their footprint and ``config.margin``).
    views : list of :class:`artrecon.assign.CameraView` with ``colour`` images.
    plane : Plane
    config : FreeSpaceConfig
    seed : int

    Returns
    -------
    _Mosaic
        With ``colour`` (h, w, 3) float32, ``known`` (h, w) bool, ``offset`` (the height
        refinement along the normal) set; ``plane`` is the refined plane.
    """
    X = np.asarray(points, float)
    centres = np.array([v.centre for v in views])
    axes = np.array([v.T_cw[2, :3] for v in views])
    focus = focus_point(centres, axes)
    cam_dist = float(np.median(np.linalg.norm(centres - focus, axis=1)))
    f = float(np.median([v.K[0, 0] for v in views]))
    nrm = plane.normal
    e1 = np.cross(nrm, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 0.1:
        e1 = np.cross(nrm, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(nrm, e1)
    foot = np.stack([(X - plane.point) @ e1, (X - plane.point) @ e2], 1)
    margin = config.margin * cam_dist
    lo, hi = foot.min(0) - margin, foot.max(0) + margin
    cell = max(cam_dist / f, float(np.sqrt(np.prod(hi - lo) / config.max_cells)))
    shape = (int(np.ceil((hi[1] - lo[1]) / cell)) + 1, int(np.ceil((hi[0] - lo[0]) / cell)) + 1)
    origin = plane.point + lo[0] * e1 + lo[1] * e2
    offset = _refine_height(views, _Mosaic(plane, origin, e1, e2, cell, shape), config,
                            cam_dist, seed)
    mosaic = _Mosaic(Plane(nrm, plane.point + offset * nrm), origin + offset * nrm, e1, e2,
                     cell, shape)
    cols, oks = _stack(views, mosaic.grid_points())
    med, _ = _median(cols, oks)
    mosaic.known = _agreeing(cols, oks, med, config.colour_tolerance) >= config.min_views
    del cols, oks
    mosaic.colour = np.nan_to_num(med).astype(np.float32)
    mosaic.offset = offset
    return mosaic


def seen_through_table(points: np.ndarray, views, plane: Plane | None,
                       config: FreeSpaceConfig = FreeSpaceConfig(), seed: int = 0) -> np.ndarray:
    """Mask (n,) of the dense points that the views see the table through (True: drop).

    Parameters
    ----------
    points : (n, 3) float
        The object's dense points (one configuration).
    views : list of :class:`artrecon.assign.CameraView` with ``colour`` images (h, w, 3) uint8.
    plane : Plane or None
        The support plane (:func:`support_plane`); None: nothing is dropped.
    config : FreeSpaceConfig
    seed : int

    Returns
    -------
    (n,) bool
    """
    X = np.asarray(points, float)
    n = len(X)
    drop = np.zeros(n, bool)
    if not config.enabled or plane is None or n == 0 or not views \
            or any(getattr(v, "colour", None) is None for v in views):
        return drop
    mosaic = table_mosaic(X, views, plane, config, seed)
    plane, shape = mosaic.plane, mosaic.shape
    nrm = plane.normal
    known = mosaic.known.astype(np.float32)
    table = mosaic.colour
    # per view: the ray through each point meets the table at T behind it
    height = plane.height(X)
    through = np.zeros(n, np.int32)
    tested = np.zeros(n, np.int32)
    for view in views:
        c = view.centre
        ray = X - c
        den = ray @ nrm
        with np.errstate(divide="ignore", invalid="ignore"):
            s = ((plane.point - c) @ nrm) / den
        hit = (den < 0) & (s > 1.0) & (height > 0)
        T = c + np.where(hit, s, 1.0)[:, None] * ray
        ci, cj = mosaic.cell_of(T)
        hit &= (ci >= 0) & (ci <= shape[1] - 1) & (cj >= 0) & (cj <= shape[0] - 1)
        pix, inside = _sample(view.colour, *_project(view, X))
        mi, mj = np.where(hit, ci, -1), np.where(hit, cj, -1)
        tab = _remap(table, mi, mj, cv2.INTER_LINEAR)
        kn = _remap(known, mi, mj, cv2.INTER_NEAREST)
        ok = hit & inside & (kn > 0)
        tested += ok
        through += ok & (np.abs(pix - tab).sum(1) < config.colour_tolerance)
    share = through / np.maximum(tested, 1)
    drop = (tested > 0) & (share >= config.min_share)
    log.info("free space: table plane moved %.3g along its normal by the images; mosaic %dx%d "
             "cells of %.3g (%d known); %d of %d dense points seen through (the table behind "
             "them)", mosaic.offset, shape[1], shape[0], mosaic.cell, int(mosaic.known.sum()),
             int(drop.sum()), n)
    return drop
