"""One scene's evaluation and a run over scenes: the harness's main job.

Per scene (a bundled name or an MJCF path; default: every bundled scene):

1. **capture** both configurations with the arm (:func:`sim.capture.capture`);
2. **reconstruct** the articulated model from the two image sets (:func:`artrecon.reconstruct`),
   in the frame of the arm's FK camera poses (default) or, with ``--poses images``, in
   configuration A's SfM frame;
3. **register** it to the robot (world) frame in metres: the similarity between the SfM camera
   centres of configuration A and the FK camera positions of ``cameras.json``
   (:func:`artrecon.register.register_camera_centres`). The paper's route (hand-eye calibration
   from the capture + PnP of the last image of A) is run beside it and its disagreement reported;
   when it fails the report says so (``null`` and the reason);
4. **manipulate**: the arm grasps the child link of the scene's first moving joint that has an
   estimated joint (:func:`manipulation_target`; a static joint has none) at the point
   :func:`sim.manipulate.manipulate` chooses by default (preferring one hidden from the wrist camera
   at the fresh view's pose, where the arm is after the registration) and moves it along the
   *estimated* joint by the *estimated* motion A -> B, starting from that pose;
5. **score** everything against the ground truth (:mod:`sim.metrics`), see :func:`score_scene`.

Stage results are cached under ``OUT/cache/<stage>-<hash>/`` by the hash of their inputs
(:mod:`sim.cache`): scene file and every file it references, configuration, views, seed, the
stage's settings, the package version and the source of the code that computes it. A second run
redoes only what changed; ``timings_s`` then reports the time the cached stage took when it was
built (``cached_stages`` names them). The report (:mod:`sim.report`) goes to ``OUT``:
``results.json``, ``results.md``, ``<scene>_reconstruction.png``, ``<scene>_errors.png``; the
table is printed at the end. A scene that fails records its error (stage and message) and the run
goes on; the exit status is 1 if any scene failed.

Ground truth used for scoring (never given to ``artrecon``):

- joints: :class:`sim.scene.Joint` (world axis and point at configuration A, values in A and B);
  each moving joint is paired with the estimated joint between the same two links (then, for the
  rest, by axis geometry: :func:`pair_joints`); ``tree_correct`` says whether every pair joins
  the right links, ``invented_joints`` lists estimates left over, ``static_joints`` the joints
  that did not move (never expected to be found: their child link is one rigid body with its
  parent, and is scored as part of it, :func:`rigid_bodies`);
- true surfaces: the object's visual meshes placed by MuJoCo at configuration A, sampled
  uniformly by area (:data:`SURFACE_SPACING_M`, fixed seed), each sample labelled with its link.
  They score the model's accuracy and completeness;
- link labels: ``ground_truth/labels`` and ``ground_truth/depth`` of each capture (rendered at the
  true camera poses). Segmentation accuracy gives every model point the link that most of the
  views holding it show (:func:`segmentation_truth`), in the configuration the point was seen in
  (``Link.observed_in``: a point of B is placed where B's reconstruction saw it, through B's own
  registration); points no view holds on the object are off it (``off_surface_share``, left
  out). Then :func:`sim.metrics.segmentation_accuracy` (best one-to-one renaming of the model's
  links). ``segmentation.accuracy_nearest_surface_at_a`` keeps the earlier figure (every point
  at A, nearest true surface sample within :data:`SEGMENTATION_MAX_DISTANCE_M`);
- the hidden side: samples not visible from the last captured view of A (outside the image, or
  behind the rendered depth of ``ground_truth/depth``);
- camera poses: ``ground_truth/poses.json`` of the capture.

``--validate-only`` keeps the old behaviour: compile every scene, step 1 s of physics, print the
ground truth, no capture.
"""

from __future__ import annotations

import datetime
import logging
import platform
import time
import traceback
from collections.abc import Iterable
from concurrent.futures import Future
from pathlib import Path

from artrecon import workers
from artrecon.model import ArticulatedModel
from sim import cache, perturb
from sim.evaluate import gates
from sim.evaluate.config import EvalConfig
from sim.evaluate.scoring import (
    manipulation_reference_stage,
    score_manipulation,
    score_registration,
    score_scene,
    score_survey,
    summarise_manipulations,
    true_registration,
)
from sim.evaluate.stages import (
    configuration_chains,
    freeze_code_keys,
    fresh_arm_pose,
    fresh_view_stage,
    manipulation_stage,
    process_cpu_s,
    reconstruct_stage,
    register_configuration,
    register_stage,
    second_process,
    versions,
)
from sim.scene import load_scene
from sim.texture_check import check_texture

log = logging.getLogger(__name__)

# ---------------------------------------------------------------------------- one scene


def evaluate_scene(name: str, ev: EvalConfig, out_dir: Path) -> dict:
    """Run and score one scene; never raises for a failing stage (``error`` says which)."""
    out_dir = Path(out_dir)
    cache_root = out_dir / "cache"
    result: dict = {"scene": name, "error": None, "error_stage": None, "timings_s": {},
                    "cached_stages": [], "joints": [], "segmentation_accuracy": None,
                    "manipulation": None}
    timings = result["timings_s"]
    stage = "load"
    t_scene = time.perf_counter()
    scene_pool, cpu_before = None, None
    try:
        # the second process starts first: its start (imports, its stage keys) runs beside this
        # process's stage keys, the scene's loading and the texture check
        with second_process(ev) as pool:
            scene_pool, cpu_before = pool, process_cpu_s(pool)
            freeze_code_keys()  # the stages are keyed by the code this process runs
            scene = load_scene(name)
            result["scene"] = scene.name
            stage = "texture_check"  # a part too plain for features fails here, in seconds
            check_texture(scene)
            stage = "load"
            scene = perturb.apply_motion(scene, ev.perturb.motion_deg, ev.perturb.motion_mm)
            result["scene_file"] = str(scene.path)
            scene_hash = cache.scene_hash(scene.path)
            result["scene_hash"] = scene_hash
            sets, keys, confs, capture_sets, images = {}, [], {}, {}, {}
            stage = "capture_a"
            chains = configuration_chains(scene, ev, cache_root, scene_hash,
                                          dict(scene.reconstruct_settings), pool)
            for c in ("a", "b"):
                stage = f"capture_{c}"
                if isinstance(chains[c], BaseException):
                    stage = getattr(chains[c], "stage", stage)
                    raise chains[c]
                chain = chains[c]
                meta = chain["capture"]
                sets[c], confs[c] = chain["set"], chain["configuration"]
                images[c] = chain["images"]
                capture_sets[c] = chain["capture_set"]
                keys.append(chain["key"])
                if chain["perturb"]:
                    result[f"perturb_{c}"] = chain["perturb"]
                timings[stage] = meta["build_s"]
                result["cached_stages"] += chain["hits"]
                result[f"capture_{c}"] = {k: meta[k] for k in
                                          ("n_planned", "n_captured", "max_fk_position_error_mm",
                                           "max_fk_rotation_error_deg") if k in meta}
                result[f"capture_{c}"].update(score_survey(chain["capture_set"]))
            result["_sets"] = {c: str(p) for c, p in sets.items()}
            stage = "reconstruct"
            model_dir, meta, hit = reconstruct_stage(sets["a"], sets["b"], tuple(keys), ev,
                                                     cache_root, dict(scene.reconstruct_settings),
                                                     (confs["a"], confs["b"]),
                                                     (images["a"], images["b"]))
            result["_model_dir"] = str(model_dir)
            rt = meta.get("timings", {})
            timings["sfm"] = rt.get("sfm_a", 0.0) + rt.get("sfm_b", 0.0)
            timings["dense"] = rt.get("dense_a", 0.0) + rt.get("dense_b", 0.0)
            timings["matching"] = rt.get("match", 0.0)
            timings["segmentation_joints"] = rt.get("segment", 0.0) + rt.get("joints", 0.0)
            timings["assign_points"] = rt.get("assign", 0.0)
            result["reconstruct_timings_s"] = rt
            result["cached_stages"] += ["sfm", "dense", "matching", "segmentation_joints",
                                        "assign_points"] if hit else []
            stage = "match_outliers"
            model_dir, pmeta = perturb.outlier_stage(model_dir, meta["key"], ev.perturb, ev.seed,
                                                     cache_root, dict(scene.reconstruct_settings))
            if pmeta:
                result["perturb_matches"] = pmeta
            model = ArticulatedModel.load(model_dir / "model.json")
            result["model_summary"] = {"links": len(model.links), "joints": len(model.joints),
                                       **{k: model.metadata.get(k) for k in
                                          ("registered_images", "num_images", "sparse_points",
                                           "dense_points", "matches", "match_outliers",
                                           "pose_agreement")}}

            stage = "fresh_view"
            t = time.perf_counter()
            fresh, fmeta, fhit = fresh_view_stage(scene, capture_sets["a"], keys[0], ev,
                                                  cache_root)
            result["cached_stages"] += ["fresh_view"] if fhit else []
            q_arm = fresh_arm_pose(fmeta)  # where the arm is now: the manipulation starts there
            timings["fresh_view"] = time.perf_counter() - t

            stage = "registration"
            t = time.perf_counter()
            reg = register_stage(model_dir, sets["a"], fresh, ev.seed)
            timings["registration"] = time.perf_counter() - t
            registered = reg["registered"]
            result["registration"] = {**reg["summary"], **score_registration(
                reg["routes"], true_registration(model_dir, sets["a"]), model)}

            # the manipulation plans from the registered model alone: the second process moves
            # every other joint (from the first) while this one scores, then moves the rest
            elsewhere, t_manip = None, time.perf_counter()
            if ev.manipulate and pool is not None and registered.joints:
                theirs = range(0, len(registered.joints), 2)
                elsewhere = (theirs, workers.submit(
                    pool, manipulation_runs, theirs, scene, registered, q_arm, keys, ev,
                    cache_root, scene_hash))

            stage = "scoring"
            t = time.perf_counter()
            # B's own registration places B's points where B's reconstruction saw them (scoring)
            reg_b = register_configuration(model_dir, sets["b"], "b", ev.seed)[0].T_robot_model
            scores = score_scene(scene, registered, reg["sfm_poses"], reg["T"], sets["a"],
                                 ev.seed, set_b=sets["b"], model=model, T_reg_b=reg_b)
            timings["scoring"] = time.perf_counter() - t
            result.update({k: v for k, v in scores.items() if not k.startswith("_")})
            result["_arrays"] = {k: v for k, v in scores.items() if k.startswith("_")}
            result["_registered"] = registered
            result["_set_a"] = str(sets["a"])

            if ev.manipulate:
                stage = "manipulation"
                result["manipulation"] = _manipulations(scene, registered, result, q_arm, keys,
                                                        ev, cache_root, scene_hash, elsewhere)
                # from the first joint's start: beside the scoring when a second process helps
                timings["manipulation"] = time.perf_counter() - t_manip
    except Exception as err:
        result["error"] = f"{stage}: {type(err).__name__}: {err}"
        result["error_stage"] = stage
        result["traceback"] = traceback.format_exc()
        log.error("%s failed in stage %s: %s", name, stage, err)
    result["wall_s"] = time.perf_counter() - t_scene
    # the kept second process's CPU over the scene (its block has waited for its tasks)
    cpu_after = process_cpu_s(scene_pool)
    if cpu_before is not None and cpu_after is not None:
        result["second_process_cpu_s"] = cpu_after - cpu_before
    v = gates.verdict(result, manipulate=ev.manipulate)
    result["passed"], result["failed_gates"] = v["passed"], v["failed"]
    return result


def manipulation_runs(joints, scene, registered, q_start, keys, ev, cache_root,
                      scene_hash) -> dict[int, tuple[dict, bool]]:
    """:func:`manipulation_stage` of each of the model's ``joints`` (indices), in turn: ``{joint:
    (its run record, taken from the cache)}``. Each starts from ``q_start`` in a world of its own,
    so they may run in any process and order (the second process takes some of them)."""
    out = {}
    for k in joints:
        run, _, hit = manipulation_stage(scene, registered, k, q_start, keys, ev, cache_root,
                                         scene_hash)
        out[k] = (run, hit)
    return out


def _manipulations(scene, registered, result, q_start, keys, ev, cache_root,
                   scene_hash, elsewhere: tuple[Iterable[int], Future] | None = None) -> dict:
    """Every joint of the model moved in turn, each as the model says (:func:`manipulation_stage`:
    planned from the registered model alone, from the arm's configuration ``q_start``: where the
    fresh view left it); then scored: the true joint each estimates (the scoring's pairing), how
    far it moved against the requested motion, the force against the force the true joint
    needs (:func:`manipulation_reference_stage`).

    ``elsewhere``: the joints another process moves and the future of its
    :func:`manipulation_runs`. This process moves the others first and only then waits for it:
    waiting first left this process idle while the other moved its joint (cabinet: the door
    8.7 s, then the drawer 5 s after it, one core idle)."""
    by_est = {r["estimated_joint"]: r for r in result.get("joints") or []
              if r.get("estimated_joint") is not None}
    theirs, future = elsewhere if elsewhere is not None else ((), None)
    theirs = set(theirs)
    done = manipulation_runs([k for k in range(len(registered.joints)) if k not in theirs],
                             scene, registered, q_start, keys, ev, cache_root, scene_hash)
    if future is not None:
        done.update(future.result())
    runs = []
    for k, j in enumerate(registered.joints):
        run, hit = done[k]
        if hit:
            result["cached_stages"].append(f"manipulation[{j.name}]")
        row = by_est.get(j.name)
        reference = None
        if row is not None and not run.get("error"):
            reference, _, _ = manipulation_reference_stage(scene, row["name"], run, q_start,
                                                           cache_root, scene_hash)
        runs.append(score_manipulation(scene, j.name, run, row, reference))
    return {**summarise_manipulations(runs),
            "q_start": None if q_start is None else [float(x) for x in q_start],
            "q_start_from": "the fresh view's arm pose (where the registration left the arm)"}


# ---------------------------------------------------------------------------- run


def run_meta(ev: EvalConfig, command: str) -> dict:
    """The ``meta`` record of a results.json: versions, settings (the capture settings only when
    set), command, date, platform (``scene_hashes`` is filled in as scenes run)."""
    settings = ev.capture_settings.changed()
    return {"versions": versions(), "seed": ev.seed, "views_per_ring": ev.views,
            "poses": ev.poses, "manipulate": ev.manipulate,
            "perturbation": ev.perturb.changed(),
            **({"capture_settings": settings} if settings else {}), "command": command,
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "scene_hashes": {}, "gates": gates.GATES, "platform": platform.platform()}
