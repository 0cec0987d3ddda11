"""The refinement stage: the joints' articulated bundle adjustment against both configurations'
images.

Input: ``OUT/links/`` and ``OUT/joints/`` (read back), the matches' background and SfM ids
(``OUT/matches/``) and each configuration's SfM model (its images' 2D observations of the
matched points). The step is :func:`refine_articulation` (:func:`artrecon.refine.refine_joints`,
``refine.*``): each joint's 1-sigma uncertainty and refined figures (in
``Joint.confidence["refinement"]``); the refined figures replace a joint only with
``refine.adopt`` (and its checks passed), and then the links' motions and points follow the
joints kept. Output: a folder (``OUT/refine``)::

    refined.json    the refinement's summary (None when ``refine.enabled`` is off), the joints
                    as adopted (model.json's encoding, each with its refinement record) and,
                    when a refined joint was adopted, each link's A -> B transform from the
                    joints kept (else None: the links stage's stand)
    link_<k>.ply    only when a refined joint was adopted: each link's dense points moved with
                    those transforms (OUT/links/link_<k>.ply keeps the links stage's)
    refine.json     the record, written last: the joints' inputs_digest, the settings
                    (``refine.*``), seed, artrecon version, each file's SHA-256, the timing

:func:`run_refine` writes it and reads it back, :func:`check_refine` refuses one that is not
this run's, :func:`load_refine` reads it.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from artrecon import workers
from artrecon._version import __version__
from artrecon.articulation import JointSet, Links, links_from_labels
from artrecon.files import ply_bytes, read_json
from artrecon.model import joint_from_dict, joint_to_dict
from artrecon.procrustes import Similarity
from artrecon.refine import RefineConfig, Refinement, refine_joints, tracks_of, views_of
from artrecon.stage_record import (
    check_record,
    inputs_digest,
    record_of,
    stage_settings,
    write_stage,
)

log = logging.getLogger(__name__)

#: Version of the folder contract (``refine.json`` ``format``).
FORMAT = "artrecon-refine/1"
#: The record, written last.
RECORD = "refine.json"
#: The settings the stage reads (``--from model`` needs them unchanged).
SETTINGS = ("refine",)
_REQUIRED = {"refined.json"}


@dataclass
class Refined:
    """What the refinement stage leaves (:func:`load_refine`)."""

    joints: list
    """The joints as adopted (the joints stage's, each with its refinement record)."""
    transforms: list[Similarity] | None
    """Each link's A -> B motion from the joints kept, when a refined joint was adopted; None:
    the links stage's motions stand."""
    summary: dict | None
    """:attr:`artrecon.refine.Refinement.summary`; None when the refinement is off."""
    timings: dict[str, float]

    def links(self, links: Links, confs: dict) -> Links:
        """``links`` with the refined motions (their dense points moved with them), or
        ``links`` when no refined joint was adopted."""
        if self.transforms is None:
            return links
        seg = replace(links.segmentation, transforms=list(self.transforms))
        moved = links_from_labels(confs["a"].dense, confs["b"].dense, links.labels_a,
                                  links.labels_b, seg.transforms)
        return replace(links, segmentation=seg, links=moved)


def run_refine(confs: dict, found, links: Links, joints: JointSet, folder: Path, config,
               seed: int, joints_digest: str, *, scale_known: bool) -> Refined:
    """The refinement of ``joints`` (the joints stage's folder read back; its record's
    ``inputs_digest`` is ``joints_digest``) on ``links`` and the matches ``found``, against
    the SfM models of ``confs``; written to ``folder`` and read back as :func:`load_refine`
    reads it. ``scale_known``: both configurations in one metric frame (given camera poses).
    """
    timings: dict[str, float] = {}
    out = None
    if config.refine.enabled:
        t = time.perf_counter()
        matches = found.matches
        # SfM point ids of the matches the links were fitted to (the guided ones appended)
        ids_a = np.r_[matches.point3D_ids_a, links.guided_ids[:, 0]]
        ids_b = np.r_[matches.point3D_ids_b, links.guided_ids[:, 1]]
        # the background anchors the base, as it did in the links' fit (when it shows the base)
        anchor = found.background if links.root is not None else None
        out = refine_articulation(links, joints, {k: c.sfm for k, c in confs.items()}, ids_a,
                                  ids_b, anchor, scale_known=scale_known, config=config.refine)
        timings["refine"] = time.perf_counter() - t
    adopted = out is not None and any(out.accepted)
    refined = {"summary": None if out is None else out.summary,
               "joints": [joint_to_dict(j) for j in (joints.joints if out is None
                                                      else out.joints)],
               "transforms": [t.to_dict() for t in out.transforms] if adopted else None}
    files = {"refined.json": json.dumps(refined, indent=1).encode()}
    result = _refined(refined, timings)
    if adopted:
        moved = result.links(links, confs).links
        files.update({f"link_{k}.ply": ply_bytes(lk.points, lk.normals, lk.colours)
                      for k, lk in enumerate(moved)})
    settings = stage_settings(config, SETTINGS)
    upstream = {"joints": joints_digest}
    record = write_stage(folder, files, {
        "format": FORMAT, "inputs_digest": inputs_digest(upstream, settings, seed), **upstream,
        "settings": settings, "seed": seed, "artrecon_version": __version__,
        "adopted": adopted, "timings": timings,
    }, RECORD)
    return _read_refine(Path(folder), record)


def refine_articulation(links: Links, joints: JointSet, sfms: dict, ids_a: np.ndarray,
                        ids_b: np.ndarray, background=None, *, scale_known: bool,
                        config: RefineConfig) -> Refinement:
    """The ``joints`` of ``links`` refined against both configurations' images
    (:func:`artrecon.refine.refine_joints`; each SfM point's track of 2D observations).

    Parameters
    ----------
    links : Links
    joints : JointSet
    sfms : dict
        ``"a"``, ``"b"``: each configuration's SfM result (its pycolmap reconstruction).
    ids_a, ids_b : (n,) int
        SfM point ids of ``links.points_a`` / ``links.points_b``, row for row.
    background : artrecon.features.CrossMatches, optional
        The background's matches (points and SfM ids): they move with the base (the room it
        stands in), as in the links' fit (:func:`artrecon.link_motions.anchor_base`).
    scale_known : bool
        Both configurations in one metric frame (given camera poses).
    config : RefineConfig
    """
    views_a, rows_a = views_of(sfms["a"].reconstruction)
    views_b, rows_b = views_of(sfms["b"].reconstruction)
    seg = links.segmentation
    root = joints.tree.root
    points_a, points_b, labels = links.points_a, links.points_b, seg.labels
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
        return refine_joints(points_a, labels, tracks_a, tracks_b, views_a, views_b,
                             joints.joints, root, seg.transforms[root], seg.n_links,
                             scale_known=scale_known, points_b=points_b,
                             populations=populations, config=config)


def check_refine(folder: Path, joints_digest: str, config, seed: int, *, restart: str) -> dict:
    """Refuse a folder that is not a finished refinement stage of these joints (their record's
    ``inputs_digest``), settings (``refine.*``) and seed: InputError naming what differs and
    ``restart``. Returns the record."""
    return check_record(Path(folder), RECORD, FORMAT, "refined joints",
                        {"joints": joints_digest}, stage_settings(config, SETTINGS), seed,
                        required=_REQUIRED, restart=restart)


def load_refine(folder: Path, record: dict | None = None) -> Refined:
    """What a folder written by :func:`run_refine` holds (``record``: its record, already
    checked by :func:`check_refine`; without it, read, the files trusted).
    (ReconstructionError: no record, or one of another format.)
    """
    folder = Path(folder)
    return _read_refine(folder, record_of(folder, record, RECORD, FORMAT, "refined joints"))


def _read_refine(folder: Path, record: dict) -> Refined:
    return _refined(read_json(folder / "refined.json"), dict(record["timings"]))


def _refined(refined: dict, timings: dict) -> Refined:
    transforms = refined["transforms"]
    return Refined([joint_from_dict(j) for j in refined["joints"]],
                   None if transforms is None else [Similarity.from_dict(t)
                                                    for t in transforms],
                   refined["summary"], timings)
