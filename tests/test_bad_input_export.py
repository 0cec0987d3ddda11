"""``artrecon export``: bad model files and output paths are refused with a clear message, exit 2,
and nothing is written or changed (never the model file, never a file the export did not write,
unless --overwrite); the library's writers are whole or not at all (test_export.py)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from badinput import case_registry, refused, tree
from test_export import synthetic_model

from artrecon.cli import main


def _model(t, **changes):
    """A valid model file (a synthetic hinge) at t/m/model.json, optionally edited as a dict."""
    _, model = synthetic_model(3, "pair", ("revolute",), 0.5, True)
    model.frames["T_world_model"] = np.eye(4)
    path = model.save(t / "m" / "model.json")
    if changes:
        d = json.loads(path.read_text())
        for key, value in changes.items():
            if value is None:
                del d[key]
            else:
                d[key] = value
        path.write_text(json.dumps(d))
    return path


def _export(model, fmt, out, *extra):
    return ["export", str(model), "--format", fmt, "--out", str(out), *extra]


CASES, case = case_registry()


# model files
@case("does not exist", "run the reconstruction first")
def model_missing(t):
    return _export(t / "nope.json", "mjcf", t / "t.xml")


@case("is a folder", "model.json")
def model_is_a_folder(t):
    return _export(_model(t).parent, "mjcf", t / "t.xml")


@case("is not valid JSON")
def model_not_json(t):
    (t / "model.json").write_text('{"format": "artrecon.ArticulatedModel", "links": [')
    return _export(t / "model.json", "urdf", t / "t.urdf")


@case("is not valid JSON")
def model_binary(t):
    (t / "model.json").write_bytes(bytes(range(256)))
    return _export(t / "model.json", "urdf", t / "t.urdf")


@case("holds a list", "model.json a reconstruction wrote")
def model_top_level_list(t):
    (t / "model.json").write_text("[1, 2, 3]")
    return _export(t / "model.json", "mjcf", t / "t.xml")


@case("missing key 'links'", "damaged")
def model_without_links(t):
    return _export(_model(t, links=None), "mjcf", t / "t.xml")


@case("links[0] is malformed", "cannot reshape")
def model_with_a_bad_array(t):
    path = _model(t)
    d = json.loads(path.read_text())
    d["links"][0]["points"]["data"] = [1.0, 2.0]
    path.write_text(json.dumps(d))
    return _export(path, "glb", t / "t.glb")


@case("format version 7", "newer artrecon", "upgrade artrecon")
def model_of_a_future_version(t):
    return _export(_model(t, version=7), "mjcf", t / "t.xml")


@case("not an artrecon articulated model")
def model_of_another_format(t):
    return _export(_model(t, format="something.else"), "mjcf", t / "t.xml")


@case("model.json: the points of link(s) [1] hold non-finite", "reconstruct again")
def model_with_nan_points(t):
    path = _model(t)
    d = json.loads(path.read_text())
    d["links"][1]["points"]["data"][4] = float("nan")
    path.write_text(json.dumps(d))
    return _export(path, "mjcf", t / "t.xml")


@case("has no frame 'T_robot'")
def unknown_base_frame(t):
    return _export(_model(t), "urdf", t / "t.urdf", "--base-frame", "T_robot")


# settings of the export
@case("voxel_size must be > 0")
def voxel_size_negative(t):
    return _export(_model(t), "mjcf", t / "t.xml", "--voxel-size=-0.01")


@case("density must be > 0")
def density_nan(t):
    return _export(_model(t), "mjcf", t / "t.xml", "--density", "nan")


@case("collision_clusters must be >= 1")
def no_collision_clusters(t):
    return _export(_model(t), "mjcf", t / "t.xml", "--collision-clusters", "0")


# output paths
@case("is the model file being exported", "destroy the model")
def out_is_the_model(t):
    path = _model(t)
    return _export(path, "urdf", path)


@case("is the model file being exported")
def out_is_a_link_to_the_model(t):
    path = _model(t)
    (t / "twin.urdf").symlink_to(path)
    return _export(path, "urdf", t / "twin.urdf", "--overwrite")


@case("exists; nothing was written", "--overwrite")
def out_file_exists(t):
    (t / "t.glb").write_bytes(b"a file the export did not write")
    return _export(_model(t), "glb", t / "t.glb")


@case("is a folder; name the MJCF file", "twin.xml")
def out_names_a_folder(t):
    (t / "out").mkdir()
    return _export(_model(t), "mjcf", t / "out")


@case("is a file; PLY export writes one file per link into a folder")
def ply_out_is_a_file(t):
    (t / "ply").write_text("a file")
    return _export(_model(t), "ply", t / "ply")


@case("exist(s) already; nothing was written", "link_0_visual.stl")
def a_mesh_of_another_twin_exists(t):
    (t / "t_meshes").mkdir()
    (t / "t_meshes" / "link_0_visual.stl").write_bytes(b"another twin's mesh")
    return _export(_model(t), "mjcf", t / "t.xml")


@case("exist(s) already", "link_1.ply")
def a_ply_of_another_model_exists(t):
    (t / "ply").mkdir()
    (t / "ply" / "link_1.ply").write_bytes(b"another model's points")
    return _export(_model(t), "ply", t / "ply")


@pytest.mark.parametrize("name", sorted(CASES))
def test_export_refuses(tmp_path, capsys, monkeypatch, name):
    """Exit 2, the problem named, nothing written or changed under the test's folder (the model
    file included; hashed before and after)."""
    build, needles = CASES[name]
    argv = build(tmp_path)
    monkeypatch.chdir(tmp_path)
    code, err = refused(main, argv, capsys, tmp_path)
    assert code == 2, (code, err)
    assert err.startswith("artrecon export: error: "), err
    assert all(n in err for n in needles), f"{needles} not all in: {err}"


def test_overwrite_replaces_whole_and_never_the_model(tmp_path, capsys):
    """With --overwrite an export replaces its earlier files (all of them, whole); the model
    file is never written, --overwrite or not; files of another stem are left alone."""
    path = _model(tmp_path)
    out = tmp_path / "t.xml"
    assert main(_export(path, "mjcf", out, "--voxel-size", "0.02")) == 0
    first = tree(tmp_path)
    (tmp_path / "keep.txt").write_text("the user's")
    assert main(_export(path, "mjcf", out, "--voxel-size", "0.03")) == 2  # no --overwrite
    assert tree(tmp_path) == {**first, **tree(tmp_path / "keep.txt")}
    assert main(_export(path, "mjcf", out, "--voxel-size", "0.03", "--overwrite")) == 0
    second = tree(tmp_path)
    assert second[str(path)] == first[str(path)] and second[str(out)] != first[str(out)]
    assert (tmp_path / "keep.txt").read_text() == "the user's"
    assert not [p for p in tmp_path.rglob(".*.tmp")]
    code = main(_export(path, "ply", path.parent, "--overwrite"))  # beside the model: fine
    assert code == 0 and tree(path) == {str(path): first[str(path)]}
    capsys.readouterr()


def test_export_ctrl_c_is_one_line(tmp_path, capsys, monkeypatch):
    """Ctrl-C during an export: one line, exit 130, nothing written."""
    from artrecon.export import cli as export_cli

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    path = _model(tmp_path)
    monkeypatch.setattr(export_cli, "export_model", interrupted)
    code, err = refused(main, _export(path, "mjcf", tmp_path / "t.xml"), capsys, tmp_path)
    assert code == 130 and err.count("\n") == 1 and "interrupted" in err


@pytest.mark.skipif(not hasattr(os, "link"), reason="no hard links")
def test_export_never_writes_over_a_hard_link_to_its_model(tmp_path, capsys):
    path = _model(tmp_path)
    os.link(path, tmp_path / "twin.urdf")
    code, err = refused(main, _export(path, "urdf", tmp_path / "twin.urdf", "--overwrite"),
                        capsys, tmp_path)
    assert code == 2 and "is the model file being exported" in err


def test_library_writer_given_a_folder_leaves_no_temporary(tmp_path):
    """``--out`` naming a folder left a 159 kB ``.partial`` file beside it; the library's
    writers check every target before putting any in place and remove their temporaries."""
    from artrecon import export as ex
    from artrecon.errors import InputError
    from artrecon.model import ArticulatedModel

    model = ArticulatedModel.load(_model(tmp_path))
    (tmp_path / "out").mkdir()
    before = tree(tmp_path)
    with pytest.raises(InputError, match="is a folder, where a file would be written"):
        ex.export_glb(model, tmp_path / "out")
    assert tree(tmp_path) == before
