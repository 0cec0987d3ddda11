"""The links stage: the matches in, the object's rigid links out.

Input: ``OUT/matches/`` (:mod:`artrecon.matches_stage`) and the two configurations
(:mod:`artrecon.configuration`: dense points, cameras, occluders). The steps are
:func:`artrecon.articulation.find_links`'s: the matches segmented into links (sequential
RANSAC), the base anchored to the background, the guided matches, the matches' points made one
physical point in A and B (:mod:`artrecon.match_refine`), the robust refit, the dense
points the table is seen through dropped, every dense point of A and B labelled with a link and
the moving links' motions refitted with their dense surfaces (:mod:`artrecon.surface_fit`).
Output: a folder (``OUT/links``), a contract like the matches'::

    matches.npz       the matches the links were fitted to (the guided ones appended): points_a,
                      points_b (refined photometrically where ``refined``,
                      :mod:`artrecon.match_refine`), point3D_ids_a, point3D_ids_b, votes,
                      labels (link per match, -1: none), refined; background_a, background_b
                      (the background matches). The model stage copies it to
                      OUT/matches.npz
    links.npz         the rest of the segmentation (each link's A -> B transform:
                      rotations, translations, scales; the shared scale, thresholds, scene
                      sizes, hypotheses, rms, the refit's weights and precisions; the
                      surface refit's surface_information and surface_gradient), the dense
                      labels of A and B (labels_a, labels_b), the guided matches' SfM ids
                      (guided_ids) and the base's anchors (anchor<k>_<i>: link k's background
                      matches in A and B, their weights[, precisions])
    link_<k>.ply      each link's dense oriented points (model frame: A's)
    links.json        the record, written last: the matches' inputs_digest, the settings the
                      stage reads (:func:`links_settings`), seed, artrecon version, the base
                      (root, None: the background does not show it), the surface refit's
                      report per moving link (surface), each file's SHA-256, counts and
                      timings

:func:`run_links` writes it and reads it back, :func:`check_links` refuses one that is not this
run's, :func:`load_links` reads it (the links' points rebuilt from the configurations' dense
points and the labels, as the stage built them), :func:`fitted_matches` reads its matches alone
(``sim.perturb.resegment`` corrupts them).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from artrecon import workers
from artrecon._version import __version__
from artrecon.articulation import Links, find_links, links_from_labels
from artrecon.assign import views_from_sfm
from artrecon.diagnosis import blame_poses
from artrecon.errors import DegenerateError
from artrecon.files import ply_bytes
from artrecon.procrustes import Similarity
from artrecon.segment import Segmentation
from artrecon.stage_record import (
    check_record,
    inputs_digest,
    npz_bytes,
    record_of,
    stage_settings,
    write_stage,
)

log = logging.getLogger(__name__)

#: Version of the folder contract (``links.json`` ``format``).
FORMAT = "artrecon-links/1"
#: The record, written last.
RECORD = "links.json"
#: The settings the stage reads (``--from joints`` needs them unchanged).
SETTINGS = ("segmentation", "guided", "assign", "freespace", "region", "surface", "photometric")
_REQUIRED = {"matches.npz", "links.npz"}


def links_settings(config) -> dict:
    """The settings the links stage reads, as its record holds them: segmentation, guided
    matching, dense labelling, free space and the object region's support plane (which the
    free space fits again)."""
    return stage_settings(config, SETTINGS)


def run_links(confs: dict, found, folder: Path, config, seed: int) -> Links:
    """The links of the matches ``found`` (:class:`artrecon.matches_stage.Matching`) between
    the configurations ``confs`` (``{"a": Configuration, "b": ...}``), written to ``folder``
    and read back as :func:`load_links` reads it.

    Raises
    ------
    DegenerateError
        Fewer than two links (the given camera poses named when they are the likely cause).
    """
    matches, background = found.matches, found.background
    views_a, views_b = workers.side_by_side(lambda: views_from_sfm(confs["a"].sfm),
                                            lambda: views_from_sfm(confs["b"].sfm))
    sfms = {k: c.sfm for k, c in confs.items()}
    try:
        links = find_links(matches.points_a, matches.points_b, background.points_a,
                           background.points_b, confs["a"].dense, confs["b"].dense, config,
                           seed, views_a=views_a, views_b=views_b,
                           occluders_a=confs["a"].occluders, occluders_b=confs["b"].occluders,
                           candidates=found.candidates, covariances=found.covariances,
                           tracks=(sfms["a"].reconstruction, sfms["b"].reconstruction,
                                   matches.point3D_ids_a, matches.point3D_ids_b))
    except DegenerateError as exc:
        # slightly wrong given poses show up as matches that do not move together
        raise blame_poses(exc, sfms, config.sfm) from exc
    seg = links.segmentation
    guided = links.guided_ids
    files = {
        "matches.npz": npz_bytes({
            "points_a": links.points_a, "points_b": links.points_b,
            "point3D_ids_a": np.r_[matches.point3D_ids_a, guided[:, 0]],
            "point3D_ids_b": np.r_[matches.point3D_ids_b, guided[:, 1]],
            "votes": np.r_[matches.votes, np.zeros(len(guided), np.int64)],
            "labels": seg.labels, "refined": links.refined,
            "background_a": background.points_a, "background_b": background.points_b}),
        "links.npz": npz_bytes(_links_arrays(links)),
        **{f"link_{k}.ply": ply_bytes(lk.points, lk.normals, lk.colours)
           for k, lk in enumerate(links.links)},
    }
    settings = links_settings(config)
    upstream = {"matches": found.record["inputs_digest"]}
    record = write_stage(folder, files, {
        "format": FORMAT, "inputs_digest": inputs_digest(upstream, settings, seed), **upstream,
        "settings": settings, "seed": seed, "artrecon_version": __version__,
        "root": links.root,
        "anchor_fields": {str(k): len(v) for k, v in (links.anchors or {}).items()},
        "links": seg.n_links, "guided_matches": len(guided), "surface": links.surface,
        "photometric": {"refined": int(links.refined.sum()),
                        "of": int((np.asarray(seg.labels) >= 0).sum())},
        "timings": links.timings,
    }, RECORD)
    return _read_links(Path(folder), record, confs)


def _links_arrays(links: Links) -> dict:
    seg = links.segmentation
    arrays = {
        "scale": np.float64(seg.scale),
        "rotations": np.array([t.rotation for t in seg.transforms]),
        "translations": np.array([t.translation for t in seg.transforms]),
        "scales": np.array([t.scale for t in seg.transforms], float),
        "thresholds": np.array(seg.thresholds, float), "rms": np.array(seg.rms, float),
        "hypotheses": np.array(seg.hypotheses, np.int64),
        "scene_sizes": np.array([seg.scene_size_a, seg.scene_size_b], float),
        "labels_a": links.labels_a, "labels_b": links.labels_b, "guided_ids": links.guided_ids,
    }
    if seg.weights is not None:
        arrays["weights"] = seg.weights
    if seg.precisions is not None:
        arrays["precisions"] = seg.precisions
    if seg.surface_information is not None:
        arrays["surface_information"] = seg.surface_information
        arrays["surface_gradient"] = seg.surface_gradient
    for k, anchor in (links.anchors or {}).items():
        arrays.update({f"anchor{k}_{i}": a for i, a in enumerate(anchor)})
    return arrays


def check_links(folder: Path, matches_digest: str, config, seed: int, *, restart: str) -> dict:
    """Refuse a folder that is not a finished links stage of these matches (their record's
    ``inputs_digest``), settings (:func:`links_settings`) and seed: InputError naming what
    differs and ``restart``. Returns the record."""
    return check_record(Path(folder), RECORD, FORMAT, "links", {"matches": matches_digest},
                        links_settings(config), seed, required=_REQUIRED, restart=restart)


def load_links(folder: Path, confs: dict, record: dict | None = None) -> Links:
    """The links a folder written by :func:`run_links` holds, with their dense points from
    ``confs`` (the configurations they were made from). ``record``: the folder's record,
    already checked (:func:`check_links`); without it the record is read (its files are
    trusted: check them first when the folder comes from elsewhere).
    (ReconstructionError: no record, or one of another format.)
    """
    folder = Path(folder)
    return _read_links(folder, record_of(folder, record, RECORD, FORMAT, "links"), confs)


def fitted_matches(folder: Path) -> dict:
    """The arrays of a links folder's ``matches.npz`` (see the module docstring): the matches
    the links were fitted to, their labels, the background matches."""
    with np.load(Path(folder) / "matches.npz") as npz:
        return {k: npz[k] for k in npz.files}


def _read_links(folder: Path, record: dict, confs: dict) -> Links:
    m = fitted_matches(folder)
    with np.load(folder / "links.npz") as npz:
        a = {k: npz[k] for k in npz.files}
    transforms = [Similarity(r, t, float(s)) for r, t, s in
                  zip(a["rotations"], a["translations"], a["scales"], strict=True)]
    seg = Segmentation(labels=m["labels"], transforms=transforms, scale=float(a["scale"]),
                       thresholds=a["thresholds"].tolist(),
                       scene_size_a=float(a["scene_sizes"][0]),
                       scene_size_b=float(a["scene_sizes"][1]),
                       hypotheses=a["hypotheses"].tolist(), rms=a["rms"].tolist(),
                       weights=a.get("weights"), precisions=a.get("precisions"),
                       surface_information=a.get("surface_information"),
                       surface_gradient=a.get("surface_gradient"))
    anchors = {int(k): tuple(a[f"anchor{k}_{i}"] for i in range(n))
               for k, n in record["anchor_fields"].items()} or None
    dense_a, dense_b = confs["a"].dense, confs["b"].dense
    links = links_from_labels(dense_a, dense_b, a["labels_a"], a["labels_b"], transforms)
    return Links(seg, record["root"], anchors, a["labels_a"], a["labels_b"], links,
                 m["points_a"], m["points_b"], a["guided_ids"], dict(record["timings"]),
                 record.get("surface", []), m.get("refined"))
