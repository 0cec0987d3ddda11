"""Known camera poses are checked against the images: poses that disagree (a camera mount /
hand-eye error, encoder errors) are refused with a PoseMismatchError saying so, never turned into
a model from wrong cameras; exact poses pass."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from render_fixture import K, _pyrender_scene, _renderer, build_parts, rotation_about

from artrecon import io, sfm
from artrecon.errors import PoseMismatchError, ReconstructionError
from sim.camera import convert_camera_pose

#: Views on an arc, 15 degrees apart: few enough to stay fast, close enough for every
#: neighbour pair to match.
ARC_VIEWS = 8
#: SIFT from the image's own resolution (first octave 0): 3x faster, plenty of keypoints here.
FAST = sfm.SfMConfig(first_octave=0)


def arc_poses(n: int, step_deg: float = 15.0, radius: float = 0.5, height: float = 0.4):
    """OpenCV ``T_world_camera`` (n, 4, 4) on an arc around the hinge fixture, looking at it."""
    poses = []
    for k in range(n):
        ang = np.deg2rad(step_deg * k)
        c = np.array([radius * np.cos(ang), radius * np.sin(ang), height])
        z = np.array([0.0, 0.0, 0.08]) - c
        z /= np.linalg.norm(z)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
        T[:3, 3] = c
        poses.append(T)
    return np.array(poses)


def render_arc(folder, config: str, poses) -> dict:
    """Render the hinge fixture from ``poses`` into ``folder/images``; cameras.json with them."""
    import pyrender

    (folder / "images").mkdir(parents=True)
    scene = _pyrender_scene(build_parts(config))
    cam = pyrender.IntrinsicsCamera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2] + 0.5, cy=K[1, 2] + 0.5,
                                    znear=0.02, zfar=5.0)
    node = scene.add(cam, pose=np.eye(4))
    out = {}
    for i, T in enumerate(poses):
        scene.set_pose(node, convert_camera_pose(T))
        colour, _ = _renderer().render(scene, flags=pyrender.RenderFlags.FLAT)
        name = f"view_{i:03d}.png"
        cv2.imwrite(str(folder / "images" / name), colour[:, :, ::-1])
        out[name] = T
    (folder / "cameras.json").write_text(json.dumps(
        {"K": K.tolist(), "width": 640, "height": 480,
         "images": [{"name": n, "T_world_camera": T.tolist()} for n, T in out.items()]}))
    return out


def mount_error(poses: dict, mm: float, deg: float) -> dict:
    """Every pose times one fixed camera-frame error E, as a wrong hand-eye calibration gives."""
    E = np.eye(4)
    E[:3, :3] = rotation_about(np.array([1.0, -2.0, 0.5]), np.deg2rad(deg))
    E[:3, 3] = 1e-3 * mm * np.array([0.6, 0.0, -0.8])
    return {n: T @ E for n, T in poses.items()}


@pytest.fixture(scope="module")
def arc(tmp_path_factory):
    root = tmp_path_factory.mktemp("arc")
    poses = arc_poses(ARC_VIEWS)
    return {c: (root / c, render_arc(root / c, c, poses)) for c in ("a", "b")}


def test_exact_poses_are_accepted(arc, tmp_path):
    folder, poses = arc["a"]
    iset = io.load_image_folder(folder)
    intr, _ = io.load_cameras_json(folder / "cameras.json")
    res = sfm.run_sfm(iset, tmp_path / "sfm", intr, poses, config=FAST, progress=False)
    agree = res.pose_agreement
    print(agree)
    cfg = sfm.SfMConfig()
    assert agree["pairs"] >= ARC_VIEWS - 1
    assert agree["epipolar_median_px"] < cfg.max_pose_epipolar_px / 3  # measured 0.04 px
    assert agree["triangulated_share"] > cfg.min_pose_triangulated_share  # measured 0.89


def test_wrong_poses_are_refused_with_the_figures(arc, tmp_path):
    """A 20 mm / 4 deg mount error: reconstruct() refuses at configuration A's triangulation,
    names the figure, the likely cause and the way out (SfM without the poses)."""
    from artrecon import reconstruct
    from artrecon.reconstruct import ReconstructConfig

    (fa, pa), (fb, pb) = arc["a"], arc["b"]
    with pytest.raises(PoseMismatchError, match=r"(?s)do not agree with the images.*median "
                       r"[0-9.]+ px.*hand-eye.*without --use-poses") as info:
        reconstruct(fa, fb, poses=(mount_error(pa, 20, 4), mount_error(pb, 20, 4)),
                    out_dir=tmp_path / "out", config=ReconstructConfig(sfm=FAST), progress=False)
    assert isinstance(info.value, ReconstructionError)
    agree = info.value.agreement
    print(agree)
    assert agree["epipolar_median_px"] > 2 * sfm.SfMConfig().max_pose_epipolar_px
    assert not (tmp_path / "out").exists()  # nothing half-written


def test_check_needs_checkable_pairs():
    """No verified pair between posed images: the poses cannot be vouched for, so refused."""
    with pytest.raises(PoseMismatchError, match="cannot be checked"):
        sfm.check_pose_agreement({"pairs": 0, "matches": 0, "epipolar_median_px": None,
                                  "triangulated_share": None}, sfm.SfMConfig(), "test")


def test_later_failures_name_poses_that_barely_passed():
    """A segmentation / evidence failure after poses that passed the check but sit well above the
    exact poses' residual names the poses as the likely cause and the way out; exact poses (or
    SfM, no poses) leave the error as it was."""
    from types import SimpleNamespace

    from artrecon.diagnosis import blame_poses
    from artrecon.errors import SingleBodyError, WeakEvidenceError

    cfg = sfm.SfMConfig()

    def sfms(px):
        agree = None if px is None else {"epipolar_median_px": px}
        return {k: SimpleNamespace(pose_agreement=agree) for k in ("a", "b")}

    err = SingleBodyError("segment_links: found 1 rigid link(s)")
    assert blame_poses(err, sfms(None), cfg) is err
    assert blame_poses(err, sfms(0.13), cfg) is err
    out = blame_poses(err, sfms(1.2), cfg)
    assert isinstance(out, SingleBodyError)
    assert str(out).startswith(str(err)) and "1.20 px (A)" in str(out)
    assert "without --use-poses" in str(out)
    weak = blame_poses(WeakEvidenceError("weak", [{"joint": "j"}]), sfms(1.2), cfg)
    assert isinstance(weak, WeakEvidenceError) and weak.records == [{"joint": "j"}]
