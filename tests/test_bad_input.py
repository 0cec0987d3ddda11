"""Bad input gets a clear message, a non-zero exit and no traceback; results are whole or absent.

Folder-level checks of one image set (missing, a file, no images, too few, unreadable, mixed
sizes) are tested on artrecon.io in test_sfm.py, and malformed scene files on sim.scene in
test_scenes.py; here: what the user sees from the command lines, image sets that cannot be two
configurations of one object, and interrupted runs.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import render_fixture as rf
from badinput import case_registry, refused, write_images

from artrecon import files, io
from artrecon.cli import main
from artrecon.errors import InputError, NoMotionError, ReconstructionError
from artrecon.reconstruct import reconstruct

REPO = Path(__file__).resolve().parents[1]


def _write_images(folder: Path, n: int = 6, size=(64, 48), seed: int = 0) -> Path:
    return write_images(folder, n, size, seed)


def _cli(argv, capsys) -> tuple[int, str]:
    code = main(argv)  # an uncaught exception (a traceback) fails the test here
    return code, capsys.readouterr().err


# --- the reconstruct command: one table of refused inputs -------------------------------------
# Each case builds its inputs in a fresh folder and returns the command's extra arguments and
# what the message must say; every case must exit 2 with "artrecon: error: ", write nothing
# and change nothing in that folder (badinput.refused hashes it before and after).

W, H = 64, 48
K_SMALL = [[50.0, 0, (W - 1) / 2], [0, 50.0, (H - 1) / 2], [0, 0, 1]]


def _capture(folder: Path, seed: int, cameras=None) -> Path:
    """A capture folder: images/ and cameras.json (``cameras`` replaces its content)."""
    write_images(folder / "images", seed=seed)
    names = sorted(p.name for p in (folder / "images").iterdir())
    data = {"K": K_SMALL, "width": W, "height": H,
            "images": [{"name": n, "T_world_camera": np.eye(4).tolist()} for n in names]}
    text = cameras if isinstance(cameras, str) else json.dumps(cameras or data)
    (folder / "cameras.json").write_text(text)
    return folder


def _pair(t: Path):
    return write_images(t / "a", seed=1), write_images(t / "b", seed=2)


def _args(a, b, out, *extra):
    return ["reconstruct", str(a), str(b), "--out", str(out), *extra]


CASES, case = case_registry()


# image folders
@case("image folder", "does not exist")
def folder_missing(t):
    return _args(t / "nope", write_images(t / "b"), t / "o")


@case("is a file, not a folder")
def folder_is_a_file(t):
    cv2.imwrite(str(t / "photo.png"), np.zeros((30, 40, 3), np.uint8))
    return _args(write_images(t / "a"), t / "photo.png", t / "o")


@case("no images")
def folder_empty(t):
    (t / "b").mkdir()
    return _args(write_images(t / "a"), t / "b", t / "o")


@case("only 3 image(s)", "at least 5")
def folder_too_few(t):
    return _args(write_images(t / "a"), write_images(t / "b", n=3, seed=2), t / "o")


@case("cannot read image", "img_02.png", "corrupt")
def image_corrupt(t):
    a, b = _pair(t)
    (b / "img_02.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    return _args(a, b, t / "o")


@case("cannot read image", "img_03.png")
def image_empty_file(t):
    a, b = _pair(t)
    (b / "img_03.png").write_bytes(b"")
    return _args(a, b, t / "o")


@case("differ in size", "img_04.png", "64x48")
def images_mixed_sizes(t):
    a, b = _pair(t)
    cv2.imwrite(str(b / "img_04.png"), np.zeros((30, 40, 3), np.uint8))
    return _args(a, b, t / "o")


@case("did not move", "both name the folder")
def same_folder_twice(t):
    a = write_images(t / "a")
    return _args(a, a, t / "o")


@case("same images", "byte for byte", "did not move")
def byte_copy_of_a(t):
    a = write_images(t / "a")
    (t / "b").mkdir()
    for i, f in enumerate(sorted(a.iterdir())):
        shutil.copy(f, t / "b" / f"copy_{i}.png")
    return _args(a, t / "b", t / "o")


@case("nothing moved between A and B", "re-encoded copy", "move")
def reencoded_copy_of_a(t):
    a = write_images(t / "a", size=(160, 120))
    (t / "b").mkdir()
    for f in sorted(a.iterdir()):  # the same photos as JPEG: other bytes, the same pictures
        cv2.imwrite(str(t / "b" / f"{f.stem}.jpg"), cv2.imread(str(f)),
                    [cv2.IMWRITE_JPEG_QUALITY, 90])
    return _args(a, t / "b", t / "o")


# camera files and intrinsics
@case("fx,fy,cx,cy")
def intrinsics_three_numbers(t):
    return _args(*_pair(t), t / "o", "--intrinsics", "500,500,320")


@case("focal lengths must be positive")
def intrinsics_negative_focal(t):
    return _args(*_pair(t), t / "o", "--intrinsics=-50,50,31.5,23.5")


@case("finite number")
def intrinsics_nan(t):
    return _args(*_pair(t), t / "o", "--intrinsics", "nan,50,31.5,23.5")


@case("cannot read intrinsics", "3x3 'K'", "it has no 'K'")
def intrinsics_file_without_k(t):
    (t / "k.json").write_text('{"f": 50}')
    return _args(*_pair(t), t / "o", "--intrinsics", str(t / "k.json"))


@case("cannot read camera file", "cameras.json")
def cameras_json_not_json(t):
    return _args(_capture(t / "a", 1, cameras="{not json"), write_images(t / "b", seed=2),
                 t / "o")


@case("holds a JSON list", "'K' and 'images'")
def cameras_json_a_list(t):
    return _args(_capture(t / "a", 1, cameras="[1, 2]"), write_images(t / "b", seed=2), t / "o")


@case("cameras.json", "must be a 3x3 matrix of numbers")
def cameras_json_ragged_k(t):
    bad = {"K": [[50, 0], [0, 50, 23.5], [0, 0, 1]], "images": []}
    return _args(_capture(t / "a", 1, cameras=bad), write_images(t / "b", seed=2), t / "o")


@case("entry 0 needs 'name' and a 4x4 'T_world_camera'")
def cameras_json_pose_3x3(t):
    bad = {"K": K_SMALL, "images": [{"name": "img_00.png", "T_world_camera": np.eye(3).tolist()}]}
    return _args(_capture(t / "a", 1, cameras=bad), write_images(t / "b", seed=2), t / "o",
                 "--use-poses")


@case("not a finite number", "img_00.png")
def cameras_json_nan_pose(t):
    T = np.eye(4).tolist()
    T[0][3] = float("nan")
    bad = {"K": K_SMALL, "images": [{"name": "img_00.png", "T_world_camera": T}]}
    return _args(_capture(t / "a", 1, cameras=json.dumps(bad)), write_images(t / "b", seed=2),
                 t / "o")


@case("intrinsics are for 640x480 images", "64x48")
def cameras_json_other_size(t):
    other = {"K": K_SMALL, "width": 640, "height": 480, "images": []}
    return _args(_capture(t / "a", 1, cameras=other), write_images(t / "b", seed=2), t / "o")


@case("poses requested", "has no cameras.json")
def use_poses_without_cameras_json(t):
    return _args(*_pair(t), t / "o", "--use-poses")


# settings
@pytest.mark.parametrize("setting, needles", [
    ("dense.downsample", ["expected STAGE.FIELD=VALUE"]),
    ("dense.downsample=", ["expected STAGE.FIELD=VALUE"]),
    ("dense.downsample=full", ["dense.downsample=full: not a number", "[1, 8]"]),
    ("dense.nope=1", ["DenseConfig has no field 'nope'", "downsample"]),
    ("nope.x=1", ["name it stage.field", "dense"]),
    ("dense.downsample=0", ["out of range", "takes a value in [1, 8]", "default 2"]),
    ("dense.downsample=1000", ["dense.downsample=1000: out of range", "[1, 8]"]),
    ("dense.downsample=1.5", ["not a whole number", "[1, 8]"]),
    ("segmentation.max_hypotheses=nan", ["not a finite number", "[1, 10000000]"]),
    ("segmentation.max_hypotheses=inf", ["not a finite number", "[1, 10000000]"]),
    ("segmentation.max_hypotheses=0", ["out of range", "[1, 10000000]", "default 5000"]),
    ("joints.revolute_min_angle=-0.1", ["out of range", "(0, 1.5708]", "radians"]),
    ("guided.enabled=2", ["not a boolean", "0 (off) or 1 (on)"]),
    ("sfm.matching=everything", ["one of 'auto', 'exhaustive', 'sequential'"]),
])
def test_bad_setting_is_refused_with_its_range(tmp_path, capsys, monkeypatch, setting, needles):
    monkeypatch.chdir(tmp_path)
    code, err = refused(main, _args(*_pair(tmp_path), tmp_path / "o", "--set", setting), capsys,
                        tmp_path)
    assert code == 2 and err.startswith("artrecon: error: "), err
    assert all(n in err for n in needles), err


def test_settings_out_of_order_are_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = _args(*_pair(tmp_path), tmp_path / "o", "--set", "segmentation.min_links=5",
                 "--set", "segmentation.max_links=3")
    code, err = refused(main, argv, capsys, tmp_path)
    assert code == 2 and "segmentation.min_links (5) may not exceed segmentation.max_links (3)" \
        in err


# output folders
@case("is the input", "nothing was done", "outside the inputs")
def out_is_input_a(t):
    a = _capture(t / "a", 1)
    return _args(a, write_images(t / "b", seed=2), a, "--overwrite")


@case("is the input", "images")
def out_is_the_image_folder_of_a(t):
    a = _capture(t / "a", 1)
    return _args(a, write_images(t / "b", seed=2), a / "images", "--overwrite")


@case("lies inside the input folder")
def out_inside_b(t):
    a, b = _pair(t)
    return _args(a, b, b / "model")


@case("contains the input")
def out_contains_the_inputs(t):
    a, b = _pair(t)
    return _args(a, b, t, "--overwrite")


@case("is the input")
def out_is_a_link_to_a(t):
    a, b = _pair(t)
    (t / "link").symlink_to(a)
    return _args(a, b, t / "link", "--overwrite")


@case("is a file, not a folder", "never replaced")
def out_is_a_file(t):
    (t / "notes.txt").write_text("the user's notes")
    return _args(*_pair(t), t / "notes.txt", "--overwrite")


@case("is a file, not a folder", "never replaced")
def out_is_a_file_without_overwrite(t):
    """The issue's case: without --overwrite a file was called an existing 'output folder'."""
    (t / "notes.txt").write_text("the user's notes")
    return _args(*_pair(t), t / "notes.txt")


@case("output folder", "exists", "--overwrite")
def out_exists(t):
    (t / "o").mkdir()
    (t / "o" / "model.json").write_text("{}")
    return _args(*_pair(t), t / "o")


@case("holds no model.json", "never other files")
def out_overwrite_of_a_folder_that_is_no_result(t):
    (t / "docs").mkdir()
    (t / "docs" / "thesis.tex").write_text("years of work")
    return _args(*_pair(t), t / "docs", "--overwrite")


@case("cannot be made", "is a file, not a folder", "nothing was written")
def out_under_a_file(t):
    (t / "file").write_text("a file where the output's parent folder should be")
    return _args(*_pair(t), t / "file" / "o")


# running part of the run (--from / --to, artrecon.reconstruct.STAGES)
@case("--from sfm", "no such stage", "configurations (writes", "matches (writes",
      "links (writes", "joints (writes", "refine (writes", "model (writes")
def stage_unknown(t):
    return _args(*_pair(t), t / "o", "--from", "sfm")


@case("--to dense", "no such stage")
def stage_unknown_to(t):
    return _args(*_pair(t), t / "o", "--to", "dense")


@case("--from model comes after --to configurations", "nothing to run")
def stage_from_after_to(t):
    return _args(*_pair(t), t / "o", "--from", "model", "--to", "configurations")


@case("--from matches comes after --to configurations", "nothing to run")
def stage_from_matches_after_to_configurations(t):
    return _args(*_pair(t), t / "o", "--from", "matches", "--to", "configurations")


@case("--from model comes after --to matches", "nothing to run")
def stage_from_model_after_to_matches(t):
    return _args(*_pair(t), t / "o", "--from", "model", "--to", "matches")


@case("--from model", "is not a folder", "without --from")
def stage_from_model_without_a_folder(t):
    return _args(*_pair(t), t / "o", "--from", "model")


@case("--from matches", "is not a folder", "--to matches", "without --from")
def stage_from_matches_without_a_folder(t):
    return _args(*_pair(t), t / "o", "--from", "matches")


@case("configuration A", "no configuration.json", "without --from")
def stage_from_model_without_configurations(t):
    (t / "o").mkdir()
    return _args(*_pair(t), t / "o", "--from", "model")


def _configuration_records(t: Path, out: Path, digests: dict | None = None, **changes) -> None:
    """Records of finished configurations in ``out/a`` and ``out/b`` (the rest of their folders
    absent: the check reads only the record), made with ``changes`` (``digests``: the
    ``inputs_digest`` of each, default one that matches no inputs)."""
    from artrecon import __version__
    from artrecon.configuration import FORMAT, stage_settings

    for c in ("a", "b"):
        record = {"format": FORMAT, "inputs_digest": "0" * 64, "artrecon_version": __version__,
                  "seed": 0, "cameras": "SfM from the images", "num_images": 6,
                  "image_dir": str((t / c).absolute()),
                  "settings": json.loads(json.dumps(stage_settings())), **changes}
        if digests is not None:
            record["inputs_digest"] = digests[c]
        (out / c).mkdir(parents=True)
        (out / c / "configuration.json").write_text(json.dumps(record))


@case("configuration A", "other inputs or settings", "seed 1 there, 0 now",
      "dense.downsample: 2 there, 1 now", "without --from")
def stage_from_model_of_other_settings(t):
    pair = _pair(t)
    _configuration_records(t, t / "o", seed=1)
    return _args(*pair, t / "o", "--from", "model", "--set", "dense.downsample=1")


@case("configuration A", "other inputs or settings", "the images' contents")
def stage_from_model_of_other_images(t):
    pair = _pair(t)
    _configuration_records(t, t / "o")
    return _args(*pair, t / "o", "--from", "model")


@case("--from model", "holds a model already", "--overwrite")
def stage_from_model_over_a_model(t):
    pair = _pair(t)
    _configuration_records(t, t / "o")
    (t / "o" / "model.json").write_text("{}")
    return _args(*pair, t / "o", "--from", "model")


@case("holds the configurations of a run stopped after them", "--to configurations",
      "--from matches", "--overwrite")
def stage_from_the_start_over_configurations(t):
    pair = _pair(t)
    _configuration_records(t, t / "o")
    return _args(*pair, t / "o")


def _finished_configurations(t: Path, out: Path) -> dict:
    """Records of finished configurations of the images ``t/a`` and ``t/b`` (default settings,
    seed 0) in ``out/a`` and ``out/b``, which the check of ``--from matches`` and ``--from
    model`` accepts (written once); returns their ``inputs_digest`` per configuration."""
    from artrecon.configuration import inputs_digest, stage_settings

    digests = {c: inputs_digest(io.load_image_folder(t / c), None, None, stage_settings(), 0)
               for c in ("a", "b")}
    if not (out / "a").exists():
        _configuration_records(t, out, digests=digests)
    return digests


def _matches_record(t: Path, out: Path, configurations: dict | None = None,
                    files: dict | None = None, **settings) -> None:
    """The matches stage's record in ``out/matches`` (its files: ``files``, name -> bytes;
    default a stand-in for each) as a run with the default settings changed by ``settings``
    (``stage.field``: value) and these configurations (default: those of
    :func:`_finished_configurations`) writes it."""
    import hashlib

    from artrecon import __version__
    from artrecon.matches_stage import FORMAT, match_settings, matches_digest
    from artrecon.settings import ReconstructConfig, with_settings

    configurations = configurations or _finished_configurations(t, out)
    made = match_settings(with_settings(ReconstructConfig(), settings))
    if files is None:
        names = ["object", "background", "candidates"]
        names += ["covariances"] if made["segmentation"]["covariances"] else []
        files = {f"{n}.npz": f"the {n}".encode() for n in names}
    (out / "matches").mkdir(parents=True)
    for name, data in files.items():
        (out / "matches" / name).write_bytes(data)
    record = {"format": FORMAT, "inputs_digest": matches_digest(configurations, made, 0),
              "configurations": configurations, "settings": made, "seed": 0,
              "artrecon_version": __version__,
              "files": {n: hashlib.sha256(d).hexdigest() for n, d in files.items()},
              "covariances": made["segmentation"]["covariances"], "timings": {"match": 1.0}}
    (out / "matches" / "matches.json").write_text(json.dumps(record))


@case("holds no finished matches stage", "no matches.json", "--from matches")
def stage_from_links_without_matches(t):
    pair = _pair(t)
    _finished_configurations(t, t / "o")
    return _args(*pair, t / "o", "--from", "links")


@case("the matches in", "other configurations or settings", "match.ratio: 0.8 there, 0.7 now",
      "not reused", "--from matches")
def stage_from_links_with_other_match_settings(t):
    pair = _pair(t)
    _matches_record(t, t / "o")
    return _args(*pair, t / "o", "--from", "links", "--set", "match.ratio=0.7")


@case("segmentation.covariances: True there, False now", "--from matches")
def stage_from_links_without_the_covariances_matched(t):
    pair = _pair(t)
    _matches_record(t, t / "o")
    return _args(*pair, t / "o", "--from", "links", "--set", "segmentation.covariances=0")


@case("configuration B is not the one they were matched in", "--from matches")
def stage_from_links_with_matches_of_other_configurations(t):
    pair = _pair(t)
    digests = _finished_configurations(t, t / "o")
    _matches_record(t, t / "o", configurations={**digests, "b": "0" * 64})
    return _args(*pair, t / "o", "--from", "links")


@case("the matches in", "are incomplete", "object.npz is missing", "--from matches")
def stage_from_links_with_a_matches_file_missing(t):
    pair = _pair(t)
    _matches_record(t, t / "o")
    (t / "o" / "matches" / "object.npz").unlink()
    return _args(*pair, t / "o", "--from", "links")


@case("are incomplete", "the record does not name the stage's files", "--from matches")
def stage_from_links_with_a_record_of_too_few_files(t):
    pair = _pair(t)
    _matches_record(t, t / "o", files={"object.npz": b"the object"})
    return _args(*pair, t / "o", "--from", "links")


@case("are incomplete", "object.npz is not the file the record names", "--from matches")
def stage_from_links_with_a_matches_file_changed(t):
    pair = _pair(t)
    _matches_record(t, t / "o")
    (t / "o" / "matches" / "object.npz").write_bytes(b"half of it")
    return _args(*pair, t / "o", "--from", "links")


@case("holds no finished links stage", "no links.json", "--from links")
def stage_from_joints_without_links(t):
    pair = _pair(t)
    _matches_record(t, t / "o")
    return _args(*pair, t / "o", "--from", "joints")


@case("--from joints comes after --to links", "nothing to run")
def stage_from_joints_after_to_links(t):
    return _args(*_pair(t), t / "o", "--from", "joints", "--to", "links")


@case("--from matches", "holds matches already", "--from links", "--overwrite")
def stage_from_matches_over_matches(t):
    pair = _pair(t)
    _matches_record(t, t / "o")
    return _args(*pair, t / "o", "--from", "matches")


@case("holds the configurations and matches of a run stopped after them", "--to matches",
      "--from links", "--overwrite")
def stage_from_the_start_over_matches(t):
    pair = _pair(t)
    _matches_record(t, t / "o")
    return _args(*pair, t / "o")


@pytest.mark.parametrize("name", sorted(CASES))
def test_reconstruct_refuses(tmp_path, capsys, monkeypatch, name):
    """Exit 2, a message naming the problem (and what to do), nothing written, nothing changed
    (every file under the test's folder hashed before and after; the working folder is there
    too)."""
    build, needles = CASES[name]
    argv = build(tmp_path)
    monkeypatch.chdir(tmp_path)
    code, err = refused(main, argv, capsys, tmp_path)
    assert code == 2, (code, err)
    assert err.startswith("artrecon: error: "), err
    assert all(n in err for n in needles), f"{needles} not all in: {err}"


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads every file")
def test_image_without_read_permission_is_named(tmp_path, capsys, monkeypatch):
    a, b = _pair(tmp_path)
    (b / "img_01.png").chmod(0)
    monkeypatch.chdir(tmp_path)
    code, err = refused(main, _args(a, b, tmp_path / "o"), capsys, tmp_path)
    assert code == 2 and "cannot read image" in err and "img_01.png" in err


def test_every_tunable_field_has_a_checked_range():
    """Every int, float, bool or text field of every stage config has a row in
    artrecon.settings.RANGES (so it can be set and is checked), every row names a field, and
    every default lies in its range."""
    from dataclasses import fields

    from artrecon.reconstruct import ReconstructConfig
    from artrecon.settings import RANGES, check_setting

    config = ReconstructConfig()
    tunable = {}
    for f in fields(config):
        for g in fields(getattr(config, f.name)):
            value = getattr(getattr(config, f.name), g.name)
            if isinstance(value, (bool, int, float, str)):
                tunable[f"{f.name}.{g.name}"] = value
    assert set(tunable) == set(RANGES), set(tunable) ^ set(RANGES)
    for key, default in tunable.items():
        assert check_setting(key, default, default) == default, key


def test_documented_float_setting_is_taken_from_the_command_line(tmp_path, capsys, monkeypatch):
    """--set joints.revolute_min_angle=0.1 (a documented numpy float field) was refused as 'a
    float64 field cannot be set here'; now the command gets past its settings to the next check
    (the same folder twice: nothing moved), with no word about the setting."""
    monkeypatch.chdir(tmp_path)
    a = write_images(tmp_path / "a")
    code, err = refused(main, _args(a, a, tmp_path / "o", "--set",
                                    "joints.revolute_min_angle=0.1"), capsys, tmp_path)
    assert code == 2 and "did not move" in err and "revolute_min_angle" not in err, err


def test_settings_that_were_refused_or_crashed_before(tmp_path):
    """joints.revolute_min_angle (a numpy float default) is settable; sfm.matching takes its
    choices; with_settings converts and keeps the kind."""
    from artrecon.reconstruct import ReconstructConfig, with_settings

    c = with_settings(ReconstructConfig(), {"joints.revolute_min_angle": 0.1,
                                            "sfm.matching": "exhaustive",
                                            "dense.downsample": 1.0, "guided.enabled": 0.0})
    assert c.joints.revolute_min_angle == 0.1 and c.sfm.matching == "exhaustive"
    assert c.dense.downsample == 1 and isinstance(c.dense.downsample, int)
    assert c.guided.enabled is False


def test_cli_runs_as_a_program_without_traceback(tmp_path):
    """The console entry point itself (a subprocess): message on stderr, exit 2, no traceback."""
    a = _write_images(tmp_path / "a")
    r = subprocess.run([sys.executable, "-m", "artrecon", "reconstruct", str(a), str(a),
                        "--out", str(tmp_path / "o")], capture_output=True, text=True,
                       cwd=REPO, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "did not move" in r.stderr


# --- two image sets that are not two configurations of one object ---------------------------


def test_same_folder_twice_is_refused(tmp_path):
    a = _write_images(tmp_path / "a")
    with pytest.raises(InputError, match="the object did not move"):
        reconstruct(a, a, out_dir=tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_copied_image_set_is_refused(tmp_path, capsys):
    """B is a copy of A under other file names: the same photos, so nothing moved."""
    a = _write_images(tmp_path / "a")
    b = tmp_path / "b" / "images"
    b.mkdir(parents=True)
    for i, p in enumerate(sorted(a.iterdir())):
        shutil.copy(p, b / f"copy_{i}.png")
    with pytest.raises(InputError, match=r"same images .*did not move"):
        reconstruct(a, tmp_path / "b")
    code, err = _cli(["reconstruct", str(a), str(tmp_path / "b"), "--out", str(tmp_path / "o")],
                     capsys)
    assert code == 2 and "did not move" in err


def test_some_shared_images_only_warn(tmp_path, caplog):
    a = _write_images(tmp_path / "a")
    b = _write_images(tmp_path / "b", seed=5)
    shutil.copy(a / "img_00.png", b / "img_99.png")
    io.check_distinct(io.load_image_folder(a), io.load_image_folder(b))  # no error
    assert "1 image(s)" in caplog.text and "byte-identical" in caplog.text


def test_an_image_set_loaded_earlier_is_taken_while_its_files_are_unchanged(tmp_path,
                                                                           monkeypatch):
    """reconstruct takes an ImageSet that load_image_folder gave earlier in the run (the
    evaluation's configuration stage, maybe in another process): its files are checked by their
    digests, not decoded again; a file changed, added or removed since loads the folder anew,
    with load_image_folder's checks (a corrupt image is named)."""
    a = _write_images(tmp_path / "a")
    first = io.load_image_folder(a)
    decoded = []
    real = cv2.imdecode
    monkeypatch.setattr(io.cv2, "imdecode", lambda *x: decoded.append(1) or real(*x))
    again = io.image_set_again(first)
    assert again == first and again.thumbnails is first.thumbnails and not decoded
    assert again.region is None
    # with a region (the poses' file adds it), the set comes back as load_image_folder gives it
    from dataclasses import replace
    assert io.image_set_again(replace(first, region=np.zeros((4, 3)))).region is None
    # one file's bytes changed: the folder is loaded anew (and decoded)
    img = cv2.imread(str(a / "img_01.png"))
    img[0, 0] = 255 - img[0, 0]
    cv2.imwrite(str(a / "img_01.png"), img)
    changed = io.image_set_again(first)
    assert len(decoded) == 6 and changed.digests != first.digests
    assert changed.digests == io.load_image_folder(a).digests
    # an image added, and one corrupt: the folder's own errors
    shutil.copy(a / "img_00.png", a / "img_77.png")
    assert io.image_set_again(first).names == first.names + ["img_77.png"]
    (a / "img_02.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="img_02.png"):
        io.image_set_again(first)


def test_matches_of_different_objects_are_called_so():
    """Matches that no rigid motion explains (chance pairings of two different objects) are
    reported as such; a real one-body motion keeps its own message."""
    from scipy.spatial.transform import Rotation

    from artrecon.diagnosis import explain_segmentation_failure
    from artrecon.errors import DegenerateError, SingleBodyError
    from artrecon.procrustes import Similarity
    from artrecon.segment import SegmentationConfig, segment_links

    rng = np.random.default_rng(0)
    pa = rng.uniform(-1, 1, (300, 3))
    chance = rng.uniform(-1, 1, (300, 3))  # B points unrelated to A's
    with pytest.raises(DegenerateError) as info:
        segment_links(pa, chance)
    err = explain_segmentation_failure(info.value, pa, chance, SegmentationConfig())
    assert isinstance(err, ReconstructionError) and "same object" in str(err)
    assert "no consistent link" in str(err) and "of the 300 matches" in str(err)
    rigid = Similarity(Rotation.from_rotvec([0.3, 0.1, 0]).as_matrix(), np.ones(3), 1.0)
    pb = rigid.apply(pa) + 1e-3 * rng.normal(size=pa.shape)
    with pytest.raises(SingleBodyError) as info:
        segment_links(pa, pb)
    assert explain_segmentation_failure(info.value, pa, pb, SegmentationConfig()) is info.value


def test_nothing_moved_is_told_from_the_matches_first():
    """check_motion, before segmentation: matches that fit the room's motion (up to wrong
    matches that fit nothing together) are 'nothing moved'; the whole object moved against the
    room is 'one rigid body'; a real joint, or too few room matches, passes. Either verdict
    gives way to 'not the same object' when few of the object's points have a match."""
    from scipy.spatial.transform import Rotation
    from synthetic import make_object

    from artrecon.diagnosis import check_motion
    from artrecon.errors import NoMotionError, SingleBodyError
    from artrecon.procrustes import Similarity
    from artrecon.segment import SegmentationConfig

    obj = make_object(0, "pair", ("revolute",), points_per_link=150, noise=0.002)
    rng = np.random.default_rng(0)
    frame = Similarity(Rotation.from_rotvec([0.2, -0.4, 0.1]).as_matrix(),
                       np.array([0.3, 1.0, -2.0]), 1.7)  # B's SfM frame against A's
    room_a = rng.uniform(-6, 6, (300, 3))
    room_b = frame.apply(room_a) + 0.01 * rng.normal(size=room_a.shape)
    pa, cfg = obj.points_a, SegmentationConfig()
    wrong = rng.choice(len(pa), 80, replace=False)

    def with_wrong(pb):
        pb = pb.copy()
        pb[wrong] = rng.uniform(pb.min(0), pb.max(0), (len(wrong), 3))
        return pb

    still = with_wrong(frame.apply(pa) + 0.002 * rng.normal(size=pa.shape))
    with pytest.raises(NoMotionError, match="^nothing moved between A and B: 3.. of the 450"):
        check_motion(pa, still, room_a, room_b, cfg)
    turn = Similarity(Rotation.from_rotvec([0, 0, 0.5]).as_matrix(), np.array([0.2, 0, 0]), 1.0)
    with pytest.raises(SingleBodyError, match="^the whole object moved as one rigid body"):
        check_motion(pa, frame.apply(turn.apply(pa)), room_a, room_b, cfg)
    base = obj.link_motions[obj.joints[0].parent]  # the room moves with the base
    moved = np.empty_like(pa)
    for k in range(int(obj.labels.max()) + 1):
        m = obj.labels == k
        moved[m] = frame.apply(base.inverse().apply(obj.link_motions[k].apply(pa[m])))
    check_motion(pa, with_wrong(moved), room_a, room_b, cfg)  # a joint moved: no error
    check_motion(pa, still, room_a[:10], room_b[:10], cfg)  # too few room matches: no verdict
    # the same matches, but a tiny share of B's points on the object has a partner: not the
    # same object (chance pairings and the static table fit the room's motion by being static)
    with pytest.raises(NoMotionError, match="^nothing moved"):  # 450 of 900: the same object
        check_motion(pa, still, room_a, room_b, cfg, object_points=(600, 900))
    for pb, verdict in ((still, "nothing moved"), (frame.apply(turn.apply(pa)), "one rigid body")):
        with pytest.raises(ReconstructionError) as info:
            check_motion(pa, pb, room_a, room_b, cfg, object_points=(600, 20000))
        msg = str(info.value)
        assert not isinstance(info.value, NoMotionError | SingleBodyError), msg
        assert msg.startswith("no consistent link") and "does not look like A's" in msg, msg
        assert "2.2% of B's 20000" in msg and "75.0% of A's 600" in msg and verdict in msg, msg
        assert "same object" in msg, msg


def _render(folder: Path, parts, poses) -> None:
    """Render quads from OpenCV camera poses into folder/images, with cameras.json (a capture)."""
    import json

    import pyrender

    from sim.camera import convert_camera_pose

    scene = rf._pyrender_scene(parts)
    cam = pyrender.IntrinsicsCamera(fx=rf.K[0, 0], fy=rf.K[1, 1], cx=rf.K[0, 2] + 0.5,
                                    cy=rf.K[1, 2] + 0.5, znear=0.02, zfar=5.0)
    node = scene.add(cam, pose=np.eye(4))
    (folder / "images").mkdir(parents=True, exist_ok=True)
    items = []
    for i, T in enumerate(poses):
        scene.set_pose(node, convert_camera_pose(T))
        color, _ = rf._renderer().render(scene, flags=pyrender.RenderFlags.FLAT)
        name = f"view_{i:03d}.png"
        cv2.imwrite(str(folder / "images" / name), color[:, :, ::-1])
        items.append({"name": name, "T_world_camera": T.tolist()})
    (folder / "cameras.json").write_text(json.dumps(
        {"K": rf.K.tolist(), "width": rf.WIDTH, "height": rf.HEIGHT, "images": items}))


#: One ring of 18 views (20 degrees apart, the widest spacing the dense stage pairs) per set:
#: half the fixture's views, so the run (SfM + dense of both sets) stays short.
OTHER_OBJECT_RING = 18


@pytest.mark.slow
def test_two_different_objects_are_refused(tmp_path):
    """A: the hinge fixture; B: another object (its own textures) in the same room. No link can
    be found across them; the run says so instead of returning a model. (A whole run up to the
    segmentation: SfM and dense points of both sets, known poses.) The 50 matches on the object
    fit the room's motion (A's object region is mostly the table behind the box), which read as
    'nothing moved' until the share of the object's points that match was checked: 51 of B's
    4281 (1.2%) when this was written."""
    poses = rf.ring_poses(OTHER_OBJECT_RING, heights=(0.4,))
    room = [p for p in rf.build_parts("b", seed=0) if not p.is_object]
    hinge = [p for p in rf.build_parts("a", seed=0) if p.is_object]
    other = [p for p in rf.build_parts("b", seed=11) if p.is_object]  # other textures
    _render(tmp_path / "hinge", hinge + room, poses)
    _render(tmp_path / "other", other + room, poses)
    with pytest.raises(ReconstructionError) as info:
        reconstruct(tmp_path / "hinge", tmp_path / "other", poses=True,
                    out_dir=tmp_path / "o", progress=False)
    msg = str(info.value)
    print(type(info.value).__name__, msg)
    assert "no consistent link" in msg and "same object" in msg
    assert not isinstance(info.value, NoMotionError) and "does not look like A's" in msg
    assert not (tmp_path / "o").exists() and not list(tmp_path.glob(".o.tmp-*"))
def test_reencoded_copy_of_the_fixture_is_told_nothing_moved_at_once(rendered, tmp_path, capsys):
    """B = A's rendered images re-encoded as JPEG: other bytes, the same pictures. Before, SfM
    ran on both (55 s) and the run failed as 'chance pairings'; now the images are compared
    first (no SfM) and the message says nothing moved."""
    b = tmp_path / "b"
    b.mkdir()
    for name in rendered["a"].names:
        img = cv2.imread(str(rendered["a"].folder / "images" / name))
        cv2.imwrite(str(b / (Path(name).stem + ".jpg")), img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    code, err = refused(main, _args(rendered["a"].folder, b, tmp_path / "o"), capsys, tmp_path,
                        rendered["a"].folder)
    assert code == 2 and err.startswith("artrecon: error: nothing moved between A and B"), err
    # a real motion between A and B is not taken for a copy
    sa, sb = io.load_image_folder(rendered["a"].folder), io.load_image_folder(rendered["b"].folder)
    assert io.near_twins(sa, sb) == [] and io.near_twins(sb, sa) == []


@pytest.mark.slow
def test_same_configuration_from_other_views_is_told_nothing_moved(tmp_path):
    """A and B both show the hinge in configuration A, B from cameras half a step further round
    the ring (no image alike): the matches fit one motion, the room's, so the run says first and
    plainly that nothing moved (before: 'chance pairings', the cause at the end of the message)."""
    from artrecon.errors import NoMotionError

    poses = rf.ring_poses(OTHER_OBJECT_RING, heights=(0.4,))
    half_step = rf.rotation_about([0.0, 0.0, 1.0], np.pi / OTHER_OBJECT_RING)
    turned = poses.copy()
    turned[:, :3, :3] = half_step @ poses[:, :3, :3]
    turned[:, :3, 3] = poses[:, :3, 3] @ half_step.T
    parts = rf.build_parts("a", seed=0)
    _render(tmp_path / "a", parts, poses)
    _render(tmp_path / "b", parts, turned)
    with pytest.raises(NoMotionError) as info:
        reconstruct(tmp_path / "a", tmp_path / "b", poses=True, out_dir=tmp_path / "o",
                    progress=False)
    msg = str(info.value)
    print(msg)
    assert msg.startswith("nothing moved between A and B") and "the motion of the room" in msg
    assert not (tmp_path / "o").exists()


# --- interrupted runs and whole-or-nothing results --------------------------------------------


def _start_run(a: Path, b: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "artrecon", "reconstruct", str(a), str(b),
                             "--out", str(out), "--quiet"], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _wait_for_work_dir(out: Path, proc: subprocess.Popen, timeout: float = 120.0) -> Path:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        found = [p for p in out.parent.glob(f".{out.name}.tmp-{proc.pid}-*")
                 if (p / "a").is_dir()]
        if found:
            return found[0]
        if proc.poll() is not None:
            raise AssertionError(f"the run ended early: {proc.stderr.read().decode()}")
        time.sleep(0.1)
    raise AssertionError("the run made no work folder")


def test_killed_run_leaves_no_result_and_the_next_run_starts_clean(tmp_path):
    a = _write_images(tmp_path / "a", n=8, size=(160, 120), seed=1)
    b = _write_images(tmp_path / "b", n=8, size=(160, 120), seed=2)
    out = tmp_path / "out"
    first = _start_run(a, b, out)
    stale = _wait_for_work_dir(out, first)
    first.send_signal(signal.SIGKILL)
    first.wait(timeout=60)
    assert not out.exists()  # no half-written result under the output name
    assert stale.exists()  # only the hidden work folder of the dead run
    second = _start_run(a, b, out)
    try:
        _wait_for_work_dir(out, second)
        assert not stale.exists()  # the next run removed it before starting
    finally:
        second.send_signal(signal.SIGKILL)
        second.wait(timeout=60)
    assert not out.exists()


def test_work_dirs_of_live_runs_are_kept(tmp_path):
    out = tmp_path / "out"
    mine = files.make_work_dir(out)
    dead = tmp_path / ".out.tmp-999999999-abc"  # no such process
    dead.mkdir()
    (dead / "model.json").write_text("{half")
    other = files.make_work_dir(out)  # a second run starting while the first is alive
    assert mine.is_dir() and other.is_dir() and not dead.exists()
    assert (tmp_path / "unrelated.tmp-1").mkdir() is None
    files.remove_stale_work_dirs(out)
    assert (tmp_path / "unrelated.tmp-1").is_dir()


def test_publish_replaces_a_result_whole(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "model.json").write_text("old")
    work = files.make_work_dir(out)
    (work / "model.json").write_text("new")
    files.publish_dir(work, out)
    assert (out / "model.json").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_model_save_failure_keeps_the_old_file(tmp_path):
    from artrecon.model import ArticulatedModel, Link

    model = ArticulatedModel([Link(np.zeros((3, 3)), [-1] * 3)], [])
    path = model.save(tmp_path / "model.json")
    before = path.read_text()
    model.metadata["bad"] = object()  # not JSON: serialisation fails
    with pytest.raises(TypeError):
        model.save(path)
    assert path.read_text() == before and [p.name for p in tmp_path.iterdir()] == ["model.json"]


def test_evaluation_cache_ignores_and_removes_a_killed_build(tmp_path):
    from sim import cache

    inputs = {"x": 1}
    key = cache.stage_key("capture_a", inputs)
    killed = tmp_path / f".{key}.tmp-999999999-abc"  # what a SIGKILL during build leaves
    older = tmp_path / f".{key}.abc123.tmp"  # the same, before work folders carried a pid
    live = tmp_path / f".{key}.tmp-{os.getppid()}-abc"  # a concurrent run, building now
    for d in (killed, older, live):
        d.mkdir(parents=True)
        (d / "half.png").write_bytes(b"\x89PNG")
    built = []

    def build(folder):
        built.append(folder)
        (folder / "data.txt").write_text("whole")
        return {}

    folder, _, hit = cache.cached_stage(tmp_path, "capture_a", inputs, build)
    assert not hit and built and (folder / "data.txt").read_text() == "whole"
    assert not killed.exists() and not older.exists()
    assert (live / "half.png").is_file()  # another live run's files are not removed under it


def test_evaluation_cache_keeps_a_concurrent_runs_finished_stage(tmp_path, monkeypatch):
    """Two runs building the same stage at once where the file system gives no lock (where
    there is one, the second run waits and finds the first's folder): the second to finish
    keeps the first's folder and throws its own work folder away (same inputs, same result),
    leaving no work folder."""
    import contextlib

    from sim import cache

    monkeypatch.setattr(cache, "_stage_lock", lambda path: contextlib.nullcontext())
    inputs = {"x": 2}

    def build(folder):
        # the other run finishes while this one builds
        cache.cached_stage(tmp_path, "capture_a", inputs,
                           lambda f: (f / "data.txt").write_text("first") and {})
        (folder / "data.txt").write_text("second")
        return {}

    folder, _, hit = cache.cached_stage(tmp_path, "capture_a", inputs, build)
    assert hit and (folder / "data.txt").read_text() == "first"
    assert [p.name for p in tmp_path.iterdir()] == [folder.name]


def test_results_json_is_replaced_whole_or_not_at_all(tmp_path):
    from sim import cache

    path = cache.write_json_atomic(tmp_path / "results.json", {"scenes": {"a": 1}})
    with pytest.raises(ValueError):
        cache.write_json_atomic(path, {"scenes": {"a": float("nan")}})  # fails mid-write
    assert path.read_text().startswith('{\n  "scenes"') and "NaN" not in path.read_text()
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


# --- scene files ------------------------------------------------------------------------------


def test_evaluate_cli_reports_a_broken_scene_without_traceback(tmp_path, capsys):
    from sim import evaluate

    bad = tmp_path / "broken.xml"
    bad.write_text("<mujoco><worldbody><body name='x'><geom type='box'/></body>")  # unclosed
    assert evaluate.main([str(bad), "--validate-only"]) == 1
    err = capsys.readouterr().err
    assert "BAD" in err and str(bad) in err and "Traceback" not in err


def test_os_errors_writing_the_output_are_reported(tmp_path, capsys):
    a, b = _write_images(tmp_path / "a"), _write_images(tmp_path / "b", seed=1)
    (tmp_path / "file").write_text("a file where the output's parent folder should be")
    code, err = _cli(["reconstruct", str(a), str(b), "--out", str(tmp_path / "file" / "o")],
                     capsys)
    assert code == 2 and "nothing was written" in err and "file" in err


def test_guided_matching_prints_no_numpy_warning():
    """An A point with no B point near where a link's motion puts it made numpy print
    'RuntimeWarning: invalid value encountered in subtract' in every run's output; it is simply
    not matched, and a point with one clear candidate is."""
    import warnings

    from artrecon.features import PointDescriptors, guided_matches
    from artrecon.procrustes import Similarity

    rng = np.random.default_rng(0)
    desc = rng.normal(size=(3, 128)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    a = PointDescriptors(np.arange(2), np.array([[0.0, 0, 0], [5.0, 5, 5]]), desc[:2])
    b = PointDescriptors(np.arange(2), np.array([[0.01, 0, 0], [-3.0, 0, 0]]), desc[[0, 2]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ia, ib, link = guided_matches([Similarity(np.eye(3), np.zeros(3), 1.0)], [0.1], a, b)
    assert ia.tolist() == [0] and ib.tolist() == [0] and link.tolist() == [0]
