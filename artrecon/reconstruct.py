"""The whole reconstruction: two image folders in, an articulated model out.

Stages (each its own module, plain data between them)::

    sfm (per configuration) -> dense (per configuration) -> object region -> features (A x B)
        -> segment_links -> dense points the table is seen through dropped (artrecon.freespace)
        -> dense points assigned to links -> estimate_joints -> ArticulatedModel

Where they live: this module is the entry (:func:`reconstruct`: the inputs checked, the output
folder, which stages run); :mod:`artrecon.configuration` is the per-configuration stage (SfM,
dense points, object region); :mod:`artrecon.matches_stage` the matches stage (matching A x B
lifted to 3D-3D pairs, the background's, the guided matching's candidates, the covariances);
:mod:`artrecon.model_stage` the model stage (the model and its files), which calls
:func:`artrecon.articulation.articulate` for every step after matching (the links' motions:
:mod:`artrecon.link_motions`). The settings of every stage are one
:class:`artrecon.settings.ReconstructConfig`.

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
    OUT/links/link_<k>.ply            dense oriented points of each link (model frame)
    OUT/a/sparse/0, OUT/b/sparse/0    the SfM models in COLMAP's layout (+ database.db, colmap.log)
    OUT/a/dense.ply, OUT/b/dense.ply  the object's dense points of each configuration (own frame)
    OUT/a/configuration.json, ...     the per-configuration stage's record and its other files
                                      (the folder contract of artrecon.configuration)
    OUT/matches/                      the matches stage's folder: the matches as matched, the
                                      background's, the guided matching's candidates, the
                                      covariances, the record matches.json (the folder
                                      contract of artrecon.matches_stage)
    OUT/matches.npz                   the 3D-3D matches the links were fitted to (points_a,
                                      points_b, ids, votes, labels; the guided ones appended),
                                      background_a, background_b

Running part of it (:data:`STAGES`; ``from_stage``/``to_stage``, the command's ``--from`` and
``--to``). The folder holds the result of three stages; a run may stop after any of them and
start at any of them::

    configurations   images -> OUT/a, OUT/b (each: SfM, dense points, object region; written
                     side by side, the record configuration.json last)
    matches          OUT/a, OUT/b -> OUT/matches/ (the record matches.json last)
    model            OUT/a, OUT/b, OUT/matches/ -> OUT/matches.npz, OUT/links/, OUT/model.json

``to_stage="configurations"`` publishes a folder holding OUT/a and OUT/b only,
``to_stage="matches"`` one holding OUT/matches/ too. A later start takes such a folder (or a
whole result, with ``overwrite``) and checks what it starts from against this run, never
recomputing it quietly (InputError naming what differs and which stage to start from instead):
each configuration's record must name the same images, intrinsics, poses, settings (sfm, dense,
region), seed and artrecon version as this run (``from_stage="matches"`` or ``"model"``), and
the matches' record (``from_stage="model"``) the same configurations (their records' digests),
match settings (:func:`artrecon.matches_stage.match_settings`: ``match.*`` and
``segmentation.covariances``), seed and version, with its files whole. The settings of the
model stage (segmentation, guided matching, joints, assignment ...) may differ: re-running the
links and joints with other settings does not match again. The folder is published again
whole, the stages before ``from_stage`` copied and the later ones added.

The continued run's model is the one the whole run gives, bit for bit (tests/test_stages.py):
the whole run reads configuration B back from its folder too (A's folder holds what A's stage
returned, artrecon.configuration), and its model stage reads the matches back from OUT/matches/
as a run ``from_stage="model"`` does. Nothing finer is a stage: a configuration's SfM and dense
points share one record, so a folder whose dense stage failed holds no result a later run could
check; the links, joints and dense labels are one stage (:func:`artrecon.articulation.articulate`
runs them in order).
"""

from __future__ import annotations

import contextlib
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
    work_dir,
)
from artrecon.io import (
    Intrinsics,
    check_distinct,
    load_cameras_json,
    load_image_folder,
    parse_intrinsics,
)
from artrecon.matches_stage import check_matches, load_matches, match_stage
from artrecon.model import ArticulatedModel
from artrecon.model_stage import build_model
from artrecon.settings import ReconstructConfig, with_settings

log = logging.getLogger(__name__)

#: The entry points (``with_settings`` and ``ReconstructConfig`` make the ``config`` that
#: :func:`reconstruct` takes; they live in :mod:`artrecon.settings`).
__all__ = ["STAGES", "ReconstructConfig", "prepare_configuration", "reconstruct",
           "with_settings"]

#: The stages a run can start at or stop after (:func:`reconstruct`'s ``from_stage`` and
#: ``to_stage``, the command's ``--from`` and ``--to``), in order, with what each leaves in the
#: output folder for the next. Only these three: the output folder keeps nothing finer that a
#: later run could check and start from (a configuration's SfM and dense points are one record,
#: :mod:`artrecon.configuration`; links, joints and dense labels are saved together).
STAGES = {
    "configurations": "OUT/a and OUT/b: each configuration's cameras (SfM), dense points and "
                      "object region",
    "matches": "OUT/matches/: the 3D-3D matches across A and B, the background matches, the "
               "guided matching's candidates and the covariances",
    "model": "OUT/matches.npz, OUT/links/, OUT/model.json: links, joints",
}
#: Files that tell a folder written by :func:`reconstruct` (whole, or stopped after the
#: configurations or the matches) from any other folder.
OUTPUT_MARKERS = ("model.json", "a/configuration.json", "b/configuration.json")
#: The matches stage's record in the output folder (:mod:`artrecon.matches_stage`).
MATCHES_RECORD = "matches/matches.json"



def _resolve_inputs(images, intrinsics, poses_arg, which: str):
    iset = load_image_folder(images)
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
    ``to_stage="matches"`` adds ``out_dir/matches`` and stops; ``from_stage="matches"`` starts
    from the configurations of an existing ``out_dir``, ``from_stage="model"`` from its
    configurations and matches (with, if wanted, other settings of the model stage:
    segmentation, joints ...). The parts give the model the whole run gives (same inputs,
    settings and seed).

    Parameters
    ----------
    images_a, images_b : str or Path
        Folders of photos of configuration A and B (or capture folders with ``images/``).
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
        what the run writes in an ``out_dir`` that holds it already (``"matches"``: its matches
        and model; ``"model"``: its model); the stages before ``from_stage`` are kept.
    progress : bool
        tqdm bars on stderr.
    jobs : int
        Processes for the per-configuration stage (:mod:`artrecon.configuration`): 2 runs
        configuration B beside A; 1 runs them one after the other (same result).
    configurations : (folder_a, folder_b), optional
        Folders of finished per-configuration stages of these image sets (e.g. written by the
        harness while it captured): reused when their records name the same inputs and
        settings, recomputed otherwise. Only with ``from_stage="configurations"``.
    from_stage, to_stage : {"configurations", "matches", "model"}
        The first and the last stage to run (:data:`STAGES`). A later ``from_stage`` needs the
        ``out_dir`` of an earlier run of these inputs and seed (stopped after the stage before
        it, or later, or whole): ``"matches"`` its configurations (of these settings),
        ``"model"`` its configurations and matches (of these configuration and match settings;
        the model stage's may differ); their records are checked, never recomputed.

    Returns
    -------
    ArticulatedModel or None
        Links with dense oriented points (model frame = configuration A's SfM frame), joints;
        None when the run stops after the configurations or the matches.

    Raises
    ------
    InputError
        Bad folders, images or camera files; an unknown stage, ``from_stage`` after
        ``to_stage``, or (a later ``from_stage``) an ``out_dir`` without finished
        configurations (or, ``"model"``, matches) of these inputs and settings (the message
        says what differs).
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
    matches = None
    if first > 0:  # the configurations of out_dir, exactly as this run would compute them
        settings = stage_settings(config.sfm, config.dense, config.region)
        restart = ("start from the configurations instead (without --from, "
                   "from_stage='configurations'), which recomputes them")
        records = {key: check_reusable(out_dir / key, iset, intr, known, settings, seed,
                                       which=key.upper(), restart=restart)
                   for key, iset, intr, known in (("a", set_a, intr_a, poses_a),
                                                  ("b", set_b, intr_b, poses_b))}
        configurations = (out_dir / "a", out_dir / "b")
        if first > 1:  # and its matches, made from them with this run's matching settings
            check_matches(out_dir / "matches",
                          {k: r["inputs_digest"] for k, r in records.items()}, config, seed,
                          restart="start from the matches instead (--from matches, "
                          "from_stage='matches'), which recomputes them from OUT/a and OUT/b")
            matches = out_dir / "matches"
    with contextlib.ExitStack() as stack:
        # the work folder (beside OUT: work_dir also removes those of interrupted runs) goes when
        # the run ends, published or not
        work = (stack.enter_context(work_dir(out_dir)) if out_dir is not None
                else Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="artrecon-"))))
        model = _run(set_a, set_b, intr_a, intr_b, poses_a, poses_b, work, seed, config,
                     progress, jobs, configurations, matches, first=first, last=last)
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
    earlier run, holding nothing this run would write (the matches, from ``"matches"``; a
    model) unless ``overwrite`` (what it starts from is checked by the caller, against this
    run's inputs)."""
    out_dir = Path(out_dir)
    check_output_path(out_dir, inputs, example=example)
    holds_model = (out_dir / "model.json").exists()
    holds_matches = (out_dir / MATCHES_RECORD).exists()
    if from_stage == "configurations":
        if (out_dir.is_dir() and not overwrite and not holds_model
                and (out_dir / "a" / "configuration.json").is_file()):
            stopped, next_stage = (("the configurations and matches of a run stopped after "
                                    "them (--to matches)", "model") if holds_matches else
                                   ("the configurations of a run stopped after them "
                                    "(--to configurations)", "matches"))
            raise InputError(f"output folder {out_dir} exists and holds {stopped}: continue "
                             f"it with --from {next_stage}, or pass --overwrite to start it "
                             "over")
        return check_output_dir(out_dir, inputs, overwrite=overwrite, marker=OUTPUT_MARKERS,
                                example=example)
    if out_dir.is_symlink() or not out_dir.is_dir():
        raise InputError(f"--from {from_stage}: {out_dir} is not a folder; --out must name the "
                         "output folder of an earlier run of these images (whole, or stopped "
                         "with --to configurations or --to matches): run without --from to "
                         "start from the beginning")
    if holds_model and not overwrite:
        raise InputError(f"--from {from_stage}: {out_dir} holds a model already (model.json); "
                         "pass --overwrite to replace it (the stages before "
                         f"{from_stage} are kept), or choose another --out")
    if from_stage == "matches" and holds_matches and not overwrite:
        raise InputError(f"--from matches: {out_dir} holds matches already ({MATCHES_RECORD}): "
                         "continue with --from model, or pass --overwrite to match again "
                         "(its configurations are kept)")
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
         configurations: tuple | None = None, matches: Path | None = None, first: int = 0,
         last: int = len(STAGES) - 1) -> ArticulatedModel | None:
    """The stages ``first`` to ``last`` (indices in :data:`STAGES`) into ``work``: the
    configurations (computed, or reused from copies of ``configurations``; only read back when
    ``first > 0``, the caller having checked them), the matches (computed into ``work/matches``,
    or, when ``first > 1``, a copy of ``matches``, which the caller checked), then the model
    (returned; None when the run stops earlier). The model stage reads the matches back from
    ``work/matches`` either way."""
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
            except KeyboardInterrupt:
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
    with workers.single_threaded():
        if first > 1:
            shutil.copytree(matches, work / "matches", symlinks=True)
            found = load_matches(work / "matches")
        else:  # written, then read back: the model is the one a run from the folder gives
            found = match_stage(confs, work / "matches", config, seed)
        if last == 1:
            return None
        sfms = {k: c.sfm for k, c in confs.items()}
        denses = {k: c.dense for k, c in confs.items()}
        occluders = {k: c.occluders for k, c in confs.items()}
        return build_model(set_a, set_b, intr_a, intr_b, poses_a, poses_b, work, seed, config,
                           sfms, denses, occluders, found, timings)
