"""The capture's tunables from the command line (issue 25): ``--set capture.FIELD=VALUE`` and
``--set views.FIELD=VALUE`` of ``python -m sim.capture`` and ``python -m sim.evaluate``, checked
by artrecon's settings code against :data:`sim.capture_config.RANGES`, carried by EvalConfig to
the captures and to the fresh view, and part of their cache keys."""

from __future__ import annotations

import json
import types
from dataclasses import fields, replace

import numpy as np
import pytest

import sim  # noqa: F401
import sim.capture
import sim.capture.cli
from artrecon.errors import InputError
from artrecon.settings import ListOf, Range, check_setting
from sim.capture import CaptureConfig, CaptureResult
from sim.capture.rig import make_rig
from sim.capture_config import NOT_SET, RANGES, CaptureSettings, capture_settings
from sim.evaluate import EvalConfig, cli, record, runner, stages
from sim.evaluate.sweep import RunSpec
from sim.scene import load_scene
from sim.views import ViewPlanConfig

#: Two settings off their defaults, one of each part.
SET = ["--set", "capture.fresh_elevation_deg=45", "--set", "views.clearance_m=0.02"]


def test_every_tunable_field_has_a_checked_range_or_a_reason():
    """Every field of CaptureConfig and ViewPlanConfig has a row in RANGES (so ``--set`` takes
    it, checked) or says in NOT_SET why not; every row names a field; every default lies in its
    range."""
    settings = CaptureSettings()
    keys = {f"{part.name}.{f.name}": getattr(getattr(settings, part.name), f.name)
            for part in fields(settings) for f in fields(getattr(settings, part.name))}
    assert set(RANGES) | set(NOT_SET) == set(keys) and not set(RANGES) & set(NOT_SET)
    for key in RANGES:
        assert check_setting(key, keys[key], keys[key], RANGES) == keys[key], key


def test_settings_are_parsed_converted_and_listed_as_changed():
    s = capture_settings({"capture.move_speed": 0.5, "views.ik_restarts": 4.0,
                          "views.clearance_m": 0.02})
    assert s.capture == replace(CaptureConfig(), move_speed=0.5)
    assert s.views.ik_restarts == 4 and isinstance(s.views.ik_restarts, int)
    assert s.changed() == {"capture.move_speed": 0.5, "views.ik_restarts": 4,
                           "views.clearance_m": 0.02}
    assert capture_settings({}) == CaptureSettings() and CaptureSettings().changed() == {}


@pytest.mark.parametrize("items, needles", [
    (["capture.nope=1"], ["setting 'capture.nope': CaptureConfig has no field 'nope'",
                          "move_speed"]),
    (["views.clearance=1"], ["ViewPlanConfig has no field 'clearance'", "clearance_m"]),
    (["camera.fov=60"], ["setting 'camera.fov': name it stage.field with a stage of "
                         "['capture', 'views']"]),
    (["capture.move_speed=50"], ["capture.move_speed=50: out of range",
                                 "takes a value in (0, 10]", "default 1"]),
    (["views.clearance_m=0"], ["views.clearance_m=0: out of range", "(0, 0.1]"]),
    (["views.ik_restarts=2.5"], ["not a whole number", "[0, 100]"]),
    (["capture.settle_speed=nan"], ["not a finite number"]),
    (["views.fill=0.9"], ["fill must lie in fill_range (0.45, 0.75), got 0.9"]),
    (["views.seed=3"], ["'views.seed' cannot be set with --set: the seed is set by --seed"]),
    (["views.views_per_ring=18"], ["views per ring are set by --views"]),
    (["views.elevations_deg=20,95,60"], [
        "setting views.elevations_deg=20,95,60: value 2 (95) is out of range; "
        "views.elevations_deg takes one or more values separated by commas, each a value in "
        "[-80, 85]", "default 20,40,60"]),
    (["views.fill_range=0.5"], ["views.fill_range=0.5: 1 value, not 2", "takes 2 values",
                                "each a value in [0.05, 1]"]),
    (["capture.fresh_azimuth_offsets_deg=10,,20"], ["value 2 is empty", "[-180, 180]"]),
    (["views.roll_candidates_deg=0,ninety"], ["value 2 (ninety) is not a number"]),
    (["views.roll_candidates_deg=90,0"], ["roll_candidates_deg must start with 0"]),
    (["views.clearance_m"], ["--set 'views.clearance_m': expected STAGE.FIELD=VALUE, e.g. "
                             "views.clearance_m=0.02"]),
])
@pytest.mark.parametrize("command", ["sim.capture", "sim.evaluate"])
def test_a_bad_setting_is_refused_by_both_commands_naming_the_range(command, items, needles,
                                                                   tmp_path, capsys):
    """Exit 2 before any work, the message naming the field and its range; nothing written."""
    argv = [a for item in items for a in ("--set", item)]
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as info:
        if command == "sim.capture":
            sim.capture.cli.main(["pliers", "--config", "a", "--out", str(out), *argv])
        else:
            cli.main(["pliers", "--out", str(out), "--quiet", *argv])
    err = capsys.readouterr().err
    assert info.value.code == 2
    assert f"python -m {command}: error: " in err
    assert all(n in err for n in needles), err
    assert not out.exists()


def test_the_capture_command_hands_its_settings_to_the_capture(tmp_path, monkeypatch):
    seen = {}

    def fake_capture(scene, config, out_dir, **kw):
        seen.update(kw)
        return CaptureResult(out_dir=out_dir, n_planned=1, n_captured=1)

    monkeypatch.setattr(sim.capture.cli, "capture", fake_capture)
    assert sim.capture.cli.main(["pliers", "--config", "a", "--out", str(tmp_path / "s"),
                                 "--views", "18", "--seed", "3", "--fill", "0.5", *SET]) == 0
    assert seen["view_plan"] == ViewPlanConfig(views_per_ring=18, seed=3, fill=0.5,
                                               clearance_m=0.02)
    assert seen["capture_config"] == CaptureConfig(fresh_elevation_deg=45.0)
    with pytest.raises(SystemExit, match="2"):  # the fill given twice
        sim.capture.cli.main(["pliers", "--config", "a", "--out", str(tmp_path / "t"),
                              "--fill", "0.5", "--set", "views.fill=0.6"])


def test_the_evaluation_carries_its_settings_and_records_them_only_when_set():
    ev = cli.config_from_args(cli.parser().parse_args(["pliers", "--views", "18", "--seed",
                                                       "2", *SET]))
    assert ev.capture_settings.changed() == {"capture.fresh_elevation_deg": 45.0,
                                             "views.clearance_m": 0.02}
    assert ev.view_plan() == ViewPlanConfig(views_per_ring=18, seed=2, clearance_m=0.02)
    default = cli.config_from_args(cli.parser().parse_args(["pliers"]))
    assert default.capture_settings == CaptureSettings()
    assert default.view_plan() == ViewPlanConfig()
    # the records name them only when set: a default run's keys are as before
    assert "capture_settings" not in runner.run_meta(default, "cmd")
    assert "capture_settings" not in RunSpec("pliers", default).describe()["config"]
    meta = runner.run_meta(ev, "cmd")
    assert meta["capture_settings"] == ev.capture_settings.changed()
    assert RunSpec("pliers", ev).describe()["config"]["capture_settings"] == meta[
        "capture_settings"]
    assert record.Meta.from_json(meta).capture_settings == meta["capture_settings"]


def test_evalconfig_refuses_views_and_seed_inside_the_capture_settings():
    with pytest.raises(ValueError, match="EvalConfig.views and EvalConfig.seed"):
        EvalConfig(capture_settings=CaptureSettings(views=ViewPlanConfig(views_per_ring=18)))


@pytest.fixture
def pliers():
    return load_scene("pliers")


@pytest.fixture
def capture_set(tmp_path):
    """A capture folder as the fresh view reads it: the arm's joints at its last image and the
    object's sphere its survey found."""
    folder = tmp_path / "capture_a" / "set"
    folder.mkdir(parents=True)
    (folder / "cameras.json").write_text(json.dumps({"images": [
        {"file": "000.png", "q": [0.1] * 7}]}))
    (folder / "capture.json").write_text(json.dumps({"object_sphere": {
        "centre": [0.01, 0.02, 0.5], "radius": 0.12,
        "survey": {"hull_vertices": [[0.0, 0.0, 0.45], [0.1, 0.0, 0.45], [0.0, 0.1, 0.45],
                                     [0.0, 0.0, 0.55]]}}}))
    return folder


def test_the_fresh_view_gets_the_evaluations_settings(pliers, capture_set, tmp_path,
                                                      monkeypatch):
    """Issue 25: the fresh view was taken with the default capture and plan configs whatever
    the evaluation's; now with the same as the captures (EvalConfig.view_plan)."""
    seen = {}

    def fake_fresh_view(scene, config, q_start, out_dir, **kw):
        seen.update(kw, q_start=list(q_start))
        out_dir.mkdir(parents=True)
        (out_dir / "pose.json").write_text("{}")
        return types.SimpleNamespace(pose_file=out_dir / "pose.json", q=np.zeros(7))

    monkeypatch.setattr(sim.capture, "capture_fresh_view", fake_fresh_view)
    ev = cli.config_from_args(cli.parser().parse_args(["pliers", "--views", "18", "--seed",
                                                       "3", *SET]))
    stages.fresh_view_stage(pliers, capture_set, "capture_a-key", ev, tmp_path / "cache")
    assert seen["capture_config"].fresh_elevation_deg == 45.0
    assert seen["plan_config"] == ViewPlanConfig(views_per_ring=18, seed=3, clearance_m=0.02)
    assert seen["seed"] == 3 and seen["q_start"] == [0.1] * 7
    # it looks where the capture's survey found the object (issue 21), not at the truth, and
    # keeps clear of the survey's hull
    assert seen["target"] == ([0.01, 0.02, 0.5], 0.12, [[0.0, 0.0, 0.45], [0.1, 0.0, 0.45],
                                                        [0.0, 0.1, 0.45], [0.0, 0.0, 0.55]])


def test_the_captures_get_the_evaluations_settings(pliers, tmp_path, monkeypatch):
    seen = {}

    def fake_capture(scene, config, out_dir, **kw):
        seen.update(kw)
        out_dir.mkdir(parents=True)
        return CaptureResult(out_dir=out_dir, n_planned=1, n_captured=1)

    monkeypatch.setattr(sim.capture, "capture", fake_capture)
    ev = EvalConfig(views=18, seed=3, progress=False,
                    capture_settings=capture_settings({"capture.move_speed": 0.5,
                                                       "views.ik_restarts": 4}))
    stages.capture_stage(pliers, "a", ev, tmp_path / "cache", "scene-hash")
    assert seen["view_plan"] == ViewPlanConfig(views_per_ring=18, seed=3, ik_restarts=4)
    assert seen["capture_config"] == CaptureConfig(move_speed=0.5)
    # the default run captures with the plan the capture built from views and seed before
    seen.clear()
    stages.capture_stage(pliers, "a", EvalConfig(views=18, seed=3, progress=False),
                         tmp_path / "cache", "scene-hash")
    assert seen["view_plan"] == ViewPlanConfig(views_per_ring=18, seed=3)
    assert seen["capture_config"] == CaptureConfig()


def test_settings_key_the_captures_and_the_fresh_view(pliers):
    """A setting changes the key of the captures (and so of every stage after them) and of the
    fresh view; at the defaults the inputs hold no settings key at all. The view plan's own
    cache key holds every field of the plan it is given (sim.capture.plan_inputs)."""
    default = EvalConfig()
    changed = replace(default, capture_settings=capture_settings({"views.clearance_m": 0.02}))
    base = stages._capture_inputs(pliers, "a", default, "h")
    assert "capture_settings" not in base
    assert stages._capture_inputs(pliers, "a", changed, "h") == {
        **base, "capture_settings": {"views.clearance_m": 0.02}}
    assert stages._settings_inputs(default) == {}
    assert stages._settings_inputs(changed) == {"capture_settings": {"views.clearance_m": 0.02}}


def test_the_plan_cache_key_holds_the_views_settings(pliers):
    rig = make_rig(pliers, "a")
    args = (rig.model, rig.data, rig.kin, rig.K, rig.width, rig.height)
    ev = EvalConfig(capture_settings=capture_settings({"views.clearance_m": 0.02}))
    default = sim.capture.plan_inputs(*args, EvalConfig().view_plan())
    changed = sim.capture.plan_inputs(*args, ev.view_plan())
    assert default["plan"]["clearance_m"] == 0.01 and changed["plan"]["clearance_m"] == 0.02
    assert {k for k in default if default[k] != changed[k]} == {"plan"}


def test_capture_settings_refuse_a_bad_value_in_code_too():
    with pytest.raises(InputError, match="out of range"):
        capture_settings({"capture.object_drift_tol": 1.0})


# ---------------------------------------------------------------------------- list settings


def test_a_list_setting_round_trips_from_the_command_line_to_the_records_and_keys(pliers):
    """``--set views.elevations_deg=20,40`` (comma-separated values) reaches the view plan as a
    tuple of floats, and the records and cache keys as a list; the defaults given explicitly are
    the default settings, whose records and keys hold no settings at all."""
    lists = ["--set", "views.elevations_deg=20,40", "--set", "views.fill_range=0.5, 0.7",
             "--set", "capture.fresh_azimuth_offsets_deg=-10"]
    ev = cli.config_from_args(cli.parser().parse_args(["pliers", *lists]))
    assert ev.view_plan() == ViewPlanConfig(elevations_deg=(20.0, 40.0), fill_range=(0.5, 0.7))
    assert ev.capture_settings.capture == CaptureConfig(fresh_azimuth_offsets_deg=(-10.0,))
    changed = {"views.elevations_deg": [20.0, 40.0], "views.fill_range": [0.5, 0.7],
               "capture.fresh_azimuth_offsets_deg": [-10.0]}
    assert stages._settings_inputs(ev) == {"capture_settings": changed}
    assert RunSpec("pliers", ev).describe()["config"]["capture_settings"] == changed
    assert record.Meta.from_json(json.loads(json.dumps(runner.run_meta(ev, "cmd")))
                                 ).capture_settings == changed
    # the defaults, given as lists, change nothing: not the settings, not a key
    defaults = cli.config_from_args(cli.parser().parse_args([
        "pliers", "--set", "views.elevations_deg=20,40,60", "--set",
        "views.top_elevations_deg=70", "--set", "views.fill_range=0.45,0.75", "--set",
        "views.roll_candidates_deg=0,90,-90,180,45,-45,135,-135", "--set",
        "capture.fresh_azimuth_offsets_deg=5,15,-5,-15,25,-25,35,-35"]))
    assert defaults.capture_settings == CaptureSettings()
    assert stages._capture_inputs(pliers, "a", defaults, "h") == stages._capture_inputs(
        pliers, "a", EvalConfig(), "h")
    assert RunSpec("pliers", defaults).describe() == RunSpec("pliers", EvalConfig()).describe()


@pytest.mark.parametrize("value, default, row, result", [
    ("1,2", (3, 4), ListOf(Range(0, 10), length=2), (1, 2)),  # whole numbers stay int
    ([1.5, 2], (0.5, 1.0), ListOf(Range(0, 10)), (1.5, 2.0)),  # a sequence, in code
    (3.0, (0.5,), ListOf(Range(0, 10)), (3.0,)),  # one number, as the command line reads it
])
def test_check_setting_converts_a_list_to_a_tuple_of_its_defaults_kind(value, default, row,
                                                                       result):
    out = check_setting("x.values", value, default, {"x.values": row})
    assert out == result and [type(v) for v in out] == [type(v) for v in result]


@pytest.mark.parametrize("value, problem", [
    ("1.5,2", "value 1 (1.5) is not a whole number"),
    ("1,inf", "value 2 (inf) is not a finite number"),
    ([1, True], "value 2 (True) is not a number"),
    ([1, None], "value 2 (None) is not a number"),
    ("1,2,3", "3 values, not 2"),
    ((), "0 values, not 2"),
])
def test_check_setting_names_the_bad_value_of_a_list_and_its_range(value, problem):
    with pytest.raises(InputError) as info:
        check_setting("x.values", value, (3, 4), {"x.values": ListOf(Range(0, 10), length=2)})
    assert problem in str(info.value)
    assert str(info.value).endswith("x.values takes 2 values separated by commas, each a value "
                                    "in [0, 10], default 3,4")


def test_no_top_ring_is_set_as_none_and_reaches_the_view_plan():
    ev = cli.config_from_args(cli.parser().parse_args(
        ["pliers", "--set", "views.top_elevations_deg=none"]))
    assert ev.view_plan() == ViewPlanConfig(top_elevations_deg=())
    assert stages._settings_inputs(ev) == {"capture_settings": {"views.top_elevations_deg": []}}
    # a list that may not be empty still refuses none, and says what it takes
    with pytest.raises(InputError) as info:
        cli.config_from_args(cli.parser().parse_args(
            ["pliers", "--set", "views.elevations_deg=none"]))
    assert "value 1 (none) is not a number" in str(info.value)
    assert "(or none)" not in str(info.value)
