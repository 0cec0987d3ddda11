"""Procrustes: known random transforms are recovered exactly, degenerate input raises."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from artrecon.errors import DegenerateError
from artrecon.procrustes import (
    Similarity,
    batch_similarity_transforms,
    cauchy_weights,
    rigid_transform,
    robust_shared_scale_transforms,
    rotation_angle,
    shared_scale_transforms,
    similarity_transform,
)


def random_similarity(rng, scale=None):
    return Similarity(
        Rotation.random(random_state=int(rng.integers(2**31))).as_matrix(),
        rng.uniform(-10, 10, 3),
        float(np.exp(rng.uniform(-2, 2))) if scale is None else scale,
    )


@pytest.mark.parametrize("weighted", [False, True])
@pytest.mark.parametrize("with_scale", [False, True])
@pytest.mark.parametrize("n", [3, 4, 50])
def test_recovers_known_transform_every_option(weighted, with_scale, n):
    rng = np.random.default_rng(n + 10 * weighted + 100 * with_scale)
    truth = random_similarity(rng, scale=None if with_scale else 1.0)
    src = rng.normal(size=(n, 3))
    weights = rng.uniform(0.1, 2.0, n) if weighted else None
    est = similarity_transform(src, truth.apply(src), weights=weights, with_scale=with_scale)
    np.testing.assert_allclose(est.matrix, truth.matrix, atol=1e-9)
    assert np.linalg.det(est.rotation) == pytest.approx(1.0, abs=1e-12)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(3, 40), spread=st.floats(1e-2, 1e2))
def test_property_exact_without_noise(seed, n, spread):
    rng = np.random.default_rng(seed)
    truth = random_similarity(rng)
    src = spread * rng.normal(size=(n, 3))
    est = similarity_transform(src, truth.apply(src))
    assert rotation_angle(est.rotation.T @ truth.rotation) < 1e-9
    assert abs(est.scale / truth.scale - 1) < 1e-9
    np.testing.assert_allclose(est.apply(src), truth.apply(src), atol=1e-9 * spread * truth.scale)


def test_zero_weights_ignore_wrong_pairs_exactly():
    rng = np.random.default_rng(3)
    truth = random_similarity(rng)
    src = rng.normal(size=(20, 3))
    dst = truth.apply(src)
    dst[:5] += rng.normal(size=(5, 3)) * 10  # wrong pairs
    weights = np.r_[np.zeros(5), np.ones(15)]
    est = similarity_transform(src, dst, weights=weights)
    np.testing.assert_allclose(est.matrix, truth.matrix, atol=1e-9)
    unweighted = similarity_transform(src, dst)
    assert np.abs(unweighted.matrix - truth.matrix).max() > 1e-2


def test_mirrored_data_never_gives_a_reflection():
    rng = np.random.default_rng(4)
    src = rng.normal(size=(30, 3))
    dst = src * np.array([1.0, 1.0, -1.0])  # a mirror image: no proper rotation maps it exactly
    est = similarity_transform(src, dst)
    assert np.linalg.det(est.rotation) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(est.rotation @ est.rotation.T, np.eye(3), atol=1e-12)


def test_rigid_with_known_scale():
    rng = np.random.default_rng(5)
    truth = random_similarity(rng, scale=2.7)
    src = rng.normal(size=(10, 3))
    est = rigid_transform(src, truth.apply(src), scale=2.7)
    assert est.scale == 2.7
    np.testing.assert_allclose(est.matrix, truth.matrix, atol=1e-9)


def test_shared_scale_exact_and_helps_the_small_group():
    rng = np.random.default_rng(6)
    s = 1.9
    t1, t2 = random_similarity(rng, s), random_similarity(rng, s)
    big = rng.normal(size=(400, 3))
    small = 0.1 * rng.normal(size=(6, 3))  # small, few points: its own scale is poor with noise
    exact = shared_scale_transforms([(big, t1.apply(big)), (small, t2.apply(small))])
    for est, truth in zip(exact, (t1, t2), strict=True):
        np.testing.assert_allclose(est.matrix, truth.matrix, atol=1e-9)
    errs_shared, errs_alone = [], []
    for trial in range(20):
        r = np.random.default_rng(100 + trial)
        db = t1.apply(big) + 0.01 * r.normal(size=big.shape)
        ds = t2.apply(small) + 0.01 * r.normal(size=small.shape)
        shared = shared_scale_transforms([(big, db), (small, ds)])
        errs_shared.append(abs(shared[1].scale - s))
        errs_alone.append(abs(similarity_transform(small, ds).scale - s))
    assert np.mean(errs_shared) < 0.2 * np.mean(errs_alone)


def test_batch_equals_single():
    rng = np.random.default_rng(7)
    src = rng.normal(size=(25, 3, 3))
    dst = rng.normal(size=(25, 3, 3))
    rot, trans, scales = batch_similarity_transforms(src, dst)
    rot_f, trans_f, scales_f = batch_similarity_transforms(src, dst, scale=1.5)
    for i in range(25):
        single = similarity_transform(src[i], dst[i])
        np.testing.assert_allclose(rot[i], single.rotation, atol=1e-9)
        np.testing.assert_allclose(trans[i], single.translation, atol=1e-9)
        assert scales[i] == pytest.approx(single.scale, rel=1e-9)
        fixed = rigid_transform(src[i], dst[i], scale=1.5)
        np.testing.assert_allclose(rot_f[i], fixed.rotation, atol=1e-9)
        np.testing.assert_allclose(trans_f[i], fixed.translation, atol=1e-9)


def test_similarity_algebra():
    rng = np.random.default_rng(8)
    a, b = random_similarity(rng), random_similarity(rng)
    p = rng.normal(size=(7, 3))
    np.testing.assert_allclose((a @ b).apply(p), a.apply(b.apply(p)), atol=1e-9)
    np.testing.assert_allclose(a.inverse().apply(a.apply(p)), p, atol=1e-9)
    np.testing.assert_allclose(Similarity.from_matrix(a.matrix).matrix, a.matrix, atol=1e-12)
    np.testing.assert_allclose(a.apply(p[0]), a.apply(p[:1])[0])
    assert Similarity.from_dict(a.to_dict()) == a  # exact round trip
    assert a != b


def test_rotation_angle_accurate_near_zero_and_pi():
    for angle in (1e-10, 1e-4, 1.0, np.pi - 1e-6):
        r = Rotation.from_rotvec(angle * np.array([0.0, 0.6, 0.8])).as_matrix()
        assert rotation_angle(r) == pytest.approx(angle, rel=1e-6)


def test_fewer_than_three_pairs_raises():
    src = np.array([[0.0, 0, 0], [1, 0, 0]])
    with pytest.raises(DegenerateError, match="at least 3"):
        similarity_transform(src, src)
    with pytest.raises(DegenerateError, match="at least 3"):
        similarity_transform(np.eye(3), np.eye(3), weights=np.array([1.0, 1.0, 0.0]))


def test_collinear_points_raise():
    src = np.outer(np.arange(10.0), [1.0, 2.0, 3.0])
    with pytest.raises(DegenerateError, match="collinear"):
        similarity_transform(src, src + 1)
    with pytest.raises(DegenerateError, match="collinear"):
        rigid_transform(src, src + 1)


def test_shapes_are_validated():
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        similarity_transform(np.zeros((4, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="same shape"):
        similarity_transform(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="weights"):
        similarity_transform(np.eye(3), np.eye(3), weights=np.ones(2))
    with pytest.raises(ValueError, match="scale"):
        Similarity(np.eye(3), np.zeros(3), -1.0)


def _link_with_outliers(rng, truth, n, noise, outliers, offset):
    """A small link (6 x 4 x 2 cm) of n noisy pairs under ``truth``, the last ``outliers`` of them
    (at one end, as matches crowd near a hinge) pushed ``offset`` off, all the same way."""
    src = rng.normal(size=(n, 3)) * [0.03, 0.02, 0.01]
    src[-outliers:, 0] = 0.03 + rng.uniform(0, 0.005, outliers)
    dst = truth.apply(src) + rng.normal(0.0, noise, (n, 3))
    dst[len(src) - outliers:] += offset * np.array([0.0, 0.6, 0.8])
    return src, dst


def test_robust_recovers_a_known_transform_despite_gross_outliers():
    """Two links with one common scale; the small one has 4 of its 150 pairs 4 mm off (20 x the
    0.2 mm noise), all at one end. Least squares tilts its rotation by 0.1-0.3 degrees; the
    Cauchy maximum-likelihood fit, its noise scale estimated with it, stays near the truth and
    gives the outliers hardly any weight."""
    errors = []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        scale = 1.3
        big_t, small_t = random_similarity(rng, scale), random_similarity(rng, scale)
        big = _link_with_outliers(rng, big_t, 400, 2e-4, 1, 0.0)
        small = _link_with_outliers(rng, small_t, 150, 2e-4, 4, 4e-3)
        ls = shared_scale_transforms([big, small])
        robust, weights = robust_shared_scale_transforms([big, small])
        errors.append([np.degrees(rotation_angle(t[1].rotation @ small_t.rotation.T))
                       for t in (ls, robust)])
        assert robust[0].scale == robust[1].scale == pytest.approx(scale, rel=1e-3)
        assert np.all(weights[1][-4:] < 0.02 * np.median(weights[1][:-4]))
    errors = np.array(errors)
    assert errors[:, 0].min() > 0.09
    assert errors[:, 1].max() < 0.1 and errors[:, 1].mean() < 0.5 * errors[:, 0].mean(), errors


def test_robust_is_exact_without_noise_and_separates_populations():
    """Exact pairs give the exact transform (the noise scale 0: every weight 1); a second
    population with ten times the noise (background matches anchoring a link) keeps its weight
    as long as it is measured against its own noise."""
    rng = np.random.default_rng(3)
    truth = random_similarity(rng, 0.8)
    src = rng.normal(size=(60, 3))
    (est,), (w,) = robust_shared_scale_transforms([(src, truth.apply(src))])
    np.testing.assert_allclose(est.matrix, truth.matrix, atol=1e-9)
    assert np.all(w > 0.999)
    own = rng.normal(size=(100, 3))
    far = rng.normal(size=(100, 3)) * 5
    src = np.vstack([own, far])
    dst = truth.apply(src) + np.vstack([rng.normal(0, 1e-3, (100, 3)),
                                        rng.normal(0, 1e-2, (100, 3))])
    pops = np.r_[np.zeros(100, int), np.ones(100, int)]
    _, (w_sep,) = robust_shared_scale_transforms([(src, dst)], [pops])
    _, (w_one,) = robust_shared_scale_transforms([(src, dst)])
    assert np.median(w_sep[100:]) > 0.5 * np.median(w_sep[:100])
    # one noise scale for both: the noisy half is shut out
    assert np.median(w_one[100:]) < 0.1 * np.median(w_one[:100])


def test_cauchy_weights():
    r = np.array([0.0, 1.0, 3.0])
    np.testing.assert_allclose(cauchy_weights(r, 1.0), [1.0, 0.5, 0.1])
    assert np.all(cauchy_weights(r, 0.0) == 1.0)
    with pytest.raises(ValueError, match="populations"):
        robust_shared_scale_transforms([(np.eye(3), np.eye(3))], [None, None])
