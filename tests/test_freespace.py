"""The table free-space test (artrecon.freespace) on a scene with a known answer.

A flat textured slab (8 mm thick, like a pliers' half) lies on a textured table; cameras ring it
at 25-65 degrees of elevation. The images are ray-cast exactly. Points on the slab's surface
must stay; points floating 2-4 mm beside its long sides, 3-6 mm above the table (the fattened
edges the dense stage leaves there), must go; the support plane, given 2 mm too low, must be put
back on the table by the images.
"""

import numpy as np
import pytest

from artrecon.assign import CameraView
from artrecon.freespace import (
    FreeSpaceConfig,
    Plane,
    seen_through_table,
    support_plane,
    table_mosaic,
)

F, W, H = 400.0, 320, 240
SLAB = np.array([[-0.06, -0.008, 0.0], [0.06, 0.008, 0.008]])  # min, max corner (m)


def _texture(x, y, seed):
    """Smooth random RGB texture (blobs of a few cm, like the bundled scenes' table)."""
    rng = np.random.default_rng(seed)
    out = np.zeros((*x.shape, 3))
    for ch in range(3):
        for _ in range(6):
            k = rng.uniform(80, 400, size=2)
            out[..., ch] += np.sin(k[0] * x + rng.uniform(0, 6.3)) * np.cos(k[1] * y
                                                                             + rng.uniform(0, 6.3))
    return np.clip(128 + 25 * out, 0, 255)


def _camera(azimuth, elevation, dist=0.35):
    c = dist * np.array([np.cos(elevation) * np.cos(azimuth),
                         np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    z = -c / np.linalg.norm(c)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # camera from world
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ c
    return T


def _render(T_cw):
    """RGB image: the slab (its own texture, the sides a plain shade) on the textured table."""
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u)], -1)
    R, t = T_cw[:3, :3], T_cw[:3, 3]
    c = -R.T @ t
    d = rays @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        s_table = -c[2] / d[..., 2]
        # slab: ray-box intersection (slabs method)
        t0 = (SLAB[0] - c) / d
        t1 = (SLAB[1] - c) / d
    tmin = np.nanmax(np.minimum(t0, t1), axis=-1)
    tmax = np.nanmin(np.maximum(t0, t1), axis=-1)
    box = (tmax >= tmin) & (tmin > 0)
    X = c + np.where(box, tmin, s_table)[..., None] * d
    img = _texture(X[..., 0], X[..., 1], 1)
    top = box & (np.abs(X[..., 2] - SLAB[1, 2]) < 1e-6)
    img[top] = _texture(X[top][:, 0] * 3.0, X[top][:, 1] * 3.0, 2)
    side = box & ~top
    img[side] = 0.6 * _texture(X[side][:, 0] * 3.0, X[side][:, 2] * 3.0, 3)
    return K, np.round(img).astype(np.uint8)


@pytest.fixture(scope="module")
def scene():
    views = []
    for el in np.deg2rad([25, 45, 65]):
        for az in np.deg2rad(np.arange(0, 360, 20) + el):
            T = _camera(az, el)
            K, img = _render(T)
            views.append(CameraView(K, T, img.mean(-1).astype(np.float32), img))
    rng = np.random.default_rng(0)
    n = 400
    top = np.c_[rng.uniform(-0.055, 0.055, n), rng.uniform(-0.007, 0.007, n),
                np.full(n, SLAB[1, 2])]
    side = np.c_[rng.uniform(-0.055, 0.055, n), rng.choice([-1, 1], n) * SLAB[1, 1],
                 rng.uniform(0.001, 0.007, n)]
    m = 150
    float_ = np.c_[rng.uniform(-0.05, 0.05, m),
                   rng.choice([-1, 1], m) * (SLAB[1, 1] + rng.uniform(0.002, 0.004, m)),
                   rng.uniform(0.003, 0.006, m)]
    table = np.c_[rng.uniform(-0.15, 0.15, (4000, 2)), np.zeros(4000)]
    table = table[(np.abs(table[:, 0]) > 0.07) | (np.abs(table[:, 1]) > 0.02)]
    return dict(views=views, surface=np.r_[top, side], floating=float_, table=table)


def test_support_plane_is_the_table(scene):
    views = scene["views"]
    centres = np.array([v.centre for v in views])
    axes = np.array([v.T_cw[2, :3] for v in views])
    pts = np.r_[scene["table"], scene["surface"]]
    plane = support_plane(pts, centres, axes, radius_fraction=0.6, tolerance=0.01,
                          min_fraction=0.15, iterations=200)
    assert plane is not None
    assert abs(plane.normal @ [0, 0, 1]) > 0.999
    assert abs(plane.height(np.zeros((1, 3)))[0]) < 1e-4
    # cameras on both sides: not a support plane
    both = np.r_[centres, centres * [1, 1, -1]]
    assert support_plane(pts, both, np.r_[axes, axes * [1, 1, -1]], radius_fraction=0.6,
                         tolerance=0.01, min_fraction=0.15, iterations=200) is None


def test_floating_points_go_and_the_surface_stays(scene):
    views = scene["views"]
    X = np.r_[scene["surface"], scene["floating"]]
    floating = np.r_[np.zeros(len(scene["surface"]), bool), np.ones(len(scene["floating"]),
                                                                       bool)]
    # the plane given 2 mm below the table: the images must put it back
    plane = Plane(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -0.002]))
    drop = seen_through_table(X, views, plane, FreeSpaceConfig())
    assert drop[floating].mean() > 0.8, drop[floating].mean()
    assert drop[~floating].mean() < 0.02, drop[~floating].mean()


def test_the_mosaic_knows_only_the_table_the_views_agree_on(scene):
    """Under the slab no view sees the table: the views show different parts of the slab there,
    their median is no table colour and the cells are not known. The open table beside it is
    known, in the table's own colours."""
    X = np.r_[scene["surface"], scene["floating"]]
    plane = Plane(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -0.002]))
    mosaic = table_mosaic(X, scene["views"], plane)
    G = mosaic.grid_points()
    x, y = G[..., 0], G[..., 1]
    under = (np.abs(x) < 0.05) & (np.abs(y) < 0.005)
    beside = (np.abs(x) < 0.08) & (np.abs(y) > 0.02) & (np.abs(y) < 0.04)
    assert under.sum() > 500 and beside.sum() > 2000
    assert mosaic.known[under].mean() < 0.05, mosaic.known[under].mean()
    assert mosaic.known[beside].mean() > 0.99, mosaic.known[beside].mean()
    err = np.abs(mosaic.colour - _texture(x, y, 1)).sum(-1)[beside]
    assert np.percentile(err, 99) < 6.0, np.percentile(err, 99)


def test_views_meeting_unknown_table_do_not_keep_a_floating_point(scene):
    """A point floating beside the slab: the views from the far side see it in front of the
    slab, and their rays through it meet the table under the slab, which no view shows. They
    say nothing about the point (the cells there are not known), so the share of the views that
    saw the table through it is taken over the others: about half or more, not diluted below a
    quarter by the views that could not tell."""
    views = scene["views"]
    X = np.r_[scene["surface"], scene["floating"]]
    floating = np.r_[np.zeros(len(scene["surface"]), bool), np.ones(len(scene["floating"]),
                                                                       bool)]
    plane = Plane(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -0.002]))
    drop = seen_through_table(X, views, plane, FreeSpaceConfig(min_share=0.5))
    assert drop[floating].mean() > 0.85, drop[floating].mean()
    assert not drop[~floating].any()


def test_nothing_dropped_without_a_plane_or_colour(scene):
    views = scene["views"]
    X = scene["floating"]
    assert not seen_through_table(X, views, None).any()
    grey = [CameraView(v.K, v.T_cw, v.image) for v in views]
    plane = Plane(np.array([0.0, 0.0, 1.0]), np.zeros(3))
    assert not seen_through_table(X, grey, plane).any()
    assert not seen_through_table(X, views, plane, FreeSpaceConfig(enabled=False)).any()


def test_nanmedian0_is_numpys_nanmedian_bit_for_bit():
    """The mosaic's median over the views: numpy's nanmedian's figures (float32, the mean of
    the two middle values, NaN for a place no view sees), ties and odd and even counts."""
    import warnings

    from artrecon.freespace import nanmedian0

    rng = np.random.default_rng(3)
    for shape in [(121, 500, 3), (8, 300), (1, 5), (2, 4)]:
        x = rng.uniform(0, 255, shape).astype(np.float32)
        x[rng.uniform(size=shape) < 0.1] = 77.25  # ties
        x[rng.uniform(size=shape) < 0.4] = np.nan  # views that do not see the place
        x[:, 0] = np.nan  # a place no view sees
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            expected = np.nanmedian(x, axis=0)
        got = nanmedian0(x)
        assert got.dtype == expected.dtype
        assert np.array_equal(got, expected, equal_nan=True)


def test_the_mosaics_uint8_median_is_the_float_medians_bit_for_bit():
    """The mosaic's colours sampled from uint8 images stay uint8 (whole numbers either way):
    their median over the views that see each place is the float32 route's, bit for bit, with
    odd and even counts, ties, one view and a place no view sees."""
    from artrecon.freespace import _median

    rng = np.random.default_rng(4)
    for views, places in [(121, 700), (8, 300), (1, 5), (2, 4)]:
        cols = rng.integers(0, 256, (views, places, 3), dtype=np.uint8)
        cols[rng.uniform(size=cols.shape) < 0.2] = 77  # ties
        oks = rng.uniform(size=(views, places)) < 0.6
        oks[:, 0] = False  # a place no view sees
        got, count = _median(cols, oks)
        expected, count_float = _median(cols.astype(np.float32), oks)
        assert got.dtype == expected.dtype == np.float32
        assert np.array_equal(got, expected, equal_nan=True)
        assert np.isnan(got[0]).all() and np.array_equal(count, count_float)
