"""The verdict (issue 19): one gate table, a scene that misses a gate FAILs, and the main job
exits non-zero with a last line naming the scenes and gates.

Scored like the main job scores (sim.evaluate.scoring.score_joints on a scene's ground truth),
with models built from the true surfaces and joints, so that the only error is the one put in.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import sim  # noqa: F401
from artrecon.geometry import rotation_about
from artrecon.model import ArticulatedModel, Joint, Link
from sim import evaluate
from sim.evaluate import cli, gates, record
from sim.scene import load_scene


def _pliers_result(tilt_deg: float = 0.0, swap: bool = False) -> dict:
    """A pliers result from a model whose links are the true surfaces and whose joint is the true
    one, its axis turned by ``tilt_deg`` about a perpendicular, parent and child swapped if
    ``swap``; segmentation and manipulation figures inside their gates."""
    scene = load_scene("pliers")
    pts, links = evaluate.sample_surface(scene, "a", spacing=0.004, seed=1)
    (tj,) = scene.moving_joints
    axis = rotation_about(np.cross(tj.axis, [1.0, 0.0, 0.0]), np.deg2rad(tilt_deg)) @ tj.axis
    parent, child = scene.link(tj.parent), scene.link(tj.child)
    index = {li.name: k for k, li in enumerate(scene.links)}
    order = [index[child.name], index[parent.name]] if swap else [index[parent.name],
                                                                    index[child.name]]
    model_links = [Link(points=pts[links == k], match_indices=np.full(int((links == k).sum()), -1),
                        name=f"link_{i}") for i, k in enumerate(order)]
    motion = -tj.motion if swap else tj.motion
    joint = Joint(tj.type, axis, tj.point, parent=0, child=1, state_a=0.0, state_b=motion,
                  name="e_hinge")
    model = ArticulatedModel(links=model_links, joints=[joint], scale=1.0, scale_known=True)
    labels_pred = np.concatenate([np.full(len(lk.points), i) for i, lk in enumerate(model_links)])
    labels_true = np.concatenate([links[links == k] for k in order])
    link_map = evaluate.link_correspondence(labels_pred, evaluate.rigid_bodies(scene)[labels_true])
    out = evaluate.score_joints(scene, model, link_map)
    return {"scene": "pliers", "error": None, **out, "segmentation_accuracy": 0.99,
            "segmentation": {"off_surface_share": 0.01}, "manipulation": _manipulation(),
            "registration": {"truth_errors": {"pnp": {"rotation_deg": 0.02,
                                                      "translation_mm": 0.3,
                                                      "scale_percent": 0.01}}}}


def _manipulation(achieved: float = 29.9, lost: bool = False, force: float = 1.0,
                  error: str | None = None) -> dict:
    """The manipulation record of one model joint moved (sim.evaluate.scoring)."""
    run = {"model_joint": "e_hinge", "true_joint": "pliers_hinge", "error": error,
           "requested": 30.0, "achieved": None if error else achieved, "unit": "deg",
           "relative_error": None if error else abs(achieved - 30.0) / 30.0,
           "grasp_lost": lost, "peak_force_n": force, "force_limit_n": 2.0}
    return {"runs": [run]}


def test_exact_model_passes_every_gate():
    v = gates.verdict(_pliers_result())
    assert v == {"passed": True, "failed": []}


def test_axis_turned_5_degrees_fails_the_axis_gate():
    v = gates.verdict(_pliers_result(tilt_deg=5.0))
    assert not v["passed"]
    failed = {g["gate"]: g for g in v["failed"]}
    assert "axis_angle_deg" in failed
    assert failed["axis_angle_deg"]["figure"] == pytest.approx(5.0, abs=1e-6)
    assert failed["axis_angle_deg"]["limit"] == gates.GATES["axis_angle_deg"]


def test_wrong_parent_fails_the_tree_gate():
    v = gates.verdict(_pliers_result(swap=True))
    assert not v["passed"]
    assert [g["gate"] for g in v["failed"]] == ["tree"]
    assert "swapped" in v["failed"][0]["figure"]


@pytest.mark.parametrize("change, gate", [
    ({"segmentation_accuracy": 0.96}, "segmentation_accuracy"),
    ({"segmentation": {"off_surface_share": 0.06}}, "off_object_share"),
    ({"manipulation": _manipulation(achieved=28.0)}, "manipulation_relative_error"),
    ({"manipulation": _manipulation(error="ManipulationError: no grasp")}, "manipulation"),
    ({"manipulation": _manipulation(lost=True)}, "manipulation_grasp_held"),
    ({"manipulation": _manipulation(force=2.5)}, "manipulation_peak_force_n"),
    ({"manipulation": {"runs": [], "reason": "the model has no joint"}}, "manipulation"),
    ({"registration": {"truth_errors": {"pnp": {"rotation_deg": 0.7, "translation_mm": 0.3,
                                                "scale_percent": 0.01}}}},
     "registration_pnp_rotation_deg"),
    ({"invented_joints": [{"name": "ghost"}]}, "invented_joints"),
])
def test_each_scene_gate_fails_alone(change, gate):
    v = gates.verdict({**_pliers_result(), **change})
    assert [g["gate"] for g in v["failed"]] == [gate]


def test_an_error_is_a_fail():
    v = gates.verdict({"scene": "x", "error": "sfm: ReconstructionError: no pair",
                       "error_stage": "reconstruct"})
    assert not v["passed"] and v["failed"][0]["gate"] == "error"


def test_main_job_exits_non_zero_and_names_the_gate(monkeypatch, tmp_path, capsys):
    """``python -m sim.evaluate`` with a scene whose model's axis is 5 degrees off: the scene is
    FAIL in the table, the last line names it and its gate, and the exit status is 1 (0 with
    --report-only)."""
    def fake_run(names, ev, out_dir, argv=None):
        res = _pliers_result(tilt_deg=5.0)
        v = gates.verdict(res, manipulate=ev.manipulate)
        res.update(passed=v["passed"], failed_gates=v["failed"])
        # as sweep.run returns it: the record as written (JSON: lists, not tuples)
        return json.loads(json.dumps({"schema_version": record.SCHEMA_VERSION,
                                      "scenes": {"pliers": res}, "meta": {}}))

    monkeypatch.setattr(cli, "run", fake_run)
    assert cli.main(["pliers", "--out", str(tmp_path), "--quiet"]) == 1
    out = capsys.readouterr()
    assert "FAIL (1 gate)" in out.out
    assert out.out.strip().splitlines()[-1].startswith("FAIL: 1 of 1 scene(s)")
    assert "pliers (axis_angle_deg)" in out.out.strip().splitlines()[-1]
    assert "FAIL pliers: e_hinge" not in out.err  # subjects are the true joints' names
    assert "FAIL pliers: pliers_hinge: axis_angle_deg" in out.err
    assert cli.main(["pliers", "--out", str(tmp_path), "--quiet", "--report-only"]) == 0


def test_main_job_exits_zero_when_every_scene_passes(monkeypatch, tmp_path, capsys):
    def fake_run(names, ev, out_dir, argv=None):
        res = _pliers_result()
        res.update(passed=True, failed_gates=[])
        # as sweep.run returns it: the record as written (JSON: lists, not tuples)
        return json.loads(json.dumps({"schema_version": record.SCHEMA_VERSION,
                                      "scenes": {"pliers": res}, "meta": {}}))

    monkeypatch.setattr(cli, "run", fake_run)
    assert cli.main(["pliers", "--out", str(tmp_path), "--quiet"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("PASS: all 1 scene(s)")
