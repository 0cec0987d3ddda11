"""The model stage: the two configurations and their matches in, the articulated model out.

Input: what :mod:`artrecon.configuration` left for each configuration (its SfM model, dense
points, occluders) and what :mod:`artrecon.matches_stage` left in ``OUT/matches/``, read back
(the object's and the background's 3D-3D matches, the guided matching's candidates, the
triangulation covariances; :func:`artrecon.matches_stage.load_matches`): a whole run and a run
continued from the matches (``--from model``) start from the same files. Output, written into
the run's work folder (which :func:`artrecon.reconstruct.reconstruct` publishes whole as
``OUT``)::

    matches.npz          the 3D-3D matches the links were fitted to (points_a, points_b,
                         point3D_ids_a, point3D_ids_b, votes, labels; the guided matches
                         appended) and the background matches (background_a, background_b)
    links/link_<k>.ply   each link's dense oriented points (model frame)

and the :class:`artrecon.model.ArticulatedModel` it returns (saved as ``model.json``).

Steps: :func:`artrecon.articulation.articulate` (links, base, dense labels, kinematic tree,
joints, their evidence), the joints' articulated bundle adjustment against both configurations'
images (:func:`refine_articulation`, ``refine.*``: each joint's uncertainty and refined figures
in ``Joint.confidence["refinement"]``; the refined figures replace the joint only with
``refine.adopt``), then the model with its metadata. Of the settings, this stage reads the
segmentation's, guided matching's, joints', assignment's, free space's, confidence's and
refinement's, which may differ from the run that matched (``segmentation.covariances``
excepted: whether the covariances were computed is the matches stage's), and some of the
configurations' (sfm, region), which their records fix.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from artrecon import workers
from artrecon._version import __version__
from artrecon.articulation import Articulation, articulate, links_from_labels
from artrecon.assign import views_from_sfm
from artrecon.errors import DegenerateError, ReconstructionError, WeakEvidenceError
from artrecon.files import write_ply
from artrecon.joints import KinematicTree
from artrecon.matches_stage import Matching
from artrecon.model import ArticulatedModel
from artrecon.refine import RefineConfig, Refinement, refine_joints, tracks_of, views_of
from artrecon.settings import ReconstructConfig, jsonable
from artrecon.sfm import SfMConfig, camera_summary

log = logging.getLogger(__name__)


def build_model(set_a, set_b, intr_a, intr_b, poses_a, poses_b, work: Path, seed: int,
                config: ReconstructConfig, sfms: dict, denses: dict, occluders: dict,
                found: Matching, timings: dict) -> ArticulatedModel:
    """The model stage, from the two configurations on (the caller runs it with one BLAS and
    OpenCV thread per task, A's and B's own work side by side).

    Parameters
    ----------
    set_a, set_b : artrecon.io.ImageSet
    intr_a, intr_b : Intrinsics or None
        The intrinsics given (None: SfM's own), for the model's metadata.
    poses_a, poses_b : dict or None
        The camera poses given: the model is then metric, in their world frame.
    work : Path
        The folder to write ``matches.npz`` and ``links/`` into (the caller saves the model).
    seed : int
    config : ReconstructConfig
    sfms, denses, occluders : dict
        Per configuration (``"a"``, ``"b"``), from its
        :class:`artrecon.configuration.Configuration`: the SfM result, dense points, occluders.
    found : artrecon.matches_stage.Matching
        The matches stage's folder, read back (:func:`artrecon.matches_stage.load_matches`):
        the object's and the background's matches, the guided matching's candidates and the
        covariances (None when ``config.segmentation.covariances`` was off for the matching).
    timings : dict
        Seconds per step so far; the matching's (from the matches' record) and this stage's
        are added.

    Returns
    -------
    ArticulatedModel
    """
    matches, background = found.matches, found.background
    timings["match"] = found.record["timings"]["match"]
    views_a, views_b = workers.side_by_side(lambda: views_from_sfm(sfms["a"]),
                                            lambda: views_from_sfm(sfms["b"]))
    try:
        art = articulate(matches.points_a, matches.points_b, background.points_a,
                         background.points_b, denses["a"], denses["b"], config, seed,
                         views_a=views_a, views_b=views_b,
                         occluders_a=occluders["a"], occluders_b=occluders["b"],
                         candidates=found.candidates, covariances=found.covariances)
    except (DegenerateError, WeakEvidenceError) as exc:
        # slightly wrong given poses show up as matches that do not move together
        raise blame_poses(exc, sfms, config.sfm) from exc
    timings.update(art.timings)
    # SfM point ids of the matches the links were fitted to (the guided ones appended)
    ids_a = np.r_[matches.point3D_ids_a, art.guided_ids[:, 0]]
    ids_b = np.r_[matches.point3D_ids_b, art.guided_ids[:, 1]]
    refinement = None
    if config.refine.enabled:
        t = time.perf_counter()
        # the background anchors the base, as it did in the links' fit (when it shows the base)
        anchor = background if art.root is not None else None
        art, refinement = refine_articulation(art, sfms, ids_a, ids_b, denses, anchor,
                                              scale_known=poses_a is not None
                                              and poses_b is not None, config=config.refine)
        timings["refine"] = time.perf_counter() - t
    seg, links, root = art.segmentation, art.links, art.root
    np.savez(work / "matches.npz", points_a=art.points_a, points_b=art.points_b,
             point3D_ids_a=ids_a, point3D_ids_b=ids_b,
             votes=np.r_[matches.votes, np.zeros(len(art.guided_ids), np.int64)],
             labels=seg.labels, background_a=background.points_a,
             background_b=background.points_b)
    (work / "links").mkdir(exist_ok=True)
    for k, lk in enumerate(links):
        write_ply(work / "links" / f"link_{k}.ply", lk.points, lk.normals, lk.colours)
    metric = poses_a is not None and poses_b is not None
    model = ArticulatedModel(
        links=links, joints=art.joints, scale=1.0,
        frames={"T_world_model": np.eye(4)} if metric else {},
        root=art.tree.root, scale_a_to_b=float(seg.scale), scale_known=metric,
        metadata={
            "artrecon_version": __version__, "seed": seed,
            "images_a": str(set_a.root), "images_b": str(set_b.root),
            "camera_poses": "given (known-pose triangulation)" if metric else "SfM from images",
            # given poses against the images, per configuration (artrecon.sfm.pose_agreement)
            "pose_agreement": {k: s.pose_agreement for k, s in sfms.items()
                               if s.pose_agreement is not None} or None,
            "model_frame": "world frame of configuration A's camera poses (metres)" if metric
            else "configuration A's SfM frame (arbitrary scale)",
            # the focal length SfM used: given, from EXIF, or self-calibrated (and refined)
            "intrinsics": {k: camera_summary(s.reconstruction, intr is not None,
                                             s.model_dir.parents[1])
                           for (k, s), intr in zip(sfms.items(), (intr_a, intr_b), strict=True)},
            "registered_images": {k: s.reconstruction.num_reg_images() for k, s in sfms.items()},
            "num_images": {k: s.num_images for k, s in sfms.items()},
            "sparse_points": {k: s.reconstruction.num_points3D() for k, s in sfms.items()},
            "dense_points": {k: len(d) for k, d in denses.items()},
            "matches": len(matches), "guided_matches": len(art.guided_ids),
            "match_outliers": int((seg.labels < 0).sum()),
            "background_matches": len(background),
            "root_from": "background" if root is not None else "largest link",
            "root_background_matches": len(art.anchors[root][0]) if art.anchors else 0,
            "link_matches": seg.sizes.tolist(),
            "confidence": art.confidence,
            # the articulated bundle adjustment's figures (artrecon.refine), None when off
            "refinement": None if refinement is None else refinement.summary,
            # every adjacent pair's figures and how clearly the tree won (artrecon.joints)
            "kinematic_tree": tree_record(art.tree),
            "dense_unassigned": {"a": int((art.labels_a < 0).sum()),
                                 "b": int((art.labels_b < 0).sum())},
            "config": jsonable(asdict(config)),
            "timings": timings,
        })
    log.info("model: %d links, %d joints, timings %s", len(links), len(art.joints),
             {k: round(v, 1) for k, v in timings.items()})
    return model


def refine_articulation(art: Articulation, sfms: dict, ids_a: np.ndarray, ids_b: np.ndarray,
                        denses: dict, background=None, *, scale_known: bool,
                        config: RefineConfig
                        ) -> tuple[Articulation, Refinement]:
    """The joints of ``art`` refined against both configurations' images
    (:func:`artrecon.refine.refine_joints`; each SfM point's track of 2D observations), and the
    links' motions and dense points that follow from the joints kept.

    Parameters
    ----------
    art : Articulation
    sfms : dict
        ``"a"``, ``"b"``: each configuration's SfM result (its pycolmap reconstruction).
    ids_a, ids_b : (n,) int
        SfM point ids of ``art.points_a`` / ``art.points_b``, row for row.
    denses : dict
        Each configuration's dense points (the links' points are re-assembled with the refined
        motions).
    background : artrecon.features.CrossMatches, optional
        The background's matches (points and SfM ids): they move with the base (the room it
        stands in), as in the links' fit (:func:`artrecon.link_motions.anchor_base`).
    scale_known : bool
        Both configurations in one metric frame (given camera poses).
    config : RefineConfig
    """
    views_a, rows_a = views_of(sfms["a"].reconstruction)
    views_b, rows_b = views_of(sfms["b"].reconstruction)
    seg = art.segmentation
    root = art.tree.root
    points_a, points_b, labels = art.points_a, art.points_b, seg.labels
    populations = labels  # each link's matches; the background's their own
    if background is not None and len(background):
        points_a = np.r_[points_a, background.points_a]
        points_b = np.r_[points_b, background.points_b]
        labels = np.r_[labels, np.full(len(background), root)]
        populations = np.r_[seg.labels, np.full(len(background), seg.n_links)]
        ids_a = np.r_[ids_a, background.point3D_ids_a]
        ids_b = np.r_[ids_b, background.point3D_ids_b]
    tracks_a = tracks_of(sfms["a"].reconstruction, ids_a, rows_a)
    tracks_b = tracks_of(sfms["b"].reconstruction, ids_b, rows_b)
    with workers.single_threaded():  # small products; one thread, the same sums every run
        out = refine_joints(points_a, labels, tracks_a, tracks_b, views_a, views_b,
                            art.joints, root, seg.transforms[root], seg.n_links,
                            scale_known=scale_known, points_b=points_b, populations=populations,
                            config=config)
    if not any(out.accepted):  # the joints stay, and so do the links' motions and points
        return replace(art, joints=out.joints), out
    seg = replace(seg, transforms=list(out.transforms))
    links = links_from_labels(denses["a"], denses["b"], art.labels_a, art.labels_b,
                              seg.transforms)
    return replace(art, segmentation=seg, joints=out.joints, links=links), out


def blame_poses(err: Exception, sfms: dict, config: SfMConfig) -> Exception:
    """``err`` (a segmentation or joint-evidence failure) with the given camera poses named as its
    likely cause, when they were given and agree with the images worse than
    ``config.suspect_pose_epipolar_px`` (though well enough to pass the pose check); else ``err``.

    Slightly wrong poses (encoder noise, a camera mount error) put each configuration's points
    in slightly different wrong places, so the matches across configurations stop moving
    together, and segmentation blames the matches ("chance pairings", "too few inliers").
    """
    figures = {k: s.pose_agreement["epipolar_median_px"] for k, s in sfms.items()
               if s.pose_agreement and s.pose_agreement.get("epipolar_median_px") is not None}
    if not any(v > config.suspect_pose_epipolar_px for v in figures.values()):
        return err
    note = (" Likely cause: the given camera poses. They passed the pose check but agree with the "
            "images only to a median " + ", ".join(f"{v:.2f} px ({k.upper()})"
                                                   for k, v in sorted(figures.items()))
            + " from the epipolar lines they predict (exact poses: ~0.1 px); such poses "
            "(a hand-eye / camera mount calibration error, arm encoder errors) put the points of "
            "the two configurations in differently wrong places, so their matches no longer move "
            "together. Run without the poses (without --use-poses) so SfM recovers the cameras "
            "from the images, or recalibrate the camera mount and the arm.")
    if isinstance(err, WeakEvidenceError):
        return WeakEvidenceError(str(err) + note, err.records)
    try:
        return type(err)(str(err) + note)
    except TypeError:  # an error class with another constructor
        return ReconstructionError(str(err) + note)


def tree_record(tree: KinematicTree) -> dict:
    """The tree's choice, for model.json: its edges, its margin over the next best tree and every
    adjacent pair's figures (:attr:`KinematicTree.edge_figures`)."""
    return {"edges": [list(e) for e in tree.edges], "root": int(tree.root),
            "margin": float(tree.margin) if np.isfinite(tree.margin) else None,
            "pairs": [{"links": list(pair), **{k: (list(v) if isinstance(v, tuple) else v)
                                               for k, v in fig.items()}}
                      for pair, fig in sorted(tree.edge_figures.items())]}
