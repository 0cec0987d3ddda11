"""The per-configuration stage (artrecon.configuration): its folder is a contract that a later
run starts from, whole or recomputed, and the two configurations side by side give the same
model as one after the other."""

from __future__ import annotations

import json

import numpy as np
import pytest

from artrecon.configuration import (
    inputs_digest,
    load_configuration,
    reconstruct_configuration,
)
from artrecon.errors import ReconstructionError
from artrecon.io import load_cameras_json, load_image_folder
from artrecon.reconstruct import reconstruct


@pytest.fixture(scope="module")
def stage_a(rendered, tmp_path_factory):
    """Configuration A of the rendered hinge through the stage, with its known poses."""
    iset = load_image_folder(rendered["a"].folder)
    intr, poses = load_cameras_json(iset.cameras_file)
    out = tmp_path_factory.mktemp("conf") / "a"
    conf = reconstruct_configuration(iset, out, intr, poses, which="A")
    return iset, intr, poses, out, conf


def test_the_folder_holds_the_contract(stage_a):
    *_, out, conf = stage_a
    for name in ("database.db", "sparse/0", "dense.ply", "dense_views.npz", "region.npz",
                 "configuration.json"):
        assert (out / name).exists(), name
    record = json.loads((out / "configuration.json").read_text())
    assert record["format"] == "artrecon-configuration/1"
    assert record["registered_images"] == record["num_images"] > 0
    assert record["dense_points"] == len(conf.dense) > 100
    assert record["pose_agreement"]["epipolar_median_px"] < 0.45  # the known poses are right


def test_a_folder_reads_back_as_it_was_written(stage_a):
    *_, out, conf = stage_a
    back = load_configuration(out)
    np.testing.assert_array_equal(back.dense.points, conf.dense.points)
    np.testing.assert_array_equal(back.dense.normals, conf.dense.normals)
    np.testing.assert_array_equal(back.dense.colors, conf.dense.colors)
    np.testing.assert_array_equal(back.dense.visibility, conf.dense.visibility)
    np.testing.assert_array_equal(back.occluders, conf.occluders)
    assert back.object_ids == conf.object_ids and back.background_ids == conf.background_ids
    assert back.sfm.reconstruction.num_points3D() == conf.sfm.reconstruction.num_points3D()
    assert back.record == conf.record


def test_same_inputs_reuse_the_folder_other_settings_recompute(stage_a):
    iset, intr, poses, out, conf = stage_a
    db_time = (out / "database.db").stat().st_mtime_ns
    again = reconstruct_configuration(iset, out, intr, poses, which="A")
    assert (out / "database.db").stat().st_mtime_ns == db_time  # nothing recomputed
    np.testing.assert_array_equal(again.dense.points, conf.dense.points)
    settings = {"sfm": {}, "dense": {}, "region": {}}
    assert inputs_digest(iset, intr, poses, settings, 0) != inputs_digest(iset, intr, poses,
                                                                           settings, 1)


def test_an_interrupted_folder_is_refused_by_name(tmp_path):
    (tmp_path / "sparse").mkdir()
    with pytest.raises(ReconstructionError, match="no finished configuration stage"):
        load_configuration(tmp_path)


def test_the_record_names_its_images_absolutely_and_a_lost_folder_is_refused(
        stage_a, tmp_path, monkeypatch):
    """A folder read from another working directory still finds its images (the record's path
    was relative to the run's working directory once, and the labelling then went on without
    the images' evidence); images gone since are named, not skipped."""
    import shutil
    from pathlib import Path

    iset, *_, out, _ = stage_a
    record = json.loads((out / "configuration.json").read_text())
    assert Path(record["image_dir"]).is_absolute()
    assert Path(record["image_dir"]) == iset.image_dir.absolute()
    monkeypatch.chdir(tmp_path)
    assert load_configuration(out).sfm.image_dir == iset.image_dir.absolute()
    moved = tmp_path / "moved"
    shutil.copytree(out, moved)
    data = json.loads((moved / "configuration.json").read_text())
    data["image_dir"] = str(tmp_path / "nowhere")
    (moved / "configuration.json").write_text(json.dumps(data))
    with pytest.raises(ReconstructionError, match="not a folder now"):
        load_configuration(moved)


def _without_timings(path):
    d = json.loads(path.read_text())
    d["metadata"].pop("timings")
    return d


def test_side_by_side_equals_one_after_the_other_and_folders_are_reused(
        rendered, reconstruction_poses, tmp_path):
    """jobs=2 (B in a second process: the shared run) and jobs=1 give the same model, bit for
    bit: the same inputs and seed give the same model.json apart from its timings and the same
    link point files byte for byte, whichever process a configuration ran in; a run given the
    finished per-configuration folders reuses them and gives the model again."""
    a, b = rendered["a"].folder, rendered["b"].folder
    m2, shared = reconstruction_poses  # reconstruct's default, jobs=2
    one = tmp_path / "one"
    m1 = reconstruct(a, b, poses=True, out_dir=one, progress=False, jobs=1)
    assert _without_timings(one / "model.json") == _without_timings(shared / "model.json")
    links = sorted(p.name for p in (shared / "links").iterdir())
    assert sorted(p.name for p in (one / "links").iterdir()) == links
    assert any(name.endswith(".ply") for name in links)
    for name in links:  # but the links stage's record (its timings)
        if name != "links.json":
            assert (one / "links" / name).read_bytes() == (shared / "links" / name).read_bytes()
    m3 = reconstruct(a, b, poses=True, out_dir=tmp_path / "reuse", progress=False,
                     configurations=(shared / "a", shared / "b"))
    for other in (m1, m3):
        assert len(other.joints) == len(m2.joints) == 1
        np.testing.assert_allclose(other.joints[0].axis_direction, m2.joints[0].axis_direction,
                                   atol=1e-9)
        np.testing.assert_allclose(other.joints[0].axis_point, m2.joints[0].axis_point,
                                   atol=1e-9)
