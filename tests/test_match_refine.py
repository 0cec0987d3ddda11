"""The matches' photometric refinement (artrecon.match_refine) on a textured plane seen by a ring
of cameras in two configurations (the plane moved between them): rendered exactly by
homographies, so the truth of every point is known."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from synthetic import ring_cameras

from artrecon.assign import CameraView
from artrecon.geometry import rotation_about
from artrecon.match_refine import PhotometricConfig, refine_match_points

MM = 1e-3
#: The plane: 0.2 m square at z = 0, its texture 800 x 800 pixels (0.25 mm each).
SIZE, TEX = 0.2, 800
F, W, H = 500.0, 640, 480


def _texture(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 255, (TEX, TEX)).astype(np.float32)
    t = cv2.GaussianBlur(t, (0, 0), 10.0)
    return cv2.normalize(t, None, 0, 255, cv2.NORM_MINMAX)


def _ring(n: int = 12, distance: float = 0.6, elevation_deg: float = 50.0) -> list[np.ndarray]:
    """Cameras (T_cw) on a ring looking at the origin, OpenCV convention (z forward)."""
    out = []
    for R, t in ring_cameras(n, distance, (elevation_deg,)):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        out.append(T)
    return out


def _render(texture: np.ndarray, T_cw: np.ndarray, motion: np.ndarray, gain=1.0, offset=0.0):
    """The plane (moved by ``motion``) seen by camera ``T_cw``: texture pixel -> image pixel is
    K [r1 r2 t] S, S mapping texture pixels to plane metres."""
    K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1]])
    M = T_cw @ motion
    S = np.array([[SIZE / TEX, 0, -SIZE / 2], [0, SIZE / TEX, -SIZE / 2], [0, 0, 1]])
    Hm = K @ np.c_[M[:3, 0], M[:3, 1], M[:3, 3]] @ S
    img = cv2.warpPerspective(texture, Hm, (W, H), flags=cv2.INTER_CUBIC,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return CameraView(K, T_cw, (gain * img + offset).astype(np.float32))


def _scene(seed: int = 0, n_points: int = 60, noise: float = 0.5 * MM, gain=1.0, offset=0.0):
    rng = np.random.default_rng(seed)
    texture = _texture(seed)
    motion = np.eye(4)
    motion[:3, :3] = rotation_about([0.3, -0.2, 1.0], np.radians(25.0))
    motion[:3, 3] = [0.01, -0.02, 0.0]
    cams = _ring()
    views_a = [_render(texture, T, np.eye(4)) for T in cams]
    views_b = [_render(texture, T, motion, gain, offset) for T in cams]
    true_a = np.c_[rng.uniform(-0.07, 0.07, (n_points, 2)), np.zeros(n_points)]
    true_b = true_a @ motion[:3, :3].T + motion[:3, 3]
    pa = true_a + rng.normal(0, noise, true_a.shape)
    pb = true_b + rng.normal(0, noise, true_b.shape)
    rows = np.repeat(np.arange(n_points), len(cams))
    vidx = np.tile(np.arange(len(cams)), n_points)
    normals = np.tile([0.0, 0.0, 1.0], (n_points, 1))
    motions = np.repeat(motion[None], n_points, 0)
    return views_a, views_b, (rows, vidx), pa, pb, normals, motions, motion


def _offsets(pa, pb, motion):
    return np.linalg.norm(pa @ motion[:3, :3].T + motion[:3, 3] - pb, axis=1)


def test_the_two_points_of_a_match_become_one_physical_point():
    views_a, views_b, obs, pa, pb, normals, motions, motion = _scene()
    before = _offsets(pa, pb, motion)
    ra, rb, refined = refine_match_points(views_a, views_b, obs, obs, pa, pb, normals, motions)
    assert refined.mean() > 0.9
    after = _offsets(ra, rb, motion)[refined]
    # 0.5 mm of noise on each point; the refined pair is one point to a few hundredths of a mm
    assert np.median(before) > 0.5 * MM
    assert np.median(after) < 0.03 * MM, np.median(after) / MM
    # and on the surface: A's points on the plane z = 0, B's on the moved plane
    assert np.median(np.abs(ra[refined, 2])) < 0.03 * MM
    on_b = (rb[refined] - motion[:3, 3]) @ motion[:3, :3]
    assert np.median(np.abs(on_b[:, 2])) < 0.03 * MM
    # the points not refined are returned as given
    np.testing.assert_array_equal(ra[~refined], pa[~refined])


def test_gain_and_offset_between_configurations_change_nothing():
    """B's images darker and lifted (another exposure, a turned link's shading): the same
    points."""
    views_a, views_b, obs, pa, pb, normals, motions, motion = _scene()
    ra, rb, refined = refine_match_points(views_a, views_b, obs, obs, pa, pb, normals, motions)
    views_a, views_b, obs, pa, pb, normals, motions, motion = _scene(gain=0.6, offset=40.0)
    ra2, rb2, refined2 = refine_match_points(views_a, views_b, obs, obs, pa, pb, normals,
                                             motions)
    both = refined & refined2
    assert both.mean() > 0.85
    assert np.median(np.linalg.norm(rb2[both] - rb[both], axis=1)) < 0.01 * MM


def test_a_flat_patch_or_a_wrong_view_is_not_refined():
    """A point on a textureless patch keeps its SfM position; so does one whose B views see
    something else (the motion used for its patch is wrong by far more than a patch)."""
    views_a, views_b, obs, pa, pb, normals, motions, motion = _scene()
    # blank a disc of A's texture around point 0 in every A view (flat patch)
    for v in views_a:
        u = v.K @ (v.T_cw[:3, :3] @ pa[0] + v.T_cw[:3, 3])
        cv2.circle(v.image, (int(u[0] / u[2]), int(u[1] / u[2])), 12, 128.0, -1)
    # point 1's B point far from where its patch is
    pb = pb.copy()
    pb[1] += [0.02, 0.0, 0.0]
    ra, rb, refined = refine_match_points(views_a, views_b, obs, obs, pa, pb, normals, motions)
    assert not refined[0] and not refined[1]
    np.testing.assert_array_equal(rb[1], pb[1])
    assert refined[2:].mean() > 0.85


def test_too_few_views_leave_a_point_alone():
    views_a, views_b, (rows, vidx), pa, pb, normals, motions, motion = _scene(n_points=10)
    keep_b = (rows != 0) | (vidx < 2)  # point 0 seen in only two B views
    ra, rb, refined = refine_match_points(views_a, views_b, (rows, vidx),
                                          (rows[keep_b], vidx[keep_b]), pa, pb, normals,
                                          motions, PhotometricConfig(min_views=3))
    assert not refined[0]
    assert refined[1:].all()


@pytest.mark.parametrize("n", [0])
def test_no_matches(n):
    views_a, views_b, obs, pa, pb, normals, motions, motion = _scene(n_points=3)
    ra, rb, refined = refine_match_points(views_a, views_b, (np.zeros(0, int),) * 2,
                                          (np.zeros(0, int),) * 2, pa[:n], pb[:n], normals[:n],
                                          motions[:n])
    assert ra.shape == (0, 3) and rb.shape == (0, 3) and refined.shape == (0,)
