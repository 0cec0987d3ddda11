"""Dense oriented points: building blocks on synthetic data, accuracy on the rendered hinge."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from render_fixture import align_to_truth
from scipy.spatial import cKDTree

from artrecon import dense
from artrecon.files import read_ply

#: Median distance of dense points to the true surface, as a fraction of the camera distance
#: (0.5 m): 0.4% = 2 mm. Measured: about 1.1 mm (downsampled SGBM, 20-degree baselines).
DENSE_MEDIAN_GATE = 0.002
#: Share of the visible object surface within 4 mm of a dense point. Measured: about 0.85-0.9
#: for 36 views (the faces resting on the table and the lid's underside are not visible).
COVERAGE_GATE = 0.6


def ring(n=24, radius=1.0, height=0.6):
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    c = np.column_stack([radius * np.cos(ang), radius * np.sin(ang), np.full(n, height)])
    axes = -c / np.linalg.norm(c, axis=1, keepdims=True)
    return c, axes


def test_focus_point_is_where_axes_meet():
    c, axes = ring()
    target = np.array([0.1, -0.2, 0.05])
    axes = target - c
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    np.testing.assert_allclose(dense.focus_point(c, axes), target, atol=1e-9)
    with pytest.raises(ValueError, match=r"\(m, 3\)"):
        dense.focus_point(c[:, :2], axes[:, :2])


def test_normals_of_a_plane_face_the_cameras():
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.random((500, 2)), 1e-4 * rng.standard_normal(500)])
    cams = np.array([[0.5, 0.5, 2.0], [0.0, 0.0, 1.5]])
    vis = np.ones((500, 2), bool)
    n = dense.estimate_normals(pts, vis, cams)
    assert np.all(n[:, 2] > 0.99)
    n_below = dense.estimate_normals(pts, vis, cams * [1, 1, -1])
    assert np.all(n_below[:, 2] < -0.99)


def test_normals_of_a_selection_are_those_of_the_whole_cloud():
    """FusedPoints.oriented(mask): the selected points' normals from their neighbours among all
    the points, bit for bit those of the whole cloud (the occluders need none)."""
    rng = np.random.default_rng(5)
    table = np.column_stack([rng.uniform(-1, 1, (3000, 2)), 1e-3 * rng.standard_normal(3000)])
    box = np.column_stack([rng.uniform(-0.2, 0.2, (600, 2)), rng.uniform(0, 0.3, 600)])
    pts = np.concatenate([table, box])
    cams, _ = ring(n=8, radius=2.0, height=1.0)
    vis = rng.random((len(pts), len(cams))) < 0.6
    cloud = dense.FusedPoints(pts, np.zeros((len(pts), 3), np.uint8), vis,
                              [f"{k}.png" for k in range(len(cams))], cams, 16)
    whole = cloud.oriented()
    mask = np.r_[np.zeros(len(table), bool), np.ones(len(box), bool)]
    mask[:50] = True  # and some of the table, next to nothing of the box
    part = cloud.oriented(mask)
    np.testing.assert_array_equal(part.points, pts[mask])
    np.testing.assert_array_equal(part.normals, whole.normals[mask])
    np.testing.assert_array_equal(part.visibility, vis[mask])
    # neighbours from the selection alone would differ at the box's foot, beside the table
    alone = dense.estimate_normals(pts[mask], vis[mask], cams, 16)
    assert not np.array_equal(alone, part.normals)


def test_support_plane_of_a_large_cloud_from_a_sample():
    """Beyond PLANE_SCORE_SAMPLE points RANSAC counts inliers on a sample; the plane, refitted to
    its inliers among all the points, is the table's."""
    rng = np.random.default_rng(6)
    n = 3 * dense.PLANE_SCORE_SAMPLE
    tilt = np.deg2rad(10.0)
    normal = np.array([0.0, np.sin(tilt), np.cos(tilt)])
    u = np.array([1.0, 0.0, 0.0])
    v = np.cross(normal, u)
    xy = rng.uniform(-0.5, 0.5, (n, 2))
    table = xy[:, :1] * u + xy[:, 1:] * v + 2e-4 * rng.standard_normal((n, 1)) * normal
    clutter = rng.uniform(-0.5, 0.5, (n // 2, 3)) + 0.3 * normal
    P = np.concatenate([table, clutter])
    cams = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 1.5]])
    found = dense.fit_support_plane(P, cams, 0.002, 200, 0.3, seed=0)
    assert found is not None
    n_est, centroid, inliers = found
    assert inliers.shape == (len(P),)
    assert np.degrees(np.arccos(abs(n_est @ normal))) < 0.05
    assert n_est @ normal > 0  # towards the cameras
    assert abs((centroid @ normal)) < 1e-3
    assert inliers[:n].mean() > 0.99 and inliers[n:].mean() < 0.01


def test_depth_fusion_counts_as_point_by_point():
    """The fusion of merged points against the depth maps (view-major, only the points inside
    a view looked up, the points in blocks of any size) gives what comparing every point with
    every view's depth gives."""
    rng = np.random.default_rng(3)
    w, h = 40, 30
    K = np.array([[30.0, 0.0, 19.5], [0.0, 30.0, 14.5], [0.0, 0.0, 1.0]])
    c, axes = ring(n=6, radius=2.0, height=0.5)
    views = []
    for centre, z in zip(c, axes, strict=True):
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, -R @ centre
        views.append(dense._View("v", K, T, centre, z, set()))
    P = rng.uniform(-0.6, 0.6, (3000, 3))
    depth = {}
    for k in (0, 2, 3, 5):  # views 1 and 4 have no depth map (no stereo partner)
        u, v, z, inside = dense._project(views[k], K, P[:200], w, h)
        D = dense._zbuffer(u[inside], v[inside], z[inside] * rng.uniform(0.98, 1.02), w, h)
        depth[k] = D
    tol = 0.01
    agree, through, vis = dense._fuse_depths(P, views, [K] * len(views), depth, w, h, tol)
    ref_vis = np.zeros((len(P), len(views)), bool)
    ref_agree = np.zeros(len(P), np.int32)
    ref_through = np.zeros(len(P), np.int32)
    for k, D in depth.items():
        u, v, z, inside = dense._project(views[k], K, P, w, h)
        d = np.full(len(P), np.inf)
        d[inside] = D[v[inside], u[inside]]
        seen = np.isfinite(d)
        ok = seen & (np.abs(d - z) < tol * z)
        ref_vis[:, k] = ok
        ref_agree += ok
        ref_through += seen & (d > (1.0 + tol) * z)
    assert ref_agree.any() and ref_through.any()
    np.testing.assert_array_equal(agree, ref_agree)
    np.testing.assert_array_equal(through, ref_through)
    np.testing.assert_array_equal(vis.T, ref_vis)
    # in blocks (the last one short): the same, point by point
    for chunk in (1, 7, 1000):
        blocks = dense._fuse_depths(P, views, [K] * len(views), depth, w, h, tol, chunk=chunk)
        for got, want in zip(blocks, (agree, through, vis), strict=True):
            np.testing.assert_array_equal(got, want)


def _voxel_means(P, C, voxel):
    """Per voxel, in the order of its (x, y, z) index, the mean point and colour: a plain loop."""
    groups: dict[tuple, list] = {}
    for key, p, c in zip(map(tuple, np.floor(P / voxel).astype(np.int64)), P, C, strict=True):
        groups.setdefault(key, []).append((p, c))
    means = [(np.mean([p for p, _ in g], axis=0), np.mean([c for _, c in g], axis=0))
             for _, g in sorted(groups.items())]
    return np.array([m[0] for m in means]), np.array([m[1] for m in means])


def test_voxel_merge_averages_each_voxel():
    """Known answer: the merged points and colours are each voxel's means (a plain loop), for
    uint8 colours the same figures as for their float64 copies, bit for bit, and so on a grid
    too large for int32 voxel indices (one point 1 km away)."""
    rng = np.random.default_rng(3)
    P = rng.uniform(-0.05, 0.05, (4000, 3))
    C = rng.integers(0, 256, (4000, 3), dtype=np.uint8)
    voxel = 0.01
    for points in (P, np.r_[P, [[1e3, 1e3, 1e3]]]):
        colours = C if len(points) == len(C) else np.r_[C, [[1, 2, 3]]].astype(np.uint8)
        Pm, Cm = dense._voxel_merge(points, colours, voxel)
        ref_p, ref_c = _voxel_means(points, colours, voxel)
        assert len(Pm) == len(ref_p) > 100
        np.testing.assert_allclose(Pm, ref_p, rtol=0, atol=1e-15)
        np.testing.assert_allclose(Cm, ref_c, rtol=1e-12)
        Pf, Cf = dense._voxel_merge(points, colours.astype(float), voxel)
        np.testing.assert_array_equal(Pm, Pf)
        np.testing.assert_array_equal(Cm, Cf)


def test_object_region_drops_table_and_walls():
    """A box on a table inside walls, seen by a ring of cameras: only the box is kept."""
    rng = np.random.default_rng(2)
    # Surfaces sampled at one density (about 0.4 points per cm^2): a 3 m table,
    # a 0.2 x 0.2 x 0.15 m box's top and four sides, a wall.
    table = np.column_stack([rng.uniform(-1.5, 1.5, (40000, 2)), np.zeros(40000)])
    top = np.column_stack([rng.uniform(-0.1, 0.1, (180, 2)), np.full(180, 0.15)])
    sides = []
    for axis in (0, 1):
        for sgn in (-1, 1):
            s = np.column_stack([rng.uniform(-0.1, 0.1, 140), rng.uniform(0.0, 0.15, 140)])
            q = np.zeros((140, 3))
            q[:, axis] = sgn * 0.1
            q[:, 1 - axis] = s[:, 0]
            q[:, 2] = s[:, 1]
            sides.append(q)
    box = np.concatenate([top] + sides)
    box = box[box[:, 2] > 0.02]  # the lowest 2 cm of the sides are within the table tolerance
    wall = np.column_stack([np.full(800, 1.5), rng.uniform(-1.5, 1.5, 800),
                            rng.uniform(0, 1, 800)])
    pts = np.concatenate([table, box, wall])
    truth = np.r_[np.zeros(len(table), bool), np.ones(len(box), bool), np.zeros(800, bool)]
    c, _ = ring(radius=0.6, height=0.4)
    axes = np.array([0, 0, 0.05]) - c
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    mask = dense.object_region(pts, c, axes)
    assert mask[truth].mean() > 0.95
    assert mask[~truth].mean() < 0.01


def test_object_region_keeps_a_thin_object_lying_on_the_table():
    """Scissors-like: two 18 x 2 cm plates 0.5 - 4.5 mm and 5 - 9 mm above a table whose points
    scatter by 0.3 mm, cameras 0.39 m away (the support-plane band is 3.9 mm there). The plates'
    top faces stand well above the table's noise and are kept; the table is dropped."""
    rng = np.random.default_rng(4)
    table = np.column_stack([rng.uniform(-0.25, 0.25, (20000, 2)), rng.normal(0, 3e-4, 20000)])
    plates = []
    for z in (0.0045, 0.009):  # the top faces of the two halves
        plates.append(np.column_stack([rng.uniform(-0.09, 0.09, 300),
                                       rng.uniform(-0.01, 0.01, 300),
                                       z + rng.normal(0, 3e-4, 300)]))
    obj = np.concatenate(plates)
    pts = np.concatenate([table, obj])
    c, _ = ring(radius=0.3, height=0.25)
    axes = -c / np.linalg.norm(c, axis=1, keepdims=True)
    mask = dense.object_region(pts, c, axes)
    assert mask[len(table):].mean() > 0.95  # both halves, the lower one included
    assert mask[:len(table)].mean() < 0.01


def _held(pairs):
    return {k for pair in pairs.items() for k in pair}


@pytest.mark.parametrize("step", [1, -1])
def test_pair_cover_of_a_ring_keeps_every_second_pair(step):
    """36 views on a ring, each paired with its neighbour (either way round): the cover keeps 18
    pairs that share no image and still hold all 36."""
    partners = {i: (i + step) % 36 for i in range(36)}
    cover = dense.cover_pairs(partners)
    assert len(cover) == 18
    assert _held(cover) == set(range(36))
    assert all(partners[i] == j for i, j in cover.items())
    assert len(_held(cover)) == 2 * len(cover)  # no image in two kept pairs


def test_pair_cover_holds_every_image_of_odd_rings_and_partner_only_images():
    """An odd ring needs one pair more than half; an image that is only ever a partner (the
    ring's end, no partner of its own) is held through the pair it is the partner of; three
    rings in one model (121 images, as the bundled rings) keep 61 pairs."""
    odd = {i: (i + 1) % 7 for i in range(7)}
    cover = dense.cover_pairs(odd)
    assert _held(cover) == set(range(7)) and len(cover) == 4
    chain = {i: i + 1 for i in range(5)}  # image 5 has no partner of its own
    cover = dense.cover_pairs(chain)
    assert _held(cover) == set(range(6)) and len(cover) == 3
    star = {1: 0, 2: 0, 3: 0}  # every image pairs with 0: each pair is needed
    assert dense.cover_pairs(star) == star
    rings = {}
    for start, n in ((0, 36), (36, 36), (72, 36), (108, 13)):
        rings.update({start + k: start + (k + 1) % n for k in range(n)})
    cover = dense.cover_pairs(rings)
    assert _held(cover) == set(range(121)) and len(cover) == 61
    assert dense.cover_pairs({}) == {}


def _parallel_views(K: np.ndarray, baseline: float) -> list:
    """Two views with the same ``K`` looking along +z, the second ``baseline`` m to the right
    of the first (camera j to the right of camera i)."""
    views = []
    for x in (0.0, baseline):
        T = np.eye(4)
        T[0, 3] = -x
        views.append(dense._View("v", K, T, np.array([x, 0, 0]), np.array([0, 0, 1.0]), set()))
    return views


def test_disparity_range_ends_at_the_nearest_shared_point():
    """Two parallel cameras 5 cm apart (f 500 px), shared points at 0.3 m and 2 m: the range's
    near end is the nearest points' true disparity (f b / Z = 83.3 px) and its margin, not twice
    it (the doubled end searched empty space down to 0.15 m); its far end keeps the doubled
    disparity of the farthest points (2 x 12.5 px, the stereo's depth filter: nothing beyond
    about 1 m), both widened by the 8 px margin."""
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    f, b = 500.0, 0.05
    views = _parallel_views(K, b)
    no_dist = np.zeros(5)
    T_ji = views[1].T_cw @ np.linalg.inv(views[0].T_cw)
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(K, no_dist, K, no_dist, (640, 480),
                                                T_ji[:3, :3].copy(), T_ji[:3, 3].reshape(3, 1),
                                                flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1)
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.05, 0.05, (400, 2))
    Z = np.repeat([0.3, 2.0], 200)
    sparse = np.column_stack([xy * Z[:, None], Z])
    lo, num = dense._disparity_range(views[0], views[1], R1, R2, P1, P2, sparse, 8.0)
    assert lo == int(np.floor(2 * f * b / 2.0 - 8))
    near = f * b / 0.3
    assert near + 8 <= lo + num < near + 8 + 16
    assert lo + num < 2 * near


def test_pair_disparity_of_a_plane_is_its_shift():
    """Two parallel cameras 5 cm apart (f 500 px) facing a textured plane 2.5 m away: the right
    image is the left shifted by f b / Z = 10 px, and the stage's stereo finds 10 px (to SGBM's
    1/16 px step) at 99% of the pixels it keeps, inside a search range that holds it."""
    views = _parallel_views(np.array([[500.0, 0, 159.5], [0, 500, 119.5], [0, 0, 1]]), 0.05)
    rng = np.random.default_rng(3)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (240, 340)).astype(np.uint8), (3, 3), 0)
    left = cv2.cvtColor(np.ascontiguousarray(texture[:, 10:330]), cv2.COLOR_GRAY2BGR)
    right = cv2.cvtColor(np.ascontiguousarray(texture[:, 20:340]), cv2.COLOR_GRAY2BGR)
    # the plane's points and, as in a room, farther ones (the range's doubled far end needs
    # them: test_disparity_range_ends_at_the_nearest_shared_point)
    Z = np.repeat([2.5, 10.0], 50)
    sparse = np.column_stack([rng.uniform(-0.1, 0.1, (100, 2)) * Z[:, None], Z])
    pair = dense.pair_disparity(views[0], views[1], left, right, sparse,
                                dense.DenseConfig(downsample=1))
    lo, num = pair.search
    assert lo < 10 < lo + num
    assert not (pair.kept & ~pair.valid).any()
    assert pair.kept.mean() > 0.5
    err = np.abs(pair.disparity[pair.kept] - 10.0)
    assert np.median(err) == 0.0 and np.mean(err <= 1 / 16) > 0.99  # SGBM's 1/16 px step


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "coverage 0.581 < 0.6 in configuration A (median 1.44 mm, p90 3.32 mm) at 1e7cd60. Traced "
    "to 8df7fe8 (0.787 at its parent 92c06d8, 0.583 at it; not OpenCV's SIFT: COLMAP's gives "
    "0.583): its edge erosion (a pixel more than 0.5 px of disparity above the least in its 5x5 "
    "window) takes slanted surfaces for depth edges and drops 70% of the stereo pixels, a third "
    "of the box's sides (edge_erosion_px=0: 0.775). SGBM's disparities cling to whole pixels, so "
    "a slant is a staircase: the dropped pixels sit one step (0.5-1.25 px) above their window's "
    "least, and a median-filtered disparity drops as many (bundled scenes' pairs, 2026-11-29). "
    "Not fixed: edge_jump_px 1.0 keeps them and made the bundled thin objects' axes worse on "
    "seeds 0-2 (pliers seed 1 0.26 -> 0.35 deg, scissors 0.03 -> 0.17; README); a test that "
    "tells a depth edge from a step needs less locked sub-pixel disparities first"))
def test_dense_points_lie_on_the_true_surface(rendered, reconstruction_sfm):
    """Dense points of each configuration, aligned by the camera centres, lie on the object and
    cover its visible surface all around."""
    _, out = reconstruction_sfm
    for c in ("a", "b"):
        truth = rendered[c]
        S, _ = align_to_truth(out / c / "sparse" / "0", truth)
        pts, nrm, _ = read_ply(out / c / "dense.ply")
        world = S.apply(pts)
        tree = cKDTree(truth.object_points)
        dist, idx = tree.query(world)
        med = float(np.median(dist))
        # Coverage of the surfaces a camera can see (not the faces resting on the table).
        visible = truth.object_points[:, 2] > 0.008
        cov = float((cKDTree(world).query(truth.object_points[visible])[0] < 0.004).mean())
        print(f"config {c}: {len(pts)} dense points, median distance {med * 1e3:.2f} mm, "
              f"p90 {np.percentile(dist, 90) * 1e3:.2f} mm, coverage {cov:.2f}")
        assert med < DENSE_MEDIAN_GATE
        assert cov > COVERAGE_GATE
        # All around: every quadrant of azimuth around the object holds points.
        az = np.arctan2(world[:, 1], world[:, 0])
        assert np.all(np.histogram(az, bins=4, range=(-np.pi, np.pi))[0] > 100)
