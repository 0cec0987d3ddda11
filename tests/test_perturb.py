"""sim.perturb: each perturbation of a robustness run does what it says (no pipeline run)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from artrecon.files import read_ply, write_ply
from sim import perturb
from sim.perturb import Perturbation
from sim.scene import load_scene


@pytest.fixture(scope="module")
def pliers():
    return load_scene("pliers")


def _texture(model, t):
    w, h, c = int(model.tex_width[t]), int(model.tex_height[t]), int(model.tex_nchannel[t])
    adr = int(model.tex_adr[t])
    return np.asarray(model.tex_data[adr:adr + w * h * c], float).reshape(h * w, c)


def test_neutral_perturbation_changes_no_cache_key(pliers):
    p = Perturbation()
    assert not p.active and p.changed() == {}
    for c in ("a", "b"):
        assert perturb.capture_inputs(pliers, p, c) == {}
        assert perturb.capture_scene(pliers, p, c) is pliers
    assert perturb.apply_motion(pliers) is pliers


def test_out_of_range_strength_is_refused():
    with pytest.raises(ValueError, match="texture_contrast"):
        Perturbation(texture_contrast=1.5)
    with pytest.raises(ValueError, match="match_outliers"):
        Perturbation(match_outliers=1.0)


def test_smaller_motion_changes_configuration_b_only(pliers):
    j = pliers.joints[0]
    small = perturb.apply_motion(pliers, motion_deg=5.0)
    s = small.joints[0]
    assert s.value_a == j.value_a
    assert np.rad2deg(s.motion) == pytest.approx(5.0 * np.sign(j.motion))
    assert small.configuration("b")[j.name] != pliers.configuration("b")[j.name]
    # a cap above the motion leaves it; the prismatic cap does not touch a hinge
    assert perturb.apply_motion(pliers, motion_deg=90.0).joints[0].value_b == j.value_b
    assert perturb.apply_motion(pliers, motion_mm=1.0).joints[0].value_b == j.value_b
    # the capture of B is keyed by the new joint values; A's capture is shared
    p = Perturbation(motion_deg=5.0)
    assert perturb.capture_inputs(small, p, "a") == {}
    key = perturb.capture_inputs(small, p, "b")["perturbation"]["joints_b"]
    assert key[j.name] == pytest.approx(s.value_b)


def test_lighting_change_turns_and_dims_b_lights_only(pliers):
    p = Perturbation(light_b_rotate_deg=90.0, light_b_intensity=0.5)
    assert perturb.capture_scene(pliers, p, "a") is pliers
    b = perturb.capture_scene(pliers, p, "b")
    for sc in (b, b.with_joint_holds()):  # the capture compiles its own model: edited too
        m0, m1 = pliers.model, sc.model
        d0, d1 = np.asarray(m0.light_dir), np.asarray(m1.light_dir)
        np.testing.assert_allclose(d1[:, 2], d0[:, 2])
        az0, az1 = np.arctan2(d0[:, 1], d0[:, 0]), np.arctan2(d1[:, 1], d1[:, 0])
        np.testing.assert_allclose(np.rad2deg(np.angle(np.exp(1j * (az1 - az0)))), 90.0,
                                   atol=1e-9)
        np.testing.assert_allclose(m1.light_diffuse, 0.5 * np.asarray(m0.light_diffuse))
    assert "render" in perturb.capture_inputs(pliers, p, "b")["perturbation"]
    assert perturb.capture_inputs(pliers, p, "a") == {}


def test_less_texture_scales_object_texture_contrast(pliers):
    p = Perturbation(texture_contrast=0.25)
    sc = perturb.capture_scene(pliers, p, "a")
    obj = perturb.object_textures(pliers.model, pliers)
    assert obj
    for model in (sc.model, sc.with_joint_holds().model):
        for t in range(pliers.model.ntex):
            before, after = _texture(pliers.model, t), _texture(model, t)
            if t in obj:
                np.testing.assert_allclose(after.mean(0), before.mean(0), atol=0.6)
                np.testing.assert_allclose(after.std(0), 0.25 * before.std(0), rtol=0.02, atol=0.3)
            else:  # table, floor, walls, arm: untouched
                np.testing.assert_array_equal(after, before)


def test_image_noise_and_blur():
    rng = np.random.default_rng(0)
    flat = np.full((200, 200, 3), 128, np.uint8)
    noisy = perturb.degrade_image(flat, 0.0, 8.0, rng).astype(float)
    assert noisy.mean() == pytest.approx(128, abs=0.2)
    assert noisy.std() == pytest.approx(8.0, rel=0.03)
    checker = (((np.indices((200, 200)).sum(0) // 4) % 2) * 255).astype(np.uint8)
    checker = np.repeat(checker[:, :, None], 3, axis=2)
    blurred = perturb.degrade_image(checker, 3.0, 0.0, rng).astype(float)
    assert blurred.mean() == pytest.approx(checker.mean(), abs=2.0)
    # a 4 px square pattern blurred with sigma 3 px keeps under 5% of its contrast
    assert blurred.std() < 0.05 * checker.std()
    np.testing.assert_array_equal(perturb.degrade_image(checker, 0.0, 0.0, rng), checker)


def _cameras(kin, n=6, seed=1):
    rng = np.random.default_rng(seed)
    images = []
    for k in range(n):
        q = 0.2 * rng.normal(size=kin.nq)
        images.append({"file": f"{k:03d}.png", "q": q.tolist(),
                       "T_world_camera": kin.camera_pose(q).tolist()})
    return {"K": np.eye(3).tolist(), "images": images}


def test_mount_error_offsets_every_reported_pose_by_the_same_transform(pliers):
    from sim import robot

    kin = robot.load_arm_kinematics(pliers.model)
    cams = _cameras(kin)
    p = Perturbation(mount_error_mm=5.0, mount_error_deg=2.0)
    out = perturb.perturb_cameras(cams, kin, p, seed=0, configuration="a")
    E = perturb.mount_error(5.0, 2.0, seed=0)
    assert np.linalg.norm(E[:3, 3]) == pytest.approx(0.005)
    assert np.rad2deg(Rotation.from_matrix(E[:3, :3]).magnitude()) == pytest.approx(2.0)
    for old, new in zip(cams["images"], out["images"], strict=True):
        assert new["q"] == old["q"]  # no encoder noise asked for
        offset = np.linalg.inv(np.asarray(old["T_world_camera"])) @ np.asarray(
            new["T_world_camera"])
        np.testing.assert_allclose(offset, E, atol=1e-9)
    assert cams["images"][0]["T_world_camera"] != out["images"][0]["T_world_camera"]


def test_encoder_noise_perturbs_reported_angles_and_their_fk(pliers):
    from sim import robot

    kin = robot.load_arm_kinematics(pliers.model)
    cams = _cameras(kin, n=40)
    out = perturb.perturb_cameras(cams, kin, Perturbation(encoder_noise_deg=0.5), seed=0,
                                  configuration="b")
    dq = np.array([np.subtract(n["q"], o["q"]) for o, n in
                   zip(cams["images"], out["images"], strict=True)])
    assert np.rad2deg(dq.std()) == pytest.approx(0.5, rel=0.15)
    assert abs(np.rad2deg(dq.mean())) < 0.1
    for im in out["images"]:  # the reported pose is the FK of the reported (noisy) angles
        np.testing.assert_allclose(im["T_world_camera"], kin.camera_pose(im["q"]), atol=1e-12)


def test_perturb_set_keeps_ground_truth(tmp_path, pliers):
    from PIL import Image

    src = tmp_path / "set"
    (src / "images").mkdir(parents=True)
    (src / "ground_truth").mkdir()
    img = np.full((40, 50, 3), 100, np.uint8)
    Image.fromarray(img).save(src / "images" / "000.png")
    truth = {"images": [{"file": "000.png", "T_world_camera": np.eye(4).tolist()}]}
    (src / "ground_truth" / "poses.json").write_text(json.dumps(truth))
    (src / "cameras.json").write_text(json.dumps({"K": np.eye(3).tolist(), "images": []}))
    p = Perturbation(image_noise_sigma=10.0)
    summary = perturb.perturb_set(src, tmp_path / "out", pliers, p, seed=0, configuration="a")
    assert summary["images_degraded"] == 1
    got = np.asarray(Image.open(tmp_path / "out" / "images" / "000.png"), float)
    assert got.std() == pytest.approx(10.0, rel=0.1)
    assert np.asarray(Image.open(src / "images" / "000.png")).std() == 0  # source untouched
    assert json.loads((tmp_path / "out" / "ground_truth" / "poses.json").read_text()) == truth


def test_corrupt_matches_makes_the_asked_share_wrong():
    rng = np.random.default_rng(3)
    pb = rng.normal(size=(1000, 3))
    for share in (0.5, 0.7):
        out, wrong = perturb.corrupt_matches(pb, share, np.random.default_rng(0))
        assert wrong.sum() == round(share * 1000)
        changed = np.any(out != pb, axis=1)
        np.testing.assert_array_equal(changed, wrong)  # every chosen match is really wrong
        # the B point cloud is the same, only the pairing changed
        np.testing.assert_array_equal(np.sort(out, axis=0), np.sort(pb, axis=0))


def test_read_ply_reads_write_ply(tmp_path):
    rng = np.random.default_rng(0)
    pts, nrm = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    col = rng.integers(0, 255, size=(20, 3)).astype(np.uint8)
    p, n, c = read_ply(write_ply(tmp_path / "x.ply", pts, nrm, col))
    np.testing.assert_allclose(p, pts, atol=1e-6)
    np.testing.assert_allclose(n, nrm, atol=1e-6)
    np.testing.assert_array_equal(c, col)


def test_command_line_options():
    parser = argparse.ArgumentParser()
    perturb.add_arguments(parser)
    assert perturb.from_args(parser.parse_args([])) == Perturbation()
    p = perturb.from_args(parser.parse_args(["--image-noise", "4", "--match-outliers", "0.6",
                                             "--motion-deg", "5", "--mount-error-mm", "2"]))
    assert p.changed() == {"image_noise_sigma": 4.0, "match_outliers": 0.6, "motion_deg": 5.0,
                           "mount_error_mm": 2.0}


def _model_dir(tmp_path, obj):
    """A reconstruction folder as artrecon writes it, from a synthetic object's matches."""
    from artrecon.model import ArticulatedModel, Link

    d = tmp_path / "model"
    for c, pts in (("a", obj.points_a), ("b", obj.points_b)):
        (d / c).mkdir(parents=True)
        write_ply(d / c / "dense.ply", pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)),
                  np.zeros((len(pts), 3), np.uint8))
    (d / "links").mkdir()
    np.savez(d / "links" / "matches.npz", points_a=obj.points_a, points_b=obj.points_b,
             background_a=np.zeros((0, 3)), background_b=np.zeros((0, 3)))
    ArticulatedModel(links=[Link(points=obj.points_a[:3], match_indices=np.arange(3))],
                     joints=[]).save(d / "model.json")
    return d


def test_resegment_redoes_joints_on_wrong_matches(tmp_path):
    from synthetic import make_object

    from artrecon.model import ArticulatedModel

    obj = make_object(5, "pair", ("revolute",), points_per_link=150, noise=0.0)
    d = _model_dir(tmp_path, obj)
    summary = perturb.resegment(d, tmp_path / "out", 0.5, seed=0)
    n = len(obj.points_a)
    assert summary["made_wrong"] == round(0.5 * n)
    saved = np.load(tmp_path / "out" / "matches.npz")
    assert saved["wrong"].sum() == summary["made_wrong"]
    assert np.any(saved["points_b"] != obj.points_b)
    assert (tmp_path / "out" / "a" / "dense.ply").is_file()  # SfM/dense folders linked
    model = ArticulatedModel.load(tmp_path / "out" / "model.json")
    assert model.metadata["perturbation"]["made_wrong"] == summary["made_wrong"]
    # half the matches wrong, none of them noisy: RANSAC still finds the hinge
    (joint,) = model.joints
    true = obj.joints[0]
    cos = abs(float(np.dot(joint.axis_direction, true.axis_direction)))
    assert np.rad2deg(np.arccos(min(1.0, cos))) < 0.5
    assert summary["wrong_kept_in_links"] < 0.05 * summary["made_wrong"]


def test_resegment_runs_the_pipelines_steps(tmp_path):
    """resegment runs the pipeline's own post-matching steps (artrecon.articulation.articulate),
    not a copy that can drift: here the matches of one link stop short of the joint (the scraper
    truck's boom), so only the pipeline's adjacency on the links' dense points joins the two
    links; a tree built on the matches alone fails (tests/test_joints.py)."""
    from scipy.spatial import cKDTree
    from synthetic import make_object

    from artrecon.model import ArticulatedModel
    from artrecon.tolerances import scene_size

    obj = make_object(23, "pair", ("revolute",), 200, 0.0, 0.0)
    labels = obj.labels
    pa, pb = obj.points_a, obj.points_b
    size = scene_size(pa)
    d, _ = cKDTree(pa[labels == 0]).query(pa)
    keep = (labels == 0) | ((labels == 1) & (d > 0.6 * size))
    assert 50 < np.sum(keep & (labels == 1)) < np.sum(labels == 1)
    folder = _model_dir(tmp_path, obj)  # dense points: every point of both links
    np.savez(folder / "links" / "matches.npz", points_a=pa[keep], points_b=pb[keep],
             background_a=np.zeros((0, 3)), background_b=np.zeros((0, 3)))
    summary = perturb.resegment(folder, tmp_path / "out", 0.1, seed=0)
    assert summary["links"] == 2 and summary["joints"] == 1
    (joint,) = ArticulatedModel.load(tmp_path / "out" / "model.json").joints
    cos = abs(float(np.dot(joint.axis_direction, obj.joints[0].axis_direction)))
    assert np.rad2deg(np.arccos(min(1.0, cos))) < 0.5
