"""Running part of the reconstruction (``artrecon reconstruct --from STAGE --to STAGE``,
artrecon.reconstruct.STAGES): a run stopped after any stage and continued from the next gives
the whole run's model, bit for bit; the continuation checks what it starts from and computes
none of it. A later start takes other settings of the stages it runs (``--from links``:
segmentation, joints ...), never other settings of the stages it starts after (refused, naming
the stage to start from). Refused stage arguments (exit 2, nothing written) are cases of
test_bad_input.py's table."""

from __future__ import annotations

import json
import shlex
import shutil

import numpy as np
import pytest

from artrecon import configuration, joints_stage, links_stage, matches_stage, refine_stage
from artrecon.cli import main
from artrecon.errors import InputError
from artrecon.reconstruct import STAGES, reconstruct


def _model_figures(out) -> dict:
    """model.json without its timings (the only figures that differ between runs)."""
    data = json.loads((out / "model.json").read_text())
    data["metadata"].pop("timings")
    return data


def _assert_same_model(out, reference) -> None:
    assert _model_figures(out) == _model_figures(reference)
    got, want = np.load(out / "matches.npz"), np.load(reference / "matches.npz")
    assert sorted(got.files) == sorted(want.files)
    for key in want.files:
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)
    # the links stage's files to the byte, but its record (links.json: timings)
    names = sorted(p.name for p in (reference / "links").iterdir())
    assert sorted(p.name for p in (out / "links").iterdir()) == names
    for name in names:
        if name != "links.json":
            assert (out / "links" / name).read_bytes() == \
                (reference / "links" / name).read_bytes(), name


def test_the_stages_are_the_folders_contract(reconstruction_poses):
    """Each stage's folder, as the whole run leaves it: the configurations', then the matches'
    (its record naming the configurations' records and its files), then the model's files."""
    assert list(STAGES) == ["configurations", "matches", "links", "joints", "refine", "model"]
    _, whole = reconstruction_poses
    assert {p.name for p in whole.iterdir()} == {"a", "b", "matches", "links", "joints",
                                                 "refine", "matches.npz", "model.json"}
    record = json.loads((whole / "matches" / "matches.json").read_text())
    assert record["format"] == matches_stage.FORMAT
    assert record["configurations"] == {
        c: json.loads((whole / c / "configuration.json").read_text())["inputs_digest"]
        for c in ("a", "b")}
    assert sorted(record["files"]) == ["background.npz", "candidates.npz", "covariances.npz",
                                       "object.npz"]
    assert sorted(p.name for p in (whole / "matches").iterdir()) == sorted(
        [*record["files"], "matches.json"])
    found = matches_stage.load_matches(whole / "matches")
    model = _model_figures(whole)["metadata"]
    assert len(found.matches) == model["matches"] == record["matches"]
    assert len(found.background) == model["background_matches"]
    # the model's matches.npz: the stage's object matches, the guided ones appended, the points
    # of the links' matches refined photometrically where ``refined`` (artrecon.match_refine)
    saved = np.load(whole / "matches.npz")
    n = len(found.matches)
    refined = saved["refined"][:n]
    assert refined.any() and not refined[saved["labels"][:n] < 0].any()
    np.testing.assert_array_equal(saved["points_a"][:n][~refined],
                                  found.matches.points_a[~refined])
    np.testing.assert_array_equal(saved["point3D_ids_b"][:n], found.matches.point3D_ids_b)
    np.testing.assert_array_equal(saved["background_a"], found.background.points_a)
    assert (whole / "matches.npz").read_bytes() == (whole / "links" / "matches.npz").read_bytes()
    # each later stage's record names the one before it, and its files
    upstream = record["inputs_digest"]
    for stage, name in (("links", "links.json"), ("joints", "joints.json"),
                        ("refine", "refine.json")):
        later = json.loads((whole / stage / name).read_text())
        before = {"links": "matches", "joints": "links", "refine": "joints"}[stage]
        assert later[before] == upstream, stage
        assert sorted(p.name for p in (whole / stage).iterdir()) == sorted(
            [*later["files"], name]), stage
        upstream = later["inputs_digest"]
    assert sorted(json.loads((whole / "links" / "links.json").read_text())["files"]) == [
        "link_0.ply", "link_1.ply", "links.npz", "matches.npz"]
    assert not json.loads((whole / "refine" / "refine.json").read_text())["adopted"]


def test_to_configurations_then_from_matches_gives_the_whole_runs_model(
        rendered, reconstruction_poses, tmp_path, capsys, monkeypatch):
    """The session's whole run (known poses, seed 0) against the same run in two halves, each
    through the command line as a user would run it: the first prints the second."""
    whole_model, whole = reconstruction_poses
    a, b = str(rendered["a"].folder), str(rendered["b"].folder)
    out = tmp_path / "staged"
    assert main(["reconstruct", a, b, "--out", str(out), "--use-poses", "--quiet",
                 "--to", "configurations"]) == 0
    printed = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["a", "b"]  # no model, nothing else
    for c in ("a", "b"):
        record = json.loads((out / c / "configuration.json").read_text())
        assert record["inputs_digest"] == json.loads(
            (whole / c / "configuration.json").read_text())["inputs_digest"]
    assert "continue with" in printed
    command = shlex.split(printed.strip().splitlines()[-1])
    assert command[:2] == ["artrecon", "reconstruct"] and command[-2:] == ["--from", "matches"]
    assert "--use-poses" in command

    # another seed: the configurations are not this run's, and the message says why
    code = main(command[1:-2] + ["--seed", "1", "--from", "matches"])
    err = capsys.readouterr().err
    assert code == 2 and "seed 0 there, 1 now" in err and "without --from" in err, err

    def recompute(*args, **kwargs):
        raise AssertionError("the model stage recomputed a configuration")

    with monkeypatch.context() as m:
        m.setattr(configuration, "run_sfm", recompute)
        m.setattr(configuration, "fused_points", recompute)
        assert main(command[1:]) == 0
        capsys.readouterr()
        _assert_same_model(out, whole)
        assert len(_model_figures(out)["joints"]) == len(whole_model.joints) == 1
        for name in ("object.npz", "background.npz", "candidates.npz", "covariances.npz"):
            assert (out / "matches" / name).read_bytes() == \
                (whole / "matches" / name).read_bytes(), name

        # a model is there now: replaced only with --overwrite, the configurations kept
        code = main(command[1:])
        assert code == 2 and "holds a model already" in capsys.readouterr().err
        kept = {p: p.read_bytes() for c in ("a", "b") for p in (out / c).rglob("*")
                if p.is_file() and p.name != "database.db"}  # SQLite's change counter moves
        assert main(command[1:] + ["--overwrite"]) == 0
        _assert_same_model(out, whole)
        assert {p: p.read_bytes() for p in kept} == kept


def test_to_matches_then_from_links_gives_the_whole_runs_model_and_takes_other_settings(
        rendered, reconstruction_poses, tmp_path, capsys, monkeypatch):
    """Stopped after the matches and continued from them: the whole run's model, without a
    configuration or a match computed again; continued with another segmentation setting: a
    model from the same matches; with another match setting: refused (the matches would be
    other ones), nothing changed. The first half starts from copies of the whole run's
    configurations (``--from matches``; computing them through the command line is the test
    above's)."""
    whole_model, whole = reconstruction_poses
    a, b = str(rendered["a"].folder), str(rendered["b"].folder)
    out = tmp_path / "staged"
    for c in ("a", "b"):
        shutil.copytree(whole / c, out / c, symlinks=True)
    with monkeypatch.context() as m:
        _patch_stages_before(m, "matches")
        assert main(["reconstruct", a, b, "--out", str(out), "--use-poses", "--quiet",
                     "--from", "matches", "--to", "matches"]) == 0
    printed = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["a", "b", "matches"]
    assert "stage 'matches'" in printed and "continue with" in printed
    command = shlex.split(printed.strip().splitlines()[-1])
    assert command[-2:] == ["--from", "links"] and "--use-poses" in command

    def recompute(*args, **kwargs):
        raise AssertionError("the model stage recomputed a configuration or the matches")

    with monkeypatch.context() as m:
        m.setattr(configuration, "run_sfm", recompute)
        m.setattr(configuration, "fused_points", recompute)
        m.setattr(matches_stage, "match_configurations", recompute)
        assert main(command[1:]) == 0
        capsys.readouterr()
        _assert_same_model(out, whole)
        kept = {p: p.read_bytes() for p in (out / "matches").iterdir()}

        # the links and joints again with another segmentation setting, on the same matches
        assert main(command[1:] + ["--overwrite", "--set", "segmentation.refine_iterations=5"]
                    ) == 0
        capsys.readouterr()
        figures = _model_figures(out)
        assert figures["metadata"]["config"]["segmentation"]["refine_iterations"] == 5
        assert figures["metadata"]["matches"] == whole_model.metadata["matches"]
        assert len(figures["links"]) >= 2 and figures["joints"]
        assert {p: p.read_bytes() for p in kept} == kept

        # another match setting: these matches are not that run's
        before = {p: p.read_bytes() for p in out.rglob("*")
                  if p.is_file() and p.name != "database.db"}
        code = main(command[1:] + ["--overwrite", "--set", "match.ratio=0.7"])
        err = capsys.readouterr().err
        assert code == 2 and "match.ratio: 0.8 there, 0.7 now" in err, err
        assert "--from matches" in err
        assert {p: p.read_bytes() for p in before} == before


def test_the_python_call_stops_with_none_and_needs_an_output_folder(rendered):
    with pytest.raises(InputError, match="needs an output folder"):
        reconstruct(rendered["a"].folder, rendered["b"].folder, to_stage="configurations")
    with pytest.raises(InputError, match="needs an output folder"):
        reconstruct(rendered["a"].folder, rendered["b"].folder, from_stage="matches")
    with pytest.raises(InputError, match="no such stage"):
        reconstruct(rendered["a"].folder, rendered["b"].folder, from_stage="dense")


def test_matches_without_covariances_are_the_same_matches(reconstruction_poses, tmp_path):
    """segmentation.covariances off: the matches stage writes the same matches, background
    matches and candidates, no covariances.npz, and reads back None for them."""
    from artrecon.configuration import load_configuration
    from artrecon.settings import ReconstructConfig, with_settings
    from artrecon.workers import single_threaded

    _, whole = reconstruction_poses
    confs = {c: load_configuration(whole / c) for c in ("a", "b")}
    config = with_settings(ReconstructConfig(), {"segmentation.covariances": 0})
    with single_threaded():
        found = matches_stage.match_stage(confs, tmp_path / "matches", config, seed=0)
    assert found.covariances is None and found.record["covariances"] is False
    assert found.record["settings"]["segmentation"] == {"covariances": False}
    assert sorted(p.name for p in (tmp_path / "matches").iterdir()) == [
        "background.npz", "candidates.npz", "matches.json", "object.npz"]
    for name in ("object.npz", "background.npz", "candidates.npz"):
        assert (tmp_path / "matches" / name).read_bytes() == \
            (whole / "matches" / name).read_bytes(), name
    assert matches_stage.load_matches(whole / "matches").covariances is not None


def _recompute(*args, **kwargs):
    raise AssertionError("a stage before the one the run starts from was computed again")


def _patch_stages_before(m, first: str) -> None:
    """Make every stage before ``first`` fail if it computes anything."""
    before = list(STAGES)[:list(STAGES).index(first)]
    if "configurations" in before:
        m.setattr(configuration, "run_sfm", _recompute)
        m.setattr(configuration, "fused_points", _recompute)
    if "matches" in before:
        m.setattr(matches_stage, "match_configurations", _recompute)
    if "links" in before:
        m.setattr(links_stage, "find_links", _recompute)
    if "joints" in before:
        m.setattr(joints_stage, "find_joints", _recompute)
    if "refine" in before:
        m.setattr(refine_stage, "refine_joints", _recompute)


def _command(rendered, out) -> list[str]:
    return ["reconstruct", str(rendered["a"].folder), str(rendered["b"].folder), "--out",
            str(out), "--use-poses", "--quiet"]


@pytest.mark.parametrize("first", ["links", "joints", "refine", "model"])
def test_a_run_from_each_later_stage_gives_the_whole_runs_model(
        rendered, reconstruction_poses, tmp_path, capsys, monkeypatch, first):
    """The whole run's folder continued from ``first`` (over its model: --overwrite): the same
    model, bit for bit, with none of the stages before ``first`` computed again, and their
    folders as they were."""
    _, whole = reconstruction_poses
    out = tmp_path / "again"
    shutil.copytree(whole, out, symlinks=True)
    kept = {p: p.read_bytes() for name in list(STAGES)[1:list(STAGES).index(first)]
            for p in (out / name).iterdir()}
    with monkeypatch.context() as m:
        _patch_stages_before(m, first)
        assert main(_command(rendered, out) + ["--from", first, "--overwrite"]) == 0
    capsys.readouterr()
    _assert_same_model(out, whole)
    assert {p: p.read_bytes() for p in kept} == kept


@pytest.mark.parametrize(("first", "setting", "start", "named"), [
    ("joints", "segmentation.refine_iterations=5", "links",
     "segmentation.refine_iterations: 10 there, 5 now"),
    ("joints", "guided.enabled=0", "links", "guided.enabled: True there, False now"),
    ("refine", "confidence.bootstrap_samples=50", "joints",
     "confidence.bootstrap_samples: 200 there, 50 now"),
    ("model", "refine.adopt=1", "refine", "refine.adopt: False there, True now"),
])
def test_a_stage_of_other_settings_is_refused_naming_where_to_start(
        rendered, reconstruction_poses, tmp_path, capsys, first, setting, start, named):
    """A later start with another setting of a stage it starts after: refused, the setting
    named (there and now) and the stage to start from instead; nothing changed."""
    _, whole = reconstruction_poses
    out = tmp_path / "again"
    shutil.copytree(whole, out, symlinks=True)
    before = {p: p.read_bytes() for p in out.rglob("*")
              if p.is_file() and p.name != "database.db"}
    code = main(_command(rendered, out) + ["--from", first, "--overwrite", "--set", setting])
    err = capsys.readouterr().err
    assert code == 2, err
    assert f"the {'refined joints' if start == 'refine' else start} in" in err, err
    assert named in err and f"--from {start}" in err, err
    assert {p: p.read_bytes() for p in before} == before


def test_a_stage_of_another_seed_is_refused_naming_where_to_start(
        rendered, reconstruction_poses, tmp_path, capsys):
    """A links folder whose record names another seed (its digest too): ``--from joints``
    says so and to start from the links."""
    _, whole = reconstruction_poses
    out = tmp_path / "again"
    shutil.copytree(whole, out, symlinks=True)
    path = out / "links" / "links.json"
    record = json.loads(path.read_text())
    record["seed"] = 1
    record["inputs_digest"] = links_stage.inputs_digest(
        {"matches": record["matches"]}, record["settings"], 1)
    path.write_text(json.dumps(record))
    code = main(_command(rendered, out) + ["--from", "joints", "--overwrite"])
    err = capsys.readouterr().err
    assert code == 2 and "seed 1 there, 0 now" in err and "--from links" in err, err


def test_to_links_then_from_joints_gives_the_whole_runs_model(
        rendered, reconstruction_poses, tmp_path, capsys, monkeypatch):
    """Stopped after the links (from the whole run's configurations and matches) and continued
    from the joints: the command printed continues it, and the model is the whole run's."""
    _, whole = reconstruction_poses
    out = tmp_path / "staged"
    out.mkdir()
    for name in ("a", "b", "matches"):
        shutil.copytree(whole / name, out / name, symlinks=True)
    assert main(_command(rendered, out) + ["--from", "links", "--to", "links"]) == 0
    printed = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["a", "b", "links", "matches"]
    assert "stage 'links'" in printed
    command = shlex.split(printed.strip().splitlines()[-1])
    assert command[-2:] == ["--from", "joints"]
    with monkeypatch.context() as m:
        _patch_stages_before(m, "joints")
        assert main(command[1:]) == 0
    capsys.readouterr()
    _assert_same_model(out, whole)


def test_other_joint_settings_from_joints_reuse_the_links(
        rendered, reconstruction_poses, tmp_path, capsys, monkeypatch):
    """``--from joints`` with another joints.* setting: the joints again with it, the links
    neither computed nor written again (their files' bytes and times as they were)."""
    _, whole = reconstruction_poses
    out = tmp_path / "again"
    shutil.copytree(whole, out, symlinks=True)
    links = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in (out / "links").iterdir()}
    with monkeypatch.context() as m:
        _patch_stages_before(m, "joints")
        assert main(_command(rendered, out) + ["--from", "joints", "--overwrite", "--set",
                                               "joints.axis_gap_weight=2"]) == 0
    capsys.readouterr()
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in (out / "links").iterdir()} \
        == links
    record = json.loads((out / "joints" / "joints.json").read_text())
    assert record["settings"]["joints"]["axis_gap_weight"] == 2
    figures = _model_figures(out)
    assert figures["metadata"]["config"]["joints"]["axis_gap_weight"] == 2
    assert len(figures["joints"]) == 1
