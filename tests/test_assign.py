"""Dense-point labelling (artrecon.assign): each cue and the whole, on scenes with known answers.

The analytic scene is the hard case of the method's dense step: a textured floor that *slides
within its own plane* (a drawer's bottom along the pull) beside a static textured base in the same
plane. Every floor point's counterpart lies on the floor under both hypotheses ("moved" and
"stayed"), so the geometry cannot decide; only the images can. The cameras look straight down;
images are rendered by intersecting each pixel's ray with the plane z = 0 and reading the texture
of the link that is there.
"""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from artrecon import assign
from artrecon.assign import (
    AssignConfig,
    CameraView,
    _Evidence,
    _graph,
    _matches_along_surface,
    _Surface,
    assign_dense_to_links,
    label_points,
    seen_by,
)
from artrecon.dense import DensePoints
from artrecon.potts import potts_energy, potts_expansion
from artrecon.procrustes import Similarity

F, W, H = 500.0, 320, 240
SLIDE = 0.06  # the floor moves 6 cm along x between A and B
FLOOR_X = (0.0, 0.30)  # floor extent in A (x), |y| < 0.1
BASE_X = (-0.30, 0.0)  # static base, same plane


def _texture(x, y, seed):
    """A smooth random texture (sum of sinusoids), different per seed (link)."""
    rng = np.random.default_rng(seed)
    out = np.zeros_like(x)
    for _ in range(12):
        k = rng.uniform(300, 1200, size=2)
        out += np.sin(k[0] * x + rng.uniform(0, 6.3)) * np.cos(k[1] * y + rng.uniform(0, 6.3))
    return 128 + 30 * out


def _camera(cx, cy, height=0.5):
    """Camera above (cx, cy), looking down (-z), OpenCV axes."""
    R = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # camera from world rotation
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.array([cx, cy, height])
    return T


def _render(T_cw, slide):
    """Grey image of the plane scene with the floor moved by ``slide`` along x."""
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u)], -1)
    R, t = T_cw[:3, :3], T_cw[:3, 3]
    c = -R.T @ t
    d = rays @ R  # world directions (R^T r)
    s = -c[2] / d[..., 2]
    x, y = c[0] + s * d[..., 0], c[1] + s * d[..., 1]
    img = np.full(x.shape, 20.0)
    on_y = np.abs(y) < 0.1
    base = on_y & (x >= BASE_X[0]) & (x < BASE_X[1])
    floor = on_y & (x >= FLOOR_X[0] + slide) & (x < FLOOR_X[1] + slide)
    img[base] = _texture(x[base], y[base], 1)
    img[floor] = _texture(x[floor] - slide, y[floor], 2)
    return K, img.astype(np.float32)


def _views(slide):
    out = []
    for cx in np.linspace(-0.25, 0.35, 7):
        for cy in (-0.08, 0.08):
            T = _camera(cx, cy)
            K, img = _render(T, slide)
            out.append(CameraView(K, T, img))
    return out


def _points(slide, spacing=0.004):
    xs = np.arange(BASE_X[0], FLOOR_X[1], spacing) + spacing / 2
    ys = np.arange(-0.1, 0.1, spacing) + spacing / 2
    X, Y = np.meshgrid(xs, ys)
    P = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    on_floor = P[:, 0] >= FLOOR_X[0]
    P[on_floor, 0] += slide
    return P, on_floor.astype(int)


def _dense(P):
    n = len(P)
    N = np.tile([0.0, 0.0, 1.0], (n, 1))
    return DensePoints(P, N, np.zeros((n, 3), np.uint8), np.ones((n, 1), bool), ["x"])


@pytest.fixture(scope="module")
def sliding():
    Pa, la = _points(0.0)
    Pb, lb = _points(SLIDE)
    identity = Similarity(np.eye(3), np.zeros(3), 1.0)
    moved = Similarity(np.eye(3), np.array([SLIDE, 0.0, 0.0]), 1.0)
    # segmented matches: a few per link, well inside each link
    rng = np.random.default_rng(0)
    ma = np.concatenate([np.c_[rng.uniform(-0.28, -0.05, 30), rng.uniform(-0.08, 0.08, 30),
                               np.zeros(30)],
                         np.c_[rng.uniform(0.22, 0.28, 30), rng.uniform(-0.08, 0.08, 30),
                               np.zeros(30)]])
    labels = np.r_[np.zeros(30, int), np.ones(30, int)]
    mb = ma + np.where(labels[:, None] == 1, [SLIDE, 0, 0], 0.0)
    seg = SimpleNamespace(labels=labels, transforms=[identity, moved], rms=[5e-4, 5e-4],
                          scale=1.0)
    return dict(Pa=Pa, la=la, Pb=Pb, lb=lb, seg=seg, ma=ma, mb=mb,
                views_a=_views(0.0), views_b=_views(SLIDE))


def test_sliding_floor_without_images(sliding):
    """Without the images, every floor point away from its ends fits both hypotheses: point by
    point (no smoothness) the geometry cannot decide. Where the floor left its old place
    (and where it went) only the right hypothesis fits; the graph cut carries that across the
    whole floor."""
    s = sliding
    args = (_dense(s["Pa"]), _dense(s["Pb"]), s["ma"], s["mb"], s["seg"])
    floor = s["la"] == 1
    lab_a, _ = assign_dense_to_links(*args, config=AssignConfig(smoothness=0.0))
    assert np.mean(lab_a[floor] == 1) < 0.9
    lab_a, lab_b = assign_dense_to_links(*args)
    assert np.mean(lab_a == s["la"]) > 0.97
    assert np.mean(lab_b == s["lb"]) > 0.97


def test_photo_consistency_decides_the_sliding_floor(sliding):
    s = sliding
    lab_a, lab_b = assign_dense_to_links(_dense(s["Pa"]), _dense(s["Pb"]), s["ma"], s["mb"],
                                         s["seg"], views_a=s["views_a"], views_b=s["views_b"])
    acc_a = np.mean(lab_a == s["la"])
    acc_b = np.mean(lab_b == s["lb"])
    assert acc_a > 0.97, acc_a
    assert acc_b > 0.97, acc_b


def _named(views, tag):
    return [replace(v, name=f"{tag}{i:02d}") for i, v in enumerate(views)]


def _dense_seen(P, views):
    """Dense points that every one of ``views`` saw (the dense stage's visibility)."""
    n = len(P)
    return DensePoints(P, np.tile([0.0, 0.0, 1.0], (n, 1)), np.zeros((n, 3), np.uint8),
                       np.ones((n, len(views)), bool), [v.name for v in views])


def test_photo_patches_skip_views_blocked_by_what_was_not_reconstructed(sliding):
    """The arm that carries the camera stands in front of the object in some views; it is not in
    the dense points, so the z-buffers call the floor visible there. Each of A's views gets such
    a twin, listed first (so it wins every tie for the most head-on view), whose image shows the
    arm instead of the floor; the dense stage's depth fusion did not count the twins. The photo
    patches must come from the views that saw the points: point by point (no smoothness) the
    sliding floor is then decided as without the arm. Before, the patches came from the arm
    (cabinet's carcass walls: NCC 0.05-0.12 where the drawer scene's walls had 0.97)."""
    s = sliding
    views_a, views_b = _named(s["views_a"], "a"), _named(s["views_b"], "b")
    u, v = np.meshgrid(np.arange(W) * 1e-3, np.arange(H) * 1e-3)
    arm = _texture(u, v, 99).astype(np.float32)
    blocked = [replace(view, image=arm, name=f"arm{i:02d}") for i, view in enumerate(views_a)]
    dense_a, dense_b = _dense_seen(s["Pa"], views_a), _dense_seen(s["Pb"], views_b)
    config = AssignConfig(smoothness=0.0)
    floor = s["la"] == 1
    results = {}
    for name, va in (("clear", views_a), ("arm in front", blocked + views_a)):
        results[name] = assign_dense_to_links(dense_a, dense_b, s["ma"], s["mb"], s["seg"],
                                              views_a=va, views_b=views_b, config=config)
    for name, (lab_a, lab_b) in results.items():
        assert np.mean(lab_a[floor] == 1) > 0.97, name
        assert np.mean(lab_a == s["la"]) > 0.97, name
        assert np.mean(lab_b == s["lb"]) > 0.97, name


def test_seen_by_matches_views_to_the_visibility_columns_by_name():
    P = np.zeros((3, 3))
    dense = DensePoints(P, P, np.zeros((3, 3), np.uint8),
                        np.array([[1, 0], [0, 1], [1, 1]], bool), ["b.png", "a.png"])
    K = np.eye(3)
    views = [CameraView(K, np.eye(4), np.zeros((2, 2), np.float32), name=n)
             for n in ("a.png", "b.png", "unused.png")]
    assert seen_by(dense, views).tolist() == [[False, True, False], [True, False, False],
                                              [True, True, False]]
    assert seen_by(dense, [replace(views[0], name=None)]) is None


def test_match_prior_follows_the_surface_not_a_straight_line():
    """A drawer's floor (link 1, z = 0) under its carcass's top (link 0, 3 cm above, 12 cm
    long); the floor's only matches are on its far end, 15 cm away, the top's right above. In
    a straight line the floor under the top is nearest to the top's matches; along the surface
    (the points' graph: the two plates never touch) it is nearest to the floor's own."""
    s = 0.004
    xs = np.arange(0.0, 0.30, s)
    ys = np.arange(-0.05, 0.05, s)
    floor = np.array([[x, y, 0.0] for x in xs for y in ys])
    top = np.array([[x, y, 0.03] for x in xs[xs < 0.12] for y in ys])
    X = np.r_[floor, top]
    matches = np.array([[0.06, 0.0, 0.03], [0.28, 0.0, 0.0], [0.29, 0.02, 0.0]])
    labels = np.array([0, 1, 1])
    d, link = _matches_along_surface(X, _graph(X, 8, 2.5), matches, labels, 2, np.inf)
    under = np.arange(len(X)) < len(floor)
    under &= X[:, 0] < 0.12
    assert (link[under] == 1).all()
    assert (link[len(floor):] == 0).all()
    far = X[under][:, 0].min()
    assert d[under].max() >= 0.28 - far - 1e-9  # at least the straight run along the floor
    # beyond the limit: no match
    d, link = _matches_along_surface(X, _graph(X, 8, 2.5), matches, labels, 2, 0.05)
    assert np.isinf(d[under & (X[:, 0] < 0.1)]).all()
    assert (link[under & (X[:, 0] < 0.1)] == -1).all()


def test_free_space_rejects_a_point_seen_through():
    """A point in front of the observed surface is a violation; on it, visible; behind, neither."""
    T = _camera(0.0, 0.0)
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    view = CameraView(K, T, np.zeros((H, W), np.float32))
    P, _ = _points(0.0)
    surf = _Surface([view], P, cell=4)
    X = np.array([[0.01, 0.01, 0.1], [0.01, 0.01, 0.0], [0.01, 0.01, -0.1]])
    vis, bad = surf.status(X, rel=0.01, floor=0.004)
    assert bad[0].tolist() == [True, False, False]
    assert vis[0].tolist() == [False, True, False]


@pytest.mark.parametrize("block", [None, 999])
def test_the_z_buffer_is_each_cells_nearest_point(block, monkeypatch):
    """Known answer: each cell's depth is the smallest of the points projecting into it (cells
    with none: the smallest of their 3 x 3 neighbours', else infinite), by a plain loop over the
    points; points behind the camera or outside the image count nowhere. The same in one block
    and in blocks of 999 points (the last one short)."""
    if block is not None:
        monkeypatch.setattr(assign, "ZBUFFER_BLOCK", block)
    T = _camera(0.3, 0.2)
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    view = CameraView(K, T, np.zeros((H, W), np.float32))
    rng = np.random.default_rng(5)
    P = rng.uniform([-0.3, -0.2, -0.6], [0.9, 0.6, 0.7], (20000, 3))  # some behind (z > 0.5)
    cell = 4
    h, w = H // cell, W // cell
    expected = np.full((h, w), np.inf)
    u, v, z = view.project(P)
    for uk, vk, zk in zip(u, v, z, strict=True):
        if zk > 0 and 0 <= uk < w * cell and 0 <= vk < h * cell:
            r, c = int(vk // cell), int(uk // cell)
            expected[r, c] = min(expected[r, c], zk)
    assert np.isfinite(expected).sum() > 1000 and (z <= 0).any() and (u > W).any()
    holes = ~np.isfinite(expected)
    padded = np.pad(expected, 1, constant_values=np.inf)
    near = np.min([padded[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]
                   for dr in (-1, 0, 1) for dc in (-1, 0, 1)], axis=0)
    expected[holes] = near[holes]
    np.testing.assert_array_equal(_Surface([view], P, cell=cell).zbuf[0], expected)


def test_free_space_is_not_seen_through_a_hole_in_a_wall():
    """A wall whose dense points have a hole a few cells wide, the room far behind it: a point
    just behind the wall, in line with the hole, was not seen through (the wall's points stop
    short of the hole, not the wall); with a one-cell window it was, with the default not. A
    point in front of the wall stays a violation."""
    T = _camera(0.0, 0.0)
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    view = CameraView(K, T, np.zeros((H, W), np.float32))
    rng = np.random.default_rng(2)
    wall = np.c_[rng.uniform(-0.2, 0.2, 40000), rng.uniform(-0.2, 0.2, 40000), np.zeros(40000)]
    u, v, _ = view.project(wall)
    hole = (np.abs(u - W / 2) < 6) & (np.abs(v - H / 2) < 6)  # 12 px: three 4 px cells
    room = np.c_[rng.uniform(-0.5, 0.5, 40000), rng.uniform(-0.5, 0.5, 40000),
                 np.full(40000, -0.5)]
    occluders = np.r_[wall[~hole], room]
    z0 = view.project(np.zeros((1, 3)))[2][0]
    behind = np.array([[0.0, 0.0, -0.05]])
    front = np.array([[0.0, 0.0, 0.05]])
    one = _Surface([view], occluders, cell=4, window=1)
    three = _Surface([view], occluders, cell=4, window=AssignConfig().violation_window)
    assert z0 > 0 and hole.sum() > 0
    assert one.status(behind, 0.01, 0.004)[1][0, 0]  # seen through the hole
    assert not three.status(behind, 0.01, 0.004)[1][0, 0]
    assert three.status(front, 0.01, 0.004)[1][0, 0]


def _slab_over_table(rng) -> _Surface:
    """A's surface seen by one camera 0.6 m above: a base slab (z = 0.05, x < 0) over the table
    (z = 0); what lies under the slab is hidden from it."""
    T = _camera(0.0, 0.0, height=0.6)
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    table = np.c_[rng.uniform(-0.2, 0.2, 4000), rng.uniform(-0.1, 0.1, 4000), np.zeros(4000)]
    slab = np.c_[rng.uniform(-0.2, 0.0, 2000), rng.uniform(-0.1, 0.1, 2000),
                 np.full(2000, 0.05)]
    view = CameraView(K, T, np.zeros((H, W), np.float32))
    return _Surface([view], np.r_[table[table[:, 0] > 0], slab], cell=4)


def test_free_space_label_for_a_hidden_counterpart():
    """Points of B whose counterpart is hidden in A (no geometric fit either way): the hypothesis
    that puts them where A's camera saw empty table is violated; the other (hidden under the base)
    is not."""
    rng = np.random.default_rng(1)
    # B points above the table at x in (0.02, 0.08) belong to a link that slid out from under
    # the base by +0.1
    surf_a = _slab_over_table(rng)
    src = np.c_[rng.uniform(0.02, 0.08, 200), rng.uniform(-0.05, 0.05, 200), np.full(200, 0.03)]
    stay = Similarity(np.eye(3), np.zeros(3), 1.0)
    back = Similarity(np.eye(3), np.array([-0.1, 0.0, 0.0]), 1.0)
    dst = np.c_[rng.uniform(0.3, 0.4, 50), rng.uniform(-0.1, 0.1, 50), np.zeros(50)]  # no fit
    matches = np.array([[0.05, 0.0, 0.03], [0.06, 0.0, 0.03]])
    lab = label_points(src, np.tile([0, 0, 1.0], (200, 1)), dst, [stay, back], [1e-4, 1e-4],
                       matches, np.array([0, 0]), surface_src=surf_a, surface_dst=surf_a,
                       config=AssignConfig(cost_photo=0.0))
    # the nearest matches say "stay" (0); free space says the point was not there in A
    assert np.mean(lab == 1) > 0.95


def test_table_is_no_tie_where_only_the_other_links_counterpart_is_hidden():
    """Chest's drawer pulled out in B: its floor just outside the carcass has static neighbours
    (what moves as the base does). Moved back by the drawer's motion it lies under the base slab
    in A (hidden: its lack of fit says nothing); left where it is, A's camera saw the place empty
    (the base's counterpart in view, on no surface of A). Neither lands on A's surface, yet the
    cues are no tie, and the static neighbours must not pull the floor to the base (they did:
    chest's drawer floor in B, 1476 points, went to the carcass)."""
    surf_a = _slab_over_table(np.random.default_rng(3))
    X, Y = np.meshgrid(np.arange(0.02, 0.08, 0.002), np.arange(-0.03, 0.031, 0.002))
    src = np.c_[X.ravel(), Y.ravel(), np.full(X.size, 0.03)]
    # static points beside the floor, at its height (the carcass's side walls' lower edge)
    Xs, Ys = np.meshgrid(np.arange(0.02, 0.08, 0.001),
                         np.r_[-0.036, -0.034, -0.032, 0.032, 0.034, 0.036])
    static = np.c_[Xs.ravel(), Ys.ravel(), np.full(Xs.size, 0.03)]
    stay = Similarity(np.eye(3), np.zeros(3), 1.0)
    back = Similarity(np.eye(3), np.array([-0.1, 0.0, 0.0]), 1.0)
    Xd, Yd = np.meshgrid(np.arange(0.3, 0.4, 0.002), np.arange(-0.05, 0.05, 0.002))
    dst = np.c_[Xd.ravel(), Yd.ravel(), np.zeros(Xd.size)]  # no fit, 2 mm apart
    args = (src, np.tile([0, 0, 1.0], (len(src), 1)), dst, [stay, back], [1e-4, 1e-4],
            np.array([[0.0, 0.0, 0.03], [0.1, 0.0, 0.03]]), np.array([0, 1]), surf_a, surf_a,
            AssignConfig(cost_photo=0.0), static, 0)
    ev = _Evidence(*args)
    assert ev.hidden[1].all() and not ev.hidden[0].any() and not ev.fits_any.any()
    assert (ev.static_edges > 0).sum() >= 2 * X.shape[1]  # both long edges touch them
    assert (ev.label() == 1).all()
    # the failure this prevents: counted as a tie, the static edges pull more than a row's
    # worth of the floor to the base
    ev.like_base[1] = True
    assert (ev.label() == 0).sum() > X.shape[1]


def test_potts_smoothing_removes_isolated_flips():
    """A chain of points, labels 0 then 1, with isolated noisy unaries: the Potts term restores
    the two runs and keeps the boundary."""
    n = 100
    X = np.c_[np.arange(n) * 0.01, np.zeros(n), np.zeros(n)]
    truth = (np.arange(n) >= 50).astype(int)
    U = np.stack([truth.astype(float), 1.0 - truth]) * 0.4
    flips = np.array([10, 20, 70, 85])
    U[:, flips] = U[::-1, flips]
    G = _graph(X, 2, 1.5)
    lab = potts_expansion(U, G, 0.5)
    assert (lab == truth).all()
    assert (U.argmin(0) != truth).sum() == len(flips)


def test_potts_expansion_flips_a_whole_wrong_region():
    """A run of 20 points whose unaries mildly prefer the wrong label, inside a chain that is
    surely the other: per-point updates keep the run (each point would pay two cut edges on
    its own), the graph cut flips it whole (2 cut edges for the whole run are dearer than the
    run's unary cost)."""
    n = 100
    X = np.c_[np.arange(n) * 0.01, np.zeros(n), np.zeros(n)]
    U = np.zeros((2, n))
    U[1, :] = 1.0  # label 0 everywhere ...
    U[0, 40:60], U[1, 40:60] = 0.2, 0.0  # ... but the run mildly prefers label 1
    lab = potts_expansion(U, _graph(X, 2, 1.5), weight=0.5)
    # energy of keeping the run: 2 cuts = 1.0; of flipping it: 20 * 0.2 = 4.0: keep it ...
    assert (lab[40:60] == 1).all() and (lab[:40] == 0).all()
    # ... unless the cut is dear: weight 3 -> 2 cuts cost 6 > 4: the whole run flips
    lab = potts_expansion(U, _graph(X, 2, 1.5), weight=3.0)
    assert (lab == 0).all()


@pytest.mark.parametrize("K", [2, 3])
def test_potts_expansion_against_brute_force(K):
    """On small random graphs: the global optimum for two labels, within the factor 2 that
    alpha-expansion guarantees for more (and no worse than the best unary labelling)."""
    import itertools

    from scipy.sparse import csr_matrix

    rng = np.random.default_rng(K)
    for _ in range(60):
        n = 7
        U = rng.random((K, n)) * 2
        A = np.triu((rng.random((n, n)) < 0.4) * rng.uniform(0.5, 1.5, (n, n)), 1)
        G = csr_matrix(A + A.T)
        w = float(rng.random())
        edges = (np.nonzero(A)[0], np.nonzero(A)[1], w * A[np.nonzero(A)])
        lab = potts_expansion(U, G, w)
        e = potts_energy(U, edges, lab)
        opt = min(potts_energy(U, edges, np.array(lb))
                  for lb in itertools.product(range(K), repeat=n))
        assert e <= potts_energy(U, edges, U.argmin(0)) + 1e-9
        if K == 2:
            assert e == pytest.approx(opt, abs=1e-3)
        else:
            assert e <= 2 * opt + 1e-3


def test_hypothesis_fits_only_on_its_own_link_once_the_other_side_is_labelled():
    """A point of A whose "stayed" hypothesis lands on B's surface, but on points of the other
    link (which moved in there), and whose "moved" hypothesis lands on that link's own points:
    against B's whole surface both fit; against B's labels only "moved" does."""
    n = 400
    rng = np.random.default_rng(4)
    src = np.c_[rng.uniform(0.0, 0.1, n), rng.uniform(-0.01, 0.01, n), np.zeros(n)]
    stay = Similarity(np.eye(3), np.zeros(3), 1.0)
    shift = Similarity(np.eye(3), np.array([0.2, 0.0, 0.0]), 1.0)
    # B: link 1 where the shift puts the points, and more of link 1 where they were in A
    dst = np.r_[shift.apply(src), src + [0.0, 0.0, 0.0005]]
    dst_labels = np.ones(len(dst), int)
    far_matches = np.array([[1.0, 0.0, 0.0], [1.0, 0.1, 0.0]])  # no prior near the points
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    kw = dict(config=AssignConfig(cost_match=0.0))
    whole = label_points(src, normals, dst, [stay, shift], [2e-4, 2e-4], far_matches,
                         np.array([0, 1]), **kw)
    own = label_points(src, normals, dst, [stay, shift], [2e-4, 2e-4], far_matches,
                       np.array([0, 1]), dst_labels=dst_labels, **kw)
    assert (whole == 0).all()  # a tie: both fit, the first link wins
    assert (own == 1).all()


def test_an_unreadable_view_is_refused_not_skipped(tmp_path):
    """A view whose image cannot be read stops the labelling with its name: skipped, it would
    silently take that view's evidence away (and could change the kinematic tree)."""
    import cv2

    from artrecon.assign import views_from_sfm
    from artrecon.errors import ReconstructionError

    cv2.imwrite(str(tmp_path / "a.png"), np.full((H, W, 3), 128, np.uint8))
    sfm = SimpleNamespace(image_dir=tmp_path,
                          T_world_camera=lambda: {"a.png": np.eye(4), "b.png": np.eye(4)},
                          intrinsics=lambda name: np.array([[F, 0, W / 2], [0, F, H / 2],
                                                            [0, 0, 1.0]]))
    with pytest.raises(ReconstructionError, match="b.png"):
        views_from_sfm(sfm)
    (tmp_path / "b.png").write_bytes((tmp_path / "a.png").read_bytes())
    assert len(views_from_sfm(sfm)) == 2


def _colour_pngs(folder, count, rng):
    """``count`` 8-bit colour PNGs of noise, smooth ramps and grey pixels (r = g = b)."""
    import cv2

    names = []
    for k in range(count):
        img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        img[: H // 3] = np.linspace(0, 255, W, dtype=np.uint8)[None, :, None]  # grey ramp
        img[H // 3: H // 2, :, 1] = np.linspace(255, 0, W, dtype=np.uint8)[None]
        names.append(f"{k:03d}.png")
        cv2.imwrite(str(folder / names[-1]), img)
    return names


def test_the_png_grey_formula_is_opencvs_own_grey_decode(tmp_path):
    """png_grey of a PNG's colour decode is OpenCV's IMREAD_GRAYSCALE decode of it, bit for bit
    (libpng's conversion; cvtColor's differs), on noise, ramps and grey pixels."""
    import cv2

    from artrecon.assign import png_grey

    for name in _colour_pngs(tmp_path, 3, np.random.default_rng(7)):
        colour = cv2.imread(str(tmp_path / name), cv2.IMREAD_COLOR)
        own = cv2.imread(str(tmp_path / name), cv2.IMREAD_GRAYSCALE)
        assert np.array_equal(png_grey(colour), own)
        assert not np.array_equal(cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY), own)


@pytest.mark.parametrize("formula_holds", [True, False])
def test_the_views_grey_images_are_opencvs_grey_decodes(tmp_path, monkeypatch, formula_holds):
    """views_from_sfm's grey images equal OpenCV's IMREAD_GRAYSCALE decodes: through the
    formula once the first image confirmed it, through a second decode of every image when it
    did not (a formula made wrong here)."""
    import cv2

    from artrecon import assign

    names = _colour_pngs(tmp_path, 4, np.random.default_rng(8))
    if not formula_holds:
        monkeypatch.setattr(assign, "png_grey", lambda bgr: np.zeros(bgr.shape[:2], np.uint8))
    sfm = SimpleNamespace(image_dir=tmp_path,
                          T_world_camera=lambda: {n: np.eye(4) for n in names},
                          intrinsics=lambda name: np.array([[F, 0, W / 2], [0, F, H / 2],
                                                            [0, 0, 1.0]]))
    views = assign.views_from_sfm(sfm)
    for name, view in zip(names, views, strict=True):
        own = cv2.imread(str(tmp_path / name), cv2.IMREAD_GRAYSCALE).astype(np.float32)
        assert view.image.dtype == np.float32 and np.array_equal(view.image, own)
        assert np.array_equal(view.colour,
                              cv2.imread(str(tmp_path / name), cv2.IMREAD_COLOR)[:, :, ::-1])


def test_table_keeps_a_thin_strip_of_the_base_under_another_link():
    """A wall (x along it, z up), points 2 mm apart: its lowest two rows (z < 5 mm) are the base
    (link 0), the nine rows above another link (1); the table is below. Both links' motions
    slide the wall along itself, so only each point's nearest match (a weak prior) says which
    link it is on (they move it 6 mm apart, less than the two fit thresholds: near the joint).
    Without the table in the graph the strip's only other-labelled neighbours are link 1's and
    the Potts term flips it; with the table as neighbours that move as the base does, the strip
    keeps its label."""
    rng = np.random.default_rng(0)
    X, Z = np.meshgrid(np.arange(0.0, 0.2, 0.002), np.arange(1, 12) * 0.002)
    jitter = rng.normal(0.0, 0.0002, (X.size, 2))  # breaks the grid's ties among neighbours
    src = np.c_[X.ravel() + jitter[:, 0], np.zeros(X.size), Z.ravel() + jitter[:, 1]]
    truth = (src[:, 2] > 0.005).astype(int)
    Xd, Zd = np.meshgrid(np.arange(-0.1, 0.3, 0.002), np.arange(1, 12) * 0.002)
    dst = np.c_[Xd.ravel(), np.zeros(Xd.size), Zd.ravel()]  # the same wall, longer
    stay = Similarity(np.eye(3), np.zeros(3), 1.0)
    slide = Similarity(np.eye(3), np.array([0.006, 0.0, 0.0]), 1.0)
    tx = np.arange(-0.02, 0.22, 0.002)
    table = np.c_[tx, np.zeros(len(tx)), rng.normal(0.0, 0.0002, len(tx))]
    normals = np.tile([0.0, -1.0, 0.0], (len(src), 1))
    # each point's own label as its nearest match: the prior, 0.3, against 0.7 per cut edge
    args = (src, normals, dst, [stay, slide], [1e-4, 1e-4], src, truth)
    without = label_points(*args)
    with_table = label_points(*args, static=table, base=0)
    strip = truth == 0
    assert (without[strip] == 1).all()
    assert (with_table[strip] == 0).all()
    # the border may shift by a row (the strip's own graph reaches up further than down), and a
    # corner where the table juts out may follow it; the rest stays where it was
    assert (with_table[src[:, 2] > 0.007] == 1).mean() > 0.99
    # a table beside another base link (1) holds the strip on link 1
    assert (label_points(*args, static=table, base=1) == 1).all()
    # motions 20 mm apart (beyond the fit thresholds), but the other configuration shows no
    # surface there (neither motion fits, as for a surface only one configuration shows): the
    # geometric cue is silent, the table counts again
    far = (src, normals, dst + [0.0, 0.5, 0.0],
           [stay, Similarity(np.eye(3), np.array([0.02, 0.0, 0.0]), 1.0)], [1e-4, 1e-4], src,
           truth)
    assert (label_points(*far)[strip] == 1).all()
    assert (label_points(*far, static=table, base=0)[strip] == 0).all()


def test_table_does_not_pull_a_link_lying_on_it_to_the_base():
    """A low wall on the table, two rows of points 2 mm apart: the base (link 0) for x < 0.1 m,
    another link (1) beyond, which slid 30 mm away from the wall between the configurations
    (far more than its fit thresholds: its own cues tell the two motions apart). Every point of
    link 1 has table neighbours; were they to count as the base's whatever the motions, their
    cut edges would outweigh the failed fit of the base's motion and pull link 1 to the base.
    They count only where the motions are alike, so link 1 keeps its label."""
    rng = np.random.default_rng(1)
    X, Z = np.meshgrid(np.arange(0.0, 0.2, 0.002), np.array([1, 2]) * 0.002)
    jitter = rng.normal(0.0, 0.0002, (X.size, 2))
    src = np.c_[X.ravel() + jitter[:, 0], np.zeros(X.size), Z.ravel() + jitter[:, 1]]
    truth = (src[:, 0] >= 0.1).astype(int)
    stay = Similarity(np.eye(3), np.zeros(3), 1.0)
    away = Similarity(np.eye(3), np.array([0.0, 0.03, 0.0]), 1.0)
    dst = np.r_[src[truth == 0], away.apply(src[truth == 1])]
    tx, ty = np.meshgrid(np.arange(-0.02, 0.22, 0.002), np.arange(-0.01, 0.011, 0.002))
    table = np.c_[tx.ravel(), ty.ravel(), rng.normal(0.0, 0.0002, tx.size)]
    normals = np.tile([0.0, -1.0, 0.0], (len(src), 1))
    args = (src, normals, dst, [stay, away], [1e-4, 1e-4], src, truth)
    labels = label_points(*args, static=table, base=0)
    assert (labels == truth).mean() > 0.98  # the border may shift by a column
    assert (labels[src[:, 0] > 0.105] == 1).all()
    # the failure this prevents: the table counted against link 1 everywhere
    ev = _Evidence(*args, None, None, AssignConfig(), table, 0)
    assert (ev.static_edges[truth == 1] > 0).mean() > 0.9 and not ev.like_base[1].any()
    ev.like_base[:] = True
    assert (ev.label()[truth == 1] == 0).mean() > 0.9


@pytest.mark.parametrize("window", [0, 2, 4, -3])
def test_a_free_space_window_not_centred_on_its_cell_is_refused(window):
    with pytest.raises(ValueError, match="violation_window must be an odd number"):
        AssignConfig(violation_window=window)
