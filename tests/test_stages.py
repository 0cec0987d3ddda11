"""Running part of the reconstruction (``artrecon reconstruct --from STAGE --to STAGE``,
artrecon.reconstruct.STAGES): a run stopped after the configurations (or the matches) and
continued from them gives the whole run's model, bit for bit; the continuation checks what it
starts from and computes none of it. ``--from model`` takes other settings of the later stages
(segmentation, joints ...), never other match settings. Refused stage arguments (exit 2,
nothing written) are cases of test_bad_input.py's table."""

from __future__ import annotations

import json
import shlex

import numpy as np
import pytest

from artrecon import configuration, matches_stage
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
    links = sorted(p.name for p in (reference / "links").iterdir())
    assert sorted(p.name for p in (out / "links").iterdir()) == links
    for name in links:
        assert (out / "links" / name).read_bytes() == (reference / "links" / name).read_bytes()


def test_the_stages_are_the_folders_contract(reconstruction_poses):
    """Each stage's folder, as the whole run leaves it: the configurations', then the matches'
    (its record naming the configurations' records and its files), then the model's files."""
    assert list(STAGES) == ["configurations", "matches", "model"]
    _, whole = reconstruction_poses
    assert {p.name for p in whole.iterdir()} == {"a", "b", "matches", "matches.npz", "links",
                                                 "model.json"}
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
    # the model's matches.npz: the stage's object matches, the guided ones appended
    saved = np.load(whole / "matches.npz")
    n = len(found.matches)
    np.testing.assert_array_equal(saved["points_a"][:n], found.matches.points_a)
    np.testing.assert_array_equal(saved["point3D_ids_b"][:n], found.matches.point3D_ids_b)
    np.testing.assert_array_equal(saved["background_a"], found.background.points_a)


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
        m.setattr(configuration, "dense_points", recompute)
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


def test_to_matches_then_from_model_gives_the_whole_runs_model_and_takes_other_settings(
        rendered, reconstruction_poses, tmp_path, capsys, monkeypatch):
    """Stopped after the matches and continued from them: the whole run's model, without a
    configuration or a match computed again; continued with another segmentation setting: a
    model from the same matches; with another match setting: refused (the matches would be
    other ones), nothing changed."""
    whole_model, whole = reconstruction_poses
    a, b = str(rendered["a"].folder), str(rendered["b"].folder)
    out = tmp_path / "staged"
    assert main(["reconstruct", a, b, "--out", str(out), "--use-poses", "--quiet",
                 "--to", "matches"]) == 0
    printed = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["a", "b", "matches"]
    assert "stage 'matches'" in printed and "continue with" in printed
    command = shlex.split(printed.strip().splitlines()[-1])
    assert command[-2:] == ["--from", "model"] and "--use-poses" in command

    def recompute(*args, **kwargs):
        raise AssertionError("the model stage recomputed a configuration or the matches")

    with monkeypatch.context() as m:
        m.setattr(configuration, "run_sfm", recompute)
        m.setattr(configuration, "dense_points", recompute)
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
