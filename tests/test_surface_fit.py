"""The links' surface refit (artrecon.surface_fit): a link's motion from its matches and its dense
surface together, on synthetic links whose true motion is known."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from artrecon.confidence import _batch_gls_step
from artrecon.geometry import point_spacing, rotation_about
from artrecon.procrustes import Similarity, rigid_transform, rotation_angle
from artrecon.segment import Segmentation
from artrecon.surface_fit import SurfaceConfig, refit_link, surface_refit

MM = 1e-3
#: The true motion: 30 degrees about a vertical hinge at the origin (a scissor's pivot).
TRUE = Similarity(rotation_about([0.0, 0.0, 1.0], np.radians(30.0)), np.zeros(3), 1.0)


def _box_surface(rng, size, spacing):
    """Oriented points on the faces of an axis-aligned box centred at the origin (half sizes
    ``size``), about ``spacing`` apart, bottom face left out (it lies on a table)."""
    pts, nrm = [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            if axis == 2 and sign < 0:
                continue
            u, v = [a for a in range(3) if a != axis]
            nu = max(2, int(2 * size[u] / spacing))
            nv = max(2, int(2 * size[v] / spacing))
            gu, gv = np.meshgrid(np.linspace(-size[u], size[u], nu),
                                 np.linspace(-size[v], size[v], nv))
            p = np.zeros((gu.size, 3))
            p[:, u], p[:, v], p[:, axis] = gu.ravel(), gv.ravel(), sign * size[axis]
            n = np.zeros_like(p)
            n[:, axis] = sign
            pts.append(p)
            nrm.append(n)
    return np.vstack(pts), np.vstack(nrm)


def _blade(rng, noise_dense=0.3 * MM, spacing=1.0 * MM):
    """A scissor blade 180 x 14 x 4 mm (long along x), its A and B dense surfaces: sampled
    independently in each configuration, with noise along the normal."""
    size = np.array([90.0, 7.0, 2.0]) * MM
    centre = np.array([50.0, 0.0, 2.0]) * MM
    pa, na = _box_surface(rng, size, spacing)
    pa = pa + centre
    pb, nb = _box_surface(rng, size, spacing * 1.07)  # other samples of the same surface
    pb = TRUE.apply(pb + centre)
    nb = nb @ TRUE.rotation.T
    pa = pa + na * rng.normal(0, noise_dense, (len(pa), 1))
    pb = pb + nb * rng.normal(0, noise_dense, (len(pb), 1))
    return pa, na, pb, nb


def _matches(rng, n=100, noise=0.3 * MM, roll_bias_deg=0.0):
    """Matches on the blade's top face, isotropic noise; ``roll_bias_deg``: B's matches rolled
    about the blade's length (the depth errors of a narrow link's features, all one way)."""
    a = np.c_[rng.uniform(-40, 140, n), rng.uniform(-7, 7, n), np.full(n, 4.0)] * MM
    b = TRUE.apply(a)
    if roll_bias_deg:
        length = TRUE.rotation @ np.array([1.0, 0.0, 0.0])
        roll = Similarity(rotation_about(length, np.radians(roll_bias_deg)), np.zeros(3), 1.0)
        centre = b.mean(0)
        b = roll.apply(b - centre) + centre
    a = a + rng.normal(0, noise, a.shape)
    b = b + rng.normal(0, noise, b.shape)
    weights = np.tile(np.eye(3) / (2 * noise ** 2), (n, 1, 1))
    return a, b, weights


def _matches_fit(a, b, weights):
    """The matches' own fit (isotropic weights: the start the links stage gives the refit)."""
    return rigid_transform(a, b)


def _angle_deg(T):
    return float(np.degrees(rotation_angle(T.rotation @ TRUE.rotation.T)))


def test_the_surface_corrects_a_narrow_links_roll_the_matches_got_wrong():
    """The matches' depths err one way across the 14 mm blade (a 0.5 degree roll): the blade's
    surface, seen in both configurations, pins the roll; the matches keep the motion along it."""
    rng = np.random.default_rng(0)
    pa, na, pb, nb = _blade(rng)
    a, b, w = _matches(rng, roll_bias_deg=0.5)
    start = _matches_fit(a, b, w)
    refined, report, prior = refit_link(start, a, b, w, pa, na, pb, nb, 1.0 * MM)
    assert _angle_deg(start) > 0.5
    assert _angle_deg(refined) < min(0.2, _angle_deg(start) / 5), report
    assert report["applied"] and report["pairs"] > 1000
    assert prior is not None and prior[0].shape == (6, 6)


def test_with_unbiased_matches_the_surface_makes_the_motion_more_precise():
    """Over seeds, with noise alone in both, matches and surface together beat the matches."""
    before, after = [], []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        pa, na, pb, nb = _blade(rng)
        a, b, w = _matches(rng, n=60)
        start = _matches_fit(a, b, w)
        refined, _, _ = refit_link(start, a, b, w, pa, na, pb, nb, 1.0 * MM)
        before.append(_angle_deg(start))
        after.append(_angle_deg(refined))
    assert np.median(after) < 0.5 * np.median(before), (before, after)


def test_points_of_another_surface_mislabelled_as_the_link_do_not_pull_it():
    """15% of A's points labelled the blade are the table beside it (they do not move with it):
    the robust weights and the normals' agreement keep them out."""
    rng = np.random.default_rng(1)
    pa, na, pb, nb = _blade(rng)
    k = int(0.15 * len(pa))
    table = np.c_[rng.uniform(-40, 140, k), rng.uniform(8, 30, k), np.zeros(k)] * MM
    pa = np.vstack([pa, table])
    na = np.vstack([na, np.tile([0.0, 0.0, 1.0], (k, 1))])
    a, b, w = _matches(rng, roll_bias_deg=0.5)
    refined, report, _ = refit_link(_matches_fit(a, b, w), a, b, w, pa, na, pb, nb, 1.0 * MM)
    assert _angle_deg(refined) < 0.2, report


def test_the_common_scale_is_held_and_the_motion_recovered_in_sfm_units():
    """The photo route: B's frame at 2.5 times A's scale, in units that are not metres."""
    rng = np.random.default_rng(2)
    pa, na, pb, nb = _blade(rng)
    a, b, w = _matches(rng, roll_bias_deg=0.5)
    s = 2.5
    start = _matches_fit(a, b, w)
    start = Similarity(start.rotation, s * start.translation, s)
    refined, report, _ = refit_link(start, a, s * b, w / s ** 2, pa, na, s * pb, nb,
                                    s * 1.0 * MM)
    assert refined.scale == s
    assert _angle_deg(refined) < min(0.2, _angle_deg(start) / 5), report


def test_too_few_dense_points_keep_the_matches_motion_and_say_why():
    rng = np.random.default_rng(3)
    pa, na, pb, nb = _blade(rng)
    a, b, w = _matches(rng)
    start = _matches_fit(a, b, w)
    kept, report, prior = refit_link(start, a, b, w, pa[:10], na[:10], pb, nb, 1.0 * MM)
    assert kept is start and prior is None and not report["applied"]
    assert "fewer than" in report["reason"]


def _segmentation(rng):
    """Two links: a static base (the table-top plate) and the blade; the blade's matches rolled."""
    pa, na, pb, nb = _blade(rng)
    a, b, w = _matches(rng, roll_bias_deg=0.5)
    base_a = np.c_[rng.uniform(-100, 100, 80), rng.uniform(20, 60, 80), np.zeros(80)] * MM
    base_b = base_a + rng.normal(0, 0.3 * MM, base_a.shape)
    points_a, points_b = np.vstack([base_a, a]), np.vstack([base_b, b])
    labels = np.r_[np.zeros(80, int), np.ones(len(a), int)]
    precisions = np.concatenate([np.tile(np.eye(3) / (2 * (0.3 * MM) ** 2), (80, 1, 1)), w])
    seg = Segmentation(labels=labels, transforms=[Similarity(), _matches_fit(a, b, w)],
                       scale=1.0, rms=[0.0, 0.0], weights=np.ones(len(labels)),
                       precisions=precisions)
    table_a = np.c_[rng.uniform(-100, 100, 500), rng.uniform(20, 60, 500), np.zeros(500)] * MM
    up = np.tile([0.0, 0.0, 1.0], (500, 1))
    # the refit reads the dense points' positions and normals (artrecon.dense.DensePoints)
    dense_a = SimpleNamespace(points=np.vstack([table_a, pa]), normals=np.vstack([up, na]))
    dense_b = SimpleNamespace(points=np.vstack([table_a, pb]), normals=np.vstack([up, nb]))
    lab_a = np.r_[np.zeros(500, int), np.ones(len(pa), int)]
    lab_b = np.r_[np.zeros(500, int), np.ones(len(pb), int)]
    return seg, points_a, points_b, dense_a, dense_b, lab_a, lab_b


def test_surface_refit_keeps_the_base_and_refits_the_moving_link():
    rng = np.random.default_rng(4)
    seg, points_a, points_b, dense_a, dense_b, lab_a, lab_b = _segmentation(rng)
    out, reports = surface_refit(seg, 0, points_a, points_b, dense_a, dense_b, lab_a, lab_b)
    assert out.transforms[0] is seg.transforms[0]
    assert [r["link"] for r in reports] == [1] and reports[0]["applied"]
    assert _angle_deg(out.transforms[1]) < min(0.2, _angle_deg(seg.transforms[1]) / 2)
    assert not np.any(out.surface_information[0]) and np.any(out.surface_information[1])
    off, none = surface_refit(seg, 0, points_a, points_b, dense_a, dense_b, lab_a, lab_b,
                              SurfaceConfig(enabled=False))
    assert off is seg and none == []


def test_the_bootstraps_resamples_hold_the_surface():
    """Every match drawn once, the bootstrap's step from the refined motion is nil only with
    the surface's term (its gradient balances the matches'); the surface narrows the spread."""
    rng = np.random.default_rng(5)
    seg, points_a, points_b, dense_a, dense_b, lab_a, lab_b = _segmentation(rng)
    out, _ = surface_refit(seg, 0, points_a, points_b, dense_a, dense_b, lab_a, lab_b)
    m = out.labels == 1
    pa, pb, mats = points_a[m], points_b[m], out.precisions[m]
    T = out.transforms[1]
    prior = (out.surface_information[1], out.surface_gradient[1])
    once = np.arange(int(m.sum()))[None]
    with_prior = _batch_gls_step(pa, pb, T, mats, once, prior)[0][0]
    without = _batch_gls_step(pa, pb, T, mats, once)[0][0]
    assert np.degrees(rotation_angle(with_prior @ T.rotation.T)) < 1e-3
    assert np.degrees(rotation_angle(without @ T.rotation.T)) > 0.3  # back to the matches' fit
    draw = rng.integers(0, int(m.sum()), (100, int(m.sum())))
    spread = [np.std([np.degrees(rotation_angle(r @ T.rotation.T)) for r in
                      _batch_gls_step(pa, pb, T, mats, draw, p)[0]]) for p in (prior, None)]
    assert spread[0] < 0.5 * spread[1], spread


@pytest.mark.parametrize("setting", ["weight", "reach", "iterations"])
def test_surface_settings_are_reconstruct_settings(setting):
    from artrecon.settings import RANGES, ReconstructConfig, with_settings
    assert f"surface.{setting}" in RANGES
    value = {"weight": 0.5, "reach": 3.0, "iterations": 7}[setting]
    config = with_settings(ReconstructConfig(), {f"surface.{setting}": value})
    assert getattr(config.surface, setting) == value


def test_point_spacing_is_the_median_nearest_neighbour_distance():
    """The dense spacing every threshold of the refit (and the labelling, and the meshing) is a
    multiple of: a 2 mm grid with a few stray points far off gives 2 mm; too few points, 0."""
    g = np.arange(10) * 2 * MM
    grid = np.stack(np.meshgrid(g, g, [0.0]), axis=-1).reshape(-1, 3)
    stray = np.array([[1.0, 1.0, 1.0], [2.0, -1.0, 0.5]])
    assert point_spacing(np.vstack([grid, stray])) == pytest.approx(2 * MM)
    assert point_spacing(grid[:1]) == 0.0
