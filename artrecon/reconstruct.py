"""The whole reconstruction: two image folders in, an articulated model out.

Stages (each its own module, plain data between them)::

    sfm (per configuration) -> dense (per configuration) -> object region -> features (A x B)
        -> segment_links -> the matches' points refined photometrically (artrecon.match_refine)
        -> dense points the table is seen through dropped (artrecon.freespace)
        -> dense points assigned to links -> estimate_joints -> refine_joints
        -> ArticulatedModel

Where they live: this module is the entry (:func:`reconstruct`: the inputs checked, the output
folder, which stages run); :mod:`artrecon.configuration` is the per-configuration stage (SfM,
dense points, object region); :mod:`artrecon.matches_stage` the matches stage (matching A x B
lifted to 3D-3D pairs, the background's, the guided matching's candidates, the covariances);
:mod:`artrecon.links_stage` the links (:func:`artrecon.articulation.find_links`: segmentation,
the base, guided matches, robust refit, dense labels; the links' motions:
:mod:`artrecon.link_motions`); :mod:`artrecon.joints_stage` the kinematic tree and the joints
(:func:`artrecon.articulation.find_joints`); :mod:`artrecon.refine_stage` the joints'
articulated bundle adjustment; :mod:`artrecon.model_stage` the model and its files. The
settings of every stage are one :class:`artrecon.settings.ReconstructConfig`.

The model frame is configuration A's SfM frame: arbitrary scale and placement when the
cameras were found from the images alone (``model.scale_known`` is False), the frame of the given
camera poses (metres) when poses were given.

Background. The object stands on a table in a room; neither the background nor the object's base
moves between A and B, but the two SfM models are independent, so the background would join the
base link's rigid set (and its points the base link). It is told apart by
:func:`artrecon.dense.object_region`: points far from where the cameras' optical axes meet
(relative to the camera distance) are dropped, and so is the support plane the cameras all look
down on (with everything beyond it). Segmentation and the link point sets use the object only. A
sample of background points is matched as well, for one purpose: the link whose A->B transform
carries the background along is the base, the root of the kinematic tree (without background
matches, the largest link is the root).

Output folder (written whole or not at all: built in a temporary sibling folder, then renamed)::

    OUT/model.json                    the ArticulatedModel (ArticulatedModel.load reads it)
    OUT/matches.npz                   the 3D-3D matches the links were fitted to (points_a,
                                      points_b, ids, votes, labels; the guided ones appended),
                                      background_a, background_b (a copy of
                                      OUT/links/matches.npz)
    OUT/a/sparse/0, OUT/b/sparse/0    the SfM models in COLMAP's layout (+ database.db, colmap.log)
    OUT/a/dense.ply, OUT/b/dense.ply  the object's dense points of each configuration (own frame)
    OUT/a/configuration.json, ...     the per-configuration stage's record and its other files
                                      (the folder contract of artrecon.configuration)
    OUT/matches/                      the matches stage's folder (artrecon.matches_stage)
    OUT/links/                        the links stage's (artrecon.links_stage), with
                                      link_<k>.ply: each link's dense oriented points (model
                                      frame)
    OUT/joints/                       the joints stage's (artrecon.joints_stage)
    OUT/refine/                       the refinement stage's (artrecon.refine_stage)

Running part of it (:data:`STAGES`; ``from_stage``/``to_stage``, the command's ``--from`` and
``--to``). A run may stop after any stage and start at any stage::

    configurations   images -> OUT/a, OUT/b (each: SfM, dense points, object region; written
                     side by side, the record configuration.json last)
    matches          OUT/a, OUT/b -> OUT/matches/ (the record matches.json last)
    links            OUT/matches/, OUT/a, OUT/b -> OUT/links/ (links.json last)
    joints           OUT/links/ -> OUT/joints/ (joints.json last)
    refine           OUT/links/, OUT/joints/, the SfM of OUT/a, OUT/b -> OUT/refine/
                     (refine.json last)
    model            all of them -> OUT/model.json, OUT/matches.npz

``to_stage`` publishes a folder holding the stages up to it. A later start takes such a folder
(or a whole result, with ``overwrite``) and checks what it starts from against this run, never
recomputing it quietly (InputError naming what differs and which stage to start from instead):
each configuration's record must name the same images, intrinsics, poses, settings (sfm, dense,
region), seed and artrecon version as this run, and the record of each later stage before
``from_stage`` the record of the stage before it (its digest), the settings it reads (the
matches: ``match.*`` and ``segmentation.covariances``; the links: ``segmentation.*``,
``guided.*``, ``assign.*``, ``freespace.*``, ``region.*``; the joints: ``joints.*``,
``confidence.*``; the refinement: ``refine.*``), seed and version, with its files whole. The
settings of the stages it runs may differ: ``from_stage="joints"`` with other joint settings
estimates the joints again on the same links. The folder is published again whole, the stages
before ``from_stage`` copied and the later ones added.

The continued run's model is the one the whole run gives, bit for bit (tests/test_stages.py):
the whole run reads configuration B back from its folder too (A's folder holds what A's stage
returned, artrecon.configuration), and each later stage reads the ones before it back from
their folders as a continued run does. Nothing finer is a stage: a configuration's SfM and
dense points share one record, so a folder whose dense stage failed holds no result a later run
could check.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from artrecon import workers
from artrecon.configuration import (
    Configuration,
    check_reusable,
    load_configuration,
    reconstruct_configuration,
    stage_settings,
)
from artrecon.errors import InputError
from artrecon.files import (
    check_output_dir,
    check_output_path,
    publish_dir,
    read_json,
    work_dir,
)
from artrecon.io import (
    ImageSet,
    Intrinsics,
    check_distinct,
    image_set_again,
    load_cameras_json,
    load_image_folder,
    load_region,
    parse_intrinsics,
)
from artrecon.joints_stage import check_joints, load_joints, run_joints
from artrecon.links_stage import check_links, load_links, run_links
from artrecon.matches_stage import check_matches, load_matches, match_stage
from artrecon.model import ArticulatedModel
from artrecon.model_stage import build_model
from artrecon.refine_stage import check_refine, load_refine, run_refine
from artrecon.settings import ReconstructConfig, with_settings

log = logging.getLogger(__name__)

#: The entry points (``with_settings`` and ``ReconstructConfig`` make the ``config`` that
#: :func:`reconstruct` takes; they live in :mod:`artrecon.settings`).
__all__ = ["STAGES", "ReconstructConfig", "prepare_configuration", "reconstruct",
           "with_settings"]

#: The stages a run can start at or stop after (:func:`reconstruct`'s ``from_stage`` and
#: ``to_stage``, the command's ``--from`` and ``--to``), in order, with what each leaves in the
#: output folder for the next. Nothing finer: a configuration's SfM and dense points are one
#: record (:mod:`artrecon.configuration`).
STAGES = {
    "configurations": "OUT/a and OUT/b: each configuration's cameras (SfM), dense points and "
                      "object region",
    "matches": "OUT/matches/: the 3D-3D matches across A and B, the background matches, the "
               "guided matching's candidates and the covariances",
    "links": "OUT/links/: the links of the matches (RANSAC, the base, guided matches, robust "
             "refit) and every dense point's link",
    "joints": "OUT/joints/: the kinematic tree, the joints and their evidence",
    "refine": "OUT/refine/: the joints' articulated bundle adjustment (uncertainty, refined "
              "figures)",
    "model": "OUT/model.json, OUT/matches.npz: the articulated model",
}
#: Files that tell a folder written by :func:`reconstruct` (whole, or stopped after a stage)
#: from any other folder.
OUTPUT_MARKERS = ("model.json", "a/configuration.json", "b/configuration.json")
#: The record of each stage between the configurations and the model (its folder is
#: ``OUT/<stage>``): written last, so a folder holding it holds the finished stage.
STAGE_RECORDS = {"matches": "matches/matches.json", "links": "links/links.json",
                 "joints": "joints/joints.json", "refine": "refine/refine.json"}
#: How each of those stages checks a folder of an earlier run against this one (its record's
#: upstream digest, the settings it reads, seed, version, its files).
_CHECKS = {"matches": check_matches, "links": check_links, "joints": check_joints,
           "refine": check_refine}
#: What a folder holding a stage's record holds, for messages.
_HOLDS = {"matches": "matches", "links": "links", "joints": "joints", "refine": "a refinement"}


def _resolve_inputs(images, intrinsics, poses_arg, which: str):
    iset = image_set_again(images) if isinstance(images, ImageSet) else load_image_folder(images)
    intr = None
    poses = None
    if intrinsics is not None:
        intr = parse_intrinsics(intrinsics, iset.size)
    elif iset.cameras_file is not None:
        intr = load_cameras_json(iset.cameras_file)[0]
        log.info("configuration %s: intrinsics from %s", which, iset.cameras_file)
    if poses_arg is True:
        if iset.cameras_file is None:
            raise InputError(f"poses requested but {iset.root} has no cameras.json; run without "
                             "poses (SfM from the images) or add the camera file")
        intr_c, poses = load_cameras_json(iset.cameras_file)
        intr = intr or intr_c
        # where the object is, in the frame of these poses (only theirs: poses given as a dict
        # may be in another frame)
        iset = dataclasses.replace(iset, region=load_region(iset.cameras_file))
    elif isinstance(poses_arg, dict):
        poses = {Path(k).name: np.asarray(v, dtype=float) for k, v in poses_arg.items()}
    if poses is not None and intr is None:
        raise InputError(f"configuration {which}: camera poses need intrinsics too")
    if intr is not None and intr.size is not None and tuple(intr.size) != tuple(iset.size):
        raise InputError(f"configuration {which}: intrinsics are for {intr.size[0]}x{intr.size[1]}"
                         f" images but {iset.image_dir} holds {iset.size[0]}x{iset.size[1]}")
    return iset, intr, poses


def reconstruct(images_a, images_b, *, intrinsics=None, poses=None, out_dir=None, seed: int = 0,
                config: ReconstructConfig = ReconstructConfig(), overwrite: bool = False,
                progress: bool = True, jobs: int = 2, configurations: tuple | None = None,
                from_stage: str = "configurations", to_stage: str = "model"
                ) -> ArticulatedModel | None:
    """Articulated model of an object from two image sets, one per configuration.

    The whole run by default; ``from_stage`` and ``to_stage`` run part of it (:data:`STAGES`):
    ``to_stage="configurations"`` writes ``out_dir/a`` and ``out_dir/b`` and stops,
    ``to_stage="matches"`` adds ``out_dir/matches`` and stops, and so on for ``"links"``,
    ``"joints"``, ``"refine"``; a later ``from_stage`` starts from the folders an earlier run
    left in ``out_dir`` for the stages before it (with, if wanted, other settings of the stages
    it runs: ``"links"`` other segmentation or joint settings, ``"joints"`` other joint
    settings ...). The parts give the model the whole run gives (same inputs, settings and
    seed).

    Parameters
    ----------
    images_a, images_b : str, Path or ImageSet
        Folders of photos of configuration A and B (or capture folders with ``images/``), or
        the :class:`artrecon.io.ImageSet` that :func:`artrecon.io.load_image_folder` gave for
        such a folder earlier in the same run (its files are checked by their digests instead
        of decoding every image again: :func:`artrecon.io.image_set_again`).
    intrinsics : (3, 3) array, "fx,fy,cx,cy", JSON path, Intrinsics, or a pair of them, optional
        Known pinhole intrinsics (held fixed). When absent, a folder's ``cameras.json`` supplies
        them if present; otherwise COLMAP estimates them.
    poses : None, True, or a pair of dicts name -> (4, 4) ``T_world_camera``
        None (default, the method): cameras from the images alone. True: use each folder's
        ``cameras.json`` poses (the arm's forward kinematics) and only triangulate.
    out_dir : str or Path, optional
        Where to write the model, link PLYs and SfM models (see the module docstring), whole or
        not at all. Nothing is kept when None (then only the whole run).
    seed : int
    config : ReconstructConfig
    overwrite : bool
        Replace an existing ``out_dir`` (only a folder this function wrote: one holding
        ``model.json`` or the configurations' records). With a later ``from_stage``: replace
        what the run writes in an ``out_dir`` that holds it already (the stage ``from_stage``,
        the later ones, the model); the stages before ``from_stage`` are kept.
    progress : bool
        tqdm bars on stderr.
    jobs : int
        Processes for the per-configuration stage (:mod:`artrecon.configuration`): 2 runs
        configuration B beside A; 1 runs them one after the other (same result).
    configurations : (folder_a, folder_b), optional
        Folders of finished per-configuration stages of these image sets (e.g. written by the
        harness while it captured): reused when their records name the same inputs and
        settings, recomputed otherwise. Only with ``from_stage="configurations"``.
    from_stage, to_stage : {"configurations", "matches", "links", "joints", "refine", "model"}
        The first and the last stage to run (:data:`STAGES`). A later ``from_stage`` needs the
        ``out_dir`` of an earlier run of these inputs and seed (stopped after the stage before
        it, or later, or whole): the folders of the stages before it, made with this run's
        settings of those stages (the later stages' may differ); their records are checked,
        never recomputed.

    Returns
    -------
    ArticulatedModel or None
        Links with dense oriented points (model frame = configuration A's SfM frame), joints;
        None when the run stops before the model.

    Raises
    ------
    InputError
        Bad folders, images or camera files; an unknown stage, ``from_stage`` after
        ``to_stage``, or (a later ``from_stage``) an ``out_dir`` without the finished stages
        before it, of these inputs and settings (the message says what differs and where to
        start instead).
    ReconstructionError, DegenerateError
        A stage failed (the message says which and what to try). WeakEvidenceError (a
        ReconstructionError): a joint's evidence is too weak to give its axis
        (artrecon.confidence; each joint of a returned model has its ``confidence`` record).
        PoseMismatchError (a ReconstructionError): the given ``poses`` disagree with the images
        (artrecon.sfm.check_pose_agreement; a returned model records the figures in
        ``metadata["pose_agreement"]``).
    """
    t_all = time.perf_counter()
    first, last = _stage_range(from_stage, to_stage)
    if (first, last) != (0, len(STAGES) - 1) and out_dir is None:
        raise InputError(f"a run from stage {from_stage!r} to {to_stage!r} needs an output "
                         "folder (out_dir): the stages meet there")
    if first > 0 and configurations is not None:
        raise InputError(f"from stage {from_stage!r}, the configurations are those of out_dir; "
                         "give configurations= only to a run from the start")
    # One value for both sets, or a pair (a (3, 3) nested list has 3 rows, never 2).
    pair = intrinsics if isinstance(intrinsics, (tuple, list)) and len(intrinsics) == 2 \
        else (intrinsics, intrinsics)
    poses_pair = poses if isinstance(poses, (tuple, list)) else (poses, poses)
    # every image is decoded once here (checked, thumbnails): A's and B's side by side (A's
    # error, if both are bad)
    with workers.single_threaded():
        (set_a, intr_a, poses_a), (set_b, intr_b, poses_b) = workers.side_by_side(
            lambda: _resolve_inputs(images_a, pair[0], poses_pair[0], "A"),
            lambda: _resolve_inputs(images_b, pair[1], poses_pair[1], "B"))
    check_distinct(set_a, set_b)
    if out_dir is not None:
        out_dir = _check_output(out_dir, [set_a.root, set_a.image_dir, set_b.root,
                                          set_b.image_dir], overwrite, from_stage,
                                example=set_a.root.parent / "model")
    records: dict[str, dict] = {}
    if first > 0:  # the configurations of out_dir, exactly as this run would compute them
        settings = stage_settings(config.sfm, config.dense, config.region)
        restart = ("start from the configurations instead (without --from, "
                   "from_stage='configurations'), which recomputes them")
        conf_records = {key: check_reusable(out_dir / key, iset, intr, known, settings, seed,
                                     which=key.upper(), restart=restart)
                 for key, iset, intr, known in (("a", set_a, intr_a, poses_a),
                                                ("b", set_b, intr_b, poses_b))}
        configurations = (out_dir / "a", out_dir / "b")
        # and each later stage before the first, made from the one before it with this run's
        # settings of that stage
        upstream = {k: r["inputs_digest"] for k, r in conf_records.items()}
        for name in list(STAGES)[1:first]:
            records[name] = _CHECKS[name](
                out_dir / name, upstream, config, seed,
                restart=f"start from the {name} instead (--from {name}, from_stage="
                f"'{name}'), which recomputes them")
            upstream = records[name]["inputs_digest"]
    with contextlib.ExitStack() as stack:
        # the work folder (beside OUT: work_dir also removes those of interrupted runs) goes when
        # the run ends, published or not
        work = (stack.enter_context(work_dir(out_dir)) if out_dir is not None
                else Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="artrecon-"))))
        for name in records:  # the stages it starts after: copies, published with the rest
            shutil.copytree(out_dir / name, work / name, symlinks=True)
        model = _run(set_a, set_b, intr_a, intr_b, poses_a, poses_b, work, seed, config,
                     progress, jobs, configurations, records, first=first, last=last)
        if model is not None:
            model.metadata["timings"]["total"] = time.perf_counter() - t_all
        if out_dir is not None:
            if model is not None:
                model.save(work / "model.json")
            publish_dir(work, out_dir)
            log.info("wrote %s", out_dir)
    return model


def _stage_range(from_stage: str, to_stage: str) -> tuple[int, int]:
    """Indices in :data:`STAGES` of the first and the last stage to run (InputError for an
    unknown stage or a first stage after the last)."""
    names = list(STAGES)
    for flag, name in (("--from", from_stage), ("--to", to_stage)):
        if name not in STAGES:
            listing = "; ".join(f"{k} (writes {v})" for k, v in STAGES.items())
            raise InputError(f"{flag} {name}: no such stage. The stages, in order: {listing}")
    first, last = names.index(from_stage), names.index(to_stage)
    if first > last:
        raise InputError(f"--from {from_stage} comes after --to {to_stage}, so there is nothing "
                         f"to run; the stages in order: {', '.join(names)}")
    return first, last


def _check_output(out_dir, inputs, overwrite: bool, from_stage: str, example) -> Path:
    """The output folder of a run from ``from_stage``: a new folder (or, with ``overwrite``, an
    earlier result) for a run from the start; for a later start, an existing folder of an
    earlier run, holding nothing this run would write (a stage from ``from_stage`` on; a
    model) unless ``overwrite`` (what it starts from is checked by the caller, against this
    run's inputs)."""
    out_dir = Path(out_dir)
    check_output_path(out_dir, inputs, example=example)
    names = list(STAGES)
    first = names.index(from_stage)
    holds_model = (out_dir / "model.json").exists()
    finished = [n for n in STAGE_RECORDS if (out_dir / STAGE_RECORDS[n]).exists()]
    if from_stage == "configurations":
        if (out_dir.is_dir() and not overwrite and not holds_model
                and (out_dir / "a" / "configuration.json").is_file()):
            last = finished[-1] if finished else "configurations"
            held = names[:names.index(last) + 1]
            held = held[0] if len(held) == 1 else f"{', '.join(held[:-1])} and {held[-1]}"
            raise InputError(f"output folder {out_dir} exists and holds the {held} of a run "
                             f"stopped after them (--to {last}): continue it with --from "
                             f"{names[names.index(last) + 1]}, or pass --overwrite to start it "
                             "over")
        return check_output_dir(out_dir, inputs, overwrite=overwrite, marker=OUTPUT_MARKERS,
                                example=example)
    if out_dir.is_symlink() or not out_dir.is_dir():
        stopped = " or ".join(f"--to {n}" for n in names[first - 1:-1])
        raise InputError(f"--from {from_stage}: {out_dir} is not a folder; --out must name the "
                         "output folder of an earlier run of these images (whole, or stopped "
                         f"with {stopped}): run without --from to start from the beginning")
    if holds_model and not overwrite:
        raise InputError(f"--from {from_stage}: {out_dir} holds a model already (model.json); "
                         "pass --overwrite to replace it (the stages before "
                         f"{from_stage} are kept), or choose another --out")
    later = [n for n in finished if names.index(n) >= first]
    if later and not overwrite:
        raise InputError(f"--from {from_stage}: {out_dir} holds {_HOLDS[later[0]]} already "
                         f"({STAGE_RECORDS[later[0]]}): continue with --from "
                         f"{names[names.index(later[-1]) + 1]}, or pass --overwrite to run "
                         f"{from_stage} again (the stages before it are kept)")
    return out_dir


def prepare_configuration(images, out_dir, *, intrinsics=None, poses=None, seed: int = 0,
                          config: ReconstructConfig = ReconstructConfig(), which: str = "",
                          progress: bool = False) -> Path:
    """The per-configuration stage of one image set (:mod:`artrecon.configuration`), written
    to ``out_dir`` for a later :func:`reconstruct` (``configurations=``) to start from.

    ``images``, ``intrinsics`` and ``poses`` are one configuration's, as :func:`reconstruct`
    takes them. Returns ``out_dir``.
    """
    iset, intr, known = _resolve_inputs(images, intrinsics, poses, which or "?")
    _configuration(iset, Path(out_dir), intr, known, config, seed, which, progress)
    return Path(out_dir)


def _configuration(iset, folder, intr, poses, config: ReconstructConfig, seed: int, which: str,
                   progress: bool) -> Configuration:
    return reconstruct_configuration(iset, folder, intr, poses, sfm_config=config.sfm,
                                     dense_config=config.dense, region_config=config.region,
                                     seed=seed, which=which, progress=progress)


def _configuration_in_process(*args) -> None:
    """:func:`_configuration` in a worker process: the folder is the result (a pycolmap
    Reconstruction does not cross processes)."""
    _configuration(*args)


def _run(set_a, set_b, intr_a: Intrinsics | None, intr_b: Intrinsics | None, poses_a, poses_b,
         work: Path, seed: int, config: ReconstructConfig, progress: bool, jobs: int = 2,
         configurations: tuple | None = None, records: dict | None = None, first: int = 0,
         last: int = len(STAGES) - 1) -> ArticulatedModel | None:
    """The stages ``first`` to ``last`` (indices in :data:`STAGES`) into ``work``: the
    configurations (computed, or reused from copies of ``configurations``; only read back when
    ``first > 0``, the caller having checked them), then each later stage, computed into
    ``work/<stage>`` or, before ``first``, read from the copy there (``records``: the copies'
    records, which the caller checked), then the model (returned; None when the run stops
    earlier). Each stage reads the ones before it back from their folders either way."""
    records = records or {}
    timings: dict[str, float] = {}
    folders = {"a": work / "a", "b": work / "b"}
    if configurations is not None:  # finished per-configuration folders: start from copies
        for key, src in zip(("a", "b"), configurations, strict=True):
            if Path(src).is_dir():
                shutil.copytree(src, folders[key], symlinks=True)
    args = {"a": (set_a, folders["a"], intr_a, poses_a, config, seed, "A"),
            "b": (set_b, folders["b"], intr_b, poses_b, config, seed, "B")}
    confs: dict[str, Configuration] = {}
    if first > 0:
        confs = {key: load_configuration(folder) for key, folder in folders.items()}
    elif jobs > 1:
        # B in a second (spawned) process while this one does A: the two are independent
        with workers.pool(1) as pool:
            # the worker ignores Ctrl-C; this process stops it (one line, no worker traceback)
            future = workers.submit(pool, _configuration_in_process, *args["b"], False)
            try:
                confs["a"] = _configuration(*args["a"], progress)
                future.result()
            except BaseException:
                # Ctrl-C, or A failed: B's folder would not be used, and leaving the pool's
                # block waited for B's whole SfM and dense stereo before the user saw A's error
                workers.stop(pool)
                raise
        if last == 0:
            return None
        confs["b"] = load_configuration(folders["b"])
    else:
        for key in ("a", "b"):
            confs[key] = _configuration(*args[key], progress)
    if last == 0:
        return None
    for key, conf in confs.items():
        timings[f"sfm_{key}"] = conf.record["timings"]["sfm"]
        timings[f"dense_{key}"] = conf.record["timings"]["dense"]
    stage = list(STAGES).index

    def digest(name: str) -> str:  # the inputs_digest of a stage's folder in work
        return read_json(work / STAGE_RECORDS[name])["inputs_digest"]

    with workers.single_threaded():
        if first > stage("matches"):
            found = load_matches(work / "matches", records["matches"])
        else:  # written, then read back: the model is the one a run from the folder gives
            found = match_stage(confs, work / "matches", config, seed)
        if last == stage("matches"):
            return None
        if first > stage("links"):
            links = load_links(work / "links", confs, records["links"])
        else:
            links = run_links(confs, found, work / "links", config, seed)
        if last == stage("links"):
            return None
        if first > stage("joints"):
            joints = load_joints(work / "joints", records["joints"])
        else:
            joints = run_joints(confs, links, work / "joints", config, seed, digest("links"))
        if last == stage("joints"):
            return None
        if first > stage("refine"):
            refined = load_refine(work / "refine", records["refine"])
        else:
            refined = run_refine(confs, found, links, joints, work / "refine", config, seed,
                                 digest("joints"),
                                 scale_known=poses_a is not None and poses_b is not None)
        if last == stage("refine"):
            return None
        return build_model(set_a, set_b, intr_a, intr_b, poses_a, poses_b, work, seed, config,
                           confs, found, links, joints, refined, timings)
