"""Running part of the reconstruction (``artrecon reconstruct --from STAGE --to STAGE``,
artrecon.reconstruct.STAGES): a run stopped after the configurations and continued from them gives
the whole run's model, bit for bit; the continuation checks the configurations it starts from
and computes none of them. Refused stage arguments (exit 2, nothing written) are cases of
test_bad_input.py's table."""

from __future__ import annotations

import json
import shlex

import numpy as np
import pytest

from artrecon import configuration
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


def test_the_stages_are_the_folders_contract():
    assert list(STAGES) == ["configurations", "model"]


def test_to_configurations_then_from_model_gives_the_whole_runs_model(
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
    assert command[:2] == ["artrecon", "reconstruct"] and command[-2:] == ["--from", "model"]
    assert "--use-poses" in command

    # another seed: the configurations are not this run's, and the message says why
    code = main(command[1:-2] + ["--seed", "1", "--from", "model"])
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

        # a model is there now: replaced only with --overwrite, the configurations kept
        code = main(command[1:])
        assert code == 2 and "holds a model already" in capsys.readouterr().err
        kept = {p: p.read_bytes() for c in ("a", "b") for p in (out / c).rglob("*")
                if p.is_file() and p.name != "database.db"}  # SQLite's change counter moves
        assert main(command[1:] + ["--overwrite"]) == 0
        _assert_same_model(out, whole)
        assert {p: p.read_bytes() for p in kept} == kept


def test_the_python_call_stops_with_none_and_needs_an_output_folder(rendered):
    with pytest.raises(InputError, match="needs an output folder"):
        reconstruct(rendered["a"].folder, rendered["b"].folder, to_stage="configurations")
    with pytest.raises(InputError, match="no such stage"):
        reconstruct(rendered["a"].folder, rendered["b"].folder, from_stage="dense")
