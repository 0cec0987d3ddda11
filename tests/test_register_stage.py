"""The registration stage (artrecon.register.stage, ``artrecon register``) on a real
reconstruction: the rendered hinge reconstructed from its images alone (arbitrary scale and
frame), registered by its capture's camera poses and by PnP of a fresh view that no image set
holds; both against the rendering's true camera poses."""

from __future__ import annotations

import json

import numpy as np
import pytest
import render_fixture as rf

from artrecon.errors import InputError, RegistrationMismatchError
from artrecon.model import ArticulatedModel
from artrecon.register import FreshImage, register, true_registration_error
from artrecon.register.cli import run_command
from artrecon.register.stage import read_pose_file

#: A view between the two capture rings (heights 0.28 and 0.50 m, radius 0.5 m), at an azimuth
#: no capture image has.
FRESH_EYE = (0.5 * np.cos(0.3), 0.5 * np.sin(0.3), 0.39)


@pytest.fixture(scope="module")
def fresh_view(rendered, tmp_path_factory):
    T = rf.look_at(FRESH_EYE)
    path = rf.render_view(tmp_path_factory.mktemp("fresh") / "fresh.png", "a", T)
    return path, T


def _truth(model_dir, rendered):
    """The true model-to-world similarity: the SfM camera centres against the true ones."""
    S, err = rf.align_to_truth(model_dir / "a" / "sparse" / "0", rendered["a"])
    assert np.median(err) < 2e-3
    return S


def _points(model_dir):
    model = ArticulatedModel.load(model_dir / "model.json")
    return np.concatenate([lk.points for lk in model.links if len(lk.points)])


def test_camera_poses_route(reconstruction_sfm, rendered, tmp_path):
    model, model_dir = reconstruction_sfm
    out = tmp_path / "reg"
    res = register(model_dir, camera_poses=rendered["a"].folder / "cameras.json", out_dir=out)
    assert res.route == "camera_centres"
    err = true_registration_error(res.T_robot_model, _truth(model_dir, rendered),
                                  _points(model_dir))
    assert err["rotation_deg"] < 0.1 and err["translation_mm"] < 1.0, err
    assert err["scale_percent"] < 0.2, err
    # whole: the registered model (metric, robot frame) and the report
    reg = ArticulatedModel.load(out / "model.json")
    assert reg.scale_known and reg.metadata["registration"]["route"] == "camera_centres"
    report = json.loads((out / "registration.json").read_text())
    rep = report["routes"]["camera_centres"]
    assert rep["inliers"] == rep["cameras"] == len(rendered["a"].names)
    assert rep["rms_mm"] < 2.0
    # the registered joint is the true hinge, in metres
    true = rf.true_hinge()
    (j,) = reg.joints
    ang, dist = rf.axis_errors(j.axis_direction, j.axis_point, true["axis_direction"],
                               true["axis_point"])
    assert ang < 1.0 and dist < 3e-3, (ang, dist)
    # an existing output is not replaced without asking
    with pytest.raises(InputError, match="exists"):
        register(model_dir, camera_poses=rendered["a"].folder / "cameras.json", out_dir=out)


def test_pnp_route_on_a_fresh_view_checks_route_a(reconstruction_sfm, rendered, fresh_view,
                                                  tmp_path):
    """Route (b) from a view that no image set holds, its camera pose known (the arm's FK with
    the mount), the scale from route (a): within the PnP gate of the true registration, and the
    two routes' agreement recorded."""
    _, model_dir = reconstruction_sfm
    path, T = fresh_view
    names = {p.name for p in (rendered["a"].folder / "images").iterdir()}
    assert path.name not in names
    res = register(model_dir, camera_poses=rendered["a"].folder / "cameras.json",
                   images=[FreshImage(path, T_world_camera=T)], out_dir=False)
    assert set(res.routes) == {"camera_centres", "pnp"}
    pnp = res.routes["pnp"]
    (im,) = pnp["report"]["images"]
    assert im["inliers"] >= 30 and im["reprojection_rms_px"] < 1.5, im
    err = true_registration_error(pnp["T"], _truth(model_dir, rendered), _points(model_dir))
    assert err["rotation_deg"] < 0.5 and err["translation_mm"] < 3.0, err
    assert res.agreement["comparison"]["translation_mm"] < 3.0


def test_routes_that_disagree_are_refused(reconstruction_sfm, rendered, fresh_view):
    """The fresh view's pose 3 cm and 3 degrees off (a mount or joint reading error): the two
    routes put the model centimetres apart, and the stage refuses instead of answering."""
    from artrecon.geometry import rotation_about

    _, model_dir = reconstruction_sfm
    path, T = fresh_view
    bad = T.copy()
    bad[:3, :3] = rotation_about(np.array([1.0, 0, 0]), np.deg2rad(3.0)) @ bad[:3, :3]
    bad[:3, 3] += [0.03, 0.0, 0.0]
    with pytest.raises(RegistrationMismatchError):
        register(model_dir, camera_poses=rendered["a"].folder / "cameras.json",
                 images=[FreshImage(path, T_world_camera=bad)], out_dir=False)


def test_bad_inputs_are_named(reconstruction_sfm, rendered, tmp_path):
    _, model_dir = reconstruction_sfm
    with pytest.raises(InputError, match="nothing to register"):
        register(model_dir, out_dir=False)
    with pytest.raises(InputError, match="model.json"):
        register(tmp_path, camera_poses=rendered["a"].folder / "cameras.json", out_dir=False)
    bad = tmp_path / "poses.json"
    bad.write_text(json.dumps({"images": [{"file": "x.png", "T_world_camera": [[1, 0], [0, 1]]}]}))
    with pytest.raises(InputError, match="4x4"):
        read_pose_file(bad)
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"images": [{"file": "nope.png", "T_world_camera": np.eye(4)
                                             .tolist()}]}))
    with pytest.raises(InputError, match="only 0 images"):
        register(model_dir, camera_poses=other, out_dir=False)
    with pytest.raises(InputError, match="does not exist"):
        register(model_dir, camera_poses=rendered["a"].folder / "cameras.json",
                 images=[FreshImage(tmp_path / "missing.png", T_world_camera=np.eye(4))],
                 out_dir=False)
    # --overwrite replaces an output whole: never the model's folder, an input's folder or a
    # folder inside one of the model's configurations
    poses = rendered["a"].folder / "cameras.json"
    before = (model_dir / "model.json").read_bytes()
    for out in (model_dir, rendered["a"].folder, model_dir / "a" / "registration"):
        with pytest.raises(InputError, match="input"):
            register(model_dir, camera_poses=poses, out_dir=out, overwrite=True)
    assert (model_dir / "model.json").read_bytes() == before and poses.is_file()
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "mine.txt").write_text("keep")
    with pytest.raises(InputError, match="registration.json"):
        register(model_dir, camera_poses=poses, out_dir=tmp_path / "notes", overwrite=True)
    assert (tmp_path / "notes" / "mine.txt").read_text() == "keep"


def test_command(reconstruction_sfm, rendered, fresh_view, tmp_path, capsys):
    import argparse

    from artrecon.register.cli import add_register_parser

    _, model_dir = reconstruction_sfm
    p = argparse.ArgumentParser()
    add_register_parser(p.add_subparsers(dest="command"))
    path, T = fresh_view
    pose = tmp_path / "fresh_pose.json"
    pose.write_text(json.dumps({"T_world_camera": T.tolist()}))
    out = tmp_path / "reg"
    args = p.parse_args(["register", str(model_dir), "--camera-poses",
                         str(rendered["a"].folder / "cameras.json"), "--image", str(path),
                         "--flange-pose", str(pose), "--out", str(out)])
    assert run_command(args) == 0
    said = capsys.readouterr().out
    assert "route camera_centres" in said and "routes agree" in said
    assert (out / "model.json").is_file() and (out / "registration.json").is_file()
    # again without --overwrite: refused, exit 2, the first result untouched
    before = (out / "registration.json").read_bytes()
    assert run_command(args) == 2
    assert "exists" in capsys.readouterr().err
    assert (out / "registration.json").read_bytes() == before
    args = p.parse_args(["register", str(model_dir), "--image", str(path)])
    assert run_command(args) == 2
    assert "one --flange-pose per --image" in capsys.readouterr().err
