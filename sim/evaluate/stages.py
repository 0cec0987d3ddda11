"""The stages of one scene's evaluation, each cached by the hash of its inputs."""

from __future__ import annotations

import atexit
import contextlib
import functools
import importlib
import inspect
import logging
import os
import platform
import threading
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, replace
from pathlib import Path

import cv2
import mujoco
import numpy as np
import pinocchio
import pycolmap
import scipy

import artrecon
import artrecon.configuration
from artrecon import workers
from artrecon.files import read_json
from artrecon.io import load_image_folder
from artrecon.reconstruct import (
    ReconstructConfig,
    prepare_configuration,
    reconstruct,
    with_settings,
)
from artrecon.register import (
    FreshImage,
    read_fresh_pose,
    register,
    register_camera_centres,
)
from artrecon.settings import jsonable
from artrecon.sfm import camera_poses
from sim import cache, capture_config, perturb
from sim.evaluate.config import EvalConfig, StageError
from sim.scene import Scene

log = logging.getLogger(__name__)

# sim.capture, sim.render and sim.manipulate load pyrender, which needs an EGL library: they are
# imported by the functions that capture or move the arm (the lines marked "EGL"), so that
# sim.evaluate loads without one (its --help, the reports).

# ---------------------------------------------------------------------------- stages


def versions() -> dict:
    return {"python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "mujoco": mujoco.__version__,
            "pycolmap": pycolmap.__version__, "pin": pinocchio.__version__,
            "opencv": cv2.__version__, "artrecon": artrecon.__version__}


def freeze_code_keys() -> None:
    """Hash the code of every stage now, once per process (each ``_*_sources`` is cached).

    The stage keys name the code that computes a stage, and that is the code this process
    loaded, not the files as they are later: hashed from disk at each stage, a file edited
    while a run goes on (a merge, an editor) filed stages built by the old code under the new
    code's key, and the next run took them as current. Called when an evaluation starts."""
    from sim.capture import plan_sources  # EGL: see the top

    for fn in (_capture_sources, _configuration_sources, _reconstruct_sources,
               _manipulate_sources, plan_sources):
        fn()


@functools.cache
def _capture_sources() -> str:
    from sim import camera, capture, render, robot, scene, views  # EGL: see the top

    return cache.source_hash([camera, capture, capture_config, render, robot, scene, views])


@functools.cache
def _reconstruct_sources() -> str:
    return cache.source_hash([artrecon])


@functools.cache
def _configuration_sources() -> str:
    """The code of artrecon's per-configuration stage alone (SfM, dense points, the object
    region: :mod:`artrecon.configuration` and what it imports, and reconstruct.py's functions
    that prepare its inputs), so that an edit of the later stages (matching, segmentation,
    joints, assignment) reuses the configurations instead of redoing SfM for it."""
    reconstruct_module = importlib.import_module("artrecon.reconstruct")  # not the function
    parts = [cache.closure_hash(artrecon.configuration)]
    parts += [inspect.getsource(f) for f in (reconstruct_module.prepare_configuration,
                                              reconstruct_module._resolve_inputs,
                                              reconstruct_module._configuration)]
    return cache.hash_bytes(*(p.encode() for p in parts))


@functools.cache
def _manipulate_sources() -> str:
    from sim import manipulate, robot, scene, views  # EGL: see the top
    from sim.manipulate import (  # EGL: see the top
        candidates,
        estimate,
        execute,
        planning,
        planning_config,
        planning_world,
        world,
    )

    return cache.source_hash([manipulate, estimate, execute, candidates, planning, planning_config,
                              planning_world, world, robot, scene, views])


def _settings_inputs(ev: EvalConfig) -> dict:
    """The capture settings off their defaults, for the keys of the stages they change (none at
    the defaults: the keys of a default run keep their form)."""
    changed = ev.capture_settings.changed()
    return {"capture_settings": jsonable(changed)} if changed else {}


def _capture_inputs(scene: Scene, configuration: str, ev: EvalConfig, scene_hash: str) -> dict:
    return {"scene": scene.name, "scene_hash": scene_hash, "config": configuration,
            "views": ev.views, "seed": ev.seed, "version": artrecon.__version__,
            "code": _capture_sources(), **_settings_inputs(ev),
            **perturb.capture_inputs(scene, ev.perturb, configuration)}


def capture_stage(scene: Scene, configuration: str, ev: EvalConfig, cache_root: Path,
                  scene_hash: str) -> tuple[Path, dict, bool]:
    """Capture one configuration (cached), with the evaluation's view plan
    (:meth:`EvalConfig.view_plan`) and capture settings, which key it with the scene, views and
    seed. Returns the image set folder, stage metadata, hit."""
    from sim.capture import capture  # EGL: see the top

    def build(folder: Path) -> dict:
        res = capture(perturb.capture_scene(scene, ev.perturb, configuration), configuration,
                      folder / "set", view_plan=ev.view_plan(),
                      capture_config=ev.capture_settings.capture, progress=ev.progress,
                      plan_cache=cache_root)  # the view plan outlives code edits of the capture
        return {"n_planned": res.n_planned, "n_captured": res.n_captured,
                "plan_cached": res.plan_cached,
                "unreachable": res.unreachable,
                "max_fk_position_error_mm": 1e3 * res.max_fk_position_error,
                "max_fk_rotation_error_deg": float(np.rad2deg(res.max_fk_rotation_error)),
                "timings": res.timings}

    inputs = _capture_inputs(scene, configuration, ev, scene_hash)
    folder, meta, hit = cache.cached_stage(cache_root, f"capture_{configuration}", inputs, build)
    return folder / "set", meta, hit


def _configuration_inputs(capture_key: str, configuration: str, ev: EvalConfig,
                          settings: dict | None) -> dict:
    config = with_settings(ReconstructConfig(), settings or {})
    return {"capture": capture_key, "config": configuration, "poses": ev.poses,
            "seed": ev.seed, "settings": jsonable({k: asdict(getattr(config, k))
                                                   for k in ("sfm", "dense", "region")}),
            "version": artrecon.__version__, "code": _configuration_sources()}


def configuration_stage(set_dir: Path, capture_key: str, configuration: str, ev: EvalConfig,
                        cache_root: Path, settings: dict | None = None,
                        loaded: dict | None = None) -> tuple[Path, dict, bool]:
    """artrecon's per-configuration stage (SfM or FK triangulation, dense points, the object
    region) of one captured set (cached). Returns its folder, stage metadata, hit.

    ``loaded``: when the stage is built, its checked image set
    (:func:`artrecon.io.load_image_folder`) is put there under ``"images"``, for the model
    stage (:func:`reconstruct_stage`), which then need not decode every image again."""
    config = with_settings(ReconstructConfig(), settings or {})

    def build(folder: Path) -> dict:
        images = load_image_folder(set_dir)
        prepare_configuration(images, folder / "configuration", seed=ev.seed, config=config,
                              poses=True if ev.poses == "fk" else None,
                              which=configuration.upper(), progress=ev.progress)
        if loaded is not None:
            loaded["images"] = images
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
        folder), ``images`` (the set as the configuration stage checked it,
        :class:`artrecon.io.ImageSet`, or None when that stage came from the cache), ``hits``
        (names of the stages taken from the cache), ``build_s`` (seconds per stage as built).
    """
    loaded: dict = {}
    stage = f"capture_{configuration}"
    try:
        folder, meta, hit = capture_stage(scene, configuration, ev, cache_root, scene_hash)
        set_dir, key, pmeta = perturb.set_stage(folder, meta["key"], scene, ev.perturb, ev.seed,
                                                configuration, cache_root)
        stage = "reconstruct"  # artrecon's per-configuration part of it
        conf, cmeta, chit = configuration_stage(set_dir, key, configuration, ev, cache_root,
                                                settings, loaded)
    except Exception as err:
        err.stage = stage  # which stage failed, for the scene's record (crosses processes)
        raise
    return {"set": set_dir, "capture_set": folder, "capture": meta, "key": key, "perturb": pmeta,
            "configuration": conf, "images": loaded.get("images"),
            "hits": [n for n, h in ((f"capture_{configuration}", hit),
                                    (f"configuration_{configuration}", chit)) if h],
            "build_s": {f"capture_{configuration}": meta["build_s"],
                        f"configuration_{configuration}": cmeta["build_s"]}}


#: The second process of this process's scenes and the thread that started it (see
#: :func:`second_process`), or None before the first scene, after a Ctrl-C or once closed.
_SECOND: tuple[ProcessPoolExecutor, threading.Thread] | None = None


def _start_second_process() -> ProcessPoolExecutor:
    # one core each: the CPU rasteriser's threads (read when a process first renders) and,
    # in artrecon's per-configuration stage, BLAS and OpenCV (artrecon.configuration). The
    # variable is set for the worker's start only: this process keeps the rasteriser threads
    # it had (it may render first after this, e.g. the texture check).
    saved = os.environ.get("LP_NUM_THREADS")
    os.environ.setdefault("LP_NUM_THREADS", "1")
    try:
        pool = workers.pool(1)
        # the worker starts now (a pool starts its workers at the first submit) and hashes its
        # stages' code, which B's chain would do first: about 2 s (its imports 1, the hashes
        # 0.8) beside this process's own start of the scene, not on B's chain
        workers.submit(pool, freeze_code_keys)
    finally:
        if saved is None:
            os.environ.pop("LP_NUM_THREADS", None)
    return pool


def _usable(pool: ProcessPoolExecutor, started_by: threading.Thread) -> bool:
    """A kept second process serves the next scene only from the thread that started it (its
    worker dies with that thread: see :func:`artrecon.workers.pool`) and only while it works."""
    processes = workers.processes(pool)
    return (started_by is threading.current_thread() and started_by.is_alive()
            and not getattr(pool, "_broken", False) and not getattr(pool, "_shutdown_thread", False)
            and all(p.is_alive() for p in processes))


def close_second_process() -> None:
    """Shut the kept second process down (after its tasks); the next scene starts another.
    Registered to run when this process exits."""
    global _SECOND
    kept, _SECOND = _SECOND, None
    if kept is not None:
        kept[0].shutdown(wait=True)


atexit.register(close_second_process)


def process_cpu_s(pool: ProcessPoolExecutor | None) -> float | None:
    """User + system CPU seconds the worker of ``pool`` (a second process) has used so far, read
    from ``/proc`` without asking the worker (it may be busy); None without a pool, a worker or
    ``/proc``. A kept worker is nobody's finished child until it ends, so the evaluating
    process's own ``RUSAGE_CHILDREN`` does not hold its CPU: a scene's record takes the
    difference over the scene (``second_process_cpu_s``)."""
    processes = workers.processes(pool)
    if len(processes) != 1:
        return None
    try:
        fields = Path(f"/proc/{processes[0].pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    # after the command's closing parenthesis: state is field 3, utime 14 and stime 15
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@contextlib.contextmanager
def second_process(ev: EvalConfig) -> Iterator[ProcessPoolExecutor | None]:
    """The scene's second process (spawned, one worker that dies with this one), or None
    without ``ev.parallel_capture``: configuration B's chain runs there beside A's
    (:func:`configuration_chains`), then the manipulation beside the scoring
    (:func:`sim.evaluate.runner.evaluate_scene`). One process for both.

    The process is kept for this process's next scene (:func:`close_second_process` ends it,
    at the latest when this process exits): a worker costs about 2 CPU seconds to start
    (imports, its stages' code keys, its OpenGL context), and a new one per scene held B's
    chain back by about 1.5 s at every scene's start. When the block ends every task given to
    the worker in it has ended (the next scene finds it idle). Ctrl-C stops it at once; a
    worker that died or was stopped is replaced at the next scene."""
    global _SECOND
    if not ev.parallel_capture:
        yield None
        return
    if _SECOND is None or not _usable(*_SECOND):
        close_second_process()
        _SECOND = (_start_second_process(), threading.current_thread())
    pool = _SECOND[0]
    try:
        yield pool
    except KeyboardInterrupt:
        _SECOND = None
        workers.stop(pool)
        raise
    finally:
        if _SECOND is not None and _SECOND[0] is pool:
            try:  # one worker, its tasks in order: this one ends after every task before it
                pool.submit(int).result()
            except Exception:  # noqa: BLE001  (a dead worker: the next scene starts another)
                close_second_process()


def configuration_chains(scene: Scene, ev: EvalConfig, cache_root: Path, scene_hash: str,
                         settings: dict | None = None,
                         pool: ProcessPoolExecutor | None = None
                         ) -> dict[str, dict | BaseException]:
    """:func:`configuration_chain` of A and B, each its result or its exception.

    With ``pool`` (:func:`second_process`), B runs in that second process (spawned: its own
    MuJoCo and OpenGL context, no progress bar) while this process runs A: the two
    configurations are independent until their models are matched, and most of each chain
    (planning, physics, rendering, feature extraction, dense stereo) keeps one core busy.
    Without it (and with ``ev.parallel_capture``) a second process is started for B and
    stopped after it.
    """
    if pool is None and ev.parallel_capture:
        with second_process(ev) as own:
            return configuration_chains(scene, ev, cache_root, scene_hash, settings, own)
    out: dict[str, dict | BaseException] = {}
    future = None
    if pool is not None:
        # the worker ignores Ctrl-C; this process stops it (one line, no worker traceback)
        future = workers.submit(pool, configuration_chain, scene, "b",
                                replace(ev, progress=False), cache_root, scene_hash, settings)
    for c in ("a", "b"):
        try:
            out[c] = (future.result() if c == "b" and future is not None
                      else configuration_chain(scene, c, ev, cache_root, scene_hash, settings))
        except Exception as err:
            out[c] = err
    return out


def reconstruct_stage(set_a: Path, set_b: Path, keys: tuple[str, str], ev: EvalConfig,
                      cache_root: Path, settings: dict | None = None,
                      configurations: tuple[Path, Path] | None = None,
                      images: tuple | None = None) -> tuple[Path, dict, bool]:
    """Reconstruct the model from the two image sets (cached), with the default settings
    changed by ``settings`` (the scene's, :attr:`sim.scene.Scene.reconstruct_settings`),
    starting from the finished per-configuration stages when given (:func:`configuration_stage`).
    ``images``: the sets as those stages checked them (each an :class:`artrecon.io.ImageSet`
    or None), which the model stage takes instead of decoding every image again (their files
    are checked by their digests). Returns the model folder (``model.json``, ``a/sparse/0``
    ...), stage metadata, hit."""
    given = tuple(images) if images is not None else (None, None)
    config = with_settings(ReconstructConfig(), settings or {})
    inputs = {"captures": list(keys), "poses": ev.poses, "seed": ev.seed,
              "config": jsonable(asdict(config)), "version": artrecon.__version__,
              "code": _reconstruct_sources()}

    def build(folder: Path) -> dict:
        model = reconstruct(given[0] or set_a, given[1] or set_b,
                            poses=True if ev.poses == "fk" else None,
                            out_dir=folder / "model", seed=ev.seed, config=config,
                            progress=ev.progress, configurations=configurations)
        return {"timings": model.metadata.get("timings", {}),
                "links": len(model.links), "joints": len(model.joints)}

    folder, meta, hit = cache.cached_stage(cache_root, "reconstruct", inputs, build)
    return folder / "model", meta, hit


def sfm_camera_poses(model_dir: Path, configuration: str = "a") -> dict[str, np.ndarray]:
    """``{image name: T_model_camera (4, 4)}`` of a reconstruction's SfM model (OpenCV)."""
    path = Path(model_dir) / configuration / "sparse" / "0"
    if not path.is_dir():
        raise FileNotFoundError(f"no SfM model at {path}: the reconstruction output lacks it")
    return camera_poses(pycolmap.Reconstruction(str(path)))


def register_configuration(model_dir: Path, set_dir: Path, configuration: str, seed: int):
    """The similarity from one configuration's SfM frame to the world (camera centres of the
    reconstruction against the arm's FK camera positions of the capture), the SfM poses and the
    registration record. Used by scoring for configuration B (its points are scored where B's
    reconstruction saw them); the model itself is registered by :func:`register_stage`."""
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


def last_arm_pose(capture_set: Path) -> list[float]:
    """The arm's joint angles at the last image of a capture: where the capture left it (the
    capture's own record, before any perturbation of what the robot reports)."""
    cams = read_json(Path(capture_set) / "cameras.json")
    q = next((im["q"] for im in reversed(cams["images"]) if im.get("q") is not None), None)
    if q is None:
        raise StageError("fresh_view", f"no image of {capture_set} has the arm's joint angles")
    return q


def fresh_view_stage(scene: Scene, capture_set: Path, capture_key: str, ev: EvalConfig,
                     cache_root: Path) -> tuple[Path, dict, bool]:
    """One image after the reconstruction, from an arm pose in neither image set (cached):
    :func:`sim.capture.capture_fresh_view` from where the capture of A left the arm, with the
    evaluation's capture settings and view plan (:meth:`EvalConfig.view_plan`) like the
    captures, its pose file perturbed like the capture's (robustness runs). Returns its folder,
    metadata, hit."""
    from sim.capture import capture_fresh_view  # EGL: see the top

    q_start = last_arm_pose(capture_set)
    sphere = read_json(Path(capture_set) / "capture.json").get("object_sphere")
    if sphere is None:
        raise StageError("fresh_view", f"{capture_set}/capture.json has no object_sphere (the "
                         "survey's sphere the capture looked at): capture the set again")

    def build(folder: Path) -> dict:
        fv = capture_fresh_view(perturb.capture_scene(scene, ev.perturb, "a"), "a", q_start,
                                folder / "fresh", seed=ev.seed,
                                capture_config=ev.capture_settings.capture,
                                plan_config=ev.view_plan(),
                                target=(sphere["centre"], sphere["radius"],
                                        (sphere.get("survey") or {}).get("hull_vertices")))
        perturb.perturb_fresh_pose(fv.pose_file, scene, ev.perturb, ev.seed)
        return {"q": fv.q.tolist()}  # the arm's configuration now: the manipulation's start

    inputs = {"capture": capture_key, "seed": ev.seed, "code": _capture_sources(),
              "perturb": ev.perturb.changed(), **_settings_inputs(ev)}
    folder, meta, hit = cache.cached_stage(cache_root, "fresh_view", inputs, build)
    return folder / "fresh", meta, hit


def fresh_arm_pose(fresh_meta: dict) -> list[float]:
    """The arm's joint angles (rail first) at which the fresh view was taken, as
    :func:`fresh_view_stage` records them (the arm's own measured joints after its move there,
    before any perturbation of what the robot reports, like :func:`last_arm_pose`): where the
    arm is when the registration is done and the manipulation starts."""
    q = fresh_meta.get("q")
    if not q:
        raise StageError("fresh_view", "the fresh view's record holds no arm joint angles "
                         f"(stage key {fresh_meta.get('key')}): delete that cache folder")
    return [float(x) for x in q]


def register_stage(model_dir: Path, set_a: Path, fresh: Path, seed: int) -> dict:
    """Register the model with artrecon's registration stage (:func:`artrecon.register.register`),
    both routes: (a) the SfM camera centres of A against the arm's FK camera positions of
    cameras.json; (b) PnP of the fresh image, its flange pose from the arm's FK and the hand-eye
    transform calibrated from the capture of A (flange poses and SfM poses), with the scale that
    calibration estimates: nothing borrowed from route (a). Routes that disagree are refused
    (RegistrationMismatchError).

    Returns
    -------
    dict with ``registered`` (ArticulatedModel, world frame, metres), ``T`` (Similarity of
    route (a)), ``routes`` ({route: Similarity}), ``sfm_poses`` ({name: T_model_camera}) and
    ``summary`` (JSON-ready report).
    """
    pose = read_fresh_pose(Path(fresh) / "pose.json")
    res = register(model_dir, camera_poses=Path(set_a) / "cameras.json",
                   images=[FreshImage(Path(fresh) / "fresh.png", pose.get("T_world_flange"))],
                   out_dir=False, seed=seed)
    summary = {"chosen_route": res.route, **res.report()}
    return {"registered": res.model, "T": res.T_robot_model,
            "routes": {k: v["T"] for k, v in res.routes.items()},
            "sfm_poses": sfm_camera_poses(model_dir, "a"), "summary": summary}


def manipulation_stage(scene: Scene, registered, model_joint: int, q_start, keys: list[str],
                       ev: EvalConfig, cache_root: Path, scene_hash: str
                       ) -> tuple[dict, dict, bool]:
    """Move the model's joint ``model_joint`` as the model says (cached): the arm plans from the
    registered model alone (:func:`sim.manipulate.manipulate` with ``registered``), grasps the
    joint's child link and moves it by the model's motion A -> B along the model's axis, from
    ``q_start`` (where the fresh view left the arm: :func:`fresh_arm_pose`; grasp points are
    judged hidden from the wrist camera there). Returns the result record, stage metadata,
    hit. A plan or grasp that fails is recorded (``error``), not raised."""
    from sim.manipulate import (  # EGL: see the top
        ManipulationError,
        joint_estimate_from_model,
        manipulate,
    )

    est = joint_estimate_from_model(registered, model_joint)
    amount = float(registered.joints[model_joint].motion)
    inputs = {"scene_hash": scene_hash, "keys": keys, "joint": model_joint, "seed": ev.seed,
              "estimate": {"type": est.type, "axis": est.axis.tolist(),
                           "point": est.point.tolist(), "amount": amount},
              "model_points": cache.hash_bytes(*(np.ascontiguousarray(lk.points, float).tobytes()
                                                 for lk in registered.links)),
              "q_start": list(q_start), "code": _manipulate_sources()}

    def build(folder: Path) -> dict:
        try:
            res = manipulate(scene, est, amount, registered=registered, model_joint=model_joint,
                             q_start=q_start, seed=ev.seed)
            out = res.to_dict()
        except ManipulationError as err:
            out = {"error": f"{type(err).__name__}: {err}", "requested": amount,
                   "estimate": {"type": est.type, "axis": est.axis.tolist(),
                                "point": est.point.tolist(), "name": est.name}}
        cache.write_json_atomic(folder / "manipulation.json", out)
        return {}

    folder, meta, hit = cache.cached_stage(cache_root, "manipulation", inputs, build)
    return read_json(folder / "manipulation.json"), meta, hit
