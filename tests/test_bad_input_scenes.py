"""Scenes and the sim commands: a scene that cannot give a result is refused before any capture,
with the file and element named; ``--views`` has one minimum and one wording; outputs never lie
on, around or inside a scene's files; exit 2; nothing written (and no MUJOCO_LOG.TXT in the
working folder)."""

from __future__ import annotations

import re

import pytest
from badinput import REPO, refused

from sim import capture
from sim.evaluate import cli as evaluate_cli

SCENES = REPO / "scenes"


def _scene(t, name="s", numerics="", rigid=False, static=False):
    """The bundled pliers in t/<name>.xml (paths made absolute), edited."""
    text = (SCENES / "pliers.xml").read_text()
    text = text.replace('<include file="stage.xml"/>', f'<include file="{SCENES}/stage.xml"/>')
    text = text.replace('file="assets/', f'file="{SCENES}/assets/')
    if rigid:
        text = re.sub(r'<joint name="pliers_hinge"[^>]*/>', "", text)
        text = re.sub(r'<numeric name="config_[ab]:pliers_hinge"[^>]*/>', "", text)
    if static:
        text = text.replace('<numeric name="config_b:pliers_hinge" data="0.5236"/>',
                            '<numeric name="config_b:pliers_hinge" data="0"/>')
    for setting in re.findall(r'name="(reconstruct:[^"]+)"', numerics):  # replaced, not doubled
        text = re.sub(rf'<numeric name="{re.escape(setting)}"[^>]*/>', "", text)
    text = text.replace("<custom>", "<custom>\n    " + numerics)
    path = t / f"{name}.xml"
    path.write_text(text)
    return path


def _evaluate(t, capsys, *argv):
    return refused(evaluate_cli.main, [*map(str, argv), "--quiet"], capsys, t, SCENES)


def _capture(t, capsys, *argv):
    return refused(capture.main, [*map(str, argv), "--quiet"], capsys, t, SCENES)


def test_scene_without_joints_is_refused_before_any_capture(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, err = _evaluate(tmp_path, capsys, _scene(tmp_path, rigid=True), "--out",
                          tmp_path / "ev")
    assert code == 2 and "s.xml: the object has no joints" in err and "Fix:" in err


def test_scene_whose_joints_do_not_move_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, err = _evaluate(tmp_path, capsys, _scene(tmp_path, static=True), "--out",
                          tmp_path / "ev")
    assert code == 2 and "no joint moves between the two configurations" in err
    assert "pliers_hinge" in err


@pytest.mark.parametrize("data, needles", [
    ("nan", ["not a finite number", "[1, 10000000]"]),
    ("1e30", ["out of range", "[1, 10000000]"]),
])
def test_scene_setting_names_file_and_element(tmp_path, capsys, monkeypatch, data, needles):
    """reconstruct:...=nan said 'cannot convert float NaN to integer' (no file, no element), and
    MuJoCo wrote MUJOCO_LOG.TXT into the working folder (the snapshot covers it)."""
    monkeypatch.chdir(tmp_path)
    scene = _scene(tmp_path, numerics='<numeric name="reconstruct:segmentation.max_hypotheses" '
                                      f'data="{data}"/>')
    code, err = _evaluate(tmp_path, capsys, scene, "--out", tmp_path / "ev")
    assert code == 2 and str(scene) in err
    assert '<numeric name="reconstruct:segmentation.max_hypotheses"' in err
    assert all(n in err for n in needles), err
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_scene_downsample_out_of_range(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene = _scene(tmp_path, numerics='<numeric name="reconstruct:dense.downsample" '
                                      'data="1000"/>')
    code, err = _capture(tmp_path, capsys, scene, "--config", "a", "--out", tmp_path / "a")
    assert code == 2 and "dense.downsample=1000: out of range" in err and str(scene) in err


def test_views_minimum_and_wording_are_the_same_in_both_commands(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code_e, err_e = _evaluate(tmp_path, capsys, "pliers", "--views", "2", "--out",
                              tmp_path / "ev")
    code_c, err_c = _capture(tmp_path, capsys, "pliers", "--config", "a", "--views", "2",
                             "--out", tmp_path / "a")
    message = "--views must be at least 4 (views per full ring"
    assert code_e == code_c == 2 and message in err_e and message in err_c
    assert err_e.splitlines()[-1].split("error: ")[1] == err_c.splitlines()[-1].split("error: ")[1]
    assert "views_per_ring" not in err_c


@pytest.mark.parametrize("out, needle", [
    ("scenes", "contains the input"),
    ("scenes/pliers.xml", "is the input"),
    ("scenes/assets", "contains the input"),
])
def test_capture_never_writes_on_or_around_the_scene(tmp_path, capsys, monkeypatch, out, needle):
    """--out scenes --overwrite replaced the bundled scenes folder with an image set."""
    monkeypatch.chdir(tmp_path)
    code, err = _capture(tmp_path, capsys, "pliers", "--config", "a", "--out", REPO / out,
                         "--overwrite")
    assert code == 2 and needle in err and "nothing was done" in err


def test_evaluate_never_writes_around_the_scenes(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, err = _evaluate(tmp_path, capsys, "pliers", "--out", SCENES)
    assert code == 2 and "contains the input" in err and "pliers.xml" in err


def test_evaluate_out_is_a_file(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "report").write_text("a file")
    code, err = _evaluate(tmp_path, capsys, "pliers", "--out", tmp_path / "report")
    assert code == 2 and "is a file, not a folder" in err


@pytest.mark.parametrize("kind, needle", [
    ("file", "is a file, not a folder"),
    ("other folder", "holds no cameras.json"),
])
def test_capture_overwrites_only_an_image_set(tmp_path, capsys, monkeypatch, kind, needle):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    if kind == "file":
        out.write_text("the user's file")
    else:
        out.mkdir()
        (out / "notes.txt").write_text("the user's notes")
    code, err = _capture(tmp_path, capsys, "pliers", "--config", "a", "--out", out,
                         "--overwrite")
    assert code == 2 and needle in err


def test_capture_existing_file_without_overwrite_is_called_a_file(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out").write_text("x")
    code, err = _capture(tmp_path, capsys, "pliers", "--config", "a", "--out", tmp_path / "out")
    assert code == 2 and "already exists (a file)" in err


@pytest.mark.parametrize("scene, needle", [
    ("nope", "no bundled scene named 'nope'"),
    ("missing.xml", "no such scene file"),
])
def test_unknown_scene(tmp_path, capsys, monkeypatch, scene, needle):
    monkeypatch.chdir(tmp_path)
    code, err = _evaluate(tmp_path, capsys, scene, "--out", tmp_path / "ev")
    assert code == 2 and needle in err
    code, err = _capture(tmp_path, capsys, scene, "--config", "a", "--out", tmp_path / "a")
    assert code == 2 and needle in err


def test_a_scene_copied_without_its_stage_is_told_how_to_make_its_folder_whole(
        tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text = (SCENES / "pliers.xml").read_text().replace('file="assets/', f'file="{SCENES}/assets/')
    (tmp_path / "s.xml").write_text(text)  # includes stage.xml, which is not beside it
    code, err = _evaluate(tmp_path, capsys, tmp_path / "s.xml", "--out", tmp_path / "ev")
    assert code == 2 and "stage that is not beside it" in err
    assert "self-contained" in err and "sim.author" in err
