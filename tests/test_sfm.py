"""SfM stage and image-folder input: clear errors on bad input, camera poses on rendered sets."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import render_fixture as rf
from render_fixture import align_to_truth, camera_centres

from artrecon import io, sfm
from artrecon.errors import InputError, ReconstructionError
from artrecon.sfm import extraction

#: Camera centre error gates after the similarity alignment, as a fraction of the ring radius
#: (0.5 m): 0.5% = 2.5 mm. Measured: about 0.1 mm (SfM from images), ~0 with known poses.
CENTRE_ERROR_GATE = 0.0025


def _write_images(folder, n, size=(64, 48), seed=0):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for i in range(n):
        img = (rng.random((size[1], size[0], 3)) * 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"img_{i:02d}.png"), img)


def test_missing_folder_says_so(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        io.load_image_folder(tmp_path / "nope")


def test_file_instead_of_folder(tmp_path):
    f = tmp_path / "x.png"
    f.write_bytes(b"not a folder")
    with pytest.raises(InputError, match="is a file"):
        io.load_image_folder(f)


def test_empty_folder(tmp_path):
    with pytest.raises(InputError, match="no images"):
        io.load_image_folder(tmp_path)


def test_too_few_images(tmp_path):
    _write_images(tmp_path, 3)
    with pytest.raises(InputError, match="only 3 image"):
        io.load_image_folder(tmp_path)


def test_unreadable_image_is_named(tmp_path):
    _write_images(tmp_path, 6)
    (tmp_path / "img_03.png").write_bytes(b"\x89PNG broken")
    with pytest.raises(InputError, match="img_03.png"):
        io.load_image_folder(tmp_path)


def test_mixed_sizes_are_named(tmp_path):
    _write_images(tmp_path, 6)
    cv2.imwrite(str(tmp_path / "img_05.png"), np.zeros((10, 20, 3), np.uint8))
    with pytest.raises(InputError, match=r"img_05.png is 20x10"):
        io.load_image_folder(tmp_path)


def test_capture_folder_layout(tmp_path):
    _write_images(tmp_path / "images", 6)
    (tmp_path / "ground_truth").mkdir()
    (tmp_path / "ground_truth" / "poses.json").write_text("{}")
    T = np.eye(4)
    cams = {"K": [[50, 0, 31.5], [0, 50, 23.5], [0, 0, 1]], "width": 64, "height": 48,
            "images": [{"file": "img_00.png", "T_world_camera": T.tolist()},
                       {"file": "img_01.png", "T_world_camera": None}]}
    (tmp_path / "cameras.json").write_text(json.dumps(cams))
    s = io.load_image_folder(tmp_path)
    assert s.image_dir == tmp_path / "images" and len(s.names) == 6 and s.size == (64, 48)
    intr, poses = io.load_cameras_json(s.cameras_file)
    assert intr.size == (64, 48) and intr.K[0, 0] == 50
    assert list(poses) == ["img_00.png"]  # the null pose is unknown, not an error
    np.testing.assert_allclose(intr.params, [50, 50, 32.0, 24.0])  # COLMAP pixel centres


def test_intrinsics_forms(tmp_path):
    K = io.parse_intrinsics("100,110,50,40").K
    np.testing.assert_allclose(K, [[100, 0, 50], [0, 110, 40], [0, 0, 1]])
    with pytest.raises(InputError, match="fx,fy,cx,cy"):
        io.parse_intrinsics("100,110")
    with pytest.raises(ValueError, match=r"\(3, 3\)"):
        io.parse_intrinsics(np.eye(2))


def test_pair_selection_window_and_exhaustive():
    names = [f"{i:02d}" for i in range(10)]
    seq = sfm.select_pairs(names, {}, sfm.SfMConfig(matching="sequential", sequential_window=2))
    assert ("00", "01") in seq and ("00", "02") in seq and ("00", "03") not in seq
    assert len(seq) == 9 + 8
    ex = sfm.select_pairs(names, {}, sfm.SfMConfig(matching="exhaustive"))
    assert len(ex) == 45
    with pytest.raises(ValueError, match="matching"):
        sfm.select_pairs(names, {}, sfm.SfMConfig(matching="vocab"))


def test_retrieval_closes_the_loop():
    """Images sharing descriptors are paired even when far apart in name order."""
    rng = np.random.default_rng(1)
    names = [f"{i:02d}" for i in range(12)]
    base = rng.random((12, 300, 128)).astype(np.float32)
    base[11] = base[0] + 0.01 * rng.random((300, 128))  # last view sees what the first sees
    feats = {n: (i, None, base[i] * 255) for i, n in enumerate(names)}
    pairs = sfm.select_pairs(names, feats, sfm.SfMConfig(sequential_window=1,
                                                         retrieval_neighbours=1))
    assert ("00", "11") in pairs


def test_sfm_failure_is_explained(tmp_path):
    """Unrelated noise images register nothing: the error says how many and what to try."""
    _write_images(tmp_path / "img", 6, size=(160, 120))
    s = io.load_image_folder(tmp_path / "img")
    with pytest.raises(ReconstructionError, match=r"of 6 images.*(--intrinsics|overlap)"):
        sfm.run_sfm(s, tmp_path / "out", progress=False)
    assert (tmp_path / "out" / "colmap.log").stat().st_size > 0


@pytest.mark.slow
def test_sfm_from_images_recovers_camera_poses(rendered, reconstruction_sfm):
    """Every view registers; after a similarity alignment the camera centres match the truth
    and keep their order around the ring (a folded ring would fail this)."""
    _, out = reconstruction_sfm
    for c in ("a", "b"):
        truth = rendered[c]
        centres = camera_centres(out / c / "sparse" / "0")
        assert len(centres) == len(truth.names)
        S, err = align_to_truth(out / c / "sparse" / "0", truth)
        print(f"config {c}: camera centre error after Umeyama: mean {err.mean() * 1e3:.3f} mm, "
              f"max {err.max() * 1e3:.3f} mm")
        assert err.max() < CENTRE_ERROR_GATE
        # Ring order: consecutive views of a ring stay consecutive in azimuth.
        world = S.apply(np.array([centres[n] for n in truth.names]))
        az = np.unwrap(np.arctan2(world[:18, 1], world[:18, 0]))
        assert np.all(np.diff(az) > 0)


@pytest.mark.slow
@pytest.mark.parametrize("missed", [False, True])
def test_self_calibration_keeps_the_first_pass_cameras_unless_it_missed_images(
        rendered, tmp_path, monkeypatch, missed):
    """Self-calibration's second pass (focal length held): the first pass's cameras are kept and
    the points triangulated again when it registered every image; with an image it could not
    register (noise among one ring of the hinge), incremental mapping runs again from scratch,
    which may register it. Either way every view of the ring registers and the focal length is
    the renderer's."""
    import shutil

    from artrecon.sfm import mapping

    calls = []
    for name in ("map_incremental", "_retriangulate"):
        real = getattr(mapping, name)
        monkeypatch.setattr(mapping, name, lambda *a, _real=real, _name=name, **k:
                            calls.append(_name) or _real(*a, **k))
    folder = tmp_path / "img"
    folder.mkdir()
    ring = rendered["a"].names[:18]  # the lower ring, 20 degrees apart
    for name in ring:
        shutil.copy(rendered["a"].folder / "images" / name, folder / name)
    if missed:
        noise = np.random.default_rng(0).integers(0, 256, (rf.HEIGHT, rf.WIDTH, 3), np.uint8)
        cv2.imwrite(str(folder / "zz_noise.png"), noise)
    result = sfm.run_sfm(io.load_image_folder(folder), tmp_path / "out", progress=False)
    # the first pass's map_incremental is the stage's own; these are the second pass's calls
    assert calls == (["map_incremental"] if missed else ["_retriangulate"])
    registered = set(camera_centres(tmp_path / "out" / "sparse" / "0"))
    assert registered == set(ring)
    (camera,) = result.reconstruction.cameras.values()
    assert abs(camera.mean_focal_length() / rf.FOCAL - 1) < 0.01


def test_mapping_spaces_its_global_adjustments_by_the_configured_growth():
    """sfm.global_ba_growth reaches COLMAP's incremental mapper for both the images and the
    points, with or without given intrinsics (which still hold the focal length fixed)."""
    from artrecon.sfm.mapping import _mapping_options

    for intrinsics in (None, io.Intrinsics(rf.K, (rf.WIDTH, rf.HEIGHT))):
        opts = _mapping_options(intrinsics, sfm.SfMConfig(global_ba_growth=1.6), seed=3)
        assert opts.ba_global_frames_ratio == opts.ba_global_points_ratio == 1.6
        assert opts.ba_refine_focal_length == (intrinsics is None)
    default = _mapping_options(None, sfm.SfMConfig(), seed=0)
    assert default.ba_global_frames_ratio == sfm.SfMConfig().global_ba_growth


@pytest.mark.slow
def test_known_poses_fast_path(rendered, reconstruction_poses):
    """With the arm's poses the model is metric and in the world frame: no alignment needed."""
    _, out = reconstruction_poses
    for c in ("a", "b"):
        truth = rendered[c]
        centres = camera_centres(out / c / "sparse" / "0")
        err = [np.linalg.norm(centres[n] - truth.T_world_camera[i, :3, 3])
               for i, n in enumerate(truth.names)]
        assert max(err) < 1e-6


def test_layout_error_catches_a_folded_ring():
    """A ring folded onto a half ring registers fine but is far from the reference layout."""
    from types import SimpleNamespace

    ang = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    ref = {f"{i:02d}": np.eye(4) for i in range(24)}
    for i, a in enumerate(ang):
        ref[f"{i:02d}"][:3, 3] = [np.cos(a), np.sin(a), 0.5]

    def result(centres):
        out = {}
        for i, c in enumerate(centres):
            T = np.eye(4)
            T[:3, 3] = c
            out[f"{i:02d}"] = T
        return SimpleNamespace(T_world_camera=lambda: out)

    good = [2.0 * ref[f"{i:02d}"][:3, 3] + 1.0 for i in range(24)]
    folded_ang = np.where(ang < np.pi, ang, 2 * np.pi - ang)
    folded = [[np.cos(a), np.sin(a), 0.5] for a in folded_ang]
    assert sfm.layout_error(result(good), ref) < 1e-9
    assert sfm.layout_error(result(folded), ref) > sfm.SfMConfig().max_layout_error


def test_given_focal_refused_only_when_the_images_clearly_disagree():
    """check_given_focal: refused when the images support a focal length more than
    max_focal_mismatch away *and* fit it much better; right intrinsics (ratio ~1) and a focal
    length that drifts without fitting better (weak geometry) pass. Figures as measured on the
    hinge fixture's plain folder A (see SfMConfig.max_focal_mismatch)."""
    from artrecon.errors import MismatchError
    from artrecon.sfm.focal_check import check_given_focal

    config = sfm.SfMConfig()

    def figures(given, supported, before, after):
        return {"given_fx_px": given, "given_focal_px": given, "supported_focal_px": supported,
                "ratio": given / supported, "reprojection_given_px": before,
                "reprojection_free_px": after}

    check_given_focal({}, config, "A")  # not one camera: nothing to check
    check_given_focal(figures(554.26, 554.34, 0.167, 0.167), config, "A")  # right
    check_given_focal(figures(1108.5, 558.5, 0.30, 0.20), config, "A")  # drift, no better fit
    check_given_focal(figures(580.0, 554.3, 0.60, 0.15), config, "A")  # within the margin
    for given, supported, before, after in [(1108.5, 558.5, 1.30, 0.12),
                                            (277.1, 524.0, 1.15, 0.25)]:
        with pytest.raises(MismatchError) as info:
            check_given_focal(figures(given, supported, before, after), config, "SfM on A")
        msg = str(info.value)
        assert msg.startswith("SfM on A:") and "Likely cause: the intrinsics" in msg, msg
        assert f"f ≈ {supported:.0f} px" in msg and f"fx is {given:.0f} px" in msg, msg
        assert f"ratio {given / supported:.2f}" in msg and "leave --intrinsics out" in msg, msg
        assert info.value.agreement["supported_focal_px"] == supported


def _blobs(size, seed):
    """A grey image of smooth blobs: SIFT finds keypoints in every octave."""
    rng = np.random.default_rng(seed)
    img = np.full((size[1], size[0]), 128, np.float32)
    for _ in range(60):
        c = (int(rng.integers(0, size[0])), int(rng.integers(0, size[1])))
        cv2.circle(img, c, int(rng.integers(2, 14)), float(rng.integers(0, 256)), -1)
    return np.clip(cv2.GaussianBlur(img, (0, 0), 1.2), 0, 255).astype(np.uint8)


def test_opencv_keypoints_are_not_shifted(tmp_path):
    """The OpenCV extractor's keypoints turn with the image: those of an image rotated by 180 deg,
    mapped back (COLMAP's x -> width - x), land where the image's own are. OpenCV's default
    upsampled first octave puts every keypoint +0.25 px off in x and y, which the rotation turns
    into -0.25 px: 0.5 px apart (artrecon.sfm.extraction._opencv_features; a 3D error on thin
    links)."""
    import pycolmap

    size = (200, 150)
    for i in range(3):
        img = _blobs(size, i)
        cv2.imwrite(str(tmp_path / f"img_{i}a.png"), img)
        cv2.imwrite(str(tmp_path / f"img_{i}b.png"), img[::-1, ::-1].copy())
    s = io.load_image_folder(tmp_path)
    db_path = tmp_path / "out" / "database.db"
    db_path.parent.mkdir()
    sfm.extract(s, db_path, None, sfm.SfMConfig(extractor="opencv"))
    with pycolmap.Database.open(db_path) as db:
        kps = {im.name: np.asarray(db.read_keypoints(im.image_id))[:, :2]
               for im in db.read_all_images()}
    offsets = []
    for i in range(3):
        own, turned = kps[f"img_{i}a.png"], kps[f"img_{i}b.png"]
        back = np.array(size, float) - turned
        d = np.linalg.norm(own[:, None] - back[None], axis=2)
        j = d.argmin(axis=1)
        close = d[np.arange(len(own)), j] < 0.75
        offsets.append(own[close] - back[j[close]])
    offsets = np.vstack(offsets)
    assert len(offsets) > 50
    np.testing.assert_allclose(np.median(offsets, axis=0), 0.0, atol=0.05)


def test_known_camera_database_is_what_colmaps_extractor_writes(tmp_path):
    """With known intrinsics the database is written directly (no image read by COLMAP): the
    same camera, rig, frames and images, with the same ids, as COLMAP's extractor writes."""
    import pycolmap

    size = (200, 150)
    for i in range(5):
        cv2.imwrite(str(tmp_path / f"img_{i}.png"), _blobs(size, i))
    s = io.load_image_folder(tmp_path)
    intr = io.Intrinsics(np.array([[180.123456789, 0, 99.5], [0, 181.5, 74.25], [0, 0, 1]]),
                         size)
    dbs = {}
    for extractor in ("opencv", "colmap"):
        (tmp_path / extractor).mkdir()
        dbs[extractor] = tmp_path / extractor / "database.db"
        sfm.extract(s, dbs[extractor], intr, sfm.SfMConfig(extractor=extractor))

    def content(path):
        with pycolmap.Database.open(path) as db:
            cams = [(c.camera_id, c.model.name, c.width, c.height, list(c.params),
                     c.has_prior_focal_length) for c in db.read_all_cameras()]
            return (cams, [str(r) for r in db.read_all_rigs()],
                    [str(f) for f in db.read_all_frames()],
                    [(m.image_id, m.name, m.camera_id, m.frame_id) for m in db.read_all_images()],
                    [len(db.read_keypoints(m.image_id)) > 0 for m in db.read_all_images()])

    direct, colmap = content(dbs["opencv"]), content(dbs["colmap"])
    assert direct[:4] == colmap[:4]
    assert direct[0][0][1] == "PINHOLE" and len(direct[3]) == 5 and all(direct[4])


def test_keypoint_rows_in_colmaps_convention():
    """OpenCV keypoints -> COLMAP rows: pixel centres moved to (0.5, 0.5), coordinates and scale
    back in the full image when it was shrunk by ``factor``, the affine shape turned by the
    orientation (OpenCV's angle in degrees)."""
    kps = [cv2.KeyPoint(10.0, 20.0, 4.0, 0.0), cv2.KeyPoint(3.0, 5.0, 8.0, 90.0)]
    rows = extraction._colmap_keypoints(kps, 0.5)
    assert rows.dtype == np.float32 and rows.shape == (2, 6)
    np.testing.assert_allclose(rows[0], [21, 41, 4, 0, 0, 4], atol=1e-5)
    np.testing.assert_allclose(rows[1], [7, 11, 0, -8, 8, 0], atol=1e-5)
    assert extraction._colmap_keypoints((), 1.0).shape == (0, 6)
