"""ArticulatedModel: built from a segmentation, saved to JSON and loaded back bit for bit."""

import json

import numpy as np
import pytest
from synthetic import make_object

from artrecon.errors import InputError
from artrecon.joints import estimate_joints
from artrecon.model import ArticulatedModel, Joint, Link
from artrecon.segment import segment_links


def _model():
    obj = make_object(31, "star", ("revolute", "prismatic"), 50, 0.002, 0.3)
    seg = segment_links(obj.points_a, obj.points_b, seed=0)
    joints = estimate_joints(obj.points_a, obj.points_b, seg)
    rng = np.random.default_rng(0)
    n = len(obj.points_a)
    colours = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    model = ArticulatedModel.from_segmentation(
        obj.points_a, seg, joints, colours=colours, normals=normals, metadata={"seed": 0}
    )
    model.frames["T_world_model"] = np.diag([1.0, 1.0, 1.0, 1.0]) + rng.normal(size=(4, 4)) / 3
    model.frames["T_world_model"][3] = [0, 0, 0, 1]
    return obj, seg, model, colours, normals


def test_from_segmentation():
    obj, seg, model, colours, normals = _model()
    assert len(model.links) == seg.n_links == 3
    assert len(model.joints) == 2
    assert model.root == 0 and model.parent_of(0) is None
    assert sorted(model.children_of(0)) == [1, 2]
    for k, link in enumerate(model.links):
        np.testing.assert_array_equal(link.match_indices, seg.members(k))
        np.testing.assert_array_equal(link.points, obj.points_a[seg.members(k)])
        np.testing.assert_array_equal(link.colours, colours[seg.members(k)])
        assert link.transform_a_to_b == seg.transforms[k]
    assert model.scale_a_to_b == seg.scale


def test_json_round_trip_is_lossless(tmp_path):
    _, _, model, _, _ = _model()
    model.joints[0].state_b = np.nextafter(model.joints[0].state_b, 10)  # last-bit detail survives
    model.metadata["nan"] = float("nan")
    path = model.save(tmp_path / "sub" / "model.json")
    back = ArticulatedModel.load(path)
    assert len(back.links) == len(model.links)
    for a, b in zip(model.links, back.links, strict=True):
        for field in ("points", "match_indices", "colours", "normals"):
            x, y = getattr(a, field), getattr(b, field)
            assert x.dtype == y.dtype and x.shape == y.shape
            np.testing.assert_array_equal(x, y)
        assert a.transform_a_to_b == b.transform_a_to_b
        assert a.name == b.name
    for a, b in zip(model.joints, back.joints, strict=True):
        assert (a.type, a.parent, a.child, a.name) == (b.type, b.parent, b.child, b.name)
        assert a.state_a == b.state_a and a.state_b == b.state_b and a.residual == b.residual
        np.testing.assert_array_equal(a.axis_direction, b.axis_direction)
        np.testing.assert_array_equal(a.axis_point, b.axis_point)
        assert a.relative_transform == b.relative_transform
    np.testing.assert_array_equal(back.frames["T_world_model"], model.frames["T_world_model"])
    assert (back.scale, back.root, back.scale_a_to_b, back.scale_known) == (
        model.scale, model.root, model.scale_a_to_b, model.scale_known
    )
    assert np.isnan(back.metadata["nan"]) and back.metadata["seed"] == 0
    # and a second save of the loaded model writes the same bytes
    assert back.save(tmp_path / "again.json").read_text() == path.read_text()


def test_optional_fields_round_trip(tmp_path):
    link = Link(points=np.zeros((0, 3)), match_indices=np.zeros(0, dtype=np.int64))
    model = ArticulatedModel(links=[link, link], joints=[
        Joint("prismatic", [0, 0, 2.0], [1, 2, 3], 0, 1, 0.0, 0.25)
    ])
    back = ArticulatedModel.load(model.save(tmp_path / "m.json"))
    assert back.links[0].colours is None and back.links[0].normals is None
    assert back.links[0].points.shape == (0, 3)
    np.testing.assert_array_equal(back.joints[0].axis_direction, [0, 0, 1.0])


def test_observed_in_round_trips_and_is_checked(tmp_path):
    seen = np.array([0, 1, 1, 0], np.int8)
    link = Link(points=np.arange(12.0).reshape(4, 3), match_indices=np.full(4, -1),
                observed_in=seen)
    back = ArticulatedModel.load(ArticulatedModel(links=[link], joints=[]).save(tmp_path / "m"
                                                                                ".json"))
    np.testing.assert_array_equal(back.links[0].observed_in, seen)
    with pytest.raises(ValueError, match="observed_in"):
        Link(points=np.zeros((4, 3)), match_indices=np.full(4, -1), observed_in=[0, 1])
    with pytest.raises(ValueError, match="observed_in"):
        Link(points=np.zeros((2, 3)), match_indices=np.full(2, -1), observed_in=[0, 2])


def test_load_errors(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        ArticulatedModel.load(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        ArticulatedModel.load(bad)
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"format": "something"}))
    with pytest.raises(InputError, match="not an artrecon"):
        ArticulatedModel.load(other)


def test_validation():
    with pytest.raises(ValueError, match="revolute"):
        Joint("ball", [0, 0, 1], [0, 0, 0], 0, 1)
    with pytest.raises(ValueError, match="non-zero"):
        Joint("revolute", [0, 0, 0], [0, 0, 0], 0, 1)
    with pytest.raises(ValueError, match=r"\(3,\)"):
        Joint("revolute", [0, 1], [0, 0, 0], 0, 1)
    with pytest.raises(ValueError, match="match_indices"):
        Link(points=np.zeros((3, 3)), match_indices=np.zeros(2))
    link = Link(points=np.zeros((1, 3)), match_indices=[0])
    with pytest.raises(ValueError, match="refers to link 5"):
        ArticulatedModel(links=[link], joints=[Joint("revolute", [0, 0, 1], [0, 0, 0], 0, 5)])
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        ArticulatedModel(links=[link], joints=[], frames={"T_a_b": np.eye(3)})


def test_model_json_keeps_its_long_number_lists_on_one_line(tmp_path):
    """model.json: the same JSON value json.dumps(indent=1) gives, with each long list of
    numbers (a link's points, colours, normals) on one line instead of one number per line
    (the json module's Python encoder took 0.78 s for a 30k-point model); short lists, and
    lists holding anything but numbers, stay indented."""
    from artrecon.files import LONG_LIST, json_dumps

    _, _, model, _, _ = _model()
    path = model.save(tmp_path / "model.json")
    text = path.read_text()
    assert json.loads(text) == json.loads(json.dumps(model.to_dict(), indent=1))
    assert len(text) < len(json.dumps(model.to_dict(), indent=1))
    link = model.links[0]
    flat = json.dumps(link.points.ravel().tolist(), separators=(", ", ": "))
    assert f'"data": {flat}' in text  # the points' data array, on its line
    obj = {"rows": [[1, 2.5, -3e-300]] * LONG_LIST, "flat": list(range(LONG_LIST)),
           "short": [1.0, 2.0], "flags": [True] * LONG_LIST, "words": ["a"] * LONG_LIST,
           "nan": [float("nan")] * LONG_LIST, "nested": {"deep": [[0.5, 1]] * LONG_LIST},
           "mixed": [1, [2, 3]] * LONG_LIST, "rows_of_dicts": [{"x": 1}] * LONG_LIST}
    text = json_dumps(obj)
    assert json.dumps(json.loads(text)) == json.dumps(json.loads(json.dumps(obj, indent=1)))
    lines = text.splitlines()
    for key in ("rows", "flat", "nan", "deep"):  # one line each
        assert any(line.strip().startswith(f'"{key}": [') and line.rstrip().endswith(("]", "],"))
                   for line in lines), key
    for key in ("short", "flags", "words", "mixed", "rows_of_dicts"):  # as json.dumps indents
        assert any(line.strip() == f'"{key}": [' for line in lines), key
