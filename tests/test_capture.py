"""sim.capture and sim.views: image sets of the bundled scenes against MuJoCo's own geometry.

One small capture (8 views on one ring) of the pliers is made per test session and checked:
its files, the FK poses it records, and its ground-truth depth and labels against MuJoCo ray
casts (``mj_ray`` intersects the very mesh triangles MuJoCo holds). The full view plans of every
bundled scene are checked for reachability in slow tests.
"""

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest
from PIL import Image

from sim import capture as C
from sim import robot, views
from sim.camera import mujoco_camera_intrinsics
from sim.scene import list_scenes, load_scene

#: Rendered depth, back-projected with the recorded (FK) pose, must lie within this of the true
#: surface (issue 3).
SURFACE_TOL = 1e-3
#: Pixels sampled per image for the ray-cast comparison.
SAMPLES_PER_IMAGE = 400
#: A handful of sampled pixels sit on silhouettes, where the ray cast from the pixel centre and
#: the rasteriser may pick different sides; allow this share of label disagreements.
LABEL_MISMATCH_MAX = 0.02

SMALL = {"n_views": 8, "elevations_deg": (30.0,), "top_elevations_deg": (), "progress": False}


@pytest.fixture(scope="module")
def pliers_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("capture") / "pliers_b"
    result = C.capture("pliers", "b", out, **SMALL)
    return result, out


def _load_json(path):
    return json.loads(Path(path).read_text())


def test_image_set_layout_and_fk_poses(pliers_set):
    result, out = pliers_set
    assert result.n_captured == result.n_planned == 8 and not result.unreachable
    cams = _load_json(out / "cameras.json")
    sc = load_scene("pliers")
    kin = robot.load_arm_kinematics(sc.model)
    K, (w, h) = mujoco_camera_intrinsics(sc.model, "puma_wrist_cam")
    np.testing.assert_allclose(cams["K"], K)
    assert (cams["width"], cams["height"]) == (w, h)
    assert cams["joint_names"] == list(kin.joint_names)
    assert [im["file"] for im in cams["images"]] == [f"{i:03d}.png" for i in range(8)]
    truth = _load_json(out / "ground_truth" / "poses.json")
    for im, gt in zip(cams["images"], truth["images"], strict=True):
        img = np.asarray(Image.open(out / "images" / im["file"]))
        assert img.shape == (h, w, 3)
        assert (out / "ground_truth" / "depth" / im["file"]).is_file()
        # the recorded pose is the arm's FK at the recorded joint angles ...
        q = np.array(im["q"])
        assert np.all(q >= kin.lower - 1e-9) and np.all(q <= kin.upper + 1e-9)
        np.testing.assert_allclose(im["T_world_camera"], kin.camera_pose(q), atol=1e-12)
        # ... and agrees with MuJoCo's camera, which rendered the image
        T_fk, T_true = np.array(im["T_world_camera"]), np.array(gt["T_world_camera"])
        assert np.linalg.norm(T_fk[:3, 3] - T_true[:3, 3]) < 1e-6
        assert np.allclose(T_fk[:3, :3], T_true[:3, :3], atol=1e-6)
        # the camera looks at the object: the object fills part of every image
        labels = np.asarray(Image.open(out / "ground_truth" / "labels" / im["file"]))
        assert 0.01 < np.mean(labels < C.LABEL_PNG_ARM) < 0.9
        # the object did not move
        assert gt["object_joints"] == pytest.approx(sc.configuration("b"), abs=C.OBJECT_DRIFT_TOL)
    assert truth["object_joints"] == sc.configuration("b")
    # ground truth never sits beside what artrecon reads
    assert "object_joints" not in json.dumps(cams)


def test_depth_and_labels_agree_with_mujoco_ray_casts(pliers_set):
    """Back-projected depth lands on MuJoCo's surfaces within 1 mm; labels name the hit link."""
    _, out = pliers_set
    sc = load_scene("pliers")
    model = sc.model
    data = sc.make_data("b")
    cams = _load_json(out / "cameras.json")
    K = np.array(cams["K"])
    link_of = {b: i for i, li in enumerate(sc.links) for b in li.body_ids}
    rng = np.random.default_rng(0)
    geomgroup = np.array([1, 1, 1, 0, 0, 0], dtype=np.uint8)  # the rendered groups 0-2
    geomid = np.zeros(1, dtype=np.int32)
    errors, mismatches, n_object = [], 0, 0
    for im in cams["images"]:
        # put the arm where it was for this image, so rays meet the same scene
        qidx = robot.qpos_indices(model, robot.load_arm_kinematics(model))
        data.qpos[qidx] = im["q"]
        mujoco.mj_forward(model, data)
        T = np.array(im["T_world_camera"])
        depth = C.read_depth_png(out / "ground_truth" / "depth" / im["file"])
        labels = np.asarray(Image.open(out / "ground_truth" / "labels" / im["file"]))
        # half the samples on the object, half anywhere
        obj_v, obj_u = np.nonzero(labels < C.LABEL_PNG_ARM)
        pick = rng.choice(len(obj_u), SAMPLES_PER_IMAGE // 2, replace=False)
        any_v = rng.integers(0, cams["height"], SAMPLES_PER_IMAGE // 2)
        any_u = rng.integers(0, cams["width"], SAMPLES_PER_IMAGE // 2)
        for u, v in zip(np.r_[obj_u[pick], any_u], np.r_[obj_v[pick], any_v], strict=True):
            d_cam = np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], 1.0])
            d_world = T[:3, :3] @ d_cam
            dist = mujoco.mj_ray(model, data, T[:3, 3], d_world, geomgroup, 1, -1, geomid)
            g = int(geomid[0])
            if g < 0 or dist < 0:
                assert labels[v, u] == C.LABEL_PNG_BACKGROUND
                continue
            expected = link_of.get(int(model.geom_bodyid[g]))
            if labels[v, u] < C.LABEL_PNG_ARM or expected is not None:
                n_object += 1
                if expected != labels[v, u]:
                    mismatches += 1
                    continue
            if depth[v, u] > 0:
                p_render = T[:3, :3] @ (d_cam * depth[v, u]) + T[:3, 3]
                p_true = T[:3, 3] + dist * d_world
                errors.append(np.linalg.norm(p_render - p_true))
    errors = np.array(errors)
    assert n_object > 0.4 * len(cams["images"]) * SAMPLES_PER_IMAGE
    assert mismatches / n_object < LABEL_MISMATCH_MAX
    # silhouette pixels can still land on the far surface; all but those are within 1 mm
    assert np.quantile(errors, 0.99) < SURFACE_TOL, f"99th pct {np.quantile(errors, .99)*1e3} mm"
    assert np.median(errors) < 0.1 * SURFACE_TOL


def test_same_arguments_give_identical_files(pliers_set, tmp_path):
    _, out = pliers_set
    again = tmp_path / "again"
    C.capture("pliers", "b", again, **SMALL)
    files = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for f in files:
        assert (out / f).read_bytes() == (again / f).read_bytes(), f"{f} differs"


def test_failed_capture_leaves_nothing(tmp_path, monkeypatch):
    calls = {"n": 0}
    real = C.render.MjRenderer.render

    def failing(self, *a, **k):
        calls["n"] += 1
        if calls["n"] > 2:
            raise RuntimeError("renderer died")
        return real(self, *a, **k)

    monkeypatch.setattr(C.render.MjRenderer, "render", failing)
    with pytest.raises(RuntimeError, match="renderer died"):
        C.capture("pliers", "a", tmp_path / "set", **SMALL)
    assert list(tmp_path.iterdir()) == []


def test_unreachable_views_are_reported_or_taken_by_a_free_camera(tmp_path, monkeypatch):
    real = views.solve_views

    def two_unreachable(model, data, kin, vs, **kw):
        real(model, data, kin, vs, **kw)
        for v in vs[3:5]:
            v.q, v.reason = None, "made unreachable by the test"

    monkeypatch.setattr(views, "solve_views", two_unreachable)
    res = C.capture("pliers", "a", tmp_path / "arm_only", **{**SMALL, "n_views": 10})
    assert res.n_planned == 10 and res.n_captured == 8 and len(res.unreachable) == 2
    assert all(u["reason"] == "made unreachable by the test" for u in res.unreachable)
    report = _load_json(tmp_path / "arm_only" / "capture.json")
    assert report["captured"] == 8 and len(report["unreachable"]) == 2

    res = C.capture("pliers", "a", tmp_path / "free", free_camera_fallback=True,
                    **{**SMALL, "n_views": 10})
    assert res.n_captured == 10 and res.free_camera == [3, 4]
    cams = _load_json(tmp_path / "free" / "cameras.json")
    assert [im["pose_source"] for im in cams["images"]].count("free_camera") == 2
    assert cams["images"][3]["T_world_camera"] is None and cams["images"][3]["q"] is None
    truth = _load_json(tmp_path / "free" / "ground_truth" / "poses.json")
    assert truth["images"][3]["T_world_camera"] is not None


def test_bad_arguments_are_clear_errors(tmp_path, pliers_set):
    with pytest.raises(ValueError, match="no bundled scene named 'nope'"):
        C.capture("nope", "a", tmp_path / "x", **SMALL)
    with pytest.raises(ValueError, match="unknown configuration 'c'"):
        C.capture("pliers", "c", tmp_path / "x", **SMALL)
    with pytest.raises(ValueError, match="does not exist"):
        C.capture("pliers", "a", tmp_path / "missing" / "x", **SMALL)
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(ValueError, match="does not exist"):
        C.capture("pliers", "a", blocker / "x", **SMALL)
    with pytest.raises(FileExistsError, match="--overwrite"):
        C.capture("pliers", "a", pliers_set[1], **SMALL)
    with pytest.raises(ValueError, match="at least 3"):
        C.capture("pliers", "a", tmp_path / "x", **{**SMALL, "n_views": 2})
    with pytest.raises(C.CaptureError, match="need 8"):
        C.capture("pliers", "a", tmp_path / "x", **{**SMALL, "n_views": 5})
    assert not (tmp_path / "x").exists()
    # the command line turns them into a message and exit status 2
    with pytest.raises(SystemExit) as exc:
        C.main(["pliers", "--config", "c", "--out", str(tmp_path / "y")])
    assert exc.value.code == 2


def test_ring_distance_makes_the_sphere_fill_the_image():
    K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    d = views.ring_distance(0.2, K, 640, 480, fill=0.5)
    # the sphere's silhouette radius in pixels is f * tan(asin(r / d)): half of 240 px
    assert 500 * np.tan(np.arcsin(0.2 / d)) == pytest.approx(0.5 * 240)
    assert views.ring_distance(1e-3, K, 640, 480, 0.5) == views.MIN_RING_DISTANCE


def test_ring_sizes_keep_neighbours_within_ten_degrees():
    cfg = views.ViewPlanConfig()
    for el, n in views.ring_sizes(cfg):
        gap = 2 * np.arcsin(np.cos(el) * np.sin(np.pi / n))
        assert np.rad2deg(gap) <= views.MAX_NEIGHBOUR_ANGLE_DEG + 1e-9
    plan = views.plan_views(np.zeros(3), 0.5, cfg)
    for v in plan:
        # every camera looks at the centre from the planned distance
        T = v.T_world_camera
        assert np.linalg.norm(T[:3, 3]) == pytest.approx(0.5)
        np.testing.assert_allclose(T[:3, 2], -T[:3, 3] / 0.5, atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("scene", list_scenes())
@pytest.mark.parametrize("config", ["a", "b"])
def test_every_planned_view_of_the_bundled_scenes_is_reachable(scene, config):
    sc = load_scene(scene)
    model = sc.model
    data = sc.make_data(config)
    kin = robot.load_arm_kinematics(model)
    K, (w, h) = mujoco_camera_intrinsics(model, kin.spec.prefix + kin.spec.camera)
    centre, radius = views.object_bounding_sphere(model, data)
    cfg = views.ViewPlanConfig()
    distance = views.ring_distance(radius, K, w, h, cfg.fill)
    top = views.ring_distance(radius, K, w, h, cfg.top_fill)
    plan = views.order_for_rail(views.plan_views(centre, distance, cfg, top), kin)
    views.solve_views(model, data, kin, plan)
    bad = [(v.ring, round(np.rad2deg(v.azimuth)), v.reason) for v in plan if not v.reachable]
    assert not bad, f"{len(bad)} of {len(plan)} views unreachable: {bad[:3]}"
    links = views.arm_link_bodies(model, kin)
    qidx = robot.qpos_indices(model, kin)
    for v in plan:
        data.qpos[qidx] = v.q
        mujoco.mj_forward(model, data)
        assert not views.arm_collisions(model, data, links)
        np.testing.assert_allclose(kin.camera_pose(v.q), v.T_world_camera, atol=1e-3)
