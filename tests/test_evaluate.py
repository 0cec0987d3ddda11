"""Scoring, caching and report of sim.evaluate on small synthetic inputs (fast, no capture).

The expensive stages (capture, reconstruction, manipulation) are exercised by tests/test_gates.py;
here a model is built from the ground truth itself, exactly or with a known error, and the scores
must come out as that known error.
"""

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

import sim  # noqa: F401
from artrecon.model import ArticulatedModel, Joint, Link
from artrecon.procrustes import Similarity
from sim import cache, evaluate
from sim.evaluate import pictures, record, report
from sim.scene import load_scene


@pytest.fixture(scope="module")
def truck():
    return load_scene("truck")


@pytest.fixture(scope="module")
def truck_samples(truck):
    return evaluate.sample_surface(truck, "a", spacing=0.004, seed=3)


def _model_from_truth(scene, samples, links, *, tilt_deg=0.0, shift=(0.0, 0.0, 0.0),
                      motion_scale=1.0, flip=False):
    """A registered model whose links are the true surface samples and whose joint is the true
    one, tilted/shifted/scaled by a known amount."""
    j = scene.moving_joints[0]
    child = [k for k, li in enumerate(scene.links) if li.name == j.child][0]
    rng = np.random.default_rng(0)
    model_links = []
    for k in range(len(scene.links)):
        pts = samples[links == k]
        pts = pts[rng.choice(len(pts), min(len(pts), 3000), replace=False)]
        model_links.append(Link(points=pts, match_indices=np.full(len(pts), -1)))
    perp = np.cross(j.axis, [0.0, 0.0, 1.0])
    perp = perp / np.linalg.norm(perp) if np.linalg.norm(perp) > 1e-6 else np.array([1.0, 0, 0])
    axis = Rotation.from_rotvec(np.deg2rad(tilt_deg) * perp).apply(j.axis)
    sign = -1.0 if flip else 1.0
    joint = Joint(j.type, sign * axis, j.point + np.asarray(shift), parent=1 - child, child=child,
                  state_a=0.0, state_b=sign * j.motion * motion_scale, name="est0")
    return ArticulatedModel(links=model_links, joints=[joint], scale=1.0, scale_known=True)


def test_surface_samples_lie_on_the_object_and_are_deterministic(truck, truck_samples):
    pts, links = truck_samples
    assert set(np.unique(links)) == {0, 1}
    # the truck stands on the table (top at z = 0.45) and is about 30 cm long
    assert pts[:, 2].min() > 0.449 and pts[:, 2].max() < 0.75
    assert np.ptp(pts[:, 0]) == pytest.approx(0.30, abs=0.03)
    again, _ = evaluate.sample_surface(truck, "a", spacing=0.004, seed=3)
    np.testing.assert_array_equal(pts, again)
    # the bed tilts between A and B: its samples move, the chassis' do not
    pts_b, links_b = evaluate.sample_surface(truck, "b", spacing=0.004, seed=3)
    np.testing.assert_array_equal(links, links_b)
    assert np.allclose(pts[links == 0], pts_b[links_b == 0])
    assert not np.allclose(pts[links == 1], pts_b[links_b == 1])


def test_exact_model_scores_zero(truck, truck_samples):
    model = _model_from_truth(truck, *truck_samples)
    out = evaluate.score_joints(truck, model)
    (row,) = out["joints"]
    assert row["type_correct"] and row["passes"]
    assert row["axis_angle_deg"] == pytest.approx(0.0, abs=1e-6)
    assert row["axis_position_mm"] == pytest.approx(0.0, abs=1e-6)
    assert row["state_error"] == pytest.approx(0.0, abs=1e-6)
    assert row["state_error_unit"] == "deg"
    assert row["angle_to_table_normal_deg"] == pytest.approx(90.0)  # the bed hinge is horizontal
    assert out["invented_joints"] == []


def test_known_errors_are_measured(truck, truck_samples):
    model = _model_from_truth(truck, *truck_samples, tilt_deg=3.0, shift=(0.004, 0.0, 0.0),
                              motion_scale=1.1, flip=True)
    (row,) = evaluate.score_joints(truck, model)["joints"]
    assert row["axis_angle_deg"] == pytest.approx(3.0, abs=1e-6)
    # the hinge runs along y and is tilted about x (within the y-z plane): shifted 4 mm along x,
    # the common perpendicular of the two lines is that shift
    assert row["axis_position_mm"] == pytest.approx(4.0, abs=1e-6)
    motion = np.rad2deg(truck.moving_joints[0].motion)
    assert row["state_error"] == pytest.approx(0.1 * motion, rel=1e-6)  # the flip is undone
    assert not row["passes"]  # 3 deg > 2 deg gate


def test_wrong_type_and_invented_joint(truck, truck_samples):
    model = _model_from_truth(truck, *truck_samples)
    j = model.joints[0]
    model.joints[0] = Joint("prismatic", j.axis_direction, j.axis_point, j.parent, j.child, 0.0,
                            0.05, name="slide")
    (row,) = evaluate.score_joints(truck, model)["joints"]
    assert row["type_estimated"] == "prismatic" and not row["type_correct"]
    assert row["state_error"] is None and not row["passes"]
    model.joints.append(Joint("revolute", [0, 0, 1], [0, 0, 0], j.parent, j.child, 0.0, 0.3,
                              name="ghost"))
    out = evaluate.score_joints(truck, model)
    # with a revolute candidate available the Hungarian pairs revolute with revolute (the type
    # mismatch costs more than a 90 deg axis error): the slide is the invented one
    assert out["joints"][0]["estimated_joint"] == "ghost"
    assert [g["name"] for g in out["invented_joints"]] == ["slide"]


def test_segmentation_accuracy_against_true_links(truck, truck_samples):
    pts, links = truck_samples
    model = _model_from_truth(truck, pts, links)
    # relabel 10% of the bed's points as chassis: accuracy drops by that share of all points
    bed = model.links[1].points
    k = len(bed) // 10
    moved, kept = bed[:k], bed[k:]
    model.links[0] = Link(np.r_[model.links[0].points, moved],
                          np.full(len(model.links[0].points) + k, -1))
    model.links[1] = Link(kept, np.full(len(kept), -1))
    P = np.concatenate([lk.points for lk in model.links])
    pred = np.concatenate([np.full(len(lk.points), i) for i, lk in enumerate(model.links)])
    true = sim.metrics.nearest_labels(P, pts, links, evaluate.scoring.SEGMENTATION_MAX_DISTANCE_M)
    acc = sim.metrics.segmentation_accuracy(pred, true)
    assert acc == pytest.approx(1.0 - k / len(P), abs=1e-9)


def _fake_capture(folder: Path, scene, n=4, *, empty_depth=False, configuration="a"):
    """A capture folder with cameras on a ring and its ground truth: depth and link labels
    rendered in the configuration (or an empty depth: nothing occludes, no label)."""
    from sim import render
    from sim.capture.files import depth_png, geom_labels, labels_png
    from sim.robot import look_at_pose

    K = np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]])
    for sub in ("depth", "labels"):
        (folder / "ground_truth" / sub).mkdir(parents=True)
    (folder / "images").mkdir()
    renderer = render.MjRenderer(scene.model, geom_labels=geom_labels(scene.model, scene, -1))
    data = scene.make_data(configuration)
    imgs, truth = [], []
    for i in range(n):
        a = 2 * np.pi * i / n
        T = look_at_pose([0.5 * np.cos(a), 0.5 * np.sin(a), 0.8], [0, 0, 0.5])
        name = f"{i:03d}.png"
        out = renderer.render(data, K, T, 320, 240, depth=True, labels=True)
        depth = np.zeros((240, 320)) if empty_depth else out.depth
        labels = np.full((240, 320), render.LABEL_BACKGROUND) if empty_depth else out.labels
        Image.fromarray(depth_png(depth)).save(folder / "ground_truth" / "depth" / name)
        Image.fromarray(labels_png(labels)).save(folder / "ground_truth" / "labels" / name)
        Image.fromarray(np.full((240, 320, 3), 128, np.uint8)).save(folder / "images" / name)
        imgs.append({"file": name, "q": None, "T_world_camera": T.tolist()})
        truth.append({"file": name, "T_world_camera": T.tolist(),
                      "view": {"elevation_deg": 30.0}})
    (folder / "cameras.json").write_text(json.dumps({"K": K.tolist(), "images": imgs}))
    (folder / "ground_truth" / "poses.json").write_text(json.dumps({"images": truth}))
    return {im["file"]: np.asarray(im["T_world_camera"]) for im in imgs}


def test_score_scene_camera_poses_scale_and_hidden_side(tmp_path, truck, truck_samples):
    poses = _fake_capture(tmp_path / "a", truck, empty_depth=True)
    # an SfM frame at half the scale, rotated and shifted: T_world_sfm is that similarity
    T = Similarity(Rotation.from_rotvec([0.2, -0.1, 0.4]).as_matrix(), np.array([0.1, 0.2, 0.3]),
                   2.0)
    Tinv = T.inverse()
    sfm = {}
    for n, P in poses.items():
        S = np.eye(4)
        S[:3, :3] = Tinv.rotation @ P[:3, :3]
        S[:3, 3] = Tinv.apply(P[:3, 3][None])[0]
        sfm[n] = S
    # one camera 3 mm off in the world after registration
    sfm["001.png"][:3, 3] += Tinv.rotation @ np.array([0.003, 0, 0]) * Tinv.scale
    model = _model_from_truth(truck, *truck_samples)
    out = evaluate.score_scene(truck, model, sfm, T, tmp_path / "a", seed=3)
    cam = out["camera_pose_error"]
    assert cam["position_max_mm"] == pytest.approx(3.0, abs=1e-6)
    assert cam["rotation_max_deg"] == pytest.approx(0.0, abs=1e-4)  # arccos near 1
    assert cam["n"] == 4
    assert abs(out["scale_error_pct"]) < 0.5  # one 3 mm outlier among 4 cameras 0.5 m away
    # an empty depth holds no point: no view says which link any point is on
    assert out["segmentation"]["off_surface_share"] == pytest.approx(1.0)
    # the nearest-surface figure at A scores true points all but right where the links touch
    assert out["segmentation"]["accuracy_nearest_surface_at_a"] > 0.995
    # an empty depth image hides everything: the hidden side is the whole surface
    assert out["model"]["hidden_share_of_surface"] == pytest.approx(1.0)
    assert out["model"]["completeness"] == pytest.approx(out["model"]["hidden"]["completeness"])
    assert out["joints"][0]["passes"]


def _seen_in_both(scene, samples, links, wrong_share=0.0):
    """A registered model of the true surface samples: every other point "seen" in B (carried
    back into A by its link's true motion), and ``wrong_share`` of the bed given to the chassis."""
    pa, pb = scene.link_poses("a"), scene.link_poses("b")
    rng = np.random.default_rng(5)
    model_links = []
    for k, li in enumerate(scene.links):
        M = pb[li.name] @ np.linalg.inv(pa[li.name])
        T = Similarity(M[:3, :3], M[:3, 3], 1.0)
        pts = samples[links == k]
        pts = pts[rng.choice(len(pts), min(len(pts), 3000), replace=False)]
        seen = (np.arange(len(pts)) % 2).astype(np.int8)
        model_links.append(Link(points=pts, match_indices=np.full(len(pts), -1),
                                transform_a_to_b=T, observed_in=seen))
    if wrong_share:
        bed = model_links[1]
        k = int(wrong_share * len(bed.points))
        chassis = model_links[0]
        model_links[0] = Link(np.r_[chassis.points, bed.points[:k]], np.full(
            len(chassis.points) + k, -1), transform_a_to_b=chassis.transform_a_to_b,
            observed_in=np.r_[chassis.observed_in, bed.observed_in[:k]])
        model_links[1] = Link(bed.points[k:], np.full(len(bed.points) - k, -1),
                              transform_a_to_b=bed.transform_a_to_b,
                              observed_in=bed.observed_in[k:])
    return ArticulatedModel(links=model_links, joints=[], scale=1.0, scale_known=True)


def test_segmentation_scored_in_the_configuration_each_point_was_seen_in(tmp_path, truck,
                                                                        truck_samples):
    """The rendered labels of A score the points seen in A; those of B, where B's
    reconstruction put them (its link's motion), the points seen in B. True links score 1 on
    every point some view holds; 10% of the bed moved to the chassis, 10% of the bed's share."""
    set_a = tmp_path / "a"
    set_b = tmp_path / "b"
    _fake_capture(set_a, truck, n=6)
    _fake_capture(set_b, truck, n=6, configuration="b")
    identity = Similarity()
    model = _seen_in_both(truck, *truck_samples)
    labels, seen = evaluate.segmentation_truth(truck, model, set_a, set_b, model, identity)
    held = labels >= 0
    assert 0.3 < held.mean() < 1.0  # six views from one height do not see the underside
    assert set(seen[held].tolist()) == {0, 1}
    pred = np.concatenate([np.full(len(lk.points), k) for k, lk in enumerate(model.links)])
    assert np.mean(pred[held] == labels[held]) > 0.995
    # the points seen in B, scored at A instead (no B capture given), land where the bed was:
    # where the bed moved away, A's views do not put them on the bed
    at_a, seen_a = evaluate.segmentation_truth(truck, model, set_a)
    assert (seen_a == 0).all()
    assert np.mean(pred[at_a >= 0] == at_a[at_a >= 0]) > 0.995  # at A they are where A saw them
    wrong = _seen_in_both(truck, *truck_samples, wrong_share=0.1)
    labels_w, _ = evaluate.segmentation_truth(truck, wrong, set_a, set_b, wrong, identity)
    pred_w = np.concatenate([np.full(len(lk.points), k) for k, lk in enumerate(wrong.links)])
    held_w = labels_w >= 0
    # the bed points given to the chassis: right after the chassis' own points. Those seen in
    # A are scored where they are: on the bed, wrong. Those seen in B are carried by the
    # chassis' motion (none) to where the bed was: off the object, or on the chassis beneath
    n0 = len(model.links[0].points)
    k = len(wrong.links[0].points) - n0
    moved = np.zeros(len(labels_w), bool)
    moved[n0:n0 + k] = True
    seen_a = np.concatenate([lk.observed_in for lk in wrong.links]) == 0
    assert (labels_w[moved & seen_a & held_w] == 1).all()
    assert (moved & seen_a & held_w).sum() > 0.2 * k
    acc = np.mean(pred_w[held_w] == labels_w[held_w])
    assert 1 - (moved & held_w).sum() / held_w.sum() - 0.005 <= acc
    assert acc <= 1 - (moved & seen_a & held_w).sum() / held_w.sum() + 0.005


def test_cache_builds_once_and_keys_on_inputs(tmp_path):
    calls = []

    def build(folder):
        calls.append(folder)
        (folder / "x.txt").write_text("hello")
        return {"n": 1}

    d1, m1, hit1 = cache.cached_stage(tmp_path, "stage", {"a": 1}, build)
    d2, m2, hit2 = cache.cached_stage(tmp_path, "stage", {"a": 1}, build)
    d3, _, hit3 = cache.cached_stage(tmp_path, "stage", {"a": 2}, build)
    assert (hit1, hit2, hit3) == (False, True, False)
    assert d1 == d2 != d3 and len(calls) == 2
    assert (d1 / "x.txt").read_text() == "hello" and m2["n"] == 1 and m2["build_s"] >= 0


def test_cache_failed_build_leaves_nothing(tmp_path):
    def build(folder):
        (folder / "partial").write_text("half")
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        cache.cached_stage(tmp_path, "stage", {"a": 1}, build)
    assert list(tmp_path.iterdir()) == []


def test_scene_hash_follows_included_and_referenced_files(tmp_path):
    (tmp_path / "assets").mkdir()
    (tmp_path / "assets" / "m.obj").write_text("v 0 0 0\n")
    (tmp_path / "inc.xml").write_text('<mujoco><asset><mesh file="assets/m.obj"/></asset>'
                                      '</mujoco>')
    (tmp_path / "top.xml").write_text('<mujoco><!-- file="ignored.xml" -->'
                                      '<include file="inc.xml"/></mujoco>')
    files = {p.name for p in cache.scene_files(tmp_path / "top.xml")}
    assert files == {"top.xml", "inc.xml", "m.obj"}
    h1 = cache.scene_hash(tmp_path / "top.xml")
    (tmp_path / "assets" / "m.obj").write_text("v 0 0 1\n")
    assert cache.scene_hash(tmp_path / "top.xml") != h1


def test_module_closure_follows_imports_inside_functions_and_nothing_else(tmp_path,
                                                                          monkeypatch):
    pkg = tmp_path / "closurepkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("from closurepkg.top import run\n")
    (pkg / "top.py").write_text("def run():\n    from closurepkg import helper\n"
                                "    return helper.x\n")
    (pkg / "helper.py").write_text("import closurepkg.leaf\nx = 1\n")
    (pkg / "leaf.py").write_text("y = 2\n")
    (pkg / "later.py").write_text("from closurepkg.top import run\n")  # imports top, not used
    monkeypatch.syspath_prepend(str(tmp_path))
    import importlib

    top = importlib.import_module("closurepkg.top")
    files = {p.name for p in cache.module_closure(top)}
    assert files == {"__init__.py", "top.py", "helper.py", "leaf.py"}
    h1 = cache.closure_hash(top)
    (pkg / "later.py").write_text("# edited\n")
    assert cache.closure_hash(top) == h1  # a module it never runs
    (pkg / "leaf.py").write_text("y = 3\n")
    assert cache.closure_hash(top) != h1


def test_the_configuration_stage_is_keyed_on_its_own_code_only():
    import artrecon.configuration

    root = Path(artrecon.configuration.__file__).parent
    names = {p.relative_to(root).as_posix() for p in cache.module_closure(artrecon.configuration)}
    assert {"configuration.py", "dense.py", "io.py", "sfm/__init__.py", "sfm/stage.py",
            "sfm/extraction.py", "sfm/pairs.py", "sfm/mapping.py", "sfm/pose_check.py"} <= names
    assert not names & {"segment.py", "joints.py", "assign.py", "features.py", "reconstruct.py",
                        "model_stage.py", "articulation.py", "settings.py"}


def test_bundled_scene_files_include_stage_arm_and_assets():
    files = {p.name for p in cache.scene_files(load_scene("truck").path)}
    assert {"truck.xml", "stage.xml", "truck_bed.obj", "truck_bed.png", "puma560.xml"} <= files


def _results():
    row = {"name": "hinge", "type_true": "revolute", "type_estimated": "revolute",
           "axis_angle_deg": 0.5, "axis_position_mm": 7.0, "state_error": 0.2,
           "state_error_unit": "deg", "type_correct": True, "angle_to_table_normal_deg": 89.0}
    scene = {"scene": "toy", "joints": [row], "segmentation_accuracy": 0.97,
             "manipulation": {"requested": 30.0, "achieved": 29.0, "peak_force_n": 3.0,
                              "unit": "deg", "relative_error": 1 / 30},
             "timings_s": {"sfm": 1.0}, "error": None, "model": {"completeness": float("nan")},
             "segmentation": {"off_surface_share": 0.1, "scored_in": {"a": 90, "b": 10},
                              "accuracy_in": {"a": 0.98, "b": 0.9},
                              "accuracy_nearest_surface_at_a": 0.95}}
    bad = {"scene": "broken", "joints": [], "segmentation_accuracy": None, "manipulation": None,
           "timings_s": {}, "error": "capture_a: CaptureError: unreachable"}
    return {"scenes": {"toy": scene, "broken": bad}, "meta": {"seed": 0, "gates": evaluate.GATES}}


def test_results_json_shape_and_report(tmp_path):
    res = _results()
    report.write_results(res, tmp_path)
    back = json.loads((tmp_path / "results.json").read_text())  # strict JSON: NaN became null
    assert back["scenes"]["toy"]["model"]["completeness"] is None
    j = back["scenes"]["toy"]["joints"][0]
    for key in ("name", "type_true", "type_estimated", "axis_angle_deg", "axis_position_mm",
                "state_error", "state_error_unit"):
        assert key in j
    assert back["scenes"]["broken"]["error"].startswith("capture_a")
    md = (tmp_path / "results.md").read_text()
    assert "| toy | hinge |" in md and "**Error** in stage" in md
    assert ("- segmentation: 0.970 against the rendered link labels (points seen in A: 0.980 of "
            "90, in B: 0.900 of 10; 0.100 of the points left out") in md
    table = report.terminal_table(record.read_results(tmp_path / "results.json"))
    assert "29.0/30.0 deg" in table and "ERROR capture_a" in table


def test_report_gives_the_kinematic_tree_verdict(tmp_path):
    """results.md says whether the tree is right, which joints were invented and which were
    static, per scene: in the table (a column) and in the scene's section."""
    res = _results()
    res["scenes"]["toy"].update(
        tree_correct=True, invented_joints=[], static_joints=["drawer_slide"], pairs=[
            ("est0", "hinge")], n_estimated_joints=1, n_true_moving_joints=1,
        link_correspondence={"link_0": "object", "link_1": "door"})
    res["scenes"]["toy"]["joints"][0].update(estimated_joint="est0", paired_by_links=True)
    wrong = {"scene": "chain", "error": None, "segmentation_accuracy": 0.9, "manipulation": None,
             "timings_s": {}, "tree_correct": False, "static_joints": [],
             "invented_joints": [{"name": "ghost", "type": "prismatic",
                                  "angle_to_table_normal_deg": 88.04}],
             "pairs": [("e_boom", "boom"), ("e_blade", "blade")], "n_estimated_joints": 3,
             "n_true_moving_joints": 2,
             "joints": [{"name": "boom", "type_true": "revolute", "estimated_joint": "e_boom",
                         "paired_by_links": True, "state_error_unit": "deg"},
                        {"name": "blade", "type_true": "revolute", "estimated_joint": "e_blade",
                         "paired_by_links": False, "state_error_unit": "deg"}]}
    res["scenes"]["chain"] = wrong
    report.write_results(res, tmp_path)
    back = json.loads((tmp_path / "results.json").read_text())
    assert back["scenes"]["toy"]["tree_correct"] is True
    assert back["scenes"]["chain"]["invented_joints"][0]["name"] == "ghost"
    md = (tmp_path / "results.md").read_text()
    col = report.HEADER.index("tree ok")
    cells = {line.split(" | ")[0].lstrip("| "): line.strip("|").split(" | ")[col].strip()
             for line in md.splitlines() if line.startswith("| ") and " | " in line}
    assert cells["toy"] == "yes, 1 static"
    assert cells["chain"] == "NO, 1 invented"
    assert cells["broken"] == "-"  # failed before scoring: no verdict
    toy = md.split("## toy")[1].split("## ")[0]
    assert "- kinematic tree: correct (1 estimated joint(s) for 1 moving; true <- estimated: " \
           "hinge <- est0; links: link_0 = object, link_1 = door)" in toy
    assert "- invented joints: none" in toy
    assert "not to be found; their link is scored with its parent): drawer_slide" in toy
    chain = md.split("## chain")[1]
    assert "- kinematic tree: **wrong** (3 estimated joint(s) for 2 moving" in chain
    assert "- paired by axis geometry, not by the links they join: blade" in chain
    assert "- invented joints: ghost (prismatic, axis 88.0 deg from the table normal)" in chain
    assert "static joints" in chain and chain.split("static joints")[1].split("\n")[0].endswith(
        ": none")
    assert "kinematic tree" not in md.split("## broken")[1].split("## ")[0]
    back = record.read_results(tmp_path / "results.json")
    assert report.tree_verdict(back.scenes["chain"]) in report.terminal_table(back)


def test_error_chart_marks_failures():
    toy = record.SceneRecord.from_json(report.jsonable_scene(_results()["scenes"]["toy"]))
    bars = pictures.error_bars(toy, evaluate.GATES)
    labels = [b[0] for b in bars]
    assert labels == ["hinge axis angle", "hinge axis position", "hinge state",
                      "segmentation miss", "points off the object", "manipulation rel. err"]
    img = pictures.draw_error_chart("toy", bars)
    assert img.dtype == np.uint8 and img.shape[2] == 3
    # the axis position (7 mm > 2 mm gate) is drawn red, the axis angle (at its gate) green
    rows = [50 + i * 34 + 17 for i in range(len(bars))]
    assert tuple(img[rows[0], 235]) == pictures.GREEN
    assert tuple(img[rows[1], 235]) == pictures.RED


def test_reconstruction_picture_projects_points_where_the_camera_sees_them():
    K = np.array([[100.0, 0, 150], [0, 100, 100], [0, 0, 1]])
    T = np.eye(4)  # camera at the origin looking along +z
    img = np.zeros((200, 300, 3), np.uint8)
    pts = np.array([[0.0, 0.0, 1.0], [0.2, 0.1, 1.0], [0.0, 0.0, -1.0]])
    pic = pictures.draw_reconstruction(img, K, T, pts, np.array([0, 1, 1]), axes=[])
    assert tuple(pic[100, 150]) == pictures.PALETTE[0]
    assert tuple(pic[110, 170]) == pictures.PALETTE[1]
    uv, z = pictures.project(pts, K, T)
    np.testing.assert_allclose(uv[:2], [[150, 100], [170, 110]])
    assert z[2] < 0  # behind the camera: not drawn


def test_swapped_parent_and_child_compare_the_same_motion(truck, truck_samples):
    """A model that took the bed as its base reports the inverse motion (opposite sense about
    the same line): with the link correspondence the state error is still zero."""
    model = _model_from_truth(truck, *truck_samples)
    j = model.joints[0]
    model.joints[0] = Joint(j.type, j.axis_direction, j.axis_point, parent=j.child,
                            child=j.parent, state_a=0.0, state_b=-j.motion, name="inverse")
    (row,) = evaluate.score_joints(truck, model)["joints"]
    assert row["state_error"] == pytest.approx(2 * np.rad2deg(j.motion))  # without the map
    link_map = {0: 0, 1: 1}
    (row,) = evaluate.score_joints(truck, model, link_map)["joints"]
    assert row["links_swapped"] and row["state_error"] == pytest.approx(0.0, abs=1e-9)
    labels_pred = np.array([0, 0, 1, 1, 1])
    assert evaluate.link_correspondence(labels_pred, np.array([1, 1, 0, 0, 1])) == {0: 1, 1: 0}


def test_stage_keys_name_the_code_the_process_loaded(monkeypatch):
    """Once an evaluation has started, editing the files on disk (a merge during a run) does not
    change the code keys of its stages: they name the code that builds them."""
    from sim.evaluate import stages

    stages.freeze_code_keys()
    before = (stages._capture_sources(), stages._configuration_sources(),
              stages._reconstruct_sources(), stages._manipulate_sources())
    monkeypatch.setattr(cache, "source_hash", lambda modules: "edited on disk")
    monkeypatch.setattr(cache, "closure_hash", lambda module, package=None: "edited on disk")
    stages.freeze_code_keys()
    assert (stages._capture_sources(), stages._configuration_sources(),
            stages._reconstruct_sources(), stages._manipulate_sources()) == before
