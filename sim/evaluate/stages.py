"""The stages of one scene's evaluation, each cached by the hash of its inputs."""

from __future__ import annotations

import logging
import platform
from dataclasses import asdict
from pathlib import Path

import mujoco
import numpy as np

from artrecon import workers
from artrecon.io import read_json
from sim import cache, perturb
from sim.evaluate.config import EvalConfig, StageError
from sim.scene import Scene

log = logging.getLogger(__name__)

# ---------------------------------------------------------------------------- stages


def versions() -> dict:
    import cv2
    import pinocchio
    import pycolmap
    import scipy

    import artrecon

    return {"python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "mujoco": mujoco.__version__,
            "pycolmap": pycolmap.__version__, "pin": pinocchio.__version__,
            "opencv": cv2.__version__, "artrecon": artrecon.__version__}


def _capture_sources() -> str:
    from sim import camera, capture, render, robot, scene, views

    return cache.source_hash([camera, capture, render, robot, scene, views])


def _reconstruct_sources() -> str:
    import artrecon

    return cache.source_hash([artrecon])


def _manipulate_sources() -> str:
    from sim import manipulate, robot, scene, views

    return cache.source_hash([manipulate, robot, scene, views])


def _capture_inputs(scene: Scene, configuration: str, ev: EvalConfig, scene_hash: str) -> dict:
    import artrecon

    return {"scene": scene.name, "scene_hash": scene_hash, "config": configuration,
            "views": ev.views, "seed": ev.seed, "version": artrecon.__version__,
            "code": _capture_sources(),
            **perturb.capture_inputs(scene, ev.perturb, configuration)}


def capture_stage(scene: Scene, configuration: str, ev: EvalConfig, cache_root: Path,
                  scene_hash: str) -> tuple[Path, dict, bool]:
    """Capture one configuration (cached). Returns the image set folder, stage metadata, hit."""
    from sim.capture import capture

    def build(folder: Path) -> dict:
        res = capture(perturb.capture_scene(scene, ev.perturb, configuration), configuration,
                      folder / "set", n_views=ev.views, seed=ev.seed, progress=ev.progress)
        return {"n_planned": res.n_planned, "n_captured": res.n_captured,
                "unreachable": res.unreachable,
                "max_fk_position_error_mm": 1e3 * res.max_fk_position_error,
                "max_fk_rotation_error_deg": float(np.rad2deg(res.max_fk_rotation_error)),
                "timings": res.timings}

    inputs = _capture_inputs(scene, configuration, ev, scene_hash)
    folder, meta, hit = cache.cached_stage(cache_root, f"capture_{configuration}", inputs, build)
    return folder / "set", meta, hit


def _configuration_inputs(capture_key: str, configuration: str, ev: EvalConfig,
                          settings: dict | None) -> dict:
    import artrecon
    from artrecon.reconstruct import ReconstructConfig, _jsonable, with_settings

    config = with_settings(ReconstructConfig(), settings or {})
    return {"capture": capture_key, "config": configuration, "poses": ev.poses,
            "seed": ev.seed, "settings": _jsonable({k: asdict(getattr(config, k))
                                                    for k in ("sfm", "dense", "region")}),
            "version": artrecon.__version__, "code": _reconstruct_sources()}


def configuration_stage(set_dir: Path, capture_key: str, configuration: str, ev: EvalConfig,
                        cache_root: Path, settings: dict | None = None
                        ) -> tuple[Path, dict, bool]:
    """artrecon's per-configuration stage (SfM or FK triangulation, dense points, the object
    region) of one captured set (cached). Returns its folder, stage metadata, hit."""
    from artrecon.reconstruct import ReconstructConfig, prepare_configuration, with_settings

    config = with_settings(ReconstructConfig(), settings or {})

    def build(folder: Path) -> dict:
        prepare_configuration(set_dir, folder / "configuration", seed=ev.seed, config=config,
                              poses=True if ev.poses == "fk" else None,
                              which=configuration.upper(), progress=ev.progress)
        return {}

    inputs = _configuration_inputs(capture_key, configuration, ev, settings)
    folder, meta, hit = cache.cached_stage(cache_root, f"configuration_{configuration}", inputs,
                                           build)
    return folder / "configuration", meta, hit


def configuration_chain(scene: Scene, configuration: str, ev: EvalConfig, cache_root: Path,
                        scene_hash: str, settings: dict | None = None) -> dict:
    """Everything one configuration needs before the two meet: the capture, its perturbation
    (robustness runs) and artrecon's per-configuration stage, each cached.

    Returns
    -------
    dict
        ``set`` (the image set artrecon reads), ``capture`` (capture metadata), ``key`` (the
        set's cache key), ``perturb`` (perturbation summary), ``configuration`` (the stage's
        folder), ``hits`` (names of the stages taken from the cache), ``build_s`` (seconds
        per stage as built).
    """
    stage = f"capture_{configuration}"
    try:
        folder, meta, hit = capture_stage(scene, configuration, ev, cache_root, scene_hash)
        set_dir, key, pmeta = perturb.set_stage(folder, meta["key"], scene, ev.perturb, ev.seed,
                                                configuration, cache_root)
        stage = "reconstruct"  # artrecon's per-configuration part of it
        conf, cmeta, chit = configuration_stage(set_dir, key, configuration, ev, cache_root,
                                                settings)
    except Exception as err:
        err.stage = stage  # which stage failed, for the scene's record (crosses processes)
        raise
    return {"set": set_dir, "capture": meta, "key": key, "perturb": pmeta,
            "configuration": conf,
            "hits": [n for n, h in ((f"capture_{configuration}", hit),
                                    (f"configuration_{configuration}", chit)) if h],
            "build_s": {f"capture_{configuration}": meta["build_s"],
                        f"configuration_{configuration}": cmeta["build_s"]}}


def configuration_chains(scene: Scene, ev: EvalConfig, cache_root: Path, scene_hash: str,
                         settings: dict | None = None) -> dict[str, dict | BaseException]:
    """:func:`configuration_chain` of A and B, each its result or its exception.

    With ``ev.parallel_capture``, B runs in a second process (spawned: its own MuJoCo and OpenGL
    context, no progress bar) while this process runs A: the two configurations are independent
    until their models are matched, and most of each chain (planning, physics, rendering,
    feature extraction, dense stereo) keeps one core busy.
    """
    out: dict[str, dict | BaseException] = {}
    pool = future = None
    if ev.parallel_capture:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        from dataclasses import replace

        pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        # the worker ignores Ctrl-C; this process stops it (one line, no worker traceback)
        future = workers.submit(pool, configuration_chain, scene, "b",
                                replace(ev, progress=False), cache_root, scene_hash, settings)
    try:
        for c in ("a", "b"):
            try:
                out[c] = (future.result() if c == "b" and future is not None
                          else configuration_chain(scene, c, ev, cache_root, scene_hash,
                                                   settings))
            except Exception as err:
                out[c] = err
    except KeyboardInterrupt:
        if pool is not None:
            workers.stop(pool)
        raise
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
    return out


def reconstruct_stage(set_a: Path, set_b: Path, keys: tuple[str, str], ev: EvalConfig,
                      cache_root: Path, settings: dict | None = None,
                      configurations: tuple[Path, Path] | None = None
                      ) -> tuple[Path, dict, bool]:
    """Reconstruct the model from the two image sets (cached), with the default settings
    changed by ``settings`` (the scene's, :attr:`sim.scene.Scene.reconstruct_settings`),
    starting from the finished per-configuration stages when given (:func:`configuration_stage`).
    Returns the model folder (``model.json``, ``a/sparse/0`` ...), stage metadata, hit."""
    import artrecon
    from artrecon.reconstruct import ReconstructConfig, _jsonable, reconstruct, with_settings

    config = with_settings(ReconstructConfig(), settings or {})
    inputs = {"captures": list(keys), "poses": ev.poses, "seed": ev.seed,
              "config": _jsonable(asdict(config)), "version": artrecon.__version__,
              "code": _reconstruct_sources()}

    def build(folder: Path) -> dict:
        model = reconstruct(set_a, set_b, poses=True if ev.poses == "fk" else None,
                            out_dir=folder / "model", seed=ev.seed, config=config,
                            progress=ev.progress, configurations=configurations)
        return {"timings": model.metadata.get("timings", {}),
                "links": len(model.links), "joints": len(model.joints)}

    folder, meta, hit = cache.cached_stage(cache_root, "reconstruct", inputs, build)
    return folder / "model", meta, hit


def sfm_camera_poses(model_dir: Path, configuration: str = "a") -> dict[str, np.ndarray]:
    """``{image name: T_model_camera (4, 4)}`` of a reconstruction's SfM model (OpenCV)."""
    import pycolmap

    from artrecon.sfm import camera_poses

    path = Path(model_dir) / configuration / "sparse" / "0"
    if not path.is_dir():
        raise FileNotFoundError(f"no SfM model at {path}: the reconstruction output lacks it")
    return camera_poses(pycolmap.Reconstruction(str(path)))


def register_configuration(model_dir: Path, set_dir: Path, configuration: str, seed: int):
    """The similarity from one configuration's SfM frame to the world (camera centres of the
    reconstruction against the arm's FK camera positions of the capture), the SfM poses and the
    registration record."""
    from artrecon.register import register_camera_centres

    sfm = sfm_camera_poses(model_dir, configuration)
    cams = read_json(Path(set_dir) / "cameras.json")
    names = [im["file"] for im in cams["images"]
             if im.get("T_world_camera") is not None and im["file"] in sfm]
    if len(names) < 3:
        raise StageError("registration", f"only {len(names)} images of "
                         f"{configuration.upper()} have both an SfM pose and an FK pose; need 3")
    fk = {im["file"]: np.asarray(im["T_world_camera"], float) for im in cams["images"]
          if im.get("T_world_camera") is not None}
    centres = np.array([sfm[n][:3, 3] for n in names])
    reg = register_camera_centres(centres, np.array([fk[n] for n in names]), seed=seed)
    return reg, sfm, cams, names


def register_stage(model, model_dir: Path, set_a: Path, scene: Scene, seed: int) -> dict:
    """Register the model into the world frame (camera-centre route) and try the PnP route.

    Returns
    -------
    dict with ``registered`` (ArticulatedModel in the world frame, metres), ``T`` (Similarity),
    ``sfm_poses`` ({name: T_model_camera}), ``summary`` (JSON-ready, incl. ``pnp``).
    """
    from artrecon.register import apply_registration

    reg, sfm, cams, names = register_configuration(model_dir, set_a, "a", seed)
    registered = apply_registration(model, reg.T_robot_model)
    summary = {"method": "camera centres (SfM of A vs FK), RANSAC Umeyama",
               **reg.summary(), "images_used": len(names), "images_of_a": len(cams["images"])}
    summary["pnp"], summary["pnp_reason"] = None, None
    try:
        summary["pnp"] = _pnp_route(model, model_dir, set_a, scene, cams, sfm, reg, seed)
    except Exception as err:  # a route that does not work is reported, not hidden
        summary["pnp_reason"] = f"{type(err).__name__}: {err}"
        log.warning("%s: PnP registration route failed: %s", scene.name, err)
    else:
        # issue 9: the two routes' agreement, overall and at each joint's axis, joins the
        # joints' confidence records of the registered model; routes that disagree refuse
        from artrecon.confidence import check_registration_agreement, registration_agreement

        summary["pnp"]["agreement"] = registration_agreement(
            model, reg.T_robot_model, summary["pnp"].pop("_T"), registered=registered)
        check_registration_agreement(summary["pnp"]["agreement"])
    return {"registered": registered, "T": reg.T_robot_model, "sfm_poses": sfm,
            "summary": summary}


def _pnp_route(model, model_dir, set_a, scene, cams, sfm, reg, seed) -> dict:
    """The paper's registration route on the capture of A; its disagreement with route (a)."""
    import pycolmap
    from PIL import Image

    from artrecon.register import (
        calibrate_hand_eye,
        compare_registrations,
        landmarks_from_tracks,
        localize_image,
        register_by_pnp,
        sift_features,
    )
    from artrecon.sfm import read_features
    from sim import robot

    kin = robot.load_arm_kinematics(scene.model)
    with_q = [im for im in cams["images"] if im.get("q") is not None and im["file"] in sfm]
    if len(with_q) < 3:
        raise StageError("registration", "fewer than 3 images of A with joint angles and an SfM "
                         "pose: no hand-eye calibration")
    G = np.array([kin.frame_pose(np.asarray(im["q"], float), "flange") for im in with_q])
    C = np.array([sfm[im["file"]] for im in with_q])
    scale = reg.T_robot_model.scale
    he = calibrate_hand_eye(G, C, scale)
    rec = pycolmap.Reconstruction(str(Path(model_dir) / "a" / "sparse" / "0"))
    feats = read_features(Path(model_dir) / "a" / "database.db")
    names = {int(i): im.name for i, im in rec.images.items()}
    L, LD = landmarks_from_tracks(rec.points3D, feats, names)
    last = cams["images"][-1]
    if last.get("q") is None:
        raise StageError("registration", "the last image of A has no joint angles")
    img = np.asarray(Image.open(Path(set_a) / "images" / last["file"]).convert("RGB"))
    kp, desc = sift_features(img)
    pnp = localize_image(kp, desc, L, LD, np.asarray(cams["K"], float), seed=seed)
    T_pnp = register_by_pnp(kin.frame_pose(np.asarray(last["q"], float), "flange"),
                            he.T_flange_camera, pnp.T_camera_model, scale)
    pts = np.concatenate([lk.points for lk in model.links if len(lk.points)])
    cmp = compare_registrations(reg.T_robot_model, T_pnp, pts)
    return {"image": last["file"],
            "note": "fresh image = the last image of A (also used by the SfM); scale from the "
                    "camera-centre route (monocular PnP cannot give it)",
            "hand_eye_backend": he.backend,
            "hand_eye_consistency_mm": he.translation_residual_mm,
            "hand_eye_consistency_deg": he.rotation_residual_deg,
            "pnp_inliers": int(pnp.inliers.sum()), "pnp_matches": int(len(pnp.matches)),
            "pnp_reprojection_rms_px": pnp.reprojection_rms,
            "disagreement": cmp.to_dict(), "_T": T_pnp}


def manipulation_stage(scene: Scene, registered, joint_index: int, set_a: Path,
                       keys: list[str], ev: EvalConfig, cache_root: Path,
                       scene_hash: str, swapped: bool = False,
                       true_joint: str | None = None) -> tuple[dict, dict, bool]:
    """Move the scene's joint ``true_joint`` (default :func:`sim.manipulate.default_joint`)
    along the estimated joint ``joint_index`` (cached).

    The arm grasps that joint's child link (sim.manipulate's default candidates); when the model
    took that link as the parent (``swapped``), the motion of the grasped link is the model's
    joint motion reversed: same axis line, opposite direction (the requested amount stays the
    model's motion A -> B).
    """
    from sim.manipulate import JointEstimate, default_joint, joint_estimate_from_model, manipulate

    true_joint = true_joint or default_joint(scene).name
    cams = read_json(set_a / "cameras.json")
    q_last = next((im["q"] for im in reversed(cams["images"]) if im.get("q") is not None), None)
    est, _, _ = joint_estimate_from_model(registered, joint_index)
    if swapped:
        est = JointEstimate(est.type, -est.axis, est.point, "model (parent/child swapped)",
                            est.name)
    amount = float(registered.joints[joint_index].motion)
    inputs = {"scene_hash": scene_hash, "keys": keys, "joint": joint_index,
              "true_joint": true_joint, "seed": ev.seed,
              "estimate": {"type": est.type, "axis": est.axis.tolist(),
                           "point": est.point.tolist(), "amount": amount},
              "q_start": q_last, "code": _manipulate_sources()}

    def build(folder: Path) -> dict:
        res = manipulate(scene, est, amount, q_start=q_last, seed=ev.seed, joint=true_joint)
        cache.write_json_atomic(folder / "manipulation.json", res.to_dict())
        return {}

    folder, meta, hit = cache.cached_stage(cache_root, "manipulation", inputs, build)
    return read_json(folder / "manipulation.json"), meta, hit


