"""The typed record of results.json (:mod:`sim.evaluate.record`): what the writers write and the
readers read, refusing a file of another schema_version.

``data/results_pliers_seed0.json`` is a real results.json: ``python -m sim.evaluate pliers``
(seed 0, the main job's defaults) as written by this code.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import sim  # noqa: F401
from sim.evaluate import EvalConfig, gates, record, report, sweep, sweep_report
from sim.evaluate.gates import GateCheck

SAMPLE = Path(__file__).parent / "data" / "results_pliers_seed0.json"


def _scene(**change) -> record.SceneRecord:
    """A scene record made in code, one of each nested record."""
    fields = dict(
        scene="pliers", error=None, error_stage=None, timings_s={"sfm": 1.5},
        cached_stages=["capture_a"],
        joints=[record.JointRecord(name="hinge", type_true="revolute", axis_angle_deg=0.6,
                                   state_error_unit="deg", confidence={"score": 1.0},
                                   passes=False)],
        segmentation_accuracy=0.98,
        manipulation=record.ManipulationRecord(
            runs=[record.ManipulationRun(model_joint="e0", requested=30.0, achieved=29.9,
                                         moved={"hinge": 0.52}, passes=True)],
            q_start=[0.0, 0.1]),
        capture_a=record.CaptureSummary(n_planned=121, n_captured=121),
        model_summary=record.ModelSummary(links=2, registered_images={"a": 121, "b": 121}),
        registration=record.RegistrationRecord(
            chosen_route="camera_centres",
            truth_errors={"pnp": record.TruthError(rotation_deg=0.06, scale_percent=0.0)}),
        invented_joints=[record.InventedJoint(name="ghost", type="prismatic")],
        pairs=[["e0", "hinge"]],
        segmentation=record.SegmentationRecord(points=10, accuracy_in={"a": 0.9, "b": None}),
        model=record.ModelScore(completeness=0.9, hidden=record.SurfaceScore(n_points=3)),
        camera_pose_error=record.PoseErrors(n=121),
        passed=False, failed_gates=[GateCheck("axis_angle_deg", "hinge", 0.6, 0.5, False)])
    return record.SceneRecord(**{**fields, **change})


def test_a_record_made_in_code_round_trips():
    rec = record.Results(scenes={"pliers": _scene()},
                         meta=record.Meta(seed=0, gates=dict(gates.GATES)))
    data = rec.to_json()
    assert list(data) == ["schema_version", "scenes", "meta"]
    assert data["schema_version"] == record.SCHEMA_VERSION
    assert json.loads(json.dumps(data)) == data  # plain JSON
    assert data["scenes"]["pliers"]["failed_gates"] == [
        {"gate": "axis_angle_deg", "subject": "hinge", "figure": 0.6, "limit": 0.5,
         "passed": False}]
    assert record.Results.from_json(data) == rec
    assert record.Results.from_json(data).to_json() == data


def test_a_sweep_round_trips():
    spec = record.RunSpecRecord(scene="pliers", config={"seed": 0}, perturbation="",
                                strength=None, label="")
    done = record.RunRecord(id="pliers-seed0", group="pliers", spec=spec, code="c0ffee",
                            status="failed", attempts=1, worker={"host": "h", "pid": 1},
                            dir="runs/pliers-seed0", result=_scene())
    # a run not run has no code: the key is absent, not null
    waiting = record.RunRecord(id="pliers-seed1", group="pliers", spec=spec, status="not run",
                               attempts=0, worker=None, dir="runs/pliers-seed1", result=None,
                               present=frozenset({"id", "group", "spec", "status", "attempts",
                                                  "worker", "dir", "result"}))
    summary = record.GroupSummary(group="pliers", seeds=[0, 1], runs=2, passed=0,
                                  figures={"hinge axis angle": record.FigureSummary(
                                      unit="deg", gate=0.5, values={"0": 0.6, "1": None})})
    rec = record.Results(meta=record.Meta(seeds=[0, 1], sweep=record.SweepMeta(jobs=2)),
                         runs=[done, waiting], summary=[summary])
    data = rec.to_json()
    assert rec.layout == "sweep" and list(data) == ["schema_version", "meta", "runs", "summary"]
    assert "code" not in data["runs"][1] and data["runs"][0]["code"] == "c0ffee"
    assert record.Results.from_json(data) == rec


def test_a_real_results_json_validates_and_is_written_again_unchanged():
    """The record reads every key the runner wrote and writes the same file again: the same
    keys, in the same order, with the same values."""
    text = SAMPLE.read_text()
    rec = record.read_results(SAMPLE)
    assert json.dumps(rec.to_json(), indent=2) == json.dumps(json.loads(text), indent=2)
    assert rec.layout == "scenes"
    pliers = rec.scenes["pliers"]
    assert pliers.passed and pliers.failed_gates == [] and pliers.error is None
    (joint,) = pliers.joints
    assert joint.name == "pliers_hinge" and joint.axis_angle_deg < gates.GATES["axis_angle_deg"]
    assert pliers.registration.truth_errors["pnp"].rotation_deg < 0.5
    assert pliers.manipulation.runs[0].model_joint == pliers.joints[0].estimated_joint
    assert pliers.model.hidden.completeness > 0.5
    assert pliers.perturb_a is None and "perturb_a" not in pliers.to_json()  # absent stays absent


def test_the_runner_writes_a_results_json_of_the_record(tmp_path):
    """The main job's own run, writer and file (a scene that fails at once: no capture)."""
    missing = str(tmp_path / "no_such_scene.xml")
    out = tmp_path / "out"
    res = sweep.run([missing], EvalConfig(progress=False, parallel_capture=False), out)
    rec = record.read_results(out / "results.json")
    assert rec.to_json() == res == json.loads((out / "results.json").read_text())
    scene = rec.scenes[missing]
    assert scene.error_stage == "load" and scene.passed is False
    assert [g.gate for g in scene.failed_gates] == ["error"]
    assert rec.meta.seed == 0 and rec.meta.gates == gates.GATES


@pytest.mark.parametrize("version, said", [
    (None, "has no schema_version: it was written before sim.evaluate versioned its results"),
    (0, "is of schema_version 0"),
    (record.SCHEMA_VERSION + 1, f"is of schema_version {record.SCHEMA_VERSION + 1}")])
def test_a_results_json_of_another_version_is_refused_with_its_message(tmp_path, version, said):
    data = json.loads(SAMPLE.read_text())
    if version is None:
        del data["schema_version"]
    else:
        data["schema_version"] = version
    path = tmp_path / "results.json"
    path.write_text(json.dumps(data))
    with pytest.raises(record.SchemaError) as info:
        record.read_results(path)
    assert str(info.value) == (
        f"{path} {said}; this code reads schema_version {record.SCHEMA_VERSION} "
        "(sim/evaluate/record.py). Run the evaluation again with this code, or read the file "
        "with the code that wrote it.")


@pytest.mark.parametrize("change, message", [
    (lambda r: r["joints"][0].update(axis_deg=1.0),
     r"results\.json\.scenes\['pliers'\]\.joints\[0\]: 'axis_deg' is not a key of JointRecord"),
    (lambda r: r.update(passed="yes"),
     r"results\.json\.scenes\['pliers'\]\.passed: expected bool, got str 'yes'"),
    (lambda r: r["failed_gates"].append({"gate": "tree"}),
     r"failed_gates\[0\]: GateCheck has the keys gate, subject, figure, limit, passed, got gate"),
    (lambda r: r["joints"][0].pop("name"), r"joints\[0\]: JointRecord needs name"),
])
def test_a_key_or_value_the_record_does_not_hold_is_named(change, message):
    data = json.loads(SAMPLE.read_text())
    change(data["scenes"]["pliers"])
    with pytest.raises(record.SchemaError, match=message):
        record.Results.from_json(data)


def test_the_writer_refuses_a_result_off_the_schema_and_writes_nothing(tmp_path):
    scene = {**_scene().to_json(), "views": 36}
    with pytest.raises(record.SchemaError, match="'views' is not a key of SceneRecord"):
        report.write_results({"scenes": {"pliers": scene}, "meta": {"seed": 0}}, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_one_layout_at_a_time():
    with pytest.raises(record.SchemaError, match="not both"):
        record.Results(scenes={}, runs=[], summary=[], meta=record.Meta())
    with pytest.raises(record.SchemaError, match="not neither"):
        record.Results(meta=record.Meta())


# ---------------------------------------------------------------------------- a sweep's run.json


def _run() -> record.RunRecord:
    spec = record.RunSpecRecord(scene="pliers", config={"seed": 0}, perturbation="",
                                strength=None, label="")
    return record.RunRecord(id="pliers-seed0", group="pliers", spec=spec, code="c0ffee",
                            status="passed", attempts=1, worker={"host": "h", "pid": 1},
                            dir="runs/pliers-seed0", result=_scene(passed=True, failed_gates=[]))


def test_a_run_json_round_trips_with_its_schema_version(tmp_path):
    rec = _run()
    data = record.run_file(rec)
    assert list(data)[:2] == ["schema_version", "id"]
    assert data["schema_version"] == record.SCHEMA_VERSION
    path = tmp_path / "run.json"
    path.write_text(json.dumps(data, indent=2))
    assert record.read_run(path) == rec


@pytest.mark.parametrize("change, message", [
    (lambda d: d.pop("schema_version"),
     "run.json has no schema_version: it was written before sim.evaluate versioned its results; "
     "this code reads schema_version 1"),
    (lambda d: d.update(schema_version=2), "run.json is of schema_version 2; this code reads"),
    (lambda d: d.update(note="by hand"),
     "run.json: 'note' is not a key of RunRecord (results.json schema_version 1); its keys are "
     "id, group, spec"),
    (lambda d: d["result"].update(views=36), r"run.json.result: 'views' is not a key of "
     "SceneRecord"),
    (lambda d: d.update(attempts="1"), "run.json.attempts: expected int, got str '1'"),
])
def test_a_run_json_of_another_version_or_off_the_record_is_refused(tmp_path, change, message):
    data = record.run_file(_run())
    change(data)
    path = tmp_path / "run.json"
    path.write_text(json.dumps(data))
    with pytest.raises(record.SchemaError) as info:
        record.read_run(path)
    assert str(info.value).startswith(str(path)) and message in str(info.value)


def test_a_run_json_that_is_not_json_is_refused(tmp_path):
    path = tmp_path / "run.json"
    path.write_text('{"schema_version": 1, "id": ')  # a file cut short
    with pytest.raises(record.SchemaError, match=r"run\.json: not JSON"):
        record.read_run(path)


# ---------------------------------------------------------------------------- the readers


@pytest.mark.parametrize("name", ["results_pliers_seed0", "results_sweep_light"])
def test_the_report_of_a_committed_results_json_is_unchanged(name):
    """results.md and the terminal table, read from the record, are byte for byte those the
    readers wrote when they read the JSON as dicts (``data/<name>.md`` and ``.txt`` were written
    by that code, at d13ff61, from ``data/<name>.json``). ``results_sweep_light`` is a sweep of
    light runs (tests/test_sweep.py): passed, died, raised and not run, a perturbation."""
    rec = record.read_results(SAMPLE.parent / f"{name}.json")
    if rec.layout == "scenes":
        markdown, table = report.markdown, report.terminal_table
    else:
        markdown, table = sweep_report.sweep_markdown, sweep_report.sweep_table
    assert markdown(rec) == (SAMPLE.parent / f"{name}.md").read_text()
    assert table(rec) + "\n" == (SAMPLE.parent / f"{name}.txt").read_text()
