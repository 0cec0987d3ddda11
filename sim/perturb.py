"""Perturbations that real captures bring, for robustness runs of ``python -m sim.evaluate``.

Each perturbation has a strength; at its neutral value (the default) it does nothing and the
evaluation's cache keys are exactly those of an unperturbed run. They act at four places:

- **the scene** (before capture and scoring): a smaller joint motion. ``motion_deg`` /
  ``motion_mm`` cap the motion A -> B of every moving revolute / prismatic joint (configuration B
  moves toward A, same sense); couplings are re-applied. The scene used for scoring is the
  perturbed one, so the true motion is the smaller one (:func:`apply_motion`).
- **the rendered world** (capture): a lighting change between the configurations (B's lights
  turned about the vertical by ``light_b_rotate_deg`` and scaled by ``light_b_intensity``) and a
  less textured object (``texture_contrast``: the object's textures blended toward their mean
  colour, 1 = as made, 0 = flat). The capture compiles its own model (the scene with joint holds),
  so these edits ride on a :class:`PerturbedScene` that re-applies them to every model it
  compiles (:func:`edit_model`); the capture code is unchanged.
- **the captured image set** (after capture; images and ``cameras.json`` only, ``ground_truth/``
  stays true): Gaussian blur (``image_blur_sigma`` px, the optics) then Gaussian noise
  (``image_noise_sigma`` grey levels, the sensor) on every image; arm encoder noise
  (``encoder_noise_deg``: Gaussian, per image and per joint of rail + arm, on the ``q`` that
  cameras.json reports) and an error of the camera's mount on the wrist (``mount_error_mm``,
  ``mount_error_deg``: one fixed transform ``E`` in the camera frame, direction from the seed), so
  that the reported pose is ``FK(q + noise) @ E`` instead of the true camera pose
  (:func:`perturb_set`).
- **the cross-configuration matches** (after the reconstruction): ``match_outliers``, the share
  of object matches whose B point is replaced by the B point of another match (wrong matches, the
  same point cloud). The reconstruction's matches (``links/matches.npz``) are corrupted and
  segmentation, joints and link points are redone through artrecon's own functions
  (:func:`resegment`); SfM and dense points are the reconstruction's. Done after the fact
  rather than through a knob in ``artrecon.ReconstructConfig``: artrecon's public settings stay
  free of test-only switches, and the SfM/dense stages, which the corruption does not touch, are
  reused from the cache.

Fewer views need no perturbation: ``--views``.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import shutil
import sys
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import cv2
import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from artrecon.articulation import articulate
from artrecon.dense import DensePoints
from artrecon.files import read_ply
from artrecon.links_stage import fitted_matches
from artrecon.model import ArticulatedModel
from artrecon.reconstruct import ReconstructConfig, with_settings
from sim import cache, robot
from sim.scene import Scene

#: Neutral values: a perturbation at these does nothing.
NEUTRAL = {"light_b_rotate_deg": 0.0, "light_b_intensity": 1.0, "texture_contrast": 1.0,
           "image_noise_sigma": 0.0, "image_blur_sigma": 0.0, "motion_deg": None,
           "motion_mm": None, "match_outliers": 0.0, "encoder_noise_deg": 0.0,
           "mount_error_mm": 0.0, "mount_error_deg": 0.0}


@dataclass(frozen=True)
class Perturbation:
    """Strengths of every perturbation (defaults: none)."""

    light_b_rotate_deg: float = 0.0
    """configuration B's lights turned about the vertical (deg)"""
    light_b_intensity: float = 1.0
    """configuration B's lights scaled by this (diffuse, specular and ambient)"""
    texture_contrast: float = 1.0
    """object textures: mean + contrast * (texture - mean); 1 as made, 0 flat"""
    image_noise_sigma: float = 0.0
    """Gaussian image noise, standard deviation in grey levels (0-255)"""
    image_blur_sigma: float = 0.0
    """Gaussian blur, standard deviation in pixels"""
    motion_deg: float | None = None
    """cap of every revolute joint's motion A -> B (deg)"""
    motion_mm: float | None = None
    """cap of every prismatic joint's motion A -> B (mm)"""
    match_outliers: float = 0.0
    """share of object matches made wrong (their B point replaced by another match's)"""
    encoder_noise_deg: float = 0.0
    """Gaussian noise on each reported joint angle (rail and arm), standard deviation (deg)"""
    mount_error_mm: float = 0.0
    """translation of the camera mount error (mm)"""
    mount_error_deg: float = 0.0
    """rotation of the camera mount error (deg)"""

    def __post_init__(self):
        checks = [("light_b_intensity", self.light_b_intensity >= 0),
                  ("texture_contrast", 0 <= self.texture_contrast <= 1),
                  ("image_noise_sigma", self.image_noise_sigma >= 0),
                  ("image_blur_sigma", self.image_blur_sigma >= 0),
                  ("motion_deg", self.motion_deg is None or self.motion_deg > 0),
                  ("motion_mm", self.motion_mm is None or self.motion_mm > 0),
                  ("match_outliers", 0 <= self.match_outliers < 1),
                  ("encoder_noise_deg", self.encoder_noise_deg >= 0),
                  ("mount_error_mm", self.mount_error_mm >= 0),
                  ("mount_error_deg", self.mount_error_deg >= 0)]
        bad = [name for name, ok in checks if not ok]
        if bad:
            raise ValueError(f"perturbation {bad[0]}={getattr(self, bad[0])!r} is out of range: "
                             "intensity >= 0, contrast in [0, 1], outlier share in [0, 1), "
                             "motion caps > 0, sigmas and mount errors >= 0")

    def changed(self) -> dict:
        """The perturbations that are not neutral, ``{name: strength}``."""
        return {k: v for k, v in asdict(self).items() if v != NEUTRAL[k]}

    @property
    def active(self) -> bool:
        return bool(self.changed())

    def scene_part(self) -> dict:
        return {k: v for k, v in self.changed().items() if k in ("motion_deg", "motion_mm")}

    def render_part(self, configuration: str) -> dict:
        keys = ("texture_contrast",) + (("light_b_rotate_deg", "light_b_intensity")
                                        if configuration == "b" else ())
        return {k: v for k, v in self.changed().items() if k in keys}

    def set_part(self) -> dict:
        keys = ("image_noise_sigma", "image_blur_sigma", "encoder_noise_deg", "mount_error_mm",
                "mount_error_deg")
        return {k: v for k, v in self.changed().items() if k in keys}


def _source() -> str:
    return cache.source_hash([sys.modules[__name__]])


# ---------------------------------------------------------------------------- scene: motion


def apply_motion(scene: Scene, motion_deg: float | None = None,
                 motion_mm: float | None = None) -> Scene:
    """The scene with every moving joint's motion A -> B capped (configuration B changed).

    A revolute joint moving more than ``motion_deg`` (a prismatic one more than ``motion_mm``)
    gets ``value_b = value_a + sign(motion) * cap``; joints driven by a coupling take the value the
    coupling gives for the new B of their driver. Returns ``scene`` itself when nothing changes.
    """
    if motion_deg is None and motion_mm is None:
        return scene
    caps = {"revolute": None if motion_deg is None else np.deg2rad(motion_deg),
            "prismatic": None if motion_mm is None else motion_mm * 1e-3}
    new_b = {}
    for j in scene.joints:
        cap = caps[j.type]
        new_b[j.name] = (j.value_a + np.sign(j.motion) * cap
                         if cap is not None and abs(j.motion) > cap else j.value_b)
    for c in scene.couplings:
        new_b[c.joint1] = c.value(new_b[c.joint2])
    joints = []
    for j in scene.joints:
        vb = float(new_b[j.name])
        if not j.range[0] - 1e-9 <= vb <= j.range[1] + 1e-9:
            raise ValueError(f"{scene.name}: the capped motion puts joint {j.name!r} at {vb:g}, "
                             f"outside its range {j.range.tolist()}")
        joints.append(replace(j, value_b=vb))
    return replace(scene, joints=tuple(joints))


# ---------------------------------------------------------------------------- rendered world


def object_textures(model, scene: Scene) -> list[int]:
    """Ids of the colour textures of the object's geoms (its links' bodies), sorted."""
    from sim.render import material_texture  # pyrender (1 s, needs EGL): only to render

    bodies = {b for li in scene.links for b in li.body_ids}
    tex = {material_texture(model, int(model.geom_matid[g])) for g in range(model.ngeom)
           if int(model.geom_bodyid[g]) in bodies}
    return sorted(t for t in tex if t >= 0)


def blend_texture(img: np.ndarray, contrast: float) -> np.ndarray:
    """``mean + contrast * (img - mean)`` per channel, rounded to uint8."""
    img = np.asarray(img)
    flat = img.reshape(-1, img.shape[-1]).astype(float)
    mean = flat.mean(axis=0)
    out = mean + contrast * (flat - mean)
    return np.clip(np.round(out), 0, 255).astype(np.uint8).reshape(img.shape)


def edit_model(model, scene: Scene, light_rotate_deg: float = 0.0, light_intensity: float = 1.0,
               texture_contrast: float = 1.0) -> None:
    """Change lights and object textures of a compiled model in place (before rendering).

    Lights: every light's direction and position turned by ``light_rotate_deg`` about the world
    vertical (the stage's lights hang in the world body), diffuse, specular and ambient scaled by
    ``light_intensity``. Textures: :func:`blend_texture` on each of :func:`object_textures`.
    """
    if light_rotate_deg or light_intensity != 1.0:
        a = np.deg2rad(light_rotate_deg)
        R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
        for name in ("light_dir", "light_pos", "light_dir0", "light_pos0"):
            arr = getattr(model, name, None)
            if arr is not None:
                arr[:] = np.asarray(arr) @ R.T
        for name in ("light_diffuse", "light_specular", "light_ambient"):
            arr = getattr(model, name)
            arr[:] = np.clip(np.asarray(arr) * light_intensity, 0.0, None)
    if texture_contrast != 1.0:
        for t in object_textures(model, scene):
            w, h, c = int(model.tex_width[t]), int(model.tex_height[t]), int(model.tex_nchannel[t])
            adr = int(model.tex_adr[t])
            img = np.asarray(model.tex_data[adr:adr + w * h * c]).reshape(h * w, c)
            model.tex_data[adr:adr + w * h * c] = blend_texture(img, texture_contrast).ravel()


@dataclass(frozen=True, eq=False)
class PerturbedScene(Scene):
    """A scene whose compiled models have changed lights and textures (:func:`edit_model`).

    :meth:`Scene.with_joint_holds` compiles the file anew (the capture does that); here the edits
    are applied to that model too, so a capture of this scene renders the perturbed world.
    """

    light_rotate_deg: float = 0.0
    light_intensity: float = 1.0
    texture_contrast: float = 1.0

    def _edit(self) -> None:
        edit_model(self.model, self, self.light_rotate_deg, self.light_intensity,
                   self.texture_contrast)

    def with_joint_holds(self) -> PerturbedScene:
        held = super().with_joint_holds()  # a fresh model compiled from the file
        held._edit()
        return held


def capture_scene(scene: Scene, p: Perturbation, configuration: str) -> Scene:
    """The scene to capture ``configuration`` of: ``scene`` itself when nothing is rendered
    differently, else a :class:`PerturbedScene` (with its own edited copy of the model)."""
    part = p.render_part(configuration)
    if not part:
        return scene

    kw = {f.name: getattr(scene, f.name) for f in fields(Scene)}
    kw["model"] = copy.deepcopy(scene.model)
    out = PerturbedScene(**kw, light_rotate_deg=part.get("light_b_rotate_deg", 0.0),
                         light_intensity=part.get("light_b_intensity", 1.0),
                         texture_contrast=part.get("texture_contrast", 1.0))
    out._edit()
    return out


def capture_inputs(scene: Scene, p: Perturbation, configuration: str) -> dict:
    """What the perturbation adds to the capture stage's cache inputs (empty when it changes
    nothing of this capture, so unperturbed caches are shared)."""
    extra = {}
    if p.render_part(configuration):
        extra["render"] = p.render_part(configuration)
    if p.scene_part() and configuration == "b":
        extra["joints_b"] = scene.configuration("b")
    if extra:
        extra["perturb_code"] = _source()
    return {"perturbation": extra} if extra else {}


# ---------------------------------------------------------------------------- image set


def degrade_image(img: np.ndarray, blur_sigma: float, noise_sigma: float,
                  rng: np.random.Generator) -> np.ndarray:
    """Gaussian blur (``blur_sigma`` px) then additive Gaussian noise (``noise_sigma`` grey
    levels) of a uint8 image, rounded and clipped to uint8."""
    out = np.asarray(img)
    if blur_sigma > 0:
        out = cv2.GaussianBlur(out, (0, 0), sigmaX=blur_sigma, sigmaY=blur_sigma,
                               borderType=cv2.BORDER_REFLECT)
    if noise_sigma > 0:
        noisy = out.astype(float) + rng.normal(0.0, noise_sigma, out.shape)
        out = np.clip(np.round(noisy), 0, 255).astype(np.uint8)
    return out


def mount_error(mm: float, deg: float, seed: int = 0) -> np.ndarray:
    """The camera mount error ``E`` (4, 4): a rotation of ``deg`` about a random axis and a
    translation of ``mm`` along a random direction (camera frame), from ``seed``."""
    rng = np.random.default_rng([seed, 4711])
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    E = np.eye(4)
    E[:3, :3] = Rotation.from_rotvec(np.deg2rad(deg) * axis / np.linalg.norm(axis)).as_matrix()
    E[:3, 3] = 1e-3 * mm * direction / np.linalg.norm(direction)
    return E


def perturb_cameras(cameras: dict, kin, p: Perturbation, seed: int,
                    configuration: str) -> dict:
    """A copy of a ``cameras.json`` dict with the arm's reported joint angles and poses perturbed.

    Each image with an FK pose gets ``q' = q + N(0, encoder_noise_deg)`` per joint and
    ``T_world_camera = kin.camera_pose(q') @ E`` (:func:`mount_error`), i.e. the pose the robot
    believes; ``q`` becomes ``q'`` (what its encoders say).
    """
    out = json.loads(json.dumps(cameras))
    E = mount_error(p.mount_error_mm, p.mount_error_deg, seed)
    rng = np.random.default_rng([seed, ord(configuration), 17])
    for im in out["images"]:
        if im.get("q") is None:
            continue
        q = np.asarray(im["q"], float)
        q_rep = q + np.deg2rad(p.encoder_noise_deg) * rng.normal(size=q.shape)
        im["q"] = [float(x) for x in q_rep]
        im["T_world_camera"] = (kin.camera_pose(q_rep) @ E).tolist()
        im["T_world_flange"] = kin.frame_pose(q_rep, "flange").tolist()
        im["pose_source"] = "arm_fk (perturbed: encoder noise / mount error)"
    return out


def perturb_fresh_pose(pose_file: Path, scene: Scene, p: Perturbation, seed: int) -> None:
    """Perturb a fresh view's ``pose.json`` (:func:`sim.capture.capture_fresh_view`) like the
    capture's poses: encoder noise on its joint angles, and the flange and camera poses the
    robot then believes (the mount error moves the camera, not the flange). No-op without
    those perturbations."""
    if not (p.encoder_noise_deg > 0 or p.mount_error_mm > 0 or p.mount_error_deg > 0):
        return

    kin = robot.load_arm_kinematics(scene.model)
    pose = json.loads(Path(pose_file).read_text())
    rng = np.random.default_rng([seed, ord("f"), 17])
    q = np.asarray(pose["q"], float) + np.deg2rad(p.encoder_noise_deg) * rng.normal(
        size=len(pose["q"]))
    pose["q"] = [float(x) for x in q]
    pose["T_world_flange"] = kin.frame_pose(q, "flange").tolist()
    pose["T_world_camera"] = (kin.camera_pose(q) @ mount_error(p.mount_error_mm,
                                                               p.mount_error_deg, seed)).tolist()
    pose["pose_source"] = "arm_fk (perturbed: encoder noise / mount error)"
    Path(pose_file).write_text(json.dumps(pose, indent=2) + "\n")


def perturb_set(src: Path, dst: Path, scene: Scene, p: Perturbation, seed: int,
                configuration: str) -> dict:
    """Copy the image set ``src`` to ``dst`` with :meth:`Perturbation.set_part` applied (images
    and cameras.json; ``ground_truth/`` is copied unchanged). Returns a summary."""
    shutil.copytree(src, dst)
    summary = {"perturbation": p.set_part()}
    if p.image_noise_sigma > 0 or p.image_blur_sigma > 0:
        files = sorted((dst / "images").glob("*.png"))
        for k, f in enumerate(files):
            rng = np.random.default_rng([seed, ord(configuration), k])
            img = np.asarray(Image.open(f))
            Image.fromarray(degrade_image(img, p.image_blur_sigma, p.image_noise_sigma,
                                          rng)).save(f)
        summary["images_degraded"] = len(files)
    if p.encoder_noise_deg > 0 or p.mount_error_mm > 0 or p.mount_error_deg > 0:
        kin = robot.load_arm_kinematics(scene.model)
        cams = json.loads((dst / "cameras.json").read_text())
        new = perturb_cameras(cams, kin, p, seed, configuration)
        (dst / "cameras.json").write_text(json.dumps(new, indent=2) + "\n")
        truth = json.loads((dst / "ground_truth" / "poses.json").read_text())
        true = {im["file"]: np.asarray(im["T_world_camera"]) for im in truth["images"]}
        err = [np.linalg.norm(np.asarray(im["T_world_camera"])[:3, 3] - true[im["file"]][:3, 3])
               for im in new["images"] if im.get("T_world_camera") is not None]
        summary["reported_pose_position_error_mm"] = {
            "median": 1e3 * float(np.median(err)), "max": 1e3 * float(np.max(err))}
    return summary


def set_stage(set_dir: Path, capture_key: str, scene: Scene, p: Perturbation, seed: int,
              configuration: str, cache_root: Path) -> tuple[Path, str, dict]:
    """The perturbed copy of a captured set (cached). Returns (set folder, key, summary);
    the captured set and its key unchanged when :meth:`Perturbation.set_part` is empty."""
    if not p.set_part():
        return set_dir, capture_key, {}
    inputs = {"capture": capture_key, "perturbation": p.set_part(), "seed": seed,
              "config": configuration, "code": _source()}

    def build(folder: Path) -> dict:
        return perturb_set(set_dir, folder / "set", scene, p, seed, configuration)

    folder, meta, _ = cache.cached_stage(cache_root, f"perturb_{configuration}", inputs, build)
    return folder / "set", meta["key"], {k: v for k, v in meta.items() if k != "inputs"}


# ---------------------------------------------------------------------------- matches


def corrupt_matches(points_b: np.ndarray, fraction: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Make ``round(fraction * n)`` matches wrong: their B points are those of other matches.

    The chosen matches' B points are passed round a random cycle, so each one gets another
    match's B point (the point cloud of B stays the same). Returns (new points_b, wrong mask).
    """
    pb = np.asarray(points_b, float)
    n = len(pb)
    k = int(round(fraction * n))
    wrong = np.zeros(n, bool)
    out = pb.copy()
    if k < 2:
        return out, wrong
    order = rng.permutation(n)[:k]
    out[order] = pb[np.roll(order, 1)]
    wrong[order] = True
    return out, wrong


def resegment(model_dir: Path, out_dir: Path, fraction: float, seed: int = 0,
              settings: dict | None = None) -> dict:
    """Redo segmentation, joints and link points of a reconstruction with wrong matches.

    Reads the matches the links of ``model_dir`` were fitted to (its links stage's
    ``links/matches.npz``, :func:`artrecon.links_stage.fitted_matches`: the guided ones
    appended) and its dense points, corrupts the object matches
    (:func:`corrupt_matches`), runs the pipeline's own steps after matching on them
    (:func:`artrecon.articulation.articulate`: segmentation, the base anchored to the background,
    dense labelling -- geometric only: the image cues need the SfM images --, tree, joints and
    the confidence check that refuses weak joints) and writes ``out_dir/model.json`` and
    ``out_dir/matches.npz``; ``out_dir/a`` and ``out_dir/b`` link to the SfM models. Raises what
    those steps raise (a refusal included). ``settings``: the reconstruction's settings that
    differ from the defaults, as for artrecon.reconstruct.with_settings (the scene's).
    """
    model_dir, out_dir = Path(model_dir), Path(out_dir)
    m = fitted_matches(model_dir / "links")
    pa = m["points_a"]
    pb, wrong = corrupt_matches(m["points_b"], fraction, np.random.default_rng([seed, 99]))
    dense = {}
    for c in ("a", "b"):
        pts, nrm, col = read_ply(model_dir / c / "dense.ply")
        dense[c] = DensePoints(pts, nrm, col, np.zeros((len(pts), 0), bool), [])
    old = ArticulatedModel.load(model_dir / "model.json")
    config = with_settings(ReconstructConfig(), settings or {})
    art = articulate(pa, pb, m["background_a"], m["background_b"], dense["a"], dense["b"],
                     config, seed)
    seg, links, joints, root = art.segmentation, art.links, art.joints, art.root
    correct = ~wrong
    summary = {"match_outliers": fraction, "matches": int(len(pa)), "made_wrong": int(wrong.sum()),
               "outliers_found": int((seg.labels < 0).sum()),
               "wrong_kept_in_links": int(((seg.labels >= 0) & wrong).sum()),
               "right_rejected": int(((seg.labels < 0) & correct).sum()), "links": len(links),
               "joints": len(joints)}
    model = ArticulatedModel(
        links=links, joints=joints, scale=old.scale, frames=old.frames, root=art.tree.root,
        scale_a_to_b=float(seg.scale), scale_known=old.scale_known,
        metadata={**old.metadata, "match_outliers": int((seg.labels < 0).sum()),
                  "link_matches": seg.sizes.tolist(),
                  "root_from": "background" if root is not None else "largest link",
                  "confidence": art.confidence, "perturbation": summary})
    out_dir.mkdir(parents=True, exist_ok=True)
    model.save(out_dir / "model.json")
    np.savez(out_dir / "matches.npz", points_a=pa, points_b=pb, wrong=wrong, labels=seg.labels,
             background_a=m["background_a"], background_b=m["background_b"])
    for c in ("a", "b"):
        os.symlink(os.path.relpath(model_dir / c, out_dir), out_dir / c)
    return summary


def outlier_stage(model_dir: Path, reconstruct_key: str, p: Perturbation, seed: int,
                  cache_root: Path, settings: dict | None = None) -> tuple[Path, dict]:
    """The reconstruction with :attr:`Perturbation.match_outliers` wrong matches (cached), its
    steps run with the reconstruction's ``settings`` (see :func:`resegment`). Returns (model
    folder, summary); ``model_dir`` itself when there are none."""
    if not p.match_outliers:
        return model_dir, {}
    inputs = {"reconstruct": reconstruct_key, "match_outliers": p.match_outliers, "seed": seed,
              "code": _source()}
    folder, meta, _ = cache.cached_stage(
        cache_root, "outliers", inputs,
        lambda f: resegment(model_dir, f / "model", p.match_outliers, seed, settings))
    return folder / "model", {k: v for k, v in meta.items() if k != "inputs"}


# ---------------------------------------------------------------------------- command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The perturbation options of ``python -m sim.evaluate`` (robustness runs)."""
    g = parser.add_argument_group("perturbations (robustness runs; defaults: none)")
    g.add_argument("--light-b-rotate", type=float, default=0.0, metavar="DEG",
                   help="turn configuration B's lights about the vertical by DEG")
    g.add_argument("--light-b-intensity", type=float, default=1.0, metavar="F",
                   help="scale configuration B's lights by F")
    g.add_argument("--texture-contrast", type=float, default=1.0, metavar="C",
                   help="object textures blended toward their mean colour (1 as made, 0 flat)")
    g.add_argument("--image-noise", type=float, default=0.0, metavar="SIGMA",
                   help="Gaussian noise on the captured images (grey levels)")
    g.add_argument("--image-blur", type=float, default=0.0, metavar="SIGMA",
                   help="Gaussian blur of the captured images (pixels)")
    g.add_argument("--motion-deg", type=float, default=None, metavar="DEG",
                   help="cap every revolute joint's motion A -> B at DEG")
    g.add_argument("--motion-mm", type=float, default=None, metavar="MM",
                   help="cap every prismatic joint's motion A -> B at MM")
    g.add_argument("--match-outliers", type=float, default=0.0, metavar="SHARE",
                   help="make this share of the cross-configuration matches wrong (0-1)")
    g.add_argument("--encoder-noise", type=float, default=0.0, metavar="DEG",
                   help="Gaussian noise on the arm's reported joint angles (deg)")
    g.add_argument("--mount-error-mm", type=float, default=0.0, metavar="MM",
                   help="translation error of the camera's mount on the wrist (mm)")
    g.add_argument("--mount-error-deg", type=float, default=0.0, metavar="DEG",
                   help="rotation error of the camera's mount on the wrist (deg)")


def from_args(args: argparse.Namespace) -> Perturbation:
    """The :class:`Perturbation` of parsed :func:`add_arguments` options."""
    return Perturbation(
        light_b_rotate_deg=args.light_b_rotate, light_b_intensity=args.light_b_intensity,
        texture_contrast=args.texture_contrast, image_noise_sigma=args.image_noise,
        image_blur_sigma=args.image_blur, motion_deg=args.motion_deg, motion_mm=args.motion_mm,
        match_outliers=args.match_outliers, encoder_noise_deg=args.encoder_noise,
        mount_error_mm=args.mount_error_mm, mount_error_deg=args.mount_error_deg)
