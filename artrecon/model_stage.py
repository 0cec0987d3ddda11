"""The model stage: the stages before it in, the articulated model out.

Input: what the earlier stages left, read back: each configuration's
(:mod:`artrecon.configuration`: its SfM model and dense points, for the model's metadata and
points), the matches (:mod:`artrecon.matches_stage`), the links (:mod:`artrecon.links_stage`),
the joints (:mod:`artrecon.joints_stage`) and their refinement (:mod:`artrecon.refine_stage`).
A whole run and a run continued from any stage start this one from the same files. Output,
written into the run's work folder (which :func:`artrecon.reconstruct.reconstruct` publishes
whole as ``OUT``)::

    matches.npz          a copy of OUT/links/matches.npz: the 3D-3D matches the links were
                         fitted to (points_a, points_b, point3D_ids_a, point3D_ids_b, votes,
                         labels; the guided matches appended) and the background matches
                         (background_a, background_b)

and the :class:`artrecon.model.ArticulatedModel` it returns (saved as ``model.json``): the
links (with the refined motions when a refined joint was adopted), the joints as the
refinement adopted them, and the metadata. It computes nothing and reads no setting of its
own: ``--from model`` only assembles the model again.
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np

from artrecon._version import __version__
from artrecon.articulation import JointSet, Links
from artrecon.joints_stage import tree_record
from artrecon.matches_stage import Matching
from artrecon.model import ArticulatedModel
from artrecon.refine_stage import Refined
from artrecon.settings import ReconstructConfig, jsonable
from artrecon.sfm import camera_summary

log = logging.getLogger(__name__)


def build_model(set_a, set_b, intr_a, intr_b, poses_a, poses_b, work: Path, seed: int,
                config: ReconstructConfig, confs: dict, found: Matching, links: Links,
                joints: JointSet, refined: Refined, timings: dict) -> ArticulatedModel:
    """The model from the stages' results.

    Parameters
    ----------
    set_a, set_b : artrecon.io.ImageSet
    intr_a, intr_b : Intrinsics or None
        The intrinsics given (None: SfM's own), for the model's metadata.
    poses_a, poses_b : dict or None
        The camera poses given: the model is then metric, in their world frame.
    work : Path
        The folder holding ``links/`` and to write ``matches.npz`` into (the caller saves the
        model).
    seed : int
    config : ReconstructConfig
        Recorded in the metadata.
    confs : dict
        ``"a"``, ``"b"``: each :class:`artrecon.configuration.Configuration`.
    found, links, joints, refined :
        The matches', links', joints' and refinement stages' results, read back.
    timings : dict
        Seconds per step so far; the later stages' (from their records) are added.

    Returns
    -------
    ArticulatedModel
    """
    matches, background = found.matches, found.background
    for stage in (found.record["timings"], links.timings, joints.timings, refined.timings):
        timings.update(stage)
    sfms = {k: c.sfm for k, c in confs.items()}
    denses = {k: c.dense for k, c in confs.items()}
    art = refined.links(links, confs)
    seg, root = art.segmentation, art.root
    shutil.copyfile(work / "links" / "matches.npz", work / "matches.npz")
    metric = poses_a is not None and poses_b is not None
    model = ArticulatedModel(
        links=art.links, joints=refined.joints, scale=1.0,
        frames={"T_world_model": np.eye(4)} if metric else {},
        root=joints.tree.root, scale_a_to_b=float(seg.scale), scale_known=metric,
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
            "confidence": joints.confidence,
            # the articulated bundle adjustment's figures (artrecon.refine), None when off
            "refinement": refined.summary,
            # every adjacent pair's figures and how clearly the tree won (artrecon.joints)
            "kinematic_tree": tree_record(joints.tree),
            "dense_unassigned": {"a": int((art.labels_a < 0).sum()),
                                 "b": int((art.labels_b < 0).sum())},
            "config": jsonable(asdict(config)),
            "timings": timings,
        })
    log.info("model: %d links, %d joints, timings %s", len(art.links), len(refined.joints),
             {k: round(v, 1) for k, v in timings.items()})
    return model
