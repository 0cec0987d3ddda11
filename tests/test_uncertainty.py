"""Triangulation covariances of SfM points and the links' motions fitted with them
(artrecon.uncertainty), on synthetic data with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from artrecon.procrustes import Similarity, robust_shared_scale_transforms, rotation_angle
from artrecon.uncertainty import point_covariances, robust_gls_transforms


def _two_ring_reconstruction(point):
    """A pycolmap reconstruction of one point seen by five cameras 0.8 m away on an arc of 60
    degrees about the y axis (all looking at the origin), and the cameras' (R, t, fx, fy)."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    fx, fy = 500.0, 520.0
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=640, height=480,
                                                    params=[fx, fy, 320, 240], camera_id=1))
    cams = []
    for i, ang in enumerate(np.radians([-30, -15, 0, 15, 30])):
        rot = Rotation.from_rotvec([0, ang, 0]).as_matrix()
        centre = 0.8 * np.array([np.sin(ang), 0.0, -np.cos(ang)])
        t = -rot @ centre
        image = pycolmap.Image(name=f"{i}.png", camera_id=1, image_id=i + 1,
                               points2D=pycolmap.Point2DList([pycolmap.Point2D(np.zeros(2))]))
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.c_[rot, t]))
        cams.append((rot, t, fx, fy))
    track = pycolmap.Track()
    for i in range(len(cams)):
        track.add_element(i + 1, 0)
    pid = rec.add_point3D(np.asarray(point, float), track)
    return rec, pid, cams


def test_point_covariance_is_the_inverse_information_of_its_views():
    """The covariance equals (sum J^T J)^-1 with each view's projection derivative taken by
    finite differences, and its long axis runs along the cameras' mean viewing direction (z)
    several times longer than across it (views within +-30 degrees)."""
    point = np.array([0.01, 0.02, 0.03])
    rec, pid, cams = _two_ring_reconstruction(point)
    cov = point_covariances(rec, [pid])[0]

    def project(cam, x):
        rot, t, fx, fy = cam
        xc = rot @ x + t
        return np.array([fx * xc[0] / xc[2], fy * xc[1] / xc[2]])

    info = np.zeros((3, 3))
    for cam in cams:
        jac = np.stack([(project(cam, point + h) - project(cam, point - h)) / 2e-7
                        for h in np.eye(3) * 1e-7], axis=1)
        info += jac.T @ jac
    np.testing.assert_allclose(cov, np.linalg.inv(info), rtol=1e-5)
    vals, vecs = np.linalg.eigh(cov)
    assert abs(vecs[2, 2]) > 0.99  # the least precise direction: depth
    assert np.sqrt(vals[2] / vals[0]) > 2.5
    assert point_covariances(rec, []).shape == (0, 3, 3)


def test_group_sums_are_add_at_bit_for_bit():
    """The per-column bincount gives np.add.at's sums exactly (float32 rows into float64, each
    group's rows in their order), empty groups zero: the matches stage's point descriptors and
    covariances are the same as before it, only faster."""
    from artrecon.geometry import group_sums

    rng = np.random.default_rng(3)
    for m, n, k in ((50000, 4000, 128), (3000, 10, 9), (0, 5, 3)):
        groups = rng.integers(0, n - 1, m)  # the last group stays empty
        values = rng.standard_normal((m, k)).astype(np.float32)
        expected = np.zeros((n, k))
        np.add.at(expected, groups, values)
        got = group_sums(groups, values, n)
        assert got.dtype == np.float64 and np.array_equal(got, expected)


def test_inverse_informations_at_once_are_each_ones():
    """The covariances of a stack of informations are each one's own (eigenvalues floored at
    1 / MAX_ANISOTROPY^2 of the largest), bit for bit, and a point with no information gets the
    huge isotropic covariance."""
    from artrecon.uncertainty import MAX_ANISOTROPY, _inverse_information

    rng = np.random.default_rng(4)
    a = rng.standard_normal((200, 3, 3))
    info = a @ np.swapaxes(a, 1, 2)
    info[7] = np.diag([1.0, 1e-12, 4.0])  # nearly degenerate: floored
    info[9] = 0.0  # seen by no usable view
    got = _inverse_information(info)
    for h, c in zip(info, got, strict=True):
        vals, vecs = np.linalg.eigh(h)
        if not vals[-1] > 0:
            assert np.array_equal(c, np.eye(3) * 1e12)
            continue
        vals = np.maximum(vals, vals[-1] / MAX_ANISOTROPY ** 2)
        assert np.array_equal(c, (vecs / vals) @ vecs.T)


def _thin_link(seed: int, n: int = 120):
    """Matches on a thin beam (16 x 3 x 2 cm, its top face and sides) turned 30 degrees about y
    between the configurations, B also in another frame (scale 1.3). Each point is triangulated
    by views on one side of it, from a ring of cameras 20-70 degrees above the table: 5 x more
    error along that side's mean viewing direction than across it, in A and in B (the same
    cameras, the object turned)."""
    rng = np.random.default_rng(seed)
    pts = np.c_[rng.uniform(0, 0.16, n), rng.uniform(-0.015, 0.015, n), np.zeros(n)]
    side = rng.random(n) < 0.3
    pts[side, 1] = np.sign(pts[side, 1]) * 0.015
    pts[side, 2] = rng.uniform(-0.02, 0, side.sum())
    motion = Similarity(Rotation.from_rotvec([0, -np.pi / 6, 0]).as_matrix(), [0.0, 0.0, 0.0])
    frame = Similarity(Rotation.from_rotvec([0.2, 0.1, -0.3]).as_matrix(), [0.1, -0.2, 0.3], 1.3)
    truth = frame @ motion

    def covariances():
        az = rng.uniform(0, 2 * np.pi, n)
        el = rng.uniform(np.radians(20), np.radians(70), n)
        depth = np.c_[np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]
        across = np.eye(3)[None] - np.einsum("ni,nj->nij", depth, depth)
        return (0.5e-3) ** 2 * np.einsum("ni,nj->nij", depth, depth) + (0.1e-3) ** 2 * across

    cov_a, cov_b_world = covariances(), covariances()
    # through the Cholesky factor, which is unique: multivariate_normal factors by SVD, whose
    # signs follow the machine's LAPACK, and the same seed gave other noise on an AMD EPYC
    # than on the machine the test was written on (GLS RMS 0.105 deg there; on the EPYC
    # 0.117, where the gate, 0.75 x the isotropic 0.156, failed)
    noise_a = np.einsum("nij,nj->ni", np.linalg.cholesky(cov_a), rng.standard_normal((n, 3)))
    noise_b = np.einsum("nij,nj->ni", np.linalg.cholesky(cov_b_world),
                        rng.standard_normal((n, 3)))
    pa = pts + noise_a
    pb = frame.apply(motion.apply(pts) + noise_b)
    cov_b = frame.scale ** 2 * np.einsum("ij,njk,lk->nil", frame.rotation, cov_b_world,
                                         frame.rotation)
    return pa, pb, cov_a, cov_b, truth


def test_gls_fit_holds_a_thin_links_roll_that_isotropic_weights_let_go():
    """On a thin link whose points are far less precise along their viewing directions than
    across them, the isotropic fit takes depth errors for a roll about the link's length; the
    fit with the covariances, the maximum-likelihood one, errs a third less (20 seeds, RMS
    rotation error: 0.22 and 0.12 degrees; the noise drawn through Cholesky factors, the same
    on every machine)."""
    errors = []
    for seed in range(20):
        pa, pb, cov_a, cov_b, truth = _thin_link(seed)
        (iso,), _ = robust_shared_scale_transforms([(pa, pb)])
        (gls,), (w,), (mats,) = robust_gls_transforms([(pa, pb)], [(cov_a, cov_b)])
        assert w.shape == (len(pa),) and mats.shape == (len(pa), 3, 3)
        errors.append([np.degrees(rotation_angle(T.rotation.T @ truth.rotation))
                       for T in (iso, gls)])
    rms = np.sqrt(np.mean(np.square(errors), axis=0))
    assert rms[1] < 0.75 * rms[0], rms


def test_gls_fit_is_exact_on_exact_data_and_the_isotropic_fit_with_unit_covariances():
    """Noise-free pairs give the true motions and common scale; identity covariances give the
    isotropic robust fit of one link (the same Cauchy EM on lengths)."""
    pa, pb, cov_a, cov_b, truth = _thin_link(0)
    exact_b = truth.apply(pa)
    rng = np.random.default_rng(1)
    other_a = rng.uniform(-0.1, 0.1, (80, 3))
    other = Similarity(Rotation.from_rotvec([0.2, 0.1, -0.3]).as_matrix(), [0.1, -0.2, 0.3], 1.3)
    (t1, t2), _, _ = robust_gls_transforms([(pa, exact_b), (other_a, other.apply(other_a))],
                                           [(cov_a, cov_b), (np.tile(np.eye(3), (80, 1, 1)),) * 2])
    for T, want in ((t1, truth), (t2, other)):
        np.testing.assert_allclose(T.matrix, want.matrix, atol=1e-9)
    unit = np.tile(np.eye(3), (len(pa), 1, 1))
    (iso,), (w_iso,) = robust_shared_scale_transforms([(pa, pb)])
    (gls,), (w_gls,), _ = robust_gls_transforms([(pa, pb)], [(unit, unit)])
    np.testing.assert_allclose(gls.matrix, iso.matrix, atol=1e-6)
    np.testing.assert_allclose(w_gls, w_iso, atol=1e-5)


def test_robust_refit_with_covariances_keeps_weight_matrices_for_the_bootstrap():
    """robust_refit with the matches' covariances fits with them (precisions per match, the
    anchors' weight matrices appended), and the confidence's linearised resampled fits agree
    with exact refits of the same resamples (identity matrices: weighted Procrustes)."""
    from artrecon.confidence import _batch_gls_step, _batch_rigid
    from artrecon.link_motions import robust_refit
    from artrecon.segment import Segmentation

    pa, pb, cov_a, cov_b, truth = _thin_link(3)
    rng = np.random.default_rng(0)
    base_a = rng.uniform(-0.1, 0.1, (200, 3))
    frame = Similarity(truth.rotation @ Rotation.from_rotvec([0, np.pi / 6, 0]).as_matrix(),
                       truth.translation, truth.scale)
    base_b = frame.apply(base_a) + rng.normal(0, 1e-4, base_a.shape)
    room_a = rng.uniform(-1, 1, (100, 3))
    room_b = frame.apply(room_a) + rng.normal(0, 5e-4, room_a.shape)
    unit = np.tile(np.eye(3) * 1e-8, (300, 1, 1))
    all_a, all_b = np.vstack([pa, base_a]), np.vstack([pb, base_b])
    labels = np.r_[np.zeros(len(pa), int), np.ones(200, int)]
    seg = Segmentation(labels=labels, transforms=[truth, frame], scale=truth.scale)
    covs = (np.concatenate([cov_a, unit[:200]]), np.concatenate([cov_b, unit[:200]]),
            {1: (unit[:100], unit[:100])})
    refit, anchors = robust_refit(all_a, all_b, seg, {1: (room_a, room_b)}, covs)
    assert refit.precisions.shape == (len(all_a), 3, 3) and refit.weights.shape == (len(all_a),)
    assert len(anchors[1]) == 4 and anchors[1][3].shape == (100, 3, 3)
    iso, _ = robust_refit(all_a, all_b, seg, {1: (room_a, room_b)})
    assert iso.precisions is None
    err = [np.degrees(rotation_angle(s.transforms[0].rotation.T @ truth.rotation))
           for s in (iso, refit)]
    assert err[1] < err[0], err
    # one Gauss-Newton step from the full fit = the exact refit of a resample (identity weights)
    (T,), _ = robust_shared_scale_transforms([(pa, pb)])
    draw = rng.integers(0, len(pa), size=(10, len(pa)))
    rots, trans = _batch_gls_step(pa, pb, T, np.tile(np.eye(3), (len(pa), 1, 1)), draw)
    rots_x, trans_x = _batch_rigid(pa[draw], pb[draw], T.scale)
    spread = max(np.degrees(rotation_angle(T.rotation.T @ r)) for r in rots_x)
    for r1, r2 in zip(rots, rots_x, strict=True):
        assert np.degrees(rotation_angle(r1.T @ r2)) < 0.02 * spread
    np.testing.assert_allclose(trans, trans_x, atol=1e-3 * np.ptp(pb))


@pytest.mark.parametrize("bad", ["covariances", "populations"])
def test_gls_fit_checks_its_inputs(bad):
    pa, pb, cov_a, cov_b, _ = _thin_link(0, n=20)
    with pytest.raises(ValueError):
        if bad == "covariances":
            robust_gls_transforms([(pa, pb)], [(cov_a[:5], cov_b)])
        else:
            robust_gls_transforms([(pa, pb)], [(cov_a, cov_b)], [np.zeros(3, int)])
