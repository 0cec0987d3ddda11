"""Bad input gets a clear message, a non-zero exit and no traceback; results are whole or absent.

Folder-level checks of one image set (missing, a file, no images, too few, unreadable, mixed
sizes) are tested on artrecon.io in test_sfm.py, and malformed scene files on sim.scene in
test_scenes.py; here: what the user sees from the command lines, image sets that cannot be two
configurations of one object, and interrupted runs.
"""

from __future__ import annotations

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

from artrecon import io
from artrecon.cli import main
from artrecon.errors import InputError, ReconstructionError
from artrecon.reconstruct import reconstruct

REPO = Path(__file__).resolve().parents[1]


def _write_images(folder: Path, n: int = 6, size=(64, 48), seed: int = 0) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for i in range(n):
        cv2.imwrite(str(folder / f"img_{i:02d}.png"),
                    (rng.random((size[1], size[0], 3)) * 255).astype(np.uint8))
    return folder


def _cli(argv, capsys) -> tuple[int, str]:
    code = main(argv)  # an uncaught exception (a traceback) fails the test here
    return code, capsys.readouterr().err


# --- the command line -------------------------------------------------------------------------


@pytest.mark.parametrize("case, needle", [
    ("empty", "no images"),
    ("unreadable", "cannot read image"),
    ("mixed sizes", "differ in size"),
    ("a file", "is a file, not a folder"),
])
def test_cli_bad_image_folder_exits_2_with_message(tmp_path, capsys, case, needle):
    good = _write_images(tmp_path / "good", seed=1)
    bad = tmp_path / "bad"
    if case == "empty":
        bad.mkdir()
    elif case == "unreadable":
        _write_images(bad)
        (bad / "img_02.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    elif case == "mixed sizes":
        _write_images(bad)
        cv2.imwrite(str(bad / "img_04.png"), np.zeros((30, 40, 3), np.uint8))
    else:
        bad = tmp_path / "photo.png"
        cv2.imwrite(str(bad), np.zeros((30, 40, 3), np.uint8))
    code, err = _cli(["reconstruct", str(good), str(bad), "--out", str(tmp_path / "o")], capsys)
    assert code == 2
    assert err.startswith("artrecon: error: ") and needle in err
    if case in ("unreadable", "mixed sizes"):
        assert "img_02.png" in err or "img_04.png" in err  # names the image
    assert not (tmp_path / "o").exists() and not list(tmp_path.glob(".o.tmp-*"))


def test_cli_bad_intrinsics_is_input_error(tmp_path, capsys):
    a, b = _write_images(tmp_path / "a"), _write_images(tmp_path / "b", seed=1)
    code, err = _cli(["reconstruct", str(a), str(b), "--out", str(tmp_path / "o"),
                      "--intrinsics", "500,500,320"], capsys)
    assert code == 2 and "fx,fy,cx,cy" in err


@pytest.mark.parametrize("setting, needle", [
    ("dense.downsample", "expected STAGE.FIELD=NUMBER"),
    ("dense.downsample=full", "expected STAGE.FIELD=NUMBER"),
    ("dense.nope=1", "DenseConfig has no field 'nope'"),
    ("dense.downsample=0", "downsample must be 1"),
    ("nope.x=1", "name it stage.field"),
])
def test_cli_bad_setting_is_input_error(tmp_path, capsys, setting, needle):
    a, b = _write_images(tmp_path / "a"), _write_images(tmp_path / "b", seed=1)
    code, err = _cli(["reconstruct", str(a), str(b), "--out", str(tmp_path / "o"),
                      "--set", setting], capsys)
    assert code == 2 and needle in err, err
    assert not (tmp_path / "o").exists()


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


def test_matches_of_different_objects_are_called_so():
    """Matches that no rigid motion explains (chance pairings of two different objects) are
    reported as such; a real one-body motion keeps its own message."""
    from scipy.spatial.transform import Rotation

    from artrecon.confidence import explain_segmentation_failure
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
    segmentation: SfM and dense points of both sets, known poses.)"""
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
    assert not (tmp_path / "o").exists() and not list(tmp_path.glob(".o.tmp-*"))
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
    mine = io.make_work_dir(out)
    dead = tmp_path / ".out.tmp-999999999-abc"  # no such process
    dead.mkdir()
    (dead / "model.json").write_text("{half")
    other = io.make_work_dir(out)  # a second run starting while the first is alive
    assert mine.is_dir() and other.is_dir() and not dead.exists()
    assert (tmp_path / "unrelated.tmp-1").mkdir() is None
    io.remove_stale_work_dirs(out)
    assert (tmp_path / "unrelated.tmp-1").is_dir()


def test_publish_replaces_a_result_whole(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "model.json").write_text("old")
    work = io.make_work_dir(out)
    (work / "model.json").write_text("new")
    io.publish_dir(work, out)
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
