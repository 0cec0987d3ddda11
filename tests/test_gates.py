"""Accuracy gates on the bundled scenes (issue 7): the whole method, scored against ground truth.

Each scene runs once (module-scoped fixture): capture both configurations with the arm, SfM
reconstruction from the images alone, registration by the camera centres, manipulation along the
estimated joint; then every gate is its own test so a report shows which figure failed.

Views: ``GATE_VIEWS`` per full ring (18: rings of 18/18/18/7 images per configuration, 20 degrees
apart) keeps the three scenes inside ~25 minutes on the 2-core CI machine; the default of the
command line (36) is what the reported figures use. The results are cached in a temporary folder
per session (``sim.cache``), so re-running a failed gate in the same session costs nothing.

Gates (``sim.evaluate.GATES``, never loosened here): joint type correct, axis angle <= 2 deg,
axis position <= 5 mm (revolute), state error <= 2 deg or 5 mm, segmentation accuracy >= 0.95,
manipulation achieved within 10% of requested.
"""

import os
from pathlib import Path

import pytest

import sim  # noqa: F401
from sim import evaluate
from sim.evaluate import report

#: Views per full capture ring in the gates (see the module docstring).
GATE_VIEWS = int(os.environ.get("ARTRECON_GATE_VIEWS", "18"))
#: The bundled scenes the gates run on (the issue's three; the others are reported by
#: ``python -m sim.evaluate`` until they pass).
GATE_SCENES = ("pliers", "truck", "drawer")

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """Every gate scene, evaluated once. ARTRECON_GATES_OUT names a folder to keep instead of a
    temporary one: its stage cache serves the next session, and results.json / results.md there
    hold the figures behind the gates."""
    keep = os.environ.get("ARTRECON_GATES_OUT")
    out = Path(keep) / "gates" if keep else tmp_path_factory.mktemp("gates")
    ev = evaluate.EvalConfig(views=GATE_VIEWS, seed=0, progress=False)
    res = {name: evaluate.evaluate_scene(name, ev, out) for name in GATE_SCENES}
    if keep:
        meta = evaluate.run_meta(ev, "pytest tests/test_gates.py")
        meta["scene_hashes"] = {n: r.get("scene_hash") for n, r in res.items()}
        report.write_results({"scenes": {n: report.jsonable_scene(r) for n, r in res.items()},
                              "meta": meta}, out)
    return res


def _scene(results, name):
    r = results[name]
    assert r["error"] is None, f"{name} failed: {r['error']}"
    return r


def _joints(results, name):
    r = _scene(results, name)
    assert r["joints"], f"{name}: no moving joint in the scene"
    return r["joints"]


@pytest.mark.parametrize("name", GATE_SCENES)
def test_joint_types_correct(results, name):
    for j in _joints(results, name):
        assert j["type_correct"], (f"{name}/{j['name']}: true {j['type_true']}, estimated "
                                   f"{j['type_estimated']}")


#: The pliers' axis rests on two long, thin halves: each link's roll about its length hinges on
#: its few matches off the line, amplified ~2x into the axis at 30 deg. It measured 0.16-2.0 deg
#: over runs (2.01 in one CI) while the base was fitted to its own matches alone; since the base is
#: fitted with the background it stays with (reconstruct.anchor_to_background, 9b58f88) it
#: measured 0.08, 1.10, 0.21, 0.21 deg with SfM at seeds 0-3 and 0.24-1.32 deg from known poses
#: (the moving half's roll is what is left). Gated strictly like the other scenes.
@pytest.mark.parametrize("name", GATE_SCENES)
def test_axis_angle(results, name):
    for j in _joints(results, name):
        assert j["axis_angle_deg"] is not None, f"{name}/{j['name']}: no matching joint"
        assert j["axis_angle_deg"] <= evaluate.GATES["axis_angle_deg"], (name, j)


@pytest.mark.parametrize("name", GATE_SCENES)
def test_axis_position(results, name):
    for j in _joints(results, name):
        if j["type_true"] != "revolute":
            assert j["axis_position_mm"] is None  # no meaning for a prismatic axis
            continue
        assert j["axis_position_mm"] is not None, f"{name}/{j['name']}: no matching hinge"
        assert j["axis_position_mm"] <= evaluate.GATES["axis_position_mm"], (name, j)


@pytest.mark.parametrize("name", GATE_SCENES)
def test_state_error(results, name):
    for j in _joints(results, name):
        gate = evaluate.GATES[f"state_error_{j['state_error_unit']}"]
        assert j["state_error"] is not None, f"{name}/{j['name']}: no state (wrong type?)"
        assert j["state_error"] <= gate, (name, j)


#: Known misses of the segmentation gate, measured at 18 views per ring, seed 0. Strict: the day
#: a scene passes, this list must shrink. Empty since the figure is scored against the rendered
#: link labels, each point where it was seen, and the dense points are labelled by graph cuts in
#: two passes (pliers 0.963, was 0.923-0.928 with the nearest-surface figure and ICM; drawer
#: 0.986, was 0.945-0.954; truck 0.997).
SEGMENTATION_KNOWN_MISSES: dict[str, str] = {}


#: A gate that passes in some runs and not others (SfM's run-to-run spread, or a capture plan
#: that moved): not strict, so both outcomes show in the summary (XPASS / XFAIL). Empty: truck's
#: segmentation was here after one run of three at 4140519 found a spurious third link among the
#: matches (0.908 then); since segment_links keeps the best of 8 RANSAC runs with the most
#: frequent link count (12767e5) and links moving alike are merged, it measured 0.996-0.997 in
#: every run (c571d97, 1c95ab0, 9b58f88).
SEGMENTATION_FLAKY: dict[str, str] = {}


def _segmentation_param(n):
    if n in SEGMENTATION_KNOWN_MISSES:
        return pytest.param(n, marks=pytest.mark.xfail(strict=True,
                                                       reason=SEGMENTATION_KNOWN_MISSES[n]))
    if n in SEGMENTATION_FLAKY:
        return pytest.param(n, marks=pytest.mark.xfail(strict=False,
                                                       reason=SEGMENTATION_FLAKY[n]))
    return n


@pytest.mark.parametrize("name", [_segmentation_param(n) for n in GATE_SCENES])
def test_segmentation_accuracy(results, name):
    r = _scene(results, name)
    assert r["segmentation_accuracy"] >= evaluate.GATES["segmentation_accuracy"], \
        (name, r["segmentation"])


#: Issue 5 on the bundled scenes: SfM camera poses (from the images alone, then registered by
#: the camera centres) against the true poses, and the dense points against the true surfaces.
#: Bounds a tenth of the axis gates and below them: pose and surface errors must not be what
#: spends the 5 mm / 2 deg budget. Measured (18 views per ring): 0.14-0.15 mm, 0.009-0.020 deg,
#: dense median 1.4-2.4 mm.
CAMERA_POSITION_MEDIAN_MM = 1.0
CAMERA_ROTATION_MEDIAN_DEG = 0.1
DENSE_ACCURACY_MEDIAN_MM = 3.0


@pytest.mark.parametrize("name", GATE_SCENES)
def test_camera_poses_and_dense_points(results, name):
    r = _scene(results, name)
    cam = r["camera_pose_error"]
    assert cam["n"] == r["capture_a"]["n_captured"], (name, cam)  # every image registered
    assert cam["position_median_mm"] <= CAMERA_POSITION_MEDIAN_MM, (name, cam)
    assert cam["rotation_median_deg"] <= CAMERA_ROTATION_MEDIAN_DEG, (name, cam)
    assert r["model"]["accuracy_median_mm"] <= DENSE_ACCURACY_MEDIAN_MM, (name, r["model"])


@pytest.mark.parametrize("name", GATE_SCENES)
def test_every_planned_view_captured(results, name):
    r = _scene(results, name)
    for cfg in ("capture_a", "capture_b"):
        cap = r[cfg]
        assert cap["n_planned"] > 0 and cap["n_captured"] == cap["n_planned"], (name, cfg, cap)
        # the recorded poses are the arm's forward kinematics, and they are where the camera was
        assert cap["max_fk_position_error_mm"] < 1e-6, (name, cfg, cap)


@pytest.mark.parametrize("name", GATE_SCENES)
def test_manipulation_achieves_request(results, name):
    man = _scene(results, name)["manipulation"]
    assert man and man.get("requested") is not None, f"{name}: no manipulation: {man}"
    rel = abs(man["achieved"] - man["requested"]) / abs(man["requested"])
    assert rel <= evaluate.GATES["manipulation_relative_error"], (name, man)


#: Issue 8 on the reconstruction: the twin, driven by the true motion, must put its points within
#: "a few mm" of the true surface; the median over each link's points (the reconstruction's own
#: accuracy is 1.4-2.4 mm median in configuration A, its p90 3-6 mm).
TWIN_MEDIAN_MM = 5.0


@pytest.mark.parametrize("name", GATE_SCENES)
def test_exported_twin_moves_like_the_true_object(results, name, tmp_path):
    """The registered reconstruction exported as MJCF and URDF, its joint driven by the true
    object's motion in MuJoCo and pinocchio: the twin's points land on the true surfaces of
    configuration B."""
    import numpy as np
    from scipy.spatial import cKDTree
    from test_export import mujoco_points, pinocchio_points

    from artrecon import export as ex
    from sim.scene import load_scene

    r = _scene(results, name)
    model = r["_registered"]
    scene = load_scene(name)
    (row,) = r["joints"]
    (true_joint,) = scene.moving_joints
    assert not row["links_swapped"], f"{name}: the twin's base is the true moving link"
    idx = next(k for k, j in enumerate(model.joints) if j.name == row["estimated_joint"])
    twin = ex.build_twin(model)
    tj = twin.joints[idx]
    assert np.sign(tj.motion) == np.sign(model.joints[idx].motion)
    value = {tj.name: float(np.sign(tj.motion) * abs(true_joint.motion))}
    xml = ex.export_mjcf(twin, tmp_path / f"{name}.xml")[-1]
    urdf = ex.export_urdf(twin, tmp_path / f"{name}.urdf")[-1]
    pts_mj, _ = mujoco_points(xml, twin, value)
    pts_pin, _ = pinocchio_points(urdf, twin, value)
    samples, _ = evaluate.sample_surface(scene, "b", seed=0)
    tree = cKDTree(samples)
    report = {}
    for lk, p_mj, p_pin in zip(twin.links, pts_mj, pts_pin, strict=True):
        np.testing.assert_allclose(p_mj, p_pin, atol=1e-9)
        d = tree.query(p_mj)[0] * 1e3
        report[lk.name] = (round(float(np.median(d)), 2), round(float(np.percentile(d, 90)), 2))
    print(name, "twin in B, median/p90 mm per link:", report)
    assert all(med <= TWIN_MEDIAN_MM for med, _ in report.values()), (name, report)
