"""Features only where the object is (issue 20): with known poses and the object's region
(``cameras.json``'s ``region``), SfM searches each image only in the box around the region's
projection."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
import render_fixture
from render_fixture import look_at

from artrecon import io, sfm
from artrecon.errors import InputError
from artrecon.reconstruct import _resolve_inputs
from artrecon.sfm import extraction


def _camera(eye, target=(0.0, 0.0, 0.08)):
    return look_at(np.asarray(eye, float), target)


def test_a_box_holds_the_region_projection_and_its_margin():
    K = render_fixture.K
    intr = io.Intrinsics(K, (render_fixture.WIDTH, render_fixture.HEIGHT))
    region = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.04, 0.04)
                       for z in (0.0, 0.12)])
    T = _camera([0.45, 0.1, 0.3])
    boxes = extraction.region_boxes(region, {"v": T}, intr, intr.size, margin=10)
    x0, y0, x1, y1 = boxes["v"]
    T_cw = np.linalg.inv(T)
    P = region @ T_cw[:3, :3].T + T_cw[:3, 3]
    uv = (P @ K.T)[:, :2] / P[:, 2:3]
    # every corner projects inside, at least the margin from the box's edges
    assert np.all(uv[:, 0] - 10 >= x0) and np.all(uv[:, 1] - 10 >= y0)
    assert np.all(uv[:, 0] + 10 < x1) and np.all(uv[:, 1] + 10 < y1)
    # and the box is no larger than that, but for the corner's alignment
    assert x1 - np.ceil(uv[:, 0].max() + 10) <= 1 and y1 - np.ceil(uv[:, 1].max() + 10) <= 1
    assert np.floor(uv[:, 0].min() - 10) - x0 < extraction.BOX_ALIGN
    assert x0 % extraction.BOX_ALIGN == 0 and y0 % extraction.BOX_ALIGN == 0
    assert 0 < (x1 - x0) * (y1 - y0) < 0.5 * intr.size[0] * intr.size[1]


def test_a_region_behind_or_around_the_camera_gives_the_whole_image():
    intr = io.Intrinsics(render_fixture.K, (render_fixture.WIDTH, render_fixture.HEIGHT))
    T = _camera([0.45, 0.0, 0.3])
    centre = T[:3, 3]
    region = centre + np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.1, 0.1)
                                for z in (-0.1, 0.1)])  # the camera sits inside the region
    boxes = extraction.region_boxes(region, {"v": T}, intr, intr.size, margin=0)
    assert boxes["v"] == (0, 0, *intr.size)


def test_features_in_a_box_are_the_whole_images_features_there(tmp_path):
    """Known answer: away from the box's edges, the keypoints and descriptors of the cropped
    search are those of the whole image (the crop's corner on the octaves' grid)."""
    path = render_fixture.render_view(tmp_path / "v.png", "a", _camera([0.42, -0.15, 0.3]))
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    config = sfm.SfMConfig(max_num_features=100_000)  # no cap: both keep every keypoint
    sift = extraction.sift_extractor(config)
    whole, d_whole = extraction.image_features(gray, sift, config)
    box = (96, 64, 416, 352)
    crop, d_crop = extraction.image_features(gray, sift, config, box)
    assert len(crop) > 200
    # COLMAP coordinates (pixel centres at 0.5) within the box
    assert crop[:, 0].min() >= box[0] and crop[:, 0].max() <= box[2]
    assert crop[:, 1].min() >= box[1] and crop[:, 1].max() <= box[3]

    def interior(rows):
        scale = np.hypot(rows[:, 2], rows[:, 4])
        reach = 24 + 6 * scale  # the keypoint's blur and descriptor window, generously
        return ((rows[:, 0] - reach > box[0]) & (rows[:, 0] + reach < box[2])
                & (rows[:, 1] - reach > box[1]) & (rows[:, 1] + reach < box[3]))

    a, da = whole[interior(whole)], d_whole[interior(whole)]
    b, db = crop[interior(crop)], d_crop[interior(crop)]
    assert len(a) > 100
    dist = np.linalg.norm(a[:, None, :2] - b[None, :, :2], axis=2)
    nearest = dist.argmin(1)
    found = dist[np.arange(len(a)), nearest] < 1e-3
    assert found.mean() > 0.99, f"{found.mean():.3f} of the interior keypoints found again"
    desc_diff = np.abs(da[found] - db[nearest[found]]).max(1)
    assert np.median(desc_diff) < 1e-3


def _blobs(centres, size=(640, 480), sigma=6.0):
    """A grey image (uint8) of dark Gaussian blobs on a mid-grey ground, at ``centres`` (OpenCV
    pixel coordinates, pixel centres on integers)."""
    yy, xx = np.mgrid[0:size[1], 0:size[0]].astype(float)
    img = np.full(xx.shape, 200.0)
    for x, y in centres:
        img -= 150.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * sigma ** 2))
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def test_background_features_outside_the_box_sit_where_the_image_has_them():
    """Known answer: blobs at known sub-pixel places. Searched in the quarter-scale image, those
    outside the box give keypoints at their centres in the whole image's COLMAP coordinates
    (pixel centres at 0.5), and none falls inside the box, whose own search finds its blob."""
    outside = [(100.3, 90.7), (520.6, 100.2), (110.1, 400.4), (530.8, 380.9), (320.4, 60.3)]
    inside = [(320.2, 250.6)]
    gray = _blobs(outside + inside)
    config = sfm.SfMConfig(background_features=64, background_scale=0.25)
    box = (256, 192, 400, 320)
    sift = extraction.sift_extractor(config)
    rows, desc = extraction.image_features(gray, sift, config, box)
    background = extraction.sift_extractor(config, config.background_features)
    both, both_desc = extraction._with_background(gray, box, rows, desc, background, config)
    assert len(both) == len(both_desc) and len(both) > len(rows)
    np.testing.assert_array_equal(both[:len(rows)], rows)
    extra = both[len(rows):]
    in_box = ((extra[:, 0] >= box[0]) & (extra[:, 0] <= box[2]) & (extra[:, 1] >= box[1])
              & (extra[:, 1] <= box[3]))
    assert not in_box.any()
    for x, y in outside:
        d = np.hypot(extra[:, 0] - (x + 0.5), extra[:, 1] - (y + 0.5))
        assert d.min() < 0.3, f"blob at ({x}, {y}): nearest background keypoint {d.min():.2f} px"
    for x, y in inside:
        d = np.hypot(rows[:, 0] - (x + 0.5), rows[:, 1] - (y + 0.5))
        assert d.min() < 0.1


def _capture_folder(tmp_path, region):
    from test_sfm import _write_images
    _write_images(tmp_path / "images", 6)
    cams = {"K": [[50, 0, 31.5], [0, 50, 23.5], [0, 0, 1]], "width": 64, "height": 48,
            "images": [{"file": f"img_{i:02d}.png", "T_world_camera": np.eye(4).tolist()}
                       for i in range(6)]}
    if region is not None:
        cams["region"] = region
    (tmp_path / "cameras.json").write_text(json.dumps(cams))
    return tmp_path


def test_the_region_comes_only_with_the_camera_files_own_poses(tmp_path):
    pts = [[0, 0, 1], [1, 0, 1], [0, 1, 1], [0, 0, 2]]
    folder = _capture_folder(tmp_path, {"points": pts, "source": "a test"})
    iset, _, poses = _resolve_inputs(folder, None, True, "A")
    np.testing.assert_allclose(iset.region, pts)
    iset, _, poses = _resolve_inputs(folder, None, None, "A")  # SfM from the images
    assert poses is None and iset.region is None
    given = {f"img_{i:02d}.png": np.eye(4) for i in range(6)}  # poses of another frame, maybe
    iset, _, poses = _resolve_inputs(folder, None, given, "A")
    assert poses is not None and iset.region is None


@pytest.mark.parametrize("region, says", [
    ({"points": [[0, 0, 1], [1, 0, 1]]}, "at least four"),
    ({"points": [[0, 0, 1], [1, 0, 1], [0, 1, 1], [0, 0, float("nan")]]}, "at least four"),
    ({"points": "here"}, "region"),
    ({"vertices": [[0, 0, 1]]}, "region"),
])
def test_a_malformed_region_is_refused_with_its_file(tmp_path, region, says):
    folder = _capture_folder(tmp_path, region)
    with pytest.raises(InputError, match=says) as err:
        _resolve_inputs(folder, None, True, "A")
    assert "cameras.json" in str(err.value) and "remove the region" in str(err.value)


def test_no_region_is_none(tmp_path):
    assert io.load_region(_capture_folder(tmp_path, None) / "cameras.json") is None


def test_the_capture_gives_the_surveys_hull_or_the_cube_around_its_sphere():
    from sim.capture.image_set import object_region
    from sim.views import ViewPlan

    hull = [[0.0, 0.0, 0.4], [0.1, 0.0, 0.4], [0.0, 0.1, 0.4], [0.0, 0.0, 0.5]]
    plan = ViewPlan(centre=np.array([0.02, 0.02, 0.42]), radius=0.08,
                    survey={"hull_vertices": hull})
    np.testing.assert_allclose(object_region(plan)["points"], hull)
    cube = np.array(object_region(ViewPlan(centre=np.array([0.0, 0.0, 0.4]), radius=0.1))
                    ["points"])
    assert cube.shape == (8, 3)
    np.testing.assert_allclose(cube.min(axis=0), [-0.1, -0.1, 0.3])
    np.testing.assert_allclose(cube.max(axis=0), [0.1, 0.1, 0.5])


@pytest.mark.slow
def test_sfm_in_the_region_keeps_the_objects_points(rendered, tmp_path):
    """The hinge fixture's configuration A with its poses, once with the object's box as the
    region and once without: every keypoint lies in its image's box but for the few background
    ones outside it, the features are fewer,
    and the object keeps (nearly) all its triangulated points."""
    truth = rendered["a"]
    lo, hi = truth.object_points.min(axis=0), truth.object_points.max(axis=0)
    region = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                       for z in (lo[2], hi[2])])
    iset = io.load_image_folder(truth.folder)
    intr, poses = io.load_cameras_json(iset.cameras_file)

    def on_object(res):
        xyz = np.array([p.xyz for p in res.reconstruction.points3D.values()])
        return int(np.all((xyz > lo - 0.002) & (xyz < hi + 0.002), axis=1).sum())

    whole = sfm.run_sfm(iset, tmp_path / "whole", intr, poses, progress=False)
    boxed_set = dataclasses.replace(iset, region=region)
    boxed = sfm.run_sfm(boxed_set, tmp_path / "boxed", intr, poses, progress=False)
    boxes = extraction.region_boxes(region, poses, intr, iset.size,
                                    sfm.SfMConfig().region_margin_px)
    feats = extraction.read_features(tmp_path / "boxed" / "database.db")
    n_whole = sum(len(f[1]) for f in extraction.read_features(
        tmp_path / "whole" / "database.db").values())
    config = sfm.SfMConfig()
    for name, (_, kp, _) in feats.items():
        x0, y0, x1, y1 = boxes[name]
        inside = (kp[:, 0] >= x0 - 0.5) & (kp[:, 0] < x1) & (kp[:, 1] >= y0 - 0.5) & (
            kp[:, 1] < y1)
        # the box's own features first, then at most background_features outside it
        n_box = int(np.argmin(inside)) if not inside.all() else len(kp)
        assert inside[:n_box].all() and not inside[n_box:].any(), name
        assert len(kp) - n_box <= config.background_features, name
    assert sum(len(f[1]) for f in feats.values()) < 0.8 * n_whole
    print(f"object points: {on_object(boxed)} in the region, {on_object(whole)} from the whole "
          f"images")
    assert on_object(boxed) >= 0.9 * on_object(whole)
